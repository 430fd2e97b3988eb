//! The explicit, inspectable state of a run and the reasons a run ends.

use std::fmt;

use crate::objective::all_finite;
use crate::{Bounds, LineSearchError, Objective};

/// Why a run ended.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Termination {
    /// The projected gradient's infinity norm fell to the tolerance.
    GradientTolerance,
    /// The relative decrease `(f_prev - f) / max(|f_prev|, |f|, 1)` fell to the tolerance.
    CostChange,
    /// The iteration budget is spent.
    MaxIters,
    /// The evaluation budget is spent.
    MaxEvals,
    /// The line search failed even from steepest descent.
    LineSearchFailed(LineSearchError),
    /// The objective kept returning NaN or infinity; the best finite point is kept.
    NonFinite,
    /// Reduce-on-plateau hit its learning-rate floor and the value still stalled.
    Plateau,
}

impl Termination {
    /// Whether the reason certifies convergence rather than a spent budget or a failure.
    pub fn converged(&self) -> bool {
        matches!(self, Termination::GradientTolerance | Termination::CostChange)
    }
}

impl fmt::Display for Termination {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Termination::GradientTolerance => write!(f, "projected gradient norm below tolerance"),
            Termination::CostChange => write!(f, "relative cost change below tolerance"),
            Termination::MaxIters => write!(f, "iteration budget spent"),
            Termination::MaxEvals => write!(f, "evaluation budget spent"),
            Termination::LineSearchFailed(e) => write!(f, "line search failed: {e}"),
            Termination::NonFinite => write!(f, "objective returned non-finite values"),
            Termination::Plateau => write!(f, "value stalled at the learning-rate floor"),
        }
    }
}

/// Everything a run knows after each iteration; solvers update it, observers read it.
#[derive(Debug, Clone)]
pub struct State {
    /// Completed iterations.
    pub iter: usize,
    /// Objective evaluations (value and gradient together), including rejected ones.
    pub evals: usize,
    /// Current parameters (always finite and inside the bounds).
    pub x: Vec<f64>,
    /// Objective value at `x`.
    pub value: f64,
    /// Gradient at `x`.
    pub grad: Vec<f64>,
    /// Infinity norm of the projected gradient at `x`.
    pub grad_norm: f64,
    /// Parameters with the lowest value seen.
    pub best_x: Vec<f64>,
    /// Lowest value seen (`+inf` until a finite value is seen).
    pub best_value: f64,
    /// Last accepted step length (L-BFGS) or learning rate of the first group (Adam).
    pub step_size: f64,
    /// Evaluations rejected because the value or gradient was not finite.
    pub rejected: usize,
    /// Times the solver discarded its curvature memory (L-BFGS) or backed off its rate (Adam).
    pub restarts: usize,
    /// Why the run ended; `None` while it runs.
    pub termination: Option<Termination>,
}

impl State {
    /// Projects `x0`, evaluates it and fills a fresh state; a non-finite start ends the run.
    pub(crate) fn start<O: Objective>(objective: &mut O, mut x0: Vec<f64>, bounds: &Bounds) -> Self {
        bounds.project(&mut x0);
        let mut grad = vec![0.0; x0.len()];
        let value = objective.eval(&x0, &mut grad);
        let finite = all_finite(value, &grad);
        let mut state = State {
            iter: 0,
            evals: 1,
            best_x: x0.clone(),
            best_value: if finite { value } else { f64::INFINITY },
            grad_norm: if finite {
                bounds.projected_grad_norm(&x0, &grad)
            } else {
                f64::INFINITY
            },
            x: x0,
            value,
            grad,
            step_size: 0.0,
            rejected: 0,
            restarts: 0,
            termination: None,
        };
        if !finite {
            state.rejected = 1;
            state.termination = Some(Termination::NonFinite);
        }
        state
    }

    /// Copies `x` into `best_x` if `value` is the lowest seen.
    pub(crate) fn record_best(&mut self) {
        if self.value < self.best_value {
            self.best_value = self.value;
            self.best_x.copy_from_slice(&self.x);
        }
    }
}
