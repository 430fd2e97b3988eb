//! `alp synth`: a synthetic scene, a capture folder, or the inputs people
//! have of a scene.

use std::path::PathBuf;

use render::bsdf::GgxMetal;
use render::camera::Camera;
use render::envmap::EnvMap;

use crate::synth::{CaptureSettings, SynthSettings};
use crate::{Error, Result};

/// `alp synth`: a scene (its flags), or one of its subcommands.
#[derive(clap::Args, Debug)]
#[command(args_conflicts_with_subcommands = true)]
pub struct SynthCommand {
    #[command(subcommand)]
    pub what: Option<SynthWhat>,
    #[command(flatten)]
    pub scene: Option<SynthArgs>,
}

#[derive(clap::Subcommand, Debug)]
pub enum SynthWhat {
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

#[derive(clap::Args, Debug)]
pub struct InputsArgs {
    /// Scene folder: image.exr, mask.png (exact) and camera.json; the inputs are written into it.
    #[arg(long)]
    pub scene: PathBuf,
    /// Seed of every draw.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
}

#[derive(clap::Args, Debug)]
pub struct CaptureArgs {
    /// Probe folder (probe.json), or a procedural probe name (can, cap, sphere).
    #[arg(long)]
    pub probe: PathBuf,
    /// Environment map lighting every view (written to the capture as lighting.exr).
    #[arg(long)]
    pub env: PathBuf,
    /// Number of views.
    #[arg(long, default_value_t = 24)]
    pub views: usize,
    /// The capture folder to write.
    #[arg(long)]
    pub out: PathBuf,
    /// Seed of every random choice (the scan's frame, the rings, the renders, the noise).
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Relative standard deviation of multiplicative Gaussian noise.
    #[arg(long, default_value_t = 0.0)]
    pub noise: f32,
    /// Samples per pixel of each view.
    #[arg(long, default_value_t = 64)]
    pub spp: u32,
    /// Image width, pixels.
    #[arg(long, default_value_t = 320)]
    pub width: u32,
    /// Image height, pixels.
    #[arg(long, default_value_t = 240)]
    pub height: u32,
}

#[derive(clap::Args, Debug)]
pub struct SynthArgs {
    /// Probe folder (probe.json), or a procedural probe name (can, cap, sphere).
    #[arg(long)]
    pub probe: PathBuf,
    /// Environment map lighting the scene (written to the scene as gt_env.exr).
    #[arg(long)]
    pub env: PathBuf,
    /// The scene folder to write.
    #[arg(long)]
    pub out: PathBuf,
    /// Seed of every random choice (camera, pose, render, noise).
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Relative standard deviation of multiplicative Gaussian noise.
    #[arg(long, default_value_t = 0.0)]
    pub noise: f32,
    /// Clamp radiance above this value (sensor saturation); default: no clipping.
    #[arg(long)]
    pub exposure_clip: Option<f32>,
    /// Samples per pixel of the render.
    #[arg(long, default_value_t = 256)]
    pub spp: u32,
    /// Tilt the probe up to ~60 degrees or lay it on its side (default: upright, random turn).
    #[arg(long)]
    pub tilted: bool,
    /// Image width, pixels.
    #[arg(long, default_value_t = 640)]
    pub width: u32,
    /// Image height, pixels.
    #[arg(long, default_value_t = 480)]
    pub height: u32,
}

/// Runs `alp synth` as its flags or subcommand say.
pub fn run(command: &SynthCommand) -> Result<()> {
    match command {
        SynthCommand {
            what: Some(SynthWhat::Captures(args)),
            ..
        } => captures(args),
        SynthCommand {
            what: Some(SynthWhat::Inputs(args)),
            ..
        } => inputs(args),
        SynthCommand { scene: Some(args), .. } => scene(args),
        _ => Err(Error::invalid(
            "alp synth",
            "needs --probe, --env and --out (a scene), or `captures` (see alp synth --help)",
        )),
    }
}

fn scene(args: &SynthArgs) -> Result<()> {
    let probe = crate::probes::load(&args.probe)?;
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
    let scene = crate::synth::synthesize(&probe, &env, &settings)?;
    if scene.mask.count() == 0 {
        return Err(Error::invalid(
            "--probe",
            "the probe is not visible in the synthetic view",
        ));
    }
    let reference = crate::synth::probe_reference(&args.probe, &args.out)?;
    crate::synth::write_scene(&args.out, &scene, &env, &reference)
}

fn inputs(args: &InputsArgs) -> Result<()> {
    let dir = &args.scene;
    let image = render::image_io::RgbImage::read_exr(dir.join("image.exr"))?;
    let mask = render::image_io::Mask::read_png(dir.join("mask.png"))?;
    let camera = Camera::read(dir.join("camera.json"))?;
    let photo = crate::estimate::Photo::new(image, mask, camera).map_err(|e| e.in_file(dir.join("image.exr")))?;
    let inputs = crate::study::inputs::draw(&photo, args.seed)?;
    crate::study::inputs::write(dir, &inputs)
}

fn captures(args: &CaptureArgs) -> Result<()> {
    let probe = crate::probes::load(&args.probe)?;
    let env = EnvMap::read(&args.env)?;
    let settings = CaptureSettings {
        seed: args.seed,
        views: args.views,
        noise: args.noise,
        spp: args.spp,
        width: args.width,
        height: args.height,
    };
    let capture = crate::synth::synthesize_capture(&probe, &env, &GgxMetal, &settings)?;
    crate::synth::write_capture(&args.out, &capture)
}
