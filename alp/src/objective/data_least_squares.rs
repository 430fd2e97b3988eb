//! The lighting phase's data term: the weighted squared error of the
//! re-rendered pixels against the photo, `sum_pc w_pc r_pc^2 / sum_pc w_pc
//! b_pc^2 / 3`, where a clipped pixel bounds from below and a stored value
//! stands for an interval of radiance ([`DataTerm::residual`]). Linear in
//! the map through the transport, it is what the exact least-squares solve
//! covers.

use std::sync::Arc;

use autodiff::{CustomOp, Var};

use super::{Input, LeastSquaresForm, Phases, Term, TermContext};
use crate::error::{Error, Result};

/// The photo as a lighting solve reads it, per data pixel: the target
/// radiance, the weight per channel, whether the target is a lower bound
/// only (a pixel the sensor clipped: its radiance is at least the clipping
/// level, and a re-render above it is no error), and per channel the
/// half-width of the interval of radiance the stored value stands for (an
/// 8-bit value is any radiance that rounds to it: a re-render within it is
/// no error; 0 for linear HDR).
#[derive(Clone, Debug, Default)]
pub struct DataTerm {
    /// The photo's radiance per data pixel.
    pub target: Vec<[f64; 3]>,
    /// Each pixel's weight per channel (0: left out).
    pub weight: Vec<[f64; 3]>,
    /// Whether the pixel's target is a lower bound (clipped).
    pub at_least: Vec<bool>,
    /// Per channel, the half-width of the radiance interval the stored value stands for.
    pub tolerance: Vec<[f64; 3]>,
}

impl DataTerm {
    /// The residual of pixel `p`'s channel `c` rendered as `value`: zero
    /// above a lower bound and within the value's interval, measured from
    /// the interval's end beyond it.
    #[inline]
    pub fn residual(&self, p: usize, c: usize, value: f64) -> f64 {
        let r = value - self.target[p][c];
        let tolerance = self.tolerance[p][c];
        match self.at_least[p] && r > 0.0 {
            true => 0.0,
            false if r > tolerance => r - tolerance,
            false if r < -tolerance => r + tolerance,
            false => 0.0,
        }
    }

    /// Targets met exactly (no bound, no interval), with their weights.
    pub fn exact(target: Vec<[f64; 3]>, weight: Vec<[f64; 3]>) -> Self {
        let at_least = vec![false; target.len()];
        let tolerance = vec![[0.0; 3]; target.len()];
        DataTerm {
            target,
            weight,
            at_least,
            tolerance,
        }
    }

    /// Whether pixel `p` weighs in any channel.
    pub fn used(&self, p: usize) -> bool {
        self.weight[p].iter().any(|&w| w > 0.0)
    }

    /// The target's weighted energy, `sum_pc w_pc b_pc^2 / 3` (at least
    /// 1e-30): the data term's scale, so that it reads alike at any
    /// exposure (over the weights' sum alone, a photo ten times brighter
    /// would weigh its data a hundred times more against a prior whenever
    /// the weights are relative, 1 / level^2, as the estimate's are).
    pub fn norm(&self) -> f64 {
        (self.target.iter().zip(&self.weight))
            .map(|(t, w)| (0..3).map(|c| w[c] * t[c] * t[c]).sum::<f64>() / 3.0)
            .sum::<f64>()
            .max(1e-30)
    }

    /// The weighted squared error at the pixels' radiance (one value per
    /// pixel and channel, `at(p, c)`), `sum_pc w_pc r_pc^2`: the data term
    /// times its [`norm`](Self::norm), which a solve computes once.
    pub fn weighted_sq_sum(&self, at: impl Fn(usize, usize) -> f64) -> f64 {
        let mut f = 0.0;
        for p in 0..self.target.len() {
            for c in 0..3 {
                f += self.weight[p][c] * self.residual(p, c, at(p, c)).powi(2);
            }
        }
        f
    }
}

/// The data term over the re-rendered pixels: applies in the lighting
/// phase, whose context holds the photo's [`DataTerm`]
/// ([`TermContext::lighting`]). Unweighted it is the exact solve's data
/// term; it has no settings (the estimate sets the pixels' weights).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct LeastSquaresData;

impl Term for LeastSquaresData {
    fn name(&self) -> &str {
        "data_least_squares"
    }

    fn reads(&self) -> &'static [Input] {
        &[Input::Image, Input::LightingData]
    }

    fn phases(&self) -> Phases {
        Phases::LIGHTING
    }

    fn least_squares_form(&self) -> Option<LeastSquaresForm> {
        Some(LeastSquaresForm::Data)
    }

    fn evaluate<'t>(&self, ctx: &TermContext<'_, 't>) -> Result<Option<Var<'t, f64>>> {
        let (Some(image), Some(lighting)) = (&ctx.image, ctx.lighting) else {
            return Ok(None);
        };
        let pixels = image.pixels().len();
        if lighting.data.target.len() != pixels {
            return Err(Error::invalid(
                "data_least_squares",
                format!(
                    "the data term holds {} pixels but the phase renders {pixels}",
                    lighting.data.target.len()
                ),
            ));
        }
        let op = Arc::new(DataOp {
            data: lighting.data.clone(),
            norm: lighting.data.norm(),
        });
        Ok(Some(ctx.tape.custom(op, &image.rendered())))
    }
}

/// The data term as one tape op over the three channels' pixels (its
/// residual's dead zones are no tape ops): forward the value, backward
/// `2 w r / norm`.
struct DataOp {
    data: Arc<DataTerm>,
    norm: f64,
}

impl CustomOp<f64> for DataOp {
    fn name(&self) -> &str {
        "data_least_squares"
    }

    fn output_len(&self, input_lens: &[usize]) -> usize {
        let n = self.data.target.len();
        assert!(
            input_lens == [n, n, n],
            "data_least_squares: takes three channels of {n} pixels, got {input_lens:?}"
        );
        1
    }

    fn forward(&self, inputs: &[&[f64]], output: &mut [f64]) {
        output[0] = self.data.weighted_sq_sum(|p, c| inputs[c][p]) / self.norm;
    }

    fn vjp(&self, inputs: &[&[f64]], _output: &[f64], grad_output: &[f64], grad_inputs: &mut [Option<&mut [f64]>]) {
        let scale = 2.0 * grad_output[0] / self.norm;
        for (c, grad) in grad_inputs.iter_mut().enumerate() {
            let Some(grad) = grad.as_deref_mut() else { continue };
            for (p, g) in grad.iter_mut().enumerate() {
                *g += scale * self.data.weight[p][c] * self.data.residual(p, c, inputs[c][p]);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use autodiff::Tape;
    use autodiff::gradcheck::{Input as GradInput, gradcheck, uniform};

    use super::*;

    #[test]
    fn a_value_s_interval_is_no_error_and_beyond_it_the_error_is_from_its_end() {
        let mut data = DataTerm::exact(vec![[1.0, 2.0, 3.0]], vec![[1.0; 3]]);
        data.tolerance[0] = [0.1, 0.0, 0.5];
        assert_eq!(data.residual(0, 0, 1.05), 0.0);
        assert_eq!(data.residual(0, 0, 0.95), 0.0);
        assert!((data.residual(0, 0, 1.3) - 0.2).abs() < 1e-12);
        assert!((data.residual(0, 0, 0.7) + 0.2).abs() < 1e-12);
        assert!((data.residual(0, 1, 2.01) - 0.01).abs() < 1e-12, "no interval, exact");
        // A clipped pixel's bound holds from below, beyond its interval too.
        data.at_least[0] = true;
        assert_eq!(data.residual(0, 2, 9.0), 0.0);
        assert!((data.residual(0, 2, 2.0) + 0.5).abs() < 1e-12);
    }

    #[test]
    fn the_op_s_gradient_matches_central_differences() {
        // Seven pixels: some weighted per channel, one a lower bound, one
        // with an interval; the rendered values keep clear of the kinks.
        let n = 7;
        let target: Vec<[f64; 3]> = (0..n).map(|p| [1.0 + p as f64, 0.5, 2.0 - 0.1 * p as f64]).collect();
        let weight: Vec<[f64; 3]> = (0..n).map(|p| [0.5, 1.0 + p as f64, 0.2]).collect();
        let mut data = DataTerm::exact(target, weight);
        data.at_least[2] = true;
        data.tolerance[4] = [0.05; 3];
        let op = Arc::new(DataOp {
            norm: data.norm(),
            data: Arc::new(data),
        });
        let inputs: Vec<GradInput> = (0..3).map(|c| GradInput::Var(uniform(n, 0.1, 3.0, 11 + c))).collect();
        let report = gradcheck(&inputs, |t: &Tape<f64>, x| t.custom(op.clone(), x));
        assert!(report.worst_rel_error < 1e-6, "{report}");
    }
}
