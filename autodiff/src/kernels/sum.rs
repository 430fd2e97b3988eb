//! Sum of all elements, `y = x[0] + ... + x[n-1]`, a length-1 array (and the
//! mean built on it).
//!
//! VJP, with `gx = dL/dx` and `gy = dL/dy`: `gx[i] += gy` for every `i` (the
//! output's adjoint, broadcast).
//!
//! Structural: a sum ends its region (it is a *sink*). Its value is
//! complete only after every tile has run, so each tile writes a partial sum
//! in f64 and the partials are added in tile order after the chunks are done:
//! the result does not depend on the thread count. Its adjoint, one number,
//! is known before the backward pass's first tile.

use crate::real::Real;

/// Sum with 16 independent accumulators (vectorises; exact order is fixed).
#[inline]
pub(crate) fn tile_sum<T: Real>(x: &[T]) -> T {
    let mut acc = [T::zero(); 16];
    let chunks = x.chunks_exact(16);
    let rest = chunks.remainder();
    for c in chunks {
        for (a, &v) in acc.iter_mut().zip(c) {
            *a += v;
        }
    }
    let mut s = rest.iter().fold(T::zero(), |s, &v| s + v);
    for a in acc {
        s += a;
    }
    s
}

/// Forward over one tile: its partial sum.
#[inline]
pub(crate) fn forward_tile<T: Real>(x: &[T]) -> f64 {
    tile_sum(x).f64()
}

/// The sum from its tiles' partial sums, added in tile order.
pub(crate) fn finish<T: Real>(partials: impl Iterator<Item = f64>) -> T {
    let total: f64 = partials.sum();
    T::c(total)
}

/// VJP over one tile: `gx += gy` (`gx = gy` when `accumulate` is false: the
/// first contribution to a tile slot writes, which spares zeroing it).
#[inline]
pub(crate) fn backward_tile<T: Real>(gy: T, gx: &mut [T], accumulate: bool) {
    if accumulate {
        gx.iter_mut().for_each(|g| *g += gy);
    } else {
        gx.fill(gy);
    }
}
