//! Concat: `y = [x_0, x_1, ...]`, arrays laid end to end.
//!
//! VJP, with `gx_k = dL/dx_k` and `gy = dL/dy`: `gx_k += gy[at_k..at_k + len_k]`,
//! where `at_k` is where part `k` starts in `y` (a part listed twice gets
//! both ranges).
//!
//! Structural: its output has another length than any input, so it cannot
//! share a region's tiles; it runs as a plain step over whole arrays.

use crate::ops::add_into;
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

/// Forward: the parts, in order, fill `y`.
pub(crate) fn forward<'a, T: Real>(parts: impl Iterator<Item = &'a [T]>, y: &mut [T]) {
    let mut at = 0;
    for x in parts {
        y[at..at + x.len()].copy_from_slice(x);
        at += x.len();
    }
}

/// VJP: for each part, in order, its length and its gradient (None where
/// none flows), `gx_k += gy[at_k..at_k + len_k]`. The parts' gradients are
/// taken one at a time, so a part listed twice may yield the same buffer twice.
pub(crate) fn backward<'a, T: Real>(gy: &[T], parts: impl Iterator<Item = (usize, Option<&'a mut [T]>)>) {
    let mut at = 0;
    for (len, gx) in parts {
        if let Some(gx) = gx {
            add_into(gx, &gy[at..at + len]);
        }
        at += len;
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
