//! Sum and mean of all elements.

use crate::real::Real;
use crate::tape::{Op, Var};

impl<'t, T: Real> Var<'t, T> {
    /// Sum of all elements (length 1). Adjoint: the output's adjoint, broadcast.
    pub fn sum(self) -> Self {
        self.tape.record(Op::Sum, 1, &[self])
    }

    /// Mean of all elements (length 1).
    pub fn mean(self) -> Self {
        let n = T::c(self.len() as f64);
        self.sum() / n
    }
}
