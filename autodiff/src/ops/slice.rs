//! Slice: a contiguous part of an array.

use crate::real::Real;
use crate::tape::{Op, Var};

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
