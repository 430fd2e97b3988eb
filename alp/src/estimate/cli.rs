//! `alp estimate`: the main job, from files to an output folder.

use std::io::IsTerminal;
use std::path::PathBuf;
use std::sync::Arc;

use render::bsdf::GgxMetal;
use render::pose::Pose;

use crate::cli::photo::{ProbeMarking, read_inputs};
use crate::cli::{QualityArg, ThreadsArg, parse_size, progress_bar};
use crate::error::{Error, Result};

use super::settings::ADAM_LIGHTING;
use super::settings::LightingMethod;
use super::{Settings, estimate_with};
use crate::estimate::lighting::LightingTerms;
use crate::objective::Objective;

/// Flags of `alp estimate`.
#[derive(clap::Args, Debug)]
pub struct EstimateArgs {
    /// The photo: linear HDR (OpenEXR or Radiance .hdr), or an 8/16-bit sRGB PNG or JPEG (linearised, with a warning).
    #[arg(long)]
    pub image: PathBuf,
    /// The probe's mask: an 8-bit image (PNG), grey or colour > 127 marks the probe (opaque pixels only, when it has alpha).
    /// A hint: the photo decides the outline (`mask_found.png`).
    #[arg(long, required_unless_present = "probe_box", conflicts_with = "probe_box")]
    pub mask: Option<PathBuf>,
    /// Instead of --mask: a box round the probe, x0,y0,x1,y1 (pixel edges,
    /// x1 and y1 one past its last column and row); its first outline is
    /// split from the background by colour inside the box.
    #[arg(long = "box", value_name = "X0,Y0,X1,Y1")]
    pub probe_box: Option<String>,
    /// camera.json of the photo; default: the photo's own camera from its
    /// EXIF tags (a JPEG's or PNG's focal length), at the origin looking
    /// along -z, +y up.
    #[arg(long)]
    pub camera: Option<PathBuf>,
    /// Probe folder (probe.json), or a procedural probe name (can, cap, sphere).
    #[arg(long)]
    pub probe: PathBuf,
    /// Output folder (written whole or not at all).
    #[arg(long)]
    pub out: PathBuf,
    #[command(flatten)]
    pub quality: QualityArg,
    /// Random seed.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    #[command(flatten)]
    pub threads: ThreadsArg,
    /// The probe's pose.json when it is known: the lighting alone is estimated.
    #[arg(long)]
    pub pose: Option<PathBuf>,
    /// The loss as a JSON objective file (default: assets/objectives/paper_default.json's terms).
    #[arg(long)]
    pub objective: Option<PathBuf>,
    /// Output env map size, WIDTHxHEIGHT (2:1).
    #[arg(long, default_value = "256x128")]
    pub env_size: String,
    /// Joint rounds after the search: the pose by the objective's image and
    /// mask terms under a fixed map, then the map at the new pose (default:
    /// none, at every quality).
    #[arg(long)]
    pub rounds: Option<usize>,
    /// Search the probe's size in the photo by the lighting's fit (steps of
    /// half a pixel at the mask's radius), before the photo judges a
    /// cap's ends or a label's turns: for a mask that may be a pixel or two
    /// too wide or too narrow. Costs a few lighting solves more.
    #[arg(long)]
    pub size_search: bool,
    /// The photo's blur beyond its pixels (defocus, motion, the lens), a
    /// Gaussian's standard deviation in pixels; default: measured on the
    /// probe's edges (report.json `blur`). 0 for a photo known to be sharp.
    #[arg(long)]
    pub blur: Option<f32>,
    /// How the lighting is solved: `least-squares` (the exact bounded
    /// solve where the objective's lighting terms have its form), `tape`
    /// (the terms recorded on a tape at each step, as any declared term
    /// is) or `adam` (the paper's recipe: many Adam steps on the same loss,
    /// several times the time).
    #[arg(long, default_value = "least-squares")]
    pub lighting: String,
}

pub(crate) fn parse_lighting(method: &str) -> Result<LightingMethod> {
    match method {
        "least-squares" => Ok(LightingMethod::LeastSquares),
        "adam" => Ok(ADAM_LIGHTING),
        "tape" => Ok(LightingMethod::Tape),
        other => Err(Error::invalid(
            "--lighting",
            format!("`{other}` is not one of least-squares, tape, adam"),
        )),
    }
}

/// Runs the estimation and writes `env.exr`, `pose.json`, `confidence.exr`,
/// `rerender.exr`, `mask_found.png`, `preview.png`, `report.json` and
/// `camera.json` into `--out`.
pub fn run(args: &EstimateArgs) -> Result<()> {
    let mut settings = Settings::new(args.quality.preset()?);
    settings.seed = args.seed;
    settings.env_size = parse_size(&args.env_size)?;
    settings.lighting.method = parse_lighting(&args.lighting)?;
    if let Some(rounds) = args.rounds {
        settings.joint.rounds = rounds;
    }
    if args.size_search {
        settings.pose_search.size_step_px = 0.5;
    }
    if let Some(blur) = args.blur {
        if !(blur.is_finite() && blur >= 0.0) {
            return Err(Error::invalid(
                "--blur",
                format!("{blur} must be a finite number of pixels >= 0"),
            ));
        }
        settings.photo.blur_px = Some(blur);
    }
    settings.known_pose = args.pose.as_ref().map(Pose::read).transpose()?;
    if let Some(path) = &args.objective {
        settings.objective = Arc::new(Objective::from_file(path)?);
        // What only the estimate needs of it (a lighting term), checked
        // before the photo is read.
        LightingTerms::compile(settings.objective.clone(), settings.lighting.method).map_err(|e| e.in_file(path))?;
    }
    let marking = match (&args.mask, &args.probe_box) {
        (Some(path), _) => ProbeMarking::Mask(path),
        (None, Some(text)) => ProbeMarking::Box { text, field: "--box" },
        (None, None) => return Err(Error::invalid("--mask", "give the probe's mask, or --box round it")),
    };
    let photo = read_inputs(&args.image, marking, args.camera.as_deref(), &settings)?;
    let probe = crate::probes::load(&args.probe)?;
    let pool = args.threads.pool()?;
    let verbose = std::io::stderr().is_terminal();
    let bar = progress_bar(verbose, "alp estimate {bar:30} {pos}/{len} phases, {elapsed} {msg}");
    let result = pool.install(|| {
        estimate_with(&photo, &probe, &GgxMetal, &settings, &mut |phase, done, expected| {
            bar.set_length(expected as u64);
            bar.set_position(done as u64);
            bar.set_message(phase.name.clone());
        })
    });
    bar.finish_and_clear();
    let result = result?;
    let on_border = result.report.mask_on_border_pixels;
    if on_border > 0 {
        eprintln!(
            "alp: warning: {on_border} pixels of the mask lie on the image's border: if the probe goes on beyond it, \
             its hidden part is unseen and its pose (and the lighting with it) less certain"
        );
    }
    for warning in &result.report.warnings {
        eprintln!("alp: warning: {warning}");
    }
    if verbose {
        for p in &result.report.phases {
            eprintln!("  {:<15} {:>4} evals {:>7.2} s", p.name, p.evaluations, p.wall_s);
        }
        eprintln!("  PSNR {:.2} dB, {:.2} s", result.report.psnr_db, result.report.wall_s);
    }
    crate::output::write_folder_atomically(&args.out, |dir| crate::output::write_estimate(dir, &photo, &result))
}
