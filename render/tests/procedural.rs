//! Procedural probes: closed, outward-facing, UV-mapped, of the right size, with the intended materials.

use std::f64::consts::PI;

use glam::{Vec2, Vec3};
use render::mesh::{EdgeAdjacency, Mesh};
use render::probe::ProbeAsset;
use render::procedural::{SodaCan, ThermosCap, UvSphere};

/// Checks that `mesh` is closed after welding, wound outwards and has consistent normals and uvs.
fn check_closed_and_outward(name: &str, mesh: &Mesh) {
    let adjacency = EdgeAdjacency::new(mesh);
    assert_eq!(adjacency.boundary_edges().count(), 0, "{name}: open edges");
    assert!(
        adjacency.edges.iter().all(|e| e.triangles.len() == 2),
        "{name}: non-manifold edges"
    );
    assert!(mesh.signed_volume() > 0.0, "{name}: inward winding");
    for t in 0..mesh.triangles.len() {
        let face = mesh.face_normal(t);
        assert!(face.length() > 0.0, "{name}: degenerate triangle {t}");
        for &i in &mesh.triangles[t] {
            let n = mesh.normals[i as usize];
            assert!((n.length() - 1.0).abs() < 1e-4, "{name}: normal {i} not unit");
            assert!(
                n.dot(face.normalize()) > 0.0,
                "{name}: vertex normal {i} points against triangle {t}"
            );
        }
    }
    assert!(
        mesh.uvs
            .iter()
            .all(|uv| (0.0..=1.0).contains(&uv.x) && (0.0..=1.0).contains(&uv.y)),
        "{name}: uv outside [0, 1]"
    );
}

fn bounds(mesh: &Mesh) -> (Vec3, Vec3) {
    let min = mesh.positions.iter().fold(Vec3::splat(f32::MAX), |a, &p| a.min(p));
    let max = mesh.positions.iter().fold(Vec3::splat(f32::MIN), |a, &p| a.max(p));
    (min, max)
}

#[test]
fn soda_can_shape() {
    let can = SodaCan::default().build();
    check_closed_and_outward("soda can", &can.mesh);
    let triangles = can.mesh.triangles.len();
    assert!((2_000..8_000).contains(&triangles), "{triangles} triangles");
    let (min, max) = bounds(&can.mesh);
    assert!(
        (min.y - 0.0).abs() < 1e-6 && (max.y - 0.122).abs() < 1e-6,
        "height {min} {max}"
    );
    assert!(
        (max.x - 0.033).abs() < 1e-4 && (min.z + 0.033).abs() < 1e-4,
        "diameter {min} {max}"
    );
    // About 355 ml of can (the dome and neck take some of the 417 ml cylinder).
    let ml = can.mesh.signed_volume() * 1e6;
    assert!((340.0..417.0).contains(&ml), "volume {ml} ml");
    // The bottom is concave: its centre is above the standing ring, facing down.
    let centre = can
        .mesh
        .positions
        .iter()
        .position(|p| p.x == 0.0 && p.z == 0.0 && p.y < 0.05)
        .unwrap();
    assert!(can.mesh.positions[centre].y > 0.005);
    assert!(can.mesh.normals[centre].y < -0.99);
}

#[test]
fn soda_can_label_and_bare_metal() {
    let can = SodaCan::default().build();
    let profile = SodaCan::default().profile();
    // v along the profile at half the body height, 61 mm up: painted, rough.
    let v_of_height = |y: f32| profile.v[profile.points.iter().position(|p| p.x >= 0.0329 && p.y >= y).unwrap()];
    let label = can.material(Vec2::new(0.7, v_of_height(0.03)));
    assert_eq!(label.roughness, 0.35);
    assert!(
        label.albedo[0] > 0.5 && label.albedo[1] < 0.2,
        "red paint {:?}",
        label.albedo
    );
    // The bare-metal window at u = 0.25, 45 mm up.
    let window = can.material(Vec2::new(0.25, v_of_height(0.045)));
    assert!((window.roughness - 0.2).abs() < 1e-6 && window.albedo[1] > 0.9);
    // The lid (end of the profile) is bare aluminium.
    let lid = can.material(Vec2::new(0.5, 0.99));
    assert!((lid.roughness - 0.2).abs() < 1e-6 && lid.albedo.iter().all(|&a| a > 0.9));
    assert_eq!(lid.visibility, 1.0);
}

#[test]
fn thermos_cap_recess_is_rougher() {
    let cap = ThermosCap::default().build();
    check_closed_and_outward("thermos cap", &cap.mesh);
    let (min, max) = bounds(&cap.mesh);
    assert!((min.y).abs() < 1e-6 && (max.y - 0.05).abs() < 1e-6 && (max.x - 0.036).abs() < 1e-4);
    // Near the end of the profile: the recess floor; near the start: the base.
    let floor = cap.material(Vec2::new(0.3, 0.98));
    let base = cap.material(Vec2::new(0.3, 0.02));
    // The renderer traces the recess's shadows: no darkening stands in for them.
    assert_eq!((floor.visibility, base.visibility), (1.0, 1.0));
    assert!(floor.roughness > base.roughness);
}

#[test]
fn uv_sphere_is_a_sphere() {
    let sphere = UvSphere {
        radius: 0.5,
        ..UvSphere::default()
    }
    .build();
    check_closed_and_outward("uv sphere", &sphere.mesh);
    let volume = sphere.mesh.signed_volume();
    let exact = 4.0 / 3.0 * PI * 0.125;
    assert!((volume / exact - 1.0).abs() < 0.02, "volume {volume} vs {exact}");
    assert!(sphere.mesh.positions.iter().all(|p| (p.length() - 0.5).abs() < 1e-6));
    let m = sphere.material(Vec2::new(0.1, 0.9));
    assert_eq!((m.albedo, m.roughness, m.visibility), ([1.0; 3], 0.316, 1.0));
}

#[test]
fn silhouette_of_a_sphere_is_one_loop_around_the_view_axis() {
    let sphere = UvSphere::default().build();
    let adjacency = EdgeAdjacency::new(&sphere.mesh);
    let eye = Vec3::new(0.0, 0.0, 10.0);
    let silhouette: Vec<_> = adjacency.silhouette_edges(&sphere.mesh, eye).collect();
    assert!(silhouette.len() >= 32, "{} silhouette edges", silhouette.len());
    // Every silhouette vertex is near the great circle orthogonal to the view, and a closed loop
    // uses each of its vertices twice.
    let mut uses = std::collections::HashMap::new();
    for e in &silhouette {
        for &v in &e.vertices {
            assert!(sphere.mesh.positions[v as usize].z.abs() < 0.2);
            *uses.entry(v).or_insert(0) += 1;
        }
    }
    assert!(uses.values().all(|&u| u == 2), "silhouette is not a simple loop");
}

#[test]
fn probes_write_to_folders() {
    let dir = std::env::temp_dir().join(format!("render-procedural-{}", std::process::id()));
    let sphere = UvSphere::default().build();
    sphere.write(&dir).unwrap();
    let json = std::fs::read_to_string(dir.join("probe.json")).unwrap();
    assert!(json.contains("\"roughness\": 0.316"), "{json}");
    assert_eq!(
        ProbeAsset::read(&dir).unwrap().mesh.triangles.len(),
        sphere.mesh.triangles.len()
    );
}
