//! Lights brighter than the sensor, as the solved map holds them.
//!
//! A pixel clipped by the sensor bounds what it sees from below only (the
//! data term's `at_least`), and the texels the clipped pixels read most,
//! seen mostly through them, are free of the prior
//! ([`clipped_lights`](crate::objective::clipped_lights)). Each patch of
//! clipped pixels in the photo sees a light: the texels its pixels read
//! most. Where the patch's bounds are what holds the light up (its pixels
//! render at their clip level), the photo tells only that the light is at
//! least as bright as the map has it; where the light's unclipped shoulders
//! (a rough lobe's tail) raise it above the bounds, they set its power.
//! `report.json` lists each light with which of the two it is.

use std::collections::BTreeSet;

use glam::Vec3;
use render::colour::luminance;
use render::envmap::EnvMap;
use serde::Serialize;

use super::Transport;
use crate::estimate::photo::pieces;
use crate::objective::DataTerm;

/// A patch whose clipped pixels render within this factor of their clip
/// level (median, luminance) holds its light at its bound: the light's
/// power is a lower bound. The solve meets a bound to its tolerance; a
/// light its shoulders set renders its clipped pixels well above it.
const AT_BOUND: f64 = 1.05;

/// How the photo tells a clipped light's power.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum PowerTold {
    /// Only its clipped pixels' bounds hold it up: at least this power.
    LowerBound,
    /// Its unclipped shoulders set it above the bounds.
    Fitted,
}

/// The light a patch of clipped pixels sees, in the solved map.
#[derive(Clone, Debug, Serialize)]
pub struct ClippedLight {
    /// Its direction (unit, world): the mean over its texels weighted by
    /// their power.
    pub direction: [f32; 3],
    /// Its texels' solid angle (sr) in the working map.
    pub solid_angle_sr: f64,
    /// Its power in the map, radiance integrated over its texels, RGB.
    pub power: [f64; 3],
    /// Its share of the map's power (luminance).
    pub share_of_map: f64,
    /// The patch's clipped pixels (of the working image).
    pub clipped_pixels: usize,
    /// Whether `power` is a lower bound or fitted to its shoulders.
    pub power_told: PowerTold,
}

impl ClippedLight {
    /// The lights of the patches of clipped pixels (eight neighbours in a
    /// `width x height` image; `pixels` the transport's pixels' row-major
    /// indices there) in the map `env`
    /// (the transport's size) solved from `data` over `transport`, which
    /// renders `rendered`. Brightest first.
    pub fn found(
        transport: &Transport,
        data: &DataTerm,
        pixels: &[u32],
        (width, height): (usize, usize),
        env: &EnvMap,
        rendered: &[[f64; 3]],
    ) -> Vec<Self> {
        let (w, h) = (transport.width, transport.height);
        debug_assert_eq!((env.width(), env.height()), (w, h));
        // The clipped pixels in the image, each patch's in turn.
        let mut clipped = vec![false; width * height];
        let mut transport_pixel = vec![usize::MAX; width * height];
        for p in (0..transport.pixels).filter(|&p| data.at_least[p] && data.used(p)) {
            clipped[pixels[p] as usize] = true;
            transport_pixel[pixels[p] as usize] = p;
        }
        let piece = pieces(&clipped, width, height, true);
        let mut patches: Vec<Vec<usize>> = Vec::new();
        for (i, k) in piece.iter().enumerate() {
            if let Some(k) = *k {
                if k == patches.len() {
                    patches.push(Vec::new());
                }
                patches[k].push(transport_pixel[i]);
            }
        }
        let solid_angle = |t: usize| env.texel_solid_angle(t / w) as f64;
        let texel = |t: usize| env.radiance()[t].map(f64::from);
        let map_power: f64 = (0..w * h).map(|t| luminance(texel(t)) * solid_angle(t)).sum();
        let mut lights: Vec<ClippedLight> = patches
            .into_iter()
            .map(|patch| {
                let texels: BTreeSet<usize> = patch.iter().filter_map(|&p| transport.strongest_texel(p)).collect();
                let (mut power, mut solid_angle_sr, mut direction) = ([0.0; 3], 0.0, Vec3::ZERO);
                for &t in &texels {
                    let omega = solid_angle(t);
                    let radiance = texel(t);
                    (0..3).for_each(|c| power[c] += radiance[c] * omega);
                    solid_angle_sr += omega;
                    direction += env.texel_direction(t / w, t % w) * (luminance(radiance) * omega).max(1e-30) as f32;
                }
                let mut ratios: Vec<f64> = patch
                    .iter()
                    .map(|&p| luminance(rendered[p]) / luminance(data.target[p]).max(1e-30))
                    .collect();
                ratios.sort_by(f64::total_cmp);
                ClippedLight {
                    direction: direction.normalize_or(Vec3::Y).to_array(),
                    solid_angle_sr,
                    power,
                    share_of_map: luminance(power) / map_power.max(1e-30),
                    clipped_pixels: patch.len(),
                    power_told: match ratios[ratios.len() / 2] <= AT_BOUND {
                        true => PowerTold::LowerBound,
                        false => PowerTold::Fitted,
                    },
                }
            })
            .collect();
        lights.sort_by(|a, b| luminance(b.power).total_cmp(&luminance(a.power)));
        lights
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Vec2;
    use render::envmap::uv_to_direction;

    /// An 8 x 4 map of 1s with a light of `light` in texel 9 that each
    /// pixel reads one texel of, texel 9's pixel clipped at 2, and (with
    /// `shoulder`) one more pixel that reads texel 9 at 5 % beside texel 10.
    fn scene(light: f64, shoulder: bool) -> (Transport, DataTerm, Vec<f64>) {
        let (w, h) = (8, 4);
        let centre = |t: usize| Vec2::new(((t % w) as f32 + 0.5) / w as f32, ((t / w) as f32 + 0.5) / h as f32);
        let mut uv: Vec<Vec2> = (0..w * h).map(centre).collect();
        let mut segment: Vec<u32> = (0..uv.len() as u32).collect();
        let mut throughput = vec![[1.0f32; 3]; uv.len()];
        let mut pixels = w * h;
        if shoulder {
            uv.extend([centre(9), centre(10)]);
            segment.extend([pixels as u32; 2]);
            throughput.extend([[0.05; 3], [0.95; 3]]);
            pixels += 1;
        }
        let transport = Transport::new(&segment, &uv, &throughput, pixels, w, h);
        let env: Vec<f64> = (0..w * h * 3).map(|i| if i / 3 == 9 { light } else { 1.0 }).collect();
        let mut target = vec![[0.0; 3]; pixels];
        transport.apply(&env, &mut target);
        target[9] = [2.0; 3];
        let mut data = DataTerm::exact(target, vec![[1.0; 3]; pixels]);
        data.at_least[9] = true;
        (transport, data, env)
    }

    fn lights(light: f64, shoulder: bool) -> Vec<ClippedLight> {
        let (transport, data, env) = scene(light, shoulder);
        let mut rendered = vec![[0.0; 3]; transport.pixels];
        transport.apply(&env, &mut rendered);
        // The pixels in a row of an image 100 wide: the clipped one alone.
        let pixels: Vec<u32> = (0..transport.pixels as u32).map(|p| 3 * p).collect();
        let map = EnvMap::new(
            8,
            4,
            env.chunks_exact(3)
                .map(|t| [t[0] as f32, t[1] as f32, t[2] as f32])
                .collect(),
        )
        .expect("a map");
        ClippedLight::found(&transport, &data, &pixels, (100, 1), &map, &rendered)
    }

    #[test]
    fn a_light_held_at_its_bound_is_a_lower_bound_and_one_its_shoulders_lift_is_fitted() {
        // At its bound (2): a lower bound. At 100 with a shoulder pixel: fitted.
        let bound = lights(2.0, false);
        assert_eq!(bound.len(), 1);
        assert_eq!(bound[0].power_told, PowerTold::LowerBound);
        assert_eq!(bound[0].clipped_pixels, 1);
        let fitted = lights(100.0, true);
        assert_eq!(fitted.len(), 1);
        assert_eq!(fitted[0].power_told, PowerTold::Fitted);
        // Its power and direction are texel 9's: row 1, column 1 of 8 x 4.
        let omega = 2.0 * std::f64::consts::PI / 8.0
            * ((std::f64::consts::PI / 4.0).cos() - (std::f64::consts::PI / 2.0).cos());
        // (The map is f32: its solid angles and power to f32's precision.)
        assert!((fitted[0].solid_angle_sr - omega).abs() < 1e-6 * omega);
        assert!(
            (fitted[0].power[0] - 100.0 * omega).abs() < 1e-5 * 100.0 * omega,
            "{:?}",
            fitted[0].power
        );
        let expected = uv_to_direction(Vec2::new(1.5 / 8.0, 1.5 / 4.0));
        assert!(Vec3::from(fitted[0].direction).angle_between(expected) < 1e-4);
        let total = 4.0 * std::f64::consts::PI + 99.0 * omega;
        assert!(
            (fitted[0].share_of_map - 100.0 * omega / total).abs() < 1e-3,
            "{}",
            fitted[0].share_of_map
        );
    }
}
