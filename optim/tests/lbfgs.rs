//! L-BFGS on the problems: exact minimizers, SciPy's evaluation count, bounds.

mod common;

use common::max_abs_diff;
use optim::problems::{Lighting, Quadratic, Rosenbrock, bounded_quadratic};
use optim::{Bounds, Lbfgs, OptimError, Solver, State, Termination};

/// SciPy 1.17.1, `scipy.optimize.minimize(fun, x0, jac=True, method="L-BFGS-B",
/// options={"maxcor": 10, "gtol": 1e-10, "ftol": 0.0, "maxiter": 10000, "maxfun": 100000})`
/// on `rosen`/`rosen_der` with n = 100, x0 = [-1.2, 1, -1.2, 1, ...]
/// (script: optim/tests/scipy_rosenbrock100.py). Function evaluations until the first
/// iterate with max|x - 1| <= 1e-8:
const SCIPY_NFEV_TO_1E8: usize = 634;
/// ... and until its projected-gradient test (pgtol 1e-10) ended the run (nit = 544):
const SCIPY_NFEV_TOTAL: usize = 647;
/// Evaluations over SciPy's counts that rounding accounts for: over 600
/// evaluations of Rosenbrock's valley, the order in which a dot product adds
/// its terms moves the count by one or two either way.
const ROUNDING_EVALS: usize = 3;

fn lbfgs_tight() -> optim::LbfgsBuilder {
    Lbfgs::builder().grad_tol(1e-10).cost_tol(0.0)
}

#[test]
fn quadratics_reach_their_minimizers() -> Result<(), OptimError> {
    for (condition, max_evals) in [(10.0, 50), (1e4, 1100)] {
        let mut f = Quadratic::conditioned(30, condition);
        let state = lbfgs_tight().build()?.minimize(&mut f, vec![0.0; 30])?;
        assert_eq!(
            state.termination,
            Some(Termination::GradientTolerance),
            "condition {condition}"
        );
        let err = max_abs_diff(&state.best_x, f.minimizer());
        assert!(err < 1e-9, "condition {condition}: error {err}");
        assert!(state.evals <= max_evals, "condition {condition}: {} evals", state.evals);
    }
    Ok(())
}

#[test]
fn rosenbrock_2_converges() -> Result<(), OptimError> {
    let state = lbfgs_tight().build()?.minimize(&mut Rosenbrock, vec![-1.2, 1.0])?;
    assert_eq!(state.termination, Some(Termination::GradientTolerance));
    assert!(max_abs_diff(&state.best_x, &[1.0, 1.0]) < 1e-9, "{:?}", state.best_x);
    assert!(state.evals < 60, "{} evals", state.evals);
    Ok(())
}

#[test]
fn rosenbrock_100_needs_no_more_evaluations_than_scipy() -> Result<(), OptimError> {
    let mut reached = None;
    let mut record = |s: &State| {
        if reached.is_none() && max_abs_diff(&s.x, &[1.0; 100]) <= 1e-8 {
            reached = Some(s.evals);
        }
    };
    let state = lbfgs_tight()
        .build()?
        .minimize_observed(&mut Rosenbrock, Rosenbrock::start(100), &mut record)?;
    assert_eq!(state.termination, Some(Termination::GradientTolerance));
    let reached = reached.expect("L-BFGS never came within 1e-8 of the minimizer");
    eprintln!(
        "rosenbrock_100: 1e-8 after {reached} evals (SciPy {SCIPY_NFEV_TO_1E8}), {} total (SciPy {SCIPY_NFEV_TOTAL})",
        state.evals
    );
    assert!(
        reached <= SCIPY_NFEV_TO_1E8 + ROUNDING_EVALS,
        "{reached} evals to 1e-8, SciPy needs {SCIPY_NFEV_TO_1E8}"
    );
    assert!(
        state.evals <= SCIPY_NFEV_TOTAL + ROUNDING_EVALS,
        "{} evals in total, SciPy needs {SCIPY_NFEV_TOTAL}",
        state.evals
    );
    Ok(())
}

#[test]
fn bounded_minimum_lands_exactly_on_the_bounds() -> Result<(), OptimError> {
    let mut f = bounded_quadratic(21);
    let bounds = Bounds::uniform(21, 0.0, 1.0)?;
    let state = lbfgs_tight().bounds(bounds).build()?.minimize(&mut f, vec![0.5; 21])?;
    // f* = 1.7 is far from 0, so rounding in f limits x to about sqrt(eps f* / lambda_min) ~ 2e-8;
    // the run ends when a step can no longer decrease f.
    assert!(
        state.termination.is_some_and(|t| t.converged()),
        "{:?}",
        state.termination
    );
    assert!(max_abs_diff(&state.best_x, f.minimizer()) < 1e-7);
    for i in (0..21).step_by(3) {
        // Projection puts active coordinates exactly on the bound, not near it.
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
fn nonnegative_lighting_solve_is_fast_and_exact() -> Result<(), OptimError> {
    let mut f = Lighting::new(64, 0.05);
    let bounds = Bounds::uniform(64, 0.0, f64::INFINITY)?;
    let state = lbfgs_tight().bounds(bounds).build()?.minimize(&mut f, vec![1.0; 64])?;
    assert!(
        state.termination.is_some_and(|t| t.converged()),
        "{:?}",
        state.termination
    );
    assert!(max_abs_diff(&state.best_x, f.minimizer()) < 1e-7);
    let dark = f.minimizer().iter().filter(|&&x| x == 0.0).count();
    assert!(dark > 10 && state.best_x.iter().filter(|&&x| x == 0.0).count() == dark);
    assert!(state.evals < 60, "{} evals", state.evals);
    Ok(())
}

#[test]
fn each_budget_and_tolerance_is_reported_as_the_reason() -> Result<(), OptimError> {
    let x0 = Rosenbrock::start(10);
    let by_iters = Lbfgs::builder()
        .max_iters(5)
        .build()?
        .minimize(&mut Rosenbrock, x0.clone())?;
    assert_eq!((by_iters.termination, by_iters.iter), (Some(Termination::MaxIters), 5));
    let by_evals = Lbfgs::builder()
        .max_evals(7)
        .build()?
        .minimize(&mut Rosenbrock, x0.clone())?;
    assert_eq!((by_evals.termination, by_evals.evals), (Some(Termination::MaxEvals), 7));
    let by_cost = Lbfgs::builder()
        .grad_tol(0.0)
        .cost_tol(1e-3)
        .build()?
        .minimize(&mut Rosenbrock, x0.clone())?;
    assert_eq!(by_cost.termination, Some(Termination::CostChange));
    let by_grad = Lbfgs::builder()
        .grad_tol(1e-3)
        .cost_tol(0.0)
        .build()?
        .minimize(&mut Rosenbrock, x0)?;
    assert_eq!(by_grad.termination, Some(Termination::GradientTolerance));
    assert!(by_grad.grad_norm <= 1e-3);
    Ok(())
}

#[test]
fn wrong_lengths_and_settings_are_errors() {
    let bounds = Bounds::uniform(3, 0.0, 1.0).expect("valid bounds");
    let err = Lbfgs::builder()
        .bounds(bounds)
        .build()
        .and_then(|mut s| s.minimize(&mut Rosenbrock, vec![0.0; 4]));
    assert_eq!(
        err.unwrap_err(),
        OptimError::WrongLength {
            field: "x0",
            expected: 3,
            actual: 4
        }
    );
    assert!(Bounds::new(vec![0.0], vec![-1.0]).is_err());
    let ls = optim::MoreThuente {
        c2: 1.0,
        ..Default::default()
    };
    assert!(Lbfgs::builder().line_search(ls).build().is_err());
}

#[test]
fn observer_sees_every_iteration() -> Result<(), OptimError> {
    let mut seen = Vec::new();
    let state = Lbfgs::builder()
        .build()?
        .minimize_observed(&mut Rosenbrock, vec![-1.2, 1.0], &mut |s: &State| {
            seen.push((s.iter, s.evals, s.value))
        })?;
    assert_eq!(seen.len(), state.iter + 1);
    assert!(
        seen.windows(2)
            .all(|w| w[1].0 == w[0].0 + 1 && w[1].1 > w[0].1 && w[1].2 <= w[0].2)
    );
    Ok(())
}
