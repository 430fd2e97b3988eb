//! Procedural probes for tests and demos: a soda can, a thermos cap and a UV sphere.
//!
//! Each is an in-memory [`ProbeAsset`](crate::probe::ProbeAsset) (write it with
//! `ProbeAsset::write`). Mesh frame: metres, +Y up; the can and the cap stand on the XZ plane
//! with the centre of their base at the origin, the sphere is centred on the origin. All are
//! surfaces of revolution around +Y, UV-mapped with u around the axis and v along the profile.

mod revolution;
mod soda_can;
mod sphere;
mod thermos_cap;

pub use revolution::{Profile, surface_of_revolution};
pub use soda_can::SodaCan;
pub use sphere::UvSphere;
pub use thermos_cap::ThermosCap;
