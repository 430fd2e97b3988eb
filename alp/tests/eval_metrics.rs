//! The relighting metrics on literal values, and the relit spheres of a constant env map.

use glam::Vec3;

use alp::eval::{angular_error_deg, compare_spheres, rgb_angle_deg, si_rmse};
use alp::relight::{RelightSettings, Sphere, evaluation_region, relight};
use render::camera::Camera;
use render::envmap::EnvMap;

const EST: [[f32; 3]; 3] = [[0.2, 0.4, 0.1], [1.0, 0.0, 0.5], [3.0, 2.0, 1.0]];

#[test]
fn identical_images_score_zero() {
    assert_eq!(angular_error_deg(&EST, &EST), 0.0);
    assert_eq!(si_rmse(&EST, &EST), 0.0);
}

#[test]
fn a_scaled_image_scores_zero() {
    let doubled = EST.map(|p| p.map(|v| 2.0 * v));
    assert!(angular_error_deg(&doubled, &EST) < 1e-12);
    assert!(si_rmse(&doubled, &EST) < 1e-7);
}

#[test]
fn hand_computed_case() {
    let est = [[1.0, 0.0, 0.0], [1.0, 1.0, 0.0]];
    let gt = [[1.0, 0.0, 0.0], [1.0, 0.0, 0.0]];
    // Angles 0 and 45 degrees.
    assert!((angular_error_deg(&est, &gt) - 22.5).abs() < 1e-12);
    // s = est.gt / est.est = 2 / 3; residual = 1/9 + 1/9 + 4/9 = 2/3; gt.gt = 2: sqrt(1/3).
    assert!((si_rmse(&est, &gt) - (1.0f64 / 3.0).sqrt()).abs() < 1e-7);
}

#[test]
fn zero_vectors() {
    assert_eq!(rgb_angle_deg([0.0; 3], [0.0; 3]), 0.0);
    assert_eq!(
        angular_error_deg(&[[0.0; 3], [1.0, 1.0, 1.0]], &[[1.0, 1.0, 1.0]; 2]),
        45.0
    );
    // A black estimate: the best scale is 0 and the error is the truth's whole RMS.
    assert_eq!(si_rmse(&[[0.0; 3]; 2], &EST[..2]), 1.0);
    assert_eq!(si_rmse(&EST[..2], &[[0.0; 3]; 2]), 0.0);
}

#[test]
fn a_constant_map_relights_uniform_spheres() {
    let radiance = [0.5, 1.0, 2.0];
    let env = EnvMap::constant(8, radiance);
    let camera = Camera::new(64, 48, 40.0, Vec3::new(0.4, 0.3, 1.0), Vec3::ZERO, Vec3::Y).expect("camera");
    let spheres = relight(&env, &camera, &RelightSettings { spp: 16, seed: 3 }).expect("relight");
    assert_eq!(
        (spheres.side_by_side().width, spheres.side_by_side().height),
        (768, 256)
    );
    let region = evaluation_region();
    let inside = |sphere: Sphere| -> Vec<[f32; 3]> {
        let image = spheres.image(sphere);
        image
            .pixels
            .iter()
            .zip(&region.inside)
            .filter(|(_, m)| **m)
            .map(|(p, _)| *p)
            .collect()
    };
    // Mirror: reflectance 1. Diffuse: albedo 0.8 times pi L / pi (the quadrature is within 1e-3).
    for (sphere, scale, tolerance) in [(Sphere::Mirror, 1.0, 1e-6), (Sphere::Diffuse, 0.8, 2e-3)] {
        for p in inside(sphere) {
            for c in 0..3 {
                let expected = scale * radiance[c];
                assert!((p[c] - expected).abs() <= tolerance * expected, "{sphere:?}: {p:?}");
            }
        }
    }
    // Shiny: GGX loses a little energy (single scattering), most at grazing angles; 16 spp are noisy.
    let shiny = inside(Sphere::Shiny);
    let centre = spheres.image(Sphere::Shiny).get(128, 128);
    assert!((centre[1] - 1.0).abs() < 0.05, "{centre:?}");
    for p in &shiny {
        assert!(p[1] > 0.6 && p[1] < 1.15, "{p:?}");
        assert!(rgb_angle_deg(*p, radiance) < 1e-3, "{p:?}");
    }
    let errors = compare_spheres(&spheres, &spheres, &region);
    for e in errors {
        assert_eq!((e.angular_deg, e.si_rmse), (0.0, 0.0));
    }
}

#[test]
fn a_brighter_copy_of_a_map_scores_zero() {
    let radiance: Vec<[f32; 3]> = (0..16 * 32)
        .map(|i| [(i % 7) as f32 + 0.1, (i % 5) as f32 + 0.2, (i % 3) as f32 + 0.3])
        .collect();
    let env = EnvMap::new(32, 16, radiance.clone()).expect("env");
    let brighter = EnvMap::new(32, 16, radiance.iter().map(|p| p.map(|v| 2.0 * v)).collect()).expect("env");
    let camera = Camera::new(64, 48, 40.0, Vec3::new(0.0, 0.3, 1.0), Vec3::ZERO, Vec3::Y).expect("camera");
    let settings = RelightSettings { spp: 16, seed: 0 };
    let errors = alp::eval::relighting_errors(&brighter, &env, &camera, &settings).expect("relight");
    for e in errors {
        assert!(e.angular_deg < 1e-3 && e.si_rmse < 1e-5, "{e:?}");
    }
    // And a different map does not.
    let other = EnvMap::new(32, 16, radiance.iter().map(|p| [p[2], p[0], p[1]]).collect()).expect("env");
    let errors = alp::eval::relighting_errors(&other, &env, &camera, &settings).expect("relight");
    for e in errors {
        assert!(e.angular_deg > 1.0 && e.si_rmse > 0.01, "{e:?}");
    }
}

#[test]
fn the_mirror_splits_where_the_probe_saw_the_map() {
    // The estimate is the truth above the horizon and wrong below; the probe "saw" the upper
    // half. The seen part scores 0, the unseen part the whole error, and the shares add to the
    // mirror's region (the pixels off the sphere's centre rays aside).
    let truth: Vec<[f32; 3]> = (0..16 * 32).map(|i| [1.0, 0.5 + (i % 3) as f32 * 0.1, 0.3]).collect();
    let estimate: Vec<[f32; 3]> = truth
        .iter()
        .enumerate()
        .map(|(i, &t)| if i < 8 * 32 { t } else { [t[2], t[0], t[1]] })
        .collect();
    let upper = EnvMap::new(
        32,
        16,
        (0..16 * 32).map(|i| [if i < 8 * 32 { 1.0 } else { 0.0 }; 3]).collect(),
    )
    .unwrap();
    let (truth, estimate) = (
        EnvMap::new(32, 16, truth).unwrap(),
        EnvMap::new(32, 16, estimate).unwrap(),
    );
    let camera = Camera::new(64, 48, 40.0, Vec3::new(0.0, 0.3, 1.0), Vec3::ZERO, Vec3::Y).expect("camera");
    let settings = RelightSettings { spp: 4, seed: 0 };
    let (est, gt) = (
        relight(&estimate, &camera, &settings).unwrap(),
        relight(&truth, &camera, &settings).unwrap(),
    );
    let directions = alp::relight::mirror_directions(&camera).unwrap();
    // Within half a texel of the horizon the lookups blend both halves: the seen part's error
    // is small, not 0.
    let [seen, unseen] = alp::eval::seen_and_unseen(&est, &gt, &directions, &upper);
    assert!(seen.angular_deg < 0.1 * unseen.angular_deg, "{seen:?} vs {unseen:?}");
    assert!((seen.share + unseen.share - 1.0).abs() < 1e-9 && seen.share > 0.2 && unseen.share > 0.2);
    let all_seen = EnvMap::constant(16, [1.0; 3]);
    let [seen, unseen] = alp::eval::seen_and_unseen(&est, &gt, &directions, &all_seen);
    assert_eq!((seen.share, unseen.share), (1.0, 0.0));
}
