//! Adam and L-BFGS over plain parameter vectors and a value-and-gradient callback.
//!
//! Both solvers share the argmin-style shape of [`Solver`]: `init` evaluates the
//! start, `step` performs one iteration on an explicit [`State`] (iteration,
//! evaluations, best value and parameters, termination reason), and `terminate`
//! names the reason to stop. Builders validate their settings and return
//! [`OptimError`] naming the field and the rule. A non-finite value or gradient is
//! never written into the parameters: the step is rejected and the solver backs off
//! (Adam halves its rates, L-BFGS shortens the step) or ends with a reason.
//!
//! Which to use: [`Lbfgs`] for smooth deterministic objectives (the lighting solve
//! at a fixed pose is nearly linear in the env-map texels, i.e. a quadratic
//! objective, where it needs a few dozen evaluations); [`Adam`] for Monte Carlo
//! gradients, nonsmooth losses, or per-group rates (pose vs. env map).
//!
//! ```
//! use optim::{Adam, Bounds, Lbfgs, ParamGroup, Solver, schedule::Cosine};
//!
//! // Least squares with x >= 0: min (x0 - 1)^2 + (x1 + 2)^2, minimizer (1, 0).
//! let mut loss = |x: &[f64], g: &mut [f64]| {
//!     g[0] = 2.0 * (x[0] - 1.0);
//!     g[1] = 2.0 * (x[1] + 2.0);
//!     (x[0] - 1.0).powi(2) + (x[1] + 2.0).powi(2)
//! };
//! let mut lbfgs = Lbfgs::builder().bounds(Bounds::uniform(2, 0.0, f64::INFINITY)?).build()?;
//! let state = lbfgs.minimize(&mut loss, vec![5.0, 5.0])?;
//! assert!(state.termination.unwrap().converged());
//! assert_eq!(state.best_x[1], 0.0);
//!
//! // Adam with one group per block of parameters, e.g. pose then env-map texels.
//! let mut adam = Adam::builder(2)
//!     .group(ParamGroup::new(0..1, 0.1))
//!     .group(ParamGroup::new(1..2, 0.1).bounds(0.0, f64::INFINITY).schedule(Cosine::new(500, 0.01)?))
//!     .max_iters(500)
//!     .build()?;
//! let state = adam.minimize_observed(&mut loss, vec![5.0, 5.0], &mut |s: &optim::State| {
//!     if s.iter % 100 == 0 { eprintln!("iter {} value {:.3e}", s.iter, s.value) }
//! })?;
//! assert!((state.best_x[0] - 1.0).abs() < 1e-3 && state.best_x[1] == 0.0);
//! # Ok::<(), optim::OptimError>(())
//! ```

mod adam;
mod bounds;
mod error;
mod lbfgs;
mod linesearch;
mod objective;
pub mod problems;
pub mod schedule;
mod solver;
mod state;

pub use adam::{Adam, AdamBuilder, GradClip, ParamGroup, Plateau};
pub use bounds::Bounds;
pub use error::OptimError;
pub use lbfgs::{Lbfgs, LbfgsBuilder};
pub use linesearch::{LineSearchError, MoreThuente};
pub use objective::Objective;
pub use schedule::Schedule;
pub use solver::{Observer, Solver};
pub use state::{State, Termination};
