//! The probe on a tape: its pose as parameters and its mesh as arrays, so
//! that everything computed from the posed mesh is differentiable in pose.
//!
//! The pose is packed as 8 numbers `[qw, qx, qy, qz, tx, ty, tz, ln s]`:
//! an unnormalised rotation quaternion (normalised where used, so an
//! optimiser steps freely in R^4), the translation in metres, and the log of
//! the uniform scale (positive by construction).

use autodiff::{Quat as QuatVar, Real, Tape, Var, Vec3 as Vec3Var};
use glam::{Quat, Vec3};

use crate::mesh::Mesh;
use crate::pose::Pose;

/// Number of packed pose parameters.
pub const POSE_PARAMS: usize = 8;

/// Packs a pose as `[qw, qx, qy, qz, tx, ty, tz, ln s]`.
pub fn pack_pose(pose: &Pose) -> [f64; POSE_PARAMS] {
    let (q, t) = (pose.rotation, pose.translation);
    [
        q.w as f64,
        q.x as f64,
        q.y as f64,
        q.z as f64,
        t.x as f64,
        t.y as f64,
        t.z as f64,
        (pose.scale as f64).ln(),
    ]
}

/// Unpacks `[qw, qx, qy, qz, tx, ty, tz, ln s]` (the quaternion is normalised).
pub fn unpack_pose(p: &[f64]) -> Pose {
    assert_eq!(
        p.len(),
        POSE_PARAMS,
        "unpack_pose: {POSE_PARAMS} parameters expected, got {}",
        p.len()
    );
    let q = Quat::from_xyzw(p[1] as f32, p[2] as f32, p[3] as f32, p[0] as f32);
    Pose::new(q, p[7].exp() as f32, Vec3::new(p[4] as f32, p[5] as f32, p[6] as f32))
}

/// The pose on a tape: one array of [`POSE_PARAMS`] numbers, and the
/// rotation, translation and scale derived from it.
#[derive(Clone, Copy, Debug)]
pub struct PoseVars<'t, T: Real> {
    /// The packed parameters (a leaf when gradients are wanted).
    pub params: Var<'t, T>,
    /// Unit rotation quaternion.
    pub rotation: QuatVar<'t, T>,
    /// Translation, metres.
    pub translation: Vec3Var<'t, T>,
    /// Uniform scale, `exp(ln s)`.
    pub scale: Var<'t, T>,
}

impl<'t, T: Real> PoseVars<'t, T> {
    /// Records packed pose parameters on `tape`: a leaf (`differentiable`) or a constant.
    pub fn new(tape: &'t Tape<T>, packed: &[f64], differentiable: bool) -> Self {
        assert_eq!(
            packed.len(),
            POSE_PARAMS,
            "PoseVars: {POSE_PARAMS} parameters expected, got {}",
            packed.len()
        );
        let values: Vec<T> = packed.iter().map(|&v| T::c(v)).collect();
        let params = if differentiable {
            tape.leaf(&values)
        } else {
            tape.constant(&values)
        };
        Self::from_params(params)
    }

    /// The pose derived from an array of packed parameters already on a tape.
    pub fn from_params(params: Var<'t, T>) -> Self {
        assert_eq!(
            params.len(),
            POSE_PARAMS,
            "PoseVars: {POSE_PARAMS} parameters expected, got {}",
            params.len()
        );
        let p = |k| params.slice(k, 1);
        PoseVars {
            params,
            rotation: QuatVar::new(p(0), p(1), p(2), p(3)).normalize(),
            translation: Vec3Var::new(p(4), p(5), p(6)),
            scale: p(7).exp(),
        }
    }

    /// Mesh-frame points to world: `s R p + t`.
    pub fn transform_points(&self, p: Vec3Var<'t, T>) -> Vec3Var<'t, T> {
        self.rotation.rotate(p).scale(self.scale) + self.translation
    }

    /// Mesh-frame directions (normals) to world: `R n` (a similarity keeps them unit).
    pub fn rotate(&self, n: Vec3Var<'t, T>) -> Vec3Var<'t, T> {
        self.rotation.rotate(n)
    }
}

/// A mesh's per-vertex data as constant arrays on a tape.
#[derive(Clone, Copy, Debug)]
pub struct MeshVars<'t, T: Real> {
    /// Vertex positions, mesh frame.
    pub positions: Vec3Var<'t, T>,
    /// Vertex normals, mesh frame.
    pub normals: Vec3Var<'t, T>,
    /// Vertex texture coordinates (OBJ convention: v = 0 at the bottom of the image).
    pub uv: [Var<'t, T>; 2],
}

impl<'t, T: Real> MeshVars<'t, T> {
    /// Records the mesh's vertex arrays as constants.
    pub fn new(tape: &'t Tape<T>, mesh: &Mesh) -> Self {
        let column = |f: &dyn Fn(usize) -> f32| -> Var<'t, T> {
            let values: Vec<T> = (0..mesh.positions.len()).map(|i| T::c(f(i) as f64)).collect();
            tape.constant(&values)
        };
        MeshVars {
            positions: Vec3Var::new(
                column(&|i| mesh.positions[i].x),
                column(&|i| mesh.positions[i].y),
                column(&|i| mesh.positions[i].z),
            ),
            normals: Vec3Var::new(
                column(&|i| mesh.normals[i].x),
                column(&|i| mesh.normals[i].y),
                column(&|i| mesh.normals[i].z),
            ),
            uv: [column(&|i| mesh.uvs[i].x), column(&|i| mesh.uvs[i].y)],
        }
    }
}

/// The posed mesh: world positions and normals of every vertex.
#[derive(Clone, Copy, Debug)]
pub struct PosedMesh<'t, T: Real> {
    /// World positions.
    pub positions: Vec3Var<'t, T>,
    /// World unit normals.
    pub normals: Vec3Var<'t, T>,
    /// Texture coordinates (unchanged by the pose).
    pub uv: [Var<'t, T>; 2],
}

impl<'t, T: Real> PosedMesh<'t, T> {
    /// Applies the pose to the mesh.
    pub fn new(mesh: &MeshVars<'t, T>, pose: &PoseVars<'t, T>) -> Self {
        PosedMesh {
            positions: pose.transform_points(mesh.positions),
            normals: pose.rotate(mesh.normals),
            uv: mesh.uv,
        }
    }

    /// World positions as f32 values, for tracing rays (not differentiated).
    pub fn position_values(&self) -> Vec<Vec3> {
        let tape = self.positions.x.tape();
        let (x, y, z) = (
            tape.to_vec(self.positions.x),
            tape.to_vec(self.positions.y),
            tape.to_vec(self.positions.z),
        );
        x.iter()
            .zip(&y)
            .zip(&z)
            .map(|((&x, &y), &z)| Vec3::new(x.f64() as f32, y.f64() as f32, z.f64() as f32))
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use autodiff::gradcheck::{Input, gradcheck};

    #[test]
    fn packed_pose_round_trips_and_transforms_like_the_pose() {
        let pose = Pose::new(
            Quat::from_axis_angle(Vec3::new(0.3, 1.0, -0.2).normalize(), 0.7),
            1.3,
            Vec3::new(0.1, -0.2, 0.5),
        );
        let packed = pack_pose(&pose);
        let back = unpack_pose(&packed);
        assert!((back.scale - pose.scale).abs() < 1e-6 && back.rotation.abs_diff_eq(pose.rotation, 1e-6));
        let tape = Tape::<f64>::new();
        let pv = PoseVars::new(&tape, &packed, false);
        let p = Vec3::new(0.2, -0.4, 0.9);
        let world = pv.transform_points(Vec3Var::new(
            tape.constant(&[p.x as f64]),
            tape.constant(&[p.y as f64]),
            tape.constant(&[p.z as f64]),
        ));
        let want = pose.transform_point(p);
        let got = Vec3::new(
            tape.item(world.x) as f32,
            tape.item(world.y) as f32,
            tape.item(world.z) as f32,
        );
        assert!(got.abs_diff_eq(want, 1e-5), "{got} vs {want}");
    }

    #[test]
    fn posed_points_are_differentiable_in_the_pose() {
        let packed = pack_pose(&Pose::new(Quat::from_rotation_y(0.4), 0.9, Vec3::new(0.0, 0.1, -0.3)));
        let report = gradcheck(&[Input::Var(packed.to_vec())], |t, v| {
            let pose = PoseVars::from_params(v[0]);
            let p = Vec3Var::new(
                t.constant(&[0.1, -0.3]),
                t.constant(&[0.5, 0.2]),
                t.constant(&[-0.7, 0.4]),
            );
            let w = pose.transform_points(p);
            let n = pose.rotate(p);
            w.x + w.y * 2.0 + w.z * 3.0 + n.x * n.z
        });
        assert!(report.worst_rel_error < 1e-6, "{report}");
    }
}
