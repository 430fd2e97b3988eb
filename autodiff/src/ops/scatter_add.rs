//! Scatter-add on the tape: its constructor and its tests. What it
//! computes, forward and backward, is `kernels::scatter_add`.

use crate::exec::Op;
use crate::kernels::index::check_addressable;
use crate::real::Real;
use crate::tape::Var;

impl<'t, T: Real> Var<'t, T> {
    /// `out[indices[i]] += self[i]` into `len` zeros. Adjoint: gather of the
    /// output's adjoint at `indices`.
    pub fn scatter_add(self, indices: Self, len: usize) -> Self {
        self.same_tape(indices, "scatter_add");
        assert_eq!(
            self.len(),
            indices.len(),
            "scatter_add: shape mismatch: values have shape [{}], indices [{}]",
            self.len(),
            indices.len()
        );
        assert!(len > 0, "scatter_add: the output needs at least one element");
        check_addressable::<T>(len, "scatter_add");
        self.tape.record(Op::ScatterAdd, len, &[self, indices])
    }

    /// Sums the elements of each segment: `out[s] = sum of self[i] with
    /// segment_ids[i] = s` (e.g. samples into pixels), `segments` outputs.
    pub fn segmented_sum(self, segment_ids: Self, segments: usize) -> Self {
        self.scatter_add(segment_ids, segments)
    }
}

#[cfg(test)]
mod tests {
    use crate::Tape;
    use crate::gradcheck::{Input, gradcheck, uniform};
    use crate::ops::tests::TOL;

    #[test]
    fn scatter_add_and_segmented_sum() {
        let tape = Tape::<f64>::new();
        let idx = tape.constant(&[2.0, 0.0, 2.0, 1.0]);
        let vals = tape.constant(&[1.0, 2.0, 3.0, 4.0]);
        assert_eq!(&*tape.value(vals.scatter_add(idx, 4)), &[2.0, 4.0, 4.0, 0.0]);
        let seg = tape.constant(&[0.0, 0.0, 1.0, 1.0]);
        assert_eq!(&*tape.value(vals.segmented_sum(seg, 2)), &[3.0, 7.0]);
        let idx = Input::Const(vec![2.0, 0.0, 2.0, 1.0, 4.0, 4.0, 3.0]);
        let r = gradcheck(&[Input::Var(uniform(7, -1.0, 1.0, 11)), idx], |_, x| {
            x[0].scatter_add(x[1], 6).sin()
        });
        assert!(r.worst_rel_error < TOL, "scatter_add: {r}");
    }

    #[test]
    fn a_scatter_add_keeps_every_chunk_s_values_when_backward_runs_its_region() {
        // Long enough to be cut into chunks on threads; the scatter-add and
        // the loss end one region, which `backward` runs forward and backward
        // in one pass.
        let n = 40_000;
        let tape = Tape::<f64>::new();
        let x = tape.leaf(&vec![1.0; n]);
        let idx = tape.constant(&(0..n).map(|i| (i % 4) as f64).collect::<Vec<_>>());
        let bins = x.scatter_add(idx, 4);
        let loss = (x * x).sum();
        tape.backward(loss);
        assert_eq!(&*tape.value(bins), &[10_000.0; 4]);
        assert!(tape.grad(x).iter().all(|&g| g == 2.0));
    }

    #[test]
    #[should_panic(expected = "scatter_add: index 2 out of range for an array of 2 elements")]
    fn scatter_add_out_of_range_names_the_op() {
        let tape = Tape::<f32>::new();
        let vals = tape.constant(&[1.0, 2.0]);
        let _ = tape.value(vals.scatter_add(tape.constant(&[0.0, 2.0]), 2));
    }
}
