//! Starting poses, from the mask and the camera: the probe's known size
//! against the mask's extent gives the depth, the mask's barycenter the
//! direction, and a search over the whole sphere of axis directions, each
//! scored by how well its outline covers the mask, the hypotheses of where
//! the probe's axis points. Also the moves of a pose that the searches try:
//! a turn about the axis, a lean towards the view ray, a sway across it, a
//! change of size, the outline's look-alikes.

use glam::{Mat3, Quat, Vec2, Vec3};
use rayon::prelude::*;
use render::camera::Camera;
use render::image_io::Mask;
use render::mesh::Mesh;
use render::pose::Pose;

use crate::error::{Error, Result};
use crate::estimate::settings::HypothesisSettings;

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

/// The mask's barycenter, its bounding box (pixels) and which of the
/// image's sides it touches.
pub struct MaskShape {
    /// Barycenter, pixels.
    pub barycenter: Vec2,
    /// Bounding box, pixel edges: the low corner of its first pixel and the
    /// high corner of its last.
    pub lo: Vec2,
    /// See `lo`.
    pub hi: Vec2,
    /// Whether the mask reaches the image's low side along x and y (left,
    /// top): the probe may go on beyond it.
    pub cut_lo: [bool; 2],
    /// Whether it reaches the high side (right, bottom).
    pub cut_hi: [bool; 2],
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
            return Err(Error::invalid("mask", "is empty: no pixel marks the probe"));
        }
        let barycenter = points.iter().sum::<Vec2>() / points.len() as f32;
        let (lo, hi) = points.iter().fold(
            (Vec2::splat(f32::INFINITY), Vec2::splat(f32::NEG_INFINITY)),
            |(lo, hi), &p| (lo.min(p), hi.max(p)),
        );
        let (lo, hi) = (lo - Vec2::splat(0.5), hi + Vec2::splat(0.5));
        let size = Vec2::new(mask.width as f32, mask.height as f32);
        Ok(MaskShape {
            barycenter,
            lo,
            hi,
            cut_lo: [lo.x <= 0.0, lo.y <= 0.0],
            cut_hi: [hi.x >= size.x, hi.y >= size.y],
        })
    }
}

/// The mask on a coarse grid over its bounding box (grown by a quarter of
/// its size each way, within the image): what an axis's outline is scored
/// against, cheaply enough to score hundreds of axes.
pub struct OutlineGrid {
    /// Pixel position of the grid's low corner.
    origin: Vec2,
    /// Cell side, pixels.
    cell: f32,
    cols: usize,
    rows: usize,
    /// The share of each cell's pixels that the mask marks.
    covered: Vec<f32>,
}

impl OutlineGrid {
    /// `mask` (of bounding box `shape`) on a grid `cells` cells across its
    /// longer side.
    pub fn new(mask: &Mask, shape: &MaskShape, cells: usize) -> Self {
        let margin = 0.25 * (shape.hi - shape.lo);
        let size = Vec2::new(mask.width as f32, mask.height as f32);
        let (lo, hi) = ((shape.lo - margin).max(Vec2::ZERO), (shape.hi + margin).min(size));
        let cell = ((hi - lo).max_element() / cells.max(1) as f32).max(1.0);
        let (cols, rows) = (
            ((hi.x - lo.x) / cell).ceil() as usize,
            ((hi.y - lo.y) / cell).ceil() as usize,
        );
        let (mut covered, mut pixels) = (vec![0.0f32; cols * rows], vec![0.0f32; cols * rows]);
        for y in lo.y as usize..(hi.y as usize).min(mask.height) {
            for x in lo.x as usize..(hi.x as usize).min(mask.width) {
                let c = (((x as f32 + 0.5 - lo.x) / cell) as usize).min(cols - 1);
                let r = (((y as f32 + 0.5 - lo.y) / cell) as usize).min(rows - 1);
                pixels[r * cols + c] += 1.0;
                covered[r * cols + c] += mask.inside[y * mask.width + x] as u8 as f32;
            }
        }
        for (c, n) in covered.iter_mut().zip(&pixels) {
            *c /= n.max(1.0);
        }
        OutlineGrid {
            origin: lo,
            cell,
            cols,
            rows,
            covered,
        }
    }

    /// How well the outline of `mesh` at `pose` covers the mask: the
    /// intersection over union of the shares of each cell that its
    /// triangles cover (on a 3 x 3 grid of points per cell) and that the
    /// mask marks. 1 is a perfect cover.
    pub fn overlap(&self, mesh: &Mesh, camera: &Camera, pose: &Pose) -> f32 {
        const SUB: usize = 3;
        let to_sub = |p: Vec3| {
            camera
                .project(pose.transform_point(p))
                .map(|px| (px - self.origin) / self.cell * SUB as f32)
        };
        let points: Vec<Option<Vec2>> = mesh.positions.iter().map(|&p| to_sub(p)).collect();
        let (cols, rows) = (self.cols * SUB, self.rows * SUB);
        let mut hit = vec![false; cols * rows];
        for t in &mesh.triangles {
            let [Some(a), Some(b), Some(c)] = t.map(|i| points[i as usize]) else {
                continue;
            };
            let area = (b - a).perp_dot(c - a);
            let (lo, hi) = (
                a.min(b).min(c).max(Vec2::ZERO),
                a.max(b).max(c).min(Vec2::new(cols as f32, rows as f32)),
            );
            if area == 0.0 || lo.x >= hi.x || lo.y >= hi.y {
                continue;
            }
            for r in lo.y.floor() as usize..hi.y.ceil() as usize {
                for col in lo.x.floor() as usize..hi.x.ceil() as usize {
                    let p = Vec2::new(col as f32 + 0.5, r as f32 + 0.5);
                    let w = [
                        (c - b).perp_dot(p - b),
                        (a - c).perp_dot(p - c),
                        (b - a).perp_dot(p - a),
                    ];
                    if w.iter().all(|&w| w * area >= 0.0) {
                        hit[r * cols + col] = true;
                    }
                }
            }
        }
        let (mut both, mut either) = (0.0f32, 0.0f32);
        for (i, &m) in self.covered.iter().enumerate() {
            let (r, c) = (i / self.cols * SUB, i % self.cols * SUB);
            let h = (0..SUB * SUB)
                .filter(|k| hit[(r + k / SUB) * cols + c + k % SUB])
                .count() as f32
                / (SUB * SUB) as f32;
            both += m.min(h);
            either += m.max(h);
        }
        both / either.max(1e-6)
    }
}

/// `n` axis directions spread evenly over the sphere (a Fibonacci lattice).
pub fn sphere_of_axes(n: usize) -> Vec<Vec3> {
    let golden = std::f32::consts::PI * (3.0 - 5f32.sqrt());
    (0..n)
        .map(|i| {
            let y = 1.0 - 2.0 * (i as f32 + 0.5) / n as f32;
            let r = (1.0 - y * y).max(0.0).sqrt();
            let phi = golden * i as f32;
            Vec3::new(r * phi.cos(), y, r * phi.sin())
        })
        .collect()
}

/// Where the probe's axis (mesh +Y) may point in the world: upright and
/// every axis of [`sphere_of_axes`] (`HypothesisSettings::sphere_axes`), each started by
/// [`initial_pose`] and scored by its outline's cover of the mask
/// ([`OutlineGrid::overlap`]); the best `HypothesisSettings::axes_fitted`
/// that lie at least `same_axis_deg` apart, best first, with their scores.
/// The outline cannot tell an axis from its mirror image across the view
/// ray, nor (for like ends) from its reverse: those score alike, and the
/// photo decides between them later.
pub fn axis_hypotheses(
    camera: &Camera,
    shape: &MaskShape,
    grid: &OutlineGrid,
    mesh: &Mesh,
    h: &HypothesisSettings,
) -> Vec<(Vec3, f32)> {
    // Upright (the camera's world up) is scored beside the sphere: the
    // likeliest single orientation for a probe at rest, which no lattice
    // point hits exactly.
    let mut axes = vec![camera.up.normalize()];
    axes.extend(sphere_of_axes(h.sphere_axes));
    let mut scored: Vec<(Vec3, f32)> = axes
        .into_par_iter()
        .map(|axis| {
            let pose = initial_pose(mesh, camera, shape, axis);
            (axis, grid.overlap(mesh, camera, &pose))
        })
        .collect();
    scored.sort_by(|a, b| b.1.total_cmp(&a.1));
    let cos_same = h.same_axis_deg.to_radians().cos();
    let mut kept: Vec<(Vec3, f32)> = Vec::new();
    for (axis, score) in scored {
        if kept.len() < h.axes_fitted && kept.iter().all(|(a, _)| a.dot(axis) < cos_same) {
            kept.push((axis, score));
        }
    }
    kept
}

/// The starting pose with the probe's axis along `axis`, facing the camera:
/// the depth from the probe's known size, as it shows in that orientation,
/// against the mask's extent; the position on the mask's barycenter.
///
/// A mask that reaches a side of the image may belong to a probe going on
/// beyond it, whose extent and barycenter it understates: the depth then
/// comes from the extent across the other way, if the mask spans it whole
/// (else from the extent that says nearer), and the probe's outline is
/// lined up with the mask's edge opposite the cut instead of centred on its
/// barycenter.
pub fn initial_pose(mesh: &Mesh, camera: &Camera, shape: &MaskShape, axis: Vec3) -> Pose {
    let rotation = facing(camera, axis);
    // The extent of the turned mesh across the view (orthographic: the
    // probe is small against its distance), image x right and y up.
    let on_image = |q: Vec3| Vec2::new(camera.right.dot(q), camera.image_up.dot(q));
    let (lo, hi) = mesh.positions.iter().fold(
        (Vec2::splat(f32::INFINITY), Vec2::splat(f32::NEG_INFINITY)),
        |(lo, hi), &p| {
            let q = on_image(rotation * p);
            (lo.min(q), hi.max(q))
        },
    );
    let focal_px = 0.5 * camera.height as f32 / (0.5 * camera.fov_y_deg.to_radians()).tan();
    let (extent_m, extent_px) = (hi - lo, shape.hi - shape.lo);
    let whole = [0, 1].map(|k| !shape.cut_lo[k] && !shape.cut_hi[k]);
    let depth = match whole {
        [true, true] => focal_px * extent_m.length() / extent_px.length(),
        [true, false] => focal_px * extent_m.x / extent_px.x,
        [false, true] => focal_px * extent_m.y / extent_px.y,
        [false, false] => focal_px * (extent_m / extent_px).min_element(),
    };
    let (mesh_lo, mesh_hi) = mesh.bounds();
    let centre = 0.5 * (mesh_lo + mesh_hi);
    // Where the turned mesh's centre projects (pixels, y down), and how far
    // its outline reaches from there towards the image's low and high sides.
    let mut at = shape.barycenter;
    let c = on_image(rotation * centre);
    let px_per_m = focal_px / depth;
    let reach_lo = Vec2::new(c.x - lo.x, hi.y - c.y) * px_per_m;
    let reach_hi = Vec2::new(hi.x - c.x, c.y - lo.y) * px_per_m;
    for k in 0..2 {
        match (shape.cut_lo[k], shape.cut_hi[k]) {
            (true, false) => at[k] = shape.hi[k] - reach_hi[k],
            (false, true) => at[k] = shape.lo[k] + reach_lo[k],
            _ => {}
        }
    }
    let dir = camera.direction_through(at);
    let translation = camera.origin + dir * (depth / dir.dot(camera.forward)) - rotation * centre;
    Pose::new(rotation, 1.0, translation)
}

/// The poses whose outline is about that of `pose`, with the probe's
/// centre in place: its axis mirrored through the plane across the view
/// ray (an axis leaning towards the camera and one leaning as far away
/// show the same outline under orthographic projection), the probe turned
/// end for end (half a turn about its mesh X axis: the same outline where
/// its two ends have like outlines), and both. A silhouette fit stops on
/// whichever of them is nearest its start, or, between two mirror images,
/// on the saddle where the axis crosses the view ray square (a cap 10 deg
/// from square can stop there several degrees off its axis): the twins of an axis
/// within `HypothesisSettings::upright_lean_deg` of square lean
/// `HypothesisSettings::twin_lean_deg` towards and away from the camera, each also end for
/// end.
pub fn outline_twins(pose: &Pose, mesh: &Mesh, camera: &Camera, h: &HypothesisSettings) -> Vec<Pose> {
    let (axis, view, tip) = lean_frame(pose, mesh, camera);
    let lean = axis.dot(view).clamp(-1.0, 1.0).asin();
    let leans = match lean.abs() < h.upright_lean_deg.to_radians() {
        true => vec![h.twin_lean_deg.to_radians(), -h.twin_lean_deg.to_radians()],
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
pub(in crate::estimate) fn lean_frame(pose: &Pose, mesh: &Mesh, camera: &Camera) -> (Vec3, Vec3, Vec3) {
    let view = (box_centre(pose, mesh) - camera.origin).normalize();
    let axis = (pose.rotation * Vec3::Y).normalize();
    (axis, view, axis.cross(view).normalize_or(axis.any_orthonormal_vector()))
}

/// `pose` leaned by `deg` towards the camera's view ray (see
/// `lean_frame`) about the centre of its bounding box: the turn of the
/// axis that the outline tells least.
pub fn leaned(pose: &Pose, mesh: &Mesh, camera: &Camera, deg: f32) -> Pose {
    let (_, _, tip) = lean_frame(pose, mesh, camera);
    rotated(pose, mesh, Quat::from_axis_angle(tip, deg.to_radians()) * pose.rotation)
}

/// `pose` with its axis swayed by `deg` across the view (towards the lean
/// frame's `axis x view`, see `lean_frame`) about the centre of its
/// bounding box: square to the lean, the axis turns in the image's plane
/// and keeps its angle to the view ray.
pub fn swayed(pose: &Pose, mesh: &Mesh, camera: &Camera, deg: f32) -> Pose {
    let (axis, _, tip) = lean_frame(pose, mesh, camera);
    rotated(
        pose,
        mesh,
        Quat::from_axis_angle(axis.cross(tip).normalize(), deg.to_radians()) * pose.rotation,
    )
}

/// `fitted`'s axis, place (the centre of its bounding box) and scale with
/// `pose`'s turn about the axis: `pose` turned by the shortest arc that
/// takes its axis on to `fitted`'s.
pub fn on_axis_of(pose: &Pose, fitted: &Pose, mesh: &Mesh) -> Pose {
    let axis = |p: &Pose| (p.rotation * Vec3::Y).normalize();
    let arc = Quat::from_rotation_arc(axis(pose), axis(fitted));
    placed(
        box_centre(fitted, mesh),
        mesh,
        (arc * pose.rotation).normalize(),
        fitted.scale,
    )
}

/// `pose` with the orientation `rotation`, the centre of the probe's
/// bounding box kept in place.
pub(in crate::estimate) fn rotated(pose: &Pose, mesh: &Mesh, rotation: Quat) -> Pose {
    centred(pose, mesh, rotation.normalize(), pose.scale)
}

/// `pose` with its scale times `factor`, the centre of its bounding box
/// kept in place: the probe's image grows about that centre by `factor`
/// (a larger probe further away looks the same, so this is all a mask a
/// pixel too wide or too narrow gets wrong about the pose).
pub fn rescaled(pose: &Pose, mesh: &Mesh, factor: f32) -> Pose {
    centred(pose, mesh, pose.rotation, pose.scale * factor)
}

/// The pose at the probe's own size (scale 1: the asset is in metres) that
/// the camera sees as it sees `pose`: `pose` scaled by `1 / scale` about
/// the camera's centre, which moves no ray, and no normal either. Scale and
/// distance are one unknown to a pinhole camera under distant light (an
/// outline fit's scale drifts freely along it); the known size pins it.
pub fn at_own_size(pose: &Pose, mesh: &Mesh, camera: &Camera) -> Pose {
    let centre = camera.origin + (box_centre(pose, mesh) - camera.origin) / pose.scale;
    placed(centre, mesh, pose.rotation, 1.0)
}

/// The pose of `rotation` and `scale` that keeps the centre of the
/// probe's bounding box where `pose` has it.
pub(in crate::estimate) fn centred(pose: &Pose, mesh: &Mesh, rotation: Quat, scale: f32) -> Pose {
    placed(box_centre(pose, mesh), mesh, rotation, scale)
}

/// Where `pose` puts the centre of the probe's bounding box.
pub(in crate::estimate) fn box_centre(pose: &Pose, mesh: &Mesh) -> Vec3 {
    let (lo, hi) = mesh.bounds();
    pose.transform_point(0.5 * (lo + hi))
}

/// The pose of `rotation` and `scale` that puts the centre of the probe's
/// bounding box at `centre`.
pub(in crate::estimate) fn placed(centre: Vec3, mesh: &Mesh, rotation: Quat, scale: f32) -> Pose {
    let (lo, hi) = mesh.bounds();
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
    use crate::estimate::Settings;

    /// The default settings.
    fn h() -> HypothesisSettings {
        Settings::default().hypotheses
    }
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
        // About 0.013 m with the depth from the extent the turned mesh shows;
        // a depth from the mesh's 3D bounding box diagonal fails (0.028 m).
        assert!(err < 0.02, "start is {err} m from the truth");
        let axis = start.rotation * Vec3::Y;
        assert!(
            axis.dot(truth.rotation * Vec3::Y) > 0.95,
            "the start stands upright: {axis}"
        );
    }

    #[test]
    fn a_can_cut_by_any_side_of_the_photo_starts_where_it_shows_and_its_axis_is_a_hypothesis() {
        let probe = SodaCan::default().build();
        let truth = Pose::new(Quat::from_rotation_y(0.4), 1.0, Vec3::ZERO);
        let centre = Vec3::new(0.0, 0.061, 0.0);
        // The camera looks past the can, which reaches beyond the photo's
        // right, left, bottom or top side by about a third of its extent.
        for (target, cut) in [
            (Vec3::new(-0.205, 0.061, 0.0), "right"),
            (Vec3::new(0.205, 0.061, 0.0), "left"),
            (Vec3::new(0.0, 0.205, 0.0), "bottom"),
            (Vec3::new(0.0, -0.083, 0.0), "top"),
        ] {
            let camera = Camera::new(160, 120, 40.0, Vec3::new(0.0, 0.1, 0.45), target, Vec3::Y).expect("camera");
            let mask = can_mask(&probe, &camera, &truth);
            let shape = MaskShape::new(&mask).expect("a mask");
            let flags = [shape.cut_lo[0], shape.cut_hi[0], shape.cut_lo[1], shape.cut_hi[1]];
            let expected = ["left", "right", "top", "bottom"].map(|side| side == cut);
            assert_eq!(flags, expected, "the can reaches the {cut} side only");
            let start = initial_pose(&probe.mesh, &camera, &shape, camera.up);
            let shown = |pose: &Pose| camera.project(pose.transform_point(centre)).expect("in front");
            // About 1 px off and 0.95 to 0.97 of the depth; started as a
            // whole mask is (on its barycenter, the depth from its diagonal),
            // it fails (4 to 9 px off, up to 1.39 of the depth).
            let off = (shown(&start) - shown(&truth)).length();
            assert!(off < 2.5, "cut at the {cut}: the start's centre shows {off} px off");
            let depth = |pose: &Pose| (pose.transform_point(centre) - camera.origin).dot(camera.forward);
            let ratio = depth(&start) / depth(&truth);
            assert!(
                (ratio - 1.0).abs() < 0.06,
                "cut at the {cut}: depth {ratio} of the truth's"
            );
            // The outline search finds the upright axis though the mask
            // shows only part of the can.
            let grid = OutlineGrid::new(&mask, &shape, h().outline_cells);
            let axes = axis_hypotheses(&camera, &shape, &grid, &probe.mesh, &h());
            assert!(
                axes.iter().any(|(a, _)| a.dot(Vec3::Y) > 15f32.to_radians().cos()),
                "cut at the {cut}: no axis near upright among {axes:?}"
            );
        }
    }

    #[test]
    fn one_axis_hypothesis_is_near_the_truth_however_a_can_or_a_squat_cap_lies() {
        let can = SodaCan::default().build();
        let cap = render::procedural::ThermosCap::default().build();
        let camera = camera(0.25, 0.03);
        let lying = |heading: f32| Quat::from_rotation_y(heading) * Quat::from_rotation_z(std::f32::consts::FRAC_PI_2);
        let cases = [
            ("upright", Quat::IDENTITY),
            ("lying across", lying(0.0)),
            ("lying at 40 deg", lying(0.7)),
            ("lying at -60 deg", lying(-1.05)),
            ("leaning", Quat::from_rotation_z(0.6)),
            ("lying end-on", Quat::from_rotation_x(std::f32::consts::FRAC_PI_2)),
            ("standing on its top", Quat::from_rotation_x(std::f32::consts::PI)),
            ("tilted 55 deg in depth", Quat::from_rotation_x(55f32.to_radians())),
            (
                "tilted 55 deg both ways",
                Quat::from_rotation_z(0.5) * Quat::from_rotation_x(55f32.to_radians()),
            ),
        ];
        for (probe, kind) in [(&can, "can"), (&cap, "cap")] {
            let (lo, hi) = probe.mesh.bounds();
            let centre = 0.5 * (lo + hi);
            for (name, rotation) in cases {
                let truth = Pose::new(rotation, 1.0, Vec3::new(0.0, 0.035, 0.0) - rotation * centre);
                let mask = can_mask(probe, &camera, &truth);
                let shape = MaskShape::new(&mask).expect("a mask");
                let grid = OutlineGrid::new(&mask, &shape, h().outline_cells);
                let axes = axis_hypotheses(&camera, &shape, &grid, &probe.mesh, &h());
                let true_axis = rotation * Vec3::Y;
                // The truth's own outline covers its mask best of all.
                let own = grid.overlap(&probe.mesh, &camera, &truth);
                assert!(own > 0.9, "{kind} {name}: the true pose covers {own} of its mask");
                // The outline cannot tell an axis from its reverse: either counts.
                let best = axes
                    .iter()
                    .map(|(a, _)| a.dot(true_axis).abs().clamp(0.0, 1.0).acos().to_degrees())
                    .fold(f32::INFINITY, f32::min);
                assert!(
                    axes.len() <= h().axes_fitted,
                    "{kind} {name}: {} hypotheses",
                    axes.len()
                );
                assert!(
                    best < 15.0,
                    "{kind} {name}: nearest hypothesis {best} deg from the axis ({axes:?})"
                );
            }
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
        let twins = outline_twins(&pose, &probe.mesh, &camera, &h());
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
        let axes: Vec<Vec3> = outline_twins(&pose, &probe.mesh, &camera, &h())
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
    fn at_its_own_size_the_probe_looks_the_same() {
        let probe = SodaCan::default().build();
        let camera = camera(0.06, 0.06);
        let pose = Pose::new(Quat::from_rotation_x(0.5), 0.85, Vec3::new(0.01, 0.02, 0.03));
        let own = at_own_size(&pose, &probe.mesh, &camera);
        assert_eq!((own.scale, own.rotation), (1.0, pose.rotation));
        let further = (own.translation - camera.origin).length() / (pose.translation - camera.origin).length();
        assert!(further > 1.1, "the larger probe is further away: {further}");
        for &p in &probe.mesh.positions {
            let (seen, seen_own) = (
                camera.project(pose.transform_point(p)),
                camera.project(own.transform_point(p)),
            );
            let moved = (seen.unwrap() - seen_own.unwrap()).length();
            assert!(moved < 1e-3, "vertex {p} moved {moved} px");
        }
        let same = at_own_size(&own, &probe.mesh, &camera);
        assert!((same.translation - own.translation).length() < 1e-6);
    }

    #[test]
    fn on_a_fitted_axis_a_pose_keeps_its_turn() {
        let probe = SodaCan::default().build();
        let pose = Pose::new(Quat::from_rotation_x(0.5), 1.0, Vec3::new(0.01, 0.02, 0.03));
        // A fit that tipped the axis by 1 deg, moved the probe and turned it 20 deg about the axis.
        let tip = Quat::from_axis_angle(Vec3::new(0.6, 0.0, 0.8), 1f32.to_radians());
        let fitted = turned(
            &Pose::new(tip * pose.rotation, 1.0, pose.translation + Vec3::new(0.001, 0.0, 0.0)),
            &probe.mesh,
            20.0,
        );
        let kept = on_axis_of(&pose, &fitted, &probe.mesh);
        let axis = |p: &Pose| p.rotation * Vec3::Y;
        assert!(axis(&kept).angle_between(axis(&fitted)) < 1e-3, "on the fitted axis");
        let centre = |p: &Pose| box_centre(p, &probe.mesh);
        assert!((centre(&kept) - centre(&fitted)).length() < 1e-6, "at the fitted place");
        // From the pose to the kept one, a tip of the axis alone: no turn about it.
        let (about, angle) = (kept.rotation * pose.rotation.inverse()).to_axis_angle();
        let tipped = axis(&pose).angle_between(axis(&fitted));
        assert!(tipped > 0.5f32.to_radians(), "the fit tipped the axis");
        assert!((angle - tipped).abs() < 1e-5, "turned {angle} rad, tipped {tipped}");
        assert!(about.dot(axis(&pose)).abs() < 1e-3, "turned about the axis: {about}");
    }

    #[test]
    fn a_sway_turns_the_axis_across_the_view_keeping_its_angle_to_the_view_ray() {
        let probe = SodaCan::default().build();
        let camera = camera(0.06, 0.06);
        let pose = Pose::new(
            Quat::from_rotation_x(0.4) * Quat::from_rotation_y(0.7),
            1.0,
            Vec3::new(0.01, 0.0, 0.0),
        );
        let (lo, hi) = probe.mesh.bounds();
        let centre = pose.transform_point(0.5 * (lo + hi));
        let view = (centre - camera.origin).normalize();
        let axis = |p: &Pose| (p.rotation * Vec3::Y).normalize();
        for deg in [-0.5f32, 1.0] {
            let swayed = swayed(&pose, &probe.mesh, &camera, deg);
            assert!((swayed.transform_point(0.5 * (lo + hi)) - centre).length() < 1e-6);
            let turned = axis(&swayed).angle_between(axis(&pose)).to_degrees();
            assert!(
                (turned - deg.abs()).abs() < 1e-3,
                "swayed {deg}: the axis turned {turned} deg"
            );
            // Across the view: the axis keeps its angle to the view ray (to
            // the cosine of the sway), where a lean would tip it by `deg`.
            let to_view = |p: &Pose| axis(p).dot(view).asin().to_degrees();
            assert!(
                (to_view(&swayed) - to_view(&pose)).abs() < 0.01 * deg.abs(),
                "swayed {deg}: the axis tipped {} deg towards the view ray",
                to_view(&swayed) - to_view(&pose)
            );
        }
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
