//! Inverse rendering across the crates, as a researcher runs it: a soda can
//! rendered differentiably (`render` on an `autodiff` tape) under a tiny
//! known env map, whose texels are then recovered from that image by
//! `optim`'s L-BFGS.
//!
//! At a fixed pose the light samples (directions and throughputs) do not
//! depend on the env map, and the rendering equation (PAPER.md, "Forward
//! model") is linear in `L_i`: the image is `A env_map` and the squared
//! error is quadratic in the texels. So central differences agree with
//! reverse mode to rounding, and L-BFGS reaches the least-squares map.

use autodiff::{Mark, Tape, Var};
use glam::Vec3;
use optim::{Bounds, Lbfgs, Solver};
use render::bsdf::GgxMetal;
use render::camera::Camera;
use render::integrator::{LightSamples, LightSampling, PrimaryHits, ProbeScene, ProbeVars, RenderSettings};
use render::lookup::ImageVars;
use render::pose::Pose;
use render::posed::{PoseVars, PosedMesh, pack_pose};
use render::procedural::SodaCan;

/// Columns of the env map (width = 2 x height, FORMATS.md).
const ENV_WIDTH: usize = 8;
/// Rows of the env map.
const ENV_HEIGHT: usize = 4;
/// Texels of the env map.
const TEXELS: usize = ENV_WIDTH * ENV_HEIGHT;
/// The light (row, col): 22.5 deg above the horizon, towards the camera
/// (u = 0.5 is +z) and a little to its left, where the can's body reflects
/// it to the camera.
const LIGHT_TEXEL: (usize, usize) = (1, 4);

/// The map the target image is rendered under (texel-major RGB): each texel
/// a colour unlike its neighbours', so that a texel recovered in another's
/// place shows, and the light 20 times brighter than the rest.
fn true_env_map() -> Vec<f64> {
    (0..TEXELS)
        .flat_map(|t| {
            let gain = if t == LIGHT_TEXEL.0 * ENV_WIDTH + LIGHT_TEXEL.1 {
                20.0
            } else {
                1.0
            };
            [
                0.2 + 0.1 * (t % 5) as f64,
                0.3 + 0.05 * (t % 7) as f64,
                0.1 + 0.08 * (t % 3) as f64,
            ]
            .map(|c| gain * c)
        })
        .collect()
}

/// The can's light samples, recorded once on `tape` (fixed seed, fixed
/// pose), and the tape's mark after them: each evaluation rewinds to it and
/// records only the env map's lookups, so the image is a deterministic
/// function of the texels.
struct Rendering<'t> {
    tape: &'t Tape<f64>,
    samples: LightSamples<'t, f64>,
    mark: Mark,
}

impl<'t> Rendering<'t> {
    /// The can at its mesh's frame, 4 BRDF samples per pixel, seen from 35
    /// cm by a 36 x 48 camera a little above its middle, so that its lid
    /// reflects the sky and its body the horizon.
    fn new(tape: &'t Tape<f64>) -> Self {
        let probe = SodaCan::default().build();
        let camera = Camera::new(
            36,
            48,
            30.0,
            Vec3::new(0.0, 0.15, 0.33),
            Vec3::new(0.0, 0.06, 0.0),
            Vec3::Y,
        )
        .expect("a valid camera");
        let vars = ProbeVars::new(tape, &probe, false);
        let pose = PoseVars::new(tape, &pack_pose(&Pose::IDENTITY), false);
        let posed = PosedMesh::new(&vars.mesh, &pose);
        let settings = RenderSettings { spp: 4, seed: 11 };
        let hits = PrimaryHits::trace(&probe.mesh, &posed.position_values(), &camera, &settings);
        let samples = ProbeScene {
            tape,
            hits: &hits,
            camera: &camera,
            probe: &vars,
            posed: &posed,
            triangles: &probe.mesh.triangles,
            bsdf: &GgxMetal,
        }
        .light_samples(&LightSampling::BSDF);
        let mark = tape.mark();
        Rendering { tape, samples, mark }
    }

    /// The env map's texels as a tape leaf, and the image they render (one
    /// array per channel, over the pixels that see the can).
    fn render(&self, env_map: &[f64]) -> (Var<'t, f64>, [Var<'t, f64>; 3]) {
        self.tape.reset_to(self.mark);
        let texels = self.tape.leaf(env_map);
        let image = self
            .samples
            .radiance(&ImageVars::from_texels(texels, ENV_WIDTH, ENV_HEIGHT));
        (texels, image)
    }

    /// The image under `env_map`.
    fn image(&self, env_map: &[f64]) -> [Vec<f64>; 3] {
        self.render(env_map).1.map(|c| self.tape.to_vec(c))
    }

    /// The squared error of the image under `env_map` against `target`,
    /// summed over pixels and channels; its gradient in the texels is
    /// written to `gradient`.
    fn loss(&self, env_map: &[f64], target: &[Vec<f64>; 3], gradient: &mut [f64]) -> f64 {
        let (texels, image) = self.render(env_map);
        let squared_error = |c: usize| (image[c] - self.tape.constant(&target[c])).square().sum();
        let loss = squared_error(0) + squared_error(1) + squared_error(2);
        self.tape.backward(loss);
        gradient.copy_from_slice(&self.tape.grad(texels));
        self.tape.item(loss)
    }

    /// Each texel value's weight in the image, PAPER.md's confidence map
    /// (how often the probe samples a direction): the gradient of the
    /// image's sum, `1' A`, the same at any map since the image is linear.
    fn exposure(&self) -> Vec<f64> {
        let (texels, image) = self.render(&vec![1.0; 3 * TEXELS]);
        self.tape.backward(image[0].sum() + image[1].sum() + image[2].sum());
        self.tape.grad(texels).to_vec()
    }
}

#[test]
fn the_env_map_gradient_matches_central_differences() {
    let tape = Tape::new();
    let rendering = Rendering::new(&tape);
    let truth = true_env_map();
    let target = rendering.image(&truth);
    // Neither the truth (a zero gradient) nor a multiple of it.
    let env_map: Vec<f64> = truth
        .iter()
        .enumerate()
        .map(|(k, v)| 0.5 * v + 0.03 * (k % 4) as f64)
        .collect();
    let mut gradient = vec![0.0; env_map.len()];
    rendering.loss(&env_map, &target, &mut gradient);
    let largest = gradient.iter().fold(0.0f64, |m, g| m.max(g.abs()));
    let mut unused = vec![0.0; env_map.len()];
    for k in 0..env_map.len() {
        // The loss is quadratic: the central difference has no truncation
        // error, only rounding (about eps |loss| / h, 1e-9 relative here).
        let h = 1e-4 * env_map[k];
        let mut at = env_map.clone();
        at[k] += h;
        let above = rendering.loss(&at, &target, &mut unused);
        at[k] -= 2.0 * h;
        let below = rendering.loss(&at, &target, &mut unused);
        let numeric = (above - below) / (2.0 * h);
        // A texel the can hardly sees has a gradient near 0: compare it at
        // the scale of the largest.
        let error = (gradient[k] - numeric).abs() / gradient[k].abs().max(1e-3 * largest);
        assert!(
            error < 1e-6,
            "texel value {k}: reverse mode {:.9e}, central difference {numeric:.9e} (relative error {error:.2e})",
            gradient[k]
        );
    }
}

#[test]
fn lbfgs_recovers_the_env_map_the_can_sees() {
    let tape = Tape::new();
    let rendering = Rendering::new(&tape);
    let truth = true_env_map();
    let target = rendering.image(&truth);
    let mut objective = |env_map: &[f64], gradient: &mut [f64]| rendering.loss(env_map, &target, gradient);
    let mut lbfgs = Lbfgs::builder()
        .bounds(Bounds::uniform(truth.len(), 0.0, f64::INFINITY).expect("valid bounds"))
        .build()
        .expect("valid L-BFGS settings");
    let state = lbfgs
        .minimize(&mut objective, vec![0.5; truth.len()])
        .expect("a finite start");
    let termination = state.termination.expect("a finished run");
    assert!(termination.converged(), "L-BFGS stopped: {termination}");
    let recovered = state.best_x;

    // What the data determine is the image: the recovered map must render
    // the target.
    let image = rendering.image(&recovered);
    let (image, target) = (image.concat(), target.concat());
    let norm = |v: &[f64]| v.iter().map(|x| x * x).sum::<f64>().sqrt();
    let residual: Vec<f64> = image.iter().zip(&target).map(|(a, b)| a - b).collect();
    let image_error = norm(&residual) / norm(&target);
    assert!(
        image_error < 1e-4,
        "the recovered map renders the target {image_error:.2e} off (relative), {} evaluations",
        state.evals
    );

    // The texels are determined only as far as the can sees them: those
    // near the poles and behind it (u near 0) reach few pixels, at grazing
    // angles, with a hundredth of the weight of the horizon in front. A
    // real photo's noise would leave them undetermined; from this exact
    // image the solver's stopping rule (relative decrease 2.2e-9) leaves
    // them about 1e-3 off, ten times the rest. Only texel values with at
    // least a quarter of the largest exposure are held to the truth.
    let exposure = rendering.exposure();
    let most = exposure.iter().fold(0.0f64, |m, &e| m.max(e));
    let seen_well: Vec<usize> = (0..truth.len()).filter(|&k| exposure[k] >= 0.25 * most).collect();
    assert!(
        seen_well.len() >= truth.len() / 4,
        "the can sees only {} of {} texel values well",
        seen_well.len(),
        truth.len()
    );
    for k in seen_well {
        let error = (recovered[k] - truth[k]).abs() / truth[k];
        assert!(
            error < 1e-3,
            "texel value {k} (exposure {:.2} of the most): recovered {:.6}, true {:.6}",
            exposure[k] / most,
            recovered[k],
            truth[k]
        );
    }

    // The light is seen well, and must come out the brightest texel.
    let brightness = |t: usize| recovered[3 * t..3 * t + 3].iter().sum::<f64>();
    let brightest = (0..TEXELS)
        .max_by(|&a, &b| brightness(a).total_cmp(&brightness(b)))
        .expect("a texel");
    assert_eq!(
        (brightest / ENV_WIDTH, brightest % ENV_WIDTH),
        LIGHT_TEXEL,
        "the brightest recovered texel (row, col) is not the light's"
    );
}
