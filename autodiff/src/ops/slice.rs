//! Slice on the tape: its constructor and its tests. What it
//! computes, forward and backward, is `kernels::slice`.

use crate::exec::Op;
use crate::real::Real;
use crate::tape::Var;

impl<'t, T: Real> Var<'t, T> {
    /// Elements `start..start + len`.
    pub fn slice(self, start: usize, len: usize) -> Self {
        assert!(
            len > 0 && start + len <= self.len(),
            "slice: range {start}..{} out of bounds for shape [{}]",
            start + len,
            self.len()
        );
        self.tape.record(Op::Slice(start as u32), len, &[self])
    }
}

#[cfg(test)]
mod tests {
    use crate::Tape;
    use crate::gradcheck::{Input, gradcheck, uniform};
    use crate::ops::tests::TOL;

    #[test]
    fn slice_takes_a_contiguous_part() {
        let tape = Tape::<f64>::new();
        let x = tape.constant(&[1.0, 2.0, 3.0, 4.0]);
        assert_eq!(&*tape.value(x.slice(1, 2)), &[2.0, 3.0]);
        // Overlapping slices: their adjoints add up in the shared elements.
        let r = gradcheck(&[Input::Var(uniform(6, -1.0, 1.0, 12))], |_, x| {
            x[0].slice(1, 3).exp() * x[0].slice(3, 3)
        });
        assert!(r.worst_rel_error < TOL, "slice: {r}");
    }
}
