//! Custom ops on the tape: its constructor and its tests. What it
//! computes, forward and backward, is `kernels::custom`.

use std::sync::Arc;

use crate::exec::Op;
use crate::kernels::custom::{CustomOp, MAX_INPUTS};
use crate::real::Real;
use crate::tape::{Tape, Var};

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

#[cfg(test)]
mod tests {
    use std::sync::Arc;

    use super::CustomOp;
    use crate::gradcheck::{Input, gradcheck, uniform};
    use crate::ops::tests::TOL;
    use crate::{Real, Tape};

    /// `y[i] = s x[i] x[i + 1]` for inputs `(x, s)`, `s` of length 1.
    struct NeighbourProduct;

    impl<T: Real> CustomOp<T> for NeighbourProduct {
        fn name(&self) -> &str {
            "neighbour_product"
        }

        fn output_len(&self, input_lens: &[usize]) -> usize {
            input_lens[0] - 1
        }

        fn forward(&self, inputs: &[&[T]], output: &mut [T]) {
            let (x, s) = (inputs[0], inputs[1][0]);
            for (i, y) in output.iter_mut().enumerate() {
                *y = s * x[i] * x[i + 1];
            }
        }

        fn vjp(&self, inputs: &[&[T]], _output: &[T], grad_output: &[T], grad_inputs: &mut [Option<&mut [T]>]) {
            let (x, s) = (inputs[0], inputs[1][0]);
            if let Some(gx) = grad_inputs[0].as_deref_mut() {
                for (i, &gy) in grad_output.iter().enumerate() {
                    gx[i] += gy * s * x[i + 1];
                    gx[i + 1] += gy * s * x[i];
                }
            }
            if let Some(gs) = grad_inputs[1].as_deref_mut() {
                for (i, &gy) in grad_output.iter().enumerate() {
                    gs[0] += gy * x[i] * x[i + 1];
                }
            }
        }
    }

    #[test]
    fn custom_op_runs_its_forward_and_vjp() {
        let tape = Tape::<f64>::new();
        let op: Arc<dyn CustomOp<f64>> = Arc::new(NeighbourProduct);
        let y = tape.custom(op, &[tape.constant(&[1.0, 2.0, 3.0]), tape.scalar(2.0)]);
        assert_eq!(&*tape.value(y), &[4.0, 12.0]);
        for scale in [Input::Var(vec![0.7]), Input::Const(vec![0.7])] {
            let r = gradcheck(&[Input::Var(uniform(9, -1.0, 1.0, 14)), scale], |t, x| {
                let op: Arc<dyn CustomOp<f64>> = Arc::new(NeighbourProduct);
                t.custom(op, &[x[0].exp(), x[1]]).sin()
            });
            assert!(r.worst_rel_error < TOL, "custom: {r}");
        }
    }

    /// `y[i] = a[i] b[i]` for inputs `(a, b)`.
    struct Product;

    impl<T: Real> CustomOp<T> for Product {
        fn name(&self) -> &str {
            "product"
        }

        fn output_len(&self, input_lens: &[usize]) -> usize {
            input_lens[0]
        }

        fn forward(&self, inputs: &[&[T]], output: &mut [T]) {
            for (i, y) in output.iter_mut().enumerate() {
                *y = inputs[0][i] * inputs[1][i];
            }
        }

        fn vjp(&self, inputs: &[&[T]], _output: &[T], grad_output: &[T], grad_inputs: &mut [Option<&mut [T]>]) {
            for k in 0..2 {
                if let Some(g) = grad_inputs[k].as_deref_mut() {
                    for (i, &gy) in grad_output.iter().enumerate() {
                        g[i] += gy * inputs[1 - k][i];
                    }
                }
            }
        }
    }

    #[test]
    fn an_input_listed_twice_gets_both_its_gradients() {
        // `product(x, x)` is x^2: both listings' products reach x.
        let r = gradcheck(&[Input::Var(uniform(5, 0.5, 1.5, 3))], |t, x| {
            let op: Arc<dyn CustomOp<f64>> = Arc::new(Product);
            t.custom(op, &[x[0], x[0]]).sin()
        });
        assert!(r.worst_rel_error < TOL, "custom with a repeated input: {r}");
    }
}
