//! Slice: `y[i] = x[start + i]` for `i < len`, a contiguous part of an array.
//!
//! VJP, with `gx = dL/dx` and `gy = dL/dy`: `gx[start + i] += gy[i]`; the
//! rest of `gx` gets nothing.
//!
//! Structural: its output has another length than its input, so it cannot
//! share a region's tiles; it runs as a plain step over whole arrays.

use crate::kernels::add_into;
use crate::real::Real;

/// Forward: `y` gets `x[start..start + y.len()]`.
pub(crate) fn forward<T: Real>(x: &[T], start: usize, y: &mut [T]) {
    y.copy_from_slice(&x[start..start + y.len()]);
}

/// VJP: `gx[start..start + gy.len()] += gy`.
pub(crate) fn backward<T: Real>(gy: &[T], start: usize, gx: &mut [T]) {
    add_into(&mut gx[start..start + gy.len()], gy);
}
