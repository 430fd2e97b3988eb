//! The float types a tape computes in, and the elementwise math they need.
//!
//! `f32` is the speed type: its transcendental functions are branchless
//! polynomial approximations (Cephes' single-precision ones) that the compiler
//! turns into AVX2 code inside the tape's loops, where std's `expf` & co. are
//! scalar libm calls that never vectorise. They stay within a few ulp of the
//! correctly rounded result (tested against f64 below).
//!
//! `f64` is the checking type (gradient checks by central differences): it uses
//! std's libm functions, whose accuracy the finite differences rely on.

use std::fmt::{Debug, Display};

/// A float type a [`Tape`](crate::Tape) computes in: `f32` (fast) or `f64` (checks).
pub trait Real:
    num_traits::Float
    + num_traits::FloatConst
    + num_traits::NumAssign
    + Copy
    + Send
    + Sync
    + Default
    + Debug
    + Display
    + 'static
{
    /// Type name, for messages.
    const NAME: &'static str;
    /// Largest integer such that every integer up to it is exactly representable
    /// (indices for gather/scatter are carried as floats).
    const MAX_EXACT_INT: f64;

    /// Truncation to an index.
    ///
    /// # Safety
    /// `self` is finite and in `[0, 2^31)`.
    unsafe fn to_index_unchecked(self) -> usize;
    /// For each `(stride, offset, out)` of the group:
    /// `out[i] = source[idx[i] * stride + offset]` (the channels of a texel
    /// read together, so that they share the cache line's trip).
    ///
    /// # Safety
    /// The indices are finite, non-negative and below 2^24, every position is
    /// within `source`, and every `out` has `idx`'s length.
    #[inline(always)]
    unsafe fn gather_unchecked(source: &[Self], idx: &[Self], group: &mut [(usize, usize, &mut [Self])]) {
        for (i, &t) in idx.iter().enumerate() {
            // SAFETY: the caller guarantees the ranges.
            let t = unsafe { t.to_index_unchecked() };
            for (stride, offset, out) in group.iter_mut() {
                unsafe { *out.get_unchecked_mut(i) = *source.get_unchecked(t * *stride + *offset) };
            }
        }
    }
    /// `e^x`, vectorisable.
    fn exp_v(self) -> Self;
    /// Natural logarithm, vectorisable.
    fn ln_v(self) -> Self;
    /// `(sin x, cos x)`, vectorisable.
    fn sin_cos_v(self) -> (Self, Self);
    /// Four-quadrant arctangent of `self / x`, vectorisable.
    fn atan2_v(self, x: Self) -> Self;
    /// Arcsine, vectorisable.
    fn asin_v(self) -> Self;
    /// Arccosine, vectorisable.
    fn acos_v(self) -> Self;

    /// Conversion from an `f64` constant.
    #[inline(always)]
    fn c(x: f64) -> Self {
        <Self as num_traits::NumCast>::from(x).expect("every f64 converts to a float type")
    }
    /// Conversion to `f64`.
    #[inline(always)]
    fn f64(self) -> f64 {
        num_traits::ToPrimitive::to_f64(&self).expect("every float converts to f64")
    }
}

impl Real for f64 {
    const NAME: &'static str = "f64";
    #[inline(always)]
    unsafe fn to_index_unchecked(self) -> usize {
        // SAFETY: the caller guarantees the range.
        unsafe { self.to_int_unchecked::<i32>() as usize }
    }
    const MAX_EXACT_INT: f64 = 9007199254740992.0;
    #[inline(always)]
    fn exp_v(self) -> Self {
        self.exp()
    }
    #[inline(always)]
    fn ln_v(self) -> Self {
        self.ln()
    }
    #[inline(always)]
    fn sin_cos_v(self) -> (Self, Self) {
        self.sin_cos()
    }
    #[inline(always)]
    fn atan2_v(self, x: Self) -> Self {
        self.atan2(x)
    }
    #[inline(always)]
    fn asin_v(self) -> Self {
        self.asin()
    }
    #[inline(always)]
    fn acos_v(self) -> Self {
        self.acos()
    }
}

impl Real for f32 {
    const NAME: &'static str = "f32";
    /// With AVX2, eight lanes per hardware gather instruction.
    #[cfg(all(target_arch = "x86_64", target_feature = "avx2"))]
    #[inline(always)]
    unsafe fn gather_unchecked(source: &[Self], idx: &[Self], group: &mut [(usize, usize, &mut [Self])]) {
        use std::arch::x86_64::*;
        let n = idx.len();
        let full = n / 8 * 8;
        // SAFETY: AVX2 is enabled at compile time; positions are in range and
        // below 2^24, so they fit 32-bit lanes; loads and stores stay within
        // the first `full` elements of `idx` and of each `out`.
        unsafe {
            for i in (0..full).step_by(8) {
                let texel = _mm256_cvttps_epi32(_mm256_loadu_ps(idx.as_ptr().add(i)));
                for (stride, offset, out) in group.iter_mut() {
                    let at = _mm256_mullo_epi32(texel, _mm256_set1_epi32(*stride as i32));
                    let at = _mm256_add_epi32(at, _mm256_set1_epi32(*offset as i32));
                    _mm256_storeu_ps(out.as_mut_ptr().add(i), _mm256_i32gather_ps::<4>(source.as_ptr(), at));
                }
            }
            for i in full..n {
                let t = idx.get_unchecked(i).to_index_unchecked();
                for (stride, offset, out) in group.iter_mut() {
                    *out.get_unchecked_mut(i) = *source.get_unchecked(t * *stride + *offset);
                }
            }
        }
    }
    #[inline(always)]
    unsafe fn to_index_unchecked(self) -> usize {
        // SAFETY: the caller guarantees the range.
        unsafe { self.to_int_unchecked::<i32>() as usize }
    }
    const MAX_EXACT_INT: f64 = 16777216.0;
    #[inline(always)]
    fn exp_v(self) -> Self {
        exp_f32(self)
    }
    #[inline(always)]
    fn ln_v(self) -> Self {
        ln_f32(self)
    }
    #[inline(always)]
    fn sin_cos_v(self) -> (Self, Self) {
        sin_cos_f32(self)
    }
    #[inline(always)]
    fn atan2_v(self, x: Self) -> Self {
        atan2_f32(self, x)
    }
    #[inline(always)]
    fn asin_v(self) -> Self {
        asin_acos_f32(self).0
    }
    #[inline(always)]
    fn acos_v(self) -> Self {
        asin_acos_f32(self).1
    }
}

/// Round-to-nearest-even by the 1.5 * 2^23 trick: branchless, and the integer
/// lands in the low mantissa bits, so no float-to-int conversion is needed.
const ROUND_MAGIC: f32 = 12582912.0;

/// `e^x` in single precision (Cephes `expf`): x = n ln2 + r, |r| <= ln2 / 2,
/// e^r by a degree-6 polynomial, 2^n by building the exponent bits.
#[inline(always)]
pub fn exp_f32(x: f32) -> f32 {
    const HI: f32 = 88.72283;
    const LO: f32 = -87.33654;
    // Comparisons (not min/max) so that NaN passes through untouched.
    let xc = if x > HI { HI } else { x };
    let xc = if xc < LO { LO } else { xc };
    let t = xc * std::f32::consts::LOG2_E + ROUND_MAGIC;
    let n = t - ROUND_MAGIC;
    let r = n.mul_add(-0.693_359_4, xc);
    let r = n.mul_add(2.121_944_4e-4, r);
    let mut p = 1.987_569_1e-4_f32;
    p = p.mul_add(r, 1.398_199_9e-3);
    p = p.mul_add(r, 8.333_452e-3);
    p = p.mul_add(r, 4.166_579_6e-2);
    p = p.mul_add(r, 1.666_666_5e-1);
    p = p.mul_add(r, 5e-1);
    let er = p.mul_add(r * r, r) + 1.0;
    // n in [-126, 128]: split 2^n into two factors so that n = 128 and the
    // subnormal end do not overflow the exponent field.
    let ni = (t.to_bits() as i32).wrapping_sub(0x4B40_0000);
    let half = ni >> 1;
    let s1 = f32::from_bits(((half + 127) << 23) as u32);
    let s2 = f32::from_bits(((ni - half + 127) << 23) as u32);
    let y = er * s1 * s2;
    if x > HI {
        f32::INFINITY
    } else if x < LO {
        0.0
    } else {
        y
    }
}

/// Natural log in single precision (Cephes `logf`): x = m 2^e with
/// m in [sqrt(1/2), sqrt(2)), ln(m) by a degree-9 polynomial in m - 1.
#[inline(always)]
pub fn ln_f32(x: f32) -> f32 {
    const SQRTH: f32 = std::f32::consts::FRAC_1_SQRT_2;
    // Subnormals: scale into the normal range first.
    let tiny = x < f32::MIN_POSITIVE;
    let xs = if tiny { x * 8388608.0 } else { x };
    let bits = xs.to_bits();
    let e = ((bits >> 23) & 0xff) as i32 - 126;
    let m = f32::from_bits((bits & 0x807f_ffff) | 0x3f00_0000); // in [0.5, 1)
    let small = m < SQRTH;
    let e = (e - small as i32) as f32 - if tiny { 23.0 } else { 0.0 };
    let z = if small { m + m - 1.0 } else { m - 1.0 };
    let z2 = z * z;
    let mut p = 7.037_683_6e-2_f32;
    p = p.mul_add(z, -1.151_461e-1);
    p = p.mul_add(z, 1.167_699_9e-1);
    p = p.mul_add(z, -1.242_014_1e-1);
    p = p.mul_add(z, 1.424_932_3e-1);
    p = p.mul_add(z, -1.666_805_8e-1);
    p = p.mul_add(z, 2.000_071_4e-1);
    p = p.mul_add(z, -2.499_999_4e-1);
    p = p.mul_add(z, 3.333_333e-1);
    let mut y = p * z * z2;
    y = e.mul_add(-2.121_944_4e-4, y);
    y = (-0.5f32).mul_add(z2, y);
    let r = e.mul_add(0.693_359_4, z + y);
    if x == 0.0 {
        f32::NEG_INFINITY
    } else if x < 0.0 || x.is_nan() {
        f32::NAN
    } else if x == f32::INFINITY {
        f32::INFINITY
    } else {
        r
    }
}

/// `(sin x, cos x)` in single precision (Cephes `sinf`/`cosf`): reduce by
/// multiples of pi/4 (three-part Cody-Waite constant), then a polynomial for
/// sine or cosine on [-pi/4, pi/4] chosen by the octant. Accurate to a few ulp
/// for |x| < 8192, the range of angles a renderer produces.
#[inline(always)]
pub fn sin_cos_f32(x: f32) -> (f32, f32) {
    let ax = x.abs();
    let j = (ax * 1.273_239_5) as i32;
    let j = (j + 1) & !1;
    let y = j as f32;
    let r = y.mul_add(-0.785_156_25, ax);
    let r = y.mul_add(-2.418_756_5e-4, r);
    let r = y.mul_add(-3.774_895e-8, r);
    let z = r * r;
    let mut ps = -1.951_529_6e-4_f32;
    ps = ps.mul_add(z, 8.332_161e-3);
    ps = ps.mul_add(z, -1.666_665_5e-1);
    let sin_r = (ps * z).mul_add(r, r);
    let mut pc = 2.443_315_7e-5_f32;
    pc = pc.mul_add(z, -1.388_731_6e-3);
    pc = pc.mul_add(z, 4.166_664_6e-2);
    let cos_r = (pc * z).mul_add(z, (-0.5f32).mul_add(z, 1.0));
    let q = j & 7;
    let swap = q & 2 != 0;
    let (s, c) = if swap { (cos_r, sin_r) } else { (sin_r, cos_r) };
    let sin_flip = (q & 4 != 0) ^ (x < 0.0);
    let cos_flip = (q & 4 != 0) ^ swap;
    let s = if sin_flip { -s } else { s };
    let c = if cos_flip { -c } else { c };
    // Past the reduction's range the result would be noise: say so with NaN.
    if ax > 8192.0 || x.is_nan() {
        (f32::NAN, f32::NAN)
    } else {
        (s, c)
    }
}

/// atan(t) for t in [0, 1] (Cephes `atanf` after its range reduction at tan(pi/8)).
#[inline(always)]
fn atan_unit_f32(t: f32) -> f32 {
    let mid = t > 0.414_213_57;
    let u = if mid { (t - 1.0) / (t + 1.0) } else { t };
    let z = u * u;
    let mut p = 8.053_744_5e-2_f32;
    p = p.mul_add(z, -1.387_768_5e-1);
    p = p.mul_add(z, 1.997_771_1e-1);
    p = p.mul_add(z, -3.333_295e-1);
    let a = (p * z).mul_add(u, u);
    if mid { a + std::f32::consts::FRAC_PI_4 } else { a }
}

/// Four-quadrant arctangent of y / x, by atan of min/max on [0, 1] and
/// reflections (no overflow for large ratios). atan2(0, 0) = 0.
#[inline(always)]
pub fn atan2_f32(y: f32, x: f32) -> f32 {
    let ax = x.abs();
    let ay = y.abs();
    let hi = if ax > ay { ax } else { ay };
    let lo = if ax > ay { ay } else { ax };
    let t = if hi == 0.0 { 0.0 } else { lo / hi };
    let mut a = atan_unit_f32(t);
    if ay > ax {
        a = std::f32::consts::FRAC_PI_2 - a;
    }
    if x.is_sign_negative() {
        a = std::f32::consts::PI - a;
    }
    let r = a.copysign(y);
    if x.is_nan() || y.is_nan() { f32::NAN } else { r }
}

/// `(asin x, acos x)` in single precision (Cephes `asinf`/`acosf`): a
/// polynomial on |x| <= 1/2, and asin(x) = pi/2 - 2 asin(sqrt((1 - x) / 2))
/// beyond, which keeps acos accurate near 1.
#[inline(always)]
pub fn asin_acos_f32(x: f32) -> (f32, f32) {
    let a = x.abs();
    let big = a > 0.5;
    let z = if big { 0.5 * (1.0 - a) } else { x * x };
    let s = if big { z.sqrt() } else { a };
    let mut p = 4.216_32e-2_f32;
    p = p.mul_add(z, 2.418_131_2e-2);
    p = p.mul_add(z, 4.547_002_6e-2);
    p = p.mul_add(z, 7.495_300_3e-2);
    p = p.mul_add(z, 1.666_675_2e-1);
    let asin_s = (p * z).mul_add(s, s);
    let half_pi = std::f32::consts::FRAC_PI_2;
    let asin_a = if big { half_pi - 2.0 * asin_s } else { asin_s };
    let asin = asin_a.copysign(x);
    let acos = if big {
        if x > 0.0 {
            2.0 * asin_s
        } else {
            std::f32::consts::PI - 2.0 * asin_s
        }
    } else {
        half_pi - asin
    };
    if a > 1.0 || x.is_nan() {
        (f32::NAN, f32::NAN)
    } else {
        (asin, acos)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Worst error of `f` against the f64 reference over `n` points in [lo, hi],
    /// relative to max(|reference|, `abs_floor`).
    fn worst_error(
        f: impl Fn(f32) -> f32,
        reference: impl Fn(f64) -> f64,
        lo: f64,
        hi: f64,
        abs_floor: f64,
    ) -> (f64, f64) {
        let n = 200_001;
        let mut worst = (0.0, lo);
        for i in 0..n {
            let x = (lo + (hi - lo) * i as f64 / (n - 1) as f64) as f32;
            let want = reference(x as f64);
            let got = f(x) as f64;
            let err = (got - want).abs() / want.abs().max(abs_floor);
            if err > worst.0 {
                worst = (err, x as f64);
            }
        }
        worst
    }

    #[test]
    fn exp_within_three_ulp() {
        let (err, at) = worst_error(exp_f32, f64::exp, -87.0, 88.7, 0.0);
        assert!(err < 3.0 * f32::EPSILON as f64, "exp: {err:e} at {at}");
        assert_eq!(exp_f32(0.0), 1.0);
        assert_eq!(exp_f32(100.0), f32::INFINITY);
        assert_eq!(exp_f32(-100.0), 0.0);
        assert!(exp_f32(f32::NAN).is_nan());
    }

    #[test]
    fn ln_within_three_ulp() {
        let (err, at) = worst_error(ln_f32, f64::ln, 1e-6, 10.0, 1e-30);
        assert!(err < 3.0 * f32::EPSILON as f64, "ln: {err:e} at {at}");
        let (err, at) = worst_error(ln_f32, f64::ln, 10.0, 1e30, 1e-30);
        assert!(err < 3.0 * f32::EPSILON as f64, "ln: {err:e} at {at}");
        assert!((ln_f32(1e-40) as f64 - (1e-40f32 as f64).ln()).abs() < 1e-5);
        assert_eq!(ln_f32(1.0), 0.0);
        assert_eq!(ln_f32(0.0), f32::NEG_INFINITY);
        assert!(ln_f32(-1.0).is_nan());
        assert_eq!(ln_f32(f32::INFINITY), f32::INFINITY);
    }

    #[test]
    fn sin_cos_within_a_few_ulp_of_unit() {
        // Absolute error against the unit amplitude: near the zeros of sin the
        // relative error of any argument-rounded f32 input is unbounded.
        let (err, at) = worst_error(|x| sin_cos_f32(x).0, f64::sin, -100.0, 100.0, 1.0);
        assert!(err < 2.0 * f32::EPSILON as f64, "sin: {err:e} at {at}");
        let (err, at) = worst_error(|x| sin_cos_f32(x).1, f64::cos, -100.0, 100.0, 1.0);
        assert!(err < 2.0 * f32::EPSILON as f64, "cos: {err:e} at {at}");
        let (err, at) = worst_error(|x| sin_cos_f32(x).0, f64::sin, -0.7, 0.7, 0.0);
        assert!(err < 3.0 * f32::EPSILON as f64, "sin small: {err:e} at {at}");
        assert!(sin_cos_f32(1e5).0.is_nan());
    }

    #[test]
    fn atan2_within_a_few_ulp() {
        for &x in &[1.0f32, -1.0, 0.3, -2.5, 1e-3, -1e3] {
            let (err, at) = worst_error(|y| atan2_f32(y, x), |y| y.atan2(x as f64), -5.0, 5.0, 1e-3);
            assert!(err < 4.0 * f32::EPSILON as f64, "atan2(y, {x}): {err:e} at {at}");
        }
        assert_eq!(atan2_f32(0.0, 0.0), 0.0);
        assert_eq!(atan2_f32(0.0, -1.0), std::f32::consts::PI);
        assert_eq!(atan2_f32(-0.0, -1.0), -std::f32::consts::PI);
        assert_eq!(atan2_f32(1.0, 0.0), std::f32::consts::FRAC_PI_2);
    }

    #[test]
    fn asin_acos_within_a_few_ulp() {
        let (err, at) = worst_error(|x| asin_acos_f32(x).0, f64::asin, -1.0, 1.0, 1e-3);
        assert!(err < 3.0 * f32::EPSILON as f64, "asin: {err:e} at {at}");
        let (err, at) = worst_error(|x| asin_acos_f32(x).1, f64::acos, -1.0, 1.0, 1e-3);
        assert!(err < 3.0 * f32::EPSILON as f64, "acos: {err:e} at {at}");
        assert!(asin_acos_f32(1.5).0.is_nan());
        assert_eq!(asin_acos_f32(1.0).1, 0.0);
    }
}
