//! The forward model against what physics says it must give, and its
//! derivatives against central differences.

use autodiff::Tape;
use autodiff::gradcheck::{Input, gradcheck_sampled, gradcheck_with};
use glam::{Quat, Vec3};
use render::accel::Accel;
use render::bsdf::{Bsdf, GgxMetal, Lambertian, Mirror};
use render::camera::Camera;
use render::envmap::EnvMap;
use render::integrator::{
    LightSamples, LightSampling, PrimaryHits, ProbeScene, ProbeVars, RenderSettings, coverage_mask, render_image,
};
use render::lookup::{ImageVars, TextureVars, image_texels};
use render::mesh::Mesh;
use render::pose::Pose;
use render::posed::{MeshVars, PoseVars, PosedMesh, pack_pose};
use render::probe::{ProbeAsset, Texture};
use render::procedural::{SodaCan, UvSphere};
use render::sampling::{EnvSampler, ggx};

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
    sampling: &LightSampling,
) -> (PrimaryHits, [Vec<f64>; 3]) {
    render_pixels(probe, pose, camera, env, bsdf, settings, sampling, |_| true)
}

/// [`render`] of the pixels `keep` accepts (row-major indices) only.
#[allow(clippy::too_many_arguments)]
fn render_pixels(
    probe: &ProbeAsset,
    pose: &Pose,
    camera: &Camera,
    env: &EnvMap,
    bsdf: &dyn Bsdf<f64>,
    settings: RenderSettings,
    sampling: &LightSampling,
    keep: impl Fn(u32) -> bool,
) -> (PrimaryHits, [Vec<f64>; 3]) {
    let tape = Tape::<f64>::new();
    let vars = ProbeVars::new(&tape, probe, false);
    let pose_vars = PoseVars::new(&tape, &pack_pose(pose), false);
    let posed = PosedMesh::new(&vars.mesh, &pose_vars);
    let mut hits = PrimaryHits::trace(&probe.mesh, &posed.position_values(), camera, &settings);
    hits.retain_pixels(keep);
    let env_vars = ImageVars::env(&tape, env, false);
    let rgb = ProbeScene {
        tape: &tape,
        hits: &hits,
        camera,
        probe: &vars,
        posed: &posed,
        triangles: &probe.mesh.triangles,
        bsdf,
    }
    .light_samples(sampling)
    .radiance(&env_vars);
    let values = rgb.map(|c| tape.to_vec(c));
    (hits, values)
}

/// [`render`] of a mirror at its mesh's frame, BRDF-sampled.
fn render_mirror(
    probe: &ProbeAsset,
    camera: &Camera,
    env: &EnvMap,
    settings: RenderSettings,
    sampling: &LightSampling,
) -> (PrimaryHits, [Vec<f64>; 3]) {
    render(probe, &Pose::IDENTITY, camera, env, &Mirror, settings, sampling)
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
    white_furnace(&LightSampling::BSDF);
}

#[test]
fn white_furnace_holds_with_mis() {
    white_furnace(&LightSampling::mis(&EnvSampler::new(&EnvMap::constant(8, [1.0; 3]))));
}

/// A rough white metal sphere in a white environment reflects the GGX
/// directional albedo (below 1: single scattering loses energy).
fn white_furnace(sampling: &LightSampling) {
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
        sampling,
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
    let (hits, rgb) = render_mirror(&probe, &camera, &env, settings, &LightSampling::BSDF);
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

/// The can seen from 35 cm, 48 x 64 pixels, `fov_y_deg` (30: all of it).
fn can_camera(fov_y_deg: f32) -> Camera {
    Camera::new(
        48,
        64,
        fov_y_deg,
        Vec3::new(0.0, 0.06, 0.35),
        Vec3::new(0.0, 0.06, 0.0),
        Vec3::Y,
    )
    .expect("camera")
}

fn studio() -> EnvMap {
    EnvMap::read(envmaps().join("studio.exr")).expect("env")
}

#[test]
fn the_same_seed_gives_the_same_image_on_any_thread_count() {
    let probe = SodaCan::default().build();
    let camera = can_camera(30.0);
    let env = studio().downsample(32);
    let sampler = EnvSampler::new(&env);
    let settings = RenderSettings { spp: 4, seed: 7 };
    for sampling in [LightSampling::BSDF, LightSampling::mis(&sampler)] {
        let image = |settings| render(&probe, &Pose::IDENTITY, &camera, &env, &GgxMetal, settings, &sampling).1;
        let run = |threads| {
            rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .expect("pool")
                .install(|| image(settings))
        };
        assert!(run(1) == run(2), "{sampling:?}: images differ between 1 and 2 threads");
        let other = image(RenderSettings { seed: 8, ..settings });
        assert!(other != run(1), "{sampling:?}: another seed must give another estimate");
    }
}

#[test]
fn the_coverage_mask_is_the_render_s_mask_without_the_shading() {
    let probe = SodaCan::default().build();
    let camera = can_camera(30.0);
    let pose = Pose::new(Quat::from_rotation_z(0.4), 1.0, Vec3::new(0.004, 0.0, 0.0));
    let settings = RenderSettings { spp: 4, seed: 3 };
    let mask = coverage_mask(&probe, &pose, &camera, &settings);
    let rendered = render_image(&probe, &pose, &camera, &studio().downsample(32), &GgxMetal, &settings).1;
    assert!(mask.count() > 100, "{} pixels", mask.count());
    assert_eq!(mask, rendered);
}

/// Two renders (seeds 1 and 2) of the can under `env` by BRDF sampling,
/// then two by MIS (with `bounces` bounces of inter-reflection, sampled
/// the same way at each bounce's point): per fully covered pixel, the sum
/// of its channels.
fn can_by_both_strategies(env: &EnvMap, camera: &Camera, spp: u32, bounces: u32) -> [[Vec<f64>; 2]; 2] {
    let probe = SodaCan::default().build();
    let sampler = EnvSampler::new(env);
    let strategies = [LightSampling::BSDF, LightSampling::mis(&sampler)];
    strategies.map(|sampling| {
        let sampling = sampling.with_bounces(bounces);
        [1, 2].map(|seed| {
            let settings = RenderSettings { spp, seed };
            let (hits, rgb) = render(&probe, &Pose::IDENTITY, camera, env, &GgxMetal, settings, &sampling);
            let inside = (0..hits.pixels.len()).filter(|&k| hits.coverage[k] == 1.0);
            inside.map(|k| rgb[0][k] + rgb[1][k] + rgb[2][k]).collect()
        })
    })
}

/// Mean over pixels of the squared difference of two images.
fn mean_square_difference(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| (x - y).powi(2)).sum::<f64>() / a.len() as f64
}

fn mean(v: &[f64]) -> f64 {
    v.iter().sum::<f64>() / v.len() as f64
}

#[test]
fn mis_and_bsdf_sampling_agree_on_the_can_under_studio() {
    // Studio at 64 rows: its lights still a few texels wide, while BRDF
    // sampling converges well enough to tell a bias of 1 %.
    let env = studio().downsample(64);
    the_strategies_agree(can_by_both_strategies(&env, &can_camera(10.0), 512, 0), 2000);
}

#[test]
fn mis_and_bsdf_sampling_agree_on_the_light_the_can_reflects_onto_its_lid() {
    // From above: the lid, which its rim shadows and lights by reflection.
    let camera = Camera::new(
        64,
        64,
        8.0,
        Vec3::new(0.0, 0.4, 0.2),
        Vec3::new(0.0, 0.122, 0.0),
        Vec3::Y,
    )
    .expect("camera");
    let env = EnvMap::read(envmaps().join("courtyard.exr"))
        .expect("env")
        .downsample(8);
    the_strategies_agree(can_by_both_strategies(&env, &camera, 512, 2), 400);
}

/// BRDF sampling and MIS give the same image up to their noise.
fn the_strategies_agree([[bsdf, bsdf2], [mis, mis2]]: [[Vec<f64>; 2]; 2], min_pixels: usize) {
    assert!(bsdf.len() > min_pixels, "too few covered pixels: {}", bsdf.len());
    // Each estimator's per-pixel variance, from its two seeds.
    let variance = [(&bsdf, &bsdf2), (&mis, &mis2)].map(|(a, b)| mean_square_difference(a, b) / 2.0);
    // Per pixel, the two differ by their noise alone.
    let difference = mean_square_difference(&bsdf, &mis);
    let noise = variance[0] + variance[1];
    assert!(
        difference < 1.2 * noise,
        "mean square difference {difference}, noise alone {noise}"
    );
    // Over the image: the means agree to 4 standard errors (3 %).
    let error = mean(&mis) - mean(&bsdf);
    let standard_error = (noise / bsdf.len() as f64).sqrt();
    assert!(
        standard_error < 0.0075 * mean(&bsdf),
        "too noisy to tell: standard error {standard_error}, mean {}, {} pixels",
        mean(&bsdf),
        bsdf.len()
    );
    assert!(
        error.abs() < 4.0 * standard_error,
        "means {} (MIS) and {} (BRDF) differ by {error}, standard error {standard_error}",
        mean(&mis),
        mean(&bsdf)
    );
}

#[test]
fn mis_is_much_less_noisy_than_bsdf_sampling_under_studio() {
    // Full resolution: lights of a few texels. A close-up (0.4 mm pixels, as
    // a can 200 pixels tall), so that the noise measured is the lighting's,
    // not the variation of the texture and normals within a pixel, which no
    // light sampling removes.
    let [[bsdf, bsdf2], [mis, mis2]] = can_by_both_strategies(&studio(), &can_camera(4.0), 16, 0);
    let ratio = mean_square_difference(&bsdf, &bsdf2) / mean_square_difference(&mis, &mis2);
    assert!(ratio > 20.0, "per-pixel variance only {ratio} times lower with MIS");
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
    grad_scene_from(textured, Vec3::new(0.5, 0.8, 3.5))
}

/// [`grad_scene`] seen from `eye` (the can is 1.2 m tall, standing on the origin).
fn grad_scene_from(textured: bool, eye: Vec3) -> GradScene {
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
    let camera = Camera::new(12, 16, 30.0, eye, Vec3::new(0.0, 0.6, 0.0), Vec3::Y).expect("camera");
    let pose = Pose::new(Quat::from_rotation_y(0.3), 10.0, Vec3::new(0.0, 0.0, 0.2));
    let env = smooth_env(32);
    let hits = trace(&probe, &pose, &camera, 2);
    assert!(hits.len() > 50, "the can must cover some pixels: {}", hits.len());
    GradScene {
        probe,
        camera,
        pose,
        env,
        hits,
    }
}

/// `probe`'s hits at `pose`, `spp` rays through each pixel of `camera`.
fn trace(probe: &ProbeAsset, pose: &Pose, camera: &Camera, spp: u32) -> PrimaryHits {
    let tape = Tape::<f32>::new();
    let mesh = MeshVars::new(&tape, &probe.mesh);
    let posed = PosedMesh::new(&mesh, &PoseVars::new(&tape, &pack_pose(pose), false));
    PrimaryHits::trace(
        &probe.mesh,
        &posed.position_values(),
        camera,
        &RenderSettings { spp, seed: 5 },
    )
}

impl GradScene {
    /// The rendered pixels, all three channels in one array.
    fn image<'t>(
        &self,
        t: &'t Tape<f64>,
        probe: &ProbeVars<'t, f64>,
        posed: &PosedMesh<'t, f64>,
        env: &ImageVars<'t, f64>,
        sampling: &LightSampling,
    ) -> autodiff::Var<'t, f64> {
        let rgb = ProbeScene {
            tape: t,
            hits: &self.hits,
            camera: &self.camera,
            probe,
            posed,
            triangles: &self.probe.mesh.triangles,
            bsdf: &GgxMetal,
        }
        .light_samples(sampling)
        .radiance(env);
        t.concat(&rgb)
    }
}

/// Where [`grad_scene_from`] sees the can's lid, which its rim shadows.
const LID_VIEW: Vec3 = Vec3::new(0.5, 2.4, 3.0);

/// The light samples of `g`'s probe at its pose, picked by `sampling`.
fn light_samples_of<'t>(tape: &'t Tape<f64>, g: &GradScene, sampling: &LightSampling) -> LightSamples<'t, f64> {
    let probe = ProbeVars::new(tape, &g.probe, false);
    let posed = PosedMesh::new(&probe.mesh, &PoseVars::new(tape, &pack_pose(&g.pose), false));
    let triangles = &g.probe.mesh.triangles;
    ProbeScene {
        tape,
        hits: &g.hits,
        camera: &g.camera,
        probe: &probe,
        posed: &posed,
        triangles,
        bsdf: &GgxMetal,
    }
    .light_samples(sampling)
}

/// The gradient checks: the side view by BRDF sampling and by MIS, and the
/// lid view with inter-reflection (checked to bounce).
fn grad_cases<'a>(
    side: &'a GradScene,
    top: &'a GradScene,
    sampler: &'a EnvSampler,
) -> [(&'a GradScene, LightSampling<'a>); 3] {
    let bouncing = LightSampling::BSDF.with_bounces(2);
    let tape = Tape::<f64>::new();
    let samples = light_samples_of(&tape, top, &bouncing);
    let counts: Vec<usize> = samples.bounce_ranges().map(|r| r.len()).collect();
    let [first, second] = counts[..] else {
        panic!("the lid view must bounce twice: bounces of {counts:?} samples")
    };
    // A second bounce is rarer (a lobe of roughness 0.3 leaves the rim's
    // inside mostly for the sky): a few samples, each checked all the same.
    assert!(
        first > 10 && second > 2,
        "the lid view must bounce twice: {first}, {second} bounces"
    );
    [
        (side, LightSampling::BSDF),
        (side, LightSampling::mis(sampler)),
        (top, bouncing),
    ]
}

#[test]
fn env_sampled_marks_the_samples_the_env_map_sampler_drew() {
    // A map dark but for one patch: the sampler draws only there, while
    // the lobes of the lid view reach elsewhere too.
    let top = grad_scene_from(false, LID_VIEW);
    let (w, h) = (16, 8);
    let patch = |k: usize| (k / w == 2 && (3..6).contains(&(k % w))) as u8 as f32;
    let env = EnvMap::new(w, h, (0..w * h).map(|k| [patch(k); 3]).collect()).expect("env");
    let sampler = EnvSampler::new(&env);
    let tape = Tape::<f64>::new();
    let samples = light_samples_of(&tape, &top, &LightSampling::mis(&sampler).with_bounces(1));
    let wi = [samples.wi.x, samples.wi.y, samples.wi.z].map(|v| tape.to_vec(v));
    let density = |k: usize| sampler.pdf(Vec3::new(wi[0][k] as f32, wi[1][k] as f32, wi[2][k] as f32));
    let count =
        |from_env: bool, range: std::ops::Range<usize>| range.filter(|&k| samples.env_sampled[k] == from_env).count();
    let (direct, all) = (samples.direct, samples.env_sampled.len());
    // One BRDF and one env-map sample at every shading point, bounces included.
    assert_eq!(count(true, 0..direct), count(false, 0..direct));
    assert_eq!(count(true, direct..all), count(false, direct..all));
    assert!(all > direct, "the lid view must bounce");
    for k in (0..all).filter(|&k| samples.env_sampled[k]) {
        assert!(
            density(k) > 0.0,
            "sample {k} is marked as the sampler's but lies where it never draws"
        );
    }
    let elsewhere = (0..all)
        .filter(|&k| !samples.env_sampled[k] && density(k) == 0.0)
        .count();
    assert!(
        elsewhere > all / 10,
        "BRDF samples outside the patch: {elsewhere} of {all}"
    );
}

#[test]
fn a_pixel_s_env_map_samples_are_stratified() {
    // Under a constant map the sampler's second number sets the azimuth
    // alone, evenly: a pixel's n env-map samples, stratified, leave no
    // azimuth gap of 2/n (each of n equal strata holds one). Sixteen
    // independent draws leave one in 99 % of pixels (simulated).
    let mut g = grad_scene(false);
    let n = 16;
    g.hits = trace(&g.probe, &g.pose, &g.camera, n);
    let env = EnvMap::new(16, 8, vec![[1.0; 3]; 128]).expect("env");
    let sampler = EnvSampler::new(&env);
    let tape = Tape::<f64>::new();
    let samples = light_samples_of(&tape, &g, &LightSampling::mis(&sampler));
    let wi = [samples.wi.x, samples.wi.y, samples.wi.z].map(|v| tape.to_vec(v));
    let segment = tape.to_vec(samples.segment);
    let mut azimuths = vec![Vec::new(); g.hits.pixels.len()];
    for k in (0..samples.direct).filter(|&k| samples.env_sampled[k]) {
        let turn = (wi[0][k].atan2(-wi[2][k]) / std::f64::consts::TAU).rem_euclid(1.0);
        azimuths[segment[k] as usize].push(turn);
    }
    let whole: Vec<&mut Vec<f64>> = azimuths.iter_mut().filter(|a| a.len() == n as usize).collect();
    assert!(whole.len() > 50, "pixels with {n} samples: {}", whole.len());
    for a in whole {
        a.sort_by(f64::total_cmp);
        let wrap = a[0] + 1.0 - a[a.len() - 1];
        let widest = a.windows(2).map(|w| w[1] - w[0]).fold(wrap, f64::max);
        assert!(widest < 2.0 / n as f64, "azimuths {a:?} leave a gap of {widest}");
    }
}

#[test]
fn image_gradients_in_pose_match_finite_differences() {
    let (side, top) = (grad_scene(false), grad_scene_from(false, LID_VIEW));
    let inputs = [Input::Var(pack_pose(&side.pose).to_vec())];
    let sampler = EnvSampler::new(&side.env);
    for (g, sampling) in grad_cases(&side, &top, &sampler) {
        // The image is stiff in the pose (third derivatives ~1e4 at this
        // scale) and sums many samples (rounding error eps |f| / h): at a
        // step of 3e-7 both stay below 1e-6 (1e-7 leaves 2e-6 of rounding
        // with MIS's two samples a hit, 3e-8 leaves 3e-6). A bounce is
        // stiffer still (its second hit slides along the inside of the rim
        // at a grazing angle): 4e-6 of truncation error at 3e-7, 4e-5 at
        // 1e-6, against 2e-6 of rounding at 1e-7.
        let (step, tolerance) = match sampling.bounces {
            0 => (3e-7, 1e-6),
            _ => (1e-7, 3e-6),
        };
        let report = gradcheck_with(&inputs, 8, step, |t, v| {
            let probe = ProbeVars::new(t, &g.probe, false);
            let posed = PosedMesh::new(&probe.mesh, &PoseVars::from_params(v[0]));
            let env = ImageVars::env(t, &g.env, false);
            g.image(t, &probe, &posed, &env, &sampling)
        });
        assert!(report.worst_rel_error < tolerance, "pose, {sampling:?}: {report}");
    }
}

#[test]
fn image_gradients_in_env_texels_and_material_match_finite_differences() {
    let (side, top) = (grad_scene(true), grad_scene_from(true, LID_VIEW));
    let image = |t: &Texture| Input::Var(image_texels::<f64>(&t.image));
    let inputs = [
        Input::Var(image_texels::<f64>(&side.env.to_image())),
        image(&side.probe.albedo),
        image(&side.probe.roughness),
        image(&side.probe.visibility),
    ];
    let size = |t: &Texture| (t.image.width, t.image.height);
    // The sampler stays the one of the unperturbed map: a fixed density.
    let sampler = EnvSampler::new(&side.env);
    for (g, sampling) in grad_cases(&side, &top, &sampler) {
        let report = gradcheck_sampled(&inputs, 40, |t, v| {
            let mut probe = ProbeVars::new(t, &g.probe, false);
            let texture =
                |k: usize, tex: &Texture| TextureVars::Image(ImageVars::from_texels(v[k], size(tex).0, size(tex).1));
            probe.albedo = texture(1, &g.probe.albedo);
            probe.roughness = texture(2, &g.probe.roughness);
            probe.visibility = texture(3, &g.probe.visibility);
            let posed = PosedMesh::new(&probe.mesh, &PoseVars::new(t, &pack_pose(&g.pose), false));
            let env = ImageVars::from_texels(v[0], g.env.width(), g.env.height());
            g.image(t, &probe, &posed, &env, &sampling)
        });
        assert!(
            report.worst_rel_error < 1e-6,
            "env and material, {sampling:?}: {report}"
        );
    }
}

#[test]
fn an_empty_view_is_reported_not_rendered() {
    let probe = UvSphere::default().build();
    let camera = Camera::new(8, 8, 20.0, Vec3::new(0.0, 0.0, 5.0), Vec3::new(0.0, 0.0, 10.0), Vec3::Y).expect("camera");
    let hits = PrimaryHits::trace(&probe.mesh, &probe.mesh.positions, &camera, &RenderSettings::default());
    assert!(hits.is_empty());
}

/// A flat square probe facing a camera on +Z, turned 20 degrees about the
/// view axis so that its edges cross pixels at every offset, and its camera.
fn tilted_plate() -> (ProbeAsset, Camera) {
    let (s, c) = 20f32.to_radians().sin_cos();
    let corner = |x: f32, y: f32| Vec3::new(c * x - s * y, s * x + c * y, 0.0);
    let positions = vec![
        corner(-1.0, -1.0),
        corner(1.0, -1.0),
        corner(1.0, 1.0),
        corner(-1.0, 1.0),
    ];
    let uvs = vec![glam::Vec2::ZERO, glam::Vec2::X, glam::Vec2::ONE, glam::Vec2::Y];
    let mesh = Mesh::new(positions, vec![Vec3::Z; 4], uvs, vec![[0, 1, 2], [0, 2, 3]]);
    let probe = ProbeAsset {
        name: "plate".into(),
        mesh,
        albedo: Texture::constant([1.0; 3]),
        roughness: Texture::constant([0.5; 3]),
        visibility: Texture::constant([1.0; 3]),
    };
    let camera = Camera::new(40, 40, 30.0, Vec3::new(0.0, 0.0, 5.0), Vec3::ZERO, Vec3::Y).expect("camera");
    (probe, camera)
}

/// Area of the convex polygon `polygon` (pixel coordinates) inside pixel
/// (row, col): Sutherland-Hodgman clipping by the pixel's four sides, then
/// the shoelace formula.
fn area_in_pixel(polygon: &[glam::Vec2], row: usize, col: usize) -> f64 {
    let (x0, y0) = (col as f32, row as f32);
    // Half-planes n.p >= d.
    let sides = [
        (glam::Vec2::X, x0),
        (-glam::Vec2::X, -x0 - 1.0),
        (glam::Vec2::Y, y0),
        (-glam::Vec2::Y, -y0 - 1.0),
    ];
    let mut poly = polygon.to_vec();
    for (n, d) in sides {
        let distance = |p: glam::Vec2| n.dot(p) - d;
        let mut clipped = Vec::new();
        for i in 0..poly.len() {
            let (a, b) = (poly[i], poly[(i + 1) % poly.len()]);
            if distance(a) >= 0.0 {
                clipped.push(a);
            }
            if (distance(a) >= 0.0) != (distance(b) >= 0.0) {
                clipped.push(a + distance(a) / (distance(a) - distance(b)) * (b - a));
            }
        }
        poly = clipped;
        if poly.is_empty() {
            return 0.0;
        }
    }
    let twice: f64 = (0..poly.len())
        .map(|i| {
            let (a, b) = (poly[i], poly[(i + 1) % poly.len()]);
            a.x as f64 * b.y as f64 - b.x as f64 * a.y as f64
        })
        .sum();
    twice.abs() / 2.0
}

#[test]
fn silhouette_samples_bring_coverage_closer_to_the_area_fraction() {
    let (probe, camera) = tilted_plate();
    let outline: Vec<glam::Vec2> = probe
        .mesh
        .positions
        .iter()
        .map(|&p| camera.project(p).expect("in front"))
        .collect();
    let settings = RenderSettings { spp: 4, seed: 11 };
    // Mean absolute coverage error over the partly covered pixels, over 8
    // seeds (measured: 0.081 with 4 samples, 0.038 with 16 at the
    // silhouette, 0.019 with 64).
    let error = |silhouette_spp: u32| {
        let (mut sum, mut count) = (0.0, 0);
        for seed in 0..8 {
            let settings = RenderSettings { seed, ..settings };
            let hits =
                PrimaryHits::trace_refined(&probe.mesh, &probe.mesh.positions, &camera, &settings, silhouette_spp);
            let mut coverage = vec![0.0; 40 * 40];
            for (k, &p) in hits.pixels.iter().enumerate() {
                coverage[p as usize] = hits.coverage[k] as f64;
            }
            for (p, &c) in coverage.iter().enumerate() {
                let truth = area_in_pixel(&outline, p / 40, p % 40);
                if truth > 0.0 && truth < 1.0 {
                    sum += (c - truth).abs();
                    count += 1;
                }
            }
        }
        assert!(count > 8 * 60, "too few silhouette pixels: {count}");
        sum / count as f64
    };
    let (uniform, refined) = (error(4), error(16));
    assert!(
        refined < 0.6 * uniform,
        "coverage error {refined} with 16 samples at the silhouette, {uniform} with 4"
    );
}

#[test]
fn each_pixel_averages_its_own_samples() {
    // A white Lambertian plate under a white sky: every BRDF sample weighs 1,
    // so a pixel's radiance is its coverage exactly, wherever it has 4 or 16
    // samples.
    let (probe, camera) = tilted_plate();
    let settings = RenderSettings { spp: 4, seed: 2 };
    let hits = PrimaryHits::trace_refined(&probe.mesh, &probe.mesh.positions, &camera, &settings, 16);
    assert!(hits.samples.contains(&16) && hits.samples.contains(&4));
    let tape = Tape::<f64>::new();
    let vars = ProbeVars::new(&tape, &probe, false);
    let posed = PosedMesh::new(&vars.mesh, &PoseVars::new(&tape, &pack_pose(&Pose::IDENTITY), false));
    let env = ImageVars::env(&tape, &EnvMap::constant(4, [1.0; 3]), false);
    let rgb = ProbeScene {
        tape: &tape,
        hits: &hits,
        camera: &camera,
        probe: &vars,
        posed: &posed,
        triangles: &probe.mesh.triangles,
        bsdf: &Lambertian,
    }
    .shade(&env);
    for (k, value) in tape.to_vec(rgb[0]).iter().enumerate() {
        assert!(
            (value - hits.coverage[k] as f64).abs() < 1e-6,
            "pixel {}: {value} vs coverage {}",
            hits.pixels[k],
            hits.coverage[k]
        );
    }
}

/// A mirror floor (y = 0) half under a roof (y = 0.5 over x < 0, facing
/// down), both 2 m square, seen from above and in front.
fn floor_under_roof() -> (ProbeAsset, Camera) {
    let positions = vec![
        Vec3::new(-1.0, 0.0, -1.0),
        Vec3::new(1.0, 0.0, -1.0),
        Vec3::new(1.0, 0.0, 1.0),
        Vec3::new(-1.0, 0.0, 1.0),
        Vec3::new(-1.0, 0.5, -1.0),
        Vec3::new(0.0, 0.5, -1.0),
        Vec3::new(0.0, 0.5, 1.0),
        Vec3::new(-1.0, 0.5, 1.0),
    ];
    let normals = [[Vec3::Y; 4], [Vec3::NEG_Y; 4]].concat();
    let uvs = [[glam::Vec2::ZERO, glam::Vec2::X, glam::Vec2::ONE, glam::Vec2::Y]; 2].concat();
    let triangles = vec![[0, 2, 1], [0, 3, 2], [4, 5, 6], [4, 6, 7]];
    let probe = ProbeAsset {
        name: "floor under a roof".into(),
        mesh: Mesh::new(positions, normals, uvs, triangles),
        albedo: Texture::constant([1.0; 3]),
        roughness: Texture::constant([0.0; 3]),
        visibility: Texture::constant([1.0; 3]),
    };
    let camera = Camera::new(48, 48, 60.0, Vec3::new(0.3, 2.5, 2.5), Vec3::ZERO, Vec3::Y).expect("camera");
    (probe, camera)
}

#[test]
fn the_probe_shadows_itself() {
    floor_under_roof_is_lit_as_traced(&LightSampling::BSDF);
}

#[test]
fn the_probe_lights_itself_by_one_bounce() {
    floor_under_roof_is_lit_as_traced(&LightSampling::BSDF.with_bounces(1));
}

#[test]
fn the_probe_lights_itself_by_two_bounces() {
    floor_under_roof_is_lit_as_traced(&LightSampling::BSDF.with_bounces(2));
}

#[test]
fn without_shadows_every_sample_sees_the_map() {
    floor_under_roof_is_lit_as_traced(&LightSampling::BSDF.with_bounces(1).without_shadows());
}

/// Renders [`floor_under_roof`] under a map brighter below the horizon
/// than above, and checks each floor pixel against the rays traced by
/// hand: a floor sample reflects about +Y and reads the map there, unless
/// the reflected ray meets the roof (y = 0.5, -1 < x < 0, -1 < z < 1).
/// There it is dark, or, with `sampling`'s bounces, the roof reflects it
/// down again, to read the map below unless the floor is in the way, where
/// a second bounce sends it up again, and so on.
fn floor_under_roof_is_lit_as_traced(sampling: &LightSampling) {
    let (probe, camera) = floor_under_roof();
    let env = EnvMap::new(8, 4, [[[0.5, 1.0, 2.0]; 16], [[3.0, 2.0, 1.0]; 16]].concat()).expect("a map");
    let settings = RenderSettings { spp: 4, seed: 3 };
    let (hits, rgb) = render_mirror(&probe, &camera, &env, settings, sampling);
    let within = |p: Vec3, x: std::ops::Range<f32>| x.contains(&p.x) && (-1.0..1.0).contains(&p.z);
    let mut want = vec![[0.0f64; 3]; hits.pixels.len()];
    let mut on_floor = vec![true; hits.pixels.len()];
    // Samples that read the map after 0, 1, 2 bounces, and that are dark.
    let (mut reached, mut shadowed) = ([0; 3], 0);
    for i in 0..hits.len() {
        let (p, d) = (hits.point[i], hits.direction[i]);
        let k = hits.segment[i] as usize;
        if p.y > 0.25 {
            on_floor[k] = false;
            continue;
        }
        let r = Vec3::new(d.x, -d.y, d.z);
        // Follow the mirror path: up (r) towards the roof, down (d) towards
        // the floor, until it leaves or runs out of bounces.
        let (mut at, mut w, mut depth) = (p, r, 0);
        let light = loop {
            let (height, x) = match w.y > 0.0 {
                true => (0.5, -1.0..0.0),
                false => (0.0, -1.0..1.0),
            };
            let next = at + w * ((height - at.y) / w.y);
            if !sampling.shadows || !within(next, x) {
                break Some((w, depth));
            }
            if depth == sampling.bounces {
                break None;
            }
            (at, w, depth) = (next, Vec3::new(w.x, -w.y, w.z), depth + 1);
        };
        match light {
            Some((_, depth)) => reached[depth as usize] += 1,
            None => shadowed += 1,
        }
        let light = light.map(|(w, _)| w);
        if let Some(w) = light {
            let l = env.lookup(w);
            (0..3).for_each(|c| want[k][c] += l[c] as f64 / settings.spp as f64);
        }
    }
    let bounces = sampling.bounces as usize;
    assert!(
        (shadowed > 40) == sampling.shadows && (0..3).all(|k| (reached[k] > 40) == (k <= bounces)),
        "the view must show each case: {shadowed} shadowed, {reached:?} reaching the map after 0, 1, 2 bounces"
    );
    let mut worst = 0.0f64;
    for k in (0..hits.pixels.len()).filter(|&k| on_floor[k] && hits.coverage[k] == 1.0) {
        worst = (0..3).map(|c| (rgb[c][k] - want[k][c]).abs()).fold(worst, f64::max);
    }
    assert!(
        worst < 1e-4,
        "the floor's light differs from the traced rays by up to {worst}"
    );
}

#[test]
fn a_subset_of_pixels_renders_as_they_render_in_the_whole() {
    let probe = SodaCan::default().build();
    let camera = can_camera(30.0);
    let env = studio().downsample(32);
    let sampler = EnvSampler::new(&env);
    let settings = RenderSettings { spp: 4, seed: 3 };
    let checkerboard = |p: u32| (p % camera.width + p / camera.width).is_multiple_of(2);
    for sampling in [LightSampling::BSDF, LightSampling::mis(&sampler).with_bounces(1)] {
        let (whole, whole_rgb) = render(&probe, &Pose::IDENTITY, &camera, &env, &GgxMetal, settings, &sampling);
        let (half, rgb) = render_pixels(
            &probe,
            &Pose::IDENTITY,
            &camera,
            &env,
            &GgxMetal,
            settings,
            &sampling,
            checkerboard,
        );
        let expected: Vec<u32> = whole.pixels.iter().copied().filter(|&p| checkerboard(p)).collect();
        assert!(expected.len() > 100 && expected.len() < whole.pixels.len());
        assert_eq!(half.pixels, expected, "{sampling:?}: the kept pixels, in order");
        assert!(
            half.segment.windows(2).all(|s| s[0] <= s[1]) && half.segment.last() == Some(&(expected.len() as u32 - 1)),
            "{sampling:?}: samples stay in pixel order and point into the kept pixels"
        );
        for (k, p) in half.pixels.iter().enumerate() {
            let w = whole.pixels.iter().position(|q| q == p).expect("a pixel of the whole");
            assert_eq!(half.coverage[k], whole.coverage[w]);
            for c in 0..3 {
                assert_eq!(rgb[c][k], whole_rgb[c][w], "{sampling:?}: pixel {p} channel {c}");
            }
        }
    }
}

#[test]
fn a_traced_record_s_transport_renders_the_probe_as_the_renderer_does() {
    // The linear operator from texels to pixels that the lighting solve
    // inverts must be the forward model: applied to a map's texels it gives
    // `render_image`'s pixels, to the Monte Carlo noise of both.
    let probe = SodaCan::default().build();
    let camera = can_camera(30.0);
    let pose = Pose::new(Quat::from_rotation_y(0.7), 1.0, Vec3::ZERO);
    let env = studio().downsample(16);
    let sampler = EnvSampler::new(&env);
    let sampling = LightSampling::mis(&sampler).with_bounces(1);
    let settings = RenderSettings { spp: 128, seed: 3 };
    let record =
        render::transport::SampleRecord::trace(&probe, &GgxMetal, &pose, &camera, &settings, &sampling, 2, |_| true)
            .expect("a record");
    let transport = record.transport(env.width(), env.height());
    let texels: Vec<f64> = env.radiance().iter().flatten().map(|&v| v as f64).collect();
    let mut rendered = vec![[0.0; 3]; record.hits.pixels.len()];
    transport.apply(&texels, &mut rendered);
    let (image, _) = render::integrator::render_image(
        &probe,
        &pose,
        &camera,
        &env,
        &GgxMetal,
        &RenderSettings { spp: 256, seed: 5 },
    );
    // Pixels wholly on the probe (an edge pixel's coverage is sampled apart).
    let (mut ours, mut theirs, mut pixels) = ([0.0f64; 3], [0.0f64; 3], 0);
    for (k, &p) in record.hits.pixels.iter().enumerate() {
        if record.hits.coverage[k] >= 1.0 {
            (0..3).for_each(|c| {
                ours[c] += rendered[k][c];
                theirs[c] += image.pixels[p as usize][c] as f64;
            });
            pixels += 1;
        }
    }
    assert!(pixels > 500, "{pixels} pixels on the probe");
    for c in 0..3 {
        let relative = (ours[c] - theirs[c]).abs() / theirs[c];
        assert!(
            relative < 0.01,
            "channel {c}: transport {} against render {}",
            ours[c],
            theirs[c]
        );
    }
    // Per pixel too, where a map turned upside down differs: the comparison
    // tells a wrong lookup.
    let flipped: Vec<f64> = (0..env.height())
        .rev()
        .flat_map(|r| texels[r * env.width() * 3..(r + 1) * env.width() * 3].to_vec())
        .collect();
    let l1_off = |map: &[f64]| {
        let mut out = vec![[0.0; 3]; record.hits.pixels.len()];
        transport.apply(map, &mut out);
        let (mut off, mut all) = (0.0, 0.0);
        for (k, &p) in record.hits.pixels.iter().enumerate() {
            if record.hits.coverage[k] >= 1.0 {
                for (got, want) in out[k].iter().zip(image.pixels[p as usize]) {
                    off += (got - want as f64).abs();
                    all += want as f64;
                }
            }
        }
        off / all
    };
    let (right, upside_down) = (l1_off(&texels), l1_off(&flipped));
    assert!(
        right < 0.1 && upside_down > 3.0 * right,
        "per pixel: {right} right way up, {upside_down} upside down"
    );
}

/// A blurred camera's pixel sees the probe in the share its footprint -- the pixel's box spread
/// by a Gaussian of `footprint_px` -- lies on it: across a straight edge, the box's mean of
/// `Phi(distance / footprint)`.
#[test]
fn a_blurred_camera_s_coverage_falls_off_across_an_edge_as_its_footprint_says() {
    // A 0.03 m cube square to a 64x48 camera 0.3 m away: its front face's left edge is a
    // vertical line of the image.
    let mesh = render::procedural::unit_cube();
    let probe = ProbeAsset {
        mesh,
        ..SodaCan::default().build()
    };
    let pose = Pose::new(Quat::IDENTITY, 0.03, Vec3::new(0.0, 0.0, 0.0));
    let sharp = Camera::new(
        64,
        48,
        30.0,
        Vec3::new(0.001, 0.0, 0.3),
        Vec3::new(0.001, 0.0, 0.0),
        Vec3::Y,
    )
    .expect("camera");
    let edge_x = sharp.project(Vec3::new(-0.015, 0.0, 0.015)).expect("in view").x as f64;
    let phi = |x: f64| 0.5 * (1.0 + erf(x / std::f64::consts::SQRT_2));
    for footprint in [0.0f32, 1.5] {
        let camera = sharp.with_footprint(footprint).expect("a footprint");
        let hits = trace(&probe, &pose, &camera, 1024);
        let row = 24usize;
        for col in (edge_x.floor() as usize).saturating_sub(5)..edge_x as usize + 6 {
            let p = (row * 64 + col) as u32;
            let coverage = hits
                .pixels
                .iter()
                .position(|&q| q == p)
                .map_or(0.0, |k| hits.coverage[k] as f64);
            // The pixel's box [col, col + 1), each point's share of the Gaussian right of the edge.
            let expected = match footprint {
                0.0 => (col as f64 + 1.0 - edge_x).clamp(0.0, 1.0),
                s => {
                    (0..1000)
                        .map(|k| phi((col as f64 + (k as f64 + 0.5) / 1000.0 - edge_x) / s as f64))
                        .sum::<f64>()
                        / 1000.0
                }
            };
            assert!(
                (coverage - expected).abs() < 0.05,
                "footprint {footprint}, column {col} ({} px from the edge): coverage {coverage}, expected {expected}",
                col as f64 + 0.5 - edge_x
            );
        }
    }
    assert!(sharp.with_footprint(-1.0).is_err() && sharp.with_footprint(f32::NAN).is_err());
}

/// The error function (Abramowitz and Stegun 7.1.26, within 1.5e-7).
fn erf(x: f64) -> f64 {
    let t = 1.0 / (1.0 + 0.327_591_1 * x.abs());
    let poly =
        t * (0.254_829_592 + t * (-0.284_496_736 + t * (1.421_413_741 + t * (-1.453_152_027 + t * 1.061_405_429))));
    (1.0 - poly * (-x * x).exp()).copysign(x)
}
