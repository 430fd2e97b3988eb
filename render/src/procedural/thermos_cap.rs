//! A stainless-steel thermos cap: a 72 mm wide, 50 mm tall cup-like cylinder with a 22 mm deep
//! concave recess on top. The recess's walls shadow its floor: the renderer traces that, so the
//! visibility texture is 1 everywhere.

use glam::Vec2;

use super::{Profile, surface_of_revolution};
use crate::probe::{ProbeAsset, Texture};

const STEEL: [f32; 3] = [0.75, 0.74, 0.72];
const STEEL_ROUGHNESS: f32 = 0.25;
/// The inside of the recess is less polished.
const RECESS_ROUGHNESS: f32 = 0.35;
const TOP: f32 = 0.050;
const RECESS_FLOOR: f32 = 0.028;
const RECESS_RADIUS: f32 = 0.0285;

/// Parameters of the procedural thermos cap.
#[derive(Clone, Debug, PartialEq)]
pub struct ThermosCap {
    /// Steps around the axis.
    pub segments: u32,
    /// Longest profile segment, metres.
    pub profile_step: f32,
    /// Texture size (u around, v along the profile).
    pub texture_size: [usize; 2],
}

impl Default for ThermosCap {
    /// 64 segments, 5 mm profile steps, 64 x 128 textures (the material does not vary around).
    fn default() -> Self {
        Self {
            segments: 64,
            profile_step: 0.005,
            texture_size: [64, 128],
        }
    }
}

impl ThermosCap {
    /// The profile from the centre of the base to the centre of the recess floor, (radius, height) in metres.
    pub fn profile(&self) -> Profile {
        let corners = [
            [0.0, 0.0],
            [0.034, 0.0],
            [0.036, 0.002],
            [0.036, 0.048],
            [0.0345, TOP],
            [0.0295, TOP],
            [RECESS_RADIUS, 0.046],
            [RECESS_RADIUS, 0.030],
            [0.0265, RECESS_FLOOR],
            [0.0, RECESS_FLOOR],
        ]
        .map(Vec2::from_array);
        Profile::new(&corners, self.profile_step)
    }

    /// Builds the cap with its roughness texture.
    pub fn build(&self) -> ProbeAsset {
        let profile = self.profile();
        let mesh = surface_of_revolution(&profile, self.segments);
        let [width, height] = self.texture_size;
        // The recess: inside its radius and between its floor and the top (the base is below the floor).
        let in_recess = |p: Vec2| p.x <= RECESS_RADIUS + 1e-4 && (RECESS_FLOOR - 1e-4..TOP - 1e-4).contains(&p.y);
        let roughness = profile.bake(width, height, |_, p| {
            [if in_recess(p) {
                RECESS_ROUGHNESS
            } else {
                STEEL_ROUGHNESS
            }; 3]
        });
        ProbeAsset {
            name: "thermos_cap".into(),
            mesh,
            albedo: Texture::constant(STEEL),
            roughness: Texture { image: roughness },
            visibility: Texture::constant([1.0; 3]),
        }
    }
}
