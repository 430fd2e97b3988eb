//! Starting poses, from the mask and the camera: the probe's known size
//! against the mask's extent gives the depth, the mask's barycenter the
//! direction, and the mask's shape the hypotheses of where the probe's axis
//! points (upright, along the mask's principal direction, end-on); turns
//! about the axis (yaws) make the orientation starts.

use std::collections::BTreeMap;

use glam::{DMat3, DVec3, Mat3, Quat, Vec2, Vec3};
use render::camera::Camera;
use render::image_io::Mask;
use render::mesh::Mesh;
use render::pose::Pose;
use render::probe::ProbeAsset;
use render::{RenderError, Result};

/// Eigenvalues of the surface's spread closer than this factor are equal:
/// no axis stands out (a sphere), or not that one.
const DISTINCT_SPREAD: f64 = 1.05;

/// An axis found within this angle (degrees) of the mesh's +Y is +Y: the
/// mesh was built along it (faceting tilts the found axis a little).
const AXIS_IS_Y_DEG: f64 = 1.0;

/// A facet's normal line passes within this fraction of the surface's size
/// (RMS distance from its centroid) of an axis of revolution it belongs to,
/// measured as `((p - c) x n) . a`: faceting leaves a third of a 64-sided
/// can's triangles within 1 %, all within 5 % (a triangle's centroid is off
/// its quad's meridian); the surface has that axis when at least
/// [`REVOLVED_SHARE`] of its area does.
const ON_AXIS: f64 = 0.05;

/// An axis of revolution is one only when the next best line leaves this
/// many times its residual (the suite's can, cap and ring: 780 to 3,900
/// times; a sphere, 1.1).
const SECOND_AXIS_RATIO: f64 = 20.0;

/// A surface this much of revolution about its axis (by area) shows one
/// outline at every turn about it (the suite's can, cap and ring: all of
/// it; a mug with a handle: 0.90).
const WHOLLY_REVOLVED: f64 = 0.98;

/// Fits of the axis of revolution, each weighing the facets by how far the
/// one before left their normal lines from it.
const REWEIGHTINGS: usize = 8;

/// The share of a probe's surface that must be of revolution about one
/// axis for that to be its axis (a mug's body without its handle).
const REVOLVED_SHARE: f64 = 0.6;

/// The rotation that turns the probe's axis to mesh +Y: the estimate turns
/// the probe about +Y (its yaw starts) and reads its length along it. The
/// axis is the probe's axis of revolution ([`axis_of_revolution`]: a mug's
/// body's, where the spread of its surface picks the direction across its
/// handle), else the principal direction of the surface's spread
/// (area-weighted second moments) whose spread stands out from the other
/// two: the longest for a probe longer than wide, the shortest for one
/// wider than long. Identity when the axis is already +Y (to
/// [`AXIS_IS_Y_DEG`]) or none stands out (a sphere). Of the axis's two
/// directions, the one nearer +Y, or with its largest component positive,
/// goes to +Y.
pub fn axis_to_y(mesh: &Mesh) -> Quat {
    let revolved = axis_of_revolution(mesh).map(|revolution| revolution.axis);
    let Some(axis) = revolved.or_else(|| axis_of_spread(mesh)) else {
        return Quat::IDENTITY;
    };
    if axis.y.abs() >= AXIS_IS_Y_DEG.to_radians().cos() {
        return Quat::IDENTITY;
    }
    let largest = axis.abs().max_element();
    let positive = match axis.y.abs() > 1e-3 {
        true => axis.y > 0.0,
        false => axis
            .to_array()
            .iter()
            .find(|v| v.abs() == largest)
            .is_some_and(|v| *v > 0.0),
    };
    let axis = if positive { axis } else { -axis };
    Quat::from_rotation_arc(axis.as_vec3().normalize(), Vec3::Y)
}

/// The facets of `mesh`: centroid, unit normal and area (degenerate ones
/// left out).
fn facets(mesh: &Mesh) -> Vec<(DVec3, DVec3, f64)> {
    (0..mesh.triangles.len())
        .filter_map(|t| {
            let [a, b, c] = mesh.corners(t).map(|p| p.as_dvec3());
            let twice_area = mesh.face_normal(t).as_dvec3();
            let area = 0.5 * twice_area.length();
            (area > 0.0).then(|| ((a + b + c) / 3.0, twice_area / (2.0 * area), area))
        })
        .collect()
}

/// The line about which at least [`REVOLVED_SHARE`] of the surface is of
/// revolution, if there is one line only (a sphere, of revolution about
/// every line through its centre, has none): its direction and that share.
/// Every
/// normal line of a surface of revolution meets its axis (or runs parallel
/// to it): with the axis's direction `a` and moment `m = c x a` (`c` a
/// point on it), each facet's `(p x n) . a + n . m` is 0 (`p` its centroid,
/// `n` its normal; Pottmann and Randrup's line-geometric test for surfaces
/// of revolution). Least squares over the facets' areas gives `m` for
/// each `a`, and `a` as the least eigenvector of what is left; facets off
/// the axis (a handle) are then weighed down and the fit repeated.
pub fn axis_of_revolution(mesh: &Mesh) -> Option<Revolution> {
    let facets = facets(mesh);
    let area: f64 = facets.iter().map(|f| f.2).sum();
    let centroid = facets.iter().map(|(p, _, w)| *p * *w).sum::<DVec3>() / area.max(1e-300);
    let size = (facets
        .iter()
        .map(|(p, _, w)| w * (*p - centroid).length_squared())
        .sum::<f64>()
        / area.max(1e-300))
    .sqrt();
    if !size.is_finite() || size <= 0.0 {
        return None;
    }
    // Centred and in units of the size: the residual is then a distance in sizes.
    let lines: Vec<(DVec3, DVec3)> = facets.iter().map(|(p, n, _)| ((*p - centroid) / size, *n)).collect();
    let mut weight: Vec<f64> = facets.iter().map(|f| f.2 / area).collect();
    // The last fit's axis, residuals and whether a second line fits about as well.
    let mut last = None;
    for _ in 0..REWEIGHTINGS {
        let outer = |u: DVec3, v: DVec3| DMat3::from_cols(u * v.x, u * v.y, u * v.z);
        let (mut nn, mut mn, mut mm) = (DMat3::ZERO, DMat3::ZERO, DMat3::ZERO);
        for ((p, n), &w) in lines.iter().zip(&weight) {
            let pn = p.cross(*n);
            nn += outer(*n, *n) * w;
            mn += outer(pn, *n) * w;
            mm += outer(pn, pn) * w;
        }
        if nn.determinant().abs() < 1e-12 {
            return None;
        }
        // The moment that fits direction a best is -nn^-1 mn^T a; what is
        // left is a^T (mm - mn nn^-1 mn^T) a.
        let to_moment = -(nn.inverse() * mn.transpose());
        let left = mm + mn * to_moment;
        let (values, vectors) = symmetric_eigen(std::array::from_fn(|i| std::array::from_fn(|j| left.col(j)[i])));
        let mut order = [0, 1, 2];
        order.sort_by(|&i, &j| values[i].total_cmp(&values[j]));
        let axis = DVec3::from_array(vectors[order[0]]);
        let moment = to_moment * axis;
        let residual: Vec<f64> = lines
            .iter()
            .map(|(p, n)| (p.cross(*n).dot(axis) + n.dot(moment)).abs())
            .collect();
        weight = facets
            .iter()
            .zip(&residual)
            .map(|(f, r)| f.2 / area / (1.0 + (r / ON_AXIS).powi(2)))
            .collect();
        // A second line that fits about as well: all normal lines pass
        // through one point (a sphere), and every line through it is an axis.
        let single = values[order[1]] >= SECOND_AXIS_RATIO * values[order[0]].max(1e-12);
        last = Some((axis, moment, residual, single));
    }
    let (axis, moment, residual, single) = last?;
    let revolved: f64 = facets
        .iter()
        .zip(&residual)
        .filter(|(_, r)| **r <= ON_AXIS)
        .map(|(f, _)| f.2)
        .sum();
    (single && revolved >= REVOLVED_SHARE * area).then_some(Revolution {
        axis,
        // The point of the line nearest the centroid, back in mesh units.
        point: centroid + axis.cross(moment) * size,
        share: revolved / area,
    })
}

/// A probe's axis of revolution and the share of its surface's area that
/// is of revolution about it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Revolution {
    /// The axis's unit direction.
    pub axis: DVec3,
    /// A point on the axis.
    pub point: DVec3,
    /// The share of the area whose normal lines meet the axis (within [`ON_AXIS`]).
    pub share: f64,
}

/// Whether turning the probe about its axis changes its outline: a surface
/// not wholly of revolution (a mug's handle; a box), though not a sphere,
/// of revolution about every line through its centre.
pub fn turns_show(mesh: &Mesh) -> bool {
    match axis_of_revolution(mesh) {
        Some(revolution) => revolution.share < WHOLLY_REVOLVED,
        None => axis_of_spread(mesh).is_some(),
    }
}

/// Whether the probe looks the same at every turn about its axis of
/// revolution, decided from the asset (Some): its whole surface of
/// revolution, and its material (albedo, roughness, visibility) the same all
/// round each circle about the axis, as on a cap of one colour and not on a
/// can's label. None where the asset cannot tell: no single axis (a sphere,
/// of revolution about every line through its centre), or facets that do
/// not sample the circles (a scan's irregular mesh). Comparing two turns'
/// renders tells it only where the mesh's facets come back at that turn
/// (45 deg for the suite's 64-sided caps: at 30 deg, best quality's first
/// two turns, the facets made the renders of 7 of its 9 caps differ by
/// more than `renders_alike` allows: relative errors up to 1.5e-3 apart
/// against 1e-4, or RGB angles 0.034 deg against 0.02; ranked as
/// patterned, 2 upright caps came out end for end).
pub fn looks_alike_turned(asset: &ProbeAsset) -> Option<bool> {
    let revolution = axis_of_revolution(&asset.mesh)?;
    if revolution.share < WHOLLY_REVOLVED {
        return Some(false);
    }
    if [&asset.albedo, &asset.roughness, &asset.visibility]
        .iter()
        .all(|t| t.is_constant())
    {
        return Some(true);
    }
    let mesh = &asset.mesh;
    let extent = mesh
        .positions
        .iter()
        .map(|p| (p.as_dvec3() - revolution.point).length())
        .fold(0.0, f64::max);
    let bin = CIRCLE_BIN * extent;
    // Per circle about the axis (height along it and radius from it, in
    // bins): each channel's least and greatest value, the area sampled
    // and the samples (in key order, so that the sums do not depend on a
    // hash's seed).
    let mut circles: BTreeMap<(i64, i64), Circle> = BTreeMap::new();
    let mut total = 0.0;
    for t in 0..mesh.triangles.len() {
        let share = 0.5 * mesh.face_normal(t).length() as f64 / CIRCLE_SAMPLES.len() as f64;
        if share.is_nan() || share <= 0.0 {
            continue;
        }
        for b in CIRCLE_SAMPLES.map(|[b1, b2]| Vec2::new(b1, b2)) {
            let p = mesh.interpolate(&mesh.positions, t, b).as_dvec3() - revolution.point;
            let m = asset.material(mesh.interpolate(&mesh.uvs, t, b));
            let value = [m.albedo[0], m.albedo[1], m.albedo[2], m.roughness, m.visibility];
            let height = p.dot(revolution.axis);
            let radius = (p - revolution.axis * height).length();
            let key = ((height / bin).round() as i64, (radius / bin).round() as i64);
            let circle = circles.entry(key).or_insert(Circle {
                least: value,
                greatest: value,
                area: 0.0,
                samples: 0,
            });
            for ((least, greatest), v) in circle.least.iter_mut().zip(&mut circle.greatest).zip(value) {
                *least = least.min(v);
                *greatest = greatest.max(v);
            }
            circle.area += share;
            circle.samples += 1;
            total += share;
        }
    }
    let area_where = |keep: &dyn Fn(&Circle) -> bool| circles.values().filter(|c| keep(c)).map(|c| c.area).sum::<f64>();
    if area_where(&|c| c.samples >= CIRCLE_MIN_SAMPLES) < 0.5 * total {
        return None;
    }
    let varied = area_where(&|c| {
        c.least
            .iter()
            .zip(&c.greatest)
            .any(|(least, greatest)| greatest - least > MATERIAL_TOLERANCE)
    });
    Some(varied <= VARIED_SHARE * total)
}

/// The material sampled along one circle about the axis of revolution.
struct Circle {
    least: [f32; 5],
    greatest: [f32; 5],
    area: f64,
    samples: usize,
}

/// Circles about the axis are told apart to this fraction of the probe's
/// extent from it: points of a revolved mesh's facets that its turns map
/// onto each other fall in one.
const CIRCLE_BIN: f64 = 1e-3;

/// Where on each facet the material is sampled (barycentric weights of
/// corners 1 and 2): its centroid and a point towards each corner.
const CIRCLE_SAMPLES: [[f32; 2]; 4] = [
    [1.0 / 3.0, 1.0 / 3.0],
    [1.0 / 6.0, 1.0 / 6.0],
    [2.0 / 3.0, 1.0 / 6.0],
    [1.0 / 6.0, 2.0 / 3.0],
];

/// A circle sampled this many times at least tells whether the material
/// varies along it; the asset decides when such circles hold half its area.
const CIRCLE_MIN_SAMPLES: usize = 4;

/// A material channel that varies by more than this along a circle shows
/// the turn (an 8-bit texture's steps are 0.004).
const MATERIAL_TOLERANCE: f32 = 0.01;

/// The material looks alike at every turn when the circles along which it
/// varies hold at most this share of the area (the probe's own bands put a
/// circle's samples on both sides of an edge only by rounding). The
/// procedural cap: none of its 142 circles; the can: 33 % of its area.
const VARIED_SHARE: f64 = 0.01;

/// The principal direction of the surface's spread that stands out from
/// the other two, if one does (see [`axis_to_y`]).
fn axis_of_spread(mesh: &Mesh) -> Option<DVec3> {
    let (mut area, mut first, mut second) = (0.0f64, [0.0f64; 3], [[0.0f64; 3]; 3]);
    for t in 0..mesh.triangles.len() {
        let [a, b, c] = mesh.corners(t).map(|p| p.as_dvec3());
        let da = 0.5 * (b - a).cross(c - a).length();
        let sum = a + b + c;
        area += da;
        for i in 0..3 {
            first[i] += da * sum[i] / 3.0;
            for j in 0..3 {
                // The exact second moment of a triangle about the origin.
                second[i][j] += da / 12.0 * (a[i] * a[j] + b[i] * b[j] + c[i] * c[j] + sum[i] * sum[j]);
            }
        }
    }
    if area <= 0.0 {
        return None;
    }
    let mean = first.map(|m| m / area);
    let spread: [[f64; 3]; 3] =
        std::array::from_fn(|i| std::array::from_fn(|j| second[i][j] / area - mean[i] * mean[j]));
    let (values, vectors) = symmetric_eigen(spread);
    let mut order = [0, 1, 2];
    order.sort_by(|&i, &j| values[i].total_cmp(&values[j]));
    let [low, mid, high] = order.map(|k| values[k].max(1e-30));
    let (stands_out, axis) = match high / mid > mid / low {
        true => (high / mid, vectors[order[2]]),
        false => (mid / low, vectors[order[0]]),
    };
    (stands_out >= DISTINCT_SPREAD).then(|| DVec3::from_array(axis))
}

/// Eigenvalues and unit eigenvectors of a symmetric 3x3 matrix, by cyclic
/// Jacobi rotations.
fn symmetric_eigen(mut a: [[f64; 3]; 3]) -> ([f64; 3], [[f64; 3]; 3]) {
    let mut v = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
    for _ in 0..50 {
        let off = a[0][1].abs() + a[0][2].abs() + a[1][2].abs();
        let scale = a[0][0].abs() + a[1][1].abs() + a[2][2].abs();
        if off <= 1e-15 * scale {
            break;
        }
        for (p, q) in [(0, 1), (0, 2), (1, 2)] {
            if a[p][q] == 0.0 {
                continue;
            }
            let theta = 0.5 * (a[q][q] - a[p][p]) / a[p][q];
            // The smaller root of t^2 + 2 theta t - 1 = 0 (1 for theta 0).
            let t = theta.signum() / (theta.abs() + (theta * theta + 1.0).sqrt());
            let (c, s) = (1.0 / (t * t + 1.0).sqrt(), t / (t * t + 1.0).sqrt());
            // A <- J^T A J and V <- V J, J the rotation in the (p, q) plane.
            let rotate_columns = |m: &mut [[f64; 3]; 3]| {
                for row in m.iter_mut() {
                    let (mp, mq) = (row[p], row[q]);
                    row[p] = c * mp - s * mq;
                    row[q] = s * mp + c * mq;
                }
            };
            rotate_columns(&mut a);
            rotate_columns(&mut v);
            let (ap, aq) = (a[p], a[q]);
            a[p] = std::array::from_fn(|k| c * ap[k] - s * aq[k]);
            a[q] = std::array::from_fn(|k| s * ap[k] + c * aq[k]);
        }
    }
    // Eigenvector k is column k of v.
    let vectors = std::array::from_fn(|k| [v[0][k], v[1][k], v[2][k]]);
    ([a[0][0], a[1][1], a[2][2]], vectors)
}

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

/// The mask's barycenter, its bounding box (pixels), which of the image's
/// sides it touches, its principal direction (unit, image x right and y
/// down) and elongation (the ratio of the standard deviations along and
/// across that direction).
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
        let (lo, hi) = (lo - Vec2::splat(0.5), hi + Vec2::splat(0.5));
        let size = Vec2::new(mask.width as f32, mask.height as f32);
        Ok(MaskShape {
            barycenter,
            lo,
            hi,
            cut_lo: [lo.x <= 0.0, lo.y <= 0.0],
            cut_hi: [hi.x >= size.x, hi.y >= size.y],
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
/// the view ray both ways (a probe seen end-on); for a mask the image's
/// border cuts, all of these, along both of its directions. Upright is both ways too
/// unless `top_known` (mesh +Y is the probe's top, as a probe standing on
/// its -Y end is built; not so for one whose axis [`axis_to_y`] turned to
/// +Y, whose ends are anyone's guess). Hypotheses within `SAME_AXIS_DEG`
/// (15) degrees of an earlier one are left out.
pub fn axis_hypotheses(camera: &Camera, shape: &MaskShape, mesh: &Mesh, top_known: bool) -> Vec<Vec3> {
    let up = camera.up.normalize();
    let ray = camera.direction_through(shape.barycenter);
    let mut candidates = match top_known {
        true => vec![up],
        false => vec![up, -up],
    };
    let (lo, hi) = mesh.bounds();
    let (length, width) = (hi.y - lo.y, (hi.x - lo.x).max(hi.z - lo.z));
    let across = Vec2::new(-shape.principal.y, shape.principal.x);
    let round = shape.elongation <= ROUND_MASK;
    // A mask the image's border cuts shows neither the probe's proportions
    // nor whether it is round: every direction is tried.
    let cut = shape.cut_lo.iter().chain(&shape.cut_hi).any(|&c| c);
    let directions = if cut {
        vec![shape.principal, across]
    } else if round {
        vec![]
    } else if length > ROUND_MASK * width {
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
    if round || cut {
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
    let view = (box_centre(pose, mesh) - camera.origin).normalize();
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

/// `pose` with its axis swayed by `deg` across the view (towards the lean
/// frame's `axis x view`, see [`lean_frame`]) about the centre of its
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
fn centred(pose: &Pose, mesh: &Mesh, rotation: Quat, scale: f32) -> Pose {
    placed(box_centre(pose, mesh), mesh, rotation, scale)
}

/// Where `pose` puts the centre of the probe's bounding box.
fn box_centre(pose: &Pose, mesh: &Mesh) -> Vec3 {
    let (lo, hi) = mesh.bounds();
    pose.transform_point(0.5 * (lo + hi))
}

/// The pose of `rotation` and `scale` that puts the centre of the probe's
/// bounding box at `centre`.
fn placed(centre: Vec3, mesh: &Mesh, rotation: Quat, scale: f32) -> Pose {
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
    use render::bsdf::GgxMetal;
    use render::envmap::EnvMap;
    use render::integrator::{RenderSettings, render_image};
    use render::procedural::SodaCan;

    #[test]
    fn the_eigen_decomposition_rebuilds_its_matrix() {
        let a = [[2.0, -0.7, 0.3], [-0.7, 1.1, 0.05], [0.3, 0.05, 0.4]];
        let (values, vectors) = symmetric_eigen(a);
        for i in 0..3 {
            for j in 0..3 {
                let rebuilt: f64 = (0..3).map(|k| values[k] * vectors[k][i] * vectors[k][j]).sum();
                assert!(
                    (rebuilt - a[i][j]).abs() < 1e-12,
                    "({i}, {j}): {rebuilt} against {}",
                    a[i][j]
                );
                let dot: f64 = (0..3).map(|k| vectors[i][k] * vectors[j][k]).sum();
                assert!((dot - (i == j) as u8 as f64).abs() < 1e-12);
            }
        }
    }

    #[test]
    fn a_probe_s_axis_goes_to_y_whichever_way_its_mesh_was_built() {
        let can = SodaCan::default().build().mesh;
        let cap = render::procedural::ThermosCap::default().build().mesh;
        // A disc-like probe (wider than long, like a ring): a flattened
        // sphere (its normals, which the axis does not read, left as they were).
        let sphere = render::procedural::UvSphere::default().build().mesh;
        let disc = Mesh {
            positions: sphere
                .positions
                .iter()
                .map(|p| Vec3::new(p.x, 0.3 * p.y, p.z))
                .collect(),
            ..sphere.clone()
        };
        // Built along +Y: left as it is (the suite's outputs stay as they were).
        for mesh in [&can, &cap, &disc] {
            assert_eq!(axis_to_y(mesh), Quat::IDENTITY);
        }
        // A sphere has no axis.
        assert_eq!(axis_to_y(&sphere), Quat::IDENTITY);
        // Built along another axis (and off the origin): turned to +Y.
        let turn = Quat::from_axis_angle(Vec3::new(0.3, -0.5, 0.8).normalize(), 1.9);
        for mesh in [&can, &cap, &disc] {
            let built = mesh.posed(&Pose::new(turn, 1.0, Vec3::new(0.2, -0.1, 0.05)));
            let to_y = axis_to_y(&built);
            let axis = to_y * (turn * Vec3::Y);
            assert!(axis.y.abs() > 0.9999, "the axis goes to {axis}");
        }
    }

    /// A closed tube swept along `centre(t)` (t in [0, 1], `rings` steps)
    /// with a circle of `radius` in the plane of `across(t)`'s two unit
    /// vectors, `sides` facets round: a mug's body (swept along its axis)
    /// or its handle (along an arc beside it).
    fn tube(
        centre: impl Fn(f32) -> Vec3,
        across: impl Fn(f32) -> (Vec3, Vec3),
        radius: f32,
        (rings, sides): (usize, usize),
        mesh: &mut (Vec<Vec3>, Vec<[u32; 3]>),
    ) {
        let first = mesh.0.len() as u32;
        for k in 0..=rings {
            let t = k as f32 / rings as f32;
            let (u, v) = across(t);
            for l in 0..sides {
                let s = std::f32::consts::TAU * l as f32 / sides as f32;
                mesh.0.push(centre(t) + radius * (s.cos() * u + s.sin() * v));
            }
        }
        let at = |k: usize, l: usize| first + (k * sides + l % sides) as u32;
        for k in 0..rings {
            for l in 0..sides {
                mesh.1.push([at(k, l), at(k, l + 1), at(k + 1, l + 1)]);
                mesh.1.push([at(k, l), at(k + 1, l + 1), at(k + 1, l)]);
            }
        }
    }

    /// A mug built along +Y: a body 80 mm across and 95 mm tall, closed at
    /// both ends, and a handle on its +X side above the middle. Not a solid
    /// of revolution, and the spread of its surface picks another direction.
    fn mug() -> Mesh {
        let mut mesh = (Vec::new(), Vec::new());
        let (r, h) = (0.04f32, 0.095f32);
        tube(
            |t| Vec3::new(0.0, h * t, 0.0),
            |_| (Vec3::Z, Vec3::X),
            r,
            (24, 64),
            &mut mesh,
        );
        // The ends: a fan from each centre to the body's first and last ring.
        for (centre, ring) in [(Vec3::ZERO, 0u32), (Vec3::new(0.0, h, 0.0), 24 * 64)] {
            let c = mesh.0.len() as u32;
            mesh.0.push(centre);
            for l in 0..64u32 {
                let (a, b) = (ring + l, ring + (l + 1) % 64);
                mesh.1.push(if ring == 0 { [c, b, a] } else { [c, a, b] });
            }
        }
        let arc = |t: f32| std::f32::consts::PI * (t - 0.5);
        tube(
            |t| Vec3::new(r - 0.004 + 0.026 * arc(t).cos(), 0.6 * h + 0.026 * arc(t).sin(), 0.0),
            |t| (Vec3::new(arc(t).cos(), arc(t).sin(), 0.0), Vec3::Z),
            0.0075,
            (32, 16),
            &mut mesh,
        );
        let (positions, triangles) = mesh;
        let n = positions.len();
        Mesh::new(positions, vec![Vec3::Y; n], vec![Vec2::ZERO; n], triangles)
    }

    #[test]
    fn a_mug_s_axis_is_its_body_s_not_the_direction_its_handle_spreads_it() {
        let mug = mug();
        let axis = axis_of_revolution(&mug).expect("the body's axis").axis;
        assert!(axis.y.abs() > 0.5f64.to_radians().cos(), "axis {axis}");
        // The surface's spread alone would take another direction for it.
        let spread = axis_of_spread(&mug).expect("a direction stands out");
        assert!(spread.y.abs() < 0.5, "spread {spread}");
        assert_eq!(axis_to_y(&mug), Quat::IDENTITY);
        // Its handle shows how it is turned; a can and a cap show nothing.
        assert!(turns_show(&mug));
        for probe in [
            SodaCan::default().build(),
            render::procedural::ThermosCap::default().build(),
        ] {
            assert!(!turns_show(&probe.mesh));
        }
        let turn = Quat::from_axis_angle(Vec3::new(0.3, -0.5, 0.8).normalize(), 1.9);
        let built = mug.posed(&Pose::new(turn, 1.0, Vec3::new(0.2, -0.1, 0.05)));
        let axis = axis_to_y(&built) * (turn * Vec3::Y);
        assert!(axis.y.abs() > 0.9999, "the body's axis goes to {axis}");
    }

    #[test]
    fn the_asset_tells_whether_a_turn_shows() {
        let cap = render::procedural::ThermosCap::default().build();
        // Its roughness varies along its profile only (a rougher recess).
        assert!(!cap.roughness.is_constant());
        assert_eq!(looks_alike_turned(&cap), Some(true));
        // A rougher stripe down one side shows how it is turned.
        let mut striped = cap.clone();
        let image = &mut striped.roughness.image;
        for row in 0..image.height {
            for column in 0..image.width / 8 {
                image.pixels[row * image.width + column] = [0.5; 3];
            }
        }
        assert_eq!(looks_alike_turned(&striped), Some(false));
        // So does a label, and a turned cap tells as the cap does.
        assert_eq!(looks_alike_turned(&SodaCan::default().build()), Some(false));
        let turned = ProbeAsset {
            mesh: cap.mesh.posed(&Pose::new(
                Quat::from_axis_angle(Vec3::new(0.3, -0.5, 0.8).normalize(), 1.9),
                1.0,
                Vec3::new(0.2, -0.1, 0.05),
            )),
            ..cap.clone()
        };
        assert_eq!(looks_alike_turned(&turned), Some(true));
        // One facet in seven, each slid along the axis by its own fraction
        // of 4 mm (a coarse scan's irregular facets): still of revolution,
        // but no circle is sampled often enough to tell.
        let (mut positions, mut normals, mut uvs, mut triangles) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
        for (t, corners) in cap.mesh.triangles.iter().enumerate().step_by(7) {
            let slide = Vec3::Y * 4e-3 * (t as f32 * 0.618_034).fract();
            let first = positions.len() as u32;
            for &i in corners {
                positions.push(cap.mesh.positions[i as usize] + slide);
                normals.push(cap.mesh.normals[i as usize]);
                uvs.push(cap.mesh.uvs[i as usize]);
            }
            triangles.push([first, first + 1, first + 2]);
        }
        let irregular = ProbeAsset {
            mesh: Mesh::new(positions, normals, uvs, triangles),
            ..cap.clone()
        };
        assert!(axis_of_revolution(&irregular.mesh).is_some());
        assert_eq!(looks_alike_turned(&irregular), None);
        // A sphere has no single axis: the renders tell.
        assert_eq!(
            looks_alike_turned(&render::procedural::UvSphere::default().build()),
            None
        );
    }

    #[test]
    fn a_sphere_and_a_box_have_no_axis_of_revolution() {
        let sphere = render::procedural::UvSphere::default().build().mesh;
        assert_eq!(axis_of_revolution(&sphere), None);
        assert!(!turns_show(&sphere), "a sphere turned shows its outline");
        // A box 3 x 2 x 1, each face in 8 x 8 squares (a scan's facets, not
        // a few large ones that some line meets by chance): a direction of
        // spread stands out, but no surface of revolution.
        let half = Vec3::new(1.5, 1.0, 0.5);
        let (mut positions, mut triangles) = (Vec::new(), Vec::new());
        for axis in 0..3 {
            for side in [-1.0f32, 1.0] {
                let (u, v) = ((axis + 1) % 3, (axis + 2) % 3);
                let first = positions.len() as u32;
                for i in 0..=8 {
                    for j in 0..=8 {
                        let mut p = Vec3::ZERO;
                        p[axis] = side * half[axis];
                        p[u] = half[u] * (i as f32 / 4.0 - 1.0);
                        p[v] = half[v] * (j as f32 / 4.0 - 1.0);
                        positions.push(p);
                    }
                }
                let at = |i: u32, j: u32| first + i * 9 + j;
                for i in 0..8 {
                    for j in 0..8 {
                        let quad = [at(i, j), at(i + 1, j), at(i + 1, j + 1), at(i, j + 1)];
                        triangles.push([quad[0], quad[1], quad[2]]);
                        triangles.push([quad[0], quad[2], quad[3]]);
                    }
                }
            }
        }
        let n = positions.len();
        let cuboid = Mesh::new(positions, vec![Vec3::Y; n], vec![Vec2::ZERO; n], triangles);
        assert_eq!(axis_of_revolution(&cuboid), None);
        assert!(turns_show(&cuboid));
        let spread = axis_of_spread(&cuboid).expect("a side that stands out");
        assert!(spread.abs().max_element() > 0.999, "spread {spread}");
    }

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
            // Measured 0.9 to 1.3 px off and 0.95 to 0.97 of the depth;
            // started as a whole mask is (on its barycenter, the depth from
            // its diagonal), 4.3 to 8.7 px and 1.00 to 1.39.
            let off = (shown(&start) - shown(&truth)).length();
            assert!(off < 2.5, "cut at the {cut}: the start's centre shows {off} px off");
            let depth = |pose: &Pose| (pose.transform_point(centre) - camera.origin).dot(camera.forward);
            let ratio = depth(&start) / depth(&truth);
            assert!(
                (ratio - 1.0).abs() < 0.06,
                "cut at the {cut}: depth {ratio} of the truth's"
            );
            // A cut mask shows no proportions: the can lying across the
            // image is tried too, though its mask stands taller than wide.
            let axes = axis_hypotheses(&camera, &shape, &probe.mesh, true);
            assert!(
                axes.iter().any(|a| a.x.abs() > 0.97),
                "cut at the {cut}: no axis across the image among {axes:?}"
            );
        }
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
            ("standing on its top", Quat::from_rotation_x(std::f32::consts::PI)),
        ];
        for (name, rotation) in cases {
            let truth = Pose::new(
                rotation,
                1.0,
                Vec3::new(0.0, 0.035, 0.0) - rotation * Vec3::new(0.0, 0.061, 0.0),
            );
            let mask = can_mask(&probe, &camera, &truth);
            let shape = MaskShape::new(&mask).expect("a mask");
            // A probe standing on its top is hypothesised as such only when
            // its top is not known (the upside-down twins of the upright
            // hypothesis cover it otherwise).
            let top_known = name != "standing on its top";
            let axes = axis_hypotheses(&camera, &shape, &probe.mesh, top_known);
            let true_axis = rotation * Vec3::Y;
            let best = axes
                .iter()
                .map(|a| a.dot(true_axis).clamp(-1.0, 1.0).acos().to_degrees())
                .fold(f32::INFINITY, f32::min);
            assert!(
                axes.len() <= 5 + !top_known as usize,
                "{name}: {} hypotheses",
                axes.len()
            );
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
