//! The transport as a tape op: `rendered = A env`, its vector-Jacobian
//! product `grad_env += A^T grad_rendered` ([`Transport::pull_back`]). Any
//! loss over the re-rendered pixels or the map, written in tape ops, is then
//! differentiated through the light transport at a fixed pose, without a
//! render per evaluation.

use std::sync::{Arc, Mutex};

use autodiff::{CustomOp, Tape, Var};

use super::{PullBackScratch, Transport};

/// `A env` on the tape: the input is the map (texel-major RGB, as
/// [`crate::lookup::ImageVars`] holds it), the output the pixels' radiance,
/// channel-planar (all red, then green, then blue).
pub struct TransportOp {
    transport: Arc<Transport>,
    /// The pixels' RGB and the pull-back's sums, reused from call to call
    /// (a solve evaluates the op a few hundred times).
    scratch: Mutex<(Vec<[f64; 3]>, PullBackScratch)>,
}

impl TransportOp {
    /// The op of `transport`.
    pub fn new(transport: Arc<Transport>) -> Self {
        TransportOp {
            transport,
            scratch: Mutex::default(),
        }
    }

    /// The pixels' radiance (one array a channel, in the transport's pixel
    /// order) under the map `env` on `tape`, differentiable in `env`.
    /// Panics unless `env` holds the transport's texels (a programming error).
    pub fn render<'t>(self: &Arc<Self>, tape: &'t Tape<f64>, env: Var<'t, f64>) -> [Var<'t, f64>; 3] {
        let pixels = self.transport.pixels;
        let planar = tape.custom(self.clone(), &[env]);
        std::array::from_fn(|c| planar.slice(c * pixels, pixels))
    }
}

impl CustomOp<f64> for TransportOp {
    fn name(&self) -> &str {
        "transport"
    }

    fn output_len(&self, input_lens: &[usize]) -> usize {
        assert!(
            input_lens == [self.transport.unknowns()],
            "transport op: takes one map of {} values (texel-major RGB), got {input_lens:?}",
            self.transport.unknowns()
        );
        3 * self.transport.pixels
    }

    fn forward(&self, inputs: &[&[f64]], output: &mut [f64]) {
        let pixels = self.transport.pixels;
        let mut scratch = self.scratch.lock().unwrap_or_else(|e| e.into_inner());
        let rendered = &mut scratch.0;
        rendered.resize(pixels, [0.0; 3]);
        self.transport.apply(inputs[0], rendered);
        for (p, rgb) in rendered.iter().enumerate() {
            (0..3).for_each(|c| output[c * pixels + p] = rgb[c]);
        }
    }

    fn vjp(&self, _inputs: &[&[f64]], _output: &[f64], grad_output: &[f64], grad_inputs: &mut [Option<&mut [f64]>]) {
        let Some(grad_env) = grad_inputs[0].as_deref_mut() else {
            return;
        };
        let pixels = self.transport.pixels;
        let mut scratch = self.scratch.lock().unwrap_or_else(|e| e.into_inner());
        let (r, sums) = &mut *scratch;
        r.clear();
        r.extend((0..pixels).map(|p| std::array::from_fn(|c| grad_output[c * pixels + p])));
        self.transport.pull_back_with(r, grad_env, sums);
    }
}

#[cfg(test)]
mod tests {
    use autodiff::gradcheck::{Input, gradcheck, uniform};
    use glam::Vec2;

    use super::*;

    /// A transport of `pixels` pixels onto a 16 x 8 map, several samples a
    /// pixel, some reading the same texels.
    fn transport(pixels: usize) -> Arc<Transport> {
        let (mut segment, mut uv, mut throughput) = (Vec::new(), Vec::new(), Vec::new());
        for k in 0..12 * pixels as u32 {
            segment.push(k % pixels as u32);
            uv.push(Vec2::new((k as f32 * 0.137).fract(), (k as f32 * 0.291).fract()));
            throughput.push([0.5 + 0.01 * k as f32, 0.3, 0.1]);
        }
        Arc::new(Transport::new(&segment, &uv, &throughput, pixels, 16, 8))
    }

    #[test]
    fn the_op_renders_as_the_transport_and_its_gradient_is_the_adjoint() {
        let transport = transport(5);
        let op = Arc::new(TransportOp::new(transport.clone()));
        let env = uniform(transport.unknowns(), 0.1, 2.0, 3);
        let tape = Tape::<f64>::new();
        let rendered = op.render(&tape, tape.constant(&env));
        let mut want = vec![[0.0; 3]; 5];
        transport.apply(&env, &mut want);
        for c in 0..3 {
            let got = tape.to_vec(rendered[c]);
            assert_eq!(got, want.iter().map(|p| p[c]).collect::<Vec<_>>(), "channel {c}");
        }
        // A loss non-linear in the pixels and in the map, through the op.
        let report = gradcheck(&[Input::Var(env)], |t, x| {
            let [r, g, b] = op.render(t, x[0]);
            (r * g).sum() + b.sin().sum() + (x[0] * x[0]).sum() * 0.1
        });
        assert!(report.worst_rel_error < 1e-6, "{report}");
    }
}
