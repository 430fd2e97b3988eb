//! The shape every solver shares: `init` / `step` / `terminate` over a [`State`].

use crate::{Objective, OptimError, State, Termination};

/// Receives the state after initialization and after every iteration (progress bars, plots).
pub trait Observer {
    /// Called with the state after each iteration; the default does nothing.
    fn observe(&mut self, _state: &State) {}
}

/// The no-op observer.
impl Observer for () {}

impl<F: FnMut(&State)> Observer for F {
    fn observe(&mut self, state: &State) {
        self(state)
    }
}

/// An iterative minimizer in the style of argmin: explicit state, one iteration per `step`.
///
/// ```
/// use optim::{Lbfgs, Solver};
/// let mut f = |x: &[f64], g: &mut [f64]| {
///     g[0] = 2.0 * (x[0] - 3.0);
///     (x[0] - 3.0).powi(2)
/// };
/// let mut solver = Lbfgs::builder().build()?;
/// // The loop `minimize` runs, spelled out:
/// let mut state = solver.init(&mut f, vec![0.0])?;
/// while state.termination.is_none() {
///     state.termination = solver.terminate(&state);
///     if state.termination.is_none() {
///         solver.step(&mut f, &mut state);
///         state.iter += 1;
///     }
/// }
/// assert!((state.best_x[0] - 3.0).abs() < 1e-8);
/// # Ok::<(), optim::OptimError>(())
/// ```
pub trait Solver {
    /// Checks `x0` against the configuration, evaluates it and returns the initial state.
    fn init<O: Objective>(&mut self, objective: &mut O, x0: Vec<f64>) -> Result<State, OptimError>;

    /// Performs one iteration; sets `state.termination` itself only on failure.
    fn step<O: Objective>(&mut self, objective: &mut O, state: &mut State);

    /// The reason to stop before the next iteration, if any.
    fn terminate(&self, state: &State) -> Option<Termination>;

    /// Runs from `x0` until a termination reason is found.
    fn minimize<O: Objective>(&mut self, objective: &mut O, x0: Vec<f64>) -> Result<State, OptimError>
    where
        Self: Sized,
    {
        self.minimize_observed(objective, x0, &mut ())
    }

    /// Like [`Solver::minimize`], reporting every iteration to `observer`.
    fn minimize_observed<O: Objective, B: Observer>(
        &mut self,
        objective: &mut O,
        x0: Vec<f64>,
        observer: &mut B,
    ) -> Result<State, OptimError>
    where
        Self: Sized,
    {
        let mut state = self.init(objective, x0)?;
        observer.observe(&state);
        while state.termination.is_none() {
            state.termination = self.terminate(&state);
            if state.termination.is_none() {
                self.step(objective, &mut state);
                state.iter += 1;
                observer.observe(&state);
            }
        }
        Ok(state)
    }
}

/// Stopping rules both solvers share; `check` is their part of `Solver::terminate`.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Stopping {
    pub grad_tol: f64,
    pub max_iters: usize,
    pub max_evals: usize,
}

impl Stopping {
    /// Validates the tolerances (budgets of 0 are allowed: they stop before the first step).
    pub fn validate(&self) -> Result<(), OptimError> {
        OptimError::check(
            self.grad_tol >= 0.0,
            "grad_tol",
            "must be >= 0 (and not NaN)",
            self.grad_tol,
        )
    }

    /// The first shared rule that `state` meets.
    pub fn check(&self, state: &State) -> Option<Termination> {
        if state.grad_norm <= self.grad_tol {
            Some(Termination::GradientTolerance)
        } else if state.iter >= self.max_iters {
            Some(Termination::MaxIters)
        } else if state.evals >= self.max_evals {
            Some(Termination::MaxEvals)
        } else {
            None
        }
    }
}
