//! The forward model (PAPER.md): direct image-based lighting of the probe,
//!
//!   L(wo) = v(x) * integral of L_env(wi) V(x, wi) f(wi, wo) cos(theta_i) dwi,
//!
//! estimated per sub-pixel sample with one BRDF sample (the BRDF's own
//! importance sampling: GGX visible normals for the metal), or with one BRDF
//! and one env-map sample combined by multiple importance sampling
//! ([`LightSampling`]), times the soft visibility texture v, averaged into
//! pixels. V is 0 where the probe itself blocks the light (a shadow ray
//! against its mesh): a concave probe's recesses (a can's lid, a cap's
//! inside) do not see the sky above them. What they see instead, the probe
//! itself, can be followed for a few bounces
//! ([`LightSampling::bounces`]): the shadowed BRDF sample goes on from the
//! point it hits with a BRDF sample there, and so on. Further bounces are
//! left out.
//!
//! Two steps: [`PrimaryHits::trace`] finds which triangle each sub-pixel
//! sample sees (a BVH, not differentiated); [`ProbeScene`] recomputes the hit
//! point on that triangle from the posed vertices (Moller-Trumbore on the
//! tape), so the image is differentiable in the pose through the hit point,
//! the interpolated normal and uv, and in the env map, the textures and the
//! roughness. Silhouette changes are not differentiated here: the soft masks
//! of `silhouette` carry them; nor are shadow edges moving with the pose (V
//! is a constant of each sample).

mod hits;
mod point;
mod samples;

use autodiff::Tape;
use glam::Vec3;

use crate::bsdf::Bsdf;
use crate::camera::Camera;
use crate::envmap::EnvMap;
use crate::image_io::{Mask, RgbImage};
use crate::lookup::ImageVars;
use crate::pose::Pose;
use crate::posed::{PoseVars, PosedMesh, pack_pose};
use crate::probe::ProbeAsset;
use crate::sampling::EnvSampler;

pub use hits::{Occluder, PrimaryHits};
pub use point::ShadingPoint;
pub use samples::{LightSamples, LightSampling, ProbeScene, ProbeVars};

/// Monte Carlo settings.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RenderSettings {
    /// Samples per pixel (stratified sub-pixel positions, one light sample per strategy each).
    pub spp: u32,
    /// Seed of every random number: the same seed gives the same image on any thread count.
    pub seed: u64,
}

impl Default for RenderSettings {
    fn default() -> Self {
        RenderSettings { spp: 8, seed: 0 }
    }
}

/// How many bounces off the probe its renders follow (`render_layer`, the
/// acquisition's texture solves). A can's lid sees its rim's inside, which
/// sees the lid: with one bounce the top of a can seen from above renders
/// 16 % darker than a path tracer's (depth 4), with two 7 %; a third adds
/// about 0.1 %. A bounce costs its shadowed samples only.
pub const PROBE_BOUNCES: u32 = 2;

/// Start of the random number streams of the BRDF samples (plus the pixel
/// index: apart from the sub-pixel offsets', whose stream is the pixel index).
const BSDF_STREAM: u64 = 1 << 40;
/// Start of the random number streams of the env-map samples (plus the pixel index).
const LIGHT_STREAM: u64 = 2 << 40;
/// Start of the random number streams of a blurred camera's spread of the sub-pixel offsets
/// (plus the pixel index).
const FOOTPRINT_STREAM: u64 = 3 << 40;
/// Start of the random number streams of the first bounce's BRDF samples (plus the pixel index).
const BOUNCE_STREAM: u64 = 3 << 40;
/// Start of the random number streams of the first bounce's env-map samples (plus the pixel index).
const BOUNCE_LIGHT_STREAM: u64 = 4 << 40;
/// Start of the streams of the later bounces: bounce `k` (from 2) draws its BRDF
/// samples from `LATER_BOUNCE_STREAM + (2 (k - 2) << 40)` and its env-map samples from the next.
const LATER_BOUNCE_STREAM: u64 = 5 << 40;

/// The random number streams (BRDF, env map) of bounce `level` (from 1).
fn bounce_streams(level: u32) -> (u64, u64) {
    match level {
        1 => (BOUNCE_STREAM, BOUNCE_LIGHT_STREAM),
        _ => {
            let start = LATER_BOUNCE_STREAM + ((2 * (level as u64 - 2)) << 40);
            (start, start + (1 << 40))
        }
    }
}

/// Most samples per pixel one pass of [`render_image`] holds in memory
/// (every sample's intermediates live on the tape for a pass).
const SPP_PER_PASS: u32 = 16;

/// How many times more samples [`render_image`] spends on a silhouette pixel
/// (about 3 % of a 200-pixel-tall can's pixels: 10 % more samples).
const SILHOUETTE_SPP_FACTOR: u32 = 4;

/// Renders the probe at `pose` under `env` (f32, no gradients): the image
/// (black background, each pixel the sum of its probe samples' radiance over
/// all its samples: premultiplied by the coverage) and the share of each
/// pixel's samples that see the probe, for compositing over a photo. Light
/// is sampled by MIS of the BRDF and the env map ([`LightSampling::mis`]),
/// and what the probe reflects onto itself by [`PROBE_BOUNCES`] bounces
/// ([`LightSampling::bounces`]); silhouette pixels get
/// `SILHOUETTE_SPP_FACTOR` times the samples ([`PrimaryHits::trace_refined`]).
/// High sample counts run in passes of at most 16 spp (seeds `seed`,
/// `seed + 2^32`, ...), averaged, so memory stays bounded.
pub fn render_layer(
    probe: &ProbeAsset,
    pose: &Pose,
    camera: &Camera,
    env: &EnvMap,
    bsdf: &dyn Bsdf<f32>,
    settings: &RenderSettings,
) -> (RgbImage, Vec<f32>) {
    let (w, h) = (camera.width as usize, camera.height as usize);
    let mut sum = vec![[0.0f64; 3]; w * h];
    let mut covered = vec![0.0f64; w * h];
    let total = settings.spp.max(1);
    let passes = total.div_ceil(SPP_PER_PASS);
    let tape = Tape::<f32>::new();
    let vars = ProbeVars::new(&tape, probe, false);
    let posed = PosedMesh::new(&vars.mesh, &PoseVars::new(&tape, &pack_pose(pose), false));
    let env_vars = ImageVars::env(&tape, env, false);
    let sampler = EnvSampler::new(env);
    let positions = posed.position_values();
    let mark = tape.mark();
    for pass in 0..passes {
        let spp = SPP_PER_PASS.min(total - pass * SPP_PER_PASS);
        let pass_settings = RenderSettings {
            spp,
            // Apart from the passes of seeds `seed + 1`, ... (a second
            // render for a noise estimate would otherwise share its passes).
            seed: settings.seed.wrapping_add((pass as u64) << 32),
        };
        let hits = PrimaryHits::trace_refined(
            &probe.mesh,
            &positions,
            camera,
            &pass_settings,
            spp * SILHOUETTE_SPP_FACTOR,
        );
        if hits.is_empty() {
            break;
        }
        tape.reset_to(mark);
        let rgb = ProbeScene {
            tape: &tape,
            hits: &hits,
            camera,
            probe: &vars,
            posed: &posed,
            triangles: &probe.mesh.triangles,
            bsdf,
        }
        .light_samples(&LightSampling::mis(&sampler).with_bounces(PROBE_BOUNCES))
        .radiance(&env_vars);
        let rgb = rgb.map(|c| tape.to_vec(c));
        let share = spp as f64 / total as f64;
        for (k, &p) in hits.pixels.iter().enumerate() {
            for c in 0..3 {
                sum[p as usize][c] += rgb[c][k] as f64 * share;
            }
            covered[p as usize] += hits.coverage[k] as f64 * share;
        }
    }
    let image = RgbImage::new(w, h, sum.iter().map(|p| p.map(|v| v as f32)).collect());
    (image, covered.iter().map(|&c| c as f32).collect())
}

/// [`render_layer`] with its coverage made a hard mask: at least half of a
/// pixel's samples see the probe.
pub fn render_image(
    probe: &ProbeAsset,
    pose: &Pose,
    camera: &Camera,
    env: &EnvMap,
    bsdf: &dyn Bsdf<f32>,
    settings: &RenderSettings,
) -> (RgbImage, Mask) {
    let (image, coverage) = render_layer(probe, pose, camera, env, bsdf, settings);
    let mask = Mask::new(image.width, image.height, coverage.iter().map(|&c| c >= 0.5).collect());
    (image, mask)
}

/// [`render_image`]'s mask alone (the pixels at least half of whose samples
/// see the probe, the silhouette refined as there), without shading the
/// probe: at most 16 spp, where both trace the same rays.
pub fn coverage_mask(probe: &ProbeAsset, pose: &Pose, camera: &Camera, settings: &RenderSettings) -> Mask {
    let positions: Vec<Vec3> = probe.mesh.positions.iter().map(|&p| pose.transform_point(p)).collect();
    let spp = settings.spp.clamp(1, SPP_PER_PASS);
    let pass = RenderSettings { spp, ..*settings };
    let hits = PrimaryHits::trace_refined(&probe.mesh, &positions, camera, &pass, spp * SILHOUETTE_SPP_FACTOR);
    let mut inside = vec![false; camera.width as usize * camera.height as usize];
    for (&p, &c) in hits.pixels.iter().zip(&hits.coverage) {
        inside[p as usize] = c >= 0.5;
    }
    Mask::new(camera.width as usize, camera.height as usize, inside)
}
