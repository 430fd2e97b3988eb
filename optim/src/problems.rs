//! Test objectives with known minimizers, shared by the tests and the benchmarks.

use crate::{Bounds, Objective};

/// `f(x) = (x-c)' A (x-c) / 2` with `A = Q diag(eigenvalues) Q`, `Q = I - 2 u u'/u'u`, `u = 1`.
///
/// The Householder reflection `Q` couples every coordinate (so a diagonal
/// preconditioner such as Adam's cannot undo the conditioning) at O(n) per evaluation.
#[derive(Debug, Clone)]
pub struct Quadratic {
    eigenvalues: Vec<f64>,
    center: Vec<f64>,
    minimizer: Vec<f64>,
    scratch: Vec<f64>,
}

impl Quadratic {
    /// Unconstrained quadratic minimized at `minimizer`.
    pub fn new(eigenvalues: Vec<f64>, minimizer: Vec<f64>) -> Self {
        Self::with_multipliers(eigenvalues, minimizer, &[])
    }

    /// Eigenvalues spaced geometrically from 1 to `condition`; minimizer `x*_i = sin(i + 1)`.
    pub fn conditioned(n: usize, condition: f64) -> Self {
        let eigenvalues = (0..n)
            .map(|i| condition.powf(i as f64 / (n - 1).max(1) as f64))
            .collect();
        Self::new(eigenvalues, (0..n).map(|i| ((i + 1) as f64).sin()).collect())
    }

    /// Quadratic whose gradient at `minimizer` equals `multipliers` (empty means zero).
    ///
    /// With `multipliers >= 0` where the minimizer is on a lower bound, `<= 0` on an upper
    /// bound and 0 elsewhere, `minimizer` satisfies the KKT conditions of the box problem,
    /// and, `A` being positive definite, it is the unique box-constrained minimizer.
    pub fn with_multipliers(eigenvalues: Vec<f64>, minimizer: Vec<f64>, multipliers: &[f64]) -> Self {
        assert_eq!(
            eigenvalues.len(),
            minimizer.len(),
            "Quadratic: eigenvalues vs minimizer length"
        );
        assert!(
            eigenvalues.iter().all(|&l| l > 0.0),
            "Quadratic: eigenvalues must be > 0"
        );
        let n = minimizer.len();
        let mut q = Self {
            eigenvalues,
            center: minimizer.clone(),
            minimizer,
            scratch: vec![0.0; n],
        };
        if !multipliers.is_empty() {
            assert_eq!(multipliers.len(), n, "Quadratic: multipliers length");
            // grad(x*) = Q L Q (x* - c) = mu  =>  c = x* - Q L^-1 Q mu.
            let mut w = multipliers.to_vec();
            reflect(&mut w);
            w.iter_mut().zip(&q.eigenvalues).for_each(|(wi, l)| *wi /= l);
            reflect(&mut w);
            q.center.iter_mut().zip(&w).for_each(|(c, wi)| *c -= wi);
        }
        q
    }

    /// The known minimizer.
    pub fn minimizer(&self) -> &[f64] {
        &self.minimizer
    }
}

/// `v <- (I - 2 u u'/u'u) v` with `u = 1`: subtract twice the mean.
fn reflect(v: &mut [f64]) {
    let twice_mean = 2.0 * v.iter().sum::<f64>() / v.len() as f64;
    v.iter_mut().for_each(|vi| *vi -= twice_mean);
}

impl Objective for Quadratic {
    fn eval(&mut self, x: &[f64], grad: &mut [f64]) -> f64 {
        let y = &mut self.scratch;
        y.iter_mut()
            .zip(x.iter().zip(&self.center))
            .for_each(|(yi, (xi, ci))| *yi = xi - ci);
        reflect(y);
        let mut value = 0.0;
        for ((g, yi), l) in grad.iter_mut().zip(y.iter()).zip(&self.eigenvalues) {
            value += 0.5 * l * yi * yi;
            *g = l * yi;
        }
        reflect(grad);
        value
    }
}

/// The chained Rosenbrock function `sum 100 (x[i+1] - x[i]^2)^2 + (1 - x[i])^2` (SciPy's `rosen`).
#[derive(Debug, Clone, Copy)]
pub struct Rosenbrock;

impl Rosenbrock {
    /// The classic start `[-1.2, 1, -1.2, 1, ...]`.
    pub fn start(n: usize) -> Vec<f64> {
        (0..n).map(|i| if i % 2 == 0 { -1.2 } else { 1.0 }).collect()
    }
}

impl Objective for Rosenbrock {
    fn eval(&mut self, x: &[f64], grad: &mut [f64]) -> f64 {
        grad.fill(0.0);
        let mut value = 0.0;
        for i in 0..x.len() - 1 {
            let (a, b) = (x[i + 1] - x[i] * x[i], 1.0 - x[i]);
            value += 100.0 * a * a + b * b;
            grad[i] += -400.0 * x[i] * a - 2.0 * b;
            grad[i + 1] += 200.0 * a;
        }
        value
    }
}

/// `f(x) = sum w_i |x_i - c_i|`: nonsmooth, minimized at `c`; the subgradient at a kink is 0.
#[derive(Debug, Clone)]
pub struct WeightedL1 {
    /// The minimizer `c`.
    pub center: Vec<f64>,
    /// Positive weights `w`.
    pub weights: Vec<f64>,
}

impl Objective for WeightedL1 {
    fn eval(&mut self, x: &[f64], grad: &mut [f64]) -> f64 {
        let mut value = 0.0;
        for i in 0..x.len() {
            let r = x[i] - self.center[i];
            value += self.weights[i] * r.abs();
            grad[i] = if r == 0.0 { 0.0 } else { self.weights[i] * r.signum() };
        }
        value
    }
}

/// A small lighting solve: nonnegative env-map texels seen by a glossy probe.
///
/// `f(x) = |K x - b_d|^2 / 2 + |a x - b_s|^2 / 2 + smoothness |D x|^2 / 2`, `x >= 0`, where
/// `x` holds `n` texels on a circle, `K` is the clamped-cosine (diffuse) kernel seen by
/// `n / 2` surface normals, `a` the mirror (specular) reflectance seeing each texel
/// directly, and `D` the periodic first difference. The data `b` are built so that a
/// chosen env map with dark (zero) texels is the exact minimizer: at `x*` the gradient
/// is `mu >= 0` on the zero texels and 0 elsewhere (KKT), and `a > 0` makes `f` strictly convex.
#[derive(Debug, Clone)]
pub struct Lighting {
    kernel: Vec<f64>,
    diffuse: Vec<f64>,
    specular: Vec<f64>,
    smoothness: f64,
    minimizer: Vec<f64>,
    residual: Vec<f64>,
}

/// Mirror reflectance `a` of the probe.
const SPECULAR_ALBEDO: f64 = 0.5;

impl Lighting {
    /// `n` texels; the true env map is a bright lobe `max(0, 3 sin t + 1)` with a dark half.
    pub fn new(n: usize, smoothness: f64) -> Self {
        let pixels = n / 2;
        let angle = |i: usize, count: usize| std::f64::consts::TAU * i as f64 / count as f64;
        let mut kernel = vec![0.0; pixels * n];
        for p in 0..pixels {
            for t in 0..n {
                let cosine = (angle(t, n) - angle(p, pixels)).cos().max(0.0);
                kernel[p * n + t] = cosine * std::f64::consts::TAU / n as f64;
            }
        }
        let minimizer: Vec<f64> = (0..n).map(|t| (3.0 * angle(t, n).sin() + 1.0).max(0.0)).collect();
        let mut lighting = Lighting {
            diffuse: vec![0.0; pixels],
            specular: vec![0.0; n],
            kernel,
            smoothness,
            minimizer,
            residual: vec![0.0; pixels],
        };
        // b_d = K x*;  b_s = a x* + (smoothness D'D x* - mu) / a, so that grad f(x*) = mu.
        let x = lighting.minimizer.clone();
        lighting.apply_kernel(&x);
        lighting.diffuse.copy_from_slice(&lighting.residual);
        for t in 0..n {
            let mu = if x[t] == 0.0 { 0.1 } else { 0.0 };
            lighting.specular[t] = SPECULAR_ALBEDO * x[t] + (smoothness * laplacian(&x, t) - mu) / SPECULAR_ALBEDO;
        }
        lighting
    }

    /// The env map the data were made from, which is the exact minimizer.
    pub fn minimizer(&self) -> &[f64] {
        &self.minimizer
    }

    /// `residual <- K x`.
    fn apply_kernel(&mut self, x: &[f64]) {
        let n = x.len();
        for (p, r) in self.residual.iter_mut().enumerate() {
            *r = self.kernel[p * n..(p + 1) * n]
                .iter()
                .zip(x)
                .map(|(k, xi)| k * xi)
                .sum();
        }
    }
}

/// `(D'D x)_t` for the periodic first difference `D`: `2 x_t - x_{t-1} - x_{t+1}`.
fn laplacian(x: &[f64], t: usize) -> f64 {
    let n = x.len();
    2.0 * x[t] - x[(t + n - 1) % n] - x[(t + 1) % n]
}

impl Objective for Lighting {
    fn eval(&mut self, x: &[f64], grad: &mut [f64]) -> f64 {
        let n = x.len();
        self.apply_kernel(x);
        let mut value = 0.0;
        for t in 0..n {
            let r = SPECULAR_ALBEDO * x[t] - self.specular[t];
            let d = x[(t + 1) % n] - x[t];
            value += 0.5 * r * r + 0.5 * self.smoothness * d * d;
            grad[t] = SPECULAR_ALBEDO * r + self.smoothness * laplacian(x, t);
        }
        for (p, r) in self.residual.iter_mut().enumerate() {
            *r -= self.diffuse[p];
            value += 0.5 * *r * *r;
            let row = &self.kernel[p * n..(p + 1) * n];
            grad.iter_mut().zip(row).for_each(|(g, k)| *g += k * *r);
        }
        value
    }
}

/// One benchmark problem: objective, start, box and known minimizer.
pub struct Case {
    /// Short name used as the benchmark `mode`.
    pub name: &'static str,
    /// The objective.
    pub objective: Box<dyn Objective>,
    /// Start point.
    pub x0: Vec<f64>,
    /// Box constraints (unbounded when the problem has none).
    pub bounds: Bounds,
    /// Known minimizer.
    pub minimizer: Vec<f64>,
    /// An Adam learning rate suited to the problem's scale (found by a coarse sweep).
    pub adam_lr: f64,
}

impl Objective for Box<dyn Objective> {
    fn eval(&mut self, x: &[f64], grad: &mut [f64]) -> f64 {
        (**self).eval(x, grad)
    }

    fn is_stochastic(&self) -> bool {
        (**self).is_stochastic()
    }
}

/// The problems of the issue: quadratics (condition 10 and 1e4), Rosenbrock 2 and 100,
/// a box-bounded quadratic with its minimum on the bounds, and a nonnegative lighting solve.
pub fn suite() -> Vec<Case> {
    let unbounded = |name, objective: Box<dyn Objective>, x0: Vec<f64>, minimizer, adam_lr| Case {
        name,
        objective,
        bounds: Bounds::unbounded(x0.len()),
        x0,
        minimizer,
        adam_lr,
    };
    let well = Quadratic::conditioned(20, 10.0);
    let ill = Quadratic::conditioned(20, 1e4);
    let bounded = bounded_quadratic(20);
    let lighting = Lighting::new(64, 0.05);
    vec![
        unbounded(
            "quadratic_cond10",
            Box::new(well.clone()),
            vec![0.0; 20],
            well.minimizer().to_vec(),
            0.1,
        ),
        unbounded(
            "quadratic_cond1e4",
            Box::new(ill.clone()),
            vec![0.0; 20],
            ill.minimizer().to_vec(),
            0.1,
        ),
        unbounded(
            "rosenbrock_2",
            Box::new(Rosenbrock),
            Rosenbrock::start(2),
            vec![1.0; 2],
            0.05,
        ),
        unbounded(
            "rosenbrock_100",
            Box::new(Rosenbrock),
            Rosenbrock::start(100),
            vec![1.0; 100],
            0.05,
        ),
        Case {
            name: "bounded_quadratic",
            bounds: Bounds::uniform(20, 0.0, 1.0).expect("constant bounds are valid"),
            x0: vec![0.5; 20],
            minimizer: bounded.minimizer().to_vec(),
            objective: Box::new(bounded),
            adam_lr: 0.05,
        },
        Case {
            name: "lighting_nnls",
            bounds: Bounds::uniform(64, 0.0, f64::INFINITY).expect("constant bounds are valid"),
            x0: vec![1.0; 64],
            minimizer: lighting.minimizer().to_vec(),
            objective: Box::new(lighting),
            adam_lr: 0.1,
        },
    ]
}

/// Condition-100 quadratic on `[0, 1]^n` whose minimizer has a third of its coordinates
/// on the lower bound, a third on the upper bound, the rest inside.
pub fn bounded_quadratic(n: usize) -> Quadratic {
    let eigenvalues = (0..n).map(|i| 100f64.powf(i as f64 / (n - 1).max(1) as f64)).collect();
    let minimizer = (0..n)
        .map(|i| [0.0, 1.0, 0.25 + 0.5 * (i as f64 / n as f64)][i % 3])
        .collect();
    let multipliers: Vec<f64> = (0..n).map(|i| [1.0, -1.0, 0.0][i % 3]).collect();
    Quadratic::with_multipliers(eigenvalues, minimizer, &multipliers)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Central differences with h = cbrt(eps), as the style guide asks.
    fn assert_gradient(f: &mut dyn Objective, x: &[f64]) {
        let n = x.len();
        let mut grad = vec![0.0; n];
        let mut scratch = vec![0.0; n];
        f.eval(x, &mut grad);
        let h = f64::EPSILON.cbrt();
        for i in 0..n {
            let (mut plus, mut minus) = (x.to_vec(), x.to_vec());
            plus[i] += h;
            minus[i] -= h;
            let fd = (f.eval(&plus, &mut scratch) - f.eval(&minus, &mut scratch)) / (2.0 * h);
            assert!(
                (fd - grad[i]).abs() <= 1e-6 * (1.0 + fd.abs()),
                "d/dx{i}: analytic {} vs fd {fd}",
                grad[i]
            );
        }
    }

    #[test]
    fn gradients_match_central_differences() {
        let x: Vec<f64> = (0..20).map(|i| 0.3 + 0.1 * (i as f64).cos()).collect();
        assert_gradient(&mut Quadratic::conditioned(20, 1e2), &x);
        assert_gradient(&mut bounded_quadratic(20), &x);
        assert_gradient(&mut Rosenbrock, &x);
        let lx: Vec<f64> = (0..16).map(|i| 0.5 + 0.2 * (i as f64).sin()).collect();
        assert_gradient(&mut Lighting::new(16, 0.05), &lx);
    }

    #[test]
    fn known_minimizers_satisfy_kkt() {
        for mut case in suite() {
            let mut grad = vec![0.0; case.x0.len()];
            case.objective.eval(&case.minimizer, &mut grad);
            let kkt = case.bounds.projected_grad_norm(&case.minimizer, &grad);
            assert!(kkt < 1e-12, "{}: projected gradient {kkt} at the minimizer", case.name);
        }
        let mut rosen = Rosenbrock;
        assert_eq!(rosen.eval(&[1.0, 1.0, 1.0], &mut [0.0; 3]), 0.0);
        assert_eq!(rosen.eval(&[-1.2, 1.0], &mut [0.0; 2]), 24.199999999999996);
    }
}
