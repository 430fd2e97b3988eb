//! 3-vector fields (struct of arrays) and their rotation by a unit
//! quaternion, composed from the tape's ops (their gradients come for free).

use crate::real::Real;
use crate::tape::{Tape, Var};

/// A field of 3-vectors: three arrays of equal length (or length 1).
#[derive(Clone, Copy, Debug)]
pub struct Vec3<'t, T: Real> {
    /// x components.
    pub x: Var<'t, T>,
    /// y components.
    pub y: Var<'t, T>,
    /// z components.
    pub z: Var<'t, T>,
}

impl<'t, T: Real> Vec3<'t, T> {
    /// A field from its three component arrays.
    pub fn new(x: Var<'t, T>, y: Var<'t, T>, z: Var<'t, T>) -> Self {
        Vec3 { x, y, z }
    }

    /// A constant vector (length-1 components) on `tape`.
    pub fn constant(tape: &'t Tape<T>, v: [T; 3]) -> Self {
        Vec3 {
            x: tape.scalar(v[0]),
            y: tape.scalar(v[1]),
            z: tape.scalar(v[2]),
        }
    }

    /// Every vector times the scalar field `s`.
    pub fn scale(self, s: Var<'t, T>) -> Self {
        Vec3 {
            x: self.x * s,
            y: self.y * s,
            z: self.z * s,
        }
    }

    /// `self * s + o`, fused per component.
    pub fn scale_add(self, s: Var<'t, T>, o: Self) -> Self {
        Vec3 {
            x: self.x.mul_add(s, o.x),
            y: self.y.mul_add(s, o.y),
            z: self.z.mul_add(s, o.z),
        }
    }

    /// Dot product per element.
    pub fn dot(self, o: Self) -> Var<'t, T> {
        self.x.mul_add(o.x, self.y.mul_add(o.y, self.z * o.z))
    }

    /// Cross product per element.
    pub fn cross(self, o: Self) -> Self {
        Vec3 {
            x: self.y.mul_add(o.z, -(self.z * o.y)),
            y: self.z.mul_add(o.x, -(self.x * o.z)),
            z: self.x.mul_add(o.y, -(self.y * o.x)),
        }
    }

    /// Euclidean length per element.
    pub fn length(self) -> Var<'t, T> {
        self.dot(self).sqrt()
    }

    /// Unit vectors; a vector shorter than `eps` is divided by `eps` instead
    /// of its length, so a degenerate vector gives a finite value and gradient.
    pub fn normalize(self, eps: T) -> Self {
        let inv = self.dot(self).max_scalar(eps * eps).rsqrt();
        self.scale(inv)
    }

    /// Mirror reflection of `self` (pointing away from the surface) about
    /// the normal `n`: `2 (n . v) n - v`.
    pub fn reflect(self, n: Self) -> Self {
        let two_dot = self.dot(n) * T::c(2.0);
        n.scale_add(
            two_dot,
            Vec3 {
                x: -self.x,
                y: -self.y,
                z: -self.z,
            },
        )
    }
}

impl<'t, T: Real> std::ops::Add for Vec3<'t, T> {
    type Output = Self;
    /// Componentwise sum.
    fn add(self, o: Self) -> Self {
        Vec3 {
            x: self.x + o.x,
            y: self.y + o.y,
            z: self.z + o.z,
        }
    }
}

impl<'t, T: Real> std::ops::Sub for Vec3<'t, T> {
    type Output = Self;
    /// Componentwise difference.
    fn sub(self, o: Self) -> Self {
        Vec3 {
            x: self.x - o.x,
            y: self.y - o.y,
            z: self.z - o.z,
        }
    }
}

impl<'t, T: Real> std::ops::Neg for Vec3<'t, T> {
    type Output = Self;
    /// Componentwise negation.
    fn neg(self) -> Self {
        Vec3 {
            x: -self.x,
            y: -self.y,
            z: -self.z,
        }
    }
}

/// A rotation as a unit quaternion `w + xi + yj + zk` (length-1 arrays for a
/// single pose, or per-element fields).
#[derive(Clone, Copy, Debug)]
pub struct Quat<'t, T: Real> {
    /// Real part.
    pub w: Var<'t, T>,
    /// Imaginary parts.
    pub v: Vec3<'t, T>,
}

impl<'t, T: Real> Quat<'t, T> {
    /// From components (not normalised).
    pub fn new(w: Var<'t, T>, x: Var<'t, T>, y: Var<'t, T>, z: Var<'t, T>) -> Self {
        Quat {
            w,
            v: Vec3::new(x, y, z),
        }
    }

    /// Divided by its norm: optimisers step freely in R^4, the rotation
    /// stays a rotation.
    pub fn normalize(self) -> Self {
        let inv = self.w.mul_add(self.w, self.v.dot(self.v)).rsqrt();
        Quat {
            w: self.w * inv,
            v: self.v.scale(inv),
        }
    }

    /// Rotates the field `p`: `p + 2w (v x p) + 2 v x (v x p)` (the sandwich
    /// q p q* expanded for a unit q).
    pub fn rotate(self, p: Vec3<'t, T>) -> Vec3<'t, T> {
        let t = self.v.cross(p);
        let t = Vec3 {
            x: t.x * T::c(2.0),
            y: t.y * T::c(2.0),
            z: t.z * T::c(2.0),
        };
        t.scale_add(self.w, p) + self.v.cross(t)
    }
}
