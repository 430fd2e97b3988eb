//! The pinhole camera of `camera.json`: a look-at with a vertical field of view.
//!
//! Image row 0 is the top, column 0 the left; pixel (row, col) covers
//! [col, col + 1) x [row, row + 1) in pixel coordinates, its centre at +0.5 (FORMATS.md).

use std::path::Path;

use glam::{Vec2, Vec3};
use serde::{Deserialize, Serialize};

use crate::error::{RenderError, Result};
use crate::json::{read_json, write_json};

/// The fields of `camera.json`, as stored.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct CameraFile {
    width: u32,
    height: u32,
    fov_y_deg: f32,
    origin: [f32; 3],
    target: [f32; 3],
    up: [f32; 3],
}

/// A validated pinhole camera with its orthonormal look-at basis.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Camera {
    /// Image width in pixels.
    pub width: u32,
    /// Image height in pixels.
    pub height: u32,
    /// Vertical field of view, degrees.
    pub fov_y_deg: f32,
    /// Centre of projection, world.
    pub origin: Vec3,
    /// The point looked at, world.
    pub target: Vec3,
    /// The `up` hint that fixes the roll, world.
    pub up: Vec3,
    /// Unit viewing direction (world).
    pub forward: Vec3,
    /// Unit image-right direction (world): `forward x up`, normalised.
    pub right: Vec3,
    /// Unit image-up direction (world): the projection of `up` orthogonal to `forward`.
    pub image_up: Vec3,
    /// The photo's blur beyond its pixels' box, the standard deviation of a
    /// Gaussian in pixels (defocus, motion, the lens, demosaicing): each
    /// rendered pixel's rays spread over it. 0 (as `camera.json` gives it):
    /// a sharp pinhole. Not part of `camera.json`; the estimate measures it.
    pub footprint_px: f32,
    tan_half_fov_y: f32,
}

impl Camera {
    /// A camera from the `camera.json` values; fails on an empty image, a field of view outside
    /// (0, 180) degrees, `origin == target`, or `up` parallel to the view direction.
    pub fn new(width: u32, height: u32, fov_y_deg: f32, origin: Vec3, target: Vec3, up: Vec3) -> Result<Self> {
        if width == 0 || height == 0 {
            return Err(RenderError::value(
                "width/height",
                format!("image size {width}x{height} must be > 0"),
            ));
        }
        if !(fov_y_deg > 0.0 && fov_y_deg < 180.0) {
            return Err(RenderError::value(
                "fov_y_deg",
                format!("value {fov_y_deg} outside (0, 180)"),
            ));
        }
        for (name, v) in [("origin", origin), ("target", target), ("up", up)] {
            if !v.is_finite() {
                return Err(RenderError::value(name, format!("{v} is not finite")));
            }
        }
        let view = target - origin;
        if view.length() <= 1e-12 {
            return Err(RenderError::value(
                "target",
                format!("equals origin {origin}: no view direction"),
            ));
        }
        let forward = view.normalize();
        let right = forward.cross(up);
        // sin of the angle between up and the view direction, below ~0.06 degrees counts as parallel.
        if up.length() == 0.0 || right.length() <= 1e-3 * up.length() {
            return Err(RenderError::value(
                "up",
                format!("{up} is zero or parallel to the view direction {forward}"),
            ));
        }
        let right = right.normalize();
        let image_up = right.cross(forward);
        let tan_half_fov_y = (0.5 * fov_y_deg.to_radians()).tan();
        Ok(Self {
            width,
            height,
            fov_y_deg,
            origin,
            target,
            up,
            forward,
            right,
            image_up,
            footprint_px: 0.0,
            tan_half_fov_y,
        })
    }

    /// The camera with a blur of `footprint_px` (see [`Camera::footprint_px`]);
    /// fails on a negative or non-finite one.
    pub fn with_footprint(self, footprint_px: f32) -> Result<Self> {
        if !(footprint_px.is_finite() && footprint_px >= 0.0) {
            return Err(RenderError::value(
                "footprint_px",
                format!("{footprint_px} must be finite and >= 0"),
            ));
        }
        Ok(Camera { footprint_px, ..self })
    }

    /// Reads and validates `camera.json`.
    pub fn read(path: impl AsRef<Path>) -> Result<Self> {
        let path = path.as_ref();
        let f: CameraFile = read_json(path)?;
        Self::new(
            f.width,
            f.height,
            f.fov_y_deg,
            f.origin.into(),
            f.target.into(),
            f.up.into(),
        )
        .map_err(|e| e.in_file(path))
    }

    /// Writes `camera.json`.
    pub fn write(&self, path: impl AsRef<Path>) -> Result<()> {
        let f = CameraFile {
            width: self.width,
            height: self.height,
            fov_y_deg: self.fov_y_deg,
            origin: self.origin.into(),
            target: self.target.into(),
            up: self.up.into(),
        };
        write_json(path.as_ref(), &f)
    }

    /// Number of pixels, `width * height`.
    pub fn pixel_count(&self) -> usize {
        self.width as usize * self.height as usize
    }

    /// The unit direction (world) through pixel coordinates (x right, y down, in pixels; the centre
    /// of pixel (row, col) is (col + 0.5, row + 0.5)).
    pub fn direction_through(&self, pixel: Vec2) -> Vec3 {
        let aspect = self.width as f32 / self.height as f32;
        let ndc_x = 2.0 * pixel.x / self.width as f32 - 1.0;
        let ndc_y = 1.0 - 2.0 * pixel.y / self.height as f32;
        (self.forward
            + (ndc_x * aspect * self.tan_half_fov_y) * self.right
            + (ndc_y * self.tan_half_fov_y) * self.image_up)
            .normalize()
    }

    /// The primary ray (origin, unit direction) of pixel (row, col) at sub-pixel `offset` in [0, 1)^2
    /// (x right, y down; (0.5, 0.5) is the pixel centre).
    pub fn primary_ray(&self, row: u32, col: u32, offset: Vec2) -> (Vec3, Vec3) {
        let pixel = Vec2::new(col as f32 + offset.x, row as f32 + offset.y);
        (self.origin, self.direction_through(pixel))
    }

    /// Pixel coordinates (x right, y down) of a world point, or `None` if it is not in front of the camera.
    pub fn project(&self, world: Vec3) -> Option<Vec2> {
        let d = world - self.origin;
        let depth = d.dot(self.forward);
        if depth <= 0.0 {
            return None;
        }
        let aspect = self.width as f32 / self.height as f32;
        let ndc_x = d.dot(self.right) / (depth * aspect * self.tan_half_fov_y);
        let ndc_y = d.dot(self.image_up) / (depth * self.tan_half_fov_y);
        Some(Vec2::new(
            0.5 * (ndc_x + 1.0) * self.width as f32,
            0.5 * (1.0 - ndc_y) * self.height as f32,
        ))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use approx::assert_abs_diff_eq;

    fn example() -> Camera {
        Camera::new(
            640,
            480,
            40.0,
            Vec3::new(0.0, 0.1, 0.5),
            Vec3::new(0.0, 0.06, 0.0),
            Vec3::Y,
        )
        .unwrap()
    }

    #[test]
    fn basis_is_orthonormal_and_right_handed() {
        let c = example();
        assert_abs_diff_eq!(c.forward.dot(c.right), 0.0, epsilon = 1e-6);
        assert_abs_diff_eq!(c.forward.dot(c.image_up), 0.0, epsilon = 1e-6);
        assert_vec_close!(c.right.cross(c.image_up), -c.forward, 1e-6);
        // Looking down -Z with +Y up: right is +X.
        assert_vec_close!(c.right, Vec3::X, 1e-6);
        assert!(c.image_up.y > 0.9);
    }

    #[test]
    fn centre_ray_hits_target_and_corners_span_the_fov() {
        let c = example();
        let centre = c.direction_through(Vec2::new(320.0, 240.0));
        assert_vec_close!(centre, c.forward, 1e-6);
        let top = c.direction_through(Vec2::new(320.0, 0.0));
        assert_abs_diff_eq!(top.dot(centre).acos().to_degrees(), 20.0, epsilon = 1e-3);
        // Row 0 is the top of the image.
        assert!(top.dot(c.image_up) > 0.0);
        let left = c.direction_through(Vec2::new(0.0, 240.0));
        assert!(left.dot(c.right) < 0.0);
    }

    #[test]
    fn projection_inverts_primary_rays() {
        let c = example();
        for (row, col, off) in [
            (0, 0, Vec2::splat(0.5)),
            (479, 639, Vec2::new(0.9, 0.1)),
            (123, 456, Vec2::ZERO),
        ] {
            let (o, d) = c.primary_ray(row, col, off);
            let p = c.project(o + 0.37 * d).unwrap();
            assert_vec_close!(p, Vec2::new(col as f32, row as f32) + off, 1e-3);
        }
        assert!(c.project(c.origin - c.forward).is_none());
    }

    #[test]
    fn rejects_invalid_cameras() {
        let cases = [
            (Camera::new(0, 10, 40.0, Vec3::Z, Vec3::ZERO, Vec3::Y), "width/height"),
            (Camera::new(10, 10, 180.0, Vec3::Z, Vec3::ZERO, Vec3::Y), "fov_y_deg"),
            (Camera::new(10, 10, 40.0, Vec3::Z, Vec3::Z, Vec3::Y), "target"),
            (Camera::new(10, 10, 40.0, Vec3::Y, Vec3::ZERO, Vec3::Y), "up"),
        ];
        for (result, field) in cases {
            let e = result.unwrap_err();
            assert_eq!(e.field_name(), Some(field), "{e}");
        }
    }
}
