//! `alp acquire`: a capture folder in, a probe folder out.

use std::io::IsTerminal;
use std::path::PathBuf;

use render::RenderError;
use render::bsdf::GgxMetal;
use render::image_io::RgbImage;

use super::capture::Capture;
use super::registration::RegistrationSettings;
use super::truth::Truth;
use super::{AcquireSettings, Acquisition, Solver, acquire};
use crate::cli::{QualityArg, ThreadsArg, parse_dimensions, progress_bar};
use crate::error::{Error, Result};

/// Flags of `alp acquire`.
#[derive(clap::Args, Debug)]
pub struct AcquireArgs {
    /// The capture folder: mesh.obj (with vt), lighting.exr and `views/<name>/{image.exr, mask.png, camera.json}`.
    #[arg(long)]
    pub captures: PathBuf,
    /// The probe folder to write (whole or not at all): probe.json, mesh.obj, albedo.exr,
    /// roughness.exr, visibility.exr, and beside them coverage.exr, report.json, preview.png.
    #[arg(long)]
    pub out: PathBuf,
    /// Texture size, WIDTHxHEIGHT.
    #[arg(long, default_value = "512x256")]
    pub texture_size: String,
    #[command(flatten)]
    pub quality: QualityArg,
    #[command(flatten)]
    pub threads: ThreadsArg,
    /// Texture solve: least-squares (a roughness search, a grooved scan's
    /// turn by the same search, and an exact albedo solve) or adam (Adam on
    /// the re-rendering error: several times slower, and less accurate on
    /// the capture benchmark's train probes, see docs/results/acquisition.md 17.4).
    #[arg(long, default_value = "least-squares")]
    pub solver: String,
    /// on: the pose refined against the views' pixels once the textures are
    /// fitted, and the textures solved again at it (more than twice the
    /// texture time; not yet better on the Mitsuba captures); off: the
    /// silhouettes' pose.
    #[arg(long, default_value = "off")]
    pub registration: String,
    /// Weight of the albedo's smoothness prior (default: the preset's):
    /// higher fills unseen or noisy texels more smoothly and blurs printed detail.
    #[arg(long)]
    pub albedo_smoothness: Option<f64>,
    /// Weight of the roughness's smoothness prior (default: the preset's).
    #[arg(long)]
    pub roughness_smoothness: Option<f64>,
}

/// A prior's weight from its flag: finite and not negative.
fn weight(flag: &str, value: Option<f64>, preset: f64) -> Result<f64> {
    match value {
        None => Ok(preset),
        Some(w) if w.is_finite() && w >= 0.0 => Ok(w),
        Some(w) => Err(Error::invalid(flag, format!("{w}: a weight is finite and at least 0"))),
    }
}

/// The texture solve of `--solver`.
fn parse_solver(s: &str) -> Result<Solver> {
    match s {
        "adam" => Ok(Solver::Adam),
        "least-squares" => Ok(Solver::LeastSquares),
        _ => Err(Error::invalid(
            "--solver",
            format!("`{s}` is not adam or least-squares"),
        )),
    }
}

/// The texture size of `--texture-size`.
fn parse_texture_size(s: &str) -> Result<[usize; 2]> {
    let sides = MIN_SIDE..=MAX_SIDE;
    let what = format!("each side from {MIN_SIDE} to {MAX_SIDE}");
    let (w, h) = parse_dimensions(s, "--texture-size", &what, |w, h| {
        sides.contains(&w) && sides.contains(&h)
    })?;
    Ok([w, h])
}

/// The texture sides accepted: a side below 4 texels holds no pattern; one
/// above 4096 is more unknowns than views of a few hundred pixels can fix.
const MIN_SIDE: usize = 4;
const MAX_SIDE: usize = 4096;

/// Reads and checks the capture, acquires the probe and writes the folder.
pub fn run(args: &AcquireArgs) -> Result<()> {
    let size = parse_texture_size(&args.texture_size)?;
    let mut settings = AcquireSettings::preset(args.quality.preset()?);
    settings.solver = parse_solver(&args.solver)?;
    match args.registration.as_str() {
        "on" => settings.registration = Some(RegistrationSettings::preset(settings.quality)),
        "off" => {}
        other => return Err(Error::invalid("--registration", format!("`{other}` is not on or off"))),
    }
    let (albedo, roughness) = match settings.solver {
        Solver::Adam => (
            &mut settings.material.albedo_smoothness,
            &mut settings.material.roughness_smoothness,
        ),
        Solver::LeastSquares => (
            &mut settings.least_squares.albedo_smoothness,
            &mut settings.least_squares.roughness_smoothness,
        ),
    };
    *albedo = weight("--albedo-smoothness", args.albedo_smoothness, *albedo)?;
    *roughness = weight("--roughness-smoothness", args.roughness_smoothness, *roughness)?;
    let pool = args.threads.pool()?;
    let capture = Capture::read(&args.captures)?;
    let truth = Truth::read(&args.captures)?;
    let name = args
        .out
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| "probe".to_string());
    let verbose = std::io::stderr().is_terminal();
    let bar = progress_bar(verbose, "alp acquire {bar:30} {pos}/{len} {msg}, {elapsed}");
    let result = pool.install(|| {
        acquire(
            &capture,
            &name,
            size,
            &GgxMetal,
            &settings,
            truth.as_ref(),
            &|phase, done, all| {
                bar.set_length(all as u64);
                bar.set_position(done as u64);
                bar.set_message(phase.to_string());
            },
        )
    });
    bar.finish_and_clear();
    let acquisition = result?;
    if verbose {
        let report = &acquisition.report;
        let psnr = report.views.iter().map(|v| v.psnr_db).sum::<f64>() / report.views.len() as f64;
        eprintln!(
            "  mean PSNR {psnr:.2} dB over {} views, mean coverage {:.2}, {:.1} s",
            report.views.len(),
            report.mean_coverage,
            report.seconds.total
        );
    }
    crate::output::write_folder_atomically(&args.out, |dir| write(dir, &capture, &acquisition))
}

/// The probe folder's files.
fn write(dir: &std::path::Path, capture: &Capture, acquisition: &Acquisition) -> Result<()> {
    acquisition.asset.write(dir)?;
    acquisition.coverage.write_exr(dir.join("coverage.exr"))?;
    preview(capture, acquisition).write_png_preview(dir.join("preview.png"), 0.0)?;
    let path = dir.join("report.json");
    let json = serde_json::to_string_pretty(&acquisition.report).map_err(|e| RenderError::io(&path, "serialise", e))?;
    std::fs::write(&path, json + "\n").map_err(|e| RenderError::io(&path, "write", e).into())
}

/// Height of each row of the preview, pixels.
const PREVIEW_ROW_PX: usize = 160;
/// Views shown in the preview (spread over the capture).
const PREVIEW_VIEWS: usize = 4;

/// The textures (albedo, roughness, visibility, coverage) in a row, and
/// below it a few views, each photo beside its re-render (both exposed so
/// the view's mean in the mask is mid-grey).
fn preview(capture: &Capture, acquisition: &Acquisition) -> RgbImage {
    let asset = &acquisition.asset;
    let mut rows = vec![hstack(&[
        &asset.albedo.image,
        &asset.roughness.image,
        &asset.visibility.image,
        &acquisition.coverage,
    ])];
    let shown = PREVIEW_VIEWS.min(capture.views.len());
    for k in 0..shown {
        let v = k * capture.views.len() / shown;
        let photo = &capture.views[v].photo;
        let inside: Vec<&[f32; 3]> = photo
            .image
            .pixels
            .iter()
            .zip(&photo.mask.inside)
            .filter(|(_, inside)| **inside)
            .map(|(p, _)| p)
            .collect();
        let mean = inside.iter().map(|p| (p[0] + p[1] + p[2]) / 3.0).sum::<f32>() / inside.len().max(1) as f32;
        let exposure = if mean > 0.0 { 0.18 / mean } else { 1.0 };
        let exposed = |image: &RgbImage| {
            RgbImage::new(
                image.width,
                image.height,
                image.pixels.iter().map(|p| p.map(|c| c * exposure)).collect(),
            )
        };
        rows.push(hstack(&[&exposed(&photo.image), &exposed(&acquisition.rerenders[v])]));
    }
    vstack(&rows)
}

/// `image` scaled (nearest texel) to `height` rows.
fn scaled(image: &RgbImage, height: usize) -> RgbImage {
    let width = (image.width * height).div_ceil(image.height).max(1);
    let pixels = (0..width * height)
        .map(|p| {
            let (row, col) = (p / width * image.height / height, p % width * image.width / width);
            image.get(row, col)
        })
        .collect();
    RgbImage::new(width, height, pixels)
}

/// Images side by side, each scaled to [`PREVIEW_ROW_PX`] rows.
fn hstack(images: &[&RgbImage]) -> RgbImage {
    let scaled: Vec<RgbImage> = images.iter().map(|i| scaled(i, PREVIEW_ROW_PX)).collect();
    let width: usize = scaled.iter().map(|i| i.width).sum();
    let mut pixels = Vec::with_capacity(width * PREVIEW_ROW_PX);
    for row in 0..PREVIEW_ROW_PX {
        for image in &scaled {
            pixels.extend_from_slice(&image.pixels[row * image.width..(row + 1) * image.width]);
        }
    }
    RgbImage::new(width, PREVIEW_ROW_PX, pixels)
}

/// Rows one above the other, left-aligned on black.
fn vstack(rows: &[RgbImage]) -> RgbImage {
    let width = rows.iter().map(|r| r.width).max().unwrap_or(1);
    let height: usize = rows.iter().map(|r| r.height).sum();
    let mut out = RgbImage::filled(width, height, [0.0; 3]);
    let mut top = 0;
    for r in rows {
        for row in 0..r.height {
            let at = (top + row) * width;
            out.pixels[at..at + r.width].copy_from_slice(&r.pixels[row * r.width..(row + 1) * r.width]);
        }
        top += r.height;
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn texture_sizes_parse_within_their_range() {
        assert_eq!(parse_texture_size("512x256").expect("valid"), [512, 256]);
        for bad in ["512", "512x", "x256", "2x256", "512x5000", "a x b"] {
            let err = parse_texture_size(bad).expect_err(bad).to_string();
            assert!(err.contains("--texture-size"), "{bad}: {err}");
        }
    }
}
