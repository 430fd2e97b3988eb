//! Scalar (non-differentiated) samplers with their pdfs, and the random numbers that drive them.
//!
//! Every sampler maps uniform numbers in [0, 1)^2 to a direction and has a matching `pdf` in
//! solid angle; `tests/sampling_chi2.rs` checks each against its pdf with a chi-squared test.

mod distribution;
mod env;
mod frame;
pub mod ggx;
mod rng;
mod warp;

pub use distribution::Distribution1D;
pub use env::{EnvSample, EnvSampler};
pub use frame::Frame;
pub use rng::{Rng, stratified_square};
pub use warp::{
    cosine_hemisphere_pdf, sample_concentric_disk, sample_cosine_hemisphere, sample_linear, sample_standard_normal_2d,
    sample_uniform_sphere, uniform_sphere_pdf,
};
