//! Concat: arrays laid end to end.

use crate::real::Real;
use crate::tape::{Op, Tape, Var};

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
