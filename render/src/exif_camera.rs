//! The photo's own camera, from the EXIF tags a camera or phone writes into
//! its JPEG or PNG: the field of view from the focal length, the camera at
//! the origin looking along -z with +y up (docs/own_photo.md), so that the
//! map comes out in the camera's frame.
//!
//! The field of view comes from the 35 mm equivalent focal length when the
//! photo gives it (defined on the 36 x 24 mm frame's diagonal, 43.27 mm),
//! else from the focal length and the sensor's resolution in the focal
//! plane. A photo cropped after it was taken (its aspect differs from the
//! EXIF's pixel dimensions) keeps the original's pixel pitch; one scaled
//! keeps its field of view.

use std::io::BufReader;
use std::path::Path;

use exif::{In, Reader, Tag, Value};
use glam::Vec3;

use crate::camera::Camera;
use crate::error::{RenderError, Result};

/// The diagonal of the 35 mm frame (36 x 24 mm), millimetres.
const FRAME_35MM_DIAGONAL_MM: f64 = 43.266_615;

/// Aspect ratios closer than this are one (a scaled photo, not a crop).
const SAME_ASPECT: f64 = 0.01;

/// The camera of the `width x height` photo at `path` from its EXIF tags,
/// at the origin looking along -z, +y up. Fails, naming the file and what to
/// give instead, when the photo has no EXIF or no focal length in it.
pub fn camera_from_exif(path: impl AsRef<Path>, width: u32, height: u32) -> Result<Camera> {
    let path = path.as_ref();
    let missing = |what: &str| {
        RenderError::file(
            path,
            format!("{what}: give the camera with --camera camera.json (docs/own_photo.md, \"The camera\")"),
        )
    };
    let file = std::fs::File::open(path).map_err(|e| RenderError::io(path, "open photo", e))?;
    let exif = Reader::new()
        .read_from_container(&mut BufReader::new(file))
        .map_err(|e| missing(&format!("no EXIF tags ({e})")))?;
    let number = |tag: Tag| -> Option<f64> {
        let field = exif.get_field(tag, In::PRIMARY)?;
        match &field.value {
            Value::Short(v) => v.first().map(|&x| x as f64),
            Value::Long(v) => v.first().map(|&x| x as f64),
            Value::Rational(v) => v.first().map(|r| r.to_f64()),
            _ => None,
        }
        .filter(|x| x.is_finite() && *x > 0.0)
    };
    // The pixel pitch the focal length is measured in: the original frame's,
    // scaled to this photo unless it is a crop of it.
    let (w, h) = (width as f64, height as f64);
    let original = match (number(Tag::PixelXDimension), number(Tag::PixelYDimension)) {
        (Some(ow), Some(oh)) if (ow / oh - w / h).abs() > SAME_ASPECT * w / h && ow >= w && oh >= h => (ow, oh),
        _ => (w, h),
    };
    let focal_px = match number(Tag::FocalLengthIn35mmFilm) {
        Some(f35) => original.0.hypot(original.1) * f35 / FRAME_35MM_DIAGONAL_MM,
        None => {
            let focal_mm = number(Tag::FocalLength).ok_or_else(|| missing("no focal length in its EXIF tags"))?;
            let per_unit = number(Tag::FocalPlaneXResolution)
                .ok_or_else(|| missing("a focal length but no 35 mm equivalent or focal-plane resolution"))?;
            // FocalPlaneResolutionUnit: 2 inches (the default), 3 centimetres.
            let mm_per_unit = match number(Tag::FocalPlaneResolutionUnit) {
                Some(3.0) => 10.0,
                Some(4.0) => 1.0,
                _ => 25.4,
            };
            focal_mm * per_unit / mm_per_unit * original.0 / number(Tag::PixelXDimension).unwrap_or(original.0)
        }
    };
    let fov_y_deg = (2.0 * (0.5 * h / focal_px).atan()).to_degrees() as f32;
    Camera::new(width, height, fov_y_deg, Vec3::ZERO, Vec3::NEG_Z, Vec3::Y).map_err(|e| e.in_file(path))
}

#[cfg(test)]
mod tests {
    use super::*;
    use exif::experimental::Writer;
    use exif::{Field, Rational};

    /// A tiny JPEG with `fields` as its EXIF (an APP1 segment after SOI).
    fn jpeg_with(fields: &[Field], dir: &Path, name: &str) -> std::path::PathBuf {
        let mut tiff = std::io::Cursor::new(Vec::new());
        let mut writer = Writer::new();
        fields.iter().for_each(|f| writer.push_field(f));
        writer.write(&mut tiff, false).expect("EXIF");
        let tiff = tiff.into_inner();
        let mut plain = Vec::new();
        image::codecs::jpeg::JpegEncoder::new(&mut plain)
            .encode(&[128u8; 8 * 6 * 3], 8, 6, image::ExtendedColorType::Rgb8)
            .expect("JPEG");
        let mut out = plain[..2].to_vec();
        out.extend_from_slice(&[0xff, 0xe1]);
        out.extend_from_slice(&((tiff.len() + 8) as u16).to_be_bytes());
        out.extend_from_slice(b"Exif\0\0");
        out.extend_from_slice(&tiff);
        out.extend_from_slice(&plain[2..]);
        let path = dir.join(name);
        std::fs::write(&path, out).expect("write");
        path
    }

    fn field(tag: Tag, value: Value) -> Field {
        Field {
            tag,
            ifd_num: In::PRIMARY,
            value,
        }
    }

    #[test]
    fn the_field_of_view_comes_from_the_35mm_equivalent_or_the_sensor() {
        let dir = std::env::temp_dir().join(format!("alp-exif-{}", std::process::id()));
        std::fs::create_dir_all(&dir).expect("dir");
        // 26 mm equivalent on a 4:3 photo: the diagonal's field is
        // 2 atan(21.63 / 26) = 79.5 deg; the vertical, 3/5 of the diagonal.
        let phone = jpeg_with(
            &[field(Tag::FocalLengthIn35mmFilm, Value::Short(vec![26]))],
            &dir,
            "phone.jpg",
        );
        let camera = camera_from_exif(&phone, 4000, 3000).expect("a camera");
        let expected = 2.0 * (0.6 * FRAME_35MM_DIAGONAL_MM / 2.0 / 26.0).atan().to_degrees();
        assert!(
            (camera.fov_y_deg as f64 - expected).abs() < 1e-3,
            "{} vs {expected}",
            camera.fov_y_deg
        );
        assert_eq!(
            (camera.origin, camera.forward, camera.image_up),
            (Vec3::ZERO, Vec3::NEG_Z, Vec3::Y)
        );
        // A 3:2 photo at 24 mm equivalent: 2 atan(12 / 24) = 53.13 deg, at any size.
        let frame = jpeg_with(
            &[field(Tag::FocalLengthIn35mmFilm, Value::Short(vec![24]))],
            &dir,
            "frame.jpg",
        );
        for (w, h) in [(6000, 4000), (600, 400)] {
            let fov = camera_from_exif(&frame, w, h).expect("a camera").fov_y_deg;
            assert!((fov - 53.130_1).abs() < 1e-3, "{w}x{h}: {fov}");
        }
        // The same frame cropped to a square keeps the pixel pitch.
        let cropped = jpeg_with(
            &[
                field(Tag::FocalLengthIn35mmFilm, Value::Short(vec![24])),
                field(Tag::PixelXDimension, Value::Long(vec![6000])),
                field(Tag::PixelYDimension, Value::Long(vec![4000])),
            ],
            &dir,
            "cropped.jpg",
        );
        let fov = camera_from_exif(&cropped, 2000, 2000).expect("a camera").fov_y_deg as f64;
        let pitch = (6000f64.hypot(4000.0) * 24.0 / FRAME_35MM_DIAGONAL_MM).recip();
        assert!((fov - 2.0 * (1000.0 * pitch).atan().to_degrees()).abs() < 1e-3, "{fov}");
        // A full-frame sensor's 50 mm lens: 36 mm across 6000 px.
        let sensor = jpeg_with(
            &[
                field(Tag::FocalLength, Value::Rational(vec![Rational { num: 50, denom: 1 }])),
                field(
                    Tag::FocalPlaneXResolution,
                    Value::Rational(vec![Rational { num: 6000, denom: 36 }]),
                ),
                field(Tag::FocalPlaneResolutionUnit, Value::Short(vec![4])),
            ],
            &dir,
            "sensor.jpg",
        );
        let fov = camera_from_exif(&sensor, 6000, 4000).expect("a camera").fov_y_deg as f64;
        assert!((fov - 2.0 * (12.0f64 / 50.0).atan().to_degrees()).abs() < 1e-3, "{fov}");
        // No EXIF, or no focal length: the error names the file and the flag.
        let bare = jpeg_with(&[field(Tag::Orientation, Value::Short(vec![1]))], &dir, "bare.jpg");
        for path in [bare, dir.join("phone.jpg").with_file_name("missing.jpg")] {
            let e = camera_from_exif(&path, 8, 6).expect_err("no camera").to_string();
            assert!(
                e.contains(path.file_name().and_then(|n| n.to_str()).expect("name")),
                "{e}"
            );
        }
        let e = camera_from_exif(dir.join("bare.jpg"), 8, 6)
            .expect_err("no camera")
            .to_string();
        assert!(e.contains("--camera"), "{e}");
        let _ = std::fs::remove_dir_all(&dir);
    }
}
