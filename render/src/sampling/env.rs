//! Importance sampling of an env map by a density that is continuous, like the map's bilinear
//! lookup (FORMATS.md), rather than constant per texel (pbrt-v4, section 12.5.2, samples the
//! piecewise-constant one).
//!
//! Why continuous: the integrator combines this sampler with the BRDF's by multiple importance
//! sampling and differentiates the result. A BRDF sample's direction moves with the pose and the
//! roughness; its MIS weight holds this pdf at that direction, and a pdf that jumps at texel edges
//! would make the sample's contribution jump as it crosses them: the derivative of each sample
//! would then miss the jumps, and the gradient of the expected image would be biased.
//!
//! The density in (u, v) is the bilinear interpolant `B` of knots at the texel centres, with the
//! lookup's rules (columns wrap, rows clamp), normalised by its integral `Z`:
//!
//!   c_ij = luminance(texel ij) sin(theta_i),  p(u, v) = B(u, v) / Z,  Z = mean of the c_ij,
//!
//! and since d(omega) = 2 pi^2 sin(theta) du dv, the solid-angle pdf is
//! p(omega) = p(u, v) / (2 pi^2 sin theta): about proportional to the luminance (exactly so at the
//! texel centres). Wherever the bilinear radiance is non-zero, so is the density.
//!
//! Sampling inverts the CDFs, so that stratified numbers give stratified directions: a strip
//! between two rows of knots by its mass, a row position in it from the linear marginal, then the
//! conditional over columns at that row position, `(1 - t)` times the profile of the row above
//! plus `t` times the one below: a segment from the blend of the two rows' segment CDFs, a
//! position in it from the linear density.

use std::f64::consts::PI;

use glam::{Vec2, Vec3};

use crate::colour::luminance;
use crate::envmap::{EnvMap, direction_to_uv, uv_to_direction};
use crate::sampling::{Distribution1D, sample_linear};

/// A direction drawn from an [`EnvSampler`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EnvSample {
    /// Unit direction towards the light (world).
    pub direction: Vec3,
    /// Its solid-angle pdf.
    pub pdf: f32,
}

/// Samples directions about proportionally to the luminance of an env map, by a continuous
/// density (the module's comment).
#[derive(Clone)]
pub struct EnvSampler {
    width: usize,
    height: usize,
    /// The knots `c_ij`, row-major.
    knots: Vec<f64>,
    /// Per row of knots: its mean `m_i` (the integral of the row's profile over u).
    row_means: Vec<f64>,
    /// Over the `height + 1` strips of rows: half a row above the first knots, one between each
    /// two rows of knots, half a row below the last.
    strips: Distribution1D,
    /// Per row of knots: the CDF over its `width` segments between neighbouring knots (the last
    /// wraps), `width + 1` values from 0 to 1, row after row.
    segment_cdfs: Vec<f64>,
    /// `p(u, v)` at the texel centres, in a grey map: its bilinear lookup is `p(u, v)` anywhere.
    density: EnvMap,
}

/// The size only: the tables hold a few values per texel.
impl std::fmt::Debug for EnvSampler {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("EnvSampler")
            .field("width", &self.width)
            .field("height", &self.height)
            .finish_non_exhaustive()
    }
}

impl EnvSampler {
    /// Builds the sampler of `env`; a black map falls back to sampling by solid angle.
    pub fn new(env: &EnvMap) -> Self {
        let (width, height) = (env.width(), env.height());
        let sin_theta = |row: usize| (PI * (row as f64 + 0.5) / height as f64).sin();
        let mut knots: Vec<f64> = env
            .radiance()
            .iter()
            .enumerate()
            .map(|(i, &t)| luminance(t.map(f64::from)) * sin_theta(i / width))
            .collect();
        if knots.iter().all(|&c| c == 0.0) {
            knots = (0..width * height).map(|i| sin_theta(i / width)).collect();
        }
        let rows = || knots.chunks_exact(width);
        let row_means: Vec<f64> = rows().map(|row| row.iter().sum::<f64>() / width as f64).collect();
        let z = row_means.iter().sum::<f64>() / height as f64;
        let mut strip_masses = vec![0.5 * row_means[0]];
        strip_masses.extend(row_means.windows(2).map(|m| 0.5 * (m[0] + m[1])));
        strip_masses.push(0.5 * row_means[height - 1]);
        let mut segment_cdfs = Vec::with_capacity(height * (width + 1));
        for (row, &mean) in rows().zip(&row_means) {
            // Segment masses (c_j + c_j+1) / 2, summing to `width` times the row's mean.
            let mut sum = 0.0;
            segment_cdfs.push(0.0);
            for j in 0..width {
                sum += 0.5 * (row[j] + row[(j + 1) % width]);
                // A black row is never picked; any CDF will do.
                segment_cdfs.push(if mean > 0.0 {
                    sum / (width as f64 * mean)
                } else {
                    (j + 1) as f64 / width as f64
                });
            }
        }
        let density = knots.iter().map(|&c| [(c / z) as f32; 3]).collect();
        Self {
            width,
            height,
            row_means,
            strips: Distribution1D::new(&strip_masses),
            segment_cdfs,
            density: EnvMap::new(width, height, density).expect("a density map of the env map's size"),
            knots,
        }
    }

    /// The density in (u, v) at the texel centres, as a grey map of the env map's size: its
    /// bilinear lookup is `p(u, v)` anywhere (for the same lookup on a tape).
    pub fn density_map(&self) -> &EnvMap {
        &self.density
    }

    /// Draws a direction from uniform `u` in [0, 1)^2.
    pub fn sample(&self, u: Vec2) -> EnvSample {
        let (h, w) = (self.height, self.width);
        // Rows in knot coordinates y = v H - 1/2 (knots at integers).
        let (strip, fy) = self.strips.sample(u.x);
        let (y, rows, t) = match strip {
            0 => (0.5 * fy as f64 - 0.5, (0, 0), 0.0),
            s if s == h => ((h - 1) as f64 + 0.5 * fy as f64, (h - 1, h - 1), 0.0),
            s => {
                let t = sample_linear(fy as f64, self.row_means[s - 1], self.row_means[s]);
                ((s - 1) as f64 + t, (s - 1, s), t)
            }
        };
        // The blend's weights: each row's share of the conditional's mass.
        let (mass_a, mass_b) = ((1.0 - t) * self.row_means[rows.0], t * self.row_means[rows.1]);
        let share_b = if mass_b > 0.0 { mass_b / (mass_a + mass_b) } else { 0.0 };
        let cdf = |j: usize| {
            let at = |row: usize| self.segment_cdfs[row * (w + 1) + j];
            (1.0 - share_b) * at(rows.0) + share_b * at(rows.1)
        };
        let ux = u.y as f64;
        // Bisection for cdf(j) <= ux < cdf(j + 1) (cdf(0) = 0, cdf(w) = 1): segment j has positive mass.
        let (mut segment, mut above) = (0, w);
        while above - segment > 1 {
            let mid = (segment + above) / 2;
            if cdf(mid) <= ux {
                segment = mid;
            } else {
                above = mid;
            }
        }
        let fx = ((ux - cdf(segment)) / (cdf(segment + 1) - cdf(segment))).clamp(0.0, 1.0);
        let knot = |col: usize| {
            let at = |row: usize| self.knots[row * w + col % w];
            (1.0 - t) * at(rows.0) + t * at(rows.1)
        };
        let x = segment as f64 + sample_linear(fx, knot(segment), knot(segment + 1));
        let uv = Vec2::new(
            ((x + 0.5) / w as f64).rem_euclid(1.0) as f32,
            ((y + 0.5) / h as f64) as f32,
        );
        // rem_euclid of a tiny negative can round to exactly 1.
        let uv = Vec2::new(if uv.x >= 1.0 { 0.0 } else { uv.x }, uv.y);
        EnvSample {
            direction: uv_to_direction(uv),
            pdf: self.pdf_at(uv, (std::f32::consts::PI * uv.y).sin()),
        }
    }

    /// Solid-angle pdf that [`EnvSampler::sample`] returns `direction` (unit); infinite exactly
    /// on a pole next to light.
    pub fn pdf(&self, direction: Vec3) -> f32 {
        // sqrt(x^2 + z^2) keeps its precision near the poles, unlike sqrt(1 - y^2).
        let sin_theta = Vec2::new(direction.x, direction.z).length();
        self.pdf_at(direction_to_uv(direction), sin_theta)
    }

    fn pdf_at(&self, uv: Vec2, sin_theta: f32) -> f32 {
        let pdf_uv = self.density.lookup_uv(uv)[0] as f64;
        if sin_theta <= 0.0 {
            // On a pole the (u, v) density covers no solid angle.
            return if pdf_uv > 0.0 { f32::INFINITY } else { 0.0 };
        }
        (pdf_uv / (2.0 * PI * PI * sin_theta as f64)) as f32
    }
}
