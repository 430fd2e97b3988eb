//! Accidental light probes: recover the lighting (an environment map) and the
//! probe's pose from one HDR photo of a known shiny object (Yu et al., CVPR
//! 2023), by inverting the differentiable renderer of the `render` crate.
//!
//! This crate holds what the method adds on top of the renderer: output
//! folders written atomically, the probe catalogue, the declarative
//! objective, the estimation, evaluation, virtual object insertion and the
//! `alp` CLI.
//!
//! From a photo to its lighting, and an object set into it under that light:
//!
//! ```no_run
//! use std::path::Path;
//! use alp::estimate::{estimate, Photo, Quality, Settings};
//! use alp::insert::{insert, Finish, InsertSettings, MaterialSpec, VirtualObject};
//! use render::camera::Camera;
//! use render::image_io::{Mask, RgbImage};
//! use render::pose::Pose;
//!
//! # fn main() -> alp::Result<()> {
//! let (image, _encoding) = RgbImage::read_photo("photo.exr")?;
//! let camera = Camera::read("camera.json")?;
//! let photo = Photo::new(image.clone(), Mask::read_png("mask.png")?, camera)?;
//! let probe = alp::probes::load(Path::new("can"))?;
//! let found = estimate(&photo, &probe, &Settings::new(Quality::Default))?;
//! found.env.write("env.exr")?;
//!
//! let gold = MaterialSpec { finish: Finish::Metal, albedo: Some([1.0, 0.78, 0.34]), roughness: Some(0.15) };
//! let object = VirtualObject::load(Path::new("sphere"), Some(&gold))?;
//! let at = Pose::read("object_pose.json")?;
//! let inserted = insert(&image, &found.env, &camera, &object, &at, &InsertSettings::default())?;
//! inserted.image.write_exr("inserted.exr")?;
//! # Ok(())
//! # }
//! ```

pub mod acquire;
pub mod batch;
pub mod cli;
pub mod demo;
pub mod error;
pub mod estimate;
pub mod eval;
pub mod insert;
pub mod linalg;
pub mod objective;
pub mod output;
pub mod pose_frame;
pub mod probes;
pub mod relight;
pub mod study;
pub mod synth;

pub use crate::error::{Error, Result};
