//! `alp estimate`: the main job, from files to an output folder.

use std::io::IsTerminal;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use render::RenderError;
use render::bsdf::GgxMetal;
use render::camera::Camera;
use render::exif_camera::camera_from_exif;
use render::image_io::{Mask, PhotoEncoding, RgbImage};
use render::pose::Pose;

use crate::error::{Error, Result};

use super::probe_box::{ProbeBox, mask_in_box};
use super::settings::ADAM_LIGHTING;
use super::settings::LightingMethod;
use super::{Estimate, Photo, Quality, Settings, estimate_with};
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
    /// fast, default or best.
    #[arg(long, default_value = "default")]
    pub quality: String,
    /// Random seed.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Worker threads (default: all cores).
    #[arg(long)]
    pub threads: Option<usize>,
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
    /// solve) or `adam` (the paper's recipe: many Adam steps on the same
    /// loss, several times the time).
    #[arg(long, default_value = "least-squares")]
    pub lighting: String,
}

pub(crate) fn parse_quality(q: &str) -> Result<Quality> {
    match q {
        "fast" => Ok(Quality::Fast),
        "default" => Ok(Quality::Default),
        "best" => Ok(Quality::Best),
        other => Err(Error::invalid(
            "--quality",
            format!("`{other}` is not one of fast, default, best"),
        )),
    }
}

pub(crate) fn parse_lighting(method: &str) -> Result<LightingMethod> {
    match method {
        "least-squares" => Ok(LightingMethod::LeastSquares),
        "adam" => Ok(ADAM_LIGHTING),
        other => Err(Error::invalid(
            "--lighting",
            format!("`{other}` is not one of least-squares, adam"),
        )),
    }
}

pub(crate) fn parse_size(s: &str) -> Result<(usize, usize)> {
    let bad = || {
        Error::invalid(
            "--env-size",
            format!("`{s}` is not WIDTHxHEIGHT with WIDTH = 2 x HEIGHT"),
        )
    };
    let (w, h) = s.split_once('x').ok_or_else(bad)?;
    let (w, h): (usize, usize) = (w.parse().map_err(|_| bad())?, h.parse().map_err(|_| bad())?);
    if w != 2 * h || h < 2 {
        return Err(bad());
    }
    Ok((w, h))
}

/// Runs the estimation and writes `env.exr`, `pose.json`, `confidence.exr`,
/// `rerender.exr`, `mask_found.png`, `preview.png`, `report.json` and
/// `camera.json` into `--out`.
pub fn run(args: &EstimateArgs) -> Result<()> {
    let mut settings = Settings::new(parse_quality(&args.quality)?);
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
    }
    let marking = match (&args.mask, &args.probe_box) {
        (Some(path), _) => ProbeMarking::Mask(path),
        (None, Some(text)) => ProbeMarking::Box { text, field: "--box" },
        (None, None) => return Err(Error::invalid("--mask", "give the probe's mask, or --box round it")),
    };
    let photo = read_inputs(&args.image, marking, args.camera.as_deref(), &settings)?;
    let probe = crate::probes::load(&args.probe)?;
    let pool = thread_pool(args.threads)?;
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
    if verbose {
        for p in &result.report.phases {
            eprintln!("  {:<15} {:>4} evals {:>7.2} s", p.name, p.evaluations, p.wall_s);
        }
        eprintln!("  PSNR {:.2} dB, {:.2} s", result.report.psnr_db, result.report.wall_s);
    }
    crate::output::write_folder_atomically(&args.out, |dir| write_estimate(dir, &photo, &result))
}

/// What marks the probe in the photo, as the user gives it.
pub(crate) enum ProbeMarking<'a> {
    /// A mask image.
    Mask(&'a Path),
    /// A box round it, `x0,y0,x1,y1`, given as `field` (its errors name it).
    Box { text: &'a str, field: &'a str },
}

/// The photo at `image` as the user gives it: the probe marked by a mask
/// or a box (its first outline then found by colour inside it,
/// [`mask_in_box`]), the camera from `camera` or else the image's EXIF.
pub(crate) fn read_inputs(
    image_path: &Path,
    marking: ProbeMarking,
    camera: Option<&Path>,
    settings: &Settings,
) -> Result<Photo> {
    let (image, encoding) = read_photo(image_path)?;
    let camera = match camera {
        Some(path) => Camera::read(path)?,
        None => {
            let camera = camera_from_exif(image_path, image.width as u32, image.height as u32)?;
            eprintln!(
                "alp: the camera from {}'s EXIF: vertical field of view {:.2} deg, at the origin looking along -z",
                image_path.display(),
                camera.fov_y_deg
            );
            camera
        }
    };
    let mask = match marking {
        ProbeMarking::Mask(path) => Mask::read_png(path)?,
        ProbeMarking::Box { text, field } => {
            let probe_box =
                ProbeBox::parse(text, image.width, image.height).map_err(|e| Error::invalid(field, e.rule()))?;
            mask_in_box(&image, &probe_box, &settings.photo.probe_box)?
        }
    };
    Ok(Photo::new(image, mask, camera)
        .map_err(|e| e.in_file(image_path))?
        .with_encoding(encoding))
}

/// Writes an estimate's files into `dir`: `env.exr`, `pose.json`,
/// `confidence.exr`, `rerender.exr`, `mask_found.png`, `preview.png`,
/// `report.json` and `camera.json` (the camera it used, the EXIF's when
/// none was given: for `alp insert` and `alp render`).
pub(crate) fn write_estimate(dir: &Path, photo: &Photo, result: &Estimate) -> Result<()> {
    photo.camera.write(dir.join("camera.json"))?;
    result.env.write(dir.join("env.exr"))?;
    result.outline.write_png(dir.join("mask_found.png"))?;
    result.pose.write(dir.join("pose.json"))?;
    result.confidence.write(dir.join("confidence.exr"))?;
    result.rerender.write_exr(dir.join("rerender.exr"))?;
    preview(&photo.image, &result.rerender, &result.env.to_image()).write_png_preview(dir.join("preview.png"), 0.0)?;
    let json = serde_json::to_string_pretty(&result.report)
        .map_err(|e| RenderError::io(dir.join("report.json"), "serialise", e))?;
    std::fs::write(dir.join("report.json"), json + "\n")
        .map_err(|e| RenderError::io(dir.join("report.json"), "write", e).into())
}

/// Reads a photo (OpenEXR, Radiance HDR, PNG or JPEG: [`RgbImage::read_photo`]),
/// warning on stderr when it is display-referred sRGB; and how it was stored.
pub(crate) fn read_photo(path: &Path) -> Result<(RgbImage, PhotoEncoding)> {
    let (image, encoding) = RgbImage::read_photo(path)?;
    if let PhotoEncoding::Srgb { bits } = encoding {
        eprintln!(
            "alp: warning: {} is a {bits}-bit sRGB image, not HDR: it is linearised, its clipped highlights are \
             read as lower bounds (the brightest lights may come out dimmer than they are) and its exposure is \
             unknown (the map is right up to one scale)",
            path.display()
        );
    }
    Ok((image, encoding))
}

/// A pool of `threads` workers (all cores when `None`).
pub(crate) fn thread_pool(threads: Option<usize>) -> Result<rayon::ThreadPool> {
    if threads == Some(0) {
        return Err(Error::invalid("--threads", "needs at least one thread"));
    }
    rayon::ThreadPoolBuilder::new()
        .num_threads(threads.unwrap_or_else(rayon::current_num_threads))
        .build()
        .map_err(|e| Error::invalid("--threads", e.to_string()))
}

/// A progress bar on a terminal (`verbose`), hidden otherwise.
pub(crate) fn progress_bar(verbose: bool, template: &str) -> indicatif::ProgressBar {
    let bar = if verbose {
        indicatif::ProgressBar::new(1)
    } else {
        indicatif::ProgressBar::hidden()
    };
    bar.set_style(indicatif::ProgressStyle::with_template(template).expect("a valid template"));
    bar
}

/// Photo, re-render and env map side by side (the map scaled to the photo's height).
fn preview(photo: &RgbImage, rerender: &RgbImage, env: &RgbImage) -> RgbImage {
    let h = photo.height;
    let env_w = 2 * h;
    let width = 2 * photo.width + env_w;
    let mut out = RgbImage::filled(width, h, [0.0; 3]);
    for r in 0..h {
        for c in 0..photo.width {
            out.pixels[r * width + c] = photo.pixels[r * photo.width + c];
            out.pixels[r * width + photo.width + c] = rerender.pixels[r * photo.width + c];
        }
        for c in 0..env_w {
            let (er, ec) = (r * env.height / h, c * env.width / env_w);
            out.pixels[r * width + 2 * photo.width + c] = env.pixels[er * env.width + ec];
        }
    }
    out
}
