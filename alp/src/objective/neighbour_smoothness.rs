//! The lighting phase's smoothness prior: neighbouring texels' differences,
//! area-weighted, relative to the local radiance level of the solve's start,
//! penalised quadratically up to an edge and linearly beyond (a vectorial
//! Charbonnier penalty), with the texels of a light brighter than the
//! sensor left free. It fills directions the probe sees poorly from
//! confident neighbours; the exact least-squares solve covers it.
//!
//! What it is built on ([`PriorBasis`]) the solve fixes once from its start
//! and the data: the local levels, the data's scale and the clipped lights.

use std::sync::Arc;

use autodiff::Var;
use render::colour::luminance;
use render::transport::Transport;

use super::map_prior::{MapPrior, record_map_prior};
use super::{DataTerm, Input, LeastSquaresForm, Phases, Term, TermContext};
use crate::error::{Error, Result};

/// Texels darker than this fraction of the start's mean level count as
/// that level in the relative smoothness (no division by zero radiance).
pub const DARK_LEVEL: f64 = 0.05;

/// A lighting solve's smoothness: its weight and its penalty's shape.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct Smoothness {
    /// Weight of the term (relative to the data term, scale-free).
    pub weight: f64,
    /// The RMS difference of two neighbours over the channels, as a
    /// fraction of the level it is measured against, past which the
    /// penalty grows linearly (a vectorial Charbonnier penalty: an edge
    /// costs in proportion to its height, not its square, so a light's
    /// edge stays sharp, and its three channels share one cost, so they
    /// keep their edge in one place instead of fringing in colour).
    /// 0: quadratic at every difference.
    pub edge: f64,
    /// The weight of a difference's chromatic part (its channels'
    /// departure from their mean) against its grey part: above 1, colour
    /// varies more slowly over the map than brightness, as in real scenes,
    /// so a direction whose colour the photo hardly shows (seen through a
    /// red label, its green and blue dim) takes its neighbours' colour
    /// instead of fitting noise. 1: the channels apart.
    pub chroma: f64,
}

impl Smoothness {
    /// Quadratic smoothness of `weight`, the channels apart.
    pub fn quadratic(weight: f64) -> Self {
        Smoothness {
            weight,
            edge: 0.0,
            chroma: 1.0,
        }
    }

    /// The smoothness as a least-squares form and its weight.
    pub fn form(&self) -> (LeastSquaresForm, f64) {
        let shape = NeighbourSmoothness::charbonnier(self.edge).chroma(self.chroma);
        (LeastSquaresForm::Smoothness(shape), self.weight)
    }

    /// The curvature of a neighbour pair's penalty in one channel of one
    /// texel, per unit of `lambda area q`, at small differences.
    pub fn channel_curvature(&self) -> f64 {
        (2.0 + 4.0 * self.chroma) / 3.0
    }
}

/// The smoothness prior as a declared term of the lighting phase; its
/// weight is the objective's. Applies where the map is on the tape and the
/// phase holds its [`LightingInputs`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct NeighbourSmoothness {
    edge: f64,
    chroma: f64,
}

impl NeighbourSmoothness {
    /// Quadratic at every difference, the channels apart.
    pub fn quadratic() -> Self {
        NeighbourSmoothness { edge: 0.0, chroma: 1.0 }
    }

    /// Linear past `edge` ([`Smoothness::edge`]), the channels apart.
    pub fn charbonnier(edge: f64) -> Self {
        NeighbourSmoothness { edge, chroma: 1.0 }
    }

    /// The same with colour `chroma` times as stiff as brightness
    /// ([`Smoothness::chroma`]).
    pub fn chroma(self, chroma: f64) -> Self {
        NeighbourSmoothness { chroma, ..self }
    }

    /// The solve's smoothness at `weight`.
    pub fn at_weight(&self, weight: f64) -> Smoothness {
        Smoothness {
            weight,
            edge: self.edge,
            chroma: self.chroma,
        }
    }

    /// Fails unless the edge is finite and >= 0 and chroma finite and > 0.
    pub fn validate(&self) -> Result<()> {
        if !(self.edge.is_finite() && self.edge >= 0.0) {
            return Err(Error::invalid("edge", format!("{} must be finite and >= 0", self.edge)));
        }
        if !(self.chroma.is_finite() && self.chroma > 0.0) {
            return Err(Error::invalid(
                "chroma",
                format!("{} must be finite and > 0", self.chroma),
            ));
        }
        Ok(())
    }
}

impl Term for NeighbourSmoothness {
    fn name(&self) -> &str {
        "neighbour_smoothness"
    }

    fn reads(&self) -> &'static [Input] {
        &[Input::Env, Input::LightingData]
    }

    fn phases(&self) -> Phases {
        Phases::LIGHTING
    }

    fn least_squares_form(&self) -> Option<LeastSquaresForm> {
        Some(LeastSquaresForm::Smoothness(*self))
    }

    fn evaluate<'t>(&self, ctx: &TermContext<'_, 't>) -> Result<Option<Var<'t, f64>>> {
        self.validate()?;
        record_map_prior(ctx, "neighbour_smoothness", |basis| basis.prior(&self.at_weight(1.0)))
    }
}

/// What a lighting solve fixes from its start and its data before it
/// begins: the local radiance level of each texel (the start's luminance),
/// the data's scale, its curvature per unknown and the texels free of the
/// prior.
pub struct PriorBasis {
    /// The map's columns.
    pub width: usize,
    /// The map's rows.
    pub height: usize,
    /// The start map (texel-major RGB).
    pub start: Vec<f64>,
    /// The start's luminance per texel.
    pub level: Vec<f64>,
    /// The mean of `level`.
    pub mean_level: f64,
    /// Whether differences count relative to the local level.
    pub relative: bool,
    /// The weighted mean square of the target: the prior's weight is
    /// relative to it, scale-free like the data term.
    pub mean_sq: f64,
    /// The data term's curvature per unknown (texel-major RGB).
    pub data_curvature: Vec<f64>,
    /// Texels of a light brighter than the sensor ([`clipped_lights`]).
    pub free: Vec<bool>,
}

impl PriorBasis {
    /// The basis of a solve over `transport` of `data` from `start`
    /// (texel-major RGB), differences `relative` to the start's level or
    /// not, and texels seen more than `clipped_light_share` through
    /// clipped pixels free.
    pub fn new(
        transport: &Transport,
        data: &DataTerm,
        start: &[f64],
        relative: bool,
        clipped_light_share: f64,
    ) -> Self {
        // Normalised by the mean weight over pixels and channels: the same as
        // a per-pixel weight's sum when the channels weigh alike.
        let weight_sum: f64 = data.weight.iter().flatten().sum::<f64>().max(1e-30) / 3.0;
        let data_norm = data.norm();
        let level: Vec<f64> = start.chunks_exact(3).map(|t| luminance([t[0], t[1], t[2]])).collect();
        let mean_level = level.iter().sum::<f64>() / level.len() as f64;
        let column_norms = transport.weighted_column_norms(&data.weight);
        PriorBasis {
            start: start.to_vec(),
            width: transport.width,
            height: transport.height,
            relative,
            mean_sq: data_norm / weight_sum,
            data_curvature: column_norms.iter().map(|h| 2.0 * h / data_norm).collect(),
            free: clipped_lights(transport, data, &column_norms, clipped_light_share),
            level,
            mean_level,
        }
    }

    /// The darkest level a relative difference is measured against.
    pub fn floor(&self) -> f64 {
        DARK_LEVEL * self.mean_level
    }

    /// The prior of `smoothness` on this basis: `lambda = weight / mean_sq /
    /// texels`, every neighbour pair but those touching a free texel, with
    /// its area weight sin(theta), its relative factor and its edge.
    pub fn prior(&self, smoothness: &Smoothness) -> Prior {
        let (w, h) = (self.width, self.height);
        let lambda = smoothness.weight / self.mean_sq / (w * h) as f64;
        let floor = self.floor();
        let relative = |i: usize, j: usize| -> f64 {
            let m = 0.5 * (self.level[i] + self.level[j]) + floor;
            match self.relative {
                true => ((self.mean_level + floor) / m.max(1e-30)).powi(2),
                false => 1.0,
            }
        };
        let edge_sq = (smoothness.edge * (self.mean_level + floor)).powi(2);
        let mut pairs = Vec::with_capacity(2 * w * h);
        for r in 0..h {
            let area = (std::f64::consts::PI * (r as f64 + 0.5) / h as f64).sin();
            for c in 0..w {
                let i = r * w + c;
                let below = (r + 1 < h).then_some((r + 1) * w + c);
                for j in std::iter::once(r * w + (c + 1) % w).chain(below) {
                    if !self.free[i] && !self.free[j] {
                        pairs.push(Pair {
                            i,
                            j,
                            area,
                            relative: relative(i, j),
                            edge_sq,
                        });
                    }
                }
            }
        }
        Prior {
            pairs,
            lambda,
            chroma: smoothness.chroma,
        }
    }
}

/// What the lighting phase's terms read besides the map: the photo's data
/// term and the solve's [`PriorBasis`].
pub struct LightingInputs {
    /// The photo's pixels as the solve weighs them.
    pub data: Arc<DataTerm>,
    /// What the smoothness is built on.
    pub basis: PriorBasis,
}

/// The texels of a light brighter than the sensor's range: those that a
/// clipped pixel (`data.at_least`) reads most strongly and that the data
/// see more than `share` through clipped pixels (their curvature, against
/// `column_norms`, [`Transport::weighted_column_norms`] of `data.weight`). A
/// clipped pixel only bounds the light from below, and the prior, relative
/// to the start's level there (the searches leave clipped pixels out),
/// would hold the light at the bound's least; free of it, the light rises
/// as far as the unclipped pixels around its footprint allow.
pub fn clipped_lights(transport: &Transport, data: &DataTerm, column_norms: &[f64], share: f64) -> Vec<bool> {
    let texels = transport.width * transport.height;
    let mut aimed = vec![false; texels];
    (0..transport.pixels)
        .filter(|&p| data.at_least[p] && data.used(p))
        .filter_map(|p| transport.strongest_texel(p))
        .for_each(|t| aimed[t] = true);
    if !aimed.contains(&true) {
        return aimed;
    }
    let clipped_weight: Vec<[f64; 3]> = (data.weight.iter().zip(&data.at_least))
        .map(|(w, &a)| if a { *w } else { [0.0; 3] })
        .collect();
    let clipped = transport.weighted_column_norms(&clipped_weight);
    let sum = |v: &[f64], t: usize| v[3 * t..3 * t + 3].iter().sum::<f64>();
    (0..texels)
        .map(|t| aimed[t] && sum(&clipped, t) > share * sum(column_norms, t))
        .collect()
}

/// Two neighbouring texels, the area weight of their difference, the
/// factor that makes it relative to their local level, and its edge.
pub struct Pair {
    /// The first texel.
    pub i: usize,
    /// Its neighbour (right or below).
    pub j: usize,
    /// sin(theta) of the pair's row: the texels' solid angle.
    pub area: f64,
    /// The factor that makes the difference relative to the local level.
    pub relative: f64,
    /// The squared difference (of the pair's relative difference) past
    /// which the penalty turns linear; 0: quadratic.
    pub edge_sq: f64,
}

/// The smoothness prior over an env map's neighbour pairs.
pub struct Prior {
    /// Every neighbour pair the prior holds.
    pub pairs: Vec<Pair>,
    /// The prior's weight over the data's scale and the texel count.
    pub lambda: f64,
    /// The weight of a difference's chromatic part ([`Smoothness::chroma`]).
    pub chroma: f64,
}

impl MapPrior for Prior {
    /// A pair's penalty is `lambda area s` with
    /// `s = q (3 m^2 + chroma |d - m|^2)` (`q` its relative factor, `d` its
    /// RGB difference, `m` the mean of `d`'s channels: `s = q |d|^2` at
    /// `chroma` 1) while that is small against `3 edge^2` (the pair's),
    /// and `lambda area 6 edge^2 (sqrt(1 + s / (3 edge^2)) - 1)` in
    /// general: the same at small differences, linear in `sqrt(s)` at
    /// large ones.
    fn add_value_and_gradient(&self, x: &[f64], g: &mut [f64]) -> f64 {
        let mut f = 0.0;
        for p in &self.pairs {
            let d: [f64; 3] = std::array::from_fn(|c| x[p.i * 3 + c] - x[p.j * 3 + c]);
            let m = (d[0] + d[1] + d[2]) / 3.0;
            let chromatic = (d[0] - m).powi(2) + (d[1] - m).powi(2) + (d[2] - m).powi(2);
            let sq = p.relative * (3.0 * m * m + self.chroma * chromatic);
            let slope = match p.edge_sq > 0.0 {
                true => {
                    let root = (1.0 + sq / (3.0 * p.edge_sq)).sqrt();
                    // 6 edge^2 (root - 1), without the cancellation of a
                    // wide edge's root near 1.
                    f += self.lambda * p.area * 2.0 * sq / (root + 1.0);
                    1.0 / root
                }
                false => {
                    f += self.lambda * p.area * sq;
                    1.0
                }
            };
            for c in 0..3 {
                let dg = 2.0 * self.lambda * p.area * p.relative * slope * (m + self.chroma * (d[c] - m));
                g[p.i * 3 + c] += dg;
                g[p.j * 3 + c] -= dg;
            }
        }
        f
    }

    fn texel_curvature(&self, texels: usize) -> Vec<f64> {
        let pair_curvature = (2.0 + 4.0 * self.chroma) / 3.0;
        let mut curvature = vec![0.0; texels];
        for p in &self.pairs {
            curvature[p.i] += pair_curvature * self.lambda * p.area * p.relative;
            curvature[p.j] += pair_curvature * self.lambda * p.area * p.relative;
        }
        curvature
    }
}

#[cfg(test)]
mod tests {
    use super::super::map_prior::tests::check_prior;
    use super::*;

    #[test]
    fn the_prior_s_gradient_matches_central_differences() {
        let (w, h) = (5, 3);
        let x: Vec<f64> = (0..w * h * 3).map(|i| 0.3 + ((i * 7919) % 23) as f64 * 0.11).collect();
        let mut pairs = Vec::new();
        for i in 0..w * h {
            let j = (i + 1) % (w * h);
            pairs.push(Pair {
                i,
                j,
                area: 0.2 + 0.1 * (i % 4) as f64,
                relative: 0.5 + (i % 3) as f64,
                edge_sq: 0.0,
            });
        }
        // Quadratic, and with two edges: the pairs' `q |d|^2 / (3 edge^2)`
        // runs from 0.005 to 0.9 with the first (near-quadratic pairs to the
        // bend) and from 0.5 to 90 with the second (the bend to far into
        // the linear part); each with the channels apart and with colour 8
        // times stiffer; and with each pair's edge of its own, from
        // near-quadratic (1e9) to far past the bend.
        let cases = [0.0, 5.0, 0.05].into_iter().flat_map(|e| [(e, 1.0), (e, 8.0)]);
        for (edge_sq, chroma) in cases.chain([(-1.0, 8.0)]) {
            for (k, p) in pairs.iter_mut().enumerate() {
                p.edge_sq = match edge_sq < 0.0 {
                    true => [1e9, 5.0, 0.05][k % 3],
                    false => edge_sq,
                };
            }
            let prior = Prior {
                pairs: std::mem::take(&mut pairs),
                lambda: 0.7,
                chroma,
            };
            let what = format!("edge^2 {edge_sq}, chroma {chroma}");
            pairs = check_prior(prior, &x, &what).pairs;
        }
    }

    #[test]
    fn bad_shapes_are_errors() {
        for (term, field) in [
            (NeighbourSmoothness::charbonnier(-0.1), "edge"),
            (NeighbourSmoothness::charbonnier(f64::NAN), "edge"),
            (NeighbourSmoothness::quadratic().chroma(0.0), "chroma"),
        ] {
            assert_eq!(term.validate().unwrap_err().field_name(), Some(field));
        }
    }
}
