//! Adam with parameter groups, schedules, clipping, box projection and reduce-on-plateau.
//!
//! The update is bias-corrected Adam (Kingma & Ba 2015, Alg. 1):
//! `m = b1 m + (1-b1) g`, `v = b2 v + (1-b2) g^2`,
//! `x -= lr_t (m / (1-b1^t)) / (sqrt(v / (1-b2^t)) + eps)`, then `x` is clamped into
//! its group's box. Each group is a contiguous range of the parameter vector with its
//! own rate, betas, bounds and schedule (e.g. pose in one group, env-map texels in
//! another, the latter with `lower = 0`).
//!
//! Adam needs only gradients that are right on average, which is why it is the solver
//! for Monte Carlo objectives. A step whose value or gradient is not finite is
//! rejected: the parameters stay where they were and every group's rate is halved
//! (a back-off); too many back-offs in a row end the run with [`Termination::NonFinite`].

use std::ops::Range;

use crate::objective::all_finite;
use crate::schedule::{Constant, Schedule};
use crate::solver::Stopping;
use crate::{Bounds, Objective, OptimError, Solver, State, Termination};

/// A contiguous range of parameters sharing a learning rate, betas, bounds and schedule.
pub struct ParamGroup {
    range: Range<usize>,
    lr: f64,
    beta1: f64,
    beta2: f64,
    eps: f64,
    lower: f64,
    upper: f64,
    schedule: Box<dyn Schedule>,
}

impl ParamGroup {
    /// Parameters `range` with learning rate `lr`, betas (0.9, 0.999), eps 1e-8, unbounded, constant rate.
    pub fn new(range: Range<usize>, lr: f64) -> Self {
        ParamGroup {
            range,
            lr,
            beta1: 0.9,
            beta2: 0.999,
            eps: 1e-8,
            lower: f64::NEG_INFINITY,
            upper: f64::INFINITY,
            schedule: Box::new(Constant),
        }
    }

    /// Decay rates of the first and second moment estimates, each in [0, 1).
    pub fn betas(mut self, beta1: f64, beta2: f64) -> Self {
        self.beta1 = beta1;
        self.beta2 = beta2;
        self
    }

    /// The denominator's floor, which bounds the step where gradients vanish.
    pub fn eps(mut self, eps: f64) -> Self {
        self.eps = eps;
        self
    }

    /// Box `[lower, upper]` for every parameter of the group, enforced by projection.
    pub fn bounds(mut self, lower: f64, upper: f64) -> Self {
        self.lower = lower;
        self.upper = upper;
        self
    }

    /// Multiplies the rate by `schedule.factor(iteration)`.
    pub fn schedule(mut self, schedule: impl Schedule + 'static) -> Self {
        self.schedule = Box::new(schedule);
        self
    }

    fn validate(&self, k: usize, start: usize) -> Result<(), OptimError> {
        let field = |name: &str| format!("group[{k}].{name}");
        let r = &self.range;
        OptimError::check(
            r.start == start,
            field("range"),
            "must start where the previous group ends",
            r,
        )?;
        OptimError::check(r.start < r.end, field("range"), "must not be empty", r)?;
        OptimError::check(
            self.lr >= 0.0 && self.lr.is_finite(),
            field("lr"),
            "must be finite and >= 0",
            self.lr,
        )?;
        for (name, beta) in [("beta1", self.beta1), ("beta2", self.beta2)] {
            OptimError::check((0.0..1.0).contains(&beta), field(name), "must be in [0, 1)", beta)?;
        }
        OptimError::check(
            self.eps > 0.0 && self.eps.is_finite(),
            field("eps"),
            "must be finite and > 0",
            self.eps,
        )?;
        OptimError::check(
            self.lower <= self.upper,
            field("bounds"),
            "must have lower <= upper",
            (self.lower, self.upper),
        )
    }
}

/// Gradient clipping applied before the moment updates.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum GradClip {
    /// Rescale the whole gradient so its Euclidean norm is at most this.
    Norm(f64),
    /// Clamp each component to `[-c, c]`.
    Value(f64),
}

/// Reduce-on-plateau: scale every rate by `factor` after `patience` iterations
/// without a relative improvement of `threshold` in the value.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Plateau {
    /// Iterations without improvement before a reduction.
    pub patience: usize,
    /// Multiplier applied at each reduction, in (0, 1).
    pub factor: f64,
    /// Relative improvement that counts, `best - value > threshold |best|`.
    pub threshold: f64,
    /// Smallest overall rate scale; a plateau at this scale ends the run.
    pub min_scale: f64,
}

impl Default for Plateau {
    fn default() -> Self {
        Plateau {
            patience: 10,
            factor: 0.5,
            threshold: 1e-4,
            min_scale: 1e-3,
        }
    }
}

impl Plateau {
    fn validate(&self) -> Result<(), OptimError> {
        OptimError::check(self.patience > 0, "plateau.patience", "must be > 0", self.patience)?;
        OptimError::check(
            self.factor > 0.0 && self.factor < 1.0,
            "plateau.factor",
            "must be in (0, 1)",
            self.factor,
        )?;
        OptimError::check(
            self.threshold >= 0.0,
            "plateau.threshold",
            "must be >= 0",
            self.threshold,
        )?;
        OptimError::check(
            self.min_scale > 0.0 && self.min_scale <= 1.0,
            "plateau.min_scale",
            "must be in (0, 1]",
            self.min_scale,
        )
    }
}

/// Builder for [`Adam`] over `n` parameters.
pub struct AdamBuilder {
    n: usize,
    groups: Vec<ParamGroup>,
    clip: Option<GradClip>,
    plateau: Option<Plateau>,
    stopping: Stopping,
    max_backoffs: usize,
}

impl AdamBuilder {
    /// Adds the next group; groups must tile `0..n` in order.
    pub fn group(mut self, group: ParamGroup) -> Self {
        self.groups.push(group);
        self
    }

    /// Clips gradients before they enter the moments (default none).
    pub fn clip(mut self, clip: GradClip) -> Self {
        self.clip = Some(clip);
        self
    }

    /// Enables reduce-on-plateau (default off).
    pub fn plateau(mut self, plateau: Plateau) -> Self {
        self.plateau = Some(plateau);
        self
    }

    /// Stop when the projected gradient's infinity norm is at most this (default 0: exact zero).
    pub fn grad_tol(mut self, tol: f64) -> Self {
        self.stopping.grad_tol = tol;
        self
    }

    /// Iteration budget (default 1000).
    pub fn max_iters(mut self, n: usize) -> Self {
        self.stopping.max_iters = n;
        self
    }

    /// Evaluation budget (default unlimited).
    pub fn max_evals(mut self, n: usize) -> Self {
        self.stopping.max_evals = n;
        self
    }

    /// Consecutive rejected (non-finite) steps tolerated, each halving the rates (default 20).
    pub fn max_backoffs(mut self, n: usize) -> Self {
        self.max_backoffs = n;
        self
    }

    /// Validates the groups and settings.
    pub fn build(self) -> Result<Adam, OptimError> {
        OptimError::check(!self.groups.is_empty(), "groups", "must hold at least one group", 0)?;
        let mut bounds = Bounds::unbounded(self.n);
        let mut end = 0;
        for (k, group) in self.groups.iter().enumerate() {
            group.validate(k, end)?;
            end = group.range.end;
            OptimError::check(
                end <= self.n,
                format!("group[{k}].range"),
                "must end within the n parameters",
                &group.range,
            )?;
            bounds = bounds.with_range(group.range.clone(), group.lower, group.upper)?;
        }
        OptimError::check(end == self.n, "groups", "must cover all n parameters", (end, self.n))?;
        if let Some(GradClip::Norm(c) | GradClip::Value(c)) = self.clip {
            OptimError::check(c > 0.0, "clip", "must be > 0", c)?;
        }
        if let Some(p) = &self.plateau {
            p.validate()?;
        }
        self.stopping.validate()?;
        let n = self.n;
        Ok(Adam {
            config: self,
            bounds,
            m: vec![0.0; n],
            v: vec![0.0; n],
            trial: vec![0.0; n],
            trial_grad: vec![0.0; n],
            t: 0,
            scale: 1.0,
            backoffs: 0,
            plateau_best: f64::INFINITY,
            plateau_wait: 0,
            plateau_exhausted: false,
        })
    }
}

/// Bias-corrected Adam over parameter groups; steps allocate nothing.
pub struct Adam {
    config: AdamBuilder,
    bounds: Bounds,
    m: Vec<f64>,
    v: Vec<f64>,
    trial: Vec<f64>,
    trial_grad: Vec<f64>,
    /// Moment updates so far (the `t` of the bias correction).
    t: u64,
    /// Overall rate scale from back-offs and plateaus.
    scale: f64,
    /// Consecutive rejected steps.
    backoffs: usize,
    plateau_best: f64,
    plateau_wait: usize,
    plateau_exhausted: bool,
}

impl Adam {
    /// A builder for `n` parameters with no groups yet.
    pub fn builder(n: usize) -> AdamBuilder {
        AdamBuilder {
            n,
            groups: Vec::new(),
            clip: None,
            plateau: None,
            stopping: Stopping {
                grad_tol: 0.0,
                max_iters: 1000,
                max_evals: usize::MAX,
            },
            max_backoffs: 20,
        }
    }

    /// The box built from the groups' bounds.
    pub fn bounds(&self) -> &Bounds {
        &self.bounds
    }

    /// Factor that maps the raw gradient to the clipped one under `GradClip::Norm`.
    fn norm_clip_factor(&self, grad: &[f64]) -> f64 {
        match self.config.clip {
            Some(GradClip::Norm(c)) => {
                let norm = grad.iter().map(|g| g * g).sum::<f64>().sqrt();
                if norm > c { c / norm } else { 1.0 }
            }
            _ => 1.0,
        }
    }

    /// Updates the plateau counters with an accepted value; may lower `scale`.
    fn track_plateau(&mut self, value: f64) {
        let Some(p) = self.config.plateau else { return };
        if value < self.plateau_best - p.threshold * self.plateau_best.abs() {
            self.plateau_best = value;
            self.plateau_wait = 0;
            return;
        }
        self.plateau_wait += 1;
        if self.plateau_wait >= p.patience {
            self.plateau_wait = 0;
            if self.scale <= p.min_scale {
                self.plateau_exhausted = true;
            }
            self.scale = (self.scale * p.factor).max(p.min_scale);
        }
    }
}

impl Solver for Adam {
    fn init<O: Objective>(&mut self, objective: &mut O, x0: Vec<f64>) -> Result<State, OptimError> {
        if x0.len() != self.config.n {
            return Err(OptimError::WrongLength {
                field: "x0",
                expected: self.config.n,
                actual: x0.len(),
            });
        }
        self.m.fill(0.0);
        self.v.fill(0.0);
        self.t = 0;
        self.scale = 1.0;
        self.backoffs = 0;
        self.plateau_wait = 0;
        self.plateau_exhausted = false;
        let mut state = State::start(objective, x0, &self.bounds);
        state.step_size = self.config.groups[0].lr;
        self.plateau_best = state.value;
        Ok(state)
    }

    fn step<O: Objective>(&mut self, objective: &mut O, state: &mut State) {
        self.t += 1;
        let clip_factor = self.norm_clip_factor(&state.grad);
        let clip_value = match self.config.clip {
            Some(GradClip::Value(c)) => c,
            _ => f64::INFINITY,
        };
        for (k, group) in self.config.groups.iter().enumerate() {
            let lr = group.lr * group.schedule.factor(state.iter) * self.scale;
            if k == 0 {
                state.step_size = lr;
            }
            let bias1 = 1.0 - group.beta1.powf(self.t as f64);
            let bias2 = 1.0 - group.beta2.powf(self.t as f64);
            for i in group.range.clone() {
                let g = (state.grad[i] * clip_factor).clamp(-clip_value, clip_value);
                self.m[i] = group.beta1 * self.m[i] + (1.0 - group.beta1) * g;
                self.v[i] = group.beta2 * self.v[i] + (1.0 - group.beta2) * g * g;
                let update = (self.m[i] / bias1) / ((self.v[i] / bias2).sqrt() + group.eps);
                self.trial[i] = (state.x[i] - lr * update).clamp(group.lower, group.upper);
            }
        }
        let value = objective.eval(&self.trial, &mut self.trial_grad);
        state.evals += 1;
        if !all_finite(value, &self.trial_grad) {
            // Keep `x`; the moments already hold this gradient, so the retry re-weights
            // it slightly rather than losing it.
            state.rejected += 1;
            state.restarts += 1;
            self.scale *= 0.5;
            self.backoffs += 1;
            if self.backoffs > self.config.max_backoffs {
                state.termination = Some(Termination::NonFinite);
            }
            return;
        }
        self.backoffs = 0;
        std::mem::swap(&mut state.x, &mut self.trial);
        std::mem::swap(&mut state.grad, &mut self.trial_grad);
        state.value = value;
        state.grad_norm = self.bounds.projected_grad_norm(&state.x, &state.grad);
        state.record_best();
        self.track_plateau(value);
    }

    fn terminate(&self, state: &State) -> Option<Termination> {
        if self.plateau_exhausted {
            Some(Termination::Plateau)
        } else {
            self.config.stopping.check(state)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn field_of(err: OptimError) -> String {
        match err {
            OptimError::InvalidSetting { field, .. } => field,
            other => panic!("expected InvalidSetting, got {other:?}"),
        }
    }

    #[test]
    fn builder_names_the_broken_field() {
        let build = |g: ParamGroup| Adam::builder(4).group(g).build().err().map(field_of);
        assert_eq!(build(ParamGroup::new(0..4, -1.0)), Some("group[0].lr".into()));
        assert_eq!(
            build(ParamGroup::new(0..4, 0.1).betas(0.9, 1.0)),
            Some("group[0].beta2".into())
        );
        assert_eq!(
            build(ParamGroup::new(0..4, 0.1).bounds(1.0, 0.0)),
            Some("group[0].bounds".into())
        );
        assert_eq!(build(ParamGroup::new(0..3, 0.1)), Some("groups".into()));
        let gap = Adam::builder(4)
            .group(ParamGroup::new(0..2, 0.1))
            .group(ParamGroup::new(3..4, 0.1))
            .build();
        assert_eq!(gap.err().map(field_of), Some("group[1].range".into()));
        let clip = Adam::builder(1)
            .group(ParamGroup::new(0..1, 0.1))
            .clip(GradClip::Norm(0.0))
            .build();
        assert_eq!(clip.err().map(field_of), Some("clip".into()));
        assert!(Adam::builder(1).group(ParamGroup::new(0..1, 0.1)).build().is_ok());
    }

    #[test]
    fn first_step_moves_every_coordinate_by_lr() {
        // With bias correction the first update is lr * g / |g| (up to eps), whatever the scale of g.
        let mut adam = Adam::builder(2).group(ParamGroup::new(0..2, 0.1)).build().unwrap();
        let mut f = |x: &[f64], g: &mut [f64]| {
            g[0] = 1e3;
            g[1] = -1e-3;
            1e3 * x[0] - 1e-3 * x[1]
        };
        let mut state = adam.init(&mut f, vec![0.0, 0.0]).unwrap();
        adam.step(&mut f, &mut state);
        assert!(
            (state.x[0] + 0.1).abs() < 1e-9 && (state.x[1] - 0.1).abs() < 1e-5,
            "{:?}",
            state.x
        );
    }
}
