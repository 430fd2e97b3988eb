//! Gather: `y[i] = x[idx[i] * stride + offset]`, an array read at integer
//! positions (one channel of interleaved data, e.g. texel-major RGB with
//! stride 3; stride 1 and offset 0 for a plain lookup).
//!
//! VJP, with `gx = dL/dx` and `gy = dL/dy`:
//! `gx[idx[i] * stride + offset] += gy[i]`. The adjoint of a gather is a
//! scatter-add.
//!
//! Structural: it reads its whole source at data-dependent positions, so the
//! source must be complete before the gather's region starts, and every tile
//! may add into any element of the source's adjoint (the chunks of a parallel
//! region into private copies, reduced in chunk order). The gathers of a
//! region that read one source at the same indices (the channels of a texel)
//! run in one loop, and all gathers from one source scatter their adjoints in
//! one loop, so that neighbouring lookups share their cache lines' trips.

use crate::kernels::index::check_indices;
use crate::real::Real;

/// Most gathers from one array run (forward) or scatter (backward) in one loop.
pub(crate) const GROUP: usize = 16;

/// Forward over one tile for a group of gathers (at most [`GROUP`]) that
/// read `source` at the same indices `idx`: each member
/// `(stride, offset, y)` gets `y[i] = source[idx[i] * stride + offset]`, all
/// in one pass over the indices.
#[inline]
pub(crate) fn forward_tile<'a, T: Real>(
    source: &[T],
    idx: &[T],
    members: impl ExactSizeIterator<Item = (u32, u32, &'a mut [T])>,
) {
    let mut group: [(usize, usize, &mut [T]); GROUP] = std::array::from_fn(|_| (1, 0, &mut [][..]));
    // Taken before the loop, not counted in it: with the count known up
    // front the compiler keeps the gather loop below free of extra work.
    let count = members.len();
    // The members share the indices: one check against the least count.
    let mut least = usize::MAX;
    for ((stride, offset, y), member) in members.zip(&mut group) {
        let at = Strided::new(stride, offset, source.len());
        least = least.min(at.count);
        debug_assert_eq!(y.len(), idx.len());
        *member = (at.stride, at.offset, y);
    }
    if count > 0 {
        check_indices(idx, least, "gather");
    }
    // SAFETY: indices checked above; every output holds the tile's elements.
    unsafe { T::gather_unchecked(source, idx, &mut group[..count]) };
}

/// VJP over one tile of the gathers from one source: for each member
/// `(stride, offset, idx, gy)`, `gx[idx[i] * stride + offset] += gy[i]` for
/// the tile's `n` elements, [`GROUP`] members per loop, in member order.
#[inline]
pub(crate) fn backward_tile<'a, T: Real>(
    gx: &mut [T],
    n: usize,
    members: impl Iterator<Item = (u32, u32, &'a [T], &'a [T])>,
) {
    let mut group: [(&[T], &[T], Strided); GROUP] = [(&[], &[], Strided::UNIT); GROUP];
    let mut count = 0;
    // Consecutive members at the same indices (a texel's channels) are
    // checked once, against the least of their counts.
    let mut unchecked: Option<(&[T], usize)> = None;
    for (stride, offset, idx, gy) in members {
        let at = Strided::new(stride, offset, gx.len());
        unchecked = match unchecked {
            Some((pending, least)) if std::ptr::eq(pending, idx) => Some((pending, least.min(at.count))),
            Some((pending, least)) => {
                check_indices(pending, least, "gather");
                Some((idx, at.count))
            }
            None => Some((idx, at.count)),
        };
        group[count] = (idx, gy, at);
        count += 1;
        if count == GROUP {
            if let Some((pending, least)) = unchecked.take() {
                check_indices(pending, least, "gather");
            }
            scatter_group(gx, &group[..count], n);
            count = 0;
        }
    }
    if let Some((pending, least)) = unchecked {
        check_indices(pending, least, "gather");
    }
    scatter_group(gx, &group[..count], n);
}

/// `target[at(idx[i])] += g[i]` for every `(idx, g, at)` of the group, element by element.
#[inline]
fn scatter_group<T: Real>(target: &mut [T], group: &[(&[T], &[T], Strided)], n: usize) {
    let Some(&(idx0, _, at0)) = group.first() else { return };
    // Channels of one texel: one index conversion per element, and for the
    // usual channel counts a loop the compiler unrolls over the group.
    if group
        .iter()
        .all(|&(idx, _, at)| std::ptr::eq(idx, idx0) && at.stride == at0.stride)
    {
        match group.len() {
            1 => return scatter_channels::<T, 1>(target, idx0, at0.stride, group, n),
            2 => return scatter_channels::<T, 2>(target, idx0, at0.stride, group, n),
            3 => return scatter_channels::<T, 3>(target, idx0, at0.stride, group, n),
            4 => return scatter_channels::<T, 4>(target, idx0, at0.stride, group, n),
            _ => {}
        }
    }
    for i in 0..n {
        for &(idx, g, at) in group {
            // SAFETY: the caller checked the indices against each member's count.
            unsafe { *target.get_unchecked_mut(at.index(*idx.get_unchecked(i))) += *g.get_unchecked(i) };
        }
    }
}

/// [`scatter_group`] for `C` channels read at the same texel indices.
#[inline(always)]
fn scatter_channels<T: Real, const C: usize>(
    target: &mut [T],
    idx: &[T],
    stride: usize,
    group: &[(&[T], &[T], Strided)],
    n: usize,
) {
    let g: [&[T]; C] = std::array::from_fn(|c| group[c].1);
    let offset: [usize; C] = std::array::from_fn(|c| group[c].2.offset);
    for i in 0..n {
        // SAFETY: every slice holds the tile's n elements; the indices were
        // checked against the target's length for every offset.
        unsafe {
            let base = idx.get_unchecked(i).to_index_unchecked() * stride;
            for c in 0..C {
                *target.get_unchecked_mut(base + offset[c]) += *g[c].get_unchecked(i);
            }
        }
    }
}

/// The element a gather index addresses: `index * stride + offset` (e.g. a
/// channel of texel-major RGB data), and how many indices are valid.
#[derive(Clone, Copy)]
struct Strided {
    stride: usize,
    offset: usize,
    count: usize,
}

impl Strided {
    const UNIT: Strided = Strided {
        stride: 1,
        offset: 0,
        count: 0,
    };

    fn new(stride: u32, offset: u32, len: usize) -> Self {
        let (stride, offset) = (stride as usize, offset as usize);
        let count = if len > offset {
            (len - 1 - offset) / stride + 1
        } else {
            0
        };
        Strided { stride, offset, count }
    }

    /// The element of index `i`, which the caller checked against `count`.
    #[inline(always)]
    fn index<T: Real>(self, i: T) -> usize {
        // SAFETY: the caller checked 0 <= i < count <= 2^24.
        let i = unsafe { i.to_index_unchecked() };
        i * self.stride + self.offset
    }
}
