//! Evaluations and wall time to reach the known minimizer, Adam vs L-BFGS, per problem.
//!
//! One JSON line per (problem, method) on stdout; progress on stderr. A run stops
//! when `max|x - x*| <= TOL` (the bench knows `x*`; a solver in the field does not)
//! or when the solver ends on its own. `evals` counts value-and-gradient evaluations,
//! line-search trials included. Run with
//! `CARGO_TARGET_DIR=/work/target-optim cargo bench --bench optim_convergence`.

use std::time::Instant;

use optim::problems::{Case, suite};
use optim::{Adam, Lbfgs, Objective, OptimError, ParamGroup, Plateau, Solver, State};
use serde_json::json;

/// Distance to the minimizer (infinity norm) that counts as solved.
const TOL: f64 = 1e-6;
/// Timed runs per case, after one untimed warm-up run.
const RUNS: usize = 5;

/// Runs `solver` from `x0` until within `TOL` of `minimizer` or until it terminates.
fn solve<S: Solver>(solver: &mut S, objective: &mut Box<dyn Objective>, x0: &[f64], minimizer: &[f64]) -> (State, f64) {
    let mut state = solver.init(objective, x0.to_vec()).expect("bench settings are valid");
    loop {
        let err = x_err(&state.x, minimizer);
        if err <= TOL {
            return (state, err);
        }
        state.termination = state.termination.or_else(|| solver.terminate(&state));
        if state.termination.is_some() {
            return (state, err);
        }
        solver.step(objective, &mut state);
        state.iter += 1;
    }
}

fn x_err(x: &[f64], minimizer: &[f64]) -> f64 {
    x.iter().zip(minimizer).map(|(a, b)| (a - b).abs()).fold(0.0, f64::max)
}

fn lbfgs(case: &Case) -> Result<Lbfgs, OptimError> {
    // Tolerances off: the bench's own x-error test decides when the run is done.
    Lbfgs::builder()
        .bounds(case.bounds.clone())
        .grad_tol(0.0)
        .cost_tol(0.0)
        .max_evals(50_000)
        .build()
}

fn adam(case: &Case) -> Result<Adam, OptimError> {
    let n = case.x0.len();
    let (lo, hi) = (case.bounds.lower()[0], case.bounds.upper()[0]);
    // Reduce-on-plateau lets a constant-rate Adam settle instead of hovering at the scale of its rate.
    let plateau = Plateau {
        patience: 20,
        factor: 0.5,
        threshold: 0.0,
        min_scale: 1e-6,
    };
    Adam::builder(n)
        .group(ParamGroup::new(0..n, case.adam_lr).bounds(lo, hi))
        .plateau(plateau)
        .max_iters(50_000)
        .build()
}

fn report<S: Solver>(case: &mut Case, method: &str, make: fn(&Case) -> Result<S, OptimError>) {
    let mut times = Vec::with_capacity(RUNS);
    let mut last = None;
    for run in 0..=RUNS {
        let mut solver = make(case).expect("bench settings are valid");
        let start = Instant::now();
        let result = solve(&mut solver, &mut case.objective, &case.x0, &case.minimizer);
        if run > 0 {
            times.push(start.elapsed().as_secs_f64());
        }
        last = Some(result);
    }
    times.sort_by(f64::total_cmp);
    let (state, err) = last.expect("at least one run");
    eprintln!(
        "{:>18} {method:>5}: {} evals, x_err {err:.1e}, ended: {}",
        case.name,
        state.evals,
        state
            .termination
            .map_or("reached tolerance".to_string(), |t| t.to_string())
    );
    let line = json!({
        "bench": "optim_convergence",
        "impl": method,
        "mode": case.name,
        "threads": 1,
        "evals": state.evals,
        "iters": state.iter,
        "final_value": state.value,
        "reached_tol": err <= TOL,
        "median_s": times[times.len() / 2],
        "min_s": times[0],
        "runs": RUNS,
        "check": {"x_err": err, "tol": TOL},
    });
    println!("{line}");
}

fn main() {
    for mut case in suite() {
        report(&mut case, "adam", adam);
        report(&mut case, "lbfgs", lbfgs);
    }
}
