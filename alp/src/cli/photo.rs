//! The user's photo as the commands read it: its pixels (any format, a
//! warning when it is display-referred), the probe marked by a mask or a
//! box, the camera from a file or the photo's EXIF.

use std::path::Path;

use render::camera::Camera;
use render::exif_camera::camera_from_exif;
use render::image_io::{Mask, PhotoEncoding, RgbImage};

use crate::error::{Error, Result};
use crate::estimate::probe_box::{ProbeBox, mask_in_box};
use crate::estimate::{Photo, Settings};

/// What marks the probe in the photo, as the user gives it.
pub(crate) enum ProbeMarking<'a> {
    /// A mask image.
    Mask(&'a Path),
    /// A box round it, `x0,y0,x1,y1`, given as `field` (its errors name it).
    Box { text: &'a str, field: &'a str },
}

/// The photo at `image` as the user gives it: the probe marked by a mask
/// or a box (its first outline then found by colour inside it,
/// [`mask_in_box`]), the camera from `camera` or else the image's EXIF.
pub(crate) fn read_inputs(
    image_path: &Path,
    marking: ProbeMarking,
    camera: Option<&Path>,
    settings: &Settings,
) -> Result<Photo> {
    let (image, encoding) = read_photo(image_path)?;
    let camera = match camera {
        Some(path) => Camera::read(path)?,
        None => {
            let camera = camera_from_exif(image_path, image.width as u32, image.height as u32)?;
            eprintln!(
                "alp: the camera from {}'s EXIF: vertical field of view {:.2} deg, at the origin looking along -z",
                image_path.display(),
                camera.fov_y_deg
            );
            camera
        }
    };
    let mask = match marking {
        ProbeMarking::Mask(path) => Mask::read_png(path)?,
        ProbeMarking::Box { text, field } => {
            let probe_box =
                ProbeBox::parse(text, image.width, image.height).map_err(|e| Error::invalid(field, e.rule()))?;
            mask_in_box(&image, &probe_box, &settings.photo.probe_box)?
        }
    };
    Ok(Photo::new(image, mask, camera)
        .map_err(|e| e.in_file(image_path))?
        .with_encoding(encoding))
}

/// Reads a photo (OpenEXR, Radiance HDR, PNG or JPEG: [`RgbImage::read_photo`]),
/// warning on stderr when it is display-referred sRGB; and how it was stored.
pub(crate) fn read_photo(path: &Path) -> Result<(RgbImage, PhotoEncoding)> {
    let (image, encoding) = RgbImage::read_photo(path)?;
    if let PhotoEncoding::Srgb { bits } = encoding {
        eprintln!(
            "alp: warning: {} is a {bits}-bit sRGB image, not HDR: it is linearised, its clipped highlights are \
             read as lower bounds (the brightest lights may come out dimmer than they are) and its exposure is \
             unknown (the map is right up to one scale)",
            path.display()
        );
    }
    Ok((image, encoding))
}
