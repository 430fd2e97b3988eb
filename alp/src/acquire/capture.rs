//! The capture folder (FORMATS.md, "Capture folder"): the scanned mesh (any
//! frame and scale, with `vt`), the capture's lighting (an equirectangular
//! map in the cameras' world frame) and the views,
//! `views/<name>/{image.exr, mask.png, camera.json}`. Everything is read and
//! checked before anything is solved; an error names the view's file and
//! the rule it breaks.

use std::path::Path;

use glam::{DMat3, DVec3, Vec3};
use render::RenderError;
use render::camera::Camera;
use render::envmap::EnvMap;
use render::image_io::{Mask, RgbImage};
use render::mesh::Mesh;
use render::silhouette::mask_barycenter;

use crate::error::{Error, Result};
use crate::estimate::Photo;

/// The fewest views a capture holds: one silhouette cannot tell a shape's
/// size from its distance.
pub const LEAST_VIEWS: usize = 2;

/// The files of one view folder.
pub const VIEW_FILES: [&str; 3] = ["image.exr", "mask.png", "camera.json"];

/// One view: its name (its folder's) and its photo (image, mask, camera,
/// checked to agree).
pub struct View {
    pub name: String,
    pub photo: Photo,
}

/// A capture folder, read and checked.
pub struct Capture {
    /// The scanned shape, in its own frame and scale.
    pub mesh: Mesh,
    /// The lighting of every view, in the cameras' world frame.
    pub lighting: EnvMap,
    /// The views, in the order of their names.
    pub views: Vec<View>,
}

impl Capture {
    /// Reads and checks the capture folder `dir`.
    pub fn read(dir: impl AsRef<Path>) -> Result<Self> {
        let dir = dir.as_ref();
        if !dir.is_dir() {
            return Err(RenderError::file(
                dir,
                "is not a folder (a capture holds mesh.obj, lighting.exr and views/)",
            )
            .into());
        }
        let mesh = Mesh::read_obj(dir.join("mesh.obj"))?;
        let lighting = EnvMap::read(dir.join("lighting.exr"))?;
        let views_dir = dir.join("views");
        let entries = std::fs::read_dir(&views_dir).map_err(|e| RenderError::io(&views_dir, "list the views", e))?;
        let mut names = Vec::new();
        for entry in entries {
            let entry = entry.map_err(|e| RenderError::io(&views_dir, "list the views", e))?;
            if entry.path().is_dir() {
                let name = entry.file_name();
                let name = name
                    .to_str()
                    .ok_or_else(|| RenderError::file(entry.path(), "a view's folder name is not valid UTF-8"))?;
                names.push(name.to_string());
            }
        }
        names.sort();
        if names.len() < LEAST_VIEWS {
            return Err(RenderError::file(
                &views_dir,
                format!(
                    "holds {} view folder(s): a capture needs at least {LEAST_VIEWS} (views/<name>/ with {})",
                    names.len(),
                    VIEW_FILES.join(", ")
                ),
            )
            .into());
        }
        let views = names
            .into_iter()
            .map(|name| read_view(&views_dir, name))
            .collect::<Result<Vec<_>>>()?;
        let capture = Capture { mesh, lighting, views };
        // Every camera sees where the views' masks say the object stands.
        let centre = capture.centre()?;
        for view in &capture.views {
            let camera = &view.photo.camera;
            let (w, h) = (camera.width as f32, camera.height as f32);
            let seen = camera
                .project(centre)
                .is_some_and(|p| (-0.5 * w..=1.5 * w).contains(&p.x) && (-0.5 * h..=1.5 * h).contains(&p.y));
            if !seen {
                return Err(RenderError::file(
                    views_dir.join(&view.name).join("camera.json"),
                    format!(
                        "does not see the object its mask marks: the point where the views' rays through \
                         their masks meet, ({:.3}, {:.3}, {:.3}), is behind this camera or far outside its image",
                        centre.x, centre.y, centre.z
                    ),
                )
                .into());
            }
        }
        Ok(capture)
    }

    /// The point nearest (least squares) to the rays through every view's
    /// mask centre: where the object stands.
    pub fn centre(&self) -> Result<Vec3> {
        let (mut a, mut b) = (DMat3::ZERO, DVec3::ZERO);
        for view in &self.views {
            let camera = &view.photo.camera;
            let centre =
                mask_barycenter(&view.photo.mask).ok_or_else(|| Error::invalid(view.name.clone(), "an empty mask"))?;
            let d = camera.direction_through(centre.as_vec2()).as_dvec3().normalize();
            let o = camera.origin.as_dvec3();
            // (I - d d^T) (x - o) = 0 for each ray, summed.
            let m = DMat3::IDENTITY - DMat3::from_cols(d * d.x, d * d.y, d * d.z);
            a += m;
            b += m * o;
        }
        if a.determinant().abs() < 1e-12 {
            return Err(Error::invalid(
                "views",
                "their rays through the masks are parallel: the cameras must look from different directions",
            ));
        }
        Ok((a.inverse() * b).as_vec3())
    }

    /// Writes the capture to the folder `dir` (which exists): `mesh.obj`,
    /// `lighting.exr` and each view's files.
    pub fn write(&self, dir: &Path) -> Result<()> {
        self.mesh.write_obj(dir.join("mesh.obj"))?;
        self.lighting.write(dir.join("lighting.exr"))?;
        for view in &self.views {
            let at = dir.join("views").join(&view.name);
            std::fs::create_dir_all(&at).map_err(|e| RenderError::io(&at, "create", e))?;
            view.photo.image.write_exr(at.join("image.exr"))?;
            view.photo.mask.write_png(at.join("mask.png"))?;
            view.photo.camera.write(at.join("camera.json"))?;
        }
        Ok(())
    }
}

/// View `name` of `views_dir`: its three files present, readable, of the
/// camera's size, the image finite and the mask not empty.
fn read_view(views_dir: &Path, name: String) -> Result<View> {
    let dir = views_dir.join(&name);
    for file in VIEW_FILES {
        if !dir.join(file).is_file() {
            return Err(RenderError::file(
                dir.join(file),
                format!("is missing: a view holds {}", VIEW_FILES.join(", ")),
            )
            .into());
        }
    }
    let camera = Camera::read(dir.join("camera.json"))?;
    let image = RgbImage::read_exr(dir.join("image.exr"))?;
    let mask = Mask::read_png(dir.join("mask.png"))?;
    let photo = Photo::new(image, mask, camera).map_err(|e| {
        let file = match e.field_name() {
            Some("mask") => "mask.png",
            _ => "image.exr",
        };
        e.in_file(dir.join(file))
    })?;
    Ok(View { name, photo })
}
