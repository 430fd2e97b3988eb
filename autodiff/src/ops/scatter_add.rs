//! Scatter-add: adds values into an array at integer positions.

use crate::ops::index::check_addressable;
use crate::real::Real;
use crate::tape::{Op, Var};

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
