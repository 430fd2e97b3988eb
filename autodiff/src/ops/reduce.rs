//! Reductions and index ops: sum, mean, gather, scatter-add, segmented sum.
//!
//! Indices are carried as float arrays holding integers (so that they can be
//! computed by tape ops, e.g. a texel index from a direction); f32 represents
//! every integer up to 2^24 exactly, which bounds the arrays they address.

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

    /// `y[i] = self[indices[i]]`: reads an array at integer positions. Adjoint:
    /// scatter-add of `y`'s adjoint into `self`'s.
    pub fn gather(self, indices: Self) -> Self {
        self.gather_channel(indices, 1, 0)
    }

    /// `y[i] = self[indices[i] * channels + channel]`: one channel of
    /// interleaved data (texel-major RGB: `channels` = 3) at integer texel
    /// indices. Gathers from one array scatter their adjoints together, so the
    /// channels of a texel cost one pass over its cache line.
    pub fn gather_channel(self, indices: Self, channels: usize, channel: usize) -> Self {
        self.same_tape(indices, "gather");
        assert!(
            channels > 0 && channel < channels,
            "gather: channel {channel} out of range for {channels} channels"
        );
        check_addressable::<T>(self.len(), "gather");
        let op = Op::Gather {
            stride: channels as u32,
            offset: channel as u32,
        };
        self.tape.record(op, indices.len(), &[self, indices])
    }

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

fn check_addressable<T: Real>(len: usize, op: &str) {
    assert!(
        (len as f64) <= T::MAX_EXACT_INT,
        "{op}: {len} elements cannot all be addressed by {} indices (at most {})",
        T::NAME,
        T::MAX_EXACT_INT
    );
}
