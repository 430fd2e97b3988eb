//! The probe catalogue: procedural probes by name, and probe folders.

use std::path::Path;

use render::probe::ProbeAsset;
use render::procedural::{SodaCan, ThermosCap, UvSphere};

use crate::error::{Error, Result};

/// The procedural probes `alp probe make` writes.
pub const PROCEDURAL: [&str; 3] = ["can", "cap", "sphere"];

/// Radius of the procedural `sphere`, metres.
pub const SPHERE_RADIUS: f32 = 0.03;

/// Builds a procedural probe: `can` (a soda can), `cap` (a thermos cap) or
/// `sphere` (a 3 cm sphere with the evaluation's "shiny" roughness).
pub fn procedural(kind: &str) -> Result<ProbeAsset> {
    match kind {
        "can" | "soda_can" => Ok(SodaCan::default().build()),
        "cap" | "thermos_cap" => Ok(ThermosCap::default().build()),
        "sphere" => Ok(UvSphere {
            radius: SPHERE_RADIUS,
            ..UvSphere::default()
        }
        .build()),
        other => Err(Error::invalid(
            "probe kind",
            format!("unknown procedural probe `{other}` (known: {})", PROCEDURAL.join(", ")),
        )),
    }
}

/// Reads a probe folder, or builds a procedural probe when `name_or_dir` is
/// one of [`PROCEDURAL`] and no folder of that name exists.
pub fn load(name_or_dir: &Path) -> Result<ProbeAsset> {
    if !name_or_dir.exists()
        && let Some(kind) = name_or_dir.to_str()
        && PROCEDURAL.contains(&kind)
    {
        return procedural(kind);
    }
    Ok(ProbeAsset::read(name_or_dir)?)
}
