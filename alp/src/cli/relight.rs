//! `alp relight`: the evaluation's three spheres under an env map.

use std::path::PathBuf;

use render::camera::Camera;
use render::envmap::EnvMap;

use crate::Result;
use crate::relight::RelightSettings;

/// Flags of `alp relight`.
#[derive(clap::Args, Debug)]
pub struct RelightArgs {
    /// Environment map (equirectangular linear EXR, width = 2 x height).
    #[arg(long)]
    pub env: PathBuf,
    /// camera.json: the spheres are seen along its viewing direction, with its `up`.
    #[arg(long)]
    pub camera: PathBuf,
    /// Output image (linear EXR; mirror, shiny, diffuse left to right); a PNG preview is written beside it.
    #[arg(long)]
    pub out: PathBuf,
    /// Samples per pixel, a square (n x n stratified sub-pixel positions and BRDF samples).
    #[arg(long, default_value_t = crate::relight::DEFAULT_SPP)]
    pub spp: u32,
    /// Random seed.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
}

/// Relights the spheres; writes the side-by-side EXR and its preview.
pub fn run(args: &RelightArgs) -> Result<()> {
    let env = EnvMap::read(&args.env)?;
    let camera = Camera::read(&args.camera)?;
    let settings = RelightSettings {
        spp: args.spp,
        seed: args.seed,
    };
    let spheres = crate::relight::relight(&env, &camera, &settings)?;
    let image = spheres.side_by_side();
    crate::output::write_image_and_preview(&args.out, &image)
}
