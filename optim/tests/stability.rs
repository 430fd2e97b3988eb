//! Non-finite values, a zero gradient at the start, and noisy gradients, for both solvers.

mod common;

use common::{NoisyQuadratic, Rng, max_abs_diff};
use optim::schedule::Decay;
use optim::{Adam, Lbfgs, OptimError, ParamGroup, Solver, Termination};

/// `sum log cosh(x_i - 2)`, but NaN (value and gradient) wherever some `x_i > 3`.
///
/// Far from 2 the slope is almost constant, so a line search extrapolates boldly
/// and runs into the NaN region.
fn nan_beyond_three(x: &[f64], g: &mut [f64]) -> f64 {
    if x.iter().any(|&v| v > 3.0) {
        g.fill(f64::NAN);
        return f64::NAN;
    }
    x.iter()
        .zip(g.iter_mut())
        .map(|(&v, gi)| {
            *gi = (v - 2.0).tanh();
            (v - 2.0).cosh().ln()
        })
        .sum()
}

#[test]
fn lbfgs_steps_around_a_nan_region() -> Result<(), OptimError> {
    // From x0 = (-10, -30) the extrapolating line search overshoots beyond 3 (NaN).
    let mut f = nan_beyond_three;
    let state = Lbfgs::builder().build()?.minimize(&mut f, vec![-10.0, -30.0])?;
    assert!(state.rejected > 0, "the test should exercise a rejection");
    assert_eq!(state.termination, Some(Termination::GradientTolerance));
    assert!(max_abs_diff(&state.best_x, &[2.0, 2.0]) < 1e-5);
    Ok(())
}

#[test]
fn adam_backs_off_from_a_nan_region() -> Result<(), OptimError> {
    // lr 2 overshoots into NaN; each rejection halves the rate until steps fit.
    let mut f = nan_beyond_three;
    let mut adam = Adam::builder(2)
        .group(ParamGroup::new(0..2, 2.0).schedule(Decay::exponential(0.995)?))
        .max_iters(2000)
        .build()?;
    let state = adam.minimize(&mut f, vec![1.5, 2.5])?;
    assert!(state.rejected > 0 && state.restarts == state.rejected);
    assert!(state.x.iter().all(|v| v.is_finite()) && state.value.is_finite());
    assert!(max_abs_diff(&state.best_x, &[2.0, 2.0]) < 1e-3, "{:?}", state.best_x);
    Ok(())
}

#[test]
fn a_non_finite_start_ends_the_run_and_keeps_x0() -> Result<(), OptimError> {
    let mut inf = |_: &[f64], g: &mut [f64]| {
        g.fill(0.0);
        f64::INFINITY
    };
    let lbfgs = Lbfgs::builder().build()?.minimize(&mut inf, vec![1.0, 2.0])?;
    let adam = Adam::builder(2)
        .group(ParamGroup::new(0..2, 0.1))
        .build()?
        .minimize(&mut inf, vec![1.0, 2.0])?;
    for state in [lbfgs, adam] {
        assert_eq!(
            (state.termination, state.evals, state.iter),
            (Some(Termination::NonFinite), 1, 0)
        );
        assert_eq!(state.best_x, [1.0, 2.0]);
    }
    Ok(())
}

#[test]
fn adam_ends_when_every_step_is_non_finite() -> Result<(), OptimError> {
    let mut calls = 0;
    let mut cliff = |x: &[f64], g: &mut [f64]| {
        calls += 1;
        g[0] = -1.0;
        if calls == 1 { -x[0] } else { f64::NAN }
    };
    let state = Adam::builder(1)
        .group(ParamGroup::new(0..1, 0.1))
        .max_backoffs(4)
        .build()?
        .minimize(&mut cliff, vec![0.0])?;
    assert_eq!((state.termination, state.rejected), (Some(Termination::NonFinite), 5));
    assert_eq!(state.x, [0.0]);
    Ok(())
}

#[test]
fn lbfgs_reports_a_line_search_that_cannot_descend() -> Result<(), OptimError> {
    // A gradient that lies (points uphill): no step along -g decreases f, even after the restart.
    let mut liar = |x: &[f64], g: &mut [f64]| {
        g[0] = -2.0 * x[0];
        x[0] * x[0]
    };
    let state = Lbfgs::builder().build()?.minimize(&mut liar, vec![1.0])?;
    assert!(
        matches!(state.termination, Some(Termination::LineSearchFailed(_))),
        "{:?}",
        state.termination
    );
    assert_eq!((state.best_x[0], state.best_value), (1.0, 1.0));
    Ok(())
}

#[test]
fn zero_gradient_at_the_start_stops_at_once() -> Result<(), OptimError> {
    // x0 is the maximum of -x^2: a stationary point where no first-order method can move.
    let mut hill = |x: &[f64], g: &mut [f64]| {
        g[0] = -2.0 * x[0];
        -x[0] * x[0]
    };
    let lbfgs = Lbfgs::builder().build()?.minimize(&mut hill, vec![0.0])?;
    let adam = Adam::builder(1)
        .group(ParamGroup::new(0..1, 0.1))
        .build()?
        .minimize(&mut hill, vec![0.0])?;
    for state in [lbfgs, adam] {
        assert_eq!(
            (state.termination, state.evals, state.x[0]),
            (Some(Termination::GradientTolerance), 1, 0.0)
        );
    }
    Ok(())
}

fn noisy(declared: bool) -> NoisyQuadratic {
    NoisyQuadratic {
        center: (0..10).map(|i| i as f64 * 0.5 - 2.0).collect(),
        sigma: 0.5,
        rng: Rng(0x9e3779b97f4a7c15),
        declared,
    }
}

#[test]
fn lbfgs_refuses_a_declared_stochastic_objective() {
    let err = Lbfgs::builder()
        .build()
        .and_then(|mut s| s.minimize(&mut noisy(true), vec![0.0; 10]));
    assert_eq!(err.unwrap_err(), OptimError::StochasticObjective { solver: "Lbfgs" });
}

#[test]
fn lbfgs_degrades_gracefully_on_undeclared_noise_while_adam_converges() -> Result<(), OptimError> {
    let mut f = noisy(false);
    let center = f.center.clone();
    let start_err = max_abs_diff(&[0.0; 10], &center);
    let lbfgs = Lbfgs::builder()
        .max_evals(2000)
        .build()?
        .minimize(&mut f, vec![0.0; 10])?;
    // It must end with a reason, finite parameters, and no worse than it started.
    assert!(lbfgs.termination.is_some() && lbfgs.best_x.iter().all(|v| v.is_finite()));
    assert!(max_abs_diff(&lbfgs.best_x, &center) < start_err);

    let group = ParamGroup::new(0..10, 0.1).schedule(Decay::exponential(0.998)?);
    let adam = Adam::builder(10)
        .group(group)
        .max_iters(3000)
        .build()?
        .minimize(&mut f, vec![0.0; 10])?;
    let adam_err = max_abs_diff(&adam.x, &center);
    assert!(adam_err < 0.05, "Adam error {adam_err}");
    eprintln!(
        "noisy: L-BFGS ended by {:?} at error {:.2e}; Adam error {adam_err:.2e}",
        lbfgs.termination,
        max_abs_diff(&lbfgs.best_x, &center)
    );
    Ok(())
}
