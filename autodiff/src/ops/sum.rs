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
use crate::tape::{Op, Var};

impl<'t, T: Real> Var<'t, T> {
    /// Sum of all elements (length 1). Adjoint: the output's adjoint, broadcast.
    pub fn sum(self) -> Self {
        self.tape.record(Op::Sum, 1, &[self])
    }

    /// Mean of all elements (length 1).
    pub fn mean(self) -> Self {
        let n = T::c(self.len() as f64);
        self.sum() / n
    }
}

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

#[cfg(test)]
mod tests {
    use crate::Tape;
    use crate::gradcheck::{Input, gradcheck, uniform};
    use crate::ops::tests::TOL;

    #[test]
    fn sum_and_mean() {
        let tape = Tape::<f64>::new();
        let x = tape.constant(&[1.0, 2.0, 3.5]);
        assert_eq!(tape.value(x.sum())[0], 6.5);
        assert_eq!(tape.value(x.mean())[0], 6.5 / 3.0);
        let r = gradcheck(&[Input::Var(uniform(10, -1.0, 1.0, 9))], |_, x| (x[0] * x[0]).mean());
        assert!(r.worst_rel_error < TOL, "mean: {r}");
    }
}
