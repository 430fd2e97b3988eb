//! Accidental light probes: recover the lighting (an environment map) and the
//! probe's pose from one HDR photo of a known shiny object (Yu et al., CVPR
//! 2023), by inverting the differentiable renderer of the `render` crate.
//!
//! This crate holds what the method adds on top of the renderer: output
//! folders written atomically, the probe catalogue, the declarative
//! objective, the estimation, evaluation, virtual object insertion and the
//! `alp` CLI.

pub mod acquire;
pub mod batch;
pub mod demo;
pub mod error;
pub mod estimate;
pub mod eval;
pub mod insert;
pub mod objective;
pub mod output;
pub mod probes;
pub mod relight;
pub mod study;
pub mod synth;

pub use crate::error::{Error, Result};
