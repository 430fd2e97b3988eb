//! The latitude prior: a scene's radiance and colour vary far more with
//! elevation (sky, horizon, ground) than with azimuth, so a texel the photo
//! tells little of leans towards what the seen part of its row shows.
//!
//! Per channel, with `m_r` the row's seen level in the solve's start -- the
//! mean of its texels weighted by how much the photo tells of each (its
//! data curvature relative to the best-seen texel's) over their level (so
//! that a light in the row does not lift the rest) -- the prior is
//!
//! ```text
//! lambda sum_r area_r q_r sum_{t in r} (x_t - m_r)^2
//! ```
//!
//! with `q_r` the row's relative factor (differences count against its
//! level, as the smoothness's do) and `lambda` the smoothness's scale. Its
//! curvature is alike for every texel, so it moves a texel in proportion to
//! how little the data tell of it (their curvature against its). `m_r` is a
//! constant of the solve (the start is the coarser level's solution): were
//! it the current map's, the few texels that set it would answer for the
//! whole row. The lights brighter than the sensor are left out. Not in the
//! default objective: on the train split it costs every sphere, the lights'
//! energy most (docs/results/benchmark.md 19.2).

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
            let confidence = |t: usize| told[t] / most;
            let seen_weight = |t: usize| match basis.free[t] {
                true => 0.0,
                false => confidence(t) / (basis.level[t] + floor),
            };
            let total: f64 = texels.clone().map(seen_weight).sum();
            if total <= 0.0 {
                continue;
            }
            let beta: Vec<f64> = texels.clone().map(|t| seen_weight(t) / total).collect();
            let level: f64 = texels.clone().zip(&beta).map(|(t, b)| b * basis.level[t]).sum();
            let target: [f64; 3] =
                std::array::from_fn(|c| texels.clone().zip(&beta).map(|(t, b)| b * basis.start[3 * t + c]).sum());
            let relative = match basis.relative {
                true => ((basis.mean_level + floor) / (level + floor)).powi(2),
                false => 1.0,
            };
            let area = (std::f64::consts::PI * (r as f64 + 0.5) / h as f64).sin();
            let held = texels.map(|t| if basis.free[t] { 0.0 } else { 1.0 }).collect();
            rows.push(Band {
                start: r * w,
                scale: lambda * area * relative,
                target,
                held,
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
    /// `lambda area q` of the row.
    scale: f64,
    /// The row's seen level in the start, per channel.
    target: [f64; 3],
    /// 1 for a texel the prior holds, 0 for a free light.
    held: Vec<f64>,
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
            for (k, held) in band.held.iter().enumerate() {
                let t = band.start + k;
                for c in 0..3 {
                    let d = x[3 * t + c] - band.target[c];
                    f += band.scale * held * d * d;
                    g[3 * t + c] += 2.0 * band.scale * held * d;
                }
            }
        }
        f
    }

    fn texel_curvature(&self, texels: usize) -> Vec<f64> {
        let mut curvature = vec![0.0; texels];
        for band in &self.rows {
            for (k, u) in band.held.iter().enumerate() {
                curvature[band.start + k] += 2.0 * band.scale * u;
            }
        }
        curvature
    }
}

#[cfg(test)]
mod tests {
    use super::super::map_prior::tests::check_prior;
    use super::*;

    /// A 6 x 3 map of 2 with a light of 40 in the middle row and its right
    /// half at `right`.
    fn map(right: f64) -> Vec<f64> {
        (0..18)
            .flat_map(|t| {
                let v = match (t / 6, t % 6) {
                    (1, 1) => 40.0,
                    (1, c) if c >= 3 => right,
                    _ => 2.0,
                };
                [v; 3]
            })
            .collect()
    }

    /// A 6 x 3 basis from [`map`]`(2)` whose middle row is seen on its left
    /// half only, with one free light there; the top row unseen.
    fn basis() -> PriorBasis {
        let (w, h) = (6, 3);
        let told = |t: usize| match (t / w, t % w) {
            (1, c) if c < 3 => 10.0,
            (2, _) => 1.0,
            _ => 0.0,
        };
        PriorBasis {
            start: map(2.0),
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
    fn an_unseen_texel_takes_its_row_s_seen_level_and_a_seen_one_keeps_its_own() {
        let basis = basis();
        let bands = LatitudePrior.bands(&basis, 1.0);
        // The top row holds no seen texel: no band. The middle row's seen level is its seen
        // texels' in the start (the free light left out): a map that is 2 there and 5 on the
        // unseen right half costs, and moving the right half to 2 removes the cost.
        assert_eq!(bands.rows.len(), 2);
        let value = |x: &[f64]| bands.add_value_and_gradient(x, &mut vec![0.0; x.len()]);
        assert!(value(&map(5.0)) > 0.0);
        assert!(value(&map(2.0)).abs() < 1e-12, "{}", value(&map(2.0)));
        // The free light is not held.
        let curvature = bands.texel_curvature(18);
        assert!(curvature[6 + 4] > 0.0 && curvature[6] > 0.0, "{curvature:?}");
        assert_eq!(curvature[6 + 1], 0.0);
    }
}
