//! Indices as float arrays, shared by gather and scatter-add.
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
