//! Sum on the tape: its constructor and its tests. What it
//! computes, forward and backward, is `kernels::sum`.

use crate::exec::Op;
use crate::real::Real;
use crate::tape::Var;

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

#[cfg(test)]
mod tests {
    use crate::Tape;
    use crate::gradcheck::{Input, gradcheck, uniform};
    use crate::ops::tests::TOL;

    #[test]
    fn sum_and_mean() {
        let tape = Tape::<f64>::new();
        let x = tape.constant(&[1.0, 2.0, 3.5]);
        assert_eq!(tape.value(x.sum())[0], 6.5);
        assert_eq!(tape.value(x.mean())[0], 6.5 / 3.0);
        let r = gradcheck(&[Input::Var(uniform(10, -1.0, 1.0, 9))], |_, x| (x[0] * x[0]).mean());
        assert!(r.worst_rel_error < TOL, "mean: {r}");
    }
}
