//! Helpers shared by the integration tests.
#![allow(dead_code)]

/// Infinity-norm distance between two points.
pub fn max_abs_diff(a: &[f64], b: &[f64]) -> f64 {
    assert_eq!(a.len(), b.len(), "max_abs_diff: lengths {} vs {}", a.len(), b.len());
    a.iter().zip(b).map(|(x, y)| (x - y).abs()).fold(0.0, f64::max)
}

/// A deterministic xorshift generator, so noisy tests are reproducible.
pub struct Rng(pub u64);

impl Rng {
    /// Uniform in [-1, 1).
    pub fn symmetric(&mut self) -> f64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        (self.0 >> 11) as f64 / (1u64 << 52) as f64 - 1.0
    }
}

/// `0.5 |x - c|^2` observed through Monte Carlo-like noise of size `sigma` on value and gradient.
pub struct NoisyQuadratic {
    pub center: Vec<f64>,
    pub sigma: f64,
    pub rng: Rng,
    pub declared: bool,
}

impl optim::Objective for NoisyQuadratic {
    fn eval(&mut self, x: &[f64], grad: &mut [f64]) -> f64 {
        let mut value = 0.0;
        for i in 0..x.len() {
            let r = x[i] - self.center[i];
            value += 0.5 * r * r;
            grad[i] = r + self.sigma * self.rng.symmetric();
        }
        value * (1.0 + 0.1 * self.sigma * self.rng.symmetric())
    }

    fn is_stochastic(&self) -> bool {
        self.declared
    }
}
