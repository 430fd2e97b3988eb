//! Concat: `y = [x_0, x_1, ...]`, arrays laid end to end.
//!
//! VJP, with `gx_k = dL/dx_k` and `gy = dL/dy`: `gx_k += gy[at_k..at_k + len_k]`,
//! where `at_k` is where part `k` starts in `y` (a part listed twice gets
//! both ranges).
//!
//! Structural: its output has another length than any input, so it cannot
//! share a region's tiles; it runs as a plain step over whole arrays.

use crate::kernels::add_into;
use crate::real::Real;

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
