//! Concat on the tape: its constructor and its tests. What it
//! computes, forward and backward, is `kernels::concat`.

use crate::exec::Op;
use crate::real::Real;
use crate::tape::{Tape, Var};

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

#[cfg(test)]
mod tests {
    use crate::Tape;
    use crate::gradcheck::{Input, gradcheck, uniform};
    use crate::ops::tests::TOL;

    #[test]
    fn concat_lays_parts_end_to_end() {
        let tape = Tape::<f64>::new();
        let x = tape.constant(&[1.0, 2.0, 3.0, 4.0]);
        assert_eq!(
            &*tape.value(tape.concat(&[x.slice(2, 2), x.slice(0, 1)])),
            &[3.0, 4.0, 1.0]
        );
        // A part listed twice gets the adjoints of both its ranges.
        let r = gradcheck(&[Input::Var(uniform(6, -1.0, 1.0, 12))], |t, x| {
            let a = x[0].slice(1, 3).exp();
            let b = x[0].slice(0, 2) * 3.0;
            t.concat(&[a, b, a]).sin()
        });
        assert!(r.worst_rel_error < TOL, "concat: {r}");
    }
}
