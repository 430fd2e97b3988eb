//! Surfaces of revolution around +Y from a profile curve in the (radius, height) half-plane.

use std::f32::consts::PI;

use glam::{Vec2, Vec3};

use crate::image_io::RgbImage;
use crate::mesh::Mesh;

/// A profile polyline in the (radius, height) half-plane, arc-length parameterised by v in [0, 1].
///
/// It runs from a point on the axis (radius 0) at the bottom, outwards and up, back to the axis
/// at the top, so that its surface of revolution is closed and its outward normal is the tangent
/// turned clockwise: `(dy, -dr)`.
#[derive(Clone, Debug)]
pub struct Profile {
    /// The points, (radius, height) in metres.
    pub points: Vec<Vec2>,
    /// Cumulative arc length at each point, normalised to end at 1.
    pub v: Vec<f32>,
}

impl Profile {
    /// A profile through `corners`, each segment split into pieces no longer than `max_step` metres.
    pub fn new(corners: &[Vec2], max_step: f32) -> Self {
        assert!(
            corners.len() >= 2 && max_step > 0.0,
            "Profile::new: need 2 corners and a positive step"
        );
        let mut points = vec![corners[0]];
        for pair in corners.windows(2) {
            let pieces = ((pair[1] - pair[0]).length() / max_step).ceil().max(1.0) as usize;
            points.extend((1..=pieces).map(|k| pair[0].lerp(pair[1], k as f32 / pieces as f32)));
        }
        let mut v = vec![0.0f32];
        for pair in points.windows(2) {
            v.push(v[v.len() - 1] + (pair[1] - pair[0]).length());
        }
        let total = v[v.len() - 1];
        v.iter_mut().for_each(|x| *x /= total);
        Self { points, v }
    }

    /// The (radius, height) at arc-length parameter `v` in [0, 1].
    pub fn at(&self, v: f32) -> Vec2 {
        let i = self.v.partition_point(|&x| x <= v).clamp(1, self.points.len() - 1);
        let span = self.v[i] - self.v[i - 1];
        let t = if span > 0.0 {
            ((v - self.v[i - 1]) / span).clamp(0.0, 1.0)
        } else {
            0.0
        };
        self.points[i - 1].lerp(self.points[i], t)
    }

    /// Outward unit normal in the (radius, height) plane at point `i` (mean of the adjacent segments' tangents, turned).
    fn normal(&self, i: usize) -> Vec2 {
        let prev = self.points[i.saturating_sub(1)];
        let next = self.points[(i + 1).min(self.points.len() - 1)];
        let tangent = (next - prev).normalize_or_zero();
        Vec2::new(tangent.y, -tangent.x)
    }

    /// A texture of `width` x `height` texels, each the value of `material(u, (radius, height))`
    /// at its centre. Row 0 is the top of the image, which is OBJ v = 1 (the end of the profile).
    pub fn bake(&self, width: usize, height: usize, material: impl Fn(f32, Vec2) -> [f32; 3]) -> RgbImage {
        let pixels = (0..height)
            .flat_map(|row| (0..width).map(move |col| (row, col)))
            .map(|(row, col)| {
                let u = (col as f32 + 0.5) / width as f32;
                let v = 1.0 - (row as f32 + 0.5) / height as f32;
                material(u, self.at(v))
            })
            .collect();
        RgbImage::new(width, height, pixels)
    }
}

/// The closed triangle mesh swept by `profile` around +Y in `segments` steps.
///
/// u = angle / 2 pi with the angle measured from +Z towards +X; the seam (u = 0 and u = 1) has
/// duplicated vertices at bit-identical positions. Triangles that collapse on the axis are left out.
pub fn surface_of_revolution(profile: &Profile, segments: u32) -> Mesh {
    assert!(
        segments >= 3,
        "surface_of_revolution: need at least 3 segments, got {segments}"
    );
    let columns = segments as usize + 1;
    let (mut positions, mut normals, mut uvs) = (Vec::new(), Vec::new(), Vec::new());
    for (i, (&p, &v)) in profile.points.iter().zip(&profile.v).enumerate() {
        let n = profile.normal(i);
        for j in 0..columns {
            // The last column repeats the first angle exactly, so the seam welds.
            let angle = 2.0 * PI * (j % segments as usize) as f32 / segments as f32;
            let (sin, cos) = angle.sin_cos();
            positions.push(Vec3::new(p.x * sin, p.y, p.x * cos));
            normals.push(Vec3::new(n.x * sin, n.y, n.x * cos));
            uvs.push(Vec2::new(j as f32 / segments as f32, v));
        }
    }
    let mut triangles = Vec::new();
    for i in 0..profile.points.len() - 1 {
        for j in 0..segments as usize {
            let at = |di: usize, dj: usize| ((i + di) * columns + j + dj) as u32;
            // Counter-clockwise seen from outside: u runs along +X at angle 0, the profile along +Y.
            for tri in [[at(0, 0), at(0, 1), at(1, 1)], [at(0, 0), at(1, 1), at(1, 0)]] {
                let [a, b, c] = tri.map(|k| positions[k as usize]);
                if a != b && b != c && c != a {
                    triangles.push(tri);
                }
            }
        }
    }
    Mesh::new(positions, normals, uvs, triangles)
}
