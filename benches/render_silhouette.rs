//! Soft silhouette cost: plan build, soft mask + mask L1 + Chamfer forward, and forward+backward
//! to the pose, f32, on 1 and 2 threads.
//!
//! A 640x480 camera sees the procedural soda can about 200 px tall; the reference is the can's
//! hard mask at a pose a few pixels away. Two meshes of the can (`probe`): the default one (6k
//! triangles) and a dense one (`dense_can`, 127k: what a scanned probe brings, whose triangles
//! are a pixel or less). One JSON line per case on stdout. Run with
//! `cargo bench --bench render_silhouette`.

use std::hint::black_box;
use std::time::Instant;

use autodiff::Tape;
use glam::{Quat, Vec3};
use render::camera::Camera;
use render::mesh::EdgeAdjacency;
use render::pose::Pose;
use render::posed::{MeshVars, PoseVars, PosedMesh, pack_pose};
use render::procedural::SodaCan;
use render::silhouette::{ReferenceMask, SilhouettePlan, SilhouetteSettings};
use serde_json::json;

/// Median and minimum of `runs` warm timings of `f` (one untimed call first), in seconds.
fn time(runs: usize, mut f: impl FnMut()) -> (f64, f64) {
    f();
    let mut t: Vec<f64> = (0..runs)
        .map(|_| {
            let start = Instant::now();
            f();
            start.elapsed().as_secs_f64()
        })
        .collect();
    t.sort_by(f64::total_cmp);
    (t[runs / 2], t[0])
}

fn main() {
    let dense = SodaCan {
        segments: 256,
        profile_step: 0.001,
        ..SodaCan::default()
    };
    for (probe, can) in [("can", SodaCan::default()), ("dense_can", dense)] {
        bench_probe(probe, &can.build().mesh);
    }
}

fn bench_probe(probe: &str, mesh: &render::mesh::Mesh) {
    // f = 240 / tan(15 deg) = 896 px: the 0.122 m can is 200 px tall at 0.546 m.
    let camera = Camera::new(
        640,
        480,
        30.0,
        Vec3::new(0.0, 0.061, 0.546),
        Vec3::new(0.0, 0.061, 0.0),
        Vec3::Y,
    )
    .expect("bench camera is valid");
    let pose = Pose::new(
        Quat::from_rotation_y(0.3) * Quat::from_rotation_x(0.15),
        1.0,
        Vec3::ZERO,
    );
    let truth = Pose::new(pose.rotation, 1.02, Vec3::new(0.004, -0.002, 0.0));
    let settings = SilhouetteSettings::default();
    let edges = EdgeAdjacency::new(mesh);
    let reference_mask = SilhouettePlan::with_edges(mesh, &edges, &mesh.posed(&truth).positions, &camera, settings)
        .expect("reference plan")
        .hard_mask();
    let reference = ReferenceMask::new(&reference_mask).expect("reference is not empty");
    let posed = mesh.posed(&pose).positions;
    let packed = pack_pose(&pose);
    let runs = 15;

    for threads in [1, 2] {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .expect("thread pool");
        pool.install(|| {
            let plan = SilhouettePlan::with_edges(mesh, &edges, &posed, &camera, settings).expect("plan");
            let check_plan = json!({"band_pixels": plan.band_pixels().len(), "pairs": plan.pair_count(),
                                    "contour_edges": plan.contour_edge_count(), "triangles": mesh.triangles.len()});
            let (median, min) = time(runs, || {
                black_box(SilhouettePlan::with_edges(mesh, &edges, &posed, &camera, settings).expect("plan"));
            });
            println!(
                "{}",
                json!({"bench": "silhouette", "impl": "tape", "probe": probe, "mode": "plan", "threads": threads,
                       "median_s": median, "min_s": min, "runs": runs, "check": check_plan})
            );

            let tape = Tape::<f32>::new();
            let params: Vec<f32> = packed.iter().map(|&v| v as f32).collect();
            let leaf = tape.leaf(&params).id();
            let mesh_vars = MeshVars::new(&tape, mesh);
            let mark = tape.mark();
            for mode in ["fwd", "fwd_bwd"] {
                let mut check = json!({});
                let (median, min) = time(runs, || {
                    tape.reset_to(mark);
                    let pose_vars = PoseVars::from_params(tape.var(leaf));
                    let soft = plan.soft_mask(&PosedMesh::new(&mesh_vars, &pose_vars));
                    let l1 = soft.mask_l1(&reference).expect("same size");
                    let chamfer = soft.chamfer(&reference).expect("same size");
                    let loss = l1 + chamfer;
                    let value = tape.item(loss) as f64;
                    check = json!({"loss": value, "l1": tape.item(l1), "chamfer": tape.item(chamfer),
                                   "band_pixels": plan.band_pixels().len(), "pairs": plan.pair_count()});
                    if mode == "fwd_bwd" {
                        tape.backward(loss);
                        let g = tape.grad(tape.var(leaf));
                        check["grad_tx"] = json!(g[4]);
                        check["grad_ty"] = json!(g[5]);
                    }
                });
                println!(
                    "{}",
                    json!({"bench": "silhouette", "impl": "tape", "probe": probe, "mode": mode, "threads": threads,
                           "median_s": median, "min_s": min, "runs": runs, "check": check})
                );
            }
        });
    }
}
