//! The ops a program records on a tape, as methods and operators of [`Var`].
//!
//! Elementwise ops broadcast length-1 arrays; any other length mismatch
//! panics with the op's name and both shapes. Their constructors are here,
//! each one's forward `f` and derivatives `df` in `kernels::map`, their
//! tests in `tests`.
//!
//! A structural op (its output is not an elementwise function of its
//! inputs) has a file here with its constructor and its tests (`sum`,
//! `gather`, `scatter_add`, `slice`, `concat`, `custom`), and one of the same
//! name in `kernels` with what it computes, forward and backward. The layers
//! go one way: the kernels know only the numbers, the executor (`exec`) the
//! recorded graph and the kernels, the tape the executor, and the ops here
//! the tape.

pub(crate) mod concat;
pub mod custom;
pub(crate) mod gather;
pub(crate) mod scatter_add;
pub(crate) mod slice;
pub(crate) mod sum;

#[cfg(test)]
mod tests;

use std::ops::{Add, Div, Mul, Neg, Sub};

use crate::exec::Op;
use crate::kernels::map::MapKind;
use crate::real::Real;
use crate::tape::Var;

impl<'t, T: Real> Var<'t, T> {
    /// Records an elementwise op over `inputs` (lengths equal, or 1 to broadcast).
    fn map(kind: MapKind, params: [T; 2], inputs: &[Var<'t, T>]) -> Var<'t, T> {
        let tape = inputs[0].tape;
        let mut len = 1;
        for v in inputs {
            inputs[0].same_tape(*v, kind.name());
            let l = v.len();
            if l != 1 {
                if len != 1 && l != len {
                    let shapes: Vec<String> = inputs.iter().map(|v| format!("[{}]", v.len())).collect();
                    panic!(
                        "{}: shape mismatch: operands have shapes {}",
                        kind.name(),
                        shapes.join(" and ")
                    );
                }
                len = l;
            }
        }
        tape.record(Op::Map(kind, params), len, inputs)
    }

    fn unary(self, kind: MapKind) -> Self {
        Self::map(kind, [T::zero(); 2], &[self])
    }

    fn binary(self, kind: MapKind, other: Self) -> Self {
        Self::map(kind, [T::zero(); 2], &[self, other])
    }

    /// A constant scalar on this array's tape.
    fn constant_like(self, value: T) -> Self {
        self.tape.scalar(value)
    }

    /// `scale * self + offset` in one op.
    pub fn affine(self, scale: T, offset: T) -> Self {
        Self::map(MapKind::Affine, [scale, offset], &[self])
    }
    /// `c - self` (for generic code, where `T - Var` cannot be written).
    pub fn rsub(self, c: T) -> Self {
        self.affine(-T::one(), c)
    }
    /// Square root.
    pub fn sqrt(self) -> Self {
        self.unary(MapKind::Sqrt)
    }
    /// `1 / sqrt(x)`.
    pub fn rsqrt(self) -> Self {
        self.unary(MapKind::Rsqrt)
    }
    /// `e^x`.
    pub fn exp(self) -> Self {
        self.unary(MapKind::Exp)
    }
    /// Natural logarithm.
    pub fn ln(self) -> Self {
        self.unary(MapKind::Ln)
    }
    /// Sine.
    pub fn sin(self) -> Self {
        self.unary(MapKind::Sin)
    }
    /// Cosine.
    pub fn cos(self) -> Self {
        self.unary(MapKind::Cos)
    }
    /// Arcsine (input in [-1, 1]).
    pub fn asin(self) -> Self {
        self.unary(MapKind::Asin)
    }
    /// Arccosine (input in [-1, 1]).
    pub fn acos(self) -> Self {
        self.unary(MapKind::Acos)
    }
    /// Absolute value (derivative 0 at 0).
    pub fn abs(self) -> Self {
        self.unary(MapKind::Abs)
    }
    /// Logistic sigmoid `1 / (1 + e^-x)`.
    pub fn sigmoid(self) -> Self {
        self.unary(MapKind::Sigmoid)
    }
    /// `ln(1 + e^x)`, without overflow.
    pub fn softplus(self) -> Self {
        self.unary(MapKind::Softplus)
    }
    /// `x^exponent` for a constant exponent (negative x needs an integer exponent).
    pub fn powf(self, exponent: T) -> Self {
        Self::map(MapKind::Powf, [exponent, T::zero()], &[self])
    }
    /// `self^exponent` elementwise, for `self >= 0`.
    pub fn pow(self, exponent: Self) -> Self {
        self.binary(MapKind::Pow, exponent)
    }
    /// Four-quadrant arctangent of `self / x` (the angle of the point (x, self)).
    pub fn atan2(self, x: Self) -> Self {
        self.binary(MapKind::Atan2, x)
    }
    /// Elementwise minimum (ties split the gradient).
    pub fn min(self, other: Self) -> Self {
        self.binary(MapKind::Min, other)
    }
    /// Elementwise maximum (ties split the gradient).
    pub fn max(self, other: Self) -> Self {
        self.binary(MapKind::Max, other)
    }
    /// Minimum with a constant.
    pub fn min_scalar(self, c: T) -> Self {
        self.min(self.constant_like(c))
    }
    /// Maximum with a constant.
    pub fn max_scalar(self, c: T) -> Self {
        self.max(self.constant_like(c))
    }
    /// Clamp into `[lo, hi]`; gradient 1 strictly inside, 0 at and beyond the bounds.
    pub fn clamp(self, lo: T, hi: T) -> Self {
        assert!(lo <= hi, "clamp: lower bound {lo} above upper bound {hi}");
        Self::map(MapKind::Clamp, [lo, hi], &[self])
    }
    /// Huber function with threshold `delta`: quadratic inside, linear outside.
    pub fn huber(self, delta: T) -> Self {
        assert!(delta > T::zero(), "huber: delta must be positive, got {delta}");
        Self::map(MapKind::Huber, [delta, T::zero()], &[self])
    }
    /// Largest integer not above x (no gradient).
    pub fn floor(self) -> Self {
        self.unary(MapKind::Floor)
    }
    /// `self * b + c`, fused.
    pub fn mul_add(self, b: Self, c: Self) -> Self {
        Self::map(MapKind::MulAdd, [T::zero(); 2], &[self, b, c])
    }
    /// Mask (1 or 0, no gradient): `self < other`.
    pub fn lt(self, other: Self) -> Self {
        self.binary(MapKind::Lt, other)
    }
    /// Mask: `self <= other`.
    pub fn le(self, other: Self) -> Self {
        self.binary(MapKind::Le, other)
    }
    /// Mask: `self > other`.
    pub fn gt(self, other: Self) -> Self {
        self.binary(MapKind::Gt, other)
    }
    /// Mask: `self >= other`.
    pub fn ge(self, other: Self) -> Self {
        self.binary(MapKind::Ge, other)
    }
    /// Mask: `self == other`.
    pub fn eq_mask(self, other: Self) -> Self {
        self.binary(MapKind::Eq, other)
    }
    /// With `self` a mask: `a` where the mask is non-zero, `b` elsewhere.
    pub fn select(self, a: Self, b: Self) -> Self {
        Self::map(MapKind::Select, [T::zero(); 2], &[self, a, b])
    }
    /// A length-1 array repeated `len` times. Adjoint: the sum of the output's.
    pub fn broadcast(self, len: usize) -> Self {
        assert!(
            self.len() == 1 || self.len() == len,
            "broadcast: shape mismatch: cannot broadcast shape [{}] to [{len}]",
            self.len()
        );
        self.tape
            .record(Op::Map(MapKind::Identity, [T::zero(); 2]), len, &[self])
    }
    /// The same values with the gradient cut.
    pub fn stop_gradient(self) -> Self {
        self.tape
            .record_detached(Op::Map(MapKind::Identity, [T::zero(); 2]), self.len(), &[self])
    }
    /// `x * x`.
    pub fn square(self) -> Self {
        self * self
    }
}

macro_rules! binary_operator {
    ($trait:ident, $method:ident, $kind:ident, $scale:expr, $offset:expr) => {
        impl<'t, T: Real> $trait for Var<'t, T> {
            type Output = Var<'t, T>;
            fn $method(self, rhs: Self) -> Self {
                self.binary(MapKind::$kind, rhs)
            }
        }
        impl<'t, T: Real> $trait<T> for Var<'t, T> {
            type Output = Var<'t, T>;
            fn $method(self, rhs: T) -> Self {
                let (scale, offset): (fn(T) -> T, fn(T) -> T) = ($scale, $offset);
                self.affine(scale(rhs), offset(rhs))
            }
        }
    };
}

binary_operator!(Add, add, Add, |_| T::one(), |c| c);
binary_operator!(Sub, sub, Sub, |_| T::one(), |c| -c);
binary_operator!(Mul, mul, Mul, |c| c, |_| T::zero());
binary_operator!(Div, div, Div, |c| c.recip(), |_| T::zero());

impl<'t, T: Real> Neg for Var<'t, T> {
    type Output = Var<'t, T>;
    fn neg(self) -> Self {
        self.affine(-T::one(), T::zero())
    }
}

macro_rules! scalar_on_left {
    ($($t:ty),*) => {$(
        impl<'t> Add<Var<'t, $t>> for $t {
            type Output = Var<'t, $t>;
            fn add(self, rhs: Var<'t, $t>) -> Var<'t, $t> { rhs.affine(1.0, self) }
        }
        impl<'t> Sub<Var<'t, $t>> for $t {
            type Output = Var<'t, $t>;
            fn sub(self, rhs: Var<'t, $t>) -> Var<'t, $t> { rhs.affine(-1.0, self) }
        }
        impl<'t> Mul<Var<'t, $t>> for $t {
            type Output = Var<'t, $t>;
            fn mul(self, rhs: Var<'t, $t>) -> Var<'t, $t> { rhs.affine(self, 0.0) }
        }
        impl<'t> Div<Var<'t, $t>> for $t {
            type Output = Var<'t, $t>;
            fn div(self, rhs: Var<'t, $t>) -> Var<'t, $t> { rhs.tape().scalar(self) / rhs }
        }
    )*};
}

scalar_on_left!(f32, f64);
