//! A piecewise-constant 1D distribution sampled by inverting its CDF (pbrt-v4, section A.1).

/// Piecewise-constant distribution over `n` equal bins of [0, 1), proportional to given weights.
#[derive(Clone, Debug)]
pub struct Distribution1D {
    /// `n + 1` increasing values from 0 to exactly 1, in f64 so a million bins still sum exactly enough.
    cdf: Vec<f64>,
}

impl Distribution1D {
    /// The distribution proportional to `weights` (finite, >= 0); all-zero weights give the uniform one.
    pub fn new(weights: &[f64]) -> Self {
        assert!(!weights.is_empty(), "Distribution1D::new: no bins");
        assert!(
            weights.iter().all(|w| w.is_finite() && *w >= 0.0),
            "Distribution1D::new: weights must be finite and >= 0"
        );
        let total: f64 = weights.iter().sum();
        let n = weights.len();
        let mut cdf = Vec::with_capacity(n + 1);
        cdf.push(0.0);
        let mut sum = 0.0;
        for (i, w) in weights.iter().enumerate() {
            sum += if total > 0.0 { w / total } else { 1.0 / n as f64 };
            cdf.push(if i + 1 == n { 1.0 } else { sum });
        }
        Self { cdf }
    }

    /// Number of bins.
    pub fn len(&self) -> usize {
        self.cdf.len() - 1
    }

    /// Always false: a distribution has at least one bin.
    pub fn is_empty(&self) -> bool {
        false
    }

    /// Probability of bin `i`.
    pub fn pmf(&self, i: usize) -> f64 {
        self.cdf[i + 1] - self.cdf[i]
    }

    /// The bin holding `u` in [0, 1) under the inverse CDF, and where in that bin `u` fell, in [0, 1).
    ///
    /// Bins of probability zero are never returned.
    pub fn sample(&self, u: f32) -> (usize, f32) {
        let u = u as f64;
        // First cdf entry > u, minus one: cdf[i] <= u < cdf[i + 1], so bin i has positive width.
        let i = (self.cdf.partition_point(|&c| c <= u).max(1) - 1).min(self.len() - 1);
        let offset = (u - self.cdf[i]) / self.pmf(i);
        (i, (offset as f32).clamp(0.0, 1.0 - f32::EPSILON / 2.0))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn skips_empty_bins_and_reproduces_weights() {
        let d = Distribution1D::new(&[1.0, 0.0, 3.0]);
        assert_eq!(d.len(), 3);
        assert!((d.pmf(0) - 0.25).abs() < 1e-12 && d.pmf(1) == 0.0);
        assert_eq!(d.sample(0.0), (0, 0.0));
        assert_eq!(d.sample(0.25).0, 2);
        let (i, offset) = d.sample(0.625);
        assert_eq!(i, 2);
        assert!((offset - 0.5).abs() < 1e-6);
        let uniform = Distribution1D::new(&[0.0, 0.0]);
        assert_eq!(uniform.sample(0.75).0, 1);
    }
}
