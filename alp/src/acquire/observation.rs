//! The views' pixels as affine functions of the albedo at a fixed
//! roughness: the texture solve's observations (PAPER.md, Sec. 3.2).
//!
//! The forward model (`render::integrator`: the probe's BSDF, MIS, its
//! bounces) is linear in the light and, for a metal whose albedo enters
//! through Schlick's Fresnel `F = A + (1 - A)(1 - cos)^5` (GGX's, Beckmann's:
//! any microfacet metal of `render::bsdf`'s kind), affine in the albedo `A`
//! of the point a light sample leaves (a model that is not is taken along
//! the line between albedo 0 and 1). So
//! a hit's direct light is `offset + A(uv) * slope`, per channel, where the
//! offset is its render with albedo 0 and the slope its render with albedo
//! 1 less the offset, from the same samples. A bounce, whose light leaves
//! two or more points, is linearised in the first one's albedo with the
//! others' held at a given value (its render at albedo 1 times that value
//! once per later point), and spread over the pixel's hits. A pixel, the
//! mean of its hits, is then linear in the albedo texels its hits' bilinear
//! taps read.
//!
//! Each pixel is observed twice, from two independent sample sets (halves):
//! the product of the two residuals is an unbiased estimate of the squared
//! error under Monte Carlo noise, where one render's square adds the noise's
//! variance (which depends on the material and so biases it).
//!
//! A pixel's weight is its relative squared error's, lowered by its
//! render's noise ([`pixel_noise`]): a thin highlight of the sun swings
//! by many times its value from one render to the next (the photo's, a
//! path tracer's, as much), and in a relative error one such pixel
//! outweighed thousands of quiet ones and darkened a can's lid to half its
//! albedo.

use glam::{Vec2, Vec3};
use render::bsdf::Bsdf;
use render::camera::Camera;
use render::colour::luminance;
use render::envmap::EnvMap;
use render::image_io::{Mask, RgbImage};
use render::integrator::{
    LightSamples, LightSampling, PROBE_BOUNCES, PrimaryHits, ProbeScene, ProbeVars, RenderSettings,
};
use render::lookup::{ImageVars, TextureVars};
use render::mesh::Mesh;
use render::pose::Pose;
use render::posed::{PoseVars, PosedMesh, pack_pose};
use render::probe::Texture;
use render::sampling::{EnvSampler, Rng, stratified_square};

use autodiff::Tape;
use rayon::prelude::*;

use super::capture::Capture;

/// A view as the fit reads it: its camera and its pixels well inside the
/// probe (a mask's edge mixes in the background).
pub(crate) struct FitView<'a> {
    pub(crate) camera: &'a Camera,
    /// Row-major index -> position in `target`, for the pixels fitted.
    pub(crate) slot: Vec<Option<u32>>,
    pub(crate) target: Vec<[f32; 3]>,
}

impl<'a> FitView<'a> {
    pub(crate) fn new(camera: &'a Camera, image: &RgbImage, mask: &Mask) -> Self {
        let inner = eroded(&mask.inside, mask.width);
        let mut slot = vec![None; inner.len()];
        let mut target = Vec::new();
        for (p, _) in inner.iter().enumerate().filter(|(_, inside)| **inside) {
            slot[p] = Some(target.len() as u32);
            target.push(image.pixels[p]);
        }
        FitView { camera, slot, target }
    }

    /// The mean luminance of the pixels fitted.
    pub(crate) fn mean_luminance(&self) -> f64 {
        self.target.iter().map(|&t| luminance(t) as f64).sum::<f64>() / self.target.len().max(1) as f64
    }
}

/// The pixels `inside` (row-major, `width` wide) less their edge: a
/// pixel stays when its 4 neighbours are inside too.
pub(crate) fn eroded(inside: &[bool], width: usize) -> Vec<bool> {
    let (w, h) = (width, inside.len() / width.max(1));
    (0..w * h)
        .map(|p| {
            let (x, y) = (p % w, p / w);
            inside[p]
                && x > 0
                && y > 0
                && x + 1 < w
                && y + 1 < h
                && inside[p - 1]
                && inside[p + 1]
                && inside[p - w]
                && inside[p + w]
        })
        .collect()
}

/// The capture with its scan placed: what every observation renders.
pub(crate) struct Placed<'a> {
    pub(crate) mesh: &'a Mesh,
    pub(crate) to_world: [f64; render::posed::POSE_PARAMS],
    pub(crate) positions: Vec<Vec3>,
    pub(crate) env: &'a EnvMap,
    pub(crate) sampler: EnvSampler,
    /// The probe's reflectance model: every re-render of a view uses it.
    pub(crate) bsdf: &'a dyn Bsdf<f32>,
    pub(crate) views: Vec<FitView<'a>>,
}

impl<'a> Placed<'a> {
    pub(crate) fn new(capture: &'a Capture, to_world: &Pose, bsdf: &'a dyn Bsdf<f32>) -> Self {
        Placed {
            mesh: &capture.mesh,
            to_world: pack_pose(to_world),
            positions: capture
                .mesh
                .positions
                .iter()
                .map(|&p| to_world.transform_point(p))
                .collect(),
            env: &capture.lighting,
            sampler: EnvSampler::new(&capture.lighting),
            bsdf,
            views: capture
                .views
                .iter()
                .map(|v| FitView::new(&v.photo.camera, &v.photo.image, &v.photo.mask))
                .collect(),
        }
    }
}

/// How much an observation renders.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Budget {
    /// Samples per pixel of each half.
    pub(crate) spp: u32,
    /// Most pixels of a view observed (a random share of a view with more).
    pub(crate) pixels_per_view: usize,
    /// A pixel's weight is 1 / ((its luminance + this share of its view's
    /// mean)^2 + `noise_weight` times its render's noise variance).
    pub(crate) relative_floor: f64,
    /// How much a pixel's Monte Carlo noise lowers its weight against its
    /// relative error (see [`pixel_noise`]).
    pub(crate) noise_weight: f64,
    /// A pixel's hits closer than this in u and v are merged (about half a
    /// texel of the finest texture read).
    pub(crate) merge_uv: [f32; 2],
    /// Seed of the samples and of the pixels' share: the same seed observes
    /// the same pixels through the same primary rays at any roughness.
    pub(crate) seed: u64,
}

/// One observed pixel.
#[derive(Clone, Copy, Debug)]
pub(crate) struct PixelObservation {
    /// The photo's value.
    pub(crate) target: [f32; 3],
    /// Its weight in the data term: relative squared error, lowered by
    /// its render's noise, over the view's pixels and the views.
    pub(crate) weight: f64,
    /// Per half: the render with albedo 0.
    pub(crate) offset: [[f32; 3]; 2],
}

/// One hit's share of its pixel's slope.
#[derive(Clone, Copy, Debug)]
pub(crate) struct HitSlope {
    /// Texture coordinates of the point hit.
    pub(crate) uv: Vec2,
    /// The pixel's radiance per unit albedo at this point, RGB.
    pub(crate) slope: [f32; 3],
    /// Which sample set (0 or 1).
    pub(crate) half: u8,
}

/// Every view's observed pixels, and their hits grouped by pixel.
#[derive(Default)]
pub(crate) struct Observations {
    pub(crate) pixels: Vec<PixelObservation>,
    /// The hits of pixel `p` are `hits[hit_start[p]..hit_start[p + 1]]`.
    pub(crate) hit_start: Vec<usize>,
    pub(crate) hits: Vec<HitSlope>,
}

impl Observations {
    /// Hits of pixel `p`.
    pub(crate) fn hits_of(&self, p: usize) -> &[HitSlope] {
        &self.hits[self.hit_start[p]..self.hit_start[p + 1]]
    }
}

/// Most samples per pixel one pass holds on its tape.
const SPP_PER_PASS: u32 = 4;

/// Start of the seeds of the second half's samples.
const SECOND_HALF: u64 = 1 << 63;

/// The random stream (plus the pixel's index) of a half's BRDF samples.
const LIGHT_REDRAW_STREAM: u64 = 0x11D2_0000_0000;

/// The random stream (plus the pixel's index) of a view's share of pixels.
const PIXEL_SHARE_STREAM: u64 = 0x5A4E_0000_0000;

/// Observes every view of `placed` with the roughness texture `roughness`,
/// the bounces' later points at albedo `bounce_albedo`: the views in
/// parallel, each on its own tape, joined in the capture's order.
pub(crate) fn observe(placed: &Placed, roughness: &Texture, bounce_albedo: [f32; 3], budget: &Budget) -> Observations {
    let per_view: Vec<_> = placed
        .views
        .par_iter()
        .map(|view| observe_view(placed, view, roughness, bounce_albedo, budget))
        .collect();
    let mut out = Observations::default();
    out.hit_start.push(0);
    for (pixels, pixel_hits) in per_view {
        out.pixels.extend(pixels);
        for hits in pixel_hits {
            out.hits.extend(hits);
            out.hit_start.push(out.hits.len());
        }
    }
    out
}

/// One view's observed pixels and, per pixel, its hits (merged where close).
fn observe_view(
    placed: &Placed,
    view: &FitView,
    roughness: &Texture,
    bounce_albedo: [f32; 3],
    budget: &Budget,
) -> (Vec<PixelObservation>, Vec<Vec<HitSlope>>) {
    let tape = Tape::<f32>::new();
    let constant = |v: f32| TextureVars::new(&tape, &Texture::constant([v; 3]), false);
    let zero = ProbeVars {
        mesh: render::posed::MeshVars::new(&tape, placed.mesh),
        albedo: constant(0.0),
        roughness: TextureVars::new(&tape, roughness, false),
        visibility: constant(1.0),
    };
    let one = ProbeVars {
        albedo: constant(1.0),
        ..zero
    };
    let posed = PosedMesh::new(&zero.mesh, &PoseVars::new(&tape, &placed.to_world, false));
    let env = ImageVars::env(&tape, placed.env, false);
    let mark = tape.mark();
    let views = placed.views.len().max(1);
    let mut out = Observations::default();
    let mut pixel_hits: Vec<Vec<HitSlope>> = Vec::new();
    let share = budget.pixels_per_view as f32 / view.target.len().max(1) as f32;
    let kept = |p: u32| {
        view.slot[p as usize].is_some()
            && (share >= 1.0 || Rng::new(budget.seed, PIXEL_SHARE_STREAM + p as u64).next_f32() < share)
    };
    // Per image pixel, its index in this view's observations.
    let mut row = vec![u32::MAX; view.slot.len()];
    // Per observed pixel and half: its samples' luminance at `bounce_albedo`, summed and squared.
    let mut spread: Vec<[Spread; 2]> = Vec::new();
    let passes = budget.spp.max(1).div_ceil(SPP_PER_PASS);
    for pass in 0..passes {
        let spp = SPP_PER_PASS.min(budget.spp.max(1) - pass * SPP_PER_PASS);
        let seed = budget.seed.wrapping_add((pass as u64) << 32);
        let mut hits = PrimaryHits::trace(
            placed.mesh,
            &placed.positions,
            view.camera,
            &RenderSettings { spp, seed },
        );
        hits.retain_pixels(kept);
        if hits.is_empty() {
            continue;
        }
        for half in 0..2u8 {
            if half == 1 {
                redraw_light_samples(&mut hits, seed ^ SECOND_HALF);
            }
            tape.reset_to(mark);
            let direct = LightSampling::mis(&placed.sampler);
            let triangles = &placed.mesh.triangles;
            let bsdf = placed.bsdf;
            let dark = ProbeScene {
                tape: &tape,
                hits: &hits,
                camera: view.camera,
                probe: &zero,
                posed: &posed,
                triangles,
                bsdf,
            }
            .light_samples(&direct);
            let bright = ProbeScene {
                tape: &tape,
                hits: &hits,
                camera: view.camera,
                probe: &one,
                posed: &posed,
                triangles,
                bsdf,
            }
            .light_samples(&direct.with_bounces(PROBE_BOUNCES));
            let light = |samples: &LightSamples<'_, f32>| -> [Vec<f32>; 3] {
                let l = env.env_radiance(samples.wi);
                std::array::from_fn(|c| tape.to_vec(samples.throughput[c] * l[c]))
            };
            let n = hits.len();
            let (dark_light, bright_light) = (light(&dark), light(&bright));
            // Per pixel of the pass: the bounces' light with albedo 1 at
            // the first point and `bounce_albedo` at the later ones.
            let segment = tape.to_vec(bright.segment);
            let mut bounce = vec![[0.0f32; 3]; hits.pixels.len()];
            let mut later = [1.0f32; 3];
            for samples in bright.bounce_ranges() {
                later = std::array::from_fn(|c| later[c] * bounce_albedo[c]);
                for k in samples {
                    for c in 0..3 {
                        bounce[segment[k] as usize][c] += later[c] * bright_light[c][k];
                    }
                }
            }
            let mut count = vec![0u32; hits.pixels.len()];
            for &s in &hits.segment {
                count[s as usize] += 1;
            }
            let pass_share = spp as f32 / budget.spp.max(1) as f32;
            for &pixel in &hits.pixels {
                if row[pixel as usize] == u32::MAX {
                    row[pixel as usize] = out.pixels.len() as u32;
                    let target = view.target[view.slot[pixel as usize].expect("kept pixels are fitted") as usize];
                    out.pixels.push(PixelObservation {
                        target,
                        weight: 0.0,
                        offset: [[0.0; 3]; 2],
                    });
                    pixel_hits.push(Vec::new());
                    spread.push(Default::default());
                }
            }
            for i in 0..n {
                let j = hits.segment[i] as usize;
                let r = row[hits.pixels[j] as usize];
                let offset = &mut out.pixels[r as usize].offset[half as usize];
                let (mut slope, mut share) = ([0.0f32; 3], [0.0f32; 3]);
                for c in 0..3 {
                    let dark_i = dark_light[c][i] + dark_light[c][i + n];
                    let bright_i = bright_light[c][i] + bright_light[c][i + n];
                    offset[c] += pass_share * dark_i;
                    slope[c] = pass_share * (bright_i - dark_i + bounce[j][c] / count[j] as f32);
                    share[c] = pass_share * (dark_i + bounce_albedo[c] * (bright_i - dark_i));
                }
                spread[r as usize][half as usize].add(luminance(share) as f64);
                merge(
                    &mut pixel_hits[r as usize],
                    HitSlope {
                        uv: super::material::hit_uv(placed.mesh, &placed.positions, hits.triangle[i], hits.point[i]),
                        slope,
                        half,
                    },
                    budget.merge_uv,
                );
            }
        }
    }
    // Weights: relative squared error, less where the render is noisy,
    // over the view's pixels and the views (both halves read the same
    // hits, so every pixel has both).
    let pixels = out.pixels.len();
    let noise = if budget.noise_weight > 0.0 {
        let width = view.camera.width as usize;
        pixel_noise(
            &out.pixels,
            &pixel_hits,
            &spread,
            &row,
            width,
            bounce_albedo,
            budget.spp,
        )
    } else {
        vec![0.0; pixels]
    };
    let floor = budget.relative_floor * view.mean_luminance();
    for (p, noise) in out.pixels.iter_mut().zip(noise) {
        let scale = luminance(p.target).max(0.0) as f64 + floor;
        p.weight =
            1.0 / ((scale * scale + budget.noise_weight * noise).max(f64::MIN_POSITIVE) * (pixels * views) as f64);
    }
    (out.pixels, pixel_hits)
}

/// A pixel's samples' shares of its value: their sum and sum of squares.
#[derive(Clone, Copy, Default)]
struct Spread {
    sum: f64,
    squares: f64,
}

impl Spread {
    fn add(&mut self, share: f64) {
        self.sum += share;
        self.squares += share * share;
    }

    /// The variance of the mean of `samples` samples whose shares (each
    /// sample's value over `samples`) these are; 0 from one sample.
    fn variance_of_mean(&self, samples: u32) -> f64 {
        if samples < 2 {
            return 0.0;
        }
        let n = samples as f64;
        ((n * self.squares - self.sum * self.sum) / (n - 1.0)).max(0.0)
    }
}

/// Per observed pixel, the variance of its render's luminance at albedo
/// `bounce_albedo` under Monte Carlo noise: the larger of two estimates,
/// from the spread of its samples (primary rays and light) and from its
/// two halves' difference (which also sees the bounces' noise, spread
/// evenly over a pixel's samples), averaged over its observed 3x3
/// neighbours (`row`: image pixel -> observed pixel, `width` wide): along
/// a highlight, the neighbours tell a pixel's noise when its own samples
/// happened to agree.
fn pixel_noise(
    pixels: &[PixelObservation],
    pixel_hits: &[Vec<HitSlope>],
    spread: &[[Spread; 2]],
    row: &[u32],
    width: usize,
    bounce_albedo: [f32; 3],
    spp: u32,
) -> Vec<f64> {
    let own: Vec<f64> = (0..pixels.len())
        .map(|k| {
            let half_value = |half: usize| -> f64 {
                let mut v = pixels[k].offset[half];
                for h in pixel_hits[k].iter().filter(|h| h.half as usize == half) {
                    (0..3).for_each(|c| v[c] += bounce_albedo[c] * h.slope[c]);
                }
                luminance(v) as f64
            };
            let within = (spread[k][0].variance_of_mean(spp) + spread[k][1].variance_of_mean(spp)) / 2.0;
            // Two estimates of one half's value differ by twice its variance, in expectation.
            within.max((half_value(0) - half_value(1)).powi(2) / 2.0)
        })
        .collect();
    let height = row.len() / width.max(1);
    let mut pooled = vec![0.0; pixels.len()];
    for (p, &r) in row.iter().enumerate().filter(|(_, r)| **r != u32::MAX) {
        let (x, y) = (p % width, p / width);
        let (mut sum, mut count) = (0.0, 0.0);
        for ny in y.saturating_sub(1)..(y + 2).min(height) {
            for nx in x.saturating_sub(1)..(x + 2).min(width) {
                let n = row[ny * width + nx];
                if n != u32::MAX {
                    sum += own[n as usize];
                    count += 1.0;
                }
            }
        }
        pooled[r as usize] = sum / count;
    }
    pooled
}

/// New random numbers, from `seed`, for the light samples of `hits` (the
/// BRDF's and, through the seed, the env map's and the bounce's): the same
/// primary rays, independent light. The two halves then differ by their
/// light's noise alone; with their own rays too, a pixel's two rows would
/// read different texels, and their product would reward a checkerboard.
fn redraw_light_samples(hits: &mut PrimaryHits, seed: u64) {
    hits.seed = seed;
    let mut start = 0;
    while start < hits.len() {
        let segment = hits.segment[start];
        let end = start + hits.segment[start..].iter().take_while(|&&s| s == segment).count();
        let pixel = hits.pixels[segment as usize] as u64;
        stratified_square(
            &mut Rng::new(seed, LIGHT_REDRAW_STREAM + pixel),
            &mut hits.random[start..end],
        );
        start = end;
    }
}

/// Adds `hit` to a pixel's `hits`: into one of the same half within
/// `tolerance` in u and v (which then stands for both at its own
/// coordinates), else as a new one. A pixel's many samples then cost a
/// few entries, not one each, while a pixel across a seam of the texture
/// keeps a hit on each side.
fn merge(hits: &mut Vec<HitSlope>, hit: HitSlope, tolerance: [f32; 2]) {
    let near = |h: &&mut HitSlope| {
        h.half == hit.half && (h.uv.x - hit.uv.x).abs() <= tolerance[0] && (h.uv.y - hit.uv.y).abs() <= tolerance[1]
    };
    match hits.iter_mut().find(|h| near(h)) {
        Some(h) => (0..3).for_each(|c| h.slope[c] += hit.slope[c]),
        None => hits.push(hit),
    }
}

/// The bilinear taps (texel index, weight) of a `width` x `height`
/// texture at OBJ texture coordinates `uv`, as `Texture::lookup` reads them
/// (v = 0 the bottom row, clamped at the edges).
pub(crate) fn texel_taps(uv: Vec2, width: usize, height: usize) -> [(usize, f32); 4] {
    let x = (uv.x * width as f32 - 0.5).clamp(0.0, (width - 1) as f32);
    let y = ((1.0 - uv.y) * height as f32 - 0.5).clamp(0.0, (height - 1) as f32);
    let (col0, row0) = (x.floor() as usize, y.floor() as usize);
    let (fx, fy) = (x - col0 as f32, y - row0 as f32);
    let (col1, row1) = ((col0 + 1).min(width - 1), (row0 + 1).min(height - 1));
    [
        (row0 * width + col0, (1.0 - fx) * (1.0 - fy)),
        (row0 * width + col1, fx * (1.0 - fy)),
        (row1 * width + col0, (1.0 - fx) * fy),
        (row1 * width + col1, fx * fy),
    ]
}

/// The 4-neighbours (left, right, up, down) of cell `k` of a row-major
/// `width` x `height` grid, where they exist.
pub(crate) fn grid_neighbours(k: usize, width: usize, height: usize) -> [Option<usize>; 4] {
    let (col, row) = (k % width, k / width);
    [
        (col > 0).then(|| k - 1),
        (col + 1 < width).then(|| k + 1),
        (row > 0).then(|| k - width),
        (row + 1 < height).then(|| k + width),
    ]
}

/// The right and lower neighbours of cell `k` (each neighbouring pair once).
pub(crate) fn grid_pairs(k: usize, width: usize, height: usize) -> [Option<usize>; 2] {
    let [_, right, _, down] = grid_neighbours(k, width, height);
    [right, down]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_spread_gives_the_variance_of_the_mean() {
        let values = [1.0, 4.0, 0.0, 3.0];
        let n = values.len() as f64;
        let mut spread = Spread::default();
        values.iter().for_each(|v| spread.add(v / n));
        let mean = values.iter().sum::<f64>() / n;
        let variance = values.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (n - 1.0);
        assert!((spread.variance_of_mean(4) - variance / n).abs() < 1e-12);
        assert_eq!(spread.variance_of_mean(1), 0.0);
    }

    #[test]
    fn a_pixels_noise_is_its_neighbourhoods() {
        // A 3 x 2 image, its top-left pixel unobserved. Pixel (1, 0): its
        // halves 0.2 and 0.6 apart in luminance (offsets alone, no hits);
        // pixel (2, 1): its samples spread; the others quiet.
        let (width, row) = (3, vec![u32::MAX, 0, 1, 2, 3, 4]);
        let quiet = PixelObservation {
            target: [0.5; 3],
            weight: 0.0,
            offset: [[0.5; 3]; 2],
        };
        let mut pixels = vec![quiet; 5];
        pixels[0].offset = [[0.2; 3], [0.8; 3]];
        let mut spread = vec![[Spread::default(); 2]; 5];
        for half in &mut spread[4] {
            [0.0, 1.0].iter().for_each(|v| half.add(v / 2.0));
        }
        let noise = pixel_noise(&pixels, &vec![Vec::new(); 5], &spread, &row, width, [0.7; 3], 2);
        // Own estimates: 0.6^2 / 2 = 0.18 at (1, 0), the sample variance
        // of {0, 1} over 2 samples = 0.25 at (2, 1), 0 elsewhere.
        let own = [0.18, 0.0, 0.0, 0.0, 0.25];
        let expect = [
            (own[0] + own[1] + own[2] + own[3] + own[4]) / 5.0, // (1, 0): 5 observed neighbours
            (own[0] + own[1] + own[3] + own[4]) / 4.0,          // (2, 0)
            (own[0] + own[2] + own[3]) / 3.0,                   // (0, 1)
            (own[0] + own[1] + own[2] + own[3] + own[4]) / 5.0, // (1, 1)
            (own[0] + own[1] + own[3] + own[4]) / 4.0,          // (2, 1)
        ];
        for (k, (got, want)) in noise.iter().zip(expect).enumerate() {
            assert!((got - want).abs() < 1e-6, "pixel {k}: {got} against {want}");
        }
    }
}
