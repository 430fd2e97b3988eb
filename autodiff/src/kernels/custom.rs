//! User-defined ops: a forward `y = f(x_0, ..., x_k)` and a vector-Jacobian
//! product over whole arrays become a first-class node (see
//! `examples/custom_op.rs`).
//!
//! VJP, with `gx_j = dL/dx_j` and `gy = dL/dy`: `gx_j += gy * dy/dx_j`, as
//! the op's own [`CustomOp::vjp`] computes it.
//!
//! Structural: the tape cannot see inside the op, so it runs as a plain step
//! over whole arrays, never within a region's tiles.

use crate::real::Real;

/// Most inputs a custom op may take.
pub const MAX_INPUTS: usize = 8;

/// An op supplied by the user: forward and vector-Jacobian product.
pub trait CustomOp<T: Real>: Send + Sync {
    /// Name, for messages.
    fn name(&self) -> &str;
    /// Output length for the given input lengths (panic on a shape the op refuses).
    fn output_len(&self, input_lens: &[usize]) -> usize;
    /// Writes the output (every element).
    fn forward(&self, inputs: &[&[T]], output: &mut [T]);
    /// Adds `grad_output` times the Jacobian into each wanted input gradient
    /// (`None`: that input needs no gradient). Gradients must be *added*.
    fn vjp(&self, inputs: &[&[T]], output: &[T], grad_output: &[T], grad_inputs: &mut [Option<&mut [T]>]);
}

/// Forward: the op's output from its inputs' values (at most [`MAX_INPUTS`]).
pub(crate) fn forward<'a, T: Real>(op: &dyn CustomOp<T>, inputs: impl Iterator<Item = &'a [T]>, output: &mut [T]) {
    let mut values: [&[T]; MAX_INPUTS] = [&[]; MAX_INPUTS];
    let mut num = 0;
    for (slot, x) in values.iter_mut().zip(inputs) {
        *slot = x;
        num += 1;
    }
    op.forward(&values[..num], output);
}

/// VJP: the op adds `grad_output` times its Jacobian into the gradients of
/// its inputs, given in order with their values (None: no gradient flows
/// there). No two gradients may alias: the caller gives an input listed
/// twice its gradient once.
pub(crate) fn backward<'a, T: Real>(
    op: &dyn CustomOp<T>,
    inputs: impl Iterator<Item = (&'a [T], Option<&'a mut [T]>)>,
    output: &[T],
    grad_output: &[T],
) {
    let mut values: [&[T]; MAX_INPUTS] = [&[]; MAX_INPUTS];
    let mut grads: [Option<&mut [T]>; MAX_INPUTS] = Default::default();
    let mut num = 0;
    for ((x, g), (value, grad)) in inputs.zip(values.iter_mut().zip(&mut grads)) {
        *value = x;
        *grad = g;
        num += 1;
    }
    op.vjp(&values[..num], output, grad_output, &mut grads[..num]);
}
