//! The differentiable renderer: probe assets, env maps, GGX metal under image-based light, soft masks and Chamfer.
//!
//! This part holds the non-differentiated foundations: file formats (FORMATS.md), the camera,
//! probe assets and procedural probes, ray-triangle acceleration, and the scalar samplers.

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
pub mod envmap;
pub mod error;
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
