//! A prior over the map's texels written as a value and its gradient (the
//! lighting solve's priors: the neighbour smoothness, the latitude prior),
//! and the tape op that records one.

use std::sync::{Arc, Mutex};

use autodiff::{CustomOp, Var};

use super::{PriorBasis, TermContext};
use crate::error::{Error, Result};

/// A prior over an env map (texel-major RGB).
pub trait MapPrior: Send + Sync {
    /// Returns the prior's value at `x` and adds its gradient to `g`.
    fn add_value_and_gradient(&self, x: &[f64], g: &mut [f64]) -> f64;

    /// Per texel of the map's `texels`, the prior's curvature in one
    /// channel (at small differences, for the solve's preconditioner).
    fn texel_curvature(&self, texels: usize) -> Vec<f64>;
}

/// Per texel of the map's `texels`, the summed curvature of `priors` (in
/// one channel, at small differences).
pub fn summed_curvature(priors: &[Box<dyn MapPrior>], texels: usize) -> Vec<f64> {
    let mut curvature = vec![0.0; texels];
    for prior in priors {
        curvature
            .iter_mut()
            .zip(prior.texel_curvature(texels))
            .for_each(|(a, b)| *a += b);
    }
    curvature
}

/// The term `name`'s value on `ctx`'s tape: the prior `make` builds on the
/// lighting solve's basis, over the map on the tape (`None` where the phase
/// holds no map or no basis).
pub fn record_map_prior<'t, P: MapPrior + 'static>(
    ctx: &TermContext<'_, 't>,
    name: &'static str,
    make: impl FnOnce(&PriorBasis) -> P,
) -> Result<Option<Var<'t, f64>>> {
    let (Some(env), Some(lighting)) = (ctx.env, ctx.lighting) else {
        return Ok(None);
    };
    let basis = &lighting.basis;
    if (env.width, env.height) != (basis.width, basis.height) {
        return Err(Error::invalid(
            name,
            format!(
                "the map on the tape is {}x{} but the solve's basis {}x{}",
                env.width, env.height, basis.width, basis.height
            ),
        ));
    }
    let op = Arc::new(MapPriorOp::new(name, make(basis)));
    Ok(Some(ctx.tape.custom(op, &[env.texels])))
}

/// A [`MapPrior`] as one tape op over the map's texels, named for reports.
pub struct MapPriorOp<P> {
    name: &'static str,
    prior: P,
    /// The prior's gradient, a buffer reused from call to call.
    gradient: Mutex<Vec<f64>>,
}

impl<P: MapPrior> MapPriorOp<P> {
    /// The op of `prior`, called `name`.
    pub fn new(name: &'static str, prior: P) -> Self {
        MapPriorOp {
            name,
            prior,
            gradient: Mutex::default(),
        }
    }

    /// The prior it records.
    pub fn into_prior(self) -> P {
        self.prior
    }

    /// The prior's value at `x`, its gradient left in `gradient`.
    fn evaluate(&self, x: &[f64], gradient: &mut Vec<f64>) -> f64 {
        gradient.clear();
        gradient.resize(x.len(), 0.0);
        self.prior.add_value_and_gradient(x, gradient)
    }
}

impl<P: MapPrior> CustomOp<f64> for MapPriorOp<P> {
    fn name(&self) -> &str {
        self.name
    }

    fn output_len(&self, _input_lens: &[usize]) -> usize {
        1
    }

    fn forward(&self, inputs: &[&[f64]], output: &mut [f64]) {
        let mut gradient = self.gradient.lock().unwrap_or_else(|e| e.into_inner());
        output[0] = self.evaluate(inputs[0], &mut gradient);
    }

    fn vjp(&self, inputs: &[&[f64]], _output: &[f64], grad_output: &[f64], grad_inputs: &mut [Option<&mut [f64]>]) {
        let Some(grad) = grad_inputs[0].as_deref_mut() else {
            return;
        };
        let mut gradient = self.gradient.lock().unwrap_or_else(|e| e.into_inner());
        self.evaluate(inputs[0], &mut gradient);
        grad.iter_mut()
            .zip(gradient.iter())
            .for_each(|(a, b)| *a += grad_output[0] * b);
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    /// Checks `prior`'s gradient against central differences at `x`, and the
    /// tape op's against the tape's gradient check.
    pub(crate) fn check_prior<P: MapPrior + 'static>(prior: P, x: &[f64], what: &str) -> P {
        let mut g = vec![0.0; x.len()];
        prior.add_value_and_gradient(x, &mut g);
        let h = 1e-6;
        for k in 0..x.len() {
            let at = |dx: f64| {
                let mut y = x.to_vec();
                y[k] += dx;
                prior.add_value_and_gradient(&y, &mut vec![0.0; x.len()])
            };
            let fd = (at(h) - at(-h)) / (2.0 * h);
            assert!(
                (fd - g[k]).abs() < 1e-6 * fd.abs().max(1.0),
                "{what}, x[{k}]: {} vs {fd}",
                g[k]
            );
        }
        let op = Arc::new(MapPriorOp::new("prior", prior));
        let report = autodiff::gradcheck::gradcheck(&[autodiff::gradcheck::Input::Var(x.to_vec())], |t, v| {
            t.custom(op.clone(), v) * 1.7
        });
        assert!(report.worst_rel_error < 1e-6, "{what}: {report}");
        Arc::into_inner(op).expect("the last reference").into_prior()
    }
}
