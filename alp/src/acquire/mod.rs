//! Probe acquisition, the paper's offline stage (PAPER.md, Sec. 3.2): a shiny
//! object photographed from many views under known lighting becomes a probe
//! asset. Its input is the capture folder ([`capture`], which
//! `alp synth captures` renders for a known probe); the scan is placed in
//! the cameras' frame from the silhouettes ([`placement`]), then its
//! textures are solved for by re-rendering every view: by Adam
//! ([`material`]) or by a roughness search and an exact albedo solve
//! ([`least_squares`]).

mod albedo;
pub mod capture;
pub mod cli;
pub mod least_squares;
pub mod material;
mod observation;
pub mod placement;
pub mod registration;
mod roughness;
pub mod truth;

use std::time::Instant;

use glam::Vec3;
use render::bsdf::Bsdf;
use render::colour::luminance;
use render::image_io::RgbImage;
use render::integrator::{RenderSettings, render_image};
use render::mesh::Mesh;
use render::pose::Pose;
use render::probe::ProbeAsset;
use serde::Serialize;

use crate::error::Result;
use crate::estimate::symmetry;
use crate::estimate::{Quality, Settings};
use capture::Capture;
use least_squares::LeastSquaresSettings;
use material::{LossTerms, MaterialFit, MaterialSettings, StageReport};
use placement::PlacementSettings;
use registration::{RegistrationReport, RegistrationSettings};

/// How the textures are solved for.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Solver {
    /// Adam on the re-rendering error, differentiated in the textures ([`material`]).
    Adam,
    /// A roughness search and an exact albedo solve ([`least_squares`]), the
    /// default: several times faster than Adam, and closer on the capture
    /// benchmark's train probes (docs/results/acquisition.md 17.4).
    LeastSquares,
}

/// Everything the acquisition can be told.
#[derive(Clone, Debug, Serialize)]
pub struct AcquireSettings {
    /// The preset the numbers came from.
    pub quality: Quality,
    #[serde(skip)]
    pub placement: PlacementSettings,
    pub solver: Solver,
    /// The Adam solve's settings.
    pub material: MaterialSettings,
    /// The least-squares solve's settings.
    pub least_squares: LeastSquaresSettings,
    /// The pose refined against the views' pixels, the textures solved
    /// again at it ([`registration`]); none (every preset's) keeps the
    /// silhouettes' pose: on the Mitsuba captures it has not yet bettered
    /// the textures (docs/results/acquisition.md 17).
    pub registration: Option<RegistrationSettings>,
    /// Samples per pixel of the report's re-renders (PSNR, preview): their
    /// noise lowers the PSNR a little; each view's re-render costs its time.
    pub report_spp: u32,
}

impl AcquireSettings {
    /// The settings of a quality preset.
    pub fn preset(quality: Quality) -> Self {
        let default = AcquireSettings {
            quality,
            placement: PlacementSettings::default(),
            solver: Solver::LeastSquares,
            material: MaterialSettings::default(),
            least_squares: LeastSquaresSettings::default(),
            registration: None,
            report_spp: 4,
        };
        match quality {
            Quality::Default => default,
            Quality::Fast => AcquireSettings {
                material: MaterialSettings {
                    steps: 60,
                    views_per_step: 2,
                    spp: 2,
                    pixels_per_view: 4000,
                    ..default.material
                },
                least_squares: LeastSquaresSettings {
                    spp: 8,
                    pixels_per_view: 8000,
                    search_spp: 2,
                    search_pixels_per_view: 2000,
                    roughness_rungs: 7,
                    ..default.least_squares
                },
                report_spp: 2,
                ..default
            },
            Quality::Best => AcquireSettings {
                material: MaterialSettings {
                    steps: 300,
                    views_per_step: 3,
                    spp: 8,
                    pixels_per_view: 16000,
                    ..default.material
                },
                least_squares: LeastSquaresSettings {
                    spp: 64,
                    pixels_per_view: 32000,
                    search_spp: 8,
                    search_pixels_per_view: 8000,
                    roughness_rungs: 12,
                    ..default.least_squares
                },
                report_spp: 16,
                ..default
            },
        }
    }
}

/// One view's re-render against its photo.
#[derive(Clone, Debug, Serialize)]
pub struct ViewReport {
    pub name: String,
    /// PSNR over the view's mask, the peak its 99th-percentile luminance
    /// there (a highlight's maximum would hide everything else's error), dB.
    pub psnr_db: f64,
}

/// Seconds per phase.
#[derive(Clone, Debug, Default, Serialize)]
pub struct PhaseSeconds {
    pub placement: f64,
    pub textures: f64,
    /// The registration and the textures' second solve.
    pub registration: f64,
    pub report: f64,
    pub total: f64,
}

/// What `report.json` holds.
#[derive(Clone, Debug, Serialize)]
pub struct AcquireReport {
    pub settings: AcquireSettings,
    /// Texture width and height.
    pub texture_size: [usize; 2],
    /// The scan's mesh-to-world pose found (the cameras' frame), rows of
    /// the 4x4 matrix as in `pose.json`.
    pub to_world: [[f32; 4]; 4],
    /// The placement's silhouette loss (soft-mask L1 plus Chamfer, view
    /// mean) at the silhouettes' pose (before any registration).
    pub placement_loss: f64,
    pub registration: Option<RegistrationReport>,
    /// The texture solve's terms at its end.
    pub loss: LossTerms,
    pub stages: Vec<StageReport>,
    pub views: Vec<ViewReport>,
    /// Mean coverage over the texture's texels.
    pub mean_coverage: f64,
    pub seconds: PhaseSeconds,
    /// Against the truth when the capture holds it (`alp synth captures`).
    pub truth: Option<truth::TruthErrors>,
}

/// The acquisition's result: the probe, its coverage, the report, and the
/// re-renders of the views (in the capture's order).
pub struct Acquisition {
    pub asset: ProbeAsset,
    pub coverage: RgbImage,
    pub report: AcquireReport,
    pub rerenders: Vec<RgbImage>,
}

/// What a progress display hears: the phase's name, steps done and steps in all.
pub type Progress<'a> = dyn Fn(&str, usize, usize) + Sync + 'a;

/// Acquires the probe `name` from `capture` at texture size `size` (width,
/// height), its metal modelled by `bsdf` (the model the estimate will use
/// with it: `GgxMetal`, the paper's, or a researcher's own), judged against
/// `truth` when given.
pub fn acquire(
    capture: &Capture,
    name: &str,
    size: [usize; 2],
    bsdf: &dyn Bsdf<f32>,
    settings: &AcquireSettings,
    truth: Option<&truth::Truth>,
    progress: &Progress,
) -> Result<Acquisition> {
    let t0 = Instant::now();
    progress("placement", 0, 1);
    let placements = placement::place(capture, &settings.placement)?;
    let placed = Instant::now();
    let poses: Vec<_> = placements.iter().map(|p| p.to_world).collect();
    // The fit, the placement kept and its pose (the least-squares solve turns it).
    let textures = |poses: &[Pose], phase: &str| -> Result<(MaterialFit, usize, Pose)> {
        let progress = |done, all| progress(phase, done, all);
        match settings.solver {
            Solver::Adam => material::solve(capture, poses, size, bsdf, &settings.material, &progress)
                .map(|(fit, chosen)| (fit, chosen, poses[chosen])),
            Solver::LeastSquares => {
                least_squares::solve(capture, poses, size, bsdf, &settings.least_squares, &progress)
            }
        }
    };
    let (mut fit, chosen, pose) = textures(&poses, "textures")?;
    let mut placement = placements[chosen];
    placement.to_world = pose;
    let solved = Instant::now();
    let registration = match &settings.registration {
        Some(r) => {
            let placed = observation::Placed::new(capture, &placement.to_world, bsdf);
            let (pose, report) = registration::register(&placed, &fit.asset(name, &capture.mesh), r, &|done, all| {
                progress("registration", done, all)
            })?;
            placement.to_world = pose;
            fit = textures(&[pose], "textures at the registered pose")?.0;
            Some(report)
        }
        None => None,
    };
    let registered = Instant::now();
    let (mesh, seen_at) = probe_frame(&capture.mesh, &placement.to_world);
    let asset = fit.asset(name, &mesh);
    let render_settings = RenderSettings {
        spp: settings.report_spp,
        seed: REPORT_SEED,
    };
    let mut rerenders = Vec::with_capacity(capture.views.len());
    let mut views = Vec::with_capacity(capture.views.len());
    for (k, view) in capture.views.iter().enumerate() {
        progress("report", k, capture.views.len());
        let (image, _) = render_image(
            &asset,
            &seen_at,
            &view.photo.camera,
            &capture.lighting,
            bsdf,
            &render_settings,
        );
        views.push(ViewReport {
            name: view.name.clone(),
            psnr_db: psnr_db(&view.photo.image, &image, &view.photo.mask.inside),
        });
        rerenders.push(image);
    }
    let truth = truth.map(|t| truth::TruthErrors::of(capture, t, &asset, &placement.to_world));
    let coverage_sum: f64 = fit.coverage.pixels.iter().map(|p| p[0] as f64).sum();
    let report = AcquireReport {
        settings: settings.clone(),
        texture_size: size,
        to_world: placement.to_world.to_world().transpose().to_cols_array_2d(),
        placement_loss: placement.loss,
        registration,
        loss: fit.terms.clone(),
        stages: fit.stages.clone(),
        views,
        mean_coverage: coverage_sum / fit.coverage.pixels.len() as f64,
        seconds: PhaseSeconds {
            placement: (placed - t0).as_secs_f64(),
            textures: (solved - placed).as_secs_f64(),
            registration: (registered - solved).as_secs_f64(),
            report: registered.elapsed().as_secs_f64(),
            total: t0.elapsed().as_secs_f64(),
        },
        truth,
    };
    Ok(Acquisition {
        asset,
        coverage: fit.coverage,
        report,
        rerenders,
    })
}

/// The scan as a probe asset's mesh (FORMATS.md: metres, and the axis
/// along +Y, as the estimate reads a probe): posed into the cameras' frame
/// by its placement, turned so that its axis is +Y (`symmetry::axis_to_y`:
/// already so for a probe that stood on a turntable), the middle of its
/// base at the origin. A scan keeps its own frame and units otherwise (a
/// capture's are any), and the estimate would start from a wrong size and
/// lean it about a wrong axis. Returns the mesh and the pose that puts it
/// where the views saw it.
pub fn probe_frame(scan: &Mesh, to_world: &Pose) -> (Mesh, Pose) {
    let world = scan.posed(to_world);
    let turn = symmetry::axis_to_y(&world, &Settings::default().symmetry);
    let mut mesh = world.posed(&Pose::new(turn, 1.0, Vec3::ZERO));
    let (lo, hi) = mesh.bounds();
    let base = Vec3::new(0.5 * (lo.x + hi.x), lo.y, 0.5 * (lo.z + hi.z));
    mesh.positions.iter_mut().for_each(|p| *p -= base);
    (mesh, Pose::new(turn.inverse(), 1.0, turn.inverse() * base))
}

/// The seed of the report's re-renders.
const REPORT_SEED: u64 = 0x5EED;

/// PSNR of `rerender` against `photo` over the pixels `inside`, the peak
/// the photo's 99th-percentile luminance there; infinite when equal.
pub fn psnr_db(photo: &RgbImage, rerender: &RgbImage, inside: &[bool]) -> f64 {
    let mut peaks: Vec<f64> = Vec::new();
    let (mut sq, mut n) = (0.0, 0usize);
    for (p, _) in inside.iter().enumerate().filter(|(_, inside)| **inside) {
        peaks.push(luminance(photo.pixels[p].map(f64::from)));
        for c in 0..3 {
            sq += (photo.pixels[p][c] as f64 - rerender.pixels[p][c] as f64).powi(2);
        }
        n += 3;
    }
    if n == 0 {
        return f64::NAN;
    }
    peaks.sort_by(f64::total_cmp);
    let peak = peaks[(peaks.len() * 99 / 100).min(peaks.len() - 1)];
    10.0 * (peak * peak / (sq / n as f64)).log10()
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Quat;

    /// A can scanned in a turned frame at 7 units per metre, placed back
    /// standing: the asset's mesh is the can in metres, upright, its base
    /// at the origin, and the pose returned puts it where the views saw it.
    #[test]
    fn the_acquired_mesh_is_the_probe_in_metres_standing_on_its_base() {
        let can = render::procedural::SodaCan::default().build().mesh;
        let scan_frame = Pose::new(
            Quat::from_euler(glam::EulerRot::XYZ, 0.7, -1.1, 0.4),
            7.0,
            Vec3::new(3.0, -2.0, 5.0),
        );
        let scan = can.posed(&scan_frame);
        // Standing at (0.2, 0.1, -0.3) in the cameras' frame.
        let stands = Pose::new(Quat::IDENTITY, 1.0, Vec3::new(0.2, 0.1, -0.3));
        let to_world = Pose::new(
            scan_frame.rotation.inverse(),
            1.0 / 7.0,
            stands.translation - scan_frame.rotation.inverse() * scan_frame.translation / 7.0,
        );
        let (mesh, seen_at) = probe_frame(&scan, &to_world);
        let (lo, hi) = mesh.bounds();
        let (clo, chi) = can.bounds();
        assert!(
            ((hi - lo) - (chi - clo)).abs().max_element() < 1e-4,
            "{:?} against {:?}",
            hi - lo,
            chi - clo
        );
        assert!(lo.y.abs() < 1e-5 && (lo.x + hi.x).abs() < 1e-4 && (lo.z + hi.z).abs() < 1e-4);
        for (p, q) in mesh.positions.iter().zip(&scan.positions) {
            let (a, b) = (seen_at.transform_point(*p), to_world.transform_point(*q));
            assert!((a - b).length() < 1e-4, "{a} against {b}");
        }
    }
}
