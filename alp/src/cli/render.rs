//! `alp render`: a probe at a pose under an env map, rendered.

use std::path::PathBuf;

use render::bsdf::GgxMetal;
use render::camera::Camera;
use render::envmap::EnvMap;
use render::integrator::{RenderSettings, render_image};
use render::pose::Pose;

use crate::{Error, Result};

/// Flags of `alp render`.
#[derive(clap::Args, Debug)]
pub struct RenderArgs {
    /// Probe folder (probe.json), or a procedural probe name (can, cap, sphere).
    #[arg(long)]
    pub probe: PathBuf,
    /// pose.json: the probe's mesh-to-world transform.
    #[arg(long)]
    pub pose: PathBuf,
    /// camera.json.
    #[arg(long)]
    pub camera: PathBuf,
    /// Environment map (equirectangular linear EXR, width = 2 x height).
    #[arg(long)]
    pub env: PathBuf,
    /// Output image (linear EXR); a tone-mapped PNG preview is written beside it.
    #[arg(long)]
    pub out: PathBuf,
    /// Samples per pixel.
    #[arg(long, default_value_t = 64)]
    pub spp: u32,
    /// Also write the probe's coverage mask (8-bit PNG, 255 = probe).
    #[arg(long)]
    pub mask_out: Option<PathBuf>,
    /// Random seed (same seed, same image, on any number of threads).
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
}

/// Renders the probe; writes the EXR, its preview and (`--mask-out`) the coverage.
pub fn run(args: &RenderArgs) -> Result<()> {
    if args.spp == 0 {
        return Err(Error::invalid("--spp", "needs at least one sample per pixel"));
    }
    let probe = crate::probes::load(&args.probe)?;
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
    crate::output::write_image_and_preview(&args.out, &image)?;
    if let Some(path) = &args.mask_out {
        mask.write_png(path)?;
    }
    Ok(())
}
