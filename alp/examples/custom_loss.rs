//! A researcher's own loss terms, one for each phase of the estimate:
//!
//! - a pose term, the area of the rendered silhouette against the photo's
//!   mask: a cue to the probe's scale (distance) that does not depend on
//!   where the silhouettes lie;
//! - a lighting term, a prior pulling the lower hemisphere of the map
//!   towards a grey ground (its texels' colour towards their own grey).
//!
//! Each is written over tape ops, its gradient checked against finite
//! differences, then added to the paper's objective: the pose term's value
//! and gradient norm are reported as a pose run progresses, and the
//! lighting term changes the map an estimate makes (the lighting phase
//! minimises every declared lighting term, on a tape when the exact
//! least-squares solve does not cover them).
//!
//! `cargo run --release -p alp --example custom_loss`

use std::sync::Arc;

use alp::estimate::{Photo, Quality, Settings, estimate};
use alp::objective::testing::{Fixture, check_term};
use alp::objective::{Input, Objective, Phases, Term, TermContext, Weight, Weighting};
use alp::{Error, Result};
use autodiff::{Tape, Var};
use glam::{Quat, Vec3};
use render::bsdf::GgxMetal;
use render::camera::Camera;
use render::envmap::EnvMap;
use render::integrator::{RenderSettings, render_image};
use render::pose::Pose;
use render::procedural::SodaCan;

/// `(A_render / A_ref - 1)^2`, A = mask area in pixels: the soft mask's
/// coverage in its band plus the hard coverage elsewhere.
struct AreaRatio;

impl Term for AreaRatio {
    fn name(&self) -> &str {
        "area_ratio"
    }

    fn evaluate<'t>(&self, ctx: &TermContext<'_, 't>) -> Result<Option<Var<'t, f64>>> {
        let Some(soft) = ctx.soft_mask else { return Ok(None) };
        let plan = soft.plan();
        let band = soft.band_pixels();
        // Covered pixels outside the band are constant: count them once.
        let hard_area = plan
            .covered()
            .iter()
            .enumerate()
            .filter(|&(i, &c)| c && band.binary_search(&(i as u32)).is_err())
            .count();
        let area = soft.band_coverage.sum() + hard_area as f64;
        let ratio = area * (1.0 / ctx.reference.area() as f64);
        Ok(Some((ratio - 1.0).square()))
    }
}

/// Mean over the lower hemisphere's texels of their channels' squared
/// departure from the texel's grey, over the photo's level squared: zero
/// for a grey ground. A lighting term: it reads the map on the tape.
struct GreyGround;

impl Term for GreyGround {
    fn name(&self) -> &str {
        "grey_ground"
    }

    fn reads(&self) -> &'static [Input] {
        &[Input::Env, Input::Image]
    }

    fn phases(&self) -> Phases {
        Phases::LIGHTING
    }

    fn evaluate<'t>(&self, ctx: &TermContext<'_, 't>) -> Result<Option<Var<'t, f64>>> {
        let (Some(env), Some(image)) = (ctx.env, &ctx.image) else {
            return Ok(None);
        };
        let lower: Vec<f64> = (env.width * env.height.div_ceil(2)..env.width * env.height)
            .map(|t| t as f64)
            .collect();
        let texels = ctx.tape.constant(&lower);
        let [r, g, b] = [0, 1, 2].map(|c| env.texels.gather_channel(texels, 3, c));
        let grey = (r + g + b) * (1.0 / 3.0);
        let departure = (r - grey).square() + (g - grey).square() + (b - grey).square();
        Ok(Some(
            departure.sum() * (1.0 / (lower.len() as f64 * image.level().powi(2))),
        ))
    }
}

/// Checks a term's gradients on the fixture, or fails naming it.
fn checked(term: &dyn Term, fixture: &Fixture) -> Result<()> {
    let check = check_term(term, fixture)?;
    println!("{}: {check}", term.name());
    match check.passes() {
        true => Ok(()),
        false => Err(Error::invalid(term.name(), format!("gradient check failed: {check}"))),
    }
}

/// The lower hemisphere's mean chromatic departure of `map` (as the term
/// measures it, over the map's mean luminance squared).
fn ground_colour(map: &EnvMap) -> f64 {
    let (w, h) = (map.width(), map.height());
    let pixels = map.radiance();
    let level = pixels.iter().map(|p| (p[0] + p[1] + p[2]) as f64 / 3.0).sum::<f64>() / pixels.len() as f64;
    let lower = &pixels[w * h.div_ceil(2)..];
    let departure = |p: &[f32; 3]| {
        let grey = (p[0] + p[1] + p[2]) as f64 / 3.0;
        p.iter().map(|&c| (c as f64 - grey).powi(2)).sum::<f64>()
    };
    lower.iter().map(departure).sum::<f64>() / lower.len() as f64 / level.powi(2)
}

fn main() -> Result<()> {
    let fixture = Fixture::new()?;
    checked(&AreaRatio, &fixture)?;
    checked(&GreyGround, &fixture)?;

    let objective = Objective::paper_default().term(AreaRatio.weight(Weight::decay_to_zero(1.0, 0.5)));
    println!("\nobjective: {objective:?}");
    for progress in [0.0, 0.25, 0.5, 1.0] {
        let tape = Tape::new();
        let [pose, env] = fixture.parameters().map(|values| tape.leaf(&values));
        let reports = fixture.with_context(&tape, pose, env, progress, |ctx| {
            objective.evaluate(ctx)?.report(&[pose])
        })??;
        println!("\nprogress {progress}: term, weight, value, |weighted d/d pose|");
        for r in reports {
            println!(
                "  {:<18} {:>8.4} {:>12.4e} {:>12.4e}",
                r.name,
                r.weight,
                r.value,
                r.gradient_norm.unwrap_or(f64::NAN)
            );
        }
    }

    // The lighting term in an estimate: the procedural can under the
    // bundled courtyard (its ground is brown), at a known pose.
    let can = SodaCan::default().build();
    let truth = Pose::new(Quat::from_rotation_y(0.3), 1.0, Vec3::ZERO);
    let camera = Camera::new(
        160,
        120,
        30.0,
        Vec3::new(0.0, 0.2, 0.7),
        Vec3::new(0.0, 0.06, 0.0),
        Vec3::Y,
    )?;
    let courtyard = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../assets/envmaps/courtyard.exr");
    let env = EnvMap::read(courtyard)?.downsample(64);
    let (image, mask) = render_image(
        &can,
        &truth,
        &camera,
        &env,
        &GgxMetal,
        &RenderSettings { spp: 16, seed: 1 },
    );
    let photo = Photo::new(image, mask, camera)?;
    println!("\nthe lower hemisphere's departure from grey, over the map's mean level squared (0: grey)");
    println!("  {:<32} {:>10.4}", "true map", ground_colour(&env));
    for weight in [0.0, 1.0, 100.0] {
        let settings = Settings {
            known_pose: Some(truth),
            objective: Arc::new(Objective::paper_default().term(GreyGround.weight(weight))),
            ..Settings::new(Quality::Fast)
        };
        let estimate = estimate(&photo, &can, &settings)?;
        let lighting = estimate.report.phases.last().expect("the final lighting phase");
        println!(
            "  {:<32} {:>10.4}   ({} solve, {:.1} s; terms {:?})",
            format!("estimate, grey_ground weight {weight}"),
            ground_colour(&estimate.env),
            estimate.report.objective.lighting_solve,
            lighting.wall_s,
            lighting.loss
        );
    }
    Ok(())
}
