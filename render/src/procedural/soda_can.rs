//! A 330/355 ml aluminium soda can: 66 mm body diameter, 122 mm tall, necked top with a rolled
//! rim around a recessed lid, and a concave domed bottom standing on a ring.

use std::f32::consts::PI;

use glam::Vec2;

use super::{Profile, surface_of_revolution};
use crate::probe::{ProbeAsset, Texture};

/// Bare aluminium: silver albedo and its roughness.
const ALUMINIUM: [f32; 3] = [0.91, 0.92, 0.92];
const ALUMINIUM_ROUGHNESS: f32 = 0.2;
/// The painted label is rougher than the bare metal.
const PAINT_ROUGHNESS: f32 = 0.35;
const LABEL_RED: [f32; 3] = [0.75, 0.06, 0.08];
const LABEL_WHITE: [f32; 3] = [0.85, 0.85, 0.85];
/// Body radius, metres.
const BODY_RADIUS: f32 = 0.033;

/// Parameters of the procedural soda can.
#[derive(Clone, Debug, PartialEq)]
pub struct SodaCan {
    /// Steps around the axis.
    pub segments: u32,
    /// Longest profile segment, metres.
    pub profile_step: f32,
    /// Texture size (u around, v along the profile).
    pub texture_size: [usize; 2],
}

impl Default for SodaCan {
    /// 64 segments and 5 mm profile steps: about 5,000 triangles; 256 x 128 textures.
    fn default() -> Self {
        Self {
            segments: 64,
            profile_step: 0.005,
            texture_size: [256, 128],
        }
    }
}

impl SodaCan {
    /// The profile from the centre of the domed bottom to the centre of the lid, (radius, height) in metres.
    pub fn profile(&self) -> Profile {
        // Concave dome: 7 mm deep at the centre, meeting the standing ring at r = 23.5 mm.
        let dome = (0..6).map(|k| {
            let s = k as f32 / 6.0;
            Vec2::new(0.0235 * s, 0.0025 + 0.007 * (1.0 - s * s))
        });
        let rest = [
            [0.0235, 0.0025],
            [0.0245, 0.0005],
            [0.0255, 0.0],
            [0.0270, 0.0005],
            [0.0315, 0.0065],
            [BODY_RADIUS, 0.0120],
            [BODY_RADIUS, 0.1030],
            [0.0322, 0.1080],
            [0.0295, 0.1130],
            [0.0275, 0.1170],
            [0.0272, 0.1200],
            [0.0265, 0.1220],
            [0.0258, 0.1205],
            [0.0255, 0.1150],
            [0.0245, 0.1140],
            [0.0, 0.1140],
        ]
        .map(Vec2::from_array);
        let corners: Vec<Vec2> = dome.chain(rest).collect();
        Profile::new(&corners, self.profile_step)
    }

    /// Builds the can with its label texture (painted red and white with a bare-metal window) and roughness.
    pub fn build(&self) -> ProbeAsset {
        let profile = self.profile();
        let mesh = surface_of_revolution(&profile, self.segments);
        let [width, height] = self.texture_size;
        let albedo = profile.bake(width, height, |u, p| label(u, p).0);
        let roughness = profile.bake(width, height, |u, p| [label(u, p).1; 3]);
        ProbeAsset {
            name: "soda_can".into(),
            mesh,
            albedo: Texture { image: albedo },
            roughness: Texture { image: roughness },
            visibility: Texture::constant([1.0; 3]),
        }
    }
}

/// (albedo, roughness) of the can at angle parameter u and profile point (radius, height).
fn label(u: f32, p: Vec2) -> ([f32; 3], f32) {
    let on_body = p.x >= BODY_RADIUS - 1e-4 && (0.016..0.100).contains(&p.y);
    if !on_body {
        return (ALUMINIUM, ALUMINIUM_ROUGHNESS);
    }
    // A round bare-metal window (a "logo") 12 mm in radius, at u = 0.25, 45 mm up.
    let arc = BODY_RADIUS * 2.0 * PI * (u - 0.25);
    if Vec2::new(arc, p.y - 0.045).length() < 0.012 {
        return (ALUMINIUM, ALUMINIUM_ROUGHNESS);
    }
    // A white wave twice around the can.
    let wave = 0.065 + 0.01 * (4.0 * PI * u).sin();
    if (p.y - wave).abs() < 0.006 {
        return (LABEL_WHITE, PAINT_ROUGHNESS);
    }
    (LABEL_RED, PAINT_ROUGHNESS)
}
