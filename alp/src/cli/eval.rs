//! `alp eval`: an estimate's relighting (and pose) errors against a scene's truth.

use std::path::PathBuf;

use render::envmap::EnvMap;
use render::pose::Pose;

use crate::Result;
use crate::relight::RelightSettings;

/// Flags of `alp eval`.
#[derive(clap::Args, Debug)]
pub struct EvalArgs {
    /// Scene folder (camera.json, gt_env.exr, and pose.json when --pose is given).
    #[arg(long)]
    pub scene: PathBuf,
    /// The estimated environment map.
    #[arg(long)]
    pub env: PathBuf,
    /// An estimated pose.json, compared with the scene's pose.json.
    #[arg(long)]
    pub pose: Option<PathBuf>,
    /// Samples per pixel of the relit spheres, a square.
    #[arg(long, default_value_t = crate::relight::DEFAULT_SPP)]
    pub spp: u32,
    /// Random seed (both maps are relit with the same random numbers).
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
}

/// Prints the errors as one JSON line.
pub fn run(args: &EvalArgs) -> Result<()> {
    let env = EnvMap::read(&args.env)?;
    let pose = args.pose.as_ref().map(Pose::read).transpose()?;
    let settings = RelightSettings {
        spp: args.spp,
        seed: args.seed,
    };
    let report = crate::eval::evaluate_scene(&args.scene, &env, pose.as_ref(), &settings)?;
    println!("{}", report.to_json_line());
    Ok(())
}
