//! Shading single points without a tape: the light a surface reflects towards `wo` from the
//! env map, estimated by one BSDF sample and one map sample combined by multiple importance
//! sampling with the power heuristic (Veach 1997, section 9.2.4). The map's sampler finds small
//! bright sources (a sun) that the lobe rarely hits; the lobe covers what the map's
//! piecewise-constant pdf misses beside bright texels (the lookup is bilinear). A Dirac lobe
//! takes its own sample only. The differentiable renders estimate the same integral on the
//! tape ([`ProbeScene`](super::ProbeScene)).

use glam::{Vec2, Vec3};

use crate::bsdf::{PointBsdf, PointSurface};
use crate::sampling::{EnvSampler, Frame};

/// A surface point seen from one direction.
#[derive(Clone, Copy)]
pub struct ShadingPoint<'a> {
    /// Its reflectance model.
    pub bsdf: &'a dyn PointBsdf,
    /// Its material.
    pub surface: PointSurface,
    /// Its shading frame (the normal on +Z).
    pub frame: Frame,
    /// The direction towards the viewer, local frame.
    pub wo: Vec3,
}

impl ShadingPoint<'_> {
    /// The estimate of the reflected radiance towards `wo`, RGB, from a BSDF sample drawn with
    /// `u[0]` and a sample of `lights` drawn with `u[1]`; `incoming(direction)` is the radiance
    /// arriving from a world direction (the map's, or 0 where something blocks it).
    pub fn reflected(&self, lights: &EnvSampler, u: [Vec2; 2], incoming: impl Fn(Vec3) -> [f32; 3]) -> [f32; 3] {
        let mut out = [0.0f32; 3];
        if self.wo.z <= 0.0 {
            return out;
        }
        let mut add = |direction: Vec3, weight: [f32; 3]| {
            let counts = |w: f32| w > 0.0 && w.is_finite();
            if weight.iter().any(|&w| counts(w)) {
                let radiance = incoming(direction);
                for c in 0..3 {
                    if counts(weight[c]) {
                        out[c] += weight[c] * radiance[c];
                    }
                }
            }
        };
        let power = |a: f32, b: f32| a * a / (a * a + b * b);
        let lobe = self.bsdf.sample_at(&self.surface, self.wo, u[0]);
        let world = self.frame.to_world(lobe.wi);
        if self.bsdf.is_dirac() {
            add(world, lobe.weight);
            return out;
        }
        if lobe.pdf > 0.0 {
            let share = power(lobe.pdf, lights.pdf(world));
            add(world, lobe.weight.map(|w| w * share));
        }
        let light = lights.sample(u[1]);
        let wi = self.frame.to_local(light.direction);
        let f_cos = self.bsdf.eval_at(&self.surface, self.wo, wi);
        let lobe_pdf = self.bsdf.pdf_at(&self.surface, self.wo, wi);
        if light.pdf > 0.0 {
            let share = power(light.pdf, lobe_pdf);
            add(light.direction, f_cos.map(|f| f / light.pdf * share));
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bsdf::{GgxMetal, Lambertian, Mirror};
    use crate::envmap::EnvMap;
    use crate::sampling::Rng;

    /// The mean of `n` estimates at a point facing +Y, seen at 40 degrees.
    fn mean(bsdf: &dyn PointBsdf, surface: PointSurface, env: &EnvMap, n: usize) -> [f64; 3] {
        let lights = EnvSampler::new(env);
        let frame = Frame::from_normal(Vec3::Y);
        let point = ShadingPoint {
            bsdf,
            surface,
            frame,
            wo: Vec3::new(40f32.to_radians().sin(), 0.0, 40f32.to_radians().cos()),
        };
        let mut rng = Rng::new(3, 0);
        let mut sum = [0.0f64; 3];
        for _ in 0..n {
            let l = point.reflected(&lights, [rng.next_2d(), rng.next_2d()], |d| env.lookup(d));
            (0..3).for_each(|c| sum[c] += l[c] as f64);
        }
        sum.map(|s| s / n as f64)
    }

    #[test]
    fn a_white_furnace_returns_the_albedo() {
        // Under a constant map of 1, a Lambertian point reflects its albedo and a mirror its
        // reflectance (the diffuse one within Monte Carlo noise).
        let env = EnvMap::constant(32, [1.0; 3]);
        let surface = PointSurface {
            albedo: [0.8, 0.5, 0.2],
            roughness: 0.4,
        };
        let diffuse = mean(&Lambertian, surface, &env, 20_000);
        let mirror = mean(&Mirror, surface, &env, 10);
        for c in 0..3 {
            assert!((diffuse[c] - surface.albedo[c] as f64).abs() < 0.01, "{diffuse:?}");
            assert!((mirror[c] - surface.albedo[c] as f64).abs() < 1e-5, "{mirror:?}");
        }
        // GGX with Schlick F0 = 1 reflects at most 1, the shortfall is Smith masking's.
        let metal = mean(
            &GgxMetal,
            PointSurface {
                albedo: [1.0; 3],
                ..surface
            },
            &env,
            20_000,
        );
        assert!(metal[0] > 0.85 && metal[0] < 1.0, "{metal:?}");
    }

    #[test]
    fn both_strategies_agree_on_a_sun() {
        // A bright small source: the estimate matches the BSDF-only quadrature of the same
        // integral (many lobe samples), which MIS reaches with far fewer.
        // The sun 15 degrees off the mirror direction, inside the lobe's reach.
        let frame = Frame::from_normal(Vec3::Y);
        let wo = Vec3::new(40f32.to_radians().sin(), 0.0, 40f32.to_radians().cos());
        let mirror = frame.to_world(Vec3::new(-wo.x, -wo.y, wo.z));
        let sun = (mirror + 0.27 * Vec3::Y.cross(mirror).normalize()).normalize();
        let (height, width) = (64, 128);
        let grid = EnvMap::constant(height, [0.0; 3]);
        let texels = (0..height).flat_map(|r| (0..width).map(move |c| (r, c)));
        let nearest = texels.max_by(|a, b| {
            let cos = |t: &(usize, usize)| grid.texel_direction(t.0, t.1).dot(sun);
            cos(a).total_cmp(&cos(b))
        });
        let pixels = (0..height * width)
            .map(|i| {
                if Some((i / width, i % width)) == nearest {
                    [400.0; 3]
                } else {
                    [0.05; 3]
                }
            })
            .collect();
        let env = EnvMap::new(width, height, pixels).unwrap();
        let surface = PointSurface {
            albedo: [1.0; 3],
            roughness: 0.5,
        };
        let mis = mean(&GgxMetal, surface, &env, 40_000)[0];
        let lobe_only = {
            let mut rng = Rng::new(9, 0);
            let n = 2_000_000;
            let total: f64 = (0..n)
                .map(|_| {
                    let s = GgxMetal.sample_at(&surface, wo, rng.next_2d());
                    (s.weight[0] * env.lookup(frame.to_world(s.wi))[0]) as f64
                })
                .sum();
            total / n as f64
        };
        assert!(
            (mis - lobe_only).abs() < 0.03 * lobe_only,
            "MIS {mis} vs lobe only {lobe_only}"
        );
    }
}
