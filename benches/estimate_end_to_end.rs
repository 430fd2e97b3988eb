//! The whole estimate, pose found, as `alp estimate` runs it, on two fixed
//! scenes: the demo scene (the procedural silver can, 640x480, courtyard)
//! and a tilted thermos cap under the sunset map (`alp::synth`, seed 7,
//! 640x480, 1 % noise). Default and fast quality, 1 and 2 threads; the
//! median of the timed runs after a warm-up, each phase's share of the
//! time (its runs' wall times summed: phases that run side by side, as the
//! starts' fits and rankings do, can sum past the whole), and the errors
//! that say the timed runs computed what they should (the pose's axis and
//! rotation off the truth, the mirror sphere's relighting error). One JSON
//! object per line.
//!
//! `cargo bench --bench estimate_end_to_end [-- quick]` (quick: one timed
//! run, 2 threads)

use std::collections::BTreeMap;
use std::time::Instant;

use alp::estimate::{Photo, Quality, Settings, estimate};
use alp::eval::{pose_errors, relighting_errors};
use alp::relight::RelightSettings;
use alp::synth::{SynthSettings, synthesize};
use render::envmap::EnvMap;
use render::procedural::ThermosCap;
use serde_json::json;

mod demo;

/// A scene the bench times: its photo, the truth it is judged against.
struct Case {
    name: &'static str,
    photo: Photo,
    probe: render::probe::ProbeAsset,
    truth: render::pose::Pose,
    env: EnvMap,
}

fn cases() -> Vec<Case> {
    let d = demo::scene();
    let can = Case {
        name: "demo_can",
        photo: Photo::new(d.photo, d.mask, d.camera).expect("a valid photo"),
        probe: d.probe,
        truth: d.pose,
        env: d.env,
    };
    let assets = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("assets");
    let env = EnvMap::read(assets.join("envmaps/sunset.exr")).expect("env map");
    let cap = ThermosCap::default().build();
    let synth = SynthSettings {
        seed: 7,
        noise: 0.01,
        spp: 64,
        tilted: true,
        ..SynthSettings::default()
    };
    let scene = synthesize(&cap, &env, &synth).expect("a photo");
    let cap = Case {
        name: "tilted_cap",
        photo: Photo::new(scene.image, scene.mask, scene.camera).expect("a valid photo"),
        probe: cap,
        truth: scene.pose,
        env,
    };
    vec![can, cap]
}

fn main() {
    let quick = std::env::args().any(|a| a == "quick");
    let runs = if quick { 1 } else { 3 };
    let cases = cases();
    let bench = |n: usize| {
        for case in &cases {
            for (quality, name) in [(Quality::Default, "default"), (Quality::Fast, "fast")] {
                eprintln!("estimate_end_to_end {} {name} threads={n}", case.name);
                let settings = Settings::new(quality);
                let mut times = Vec::new();
                let mut phases: BTreeMap<String, Vec<f64>> = BTreeMap::new();
                let mut last = None;
                for run in 0..=runs {
                    let t0 = Instant::now();
                    let result = estimate(&case.photo, &case.probe, &settings).expect("an estimate");
                    if run > 0 {
                        times.push(t0.elapsed().as_secs_f64());
                        for phase in &result.report.phases {
                            phases.entry(phase.name.clone()).or_default().push(phase.wall_s);
                        }
                    }
                    last = Some(result);
                }
                let result = last.expect("a run");
                let median = |v: &mut Vec<f64>| {
                    v.sort_by(f64::total_cmp);
                    v[v.len() / 2]
                };
                let wall = median(&mut times);
                let total: f64 = times.iter().sum();
                let shares: BTreeMap<String, f64> = phases
                    .into_iter()
                    .map(|(name, v)| (name, v.iter().sum::<f64>() / total))
                    .collect();
                let pose = pose_errors(&result.pose, &case.truth);
                let mirror = relighting_errors(&result.env, &case.env, &case.photo.camera, &RelightSettings::default())
                    .expect("relit")[0]
                    .angular_deg;
                println!(
                    "{}",
                    json!({
                        "bench": "estimate_end_to_end", "scene": case.name, "quality": name, "threads": n,
                        "median_s": wall, "min_s": times[0], "runs": times.len(),
                        "phase_shares": shares,
                        "check": {"axis_deg": pose.axis_deg, "rotation_deg": pose.rotation_deg, "mirror_deg": mirror},
                    })
                );
            }
        }
    };
    match quick {
        true => rayon::ThreadPoolBuilder::new()
            .num_threads(2)
            .build()
            .expect("pool")
            .install(|| bench(2)),
        false => demo::on_1_and_2_threads(bench),
    }
}
