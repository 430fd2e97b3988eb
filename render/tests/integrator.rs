//! The forward model against what physics says it must give, and its
//! derivatives against central differences.

use autodiff::Tape;
use autodiff::gradcheck::{Input, gradcheck_sampled, gradcheck_with};
use glam::{Quat, Vec3};
use render::accel::Accel;
use render::bsdf::{Bsdf, GgxMetal, Mirror};
use render::camera::Camera;
use render::envmap::EnvMap;
use render::integrator::{PrimaryHits, ProbeVars, RenderSettings, shade};
use render::lookup::{ImageVars, TextureVars, image_texels};
use render::pose::Pose;
use render::posed::{MeshVars, PoseVars, PosedMesh, pack_pose};
use render::probe::{ProbeAsset, Texture};
use render::procedural::{SodaCan, UvSphere};
use render::sampling::ggx;

fn envmaps() -> std::path::PathBuf {
    std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../assets/envmaps")
}

/// Renders `probe` at `pose` under `env` (f64) and returns the hits and per-pixel RGB.
fn render(
    probe: &ProbeAsset,
    pose: &Pose,
    camera: &Camera,
    env: &EnvMap,
    bsdf: &dyn Bsdf<f64>,
    settings: RenderSettings,
) -> (PrimaryHits, [Vec<f64>; 3]) {
    let tape = Tape::<f64>::new();
    let vars = ProbeVars::new(&tape, probe, false);
    let pose_vars = PoseVars::new(&tape, &pack_pose(pose), false);
    let posed = PosedMesh::new(&vars.mesh, &pose_vars);
    let hits = PrimaryHits::trace(&probe.mesh, &posed.position_values(), camera, &settings);
    let env_vars = ImageVars::env(&tape, env, false);
    let rgb = shade(
        &tape,
        &hits,
        camera,
        &vars,
        &posed,
        &probe.mesh.triangles,
        &env_vars,
        bsdf,
    );
    let values = rgb.map(|c| tape.to_vec(c));
    (hits, values)
}

fn sphere_camera(size: u32) -> Camera {
    Camera::new(size, size, 26.0, Vec3::new(0.0, 0.0, 5.0), Vec3::ZERO, Vec3::Y).expect("a valid camera")
}

/// Directional albedo of single-scattering GGX with F = 1 at `cos_o`, by
/// midpoint integration of the scalar BRDF over the hemisphere.
fn ggx_directional_albedo(cos_o: f32, roughness: f32) -> f64 {
    let alpha = ggx::alpha_from_roughness(roughness);
    let wo = Vec3::new((1.0 - cos_o * cos_o).sqrt(), 0.0, cos_o);
    let (nt, np) = (400, 400);
    let mut sum = 0.0;
    for i in 0..nt {
        let ct = (i as f64 + 0.5) / nt as f64;
        let st = (1.0 - ct * ct).sqrt();
        for j in 0..np {
            let phi = (j as f64 + 0.5) / np as f64 * 2.0 * std::f64::consts::PI;
            let wi = Vec3::new((st * phi.cos()) as f32, (st * phi.sin()) as f32, ct as f32);
            sum += ggx::brdf(wo, wi, [1.0; 3], alpha)[0] as f64 * ct;
        }
    }
    sum * (1.0 / nt as f64) * (2.0 * std::f64::consts::PI / np as f64)
}

#[test]
fn white_furnace_gives_the_known_energy_loss_of_single_scattering_ggx() {
    let roughness = 0.6;
    let probe = UvSphere {
        radius: 1.0,
        segments: 96,
        rings: 48,
        albedo: [1.0; 3],
        roughness,
    }
    .build();
    let camera = sphere_camera(32);
    let env = EnvMap::constant(8, [1.0; 3]);
    let (hits, rgb) = render(
        &probe,
        &Pose::IDENTITY,
        &camera,
        &env,
        &GgxMetal,
        RenderSettings { spp: 256, seed: 3 },
    );
    // Reference per pixel: the directional albedo at each sample's exact
    // sphere normal (tabulated in cos), averaged like the render.
    let table: Vec<f64> = (0..=64)
        .map(|i| ggx_directional_albedo((i as f32 / 64.0).max(1e-3), roughness))
        .collect();
    let albedo_at = |c: f32| {
        let x = c.clamp(0.0, 1.0) * 64.0;
        let i = (x.floor() as usize).min(63);
        let f = (x - i as f32) as f64;
        table[i] * (1.0 - f) + table[i + 1] * f
    };
    assert!(table.iter().all(|&e| e < 1.0), "single scattering loses energy");
    let mut want = vec![0.0; hits.pixels.len()];
    let mut grazing = vec![false; hits.pixels.len()];
    for i in 0..hits.len() {
        let (o, d) = (camera.origin, hits.direction[i]);
        let b = o.dot(d);
        let t = -b - (b * b - o.length_squared() + 1.0).max(0.0).sqrt();
        let cos_o = (o + t * d).normalize().dot(-d);
        want[hits.segment[i] as usize] += albedo_at(cos_o) / 256.0;
        grazing[hits.segment[i] as usize] |= cos_o < 0.3;
    }
    let mut checked = 0;
    let mut mean_error = 0.0;
    for (k, &w) in want.iter().enumerate() {
        if hits.coverage[k] < 1.0 || grazing[k] {
            continue;
        }
        // 256 samples of a weight in [0, 1]: a pixel's noise is ~0.02.
        assert!(
            (rgb[0][k] - w).abs() < 0.1,
            "pixel {}: {} vs directional albedo {w}",
            hits.pixels[k],
            rgb[0][k]
        );
        mean_error += rgb[0][k] - w;
        checked += 1;
    }
    mean_error /= checked as f64;
    assert!(
        mean_error.abs() < 0.003,
        "mean deviation from the directional albedo: {mean_error}"
    );
    assert!(checked > 100, "too few interior pixels: {checked}");
}

#[test]
fn a_mirror_sphere_reflects_the_env_map_including_poles_and_seam() {
    let env = EnvMap::read(envmaps().join("courtyard.exr"))
        .expect("bundled env map")
        .downsample(64);
    let probe = UvSphere {
        radius: 1.0,
        segments: 256,
        rings: 128,
        albedo: [1.0; 3],
        roughness: 0.0,
    }
    .build();
    let camera = sphere_camera(64);
    let settings = RenderSettings { spp: 4, seed: 1 };
    let (hits, rgb) = render(&probe, &Pose::IDENTITY, &camera, &env, &Mirror, settings);
    // Reference: the same sample rays against the same mesh (its
    // interpolated normals), reflected, looked up with the scalar lookup of
    // FORMATS.md's mapping: only the direction convention can differ.
    let accel = Accel::new(&probe.mesh);
    let mut want = vec![[0.0f64; 3]; hits.pixels.len()];
    let mut pole_up = false;
    let mut seam = false;
    for i in 0..hits.len() {
        let d = hits.direction[i];
        let hit = accel
            .closest_hit(camera.origin, d, f32::INFINITY)
            .expect("the sample hit the sphere");
        let n = probe
            .mesh
            .interpolate(&probe.mesh.normals, hit.triangle as usize, hit.barycentric)
            .normalize();
        let r = d - 2.0 * d.dot(n) * n;
        pole_up |= r.y > 0.99;
        seam |= r.z < -0.9 && r.x.abs() < 0.05;
        // Near the silhouette an interpolated normal can face away from the
        // viewer: such a sample reflects nothing.
        let l = if n.dot(-d) > 0.0 { env.lookup(r) } else { [0.0; 3] };
        for c in 0..3 {
            want[hits.segment[i] as usize][c] += l[c] as f64 / settings.spp as f64;
        }
    }
    assert!(pole_up && seam, "the view must reflect the pole and the seam");
    let mut worst: f64 = 0.0;
    for (k, w) in want.iter().enumerate() {
        if hits.coverage[k] < 1.0 {
            continue;
        }
        for c in 0..3 {
            let err = (rgb[c][k] - w[c]).abs() / (w[c].abs() + 0.05);
            worst = worst.max(err);
        }
    }
    assert!(worst < 2e-3, "mirror sphere differs from the env map by up to {worst}");
}

#[test]
fn the_same_seed_gives_the_same_image_on_any_thread_count() {
    let probe = SodaCan::default().build();
    let camera = Camera::new(
        48,
        64,
        30.0,
        Vec3::new(0.0, 0.06, 0.35),
        Vec3::new(0.0, 0.06, 0.0),
        Vec3::Y,
    )
    .expect("camera");
    let env = EnvMap::read(envmaps().join("studio.exr")).expect("env").downsample(32);
    let settings = RenderSettings { spp: 4, seed: 7 };
    let run = |threads| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .expect("pool")
            .install(|| render(&probe, &Pose::IDENTITY, &camera, &env, &GgxMetal, settings).1)
    };
    assert!(run(1) == run(2), "images differ between 1 and 2 threads");
    let other = render(
        &probe,
        &Pose::IDENTITY,
        &camera,
        &env,
        &GgxMetal,
        RenderSettings { seed: 8, ..settings },
    )
    .1;
    assert!(other != run(1), "another seed must give another estimate");
}

/// An env map that is affine in texel coordinates: bilinear interpolation of
/// it has no kinks, so finite differences in direction are exact enough.
fn smooth_env(width: usize) -> EnvMap {
    let height = width / 2;
    let texels = (0..width * height)
        .map(|i| {
            let (r, c) = ((i / width) as f32, (i % width) as f32);
            [
                1.0 + 0.1 * c + 0.2 * r,
                2.0 - 0.05 * c + 0.1 * r,
                0.5 + 0.02 * c * 0.5 + 0.3 * r,
            ]
        })
        .collect();
    EnvMap::new(width, height, texels).expect("env")
}

struct GradScene {
    probe: ProbeAsset,
    camera: Camera,
    pose: Pose,
    env: EnvMap,
    hits: PrimaryHits,
}

/// A can seen from the side (away from the env map's seam), hits traced once
/// so that finite differences keep the same samples.
fn grad_scene(textured: bool) -> GradScene {
    let mut probe = SodaCan {
        segments: 24,
        ..SodaCan::default()
    }
    .build();
    if !textured {
        probe.albedo = Texture::constant([0.9, 0.7, 0.5]);
        probe.roughness = Texture::constant([0.3; 3]);
        probe.visibility = Texture::constant([0.8; 3]);
    }
    // Scaled to about a metre: finite differences step by ~1e-5 of the
    // parameters, which must be small against the scene (a 6 cm can would
    // make the O(h^2) error of the central difference dominate).
    let camera = Camera::new(
        12,
        16,
        30.0,
        Vec3::new(0.5, 0.8, 3.5),
        Vec3::new(0.0, 0.6, 0.0),
        Vec3::Y,
    )
    .expect("camera");
    let pose = Pose::new(Quat::from_rotation_y(0.3), 10.0, Vec3::new(0.0, 0.0, 0.2));
    let env = smooth_env(32);
    let tape = Tape::<f32>::new();
    let mesh = MeshVars::new(&tape, &probe.mesh);
    let posed = PosedMesh::new(&mesh, &PoseVars::new(&tape, &pack_pose(&pose), false));
    let hits = PrimaryHits::trace(
        &probe.mesh,
        &posed.position_values(),
        &camera,
        &RenderSettings { spp: 2, seed: 5 },
    );
    assert!(hits.len() > 50, "the can must cover some pixels: {}", hits.len());
    GradScene {
        probe,
        camera,
        pose,
        env,
        hits,
    }
}

impl GradScene {
    /// The rendered pixels, all three channels in one array.
    fn image<'t>(
        &self,
        t: &'t Tape<f64>,
        probe: &ProbeVars<'t, f64>,
        posed: &PosedMesh<'t, f64>,
        env: &ImageVars<'t, f64>,
    ) -> autodiff::Var<'t, f64> {
        let rgb = shade(
            t,
            &self.hits,
            &self.camera,
            probe,
            posed,
            &self.probe.mesh.triangles,
            env,
            &GgxMetal,
        );
        t.concat(&rgb)
    }
}

#[test]
fn image_gradients_in_pose_match_finite_differences() {
    let g = grad_scene(false);
    let inputs = [Input::Var(pack_pose(&g.pose).to_vec())];
    // The image is stiff in the pose (third derivatives ~1e4 at this scale):
    // a step of 1e-7 keeps the central difference's O(h^2) error below 1e-7.
    let report = gradcheck_with(&inputs, 8, 1e-7, |t, v| {
        let probe = ProbeVars::new(t, &g.probe, false);
        let posed = PosedMesh::new(&probe.mesh, &PoseVars::from_params(v[0]));
        let env = ImageVars::env(t, &g.env, false);
        g.image(t, &probe, &posed, &env)
    });
    assert!(report.worst_rel_error < 1e-6, "pose: {report}");
}

#[test]
fn image_gradients_in_env_texels_and_material_match_finite_differences() {
    let g = grad_scene(true);
    let image = |t: &Texture| Input::Var(image_texels::<f64>(&t.image));
    let inputs = [
        Input::Var(image_texels::<f64>(&g.env.to_image())),
        image(&g.probe.albedo),
        image(&g.probe.roughness),
        image(&g.probe.visibility),
    ];
    let size = |t: &Texture| (t.image.width, t.image.height);
    let report = gradcheck_sampled(&inputs, 40, |t, v| {
        let mut probe = ProbeVars::new(t, &g.probe, false);
        let texture =
            |k: usize, tex: &Texture| TextureVars::Image(ImageVars::from_texels(v[k], size(tex).0, size(tex).1));
        probe.albedo = texture(1, &g.probe.albedo);
        probe.roughness = texture(2, &g.probe.roughness);
        probe.visibility = texture(3, &g.probe.visibility);
        let posed = PosedMesh::new(&probe.mesh, &PoseVars::new(t, &pack_pose(&g.pose), false));
        let env = ImageVars::from_texels(v[0], g.env.width(), g.env.height());
        g.image(t, &probe, &posed, &env)
    });
    assert!(report.worst_rel_error < 1e-6, "env and material: {report}");
}

#[test]
fn an_empty_view_is_reported_not_rendered() {
    let probe = UvSphere::default().build();
    let camera = Camera::new(8, 8, 20.0, Vec3::new(0.0, 0.0, 5.0), Vec3::new(0.0, 0.0, 10.0), Vec3::Y).expect("camera");
    let hits = PrimaryHits::trace(&probe.mesh, &probe.mesh.positions, &camera, &RenderSettings::default());
    assert!(hits.is_empty());
}
