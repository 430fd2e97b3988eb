//! One iteration of lighting estimation as the renderer sees it: trace the
//! probe's primary hits, shade them, an L1 loss against a photo, and the
//! gradients w.r.t. a 128x64 env map and the pose. The procedural can about
//! 190 px tall in a 640x480 camera; 1, 4, 8 and 16 spp; 1 and 2 threads.
//! One JSON object per line.
//!
//! `cargo bench --bench render_iteration`

use std::time::{Duration, Instant};

use autodiff::Tape;
use render::bsdf::GgxMetal;
use render::envmap::EnvMap;
use render::integrator::{PrimaryHits, ProbeScene, ProbeVars, RenderSettings};
use render::lookup::ImageVars;
use render::posed::{PoseVars, PosedMesh, pack_pose};
use serde_json::json;

mod demo;

fn main() {
    let demo::Demo {
        probe,
        camera,
        pose,
        env: truth,
        photo,
        ..
    } = demo::scene();
    let env = truth.downsample(64);
    let start_env = EnvMap::constant(64, [0.5; 3]);
    demo::on_1_and_2_threads(|threads| {
        for spp in [1, 4, 8, 16] {
            eprintln!("render_iteration spp={spp} threads={threads}");
            let tape = Tape::<f32>::new();
            let probe_vars = ProbeVars::new(&tape, &probe, false);
            let env_vars = ImageVars::env(&tape, &start_env, true);
            let pose_vars = PoseVars::new(&tape, &pack_pose(&pose), true);
            let (env_id, pose_id) = (env_vars.texels.id(), pose_vars.params.id());
            let mark = tape.mark();
            let settings = RenderSettings { spp, seed: 1 };
            let mut times = Vec::new();
            let mut trace_times = Vec::new();
            let (mut loss, mut samples, mut pixels, mut rays) = (0.0, 0, 0, 0);
            let began = Instant::now();
            while times.len() < 6 || (times.len() < 30 && began.elapsed() < Duration::from_secs(2)) {
                let t0 = Instant::now();
                tape.reset_to(mark);
                let pose_vars = PoseVars::from_params(tape.var(pose_id));
                let env_vars = ImageVars::from_texels(tape.var(env_id), env.width(), env.height());
                let posed = PosedMesh::new(&probe_vars.mesh, &pose_vars);
                let hits = PrimaryHits::trace(&probe.mesh, &posed.position_values(), &camera, &settings);
                let t_trace = t0.elapsed().as_secs_f64();
                let rgb = ProbeScene {
                    tape: &tape,
                    hits: &hits,
                    camera: &camera,
                    probe: &probe_vars,
                    posed: &posed,
                    triangles: &probe.mesh.triangles,
                    bsdf: &GgxMetal,
                }
                .shade(&env_vars);
                let mut l1 = None;
                for (c, channel) in rgb.iter().enumerate() {
                    let target: Vec<f32> = hits.pixels.iter().map(|&p| photo.pixels[p as usize][c]).collect();
                    let term = (*channel - tape.constant(&target)).abs().sum();
                    l1 = Some(l1.map_or(term, |acc| acc + term));
                }
                let l1 = l1.expect("three channels") / (3 * hits.pixels.len()) as f32;
                tape.backward(l1);
                let g = tape.grad(tape.var(env_id))[0] + tape.grad(tape.var(pose_id))[0];
                assert!(g.is_finite());
                loss = tape.item(l1) as f64;
                (samples, pixels, rays) = (hits.len(), hits.pixels.len(), hits.rays);
                times.push(t0.elapsed().as_secs_f64());
                trace_times.push(t_trace);
            }
            let warm = &mut times[1..];
            warm.sort_by(f64::total_cmp);
            trace_times.sort_by(f64::total_cmp);
            let median = warm[warm.len() / 2];
            let trace = trace_times[trace_times.len() / 2];
            println!(
                "{}",
                json!({
                    "bench": "render_iteration", "impl": "tape", "mode": "fwd_bwd", "spp": spp, "threads": threads,
                    "median_s": median, "min_s": warm[0], "runs": warm.len(),
                    "check": {
                        "loss": loss, "samples": samples, "pixels": pixels, "rays": rays,
                        "samples_per_s": samples as f64 / median, "trace_s": trace,
                        "rays_per_s": rays as f64 / trace,
                    }
                })
            );
        }
    });
}
