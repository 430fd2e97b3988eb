//! Box constraints `lower <= x <= upper`, per parameter.

use std::ops::Range;

use crate::OptimError;

/// Per-parameter box `lower[i] <= x[i] <= upper[i]`; infinite ends mean unbounded.
#[derive(Debug, Clone, PartialEq)]
pub struct Bounds {
    lower: Vec<f64>,
    upper: Vec<f64>,
}

impl Bounds {
    /// No constraint on any of the `n` parameters.
    pub fn unbounded(n: usize) -> Self {
        Bounds {
            lower: vec![f64::NEG_INFINITY; n],
            upper: vec![f64::INFINITY; n],
        }
    }

    /// Explicit per-parameter ends; checks equal lengths and `lower <= upper`.
    pub fn new(lower: Vec<f64>, upper: Vec<f64>) -> Result<Self, OptimError> {
        if lower.len() != upper.len() {
            return Err(OptimError::WrongLength {
                field: "bounds.upper",
                expected: lower.len(),
                actual: upper.len(),
            });
        }
        for (i, (&lo, &hi)) in lower.iter().zip(&upper).enumerate() {
            check_interval(&format!("bounds[{i}]"), lo, hi)?;
        }
        Ok(Bounds { lower, upper })
    }

    /// The same box `[lo, hi]` for all `n` parameters.
    pub fn uniform(n: usize, lo: f64, hi: f64) -> Result<Self, OptimError> {
        Self::unbounded(n).with_range(0..n, lo, hi)
    }

    /// Replaces the box of the parameters in `range` with `[lo, hi]`, e.g. `x >= 0` for env texels.
    pub fn with_range(mut self, range: Range<usize>, lo: f64, hi: f64) -> Result<Self, OptimError> {
        let field = format!("bounds[{range:?}]");
        OptimError::check(
            range.start <= range.end && range.end <= self.len(),
            &field,
            "must be a range inside the parameter vector",
            self.len(),
        )?;
        check_interval(&field, lo, hi)?;
        self.lower[range.clone()].fill(lo);
        self.upper[range].fill(hi);
        Ok(self)
    }

    /// Number of parameters constrained.
    pub fn len(&self) -> usize {
        self.lower.len()
    }

    /// Whether there are no parameters at all.
    pub fn is_empty(&self) -> bool {
        self.lower.is_empty()
    }

    /// Lower ends.
    pub fn lower(&self) -> &[f64] {
        &self.lower
    }

    /// Upper ends.
    pub fn upper(&self) -> &[f64] {
        &self.upper
    }

    /// Whether any end is finite, i.e. projection can change a point.
    pub fn is_constrained(&self) -> bool {
        self.lower.iter().chain(&self.upper).any(|b| b.is_finite())
    }

    /// Clamps `x` into the box in place.
    pub fn project(&self, x: &mut [f64]) {
        assert_eq!(
            x.len(),
            self.len(),
            "Bounds::project: x has length {}, bounds {}",
            x.len(),
            self.len()
        );
        for ((xi, &lo), &hi) in x.iter_mut().zip(&self.lower).zip(&self.upper) {
            *xi = xi.clamp(lo, hi);
        }
    }

    /// Whether parameter `i` sits on a bound that `-grad_i` pushes against (frozen for the step).
    pub fn is_active(&self, i: usize, x_i: f64, grad_i: f64) -> bool {
        (x_i <= self.lower[i] && grad_i > 0.0) || (x_i >= self.upper[i] && grad_i < 0.0)
    }

    /// Infinity norm of the projected gradient `P(x - g) - x`, the first-order optimality
    /// measure of a box-constrained problem (L-BFGS-B's `pgtol` test); `max|g|` when unbounded.
    pub fn projected_grad_norm(&self, x: &[f64], grad: &[f64]) -> f64 {
        let mut norm = 0.0_f64;
        for (i, (&xi, &gi)) in x.iter().zip(grad).enumerate() {
            let pg = (xi - gi).clamp(self.lower[i], self.upper[i]) - xi;
            norm = norm.max(pg.abs());
        }
        norm
    }
}

/// Checks one interval: no NaN ends and `lo <= hi`.
fn check_interval(field: &str, lo: f64, hi: f64) -> Result<(), OptimError> {
    OptimError::check(!lo.is_nan() && !hi.is_nan(), field, "must not be NaN", (lo, hi))?;
    OptimError::check(lo <= hi, field, "must have lower <= upper", (lo, hi))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rejects_lower_above_upper() {
        let err = Bounds::new(vec![0.0, 2.0], vec![1.0, 1.0]).unwrap_err();
        assert!(matches!(err, OptimError::InvalidSetting { ref field, .. } if field == "bounds[1]"));
        assert!(Bounds::unbounded(3).with_range(1..4, 0.0, 1.0).is_err());
    }

    #[test]
    fn projected_gradient_ignores_outward_pushes_at_the_bound() {
        let b = Bounds::unbounded(3).with_range(0..2, 0.0, 1.0).unwrap();
        // x0 at its lower bound pushed outward (g > 0) contributes nothing; x1 in the
        // interior contributes |g| capped by the distance to its bound.
        let x = [0.0, 0.5, 3.0];
        assert_eq!(b.projected_grad_norm(&x, &[5.0, -2.0, 0.25]), 0.5);
        assert!(b.is_active(0, 0.0, 5.0));
        assert!(!b.is_active(0, 0.0, -5.0));
        let mut y = [-1.0, 2.0, 7.0];
        b.project(&mut y);
        assert_eq!(y, [0.0, 1.0, 7.0]);
    }
}
