//! A user-defined op: the cumulative sum, with its forward and its
//! vector-Jacobian product, becomes a first-class node of the tape.
//!
//! `cargo run --release -p autodiff --example custom_op`

use std::sync::Arc;

use autodiff::gradcheck::{Input, gradcheck, uniform};
use autodiff::{CustomOp, Real, Tape};

/// y[i] = x[0] + ... + x[i].
struct CumulativeSum;

impl<T: Real> CustomOp<T> for CumulativeSum {
    fn name(&self) -> &str {
        "cumulative_sum"
    }

    fn output_len(&self, input_lens: &[usize]) -> usize {
        assert_eq!(input_lens.len(), 1, "cumulative_sum takes one input");
        input_lens[0]
    }

    fn forward(&self, inputs: &[&[T]], output: &mut [T]) {
        let mut acc = T::zero();
        for (y, &x) in output.iter_mut().zip(inputs[0]) {
            acc += x;
            *y = acc;
        }
    }

    /// dL/dx[j] = sum over i >= j of dL/dy[i]: a cumulative sum from the end.
    fn vjp(&self, _inputs: &[&[T]], _output: &[T], grad_output: &[T], grad_inputs: &mut [Option<&mut [T]>]) {
        if let Some(gx) = grad_inputs[0].as_deref_mut() {
            let mut acc = T::zero();
            for (g, &gy) in gx.iter_mut().zip(grad_output).rev() {
                acc += gy;
                *g += acc;
            }
        }
    }
}

fn main() {
    let tape = Tape::<f32>::new();
    let x = tape.leaf(&[1.0, 2.0, 3.0, 4.0]);
    let op: Arc<dyn CustomOp<f32>> = Arc::new(CumulativeSum);
    let running = tape.custom(op, &[x]);
    let loss = (running * running).sum();
    tape.backward(loss);
    println!(
        "cumulative sum {:?}, loss {}",
        &*tape.value(running),
        tape.value(loss)[0]
    );
    println!("gradient {:?}", &*tape.grad(x));

    // Gradients verified, not trusted: the custom op inside a larger program.
    let op: Arc<dyn CustomOp<f64>> = Arc::new(CumulativeSum);
    let report = gradcheck(&[Input::Var(uniform(16, -1.0, 1.0, 1))], |t, v| {
        t.custom(op.clone(), &[v[0].sin()]).exp()
    });
    println!("gradient check: {report}");
    assert!(report.worst_rel_error < 1e-6);
}
