//! The light samples of the hits on the tape: the hit point on its
//! (moving) triangle, its material and frame, BRDF and env-map samples
//! combined by MIS, the bounces off the probe, and the pixels' radiance.

use std::borrow::Cow;

use autodiff::{Real, Tape, Var, Vec3 as Vec3Var};
use glam::{Vec2, Vec3};
use rayon::prelude::*;

use crate::bsdf::{Bsdf, BsdfSample, Surface};
use crate::camera::Camera;
use crate::lookup::{EnvPdfVars, ImageVars, TextureVars};
use crate::posed::{MeshVars, PosedMesh};
use crate::probe::ProbeAsset;
use crate::sampling::{EnvSample, EnvSampler, Rng, stratified_square};

use super::{LIGHT_STREAM, Occluder, PrimaryHits, bounce_streams};

/// The probe on a tape: mesh arrays and material textures.
#[derive(Clone, Copy, Debug)]
pub struct ProbeVars<'t, T: Real> {
    /// Vertex arrays (mesh frame).
    pub mesh: MeshVars<'t, T>,
    /// Specular albedo A.
    pub albedo: TextureVars<'t, T>,
    /// Roughness r (first channel).
    pub roughness: TextureVars<'t, T>,
    /// Soft visibility v (first channel).
    pub visibility: TextureVars<'t, T>,
}

impl<'t, T: Real> ProbeVars<'t, T> {
    /// Records a probe; `material_gradients` makes its textures leaves.
    pub fn new(tape: &'t Tape<T>, probe: &ProbeAsset, material_gradients: bool) -> Self {
        ProbeVars {
            mesh: MeshVars::new(tape, &probe.mesh),
            albedo: TextureVars::new(tape, &probe.albedo, material_gradients),
            roughness: TextureVars::new(tape, &probe.roughness, material_gradients),
            visibility: TextureVars::new(tape, &probe.visibility, material_gradients),
        }
    }
}

/// Per-sample constants of the hits, on a tape.
struct SampleVars<'t, T: Real> {
    direction: Vec3Var<'t, T>,
    corners: [Var<'t, T>; 3],
    segment: Var<'t, T>,
    /// 1 / the sample count of the sample's pixel.
    pixel_share: Var<'t, T>,
    random: [Var<'t, T>; 2],
}

impl<'t, T: Real> SampleVars<'t, T> {
    fn new(tape: &'t Tape<T>, hits: &PrimaryHits, triangles: &[[u32; 3]]) -> Self {
        let array = |f: &dyn Fn(usize) -> f64| tape.constant(&(0..hits.len()).map(|i| T::c(f(i))).collect::<Vec<T>>());
        let corner = |k: usize| array(&|i| triangles[hits.triangle[i] as usize][k] as f64);
        SampleVars {
            direction: Vec3Var::new(
                array(&|i| hits.direction[i].x as f64),
                array(&|i| hits.direction[i].y as f64),
                array(&|i| hits.direction[i].z as f64),
            ),
            corners: [corner(0), corner(1), corner(2)],
            segment: array(&|i| hits.segment[i] as f64),
            // One value, broadcast, when every pixel has `spp` samples.
            pixel_share: if hits.samples.iter().all(|&n| n == hits.spp) {
                tape.constant(&[T::c(1.0 / hits.spp as f64)])
            } else {
                array(&|i| 1.0 / hits.samples[hits.segment[i] as usize] as f64)
            },
            random: [array(&|i| hits.random[i].x as f64), array(&|i| hits.random[i].y as f64)],
        }
    }
}

/// Gathers a vector field at per-sample vertex indices.
fn gather3<'t, T: Real>(field: Vec3Var<'t, T>, idx: Var<'t, T>) -> Vec3Var<'t, T> {
    Vec3Var::new(field.x.gather(idx), field.y.gather(idx), field.z.gather(idx))
}

/// `values` at the samples `idx`: a per-sample array gathered, a broadcast
/// scalar (a constant texture's value, say) as it is.
fn at_samples<'t, T: Real>(values: Var<'t, T>, idx: Var<'t, T>) -> Var<'t, T> {
    match values.len() {
        1 => values,
        _ => values.gather(idx),
    }
}

/// Where rays meet the (moving) triangles a BVH found them to hit: the
/// barycentrics by Moller-Trumbore on the tape, so that whatever is
/// interpolated on the triangle follows the pose.
#[derive(Clone, Copy)]
struct SurfaceHit<'t, T: Real> {
    /// The vertex indices of each hit's triangle.
    corners: [Var<'t, T>; 3],
    /// The weights of corners 1 and 2.
    b1: Var<'t, T>,
    b2: Var<'t, T>,
}

impl<'t, T: Real> SurfaceHit<'t, T> {
    /// The rays `origin + t direction` against the triangles `corners` of `positions`.
    fn find(
        origin: Vec3Var<'t, T>,
        direction: Vec3Var<'t, T>,
        corners: [Var<'t, T>; 3],
        positions: Vec3Var<'t, T>,
    ) -> Self {
        let [p0, p1, p2] = corners.map(|c| gather3(positions, c));
        let (e1, e2) = (p1 - p0, p2 - p0);
        let pvec = direction.cross(e2);
        let inv_det = e1.dot(pvec).recip_var();
        let tvec = origin - p0;
        let qvec = tvec.cross(e1);
        SurfaceHit {
            corners,
            b1: tvec.dot(pvec) * inv_det,
            b2: direction.dot(qvec) * inv_det,
        }
    }

    /// A per-vertex quantity at the hits.
    fn interpolate(&self, field: Var<'t, T>) -> Var<'t, T> {
        let [f0, f1, f2] = self.corners.map(|c| field.gather(c));
        (f1 - f0).mul_add(self.b1, (f2 - f0).mul_add(self.b2, f0))
    }

    fn interpolate3(&self, field: Vec3Var<'t, T>) -> Vec3Var<'t, T> {
        Vec3Var::new(
            self.interpolate(field.x),
            self.interpolate(field.y),
            self.interpolate(field.z),
        )
    }

    /// The hits `idx`.
    fn subset(&self, idx: Var<'t, T>) -> Self {
        SurfaceHit {
            corners: self.corners.map(|c| c.gather(idx)),
            b1: self.b1.gather(idx),
            b2: self.b2.gather(idx),
        }
    }
}

/// The probe at surface hits seen from `wo_world`: the local frame of the
/// interpolated normal (see [`frame`]), the material and the soft visibility.
struct Shading<'t, T: Real> {
    frame: [Vec3Var<'t, T>; 3],
    /// The view direction, local frame.
    wo: Vec3Var<'t, T>,
    surface: Surface<'t, T>,
    visibility: Var<'t, T>,
}

impl<'t, T: Real> Shading<'t, T> {
    fn at(
        hit: &SurfaceHit<'t, T>,
        wo_world: Vec3Var<'t, T>,
        probe: &ProbeVars<'t, T>,
        posed: &PosedMesh<'t, T>,
    ) -> Self {
        let n = hit.interpolate3(posed.normals).normalize(T::c(1e-12));
        let [u, v] = posed.uv.map(|uv| hit.interpolate(uv));
        let (s, t) = frame(n, wo_world);
        let mut shading = Shading {
            frame: [s, t, n],
            wo: wo_world,
            surface: Surface {
                albedo: probe.albedo.lookup(u, v),
                roughness: probe.roughness.lookup(u, v)[0],
            },
            visibility: probe.visibility.lookup(u, v)[0],
        };
        shading.wo = shading.to_local(wo_world);
        shading
    }

    fn to_local(&self, w: Vec3Var<'t, T>) -> Vec3Var<'t, T> {
        let [s, t, n] = self.frame;
        Vec3Var::new(s.dot(w), t.dot(w), n.dot(w))
    }

    fn to_world(&self, w: Vec3Var<'t, T>) -> Vec3Var<'t, T> {
        let [s, t, n] = self.frame;
        s.scale(w.x) + t.scale(w.y) + n.scale(w.z)
    }
}

/// The shading frame (s, t, n) around unit normals `n`, with s along the
/// view direction's tangential part. The GGX lobe is isotropic, so any frame
/// gives the same integral; this one is smooth in `n` everywhere except
/// where `wo` is along `n`, whereas a frame fixed to world axes (Duff et al.
/// 2017) jumps across a whole great circle of normals, and with it the
/// sampled directions: finite differences and gradients would see the jump.
/// At normal incidence it falls back to Duff's frame.
fn frame<'t, T: Real>(n: Vec3Var<'t, T>, wo: Vec3Var<'t, T>) -> (Vec3Var<'t, T>, Vec3Var<'t, T>) {
    let tape = n.x.tape();
    let tangent = wo - n.scale(n.dot(wo));
    let len2 = tangent.dot(tangent);
    let view_aligned = len2.gt(tape.scalar(T::c(1e-10)));
    let s_view = tangent.scale(len2.max_scalar(T::c(1e-10)).rsqrt());
    // Duff et al. 2017, listing 3; the sign choice is piecewise constant.
    let sign =
        n.z.ge(tape.scalar(T::zero()))
            .select(tape.scalar(T::one()), tape.scalar(-T::one()));
    let a = -(sign + n.z).recip_var();
    let b = n.x * n.y * a;
    let s_duff = Vec3Var::new(
        (sign * n.x * n.x).mul_add(a, tape.scalar(T::one())),
        sign * b,
        -(sign * n.x),
    );
    let s = Vec3Var::new(
        view_aligned.select(s_view.x, s_duff.x),
        view_aligned.select(s_view.y, s_duff.y),
        view_aligned.select(s_view.z, s_duff.z),
    );
    (s, n.cross(s))
}

trait Recip {
    fn recip_var(self) -> Self;
}

impl<'t, T: Real> Recip for Var<'t, T> {
    fn recip_var(self) -> Self {
        self.tape().scalar(T::one()) / self
    }
}

/// Where each light sample reads the environment, and what it passes on: the
/// image is `sum over samples of throughput * L_env(wi)` per pixel, linear
/// in the environment map (the lighting solve uses this form directly).
#[derive(Clone, Debug)]
pub struct LightSamples<'t, T: Real> {
    /// World direction of the sample (towards the light).
    pub wi: Vec3Var<'t, T>,
    /// `shadow * visibility * f cos / pdf * (MIS weight) / (the pixel's samples)`, RGB
    /// (after a bounce: the product of both samples' factors).
    pub throughput: [Var<'t, T>; 3],
    /// The shadow test: 1 where the light reaches the sample's point, 0
    /// where the probe blocks it (a constant).
    pub lit: Var<'t, T>,
    /// The sample's position in `hits.pixels`.
    pub segment: Var<'t, T>,
    /// Number of pixels (segments).
    pub pixels: usize,
    /// The first `direct` samples light the probe's visible points
    /// directly (the BRDF samples, one per hit, in the hits' order; then
    /// the env-map samples, with MIS); the rest after bounces off the
    /// probe ([`LightSampling::bounces`]).
    pub direct: usize,
    /// Where each bounce's samples start: bounce `k`'s (from 1) run from
    /// `bounce_starts[k - 1]` to the next start or the end (the first
    /// start is `direct`); one entry per bounce that anything reached.
    pub bounce_starts: Vec<usize>,
    /// Per sample, whether its direction was drawn from the env map's
    /// sampler (MIS) rather than from the BRDF's lobe: the BRDF samples
    /// alone tell what share of a point's lobe the probe shadows.
    pub env_sampled: Vec<bool>,
}

impl<'t, T: Real> LightSamples<'t, T> {
    /// The pixels' radiance under `env`, one array per channel aligned with `hits.pixels`.
    pub fn radiance(&self, env: &ImageVars<'t, T>) -> [Var<'t, T>; 3] {
        let l = env.env_radiance(self.wi);
        std::array::from_fn(|c| (self.throughput[c] * l[c]).segmented_sum(self.segment, self.pixels))
    }

    /// The samples of each bounce (from the first), as ranges of indices.
    pub fn bounce_ranges(&self) -> impl Iterator<Item = std::ops::Range<usize>> + '_ {
        let ends = self.bounce_starts.iter().skip(1).copied().chain([self.lit.len()]);
        self.bounce_starts.iter().zip(ends).map(|(&start, end)| start..end)
    }

    /// These samples, then `more` (of the same pixels), as one set; `direct` is the caller's.
    fn followed_by(self, more: Self) -> Self {
        let tape = self.lit.tape();
        let both = |a: Var<'t, T>, b: Var<'t, T>| tape.concat(&[a, b]);
        LightSamples {
            wi: Vec3Var::new(
                both(self.wi.x, more.wi.x),
                both(self.wi.y, more.wi.y),
                both(self.wi.z, more.wi.z),
            ),
            throughput: std::array::from_fn(|c| both(self.throughput[c], more.throughput[c])),
            lit: both(self.lit, more.lit),
            segment: both(self.segment, more.segment),
            env_sampled: [self.env_sampled, more.env_sampled].concat(),
            ..self
        }
    }
}

/// How [`ProbeScene::light_samples`] picks the directions light arrives from.
#[derive(Clone, Copy, Debug)]
pub struct LightSampling<'a> {
    /// With a sampler of the env map: one BRDF sample and one sample of
    /// the env map's luminance per hit, each weighted by the balance
    /// heuristic (Veach 1997, section 9.2.2): far less noise under small
    /// bright sources, which the BRDF's lobe rarely finds. The sampler
    /// must stay fixed while gradients are taken (it is built from a map,
    /// not differentiated). Without: one BRDF sample per hit, the paper's
    /// estimator.
    pub env: Option<&'a EnvSampler>,
    /// How many times a BRDF sample that the probe shadows goes on from
    /// the point of the probe it hits (one more BRDF sample there, and an
    /// env-map sample with MIS, each itself shadowed): the light the probe
    /// reflects onto itself, which a concave probe's recesses see where
    /// they do not see the sky (a can's lid under its rim, lit by the
    /// rim's inner wall, which is lit by the lid in turn). 0: direct
    /// lighting only.
    pub bounces: u32,
    /// Whether the probe shadows itself (V above, a shadow ray per light
    /// sample). Without, every sample sees the map (V = 1): a convex
    /// probe's model, cheaper, and wrong in a concave one's recesses;
    /// nothing is then shadowed, so nothing bounces either.
    pub shadows: bool,
}

impl<'a> LightSampling<'a> {
    /// One BRDF sample per hit, direct lighting.
    pub const BSDF: Self = LightSampling {
        env: None,
        bounces: 0,
        shadows: true,
    };

    /// A BRDF and an env-map sample per hit by MIS, direct lighting.
    pub fn mis(sampler: &'a EnvSampler) -> Self {
        LightSampling {
            env: Some(sampler),
            ..Self::BSDF
        }
    }

    /// The same with `bounces` bounces off the probe.
    pub fn with_bounces(self, bounces: u32) -> Self {
        LightSampling { bounces, ..self }
    }

    /// The same without the probe's shadows on itself (nor its bounces).
    pub fn without_shadows(self) -> Self {
        LightSampling {
            shadows: false,
            bounces: 0,
            ..self
        }
    }

    /// Light samples per shading point: the BRDF's, and the env map's with MIS.
    pub fn strategies(&self) -> usize {
        1 + self.env.is_some() as usize
    }
}

/// What the light samples of a probe's render read: the tape, the primary
/// hits, the camera, the probe's textures and posed mesh, its triangles and
/// its reflectance model.
pub struct ProbeScene<'a, 't, T: Real> {
    pub tape: &'t Tape<T>,
    pub hits: &'a PrimaryHits,
    pub camera: &'a Camera,
    pub probe: &'a ProbeVars<'t, T>,
    pub posed: &'a PosedMesh<'t, T>,
    pub triangles: &'a [[u32; 3]],
    pub bsdf: &'a dyn Bsdf<T>,
}

impl<'a, 't, T: Real> ProbeScene<'a, 't, T> {
    pub fn light_samples(&self, sampling: &LightSampling) -> LightSamples<'t, T> {
        let ProbeScene {
            tape,
            hits,
            camera,
            probe,
            posed,
            triangles,
            bsdf,
        } = *self;
        assert!(!hits.is_empty(), "light_samples: no sample sees the probe");
        let occluder = hits
            .occluder
            .as_deref()
            .expect("light_samples: hits made by PrimaryHits::trace");
        let s = SampleVars::new(tape, hits, triangles);
        let origin = Vec3Var::constant(
            tape,
            [camera.origin.x, camera.origin.y, camera.origin.z].map(|c| T::c(c as f64)),
        );
        // The hit point on the (moving) triangle along the (fixed) ray.
        let hit = SurfaceHit::find(origin, s.direction, s.corners, posed.positions);
        let shading = Shading::at(&hit, -s.direction, probe, posed);
        let scale = shading.visibility * s.pixel_share;
        let sample = bsdf.sample(&shading.surface, shading.wo, s.random);
        let wi = shading.to_world(sample.wi);
        let unshadowed = |w: Vec3Var<'t, T>| match sampling.shadows {
            true => tape.constant(&occluder.unshadowed(&hits.point, &values(w))),
            false => tape.constant(&vec![T::one(); hits.len()]),
        };
        let lit = unshadowed(wi);
        // The BRDF sample's throughput before its shadow and MIS weight.
        let weight = sample.weight.map(|w| w * scale);
        let lights = sampling.env.map(|sampler| {
            let lights = per_pixel_draws(hits, &(0..hits.len()).collect::<Vec<_>>(), LIGHT_STREAM, |u| {
                sampler.sample(u)
            });
            (sampler, lights)
        });
        let points = PointSamples {
            shading: &shading,
            sample: &sample,
            wi,
            lit,
            segment: s.segment,
            pixels: hits.pixels.len(),
        };
        let direct = points.light(tape, bsdf, weight, [scale; 3], &unshadowed, lights.as_ref());
        let direct = LightSamples {
            direct: direct.lit.len(),
            bounce_starts: Vec::new(),
            ..direct
        };
        let mut all = direct;
        let mut from = Bounce {
            hit,
            wi,
            weight,
            lit,
            segment: s.segment,
            points: Cow::Borrowed(&hits.point),
            samples: (0..hits.len()).collect(),
        };
        let scene = BounceScene {
            hits,
            occluder,
            probe,
            posed,
            triangles,
            bsdf,
            sampler: sampling.env,
        };
        for level in 1..=sampling.bounces {
            let Some((bounced, next)) = bounce(tape, &scene, &from, level) else {
                break;
            };
            let start = all.lit.len();
            all = all.followed_by(bounced);
            all.bounce_starts.push(start);
            from = next;
        }
        all
    }

    /// Renders the probe's radiance into the pixels of the hits under
    /// `env`: one array per channel, aligned with `hits.pixels`, by BRDF
    /// sampling, averaged over each pixel's samples (a partly covered pixel
    /// sums only its probe samples: the background is black).
    pub fn shade(&self, env: &ImageVars<'t, T>) -> [Var<'t, T>; 3] {
        self.light_samples(&LightSampling::BSDF).radiance(env)
    }
}

/// One BRDF sample and one env-map sample per shading point combined by
/// the balance heuristic (see [`ProbeScene::light_samples`]).
struct Mis<'t, T: Real> {
    /// The BRDF sample's weight p_b / (p_b + p_e).
    bsdf_weight: Var<'t, T>,
    /// The env samples' directions (world).
    wi_env: Vec3Var<'t, T>,
    /// The env samples' `f cos / p_e * p_e / (p_e + p_b)`, RGB.
    env_weight: [Var<'t, T>; 3],
}

impl<'t, T: Real> Mis<'t, T> {
    /// `sample` (at `wi`, world) and `lights`, one per shading point.
    fn new(
        tape: &'t Tape<T>,
        sampler: &EnvSampler,
        bsdf: &dyn Bsdf<T>,
        shading: &Shading<'t, T>,
        sample: &BsdfSample<'t, T>,
        wi: Vec3Var<'t, T>,
        lights: &[EnvSample],
    ) -> Self {
        let (zero, one) = (tape.scalar(T::zero()), tape.scalar(T::one()));
        // A lobe that gives its own sample pdf 0 is a Dirac one (a mirror,
        // GGX at r = 0), which no other strategy reaches: weight 1.
        let p_bsdf = bsdf.pdf(&shading.surface, shading.wo, sample.wi);
        let lobe = p_bsdf.gt(zero);
        let p_env = EnvPdfVars::new(tape, sampler).pdf(wi);
        let constant = |f: &dyn Fn(&EnvSample) -> f32| {
            tape.constant(&lights.iter().map(|l| T::c(f(l) as f64)).collect::<Vec<T>>())
        };
        let wi_env = Vec3Var::new(
            constant(&|l| l.direction.x),
            constant(&|l| l.direction.y),
            constant(&|l| l.direction.z),
        );
        // f cos / p_e * p_e / (p_e + p_b) = f cos q / (1 + p_b q) with
        // q = 1 / p_e, which is 0 on a pole (p_e infinite there).
        let q = constant(&|l| 1.0 / l.pdf);
        let wi_env_local = shading.to_local(wi_env);
        let f_cos = bsdf.eval(&shading.surface, shading.wo, wi_env_local);
        let p_bsdf_env = bsdf.pdf(&shading.surface, shading.wo, wi_env_local);
        let share = q / p_bsdf_env.mul_add(q, one);
        Mis {
            bsdf_weight: lobe.select(p_bsdf / lobe.select(p_bsdf + p_env, one), one),
            wi_env,
            env_weight: f_cos.map(|f| f * share),
        }
    }
}

/// The x, y, z values of a vector array.
fn values<T: Real>(w: Vec3Var<'_, T>) -> [Vec<T>; 3] {
    let tape = w.x.tape();
    [w.x, w.y, w.z].map(|c| tape.to_vec(c))
}

/// Element `i` of x, y, z value arrays (NaN where a value has no f32).
pub(super) fn vec3_at<T: Real>(xyz: &[Vec<T>; 3], i: usize) -> Vec3 {
    Vec3::from_array(xyz.each_ref().map(|c| c[i].to_f32().unwrap_or(f32::NAN)))
}

/// One draw per listed hit sample (`samples`, in order) from a point of
/// the unit square, a pixel's points stratified over its listed samples
/// ([`stratified_square`] from the random number stream `stream + pixel`):
/// the same whatever the thread count. A pixel's few light samples spread
/// over the square as its BRDF samples do, instead of clumping where
/// independent draws fall.
fn per_pixel_draws<D: Send>(
    hits: &PrimaryHits,
    samples: &[usize],
    stream: u64,
    draw: impl Fn(Vec2) -> D + Sync,
) -> Vec<D> {
    let runs: Vec<&[usize]> = samples.chunk_by(|&a, &b| hits.segment[a] == hits.segment[b]).collect();
    runs.par_iter()
        .flat_map_iter(|run| {
            let pixel = hits.pixels[hits.segment[run[0]] as usize] as u64;
            let mut points = vec![Vec2::ZERO; run.len()];
            stratified_square(&mut Rng::new(hits.seed, stream + pixel), &mut points);
            points.into_iter().map(&draw)
        })
        .collect()
}

/// BRDF samples at a set of shading points (the hits', or a bounce's),
/// what the next bounce goes on from.
struct Bounce<'a, 't, T: Real> {
    hit: SurfaceHit<'t, T>,
    wi: Vec3Var<'t, T>,
    /// Throughput up to and including this sample, before its shadow test
    /// and any MIS weight, RGB.
    weight: [Var<'t, T>; 3],
    lit: Var<'t, T>,
    /// The points' positions in `hits.pixels`.
    segment: Var<'t, T>,
    /// The shading points' positions (values).
    points: Cow<'a, [Vec3]>,
    /// Each point's hit sample (its index in `hits`), in order.
    samples: Vec<usize>,
}

/// What every bounce is traced and shaded against.
struct BounceScene<'a, 't, T: Real> {
    hits: &'a PrimaryHits,
    occluder: &'a Occluder,
    probe: &'a ProbeVars<'t, T>,
    posed: &'a PosedMesh<'t, T>,
    triangles: &'a [[u32; 3]],
    bsdf: &'a dyn Bsdf<T>,
    sampler: Option<&'a EnvSampler>,
}

/// The BRDF samples of `from` that the probe shadows, gone on from the
/// point of the probe each one hits (bounce number `level`): one BRDF
/// sample of that point's material reads the env map, and with a sampler
/// one env-map sample too, the two combined by MIS as at the first point;
/// each shadowed in turn. Their throughput is the product of `from`'s
/// sample's, without an MIS weight (no env-map sample reaches the light the
/// probe reflects), and their own. Differentiable as the first samples are
/// (the new hit point moves with the pose along the previous sample's
/// moving ray). Returns the light samples and the BRDF samples the next
/// bounce goes on from; `None` when nothing is shadowed.
fn bounce<'t, T: Real>(
    tape: &'t Tape<T>,
    scene: &BounceScene<'_, 't, T>,
    from: &Bounce<'_, 't, T>,
    level: u32,
) -> Option<(LightSamples<'t, T>, Bounce<'static, 't, T>)> {
    let lit = tape.to_vec(from.lit);
    let d = values(from.wi);
    let (occluder, points) = (scene.occluder, &from.points);
    let blocked: Vec<(usize, u32)> = (0..points.len())
        .into_par_iter()
        .filter(|&i| lit[i] == T::zero())
        .filter_map(|i| occluder.blocker(points[i], vec3_at(&d, i)).map(|t| (i, t)))
        .collect();
    if blocked.is_empty() {
        return None;
    }
    let constant =
        |f: &dyn Fn(&(usize, u32)) -> f64| tape.constant(&blocked.iter().map(|b| T::c(f(b))).collect::<Vec<T>>());
    let idx = constant(&|&(i, _)| i as f64);
    let corners = [0, 1, 2].map(|k| constant(&|&(_, t)| scene.triangles[t as usize][k] as f64));
    let ray = gather3(from.wi, idx);
    let origin = from.hit.subset(idx).interpolate3(scene.posed.positions);
    let hit = SurfaceHit::find(origin, ray, corners, scene.posed.positions);
    let shading = Shading::at(&hit, -ray, scene.probe, scene.posed);
    let samples: Vec<usize> = blocked.iter().map(|b| from.samples[b.0]).collect();
    let (bsdf_stream, light_stream) = bounce_streams(level);
    let random = per_pixel_draws(scene.hits, &samples, bsdf_stream, |u| u);
    let random = [0, 1].map(|k| tape.constant(&random.iter().map(|r| T::c(r[k] as f64)).collect::<Vec<T>>()));
    let sample = scene.bsdf.sample(&shading.surface, shading.wo, random);
    let wi = shading.to_world(sample.wi);
    let points: Vec<Vec3> = {
        let p = values(hit.interpolate3(scene.posed.positions));
        (0..blocked.len()).map(|i| vec3_at(&p, i)).collect()
    };
    let unshadowed = |w: Vec3Var<'t, T>| tape.constant(&scene.occluder.unshadowed(&points, &values(w)));
    // The previous sample's throughput, then this point's visibility.
    let weight = from.weight.map(|w| at_samples(w, idx) * shading.visibility);
    let lights = scene.sampler.map(|sampler| {
        let lights = per_pixel_draws(scene.hits, &samples, light_stream, |u| sampler.sample(u));
        (sampler, lights)
    });
    let lit = unshadowed(wi);
    let segment = from.segment.gather(idx);
    let light_points = PointSamples {
        shading: &shading,
        sample: &sample,
        wi,
        lit,
        segment,
        pixels: scene.hits.pixels.len(),
    };
    let bsdf_weight = std::array::from_fn(|c| weight[c] * sample.weight[c]);
    let light = light_points.light(tape, scene.bsdf, bsdf_weight, weight, &unshadowed, lights.as_ref());
    let next = Bounce {
        hit,
        wi,
        weight: bsdf_weight,
        lit,
        segment,
        points: Cow::Owned(points),
        samples,
    };
    Some((light, next))
}

/// A BRDF sample at each of a set of shading points, with its shadow test.
struct PointSamples<'a, 't, T: Real> {
    shading: &'a Shading<'t, T>,
    sample: &'a BsdfSample<'t, T>,
    /// The sample's direction (world).
    wi: Vec3Var<'t, T>,
    lit: Var<'t, T>,
    /// The points' positions in `hits.pixels`.
    segment: Var<'t, T>,
    /// Number of pixels (segments).
    pixels: usize,
}

impl<'a, 't, T: Real> PointSamples<'a, 't, T> {
    /// The light samples: the BRDF samples, whose throughput before the
    /// shadow test is `bsdf_weight`, and with `env` (the sampler and one
    /// light drawn per point) the env-map samples too, each times its MIS
    /// weight; `prefix` is the throughput up to the points, `unshadowed`
    /// their shadow test. `direct` is left 0, `bounce_starts` empty.
    fn light(
        &self,
        tape: &'t Tape<T>,
        bsdf: &dyn Bsdf<T>,
        bsdf_weight: [Var<'t, T>; 3],
        prefix: [Var<'t, T>; 3],
        unshadowed: &dyn Fn(Vec3Var<'t, T>) -> Var<'t, T>,
        env: Option<&(&EnvSampler, Vec<EnvSample>)>,
    ) -> LightSamples<'t, T> {
        let bsdf_samples = |mis_weight: Option<Var<'t, T>>| LightSamples {
            wi: self.wi,
            throughput: bsdf_weight.map(|w| match mis_weight {
                Some(m) => w * self.lit * m,
                None => w * self.lit,
            }),
            lit: self.lit,
            segment: self.segment,
            pixels: self.pixels,
            direct: 0,
            bounce_starts: Vec::new(),
            env_sampled: vec![false; self.lit.len()],
        };
        let Some((sampler, lights)) = env else {
            return bsdf_samples(None);
        };
        let mis = Mis::new(tape, sampler, bsdf, self.shading, self.sample, self.wi, lights);
        let lit_env = unshadowed(mis.wi_env);
        let env_samples = LightSamples {
            wi: mis.wi_env,
            throughput: std::array::from_fn(|c| mis.env_weight[c] * prefix[c] * lit_env),
            lit: lit_env,
            segment: self.segment,
            pixels: self.pixels,
            direct: 0,
            bounce_starts: Vec::new(),
            env_sampled: vec![true; lit_env.len()],
        };
        bsdf_samples(Some(mis.bsdf_weight)).followed_by(env_samples)
    }
}
