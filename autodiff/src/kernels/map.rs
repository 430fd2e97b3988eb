//! Elementwise ops: each is a function of up to three same-length arrays
//! (length-1 arrays broadcast) and up to two constant parameters. Every op
//! states its forward `f` and its partial derivatives `df` side by side; the
//! tape's executor runs them tile by tile, forward and backward.

use crate::real::Real;

/// An elementwise function with its partial derivatives.
pub(crate) trait MapOp<T: Real> {
    /// Number of array inputs (1 to 3).
    const ARITY: usize;
    /// The output from the inputs `x` and the parameters `p`.
    fn f(x: [T; 3], p: [T; 2]) -> T;
    /// `[dy/dx0, dy/dx1, dy/dx2]` at the inputs `x` and the output `y`.
    fn df(x: [T; 3], y: T, p: [T; 2]) -> [T; 3];
}

macro_rules! map_ops {
    ($( $(#[$doc:meta])* $name:ident ($arity:literal, $diff:literal) $label:literal
        f($x:ident, $p:ident) $f:block
        df($dx:ident, $y:ident, $dp:ident) $df:block )*) => {
        /// The elementwise ops, as stored on the tape.
        #[derive(Clone, Copy, Debug, PartialEq, Eq)]
        pub(crate) enum MapKind { $($name),* }

        impl MapKind {
            /// The op's name, for messages.
            pub(crate) fn name(self) -> &'static str {
                match self { $(MapKind::$name => $label),* }
            }
            /// Number of array inputs.
            pub(crate) fn arity(self) -> usize {
                match self { $(MapKind::$name => $arity),* }
            }
            /// Whether gradients flow through the op (comparisons and floor: no).
            pub(crate) fn differentiable(self) -> bool {
                match self { $(MapKind::$name => $diff),* }
            }
        }

        $(
            $(#[$doc])*
            pub(crate) struct $name;
            impl<T: Real> MapOp<T> for $name {
                const ARITY: usize = $arity;
                #[inline(always)]
                #[allow(unused_variables)]
                fn f($x: [T; 3], $p: [T; 2]) -> T $f
                #[inline(always)]
                #[allow(unused_variables)]
                fn df($dx: [T; 3], $y: T, $dp: [T; 2]) -> [T; 3] $df
            }
        )*

        impl MapKind {
            /// y = f(x) over a tile, statically dispatched so that each op's
            /// loop is compiled and vectorised on its own.
            #[inline]
            pub(crate) fn forward<T: Real>(self, x: [&[T]; 3], y: &mut [T], p: [T; 2]) {
                match self { $(MapKind::$name => forward::<T, $name>(x, y, p)),* }
            }
            /// gx += gy * dy/dx_k over a tile (gx = ... when `accumulate` is false).
            #[inline]
            #[allow(clippy::too_many_arguments)]
            pub(crate) fn backward<T: Real>(
                self, k: usize, accumulate: bool, x: [&[T]; 3], y: &[T], gy: &[T], gx: &mut [T], p: [T; 2],
            ) {
                match self { $(MapKind::$name => backward::<T, $name>(k, accumulate, x, y, gy, gx, p)),* }
            }
        }
    };
}

#[inline(always)]
fn zero<T: Real>() -> T {
    T::zero()
}
#[inline(always)]
fn one<T: Real>() -> T {
    T::one()
}
#[inline(always)]
fn indicator<T: Real>(b: bool) -> T {
    if b { T::one() } else { T::zero() }
}
/// 1 where `a` wins, 0 where it loses, 1/2 on ties (both share the gradient).
#[inline(always)]
fn win<T: Real>(a_wins: bool, tie: bool) -> T {
    if a_wins {
        T::one()
    } else if tie {
        T::c(0.5)
    } else {
        T::zero()
    }
}
/// ln(1 + u) accurate for tiny u (Goldberg: ln(1+u) * u / ((1+u) - 1)).
#[inline(always)]
fn ln_1p<T: Real>(u: T) -> T {
    let w = T::one() + u;
    let d = w - T::one();
    if d == T::zero() { u } else { w.ln_v() * (u / d) }
}
/// a^b for a >= 0 by exp(b ln a); 0^b is 0, 1 or inf by the sign of b; NaN for a < 0.
#[inline(always)]
fn pow_nonneg<T: Real>(a: T, b: T) -> T {
    let r = (b * a.ln_v()).exp_v();
    if b == T::zero() { T::one() } else { r }
}
/// x^c for a constant c: any x when c is an integer (odd c keeps the sign), x >= 0 otherwise.
#[inline(always)]
fn powf<T: Real>(x: T, c: T) -> T {
    let m = pow_nonneg(x.abs(), c);
    let integer = c == c.floor();
    let odd = integer && (c * T::c(0.5)).floor() != c * T::c(0.5);
    if x >= T::zero() || x.is_nan() {
        m
    } else if !integer {
        T::nan()
    } else if odd {
        -m
    } else {
        m
    }
}

map_ops! {
    /// y = x (broadcast; stop_gradient is this op with the gradient cut).
    Identity (1, true) "identity"
        f(x, p) { x[0] }
        df(x, y, p) { [one(), zero(), zero()] }
    /// y = p0 x + p1 (scalar add, sub, mul, neg).
    Affine (1, true) "affine"
        f(x, p) { p[0].mul_add(x[0], p[1]) }
        df(x, y, p) { [p[0], zero(), zero()] }
    /// y = sqrt(x).
    Sqrt (1, true) "sqrt"
        f(x, p) { x[0].sqrt() }
        df(x, y, p) { [T::c(0.5) / y, zero(), zero()] }
    /// y = 1 / sqrt(x).
    Rsqrt (1, true) "rsqrt"
        f(x, p) { x[0].sqrt().recip() }
        df(x, y, p) { [T::c(-0.5) * y * y * y, zero(), zero()] }
    /// y = e^x.
    Exp (1, true) "exp"
        f(x, p) { x[0].exp_v() }
        df(x, y, p) { [y, zero(), zero()] }
    /// y = ln x.
    Ln (1, true) "ln"
        f(x, p) { x[0].ln_v() }
        df(x, y, p) { [x[0].recip(), zero(), zero()] }
    /// y = sin x.
    Sin (1, true) "sin"
        f(x, p) { x[0].sin_cos_v().0 }
        df(x, y, p) { [x[0].sin_cos_v().1, zero(), zero()] }
    /// y = cos x.
    Cos (1, true) "cos"
        f(x, p) { x[0].sin_cos_v().1 }
        df(x, y, p) { [-x[0].sin_cos_v().0, zero(), zero()] }
    /// y = asin x, x in [-1, 1].
    Asin (1, true) "asin"
        f(x, p) { x[0].asin_v() }
        df(x, y, p) { [(T::one() - x[0] * x[0]).sqrt().recip(), zero(), zero()] }
    /// y = acos x, x in [-1, 1].
    Acos (1, true) "acos"
        f(x, p) { x[0].acos_v() }
        df(x, y, p) { [-(T::one() - x[0] * x[0]).sqrt().recip(), zero(), zero()] }
    /// y = |x|; derivative 0 at 0.
    Abs (1, true) "abs"
        f(x, p) { x[0].abs() }
        df(x, y, p) {
            let s = if x[0] > T::zero() { T::one() } else if x[0] < T::zero() { -T::one() } else { T::zero() };
            [s, zero(), zero()]
        }
    /// y = 1 / (1 + e^-x).
    Sigmoid (1, true) "sigmoid"
        f(x, p) { (T::one() + (-x[0]).exp_v()).recip() }
        df(x, y, p) { [y * (T::one() - y), zero(), zero()] }
    /// y = ln(1 + e^x), computed as max(x, 0) + ln(1 + e^-|x|) (no overflow).
    Softplus (1, true) "softplus"
        f(x, p) { x[0].max(T::zero()) + ln_1p((-x[0].abs()).exp_v()) }
        df(x, y, p) { [(T::one() + (-x[0]).exp_v()).recip(), zero(), zero()] }
    /// y = x^p0 for a constant exponent.
    Powf (1, true) "powf"
        f(x, p) { powf(x[0], p[0]) }
        df(x, y, p) { [p[0] * powf(x[0], p[0] - T::one()), zero(), zero()] }
    /// y = min(max(x, p0), p1); derivative 1 strictly inside, 0 at and beyond the bounds.
    Clamp (1, true) "clamp"
        f(x, p) {
            let lo = if x[0] < p[0] { p[0] } else { x[0] };
            if lo > p[1] { p[1] } else { lo }
        }
        df(x, y, p) { [indicator(x[0] > p[0] && x[0] < p[1]), zero(), zero()] }
    /// Huber loss with threshold p0: x^2 / 2 inside [-p0, p0], p0 (|x| - p0 / 2) outside.
    Huber (1, true) "huber"
        f(x, p) {
            let a = x[0].abs();
            if a <= p[0] { T::c(0.5) * x[0] * x[0] } else { p[0] * (a - T::c(0.5) * p[0]) }
        }
        df(x, y, p) {
            let g = if x[0] > p[0] { p[0] } else if x[0] < -p[0] { -p[0] } else { x[0] };
            [g, zero(), zero()]
        }
    /// y = floor(x); no gradient.
    Floor (1, false) "floor"
        f(x, p) { x[0].floor() }
        df(x, y, p) { [zero(), zero(), zero()] }
    /// y = a + b.
    Add (2, true) "add"
        f(x, p) { x[0] + x[1] }
        df(x, y, p) { [one(), one(), zero()] }
    /// y = a - b.
    Sub (2, true) "sub"
        f(x, p) { x[0] - x[1] }
        df(x, y, p) { [one(), -T::one(), zero()] }
    /// y = a b.
    Mul (2, true) "mul"
        f(x, p) { x[0] * x[1] }
        df(x, y, p) { [x[1], x[0], zero()] }
    /// y = a / b.
    Div (2, true) "div"
        f(x, p) { x[0] / x[1] }
        df(x, y, p) { [x[1].recip(), -y / x[1], zero()] }
    /// y = a^b for a >= 0.
    Pow (2, true) "pow"
        f(x, p) { pow_nonneg(x[0], x[1]) }
        df(x, y, p) {
            let db = if y == T::zero() { T::zero() } else { y * x[0].ln_v() };
            [x[1] * pow_nonneg(x[0], x[1] - T::one()), db, zero()]
        }
    /// y = atan2(a, b): the angle of the point (b, a).
    Atan2 (2, true) "atan2"
        f(x, p) { x[0].atan2_v(x[1]) }
        df(x, y, p) {
            let r2 = (x[0] * x[0] + x[1] * x[1]).recip();
            [x[1] * r2, -x[0] * r2, zero()]
        }
    /// y = min(a, b); on ties each input gets half the gradient.
    Min (2, true) "min"
        f(x, p) { if x[1] < x[0] { x[1] } else { x[0] } }
        df(x, y, p) { [win(x[0] < x[1], x[0] == x[1]), win(x[1] < x[0], x[0] == x[1]), zero()] }
    /// y = max(a, b); on ties each input gets half the gradient.
    Max (2, true) "max"
        f(x, p) { if x[1] > x[0] { x[1] } else { x[0] } }
        df(x, y, p) { [win(x[0] > x[1], x[0] == x[1]), win(x[1] > x[0], x[0] == x[1]), zero()] }
    /// Mask: 1 where a < b, else 0; no gradient.
    Lt (2, false) "lt"
        f(x, p) { indicator(x[0] < x[1]) }
        df(x, y, p) { [zero(), zero(), zero()] }
    /// Mask: 1 where a <= b, else 0; no gradient.
    Le (2, false) "le"
        f(x, p) { indicator(x[0] <= x[1]) }
        df(x, y, p) { [zero(), zero(), zero()] }
    /// Mask: 1 where a > b, else 0; no gradient.
    Gt (2, false) "gt"
        f(x, p) { indicator(x[0] > x[1]) }
        df(x, y, p) { [zero(), zero(), zero()] }
    /// Mask: 1 where a >= b, else 0; no gradient.
    Ge (2, false) "ge"
        f(x, p) { indicator(x[0] >= x[1]) }
        df(x, y, p) { [zero(), zero(), zero()] }
    /// Mask: 1 where a == b, else 0; no gradient.
    Eq (2, false) "eq"
        f(x, p) { indicator(x[0] == x[1]) }
        df(x, y, p) { [zero(), zero(), zero()] }
    /// y = a b + c, fused.
    MulAdd (3, true) "mul_add"
        f(x, p) { x[0].mul_add(x[1], x[2]) }
        df(x, y, p) { [x[1], x[0], one()] }
    /// y = a where the mask is non-zero, else b (inputs: mask, a, b).
    Select (3, true) "select"
        f(x, p) { if x[0] != T::zero() { x[1] } else { x[2] } }
        df(x, y, p) { [zero(), indicator(x[0] != T::zero()), indicator(x[0] == T::zero())] }
}

/// y = f(x) over a tile: every input slice has the output's length.
#[inline(always)]
pub(crate) fn forward<T: Real, F: MapOp<T>>(x: [&[T]; 3], y: &mut [T], p: [T; 2]) {
    let n = y.len();
    let z = T::zero();
    match F::ARITY {
        1 => {
            for (y, &a) in y.iter_mut().zip(&x[0][..n]) {
                *y = F::f([a, z, z], p);
            }
        }
        2 => {
            for ((y, &a), &b) in y.iter_mut().zip(&x[0][..n]).zip(&x[1][..n]) {
                *y = F::f([a, b, z], p);
            }
        }
        _ => {
            for (((y, &a), &b), &c) in y.iter_mut().zip(&x[0][..n]).zip(&x[1][..n]).zip(&x[2][..n]) {
                *y = F::f([a, b, c], p);
            }
        }
    }
}

/// gx += gy * dy/dx_K over a tile (the vector-Jacobian product for input K);
/// without ACC the first contribution overwrites, which spares zeroing.
#[inline(always)]
fn backward_input<T: Real, F: MapOp<T>, const K: usize, const ACC: bool>(
    x: [&[T]; 3],
    y: &[T],
    gy: &[T],
    gx: &mut [T],
    p: [T; 2],
) {
    let n = gx.len();
    let (y, gy) = (&y[..n], &gy[..n]);
    let z = T::zero();
    let put = |g: &mut T, gy: T, d: T| *g = if ACC { gy.mul_add(d, *g) } else { gy * d };
    match F::ARITY {
        1 => {
            for (((g, &a), &y), &gy) in gx.iter_mut().zip(&x[0][..n]).zip(y).zip(gy) {
                put(g, gy, F::df([a, z, z], y, p)[K]);
            }
        }
        2 => {
            let ab = x[0][..n].iter().zip(&x[1][..n]);
            for (((g, (&a, &b)), &y), &gy) in gx.iter_mut().zip(ab).zip(y).zip(gy) {
                put(g, gy, F::df([a, b, z], y, p)[K]);
            }
        }
        _ => {
            let abc = x[0][..n].iter().zip(&x[1][..n]).zip(&x[2][..n]);
            for (((g, ((&a, &b), &c)), &y), &gy) in gx.iter_mut().zip(abc).zip(y).zip(gy) {
                put(g, gy, F::df([a, b, c], y, p)[K]);
            }
        }
    }
}

/// gx (+)= gy * dy/dx_k over a tile.
#[inline(always)]
pub(crate) fn backward<T: Real, F: MapOp<T>>(
    k: usize,
    accumulate: bool,
    x: [&[T]; 3],
    y: &[T],
    gy: &[T],
    gx: &mut [T],
    p: [T; 2],
) {
    match (k, accumulate) {
        (0, true) => backward_input::<T, F, 0, true>(x, y, gy, gx, p),
        (0, false) => backward_input::<T, F, 0, false>(x, y, gy, gx, p),
        (1, true) => backward_input::<T, F, 1, true>(x, y, gy, gx, p),
        (1, false) => backward_input::<T, F, 1, false>(x, y, gy, gx, p),
        (_, true) => backward_input::<T, F, 2, true>(x, y, gy, gx, p),
        (_, false) => backward_input::<T, F, 2, false>(x, y, gy, gx, p),
    }
}
