//! From your own photo to an inserted object: the probe's pose and the
//! lighting estimated from a photo (HDR, or an 8/16-bit PNG or JPEG, with a
//! warning), then a white diffuse sphere set on the ground beside the probe
//! and rendered into the photo under that lighting. See docs/own_photo.md
//! for the mask and the camera.
//!
//! ```text
//! cargo run --release -p alp --example own_photo -- PHOTO MASK CAMERA.json PROBE OUT_DIR
//! ```
//!
//! PROBE is a probe folder or `can`, `cap`, `sphere`; OUT_DIR gets `env.exr`,
//! `pose.json`, `inserted.exr` and `inserted.png`.

use std::path::{Path, PathBuf};

use glam::{Quat, Vec3};

use alp::estimate::{Photo, Quality, Settings, estimate};
use alp::insert::{Finish, Ground, InsertSettings, MaterialSpec, VirtualObject, insert};
use alp::{Error, Result};
use render::camera::Camera;
use render::image_io::{Mask, PhotoEncoding, RgbImage};
use render::pose::Pose;

/// The sphere's radius as a share of the probe's height.
const SPHERE_SHARE: f32 = 0.3;

fn main() -> std::process::ExitCode {
    let args: Vec<PathBuf> = std::env::args_os().skip(1).map(PathBuf::from).collect();
    let [photo, mask, camera, probe, out] = &args[..] else {
        eprintln!("usage: own_photo PHOTO MASK CAMERA.json PROBE OUT_DIR");
        return std::process::ExitCode::from(2);
    };
    match run(photo, mask, camera, probe, out) {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("own_photo: error: {e}");
            std::process::ExitCode::from(2)
        }
    }
}

fn run(photo: &Path, mask: &Path, camera: &Path, probe: &Path, out: &Path) -> Result<()> {
    let (image, encoding) = RgbImage::read_photo(photo)?;
    if encoding != PhotoEncoding::Linear {
        eprintln!(
            "own_photo: {} is not HDR: highlights clip, the map's scale is unknown",
            photo.display()
        );
    }
    let camera = Camera::read(camera)?;
    let input = Photo::new(image.clone(), Mask::read_png(mask)?, camera).map_err(|e| e.in_file(photo))?;
    let probe = alp::probes::load(probe)?;
    let found = estimate(&input, &probe, &Settings::new(Quality::Default))?;

    // The sphere stands on the ground through the probe's lowest point, beside it
    // (along the camera's right, so that it is in view).
    let posed = probe.mesh.posed(&found.pose);
    let (low, high) = posed.bounds();
    let radius = SPHERE_SHARE * (high.y - low.y);
    let right = (camera.target - camera.origin).cross(camera.up).normalize_or_zero();
    let centre = 0.5 * (low + high) + right * (0.5 * (high.x - low.x).max(high.z - low.z) + 1.5 * radius);
    let material = MaterialSpec {
        finish: Finish::Diffuse,
        albedo: Some([0.8; 3]),
        roughness: None,
    };
    let sphere = VirtualObject::load(Path::new("sphere"), Some(&material))?;
    let sphere_pose = Pose::new(
        Quat::IDENTITY,
        radius / alp::probes::SPHERE_RADIUS,
        Vec3::new(centre.x, low.y + radius, centre.z),
    );
    let settings = InsertSettings {
        ground: Ground::Height(low.y),
        ..InsertSettings::default()
    };
    let inserted = insert(&image, &found.env, &camera, &sphere, &sphere_pose, &settings)?;
    if !inserted.object_visible() {
        return Err(Error::invalid("sphere", "the sphere beside the probe is out of view"));
    }
    std::fs::create_dir_all(out).map_err(|e| render::RenderError::io(out, "create folder", e))?;
    found.env.write(out.join("env.exr"))?;
    found.pose.write(out.join("pose.json"))?;
    inserted.image.write_exr(out.join("inserted.exr"))?;
    inserted.image.write_png_preview(out.join("inserted.png"), 0.0)?;
    println!("wrote {}", out.display());
    Ok(())
}
