//! Gather: reads an array at integer positions.

use crate::ops::index::check_addressable;
use crate::real::Real;
use crate::tape::{Op, Var};

impl<'t, T: Real> Var<'t, T> {
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
}
