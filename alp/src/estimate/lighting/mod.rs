//! The lighting stage at a fixed pose. The rendered image is linear in the
//! environment map: light samples traced once at the pose record which
//! texels each pixel reads with which weight ([`render::transport`]), and the
//! map minimises the lighting terms ([`phase`]): by default the regularised,
//! non-negative least-squares solution ([`least_squares`]), coarse to fine.
//! What the fit is for sets the pixels' weights (`LightingPurpose`); the
//! output map's fit leaves out pixels on the probe's reflectance edges and
//! weighs each by the share of its light the model follows.

pub mod clipped;
pub mod least_squares;
pub mod phase;

use std::collections::BTreeMap;
use std::sync::Arc;
use std::time::Instant;

use optim::Termination;
use render::colour::luminance;
use render::envmap::{EnvMap, resample};
use render::image_io::RgbImage;
use render::integrator::{LightSampling, PrimaryHits, RenderSettings};
use render::pose::Pose;
use render::probe::ProbeAsset;
use render::sampling::EnvSampler;

pub use clipped::{ClippedLight, PowerTold};
pub use least_squares::{LightingSolve, Solved, pyramid, solve};
pub use phase::LightingTerms;
pub use render::transport::{MAX_TEXELS, SampleRecord, Transport};

use super::Probe;
use super::photo::{Photo, Pixels, on_probe};
use super::report::{PhaseReport, resident_mb};
use super::settings::{LightingSettings, Settings};
use crate::error::{Error, Result};
use crate::objective::{DARK_FRACTION, DataTerm, mask_mean_luminance};
use phase::{Level, TapeScene};

/// What a lighting fit is for.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum LightingPurpose {
    /// Explaining the photo while the pose is searched: relative errors
    /// everywhere (the probe's colour pattern counts in dark and bright
    /// regions alike) and plain smoothness.
    Search,
    /// The output map: relative errors below the photo's mean level in the
    /// mask, absolute above it (a dark region's error counts by its colour,
    /// which a mirror shows; a highlight's by its energy, which shades
    /// diffuse and shiny objects: purely relative weights let a bright
    /// light's energy go), and smoothness relative to the local radiance
    /// level. Where the weights turn absolute trades the mirror against the
    /// other spheres; see docs/results/decisions.md 5, Lighting solve.
    Output,
}

/// The lighting at `pose`: primary hits, the light transport onto a
/// `width x height` map, the solved map (texel-major RGB), the rendered
/// pixels and the data term's targets and weights.
pub(super) struct LightingFit {
    pub(super) hits: PrimaryHits,
    pub(super) transport: Arc<Transport>,
    pub(super) env: Vec<f64>,
    pub(super) rendered: Vec<[f64; 3]>,
    pub(super) data: Arc<DataTerm>,
    pub(super) evaluations: usize,
    /// Why the (finest level's) solve stopped.
    pub(super) termination: Option<Termination>,
    /// Each lighting term's value at the map, when asked for
    /// ([`FitRequest::term_values`]).
    pub(super) term_values: BTreeMap<String, f64>,
    /// Each unknown's standard deviation ([`LightingTerms::account`]),
    /// asked for with the term values.
    pub(super) sigma: Vec<f64>,
}

impl LightingFit {
    /// The re-render's PSNR over the data pixels.
    pub(super) fn psnr_db(&self) -> f64 {
        psnr(&self.rendered, &self.data)
    }

    /// The solved map, the rest dropped.
    pub(super) fn into_map(self) -> Vec<f64> {
        self.env
    }

    /// The solve's data term per data pixel and channel: the weighted
    /// squared error over the pixels of non-zero weight (with the search's
    /// weights, the mean relative squared error).
    pub(super) fn weighted_sq_error(&self) -> f64 {
        mean_weighted_sq_error(&self.rendered, &self.data)
    }

    /// The solved map, the sampling confidence (grey) and the map's
    /// uncertainty (each deviation times `LightingSettings::uncertainty_scale`,
    /// box filtered as the map is) at the output size `out`, from the
    /// working size `work`.
    pub(super) fn output_maps(
        &self,
        work: (usize, usize),
        out: (usize, usize),
        lighting: &LightingSettings,
    ) -> Result<OutputMaps> {
        let confidence: Vec<f64> = self
            .transport
            .confidence()
            .iter()
            .flat_map(|&c| [c as f64; 3])
            .collect();
        let sigma: Vec<f64> = self.sigma.iter().map(|s| s * lighting.uncertainty_scale).collect();
        Ok(OutputMaps {
            env: output_map(&self.env, work, out)?,
            confidence: output_map(&confidence, work, out)?,
            uncertainty: output_map(&sigma, work, out)?,
        })
    }

    /// The re-render at the photo's size: the fit's pixels, the rest zero.
    pub(super) fn rerender(&self) -> RgbImage {
        let channels: [Vec<f64>; 3] = std::array::from_fn(|c| self.rendered.iter().map(|p| p[c]).collect());
        self.hits.to_image([&channels[0], &channels[1], &channels[2]])
    }
}

/// The maps an estimate writes.
pub(super) struct OutputMaps {
    /// The env map.
    pub(super) env: EnvMap,
    /// The sampling confidence, grey.
    pub(super) confidence: EnvMap,
    /// The standard deviation of each texel and channel.
    pub(super) uncertainty: EnvMap,
}

/// The env map sizes (width, height) of an estimate: the output map's solve
/// works at `work`, which the probe's sharpest lobe sets; the pose searches
/// at `search`, at most `LightingSettings::search_height` rows.
pub(super) struct MapSizes {
    /// The probe's smallest roughness, which sets `work`.
    pub(super) min_roughness: f32,
    pub(super) work: (usize, usize),
    pub(super) search: (usize, usize),
}

impl MapSizes {
    /// The sizes for `asset`: its working height as set, or (None) from its
    /// roughness.
    pub(super) fn new(asset: &ProbeAsset, lighting: &LightingSettings) -> Result<Self> {
        let min_roughness = asset.roughness.image.pixels.iter().map(|p| p[0]).fold(1.0f32, f32::min);
        let work_h = lighting.working_height.unwrap_or_else(|| working_height(min_roughness));
        if work_h == 0 || 2 * work_h * work_h > MAX_TEXELS {
            return Err(Error::invalid(
                "working height",
                format!(
                    "{work_h} rows: a working map has 1 to {} rows",
                    (MAX_TEXELS as f64 / 2.0).sqrt() as usize
                ),
            ));
        }
        let search_h = work_h.min(lighting.search_height);
        Ok(MapSizes {
            min_roughness,
            work: (2 * work_h, work_h),
            search: (2 * search_h, search_h),
        })
    }
}

/// What the output map's solve starts from and minimises.
pub(super) struct OutputSolve<'a> {
    /// The kept pose's map at the search size: it guides the light samples
    /// (MIS) and starts the solve.
    pub(super) pilot: Option<&'a [f64]>,
    /// The objective's lighting terms.
    pub(super) terms: &'a LightingTerms,
}

/// The output map's fit at `poses` (the found pose first, each with its
/// share: [`fit_lighting_over`]): at `Settings::spp_final` shared among
/// them, minimising `output`'s terms from its pilot map. The transport is
/// `LightingSettings::model`'s (by default one bounce of inter-reflection:
/// a can's lid sees its rim, which reflects the sky). Returns the fit and
/// its samples per pixel at each pose.
pub(super) fn final_fit(
    probe: &Probe,
    photo: &Photo,
    clipped: &[bool],
    poses: &[(Pose, f64)],
    OutputSolve { pilot, terms }: OutputSolve,
    sizes: &MapSizes,
    settings: &Settings,
) -> Result<(LightingFit, u32)> {
    let search = sizes.search;
    let sampler = pilot
        .map(|texels| env_from_texels(texels, search.0, search.1).map(|map| EnvSampler::new(&map)))
        .transpose()?;
    let start = pilot.map(|texels| resample(texels, search, sizes.work));
    let sampling = settings.lighting.model.sampling(sampler.as_ref());
    let spp = settings
        .lighting
        .final_spp(settings.lighting.spp_final, photo.mask.count(), sampling.strategies())
        .div_ceil(poses.len() as u32);
    let render = RenderSettings {
        spp,
        seed: settings.seed.wrapping_add(77),
    };
    let fit = fit_lighting_over(
        probe,
        photo,
        clipped,
        poses,
        &FitRequest {
            size: sizes.work,
            render,
            sampling,
            terms,
            purpose: LightingPurpose::Output,
            pixels: Pixels::All,
            start: start.as_deref(),
            max_iters: settings.lighting.solve_iters,
            term_values: true,
        },
        &settings.lighting,
    )?;
    Ok((fit, spp))
}

/// What a lighting fit solves for, besides the pose.
pub(super) struct FitRequest<'a> {
    /// The map's size (width, height).
    pub(super) size: (usize, usize),
    /// Samples per pixel and seed of the light samples.
    pub(super) render: RenderSettings,
    /// How the light samples pick their directions.
    pub(super) sampling: LightSampling<'a>,
    /// What the map minimises.
    pub(super) terms: &'a LightingTerms,
    pub(super) purpose: LightingPurpose,
    pub(super) pixels: Pixels,
    /// The map to start from (None: coarse to fine from a constant map).
    pub(super) start: Option<&'a [f64]>,
    /// L-BFGS iterations at most (of the finest level).
    pub(super) max_iters: usize,
    /// Whether to evaluate each term at the solved map (for the report).
    pub(super) term_values: bool,
}

/// Whether a fit for the output map reads the pixels on the probe's
/// reflectance edges ([`albedo_edges`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Edges {
    /// Left out: a pose a fraction of a pixel off would bake the probe's
    /// colours into the map.
    LeftOut,
    /// Read: where a photo's blur shows most.
    Read,
}

/// The light samples `request` asks for at `pose`, traced on its pixels,
/// and the data term over them: for the output map each pixel weighed by
/// the square of the share of its light the model follows, and the
/// reflectance edges as `edges` says.
pub(super) fn weighed_samples(
    probe: &Probe,
    photo: &Photo,
    clipped: &[bool],
    pose: &Pose,
    request: &FitRequest,
    lighting: &LightingSettings,
    edges: Edges,
) -> Result<(SampleRecord, DataTerm)> {
    let (settings, sampling, pixels) = (&request.render, &request.sampling, request.pixels);
    // Light samples in passes: memory stays that of one pass however many
    // samples the transport gathers (with MIS a hit has two).
    let passes = settings
        .spp
        .div_ceil(lighting.spp_per_pass(sampling.strategies() * photo.mask.count()))
        .max(1);
    let camera = &photo.camera;
    let keep = |p: u32| pixels.keeps(p, camera.width);
    let record = SampleRecord::trace(probe.asset, probe.bsdf, pose, camera, settings, sampling, passes, keep)?;
    let mut data = pixel_targets(photo, &record.hits, clipped, request.purpose, lighting)?;
    if request.purpose == LightingPurpose::Output {
        let r = &record;
        let shares = LitShares::new(&r.segment, &r.direct, &r.lit, &r.env_sampled, r.hits.pixels.len());
        if edges == Edges::LeftOut {
            let on_edge = albedo_edges(r, &shares.direct, pixels, lighting);
            data.weight
                .iter_mut()
                .zip(&on_edge)
                .filter(|(_, e)| **e)
                .for_each(|(w, _)| *w = [0.0; 3]);
        }
        data.weight
            .iter_mut()
            .zip(&shares.followed)
            .for_each(|(w, f)| w.iter_mut().for_each(|w| *w *= f * f));
    }
    Ok((record, data))
}

/// The map `env` (of `request.size`) judged on the pixels `request` asks
/// for at `pose`, the probe's reflectance edges read: per pixel read, its
/// index in the photo and its weighted squared error summed over the
/// channels (the data term's weights: relative errors, whatever the
/// photo's exposure). The error is the product of two renders' residuals
/// from independent light samples, `w (a - t)(b - t)`, whose expectation
/// is the squared error of the expected render: one render's own square
/// would add its Monte Carlo variance, which differs from model to model
/// (a blurred camera's rays spread over a pixel's neighbours).
pub(super) fn pixel_errors(
    probe: &Probe,
    photo: &Photo,
    clipped: &[bool],
    pose: &Pose,
    request: &FitRequest,
    env: &[f64],
    lighting: &LightingSettings,
) -> Result<Vec<(u32, f64)>> {
    let residuals = |seed: u64| -> Result<BTreeMap<u32, [f64; 3]>> {
        let request = FitRequest {
            render: RenderSettings { seed, ..request.render },
            ..*request
        };
        let (record, data) = weighed_samples(probe, photo, clipped, pose, &request, lighting, Edges::Read)?;
        let transport = record.transport(request.size.0, request.size.1);
        let mut rendered = vec![[0.0; 3]; record.hits.pixels.len()];
        transport.apply(env, &mut rendered);
        Ok((record.hits.pixels.iter().enumerate())
            .filter(|&(k, _)| data.used(k))
            .map(|(k, &p)| {
                let w = data.weight[k];
                (
                    p,
                    std::array::from_fn(|c| w[c].sqrt() * data.residual(k, c, rendered[k][c])),
                )
            })
            .collect())
    };
    let a = residuals(request.render.seed)?;
    let b = residuals(request.render.seed.wrapping_add(1 << 20))?;
    Ok((a.iter())
        .filter_map(|(p, ra)| b.get(p).map(|rb| (*p, (0..3).map(|c| ra[c] * rb[c]).sum())))
        .collect())
}

/// The lighting at `pose` that `request` asks for: light samples traced,
/// their transport recorded, the map solved.
pub(super) fn fit_lighting(
    probe: &Probe,
    photo: &Photo,
    clipped: &[bool],
    pose: &Pose,
    request: &FitRequest,
    lighting: &LightingSettings,
) -> Result<LightingFit> {
    fit_lighting_over(probe, photo, clipped, &[(*pose, 1.0)], request, lighting)
}

/// The lighting that explains the photo at each of `poses` at once (each
/// with its share of the data term, the shares summing to 1): each pose's
/// light samples traced (its own seed past `request`'s, the first's
/// `request`'s own), their transports stacked into one solve of one map.
/// Poses the photo cannot tell apart so soften the map where they disagree
/// rather than warp it to one of them. The fit's pixels, transport and
/// data are the first pose's.
pub(super) fn fit_lighting_over(
    probe: &Probe,
    photo: &Photo,
    clipped: &[bool],
    poses: &[(Pose, f64)],
    request: &FitRequest,
    lighting: &LightingSettings,
) -> Result<LightingFit> {
    let FitRequest {
        size,
        render: ref settings,
        terms,
        purpose,
        start,
        max_iters,
        term_values,
        ..
    } = *request;
    let observations: Vec<(SampleRecord, DataTerm)> = (poses.iter().enumerate())
        .map(|(k, (pose, _))| {
            let request = FitRequest {
                render: RenderSettings {
                    seed: settings.seed.wrapping_add((k as u64) << 40),
                    ..*settings
                },
                ..*request
            };
            weighed_samples(probe, photo, clipped, pose, &request, lighting, Edges::LeftOut)
        })
        .collect::<Result<_>>()?;
    let pixels: Vec<u32> = observations
        .iter()
        .flat_map(|(r, _)| r.hits.pixels.iter().copied())
        .collect();
    let scene = TapeScene::new(photo, &poses[0].0, &pixels, settings.seed);
    let data = Arc::new(stacked_data(&observations, poses));
    let solve_settings = LightingSolve {
        relative_smoothness: purpose == LightingPurpose::Output,
        floor_of_level: match purpose {
            LightingPurpose::Output => lighting.floor_of_level,
            LightingPurpose::Search => 0.0,
        },
        clipped_light_share: lighting.clipped_light_share,
        max_iters,
        method: lighting.method,
    };
    let at = |(w, h): (usize, usize)| match &observations[..] {
        [(record, _)] => Arc::new(record.transport(w, h)),
        several => {
            let parts: Vec<Transport> = several.iter().map(|(r, _)| r.transport(w, h)).collect();
            Arc::new(Transport::stacked(&parts.iter().collect::<Vec<_>>()))
        }
    };
    // The finest level's start, which also sets its smoothness's levels.
    let (transport, solved, finest_start) = match start {
        Some(x0) => {
            let transport = at(size);
            let level = Level {
                transport: &transport,
                data: &data,
                settings: solve_settings,
                start: x0,
            };
            let solved = terms.solve(&level, &scene)?;
            (transport, solved, x0.to_vec())
        }
        None => {
            // Coarse to fine from a constant map at the photo's mean level:
            // each level starts from the one below, which also sets the
            // local radiance level its smoothness is relative to.
            let wsum: f64 = data.weight.iter().flatten().sum::<f64>().max(1e-30);
            let mean = data
                .target
                .iter()
                .zip(&data.weight)
                .map(|(t, w)| (0..3).map(|c| w[c] * t[c]).sum::<f64>())
                .sum::<f64>()
                / wsum;
            let levels = pyramid(size, lighting.coarsest_height);
            let mut solved = Solved {
                env: vec![mean.max(1e-6); levels[0].0 * levels[0].1 * 3],
                evaluations: 0,
                termination: None,
            };
            let (mut evaluations, mut previous) = (0, levels[0]);
            let (mut transport, mut finest_start) = (None, Vec::new());
            let finest = *levels.last().expect("at least one level");
            for level in levels {
                let x0 = resample(&solved.env, previous, level);
                // The coarser level's transport goes before this one is built.
                drop(transport.take());
                let t = at(level);
                // A coarser level only starts the next one.
                let level_settings = LightingSolve {
                    max_iters: match level == finest {
                        true => solve_settings.max_iters,
                        false => lighting.coarse_level_iters,
                    },
                    ..solve_settings
                };
                let at_level = Level {
                    transport: &t,
                    data: &data,
                    settings: level_settings,
                    start: &x0,
                };
                let level_solved = terms.solve(&at_level, &scene)?;
                (solved, previous, transport, finest_start) = (level_solved, level, Some(t), x0);
                evaluations += solved.evaluations;
            }
            solved.evaluations = evaluations;
            (transport.expect("at least one level"), solved, finest_start)
        }
    };
    let Solved {
        env,
        evaluations,
        termination,
    } = solved;
    let mut rendered = vec![[0.0; 3]; transport.pixels];
    transport.apply(&env, &mut rendered);
    let (term_values, sigma) = match term_values {
        true => {
            let level = Level {
                transport: &transport,
                data: &data,
                settings: solve_settings,
                start: &finest_start,
            };
            let account = terms.account(&level, &env, &rendered, &scene)?;
            (account.values, account.sigma)
        }
        false => (BTreeMap::new(), Vec::new()),
    };
    // The first pose's pixels, transport and data are the fit's.
    let (record, first_data) = observations.into_iter().next().expect("at least one pose");
    let (transport, rendered, data) = match poses.len() {
        1 => (transport, rendered, data),
        _ => {
            let first = Arc::new(record.transport(size.0, size.1));
            let mut rendered = vec![[0.0; 3]; first.pixels];
            first.apply(&env, &mut rendered);
            (first, rendered, Arc::new(first_data))
        }
    };
    Ok(LightingFit {
        hits: record.hits,
        transport,
        env,
        rendered,
        data,
        evaluations,
        termination,
        term_values,
        sigma,
    })
}

/// The observations' data terms one after another, each pixel's weights
/// times its pose's share.
fn stacked_data(observations: &[(SampleRecord, DataTerm)], poses: &[(Pose, f64)]) -> DataTerm {
    if let [(_, data)] = observations {
        return data.clone();
    }
    let mut stacked = DataTerm::default();
    for ((_, data), (_, share)) in observations.iter().zip(poses) {
        stacked.target.extend_from_slice(&data.target);
        stacked.weight.extend(data.weight.iter().map(|w| w.map(|w| w * share)));
        stacked.at_least.extend_from_slice(&data.at_least);
        stacked.tolerance.extend_from_slice(&data.tolerance);
    }
    stacked
}

/// The data term for `purpose`, aligned with `hits.pixels`: each pixel's
/// radiance, its weight per channel, and whether it is a lower bound. A
/// weight is the inverse square of the pixel's level (plus a dark floor):
/// by its luminance for the searches, by each channel's own value (capped
/// at the mask's mean level) for the output map -- a photo's error grows
/// with its level per channel, so a red label's dim green and blue are
/// measured as closely, in proportion, as its bright red, and count as
/// much. Zero outside the mask and on partly covered pixels. A clipped
/// pixel is left out of the searches; the output map reads it as a lower
/// bound (the light it reflects is at least the clipping level: how far
/// a sun's highlight stays clipped tells how bright the sun is).
pub(super) fn pixel_targets(
    photo: &Photo,
    hits: &PrimaryHits,
    clipped: &[bool],
    purpose: LightingPurpose,
    lighting: &LightingSettings,
) -> Result<DataTerm> {
    // The relative L1 term's scale (objective::RgbL1), squared for least squares.
    let level = mask_mean_luminance(&photo.image, &photo.mask)?;
    let eps = DARK_FRACTION * level;
    let cap = match purpose {
        LightingPurpose::Search => f64::INFINITY,
        LightingPurpose::Output => level,
    };
    // An sRGB photo's levels add their own noise: a JPEG's rounding of its
    // coefficients moves a value by about `srgb_noise_levels` levels.
    let noise = |v: f64| lighting.srgb_noise_levels * photo.level_step(v);
    let relative = |v: f64| 1.0 / ((v.min(cap) + eps).powi(2) + noise(v).powi(2));
    let mut data = DataTerm::default();
    for (&p, &c) in hits.pixels.iter().zip(&hits.coverage) {
        let px = photo.image.pixels[p as usize].map(|v| v as f64);
        let at_least = clipped[p as usize];
        let w = match (purpose, at_least) {
            (LightingPurpose::Search, true) => [0.0; 3],
            _ if !on_probe(c) => [0.0; 3],
            (LightingPurpose::Search, false) => [relative(luminance(px)); 3],
            (LightingPurpose::Output, _) => px.map(relative),
        };
        data.target.push(px);
        data.weight.push(w);
        data.at_least.push(at_least);
        data.tolerance.push(px.map(|v| 0.5 * photo.level_step(v)));
    }
    Ok(data)
}

/// Pixels on an edge of the probe's reflectance (its albedo or roughness
/// changes between the pixel and a neighbour the fit reads: their directional
/// albedos, their `direct` samples' summed throughputs over their `lit`
/// shares (the probe's shadow taken out), differ by more than
/// `LightingSettings::edge_contrast`): a pose off by a fraction of a pixel puts the photo's
/// edge elsewhere, and the output map would take the probe's colours in (a
/// label's red in the sky). An edge of a shadow is none: it moves with the pose smoothly, as
/// the shading does, and counting it would leave out the sky that only the
/// pixels along the probe's own shadows see. `lit` is each pixel's share of
/// direct samples that reach the map.
pub(super) fn albedo_edges(
    record: &SampleRecord,
    lit: &[f64],
    pixels: Pixels,
    lighting: &LightingSettings,
) -> Vec<bool> {
    let SampleRecord {
        hits,
        row,
        segment,
        throughput,
        direct,
        ..
    } = record;
    let mut albedo = vec![[0.0f64; 3]; hits.pixels.len()];
    for ((&s, t), d) in segment.iter().zip(throughput).zip(direct) {
        if *d {
            (0..3).for_each(|c| albedo[s as usize][c] += t[c] as f64);
        }
    }
    // A pixel in full shadow tells nothing of its albedo: no edge there.
    albedo.iter_mut().zip(lit).for_each(|(a, &f)| match f > 0.0 {
        true => a.iter_mut().for_each(|v| *v /= f),
        false => *a = [f64::NAN; 3],
    });
    let contrast = |a: [f64; 3], b: [f64; 3]| {
        let d: f64 = (0..3).map(|c| (a[c] - b[c]).abs()).sum();
        d / (a.iter().sum::<f64>() + b.iter().sum::<f64>()).max(1e-30)
    };
    hits.pixels
        .iter()
        .enumerate()
        .map(|(k, &p)| {
            pixels
                .neighbours(p as usize, hits.width, hits.height)
                .into_iter()
                .flatten()
                .any(|q| {
                    let r = row[q];
                    r != u32::MAX && contrast(albedo[k], albedo[r as usize]) > lighting.edge_contrast
                })
        })
        .collect()
}

/// Per pixel, the shares of its BRDF samples that reach the env map (the
/// env map's samples, with MIS, go where its light is, not where the lobe
/// is). Where the probe shadows a pixel's lobe it reflects light into it
/// instead; the model follows one bounce of it, not more (a photo has
/// more). The output map's data term weighs each pixel by the
/// square of the share the model follows to the env map (`followed`):
/// light that stops on the probe is left out, and such samples carry no
/// signal either, only noise. See docs/results/decisions.md 5, Lighting solve.
pub(super) struct LitShares {
    /// Of the pixel's direct samples, the share that reaches the map.
    pub(super) direct: Vec<f64>,
    /// The same, counting a shadowed sample whose bounce reaches it (a
    /// shadowed sample has one BRDF sample at the bounce, no more).
    pub(super) followed: Vec<f64>,
}

impl LitShares {
    pub(super) fn new(segment: &[u32], direct: &[bool], lit: &[bool], env_sampled: &[bool], pixels: usize) -> Self {
        let mut counts = vec![(0u32, 0u32, 0u32); pixels];
        let brdf_sampled = (0..segment.len()).filter(|&k| !env_sampled[k]);
        for (s, d, l) in brdf_sampled.map(|k| (segment[k], direct[k], lit[k])) {
            let c = &mut counts[s as usize];
            c.0 += d as u32;
            c.1 += (d && l) as u32;
            c.2 += l as u32;
        }
        let share = |n: u32, all: u32| n as f64 / all.max(1) as f64;
        LitShares {
            direct: counts.iter().map(|c| share(c.1, c.0)).collect(),
            followed: counts.iter().map(|c| share(c.2, c.0)).collect(),
        }
    }
}

/// The weighted mean squared error over weighted pixels (per channel): with
/// the search's weights, the mean relative squared error.
pub(super) fn mean_weighted_sq_error(rendered: &[[f64; 3]], data: &DataTerm) -> f64 {
    let (mut sum, mut n) = (0.0, 0usize);
    for (p, r) in rendered.iter().enumerate() {
        if data.used(p) {
            let w = data.weight[p];
            sum += (0..3).map(|c| w[c] * data.residual(p, c, r[c]).powi(2)).sum::<f64>() / 3.0;
            n += 1;
        }
    }
    sum / n.max(1) as f64
}

/// PSNR (dB) of `rendered` against `target` over weighted pixels, with the
/// target's peak as the signal.
pub(super) fn psnr(rendered: &[[f64; 3]], data: &DataTerm) -> f64 {
    let (mut se, mut n, mut peak) = (0.0, 0usize, 0.0f64);
    for (p, r) in rendered.iter().enumerate() {
        if data.used(p) {
            for (c, &rc) in r.iter().enumerate() {
                se += data.residual(p, c, rc).powi(2);
                peak = peak.max(data.target[p][c]);
            }
            n += 3;
        }
    }
    if n == 0 || se == 0.0 {
        return f64::INFINITY;
    }
    10.0 * (peak * peak / (se / n as f64)).log10()
}

/// A lighting solve's account: its loss the lighting terms' values where
/// the fit evaluated them, else the data term's weighted squared error.
pub(super) fn lighting_report(name: &str, fit: &LightingFit, started: Instant) -> PhaseReport {
    let loss = match fit.term_values.is_empty() {
        true => [("data_weighted_sq_error".to_string(), fit.weighted_sq_error())].into(),
        false => fit.term_values.clone(),
    };
    PhaseReport {
        name: name.into(),
        iterations: 0,
        evaluations: fit.evaluations,
        wall_s: started.elapsed().as_secs_f64(),
        loss,
        per_iteration: Vec::new(),
        psnr_db: Some(fit.psnr_db()),
        pose: None,
        termination: fit.termination.as_ref().map(ToString::to_string),
        resident_mb: resident_mb(),
    }
}

pub(super) fn env_from_texels(texels: &[f64], width: usize, height: usize) -> Result<EnvMap> {
    let radiance = texels
        .chunks_exact(3)
        .map(|t| [t[0] as f32, t[1] as f32, t[2] as f32])
        .collect();
    Ok(EnvMap::new(width, height, radiance)?)
}

/// A working map (texel-major RGB, `work` = width x height) at the output's
/// size: box-filtered down, which keeps its power (a light finer than the
/// output's texels keeps its energy, which bilinear taps at the output's
/// texel centres would miss), or bilinear up.
pub(super) fn output_map(texels: &[f64], work: (usize, usize), out: (usize, usize)) -> Result<EnvMap> {
    match out.1 < work.1 {
        true => Ok(env_from_texels(texels, work.0, work.1)?.downsample(out.1)),
        false => env_from_texels(&resample(texels, work, out), out.0, out.1),
    }
}

/// Working env map height for a smallest roughness `r`: texels about half
/// the narrowest reflected lobe (the half-vector spread alpha = r^2 radians
/// doubles on reflection: texels alpha wide), as a power of two in
/// 16..=128 (a can, r = 0.2, gets 64 rows; a probe sharper than r = 0.186,
/// 128). Finer texels than the lobe resolves only add unknowns the data
/// cannot tell apart; see docs/results/decisions.md 5.7, Working resolution.
pub fn working_height(min_roughness: f32) -> usize {
    let alpha = (min_roughness * min_roughness).max(0.02);
    let rows = std::f32::consts::PI / alpha;
    1usize << rows.log2().round().clamp(4.0, 7.0) as u32
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_small_output_map_keeps_the_power_of_a_light_finer_than_its_texels() {
        let power = |map: &EnvMap| -> f64 {
            let w = map.width();
            (0..map.height())
                .map(|r| {
                    let row: f64 = (0..w).map(|c| map.radiance()[r * w + c][0] as f64).sum();
                    row * map.texel_solid_angle(r) as f64
                })
                .sum()
        };
        // One bright texel off the centre of its 4x4 block, on a dim map.
        let (w, h) = (256, 128);
        let mut texels = vec![0.1; w * h * 3];
        texels[(41 * w + 100) * 3..(41 * w + 101) * 3].copy_from_slice(&[5e3; 3]);
        let working = env_from_texels(&texels, w, h).unwrap();
        let small = output_map(&texels, (w, h), (64, 32)).unwrap();
        let (before, after) = (power(&working), power(&small));
        assert!((after / before - 1.0).abs() < 1e-4, "power {before} -> {after}");
        let large = output_map(&texels, (w, h), (512, 256)).unwrap();
        assert_eq!((large.width(), large.height()), (512, 256));
    }

    #[test]
    fn the_working_map_is_as_fine_as_the_sharpest_lobe_resolves() {
        // A chrome ball, a can's bare metal (r = 0.2), a cap's steel, paint, a rough probe.
        for (roughness, rows) in [(0.05, 128), (0.15, 128), (0.2, 64), (0.25, 64), (0.35, 32), (0.6, 16)] {
            assert_eq!(working_height(roughness), rows, "roughness {roughness}");
        }
    }

    #[test]
    fn lit_shares_count_the_brdf_samples_alone() {
        // Pixel 0: a lit BRDF sample, a shadowed one whose bounce's BRDF
        // sample is lit, each with an env-map sample (the first lit, the
        // second shadowed), and the bounce's shadowed env-map sample.
        // Pixel 1: one shadowed BRDF sample, no bounce, a lit env sample.
        let segment = [0, 0, 0, 0, 0, 0, 1, 1];
        let direct = [true, true, true, true, false, false, true, true];
        let lit = [true, false, true, false, true, false, false, true];
        let env_sampled = [false, false, true, true, false, true, false, true];
        let shares = LitShares::new(&segment, &direct, &lit, &env_sampled, 2);
        assert_eq!(shares.direct, [0.5, 0.0]);
        assert_eq!(shares.followed, [1.0, 0.0]);
    }
}
