//! Triangle meshes of probes: OBJ input/output, smooth normals, welding and silhouette edges.
//!
//! OBJ files must carry texture coordinates (`vt`); OBJ `vt` v = 0 is the bottom row of a texture
//! image (FORMATS.md). Normals (`vn`) are optional and computed when absent.

use std::collections::HashMap;
use std::fmt::Write as _;
use std::path::Path;

use glam::{Vec2, Vec3};

use crate::error::{RenderError, Result};
use crate::pose::Pose;

/// Whether [`Mesh::read_obj_with`] requires texture coordinates.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Uvs {
    /// A mesh without `vt` is an error (a probe's textures need them).
    Required,
    /// A mesh without `vt` gets zero uvs.
    Optional,
}

/// An indexed triangle mesh with one position, normal and uv per vertex (OBJ `single_index` layout).
#[derive(Clone, Debug, PartialEq)]
pub struct Mesh {
    /// Vertex positions, metres.
    pub positions: Vec<Vec3>,
    /// Unit vertex normals (shading normals), pointing out of the object.
    pub normals: Vec<Vec3>,
    /// Vertex texture coordinates (OBJ `vt`: v = 0 is the bottom row of a texture).
    pub uvs: Vec<Vec2>,
    /// Vertex indices, counter-clockwise seen from outside.
    pub triangles: Vec<[u32; 3]>,
}

impl Mesh {
    /// A mesh from its arrays; panics when their lengths disagree or an index is out of range (a programming error).
    pub fn new(positions: Vec<Vec3>, normals: Vec<Vec3>, uvs: Vec<Vec2>, triangles: Vec<[u32; 3]>) -> Self {
        let n = positions.len();
        assert!(
            normals.len() == n && uvs.len() == n,
            "Mesh::new: {n} positions, {} normals, {} uvs",
            normals.len(),
            uvs.len()
        );
        assert!(
            triangles.iter().flatten().all(|&i| (i as usize) < n),
            "Mesh::new: vertex index out of range ({n} vertices)"
        );
        Self {
            positions,
            normals,
            uvs,
            triangles,
        }
    }

    /// Reads a Wavefront OBJ (all objects/groups merged, triangulated); requires `vt`, computes normals when `vn` is absent.
    pub fn read_obj(path: impl AsRef<Path>) -> Result<Self> {
        Self::read_obj_with(path, Uvs::Required)
    }

    /// [`read_obj`](Self::read_obj), with `vt` optional when `uvs` says so
    /// (all zero where absent: an object of constant material needs none).
    pub fn read_obj_with(path: impl AsRef<Path>, uvs_rule: Uvs) -> Result<Self> {
        let path = path.as_ref();
        let options = tobj::LoadOptions {
            single_index: true,
            triangulate: true,
            ..Default::default()
        };
        // The materials result is an Err when the .mtl is missing: a probe does not need it.
        let (models, _materials) = tobj::load_obj(path, &options).map_err(|e| RenderError::io(path, "read OBJ", e))?;
        let (mut positions, mut normals, mut uvs, mut triangles) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
        let mut all_have_normals = true;
        for model in &models {
            let m = &model.mesh;
            let count = m.positions.len() / 3;
            if count == 0 {
                continue;
            }
            if m.texcoords.len() == 2 * count {
                uvs.extend(m.texcoords.chunks_exact(2).map(|t| Vec2::new(t[0], t[1])));
            } else if uvs_rule == Uvs::Optional {
                uvs.extend(std::iter::repeat_n(Vec2::ZERO, count));
            } else {
                return Err(RenderError::field(
                    path,
                    format!("o/g {}", model.name),
                    "no texture coordinates (`vt`): a probe mesh needs UVs to index its textures",
                ));
            }
            all_have_normals &= m.normals.len() == 3 * count;
            let base = positions.len() as u32;
            positions.extend(m.positions.chunks_exact(3).map(|p| Vec3::new(p[0], p[1], p[2])));
            normals.extend(m.normals.chunks_exact(3).map(|n| Vec3::new(n[0], n[1], n[2])));
            triangles.extend(
                m.indices
                    .chunks_exact(3)
                    .map(|t| [base + t[0], base + t[1], base + t[2]]),
            );
        }
        if triangles.is_empty() {
            return Err(RenderError::file(path, "mesh has no triangles"));
        }
        if let Some(p) = positions.iter().find(|p| !p.is_finite()) {
            return Err(RenderError::file(path, format!("vertex position {p} is not finite")));
        }
        let normals = if all_have_normals && normals.iter().all(|n| n.length() > 0.0) {
            normals.into_iter().map(Vec3::normalize).collect()
        } else {
            smooth_vertex_normals(&positions, &triangles)
        };
        Ok(Self::new(positions, normals, uvs, triangles))
    }

    /// Writes a Wavefront OBJ with `v`, `vt`, `vn` and `f v/vt/vn` lines (one index per vertex).
    pub fn write_obj(&self, path: impl AsRef<Path>) -> Result<()> {
        let mut text = String::with_capacity(64 * self.positions.len());
        // Writing to a String cannot fail.
        for p in &self.positions {
            let _ = writeln!(text, "v {} {} {}", p.x, p.y, p.z);
        }
        for t in &self.uvs {
            let _ = writeln!(text, "vt {} {}", t.x, t.y);
        }
        for n in &self.normals {
            let _ = writeln!(text, "vn {} {} {}", n.x, n.y, n.z);
        }
        for t in &self.triangles {
            let [a, b, c] = t.map(|i| i + 1);
            let _ = writeln!(text, "f {a}/{a}/{a} {b}/{b}/{b} {c}/{c}/{c}");
        }
        std::fs::write(path.as_ref(), text).map_err(|e| RenderError::io(path.as_ref(), "write OBJ", e))
    }

    /// The mesh moved to world by `pose` (positions and normals).
    pub fn posed(&self, pose: &Pose) -> Self {
        Self {
            positions: self.positions.iter().map(|&p| pose.transform_point(p)).collect(),
            normals: self.normals.iter().map(|&n| pose.transform_normal(n)).collect(),
            ..self.clone()
        }
    }

    /// The axis-aligned bounding box of the positions (lower, upper corner).
    pub fn bounds(&self) -> (Vec3, Vec3) {
        self.positions.iter().fold(
            (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY)),
            |(lo, hi), &p| (lo.min(p), hi.max(p)),
        )
    }

    /// The three corner positions of triangle `t`.
    pub fn corners(&self, t: usize) -> [Vec3; 3] {
        self.triangles[t].map(|i| self.positions[i as usize])
    }

    /// The unnormalised geometric normal of triangle `t`, `(p1 - p0) x (p2 - p0)` (twice its area).
    pub fn face_normal(&self, t: usize) -> Vec3 {
        let [p0, p1, p2] = self.corners(t);
        (p1 - p0).cross(p2 - p0)
    }

    /// Interpolates per-vertex values of triangle `t` at barycentrics `(b1, b2)` (the weights of corners 1 and 2).
    pub fn interpolate<T>(&self, values: &[T], t: usize, barycentric: Vec2) -> T
    where
        T: Copy + std::ops::Mul<f32, Output = T> + std::ops::Add<Output = T>,
    {
        let [i0, i1, i2] = self.triangles[t].map(|i| i as usize);
        values[i0] * (1.0 - barycentric.x - barycentric.y) + values[i1] * barycentric.x + values[i2] * barycentric.y
    }

    /// For each vertex, its welded representative: see [`weld_by_position`].
    pub fn weld_by_position(&self) -> Vec<u32> {
        weld_by_position(&self.positions)
    }

    /// The mesh with its vertices merged in a grid of cubes of side `cell`
    /// (vertex clustering, Rossignac and Borrel 1993): each cube's vertices
    /// become their mean, triangles whose corners fall in fewer than three
    /// cubes are dropped and repeats kept once. A far cheaper outline of a
    /// dense scan, within about a cell of it; each merged vertex keeps the
    /// texture coordinates of its first vertex, its normals are recomputed.
    pub fn clustered(&self, cell: f32) -> Mesh {
        let cell = cell.max(f32::MIN_POSITIVE);
        let (lo, _) = self.bounds();
        let mut cluster_of: HashMap<[i32; 3], u32> = HashMap::new();
        let mut sums: Vec<(Vec3, u32, Vec2)> = Vec::new();
        let vertex: Vec<u32> = self
            .positions
            .iter()
            .zip(&self.uvs)
            .map(|(&p, &uv)| {
                let key = ((p - lo) / cell).floor().as_ivec3().to_array();
                let k = *cluster_of.entry(key).or_insert_with(|| {
                    sums.push((Vec3::ZERO, 0, uv));
                    sums.len() as u32 - 1
                });
                sums[k as usize].0 += p;
                sums[k as usize].1 += 1;
                k
            })
            .collect();
        let positions: Vec<Vec3> = sums.iter().map(|(sum, n, _)| *sum / *n as f32).collect();
        let mut seen = std::collections::HashSet::new();
        let triangles: Vec<[u32; 3]> = self
            .triangles
            .iter()
            .map(|t| t.map(|i| vertex[i as usize]))
            .filter(|&[a, b, c]| a != b && b != c && a != c)
            .filter(|t| {
                // The same three clusters in either winding are one triangle (or a sliver pair).
                let mut key = *t;
                key.sort_unstable();
                seen.insert(key)
            })
            .collect();
        let normals = smooth_vertex_normals(&positions, &triangles);
        Mesh::new(positions, normals, sums.iter().map(|s| s.2).collect(), triangles)
    }

    /// Signed volume enclosed (divergence theorem); positive for a closed mesh with outward winding.
    pub fn signed_volume(&self) -> f64 {
        (0..self.triangles.len())
            .map(|t| {
                let [a, b, c] = self.corners(t).map(|p| p.as_dvec3());
                a.dot(b.cross(c)) / 6.0
            })
            .sum()
    }
}

/// For each vertex, the lowest-numbered vertex at the bit-identical position (its welded representative).
///
/// OBJ loading with one index per vertex duplicates vertices on UV seams; without welding,
/// every seam would look like an open boundary or a silhouette.
pub fn weld_by_position(positions: &[Vec3]) -> Vec<u32> {
    let mut first_at: HashMap<[u32; 3], u32> = HashMap::with_capacity(positions.len());
    // Adding +0.0 turns -0.0 into +0.0: the same point must get the same key.
    let key = |p: Vec3| (p + Vec3::ZERO).to_array().map(f32::to_bits);
    (0..positions.len() as u32)
        .map(|i| *first_at.entry(key(positions[i as usize])).or_insert(i))
        .collect()
}

/// Area-weighted smooth vertex normals; vertices at the same position share one normal (smooth across UV seams).
pub fn smooth_vertex_normals(positions: &[Vec3], triangles: &[[u32; 3]]) -> Vec<Vec3> {
    let weld = weld_by_position(positions);
    let mut sum = vec![Vec3::ZERO; positions.len()];
    for tri in triangles {
        let [p0, p1, p2] = tri.map(|i| positions[i as usize]);
        // The cross product's length is twice the area: larger triangles weigh more.
        let n = (p1 - p0).cross(p2 - p0);
        for &i in tri {
            sum[weld[i as usize] as usize] += n;
        }
    }
    // A vertex used by no (or only degenerate) triangles gets +Y rather than NaN.
    weld.iter()
        .map(|&w| sum[w as usize].try_normalize().unwrap_or(Vec3::Y))
        .collect()
}

/// An edge between two welded vertices and the triangles that share it.
#[derive(Clone, Debug, PartialEq)]
pub struct Edge {
    /// Welded vertex indices, smaller first.
    pub vertices: [u32; 2],
    /// Triangles containing the edge (1 on an open boundary, 2 on a manifold edge, more if non-manifold).
    pub triangles: Vec<u32>,
}

/// Edge adjacency of a mesh after welding by position.
#[derive(Clone, Debug)]
pub struct EdgeAdjacency {
    /// All edges, each once.
    pub edges: Vec<Edge>,
}

impl EdgeAdjacency {
    /// Builds the edge list of `mesh`, welding vertices by position first.
    pub fn new(mesh: &Mesh) -> Self {
        let weld = mesh.weld_by_position();
        let mut index: HashMap<[u32; 2], usize> = HashMap::new();
        let mut edges: Vec<Edge> = Vec::new();
        for (t, tri) in mesh.triangles.iter().enumerate() {
            let w = tri.map(|i| weld[i as usize]);
            for k in 0..3 {
                let (a, b) = (w[k], w[(k + 1) % 3]);
                if a == b {
                    continue;
                }
                let key = [a.min(b), a.max(b)];
                let e = *index.entry(key).or_insert_with(|| {
                    edges.push(Edge {
                        vertices: key,
                        triangles: Vec::new(),
                    });
                    edges.len() - 1
                });
                edges[e].triangles.push(t as u32);
            }
        }
        Self { edges }
    }

    /// Edges used by exactly one triangle (holes, open borders).
    pub fn boundary_edges(&self) -> impl Iterator<Item = &Edge> {
        self.edges.iter().filter(|e| e.triangles.len() == 1)
    }

    /// Edges shared by a triangle facing `eye` and one facing away from it: the silhouette seen from `eye`.
    pub fn silhouette_edges<'a>(&'a self, mesh: &'a Mesh, eye: Vec3) -> impl Iterator<Item = &'a Edge> + 'a {
        let faces_eye = move |t: u32| {
            let p0 = mesh.positions[mesh.triangles[t as usize][0] as usize];
            mesh.face_normal(t as usize).dot(eye - p0) > 0.0
        };
        self.edges.iter().filter(move |e| {
            let front = e.triangles.iter().filter(|&&t| faces_eye(t)).count();
            front > 0 && front < e.triangles.len()
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cube_welds_to_8_vertices_and_is_closed() {
        let mesh = crate::procedural::unit_cube();
        let weld = mesh.weld_by_position();
        let mut reps = weld.clone();
        reps.sort();
        reps.dedup();
        assert_eq!(reps.len(), 8);
        let adjacency = EdgeAdjacency::new(&mesh);
        assert_eq!(adjacency.edges.len(), 18);
        assert_eq!(adjacency.boundary_edges().count(), 0);
        assert!((mesh.signed_volume() - 1.0).abs() < 1e-6);
        // Smooth normals at a corner point along the diagonal.
        let n = mesh.normals[0];
        assert!((n.abs() - Vec3::splat(1.0 / 3.0f32.sqrt())).length() < 1e-5);
    }

    #[test]
    fn a_clustered_can_keeps_its_shape_with_a_fifth_of_its_triangles() {
        // A dense scan's density: 512 segments round the axis.
        let can = crate::procedural::surface_of_revolution(&crate::procedural::SodaCan::default().profile(), 512);
        let (lo, hi) = can.bounds();
        let cell = (hi - lo).max_element() / 40.0;
        let coarse = can.clustered(cell);
        assert!(
            coarse.triangles.len() * 5 < can.triangles.len(),
            "{} of {} triangles",
            coarse.triangles.len(),
            can.triangles.len()
        );
        // Every merged vertex lies within a cell of the original's box, the volume within 5 %.
        let (clo, chi) = coarse.bounds();
        assert!((clo - lo).abs().max_element() < cell && (chi - hi).abs().max_element() < cell);
        let ratio = coarse.signed_volume() / can.signed_volume();
        assert!((ratio - 1.0).abs() < 0.05, "volume ratio {ratio}");
        // A cell far smaller than the triangles changes nothing but the welded seams.
        let fine = can.clustered(cell * 1e-4);
        assert_eq!(fine.triangles.len(), can.triangles.len());
    }

    #[test]
    fn cube_silhouette_seen_along_an_axis_is_its_outline() {
        let mesh = crate::procedural::unit_cube();
        let adjacency = EdgeAdjacency::new(&mesh);
        // Seen from an eye off every axis, three faces face it: the outline is a hexagon.
        let eye = Vec3::new(3.0, 4.0, 5.0);
        assert_eq!(adjacency.silhouette_edges(&mesh, eye).count(), 6);
    }

    #[test]
    fn interpolation_uses_weights_of_corners_1_and_2() {
        let mesh = crate::procedural::unit_cube();
        let p = mesh.interpolate(&mesh.positions, 0, Vec2::new(1.0, 0.0));
        assert_eq!(p, mesh.corners(0)[1]);
    }
}
