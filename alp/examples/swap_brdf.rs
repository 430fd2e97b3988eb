//! Swapping the BRDF: a researcher's own reflectance model, a Cook-Torrance
//! metal with Beckmann's microfacet distribution in place of GGX, written
//! over tape ops, checked (its sample weights are `f cos / pdf`, its
//! derivatives match central differences in f64), then plugged into the
//! estimate with `estimate_with`.
//!
//! The run renders a photo of a probe whose metal *is* Beckmann's and
//! estimates its pose and lighting twice: with the paper's GGX model (a
//! mismatched model) and with this one. It prints the relighting errors of
//! each, so the cost of modelling the material wrongly is measured, not
//! guessed. Then it acquires the probe as a user would (`alp acquire`'s
//! stage: a turntable capture of it, its scan placed and its textures
//! solved for) with each model, and prints how far each acquired probe's
//! textures are from the truth.
//!
//! ```text
//! cargo run --release -p alp --example swap_brdf [-- PROBE]
//! ```
//!
//! PROBE is a probe folder or `can` (default), `cap`, `sphere`. Its tests
//! (the two checks) run with `cargo test -p alp --example swap_brdf`.

use std::path::Path;
use std::time::Instant;

use alp::Result;
use alp::acquire::truth::Truth;
use alp::acquire::{AcquireSettings, Solver, acquire};
use alp::estimate::{Photo, ProbeBsdf, Quality, Settings, estimate_with};
use alp::eval::{pose_errors, relighting_errors};
use alp::relight::RelightSettings;
use alp::synth::{CaptureSettings, synthesize_capture};
use autodiff::{Real, Var, Vec3 as Vec3Var};
use render::bsdf::{Bsdf, BsdfSample, GgxMetal, Surface, schlick_fresnel};
use render::camera::Camera;
use render::envmap::EnvMap;
use render::integrator::{RenderSettings, render_image};
use render::pose::Pose;

/// Cook-Torrance with Beckmann's distribution (alpha = r^2, as the paper's
/// GGX), Smith's G1 in Walter et al.'s (2007) rational form, Schlick's
/// Fresnel, sampled by the distribution of normals: `tan^2 theta_h =
/// -alpha^2 ln(1 - u0)`. Beckmann's lobe has shorter tails than GGX's.
struct BeckmannMetal;

/// A denominator's floor: keeps values and derivatives finite at grazing angles.
const TINY: f64 = 1e-7;

/// `D(h) = exp(-tan^2 / alpha^2) / (pi alpha^2 cos^4)` for `cos = n.h`.
fn beckmann<'t, T: Real>(cos: Var<'t, T>, alpha2: Var<'t, T>) -> Var<'t, T> {
    let c2 = (cos * cos).max_scalar(T::c(TINY));
    let tan2 = c2.rsub(T::one()).max_scalar(T::zero()) / c2;
    (-(tan2 / alpha2)).exp() / (alpha2 * c2 * c2 * T::PI())
}

/// Smith's G1 for Beckmann: with `a = 1 / (alpha tan)`, `(3.535 a + 2.181
/// a^2) / (1 + 2.276 a + 2.577 a^2)` below a = 1.6, where it reaches 1 (so
/// clamping `a` there is the formula's other branch).
fn smith_g1<'t, T: Real>(cos: Var<'t, T>, alpha: Var<'t, T>) -> Var<'t, T> {
    let c = cos.abs().max_scalar(T::c(TINY));
    let sin = (c * c).rsub(T::one()).max_scalar(T::c(TINY)).sqrt();
    let a = (c / (alpha * sin)).min_scalar(T::c(1.6));
    (a * T::c(3.535) + a * a * T::c(2.181)) / (a * T::c(2.276) + a * a * T::c(2.577) + T::one())
}

/// 1 where `v > 0`, else 0.
fn above<'t, T: Real>(v: Var<'t, T>) -> Var<'t, T> {
    v.gt(v.tape().scalar(T::zero()))
}

/// `v` where `keep` is 1, else 0.
fn keep_where<'t, T: Real>(keep: Var<'t, T>, v: Var<'t, T>) -> Var<'t, T> {
    keep.select(v, v.tape().scalar(T::zero()))
}

impl<T: Real> Bsdf<T> for BeckmannMetal {
    fn name(&self) -> &'static str {
        "beckmann_metal"
    }

    fn eval<'t>(&self, s: &Surface<'t, T>, wo: Vec3Var<'t, T>, wi: Vec3Var<'t, T>) -> [Var<'t, T>; 3] {
        let alpha = s.roughness.square();
        let h = (wo + wi).normalize(T::c(TINY));
        // f cos = D F G1(wi) G1(wo) / (4 n.wo).
        let scale = beckmann(h.z, alpha.square()) * smith_g1(wi.z, alpha) * smith_g1(wo.z, alpha)
            / (wo.z.max_scalar(T::c(TINY)) * T::c(4.0));
        let scale = keep_where(above(wi.z) * above(wo.z), scale);
        schlick_fresnel(s.albedo, h.dot(wo)).map(|f| f * scale)
    }

    fn pdf<'t>(&self, s: &Surface<'t, T>, wo: Vec3Var<'t, T>, wi: Vec3Var<'t, T>) -> Var<'t, T> {
        let h = (wo + wi).normalize(T::c(TINY));
        let wo_h = wo.dot(h);
        // D(h) n.h / (4 wo.h): the density of h, turned into wi's.
        let pdf = beckmann(h.z, s.roughness.square().square()) * h.z / (wo_h.max_scalar(T::c(TINY)) * T::c(4.0));
        keep_where(above(wo_h) * above(wo.z), pdf)
    }

    fn sample<'t>(&self, s: &Surface<'t, T>, wo: Vec3Var<'t, T>, u: [Var<'t, T>; 2]) -> BsdfSample<'t, T> {
        let alpha = s.roughness.square();
        let tan2 = -(u[0].rsub(T::one()).max_scalar(T::c(TINY)).ln()) * alpha.square();
        let cos_h = (tan2 + T::one()).rsqrt();
        let sin_h = (cos_h * cos_h).rsub(T::one()).max_scalar(T::c(TINY)).sqrt();
        let phi = u[1] * T::c(2.0 * std::f64::consts::PI);
        let h = Vec3Var::new(sin_h * phi.cos(), sin_h * phi.sin(), cos_h);
        let wo_h = wo.dot(h);
        let wi = h.scale(wo_h * T::c(2.0)) - wo;
        // f cos / pdf = F G1(wi) G1(wo) wo.h / (n.wo n.h).
        let g = smith_g1(wi.z, alpha) * smith_g1(wo.z, alpha) * wo_h
            / (wo.z.max_scalar(T::c(TINY)) * cos_h.max_scalar(T::c(TINY)));
        let lit = above(wi.z) * above(wo.z) * above(wo_h);
        let weight = schlick_fresnel(s.albedo, wo_h).map(|f| keep_where(lit, f * g));
        BsdfSample { wi, weight }
    }
}

fn main() -> std::process::ExitCode {
    let probe = std::env::args_os().nth(1).unwrap_or_else(|| "can".into());
    match run(Path::new(&probe)) {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("swap_brdf: error: {e}");
            std::process::ExitCode::from(2)
        }
    }
}

fn run(probe: &Path) -> Result<()> {
    let assets = Path::new(env!("CARGO_MANIFEST_DIR")).join("../assets");
    let truth_env = EnvMap::read(assets.join("envmaps/courtyard.exr"))?.downsample(64);
    let camera = Camera::read(assets.join("demo/camera.json"))?;
    let truth = Pose::read(assets.join("demo/pose.json"))?;
    let probe = alp::probes::load(probe)?;
    let render = RenderSettings { spp: 64, seed: 7 };
    let (image, mask) = render_image(&probe, &truth, &camera, &truth_env, &BeckmannMetal, &render);
    let photo = Photo::new(image, mask, camera)?;

    println!("photo: {} under the courtyard, its metal Beckmann's", probe.name);
    println!("model            mirror  shiny  diffuse (deg)  rotation (deg)  wall (s)");
    let models: [&dyn ProbeBsdf; 2] = [&GgxMetal, &BeckmannMetal];
    for model in models {
        let clock = Instant::now();
        let found = estimate_with(
            &photo,
            &probe,
            model,
            &Settings::new(Quality::Default),
            &mut |_, _, _| {},
        )?;
        let wall = clock.elapsed().as_secs_f64();
        let [mirror, shiny, diffuse] = relighting_errors(&found.env, &truth_env, &camera, &RelightSettings::default())?;
        let pose = pose_errors(&found.pose, &truth);
        println!(
            "{:<16} {:>6.2} {:>6.2} {:>8.2}        {:>8.2}        {:>6.1}",
            found.report.bsdf, mirror.angular_deg, shiny.angular_deg, diffuse.angular_deg, pose.rotation_deg, wall
        );
    }

    println!(
        "\nacquired from a capture of {} views under the studio map",
        CAPTURE.views
    );
    println!("model            albedo RMSE  roughness RMSE  axis (deg)  wall (s)");
    let studio = EnvMap::read(assets.join("envmaps/studio.exr"))?.downsample(64);
    for model in [&GgxMetal as &dyn Bsdf<f32>, &BeckmannMetal] {
        let clock = Instant::now();
        let truth = acquired_against_truth(&probe, &studio, model, &CAPTURE)?;
        println!(
            "{:<16} {:>11.3} {:>15.3} {:>11.2} {:>9.1}",
            Bsdf::<f32>::name(model),
            truth.albedo_rmse,
            truth.roughness_rmse,
            truth.axis_deg,
            clock.elapsed().as_secs_f64()
        );
    }
    Ok(())
}

/// The capture the run acquires from: a turntable's views, small enough for a minute.
const CAPTURE: CaptureSettings = CaptureSettings {
    seed: 5,
    views: 12,
    noise: 0.0,
    spp: 32,
    width: 160,
    height: 120,
};

/// Renders a capture of `probe`, a Beckmann metal, under `env`, acquires it
/// with `model` (least squares, fast, 64x32 textures) and returns the
/// acquired probe's errors against the truth.
fn acquired_against_truth(
    probe: &render::probe::ProbeAsset,
    env: &EnvMap,
    model: &dyn Bsdf<f32>,
    capture: &CaptureSettings,
) -> Result<alp::acquire::truth::TruthErrors> {
    let synth = synthesize_capture(probe, env, &BeckmannMetal, capture)?;
    let truth = Truth {
        to_world: synth.to_world,
        probe: synth.probe,
    };
    let settings = AcquireSettings {
        solver: Solver::LeastSquares,
        ..AcquireSettings::preset(Quality::Fast)
    };
    let acquired = acquire(
        &synth.capture,
        "acquired",
        [64, 32],
        model,
        &settings,
        Some(&truth),
        &|_, _, _| {},
    )?;
    Ok(acquired.report.truth.expect("the truth was given"))
}

#[cfg(test)]
mod tests {
    use super::*;
    use autodiff::Tape;
    use autodiff::gradcheck::{Input, gradcheck, uniform};

    /// Viewing directions over the hemisphere, from near grazing to the normal.
    fn views(n: usize) -> [Vec<f64>; 3] {
        let dirs: Vec<[f64; 3]> = (0..n)
            .map(|i| {
                let t = (i as f64 + 0.5) / n as f64;
                let v = [(7.0 * t).sin() * 0.8, (5.0 * t).cos() * 0.6, 0.15 + t];
                let len = v.iter().map(|c| c * c).sum::<f64>().sqrt();
                v.map(|c| c / len)
            })
            .collect();
        [0, 1, 2].map(|c| dirs.iter().map(|d| d[c]).collect())
    }

    #[test]
    fn sample_weights_are_eval_over_pdf() {
        let n = 256;
        let [x, y, z] = views(n);
        for roughness in [0.2, 0.4, 0.7] {
            let tape = Tape::<f64>::new();
            let s = Surface {
                albedo: [0.9, 0.6, 0.3].map(|a| tape.scalar(a)),
                roughness: tape.scalar(roughness),
            };
            let wo = Vec3Var::new(tape.constant(&x), tape.constant(&y), tape.constant(&z));
            let u = [1, 2].map(|seed| tape.constant(&uniform(n, 0.01, 0.99, seed)));
            let sample = BeckmannMetal.sample(&s, wo, u);
            let eval = BeckmannMetal.eval(&s, wo, sample.wi);
            let pdf = tape.to_vec(BeckmannMetal.pdf(&s, wo, sample.wi));
            let lit = tape.to_vec(sample.wi.z);
            let mut checked = 0;
            for c in 0..3 {
                let (weight, eval) = (tape.to_vec(sample.weight[c]), tape.to_vec(eval[c]));
                for i in (0..n).filter(|&i| lit[i] > 1e-3 && pdf[i] > 1e-6) {
                    let ratio = eval[i] / pdf[i];
                    assert!(
                        (weight[i] - ratio).abs() < 1e-9 * ratio.max(1.0),
                        "r {roughness}: weight {} against f cos / pdf {ratio}",
                        weight[i]
                    );
                    checked += 1;
                }
            }
            assert!(checked > n, "r {roughness}: only {checked} samples above the horizon");
        }
    }

    /// The acquisition takes the model too: a capture of a Beckmann probe,
    /// acquired with Beckmann's model, comes out nearer its true roughness
    /// than acquired with GGX's (whose longer tails read as another roughness).
    #[test]
    fn a_beckmann_probe_is_acquired_best_with_its_own_model() {
        let assets = Path::new(env!("CARGO_MANIFEST_DIR")).join("../assets");
        let env = EnvMap::read(assets.join("envmaps/studio.exr"))
            .expect("studio")
            .downsample(32);
        let probe = alp::probes::load(Path::new("can")).expect("can");
        let small = CaptureSettings {
            views: 8,
            spp: 16,
            width: 96,
            height: 72,
            ..CAPTURE
        };
        let ggx = acquired_against_truth(&probe, &env, &GgxMetal, &small).expect("GGX");
        let beckmann = acquired_against_truth(&probe, &env, &BeckmannMetal, &small).expect("Beckmann");
        eprintln!("GGX {ggx:?}\nBeckmann {beckmann:?}");
        assert!(beckmann.axis_deg < 3.0, "axis {}", beckmann.axis_deg);
        assert!(
            beckmann.roughness_rmse < ggx.roughness_rmse,
            "roughness RMSE: Beckmann {} against GGX {}",
            beckmann.roughness_rmse,
            ggx.roughness_rmse
        );
    }

    #[test]
    fn derivatives_match_central_differences() {
        let n = 12;
        let [x, y, z] = views(n);
        let inputs = [
            Input::Var(vec![0.8, 0.5, 0.2]),
            Input::Var(vec![0.45]),
            Input::Var(x),
            Input::Var(y),
            Input::Var(z),
            Input::Const(uniform(n, 0.05, 0.95, 3)),
            Input::Const(uniform(n, 0.05, 0.95, 4)),
        ];
        let report = gradcheck(&inputs, |_, v| {
            let s = Surface {
                albedo: [v[0].slice(0, 1), v[0].slice(1, 1), v[0].slice(2, 1)],
                roughness: v[1],
            };
            let wo = Vec3Var::new(v[2], v[3], v[4]).normalize(1e-9);
            let sample = BeckmannMetal.sample(&s, wo, [v[5], v[6]]);
            // The lobe at a fixed direction too: eval and pdf along a turned view.
            let wi = Vec3Var::new(v[3], v[2], v[4]).normalize(1e-9);
            let [r, g, b] = sample.weight;
            let [er, eg, eb] = BeckmannMetal.eval(&s, wo, wi);
            r + g * 2.0
                + b * 3.0
                + sample.wi.x * sample.wi.z.exp()
                + er
                + eg * 0.5
                + eb * 0.25
                + BeckmannMetal.pdf(&s, wo, wi) * 0.1
        });
        assert!(report.worst_rel_error < 1e-6, "{report}");
    }
}
