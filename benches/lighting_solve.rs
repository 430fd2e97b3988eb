//! The output map's lighting phases at a known pose, as `alp estimate --pose`
//! runs them: the pilot map (BRDF samples, the sparse transport at each
//! level of the coarse-to-fine pyramid, bounded L-BFGS solves), then the
//! final transport by MIS and its solve from the pilot map. The procedural
//! can of the demo scene (640x480, courtyard) at 32 and 128 spp (per
//! strategy) of the final solve; 1 and 2 threads. One JSON object per line.
//!
//! `cargo bench --bench lighting_solve`

use std::time::Instant;

use alp::estimate::{Photo, Quality, Settings, estimate};
use serde_json::json;

/// Timed runs per case (after one warm-up run).
const RUNS: usize = 3;

mod demo;

fn main() {
    let demo::Demo {
        probe,
        camera,
        pose,
        photo,
        mask,
        ..
    } = demo::scene();
    let photo = Photo::new(photo, mask, camera).expect("a valid photo");
    demo::on_1_and_2_threads(|threads| {
        for spp in [32, 128] {
            eprintln!("lighting_solve spp={spp} threads={threads}");
            let mut settings = Settings::new(Quality::Default);
            settings.lighting.spp_final = spp;
            settings.known_pose = Some(pose);
            let mut times = Vec::new();
            let mut last = None;
            for _ in 0..=RUNS {
                let t0 = Instant::now();
                let result = estimate(&photo, &probe, &settings).expect("an estimate");
                times.push(t0.elapsed().as_secs_f64());
                last = Some(result.report);
            }
            let report = last.expect("at least one run");
            let warm = &mut times[1..];
            warm.sort_by(f64::total_cmp);
            let phase = report.phases.last().expect("the final solve's phase");
            println!(
                "{}",
                json!({
                    "bench": "lighting_solve", "impl": "transport_lbfgs", "mode": "known_pose",
                    "spp": report.final_spp, "threads": threads,
                    "median_s": warm[warm.len() / 2], "min_s": warm[0], "runs": warm.len(),
                    "check": {
                        "psnr_db": report.psnr_db, "evaluations": phase.evaluations,
                        "working_resolution": report.working_resolution,
                        "pixels": photo.mask.count(),
                    }
                })
            );
        }
    });
}
