//! Tape-based reverse-mode automatic differentiation over float arrays.
//!
//! One tape node per *array* operation: a whole image of samples costs a few
//! dozen nodes, not millions. Recording is lazy; the executor runs chains of
//! elementwise ops tile by tile on all cores, so intermediates stay in cache,
//! and the backward pass recomputes them per tile instead of storing them.
//!
//! ```
//! use autodiff::Tape;
//! let tape = Tape::<f32>::new();
//! let x = tape.leaf(&[0.5, 1.0, 2.0]);
//! let loss = (x.sin() * x).sum();
//! tape.backward(loss);
//! let g = tape.grad(x);
//! assert!((g[1] - (1f32.cos() + 1f32.sin())).abs() < 1e-6);
//! ```
//!
//! - [`Tape`], [`Var`]: recording, values, gradients, `clear` / `mark` / `reset_to`.
//! - Ops are methods and operators of [`Var`] (elementwise with broadcasting,
//!   reductions, gather / scatter-add, slice / concat); [`CustomOp`] adds your own.
//! - [`Vec3`], [`Quat`]: vector fields and their rotation.
//! - [`gradcheck`](gradcheck::gradcheck): central differences in f64.

mod exec;
pub mod gradcheck;
mod kernels;
mod ops;
pub mod real;
mod tape;
mod vec3;

pub use exec::NonFinite;
pub use kernels::custom::{CustomOp, MAX_INPUTS};
pub use real::Real;
pub use tape::{Mark, Tape, Var, VarId};
pub use vec3::{Quat, Vec3};
