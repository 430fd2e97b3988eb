//! The differentiable renderer: probe assets, env maps, GGX metal under image-based light, soft masks and Chamfer.
//!
//! This part holds the non-differentiated foundations: file formats (FORMATS.md), the camera,
//! probe assets and procedural probes, ray-triangle acceleration, and the scalar samplers.
//!
//! The forward model in a few lines: a soda can under a uniform grey sky.
//!
//! ```
//! use glam::{Quat, Vec3};
//! use render::bsdf::GgxMetal;
//! use render::camera::Camera;
//! use render::envmap::EnvMap;
//! use render::integrator::{RenderSettings, render_image};
//! use render::pose::Pose;
//! use render::procedural::SodaCan;
//!
//! let can = SodaCan::default().build();
//! let camera = Camera::new(64, 48, 40.0, Vec3::new(0.0, 0.05, 0.4), Vec3::ZERO, Vec3::Y)?;
//! let sky = EnvMap::constant(16, [1.0; 3]);
//! let settings = RenderSettings { spp: 4, seed: 0 };
//! let (image, mask) = render_image(&can, &Pose::new(Quat::IDENTITY, 1.0, Vec3::ZERO), &camera, &sky, &GgxMetal, &settings);
//! assert!(mask.count() > 100);
//! // A metal under a uniform white sky reflects at most what it receives (on average).
//! let mean = image.pixels.iter().map(|p| p[1] as f64).sum::<f64>() / mask.count() as f64;
//! assert!(mean > 0.0 && mean <= 1.0, "{mean}");
//! # Ok::<(), render::RenderError>(())
//! ```

/// Asserts that two glam vectors agree to `eps` in every component (glam's own `abs_diff_eq`).
#[cfg(test)]
macro_rules! assert_vec_close {
    ($a:expr, $b:expr, $eps:expr) => {{
        let (a, b) = ($a, $b);
        assert!(a.abs_diff_eq(b, $eps), "{a} != {b} (eps {})", $eps);
    }};
}

pub mod accel;
pub mod bsdf;
pub mod camera;
pub mod colour;
pub mod envmap;
pub mod error;
pub mod exif_camera;
pub mod image_io;
pub mod integrator;
mod json;
pub mod lookup;
pub mod mesh;
pub mod pose;
pub mod posed;
pub mod probe;
pub mod procedural;
pub mod sampling;
pub mod silhouette;
pub mod transport;

pub use error::{RenderError, Result};
