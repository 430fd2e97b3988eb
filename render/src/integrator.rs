//! The forward model (PAPER.md): direct image-based lighting of the probe,
//!
//!   L(wo) = v(x) * integral of L_env(wi) V(x, wi) f(wi, wo) cos(theta_i) dwi,
//!
//! estimated per sub-pixel sample with one BRDF sample (the BRDF's own
//! importance sampling: GGX visible normals for the metal), or with one BRDF
//! and one env-map sample combined by multiple importance sampling
//! ([`LightSampling`]), times the soft visibility texture v, averaged into
//! pixels. V is 0 where the probe itself blocks the light (a shadow ray
//! against its mesh): a concave probe's recesses (a can's lid, a cap's
//! inside) do not see the sky above them. What they see instead, the probe
//! itself, can be followed for a few bounces
//! ([`LightSampling::bounces`]): the shadowed BRDF sample goes on from the
//! point it hits with a BRDF sample there, and so on. Further bounces are
//! left out.
//!
//! Two steps: [`PrimaryHits::trace`] finds which triangle each sub-pixel
//! sample sees (a BVH, not differentiated); [`shade`] recomputes the hit
//! point on that triangle from the posed vertices (Moller-Trumbore on the
//! tape), so the image is differentiable in the pose through the hit point,
//! the interpolated normal and uv, and in the env map, the textures and the
//! roughness. Silhouette changes are not differentiated here: the soft masks
//! of `silhouette` carry them; nor are shadow edges moving with the pose (V
//! is a constant of each sample).

use std::borrow::Cow;
use std::sync::Arc;

use autodiff::{Real, Tape, Var, Vec3 as Vec3Var};
use glam::{Vec2, Vec3};
use rayon::prelude::*;

use crate::accel::{Accel, stratified_offsets};
use crate::bsdf::{Bsdf, BsdfSample, Surface};
use crate::camera::Camera;
use crate::envmap::EnvMap;
use crate::image_io::{Mask, RgbImage};
use crate::lookup::{EnvPdfVars, ImageVars, TextureVars};
use crate::mesh::Mesh;
use crate::pose::Pose;
use crate::posed::{MeshVars, PoseVars, PosedMesh, pack_pose};
use crate::probe::ProbeAsset;
use crate::sampling::{EnvSample, EnvSampler, Rng, sample_standard_normal_2d, stratified_square};

/// Monte Carlo settings.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RenderSettings {
    /// Samples per pixel (stratified sub-pixel positions, one light sample per strategy each).
    pub spp: u32,
    /// Seed of every random number: the same seed gives the same image on any thread count.
    pub seed: u64,
}

impl Default for RenderSettings {
    fn default() -> Self {
        RenderSettings { spp: 8, seed: 0 }
    }
}

/// The sub-pixel samples of a camera that see the probe (not differentiated).
#[derive(Clone, Debug, Default)]
pub struct PrimaryHits {
    /// Image width, pixels.
    pub width: usize,
    /// Image height, pixels.
    pub height: usize,
    /// Samples per pixel off the silhouette.
    pub spp: u32,
    /// Rays traced (the bounding box's pixels times their samples, and the silhouette test's).
    pub rays: usize,
    /// Row-major indices of the pixels at least one sample of which sees the probe.
    pub pixels: Vec<u32>,
    /// Per such pixel: the samples traced through it (`spp`, more on the silhouette).
    pub samples: Vec<u32>,
    /// Fraction of each such pixel's samples that see the probe.
    pub coverage: Vec<f32>,
    /// Per hit sample: its position in `pixels`.
    pub segment: Vec<u32>,
    /// Per hit sample: the triangle seen.
    pub triangle: Vec<u32>,
    /// Per hit sample: the unit ray direction (world).
    pub direction: Vec<Vec3>,
    /// Per hit sample: two uniform random numbers for the BRDF sample (a pixel's together a
    /// stratified set: `sampling::stratified_square`).
    pub random: Vec<Vec2>,
    /// The seed of the random numbers (the env-map samples draw theirs when needed).
    pub seed: u64,
    /// Per hit sample: the point it sees (world), where its shadow rays start.
    pub point: Vec<Vec3>,
    /// The posed probe, which shadows itself (`None` only on a default value).
    pub occluder: Option<Arc<Occluder>>,
}

/// The posed probe as the occluder of its own light: shadow rays from its surface.
pub struct Occluder {
    accel: Accel,
    /// Shadow rays start this far from their point: past the rounding of
    /// the hit, so a ray does not hit the triangle it leaves.
    t_min: f32,
}

/// Shadow rays start this fraction of the probe's bounding-box diagonal
/// from their point (0.15 mm on the 12-cm can): far above f32 rounding at
/// world coordinates of a metre, far below any feature of a probe.
const SHADOW_OFFSET: f32 = 1e-3;

impl std::fmt::Debug for Occluder {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Occluder")
            .field("t_min", &self.t_min)
            .finish_non_exhaustive()
    }
}

impl Occluder {
    /// Whether light arriving from `direction` (world, unit) reaches `point` on the probe.
    pub fn lit(&self, point: Vec3, direction: Vec3) -> bool {
        !self.accel.occluded(point, direction, self.t_min, f32::INFINITY)
    }

    /// The triangle that blocks light from `direction` (world, unit) at
    /// `point` on the probe (the nearest), if any.
    pub fn blocker(&self, point: Vec3, direction: Vec3) -> Option<u32> {
        self.accel
            .closest_hit(point + self.t_min * direction, direction, f32::INFINITY)
            .map(|hit| hit.triangle)
    }

    /// Per point, 1 where light from its direction in `directions` (world,
    /// unit; x, y, z arrays aligned with `points`) reaches it, 0 where the
    /// probe blocks it.
    pub fn unshadowed<T: Real>(&self, points: &[Vec3], directions: &[Vec<T>; 3]) -> Vec<T> {
        assert!(
            directions.iter().all(|d| d.len() == points.len()),
            "Occluder::unshadowed: one direction per point"
        );
        (0..points.len())
            .into_par_iter()
            .map(|i| match self.lit(points[i], vec3_at(directions, i)) {
                true => T::one(),
                false => T::zero(),
            })
            .collect()
    }
}

/// How many bounces off the probe its renders follow (`render_layer`, the
/// acquisition's texture solves). A can's lid sees its rim's inside, which
/// sees the lid: with one bounce the top of a can seen from above renders
/// 16 % darker than a path tracer's (depth 4), with two 7 %; a third adds
/// about 0.1 %. A bounce costs its shadowed samples only.
pub const PROBE_BOUNCES: u32 = 2;

/// Start of the random number streams of the BRDF samples (plus the pixel
/// index: apart from the sub-pixel offsets', whose stream is the pixel index).
const BSDF_STREAM: u64 = 1 << 40;
/// Start of the random number streams of the env-map samples (plus the pixel index).
const LIGHT_STREAM: u64 = 2 << 40;
/// Start of the random number streams of a blurred camera's spread of the sub-pixel offsets
/// (plus the pixel index).
const FOOTPRINT_STREAM: u64 = 3 << 40;
/// Start of the random number streams of the first bounce's BRDF samples (plus the pixel index).
const BOUNCE_STREAM: u64 = 3 << 40;
/// Start of the random number streams of the first bounce's env-map samples (plus the pixel index).
const BOUNCE_LIGHT_STREAM: u64 = 4 << 40;
/// Start of the streams of the later bounces: bounce `k` (from 2) draws its BRDF
/// samples from `LATER_BOUNCE_STREAM + (2 (k - 2) << 40)` and its env-map samples from the next.
const LATER_BOUNCE_STREAM: u64 = 5 << 40;

/// The random number streams (BRDF, env map) of bounce `level` (from 1).
fn bounce_streams(level: u32) -> (u64, u64) {
    match level {
        1 => (BOUNCE_STREAM, BOUNCE_LIGHT_STREAM),
        _ => {
            let start = LATER_BOUNCE_STREAM + ((2 * (level as u64 - 2)) << 40);
            (start, start + (1 << 40))
        }
    }
}

impl PrimaryHits {
    /// Traces `spp` stratified rays through every pixel of the probe's
    /// projected bounding box (the whole image if part of the probe is
    /// behind the camera), against the mesh with `posed` vertex positions.
    pub fn trace(mesh: &Mesh, posed: &[Vec3], camera: &Camera, settings: &RenderSettings) -> Self {
        Self::trace_refined(mesh, posed, camera, settings, settings.spp)
    }

    /// [`trace`](Self::trace) with `silhouette_spp` rays (when more than
    /// `spp`) through each pixel on the probe's silhouette: the pixels whose
    /// four corners disagree about hitting the probe. Each pixel averages its
    /// own samples, so its coverage and radiance stay unbiased.
    ///
    /// The corners decide, not the pixel's own samples: a choice made on the
    /// samples that are then averaged would bias them (a pixel that a corner
    /// of the probe covers by 1 % is missed by its few samples most of the
    /// time, and refined only when one of them hits). A silhouette that
    /// enters and leaves a pixel between its corners is not refined.
    pub fn trace_refined(
        mesh: &Mesh,
        posed: &[Vec3],
        camera: &Camera,
        settings: &RenderSettings,
        silhouette_spp: u32,
    ) -> Self {
        assert_eq!(
            posed.len(),
            mesh.positions.len(),
            "PrimaryHits::trace: one posed position per vertex"
        );
        let spp = settings.spp.max(1) as usize;
        let silhouette_spp = (silhouette_spp as usize).max(spp);
        let world = Mesh {
            positions: posed.to_vec(),
            ..mesh.clone()
        };
        let accel = Accel::new(&world);
        let (lo, hi) = posed.iter().fold((Vec3::INFINITY, Vec3::NEG_INFINITY), |(lo, hi), &p| {
            (lo.min(p), hi.max(p))
        });
        let t_min = SHADOW_OFFSET * (hi - lo).length();
        let (w, h) = (camera.width as usize, camera.height as usize);
        let (mut x0, mut y0, mut x1, mut y1) = (f32::INFINITY, f32::INFINITY, f32::NEG_INFINITY, f32::NEG_INFINITY);
        let mut all_in_front = true;
        for &p in posed {
            match camera.project(p) {
                Some(q) => {
                    (x0, y0, x1, y1) = (x0.min(q.x), y0.min(q.y), x1.max(q.x), y1.max(q.y));
                }
                None => all_in_front = false,
            }
        }
        // A blurred camera's rays reach three footprints beyond a pixel.
        let spread = camera.footprint_px;
        let reach = 1.0 + (3.0 * spread).ceil();
        let (cols, rows) = if all_in_front {
            let clip = |a: f32, n: usize| (a.max(0.0) as usize).min(n);
            (
                clip(x0.floor() - reach, w)..clip(x1.ceil() + reach, w),
                clip(y0.floor() - reach, h)..clip(y1.ceil() + reach, h),
            )
        } else {
            (0..w, 0..h)
        };
        let hits_probe = |row: usize, col: usize, offset: Vec2| {
            let (origin, dir) = camera.primary_ray(row as u32, col as u32, offset);
            accel
                .closest_hit(origin, dir, f32::INFINITY)
                .map(|hit| (hit.triangle, dir, origin + hit.t * dir))
        };
        // Whether each pixel corner of the box sees the probe (corner (r, c) is
        // pixel (r, c)'s top left), when refining.
        let corner_cols = cols.start..cols.end + 1;
        let corners: Vec<bool> = if silhouette_spp > spp {
            (rows.start..rows.end + 1)
                .into_par_iter()
                .flat_map_iter(|row| corner_cols.clone().map(move |col| (row, col)))
                .map(|(row, col)| hits_probe(row, col, Vec2::ZERO).is_some())
                .collect()
        } else {
            Vec::new()
        };
        let on_silhouette = |row: usize, col: usize| {
            let at = |r: usize, c: usize| corners[(r - rows.start) * corner_cols.len() + c - cols.start];
            !corners.is_empty() && {
                let first = at(row, col);
                [at(row, col + 1), at(row + 1, col), at(row + 1, col + 1)].contains(&!first)
            }
        };
        // Per row, in parallel: the hit pixels (index, samples, hit count),
        // the hit samples in pixel order, and the rays traced.
        type RowHits = (Vec<(u32, u32, u32)>, Vec<(u32, Vec3, Vec3, Vec2)>, usize);
        let per_row: Vec<RowHits> = rows
            .clone()
            .into_par_iter()
            .map(|row| {
                let mut offsets = vec![Vec2::ZERO; silhouette_spp];
                let mut lobe_points = vec![Vec2::ZERO; silhouette_spp];
                let (mut pixels, mut samples, mut rays) = (Vec::new(), Vec::new(), 0);
                for col in cols.clone() {
                    let pixel = (row * w + col) as u32;
                    let n = if on_silhouette(row, col) { silhouette_spp } else { spp };
                    let offsets = &mut offsets[..n];
                    stratified_offsets(settings.seed, pixel, offsets);
                    if spread > 0.0 {
                        let mut rng = Rng::new(settings.seed, FOOTPRINT_STREAM + pixel as u64);
                        offsets
                            .iter_mut()
                            .for_each(|o| *o += spread * sample_standard_normal_2d(rng.next_2d()));
                    }
                    let lobe = &mut lobe_points[..n];
                    stratified_square(&mut Rng::new(settings.seed, BSDF_STREAM + pixel as u64), lobe);
                    let before = samples.len();
                    for (&offset, &random) in offsets.iter().zip(lobe.iter()) {
                        if let Some((triangle, dir, point)) = hits_probe(row, col, offset) {
                            samples.push((triangle, dir, point, random));
                        }
                    }
                    rays += n;
                    if samples.len() > before {
                        pixels.push((pixel, n as u32, (samples.len() - before) as u32));
                    }
                }
                (pixels, samples, rays)
            })
            .collect();
        let mut hits = PrimaryHits {
            width: w,
            height: h,
            spp: spp as u32,
            rays: corners.len() + per_row.iter().map(|r| r.2).sum::<usize>(),
            seed: settings.seed,
            ..Default::default()
        };
        for (pixels, samples, _) in per_row {
            let mut samples = samples.into_iter();
            for (pixel, n, count) in pixels {
                let segment = hits.pixels.len() as u32;
                hits.pixels.push(pixel);
                hits.samples.push(n);
                hits.coverage.push(count as f32 / n as f32);
                for (triangle, dir, point, random) in samples.by_ref().take(count as usize) {
                    hits.segment.push(segment);
                    hits.triangle.push(triangle);
                    hits.direction.push(dir);
                    hits.point.push(point);
                    hits.random.push(random);
                }
            }
        }
        hits.occluder = Some(Arc::new(Occluder { accel, t_min }));
        hits
    }

    /// Keeps the pixels whose row-major index `keep` accepts, with their
    /// samples in order (a fit that reads a subset of the probe's pixels
    /// costs in proportion to it). `rays` still counts every ray traced.
    pub fn retain_pixels(&mut self, keep: impl Fn(u32) -> bool) {
        let pixel_kept: Vec<bool> = self.pixels.iter().map(|&p| keep(p)).collect();
        // Keeping all (a fit on every pixel) moves nothing.
        if pixel_kept.iter().all(|&kept| kept) {
            return;
        }
        let sample_kept: Vec<bool> = self.segment.iter().map(|&s| pixel_kept[s as usize]).collect();
        // Each kept pixel's position among the kept ones.
        let renumbered: Vec<u32> = pixel_kept
            .iter()
            .scan(0u32, |kept_before, &kept| {
                let at = *kept_before;
                *kept_before += kept as u32;
                Some(at)
            })
            .collect();
        retain_flagged(&mut self.pixels, &pixel_kept);
        retain_flagged(&mut self.samples, &pixel_kept);
        retain_flagged(&mut self.coverage, &pixel_kept);
        retain_flagged(&mut self.triangle, &sample_kept);
        retain_flagged(&mut self.direction, &sample_kept);
        retain_flagged(&mut self.random, &sample_kept);
        retain_flagged(&mut self.point, &sample_kept);
        retain_flagged(&mut self.segment, &sample_kept);
        self.segment.iter_mut().for_each(|s| *s = renumbered[*s as usize]);
    }

    /// Number of hit samples.
    pub fn len(&self) -> usize {
        self.segment.len()
    }

    /// Whether no sample sees the probe.
    pub fn is_empty(&self) -> bool {
        self.segment.is_empty()
    }

    /// Spreads per-pixel values (one per entry of `pixels`) over a full image.
    pub fn to_image(&self, rgb: [&[f64]; 3]) -> RgbImage {
        let mut image = RgbImage::filled(self.width, self.height, [0.0; 3]);
        for (k, &p) in self.pixels.iter().enumerate() {
            image.pixels[p as usize] = [rgb[0][k] as f32, rgb[1][k] as f32, rgb[2][k] as f32];
        }
        image
    }
}

/// Keeps the items of `items` whose flag in `kept` is set (one flag per item).
fn retain_flagged<T>(items: &mut Vec<T>, kept: &[bool]) {
    assert_eq!(items.len(), kept.len(), "retain_flagged: one flag per item");
    // `retain` visits the items once each, in order.
    let mut flags = kept.iter();
    items.retain(|_| *flags.next().expect("one flag per item"));
}

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

/// How [`light_samples_with`] picks the directions light arrives from.
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

/// The light samples of every hit: the hit point on the (moving) triangle,
/// its material, one BRDF sample (same as [`light_samples_with`] and
/// [`LightSampling::BSDF`]).
pub fn light_samples<'t, T: Real>(
    tape: &'t Tape<T>,
    hits: &PrimaryHits,
    camera: &Camera,
    probe: &ProbeVars<'t, T>,
    posed: &PosedMesh<'t, T>,
    triangles: &[[u32; 3]],
    bsdf: &dyn Bsdf<T>,
) -> LightSamples<'t, T> {
    light_samples_with(tape, hits, camera, probe, posed, triangles, bsdf, &LightSampling::BSDF)
}

/// The light samples of every hit, picked by `sampling`: the BRDF sample's
/// first, then (MIS) the env-map sample's, with the same segments, then
/// (bounces) the bounces, one after the other.
///
/// With MIS, the BRDF sample at `wi_b` (a smooth function of the pose, the
/// roughness and its random numbers) carries `f cos / p_b * p_b / (p_b + p_e)`
/// and the env sample at `wi_e` (fixed in the world) carries
/// `f cos / p_e * p_e / (p_e + p_b)`; the weights add up to 1 at every
/// direction, so the image's expectation is the integral. Nothing is
/// detached: every factor is continuous in the parameters, `p_b` included,
/// and so is `p_e` at the moving `wi_b` (the sampler's density is
/// continuous for this reason: see `sampling::env`), so each sample's
/// derivative is the derivative of its contribution and the gradient of
/// the expectation is unbiased. The one constant is `p_e` at `wi_e`.
#[allow(clippy::too_many_arguments)]
pub fn light_samples_with<'t, T: Real>(
    tape: &'t Tape<T>,
    hits: &PrimaryHits,
    camera: &Camera,
    probe: &ProbeVars<'t, T>,
    posed: &PosedMesh<'t, T>,
    triangles: &[[u32; 3]],
    bsdf: &dyn Bsdf<T>,
    sampling: &LightSampling,
) -> LightSamples<'t, T> {
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

/// One BRDF sample and one env-map sample per shading point combined by
/// the balance heuristic (see [`light_samples_with`]).
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
fn vec3_at<T: Real>(xyz: &[Vec<T>; 3], i: usize) -> Vec3 {
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

/// Renders the probe's radiance into the pixels of `hits`: one array per
/// channel, aligned with `hits.pixels`, by BRDF sampling, averaged over
/// each pixel's samples (a partly covered pixel sums only its probe
/// samples: the background is black).
#[allow(clippy::too_many_arguments)]
pub fn shade<'t, T: Real>(
    tape: &'t Tape<T>,
    hits: &PrimaryHits,
    camera: &Camera,
    probe: &ProbeVars<'t, T>,
    posed: &PosedMesh<'t, T>,
    triangles: &[[u32; 3]],
    env: &ImageVars<'t, T>,
    bsdf: &dyn Bsdf<T>,
) -> [Var<'t, T>; 3] {
    light_samples(tape, hits, camera, probe, posed, triangles, bsdf).radiance(env)
}

/// Most samples per pixel one pass of [`render_image`] holds in memory
/// (every sample's intermediates live on the tape for a pass).
const SPP_PER_PASS: u32 = 16;

/// How many times more samples [`render_image`] spends on a silhouette pixel
/// (about 3 % of a 200-pixel-tall can's pixels: 10 % more samples).
const SILHOUETTE_SPP_FACTOR: u32 = 4;

/// Renders the probe at `pose` under `env` (f32, no gradients): the image
/// (black background, each pixel the sum of its probe samples' radiance over
/// all its samples: premultiplied by the coverage) and the share of each
/// pixel's samples that see the probe, for compositing over a photo. Light
/// is sampled by MIS of the BRDF and the env map ([`LightSampling::mis`]),
/// and what the probe reflects onto itself by [`PROBE_BOUNCES`] bounces
/// ([`LightSampling::bounces`]); silhouette pixels get
/// `SILHOUETTE_SPP_FACTOR` times the samples ([`PrimaryHits::trace_refined`]).
/// High sample counts run in passes of at most 16 spp (seeds `seed`,
/// `seed + 2^32`, ...), averaged, so memory stays bounded.
pub fn render_layer(
    probe: &ProbeAsset,
    pose: &Pose,
    camera: &Camera,
    env: &EnvMap,
    bsdf: &dyn Bsdf<f32>,
    settings: &RenderSettings,
) -> (RgbImage, Vec<f32>) {
    let (w, h) = (camera.width as usize, camera.height as usize);
    let mut sum = vec![[0.0f64; 3]; w * h];
    let mut covered = vec![0.0f64; w * h];
    let total = settings.spp.max(1);
    let passes = total.div_ceil(SPP_PER_PASS);
    let tape = Tape::<f32>::new();
    let vars = ProbeVars::new(&tape, probe, false);
    let posed = PosedMesh::new(&vars.mesh, &PoseVars::new(&tape, &pack_pose(pose), false));
    let env_vars = ImageVars::env(&tape, env, false);
    let sampler = EnvSampler::new(env);
    let positions = posed.position_values();
    let mark = tape.mark();
    for pass in 0..passes {
        let spp = SPP_PER_PASS.min(total - pass * SPP_PER_PASS);
        let pass_settings = RenderSettings {
            spp,
            // Apart from the passes of seeds `seed + 1`, ... (a second
            // render for a noise estimate would otherwise share its passes).
            seed: settings.seed.wrapping_add((pass as u64) << 32),
        };
        let hits = PrimaryHits::trace_refined(
            &probe.mesh,
            &positions,
            camera,
            &pass_settings,
            spp * SILHOUETTE_SPP_FACTOR,
        );
        if hits.is_empty() {
            break;
        }
        tape.reset_to(mark);
        let rgb = light_samples_with(
            &tape,
            &hits,
            camera,
            &vars,
            &posed,
            &probe.mesh.triangles,
            bsdf,
            &LightSampling::mis(&sampler).with_bounces(PROBE_BOUNCES),
        )
        .radiance(&env_vars);
        let rgb = rgb.map(|c| tape.to_vec(c));
        let share = spp as f64 / total as f64;
        for (k, &p) in hits.pixels.iter().enumerate() {
            for c in 0..3 {
                sum[p as usize][c] += rgb[c][k] as f64 * share;
            }
            covered[p as usize] += hits.coverage[k] as f64 * share;
        }
    }
    let image = RgbImage::new(w, h, sum.iter().map(|p| p.map(|v| v as f32)).collect());
    (image, covered.iter().map(|&c| c as f32).collect())
}

/// [`render_layer`] with its coverage made a hard mask: at least half of a
/// pixel's samples see the probe.
pub fn render_image(
    probe: &ProbeAsset,
    pose: &Pose,
    camera: &Camera,
    env: &EnvMap,
    bsdf: &dyn Bsdf<f32>,
    settings: &RenderSettings,
) -> (RgbImage, Mask) {
    let (image, coverage) = render_layer(probe, pose, camera, env, bsdf, settings);
    let mask = Mask::new(image.width, image.height, coverage.iter().map(|&c| c >= 0.5).collect());
    (image, mask)
}

/// [`render_image`]'s mask alone (the pixels at least half of whose samples
/// see the probe, the silhouette refined as there), without shading the
/// probe: at most 16 spp, where both trace the same rays.
pub fn coverage_mask(probe: &ProbeAsset, pose: &Pose, camera: &Camera, settings: &RenderSettings) -> Mask {
    let positions: Vec<Vec3> = probe.mesh.positions.iter().map(|&p| pose.transform_point(p)).collect();
    let spp = settings.spp.clamp(1, SPP_PER_PASS);
    let pass = RenderSettings { spp, ..*settings };
    let hits = PrimaryHits::trace_refined(&probe.mesh, &positions, camera, &pass, spp * SILHOUETTE_SPP_FACTOR);
    let mut inside = vec![false; camera.width as usize * camera.height as usize];
    for (&p, &c) in hits.pixels.iter().zip(&hits.coverage) {
        inside[p as usize] = c >= 0.5;
    }
    Mask::new(camera.width as usize, camera.height as usize, inside)
}
