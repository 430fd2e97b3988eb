//! The `alp` command line.

use std::path::{Path, PathBuf};
use std::process::ExitCode;

use clap::{Parser, Subcommand};
use render::bsdf::GgxMetal;
use render::camera::Camera;
use render::envmap::EnvMap;
use render::integrator::{RenderSettings, render_image};
use render::pose::Pose;
use render::{RenderError, Result};

/// Accidental light probes: lighting from a photo of a known shiny object.
#[derive(Parser)]
#[command(name = "alp", version, about)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Render a probe at a pose under an environment map (linear EXR plus a PNG preview).
    Render(RenderArgs),
    /// Procedural probes.
    Probe {
        #[command(subcommand)]
        action: ProbeAction,
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
        Command::Render(args) => render(&args),
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
        return Err(RenderError::value("--spp", "needs at least one sample per pixel"));
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
    image.write_exr(&args.out)?;
    image.write_png_preview(preview_path(&args.out), 0.0)?;
    if let Some(path) = &args.mask_out {
        mask.write_png(path)?;
    }
    Ok(())
}

/// `image.exr` -> `image.png`.
fn preview_path(out: &Path) -> PathBuf {
    out.with_extension("png")
}

fn make_probe(kind: &str, out: &Path) -> Result<()> {
    let probe = alp::probes::procedural(kind)?;
    alp::output::write_folder_atomically(out, |dir| probe.write(dir))
}
