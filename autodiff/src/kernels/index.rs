//! Indices as float arrays, shared by gather and scatter-add: the checks
//! when an op is recorded and when a tile runs.
//!
//! Indices are carried as float arrays holding integers (so that they can be
//! computed by tape ops, e.g. a texel index from a direction); f32 represents
//! every integer up to 2^24 exactly, which bounds the arrays they address.

use crate::real::Real;

/// Panics unless every element of an array of `len` can be addressed by a
/// float index of type `T` (checked when the op is recorded).
pub(crate) fn check_addressable<T: Real>(len: usize, op: &str) {
    assert!(
        (len as f64) <= T::MAX_EXACT_INT,
        "{op}: {len} elements cannot all be addressed by {} indices (at most {})",
        T::NAME,
        T::MAX_EXACT_INT
    );
}

/// Checks that every index of a tile (floats holding integers) addresses an
/// array of `len` elements, in one vectorised pass, so that the gather or
/// scatter loop after it indexes unchecked.
#[inline]
pub(crate) fn check_indices<T: Real>(idx: &[T], len: usize, op: &str) {
    let hi = T::c(len as f64);
    let ok = idx.iter().fold(true, |ok, &i| ok & (i >= T::zero()) & (i < hi));
    if !ok {
        let bad = idx
            .iter()
            .find(|&&i| !(i >= T::zero() && i < hi))
            .copied()
            .unwrap_or(T::nan());
        panic!("{op}: index {bad} out of range for an array of {len} elements");
    }
}
