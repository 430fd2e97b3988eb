//! L-BFGS with a More-Thuente line search and box constraints by projection.
//!
//! The direction is the two-loop recursion (Nocedal & Wright, *Numerical
//! Optimization*, Alg. 7.4) over the last `m` curvature pairs `(s, y)`, scaled by
//! `gamma = s.y / y.y` from the newest pair. Pairs with `s.y <= eps y.y` are skipped
//! (L-BFGS-B's test), which keeps the inverse Hessian positive definite.
//!
//! # Bounds: projected L-BFGS with an active set, not full L-BFGS-B
//!
//! At each iteration the variables sitting on a bound that the gradient pushes
//! against are *active*: they are frozen by masking them out of the gradient fed to
//! the two-loop recursion and out of the direction it returns, `d = -P_F H P_F g`.
//! That `d` is a descent direction whenever `H` is positive definite
//! (`g.d = -(P_F g)' H (P_F g) < 0`). The line search then runs along the projected
//! path `P(x + a d)`, so many variables can hit their bounds in one iteration
//! (dark env-map texels reaching zero all at once), which is what L-BFGS-B's
//! generalized Cauchy point buys, at a fraction of its code (no compact
//! representation, no subspace minimization). On problems without bounds the method
//! is exactly L-BFGS, so evaluation counts compare with SciPy's L-BFGS-B.
//! The price: along a kinked path strong Wolfe may be unattainable; the line search
//! then accepts its best sufficient-decrease point, like L-BFGS-B with MINPACK's warnings.
//!
//! A failed line search discards the curvature memory and restarts from steepest
//! descent; a second failure in a row ends the run with the line search's reason.

use crate::linesearch::{Line, Point};
use crate::solver::Stopping;
use crate::{Bounds, MoreThuente, Objective, OptimError, Solver, State, Termination};

/// Builder for [`Lbfgs`]; every setting has a default (SciPy's where it has one).
#[derive(Debug, Clone)]
pub struct LbfgsBuilder {
    history: usize,
    stopping: Stopping,
    cost_tol: f64,
    bounds: Option<Bounds>,
    line_search: MoreThuente,
}

impl LbfgsBuilder {
    /// Curvature pairs kept, `m` (default 10).
    pub fn history(mut self, m: usize) -> Self {
        self.history = m;
        self
    }

    /// Stop when the projected gradient's infinity norm is at most this (default 1e-5).
    pub fn grad_tol(mut self, tol: f64) -> Self {
        self.stopping.grad_tol = tol;
        self
    }

    /// Stop when the relative decrease of one iteration is at most this (default 2.2e-9).
    pub fn cost_tol(mut self, tol: f64) -> Self {
        self.cost_tol = tol;
        self
    }

    /// Iteration budget (default 15000).
    pub fn max_iters(mut self, n: usize) -> Self {
        self.stopping.max_iters = n;
        self
    }

    /// Evaluation budget, counting line-search trials (default 15000).
    pub fn max_evals(mut self, n: usize) -> Self {
        self.stopping.max_evals = n;
        self
    }

    /// Box constraints (default none); their length must match `x0`.
    pub fn bounds(mut self, bounds: Bounds) -> Self {
        self.bounds = Some(bounds);
        self
    }

    /// Line-search constants (default [`MoreThuente::default`]).
    pub fn line_search(mut self, line_search: MoreThuente) -> Self {
        self.line_search = line_search;
        self
    }

    /// Validates the settings.
    pub fn build(self) -> Result<Lbfgs, OptimError> {
        OptimError::check(self.history > 0, "history", "must be >= 1", self.history)?;
        OptimError::check(
            self.cost_tol >= 0.0,
            "cost_tol",
            "must be >= 0 (and not NaN)",
            self.cost_tol,
        )?;
        self.stopping.validate()?;
        self.line_search.validate()?;
        Ok(Lbfgs {
            config: self,
            memory: Memory::default(),
            bounds: Bounds::unbounded(0),
            direction: Vec::new(),
            trial: Point::zeros(0),
            best: Point::zeros(0),
            rel_change: f64::INFINITY,
        })
    }
}

/// Limited-memory BFGS for smooth deterministic objectives, optionally box-constrained.
#[derive(Debug, Clone)]
pub struct Lbfgs {
    config: LbfgsBuilder,
    memory: Memory,
    bounds: Bounds,
    direction: Vec<f64>,
    trial: Point,
    best: Point,
    rel_change: f64,
}

impl Lbfgs {
    /// A builder with the defaults.
    pub fn builder() -> LbfgsBuilder {
        LbfgsBuilder {
            history: 10,
            stopping: Stopping {
                grad_tol: 1e-5,
                max_iters: 15_000,
                max_evals: 15_000,
            },
            cost_tol: 2.2e-9,
            bounds: None,
            line_search: MoreThuente::default(),
        }
    }

    /// Fills `self.direction` with `-P_F H P_F g` and returns `g.d`; active variables get 0.
    fn compute_direction(&mut self, state: &State) -> f64 {
        let d = &mut self.direction;
        for (i, di) in d.iter_mut().enumerate() {
            *di = if self.bounds.is_active(i, state.x[i], state.grad[i]) {
                0.0
            } else {
                -state.grad[i]
            };
        }
        self.memory.apply_inverse_hessian(d);
        let mut slope = 0.0;
        for (i, di) in d.iter_mut().enumerate() {
            let (x, lo, hi) = (state.x[i], self.bounds.lower()[i], self.bounds.upper()[i]);
            // Active variables stay frozen; free ones on a bound that `H` would push
            // outward would be clipped at once, so they are frozen too.
            let frozen = self.bounds.is_active(i, x, state.grad[i]) || (x <= lo && *di < 0.0) || (x >= hi && *di > 0.0);
            if frozen {
                *di = 0.0;
            }
            slope += *di * state.grad[i];
        }
        slope
    }
}

impl Solver for Lbfgs {
    fn init<O: Objective>(&mut self, objective: &mut O, x0: Vec<f64>) -> Result<State, OptimError> {
        if objective.is_stochastic() {
            return Err(OptimError::StochasticObjective { solver: "Lbfgs" });
        }
        let n = x0.len();
        self.bounds = match &self.config.bounds {
            Some(b) if b.len() != n => {
                return Err(OptimError::WrongLength {
                    field: "x0",
                    expected: b.len(),
                    actual: n,
                });
            }
            Some(b) => b.clone(),
            None => Bounds::unbounded(n),
        };
        self.memory = Memory::new(self.config.history, n);
        self.direction = vec![0.0; n];
        self.trial = Point::zeros(n);
        self.best = Point::zeros(n);
        self.rel_change = f64::INFINITY;
        Ok(State::start(objective, x0, &self.bounds))
    }

    fn step<O: Objective>(&mut self, objective: &mut O, state: &mut State) {
        let mut slope = self.compute_direction(state);
        let descends = slope < 0.0;
        if !descends && !self.memory.is_empty() {
            // Rounding can make the quasi-Newton direction ascend; steepest descent cannot.
            self.memory.clear();
            state.restarts += 1;
            slope = self.compute_direction(state);
        }
        // Without curvature information the scale of `d` is unknown: try a unit-length
        // step, as L-BFGS-B does on its first iteration.
        let first_step = if self.memory.is_empty() {
            1.0 / norm(&self.direction)
        } else {
            1.0
        };
        let line = Line {
            x: &state.x,
            value: state.value,
            direction: &self.direction,
            slope,
            first_step,
        };
        let budget = self.config.stopping.max_evals.saturating_sub(state.evals);
        let out =
            self.config
                .line_search
                .search(objective, &self.bounds, &line, budget, &mut self.trial, &mut self.best);
        state.evals += out.evals;
        state.rejected += out.rejected;
        match out.step {
            Ok(step) => {
                self.memory.push(&self.best.x, &state.x, &self.best.grad, &state.grad);
                std::mem::swap(&mut state.x, &mut self.best.x);
                std::mem::swap(&mut state.grad, &mut self.best.grad);
                let previous = state.value;
                state.value = self.best.value;
                state.grad_norm = self.bounds.projected_grad_norm(&state.x, &state.grad);
                state.step_size = step;
                state.record_best();
                self.rel_change = (previous - state.value) / previous.abs().max(state.value.abs()).max(1.0);
            }
            // The evaluation budget, not the search, ran out: `terminate` reports it.
            Err(_) if state.evals >= self.config.stopping.max_evals => {}
            Err(reason) if self.memory.is_empty() => {
                state.termination = Some(Termination::LineSearchFailed(reason));
            }
            Err(_) => {
                self.memory.clear();
                state.restarts += 1;
            }
        }
    }

    fn terminate(&self, state: &State) -> Option<Termination> {
        let stalled = self.rel_change <= self.config.cost_tol;
        self.config
            .stopping
            .check(state)
            .or(stalled.then_some(Termination::CostChange))
    }
}

/// The last `m` curvature pairs in a ring buffer, stored flat (`m x n`) so steps never allocate.
#[derive(Debug, Clone, Default)]
struct Memory {
    n: usize,
    capacity: usize,
    s: Vec<f64>,
    y: Vec<f64>,
    /// `1 / s.y` per pair.
    rho: Vec<f64>,
    /// Scratch for the first loop's coefficients.
    alpha: Vec<f64>,
    /// Slot of the oldest pair.
    start: usize,
    len: usize,
}

impl Memory {
    fn new(capacity: usize, n: usize) -> Self {
        Memory {
            n,
            capacity,
            s: vec![0.0; capacity * n],
            y: vec![0.0; capacity * n],
            rho: vec![0.0; capacity],
            alpha: vec![0.0; capacity],
            start: 0,
            len: 0,
        }
    }

    fn is_empty(&self) -> bool {
        self.len == 0
    }

    fn clear(&mut self) {
        self.len = 0;
    }

    /// Slot of the `k`-th oldest pair.
    fn slot(&self, k: usize) -> usize {
        (self.start + k) % self.capacity
    }

    /// Stores `s = x_new - x`, `y = g_new - g` unless `s.y <= eps y.y` (no positive curvature).
    fn push(&mut self, x_new: &[f64], x: &[f64], g_new: &[f64], g: &[f64]) {
        let (mut sy, mut yy) = (0.0, 0.0);
        for i in 0..self.n {
            let (s, y) = (x_new[i] - x[i], g_new[i] - g[i]);
            sy += s * y;
            yy += y * y;
        }
        let curved = sy > f64::EPSILON * yy;
        if !curved {
            return;
        }
        let slot = if self.len < self.capacity {
            self.len += 1;
            self.slot(self.len - 1)
        } else {
            let oldest = self.start;
            self.start = (self.start + 1) % self.capacity;
            oldest
        };
        let range = slot * self.n..(slot + 1) * self.n;
        for (i, (s, y)) in self.s[range.clone()].iter_mut().zip(&mut self.y[range]).enumerate() {
            *s = x_new[i] - x[i];
            *y = g_new[i] - g[i];
        }
        self.rho[slot] = 1.0 / sy;
    }

    fn pair(&self, slot: usize) -> (&[f64], &[f64]) {
        let range = slot * self.n..(slot + 1) * self.n;
        (&self.s[range.clone()], &self.y[range])
    }

    /// Replaces `q` by `H q` with the two-loop recursion; `H = I` without pairs.
    fn apply_inverse_hessian(&mut self, q: &mut [f64]) {
        for k in (0..self.len).rev() {
            let slot = self.slot(k);
            let (s, y) = self.pair(slot);
            let a = self.rho[slot] * dot(s, q);
            axpy(-a, y, q);
            self.alpha[slot] = a;
        }
        if self.len > 0 {
            let (s, y) = self.pair(self.slot(self.len - 1));
            let gamma = dot(s, y) / dot(y, y);
            q.iter_mut().for_each(|v| *v *= gamma);
        }
        for k in 0..self.len {
            let slot = self.slot(k);
            let (s, y) = self.pair(slot);
            let b = self.rho[slot] * dot(y, q);
            axpy(self.alpha[slot] - b, s, q);
        }
    }
}

/// Lanes of [`dot`]'s independent partial sums.
const DOT_LANES: usize = 8;

/// `a . b` in [`DOT_LANES`] partial sums added pairwise: one running sum
/// chains every add on the one before (a lighting solve's 10^5 unknowns,
/// 20 dot products an iteration); independent lanes vectorise. The order
/// is fixed, so the result does not depend on the machine.
fn dot(a: &[f64], b: &[f64]) -> f64 {
    let mut lanes = [0.0; DOT_LANES];
    let (a_chunks, a_rest) = a.as_chunks::<DOT_LANES>();
    let (b_chunks, b_rest) = b.as_chunks::<DOT_LANES>();
    for (x, y) in a_chunks.iter().zip(b_chunks) {
        for k in 0..DOT_LANES {
            lanes[k] += x[k] * y[k];
        }
    }
    for (k, (x, y)) in a_rest.iter().zip(b_rest).enumerate() {
        lanes[k] += x * y;
    }
    let mut width = DOT_LANES;
    while width > 1 {
        width /= 2;
        for k in 0..width {
            lanes[k] += lanes[k + width];
        }
    }
    lanes[0]
}

/// `y += a x`.
fn axpy(a: f64, x: &[f64], y: &mut [f64]) {
    y.iter_mut().zip(x).for_each(|(yi, xi)| *yi += a * xi);
}

fn norm(v: &[f64]) -> f64 {
    dot(v, v).sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn dot_sums_every_product_whatever_the_length() {
        // Lengths below, at and past the lanes, with a remainder: against the plain sum.
        for n in [0, 1, 7, 8, 9, 31, 100] {
            let a: Vec<f64> = (0..n).map(|i| 1.0 + i as f64 * 0.5).collect();
            let b: Vec<f64> = (0..n).map(|i| 2.0 - i as f64 * 0.25).collect();
            let plain: f64 = a.iter().zip(&b).map(|(x, y)| x * y).sum();
            assert!((dot(&a, &b) - plain).abs() <= 1e-12 * plain.abs().max(1.0), "n = {n}");
        }
    }

    #[test]
    fn two_loop_inverts_a_quadratic_after_n_exact_pairs() {
        // On f = x'Ax/2 with A = diag(1, 4), pairs (e_i, A e_i) make H = A^-1 exactly.
        let mut memory = Memory::new(10, 2);
        memory.push(&[1.0, 0.0], &[0.0, 0.0], &[1.0, 0.0], &[0.0, 0.0]);
        memory.push(&[1.0, 1.0], &[1.0, 0.0], &[1.0, 4.0], &[1.0, 0.0]);
        let mut q = [2.0, 8.0];
        memory.apply_inverse_hessian(&mut q);
        assert!((q[0] - 2.0).abs() < 1e-14 && (q[1] - 2.0).abs() < 1e-14, "{q:?}");
    }

    #[test]
    fn skips_pairs_without_positive_curvature() {
        let mut memory = Memory::new(3, 1);
        memory.push(&[1.0], &[0.0], &[-1.0], &[0.0]);
        assert!(memory.is_empty());
    }

    #[test]
    fn builder_names_the_broken_rule() {
        let err = Lbfgs::builder().history(0).build().unwrap_err();
        assert_eq!(err.to_string(), "optim: setting `history` = 0 must be >= 1");
        assert!(Lbfgs::builder().grad_tol(-1.0).build().is_err());
        assert!(Lbfgs::builder().cost_tol(f64::NAN).build().is_err());
    }
}
