//! Shape ops: broadcast, slice, concat.

use crate::ops::map::MapKind;
use crate::real::Real;
use crate::tape::{Op, Tape, Var};

impl<'t, T: Real> Var<'t, T> {
    /// A length-1 array repeated `len` times. Adjoint: the sum of the output's.
    pub fn broadcast(self, len: usize) -> Self {
        assert!(
            self.len() == 1 || self.len() == len,
            "broadcast: shape mismatch: cannot broadcast shape [{}] to [{len}]",
            self.len()
        );
        self.tape
            .record(Op::Map(MapKind::Identity, [T::zero(); 2]), len, &[self])
    }

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

impl<T: Real> Tape<T> {
    /// The arrays laid end to end.
    pub fn concat<'t>(&'t self, parts: &[Var<'t, T>]) -> Var<'t, T> {
        assert!(!parts.is_empty(), "concat: nothing to concatenate");
        let mut len = 0;
        for p in parts {
            assert!(std::ptr::eq(p.tape, self), "concat: operands live on different tapes");
            len += p.len();
        }
        self.record_iter(Op::Concat, len, parts.iter().copied())
    }
}
