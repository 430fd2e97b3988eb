//! `alp eval`: an estimate's relighting (and pose) errors against a scene's truth.

use std::path::PathBuf;

use render::RenderError;
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
    /// The estimate's confidence.exr: the mirror's error is also given where the probe saw the
    /// map (confidence above one half) and where it did not.
    #[arg(long)]
    pub confidence: Option<PathBuf>,
    /// The estimate's uncertainty.exr: how often the truth lies within one and two of its
    /// standard deviations.
    #[arg(long)]
    pub uncertainty: Option<PathBuf>,
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
    let confidence = match &args.confidence {
        Some(path) => {
            let map = EnvMap::read(path)?;
            if map.radiance().iter().flatten().any(|v| !(0.0..=1.0).contains(v)) {
                let rule = "a confidence map's values lie in [0, 1] (alp estimate's confidence.exr)";
                return Err(RenderError::file(path, rule).into());
            }
            Some(map)
        }
        None => None,
    };
    let settings = RelightSettings {
        spp: args.spp,
        seed: args.seed,
    };
    let uncertainty = match &args.uncertainty {
        Some(path) => {
            let map = EnvMap::read(path)?;
            if (map.width(), map.height()) != (env.width(), env.height()) {
                let rule = format!(
                    "is {}x{} but the env map {}x{}: an uncertainty map has the map's size",
                    map.width(),
                    map.height(),
                    env.width(),
                    env.height()
                );
                return Err(RenderError::file(path, rule).into());
            }
            Some(map)
        }
        None => None,
    };
    let extras = crate::eval::EstimateExtras {
        pose: pose.as_ref(),
        confidence: confidence.as_ref(),
        uncertainty: uncertainty.as_ref(),
    };
    let report = crate::eval::evaluate_scene(&args.scene, &env, extras, &settings)?;
    println!("{}", report.to_json_line());
    Ok(())
}
