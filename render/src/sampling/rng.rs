//! PCG32 (O'Neill 2014, "PCG: A Family of Simple Fast Space-Efficient Statistically Good
//! Algorithms for Random Number Generation"): small state, and 2^63 independent streams, so that
//! e.g. stream = pixel index makes sample k of pixel p reproducible whatever the thread count.

use glam::Vec2;

const MULTIPLIER: u64 = 6_364_136_223_846_793_005;

/// A PCG32 random number generator (XSH RR output, 64-bit state).
#[derive(Clone, Debug)]
pub struct Rng {
    state: u64,
    increment: u64,
}

impl Rng {
    /// The generator for `seed` on stream `stream` (distinct streams give independent sequences).
    pub fn new(seed: u64, stream: u64) -> Self {
        // The reference seeding: pcg32_srandom_r(initstate = seed, initseq = stream).
        let mut rng = Self {
            state: 0,
            increment: (stream << 1) | 1,
        };
        rng.next_u32();
        rng.state = rng.state.wrapping_add(seed);
        rng.next_u32();
        rng
    }

    /// The next uniformly distributed 32-bit integer.
    pub fn next_u32(&mut self) -> u32 {
        let old = self.state;
        self.state = old.wrapping_mul(MULTIPLIER).wrapping_add(self.increment);
        let xorshifted = (((old >> 18) ^ old) >> 27) as u32;
        let rotation = (old >> 59) as u32;
        xorshifted.rotate_right(rotation)
    }

    /// A uniform float in [0, 1) with 24 random bits (never 1.0, unlike `u32 as f32 / 2^32`).
    pub fn next_f32(&mut self) -> f32 {
        (self.next_u32() >> 8) as f32 * (1.0 / (1u32 << 24) as f32)
    }

    /// A uniform point in [0, 1)^2.
    pub fn next_2d(&mut self) -> Vec2 {
        let x = self.next_f32();
        Vec2::new(x, self.next_f32())
    }

    /// A uniform integer in [0, n) (Lemire's multiply-shift; bias below 2^-32 n).
    pub fn next_below(&mut self, n: u32) -> u32 {
        ((self.next_u32() as u64 * n as u64) >> 32) as u32
    }
}

/// Fills `points` with a stratified set in [0, 1)^2 in random order: a Hammersley set (x = (k +
/// shift) / n, y = the base-2 radical inverse of k) randomised by one shift of x (mod 1) and one
/// digital (XOR) shift of y, so each point is uniform and the set keeps its strata. A lobe
/// integrated from it converges faster than from independent points (for n a power of two every
/// elementary interval of area 1/n holds one point); the random order decorrelates it from other
/// stratified dimensions of the same sample (the pixel offsets).
pub fn stratified_square(rng: &mut Rng, points: &mut [Vec2]) {
    let n = points.len();
    let (x_shift, y_shift) = (rng.next_f32(), rng.next_u32());
    for (k, point) in points.iter_mut().enumerate() {
        let x = (k as f32 + x_shift) / n as f32;
        let y = ((k as u32).reverse_bits() ^ y_shift) >> 8;
        // x rounds to 1.0 only for the last stratum's top ulp.
        *point = Vec2::new(x.min(1.0 - f32::EPSILON / 2.0), y as f32 / (1u32 << 24) as f32);
    }
    for i in (1..n).rev() {
        points.swap(i, rng.next_below(i as u32 + 1) as usize);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn matches_pcg32_reference_output() {
        // pcg32-global demo: pcg32_srandom_r(&rng, 42u, 54u), first outputs.
        let mut rng = Rng::new(42, 54);
        let expected = [
            0xa15c02b7u32,
            0x7b47f409,
            0xba1d3330,
            0x83d2f293,
            0xbfa4784b,
            0xcbed606e,
        ];
        for e in expected {
            assert_eq!(rng.next_u32(), e);
        }
    }

    #[test]
    fn floats_are_in_unit_interval_with_the_right_mean() {
        let mut rng = Rng::new(1, 2);
        let n = 100_000;
        let mut sum = 0.0f64;
        for _ in 0..n {
            let x = rng.next_f32();
            assert!((0.0..1.0).contains(&x));
            sum += x as f64;
        }
        assert!((sum / n as f64 - 0.5).abs() < 0.005);
    }

    #[test]
    fn a_stratified_square_has_one_point_per_stratum_and_integrates_better_than_independent_points() {
        let mut rng = Rng::new(3, 4);
        let mut points = vec![Vec2::ZERO; 16];
        stratified_square(&mut rng, &mut points);
        // One point in each of the 16 columns, 16 rows and 4x4 cells.
        for cells in [(16, 1), (1, 16), (4, 4)] {
            let mut seen = [false; 16];
            for p in &points {
                assert!((0.0..1.0).contains(&p.x) && (0.0..1.0).contains(&p.y));
                let cell = (p.x * cells.0 as f32) as usize + cells.0 * (p.y * cells.1 as f32) as usize;
                assert!(!seen[cell], "two points in cell {cell} of {cells:?}");
                seen[cell] = true;
            }
        }
        // A smooth integrand over the square: the stratified estimate's
        // spread across randomisations is far below independent points'.
        let f = |p: Vec2| ((3.0 * p.x).sin() * (2.0 * p.y + 0.5).exp()) as f64;
        let spread = |estimates: Vec<f64>| {
            let mean = estimates.iter().sum::<f64>() / estimates.len() as f64;
            estimates.iter().map(|e| (e - mean).powi(2)).sum::<f64>() / estimates.len() as f64
        };
        let stratified: Vec<f64> = (0..200)
            .map(|_| {
                stratified_square(&mut rng, &mut points);
                points.iter().map(|&p| f(p)).sum::<f64>() / 16.0
            })
            .collect();
        let independent: Vec<f64> = (0..200)
            .map(|_| (0..16).map(|_| f(rng.next_2d())).sum::<f64>() / 16.0)
            .collect();
        assert!(spread(stratified) < 0.1 * spread(independent));
    }
}
