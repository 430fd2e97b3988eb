//! Warps from the unit square to the disk, the hemisphere and the sphere, with their pdfs
//! (pbrt-v4, section A.5 "Sampling Multidimensional Functions").

use std::f32::consts::{FRAC_1_PI, FRAC_PI_4, PI};

use glam::{Vec2, Vec3};

/// A point of [0, 1] with density proportional to `(1 - t) a + t b` (a, b >= 0, not both 0), by
/// inverting its CDF from uniform `u` in [0, 1) (pbrt-v4, `SampleLinear`): the root of
/// `a t + (b - a) t^2 / 2 = u (a + b) / 2`, in the form that stays exact as `a - b` vanishes.
pub fn sample_linear(u: f64, a: f64, b: f64) -> f64 {
    if u == 0.0 && a == 0.0 {
        return 0.0;
    }
    let t = u * (a + b) / (a + ((1.0 - u) * a * a + u * b * b).sqrt());
    t.min(1.0)
}

/// Two independent standard normal values from a point of [0, 1)^2 (the Box-Muller transform:
/// radius `sqrt(-2 ln(1 - u.x))`, angle `2 pi u.y`).
pub fn sample_standard_normal_2d(u: Vec2) -> Vec2 {
    let radius = (-2.0 * (1.0 - u.x).ln()).sqrt();
    let (sin, cos) = (2.0 * PI * u.y).sin_cos();
    radius * Vec2::new(cos, sin)
}

/// Shirley-Chiu concentric map of [0, 1)^2 onto the unit disk (area preserving, low distortion).
pub fn sample_concentric_disk(u: Vec2) -> Vec2 {
    let o = 2.0 * u - Vec2::ONE;
    if o == Vec2::ZERO {
        return Vec2::ZERO;
    }
    let (r, theta) = if o.x.abs() > o.y.abs() {
        (o.x, FRAC_PI_4 * (o.y / o.x))
    } else {
        (o.y, 0.5 * PI - FRAC_PI_4 * (o.x / o.y))
    };
    r * Vec2::new(theta.cos(), theta.sin())
}

/// Cosine-weighted direction on the +Z hemisphere (Malley's method: lift a uniform disk point).
pub fn sample_cosine_hemisphere(u: Vec2) -> Vec3 {
    let d = sample_concentric_disk(u);
    Vec3::new(d.x, d.y, (1.0 - d.length_squared()).max(0.0).sqrt())
}

/// Solid-angle pdf of [`sample_cosine_hemisphere`]: cos(theta) / pi above the horizon, else 0.
pub fn cosine_hemisphere_pdf(w: Vec3) -> f32 {
    w.z.max(0.0) * FRAC_1_PI
}

/// Uniform direction on the unit sphere (z uniform in [-1, 1], Archimedes).
pub fn sample_uniform_sphere(u: Vec2) -> Vec3 {
    let z = 1.0 - 2.0 * u.x;
    let r = (1.0 - z * z).max(0.0).sqrt();
    let (sin_phi, cos_phi) = (2.0 * PI * u.y).sin_cos();
    Vec3::new(r * cos_phi, r * sin_phi, z)
}

/// Solid-angle pdf of [`sample_uniform_sphere`]: 1 / (4 pi).
pub fn uniform_sphere_pdf() -> f32 {
    0.25 * FRAC_1_PI
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sample_linear_inverts_the_linear_cdf() {
        // Constant: the identity. a = 0, b = 1: density 2t, CDF t^2. And the CDF at the result
        // gives back u for a sloped segment.
        assert_eq!(sample_linear(0.3, 2.0, 2.0), 0.3);
        assert!((sample_linear(0.25, 0.0, 1.0) - 0.5).abs() < 1e-15);
        assert_eq!(sample_linear(0.0, 0.0, 1.0), 0.0);
        let (a, b) = (3.0, 0.5);
        for u in [0.01, 0.4, 0.99] {
            let t = sample_linear(u, a, b);
            let cdf = (a * t + 0.5 * (b - a) * t * t) / (0.5 * (a + b));
            assert!((cdf - u).abs() < 1e-12, "u {u}: t {t}, cdf {cdf}");
        }
    }
}
