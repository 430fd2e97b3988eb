//! The latitude prior: a scene's colour varies far more with elevation
//! (sky, horizon, ground) than with azimuth, so a texel the photo tells
//! little of leans towards the colour the seen part of its row shows.
//!
//! Per texel `t` of row `r`, with `e_r` the unit RGB direction of the row's
//! seen colour in the solve's start (its texels weighted by how much the
//! photo tells of each over their level, so that a light in the row does
//! not set it) and `u_t = 1 - c_t` (`c_t` the texel's data curvature
//! against the best-seen texel's: the sampling confidence), the prior is
//!
//! ```text
//! lambda sum_t area_t q_t u_t |x_t - (e_r . x_t) e_r|^2
//! ```
//!
//! the part of the texel's colour across the row's, with `q_t` its relative
//! factor (so the cost is about the squared angle between the two colours)
//! and `lambda` the smoothness's scale. It leaves each texel's level along
//! `e_r` to the data and the smoothness: a prior on levels pulls what the
//! blurred data set in aggregate, and the lights lose their energy
//! (docs/results/benchmark.md 19.2). `e_r` is a constant of the solve (the
//! start is the coarser level's solution), so the prior is quadratic. The
//! lights brighter than the sensor are left out.

use autodiff::Var;

use super::map_prior::{MapPrior, record_map_prior};
use super::{Input, LeastSquaresForm, Phases, PriorBasis, Term, TermContext};
use crate::error::Result;

/// The latitude prior as a declared term of the lighting phase.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct LatitudePrior;

impl LatitudePrior {
    /// The prior on `basis` at `weight` (the smoothness's scale).
    pub fn bands(&self, basis: &PriorBasis, weight: f64) -> Bands {
        let (w, h) = (basis.width, basis.height);
        let lambda = weight / basis.mean_sq / (w * h) as f64;
        let told: Vec<f64> = basis.data_curvature.chunks_exact(3).map(|c| c.iter().sum()).collect();
        let most = told.iter().cloned().fold(0.0, f64::max).max(1e-300);
        let floor = basis.floor();
        let mut rows = Vec::with_capacity(h);
        for r in 0..h {
            let texels = r * w..(r + 1) * w;
            let seen_weight = |t: usize| match basis.free[t] {
                true => 0.0,
                false => told[t] / most / (basis.level[t] + floor),
            };
            let colour: [f64; 3] = std::array::from_fn(|c| {
                texels
                    .clone()
                    .map(|t| seen_weight(t) * basis.start[3 * t + c].max(0.0))
                    .sum()
            });
            let norm = colour.iter().map(|v| v * v).sum::<f64>().sqrt();
            if norm <= 0.0 {
                continue;
            }
            let area = (std::f64::consts::PI * (r as f64 + 0.5) / h as f64).sin();
            let scale = texels
                .map(|t| {
                    let relative = match basis.relative {
                        true => ((basis.mean_level + floor) / (basis.level[t] + floor)).powi(2),
                        false => 1.0,
                    };
                    match basis.free[t] {
                        true => 0.0,
                        false => lambda * area * relative * (1.0 - told[t] / most),
                    }
                })
                .collect();
            rows.push(Band {
                start: r * w,
                colour: colour.map(|v| v / norm),
                scale,
            });
        }
        Bands { rows }
    }
}

impl Term for LatitudePrior {
    fn name(&self) -> &str {
        "latitude_prior"
    }

    fn reads(&self) -> &'static [Input] {
        &[Input::Env, Input::LightingData]
    }

    fn phases(&self) -> Phases {
        Phases::LIGHTING
    }

    fn least_squares_form(&self) -> Option<LeastSquaresForm> {
        Some(LeastSquaresForm::Latitude(*self))
    }

    fn evaluate<'t>(&self, ctx: &TermContext<'_, 't>) -> Result<Option<Var<'t, f64>>> {
        record_map_prior(ctx, "latitude_prior", |basis| self.bands(basis, 1.0))
    }
}

/// One row of the map under the latitude prior.
struct Band {
    /// Its first texel.
    start: usize,
    /// The unit RGB direction of the row's seen colour.
    colour: [f64; 3],
    /// Per texel, `lambda area q u` (0 for a free light).
    scale: Vec<f64>,
}

impl Band {
    /// The part of texel `x`'s colour across the row's.
    fn across(&self, x: &[f64]) -> [f64; 3] {
        let along: f64 = (0..3).map(|c| x[c] * self.colour[c]).sum();
        std::array::from_fn(|c| x[c] - along * self.colour[c])
    }
}

/// The latitude prior over a map's rows (rows the photo tells nothing of
/// are left out).
pub struct Bands {
    rows: Vec<Band>,
}

impl MapPrior for Bands {
    fn add_value_and_gradient(&self, x: &[f64], g: &mut [f64]) -> f64 {
        let mut f = 0.0;
        for band in &self.rows {
            for (k, scale) in band.scale.iter().enumerate() {
                let t = band.start + k;
                // |Q x|^2 with Q the symmetric projector across the colour: gradient 2 Q x.
                let v = band.across(&x[3 * t..3 * t + 3]);
                for c in 0..3 {
                    f += scale * v[c] * v[c];
                    g[3 * t + c] += 2.0 * scale * v[c];
                }
            }
        }
        f
    }

    fn texel_curvature(&self, texels: usize) -> Vec<f64> {
        // Per channel 2 s (1 - e_c^2); the mean over the channels is 2 s 2/3.
        let mut curvature = vec![0.0; texels];
        for band in &self.rows {
            for (k, scale) in band.scale.iter().enumerate() {
                curvature[band.start + k] += 4.0 / 3.0 * scale;
            }
        }
        curvature
    }
}

#[cfg(test)]
mod tests {
    use super::super::map_prior::tests::check_prior;
    use super::*;

    /// A 6 x 3 map of warm grey (2, 1.5, 1) with a white light of 40 in the
    /// middle row and that row's right half `right` (RGB).
    fn map(right: [f64; 3]) -> Vec<f64> {
        (0..18)
            .flat_map(|t| match (t / 6, t % 6) {
                (1, 1) => [40.0; 3],
                (1, c) if c >= 3 => right,
                _ => [2.0, 1.5, 1.0],
            })
            .collect()
    }

    /// A 6 x 3 basis from [`map`] (warm grey right half) whose middle row
    /// is seen on its left half only, with one free light there; the top
    /// row unseen.
    fn basis() -> PriorBasis {
        let (w, h) = (6, 3);
        let told = |t: usize| match (t / w, t % w) {
            (1, c) if c < 3 => 10.0,
            (2, _) => 1.0,
            _ => 0.0,
        };
        PriorBasis {
            start: map([2.0, 1.5, 1.0]),
            width: w,
            height: h,
            level: (0..w * h).map(|t| 0.5 + 0.1 * (t % 4) as f64).collect(),
            mean_level: 0.65,
            relative: true,
            mean_sq: 0.4,
            data_curvature: (0..3 * w * h).map(|k| told(k / 3)).collect(),
            free: (0..w * h).map(|t| t == w + 1).collect(),
        }
    }

    #[test]
    fn the_prior_s_gradient_matches_central_differences() {
        let x: Vec<f64> = (0..6 * 3 * 3).map(|i| 0.3 + ((i * 7919) % 23) as f64 * 0.11).collect();
        check_prior(LatitudePrior.bands(&basis(), 0.7), &x, "latitude prior");
    }

    #[test]
    fn an_unseen_texel_takes_its_row_s_seen_colour_at_its_own_level() {
        let basis = basis();
        let bands = LatitudePrior.bands(&basis, 1.0);
        // The top row holds no seen texel: no band. An unseen right half of the middle row
        // in blue costs; in the seen colour at any level (here 3x) it costs nothing.
        assert_eq!(bands.rows.len(), 2);
        let value = |x: &[f64]| bands.add_value_and_gradient(x, &mut vec![0.0; x.len()]);
        assert!(value(&map([1.0, 1.0, 3.0])) > 0.0);
        assert!(
            value(&map([6.0, 4.5, 3.0])).abs() < 1e-12,
            "{}",
            value(&map([6.0, 4.5, 3.0]))
        );
        // The best-seen texels and the free light are not held; the unseen ones are.
        let curvature = bands.texel_curvature(18);
        assert!(curvature[6 + 4] > 0.0 && curvature[12] > 0.0, "{curvature:?}");
        assert_eq!(curvature[6], 0.0);
        assert_eq!(curvature[6 + 1], 0.0);
    }
}
