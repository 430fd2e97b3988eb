//! `alp insert`: a virtual object rendered into a photo under its estimated lighting.

use std::path::PathBuf;

use render::camera::Camera;
use render::envmap::EnvMap;
use render::pose::Pose;

use super::{Finish, Ground, InsertSettings, MaterialSpec, VirtualObject, insert};
use crate::error::{Error, Result};
use crate::output::write_image_and_preview;

/// Flags of `alp insert`.
#[derive(clap::Args, Debug)]
pub struct InsertArgs {
    /// The photo: linear HDR (OpenEXR or Radiance .hdr), or an 8/16-bit sRGB PNG or JPEG (linearised, with a warning).
    #[arg(long)]
    pub image: PathBuf,
    /// The lighting: an env map (e.g. `alp estimate`'s env.exr).
    #[arg(long)]
    pub env: PathBuf,
    /// camera.json of the photo.
    #[arg(long)]
    pub camera: PathBuf,
    /// The object: a probe folder or procedural name (can, cap, sphere), or an OBJ mesh (metres).
    #[arg(long)]
    pub object: PathBuf,
    /// pose.json: the object's mesh-to-world transform.
    #[arg(long)]
    pub pose: PathBuf,
    /// Output image (linear EXR); a tone-mapped PNG is written beside it.
    #[arg(long)]
    pub out: PathBuf,
    /// The object's material: diffuse, metal or mirror, or a JSON file
    /// (`{"type": "metal", "albedo": [r, g, b], "roughness": 0.3}`); needed for an OBJ,
    /// replaces a probe's own.
    #[arg(long)]
    pub material: Option<String>,
    /// Albedo of a --material given by name: R,G,B or one grey value, in [0, 1] [default: 0.8].
    #[arg(long)]
    pub albedo: Option<String>,
    /// GGX roughness of --material metal, in [0, 1] [default: 0.3].
    #[arg(long)]
    pub roughness: Option<f32>,
    /// The shadow-catching ground plane: auto (through the object's lowest point), none, or its height y (metres).
    #[arg(long, default_value = "auto")]
    pub ground: Ground,
    /// Samples per pixel of the object, and shadow samples per ground pixel.
    #[arg(long, default_value_t = 64)]
    pub spp: u32,
    /// Random seed (same seed, same image, on any number of threads).
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
}

/// The material the flags give, if any.
fn material(args: &InsertArgs) -> Result<Option<MaterialSpec>> {
    let Some(given) = &args.material else {
        if args.albedo.is_some() || args.roughness.is_some() {
            return Err(Error::invalid(
                "--albedo/--roughness",
                "apply to a --material given by name",
            ));
        }
        return Ok(None);
    };
    if given.to_ascii_lowercase().ends_with(".json") {
        if args.albedo.is_some() || args.roughness.is_some() {
            return Err(Error::invalid(
                "--albedo/--roughness",
                "apply to a --material given by name; a material file holds its own",
            ));
        }
        return MaterialSpec::read(std::path::Path::new(given)).map(Some);
    }
    let finish = Finish::parse(given).ok_or_else(|| {
        Error::invalid(
            "--material",
            format!("`{given}` is neither {} nor a .json file", Finish::NAMES),
        )
    })?;
    let albedo = args.albedo.as_deref().map(parse_albedo).transpose()?;
    let spec = MaterialSpec {
        finish,
        albedo,
        roughness: args.roughness,
    };
    spec.check()
        .map_err(|e| Error::invalid(format!("--{}", e.field_name().unwrap_or("material")), e.rule()))?;
    Ok(Some(spec))
}

/// `R,G,B` or one grey value.
fn parse_albedo(s: &str) -> Result<[f32; 3]> {
    let bad = || Error::invalid("--albedo", format!("`{s}` is neither R,G,B nor one number"));
    let values: Vec<f32> = s
        .split(',')
        .map(|v| v.trim().parse::<f32>().map_err(|_| bad()))
        .collect::<Result<_>>()?;
    match values[..] {
        [v] => Ok([v; 3]),
        [r, g, b] => Ok([r, g, b]),
        _ => Err(bad()),
    }
}

/// Renders the object into the photo and writes `--out` (EXR) and its PNG.
pub fn run(args: &InsertArgs) -> Result<()> {
    let material = material(args)?;
    let object = VirtualObject::load(&args.object, material.as_ref())?;
    let (photo, _) = crate::cli::photo::read_photo(&args.image)?;
    let env = EnvMap::read(&args.env)?;
    let camera = Camera::read(&args.camera)?;
    let pose = Pose::read(&args.pose)?;
    let settings = InsertSettings {
        spp: args.spp,
        seed: args.seed,
        ground: args.ground,
    };
    let insertion = insert(&photo, &env, &camera, &object, &pose, &settings).map_err(|e| match e.field_name() {
        Some(field) if !field.starts_with("--") => Error::invalid(format!("--{field}"), e.rule()),
        _ => e,
    })?;
    if !insertion.object_visible() {
        eprintln!(
            "alp: warning: the object is not in the camera's view at this pose; the photo is unchanged but for its shadow"
        );
    }
    write_image_and_preview(&args.out, &insertion.image)
}
