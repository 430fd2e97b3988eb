//! Scatter-add: `y[idx[i]] += x[i]` into `len` zeros (a segmented sum, e.g.
//! samples into pixels, when `idx` holds segment ids).
//!
//! VJP, with `gx = dL/dx` and `gy = dL/dy`: `gx[i] += gy[idx[i]]`. The
//! adjoint of a scatter-add is a gather.
//!
//! Structural: any element of the domain may add into any output element,
//! so the output is complete only after the whole domain has run. It ends its
//! region (a *sink*), and the chunks of a parallel region add into private
//! copies that are reduced in chunk order (the same result on any number of
//! threads).

use crate::kernels::index::check_indices;
use crate::real::Real;

/// Forward over one tile: `y[idx[i]] += x[i]`, into the whole output (or a
/// chunk's private copy of it).
#[inline]
pub(crate) fn forward_tile<T: Real>(x: &[T], idx: &[T], y: &mut [T]) {
    check_indices(idx, y.len(), "scatter_add");
    for (&x, &i) in x.iter().zip(idx) {
        // SAFETY: checked above.
        unsafe { *y.get_unchecked_mut(i.to_index_unchecked()) += x };
    }
}

/// VJP over one tile: `gx[i] += gy[idx[i]]`, a gather from the whole output's
/// adjoint `gy` (`gx = ...` when `accumulate` is false).
#[inline]
pub(crate) fn backward_tile<T: Real>(gy: &[T], idx: &[T], gx: &mut [T], accumulate: bool) {
    check_indices(idx, gy.len(), "scatter_add");
    let acc = if accumulate { T::one() } else { T::zero() };
    for (g, &i) in gx.iter_mut().zip(idx) {
        // SAFETY: checked above.
        *g = acc.mul_add(*g, unsafe { *gy.get_unchecked(i.to_index_unchecked()) });
    }
}
