//! The pose's six parts as the camera sees them. About the centre of the
//! probe's bounding box and in the camera's frame, a pose differs from a
//! reference pose by a move across the view ray (image right and up), a
//! move along it, a turn of the probe's axis about the view ray (within the
//! image: the outline shows it), a lean of the axis towards or away from the
//! camera (the outline hardly shows it) and a turn about the axis itself.
//! `alp eval` splits a found pose's error so; the estimate reports its
//! pose's uncertainty so (`estimate::pose::uncertainty`); both read the same
//! frame. (`tools/pose_error_parts.py` is the benchmark's twin of it.)

use glam::{DQuat, DVec3, Vec3};
use render::camera::Camera;
use render::pose::Pose;
use serde::Serialize;

/// The parts' names, in the order of [`PoseParts::to_array`].
pub const PART_NAMES: [&str; 6] = [
    "across_x_mm",
    "across_y_mm",
    "along_mm",
    "in_view_deg",
    "lean_deg",
    "turn_deg",
];

/// A pose's six parts (see the module's description): millimetres and
/// degrees, signed.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct PoseParts {
    /// The centre moved towards the image's right.
    pub across_x_mm: f64,
    /// The centre moved towards the image's up.
    pub across_y_mm: f64,
    /// The centre moved along the view ray, away from the camera.
    pub along_mm: f64,
    /// The axis turned about the view ray, within the image.
    pub in_view_deg: f64,
    /// The axis leaned towards the view ray (about `axis x view`).
    pub lean_deg: f64,
    /// The probe turned about its own axis.
    pub turn_deg: f64,
}

impl PoseParts {
    /// The parts in the order of [`PART_NAMES`].
    pub fn to_array(self) -> [f64; 6] {
        [
            self.across_x_mm,
            self.across_y_mm,
            self.along_mm,
            self.in_view_deg,
            self.lean_deg,
            self.turn_deg,
        ]
    }

    /// The parts from an array in the order of [`PART_NAMES`].
    pub fn from_array(a: [f64; 6]) -> Self {
        PoseParts {
            across_x_mm: a[0],
            across_y_mm: a[1],
            along_mm: a[2],
            in_view_deg: a[3],
            lean_deg: a[4],
            turn_deg: a[5],
        }
    }
}

/// The camera's frame at a reference pose: the probe's centre, the view ray
/// through it, the image's right and up across it, the probe's axis, and
/// the directions about which the axis turns within the image and leans.
#[derive(Clone, Copy, Debug)]
pub struct PoseFrame {
    /// The centre of the probe's bounding box, mesh coordinates.
    centre_mesh: DVec3,
    /// The probe's axis, mesh coordinates (unit).
    axis_mesh: DVec3,
    /// Where the reference pose puts the centre, world.
    centre: DVec3,
    view: DVec3,
    right: DVec3,
    up: DVec3,
    axis: DVec3,
    in_view: DVec3,
    lean: DVec3,
}

impl PoseFrame {
    /// The frame of `camera` at `reference` for a probe whose bounding box
    /// has its centre at `centre_mesh` and whose axis is `axis_mesh` (mesh
    /// coordinates).
    pub fn new(camera: &Camera, reference: &Pose, centre_mesh: Vec3, axis_mesh: Vec3) -> Self {
        let centre_mesh = centre_mesh.as_dvec3();
        let axis_mesh = axis_mesh.as_dvec3().normalize();
        let centre = to_world(reference, centre_mesh);
        let view = (centre - camera.origin.as_dvec3()).normalize();
        let right = view.cross(camera.up.as_dvec3()).normalize();
        let up = right.cross(view);
        let axis = rotation(reference) * axis_mesh;
        // The view ray square to the axis (the image's up for an axis along the ray).
        let across = view - view.dot(axis) * axis;
        let across = match across.length() > 1e-6 {
            true => across,
            false => up - up.dot(axis) * axis,
        };
        let in_view = across.normalize();
        PoseFrame {
            centre_mesh,
            axis_mesh,
            centre,
            view,
            right,
            up,
            axis,
            in_view,
            lean: axis.cross(in_view),
        }
    }

    /// How `pose` differs from the reference pose.
    pub fn parts(&self, reference: &Pose, pose: &Pose) -> PoseParts {
        let delta = 1e3 * (to_world(pose, self.centre_mesh) - self.centre);
        let error = rotation(pose) * rotation(reference).conjugate();
        let error = if error.w < 0.0 { -error } else { error };
        // Swing and twist about the reference's axis: the twist's angle from
        // the quaternion's part along the axis.
        let turn = 2.0 * error.xyz().dot(self.axis).atan2(error.w);
        let swing = error * DQuat::from_axis_angle(self.axis, turn).conjugate();
        let swing = swing.to_scaled_axis();
        PoseParts {
            across_x_mm: delta.dot(self.right),
            across_y_mm: delta.dot(self.up),
            along_mm: delta.dot(self.view),
            in_view_deg: swing.dot(self.in_view).to_degrees(),
            lean_deg: swing.dot(self.lean).to_degrees(),
            turn_deg: turn.to_degrees(),
        }
    }

    /// The reference pose moved by `parts` (the moves across and along the
    /// view, then the turns about the probe's centre: within the image, the
    /// lean, the turn about the axis).
    pub fn moved(&self, reference: &Pose, parts: &PoseParts) -> Pose {
        let centre = self.centre
            + 1e-3 * (parts.across_x_mm * self.right + parts.across_y_mm * self.up + parts.along_mm * self.view);
        let turn = DQuat::from_scaled_axis(parts.in_view_deg.to_radians() * self.in_view)
            * DQuat::from_scaled_axis(parts.lean_deg.to_radians() * self.lean)
            * DQuat::from_axis_angle(self.axis, parts.turn_deg.to_radians());
        let rotation = (turn * rotation(reference)).normalize();
        let scale = reference.scale as f64;
        let translation = centre - rotation * (scale * self.centre_mesh);
        Pose::new(rotation.as_quat(), reference.scale, translation.as_vec3())
    }

    /// The probe's axis, mesh coordinates.
    pub fn axis_mesh(&self) -> Vec3 {
        self.axis_mesh.as_vec3()
    }
}

/// The rotation of `pose`, in f64.
fn rotation(pose: &Pose) -> DQuat {
    pose.rotation.as_dquat().normalize()
}

/// Where `pose` puts the mesh point `p`, in f64.
fn to_world(pose: &Pose, p: DVec3) -> DVec3 {
    rotation(pose) * (pose.scale as f64 * p) + pose.translation.as_dvec3()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn camera() -> Camera {
        Camera::new(640, 480, 40.0, Vec3::new(0.1, 0.2, 0.5), Vec3::ZERO, Vec3::Y).unwrap()
    }

    #[test]
    fn each_part_alone_is_read_back_alone_and_together_they_compose() {
        let reference = Pose::new(
            glam::Quat::from_axis_angle(Vec3::new(0.3, 1.0, 0.2).normalize(), 0.7),
            1.0,
            Vec3::new(0.01, 0.03, -0.02),
        );
        let centre = Vec3::new(0.0, 0.06, 0.0);
        let frame = PoseFrame::new(&camera(), &reference, centre, Vec3::Y);
        for k in 0..6 {
            for value in [1.5, -3.0] {
                let mut a = [0.0; 6];
                a[k] = value;
                let read = frame.parts(&reference, &frame.moved(&reference, &PoseParts::from_array(a)));
                for (j, v) in read.to_array().into_iter().enumerate() {
                    let want = if j == k { value } else { 0.0 };
                    assert!(
                        (v - want).abs() < 2e-3,
                        "part {} = {value}: read {read:?}",
                        PART_NAMES[k]
                    );
                }
            }
        }
        // Small parts together read back to first order.
        let small = PoseParts::from_array([0.2, -0.1, 0.3, 0.05, -0.04, 0.06]);
        let read = frame.parts(&reference, &frame.moved(&reference, &small));
        for (a, b) in read.to_array().into_iter().zip(small.to_array()) {
            assert!((a - b).abs() < 2e-3, "{read:?} against {small:?}");
        }
    }

    #[test]
    fn the_lean_and_the_turn_are_the_estimate_s_moves() {
        use crate::estimate::pose::hypotheses::{leaned, turned};
        let mesh = render::procedural::SodaCan::default().build().mesh;
        let (lo, hi) = mesh.bounds();
        let reference = Pose::new(glam::Quat::from_rotation_x(0.4), 1.0, Vec3::new(0.0, 0.0, -0.05));
        let frame = PoseFrame::new(&camera(), &reference, 0.5 * (lo + hi), Vec3::Y);
        let near = |a: &Pose, b: &Pose| {
            a.rotation.angle_between(b.rotation) < 1e-4 && (a.translation - b.translation).length() < 1e-6
        };
        let lean = frame.moved(
            &reference,
            &PoseParts {
                lean_deg: 3.0,
                ..Default::default()
            },
        );
        assert!(near(&lean, &leaned(&reference, &mesh, &camera(), 3.0)), "{lean:?}");
        let turn = frame.moved(
            &reference,
            &PoseParts {
                turn_deg: -7.0,
                ..Default::default()
            },
        );
        assert!(near(&turn, &turned(&reference, &mesh, -7.0)), "{turn:?}");
    }
}
