//! The BVH against brute force, and the primary-visibility pass against single rays and the camera.

use glam::{Quat, Vec2, Vec3};
use render::accel::{Accel, primary_visibility};
use render::camera::Camera;
use render::mesh::Mesh;
use render::pose::Pose;
use render::procedural::SodaCan;
use render::sampling::{Rng, sample_uniform_sphere};

/// A posed soda can: rotated, scaled by 2 and moved off the origin.
fn posed_can() -> Mesh {
    let pose = Pose::new(
        Quat::from_axis_angle(Vec3::new(1.0, 0.5, 0.2).normalize(), 0.6),
        2.0,
        Vec3::new(0.1, -0.05, 0.2),
    );
    SodaCan::default().build().mesh.posed(&pose)
}

/// Moeller-Trumbore in f64 over every triangle: (triangle, t) of the closest hit.
fn brute_force(mesh: &Mesh, origin: Vec3, direction: Vec3) -> Option<(usize, f64)> {
    let (o, d) = (origin.as_dvec3(), direction.as_dvec3());
    let mut best: Option<(usize, f64)> = None;
    for t in 0..mesh.triangles.len() {
        let [p0, p1, p2] = mesh.corners(t).map(|p| p.as_dvec3());
        let (e1, e2) = (p1 - p0, p2 - p0);
        let pv = d.cross(e2);
        let det = e1.dot(pv);
        if det.abs() < 1e-18 {
            continue;
        }
        let tv = o - p0;
        let u = tv.dot(pv) / det;
        let qv = tv.cross(e1);
        let v = d.dot(qv) / det;
        let dist = e2.dot(qv) / det;
        if u >= 0.0 && v >= 0.0 && u + v <= 1.0 && dist >= 0.0 && best.is_none_or(|(_, b)| dist < b) {
            best = Some((t, dist));
        }
    }
    best
}

#[test]
fn closest_hit_matches_brute_force() {
    let mesh = posed_can();
    let accel = Accel::new(&mesh);
    let centre = mesh.positions.iter().fold(Vec3::ZERO, |a, &p| a + p) / mesh.positions.len() as f32;
    let mut rng = Rng::new(11, 0);
    let (mut hits, mut edge_cases) = (0, 0);
    for _ in 0..3000 {
        // Rays from a sphere around the can towards random points near its centre.
        let origin = centre + 0.4 * sample_uniform_sphere(rng.next_2d());
        let target = centre + 0.12 * (rng.next_2d().extend(rng.next_f32()) - 0.5);
        let direction = (target - origin).normalize();
        let expected = brute_force(&mesh, origin, direction);
        let got = accel.closest_hit(origin, direction, f32::INFINITY);
        match (expected, got) {
            (Some((triangle, t)), Some(hit)) => {
                hits += 1;
                assert!((hit.t as f64 - t).abs() < 1e-5, "t {} vs {t}", hit.t);
                if hit.triangle as usize != triangle {
                    // Only on a shared edge, where both triangles are at the same t.
                    edge_cases += 1;
                }
                // The barycentrics rebuild the hit point.
                let p = mesh.interpolate(&mesh.positions, hit.triangle as usize, hit.barycentric);
                let expected_p = origin.as_dvec3() + t * direction.as_dvec3();
                assert!(p.as_dvec3().distance(expected_p) < 1e-5, "{p} vs {expected_p}");
                assert!(hit.barycentric.min_element() >= -1e-4 && hit.barycentric.element_sum() <= 1.0 + 1e-4);
                // Occlusion agrees on both sides of the hit.
                assert!(accel.occluded(origin, direction, 0.0, hit.t * 1.001));
                assert!(!accel.occluded(origin, direction, 0.0, hit.t * 0.999));
            }
            (None, None) => assert!(!accel.occluded(origin, direction, 0.0, f32::INFINITY)),
            (e, g) => {
                // A ray grazing an edge may be caught by one test and missed by the other.
                edge_cases += 1;
                assert!(edge_cases < 10, "brute force {e:?}, BVH {g:?}");
            }
        }
    }
    assert!(hits > 1500, "only {hits} hits");
    assert!(edge_cases < 10, "{edge_cases} disagreements");
}

fn camera() -> Camera {
    Camera::new(
        64,
        48,
        30.0,
        Vec3::new(0.05, 0.15, 0.35),
        Vec3::new(0.0, 0.06, 0.0),
        Vec3::Y,
    )
    .unwrap()
}

#[test]
fn primary_visibility_is_deterministic_whatever_the_thread_count() {
    let mesh = SodaCan::default().build().mesh;
    let accel = Accel::new(&mesh);
    let camera = camera();
    let run = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
        pool.install(|| primary_visibility(&accel, &camera, 4, 99))
    };
    let (one, two) = (run(1), run(2));
    assert!(one == two, "results differ between 1 and 2 threads");
    assert_ne!(primary_visibility(&accel, &camera, 4, 100)[0].offset, one[0].offset);
}

#[test]
fn primary_samples_are_stratified_and_agree_with_single_rays() {
    let mesh = SodaCan::default().build().mesh;
    let accel = Accel::new(&mesh);
    let camera = camera();
    let n = 5;
    let samples = primary_visibility(&accel, &camera, n, 7);
    assert_eq!(samples.len(), camera.pixel_count() * n as usize);
    let mut covered = 0;
    for (p, pixel_samples) in samples.chunks(n as usize).enumerate() {
        // n-rooks: one sample in each of the n columns and each of the n rows of the pixel.
        let mut strips_x = vec![0; n as usize];
        let mut strips_y = vec![0; n as usize];
        for s in pixel_samples {
            assert_eq!(s.pixel as usize, p);
            strips_x[(s.offset.x * n as f32) as usize] += 1;
            strips_y[(s.offset.y * n as f32) as usize] += 1;
        }
        assert!(
            strips_x.iter().chain(&strips_y).all(|&c| c == 1),
            "pixel {p}: {strips_x:?} {strips_y:?}"
        );
        let (row, col) = (p as u32 / camera.width, p as u32 % camera.width);
        for s in pixel_samples {
            let (origin, direction) = camera.primary_ray(row, col, s.offset);
            assert_eq!(s.hit, accel.closest_hit(origin, direction, f32::INFINITY));
            if let Some(hit) = s.hit {
                covered += 1;
                // The hit point projects back onto the sample's position in the image.
                let point = mesh.interpolate(&mesh.positions, hit.triangle as usize, hit.barycentric);
                let projected = camera.project(point).unwrap();
                assert!(projected.distance(Vec2::new(col as f32, row as f32) + s.offset) < 1e-2);
            }
        }
    }
    // The can fills a good part of this view, not all of it.
    let fraction = covered as f64 / samples.len() as f64;
    assert!(fraction > 0.1 && fraction < 0.9, "coverage {fraction}");
}

#[test]
fn brute_force_reference_sanity() {
    // A ray straight down onto a unit triangle in the XZ plane at y = 0.
    let mesh = Mesh::new(
        vec![Vec3::ZERO, Vec3::Z, Vec3::X],
        vec![Vec3::Y; 3],
        vec![Vec2::ZERO; 3],
        vec![[0, 1, 2]],
    );
    let hit = brute_force(&mesh, Vec3::new(0.2, 1.0, 0.3), -Vec3::Y).unwrap();
    assert_eq!(hit.0, 0);
    assert!((hit.1 - 1.0).abs() < 1e-12);
    let bvh_hit = Accel::new(&mesh)
        .closest_hit(Vec3::new(0.2, 1.0, 0.3), -Vec3::Y, f32::INFINITY)
        .unwrap();
    // Corner 1 is +Z, corner 2 is +X: weights (0.3, 0.2).
    assert!(
        bvh_hit.barycentric.abs_diff_eq(Vec2::new(0.3, 0.2), 1e-6),
        "{}",
        bvh_hit.barycentric
    );
}
