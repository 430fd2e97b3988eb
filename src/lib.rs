//! Accidental light probes: recover an environment map and a probe's pose from
//! one HDR photo of a known shiny object. This root crate only re-exports the
//! workspace's crates so that cross-crate tests and benchmarks have one home.

pub use alp;
pub use autodiff;
pub use optim;
pub use render;
