//! Single-image estimation of the probe's pose and the scene's lighting
//! (PAPER.md, "Single-image estimation").
//!
//! Per orientation start (yaws about the probe's axis, as the paper's code):
//! 1. *silhouette*: the pose alone, by Adam on the soft mask's L1 and Chamfer
//!    losses, the barycenter term and the front-facing orientation prior
//!    (both decaying to zero), which are defined and informative from any
//!    start, unlike the image loss;
//! 2. a quick *lighting* solve at that pose, and the re-rendering PSNR that
//!    ranks the starts.
//!
//! Then, from the best start, *joint* refinement by alternation: the pose by
//! Adam on the image loss (relative L1 inside the mask) plus the mask terms
//! with the lighting fixed, and the lighting by the linear solve at the new
//! pose (exact for that pose, which thousands of noisy Adam steps are not).
//! A final solve at more samples per pixel gives the map.
//!
//! The env map's working resolution follows what the probe can resolve: its
//! smallest roughness sets the narrowest lobe (alpha = r^2 radians wide),
//! and the map needs no texel finer than about half of it.

pub mod cli;
pub mod init;
pub mod lighting;

use std::time::Instant;

use autodiff::Tape;
use glam::{Quat, Vec3};
use optim::{Adam, ParamGroup, Solver};
use render::bsdf::GgxMetal;
use render::camera::Camera;
use render::envmap::EnvMap;
use render::image_io::{Mask, RgbImage};
use render::integrator::{PrimaryHits, ProbeVars, RenderSettings, light_samples};
use render::lookup::ImageVars;
use render::mesh::EdgeAdjacency;
use render::pose::Pose;
use render::posed::{POSE_PARAMS, PoseVars, PosedMesh, pack_pose, unpack_pose};
use render::probe::ProbeAsset;
use render::silhouette::{ReferenceMask, SilhouettePlan, SilhouetteSettings};
use render::{RenderError, Result};
use serde::Serialize;

use lighting::{LightingSolve, Transport};

/// Speed against accuracy.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Quality {
    /// Fewer starts, iterations and samples.
    Fast,
    /// The setting the project's figures are measured at.
    Default,
    /// More of everything.
    Best,
}

/// `n` yaw starts evenly around the probe's axis. The paper's code uses four
/// within +-54 degrees of front-facing, which assumes the photographer faced
/// the probe's front; a probe seen from any side needs the whole circle.
fn yaws(n: usize) -> Vec<f32> {
    (0..n).map(|k| -180.0 + 360.0 * (k as f32 + 0.5) / n as f32).collect()
}

/// Everything the estimation can be told.
#[derive(Clone, Debug, Serialize)]
pub struct Settings {
    /// The preset the numbers below came from.
    pub quality: Quality,
    /// Seed of every random choice.
    pub seed: u64,
    /// Output env map size (width, height), width = 2 x height.
    pub env_size: (usize, usize),
    /// Orientation starts: yaw about the probe's axis, degrees.
    pub starts_deg: Vec<f32>,
    /// Adam iterations of the silhouette phase per start.
    pub silhouette_iters: usize,
    /// Alternations of pose (image loss) and lighting (solve).
    pub rounds: usize,
    /// Adam iterations on the pose per round.
    pub pose_iters: usize,
    /// Samples per pixel while fitting the pose.
    pub spp_pose: u32,
    /// Samples per pixel of the final lighting solve.
    pub spp_final: u32,
    /// Working env map height (None: from the probe's roughness).
    pub working_height: Option<usize>,
    /// Weight of the lighting smoothness (scale-free).
    pub smoothness: f64,
    /// The probe's pose when it is known (the lighting alone is estimated).
    #[serde(skip)]
    pub known_pose: Option<Pose>,
}

impl Settings {
    /// The preset for `quality`.
    pub fn new(quality: Quality) -> Self {
        let (starts_deg, silhouette_iters, rounds, pose_iters, spp_pose, spp_final) = match quality {
            Quality::Fast => (yaws(4), 40, 1, 15, 1, 8),
            Quality::Default => (yaws(8), 50, 2, 20, 2, 16),
            Quality::Best => (yaws(12), 100, 3, 40, 4, 64),
        };
        Settings {
            quality,
            seed: 0,
            env_size: (256, 128),
            starts_deg,
            silhouette_iters,
            rounds,
            pose_iters,
            spp_pose,
            spp_final,
            working_height: None,
            smoothness: 1e-4,
            known_pose: None,
        }
    }
}

/// The photo and what is known about it.
pub struct Photo {
    /// Linear HDR RGB.
    pub image: RgbImage,
    /// The probe's segmentation.
    pub mask: Mask,
    /// The camera that took it.
    pub camera: Camera,
}

impl Photo {
    /// Checks that image, mask and camera agree and that the mask is usable.
    pub fn new(image: RgbImage, mask: Mask, camera: Camera) -> Result<Self> {
        let (w, h) = (camera.width as usize, camera.height as usize);
        if (image.width, image.height) != (w, h) {
            return Err(RenderError::value(
                "image",
                format!("is {}x{} but the camera is {w}x{h}", image.width, image.height),
            ));
        }
        if (mask.width, mask.height) != (w, h) {
            return Err(RenderError::value(
                "mask",
                format!("is {}x{} but the camera is {w}x{h}", mask.width, mask.height),
            ));
        }
        if mask.count() < 16 {
            return Err(RenderError::value(
                "mask",
                format!("marks {} pixels: too few to estimate anything from", mask.count()),
            ));
        }
        if image
            .pixels
            .iter()
            .any(|p| p.iter().any(|c| !c.is_finite() || *c < 0.0))
        {
            return Err(RenderError::value("image", "holds NaN, infinite or negative radiance"));
        }
        Ok(Photo { image, mask, camera })
    }
}

/// One phase's account in the report.
#[derive(Clone, Debug, Serialize)]
pub struct PhaseReport {
    /// Which phase.
    pub name: String,
    /// Optimiser iterations.
    pub iterations: usize,
    /// Objective evaluations.
    pub evaluations: usize,
    /// Wall time, seconds.
    pub wall_s: f64,
    /// The loss terms at the end.
    pub loss: std::collections::BTreeMap<String, f64>,
    /// Re-rendering PSNR inside the mask, dB (when the phase renders).
    pub psnr_db: Option<f64>,
}

/// One orientation start's account.
#[derive(Clone, Debug, Serialize)]
pub struct StartReport {
    /// The start's yaw, degrees.
    pub yaw_deg: f32,
    /// Silhouette loss after the silhouette phase.
    pub silhouette_loss: f64,
    /// Re-rendering PSNR after its quick lighting solve, dB.
    pub psnr_db: f64,
}

/// What `report.json` holds.
#[derive(Clone, Debug, Serialize)]
pub struct Report {
    /// The settings used.
    pub settings: Settings,
    /// Every start.
    pub starts: Vec<StartReport>,
    /// The index of the start kept (none when the pose was given).
    pub chosen_start: Option<usize>,
    /// Working env map resolution (width, height) and why.
    pub working_resolution: (usize, usize),
    /// The smallest roughness of the probe, which set it.
    pub min_roughness: f32,
    /// Pixels excluded as clipped (over-exposed).
    pub clipped_pixels: usize,
    /// Every phase, in order.
    pub phases: Vec<PhaseReport>,
    /// Final re-rendering PSNR inside the mask, dB.
    pub psnr_db: f64,
    /// Total wall time, seconds.
    pub wall_s: f64,
}

/// The estimate.
pub struct Estimate {
    /// The environment map at the output size.
    pub env: EnvMap,
    /// Sampling confidence of each texel in [0, 1] (grey), output size.
    pub confidence: EnvMap,
    /// The probe's pose.
    pub pose: Pose,
    /// The photo re-rendered with the estimate.
    pub rerender: RgbImage,
    /// The account of the run.
    pub report: Report,
}

/// Smoothness of the lighting while the pose is still searched: a detailed
/// map would explain a misplaced texture away (texture baked into the light)
/// and hide the pose error from the image loss. The final solve uses the
/// settings' (weaker) smoothness.
const POSE_SEARCH_SMOOTHNESS: f64 = 1e-2;

/// The env map size the orientation starts are ranked under.
const RANKING_SIZE: (usize, usize) = (16, 8);

/// Working env map height for a smallest roughness `r`: texels about half
/// the narrowest lobe (alpha = r^2 radians), as a power of two in 16..=64.
pub fn working_height(min_roughness: f32) -> usize {
    let alpha = (min_roughness * min_roughness).max(0.02);
    let rows = std::f32::consts::PI / (2.0 * alpha);
    (1usize << rows.log2().round().clamp(4.0, 6.0) as u32).clamp(16, 64)
}

/// Per-pixel data term weights: relative errors (HDR: a highlight must not
/// outweigh the rest), zero outside the mask, on partly covered pixels and
/// on clipped ones. Returns the weights and targets aligned with `hits.pixels`.
fn pixel_targets(photo: &Photo, hits: &PrimaryHits, clipped: &[bool]) -> (Vec<[f64; 3]>, Vec<f64>) {
    let lum = |p: [f32; 3]| (0.2126 * p[0] + 0.7152 * p[1] + 0.0722 * p[2]) as f64;
    let mean = photo
        .image
        .pixels
        .iter()
        .zip(&photo.mask.inside)
        .filter(|(_, m)| **m)
        .map(|(p, _)| lum(*p))
        .sum::<f64>()
        / photo.mask.count().max(1) as f64;
    let eps = 0.05 * mean.max(1e-12);
    hits.pixels
        .iter()
        .zip(&hits.coverage)
        .map(|(&p, &c)| {
            let px = photo.image.pixels[p as usize];
            let usable = photo.mask.inside[p as usize] && c >= 1.0 && !clipped[p as usize];
            let w = if usable { 1.0 / (lum(px) + eps).powi(2) } else { 0.0 };
            (px.map(|v| v as f64), w)
        })
        .unzip()
}

/// Pixels at the photo's clipping level: when many mask pixels share the
/// maximum value of a channel, the sensor saturated there.
fn clipped_pixels(photo: &Photo) -> Vec<bool> {
    let mut clipped = vec![false; photo.mask.inside.len()];
    for c in 0..3 {
        let max = photo
            .image
            .pixels
            .iter()
            .zip(&photo.mask.inside)
            .filter(|(_, m)| **m)
            .map(|(p, _)| p[c])
            .fold(0.0f32, f32::max);
        let at_max: Vec<usize> = (0..clipped.len())
            .filter(|&i| photo.mask.inside[i] && photo.image.pixels[i][c] >= 0.9999 * max)
            .collect();
        if at_max.len() * 200 > photo.mask.count() {
            at_max.into_iter().for_each(|i| clipped[i] = true);
        }
    }
    clipped
}

/// PSNR (dB) of `rendered` against `target` over weighted pixels, with the
/// target's peak as the signal.
fn psnr(rendered: &[[f64; 3]], target: &[[f64; 3]], used: &[f64]) -> f64 {
    let (mut se, mut n, mut peak) = (0.0, 0usize, 0.0f64);
    for ((r, t), &w) in rendered.iter().zip(target).zip(used) {
        if w > 0.0 {
            for c in 0..3 {
                se += (r[c] - t[c]).powi(2);
                peak = peak.max(t[c]);
            }
            n += 3;
        }
    }
    if n == 0 || se == 0.0 {
        return f64::INFINITY;
    }
    10.0 * (peak * peak / (se / n as f64)).log10()
}

/// The probe's mesh, material and topology, prepared once.
struct Probe<'a> {
    asset: &'a ProbeAsset,
    edges: EdgeAdjacency,
}

/// The lighting at `pose`: primary hits, the light transport onto a
/// `width x height` map, the solved map (texel-major RGB), the rendered
/// pixels and the data term's targets and weights.
struct LightingFit {
    hits: PrimaryHits,
    transport: Transport,
    env: Vec<f64>,
    rendered: Vec<[f64; 3]>,
    target: Vec<[f64; 3]>,
    weight: Vec<f64>,
    evaluations: usize,
}

#[allow(clippy::too_many_arguments)]
fn fit_lighting(
    probe: &Probe,
    photo: &Photo,
    pose: &Pose,
    size: (usize, usize),
    settings: &RenderSettings,
    clipped: &[bool],
    smoothness: f64,
    start: Option<&[f64]>,
) -> Result<LightingFit> {
    let tape = Tape::<f32>::new();
    let vars = ProbeVars::new(&tape, probe.asset, false);
    let posed = PosedMesh::new(&vars.mesh, &PoseVars::new(&tape, &pack_pose(pose), false));
    let hits = PrimaryHits::trace(&probe.asset.mesh, &posed.position_values(), &photo.camera, settings);
    if hits.is_empty() {
        return Err(RenderError::value("pose", "the probe left the camera's view"));
    }
    let samples = light_samples(
        &tape,
        &hits,
        &photo.camera,
        &vars,
        &posed,
        &probe.asset.mesh.triangles,
        &GgxMetal,
    );
    let (x, y, z) = (
        tape.to_vec(samples.wi.x),
        tape.to_vec(samples.wi.y),
        tape.to_vec(samples.wi.z),
    );
    let wi: Vec<Vec3> = x
        .iter()
        .zip(&y)
        .zip(&z)
        .map(|((&x, &y), &z)| Vec3::new(x, y, z))
        .collect();
    let tp = samples.throughput.map(|t| tape.to_vec(t));
    let throughput: Vec<[f32; 3]> = (0..wi.len()).map(|i| [tp[0][i], tp[1][i], tp[2][i]]).collect();
    let transport = Transport::new(&hits.segment, &wi, &throughput, hits.pixels.len(), size.0, size.1);
    let (target, weight) = pixel_targets(photo, &hits, clipped);
    // A constant map at the photo's mean level is a neutral start.
    let x0 = match start {
        Some(x) => x.to_vec(),
        None => {
            let wsum: f64 = weight.iter().sum::<f64>().max(1e-30);
            let mean = target
                .iter()
                .zip(&weight)
                .map(|(t, w)| w * (t[0] + t[1] + t[2]) / 3.0)
                .sum::<f64>()
                / wsum;
            vec![mean.max(1e-6); transport.unknowns()]
        }
    };
    let (env, evaluations) = lighting::solve(
        &transport,
        &target,
        &weight,
        LightingSolve {
            smoothness,
            max_iters: 300,
        },
        &x0,
    );
    let mut rendered = vec![[0.0; 3]; hits.pixels.len()];
    transport.apply(&env, &mut rendered);
    Ok(LightingFit {
        hits,
        transport,
        env,
        rendered,
        target,
        weight,
        evaluations,
    })
}

/// Adam over the 8 pose parameters: per parameter kind its own step size
/// (rotation quaternion, translation in metres scaled by the depth, log scale).
fn pose_adam(iters: usize, depth: f32) -> Result<Adam> {
    Adam::builder(POSE_PARAMS)
        .group(ParamGroup::new(0..4, 0.02))
        .group(ParamGroup::new(4..7, 0.004 * depth as f64))
        .group(ParamGroup::new(7..8, 0.005))
        .max_iters(iters)
        .build()
        .map_err(|e| RenderError::value("pose optimiser", e.to_string()))
}

/// The silhouette terms of the loss at a pose (recorded on `tape`), with
/// the decaying barycenter and orientation weights `prior`.
#[allow(clippy::too_many_arguments)]
fn silhouette_loss<'t>(
    tape: &'t Tape<f64>,
    probe: &Probe,
    photo: &Photo,
    reference: &ReferenceMask,
    pose_vars: &PoseVars<'t, f64>,
    q_ref: Quat,
    prior: f64,
    terms: &mut Terms,
) -> Result<autodiff::Var<'t, f64>> {
    let mesh = render::posed::MeshVars::new(tape, &probe.asset.mesh);
    let posed = PosedMesh::new(&mesh, pose_vars);
    let plan = SilhouettePlan::with_edges(
        &probe.asset.mesh,
        &probe.edges,
        &posed.position_values(),
        &photo.camera,
        SilhouetteSettings::default(),
    )?;
    let soft = plan.soft_mask(&posed);
    let diag = ((photo.camera.width.pow(2) + photo.camera.height.pow(2)) as f64).sqrt();
    let l1 = soft.mask_l1(reference)?;
    let chamfer = soft.chamfer(reference)? * (1.0 / diag);
    let (bx, by) = soft.barycenter();
    let b = reference.barycenter();
    let dx = (bx - b.x) * (1.0 / diag);
    let dy = (by - b.y) * (1.0 / diag);
    let barycenter = dx * dx + dy * dy;
    // 1 - (q . q_ref)^2: zero for both signs of the same rotation.
    let q = pose_vars.rotation;
    let dot = q.w * q_ref.w as f64 + q.v.x * q_ref.x as f64 + q.v.y * q_ref.y as f64 + q.v.z * q_ref.z as f64;
    let orientation = (dot * dot).rsub(1.0);
    let loss = l1 + chamfer + (barycenter * 10.0 + orientation * 0.1) * prior;
    for (name, v) in [
        ("mask_l1", l1),
        ("chamfer", chamfer),
        ("barycenter", barycenter),
        ("orientation", orientation),
    ] {
        terms.insert(name.into(), tape.item(v));
    }
    Ok(loss)
}

/// The loss terms a phase reports, by name.
type Terms = std::collections::BTreeMap<String, f64>;

/// Adam over the pose parameters from `start`: each evaluation records the
/// loss with `loss(tape, pose, evaluation, terms)` on a fresh f64 tape. A
/// failed evaluation (the probe left the view) ends the phase with its error.
fn fit_pose<L>(name: &str, start: Pose, iters: usize, depth: f32, mut loss: L) -> Result<(Pose, f64, PhaseReport)>
where
    L: for<'t> FnMut(&'t Tape<f64>, &PoseVars<'t, f64>, usize, &mut Terms) -> Result<autodiff::Var<'t, f64>>,
{
    let t0 = Instant::now();
    let mut adam = pose_adam(iters, depth)?;
    let (mut evals, mut failure, mut terms) = (0usize, None, Terms::new());
    let mut objective = |x: &[f64], g: &mut [f64]| -> f64 {
        let tape = Tape::<f64>::new();
        let pose_vars = PoseVars::new(&tape, x, true);
        let result = loss(&tape, &pose_vars, evals, &mut terms);
        evals += 1;
        match result {
            Ok(l) => {
                tape.backward(l);
                g.copy_from_slice(&tape.grad(pose_vars.params));
                tape.item(l)
            }
            Err(e) => {
                failure = Some(e);
                g.iter_mut().for_each(|v| *v = 0.0);
                f64::NAN
            }
        }
    };
    let state = adam
        .minimize(&mut objective, pack_pose(&start).to_vec())
        .map_err(|e| RenderError::value(format!("{name} phase"), e.to_string()))?;
    if state.best_value.is_nan() {
        return Err(failure.unwrap_or_else(|| RenderError::value(format!("{name} phase"), "no finite loss")));
    }
    let report = PhaseReport {
        name: name.into(),
        iterations: state.iter,
        evaluations: state.evals,
        wall_s: t0.elapsed().as_secs_f64(),
        loss: terms,
        psnr_db: None,
    };
    Ok((unpack_pose(&state.best_x), state.best_value, report))
}

/// The silhouette phase from one start: returns the pose, the final loss and the report.
fn fit_silhouette(
    probe: &Probe,
    photo: &Photo,
    reference: &ReferenceMask,
    start: Pose,
    q_ref: Quat,
    iters: usize,
    depth: f32,
) -> Result<(Pose, f64, PhaseReport)> {
    fit_pose("silhouette", start, iters, depth, |tape, pose_vars, eval, terms| {
        let prior = (1.0 - eval as f64 / iters.max(1) as f64).max(0.0);
        silhouette_loss(tape, probe, photo, reference, pose_vars, q_ref, prior, terms)
    })
}

/// The pose by the image loss (relative L1 in the mask) plus the mask
/// terms, with the lighting fixed.
#[allow(clippy::too_many_arguments)]
fn fit_pose_to_image(
    probe: &Probe,
    photo: &Photo,
    reference: &ReferenceMask,
    start: Pose,
    env: &EnvMap,
    fit: &LightingFit,
    settings: &Settings,
    depth: f32,
    seed: u64,
) -> Result<(Pose, PhaseReport)> {
    // Relative L1 weights: square roots of the least-squares weights.
    let target_weight: std::collections::HashMap<u32, f64> = fit
        .hits
        .pixels
        .iter()
        .zip(&fit.weight)
        .map(|(&p, &w)| (p, w.sqrt()))
        .collect();
    let (pose, _, report) = fit_pose(
        "pose",
        start,
        settings.pose_iters,
        depth,
        |tape, pose_vars, eval, terms| {
            let vars = ProbeVars::new(tape, probe.asset, false);
            let posed = PosedMesh::new(&vars.mesh, pose_vars);
            let rs = RenderSettings {
                spp: settings.spp_pose,
                seed: seed.wrapping_add(eval as u64),
            };
            let hits = PrimaryHits::trace(&probe.asset.mesh, &posed.position_values(), &photo.camera, &rs);
            if hits.is_empty() {
                return Err(RenderError::value("pose", "the probe left the camera's view"));
            }
            let env_vars = ImageVars::env(tape, env, false);
            let rgb = light_samples(
                tape,
                &hits,
                &photo.camera,
                &vars,
                &posed,
                &probe.asset.mesh.triangles,
                &GgxMetal,
            )
            .radiance(&env_vars);
            let weights: Vec<f64> = hits
                .pixels
                .iter()
                .map(|p| target_weight.get(p).copied().unwrap_or(0.0))
                .collect();
            let wsum: f64 = weights.iter().sum::<f64>().max(1e-30);
            let w = tape.constant(&weights);
            let mut image = None;
            for (c, channel) in rgb.iter().enumerate() {
                let target: Vec<f64> = hits
                    .pixels
                    .iter()
                    .map(|&p| photo.image.pixels[p as usize][c] as f64)
                    .collect();
                let term = ((*channel - tape.constant(&target)).abs() * w).sum();
                image = Some(image.map_or(term, |acc| acc + term));
            }
            let image = image.expect("three channels") * (1.0 / (3.0 * wsum));
            let mask = silhouette_loss(tape, probe, photo, reference, pose_vars, Quat::IDENTITY, 0.0, terms)?;
            terms.insert("image_rel_l1".into(), tape.item(image));
            Ok(image + mask)
        },
    )?;
    Ok((pose, report))
}

/// A lighting solve's account.
fn lighting_report(name: &str, fit: &LightingFit, started: Instant, psnr_db: f64) -> PhaseReport {
    PhaseReport {
        name: name.into(),
        iterations: 0,
        evaluations: fit.evaluations,
        wall_s: started.elapsed().as_secs_f64(),
        loss: Default::default(),
        psnr_db: Some(psnr_db),
    }
}

fn env_from_texels(texels: &[f64], width: usize, height: usize) -> Result<EnvMap> {
    let radiance = texels
        .chunks_exact(3)
        .map(|t| [t[0] as f32, t[1] as f32, t[2] as f32])
        .collect();
    EnvMap::new(width, height, radiance)
}

/// Bilinear resampling of a map to another 2:1 size (FORMATS.md lookups).
fn resample(env: &EnvMap, width: usize, height: usize) -> Result<EnvMap> {
    let mut radiance = Vec::with_capacity(width * height);
    for r in 0..height {
        for c in 0..width {
            let uv = glam::Vec2::new((c as f32 + 0.5) / width as f32, (r as f32 + 0.5) / height as f32);
            radiance.push(env.lookup_uv(uv));
        }
    }
    EnvMap::new(width, height, radiance)
}

/// What the pose search found: the pose, the lighting fitted there, every
/// start's account and the index of the start kept.
struct PoseSearch {
    pose: Pose,
    fit: LightingFit,
    starts: Vec<StartReport>,
    chosen: usize,
}

/// The pose search: the silhouette phase from every orientation start, the
/// ranking by re-rendering PSNR, then alternation of pose and lighting from
/// the best start (see the module's description).
fn search_pose(
    probe: &Probe,
    photo: &Photo,
    reference: &ReferenceMask,
    clipped: &[bool],
    work: (usize, usize),
    settings: &Settings,
    phases: &mut Vec<PhaseReport>,
) -> Result<PoseSearch> {
    let q_ref = init::front_facing(&photo.camera);
    let mut starts = Vec::new();
    let mut candidates = Vec::new();
    let quick = RenderSettings {
        spp: settings.spp_pose,
        seed: settings.seed,
    };
    for &yaw in &settings.starts_deg {
        let start = init::initial_pose(&probe.asset.mesh, &photo.camera, &photo.mask, yaw)?;
        let depth = (start.translation - photo.camera.origin).length();
        let (pose, sil_loss, report) = fit_silhouette(
            probe,
            photo,
            reference,
            start,
            q_ref,
            settings.silhouette_iters,
            depth,
        )?;
        phases.push(report);
        let t1 = Instant::now();
        // Ranked under a coarse, smooth map: a wrong orientation puts the
        // probe's texture in the wrong place, which only a detailed map could
        // explain away (texture baked into the light).
        let coarse = fit_lighting(probe, photo, &pose, RANKING_SIZE, &quick, clipped, 1.0, None)?;
        let score = psnr(&coarse.rendered, &coarse.target, &coarse.weight);
        phases.push(lighting_report("lighting_ranking", &coarse, t1, score));
        starts.push(StartReport {
            yaw_deg: yaw,
            silhouette_loss: sil_loss,
            psnr_db: score,
        });
        candidates.push((pose, depth));
    }
    let chosen = (0..starts.len())
        .max_by(|&a, &b| starts[a].psnr_db.total_cmp(&starts[b].psnr_db))
        .ok_or_else(|| RenderError::value("starts", "at least one orientation start is needed"))?;
    let (mut pose, depth) = candidates[chosen];
    // The working-resolution map only for the start kept.
    let t1 = Instant::now();
    let mut fit = fit_lighting(
        probe,
        photo,
        &pose,
        work,
        &quick,
        clipped,
        POSE_SEARCH_SMOOTHNESS,
        None,
    )?;
    phases.push(lighting_report(
        "lighting",
        &fit,
        t1,
        psnr(&fit.rendered, &fit.target, &fit.weight),
    ));
    for round in 0..settings.rounds {
        let env = env_from_texels(&fit.env, work.0, work.1)?;
        let (new_pose, report) = fit_pose_to_image(
            probe,
            photo,
            reference,
            pose,
            &env,
            &fit,
            settings,
            depth,
            settings.seed + 1000 * round as u64,
        )?;
        phases.push(report);
        pose = new_pose;
        let t1 = Instant::now();
        fit = fit_lighting(
            probe,
            photo,
            &pose,
            work,
            &quick,
            clipped,
            POSE_SEARCH_SMOOTHNESS,
            Some(&fit.env),
        )?;
        phases.push(lighting_report(
            "lighting",
            &fit,
            t1,
            psnr(&fit.rendered, &fit.target, &fit.weight),
        ));
    }
    Ok(PoseSearch {
        pose,
        fit,
        starts,
        chosen,
    })
}

/// Estimates the pose and the lighting from `photo` of `probe`.
pub fn estimate(photo: &Photo, asset: &ProbeAsset, settings: &Settings) -> Result<Estimate> {
    let t0 = Instant::now();
    let (out_w, out_h) = settings.env_size;
    if out_w != 2 * out_h || out_h < 2 {
        return Err(RenderError::value(
            "env size",
            format!("{out_w}x{out_h} is not a 2:1 map"),
        ));
    }
    let probe = Probe {
        asset,
        edges: EdgeAdjacency::new(&asset.mesh),
    };
    let reference = ReferenceMask::new(&photo.mask)?;
    let clipped = clipped_pixels(photo);
    let min_roughness = asset.roughness.image.pixels.iter().map(|p| p[0]).fold(1.0f32, f32::min);
    let work_h = settings.working_height.unwrap_or_else(|| working_height(min_roughness));
    let work = (2 * work_h, work_h);
    let mut phases = Vec::new();
    let (pose, fit, starts, chosen) = match settings.known_pose {
        Some(pose) => (pose, None, Vec::new(), None),
        None => {
            let search = search_pose(&probe, photo, &reference, &clipped, work, settings, &mut phases)?;
            (search.pose, Some(search.fit), search.starts, Some(search.chosen))
        }
    };
    let t1 = Instant::now();
    let final_settings = RenderSettings {
        spp: settings.spp_final,
        seed: settings.seed.wrapping_add(77),
    };
    let fit = fit_lighting(
        &probe,
        photo,
        &pose,
        work,
        &final_settings,
        &clipped,
        settings.smoothness,
        fit.as_ref().map(|f| f.env.as_slice()),
    )?;
    let final_psnr = psnr(&fit.rendered, &fit.target, &fit.weight);
    phases.push(lighting_report("lighting_final", &fit, t1, final_psnr));
    let working_env = env_from_texels(&fit.env, work.0, work.1)?;
    let env = resample(&working_env, out_w, out_h)?;
    let confidence = fit.transport.confidence().iter().map(|&c| [c; 3]).collect();
    let confidence = resample(&EnvMap::new(work.0, work.1, confidence)?, out_w, out_h)?;
    let channels: [Vec<f64>; 3] = std::array::from_fn(|c| fit.rendered.iter().map(|p| p[c]).collect());
    let rerender = fit.hits.to_image([&channels[0], &channels[1], &channels[2]]);
    let report = Report {
        settings: settings.clone(),
        starts,
        chosen_start: chosen,
        working_resolution: work,
        min_roughness,
        clipped_pixels: clipped.iter().filter(|&&c| c).count(),
        phases,
        psnr_db: final_psnr,
        wall_s: t0.elapsed().as_secs_f64(),
    };
    Ok(Estimate {
        env,
        confidence,
        pose,
        rerender,
        report,
    })
}
