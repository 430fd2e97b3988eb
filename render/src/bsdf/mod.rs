//! BRDFs on a tape, in the style of Mitsuba's BSDF interface: `eval` (cosine
//! included), `pdf`, and `sample` returning a direction and its weight
//! `f cos / pdf`. Everything is per-sample arrays in the local shading frame
//! (normal on +Z), composed from autodiff ops, so the estimate is
//! differentiable in the material and, through the sampled direction (the
//! sample is *attached*: a smooth function of wo, roughness and the random
//! numbers), in the pose.
//!
//! Swapping the model is one line: pass another [`Bsdf`] to the integrator.
//! Each model also has a point form ([`PointBsdf`], plain f32, no tape) for
//! renders that need no derivatives.

use autodiff::{Real, Var, Vec3 as Vec3Var};

mod point;

pub use point::{PointBsdf, PointSample, PointSurface};

/// A reflectance model in both forms: on an f32 tape and at points.
pub trait Reflectance: Bsdf<f32> + PointBsdf {}

impl<B: Bsdf<f32> + PointBsdf> Reflectance for B {}

/// The material at each sample (from the probe's textures).
#[derive(Clone, Copy, Debug)]
pub struct Surface<'t, T: Real> {
    /// Specular albedo A (Schlick's F0; the diffuse albedo for Lambertian), RGB.
    pub albedo: [Var<'t, T>; 3],
    /// Roughness r; GGX alpha = r^2.
    pub roughness: Var<'t, T>,
}

/// A sampled incident direction and its Monte Carlo weight.
#[derive(Clone, Copy, Debug)]
pub struct BsdfSample<'t, T: Real> {
    /// The direction light arrives from, local frame (below the horizon: weight 0).
    pub wi: Vec3Var<'t, T>,
    /// `f(wo, wi) cos(theta_i) / pdf(wi)`, RGB.
    pub weight: [Var<'t, T>; 3],
}

/// A reflectance model evaluated and sampled over arrays of samples.
pub trait Bsdf<T: Real>: Send + Sync {
    /// Name, for reports.
    fn name(&self) -> &'static str;
    /// `f(wo, wi) cos(theta_i)` (zero below the horizon), RGB.
    fn eval<'t>(&self, s: &Surface<'t, T>, wo: Vec3Var<'t, T>, wi: Vec3Var<'t, T>) -> [Var<'t, T>; 3];
    /// The solid-angle density with which [`sample`](Self::sample) picks `wi`.
    fn pdf<'t>(&self, s: &Surface<'t, T>, wo: Vec3Var<'t, T>, wi: Vec3Var<'t, T>) -> Var<'t, T>;
    /// Picks `wi` from two uniform random numbers per sample.
    fn sample<'t>(&self, s: &Surface<'t, T>, wo: Vec3Var<'t, T>, u: [Var<'t, T>; 2]) -> BsdfSample<'t, T>;
}

/// Smallest cosine and length used as denominators: keeps every value and
/// every derivative finite at grazing angles and degenerate vectors.
fn tiny<T: Real>() -> T {
    T::c(1e-7)
}

/// The paper's metal: Cook-Torrance with GGX D (alpha = r^2), Schlick
/// Fresnel with F0 = albedo, separable Smith G = G1(wi) G1(wo) (PAPER.md),
/// sampled by visible normals (Heitz 2018), for which the weight reduces to
/// F(wo.h) G1(wi).
#[derive(Clone, Copy, Debug, Default)]
pub struct GgxMetal;

/// A perfect mirror with reflectance = albedo (no Fresnel variation).
#[derive(Clone, Copy, Debug, Default)]
pub struct Mirror;

/// Lambertian diffuse reflection with albedo, cosine-weighted sampling.
#[derive(Clone, Copy, Debug, Default)]
pub struct Lambertian;

/// `D(h) = alpha^2 / (pi ((n.h)^2 (alpha^2 - 1) + 1)^2)` for `cos_h = n.h`.
pub fn ggx_distribution<'t, T: Real>(cos_h: Var<'t, T>, alpha2: Var<'t, T>) -> Var<'t, T> {
    let d = (cos_h * cos_h).mul_add(alpha2 - T::one(), cos_h.tape().scalar(T::one()));
    // d vanishes only for alpha = 0 on the normal (0 / 0): a Dirac lobe, whose D is 0 there as a
    // mirror's eval and pdf are.
    alpha2 / (d * d * T::PI()).max_scalar(T::c(1e-30))
}

/// `G1(w) = 2 |n.w| / (|n.w| + sqrt(alpha^2 + (1 - alpha^2) (n.w)^2))`.
pub fn smith_g1<'t, T: Real>(cos: Var<'t, T>, alpha2: Var<'t, T>) -> Var<'t, T> {
    let c = cos.abs();
    let root = (alpha2.rsub(T::one()) * c * c + alpha2).sqrt();
    (c * T::c(2.0)) / (c + root).max_scalar(tiny())
}

/// Schlick's Fresnel `A + (1 - A)(1 - |h.wo|)^5`, per channel.
pub fn schlick_fresnel<'t, T: Real>(albedo: [Var<'t, T>; 3], cos_h_wo: Var<'t, T>) -> [Var<'t, T>; 3] {
    let m = cos_h_wo.abs().rsub(T::one()).clamp(T::zero(), T::one());
    let m2 = m * m;
    let m5 = m2 * m2 * m;
    albedo.map(|a| a.rsub(T::one()).mul_add(m5, a))
}

fn above<'t, T: Real>(cos: Var<'t, T>) -> Var<'t, T> {
    cos.gt(cos.tape().scalar(T::zero()))
}

fn zero_like<'t, T: Real>(v: Var<'t, T>) -> Var<'t, T> {
    v.tape().scalar(T::zero())
}

impl<T: Real> Bsdf<T> for GgxMetal {
    fn name(&self) -> &'static str {
        "ggx_metal"
    }

    fn eval<'t>(&self, s: &Surface<'t, T>, wo: Vec3Var<'t, T>, wi: Vec3Var<'t, T>) -> [Var<'t, T>; 3] {
        let alpha2 = s.roughness.square().square();
        let h = (wo + wi).normalize(tiny());
        let lit = above(wi.z).select(above(wo.z), zero_like(wo.z));
        // f cos = D F G1(wi) G1(wo) / (4 n.wo).
        let scale = ggx_distribution(h.z, alpha2) * smith_g1(wi.z, alpha2) * smith_g1(wo.z, alpha2)
            / (wo.z.max_scalar(tiny()) * T::c(4.0));
        let scale = lit.select(scale, zero_like(scale));
        schlick_fresnel(s.albedo, h.dot(wo)).map(|f| f * scale)
    }

    fn pdf<'t>(&self, s: &Surface<'t, T>, wo: Vec3Var<'t, T>, wi: Vec3Var<'t, T>) -> Var<'t, T> {
        let alpha2 = s.roughness.square().square();
        let h = (wo + wi).normalize(tiny());
        let wo_h = wo.dot(h);
        // D_v(h) / (4 wo.h) with D_v = G1(wo) max(0, wo.h) D(h) / n.wo.
        let pdf = smith_g1(wo.z, alpha2) * ggx_distribution(h.z, alpha2) / (wo.z.max_scalar(tiny()) * T::c(4.0));
        above(wo_h).select(above(wo.z).select(pdf, zero_like(pdf)), zero_like(pdf))
    }

    fn sample<'t>(&self, s: &Surface<'t, T>, wo: Vec3Var<'t, T>, u: [Var<'t, T>; 2]) -> BsdfSample<'t, T> {
        let alpha = s.roughness.square();
        let alpha2 = alpha.square();
        // Heitz 2018, listing 1: stretch the view so the GGX ellipsoid is the
        // hemisphere, sample the visible half of a disk, unstretch.
        let vh = Vec3Var::new(wo.x * alpha, wo.y * alpha, wo.z).normalize(tiny());
        let len2 = vh.x.mul_add(vh.x, vh.y * vh.y);
        let inv_len = len2.max_scalar(tiny::<T>() * tiny::<T>()).rsqrt();
        let degenerate = len2.le(zero_like(len2));
        let t1 = Vec3Var::new(
            degenerate.select(wo.tape_scalar(T::one()), -vh.y * inv_len),
            degenerate.select(zero_like(len2), vh.x * inv_len),
            zero_like(len2),
        );
        let t2 = vh.cross(t1);
        let r = u[0].max_scalar(tiny()).sqrt();
        let phi = u[1] * T::c(2.0 * std::f64::consts::PI);
        let p1 = r * phi.cos();
        let half = vh.z.affine(T::c(0.5), T::c(0.5));
        let p2 = half.rsub(T::one()) * (p1 * p1).rsub(T::one()).max_scalar(tiny()).sqrt() + half * r * phi.sin();
        let nz = (p1 * p1 + p2 * p2).rsub(T::one()).max_scalar(tiny()).sqrt();
        let nh = t1.scale(p1) + t2.scale(p2) + vh.scale(nz);
        let h = Vec3Var::new(nh.x * alpha, nh.y * alpha, nh.z.max_scalar(T::zero())).normalize(tiny());
        let wo_h = wo.dot(h);
        let wi = h.scale(wo_h * T::c(2.0)) - wo;
        let g1 = smith_g1(wi.z, alpha2);
        let lit = above(wi.z).select(above(wo.z), zero_like(wo.z));
        let weight = schlick_fresnel(s.albedo, wo_h).map(|f| lit.select(f * g1, zero_like(g1)));
        BsdfSample { wi, weight }
    }
}

impl<T: Real> Bsdf<T> for Mirror {
    fn name(&self) -> &'static str {
        "mirror"
    }

    /// A Dirac lobe: zero for any given pair of directions.
    fn eval<'t>(&self, s: &Surface<'t, T>, _wo: Vec3Var<'t, T>, _wi: Vec3Var<'t, T>) -> [Var<'t, T>; 3] {
        s.albedo.map(zero_like)
    }

    fn pdf<'t>(&self, s: &Surface<'t, T>, _wo: Vec3Var<'t, T>, _wi: Vec3Var<'t, T>) -> Var<'t, T> {
        zero_like(s.roughness)
    }

    fn sample<'t>(&self, s: &Surface<'t, T>, wo: Vec3Var<'t, T>, _u: [Var<'t, T>; 2]) -> BsdfSample<'t, T> {
        let wi = Vec3Var::new(-wo.x, -wo.y, wo.z);
        let lit = above(wo.z);
        BsdfSample {
            wi,
            weight: s.albedo.map(|a| lit.select(a, zero_like(a))),
        }
    }
}

impl<T: Real> Bsdf<T> for Lambertian {
    fn name(&self) -> &'static str {
        "lambertian"
    }

    fn eval<'t>(&self, s: &Surface<'t, T>, wo: Vec3Var<'t, T>, wi: Vec3Var<'t, T>) -> [Var<'t, T>; 3] {
        let lit = above(wi.z).select(above(wo.z), zero_like(wo.z));
        let cos = lit.select(wi.z * T::FRAC_1_PI(), zero_like(wi.z));
        s.albedo.map(|a| a * cos)
    }

    fn pdf<'t>(&self, _s: &Surface<'t, T>, wo: Vec3Var<'t, T>, wi: Vec3Var<'t, T>) -> Var<'t, T> {
        let lit = above(wi.z).select(above(wo.z), zero_like(wo.z));
        lit.select(wi.z * T::FRAC_1_PI(), zero_like(wi.z))
    }

    fn sample<'t>(&self, s: &Surface<'t, T>, wo: Vec3Var<'t, T>, u: [Var<'t, T>; 2]) -> BsdfSample<'t, T> {
        // Cosine-weighted: a uniform disk point lifted to the hemisphere.
        let r = u[0].sqrt();
        let phi = u[1] * T::c(2.0 * std::f64::consts::PI);
        let wi = Vec3Var::new(
            r * phi.cos(),
            r * phi.sin(),
            u[0].rsub(T::one()).max_scalar(T::zero()).sqrt(),
        );
        let lit = above(wo.z);
        BsdfSample {
            wi,
            weight: s.albedo.map(|a| lit.select(a, zero_like(a))),
        }
    }
}

/// A scalar constant on the tape of a vector field.
trait TapeScalar<'t, T: Real> {
    fn tape_scalar(&self, c: T) -> Var<'t, T>;
}

impl<'t, T: Real> TapeScalar<'t, T> for Vec3Var<'t, T> {
    fn tape_scalar(&self, c: T) -> Var<'t, T> {
        self.x.tape().scalar(c)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sampling::ggx;
    use autodiff::Tape;
    use autodiff::gradcheck::{Input, gradcheck, uniform};
    use glam::{Vec2, Vec3};

    fn wo_dirs(n: usize) -> Vec<Vec3> {
        (0..n)
            .map(|i| {
                let t = (i as f32 + 0.5) / n as f32;
                Vec3::new((7.0 * t).sin() * 0.8, (5.0 * t).cos() * 0.6, 0.2 + t).normalize()
            })
            .collect()
    }

    fn var3<'t>(tape: &'t Tape<f64>, v: &[Vec3]) -> Vec3Var<'t, f64> {
        let c = |f: fn(&Vec3) -> f32| tape.constant(&v.iter().map(|p| f(p) as f64).collect::<Vec<_>>());
        Vec3Var::new(c(|p| p.x), c(|p| p.y), c(|p| p.z))
    }

    #[test]
    fn ggx_sample_matches_the_scalar_sampler_and_its_weight_is_eval_over_pdf() {
        let n = 64;
        let wo = wo_dirs(n);
        let u: Vec<Vec2> = (0..n)
            .map(|i| {
                Vec2::new(
                    ((i * 37) % 64) as f32 / 64.0 + 0.003,
                    ((i * 11) % 64) as f32 / 64.0 + 0.007,
                )
            })
            .collect();
        for roughness in [0.1f32, 0.3, 0.6, 0.9] {
            let tape = Tape::<f64>::new();
            let s = Surface {
                albedo: [0.9, 0.6, 0.3].map(|a| tape.scalar(a)),
                roughness: tape.scalar(roughness as f64),
            };
            let w = var3(&tape, &wo);
            let uv = [
                tape.constant(&u.iter().map(|p| p.x as f64).collect::<Vec<_>>()),
                tape.constant(&u.iter().map(|p| p.y as f64).collect::<Vec<_>>()),
            ];
            let sample = GgxMetal.sample(&s, w, uv);
            let eval = GgxMetal.eval(&s, w, sample.wi);
            let pdf = GgxMetal.pdf(&s, w, sample.wi);
            let (wx, wy, wz) = (
                tape.to_vec(sample.wi.x),
                tape.to_vec(sample.wi.y),
                tape.to_vec(sample.wi.z),
            );
            let weights: Vec<Vec<f64>> = sample.weight.iter().map(|v| tape.to_vec(*v)).collect();
            let evals: Vec<Vec<f64>> = eval.iter().map(|v| tape.to_vec(*v)).collect();
            let pdf = tape.to_vec(pdf);
            for i in 0..n {
                let want = ggx::sample_reflection(wo[i], ggx::alpha_from_roughness(roughness), u[i]);
                let got = Vec3::new(wx[i] as f32, wy[i] as f32, wz[i] as f32);
                assert!(got.abs_diff_eq(want.wi, 2e-4), "r {roughness}: {got} vs {}", want.wi);
                if want.wi.z > 1e-3 {
                    // The scalar sampler is f32: at r = 0.1 its peak is rounded to ~1e-3.
                    assert!(
                        (pdf[i] as f32 - want.pdf).abs() < 5e-3 * want.pdf.max(1.0),
                        "pdf {} vs {}",
                        pdf[i],
                        want.pdf
                    );
                    for c in 0..3 {
                        let ratio = evals[c][i] / pdf[i];
                        assert!(
                            (weights[c][i] - ratio).abs() < 1e-6 * ratio.max(1.0),
                            "weight {} vs f cos / pdf {ratio}",
                            weights[c][i]
                        );
                    }
                } else {
                    assert_eq!(weights[0][i], 0.0);
                }
            }
        }
    }

    #[test]
    fn sample_weights_are_differentiable_in_material_and_direction() {
        let n = 10;
        let wo = wo_dirs(n);
        let inputs = [
            Input::Var(vec![0.8, 0.5, 0.2]),
            Input::Var(vec![0.35]),
            Input::Var(wo.iter().map(|v| v.x as f64).collect()),
            Input::Var(wo.iter().map(|v| v.y as f64).collect()),
            Input::Var(wo.iter().map(|v| v.z as f64).collect()),
            Input::Const(uniform(n, 0.05, 0.95, 1)),
            Input::Const(uniform(n, 0.05, 0.95, 2)),
        ];
        for bsdf in [&GgxMetal as &dyn Bsdf<f64>, &Lambertian, &Mirror] {
            let report = gradcheck(&inputs, |_, v| {
                let s = Surface {
                    albedo: [v[0].slice(0, 1), v[0].slice(1, 1), v[0].slice(2, 1)],
                    roughness: v[1],
                };
                let wo = Vec3Var::new(v[2], v[3], v[4]).normalize(1e-9);
                let smp = bsdf.sample(&s, wo, [v[5], v[6]]);
                let [r, g, b] = smp.weight;
                r + g * 2.0 + b * 3.0 + smp.wi.x * smp.wi.z.exp() + smp.wi.y
            });
            assert!(report.worst_rel_error < 1e-6, "{}: {report}", bsdf.name());
        }
    }

    #[test]
    fn lambertian_and_mirror_literals() {
        let tape = Tape::<f64>::new();
        let s = Surface {
            albedo: [0.5, 0.25, 1.0].map(|a| tape.scalar(a)),
            roughness: tape.scalar(0.0),
        };
        let wo = var3(&tape, &[Vec3::new(0.6, 0.0, 0.8)]);
        let m = Mirror.sample(&s, wo, [tape.scalar(0.5), tape.scalar(0.5)]);
        assert_eq!(
            [tape.item(m.wi.x), tape.item(m.wi.y), tape.item(m.wi.z)],
            [-0.6f32 as f64, 0.0, 0.8f32 as f64]
        );
        assert_eq!(tape.item(m.weight[1]), 0.25);
        let wi = var3(&tape, &[Vec3::new(0.0, 0.0, 1.0)]);
        let f = Lambertian.eval(&s, wo, wi);
        assert!((tape.item(f[0]) - 0.5 / std::f64::consts::PI).abs() < 1e-12);
    }
}
