//! Adam on the problems: groups, schedules, bounds, clipping, plateaus, nonsmooth L1.

mod common;

use common::max_abs_diff;
use optim::problems::{Quadratic, Rosenbrock, WeightedL1, bounded_quadratic};
use optim::schedule::{Constant, Cosine, Decay, Warmup};
use optim::{Adam, GradClip, OptimError, ParamGroup, Plateau, Solver, Termination};

#[test]
fn well_conditioned_quadratic_converges_with_reduce_on_plateau() -> Result<(), OptimError> {
    let mut f = Quadratic::conditioned(20, 10.0);
    let plateau = Plateau {
        patience: 20,
        threshold: 0.0,
        min_scale: 1e-6,
        ..Plateau::default()
    };
    let mut adam = Adam::builder(20)
        .group(ParamGroup::new(0..20, 0.1))
        .plateau(plateau)
        .grad_tol(1e-8)
        .max_iters(5000)
        .build()?;
    let state = adam.minimize(&mut f, vec![0.0; 20])?;
    assert_eq!(state.termination, Some(Termination::GradientTolerance));
    assert!(max_abs_diff(&state.best_x, f.minimizer()) < 1e-8);
    Ok(())
}

#[test]
fn rosenbrock_2_converges_with_warmup_and_plateau() -> Result<(), OptimError> {
    let group = ParamGroup::new(0..2, 0.05).schedule(Warmup::new(20, Constant)?);
    let plateau = Plateau {
        patience: 20,
        threshold: 0.0,
        min_scale: 1e-6,
        ..Plateau::default()
    };
    let mut adam = Adam::builder(2)
        .group(group)
        .plateau(plateau)
        .grad_tol(1e-8)
        .max_iters(10_000)
        .build()?;
    let state = adam.minimize(&mut Rosenbrock, vec![-1.2, 1.0])?;
    assert_eq!(state.termination, Some(Termination::GradientTolerance));
    assert!(max_abs_diff(&state.best_x, &[1.0, 1.0]) < 1e-7, "{:?}", state.best_x);
    Ok(())
}

#[test]
fn bounded_minimum_lands_exactly_on_the_bounds() -> Result<(), OptimError> {
    let mut f = bounded_quadratic(21);
    let group = ParamGroup::new(0..21, 0.05)
        .bounds(0.0, 1.0)
        .schedule(Cosine::new(3000, 0.0)?);
    let state = Adam::builder(21)
        .group(group)
        .max_iters(3000)
        .build()?
        .minimize(&mut f, vec![0.5; 21])?;
    assert!(
        max_abs_diff(&state.best_x, f.minimizer()) < 1e-4,
        "error {}",
        max_abs_diff(&state.best_x, f.minimizer())
    );
    for i in (0..21).step_by(3) {
        assert_eq!(
            (state.best_x[i], state.best_x[i + 1]),
            (0.0, 1.0),
            "coordinates {i}, {}",
            i + 1
        );
    }
    Ok(())
}

#[test]
fn nonsmooth_l1_converges_under_cosine_annealing() -> Result<(), OptimError> {
    let center: Vec<f64> = (0..10).map(|i| (i as f64 * 0.7).sin() * 3.0).collect();
    let weights = (0..10).map(|i| 1.0 + i as f64).collect();
    let mut f = WeightedL1 {
        center: center.clone(),
        weights,
    };
    // Subgradients never shrink near a kink, so only a rate that anneals to 0 settles.
    let group = ParamGroup::new(0..10, 0.1).schedule(Cosine::new(2000, 0.0)?);
    let state = Adam::builder(10)
        .group(group)
        .max_iters(2000)
        .build()?
        .minimize(&mut f, vec![0.0; 10])?;
    assert!(
        max_abs_diff(&state.best_x, &center) < 1e-3,
        "error {}",
        max_abs_diff(&state.best_x, &center)
    );
    assert!(state.best_value < 1e-2);
    Ok(())
}

#[test]
fn groups_keep_their_own_rates_and_bounds() -> Result<(), OptimError> {
    // "Pose" (x0, unbounded, frozen with lr 0) and "env texels" (x1..3, >= 0).
    let mut f = |x: &[f64], g: &mut [f64]| {
        g[0] = 2.0 * (x[0] - 5.0);
        let mut v = (x[0] - 5.0).powi(2);
        for i in 1..4 {
            g[i] = 2.0 * (x[i] + 1.0);
            v += (x[i] + 1.0).powi(2);
        }
        v
    };
    let mut adam = Adam::builder(4)
        .group(ParamGroup::new(0..1, 0.0))
        .group(ParamGroup::new(1..4, 0.1).bounds(0.0, f64::INFINITY))
        .max_iters(100)
        .build()?;
    let state = adam.minimize(&mut f, vec![1.0, 2.0, 0.5, 0.0])?;
    assert_eq!(state.best_x, [1.0, 0.0, 0.0, 0.0]);
    Ok(())
}

#[test]
fn value_clipping_stops_one_huge_gradient_from_dominating_the_moments() -> Result<(), OptimError> {
    // One Monte Carlo firefly (g = 1e6) then the true gradient -1. Unclipped, the first
    // moment stays positive and x keeps moving the wrong way; clipped to 1 it turns.
    let second_step = |clip: Option<GradClip>| -> Result<f64, OptimError> {
        let mut calls = 0;
        let mut f = |x: &[f64], g: &mut [f64]| {
            calls += 1;
            g[0] = if calls == 1 { 1e6 } else { -1.0 };
            -x[0]
        };
        let builder = Adam::builder(1)
            .group(ParamGroup::new(0..1, 0.1).schedule(Decay::exponential(1.0)?))
            .max_iters(2);
        let mut adam = match clip {
            Some(c) => builder.clip(c),
            None => builder,
        }
        .build()?;
        Ok(adam.minimize(&mut f, vec![0.0])?.x[0])
    };
    assert!(second_step(None)? < -0.1);
    assert!(second_step(Some(GradClip::Value(1.0)))? > -0.1);
    assert!(second_step(Some(GradClip::Norm(1.0)))? > -0.1);
    Ok(())
}

#[test]
fn plateau_at_the_rate_floor_ends_the_run() -> Result<(), OptimError> {
    // A constant objective never improves: every `patience` iterations the scale halves
    // until the floor, and one more plateau there ends the run.
    let mut flat = |_: &[f64], g: &mut [f64]| {
        g[0] = 1.0;
        1.0
    };
    let plateau = Plateau {
        patience: 5,
        factor: 0.5,
        threshold: 0.0,
        min_scale: 0.25,
    };
    let mut adam = Adam::builder(1)
        .group(ParamGroup::new(0..1, 0.1))
        .plateau(plateau)
        .build()?;
    let state = adam.minimize(&mut flat, vec![0.0])?;
    assert_eq!(state.termination, Some(Termination::Plateau));
    // Scale 1 -> 0.5 -> 0.25 after 5 and 10 iterations; the floor's plateau ends it at 15.
    assert_eq!(state.iter, 15);
    assert!((state.step_size - 0.025).abs() < 1e-15);
    Ok(())
}

#[test]
fn plateau_settings_are_validated() {
    let bad = Plateau {
        factor: 1.0,
        ..Plateau::default()
    };
    let err = Adam::builder(1)
        .group(ParamGroup::new(0..1, 0.1))
        .plateau(bad)
        .build()
        .err();
    assert!(matches!(err, Some(OptimError::InvalidSetting { ref field, .. }) if field == "plateau.factor"));
    let x0_err = Adam::builder(2)
        .group(ParamGroup::new(0..2, 0.1))
        .build()
        .and_then(|mut a| a.minimize(&mut Rosenbrock, vec![0.0; 3]));
    assert_eq!(
        x0_err.err(),
        Some(OptimError::WrongLength {
            field: "x0",
            expected: 2,
            actual: 3
        })
    );
}
