//! The function being minimized: a value-and-gradient callback.

/// A differentiable objective: returns `f(x)` and writes `∇f(x)` into `grad`.
///
/// Implemented for closures `FnMut(&[f64], &mut [f64]) -> f64`, so a tape-computed
/// loss plugs in as `|x, g| { tape.forward(x); tape.backward(g) }`.
pub trait Objective {
    /// Evaluates the value at `x` and overwrites `grad` (same length as `x`) with the gradient.
    fn eval(&mut self, x: &[f64], grad: &mut [f64]) -> f64;

    /// Whether values and gradients are noisy estimates (Monte Carlo); L-BFGS refuses these.
    fn is_stochastic(&self) -> bool {
        false
    }
}

impl<F: FnMut(&[f64], &mut [f64]) -> f64> Objective for F {
    fn eval(&mut self, x: &[f64], grad: &mut [f64]) -> f64 {
        self(x, grad)
    }
}

/// True when the value and every gradient component are finite numbers.
pub(crate) fn all_finite(value: f64, grad: &[f64]) -> bool {
    value.is_finite() && grad.iter().all(|g| g.is_finite())
}
