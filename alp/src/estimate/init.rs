//! Starting poses, from the mask and the camera: the probe's known size
//! against the mask's extent gives the depth, the mask's barycenter the
//! direction, and the mask's shape the hypotheses of where the probe's axis
//! points (upright, along the mask's principal direction, end-on); turns
//! about the axis (yaws) make the orientation starts.

use glam::{Mat3, Quat, Vec2, Vec3};
use render::camera::Camera;
use render::image_io::Mask;
use render::mesh::Mesh;
use render::pose::Pose;
use render::{RenderError, Result};

/// The canonical front-facing orientation for `camera`: the probe standing
/// upright in the world (mesh +Y along the camera's `up`, which FORMATS.md
/// gives in world coordinates) and turned to face the camera.
pub fn front_facing(camera: &Camera) -> Quat {
    facing(camera, camera.up)
}

/// The orientation with mesh +Y along `axis` and mesh +Z turned towards the
/// camera as far as the axis allows (towards the image's up when the axis
/// points along the view).
pub fn facing(camera: &Camera, axis: Vec3) -> Quat {
    let up = axis.normalize();
    let toward = -camera.forward - up * up.dot(-camera.forward);
    let toward = if toward.length() > 0.1 {
        toward.normalize()
    } else {
        (camera.image_up - up * up.dot(camera.image_up)).normalize()
    };
    Quat::from_mat3(&Mat3::from_cols(up.cross(toward), up, toward)).normalize()
}

/// The mask's barycenter, the diagonal of its bounding box (pixels), its
/// principal direction (unit, image x right and y down) and elongation (the
/// ratio of the standard deviations along and across that direction).
pub struct MaskShape {
    /// Barycenter, pixels.
    pub barycenter: Vec2,
    /// Bounding box diagonal, pixels.
    pub diagonal_px: f32,
    /// Direction of largest spread.
    pub principal: Vec2,
    /// Spread along the principal direction over the spread across it (>= 1).
    pub elongation: f32,
}

impl MaskShape {
    /// The shape of `mask`; an empty mask is an error.
    pub fn new(mask: &Mask) -> Result<Self> {
        let points: Vec<Vec2> = mask
            .inside
            .iter()
            .enumerate()
            .filter(|(_, inside)| **inside)
            .map(|(i, _)| Vec2::new((i % mask.width) as f32 + 0.5, (i / mask.width) as f32 + 0.5))
            .collect();
        if points.is_empty() {
            return Err(RenderError::value("mask", "is empty: no pixel marks the probe"));
        }
        let n = points.len() as f32;
        let barycenter = points.iter().sum::<Vec2>() / n;
        let (lo, hi) = points.iter().fold(
            (Vec2::splat(f32::INFINITY), Vec2::splat(f32::NEG_INFINITY)),
            |(lo, hi), &p| (lo.min(p), hi.max(p)),
        );
        let (mut sxx, mut sxy, mut syy) = (0.0f32, 0.0f32, 0.0f32);
        for p in &points {
            let d = *p - barycenter;
            sxx += d.x * d.x / n;
            sxy += d.x * d.y / n;
            syy += d.y * d.y / n;
        }
        // Eigen-decomposition of the 2x2 covariance.
        let half_trace = 0.5 * (sxx + syy);
        let root = (0.25 * (sxx - syy).powi(2) + sxy * sxy).sqrt();
        let (major, minor) = (half_trace + root, (half_trace - root).max(1e-6));
        let angle = 0.5 * (2.0 * sxy).atan2(sxx - syy);
        Ok(MaskShape {
            barycenter,
            diagonal_px: (hi - lo + Vec2::ONE).length(),
            principal: Vec2::new(angle.cos(), angle.sin()),
            elongation: (major / minor).sqrt(),
        })
    }
}

/// Directions closer than this (degrees) are one axis hypothesis.
const SAME_AXIS_DEG: f32 = 15.0;

/// A mask rounder than this (spread ratio) shows no principal direction.
const ROUND_MASK: f32 = 1.15;

/// Where the probe's axis (mesh +Y) may point in the world, from what the
/// mask shows and the probe's proportions: upright (along the camera's
/// `up`); for an elongated mask, along the image direction the axis shows
/// as (the mask's principal direction for a probe longer than wide, the
/// direction across it for one wider than long, both when neither), both
/// ways, either in the image plane or lying on a horizontal surface (the
/// same image direction, horizontal in the world); for a round mask, along
/// the view ray both ways (a probe seen end-on). Hypotheses within
/// `SAME_AXIS_DEG` (15) degrees of an earlier one are left out.
pub fn axis_hypotheses(camera: &Camera, shape: &MaskShape, mesh: &Mesh) -> Vec<Vec3> {
    let up = camera.up.normalize();
    let ray = camera.direction_through(shape.barycenter);
    let mut candidates = vec![up];
    if shape.elongation > ROUND_MASK {
        let (lo, hi) = mesh.bounds();
        let (length, width) = (hi.y - lo.y, (hi.x - lo.x).max(hi.z - lo.z));
        let across = Vec2::new(-shape.principal.y, shape.principal.x);
        let directions = if length > ROUND_MASK * width {
            vec![shape.principal]
        } else if width > ROUND_MASK * length {
            vec![across]
        } else {
            vec![shape.principal, across]
        };
        for image_dir in directions {
            // Image y grows downwards.
            let d = camera.right * image_dir.x - camera.image_up * image_dir.y;
            let in_plane = (d - ray * ray.dot(d)).normalize();
            candidates.extend([in_plane, -in_plane]);
            let lying = ray.cross(d).cross(up);
            if lying.length() > 1e-3 {
                let lying = lying.normalize() * lying.dot(d).signum();
                candidates.extend([lying, -lying]);
            }
        }
    } else {
        candidates.extend([-ray, ray]);
    }
    let cos_same = SAME_AXIS_DEG.to_radians().cos();
    let mut axes: Vec<Vec3> = Vec::new();
    for c in candidates {
        if c.is_finite() && axes.iter().all(|a| a.dot(c) < cos_same) {
            axes.push(c);
        }
    }
    axes
}

/// The starting pose with the probe's axis along `axis`, facing the camera:
/// the depth from the probe's known size, as it shows in that orientation,
/// against the mask's extent; the position on the mask's barycenter.
pub fn initial_pose(mesh: &Mesh, camera: &Camera, shape: &MaskShape, axis: Vec3) -> Pose {
    let rotation = facing(camera, axis);
    // The extent of the turned mesh across the view (orthographic: the
    // probe is small against its distance).
    let (lo, hi) = mesh.positions.iter().fold(
        (Vec2::splat(f32::INFINITY), Vec2::splat(f32::NEG_INFINITY)),
        |(lo, hi), &p| {
            let q = rotation * p;
            let on_image = Vec2::new(camera.right.dot(q), camera.image_up.dot(q));
            (lo.min(on_image), hi.max(on_image))
        },
    );
    let diagonal_m = (hi - lo).length();
    let focal_px = 0.5 * camera.height as f32 / (0.5 * camera.fov_y_deg.to_radians()).tan();
    let depth = focal_px * diagonal_m / shape.diagonal_px;
    let (mesh_lo, mesh_hi) = mesh.bounds();
    let centre = 0.5 * (mesh_lo + mesh_hi);
    let dir = camera.direction_through(shape.barycenter);
    let translation = camera.origin + dir * (depth / dir.dot(camera.forward)) - rotation * centre;
    Pose::new(rotation, 1.0, translation)
}

/// An axis leaning towards or away from the camera by less than this
/// (degrees) is about its own mirror twin; its twins lean by
/// [`TWIN_LEAN_DEG`] either way instead.
const UPRIGHT_LEAN_DEG: f32 = 5.0;

/// The lean (degrees) of the twins of an axis that barely leans.
const TWIN_LEAN_DEG: f32 = 10.0;

/// The poses whose outline is about that of `pose`, with the probe's
/// centre in place: its axis mirrored through the plane across the view
/// ray (an axis leaning towards the camera and one leaning as far away
/// show the same outline under orthographic projection), the probe turned
/// end for end (half a turn about its mesh X axis: the same outline where
/// its two ends have like outlines), and both. A silhouette fit stops on
/// whichever of them is nearest its start, or, between two mirror images,
/// on the saddle where the axis crosses the view ray square (the cap of
/// tests/estimate.rs, 10 deg from square, stopped there 5.3 deg off its
/// axis): the twins of an axis within [`UPRIGHT_LEAN_DEG`] of square lean
/// [`TWIN_LEAN_DEG`] towards and away from the camera, each also end for
/// end.
pub fn outline_twins(pose: &Pose, mesh: &Mesh, camera: &Camera) -> Vec<Pose> {
    let (axis, view, tip) = lean_frame(pose, mesh, camera);
    let lean = axis.dot(view).clamp(-1.0, 1.0).asin();
    let leans = match lean.abs() < UPRIGHT_LEAN_DEG.to_radians() {
        true => vec![TWIN_LEAN_DEG.to_radians(), -TWIN_LEAN_DEG.to_radians()],
        false => vec![-lean],
    };
    let end_for_end = |rotation: Quat| rotation * Quat::from_rotation_x(std::f32::consts::PI);
    let mut rotations = vec![end_for_end(pose.rotation)];
    for to in leans {
        let mirror = Quat::from_axis_angle(tip, to - lean) * pose.rotation;
        rotations.extend([mirror, end_for_end(mirror)]);
    }
    rotations
        .into_iter()
        .map(|rotation| rotated(pose, mesh, rotation))
        .collect()
}

/// The probe's axis, the view ray to the centre of its bounding box, and
/// `axis x view`, about which a positive angle leans the axis towards the
/// view ray (any axis square to the probe's, for an axis along the ray).
fn lean_frame(pose: &Pose, mesh: &Mesh, camera: &Camera) -> (Vec3, Vec3, Vec3) {
    let (lo, hi) = mesh.bounds();
    let view = (pose.transform_point(0.5 * (lo + hi)) - camera.origin).normalize();
    let axis = (pose.rotation * Vec3::Y).normalize();
    (axis, view, axis.cross(view).normalize_or(axis.any_orthonormal_vector()))
}

/// `pose` leaned by `deg` towards the camera's view ray (see
/// [`lean_frame`]) about the centre of its bounding box: the turn of the
/// axis that the outline tells least.
pub fn leaned(pose: &Pose, mesh: &Mesh, camera: &Camera, deg: f32) -> Pose {
    let (_, _, tip) = lean_frame(pose, mesh, camera);
    rotated(pose, mesh, Quat::from_axis_angle(tip, deg.to_radians()) * pose.rotation)
}

/// `pose` with the orientation `rotation`, the centre of the probe's
/// bounding box kept in place.
fn rotated(pose: &Pose, mesh: &Mesh, rotation: Quat) -> Pose {
    centred(pose, mesh, rotation.normalize(), pose.scale)
}

/// `pose` with its scale times `factor`, the centre of its bounding box
/// kept in place: the probe's image grows about that centre by `factor`
/// (a larger probe further away looks the same, so this is all a mask a
/// pixel too wide or too narrow gets wrong about the pose).
pub fn rescaled(pose: &Pose, mesh: &Mesh, factor: f32) -> Pose {
    centred(pose, mesh, pose.rotation, pose.scale * factor)
}

/// The pose of `rotation` and `scale` that keeps the centre of the
/// probe's bounding box where `pose` has it.
fn centred(pose: &Pose, mesh: &Mesh, rotation: Quat, scale: f32) -> Pose {
    let (lo, hi) = mesh.bounds();
    let centre = pose.transform_point(0.5 * (lo + hi));
    Pose::new(rotation, scale, centre - rotation * (scale * 0.5 * (lo + hi)))
}

/// `pose` turned by `yaw_deg` about the probe's own axis through the centre
/// of its bounding box (which stays in place).
pub fn turned(pose: &Pose, mesh: &Mesh, yaw_deg: f32) -> Pose {
    let turn = Quat::from_axis_angle((pose.rotation * Vec3::Y).normalize(), yaw_deg.to_radians());
    rotated(pose, mesh, turn * pose.rotation)
}

#[cfg(test)]
mod tests {
    use super::*;
    use render::bsdf::GgxMetal;
    use render::envmap::EnvMap;
    use render::integrator::{RenderSettings, render_image};
    use render::procedural::SodaCan;

    /// A 160x120 camera 0.45 m in front of the origin at `height`, looking
    /// at the point `target_height` above the origin.
    fn camera(height: f32, target_height: f32) -> Camera {
        Camera::new(
            160,
            120,
            40.0,
            Vec3::new(0.0, height, 0.45),
            Vec3::new(0.0, target_height, 0.0),
            Vec3::Y,
        )
        .expect("camera")
    }

    /// The can's mask from `camera` at `truth`.
    fn can_mask(probe: &render::probe::ProbeAsset, camera: &Camera, truth: &Pose) -> Mask {
        let env = EnvMap::constant(8, [1.0; 3]);
        let settings = RenderSettings { spp: 1, seed: 0 };
        render_image(probe, truth, camera, &env, &GgxMetal, &settings).1
    }

    #[test]
    fn the_start_lands_near_the_true_position_of_an_upright_can() {
        let probe = SodaCan::default().build();
        let camera = camera(0.1, 0.06);
        let truth = Pose::new(Quat::from_rotation_y(0.4), 1.0, Vec3::new(0.02, 0.0, -0.03));
        let mask = can_mask(&probe, &camera, &truth);
        let shape = MaskShape::new(&mask).expect("a mask");
        let start = initial_pose(&probe.mesh, &camera, &shape, camera.up);
        let centre = Vec3::new(0.0, 0.061, 0.0);
        let err = (start.transform_point(centre) - truth.transform_point(centre)).length();
        // Measured 0.013 m with the depth from the extent the turned mesh
        // shows (0.028 m from the mesh's 3D bounding box diagonal).
        assert!(err < 0.02, "start is {err} m from the truth");
        let axis = start.rotation * Vec3::Y;
        assert!(
            axis.dot(truth.rotation * Vec3::Y) > 0.95,
            "the start stands upright: {axis}"
        );
    }

    #[test]
    fn one_axis_hypothesis_is_near_the_truth_whether_the_can_stands_lies_or_leans() {
        let probe = SodaCan::default().build();
        let camera = camera(0.25, 0.03);
        // Upright; lying on the table at three headings; leaning towards the
        // image's side; lying towards the camera (seen nearly end-on).
        let lying = |heading: f32| Quat::from_rotation_y(heading) * Quat::from_rotation_z(std::f32::consts::FRAC_PI_2);
        let cases = [
            ("upright", Quat::IDENTITY),
            ("lying across", lying(0.0)),
            ("lying at 40 deg", lying(0.7)),
            ("lying at -60 deg", lying(-1.05)),
            ("leaning", Quat::from_rotation_z(0.6)),
            ("lying end-on", Quat::from_rotation_x(std::f32::consts::FRAC_PI_2)),
        ];
        for (name, rotation) in cases {
            let truth = Pose::new(
                rotation,
                1.0,
                Vec3::new(0.0, 0.035, 0.0) - rotation * Vec3::new(0.0, 0.061, 0.0),
            );
            let mask = can_mask(&probe, &camera, &truth);
            let shape = MaskShape::new(&mask).expect("a mask");
            let axes = axis_hypotheses(&camera, &shape, &probe.mesh);
            let true_axis = rotation * Vec3::Y;
            let best = axes
                .iter()
                .map(|a| a.dot(true_axis).clamp(-1.0, 1.0).acos().to_degrees())
                .fold(f32::INFINITY, f32::min);
            assert!(axes.len() <= 5, "{name}: {} hypotheses", axes.len());
            assert!(
                best < 30.0,
                "{name}: nearest hypothesis {best} deg from the axis ({axes:?})"
            );
        }
    }

    /// A turn by `deg` about +x: a positive one tips the top towards a camera on +z.
    fn lean(deg: f32) -> Quat {
        Quat::from_rotation_x(deg.to_radians())
    }

    /// The can leaning `deg` ([`lean`]) with its centre on the view axis of
    /// a camera level with it: the probe, the camera, its centre and pose.
    fn can_leaning(deg: f32) -> (render::probe::ProbeAsset, Camera, Vec3, Pose) {
        let probe = SodaCan::default().build();
        let (lo, hi) = probe.mesh.bounds();
        let centre = 0.5 * (lo + hi);
        let pose = Pose::new(lean(deg), 1.0, -(lean(deg) * centre));
        (probe, camera(0.0, 0.0), centre, pose)
    }

    #[test]
    fn the_outline_twins_lean_as_far_the_other_way_or_turn_end_for_end_and_show_the_same_outline() {
        // Leaning 20 degrees towards the camera (+z).
        let (probe, camera, centre, pose) = can_leaning(20.0);
        let twins = outline_twins(&pose, &probe.mesh, &camera);
        let wants = [-(lean(20.0) * Vec3::Y), lean(-20.0) * Vec3::Y, -(lean(-20.0) * Vec3::Y)];
        assert_eq!(twins.len(), wants.len());
        let outline = |pose: &Pose| can_mask(&probe, &camera, pose).inside;
        let seen = outline(&pose);
        let area = seen.iter().filter(|&&x| x).count();
        for (twin, want) in twins.iter().zip(wants) {
            assert!(twin.transform_point(centre).length() < 1e-5, "the centre stays");
            let axis = twin.rotation * Vec3::Y;
            assert!((axis - want).length() < 1e-4, "axis {axis} vs {want}");
            let differ = outline(twin).iter().zip(&seen).filter(|(x, y)| x != y).count();
            // Perspective and the can's unlike ends: a fringe.
            assert!(differ * 8 < area, "{differ} of {area} pixels differ");
        }
    }

    #[test]
    fn the_twins_of_an_axis_square_to_the_view_lean_either_way() {
        // Its mirror image would be itself: its twins lean 10 deg away
        // from and towards the camera (the camera is on +z, so a turn about
        // +x by a positive angle tips the top towards it), each also end
        // for end.
        let (probe, camera, _, pose) = can_leaning(2.0);
        let axes: Vec<Vec3> = outline_twins(&pose, &probe.mesh, &camera)
            .iter()
            .map(|twin| twin.rotation * Vec3::Y)
            .collect();
        let wants = [
            -(lean(2.0) * Vec3::Y),
            lean(-10.0) * Vec3::Y,
            -(lean(-10.0) * Vec3::Y),
            lean(10.0) * Vec3::Y,
            -(lean(10.0) * Vec3::Y),
        ];
        assert_eq!(axes.len(), wants.len());
        for (axis, want) in axes.iter().zip(wants) {
            assert!((*axis - want).length() < 1e-4, "axis {axis} vs {want}");
        }
    }

    #[test]
    fn a_turn_keeps_the_probe_in_place_and_its_axis() {
        let probe = SodaCan::default().build();
        let pose = Pose::new(Quat::from_rotation_x(0.5), 1.3, Vec3::new(0.1, -0.2, 0.3));
        let (lo, hi) = probe.mesh.bounds();
        let centre = 0.5 * (lo + hi);
        let turned = turned(&pose, &probe.mesh, 90.0);
        assert!((turned.transform_point(centre) - pose.transform_point(centre)).length() < 1e-5);
        assert!((turned.rotation * Vec3::Y - pose.rotation * Vec3::Y).length() < 1e-5);
        let side = (turned.rotation * Vec3::X).dot(pose.rotation * Vec3::Z);
        assert!((side.abs() - 1.0).abs() < 1e-5, "a quarter turn: {side}");
    }

    #[test]
    fn a_lean_tips_the_axis_towards_the_view_ray_about_the_probe_s_centre() {
        let probe = SodaCan::default().build();
        let camera = camera(0.06, 0.06);
        let pose = Pose::new(Quat::from_rotation_y(0.7), 1.0, Vec3::new(0.01, 0.0, 0.0));
        let (lo, hi) = probe.mesh.bounds();
        let centre = pose.transform_point(0.5 * (lo + hi));
        let view = (centre - camera.origin).normalize();
        let axis_to_view = |p: &Pose| (p.rotation * Vec3::Y).dot(view).asin().to_degrees();
        for deg in [-0.3f32, 0.6] {
            let leaned = leaned(&pose, &probe.mesh, &camera, deg);
            assert!((leaned.transform_point(0.5 * (lo + hi)) - centre).length() < 1e-6);
            let tipped = axis_to_view(&leaned) - axis_to_view(&pose);
            assert!(
                (tipped - deg).abs() < 1e-3,
                "leaned {deg}: the axis tipped {tipped} deg towards the view ray"
            );
        }
    }
}
