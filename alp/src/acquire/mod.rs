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
mod roughness;
pub mod truth;

use std::time::Instant;

use render::bsdf::Bsdf;
use render::image_io::RgbImage;
use render::integrator::{RenderSettings, render_image};
use render::probe::ProbeAsset;
use serde::Serialize;

use crate::error::Result;
use crate::estimate::Quality;
use capture::Capture;
use least_squares::LeastSquaresSettings;
use material::{LossTerms, MaterialFit, MaterialSettings, StageReport};
use placement::PlacementSettings;

/// How the textures are solved for.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Solver {
    /// Adam on the re-rendering error, differentiated in the textures ([`material`]).
    Adam,
    /// A roughness search and an exact albedo solve ([`least_squares`]):
    /// several times faster, the roughness closer; its albedo is worse where
    /// a recess is lit by the probe's own reflections (docs/results.md 13).
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
            solver: Solver::Adam,
            material: MaterialSettings::default(),
            least_squares: LeastSquaresSettings::default(),
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
    /// The placement's silhouette loss (soft-mask L1 plus Chamfer, view mean).
    pub placement_loss: f64,
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
    let (fit, chosen): (MaterialFit, usize) = match settings.solver {
        Solver::Adam => material::solve(capture, &poses, size, bsdf, &settings.material, &|done, all| {
            progress("textures", done, all)
        })?,
        Solver::LeastSquares => {
            least_squares::solve(capture, &poses, size, bsdf, &settings.least_squares, &|done, all| {
                progress("textures", done, all)
            })?
        }
    };
    let placement = placements[chosen];
    let solved = Instant::now();
    let asset = fit.asset(name, &capture.mesh);
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
            &placement.to_world,
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
        loss: fit.terms.clone(),
        stages: fit.stages.clone(),
        views,
        mean_coverage: coverage_sum / fit.coverage.pixels.len() as f64,
        seconds: PhaseSeconds {
            placement: (placed - t0).as_secs_f64(),
            textures: (solved - placed).as_secs_f64(),
            report: solved.elapsed().as_secs_f64(),
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

/// The seed of the report's re-renders.
const REPORT_SEED: u64 = 0x5EED;

/// PSNR of `rerender` against `photo` over the pixels `inside`, the peak
/// the photo's 99th-percentile luminance there; infinite when equal.
pub fn psnr_db(photo: &RgbImage, rerender: &RgbImage, inside: &[bool]) -> f64 {
    let luminance = |p: &[f32; 3]| 0.2126 * p[0] as f64 + 0.7152 * p[1] as f64 + 0.0722 * p[2] as f64;
    let mut peaks: Vec<f64> = Vec::new();
    let (mut sq, mut n) = (0.0, 0usize);
    for (p, _) in inside.iter().enumerate().filter(|(_, inside)| **inside) {
        peaks.push(luminance(&photo.pixels[p]));
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
