//! Gradients verified, not trusted: reverse-mode gradients against central
//! finite differences in f64.
//!
//! The step is h = cbrt(eps) * max(1, |x|), which balances the O(h^2)
//! truncation error of the central difference against its O(eps / h)
//! rounding error (argmin's `finitediff` does the same).

use crate::tape::{Tape, Var};

/// One input of a checked function.
#[derive(Clone, Debug)]
pub enum Input {
    /// Differentiated: its gradient is checked.
    Var(Vec<f64>),
    /// Held constant (indices, masks, data).
    Const(Vec<f64>),
}

/// The outcome of [`gradcheck`]: the worst disagreement and where.
#[derive(Clone, Debug, PartialEq)]
pub struct GradcheckReport {
    /// Worst |analytic - numeric| / max(|analytic|, |numeric|, 1e-3).
    pub worst_rel_error: f64,
    /// Which input (position in the input list) and which element.
    pub worst_input: usize,
    /// Element index within that input.
    pub worst_index: usize,
    /// The reverse-mode gradient there.
    pub analytic: f64,
    /// The central-difference estimate there.
    pub numeric: f64,
    /// Number of gradient elements compared.
    pub checked: usize,
}

impl std::fmt::Display for GradcheckReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "worst relative error {:.3e} at input {} element {} (analytic {:.9e}, numeric {:.9e}; {} elements checked)",
            self.worst_rel_error, self.worst_input, self.worst_index, self.analytic, self.numeric, self.checked
        )
    }
}

/// Projects a vector output onto fixed pseudo-random weights in [0.5, 1.5],
/// so that every output element's gradient is checked at once.
fn scalar_output<'t>(tape: &'t Tape<f64>, y: Var<'t, f64>) -> Var<'t, f64> {
    if y.len() == 1 {
        return y;
    }
    let weights: Vec<f64> = (0..y.len()).map(|i| 0.5 + unit_hash(i as u64 + 0x5eed)).collect();
    (y * tape.constant(&weights)).sum()
}

/// A deterministic value in [0, 1) from an integer (splitmix64).
pub fn unit_hash(i: u64) -> f64 {
    let mut z = i.wrapping_add(0x9e37_79b9_7f4a_7c15);
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^= z >> 31;
    (z >> 11) as f64 / (1u64 << 53) as f64
}

/// `n` deterministic values uniform in [lo, hi) (for test inputs).
pub fn uniform(n: usize, lo: f64, hi: f64, seed: u64) -> Vec<f64> {
    (0..n)
        .map(|i| lo + (hi - lo) * unit_hash(seed.wrapping_mul(1_000_003).wrapping_add(i as u64)))
        .collect()
}

fn evaluate<F>(f: &F, inputs: &[Input]) -> f64
where
    F: for<'t> Fn(&'t Tape<f64>, &[Var<'t, f64>]) -> Var<'t, f64>,
{
    let tape = Tape::new();
    let vars: Vec<_> = inputs
        .iter()
        .map(|i| match i {
            Input::Var(v) => tape.constant(v),
            Input::Const(v) => tape.constant(v),
        })
        .collect();
    let y = scalar_output(&tape, f(&tape, &vars));
    tape.value(y)[0]
}

/// Compares the reverse-mode gradient of `f` (any output length: a vector
/// output is projected on fixed weights) with central differences at
/// `inputs`.
///
/// ```
/// use autodiff::gradcheck::{gradcheck, Input};
/// let report = gradcheck(&[Input::Var(vec![0.3, 1.7])], |_, x| (x[0] * x[0]).exp());
/// assert!(report.worst_rel_error < 1e-6, "{report}");
/// ```
pub fn gradcheck<F>(inputs: &[Input], f: F) -> GradcheckReport
where
    F: for<'t> Fn(&'t Tape<f64>, &[Var<'t, f64>]) -> Var<'t, f64>,
{
    gradcheck_sampled(inputs, usize::MAX, f)
}

/// [`gradcheck`] on at most `per_input` evenly spaced elements of each
/// input: for large arrays, where checking every element costs a forward
/// pass each.
pub fn gradcheck_sampled<F>(inputs: &[Input], per_input: usize, f: F) -> GradcheckReport
where
    F: for<'t> Fn(&'t Tape<f64>, &[Var<'t, f64>]) -> Var<'t, f64>,
{
    gradcheck_with(inputs, per_input, f64::EPSILON.cbrt(), f)
}

/// [`gradcheck_sampled`] with the relative step `h / max(1, |x|)` given:
/// smaller than cbrt(eps) for functions whose third derivative is large at
/// unit scale (the O(h^2) error of the central difference), at the price of
/// more rounding error (O(eps |f| / h)).
pub fn gradcheck_with<F>(inputs: &[Input], per_input: usize, step: f64, f: F) -> GradcheckReport
where
    F: for<'t> Fn(&'t Tape<f64>, &[Var<'t, f64>]) -> Var<'t, f64>,
{
    assert!(
        step > 0.0 && step.is_finite(),
        "gradcheck: the step must be positive, got {step}"
    );
    let tape = Tape::new();
    let vars: Vec<_> = inputs
        .iter()
        .map(|i| match i {
            Input::Var(v) => tape.leaf(v),
            Input::Const(v) => tape.constant(v),
        })
        .collect();
    let y = scalar_output(&tape, f(&tape, &vars));
    tape.backward(y);
    let mut report = GradcheckReport {
        worst_rel_error: 0.0,
        worst_input: 0,
        worst_index: 0,
        analytic: 0.0,
        numeric: 0.0,
        checked: 0,
    };
    let mut probe = inputs.to_vec();
    for (k, input) in inputs.iter().enumerate() {
        let Input::Var(values) = input else { continue };
        let analytic: Vec<f64> = tape.grad(vars[k]).to_vec();
        let stride = values.len().div_ceil(per_input.max(1));
        for (j, &x) in values.iter().enumerate().step_by(stride) {
            let h = step * x.abs().max(1.0);
            let set = |probe: &mut Vec<Input>, v: f64| {
                if let Input::Var(p) = &mut probe[k] {
                    p[j] = v;
                }
            };
            set(&mut probe, x + h);
            let up = evaluate(&f, &probe);
            set(&mut probe, x - h);
            let down = evaluate(&f, &probe);
            set(&mut probe, x);
            let numeric = (up - down) / (2.0 * h);
            let a = analytic[j];
            let err = (a - numeric).abs() / a.abs().max(numeric.abs()).max(1e-3);
            let err = if err.is_nan() { f64::INFINITY } else { err };
            report.checked += 1;
            if err > report.worst_rel_error || report.checked == 1 {
                report.worst_rel_error = err;
                report.worst_input = k;
                report.worst_index = j;
                report.analytic = a;
                report.numeric = numeric;
            }
        }
    }
    report
}
