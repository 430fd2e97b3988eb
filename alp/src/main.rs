//! The `alp` command line.

use std::path::{Path, PathBuf};
use std::process::ExitCode;

use alp::relight::RelightSettings;
use alp::synth::{CaptureSettings, SynthSettings};
use alp::{Error, Result};
use clap::{Parser, Subcommand};
use render::bsdf::GgxMetal;
use render::camera::Camera;
use render::envmap::EnvMap;
use render::integrator::{RenderSettings, render_image};
use render::pose::Pose;

/// Accidental light probes: lighting from a photo of a known shiny object.
#[derive(Parser)]
#[command(name = "alp", version, about)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// The first run: a photo of a soda can rendered from bundled data, its pose and lighting
    /// estimated, spheres relit and an object inserted under the estimate and the truth;
    /// writes OUT/index.html to look at, and report.json.
    Demo {
        /// The folder to write (written whole or not at all).
        #[arg(long, default_value = "demo")]
        out: PathBuf,
    },
    /// Estimate the lighting and the probe's pose from a photo (the main job).
    Estimate(alp::estimate::cli::EstimateArgs),
    /// The estimate over a dataset: a manifest of photos, sharded over machines, resumable.
    Batch(alp::batch::BatchArgs),
    /// Make a probe asset from a capture: many views of the object under known lighting.
    Acquire(alp::acquire::cli::AcquireArgs),
    /// Insert a virtual object into a photo under its estimated lighting, with the shadow it
    /// casts on a ground plane (differential rendering): linear EXR plus a PNG.
    Insert(alp::insert::cli::InsertArgs),
    /// Render a probe at a pose under an environment map (linear EXR plus a PNG preview).
    Render(RenderArgs),
    /// Render the evaluation's mirror, shiny and diffuse spheres under an env map (768x256 EXR, left to right).
    Relight(RelightArgs),
    /// Relighting errors of an estimated env map (and pose errors of an estimated pose) against a scene's truth.
    Eval(EvalArgs),
    /// Make a synthetic evaluation scene: a probe at a random pose, random camera, known lighting
    /// (or, `alp synth captures`, a capture folder of a known probe for its acquisition).
    Synth(SynthCommand),
    /// Procedural probes.
    Probe {
        #[command(subcommand)]
        action: ProbeAction,
    },
    /// Studies of the estimate on a set of scenes, with tables and charts: speed against accuracy.
    Study {
        #[command(subcommand)]
        study: alp::study::cli::StudyCommand,
    },
}

#[derive(clap::Args)]
struct RenderArgs {
    /// Probe folder (probe.json), or a procedural probe name (can, cap, sphere).
    #[arg(long)]
    probe: PathBuf,
    /// pose.json: the probe's mesh-to-world transform.
    #[arg(long)]
    pose: PathBuf,
    /// camera.json.
    #[arg(long)]
    camera: PathBuf,
    /// Environment map (equirectangular linear EXR, width = 2 x height).
    #[arg(long)]
    env: PathBuf,
    /// Output image (linear EXR); a tone-mapped PNG preview is written beside it.
    #[arg(long)]
    out: PathBuf,
    /// Samples per pixel.
    #[arg(long, default_value_t = 64)]
    spp: u32,
    /// Also write the probe's coverage mask (8-bit PNG, 255 = probe).
    #[arg(long)]
    mask_out: Option<PathBuf>,
    /// Random seed (same seed, same image, on any number of threads).
    #[arg(long, default_value_t = 0)]
    seed: u64,
}

#[derive(clap::Args)]
struct RelightArgs {
    /// Environment map (equirectangular linear EXR, width = 2 x height).
    #[arg(long)]
    env: PathBuf,
    /// camera.json: the spheres are seen along its viewing direction, with its `up`.
    #[arg(long)]
    camera: PathBuf,
    /// Output image (linear EXR; mirror, shiny, diffuse left to right); a PNG preview is written beside it.
    #[arg(long)]
    out: PathBuf,
    /// Samples per pixel, a square (n x n stratified sub-pixel positions and BRDF samples).
    #[arg(long, default_value_t = alp::relight::DEFAULT_SPP)]
    spp: u32,
    /// Random seed.
    #[arg(long, default_value_t = 0)]
    seed: u64,
}

#[derive(clap::Args)]
struct EvalArgs {
    /// Scene folder (camera.json, gt_env.exr, and pose.json when --pose is given).
    #[arg(long)]
    scene: PathBuf,
    /// The estimated environment map.
    #[arg(long)]
    env: PathBuf,
    /// An estimated pose.json, compared with the scene's pose.json.
    #[arg(long)]
    pose: Option<PathBuf>,
    /// Samples per pixel of the relit spheres, a square.
    #[arg(long, default_value_t = alp::relight::DEFAULT_SPP)]
    spp: u32,
    /// Random seed (both maps are relit with the same random numbers).
    #[arg(long, default_value_t = 0)]
    seed: u64,
}

#[derive(clap::Args)]
#[command(args_conflicts_with_subcommands = true)]
struct SynthCommand {
    #[command(subcommand)]
    what: Option<SynthWhat>,
    #[command(flatten)]
    scene: Option<SynthArgs>,
}

#[derive(Subcommand)]
enum SynthWhat {
    /// Render a capture folder of a known probe (FORMATS.md, "Capture folder"): views on rings
    /// round it standing at the origin, as on a turntable; the mesh written in a random frame and
    /// scale, its true mesh-to-world pose in true_pose.json.
    Captures(CaptureArgs),
    /// Write beside a scene's exact photo and mask the inputs people have of it: a mask traced
    /// by hand (mask_traced.png), a segmenter's (mask_segmenter.png), the photo blurred
    /// (image_blur.exr), as an 8-bit JPEG (image.jpg), a box round the probe (box.txt), and
    /// what was drawn (inputs.json).
    Inputs(InputsArgs),
}

#[derive(clap::Args)]
struct InputsArgs {
    /// Scene folder: image.exr, mask.png (exact) and camera.json; the inputs are written into it.
    #[arg(long)]
    scene: PathBuf,
    /// Seed of every draw.
    #[arg(long, default_value_t = 0)]
    seed: u64,
}

#[derive(clap::Args)]
struct CaptureArgs {
    /// Probe folder (probe.json), or a procedural probe name (can, cap, sphere).
    #[arg(long)]
    probe: PathBuf,
    /// Environment map lighting every view (written to the capture as lighting.exr).
    #[arg(long)]
    env: PathBuf,
    /// Number of views.
    #[arg(long, default_value_t = 24)]
    views: usize,
    /// The capture folder to write.
    #[arg(long)]
    out: PathBuf,
    /// Seed of every random choice (the scan's frame, the rings, the renders, the noise).
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Relative standard deviation of multiplicative Gaussian noise.
    #[arg(long, default_value_t = 0.0)]
    noise: f32,
    /// Samples per pixel of each view.
    #[arg(long, default_value_t = 64)]
    spp: u32,
    /// Image width, pixels.
    #[arg(long, default_value_t = 320)]
    width: u32,
    /// Image height, pixels.
    #[arg(long, default_value_t = 240)]
    height: u32,
}

#[derive(clap::Args)]
struct SynthArgs {
    /// Probe folder (probe.json), or a procedural probe name (can, cap, sphere).
    #[arg(long)]
    probe: PathBuf,
    /// Environment map lighting the scene (written to the scene as gt_env.exr).
    #[arg(long)]
    env: PathBuf,
    /// The scene folder to write.
    #[arg(long)]
    out: PathBuf,
    /// Seed of every random choice (camera, pose, render, noise).
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Relative standard deviation of multiplicative Gaussian noise.
    #[arg(long, default_value_t = 0.0)]
    noise: f32,
    /// Clamp radiance above this value (sensor saturation); default: no clipping.
    #[arg(long)]
    exposure_clip: Option<f32>,
    /// Samples per pixel of the render.
    #[arg(long, default_value_t = 256)]
    spp: u32,
    /// Tilt the probe up to ~60 degrees or lay it on its side (default: upright, random turn).
    #[arg(long)]
    tilted: bool,
    /// Image width, pixels.
    #[arg(long, default_value_t = 640)]
    width: u32,
    /// Image height, pixels.
    #[arg(long, default_value_t = 480)]
    height: u32,
}

#[derive(Subcommand)]
enum ProbeAction {
    /// Write a procedural probe folder.
    Make {
        /// can (soda can), cap (thermos cap) or sphere.
        kind: String,
        /// The folder to write.
        #[arg(long)]
        out: PathBuf,
    },
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Demo { out } => demo(&out),
        Command::Estimate(args) => alp::estimate::cli::run(&args),
        Command::Acquire(args) => alp::acquire::cli::run(&args),
        Command::Batch(args) => alp::batch::cli(&args),
        Command::Study { study } => alp::study::cli::run(&study),
        Command::Insert(args) => alp::insert::cli::run(&args),
        Command::Render(args) => render(&args),
        Command::Relight(args) => relight(&args),
        Command::Eval(args) => eval(&args),
        Command::Synth(SynthCommand {
            what: Some(SynthWhat::Captures(args)),
            ..
        }) => synth_captures(&args),
        Command::Synth(SynthCommand {
            what: Some(SynthWhat::Inputs(args)),
            ..
        }) => synth_inputs(&args),
        Command::Synth(SynthCommand { scene: Some(args), .. }) => synth(&args),
        Command::Synth(_) => Err(Error::invalid(
            "alp synth",
            "needs --probe, --env and --out (a scene), or `captures` (see alp synth --help)",
        )),
        Command::Probe {
            action: ProbeAction::Make { kind, out },
        } => make_probe(&kind, &out),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("alp: error: {e}");
            ExitCode::from(2)
        }
    }
}

fn render(args: &RenderArgs) -> Result<()> {
    if args.spp == 0 {
        return Err(Error::invalid("--spp", "needs at least one sample per pixel"));
    }
    let probe = alp::probes::load(&args.probe)?;
    let pose = Pose::read(&args.pose)?;
    let camera = Camera::read(&args.camera)?;
    let env = EnvMap::read(&args.env)?;
    let settings = RenderSettings {
        spp: args.spp,
        seed: args.seed,
    };
    let (image, mask) = render_image(&probe, &pose, &camera, &env, &GgxMetal, &settings);
    if mask.count() == 0 {
        eprintln!("alp: warning: the probe is not visible from this camera; the image is black");
    }
    alp::output::write_image_and_preview(&args.out, &image)?;
    if let Some(path) = &args.mask_out {
        mask.write_png(path)?;
    }
    Ok(())
}

fn relight(args: &RelightArgs) -> Result<()> {
    let env = EnvMap::read(&args.env)?;
    let camera = Camera::read(&args.camera)?;
    let settings = RelightSettings {
        spp: args.spp,
        seed: args.seed,
    };
    let spheres = alp::relight::relight(&env, &camera, &settings)?;
    let image = spheres.side_by_side();
    alp::output::write_image_and_preview(&args.out, &image)
}

fn eval(args: &EvalArgs) -> Result<()> {
    let env = EnvMap::read(&args.env)?;
    let pose = args.pose.as_ref().map(Pose::read).transpose()?;
    let settings = RelightSettings {
        spp: args.spp,
        seed: args.seed,
    };
    let report = alp::eval::evaluate_scene(&args.scene, &env, pose.as_ref(), &settings)?;
    println!("{}", report.to_json_line());
    Ok(())
}

fn synth(args: &SynthArgs) -> Result<()> {
    let probe = alp::probes::load(&args.probe)?;
    let env = EnvMap::read(&args.env)?;
    let settings = SynthSettings {
        seed: args.seed,
        noise: args.noise,
        exposure_clip: args.exposure_clip,
        spp: args.spp,
        tilted: args.tilted,
        width: args.width,
        height: args.height,
    };
    let scene = alp::synth::synthesize(&probe, &env, &settings)?;
    if scene.mask.count() == 0 {
        return Err(Error::invalid(
            "--probe",
            "the probe is not visible in the synthetic view",
        ));
    }
    let reference = alp::synth::probe_reference(&args.probe, &args.out)?;
    alp::synth::write_scene(&args.out, &scene, &env, &reference)
}

fn synth_inputs(args: &InputsArgs) -> Result<()> {
    let dir = &args.scene;
    let image = render::image_io::RgbImage::read_exr(dir.join("image.exr"))?;
    let mask = render::image_io::Mask::read_png(dir.join("mask.png"))?;
    let camera = Camera::read(dir.join("camera.json"))?;
    let photo = alp::estimate::Photo::new(image, mask, camera).map_err(|e| e.in_file(dir.join("image.exr")))?;
    let inputs = alp::study::inputs::draw(&photo, args.seed)?;
    alp::study::inputs::write(dir, &inputs)
}

fn synth_captures(args: &CaptureArgs) -> Result<()> {
    let probe = alp::probes::load(&args.probe)?;
    let env = EnvMap::read(&args.env)?;
    let settings = CaptureSettings {
        seed: args.seed,
        views: args.views,
        noise: args.noise,
        spp: args.spp,
        width: args.width,
        height: args.height,
    };
    let capture = alp::synth::synthesize_capture(&probe, &env, &GgxMetal, &settings)?;
    alp::synth::write_capture(&args.out, &capture)
}

fn demo(out: &Path) -> Result<()> {
    eprintln!("alp demo: rendering a photo of a soda can, estimating its pose and lighting (about half a minute)");
    let report = alp::demo::run(out)?;
    let shown = out.canonicalize().unwrap_or_else(|_| out.to_path_buf());
    println!(
        "Relighting errors of the estimated map (angular, degrees): mirror {:.2}, shiny {:.2}, diffuse {:.2}",
        report.mirror.angular_deg, report.shiny.angular_deg, report.diffuse.angular_deg
    );
    println!(
        "Pose errors: rotation {:.2} deg, translation {:.1} mm; re-render PSNR {:.1} dB",
        report.pose.rotation_deg, report.pose.translation_mm, report.psnr_db
    );
    println!("Look at {}", shown.join("index.html").display());
    println!("  scene/     the photo, its mask, camera, true pose and map");
    println!("  estimate/  env.exr, pose.json, confidence.exr, rerender.exr, mask_found.png, report.json");
    println!("  report.json, and the figures as PNG");
    Ok(())
}

fn make_probe(kind: &str, out: &Path) -> Result<()> {
    let probe = alp::probes::procedural(kind)?;
    alp::output::write_folder_atomically(out, |dir| Ok(probe.write(dir)?))
}
