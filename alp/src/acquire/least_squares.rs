//! The texture solve by least squares (`alp acquire --solver
//! least-squares`), the alternative to [`super::material`]'s Adam: the same
//! forward model and data term, inverted without a step size, in two parts
//! that each fit what it can tell:
//!
//! 1. The roughness by search (`roughness.rs`): every view rendered
//!    at a ladder of roughnesses, each cell of a coarse grid taking the rung
//!    that fits its pixels best. At every placement the scan might have (a
//!    scan's two ends can cast the same outline); the one that fits best
//!    goes on.
//! 2. The albedo exactly (`albedo.rs`): the views are affine in it
//!    (`observation.rs`), so its texels are a least-squares solve,
//!    coarse to fine in texture size, with a smoothness prior that fills
//!    what no view saw.
//!
//! The visibility stays 1: the renderer's shadow test already darkens what
//! the probe hides from the light, and what is left of a visibility term
//! would darken a pixel as the albedo does (indistinguishable but at
//! grazing Fresnel). The coverage texture marks how much the views tell of
//! each texel.

use std::time::Instant;

use render::bsdf::Bsdf;
use render::image_io::RgbImage;
use render::pose::Pose;
use render::probe::Texture;
use serde::Serialize;

use super::albedo::{AlbedoFit, AlbedoSolve, AlbedoSystem};
use super::capture::Capture;
use super::material::{LossTerms, MaterialFit, StageReport, level_sizes, resample};
use super::observation::{Budget, Observations, Placed, observe};
use super::roughness::{RoughnessSearch, search};
use crate::error::Result;

/// What the texture solve trades.
#[derive(Clone, Debug, Serialize)]
pub struct LeastSquaresSettings {
    /// Texture sizes the albedo is solved at, coarse to fine, each twice
    /// the last: each starts the next one's solve near its answer.
    pub levels: usize,
    /// Most conjugate-gradient iterations of an albedo solve: more reach
    /// the least-squares answer more closely on texels the prior alone holds.
    pub iterations: usize,
    /// Samples per pixel of each of the albedo's two observations: more
    /// lower the noise its answer keeps, at proportional time.
    pub spp: u32,
    /// Most pixels of a view the albedo observes (a random share of a view
    /// with more): bounds the time on a probe that fills the views.
    pub pixels_per_view: usize,
    /// Samples per pixel of the roughness search's observations, each rung.
    pub search_spp: u32,
    /// Most pixels of a view the roughness search observes, each rung.
    pub search_pixels_per_view: usize,
    /// Rungs of the roughness ladder: more resolve the roughness finer, each
    /// costs an observation of every view.
    pub roughness_rungs: usize,
    /// The ladder's ends: GGX near 0 is a mirror, and past about 0.8 a
    /// metal's lobe no longer changes much.
    pub min_roughness: f64,
    pub max_roughness: f64,
    /// The roughness grid is the texture size halved this many times: a
    /// texel's roughness shows only in how reflections blur, which takes
    /// many pixels to tell.
    pub roughness_halvings: usize,
    /// Weight of the albedo's smoothness prior (squared differences of
    /// neighbouring texels): higher fills unseen or noisy texels more
    /// smoothly and blurs printed detail.
    pub albedo_smoothness: f64,
    /// Weight of each neighbouring roughness cell's evidence in a cell's
    /// choice: higher smooths the roughness, lower follows noise.
    pub roughness_smoothness: f64,
    /// A pixel's error is relative to its value plus this share of its
    /// view's mean: dark pixels count without their noise dominating.
    pub relative_floor: f64,
    /// How much a pixel's render noise (its Monte Carlo variance, its
    /// neighbours' pooled in) counts against its relative error in its
    /// weight in the albedo's solve: the noise of a thin highlight of the
    /// sun is many times its value, the photo's (unseen) as much as the
    /// render's; higher trusts the quiet pixels more, 0 weighs every pixel
    /// by its relative error alone.
    pub noise_weight: f64,
    /// Information (the data's curvature in a texel over an average
    /// texel's) a texel needs to count as seen (coverage 1).
    pub well_seen: f64,
}

impl Default for LeastSquaresSettings {
    fn default() -> Self {
        LeastSquaresSettings {
            levels: 4,
            iterations: 300,
            spp: 32,
            pixels_per_view: 16000,
            search_spp: 4,
            search_pixels_per_view: 4000,
            roughness_rungs: 9,
            min_roughness: 0.02,
            max_roughness: 0.8,
            roughness_halvings: 3,
            albedo_smoothness: 0.1,
            roughness_smoothness: 0.25,
            relative_floor: 0.5,
            noise_weight: 64.0,
            well_seen: 0.5,
        }
    }
}

/// The albedo the roughness search holds the bounce's second point at.
const INITIAL_ALBEDO: f32 = 0.7;

/// Seeds of the search's and the albedo's observations.
const SEARCH_SEED: u64 = 0x5EA2C4;
const ALBEDO_SEED: u64 = 0xA1BED0;

/// Solves for the material of the capture's scan at texture size `size`
/// (width, height), placed at whichever of `placements` the roughness
/// search fits best; `progress` hears (units done, units in all). Returns
/// the fit and the index of the placement kept.
pub fn solve(
    capture: &Capture,
    placements: &[Pose],
    size: [usize; 2],
    bsdf: &dyn Bsdf<f32>,
    settings: &LeastSquaresSettings,
    progress: &dyn Fn(usize, usize),
) -> Result<(MaterialFit, usize)> {
    let sizes = level_sizes(size, placements.len(), settings.levels)?;
    let [width, height] = size;
    let ladder = RoughnessSearch {
        rungs: settings.roughness_rungs.max(2),
        least: settings.min_roughness,
        most: settings.max_roughness,
        cells: [
            (width >> settings.roughness_halvings).max(1),
            (height >> settings.roughness_halvings).max(1),
        ],
        smoothness: settings.roughness_smoothness,
    };
    let budget = |spp: u32, pixels_per_view: usize, noise_weight: f64, seed: u64| Budget {
        spp,
        pixels_per_view,
        relative_floor: settings.relative_floor,
        noise_weight,
        merge_uv: [0.5 / width as f32, 0.5 / height as f32],
        seed,
    };
    // Relative errors alone in the search: weights that followed each
    // rung's noise would favour the noisiest rung (a smooth surface's
    // highlights are the noisy ones), and weights by the ladder's ends'
    // noise discount the very pixels that tell a smooth surface (both
    // measured worse: results 17.3).
    let search_budget = budget(settings.search_spp, settings.search_pixels_per_view, 0.0, SEARCH_SEED);
    // Progress units: a rung of a search, the observation, an albedo level.
    let total = ladder.rungs * placements.len() + 1 + sizes.len();
    let done = std::cell::Cell::new(0);
    let tick = || {
        done.set(done.get() + 1);
        progress(done.get(), total)
    };
    let mut stages = Vec::new();
    let placed: Vec<Placed> = placements.iter().map(|p| Placed::new(capture, p, bsdf)).collect();
    let mut fits = Vec::with_capacity(placed.len());
    for placed in &placed {
        let t0 = Instant::now();
        let fit = search(placed, &ladder, &search_budget, [INITIAL_ALBEDO; 3], &|_| tick());
        stages.push(StageReport {
            stage: "roughness".into(),
            size: ladder.cells,
            iterations: ladder.rungs,
            data_loss: fit.data,
            kept: false,
            seconds: t0.elapsed().as_secs_f64(),
        });
        fits.push(fit);
    }
    let chosen = (0..fits.len())
        .min_by(|&a, &b| fits[a].data.total_cmp(&fits[b].data))
        .expect("at least one placement");
    stages[chosen].kept = true;
    let rough = fits.swap_remove(chosen);
    let t0 = Instant::now();
    let obs = observe(
        &placed[chosen],
        &Texture {
            image: rough.roughness.clone(),
        },
        rough.mean_albedo,
        &budget(
            settings.spp,
            settings.pixels_per_view,
            settings.noise_weight,
            ALBEDO_SEED,
        ),
    );
    stages.push(StageReport {
        stage: "observation".into(),
        size: [obs.pixels.len(), obs.hits.len()],
        iterations: 1,
        data_loss: f64::NAN,
        kept: true,
        seconds: t0.elapsed().as_secs_f64(),
    });
    tick();
    let start = RgbImage::filled(1, 1, rough.mean_albedo);
    let (albedo, (last, [w, h])) = solve_albedo(&obs, &start, &sizes, settings, &mut stages, &tick);
    progress(total, total);
    let well_seen = settings.well_seen.max(f64::MIN_POSITIVE);
    let coverage = RgbImage::new(
        w,
        h,
        last.information
            .iter()
            .map(|&i| [(i / well_seen).min(1.0) as f32; 3])
            .collect(),
    );
    let fit = MaterialFit {
        albedo: resample(&albedo, width, height),
        roughness: resample(&rough.roughness, width, height),
        visibility: RgbImage::filled(width, height, [1.0; 3]),
        coverage: resample(&coverage, width, height),
        terms: LossTerms {
            data: last.data,
            albedo_smoothness: last.smoothness,
            roughness_smoothness: rough.variation,
            visibility_prior: 0.0,
        },
        stages,
    };
    Ok((fit, chosen))
}

/// The albedo of `obs`, coarse to fine over `sizes` from `start`, each
/// level from the last one's answer: the finest level the views resolve
/// (a level whose quadratic is not definite is dropped with the finer ones,
/// its coarser neighbour's answer kept), its fit and size. `level_done`
/// hears each level.
fn solve_albedo(
    obs: &Observations,
    start: &RgbImage,
    sizes: &[[usize; 2]],
    settings: &LeastSquaresSettings,
    stages: &mut Vec<StageReport>,
    level_done: &dyn Fn(),
) -> (RgbImage, (AlbedoFit, [usize; 2])) {
    let solve_settings = AlbedoSolve {
        smoothness: settings.albedo_smoothness,
        iterations: settings.iterations.max(1),
    };
    let mut albedo = start.clone();
    let mut last: Option<(AlbedoFit, [usize; 2])> = None;
    for &[w, h] in sizes {
        let t0 = Instant::now();
        let start = resample(&albedo, w, h);
        let system = AlbedoSystem::new(obs, w, h, solve_settings);
        let fit = system.solve(&start.pixels.iter().map(|p| p.map(|c| c as f64)).collect::<Vec<_>>());
        let kept = fit.definite || last.is_none();
        stages.push(StageReport {
            stage: "albedo".into(),
            size: [w, h],
            iterations: fit.iterations,
            data_loss: fit.data,
            kept,
            seconds: t0.elapsed().as_secs_f64(),
        });
        level_done();
        if !kept {
            break;
        }
        albedo = RgbImage::new(w, h, fit.albedo.iter().map(|p| p.map(|c| c as f32)).collect());
        last = Some((fit, [w, h]));
    }
    (albedo, last.expect("at least one level"))
}
