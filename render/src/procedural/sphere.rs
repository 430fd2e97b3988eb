//! A UV sphere of uniform material, centred on the origin.

use std::f32::consts::PI;

use glam::Vec2;

use super::{Profile, surface_of_revolution};
use crate::probe::{ProbeAsset, Texture};

/// Parameters of a UV sphere probe.
#[derive(Clone, Debug, PartialEq)]
pub struct UvSphere {
    /// Radius, metres.
    pub radius: f32,
    /// Steps around the axis.
    pub segments: u32,
    /// Steps from pole to pole.
    pub rings: u32,
    /// Uniform specular albedo.
    pub albedo: [f32; 3],
    /// Uniform roughness.
    pub roughness: f32,
}

impl Default for UvSphere {
    /// A unit mirror-like sphere (albedo 1, r = 0.316 as the "shiny" evaluation sphere), 64 x 32 steps.
    fn default() -> Self {
        Self {
            radius: 1.0,
            segments: 64,
            rings: 32,
            albedo: [1.0; 3],
            roughness: 0.316,
        }
    }
}

impl UvSphere {
    /// Builds the probe asset.
    pub fn build(&self) -> ProbeAsset {
        let corners: Vec<Vec2> = (0..=self.rings)
            .map(|k| {
                // From the south pole (angle -pi/2) to the north pole.
                let angle = PI * (k as f32 / self.rings as f32 - 0.5);
                // Exactly 0 at the poles so that the pole vertices weld.
                let radius = if k == 0 || k == self.rings {
                    0.0
                } else {
                    self.radius * angle.cos()
                };
                Vec2::new(radius, self.radius * angle.sin())
            })
            .collect();
        let profile = Profile::new(&corners, f32::INFINITY);
        let mut mesh = surface_of_revolution(&profile, self.segments);
        // The exact sphere normal beats the polyline's averaged one.
        mesh.normals = mesh.positions.iter().map(|p| p.normalize()).collect();
        ProbeAsset {
            name: "uv_sphere".into(),
            mesh,
            albedo: Texture::constant(self.albedo),
            roughness: Texture::constant([self.roughness; 3]),
            visibility: Texture::constant([1.0; 3]),
        }
    }
}
