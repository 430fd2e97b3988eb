//! The texture solve by least squares (`alp acquire --solver
//! least-squares`, the default), the alternative to [`super::material`]'s
//! Adam: the same forward model and data term, inverted without a step
//! size, in parts that each fit what it can tell:
//!
//! 1. The roughness by search (`roughness.rs`): every view rendered
//!    at a ladder of roughnesses, each cell of a coarse grid taking the rung
//!    that fits its pixels best. At every placement the scan might have (a
//!    scan's two ends can cast the same outline); the one that fits best
//!    goes on.
//! 2. The turn about the scan's axis, by the same search: a scan nearly of
//!    revolution (a cap's grooves) shows a turn in its outline only
//!    faintly, and a turn of a degree moves a groove's highlights onto the
//!    next texels, which the search explains by a rough, dark surface. The
//!    search's error, each cell at its best roughness and albedo, is the
//!    pose's cost with the textures fitted at it (not held, which would
//!    absorb the pose's error); a compass search over the turn keeps the
//!    least.
//! 3. The albedo exactly (`albedo.rs`): the views are affine in it
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

use glam::{DVec3, Quat};
use render::bsdf::Bsdf;
use render::image_io::RgbImage;
use render::pose::Pose;
use render::probe::Texture;
use serde::Serialize;

use super::albedo::{AlbedoFit, AlbedoSolve, AlbedoSystem};
use super::capture::Capture;
use super::material::{LossTerms, MaterialFit, StageReport, level_sizes, resample};
use super::observation::{Budget, Observations, Placed, observe};
use super::roughness::{RoughnessFit, RoughnessSearch, search};
use crate::error::Result;
use crate::estimate::{self, symmetry};

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
    /// Most roughness searches spent on the turn about the scan's axis
    /// (none for a scan wholly of revolution, whose texture takes up any
    /// turn): each costs a search's time; 0 keeps the silhouettes' turn.
    pub turn_searches: usize,
    /// The turn search's first step and its last (degrees): the first
    /// spans the silhouettes' error, the last is what it resolves.
    pub turn_step_deg: [f64; 2],
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
            turn_searches: 6,
            turn_step_deg: [0.5, 0.125],
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
/// search fits best, turned about its axis as the search fits best;
/// `progress` hears (units done, units in all). Returns the fit, the index
/// of the placement kept and its pose as turned.
pub fn solve(
    capture: &Capture,
    placements: &[Pose],
    size: [usize; 2],
    bsdf: &dyn Bsdf<f32>,
    settings: &LeastSquaresSettings,
    progress: &dyn Fn(usize, usize),
) -> Result<(MaterialFit, usize, Pose)> {
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
    // The axis a turn about shows faintly, if any.
    let turn_axis = symmetry::axis_turns_show_about(&capture.mesh, &estimate::Settings::default().symmetry)
        .filter(|_| settings.turn_searches > 0);
    let turn_searches = if turn_axis.is_some() { settings.turn_searches } else { 0 };
    // Progress units: a rung of a search, the observation, an albedo level.
    let total = ladder.rungs * (placements.len() + turn_searches) + 1 + sizes.len();
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
            turn_deg: None,
        });
        fits.push(fit);
    }
    let chosen = (0..fits.len())
        .min_by(|&a, &b| fits[a].data.total_cmp(&fits[b].data))
        .expect("at least one placement");
    let rough = fits.swap_remove(chosen);
    let turn = turn_axis.map(|axis| {
        let evaluate = |at: &Pose| {
            let placed = Placed::new(capture, at, bsdf);
            let fit = search(&placed, &ladder, &search_budget, [INITIAL_ALBEDO; 3], &|_| tick());
            (fit, placed)
        };
        search_turn(&placements[chosen], axis, rough.data, settings, turn_searches, evaluate)
    });
    // The turn found, if it beat the silhouettes'.
    let (rough, pose, turned_placed) = match turn {
        Some((searched, Some((fit, at, placed)))) => {
            stages.extend(searched);
            (fit, at, Some(placed))
        }
        other => {
            stages.extend(other.into_iter().flat_map(|(searched, _)| searched));
            stages[chosen].kept = true;
            (rough, placements[chosen], None)
        }
    };
    let placed_at = turned_placed.as_ref().unwrap_or(&placed[chosen]);
    let t0 = Instant::now();
    let obs = observe(
        placed_at,
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
        turn_deg: None,
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
    Ok((fit, chosen, pose))
}

/// The turn of `pose` about `axis` (its direction and a point on it, the
/// scan's coordinates) that the roughness search (`evaluate`, at a pose)
/// fits best, by a compass search from `pose`, whose search error is
/// `at_start`: a report of every search, the best kept, and the best's fit,
/// pose and placed capture when one beat the start.
fn search_turn<'a>(
    pose: &Pose,
    (axis, point): (DVec3, DVec3),
    at_start: f64,
    settings: &LeastSquaresSettings,
    searches: usize,
    evaluate: impl Fn(&Pose) -> (RoughnessFit, Placed<'a>),
) -> (Vec<StageReport>, Option<(RoughnessFit, Pose, Placed<'a>)>) {
    let mut stages = Vec::new();
    let (degrees, best) = compass_search(
        at_start,
        settings.turn_step_deg,
        searches,
        |degrees| {
            let t0 = Instant::now();
            let at = turned(pose, axis, point, degrees);
            let (fit, placed) = evaluate(&at);
            stages.push(StageReport {
                stage: "turn".into(),
                size: [fit.roughness.width, fit.roughness.height],
                iterations: settings.roughness_rungs.max(2),
                data_loss: fit.data,
                kept: false,
                seconds: t0.elapsed().as_secs_f64(),
                turn_deg: Some(degrees),
            });
            (fit, at, placed)
        },
        |(fit, _, _)| fit.data,
    );
    if best.is_some() {
        stages
            .iter_mut()
            .filter(|s| s.turn_deg == Some(degrees))
            .for_each(|s| s.kept = true);
    }
    (stages, best)
}

/// `pose` after a turn by `degrees` about the line along `axis` through
/// `point` (the scan's coordinates).
fn turned(pose: &Pose, axis: DVec3, point: DVec3, degrees: f64) -> Pose {
    let turn = Quat::from_axis_angle(axis.normalize().as_vec3(), degrees.to_radians() as f32);
    let c = point.as_vec3();
    // p -> c + turn (p - c), then the pose.
    Pose::new(
        pose.rotation * turn,
        pose.scale,
        pose.translation + pose.rotation * (pose.scale * (c - turn * c)),
    )
}

/// A compass search of one number from 0 (where the cost is `at_start`):
/// steps of `first` on either side, halved when neither side lowers the
/// cost, down to `last`, at most `evaluations` evaluations (`evaluate` of
/// the number; `cost` of its answer). Returns the best number and its
/// answer (none when nothing beat the start). A step the search has taken
/// it does not take again.
fn compass_search<T>(
    at_start: f64,
    [first, last]: [f64; 2],
    evaluations: usize,
    mut evaluate: impl FnMut(f64) -> T,
    cost: impl Fn(&T) -> f64,
) -> (f64, Option<T>) {
    let mut tried = vec![(0.0, at_start)];
    let (mut x, mut fx, mut best) = (0.0, at_start, None);
    let (mut step, mut direction, mut failed_sides) = (first, 1.0, 0);
    let mut left = evaluations;
    while left > 0 && step >= last * (1.0 - 1e-9) {
        let candidate = x + direction * step;
        let known = tried
            .iter()
            .find(|(t, _)| (t - candidate).abs() <= 1e-9 * first.abs().max(1e-300));
        let value = match known {
            Some(&(_, value)) => value,
            None => {
                left -= 1;
                let answer = evaluate(candidate);
                let value = cost(&answer);
                tried.push((candidate, value));
                if value < fx {
                    best = Some(answer);
                }
                value
            }
        };
        if value < fx {
            (x, fx, failed_sides) = (candidate, value, 0);
            continue;
        }
        direction = -direction;
        failed_sides += 1;
        if failed_sides == 2 {
            step /= 2.0;
            failed_sides = 0;
        }
    }
    (x, best)
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
            turn_deg: None,
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

#[cfg(test)]
mod tests {
    use glam::Vec3;

    use super::*;

    #[test]
    fn the_compass_search_walks_to_a_minimum_and_halves_its_step() {
        let mut evaluated = Vec::new();
        let (x, best) = compass_search(
            0.83,
            [0.5, 0.125],
            6,
            |x| {
                evaluated.push(x);
                (x - 0.83f64).abs()
            },
            |&f| f,
        );
        // 0.5 and 1.0 better, 1.5 not; 0.5 known worse than 1.0; halved:
        // 1.25 worse, 0.75 better; 0.5 known; halved: 0.625 worse, the budget spent.
        assert_eq!(evaluated, vec![0.5, 1.0, 1.5, 1.25, 0.75, 0.625]);
        assert_eq!(x, 0.75);
        assert!((best.unwrap() - 0.08).abs() < 1e-12);
        // Nothing beats the start: it stays, with no answer.
        let (x, best) = compass_search(0.0, [0.5, 0.125], 10, |x: f64| x.abs(), |&f| f);
        assert_eq!((x, best), (0.0, None));
    }

    #[test]
    fn a_turn_keeps_the_axis_and_turns_the_rest_about_it() {
        let pose = Pose::new(Quat::from_rotation_x(0.3), 2.0, Vec3::new(1.0, -2.0, 0.5));
        let (axis, point) = (DVec3::new(0.0, 3.0, 4.0), DVec3::new(1.0, 0.0, 0.0));
        let at = turned(&pose, axis, point, 90.0);
        let on_axis = (point + axis * 0.7).as_vec3();
        assert!(at.transform_point(on_axis).distance(pose.transform_point(on_axis)) < 1e-5);
        // A point a unit off the axis, across it: turned a quarter about it.
        let across = DVec3::X.as_vec3();
        let off = point.as_vec3() + across;
        let expected = point.as_vec3() + (axis.normalize().as_vec3()).cross(across);
        assert!(at.transform_point(off).distance(pose.transform_point(expected)) < 1e-5);
    }
}
