//! Synthetic evaluation scenes (FORMATS.md, "Scene folder"): a probe at a random pose, seen by a
//! random camera, rendered under a known env map, with optional sensor noise and clipping; and
//! synthetic capture folders of a known probe for its acquisition ("Capture folder").
//!
//! Every random choice comes from `render::sampling::Rng` streams of one seed, so a seed names a
//! scene. The image has a black background: only the probe's pixels carry information.

use std::f32::consts::{FRAC_PI_2, PI};
use std::path::{Component, Path, PathBuf};

use glam::{Quat, Vec3};

use render::RenderError;
use render::bsdf::{Bsdf, GgxMetal};
use render::camera::Camera;
use render::envmap::EnvMap;
use render::image_io::{Mask, RgbImage};
use render::integrator::{RenderSettings, render_image};
use render::pose::Pose;
use render::probe::ProbeAsset;
use render::sampling::Rng;

use crate::acquire::capture::{Capture, LEAST_VIEWS, View};
use crate::error::{Error, Result};
use crate::estimate::Photo;

/// The probe's height in the image, as a fraction of the image height, is drawn from this range
/// (120 to 230 px of a 480-px image: inside the 100-250 px of the evaluation protocol).
pub const PROBE_HEIGHT_FRACTION: [f32; 2] = [0.25, 0.48];
/// Range of the camera's vertical field of view, degrees.
pub const FOV_Y_DEG: [f32; 2] = [30.0, 50.0];
/// Range of the camera's elevation above the horizontal plane through the probe, degrees.
pub const ELEVATION_DEG: [f32; 2] = [5.0, 45.0];
/// Largest tilt of a tilted (not lying) probe's axis from the vertical, degrees.
pub const MAX_TILT_DEG: f32 = 60.0;
/// Share of tilted poses that lie on their side (axis horizontal).
pub const LYING_PROBABILITY: f32 = 0.25;
/// Largest number of samples per pixel rendered in one pass (bounds the renderer's memory).
const SPP_PER_PASS: u32 = 32;

/// What `alp synth` varies.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SynthSettings {
    /// Seed of the camera, the pose, the render and the noise.
    pub seed: u64,
    /// Relative standard deviation of the multiplicative Gaussian noise (0: none).
    pub noise: f32,
    /// Radiance above this is clamped to it (a sensor's saturation), if set.
    pub exposure_clip: Option<f32>,
    /// Samples per pixel of the render.
    pub spp: u32,
    /// Tilt the probe (up to [`MAX_TILT_DEG`], or lying on its side) instead of standing it upright.
    pub tilted: bool,
    /// Image width, pixels.
    pub width: u32,
    /// Image height, pixels.
    pub height: u32,
}

impl Default for SynthSettings {
    fn default() -> Self {
        Self {
            seed: 0,
            noise: 0.0,
            exposure_clip: None,
            spp: 256,
            tilted: false,
            width: 640,
            height: 480,
        }
    }
}

/// A synthetic scene, before it is written.
#[derive(Clone, Debug)]
pub struct SynthScene {
    /// The photograph (linear radiance, black background).
    pub image: RgbImage,
    /// The probe's coverage (at least half of a pixel's samples see it).
    pub mask: Mask,
    /// The scene camera.
    pub camera: Camera,
    /// The probe's true pose.
    pub pose: Pose,
}

/// Independent random streams of one seed.
mod stream {
    pub const POSE: u64 = 1;
    pub const CAMERA: u64 = 2;
    /// Noise of pixel p uses stream `NOISE + p`.
    pub const NOISE: u64 = 1 << 40;
}

/// Renders `probe` under `env` at a random pose seen by a random camera.
pub fn synthesize(probe: &ProbeAsset, env: &EnvMap, settings: &SynthSettings) -> Result<SynthScene> {
    validate(settings)?;
    let pose = random_pose(probe, &mut Rng::new(settings.seed, stream::POSE), settings.tilted);
    let posed: Vec<Vec3> = probe.mesh.positions.iter().map(|&p| pose.transform_point(p)).collect();
    let camera = random_camera(
        &posed,
        settings.width,
        settings.height,
        &mut Rng::new(settings.seed, stream::CAMERA),
    )?;
    let (mut image, mask) = render_in_passes(probe, &pose, &camera, env, &GgxMetal, settings.spp, settings.seed);
    apply_sensor(&mut image, settings.noise, settings.exposure_clip, settings.seed);
    Ok(SynthScene {
        image,
        mask,
        camera,
        pose,
    })
}

fn validate(settings: &SynthSettings) -> Result<()> {
    if settings.spp == 0 {
        return Err(Error::invalid("--spp", "needs at least one sample per pixel"));
    }
    if !(settings.noise.is_finite() && settings.noise >= 0.0) {
        return Err(Error::invalid(
            "--noise",
            format!("{} is not a standard deviation >= 0", settings.noise),
        ));
    }
    if let Some(clip) = settings.exposure_clip
        && !(clip.is_finite() && clip > 0.0)
    {
        return Err(Error::invalid("--exposure-clip", format!("{clip} is not > 0")));
    }
    if settings.width < 16 || settings.height < 16 {
        return Err(Error::invalid(
            "--width/--height",
            format!("{}x{} is smaller than 16x16", settings.width, settings.height),
        ));
    }
    Ok(())
}

/// A uniform number in `[range[0], range[1])`.
fn uniform(rng: &mut Rng, range: [f32; 2]) -> f32 {
    range[0] + (range[1] - range[0]) * rng.next_f32()
}

/// Mesh-to-world rotation: a random turn about the mesh's +Y axis (the axis of a probe of
/// revolution), then, when `tilted`, a tilt of that axis about a random horizontal axis (up to
/// [`MAX_TILT_DEG`], or 90 degrees: lying on its side).
pub fn random_rotation(rng: &mut Rng, tilted: bool) -> Quat {
    let yaw = Quat::from_rotation_y(2.0 * PI * rng.next_f32());
    if !tilted {
        return yaw;
    }
    let tilt = if rng.next_f32() < LYING_PROBABILITY {
        FRAC_PI_2
    } else {
        MAX_TILT_DEG.to_radians() * rng.next_f32()
    };
    let heading = 2.0 * PI * rng.next_f32();
    let horizontal_axis = Vec3::new(heading.cos(), 0.0, heading.sin());
    Quat::from_axis_angle(horizontal_axis, tilt) * yaw
}

/// A random pose at scale 1 (probe assets are in metres): [`random_rotation`], then the probe
/// set down on the plane y = 0 with its bounding box centred within 5 cm of the origin.
pub fn random_pose(probe: &ProbeAsset, rng: &mut Rng, tilted: bool) -> Pose {
    let rotation = random_rotation(rng, tilted);
    let rotated: Vec<Vec3> = probe.mesh.positions.iter().map(|&p| rotation * p).collect();
    let (lo, hi) = bounds(&rotated);
    let centre = 0.5 * (lo + hi);
    let offset = Vec3::new(uniform(rng, [-0.05, 0.05]), 0.0, uniform(rng, [-0.05, 0.05]));
    let translation = offset - Vec3::new(centre.x, lo.y, centre.z);
    Pose::new(rotation, 1.0, translation)
}

/// Axis-aligned bounds of points.
fn bounds(points: &[Vec3]) -> (Vec3, Vec3) {
    points
        .iter()
        .fold((Vec3::INFINITY, Vec3::NEG_INFINITY), |(lo, hi), &p| {
            (lo.min(p), hi.max(p))
        })
}

/// A camera at a random azimuth and elevation ([`ELEVATION_DEG`]), field of view
/// ([`FOV_Y_DEG`]) and distance such that the posed probe is a random share
/// ([`PROBE_HEIGHT_FRACTION`]) of the image tall, looking near the probe's centre with +Y up.
pub fn random_camera(posed: &[Vec3], width: u32, height: u32, rng: &mut Rng) -> Result<Camera> {
    let (lo, hi) = bounds(posed);
    let centre = 0.5 * (lo + hi);
    let radius = 0.5 * (hi - lo).length();
    let fov_y_deg = uniform(rng, FOV_Y_DEG);
    let azimuth = 2.0 * PI * rng.next_f32();
    let elevation = uniform(rng, ELEVATION_DEG).to_radians();
    let towards_camera = Vec3::new(
        elevation.cos() * azimuth.sin(),
        elevation.sin(),
        elevation.cos() * azimuth.cos(),
    );
    // "Roughly" at the probe: the aim misses the centre by up to a tenth of the probe's size.
    let aim = centre + 0.1 * radius * Vec3::new(rng.next_f32() - 0.5, rng.next_f32() - 0.5, rng.next_f32() - 0.5);
    let wanted_px = uniform(rng, PROBE_HEIGHT_FRACTION) * height as f32;
    framed(posed, (width, height), fov_y_deg, towards_camera, aim, wanted_px)
}

/// The camera of `size` pixels and vertical field of view `fov_y_deg` looking at `aim` from the
/// direction `towards_camera` (unit), with +Y up, at the distance where the points `posed` are
/// `wanted_px` tall in the image.
fn framed(
    posed: &[Vec3],
    (width, height): (u32, u32),
    fov_y_deg: f32,
    towards_camera: Vec3,
    aim: Vec3,
    wanted_px: f32,
) -> Result<Camera> {
    let (lo, hi) = bounds(posed);
    let radius = 0.5 * (hi - lo).length();
    // Start where the bounding sphere fills the wanted height, then correct by the measured
    // height (inversely proportional to distance, up to perspective: a few rounds converge).
    let mut distance = radius / (0.5 * fov_y_deg.to_radians()).tan() * height as f32 / wanted_px;
    for _ in 0..6 {
        let camera = Camera::new(width, height, fov_y_deg, aim + distance * towards_camera, aim, Vec3::Y)?;
        let rows: Vec<f32> = posed.iter().filter_map(|&p| camera.project(p)).map(|q| q.y).collect();
        if rows.len() < posed.len() {
            distance *= 2.0;
            continue;
        }
        let measured =
            rows.iter().copied().fold(f32::NEG_INFINITY, f32::max) - rows.iter().copied().fold(f32::INFINITY, f32::min);
        distance *= measured / wanted_px;
    }
    Ok(Camera::new(
        width,
        height,
        fov_y_deg,
        aim + distance * towards_camera,
        aim,
        Vec3::Y,
    )?)
}

/// What `alp synth captures` varies.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CaptureSettings {
    /// Seed of the scan's frame, the rings' phases, the renders and the noise.
    pub seed: u64,
    /// Number of views, spread over [`CAPTURE_ELEVATIONS_DEG`]'s rings.
    pub views: usize,
    /// Relative standard deviation of the multiplicative Gaussian noise (0: none).
    pub noise: f32,
    /// Samples per pixel of each view.
    pub spp: u32,
    /// Image width, pixels.
    pub width: u32,
    /// Image height, pixels.
    pub height: u32,
}

impl Default for CaptureSettings {
    fn default() -> Self {
        Self {
            seed: 0,
            views: 24,
            noise: 0.0,
            spp: 64,
            width: 320,
            height: 240,
        }
    }
}

/// Elevations (degrees) of a capture's rings of cameras, as a turntable in a light box is shot;
/// fewer than nine views use the first two.
pub const CAPTURE_ELEVATIONS_DEG: [f32; 3] = [10.0, 30.0, 55.0];
/// A capture's field of view (degrees) and the probe's height in it (share of the image height).
pub const CAPTURE_FOV_Y_DEG: f32 = 35.0;
pub const CAPTURE_PROBE_HEIGHT: f32 = 0.6;
/// The scan's scale (its units per metre) is drawn from this range, log-uniform: a scan's units
/// are arbitrary.
pub const SCAN_SCALE: [f32; 2] = [0.2, 50.0];

/// A synthetic capture, before it is written: the capture folder's contents and the truth.
pub struct SynthCapture {
    /// The mesh in a random frame and scale (the scan), the lighting and the views.
    pub capture: Capture,
    /// The scan's true mesh-to-world pose (the truth an acquisition is judged against).
    pub to_world: Pose,
    /// The probe as the scan: its mesh in the scan's frame, its true textures.
    pub probe: ProbeAsset,
}

/// Renders `probe`, its metal `bsdf`'s, under `env` standing upright at the origin of the world,
/// as a turntable in a light box is shot: `settings.views` cameras on rings at
/// [`CAPTURE_ELEVATIONS_DEG`] looking at it, the mesh written in a random frame and scale.
pub fn synthesize_capture(
    probe: &ProbeAsset,
    env: &EnvMap,
    bsdf: &dyn Bsdf<f32>,
    settings: &CaptureSettings,
) -> Result<SynthCapture> {
    if settings.views < LEAST_VIEWS {
        return Err(Error::invalid(
            "--views",
            format!("{}: a capture needs at least {LEAST_VIEWS}", settings.views),
        ));
    }
    validate(&SynthSettings {
        seed: settings.seed,
        noise: settings.noise,
        spp: settings.spp,
        width: settings.width,
        height: settings.height,
        ..SynthSettings::default()
    })?;
    let mut rng = Rng::new(settings.seed, stream::POSE);
    let pose = random_pose(probe, &mut rng, false);
    let posed: Vec<Vec3> = probe.mesh.positions.iter().map(|&p| pose.transform_point(p)).collect();
    let (lo, hi) = bounds(&posed);
    let centre = 0.5 * (lo + hi);
    // The scan's frame: any rotation, a log-uniform scale, an offset of a few of its sizes.
    let scan_rotation = Quat::from_axis_angle(
        Vec3::new(rng.next_f32() - 0.5, rng.next_f32() - 0.5, rng.next_f32() - 0.5).normalize_or(Vec3::X),
        2.0 * PI * rng.next_f32(),
    );
    let scan_scale = (SCAN_SCALE[0].ln() + (SCAN_SCALE[1] / SCAN_SCALE[0]).ln() * rng.next_f32()).exp();
    let extent = (hi - lo).length() * scan_scale;
    let scan_offset = extent * Vec3::new(rng.next_f32() - 0.5, rng.next_f32() - 0.5, rng.next_f32() - 0.5);
    let scan = Pose::new(scan_rotation, scan_scale, scan_offset);
    // World from scan: the pose after the scan's inverse.
    let rotation = pose.rotation * scan_rotation.inverse();
    let scale = pose.scale / scan_scale;
    let to_world = Pose::new(rotation, scale, pose.translation - scale * (rotation * scan_offset));
    let rings = if settings.views < 9 {
        2
    } else {
        CAPTURE_ELEVATIONS_DEG.len()
    };
    let phases: Vec<f32> = (0..rings).map(|_| 2.0 * PI * rng.next_f32()).collect();
    let mut views = Vec::with_capacity(settings.views);
    for k in 0..settings.views {
        let ring = k % rings;
        // The ring's share of the views, evenly round it from its phase.
        let on_ring = (settings.views - ring).div_ceil(rings);
        let azimuth = phases[ring] + 2.0 * PI * (k / rings) as f32 / on_ring as f32;
        let elevation = CAPTURE_ELEVATIONS_DEG[ring].to_radians();
        let towards_camera = Vec3::new(
            elevation.cos() * azimuth.sin(),
            elevation.sin(),
            elevation.cos() * azimuth.cos(),
        );
        let size = (settings.width, settings.height);
        let wanted_px = CAPTURE_PROBE_HEIGHT * settings.height as f32;
        let camera = framed(&posed, size, CAPTURE_FOV_Y_DEG, towards_camera, centre, wanted_px)?;
        let seed = settings.seed.wrapping_add((k as u64 + 1) << 48);
        let (mut image, mask) = render_in_passes(probe, &pose, &camera, env, bsdf, settings.spp, seed);
        apply_sensor(&mut image, settings.noise, None, seed);
        let name = format!("view_{k:03}");
        let photo = Photo::new(image, mask, camera).map_err(|e| Error::invalid(name.clone(), e.rule()))?;
        views.push(View { name, photo });
    }
    let scanned = ProbeAsset {
        mesh: probe.mesh.posed(&scan),
        ..probe.clone()
    };
    Ok(SynthCapture {
        capture: Capture {
            mesh: scanned.mesh.clone(),
            lighting: env.clone(),
            views,
        },
        to_world,
        probe: scanned,
    })
}

/// Writes a synthetic capture folder atomically: the capture's files, and its truth
/// (`acquire::truth`): `true_pose.json`, the scan's true mesh-to-world pose, and `true_probe/`,
/// the probe with the scan's mesh and the true textures.
pub fn write_capture(out: &Path, synth: &SynthCapture) -> Result<()> {
    crate::output::write_folder_atomically(out, |dir| {
        synth.capture.write(dir)?;
        synth.probe.write(dir.join("true_probe"))?;
        Ok(synth.to_world.write(dir.join("true_pose.json"))?)
    })
}

/// `render_image` at `spp` samples per pixel, in passes of at most [`SPP_PER_PASS`] (the
/// renderer keeps every sample of a pass in memory), averaged; a pixel is in the mask when it is
/// in the mask of at least half of the passes.
fn render_in_passes(
    probe: &ProbeAsset,
    pose: &Pose,
    camera: &Camera,
    env: &EnvMap,
    bsdf: &dyn Bsdf<f32>,
    spp: u32,
    seed: u64,
) -> (RgbImage, Mask) {
    let passes = spp.div_ceil(SPP_PER_PASS);
    let (w, h) = (camera.width as usize, camera.height as usize);
    let mut sum = vec![[0.0f64; 3]; w * h];
    let mut votes = vec![0u32; w * h];
    for pass in 0..passes {
        let pass_spp = (spp - pass * SPP_PER_PASS).min(SPP_PER_PASS);
        let settings = RenderSettings {
            spp: pass_spp,
            seed: seed.wrapping_add((pass as u64) << 32),
        };
        let (image, mask) = render_image(probe, pose, camera, env, bsdf, &settings);
        for ((total, rgb), (vote, &inside)) in sum
            .iter_mut()
            .zip(&image.pixels)
            .zip(votes.iter_mut().zip(&mask.inside))
        {
            for (t, &v) in total.iter_mut().zip(rgb) {
                *t += v as f64 * pass_spp as f64;
            }
            *vote += inside as u32;
        }
    }
    let pixels = sum.iter().map(|rgb| rgb.map(|v| (v / spp as f64) as f32)).collect();
    let inside = votes.iter().map(|&v| 2 * v >= passes).collect();
    (RgbImage::new(w, h, pixels), Mask::new(w, h, inside))
}

/// Multiplicative noise `x (1 + noise g)` (g standard normal, per channel, floored at 0 so
/// radiance stays non-negative; the random streams of `seed`), then clipping at `exposure_clip`.
fn apply_sensor(image: &mut RgbImage, noise: f32, exposure_clip: Option<f32>, seed: u64) {
    for (p, rgb) in image.pixels.iter_mut().enumerate() {
        if noise > 0.0 {
            let mut rng = Rng::new(seed, stream::NOISE + p as u64);
            for v in rgb.iter_mut() {
                *v *= (1.0 + noise * standard_normal(&mut rng)).max(0.0);
            }
        }
        if let Some(clip) = exposure_clip {
            for v in rgb.iter_mut() {
                *v = v.min(clip);
            }
        }
    }
}

/// A standard normal number (Box-Muller; `1 - u` keeps the logarithm finite).
pub(crate) fn standard_normal(rng: &mut Rng) -> f32 {
    let (u1, u2) = (rng.next_f32(), rng.next_f32());
    (-2.0 * (1.0 - u1).ln()).sqrt() * (2.0 * PI * u2).cos()
}

/// What `probe.txt` says for the probe given as `probe_arg` to a scene written to `scene_dir`:
/// the name of a procedural probe, or the probe folder's path relative to the scene folder.
pub fn probe_reference(probe_arg: &Path, scene_dir: &Path) -> Result<String> {
    if !probe_arg.exists()
        && let Some(name) = probe_arg.to_str()
        && crate::probes::PROCEDURAL.contains(&name)
    {
        return Ok(name.to_string());
    }
    let probe = probe_arg
        .canonicalize()
        .map_err(|e| RenderError::io(probe_arg, "find the probe folder", e))?;
    let parent = match scene_dir.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
        _ => PathBuf::from("."),
    };
    let parent = parent
        .canonicalize()
        .map_err(|e| RenderError::io(&parent, "find the output's parent folder", e))?;
    let name = scene_dir
        .file_name()
        .ok_or_else(|| RenderError::file(scene_dir, "a scene folder needs a name (not `/` or `..`)"))?;
    let relative = relative_path(&parent.join(name), &probe);
    relative
        .to_str()
        .map(str::to_string)
        .ok_or_else(|| RenderError::file(&probe, "the probe's path is not valid UTF-8 (probe.txt is text)").into())
}

/// The path that leads from folder `from` to `to` (both absolute and free of `..`).
fn relative_path(from: &Path, to: &Path) -> PathBuf {
    let from: Vec<Component> = from.components().collect();
    let to: Vec<Component> = to.components().collect();
    let common = from.iter().zip(&to).take_while(|(a, b)| a == b).count();
    let mut out = PathBuf::new();
    for _ in common..from.len() {
        out.push("..");
    }
    for c in &to[common..] {
        out.push(c);
    }
    if out.as_os_str().is_empty() {
        out.push(".");
    }
    out
}

/// Writes a scene folder atomically: `image.exr`, `mask.png`, `camera.json`, `probe.txt`,
/// `gt_env.exr`, `pose.json`.
pub fn write_scene(out: &Path, scene: &SynthScene, env: &EnvMap, probe_reference: &str) -> Result<()> {
    crate::output::write_folder_atomically(out, |dir| {
        scene.image.write_exr(dir.join("image.exr"))?;
        scene.mask.write_png(dir.join("mask.png"))?;
        scene.camera.write(dir.join("camera.json"))?;
        let probe_txt = dir.join("probe.txt");
        std::fs::write(&probe_txt, format!("{probe_reference}\n"))
            .map_err(|e| RenderError::io(&probe_txt, "write", e))?;
        env.write(dir.join("gt_env.exr"))?;
        Ok(scene.pose.write(dir.join("pose.json"))?)
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn relative_paths() {
        let rel = |a: &str, b: &str| relative_path(Path::new(a), Path::new(b));
        assert_eq!(rel("/a/b/scene", "/a/probes/can"), PathBuf::from("../../probes/can"));
        assert_eq!(rel("/a/scene", "/a/scene/probe"), PathBuf::from("probe"));
        assert_eq!(rel("/a/scene", "/a/scene"), PathBuf::from("."));
    }

    #[test]
    fn upright_poses_keep_the_axis_vertical_and_tilted_ones_do_not() {
        let mut rng = Rng::new(7, 0);
        for _ in 0..20 {
            let up = random_rotation(&mut rng, false) * Vec3::Y;
            assert!((up - Vec3::Y).length() < 1e-5);
        }
        let tilts: Vec<f32> = (0..200)
            .map(|_| {
                (random_rotation(&mut rng, true) * Vec3::Y)
                    .y
                    .clamp(-1.0, 1.0)
                    .acos()
                    .to_degrees()
            })
            .collect();
        assert!(tilts.iter().all(|&t| t <= 90.0 + 1e-3));
        let lying = tilts.iter().filter(|&&t| (t - 90.0).abs() < 1e-3).count();
        assert!((25..=75).contains(&lying), "{lying} of 200 lying");
        assert!(tilts.iter().filter(|&&t| t < 89.0).all(|&t| t <= MAX_TILT_DEG + 1e-3));
    }

    #[test]
    fn noise_has_the_requested_spread() {
        let mut image = RgbImage::filled(100, 100, [1.0; 3]);
        let settings = SynthSettings {
            noise: 0.1,
            exposure_clip: Some(1.5),
            ..SynthSettings::default()
        };
        apply_sensor(&mut image, settings.noise, settings.exposure_clip, settings.seed);
        let values: Vec<f64> = image.pixels.iter().flatten().map(|&v| v as f64).collect();
        let mean = values.iter().sum::<f64>() / values.len() as f64;
        let std = (values.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / values.len() as f64).sqrt();
        assert!((mean - 1.0).abs() < 0.005 && (std - 0.1).abs() < 0.005, "{mean} {std}");
        assert!(values.iter().all(|&v| v <= 1.5));
    }
}
