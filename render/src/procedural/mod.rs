//! Procedural probes for tests and demos: a soda can, a thermos cap and a UV sphere (and
//! a cube mesh for tests of silhouettes and welding).
//!
//! Each is an in-memory [`ProbeAsset`](crate::probe::ProbeAsset) (write it with
//! `ProbeAsset::write`). Mesh frame: metres, +Y up; the can and the cap stand on the XZ plane
//! with the centre of their base at the origin, the sphere is centred on the origin. All are
//! surfaces of revolution around +Y, UV-mapped with u around the axis and v along the profile.

mod revolution;
mod soda_can;
mod sphere;
mod thermos_cap;

pub use revolution::{Profile, surface_of_revolution};
pub use soda_can::SodaCan;
pub use sphere::UvSphere;
pub use thermos_cap::ThermosCap;

use glam::{Vec2, Vec3};

use crate::mesh::{Mesh, smooth_vertex_normals};

/// A unit cube centred on the origin with per-face vertices (24, as an OBJ
/// with a UV seam on every edge: welding must find 8), uvs all zero.
pub fn unit_cube() -> Mesh {
    let mut positions = Vec::new();
    let mut triangles = Vec::new();
    for axis in 0..3 {
        for sign in [-1.0f32, 1.0] {
            let n = Vec3::from_array(std::array::from_fn(|i| if i == axis { sign } else { 0.0 }));
            let u = Vec3::from_array(std::array::from_fn(|i| if i == (axis + 1) % 3 { 1.0 } else { 0.0 }));
            let v = n.cross(u);
            let base = positions.len() as u32;
            for (a, b) in [(-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0)] {
                positions.push(0.5 * (n + a * u + b * v));
            }
            triangles.push([base, base + 1, base + 2]);
            triangles.push([base, base + 2, base + 3]);
        }
    }
    let normals = smooth_vertex_normals(&positions, &triangles);
    let uvs = vec![Vec2::ZERO; positions.len()];
    Mesh::new(positions, normals, uvs, triangles)
}
