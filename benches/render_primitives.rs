//! Throughput of the non-differentiated primitives: BVH build, primary visibility, samplers.
//!
//! One JSON line per measurement on stdout. Run with
//! `cargo bench --bench render_primitives`.

use std::hint::black_box;
use std::time::Instant;

use glam::Vec3;
use render::accel::{Accel, primary_visibility};
use render::camera::Camera;
use render::envmap::EnvMap;
use render::procedural::SodaCan;
use render::sampling::{EnvSampler, Rng, ggx};
use serde_json::json;

/// Best of `runs` timings of `f`, in seconds.
fn best_seconds(runs: usize, mut f: impl FnMut()) -> f64 {
    (0..runs)
        .map(|_| {
            let start = Instant::now();
            f();
            start.elapsed().as_secs_f64()
        })
        .fold(f64::INFINITY, f64::min)
}

fn main() {
    let threads = rayon::current_num_threads();
    for segments in [64u32, 256] {
        let can = SodaCan {
            segments,
            profile_step: 0.005 * 64.0 / segments as f32,
            ..SodaCan::default()
        };
        let mesh = can.build().mesh;
        let build = best_seconds(5, || {
            black_box(Accel::new(&mesh));
        });
        let accel = Accel::new(&mesh);
        let camera = Camera::new(
            640,
            480,
            30.0,
            Vec3::new(0.0, 0.08, 0.35),
            Vec3::new(0.0, 0.06, 0.0),
            Vec3::Y,
        )
        .expect("bench camera is valid");
        let spp = 4;
        let trace = best_seconds(3, || {
            black_box(primary_visibility(&accel, &camera, spp, 1));
        });
        let rays = camera.pixel_count() as f64 * spp as f64;
        println!(
            "{}",
            json!({"bench": "accel", "triangles": mesh.triangles.len(), "build_ms": build * 1e3,
                   "primary_mrays_per_s": rays / trace / 1e6, "threads": threads})
        );
    }

    let env_path = concat!(env!("CARGO_MANIFEST_DIR"), "/../assets/envmaps/courtyard.exr");
    let env = EnvMap::read(env_path).expect("courtyard.exr");
    let build = best_seconds(3, || {
        black_box(EnvSampler::new(&env));
    });
    let sampler = EnvSampler::new(&env);
    let n = 1_000_000;
    let sample = best_seconds(3, || {
        let mut rng = Rng::new(1, 0);
        for _ in 0..n {
            black_box(sampler.sample(rng.next_2d()));
        }
    });
    println!(
        "{}",
        json!({"bench": "env_sampler", "texels": env.width() * env.height(), "build_ms": build * 1e3,
               "msamples_per_s": n as f64 / sample / 1e6})
    );

    let wo = Vec3::new(0.5, 0.1, 0.8).normalize();
    let ggx_time = best_seconds(3, || {
        let mut rng = Rng::new(2, 0);
        for _ in 0..n {
            black_box(ggx::sample_reflection(wo, 0.1, rng.next_2d()));
        }
    });
    println!(
        "{}",
        json!({"bench": "ggx_vndf", "msamples_per_s": n as f64 / ggx_time / 1e6})
    );
}
