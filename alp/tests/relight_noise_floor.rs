//! Measurements behind the relighting evaluation's settings (run by hand, they take a minute):
//!
//!   cargo test -p alp --release --test relight_noise_floor -- --ignored --nocapture
//!
//! prints one JSON object per line: the noise floor (two seeds, same map) and the time of a
//! relight per spp; the error of box-filtered ground truths against the full-resolution one; and
//! how far a tessellated UV sphere rendered by `render_image` is from the analytic mirror.
//! The same seed is used for both maps of a comparison, as `alp eval` does.

use std::path::PathBuf;
use std::time::Instant;

use glam::Vec3;

use alp::eval::{compare_spheres, relighting_errors};
use alp::relight::{RelightSettings, RelitSpheres, Sphere, evaluation_region, relight, sphere_camera};
use render::bsdf::Mirror;
use render::camera::Camera;
use render::envmap::EnvMap;
use render::integrator::{RenderSettings, render_image};
use render::pose::Pose;
use render::procedural::UvSphere;

fn courtyard() -> EnvMap {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../assets/envmaps/courtyard.exr");
    EnvMap::read(path).expect("assets/envmaps/courtyard.exr")
}

/// A scene camera looking slightly down at the probe, as `alp synth` makes them.
fn scene_camera() -> Camera {
    Camera::new(640, 480, 40.0, Vec3::new(0.3, 0.2, 0.4), Vec3::ZERO, Vec3::Y).expect("camera")
}

fn errors_json(errors: &[alp::eval::SphereErrors; 3]) -> String {
    Sphere::ALL
        .iter()
        .zip(errors)
        .map(|(s, e)| format!("\"{}\": [{:.4}, {:.5}]", s.name(), e.angular_deg, e.si_rmse))
        .collect::<Vec<_>>()
        .join(", ")
}

#[test]
#[ignore = "a measurement, about a minute in release"]
fn noise_floor_timing_and_resolution() {
    let env = courtyard();
    let camera = scene_camera();
    println!(
        "{{\"env\": \"courtyard\", \"size\": [{}, {}]}}",
        env.width(),
        env.height()
    );
    for spp in [64, 256, 1024] {
        let settings = |seed| RelightSettings { spp, seed };
        let start = Instant::now();
        let a = relight(&env, &camera, &settings(0)).expect("relight");
        let seconds = start.elapsed().as_secs_f64();
        let b = relight(&env, &camera, &settings(1)).expect("relight");
        let floor = compare_spheres(&b, &a, &evaluation_region());
        println!(
            "{{\"spp\": {spp}, \"seconds_per_relight\": {seconds:.2}, \"noise_floor\": {{{}}}}}",
            errors_json(&floor)
        );
    }
    for height in [32, 64] {
        let small = env.downsample(height);
        for seed in [0, 1] {
            let settings = RelightSettings {
                seed,
                ..Default::default()
            };
            let errors = relighting_errors(&small, &env, &camera, &settings).expect("relight");
            println!(
                "{{\"downsampled\": [{}, {height}], \"seed\": {seed}, \"error\": {{{}}}}}",
                2 * height,
                errors_json(&errors)
            );
        }
    }
    // The mirror as a 256 x 128 UV-sphere mesh through the probe renderer, against the analytic one.
    let analytic: RelitSpheres = relight(&env, &camera, &RelightSettings { spp: 64, seed: 0 }).expect("relight");
    let sphere = UvSphere {
        radius: 1.0,
        segments: 256,
        rings: 128,
        albedo: [1.0; 3],
        roughness: 0.0,
    }
    .build();
    let view = sphere_camera(&camera).expect("camera");
    let (mesh_mirror, _) = render_image(
        &sphere,
        &Pose::IDENTITY,
        &view,
        &env,
        &Mirror,
        &RenderSettings { spp: 64, seed: 0 },
    );
    let mut mesh = analytic.clone();
    mesh.images[Sphere::Mirror as usize] = mesh_mirror;
    let errors = compare_spheres(&mesh, &analytic, &evaluation_region());
    println!(
        "{{\"uv_sphere_256x128_mirror_vs_analytic\": [{:.4}, {:.5}]}}",
        errors[0].angular_deg, errors[0].si_rmse
    );
}
