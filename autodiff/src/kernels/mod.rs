//! What each op computes, forward and backward, over whole arrays or one
//! tile: the numbers alone. The executor (`exec`) decides where and in
//! which order these run; the constructors that record each op on a tape
//! are in `ops`, with the ops' tests.

pub(crate) mod concat;
pub mod custom;
pub(crate) mod gather;
pub(crate) mod index;
pub(crate) mod map;
pub(crate) mod scatter_add;
pub(crate) mod slice;
pub(crate) mod sum;

use crate::real::Real;

/// dst += src, elementwise (adjoints of slice and concat, and the reduction
/// of the chunks' private accumulators).
#[inline]
pub(crate) fn add_into<T: Real>(dst: &mut [T], src: &[T]) {
    for (d, &s) in dst.iter_mut().zip(src) {
        *d += s;
    }
}
