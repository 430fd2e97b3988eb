//! The probe's pose (`pose.json`): a similarity transform from mesh coordinates to world.
//!
//! Stored as a row-major 4x4 `to_world` (FORMATS.md). Only rotation, uniform scale and
//! translation are allowed: the probe is a rigid object of unknown size.

use std::path::Path;

use glam::{Mat3, Mat4, Quat, Vec3, Vec4};
use serde::{Deserialize, Serialize};

use crate::error::{RenderError, Result};
use crate::json::{read_json, write_json};

/// The fields of `pose.json`, as stored (rows of the matrix).
#[derive(Clone, Copy, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct PoseFile {
    to_world: [[f32; 4]; 4],
}

/// A validated similarity transform `to_world = T * R * s`, kept both as a matrix and as its parts.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Pose {
    /// Unit quaternion of the rotation R.
    pub rotation: Quat,
    /// Uniform scale s > 0.
    pub scale: f32,
    /// Translation T, world metres.
    pub translation: Vec3,
}

/// Largest deviation of `R^T R` from the identity accepted as a rotation (f32 files written by other tools).
const ORTHONORMAL_TOLERANCE: f32 = 1e-4;

impl Pose {
    /// The identity pose.
    pub const IDENTITY: Self = Self {
        rotation: Quat::IDENTITY,
        scale: 1.0,
        translation: Vec3::ZERO,
    };

    /// A pose from rotation, uniform scale and translation; the rotation is normalised.
    pub fn new(rotation: Quat, scale: f32, translation: Vec3) -> Self {
        Self {
            rotation: rotation.normalize(),
            scale,
            translation,
        }
    }

    /// Decomposes a `to_world` matrix, rejecting non-finite entries, a last row other than
    /// [0, 0, 0, 1], a singular matrix, a reflection, and non-uniform scale or shear.
    pub fn from_matrix(to_world: Mat4) -> Result<Self> {
        let rows = to_world.transpose().to_cols_array_2d();
        if !to_world.is_finite() {
            return Err(RenderError::value("to_world", format!("non-finite entry in {rows:?}")));
        }
        if to_world.row(3) != Vec4::W {
            return Err(RenderError::value(
                "to_world",
                format!("last row {:?} is not [0, 0, 0, 1]", rows[3]),
            ));
        }
        let linear = Mat3::from_mat4(to_world);
        let det = linear.determinant();
        let column_lengths = [linear.x_axis.length(), linear.y_axis.length(), linear.z_axis.length()];
        let largest = column_lengths.iter().copied().fold(0.0, f32::max);
        if det.abs() <= 1e-9 * largest.powi(3) || largest == 0.0 {
            return Err(RenderError::value(
                "to_world",
                format!("singular (determinant {det}): not invertible"),
            ));
        }
        if det < 0.0 {
            return Err(RenderError::value(
                "to_world",
                format!("determinant {det} < 0: a reflection, not a rotation"),
            ));
        }
        let scale = det.cbrt();
        let rotation = linear * (1.0 / scale);
        let deviation = (rotation.transpose() * rotation - Mat3::IDENTITY)
            .abs()
            .to_cols_array()
            .into_iter()
            .fold(0.0, f32::max);
        if deviation > ORTHONORMAL_TOLERANCE {
            return Err(RenderError::value(
                "to_world",
                format!(
                    "non-uniform scale or shear: column lengths {column_lengths:?}, R^T R deviates from identity by {deviation:.2e} (> {ORTHONORMAL_TOLERANCE:.0e})"
                ),
            ));
        }
        Ok(Self::new(Quat::from_mat3(&rotation), scale, to_world.w_axis.truncate()))
    }

    /// The 4x4 mesh-to-world matrix.
    pub fn to_world(&self) -> Mat4 {
        Mat4::from_scale_rotation_translation(Vec3::splat(self.scale), self.rotation, self.translation)
    }

    /// Maps a mesh point to world.
    pub fn transform_point(&self, p: Vec3) -> Vec3 {
        self.rotation * (self.scale * p) + self.translation
    }

    /// Maps a mesh normal to world (a similarity only rotates normals).
    pub fn transform_normal(&self, n: Vec3) -> Vec3 {
        self.rotation * n
    }

    /// Reads and validates `pose.json`.
    pub fn read(path: impl AsRef<Path>) -> Result<Self> {
        let path = path.as_ref();
        let f: PoseFile = read_json(path)?;
        Self::from_matrix(Mat4::from_cols_array_2d(&f.to_world).transpose()).map_err(|e| e.in_file(path))
    }

    /// Writes `pose.json` (rows of `to_world`).
    pub fn write(&self, path: impl AsRef<Path>) -> Result<()> {
        write_json(
            path.as_ref(),
            &PoseFile {
                to_world: self.to_world().transpose().to_cols_array_2d(),
            },
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use approx::assert_abs_diff_eq;

    #[test]
    fn decomposition_round_trip() {
        let pose = Pose::new(
            Quat::from_axis_angle(Vec3::new(1.0, 2.0, 3.0).normalize(), 0.7),
            2.5,
            Vec3::new(1.0, -2.0, 0.5),
        );
        let back = Pose::from_matrix(pose.to_world()).unwrap();
        assert_abs_diff_eq!(back.scale, 2.5, epsilon = 1e-5);
        assert_vec_close!(back.translation, pose.translation, 1e-6);
        assert!(back.rotation.dot(pose.rotation).abs() > 1.0 - 1e-6);
        let p = Vec3::new(0.3, 0.1, -0.2);
        assert_vec_close!(pose.transform_point(p), pose.to_world().transform_point3(p), 1e-5);
    }

    #[test]
    fn rejects_non_similarities() {
        let cases = [
            (Mat4::from_scale(Vec3::new(1.0, 2.0, 1.0)), "non-uniform scale or shear"),
            (Mat4::from_scale(Vec3::new(1.0, 1.0, -1.0)), "reflection"),
            (Mat4::from_scale(Vec3::ZERO), "singular"),
            (
                Mat4::from_cols(Vec4::X, Vec4::Y, Vec4::Z, Vec4::new(0.0, 0.0, 0.0, 2.0)),
                "not [0, 0, 0, 1]",
            ),
            (
                Mat4::from_cols(Vec4::X, Vec4::Y, Vec4::Z, Vec4::new(f32::NAN, 0.0, 0.0, 1.0)),
                "non-finite",
            ),
        ];
        for (m, rule) in cases {
            let e = Pose::from_matrix(m).unwrap_err();
            assert!(e.to_string().contains(rule), "{e}");
        }
    }
}
