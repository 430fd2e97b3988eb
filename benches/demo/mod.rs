//! The demo scene the benches share: the procedural can at the demo pose in
//! the demo camera (640x480), under the courtyard map, and its photo (64
//! spp, seed 99).

use render::bsdf::GgxMetal;
use render::camera::Camera;
use render::envmap::EnvMap;
use render::image_io::{Mask, RgbImage};
use render::integrator::{RenderSettings, render_image};
use render::pose::Pose;
use render::probe::ProbeAsset;
use render::procedural::SodaCan;

/// The scene and its photo.
// Each bench, a crate of its own, reads the fields it needs.
#[allow(dead_code)]
pub struct Demo {
    pub probe: ProbeAsset,
    pub camera: Camera,
    pub pose: Pose,
    /// The map the photo was rendered under.
    pub env: EnvMap,
    pub photo: RgbImage,
    pub mask: Mask,
}

/// Builds the probe, reads the demo camera, pose and map from `assets/`,
/// and renders the photo.
pub fn scene() -> Demo {
    let assets = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("assets");
    let probe = SodaCan::default().build();
    let camera = Camera::read(assets.join("demo/camera.json")).expect("demo camera");
    let pose = Pose::read(assets.join("demo/pose.json")).expect("demo pose");
    let env = EnvMap::read(assets.join("envmaps/courtyard.exr")).expect("env map");
    let (photo, mask) = render_image(
        &probe,
        &pose,
        &camera,
        &env,
        &GgxMetal,
        &RenderSettings { spp: 64, seed: 99 },
    );
    Demo {
        probe,
        camera,
        pose,
        env,
        photo,
        mask,
    }
}

/// Runs `bench(threads)` inside a pool of 1, then 2 threads: the machine's
/// cores, and the speed-up they give.
pub fn on_1_and_2_threads(bench: impl Fn(usize) + Sync) {
    for threads in [1, 2] {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .expect("pool")
            .install(|| bench(threads));
    }
}
