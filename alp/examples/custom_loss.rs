//! A researcher's own loss term: the area of the rendered silhouette against
//! the photo's mask, a cue to the probe's scale (distance) that does not
//! depend on where the silhouettes lie. Written over tape ops, its gradient
//! checked against finite differences, then added to the paper's objective,
//! whose terms report their values and gradient norms as the run progresses.
//!
//! `cargo run --release -p alp --example custom_loss`

use alp::objective::testing::{Fixture, check_term};
use alp::objective::{Objective, Term, TermContext, Weight, Weighting};
use alp::{Error, Result};
use autodiff::{Tape, Var};

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

fn main() -> Result<()> {
    let fixture = Fixture::new()?;
    let check = check_term(&AreaRatio, &fixture)?;
    println!("{check}");
    if !check.passes() {
        return Err(Error::invalid("area_ratio", format!("gradient check failed: {check}")));
    }

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
    Ok(())
}
