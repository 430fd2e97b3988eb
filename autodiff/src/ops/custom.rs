//! User-defined ops: a forward and a vector-Jacobian product over whole
//! arrays become a first-class node (see `examples/custom_op.rs`).

use std::sync::Arc;

use crate::real::Real;
use crate::tape::{Op, Tape, Var};

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

impl<T: Real> Tape<T> {
    /// Records a user op on `inputs`. The `Arc` is stored as is (cloning it
    /// every iteration allocates nothing).
    pub fn custom<'t>(&'t self, op: Arc<dyn CustomOp<T>>, inputs: &[Var<'t, T>]) -> Var<'t, T> {
        assert!(
            !inputs.is_empty() && inputs.len() <= MAX_INPUTS,
            "custom op `{}`: takes 1 to {MAX_INPUTS} inputs, got {}",
            op.name(),
            inputs.len()
        );
        let mut lens = [0usize; MAX_INPUTS];
        for (k, v) in inputs.iter().enumerate() {
            assert!(
                std::ptr::eq(v.tape, self),
                "custom op `{}`: operands live on different tapes",
                op.name()
            );
            lens[k] = v.len();
        }
        let len = op.output_len(&lens[..inputs.len()]);
        assert!(
            len > 0,
            "custom op `{}`: the output needs at least one element",
            op.name()
        );
        let index = {
            let mut g = self.graph.borrow_mut();
            g.customs.push(op);
            g.customs.len() as u32 - 1
        };
        self.record(Op::Custom(index), len, inputs)
    }
}
