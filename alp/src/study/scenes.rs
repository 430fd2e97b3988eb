//! The scene folders a study runs on (FORMATS.md, "Scene folder"), each read
//! once, its truth's relit spheres rendered once for every run on it.

use std::path::{Path, PathBuf};

use render::RenderError;
use render::camera::Camera;
use render::envmap::EnvMap;
use render::image_io::{Mask, RgbImage};
use render::pose::Pose;
use render::probe::ProbeAsset;
use serde::Deserialize;

use crate::error::Result;
use crate::estimate::symmetry::looks_alike_turned;
use crate::estimate::{Photo, Settings};
use crate::eval::{PoseErrors, scene_file, scene_probe};
use crate::relight::{RelightSettings, RelitSpheres, relight};

/// The scene folders under `dirs`: each a scene folder (it holds
/// `image.exr`) or a folder of scene folders (its sub-folders that hold
/// one, by name). An error names a folder that holds none.
pub fn find(dirs: &[PathBuf]) -> Result<Vec<PathBuf>> {
    let mut scenes = Vec::new();
    for dir in dirs {
        if dir.join("image.exr").is_file() {
            scenes.push(dir.clone());
            continue;
        }
        let entries = std::fs::read_dir(dir).map_err(|e| RenderError::io(dir, "list the scene folders", e))?;
        let mut found: Vec<PathBuf> = entries
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|p| p.join("image.exr").is_file())
            .collect();
        if found.is_empty() {
            return Err(RenderError::file(
                dir,
                "holds no scene folder: neither `image.exr` in it nor in a sub-folder (FORMATS.md, \"Scene folder\")",
            )
            .into());
        }
        found.sort();
        scenes.append(&mut found);
    }
    Ok(scenes)
}

/// What of a pose can be told from a photo of the probe, and so what an
/// estimated pose is judged by.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Observable {
    /// The whole rotation (a label breaks the symmetry).
    Rotation,
    /// The axis's direction (alike at every turn about it).
    Axis,
    /// The axis's line (also alike end for end: a ring).
    AxisLine,
    /// The position only (a sphere).
    Position,
}

/// A pose is found when its observable part is within this many degrees
/// (a sphere: its centre within this share of its diameter).
pub const FOUND_DEG: f64 = 5.0;
/// See [`FOUND_DEG`].
pub const FOUND_DIAMETER_SHARE: f64 = 0.05;

impl Observable {
    /// The names a scene's `scene.json` may give as `"orientation"`: `full`,
    /// `axis`, `line`, `none`.
    fn parse(name: &str) -> Option<Self> {
        match name {
            "full" => Some(Observable::Rotation),
            "axis" => Some(Observable::Axis),
            "line" => Some(Observable::AxisLine),
            "none" => Some(Observable::Position),
            _ => None,
        }
    }

    /// Whether `errors` find the pose of a probe `diameter_mm` across.
    pub fn found(self, errors: &PoseErrors, diameter_mm: f64) -> bool {
        match self {
            Observable::Rotation => errors.rotation_deg < FOUND_DEG,
            Observable::Axis => errors.axis_deg < FOUND_DEG,
            Observable::AxisLine => errors.axis_deg.min(180.0 - errors.axis_deg) < FOUND_DEG,
            Observable::Position => errors.translation_mm < FOUND_DIAMETER_SHARE * diameter_mm,
        }
    }
}

/// The optional `scene.json` a benchmark generator writes beside a scene:
/// only `orientation` and the probe's `family` are read.
#[derive(Default, Deserialize)]
struct SceneMeta {
    orientation: Option<String>,
    family: Option<String>,
}

/// One scene, read.
pub struct StudyScene {
    /// The folder's name.
    pub name: String,
    /// The folder.
    pub dir: PathBuf,
    /// The photo, its mask and camera.
    pub photo: Photo,
    /// The probe `probe.txt` names.
    pub probe: ProbeAsset,
    /// The probe's family: `scene.json`'s `family`, else the probe's name.
    pub probe_family: String,
    /// The true lighting.
    pub env: EnvMap,
    /// The probe's true pose.
    pub pose: Pose,
    /// What of the pose the photo tells: `scene.json`'s `orientation`
    /// where the scene has one, else the probe's symmetry (the axis alone
    /// when it looks alike at every turn about it).
    pub observable: Observable,
    /// The probe's diameter at its true size, millimetres (its mesh's
    /// bounding-box diagonal).
    pub diameter_mm: f64,
}

impl StudyScene {
    /// Reads a scene folder.
    pub fn read(dir: &Path) -> Result<Self> {
        let name = dir
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_else(|| dir.display().to_string());
        let camera = Camera::read(scene_file(dir, "camera.json")?)?;
        let image_path = scene_file(dir, "image.exr")?;
        let image = RgbImage::read_exr(&image_path)?;
        let mask = Mask::read_png(scene_file(dir, "mask.png")?)?;
        let photo = Photo::new(image, mask, camera).map_err(|e| e.in_file(&image_path))?;
        let probe = scene_probe(dir)?;
        let env = EnvMap::read(scene_file(dir, "gt_env.exr")?)?;
        let pose = Pose::read(scene_file(dir, "pose.json")?)?;
        let meta_path = dir.join("scene.json");
        let meta = match meta_path.is_file() {
            true => {
                let text = std::fs::read_to_string(&meta_path).map_err(|e| RenderError::io(&meta_path, "read", e))?;
                serde_json::from_str(&text)
                    .map_err(|e| RenderError::file(&meta_path, format!("is not a JSON object: {e}")))?
            }
            false => SceneMeta::default(),
        };
        let named = match &meta.orientation {
            Some(o) => Some(Observable::parse(o).ok_or_else(|| {
                RenderError::field(
                    &meta_path,
                    "orientation",
                    format!("`{o}` is not one of full, axis, line, none"),
                )
            })?),
            None => None,
        };
        let probe_family = meta.family.unwrap_or_else(|| probe.name.clone());
        let observable = named.unwrap_or_else(|| match looks_alike_turned(&probe, &Settings::default().symmetry) {
            Some(true) => Observable::Axis,
            _ => Observable::Rotation,
        });
        let (lo, hi) = probe.mesh.positions.iter().fold(
            (glam::Vec3::splat(f32::INFINITY), glam::Vec3::splat(f32::NEG_INFINITY)),
            |(lo, hi), &p| (lo.min(p), hi.max(p)),
        );
        let diameter_mm = 1000.0 * ((hi - lo).length() * pose.scale) as f64;
        Ok(StudyScene {
            name,
            dir: dir.to_path_buf(),
            photo,
            probe,
            probe_family,
            env,
            pose,
            observable,
            diameter_mm,
        })
    }

    /// The truth's relit spheres.
    pub fn truth_spheres(&self, settings: &RelightSettings) -> Result<RelitSpheres> {
        relight(&self.env, &self.photo.camera, settings)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::synth::{SynthSettings, synthesize, write_scene};

    /// A scene reads whole; one whose `probe.txt` names a probe that does
    /// not read is an error naming `probe.txt` and the probe.
    #[test]
    fn a_scene_reads_and_its_probe_reference_is_checked() {
        let dir = std::env::temp_dir().join(format!("alp-study-scene-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let probe = crate::probes::procedural("can").expect("a can");
        let env = EnvMap::constant(8, [1.0; 3]);
        let settings = SynthSettings {
            spp: 1,
            width: 32,
            height: 24,
            ..SynthSettings::default()
        };
        let scene = synthesize(&probe, &env, &settings).expect("a scene");
        for (name, reference) in [("named", "can"), ("missing", "no_such_probe")] {
            write_scene(&dir.join(name), &scene, &env, reference).expect("written");
        }
        let read = StudyScene::read(&dir.join("named")).expect("the scene reads");
        assert_eq!((read.name.as_str(), read.photo.camera.width), ("named", 32));
        let error = StudyScene::read(&dir.join("missing"))
            .err()
            .expect("no probe")
            .to_string();
        assert!(
            error.contains("probe.txt") && error.contains("no_such_probe"),
            "{error}"
        );
        let _ = std::fs::remove_dir_all(&dir);
    }
}
