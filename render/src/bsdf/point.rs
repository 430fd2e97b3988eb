//! The same reflectance models at single points, without a tape: for renders that need no
//! derivatives (the evaluation's relit spheres, the light an inserted object sends the ground).
//! Local shading frame (normal on +Z), `f cos` as in [`Bsdf`](super::Bsdf); each model's
//! formulas and sampler are its tape twin's (a test compares the two).

use std::f32::consts::{FRAC_1_PI, PI};

use glam::{Vec2, Vec3};

use super::{GgxMetal, Lambertian, Mirror};
use crate::sampling::ggx;

/// The material at one point.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PointSurface {
    /// Specular albedo A (Schlick's F0; the diffuse albedo for Lambertian), RGB.
    pub albedo: [f32; 3],
    /// Roughness r; GGX alpha = r^2.
    pub roughness: f32,
}

/// A sampled incident direction, its weight and its density.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PointSample {
    /// The direction light arrives from, local frame (below the horizon: weight 0).
    pub wi: Vec3,
    /// `f(wo, wi) cos(theta_i) / pdf(wi)` (a Dirac lobe's reflectance), RGB.
    pub weight: [f32; 3],
    /// The solid-angle density of `wi` (0 for a Dirac lobe or below the horizon).
    pub pdf: f32,
}

/// A reflectance model evaluated and sampled at one point.
pub trait PointBsdf: Send + Sync {
    /// `f(wo, wi) cos(theta_i)` (zero below the horizon), RGB.
    fn eval_at(&self, s: &PointSurface, wo: Vec3, wi: Vec3) -> [f32; 3];
    /// The solid-angle density with which [`sample_at`](Self::sample_at) picks `wi`.
    fn pdf_at(&self, s: &PointSurface, wo: Vec3, wi: Vec3) -> f32;
    /// Picks `wi` from two uniform random numbers.
    fn sample_at(&self, s: &PointSurface, wo: Vec3, u: Vec2) -> PointSample;
    /// Whether the lobe is a single direction, which only its own sample reaches.
    fn is_dirac(&self) -> bool {
        false
    }
}

/// The sample at `wi` with weight `f cos / pdf` from `bsdf`'s own eval and pdf.
fn weighed<B: PointBsdf>(bsdf: &B, s: &PointSurface, wo: Vec3, wi: Vec3) -> PointSample {
    let pdf = bsdf.pdf_at(s, wo, wi);
    let weight = if pdf > 0.0 {
        bsdf.eval_at(s, wo, wi).map(|f| f / pdf)
    } else {
        [0.0; 3]
    };
    PointSample { wi, weight, pdf }
}

impl PointBsdf for GgxMetal {
    fn eval_at(&self, s: &PointSurface, wo: Vec3, wi: Vec3) -> [f32; 3] {
        let alpha = ggx::alpha_from_roughness(s.roughness);
        ggx::brdf(wo, wi, s.albedo, alpha).map(|f| f * wi.z)
    }

    fn pdf_at(&self, s: &PointSurface, wo: Vec3, wi: Vec3) -> f32 {
        if wo.z <= 0.0 || wi.z <= 0.0 {
            return 0.0;
        }
        ggx::reflection_pdf(wo, wi, ggx::alpha_from_roughness(s.roughness))
    }

    fn sample_at(&self, s: &PointSurface, wo: Vec3, u: Vec2) -> PointSample {
        let wi = ggx::sample_reflection(wo, ggx::alpha_from_roughness(s.roughness), u).wi;
        weighed(self, s, wo, wi)
    }
}

impl PointBsdf for Mirror {
    /// A Dirac lobe: zero for any given pair of directions.
    fn eval_at(&self, _s: &PointSurface, _wo: Vec3, _wi: Vec3) -> [f32; 3] {
        [0.0; 3]
    }

    fn pdf_at(&self, _s: &PointSurface, _wo: Vec3, _wi: Vec3) -> f32 {
        0.0
    }

    fn sample_at(&self, s: &PointSurface, wo: Vec3, _u: Vec2) -> PointSample {
        PointSample {
            wi: Vec3::new(-wo.x, -wo.y, wo.z),
            weight: if wo.z > 0.0 { s.albedo } else { [0.0; 3] },
            pdf: 0.0,
        }
    }

    fn is_dirac(&self) -> bool {
        true
    }
}

impl PointBsdf for Lambertian {
    fn eval_at(&self, s: &PointSurface, wo: Vec3, wi: Vec3) -> [f32; 3] {
        let cos = self.pdf_at(s, wo, wi);
        s.albedo.map(|a| a * cos)
    }

    fn pdf_at(&self, _s: &PointSurface, wo: Vec3, wi: Vec3) -> f32 {
        if wo.z > 0.0 && wi.z > 0.0 {
            wi.z * FRAC_1_PI
        } else {
            0.0
        }
    }

    fn sample_at(&self, s: &PointSurface, wo: Vec3, u: Vec2) -> PointSample {
        // Cosine-weighted, as the tape's: a uniform disk point lifted to the hemisphere.
        let r = u.x.sqrt();
        let (sin_phi, cos_phi) = (2.0 * PI * u.y).sin_cos();
        let wi = Vec3::new(r * cos_phi, r * sin_phi, (1.0 - u.x).max(0.0).sqrt());
        PointSample {
            wi,
            weight: if wo.z > 0.0 { s.albedo } else { [0.0; 3] },
            pdf: self.pdf_at(s, wo, wi),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::super::{Bsdf, Surface};
    use super::*;
    use autodiff::{Tape, Vec3 as Vec3Var};

    /// Each model's point form against its tape form (f64), at directions above and below the
    /// horizon: eval, pdf, the sampled direction and its weight.
    #[test]
    fn point_models_are_their_tape_twins() {
        let n = 97;
        let unit = |i: usize, k: f32| {
            let t = (i as f32 + 0.5) / n as f32;
            Vec3::new((k * 7.0 * t).sin(), (k * 5.0 * t + 1.0).cos(), 1.6 * t - 0.3).normalize()
        };
        let wo: Vec<Vec3> = (0..n).map(|i| unit(i, 1.0)).collect();
        let wi: Vec<Vec3> = (0..n).map(|i| unit(i, 2.3)).collect();
        let u: Vec<Vec2> = (0..n)
            .map(|i| {
                Vec2::new(
                    ((i * 37) % n) as f32 / n as f32 + 0.003,
                    ((i * 11) % n) as f32 / n as f32 + 0.004,
                )
            })
            .collect();
        let models: [(&dyn PointBsdf, &dyn Bsdf<f64>); 3] =
            [(&GgxMetal, &GgxMetal), (&Lambertian, &Lambertian), (&Mirror, &Mirror)];
        for (point, tape_model) in models {
            for roughness in [0.2f32, 0.5, 0.9] {
                let surface = PointSurface {
                    albedo: [0.9, 0.6, 0.3],
                    roughness,
                };
                let tape = Tape::<f64>::new();
                let s = Surface {
                    albedo: surface.albedo.map(|a| tape.scalar(a as f64)),
                    roughness: tape.scalar(roughness as f64),
                };
                let column =
                    |v: &[Vec3], f: fn(&Vec3) -> f32| tape.constant(&v.iter().map(|p| f(p) as f64).collect::<Vec<_>>());
                let var3 = |v: &[Vec3]| Vec3Var::new(column(v, |p| p.x), column(v, |p| p.y), column(v, |p| p.z));
                let (wo_t, wi_t) = (var3(&wo), var3(&wi));
                let uv = [
                    tape.constant(&u.iter().map(|p| p.x as f64).collect::<Vec<_>>()),
                    tape.constant(&u.iter().map(|p| p.y as f64).collect::<Vec<_>>()),
                ];
                let eval = tape_model.eval(&s, wo_t, wi_t).map(|c| tape.to_vec(c));
                let pdf = tape.to_vec(tape_model.pdf(&s, wo_t, wi_t));
                let sample = tape_model.sample(&s, wo_t, uv);
                let sampled = [sample.wi.x, sample.wi.y, sample.wi.z].map(|c| tape.to_vec(c));
                let weight = sample.weight.map(|c| tape.to_vec(c));
                // A value the tape holds as one scalar applies to every sample.
                let at = |v: &[f64], i: usize| v[i.min(v.len() - 1)];
                let close = |a: f32, b: f64, what: &str, i: usize| {
                    assert!(
                        (a as f64 - b).abs() <= 1e-3 * b.abs() + 1e-5,
                        "r {roughness}, {what} {i}: point {a} vs tape {b}"
                    )
                };
                for i in 0..n {
                    let f = point.eval_at(&surface, wo[i], wi[i]);
                    (0..3).for_each(|c| close(f[c], at(&eval[c], i), "eval", i));
                    close(point.pdf_at(&surface, wo[i], wi[i]), at(&pdf, i), "pdf", i);
                    let smp = point.sample_at(&surface, wo[i], u[i]);
                    (0..3).for_each(|c| close(smp.wi[c], at(&sampled[c], i), "sampled wi", i));
                    if smp.wi.z > 1e-2 {
                        (0..3).for_each(|c| close(smp.weight[c], at(&weight[c], i), "weight", i));
                    }
                }
            }
        }
    }
}
