//! The relit spheres of the evaluation (FORMATS.md, "Relighting evaluation"): a mirror, a shiny
//! and a diffuse unit sphere lit by an env map, seen along the scene camera's viewing direction.
//!
//! The spheres are rendered analytically rather than as meshes through `render_image`: each
//! sub-pixel ray meets the exact sphere, so the normal is exact (a 256 x 128 UV sphere's
//! interpolated normals put its mirror 0.08 degrees off the exact one on the courtyard map,
//! `tests/relight_noise_floor.rs`). The lighting integral (direct lighting only)
//!
//!   L(wo) = integral of L_env(wi) f(wi, wo) cos(theta_i) dwi
//!
//! is, per sphere:
//! - mirror: the env lookup of the reflected direction, one per sub-pixel position;
//! - shiny: Monte Carlo, one GGX visible-normal sample and one env-map sample per sub-pixel
//!   position, combined by multiple importance sampling (a sun defeats BRDF sampling alone):
//!   render's point shading ([`ShadingPoint`]) with its GGX metal;
//! - diffuse: a noise-free quadrature of the irradiance over a 128 x 64 grid ([`IRRADIANCE_ROWS`]).
//!
//! Sampling: `spp = n x n` sub-pixel positions on a jittered n x n grid (a box filter over the
//! pixel), each with BRDF and env samples from jittered n x n grids of the unit square whose
//! strata are shuffled per pixel (pbrt's "padded" stratified samples). Pixel p's numbers come
//! from stream p of the seed: the image does not depend on the thread count, and two maps relit
//! with one seed share their random numbers (so `eval` scores identical maps exactly 0).

use std::f32::consts::FRAC_1_PI;

use glam::{Vec2, Vec3};
use rayon::prelude::*;

use render::bsdf::{GgxMetal, PointSurface};
use render::camera::Camera;
use render::envmap::EnvMap;
use render::image_io::{Mask, RgbImage};
use render::integrator::ShadingPoint;
use render::sampling::{EnvSampler, Frame, Rng};

use crate::error::{Error, Result};

/// Width and height of each sphere's render, pixels.
pub const SPHERE_IMAGE_SIZE: u32 = 256;
/// Distance from the camera to the centre of the unit sphere.
pub const CAMERA_DISTANCE: f32 = 5.0;
/// The field of view is the sphere's angular diameter, 2 asin(1 / distance), times this margin.
pub const FOV_MARGIN: f32 = 1.04;
/// Pixels are evaluated when their centre ray hits the sphere at least this far inside its silhouette.
pub const SILHOUETTE_INSET_PX: f32 = 1.5;
/// The shiny sphere's material: GGX metal, albedo 1, roughness sqrt(0.1) (alpha = r^2 = 0.1).
pub const SHINY: PointSurface = PointSurface {
    albedo: [1.0; 3],
    roughness: 0.316_227_77,
};
/// Albedo of the diffuse sphere.
pub const DIFFUSE_ALBEDO: f32 = 0.8;
/// Default samples per pixel, 32 x 32: the shiny sphere's noise floor (two seeds, courtyard map)
/// is then 0.2 degrees; see `tests/relight_noise_floor.rs`.
pub const DEFAULT_SPP: u32 = 1024;

/// One of the three evaluation spheres.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Sphere {
    /// A perfect conductor: reflectance 1 at every angle.
    Mirror,
    /// GGX metal, albedo 1, alpha 0.1.
    Shiny,
    /// Lambertian, albedo 0.8.
    Diffuse,
}

impl Sphere {
    /// The three spheres in the order of the side-by-side image: mirror, shiny, diffuse.
    pub const ALL: [Sphere; 3] = [Sphere::Mirror, Sphere::Shiny, Sphere::Diffuse];

    /// The name used in reports and JSON: `mirror`, `shiny`, `diffuse`.
    pub fn name(self) -> &'static str {
        match self {
            Sphere::Mirror => "mirror",
            Sphere::Shiny => "shiny",
            Sphere::Diffuse => "diffuse",
        }
    }
}

/// Monte Carlo settings of [`relight`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RelightSettings {
    /// Samples per pixel; a square n x n (stratified sub-pixel positions and BRDF samples).
    pub spp: u32,
    /// Seed of every random number.
    pub seed: u64,
}

impl Default for RelightSettings {
    fn default() -> Self {
        Self {
            spp: DEFAULT_SPP,
            seed: 0,
        }
    }
}

/// The three relit spheres, each a [`SPHERE_IMAGE_SIZE`]-square linear RGB image (black background).
#[derive(Clone, Debug, PartialEq)]
pub struct RelitSpheres {
    /// Indexed like [`Sphere::ALL`]: mirror, shiny, diffuse.
    pub images: [RgbImage; 3],
}

impl RelitSpheres {
    /// The render of one sphere.
    pub fn image(&self, sphere: Sphere) -> &RgbImage {
        &self.images[sphere as usize]
    }

    /// The three renders side by side, left to right mirror, shiny, diffuse (768 x 256).
    pub fn side_by_side(&self) -> RgbImage {
        let (w, h) = (self.images[0].width, self.images[0].height);
        let mut pixels = Vec::with_capacity(3 * w * h);
        for row in 0..h {
            for image in &self.images {
                pixels.extend_from_slice(&image.pixels[row * w..(row + 1) * w]);
            }
        }
        RgbImage::new(3 * w, h, pixels)
    }
}

/// The camera that sees the unit sphere at the origin along `scene`'s viewing direction, with
/// `scene`'s `up`: 256 x 256, at distance 5, vertical fov 2 asin(1/5) x 1.04 (about 24 degrees).
pub fn sphere_camera(scene: &Camera) -> Result<Camera> {
    let fov_y_deg = 2.0 * (1.0 / CAMERA_DISTANCE).asin().to_degrees() * FOV_MARGIN;
    Ok(Camera::new(
        SPHERE_IMAGE_SIZE,
        SPHERE_IMAGE_SIZE,
        fov_y_deg,
        -CAMERA_DISTANCE * scene.forward,
        Vec3::ZERO,
        scene.up,
    )?)
}

/// The direction each pixel of the mirror sphere reflects (row-major, at its centre ray; `None`
/// off the sphere): which part of a map the mirror shows where.
pub fn mirror_directions(scene: &Camera) -> Result<Vec<Option<Vec3>>> {
    let camera = sphere_camera(scene)?;
    let size = SPHERE_IMAGE_SIZE;
    Ok((0..size * size)
        .map(|p| {
            let (origin, direction) = camera.primary_ray(p / size, p % size, Vec2::splat(0.5));
            unit_sphere_normal(origin, direction).map(|n| direction - 2.0 * direction.dot(n) * n)
        })
        .collect())
}

/// The pixels the metrics look at: those whose centre ray hits the sphere at least
/// [`SILHOUETTE_INSET_PX`] inside its silhouette (the same for every viewing direction).
///
/// The camera looks at the sphere's centre, so the silhouette is the circle of radius
/// `(size / 2) tan(asin(1 / distance)) / tan(fov / 2)` pixels about the image centre.
pub fn evaluation_region() -> Mask {
    let size = SPHERE_IMAGE_SIZE as usize;
    let half_angle = (1.0 / CAMERA_DISTANCE as f64).asin();
    let half_fov = half_angle * FOV_MARGIN as f64;
    let centre = 0.5 * size as f64;
    let radius_px = centre * half_angle.tan() / half_fov.tan();
    let inside = (0..size * size)
        .map(|p| {
            let (row, col) = (p / size, p % size);
            let (x, y) = (col as f64 + 0.5 - centre, row as f64 + 0.5 - centre);
            (x * x + y * y).sqrt() <= radius_px - SILHOUETTE_INSET_PX as f64
        })
        .collect();
    Mask::new(size, size, inside)
}

/// Renders the mirror, shiny and diffuse spheres under `env` as seen along `scene`'s view.
///
/// Fails when `settings.spp` is not a positive square (n x n stratified samples).
pub fn relight(env: &EnvMap, scene: &Camera, settings: &RelightSettings) -> Result<RelitSpheres> {
    let strata = (settings.spp as f64).sqrt().round() as u32;
    if settings.spp == 0 || strata * strata != settings.spp {
        return Err(Error::invalid(
            "spp",
            format!(
                "{} is not a positive square (n x n stratified samples: 64, 256, 1024, ...)",
                settings.spp
            ),
        ));
    }
    let camera = sphere_camera(scene)?;
    let lights = EnvSampler::new(env);
    let irradiance = Irradiance::new(env);
    let size = SPHERE_IMAGE_SIZE as usize;
    let pixels: Vec<[[f32; 3]; 3]> = (0..size * size)
        .into_par_iter()
        .map(|p| relight_pixel(env, &lights, &irradiance, &camera, p, strata, settings.seed))
        .collect();
    let images = std::array::from_fn(|s| RgbImage::new(size, size, pixels.iter().map(|px| px[s]).collect()));
    Ok(RelitSpheres { images })
}

/// The mean radiance of the three spheres over pixel `p` (row-major), from `strata^2` samples.
fn relight_pixel(
    env: &EnvMap,
    lights: &EnvSampler,
    irradiance: &Irradiance,
    camera: &Camera,
    p: usize,
    strata: u32,
    seed: u64,
) -> [[f32; 3]; 3] {
    let size = camera.width as usize;
    let (row, col) = ((p / size) as u32, (p % size) as u32);
    let mut rng = Rng::new(seed, p as u64);
    let spp = (strata * strata) as usize;
    let lobe_strata = shuffled(spp, &mut rng);
    let light_strata = shuffled(spp, &mut rng);
    let mut sum = [[0.0f64; 3]; 3];
    let mut normal_sum = Vec3::ZERO;
    let mut hits = 0;
    for k in 0..spp {
        let offset = jittered(k as u32, strata, &mut rng);
        let (origin, direction) = camera.primary_ray(row, col, offset);
        let Some(normal) = unit_sphere_normal(origin, direction) else {
            continue;
        };
        let frame = Frame::from_normal(normal);
        let wo = frame.to_local(-direction);
        if wo.z <= 0.0 {
            continue;
        }
        let u_lobe = jittered(lobe_strata[k], strata, &mut rng);
        let u_light = jittered(light_strata[k], strata, &mut rng);
        let mirror = env.lookup(direction - 2.0 * direction.dot(normal) * normal);
        let shiny = ShadingPoint {
            bsdf: &GgxMetal,
            surface: SHINY,
            frame,
            wo,
        }
        .reflected(lights, [u_lobe, u_light], |d| env.lookup(d));
        for (s, radiance) in [mirror, shiny].into_iter().enumerate() {
            for c in 0..3 {
                sum[s][c] += radiance[c] as f64;
            }
        }
        normal_sum += normal;
        hits += 1;
    }
    let mut out = sum.map(|rgb| rgb.map(|v| (v / spp as f64) as f32));
    // The diffuse radiance varies slowly across a pixel: one evaluation at the mean normal of the
    // samples that hit, times the pixel's coverage (exact inside the silhouette).
    if hits > 0 {
        let coverage = hits as f32 / spp as f32;
        let e = irradiance.at(normal_sum.normalize());
        out[Sphere::Diffuse as usize] = e.map(|v| coverage * DIFFUSE_ALBEDO * FRAC_1_PI * v);
    }
    out
}

/// Rows of the quadrature grid of the diffuse sphere's irradiance (2.8-degree texels).
pub const IRRADIANCE_ROWS: usize = 64;

/// Irradiance E(n) = integral of L_env(w) max(0, n.w) dw by the midpoint rule on a grid of
/// [`IRRADIANCE_ROWS`] x 2 [`IRRADIANCE_ROWS`] texels: the map box-filtered to it when larger,
/// and looked up (bilinearly, as FORMATS.md reads a map) at its texel centres when smaller.
///
/// The clamped cosine is smooth at the texel scale, so the quadrature error is second order in
/// the texel angle (measured: 1% on an 8-row grid, so about 2e-4 here), and there is no noise,
/// where a Monte Carlo estimate under a sun is noisy. The price: detail finer than the grid does
/// not reach the diffuse sphere (the exact response to it is of that same order).
struct Irradiance {
    /// Unit texel-centre directions.
    directions: Vec<Vec3>,
    /// Radiance times the texel's solid angle, RGB.
    power: Vec<[f32; 3]>,
}

impl Irradiance {
    fn new(env: &EnvMap) -> Self {
        let grid = EnvMap::constant(IRRADIANCE_ROWS, [0.0; 3]);
        let map = (env.height() > IRRADIANCE_ROWS).then(|| env.downsample(IRRADIANCE_ROWS));
        let texels = (0..grid.height()).flat_map(|row| (0..grid.width()).map(move |col| (row, col)));
        let (directions, power) = texels
            .map(|(row, col)| {
                let direction = grid.texel_direction(row, col);
                let radiance = match &map {
                    Some(map) => map.texel(row, col),
                    None => env.lookup(direction),
                };
                let solid_angle = grid.texel_solid_angle(row);
                (direction, radiance.map(|v| v * solid_angle))
            })
            .unzip();
        Self { directions, power }
    }

    /// E(normal), RGB.
    fn at(&self, normal: Vec3) -> [f32; 3] {
        let mut e = [0.0f32; 3];
        for (d, p) in self.directions.iter().zip(&self.power) {
            let cos = normal.dot(*d).max(0.0);
            for c in 0..3 {
                e[c] += cos * p[c];
            }
        }
        e
    }
}

/// `0..n` in a random order (Fisher-Yates).
fn shuffled(n: usize, rng: &mut Rng) -> Vec<u32> {
    let mut order: Vec<u32> = (0..n as u32).collect();
    for i in (1..n).rev() {
        order.swap(i, rng.next_below(i as u32 + 1) as usize);
    }
    order
}

/// A uniform point in stratum `k` of the `strata x strata` grid of [0, 1)^2.
fn jittered(k: u32, strata: u32, rng: &mut Rng) -> Vec2 {
    let cell = Vec2::new((k % strata) as f32, (k / strata) as f32);
    (cell + rng.next_2d()) / strata as f32
}

/// The outward normal where the ray (origin, unit direction) first meets the unit sphere at the
/// origin: t = -b - sqrt(b^2 - c) with b = o.d, c = o.o - 1; `None` on a miss.
fn unit_sphere_normal(origin: Vec3, direction: Vec3) -> Option<Vec3> {
    let b = origin.dot(direction);
    let discriminant = b * b - (origin.length_squared() - 1.0);
    if discriminant < 0.0 {
        return None;
    }
    let t = -b - discriminant.sqrt();
    (t > 0.0).then(|| (origin + t * direction).normalize())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn front_camera() -> Camera {
        Camera::new(640, 480, 40.0, Vec3::new(0.0, 0.0, 3.0), Vec3::ZERO, Vec3::Y).unwrap()
    }

    #[test]
    fn sphere_camera_frames_the_sphere_along_the_scene_view() {
        let camera = sphere_camera(&front_camera()).unwrap();
        assert_eq!((camera.width, camera.height), (256, 256));
        assert!((camera.origin - Vec3::new(0.0, 0.0, 5.0)).length() < 1e-6);
        // 2 asin(0.2) = 23.074 degrees, times 1.04.
        assert!((camera.fov_y_deg - 23.997).abs() < 1e-2, "{}", camera.fov_y_deg);
    }

    #[test]
    fn evaluation_region_is_a_disc_inset_from_the_silhouette() {
        let region = evaluation_region();
        // Silhouette radius 128 tan(asin 0.2) / tan(1.04 asin 0.2) = 122.96 px; inset 121.46 px.
        let expected = std::f64::consts::PI * 121.46f64.powi(2);
        let count = region.count() as f64;
        assert!((count - expected).abs() < 0.01 * expected, "{count} vs {expected}");
        assert!(region.inside[128 * 256 + 128]);
        assert!(!region.inside[128 * 256 + 5] && !region.inside[128 * 256 + 250]);
        assert!(region.inside[128 * 256 + 7] && region.inside[128 * 256 + 248]);
    }

    #[test]
    fn ray_sphere_normal_at_the_front() {
        let n = unit_sphere_normal(Vec3::new(0.0, 0.0, 5.0), -Vec3::Z).unwrap();
        assert!((n - Vec3::Z).length() < 1e-6);
        assert!(unit_sphere_normal(Vec3::new(0.0, 1.01, 5.0), -Vec3::Z).is_none());
    }

    #[test]
    fn the_shiny_sphere_has_alpha_a_tenth() {
        assert_eq!(SHINY.roughness * SHINY.roughness, 0.1);
    }

    #[test]
    fn rejects_non_square_spp() {
        let env = EnvMap::constant(4, [1.0; 3]);
        let settings = RelightSettings { spp: 10, seed: 0 };
        let e = relight(&env, &front_camera(), &settings).unwrap_err();
        assert_eq!(e.field_name(), Some("spp"), "{e}");
    }
}
