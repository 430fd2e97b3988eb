//! Which triangle each sub-pixel sample sees (a BVH, not differentiated),
//! and the posed probe as the occluder of its own light.

use std::sync::Arc;

use autodiff::Real;
use glam::{Vec2, Vec3};
use rayon::prelude::*;

use crate::accel::{Accel, stratified_offsets};
use crate::camera::Camera;
use crate::image_io::RgbImage;
use crate::mesh::Mesh;
use crate::sampling::{Rng, sample_standard_normal_2d, stratified_square};

use super::samples::vec3_at;
use super::{BSDF_STREAM, FOOTPRINT_STREAM, RenderSettings};

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
