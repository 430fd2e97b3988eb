//! The GGX metal microfacet model as plain scalar functions, and its visible-normal sampler.
//!
//! Local shading frame: the normal n is +Z, so `n.w = w.z`. With roughness r and alpha = r^2
//! (PAPER.md):
//!   D(h)  = alpha^2 / (pi ((n.h)^2 (alpha^2 - 1) + 1)^2)
//!   G1(w) = 2 |n.w| / (|n.w| + sqrt(alpha^2 + (1 - alpha^2) (n.w)^2))
//!   F     = A + (1 - A) (1 - |h.wo|)^5                          (Schlick, F0 = albedo A)
//! and the distribution of visible normals (Heitz 2018, eq. 3)
//!   D_v(h) = G1(wo) max(0, wo.h) D(h) / (n.wo).

use std::f32::consts::PI;

use glam::{Vec2, Vec3};

/// GGX alpha from perceptual roughness: alpha = r^2.
pub fn alpha_from_roughness(roughness: f32) -> f32 {
    roughness * roughness
}

/// The GGX normal distribution D(h) for `cos_theta_h = n.h`; zero below the surface.
pub fn distribution(cos_theta_h: f32, alpha: f32) -> f32 {
    if cos_theta_h <= 0.0 {
        return 0.0;
    }
    let alpha2 = alpha * alpha;
    let denom = cos_theta_h * cos_theta_h * (alpha2 - 1.0) + 1.0;
    alpha2 / (PI * denom * denom)
}

/// Smith's masking G1(w) for GGX, `cos_theta = n.w`.
pub fn smith_g1(cos_theta: f32, alpha: f32) -> f32 {
    let alpha2 = alpha * alpha;
    let c = cos_theta.abs();
    2.0 * c / (c + (alpha2 + (1.0 - alpha2) * c * c).sqrt())
}

/// Schlick's Fresnel with F0 = `albedo`: `A + (1 - A)(1 - |h.wo|)^5`, per channel.
pub fn schlick_fresnel(albedo: [f32; 3], cos_h_wo: f32) -> [f32; 3] {
    let m = (1.0 - cos_h_wo.abs()).clamp(0.0, 1.0);
    let m5 = (m * m) * (m * m) * m;
    albedo.map(|a| a + (1.0 - a) * m5)
}

/// The full metal BRDF f = D F G1(wi) G1(wo) / (4 (n.wi)(n.wo)) in the local frame; zero below the horizon.
pub fn brdf(wo: Vec3, wi: Vec3, albedo: [f32; 3], alpha: f32) -> [f32; 3] {
    if wo.z <= 0.0 || wi.z <= 0.0 {
        return [0.0; 3];
    }
    let h = (wo + wi).normalize();
    let scale = distribution(h.z, alpha) * smith_g1(wi.z, alpha) * smith_g1(wo.z, alpha) / (4.0 * wi.z * wo.z);
    schlick_fresnel(albedo, h.dot(wo)).map(|f| f * scale)
}

/// The density D_v(h) of visible normals seen from `wo` (unit, `wo.z > 0`), per unit solid angle of h.
pub fn visible_normal_pdf(wo: Vec3, h: Vec3, alpha: f32) -> f32 {
    if wo.z <= 0.0 {
        return 0.0;
    }
    smith_g1(wo.z, alpha) * wo.dot(h).max(0.0) * distribution(h.z, alpha) / wo.z
}

/// Samples a microfacet normal h from D_v for `wo` (unit, `wo.z > 0`) (Heitz 2018, listing 1).
pub fn sample_visible_normal(wo: Vec3, alpha: f32, u: Vec2) -> Vec3 {
    // Stretch the view so the GGX ellipsoid becomes the hemisphere.
    let vh = Vec3::new(alpha * wo.x, alpha * wo.y, wo.z).normalize();
    let len2 = vh.x * vh.x + vh.y * vh.y;
    let t1 = if len2 > 0.0 {
        Vec3::new(-vh.y, vh.x, 0.0) / len2.sqrt()
    } else {
        Vec3::X
    };
    let t2 = vh.cross(t1);
    // A uniform disk point, squeezed onto the part of the disk that is visible from vh.
    let r = u.x.sqrt();
    let (sin_phi, cos_phi) = (2.0 * PI * u.y).sin_cos();
    let p1 = r * cos_phi;
    let s = 0.5 * (1.0 + vh.z);
    let p2 = (1.0 - s) * (1.0 - p1 * p1).max(0.0).sqrt() + s * r * sin_phi;
    let nh = p1 * t1 + p2 * t2 + (1.0 - p1 * p1 - p2 * p2).max(0.0).sqrt() * vh;
    // Unstretch back to the GGX microfacet normal.
    Vec3::new(alpha * nh.x, alpha * nh.y, nh.z.max(0.0)).normalize()
}

/// A reflected direction sampled through a visible normal.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GgxSample {
    /// The sampled microfacet normal (local frame).
    pub h: Vec3,
    /// The incident light direction wi = reflect(wo, h) (local frame); may lie below the horizon.
    pub wi: Vec3,
    /// Solid-angle pdf of wi: D_v(h) / (4 |wo.h|).
    pub pdf: f32,
}

/// Samples the light direction by reflecting `wo` about a visible normal (the paper's estimator).
pub fn sample_reflection(wo: Vec3, alpha: f32, u: Vec2) -> GgxSample {
    let h = sample_visible_normal(wo, alpha, u);
    let wo_h = wo.dot(h);
    let wi = 2.0 * wo_h * h - wo;
    GgxSample {
        h,
        wi,
        pdf: visible_normal_pdf(wo, h, alpha) / (4.0 * wo_h.abs()),
    }
}

/// Solid-angle pdf that [`sample_reflection`] returns `wi` for `wo`.
pub fn reflection_pdf(wo: Vec3, wi: Vec3, alpha: f32) -> f32 {
    let Some(h) = (wo + wi).try_normalize() else {
        return 0.0;
    };
    let wo_h = wo.dot(h);
    if wo_h <= 0.0 {
        return 0.0;
    }
    visible_normal_pdf(wo, h, alpha) / (4.0 * wo_h)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn literal_values() {
        // r = 0.5: alpha = 0.25, alpha^2 = 1/16; at normal incidence D = 1 / (pi alpha^2).
        let alpha = alpha_from_roughness(0.5);
        assert!((distribution(1.0, alpha) - 16.0 / PI).abs() < 1e-4);
        assert_eq!(smith_g1(1.0, alpha), 1.0);
        // cos = 0.5: 2 * 0.5 / (0.5 + sqrt(1/16 + 15/16 * 0.25)).
        let expected = 1.0 / (0.5 + (1.0f32 / 16.0 + 15.0 / 64.0).sqrt());
        assert!((smith_g1(0.5, alpha) - expected).abs() < 1e-6);
        assert_eq!(schlick_fresnel([0.9, 0.5, 0.0], 1.0), [0.9, 0.5, 0.0]);
        assert_eq!(schlick_fresnel([0.9, 0.5, 0.0], 0.0), [1.0, 1.0, 1.0]);
    }

    #[test]
    fn projected_ndf_integrates_to_one() {
        // Integral of D(h) (n.h) over the hemisphere = 1, in (cos theta, phi) with the midpoint rule.
        for roughness in [0.3f32, 0.6, 0.9] {
            let alpha = alpha_from_roughness(roughness);
            let n = 200_000;
            let sum: f64 = (0..n)
                .map(|i| {
                    let c = (i as f64 + 0.5) / n as f64;
                    distribution(c as f32, alpha) as f64 * c
                })
                .sum();
            let integral = sum * 2.0 * std::f64::consts::PI / n as f64;
            assert!((integral - 1.0).abs() < 1e-3, "r = {roughness}: {integral}");
        }
    }

    #[test]
    fn sampled_pdf_matches_reflection_pdf() {
        let wo = Vec3::new(0.4, -0.2, 0.8).normalize();
        let s = sample_reflection(wo, 0.3, Vec2::new(0.3, 0.7));
        assert!((s.pdf - reflection_pdf(wo, s.wi, 0.3)).abs() < 1e-4 * s.pdf);
        assert!((s.wi.length() - 1.0).abs() < 1e-5);
    }
}
