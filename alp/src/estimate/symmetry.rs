//! What the probe asset tells of its symmetry: its axis (of revolution, or
//! the one direction of its surface's spread that stands out), whether a
//! turn about it changes its outline, and whether it looks the same at
//! every turn (its surface of revolution and its material the same all
//! round each circle about the axis).

use std::collections::{BTreeMap, HashMap};

use glam::{DMat3, DVec3, Quat, Vec2, Vec3};
use render::mesh::Mesh;
use render::pose::Pose;
use render::probe::ProbeAsset;

use super::settings::SymmetrySettings;
use crate::linalg::symmetric_eigen;

/// The probe turned so that its axis ([`axis_to_y`]) is mesh +Y: the
/// rotation that does it and the turned asset (None: it was built along
/// +Y). The estimate turns the probe about +Y and reads its length along
/// it; its poses are turned back at the end.
pub fn along_y(asset: &ProbeAsset, s: &SymmetrySettings) -> (Quat, Option<ProbeAsset>) {
    let to_y = axis_to_y(&asset.mesh, s);
    let turned = (to_y != Quat::IDENTITY).then(|| ProbeAsset {
        mesh: asset.mesh.posed(&Pose::new(to_y, 1.0, Vec3::ZERO)),
        ..asset.clone()
    });
    (to_y, turned)
}

/// `pose` of the mesh as built, as a pose of the mesh turned by `to_y`.
pub fn turned_to_y(pose: &Pose, to_y: Quat) -> Pose {
    Pose::new(pose.rotation * to_y.inverse(), pose.scale, pose.translation)
}

/// `pose` of the mesh turned by `to_y`, as a pose of the mesh as built.
pub fn turned_back(pose: &Pose, to_y: Quat) -> Pose {
    Pose::new(pose.rotation * to_y, pose.scale, pose.translation)
}

/// The rotation that turns the probe's axis to mesh +Y: the estimate turns
/// the probe about +Y (its yaw starts) and reads its length along it. The
/// axis is the probe's axis of revolution ([`axis_of_revolution`]: a mug's
/// body's, where the spread of its surface picks the direction across its
/// handle), else the principal direction of the surface's spread
/// (area-weighted second moments) whose spread stands out from the other
/// two: the longest for a probe longer than wide, the shortest for one
/// wider than long. Identity when the axis is already +Y (to
/// `SymmetrySettings::axis_is_y_deg`) or none stands out (a sphere). Of the axis's two
/// directions, the one nearer +Y, or with its largest component positive,
/// goes to +Y.
pub fn axis_to_y(mesh: &Mesh, s: &SymmetrySettings) -> Quat {
    let Some((axis, _)) = axis_line(mesh, s) else {
        return Quat::IDENTITY;
    };
    if axis.y.abs() >= s.axis_is_y_deg.to_radians().cos() {
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
pub(super) fn facets(mesh: &Mesh) -> Vec<(DVec3, DVec3, f64)> {
    (0..mesh.triangles.len())
        .filter_map(|t| {
            let [a, b, c] = mesh.corners(t).map(|p| p.as_dvec3());
            let twice_area = mesh.face_normal(t).as_dvec3();
            let area = 0.5 * twice_area.length();
            (area > 0.0).then(|| ((a + b + c) / 3.0, twice_area / (2.0 * area), area))
        })
        .collect()
}

/// Facets at most whose centres [`SelfMap::alike`] turns and looks up.
const SELF_MAP_FACETS: usize = 2_000;

/// The probe's surface as facet centres and their materials, to ask of a
/// turn (mesh coordinates, about the centre of the probe's bounding box)
/// whether it maps the probe on to itself, shape and material, so that
/// two poses that differ by it render the same photo: a ring's other end,
/// any turn of a ball of one metal, not a cap's other end nor a labelled
/// can's half turn. Built once per probe, asked of several turns.
pub(in crate::estimate) struct SelfMap<'a> {
    facets: Vec<(Vec3, [f32; 5])>,
    /// The facets by cell of a grid `reach` a side.
    grid: HashMap<[i64; 3], Vec<usize>>,
    /// How far a turned centre may land from another's (metres).
    reach: f64,
    centre: Vec3,
    settings: &'a SymmetrySettings,
}

impl<'a> SelfMap<'a> {
    /// The facets of `asset`, and their grid.
    pub(in crate::estimate) fn new(asset: &ProbeAsset, settings: &'a SymmetrySettings) -> Self {
        let mesh = &asset.mesh;
        let (lo, hi) = mesh.bounds();
        let middle = Vec2::splat(1.0 / 3.0);
        let facets: Vec<(Vec3, [f32; 5])> = (0..mesh.triangles.len())
            .map(|t| {
                let m = asset.material(mesh.interpolate(&mesh.uvs, t, middle));
                let value = [m.albedo[0], m.albedo[1], m.albedo[2], m.roughness, m.visibility];
                (mesh.interpolate(&mesh.positions, t, middle), value)
            })
            .collect();
        let area: f64 = (0..mesh.triangles.len())
            .map(|t| 0.5 * mesh.face_normal(t).length() as f64)
            .sum();
        let spacing = (area / facets.len().max(1) as f64).sqrt();
        let reach = (settings.self_map_reach * (hi - lo).length() as f64).max(2.0 * spacing);
        let mut map = SelfMap {
            facets,
            grid: HashMap::new(),
            reach,
            centre: 0.5 * (lo + hi),
            settings,
        };
        for (i, (p, _)) in map.facets.iter().enumerate() {
            map.grid.entry(map.cell(*p)).or_default().push(i);
        }
        map
    }

    fn cell(&self, p: Vec3) -> [i64; 3] {
        (p.as_dvec3() / self.reach).floor().as_i64vec3().to_array()
    }

    /// Whether `turn` maps the probe on to itself: of the facet centres
    /// turned, `SymmetrySettings::self_map_share` land near another
    /// facet's centre of the same material.
    pub(in crate::estimate) fn alike(&self, turn: Quat) -> bool {
        if self.facets.is_empty() {
            return false;
        }
        let lands = |(p, value): &(Vec3, [f32; 5])| {
            let q = self.centre + turn * (*p - self.centre);
            let [x, y, z] = self.cell(q);
            (-1..=1)
                .flat_map(|a| (-1..=1).flat_map(move |b| (-1..=1).map(move |c| [x + a, y + b, z + c])))
                .any(|k| {
                    self.grid.get(&k).is_some_and(|near| {
                        near.iter().any(|&j| {
                            let (r, other) = &self.facets[j];
                            (r.distance(q) as f64) <= self.reach
                                && (value.iter().zip(other))
                                    .all(|(u, v)| (u - v).abs() <= self.settings.material_tolerance)
                        })
                    })
                })
        };
        let every = self.facets.len().div_ceil(SELF_MAP_FACETS).max(1);
        let tried: Vec<bool> = self.facets.iter().step_by(every).map(lands).collect();
        tried.iter().filter(|&&l| l).count() as f64 >= self.settings.self_map_share * tried.len() as f64
    }
}

/// The line about which at least `SymmetrySettings::revolved_share` of the surface is of
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
pub fn axis_of_revolution(mesh: &Mesh, s: &SymmetrySettings) -> Option<Revolution> {
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
    for _ in 0..s.reweightings {
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
            .map(|(f, r)| f.2 / area / (1.0 + (r / s.on_axis).powi(2)))
            .collect();
        // A second line that fits about as well: all normal lines pass
        // through one point (a sphere), and every line through it is an axis.
        let single = values[order[1]] >= s.second_axis_ratio * values[order[0]].max(1e-12);
        last = Some((axis, moment, residual, single));
    }
    let (axis, moment, residual, single) = last?;
    let revolved: f64 = facets
        .iter()
        .zip(&residual)
        .filter(|(_, r)| **r <= s.on_axis)
        .map(|(f, _)| f.2)
        .sum();
    (single && revolved >= s.revolved_share * area).then_some(Revolution {
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
    /// The share of the area whose normal lines meet the axis (within `SymmetrySettings::on_axis`).
    pub share: f64,
}

/// Whether turning the probe about its axis changes its outline: a surface
/// not wholly of revolution (a mug's handle; a box), though not a sphere,
/// of revolution about every line through its centre.
pub fn turns_show(mesh: &Mesh, s: &SymmetrySettings) -> bool {
    turns_show_about(mesh, axis_of_revolution(mesh, s).as_ref(), s)
}

/// The axis (as [`axis_line`] gives it) when a turn about it changes the
/// probe's outline ([`turns_show`]: a grooved cap, a mug), none when it
/// does not (a can) or the probe has none; the axis of revolution is
/// fitted once for both.
pub fn axis_turns_show_about(mesh: &Mesh, s: &SymmetrySettings) -> Option<(DVec3, DVec3)> {
    match axis_of_revolution(mesh, s) {
        Some(revolution) => turns_show_about(mesh, Some(&revolution), s).then_some((revolution.axis, revolution.point)),
        // Without an axis of revolution a turn shows about the axis of spread.
        None => axis_of_spread(mesh, s),
    }
}

/// [`turns_show`] given the mesh's axis of revolution, if it has one.
pub(super) fn turns_show_about(mesh: &Mesh, revolution: Option<&Revolution>, s: &SymmetrySettings) -> bool {
    match revolution {
        Some(revolution) => revolution.share < s.wholly_revolved,
        None => axis_of_spread(mesh, s).is_some(),
    }
}

/// Whether the probe looks the same at every turn about its axis of
/// revolution, decided from the asset (Some): its whole surface of
/// revolution, and its colours the same all round ([`colours_alike_turned`]),
/// as on a smooth cap of one colour, not on a can's label nor on a grooved
/// cap (whose grooves a turn moves). None where the asset cannot tell: no
/// single axis (a sphere, of revolution about every line through its
/// centre), or facets that do not sample the circles (a scan's irregular
/// mesh). Comparing two turns' renders tells it only where the mesh's
/// facets come back at that turn (a 64-sided cap's at 45 deg, not at 30):
/// elsewhere the facets alone make the renders differ by more than
/// `renders_alike` allows.
pub fn looks_alike_turned(asset: &ProbeAsset, s: &SymmetrySettings) -> Option<bool> {
    alike_turned_about(asset, axis_of_revolution(&asset.mesh, s).as_ref(), s)
}

/// [`looks_alike_turned`] given the mesh's axis of revolution, if it has one.
pub(super) fn alike_turned_about(
    asset: &ProbeAsset,
    revolution: Option<&Revolution>,
    s: &SymmetrySettings,
) -> Option<bool> {
    let revolution = revolution?;
    if revolution.share < s.wholly_revolved {
        return Some(false);
    }
    material_alike_about(asset, revolution, s)
}

/// Whether the probe's material (albedo, roughness, visibility) is the same
/// all round each circle about its axis, decided from the asset (Some): a
/// cap of one colour, grooved or not, and a mug of one colour have no
/// colour pattern to tell a turn or an end by; a can's label has. The axis
/// is the surface's axis of revolution, or where none stands out (grooves
/// round most of a cap's side; a sphere) the asset's own, mesh +Y through
/// the surface's centroid. None where facets do not sample the circles.
pub fn colours_alike_turned(asset: &ProbeAsset, s: &SymmetrySettings) -> Option<bool> {
    colours_alike_about(asset, axis_of_revolution(&asset.mesh, s).as_ref(), s)
}

/// [`colours_alike_turned`] given the mesh's axis of revolution, if it has one.
pub(super) fn colours_alike_about(
    asset: &ProbeAsset,
    revolution: Option<&Revolution>,
    s: &SymmetrySettings,
) -> Option<bool> {
    let revolution = revolution.copied().unwrap_or_else(|| {
        let facets = facets(&asset.mesh);
        let area: f64 = facets.iter().map(|f| f.2).sum();
        Revolution {
            axis: DVec3::Y,
            point: facets.iter().map(|(p, _, w)| *p * *w).sum::<DVec3>() / area.max(1e-300),
            share: 0.0,
        }
    });
    material_alike_about(asset, &revolution, s)
}

/// Whether the material is the same all round each circle about
/// `revolution`'s axis (None where the facets do not sample the circles).
fn material_alike_about(asset: &ProbeAsset, revolution: &Revolution, s: &SymmetrySettings) -> Option<bool> {
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
    let bin = s.circle_bin * extent;
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
    if area_where(&|c| c.samples >= s.circle_min_samples) < 0.5 * total {
        return None;
    }
    let varied = area_where(&|c| {
        c.least
            .iter()
            .zip(&c.greatest)
            .any(|(least, greatest)| greatest - least > s.material_tolerance)
    });
    Some(varied <= s.varied_share * total)
}

/// The material sampled along one circle about the axis of revolution.
pub(super) struct Circle {
    pub(super) least: [f32; 5],
    pub(super) greatest: [f32; 5],
    pub(super) area: f64,
    pub(super) samples: usize,
}

/// Where on each facet the material is sampled (barycentric weights of
/// corners 1 and 2): its centroid and a point towards each corner.
pub(super) const CIRCLE_SAMPLES: [[f32; 2]; 4] = [
    [1.0 / 3.0, 1.0 / 3.0],
    [1.0 / 6.0, 1.0 / 6.0],
    [2.0 / 3.0, 1.0 / 6.0],
    [1.0 / 6.0, 2.0 / 3.0],
];

/// The principal direction of the surface's spread that stands out from
/// the other two, if one does (see [`axis_to_y`]), and the surface's
/// centroid, which it passes through.
pub(super) fn axis_of_spread(mesh: &Mesh, s: &SymmetrySettings) -> Option<(DVec3, DVec3)> {
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
    (stands_out >= s.distinct_spread).then(|| (DVec3::from_array(axis), DVec3::from_array(mean)))
}

/// The probe's axis as a line, its direction and a point on it: the axis
/// of revolution, else the axis of spread through the surface's centroid
/// (a grooved cap's, whose grooves take most of its area off the test of
/// revolution and keep its spread's symmetry).
pub fn axis_line(mesh: &Mesh, s: &SymmetrySettings) -> Option<(DVec3, DVec3)> {
    axis_of_revolution(mesh, s)
        .map(|revolution| (revolution.axis, revolution.point))
        .or_else(|| axis_of_spread(mesh, s))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::estimate::Settings;

    /// The default settings.
    fn s() -> SymmetrySettings {
        Settings::default().symmetry
    }
    use render::procedural::SodaCan;

    #[test]
    fn a_ball_of_one_metal_maps_on_to_itself_at_any_turn_a_can_and_a_cap_not_end_for_end() {
        let end_for_end = Quat::from_rotation_x(std::f32::consts::PI);
        let half_turn = Quat::from_rotation_y(std::f32::consts::PI);
        let settings = s();
        let ball = render::procedural::UvSphere::default().build();
        let ball = SelfMap::new(&ball, &settings);
        let odd = Quat::from_rotation_x(0.65) * Quat::from_rotation_y(1.9);
        assert!(ball.alike(odd));
        assert!(ball.alike(end_for_end));
        let can = SodaCan::default().build();
        let can = SelfMap::new(&can, &settings);
        assert!(can.alike(Quat::IDENTITY));
        // Its wave runs twice round, its logo once: the logo tells the half turn.
        assert!(!can.alike(half_turn));
        assert!(!can.alike(end_for_end));
        let cap = render::procedural::ThermosCap::default().build();
        assert!(!SelfMap::new(&cap, &settings).alike(end_for_end));
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
        // Built along +Y: left as it is (no turn, so their estimates stay as they were).
        for mesh in [&can, &cap, &disc] {
            assert_eq!(axis_to_y(mesh, &s()), Quat::IDENTITY);
        }
        // A sphere has no axis.
        assert_eq!(axis_to_y(&sphere, &s()), Quat::IDENTITY);
        // Built along another axis (and off the origin): turned to +Y.
        let turn = Quat::from_axis_angle(Vec3::new(0.3, -0.5, 0.8).normalize(), 1.9);
        for mesh in [&can, &cap, &disc] {
            let built = mesh.posed(&Pose::new(turn, 1.0, Vec3::new(0.2, -0.1, 0.05)));
            let to_y = axis_to_y(&built, &s());
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
        let axis = axis_of_revolution(&mug, &s()).expect("the body's axis").axis;
        assert!(axis.y.abs() > 0.5f64.to_radians().cos(), "axis {axis}");
        // The surface's spread alone would take another direction for it.
        let (spread, _) = axis_of_spread(&mug, &s()).expect("a direction stands out");
        assert!(spread.y.abs() < 0.5, "spread {spread}");
        assert_eq!(axis_to_y(&mug, &s()), Quat::IDENTITY);
        // Its handle shows how it is turned; a can and a cap show nothing.
        assert!(turns_show(&mug, &s()));
        assert_eq!(axis_turns_show_about(&mug, &s()).map(|line| line.0), Some(axis));
        for probe in [
            SodaCan::default().build(),
            render::procedural::ThermosCap::default().build(),
        ] {
            assert!(!turns_show(&probe.mesh, &s()));
            assert_eq!(axis_turns_show_about(&probe.mesh, &s()), None);
        }
        let turn = Quat::from_axis_angle(Vec3::new(0.3, -0.5, 0.8).normalize(), 1.9);
        let built = mug.posed(&Pose::new(turn, 1.0, Vec3::new(0.2, -0.1, 0.05)));
        let axis = axis_to_y(&built, &s()) * (turn * Vec3::Y);
        assert!(axis.y.abs() > 0.9999, "the body's axis goes to {axis}");
    }

    #[test]
    fn the_asset_tells_whether_a_turn_shows() {
        let cap = render::procedural::ThermosCap::default().build();
        // Its roughness varies along its profile only (a rougher recess).
        assert!(!cap.roughness.is_constant());
        assert_eq!(looks_alike_turned(&cap, &s()), Some(true));
        // A rougher stripe down one side shows how it is turned.
        let mut striped = cap.clone();
        let image = &mut striped.roughness.image;
        for row in 0..image.height {
            for column in 0..image.width / 8 {
                image.pixels[row * image.width + column] = [0.5; 3];
            }
        }
        assert_eq!(looks_alike_turned(&striped, &s()), Some(false));
        // So does a label, and a turned cap tells as the cap does.
        assert_eq!(looks_alike_turned(&SodaCan::default().build(), &s()), Some(false));
        let turned = ProbeAsset {
            mesh: cap.mesh.posed(&Pose::new(
                Quat::from_axis_angle(Vec3::new(0.3, -0.5, 0.8).normalize(), 1.9),
                1.0,
                Vec3::new(0.2, -0.1, 0.05),
            )),
            ..cap.clone()
        };
        assert_eq!(looks_alike_turned(&turned, &s()), Some(true));
        // Grooves round the whole cap, 45 of them 3 % deep: hardly any normal
        // meets the axis, but its colours are still the same all round.
        let mut grooved = cap.clone();
        for p in &mut grooved.mesh.positions {
            let ripple = 1.0 + 0.03 * (45.0 * p.z.atan2(p.x)).cos();
            (p.x, p.z) = (p.x * ripple, p.z * ripple);
        }
        assert!(axis_of_revolution(&grooved.mesh, &s()).is_none());
        assert_eq!(looks_alike_turned(&grooved, &s()), None);
        assert_eq!(colours_alike_turned(&grooved, &s()), Some(true));
        // A mug of one colour: its handle shows its turn, its colours do not.
        let mug = ProbeAsset {
            mesh: mug(),
            ..cap.clone()
        };
        assert_eq!(looks_alike_turned(&mug, &s()), Some(false));
        assert_eq!(colours_alike_turned(&mug, &s()), Some(true));
        assert_eq!(colours_alike_turned(&striped, &s()), Some(false));
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
        assert!(axis_of_revolution(&irregular.mesh, &s()).is_some());
        assert_eq!(looks_alike_turned(&irregular, &s()), None);
        // A sphere has no single axis: the renders tell; about its own
        // axis, one of one colour shows no colour pattern.
        let sphere = render::procedural::UvSphere::default().build();
        assert_eq!(looks_alike_turned(&sphere, &s()), None);
        assert_eq!(colours_alike_turned(&sphere, &s()), Some(true));
    }

    #[test]
    fn a_sphere_and_a_box_have_no_axis_of_revolution() {
        let sphere = render::procedural::UvSphere::default().build().mesh;
        assert_eq!(axis_of_revolution(&sphere, &s()), None);
        assert!(!turns_show(&sphere, &s()), "a sphere turned shows its outline");
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
        assert_eq!(axis_of_revolution(&cuboid, &s()), None);
        assert!(turns_show(&cuboid, &s()));
        let (spread, centroid) = axis_of_spread(&cuboid, &s()).expect("a side that stands out");
        assert!(spread.abs().max_element() > 0.999, "spread {spread}");
        // The box is centred on the origin: its axis passes through it.
        assert!(centroid.length() < 1e-6, "centroid {centroid}");
        assert_eq!(axis_line(&cuboid, &s()), Some((spread, centroid)));
        assert_eq!(axis_turns_show_about(&cuboid, &s()), Some((spread, centroid)));
    }
}
