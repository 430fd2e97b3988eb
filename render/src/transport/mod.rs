//! The light transport at a fixed pose: the image is linear in the env map.
//! Each light sample reads four texels of the map (bilinear, the taps of
//! [`crate::lookup`]) with a throughput; [`SampleRecord`] traces and keeps
//! the samples once, in passes as the renderer takes them, and
//! [`Transport`] is the sparse operator from texels to pixels they make at
//! any map size, with its transpose: a lighting solve becomes cheap sparse
//! products instead of renders.

use glam::{Vec2, Vec3};
use lanes::F64x4;
use rayon::prelude::*;

use autodiff::Tape;

use crate::bsdf::Bsdf;
use crate::camera::Camera;
use crate::envmap::direction_to_uv;
use crate::integrator::{LightSampling, PrimaryHits, ProbeScene, ProbeVars, RenderSettings};
use crate::lookup::env_taps;
use crate::pose::Pose;
use crate::posed::{PoseVars, PosedMesh, pack_pose};
use crate::probe::ProbeAsset;
use crate::{RenderError, Result};

mod op;
pub use op::TransportOp;

/// One entry of the transport: a texel and the RGB weight with which it
/// reaches a pixel, in quanta of the pixel's row ([`Transport::new`]).
/// Eight bytes where a u32 texel and f32 weights took sixteen: a solve
/// streams the whole transport at each of its hundreds of evaluations, so
/// its time goes with the transport's bytes (and a small probe's transport
/// can stay in the last-level cache). See docs/results/decisions.md 5, Lighting solve.
#[derive(Clone, Copy, Debug)]
#[repr(C, align(8))]
pub(crate) struct Entry {
    /// The RGB weight in quanta, then the texel: one load of four lanes
    /// ([`F64x4::from_entry`]).
    pub(crate) lanes: [u16; 4],
}

impl Entry {
    #[inline]
    pub(crate) fn new(index: u16, weight: [u16; 3]) -> Self {
        Entry {
            lanes: [weight[0], weight[1], weight[2], index],
        }
    }

    #[inline]
    pub(crate) fn index(&self) -> usize {
        self.lanes[3] as usize
    }

    /// The RGB weight in quanta.
    #[inline]
    pub(crate) fn quanta(&self) -> [f64; 3] {
        std::array::from_fn(|c| self.lanes[c] as f64)
    }
}

/// The most texels a transport's map may have (its entries' texels are u16).
pub const MAX_TEXELS: usize = 1 << 16;

/// The linear map from an env map (texel-major RGB at `width x height`,
/// at most [`MAX_TEXELS`] texels) to the probe's pixels, as a sparse
/// matrix stored by pixel: the texels each pixel's light samples read
/// (bilinear taps of every sample merged, so that more samples per pixel
/// cost memory only where lobes are wide), their weights quantised.
/// Products with its transpose sum per chunk of `PIXEL_CHUNK` pixels
/// into a dense map (the map is small next to the transport: no
/// transposed copy), the chunks in order: parallel, and the same sums
/// whatever the thread count.
#[derive(Clone, Debug)]
pub struct Transport {
    /// Env map columns.
    pub width: usize,
    /// Env map rows.
    pub height: usize,
    /// Number of pixels (segments).
    pub pixels: usize,
    pub(crate) row_start: Vec<usize>,
    /// Per pixel, the weight of one quantum of its row's entries.
    pub(crate) quantum: Vec<f32>,
    pub(crate) rows: Vec<Entry>,
}

/// The light samples of a posed probe, kept for its transport: per sample
/// its pixel, the map coordinates of its direction, its throughput (the
/// mean over the passes) and how it came about.
pub struct SampleRecord {
    /// The first pass's primary hits: the pixels the samples belong to.
    pub hits: PrimaryHits,
    /// Per image pixel, its index in `hits.pixels` (`u32::MAX`: none).
    pub row: Vec<u32>,
    /// Per sample, its pixel (an index into `hits.pixels`).
    pub segment: Vec<u32>,
    /// Per sample, the map coordinates of the direction it reads.
    pub uv: Vec<Vec2>,
    /// Per sample, its RGB throughput over the passes.
    pub throughput: Vec<[f32; 3]>,
    /// Per sample, whether it is a hit's own (else its bounce's, one step of
    /// inter-reflection).
    pub direct: Vec<bool>,
    /// Per sample, whether it reaches the env map (not the probe).
    pub lit: Vec<bool>,
    /// Per sample, whether the env map's sampler drew it (else the BRDF's).
    pub env_sampled: Vec<bool>,
}

impl SampleRecord {
    /// The light samples of `asset` at `pose` seen by `camera`: `settings.spp`
    /// per pixel, drawn by `sampling` in `passes` passes (each its own
    /// stratified set and seed; a pass's samples are dropped from the tape
    /// before the next), on the pixels `keep` keeps. The first pass's pixels
    /// are the data; later passes' samples join their pixels. An error when
    /// the probe leaves the view. `bsdf` is the probe's reflectance model.
    #[allow(clippy::too_many_arguments)]
    pub fn trace(
        asset: &ProbeAsset,
        bsdf: &dyn Bsdf<f32>,
        pose: &Pose,
        camera: &Camera,
        settings: &RenderSettings,
        sampling: &LightSampling,
        passes: u32,
        keep: impl Fn(u32) -> bool,
    ) -> Result<Self> {
        let mut reference: Option<PrimaryHits> = None;
        let mut row = Vec::new();
        let (mut segment, mut uv, mut throughput) = (Vec::new(), Vec::<Vec2>::new(), Vec::<[f32; 3]>::new());
        let (mut direct, mut lit, mut env_sampled) = (Vec::new(), Vec::new(), Vec::new());
        // The probe and its pose are recorded once; each pass's samples go on
        // top of them, dropped before the next pass (the tape keeps its buffers).
        let tape = Tape::<f32>::new();
        let vars = ProbeVars::new(&tape, asset, false);
        let posed = PosedMesh::new(&vars.mesh, &PoseVars::new(&tape, &pack_pose(pose), false));
        let positions = posed.position_values();
        let posed_mark = tape.mark();
        for pass in 0..passes {
            let pass_settings = RenderSettings {
                spp: settings.spp.div_ceil(passes),
                seed: settings.seed.wrapping_add((pass as u64) << 32),
            };
            tape.reset_to(posed_mark);
            let mut hits = PrimaryHits::trace(&asset.mesh, &positions, camera, &pass_settings);
            hits.retain_pixels(&keep);
            if hits.is_empty() {
                return Err(RenderError::value("pose", "the probe left the camera's view"));
            }
            if pass == 0 {
                row = vec![u32::MAX; camera.pixel_count()];
                hits.pixels
                    .iter()
                    .enumerate()
                    .for_each(|(k, &p)| row[p as usize] = k as u32);
            }
            let samples = ProbeScene {
                tape: &tape,
                hits: &hits,
                camera,
                probe: &vars,
                posed: &posed,
                triangles: &asset.mesh.triangles,
                bsdf,
            }
            .light_samples(sampling);
            let d = [samples.wi.x, samples.wi.y, samples.wi.z].map(|v| tape.to_vec(v));
            let tp = samples.throughput.map(|t| tape.to_vec(t));
            let pass_lit = tape.to_vec(samples.lit);
            let pass_segment = tape.to_vec(samples.segment);
            for (i, &seg) in pass_segment.iter().enumerate() {
                let r = row[hits.pixels[seg as usize] as usize];
                if r != u32::MAX {
                    segment.push(r);
                    uv.push(direction_to_uv(Vec3::new(d[0][i], d[1][i], d[2][i])));
                    throughput.push([0, 1, 2].map(|c| tp[c][i] / passes as f32));
                    direct.push(i < samples.direct);
                    lit.push(pass_lit[i] > 0.5);
                    env_sampled.push(samples.env_sampled[i]);
                }
            }
            if pass == 0 {
                reference = Some(hits);
            }
        }
        Ok(SampleRecord {
            hits: reference.expect("at least one pass"),
            row,
            segment,
            uv,
            throughput,
            direct,
            lit,
            env_sampled,
        })
    }

    /// The samples' transport onto a `width x height` env map.
    pub fn transport(&self, width: usize, height: usize) -> Transport {
        Transport::new(
            &self.segment,
            &self.uv,
            &self.throughput,
            self.hits.pixels.len(),
            width,
            height,
        )
    }
}

/// Pixels per chunk of the transport's construction and transposed sums.
pub(crate) const PIXEL_CHUNK: usize = 2048;

/// The pixels of chunk `chunk` of `pixels`.
#[inline]
pub(crate) fn pixel_chunk(chunk: usize, pixels: usize) -> std::ops::Range<usize> {
    chunk * PIXEL_CHUNK..((chunk + 1) * PIXEL_CHUNK).min(pixels)
}

impl Transport {
    /// The transport of light samples (`segments`, the map coordinates of
    /// their directions, throughputs) onto a `width x height` env map.
    pub fn new(
        segment: &[u32],
        uv: &[Vec2],
        throughput: &[[f32; 3]],
        pixels: usize,
        width: usize,
        height: usize,
    ) -> Self {
        assert!(
            width == 2 * height && height > 0,
            "Transport: env maps are 2:1, got {width}x{height}"
        );
        assert!(
            width * height <= MAX_TEXELS,
            "Transport: a {width}x{height} map has more than {MAX_TEXELS} texels"
        );
        // Samples grouped by pixel (a counting sort: passes append their
        // samples pixel by pixel), then each pixel's taps merged per texel
        // (`slot`: where a texel's weight is in `merged`), sorted by texel
        // and quantised; chunks of pixels in parallel, each into one
        // buffer (per-pixel buffers left the allocator holding hundreds of
        // MB). Merging before sorting sorts a row's texels, not its taps:
        // four per sample.
        let sample_start = key_starts(segment.iter().map(|&p| p as usize), pixels);
        let mut by_pixel = vec![0u32; segment.len()];
        let mut next = sample_start.clone();
        for (k, &p) in segment.iter().enumerate() {
            by_pixel[next[p as usize]] = k as u32;
            next[p as usize] += 1;
        }
        type Chunk = (Vec<usize>, Vec<f32>, Vec<Entry>);
        let chunks: Vec<Chunk> = (0..pixels.div_ceil(PIXEL_CHUNK))
            .into_par_iter()
            .map(|chunk| {
                let (mut lengths, mut quanta) = (Vec::with_capacity(PIXEL_CHUNK), Vec::with_capacity(PIXEL_CHUNK));
                let mut entries: Vec<Entry> = Vec::new();
                let mut merged: Vec<(u16, [f32; 3])> = Vec::new();
                let mut slot = vec![u32::MAX; width * height];
                for p in pixel_chunk(chunk, pixels) {
                    merged.clear();
                    // Each texel's weights add up in sample order.
                    for &k in &by_pixel[sample_start[p]..sample_start[p + 1]] {
                        // A sample the probe shadows reads no texel: no entries.
                        if throughput[k as usize] == [0.0; 3] {
                            continue;
                        }
                        let (texels, weights) = env_taps(uv[k as usize], width, height);
                        for (&index, &w) in texels.iter().zip(&weights) {
                            if w <= 0.0 {
                                continue;
                            }
                            let weight = throughput[k as usize].map(|c| c * w);
                            match slot[index as usize] {
                                u32::MAX => {
                                    slot[index as usize] = merged.len() as u32;
                                    merged.push((index as u16, weight));
                                }
                                at => {
                                    let (_, sum) = &mut merged[at as usize];
                                    (0..3).for_each(|c| sum[c] += weight[c]);
                                }
                            }
                        }
                    }
                    merged.iter().for_each(|&(index, _)| slot[index as usize] = u32::MAX);
                    merged.sort_unstable_by_key(|&(index, _)| index);
                    // A quantum of 1/65535 of the row's largest weight: a
                    // weight's rounding error is at most half of it, far
                    // below the Monte Carlo noise of the pixel's sum.
                    let largest = merged.iter().flat_map(|(_, w)| *w).fold(0.0f32, f32::max);
                    let quantum = largest / u16::MAX as f32;
                    let row_begin = entries.len();
                    if largest > 0.0 {
                        for &(index, w) in &merged {
                            let weight = w.map(|c| (c / quantum).round().min(u16::MAX as f32) as u16);
                            if weight != [0; 3] {
                                entries.push(Entry::new(index, weight));
                            }
                        }
                    }
                    lengths.push(entries.len() - row_begin);
                    quanta.push(quantum);
                }
                (lengths, quanta, entries)
            })
            .collect();
        let mut row_start = Vec::with_capacity(pixels + 1);
        row_start.push(0);
        let mut quantum = Vec::with_capacity(pixels);
        let mut rows = Vec::with_capacity(chunks.iter().map(|(_, _, e)| e.len()).sum());
        for (lengths, quanta, entries) in chunks {
            for length in lengths {
                row_start.push(row_start[row_start.len() - 1] + length);
            }
            quantum.extend_from_slice(&quanta);
            rows.extend_from_slice(&entries);
        }
        Transport {
            width,
            height,
            pixels,
            row_start,
            quantum,
            rows,
        }
    }

    /// The transports `parts` (of one map size) as one: their pixels one
    /// after another, in order. Several observations of one map -- a probe
    /// at several poses, several probes, several exposures -- solved as one.
    pub fn stacked(parts: &[&Transport]) -> Transport {
        let first = parts.first().expect("Transport::stacked: at least one transport");
        let (width, height) = (first.width, first.height);
        let mut row_start = vec![0];
        let (mut quantum, mut rows) = (Vec::new(), Vec::new());
        for part in parts {
            assert_eq!(
                (part.width, part.height),
                (width, height),
                "Transport::stacked: a {}x{} transport among {width}x{height} ones",
                part.width,
                part.height
            );
            let offset = rows.len();
            row_start.extend(part.row_start[1..].iter().map(|s| s + offset));
            quantum.extend_from_slice(&part.quantum);
            rows.extend_from_slice(&part.rows);
        }
        Transport {
            width,
            height,
            pixels: quantum.len(),
            row_start,
            quantum,
            rows,
        }
    }

    /// Number of env map values (texels x 3).
    pub fn unknowns(&self) -> usize {
        self.width * self.height * 3
    }

    /// The entries of pixel `p`'s row.
    #[inline]
    /// The texel pixel `p` reads most strongly (by the summed weight of its
    /// channels), if it reads any.
    pub fn strongest_texel(&self, p: usize) -> Option<usize> {
        self.row(p)
            .iter()
            .max_by_key(|e| e.lanes[..3].iter().map(|&q| q as u32).sum::<u32>())
            .map(Entry::index)
    }

    pub(crate) fn row(&self, p: usize) -> &[Entry] {
        &self.rows[self.row_start[p]..self.row_start[p + 1]]
    }

    /// Pixel `p`'s radiance under `env` (RGB and a 0 per texel: see
    /// [`lanes`]). Two sums, of the even and the odd entries: one would
    /// chain every multiply-add of the row on the one before.
    #[inline]
    pub(crate) fn render_pixel(&self, p: usize, env: &[[f64; 4]]) -> [f64; 3] {
        let (mut even, mut odd) = (F64x4::ZERO, F64x4::ZERO);
        let mut pairs = self.row(p).chunks_exact(2);
        for pair in &mut pairs {
            let (a, b) = (&pair[0], &pair[1]);
            even = even + F64x4::from_entry(a) * F64x4::load(&env[a.index()]);
            odd = odd + F64x4::from_entry(b) * F64x4::load(&env[b.index()]);
        }
        for e in pairs.remainder() {
            even = even + F64x4::from_entry(e) * F64x4::load(&env[e.index()]);
        }
        let sum = (even + odd).to_array();
        let quantum = self.quantum[p] as f64;
        std::array::from_fn(|c| sum[c] * quantum)
    }

    /// The pixels' radiance under `env` (texel-major RGB).
    pub fn apply(&self, env: &[f64], out: &mut [[f64; 3]]) {
        let env: Vec<_> = padded(env).collect();
        out.par_iter_mut()
            .enumerate()
            .for_each(|(p, px)| *px = self.render_pixel(p, &env));
    }

    /// `rendered = A env` and `grad += A^T r`, where `r_p =
    /// residual(p, rendered_p)` depends on pixel p's radiance alone (a
    /// least-squares gradient): one pass over the rows instead of two, each
    /// row still in cache when its residual goes back. The solve's every
    /// iteration needs both, and they are bound by memory traffic, which one
    /// pass halves. The transposed products sum per chunk of `PIXEL_CHUNK`
    /// pixels into `scratch` (reused from call to call), the chunks then in
    /// order: the same sums whatever the thread count. Rows, radiances and
    /// sums go four lanes at a time (`lanes`): a whole entry is converted,
    /// multiplied and added at once, with the same sums as plain arrays.
    pub fn apply_and_pull_back(
        &self,
        env: &[f64],
        residual: impl Fn(usize, [f64; 3]) -> [f64; 3] + Sync,
        rendered: &mut [[f64; 3]],
        grad: &mut [f64],
        scratch: &mut PullBackScratch,
    ) {
        let texels = self.width * self.height;
        scratch.env.clear();
        scratch.env.extend(padded(env));
        self.size_chunk_sums(&mut scratch.sums);
        let env = &scratch.env;
        scratch
            .sums
            .par_chunks_mut(texels)
            .zip(rendered.par_chunks_mut(PIXEL_CHUNK))
            .enumerate()
            .for_each(|(chunk, (sums, rendered))| {
                sums.fill([0.0; 4]);
                for (p, px) in pixel_chunk(chunk, self.pixels).zip(rendered) {
                    *px = self.render_pixel(p, env);
                    self.pull_back_pixel(p, residual(p, *px), sums);
                }
            });
        add_chunk_sums(&scratch.sums, texels, grad);
    }

    /// `grad += A^T r`: the pixels' RGB `r` (one per pixel) pulled back
    /// onto the map's texels (texel-major RGB), the transport's adjoint.
    pub fn pull_back(&self, r: &[[f64; 3]], grad: &mut [f64]) {
        self.pull_back_with(r, grad, &mut PullBackScratch::default());
    }

    /// [`pull_back`](Self::pull_back) summing per chunk of pixels into
    /// `scratch` (reused from call to call, as by
    /// [`apply_and_pull_back`](Self::apply_and_pull_back)).
    pub fn pull_back_with(&self, r: &[[f64; 3]], grad: &mut [f64], scratch: &mut PullBackScratch) {
        assert_eq!(r.len(), self.pixels, "Transport::pull_back: one RGB value a pixel");
        assert_eq!(
            grad.len(),
            self.unknowns(),
            "Transport::pull_back: one gradient a texel channel"
        );
        let texels = self.width * self.height;
        self.size_chunk_sums(&mut scratch.sums);
        scratch
            .sums
            .par_chunks_mut(texels)
            .enumerate()
            .for_each(|(chunk, sums)| {
                sums.fill([0.0; 4]);
                for p in pixel_chunk(chunk, self.pixels) {
                    self.pull_back_pixel(p, r[p], sums);
                }
            });
        add_chunk_sums(&scratch.sums, texels, grad);
    }

    /// Sums per chunk of pixels and texel, four lanes each, at their size
    /// (each chunk zeroes its own, in parallel: ten chunks of a 256x128
    /// map are 10 MB, which one thread would clear at every product).
    fn size_chunk_sums(&self, sums: &mut Vec<[f64; 4]>) {
        sums.resize(self.pixels.div_ceil(PIXEL_CHUNK) * self.width * self.height, [0.0; 4]);
    }

    /// Adds pixel `p`'s row times its RGB `r` into its chunk's `sums`.
    #[inline]
    fn pull_back_pixel(&self, p: usize, r: [f64; 3], sums: &mut [[f64; 4]]) {
        let quantum = self.quantum[p] as f64;
        let r = r.map(|r| r * quantum);
        let r = F64x4::load(&[r[0], r[1], r[2], 0.0]);
        for e in self.row(p) {
            let sum = &mut sums[e.index()];
            (F64x4::load(sum) + F64x4::from_entry(e) * r).store(sum);
        }
    }

    /// Per texel and channel (texel-major RGB), the sum over the entries
    /// of every pixel of `term(pixel, weight)`, the entry's weight in
    /// radiance units.
    pub(crate) fn texel_sums(&self, term: impl Fn(usize, [f64; 3]) -> [f64; 3] + Sync) -> Vec<f64> {
        let texels = self.width * self.height;
        let mut partial = vec![[0.0; 3]; self.pixels.div_ceil(PIXEL_CHUNK) * texels];
        partial.par_chunks_mut(texels).enumerate().for_each(|(chunk, sums)| {
            for p in pixel_chunk(chunk, self.pixels) {
                let quantum = self.quantum[p] as f64;
                for e in self.row(p) {
                    let t = term(p, e.quanta().map(|q| q * quantum));
                    (0..3).for_each(|c| sums[e.index()][c] += t[c]);
                }
            }
        });
        let mut total = vec![0.0; self.unknowns()];
        add_chunk_sums(&partial, texels, &mut total);
        total
    }

    /// Per texel and channel, `sum_p weight_pc a_ptc^2`: the data term's
    /// curvature along that unknown (texel-major RGB), each pixel weighted
    /// per channel.
    pub fn weighted_column_norms(&self, weight: &[[f64; 3]]) -> Vec<f64> {
        self.texel_sums(|p, w| std::array::from_fn(|c| weight[p][c] * w[c] * w[c]))
    }

    /// How strongly each texel reaches the pixels (the summed luminance of
    /// its weights), normalised to a maximum of 1: the paper's sampling
    /// frequency, our confidence map.
    pub fn confidence(&self) -> Vec<f32> {
        let freq: Vec<f64> = self
            .texel_sums(|_, w| [crate::colour::luminance(w), 0.0, 0.0])
            .into_iter()
            .step_by(3)
            .collect();
        let max = freq.iter().cloned().fold(0.0, f64::max).max(1e-30);
        freq.iter().map(|&f| (f / max) as f32).collect()
    }
}

/// The buffers of [`Transport::apply_and_pull_back`], kept from call to call.
#[derive(Default)]
pub struct PullBackScratch {
    /// The env map, four lanes per texel.
    pub(crate) env: Vec<[f64; 4]>,
    /// Per chunk of pixels, the transposed product's sums per texel.
    pub(crate) sums: Vec<[f64; 4]>,
}

/// A texel-major RGB map as four lanes per texel, the fourth 0.
#[inline]
pub(crate) fn padded(env: &[f64]) -> impl Iterator<Item = [f64; 4]> + '_ {
    env.as_chunks::<3>().0.iter().map(|t| [t[0], t[1], t[2], 0.0])
}

/// Adds the chunks' partial sums (`texels` each, in chunk order) to the
/// texel-major RGB `total` (the first three lanes of each).
pub(crate) fn add_chunk_sums<const LANES: usize>(partial: &[[f64; LANES]], texels: usize, total: &mut [f64]) {
    // Blocks of texels in parallel; each texel adds the chunks in order, as one thread would.
    total
        .par_chunks_mut(3 * TEXEL_BLOCK)
        .enumerate()
        .for_each(|(block, total)| {
            for sums in partial.chunks_exact(texels) {
                let sums = &sums[block * TEXEL_BLOCK..];
                for (t, s) in total.as_chunks_mut::<3>().0.iter_mut().zip(sums) {
                    (0..3).for_each(|c| t[c] += s[c]);
                }
            }
        });
}

/// Texels per block of [`add_chunk_sums`].
const TEXEL_BLOCK: usize = 4096;

/// `start[k]..start[k + 1]` is where the items of key k go when `keys`
/// (one per item, each below `count`) are sorted: a counting sort's offsets.
pub(crate) fn key_starts(keys: impl Iterator<Item = usize>, count: usize) -> Vec<usize> {
    let mut start = vec![0usize; count + 1];
    keys.for_each(|k| start[k + 1] += 1);
    for k in 0..count {
        start[k + 1] += start[k];
    }
    start
}

/// Four f64 lanes: a transport entry's RGB weight in quanta (its fourth
/// lane the texel index), a texel's RGB radiance or a pixel's RGB residual
/// (fourth lane 0, so that a product's fourth lane is 0). One AVX2
/// register where the machine has it: the solves' products convert,
/// multiply and add a whole entry at once. Elsewhere plain arrays, the
/// same operations in the same order, so both give the same sums.
mod lanes {
    use super::Entry;

    #[cfg(all(target_arch = "x86_64", target_feature = "avx2"))]
    mod simd {
        use super::Entry;
        use std::arch::x86_64::*;

        #[derive(Clone, Copy)]
        pub struct F64x4(__m256d);

        impl F64x4 {
            // SAFETY: an __m256d is four f64s, any bits valid.
            pub const ZERO: F64x4 = F64x4(unsafe { std::mem::transmute::<[f64; 4], __m256d>([0.0; 4]) });

            #[inline]
            pub fn from_entry(e: &Entry) -> Self {
                // SAFETY: an entry is 8 bytes: one 64-bit load; the build
                // enables AVX2 (and so SSE4.1), which this module's cfg requires.
                F64x4(unsafe { _mm256_cvtepi32_pd(_mm_cvtepu16_epi32(_mm_loadl_epi64(e.lanes.as_ptr().cast()))) })
            }

            #[inline]
            pub fn load(a: &[f64; 4]) -> Self {
                // SAFETY: four f64s.
                F64x4(unsafe { _mm256_loadu_pd(a.as_ptr()) })
            }

            #[inline]
            pub fn store(self, a: &mut [f64; 4]) {
                // SAFETY: four f64s.
                unsafe { _mm256_storeu_pd(a.as_mut_ptr(), self.0) }
            }

            #[inline]
            pub fn to_array(self) -> [f64; 4] {
                let mut a = [0.0; 4];
                self.store(&mut a);
                a
            }
        }

        impl std::ops::Add for F64x4 {
            type Output = Self;
            #[inline]
            fn add(self, o: Self) -> Self {
                // SAFETY: the build enables AVX (this module's cfg).
                F64x4(unsafe { _mm256_add_pd(self.0, o.0) })
            }
        }

        impl std::ops::Mul for F64x4 {
            type Output = Self;
            #[inline]
            fn mul(self, o: Self) -> Self {
                // SAFETY: the build enables AVX (this module's cfg).
                F64x4(unsafe { _mm256_mul_pd(self.0, o.0) })
            }
        }
    }

    #[cfg(not(all(target_arch = "x86_64", target_feature = "avx2")))]
    mod simd {
        use super::Entry;

        #[derive(Clone, Copy)]
        pub struct F64x4([f64; 4]);

        impl F64x4 {
            pub const ZERO: F64x4 = F64x4([0.0; 4]);

            #[inline]
            pub fn from_entry(e: &Entry) -> Self {
                F64x4(e.lanes.map(|q| q as f64))
            }

            #[inline]
            pub fn load(a: &[f64; 4]) -> Self {
                F64x4(*a)
            }

            #[inline]
            pub fn store(self, a: &mut [f64; 4]) {
                *a = self.0;
            }

            #[inline]
            pub fn to_array(self) -> [f64; 4] {
                self.0
            }
        }

        impl std::ops::Add for F64x4 {
            type Output = Self;
            #[inline]
            fn add(self, o: Self) -> Self {
                F64x4(std::array::from_fn(|k| self.0[k] + o.0[k]))
            }
        }

        impl std::ops::Mul for F64x4 {
            type Output = Self;
            #[inline]
            fn mul(self, o: Self) -> Self {
                F64x4(std::array::from_fn(|k| self.0[k] * o.0[k]))
            }
        }
    }

    pub use simd::F64x4;
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::envmap::{EnvMap, uv_to_direction};

    #[test]
    fn a_stack_of_transports_renders_each_one_s_pixels_and_pulls_back_their_sum() {
        let (w, h) = (16, 8);
        let env: Vec<f64> = (0..w * h * 3).map(|i| 0.2 + ((i * 37) % 11) as f64 * 0.1).collect();
        let part = |pixels: usize, shift: f32| {
            let (mut segment, mut uv, mut throughput) = (Vec::new(), Vec::new(), Vec::new());
            for k in 0..40u32 {
                segment.push(k % pixels as u32);
                uv.push(Vec2::new(
                    (k as f32 * 0.137 + shift).fract(),
                    (k as f32 * 0.291).fract(),
                ));
                throughput.push([0.5 + 0.01 * k as f32, 0.3, 0.1 + shift]);
            }
            Transport::new(&segment, &uv, &throughput, pixels, w, h)
        };
        let (a, b) = (part(5, 0.0), part(3, 0.4));
        let stacked = Transport::stacked(&[&a, &b]);
        assert_eq!(stacked.pixels, 8);
        let render = |t: &Transport| {
            let mut out = vec![[0.0; 3]; t.pixels];
            t.apply(&env, &mut out);
            out
        };
        let mut want = render(&a);
        want.extend(render(&b));
        assert_eq!(render(&stacked), want);
        let residual: Vec<[f64; 3]> = (0..8).map(|p| [p as f64 - 2.0, 0.5, 1.0 / (p as f64 + 1.0)]).collect();
        let pulled = |t: &Transport, r: &[[f64; 3]]| {
            let mut grad = vec![0.0; t.unknowns()];
            t.pull_back(r, &mut grad);
            grad
        };
        let (ga, gb) = (pulled(&a, &residual[..5]), pulled(&b, &residual[5..]));
        for ((s, x), y) in pulled(&stacked, &residual).iter().zip(&ga).zip(&gb) {
            assert!((s - (x + y)).abs() < 1e-12 * (1.0 + s.abs()), "{s} against {x} + {y}");
        }
    }

    #[test]
    fn the_transport_renders_what_the_samples_read_and_its_transpose_is_its_adjoint() {
        let (w, h, pixels) = (16, 8, 5);
        let env: Vec<f64> = (0..w * h * 3).map(|i| 0.2 + ((i * 37) % 11) as f64 * 0.1).collect();
        let texels: Vec<[f32; 3]> = env
            .chunks_exact(3)
            .map(|t| [t[0] as f32, t[1] as f32, t[2] as f32])
            .collect();
        let map = EnvMap::new(w, h, texels).expect("env");
        // Several samples per pixel, some reading the same texels (merged).
        let (mut segment, mut uv, mut throughput) = (Vec::new(), Vec::new(), Vec::new());
        for k in 0..60u32 {
            segment.push(k % pixels as u32);
            uv.push(Vec2::new((k as f32 * 0.137).fract(), (k as f32 * 0.291).fract()));
            throughput.push([0.5 + 0.01 * k as f32, 0.3, 0.1]);
        }
        let transport = Transport::new(&segment, &uv, &throughput, pixels, w, h);
        let mut rendered = vec![[0.0; 3]; pixels];
        transport.apply(&env, &mut rendered);
        let mut want = vec![[0.0f64; 3]; pixels];
        for ((&p, &uv), t) in segment.iter().zip(&uv).zip(&throughput) {
            let l = map.lookup(uv_to_direction(uv));
            (0..3).for_each(|c| want[p as usize][c] += (t[c] * l[c]) as f64);
        }
        for (a, b) in rendered.iter().zip(&want) {
            for c in 0..3 {
                assert!((a[c] - b[c]).abs() < 1e-3 * b[c].abs().max(1.0), "{a:?} vs {b:?}");
            }
        }
        let residual: Vec<[f64; 3]> = (0..pixels)
            .map(|p| [p as f64 - 2.0, 0.5, 1.0 / (p as f64 + 1.0)])
            .collect();
        // The fused pass renders the same and pulls the residual back.
        let (mut fused, mut grad) = (vec![[0.0; 3]; pixels], vec![0.0; transport.unknowns()]);
        transport.apply_and_pull_back(
            &env,
            |p, _| residual[p],
            &mut fused,
            &mut grad,
            &mut PullBackScratch::default(),
        );
        assert_eq!(fused, rendered);
        let lhs: f64 = rendered
            .iter()
            .zip(&residual)
            .map(|(a, r)| (0..3).map(|c| a[c] * r[c]).sum::<f64>())
            .sum();
        let rhs: f64 = env.iter().zip(&grad).map(|(x, g)| x * g).sum();
        assert!(
            (lhs - rhs).abs() < 1e-9 * lhs.abs().max(1.0),
            "<Ax, r> {lhs} vs <x, A^T r> {rhs}"
        );
    }

    #[test]
    fn quantised_weights_keep_every_pixel_s_radiance_whatever_its_scale() {
        // Pixels whose throughputs differ by 1e8 from one to the next, each
        // reading taps whose weights span six orders of magnitude: every
        // pixel keeps its radiance to a part in 10^4 (a quantum is relative
        // to its own row's largest weight, not to the transport's).
        let (w, h, pixels) = (32, 16, 4);
        let env: Vec<f64> = (0..w * h * 3).map(|i| 0.2 + ((i * 53) % 17) as f64 * 0.1).collect();
        let (mut segment, mut uv, mut throughput) = (Vec::new(), Vec::new(), Vec::new());
        for k in 0..400u32 {
            let p = k % pixels as u32;
            segment.push(p);
            uv.push(Vec2::new((k as f32 * 0.1371).fract(), (k as f32 * 0.2911).fract()));
            let t = 1e-4 * 1e8f32.powi(p as i32) * 10f32.powi((k % 7) as i32 - 3);
            throughput.push([t, 0.5 * t, 0.25 * t]);
        }
        let transport = Transport::new(&segment, &uv, &throughput, pixels, w, h);
        let mut rendered = vec![[0.0; 3]; pixels];
        transport.apply(&env, &mut rendered);
        let mut exact = vec![[0.0f64; 3]; pixels];
        for ((&p, &uv), t) in segment.iter().zip(&uv).zip(&throughput) {
            let (texels, weights) = env_taps(uv, w, h);
            for (&texel, &wt) in texels.iter().zip(&weights) {
                (0..3).for_each(|c| exact[p as usize][c] += t[c] as f64 * wt as f64 * env[texel as usize * 3 + c]);
            }
        }
        for (a, b) in rendered.iter().zip(&exact) {
            for c in 0..3 {
                assert!((a[c] - b[c]).abs() <= 1e-4 * b[c], "{a:?} vs {b:?}");
            }
        }
    }

    #[test]
    #[should_panic(expected = "more than 65536 texels")]
    fn a_map_beyond_the_texel_limit_is_refused() {
        Transport::new(&[0], &[Vec2::splat(0.5)], &[[1.0; 3]], 1, 512, 256);
    }

    #[test]
    fn renders_and_transposed_sums_do_not_depend_on_the_thread_count() {
        let (w, h) = (16, 8);
        // More pixels than one chunk holds, each reading several texels.
        let pixels = 2 * PIXEL_CHUNK + 77;
        let (mut segment, mut uv, mut throughput) = (Vec::new(), Vec::new(), Vec::new());
        for k in 0..4 * pixels as u32 {
            segment.push(k / 4);
            uv.push(Vec2::new((k as f32 * 0.1373).fract(), (k as f32 * 0.2917).fract()));
            throughput.push([0.1 + (k % 13) as f32 * 0.37, 0.3, 1e-3 * k as f32]);
        }
        let transport = Transport::new(&segment, &uv, &throughput, pixels, w, h);
        let residual: Vec<[f64; 3]> = (0..pixels).map(|p| [(p as f64).sin(), 1e-7 * p as f64, 3.0]).collect();
        let env: Vec<f64> = (0..w * h * 3).map(|i| 0.1 + (i % 7) as f64).collect();
        let transposed = |threads: usize| {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .expect("pool");
            pool.install(|| {
                let (mut rendered, mut grad) = (vec![[0.0; 3]; pixels], vec![0.0; transport.unknowns()]);
                // The residual depends on the rendered pixel, as a solve's does.
                let pulled = |p: usize, px: [f64; 3]| std::array::from_fn(|c| px[c] - residual[p][c]);
                transport.apply_and_pull_back(&env, pulled, &mut rendered, &mut grad, &mut PullBackScratch::default());
                (rendered, grad)
            })
        };
        assert_eq!(transposed(1), transposed(3));
    }
}
