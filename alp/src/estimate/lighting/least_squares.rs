//! The regularised, non-negative linear least-squares solve for the env map
//! over a recorded [`Transport`], by bounded L-BFGS (or, to compare, the
//! paper's many Adam steps), with a smoothness prior and a floor for texels
//! the data drive dark; and the map pyramid of a coarse-to-fine solve.

use optim::schedule::Decay;
use optim::{Adam, Bounds, Lbfgs, ParamGroup, Solver, Termination};

use render::colour::luminance;
use render::transport::{PullBackScratch, Transport};

use crate::error::{Error, Result};
use crate::estimate::settings::{LightingMethod, Smoothness};

/// The 2:1 map sizes of a coarse-to-fine solve ending at `size`: heights
/// doubling from `coarsest` (or `size` itself when not larger).
pub fn pyramid(size: (usize, usize), coarsest: usize) -> Vec<(usize, usize)> {
    let mut heights = vec![size.1];
    while heights[0] / 2 >= coarsest && heights[0] % 2 == 0 {
        heights.insert(0, heights[0] / 2);
    }
    heights.into_iter().map(|h| (2 * h, h)).collect()
}

/// The photo as a lighting solve reads it, per data pixel: the target
/// radiance, the weight per channel, whether the target is a lower bound
/// only (a pixel the sensor clipped: its radiance is at least the clipping
/// level, and a re-render above it is no error), and per channel the
/// half-width of the interval of radiance the stored value stands for (an
/// 8-bit value is any radiance that rounds to it: a re-render within it is
/// no error; 0 for linear HDR).
#[derive(Clone, Debug, Default)]
pub struct DataTerm {
    pub target: Vec<[f64; 3]>,
    pub weight: Vec<[f64; 3]>,
    pub at_least: Vec<bool>,
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
}

/// Settings of the lighting solve.
#[derive(Clone, Copy, Debug)]
pub struct LightingSolve {
    /// The smoothness prior.
    pub smoothness: Smoothness,
    /// Whether neighbour differences count relative to the start's local
    /// radiance level (else in absolute terms).
    pub relative_smoothness: bool,
    /// The least radiance of a texel, as a fraction of the start's local
    /// level (grey; 0: non-negative only).
    pub floor_of_level: f64,
    /// A texel that a clipped pixel reads most strongly, and whose data
    /// curvature comes more than this share from clipped pixels, is free
    /// of the prior (`clipped_lights`; 1: none is).
    pub clipped_light_share: f64,
    /// L-BFGS iterations at most.
    pub max_iters: usize,
    /// How the objective is minimised.
    pub method: LightingMethod,
}

/// The official code's learning-rate decay per Adam step, `10^(-0.0002)`.
const ADAM_DECAY: f64 = 0.999_539_589_003_409_1;

/// Texels darker than this fraction of the start's mean level count as
/// that level in the relative smoothness (no division by zero radiance).
pub(super) const DARK_LEVEL: f64 = 0.05;

/// The output map's least radiance of a texel, as a fraction of the
/// start's local level (grey): no direction of a scene is black,
/// and a texel the data drive to zero has no colour, which a mirror shows
/// 90 degrees off (the dark ring a solve leaves around a light sharper
/// than the probe's lobes resolve).
pub const FLOOR_OF_LEVEL: f64 = 0.02;

/// Solves `min_x>=0 sum_pc w_pc (A x - b)_pc^2 / sum_pc w_pc b_pc^2 + lambda R(x)` where
/// `R` penalises squared differences of neighbouring texels (area-weighted,
/// relative to the local level of the start `x0`, divided by the
/// target's mean square so that `lambda` is scale-free, and growing only
/// linearly past the smoothness's edge): texels the probe sees poorly are
/// filled from confident neighbours. The bound is
/// `floor_of_level` times that level.
/// An error only where L-BFGS refuses its inputs; a solve that stops short
/// of convergence says how in [`Solved::termination`].
pub fn solve(transport: &Transport, data: &DataTerm, settings: LightingSolve, x0: &[f64]) -> Result<Solved> {
    let (target, weight) = (&data.target, &data.weight);
    let (w, h) = (transport.width, transport.height);
    assert_eq!(target.len(), transport.pixels, "solve: one target per pixel");
    assert_eq!(x0.len(), transport.unknowns(), "solve: the start has the wrong size");
    // Normalised by the mean weight over pixels and channels: the same as
    // a per-pixel weight's sum when the channels weigh alike.
    let weight_sum: f64 = weight.iter().flatten().sum::<f64>().max(1e-30) / 3.0;
    // The data term is over the target's weighted energy: both terms are then
    // alike in any exposure (over `weight_sum` alone, a photo ten times
    // brighter would weigh its data a hundred times more against the prior
    // whenever the weights are relative, 1 / level^2, as the estimate's are).
    let data_norm = (target.iter().zip(weight))
        .map(|(t, wt)| (0..3).map(|c| wt[c] * t[c] * t[c]).sum::<f64>() / 3.0)
        .sum::<f64>()
        .max(1e-30);
    let mean_sq = data_norm / weight_sum;
    let lambda = settings.smoothness.weight / mean_sq / (w * h) as f64;
    // Differences may count relative to the local radiance level of the
    // start (a bright light's edge is no rougher than a dark wall's texture).
    let level: Vec<f64> = x0.chunks_exact(3).map(|t| luminance([t[0], t[1], t[2]])).collect();
    let mean_level = level.iter().sum::<f64>() / level.len() as f64;
    let floor = DARK_LEVEL * mean_level;
    let relative = |i: usize, j: usize| -> f64 {
        let m = 0.5 * (level[i] + level[j]) + floor;
        match settings.relative_smoothness {
            true => ((mean_level + floor) / m.max(1e-30)).powi(2),
            false => 1.0,
        }
    };
    // Neighbour pairs with their area weight sin(theta).
    let mut pairs = Vec::with_capacity(2 * w * h);
    for r in 0..h {
        let area = (std::f64::consts::PI * (r as f64 + 0.5) / h as f64).sin();
        for c in 0..w {
            let i = r * w + c;
            let below = (r + 1 < h).then_some((r + 1) * w + c);
            for j in std::iter::once(r * w + (c + 1) % w).chain(below) {
                pairs.push(Pair {
                    i,
                    j,
                    area,
                    relative: relative(i, j),
                    edge_sq: 0.0,
                });
            }
        }
    }
    // The data term's curvature per unknown, and the prior's per texel (at
    // small differences; alike in every channel).
    let column_norms = transport.weighted_column_norms(weight);
    let data_curvature: Vec<f64> = column_norms.iter().map(|h| 2.0 * h / data_norm).collect();
    let light = clipped_lights(transport, data, &column_norms, settings.clipped_light_share);
    pairs.retain(|p| !light[p.i] && !light[p.j]);
    let pair_curvature = settings.smoothness.channel_curvature();
    let mut prior_curvature = vec![0.0; w * h];
    for p in &pairs {
        prior_curvature[p.i] += pair_curvature * lambda * p.area * p.relative;
        prior_curvature[p.j] += pair_curvature * lambda * p.area * p.relative;
    }
    // Each pair's edge: wider where the photo tells less than the prior.
    let edge_sq = (settings.smoothness.edge * (mean_level + floor)).powi(2);
    let told = |t: usize| data_curvature[3 * t..3 * t + 3].iter().sum::<f64>() / 3.0 / prior_curvature[t].max(1e-300);
    for p in &mut pairs {
        let evidence = told(p.i).min(told(p.j)).max(1e-12);
        p.edge_sq = edge_sq * (1.0 + settings.smoothness.edge_evidence / evidence);
    }
    let prior = Prior {
        pairs,
        lambda,
        chroma: settings.smoothness.chroma,
    };
    // Jacobi preconditioning, x = s * y with s = 1 / sqrt(diag of the
    // Hessian): a texel that a thousand pixels see and one only the
    // smoothness reaches differ in curvature by orders of magnitude, and
    // L-BFGS on x crawls along the flat ones. Bounds stay y >= 0.
    let curvature: Vec<f64> = data_curvature
        .iter()
        .enumerate()
        .map(|(k, d)| d + prior_curvature[k / 3])
        .collect();
    let scale: Vec<f64> = curvature.iter().map(|&h| 1.0 / h.max(1e-300).sqrt()).collect();
    let mut x = vec![0.0; transport.unknowns()];
    let mut rendered = vec![[0.0; 3]; transport.pixels];
    let mut scratch = PullBackScratch::default();
    let mut objective = |y: &[f64], g: &mut [f64]| -> f64 {
        x.iter_mut().zip(y).zip(&scale).for_each(|((x, y), s)| *x = s * y);
        let x = &x;
        g.iter_mut().for_each(|v| *v = 0.0);
        transport.apply_and_pull_back(
            x,
            |p, px| std::array::from_fn(|c| 2.0 * weight[p][c] * data.residual(p, c, px[c]) / data_norm),
            &mut rendered,
            g,
            &mut scratch,
        );
        let mut f = 0.0;
        for p in 0..transport.pixels {
            for c in 0..3 {
                f += weight[p][c] * data.residual(p, c, rendered[p][c]).powi(2);
            }
        }
        f /= data_norm;
        f += prior.add_value_and_gradient(x, g);
        g.iter_mut().zip(&scale).for_each(|(g, s)| *g *= s);
        f
    };
    let n = transport.unknowns();
    let lower: Vec<f64> = (0..n)
        .map(|k| settings.floor_of_level * level[k / 3] / scale[k])
        .collect();
    let y0 = x0
        .iter()
        .zip(&scale)
        .zip(&lower)
        .map(|((x, s), l)| (x / s).max(*l))
        .collect();
    let (best_y, evaluations, termination) = match settings.method {
        LightingMethod::LeastSquares => {
            let bounds = Bounds::new(lower, vec![f64::INFINITY; n]).expect("valid bounds");
            let mut lbfgs = Lbfgs::builder()
                .bounds(bounds)
                .max_iters(settings.max_iters)
                .grad_tol(1e-12)
                .build()
                .map_err(Error::solver("lighting solve"))?;
            let state = lbfgs
                .minimize(&mut objective, y0)
                .map_err(Error::solver("lighting solve"))?;
            (state.best_x, state.evals, state.termination)
        }
        LightingMethod::Adam {
            steps_per_iteration,
            rate,
        } => {
            // Adam on the texels x = s (lower + z), z >= 0: its steps are in
            // radiance whatever a texel's curvature, as in the paper.
            let (mut y, mut gy) = (vec![0.0; n], vec![0.0; n]);
            let mut on_texels = |z: &[f64], gz: &mut [f64]| -> f64 {
                y.iter_mut()
                    .zip(z)
                    .zip(lower.iter().zip(&scale))
                    .for_each(|((y, z), (l, s))| *y = l + z / s);
                let f = objective(&y, &mut gy);
                gz.iter_mut().zip(&gy).zip(&scale).for_each(|((g, gy), s)| *g = gy / s);
                f
            };
            let z0: Vec<f64> = y0
                .iter()
                .zip(&lower)
                .zip(&scale)
                .map(|((y, l), s)| (y - l) * s)
                .collect();
            let schedule = Decay::exponential(ADAM_DECAY).map_err(Error::solver("lighting solve"))?;
            let mut adam = Adam::builder(n)
                .group(
                    ParamGroup::new(0..n, rate * mean_level.max(1e-12))
                        .bounds(0.0, f64::INFINITY)
                        .schedule(schedule),
                )
                .max_iters(settings.max_iters * steps_per_iteration)
                .build()
                .map_err(Error::solver("lighting solve"))?;
            let state = adam
                .minimize(&mut on_texels, z0)
                .map_err(Error::solver("lighting solve"))?;
            let y = state
                .best_x
                .iter()
                .zip(&lower)
                .zip(&scale)
                .map(|((z, l), s)| l + z / s)
                .collect();
            (y, state.evals, state.termination)
        }
    };
    Ok(Solved {
        env: best_y.iter().zip(&scale).map(|(y, s)| y * s).collect(),
        evaluations,
        termination,
    })
}

/// The texels of a light brighter than the sensor's range: those that a
/// clipped pixel (`data.at_least`) reads most strongly and that the data
/// see more than `share` through clipped pixels (their curvature, against
/// `column_norms`, [`Transport::weighted_column_norms`] of `data.weight`). A
/// clipped pixel only bounds the light from below, and the prior, relative
/// to the start's level there (the searches leave clipped pixels out),
/// would hold the light at the bound's least; free of it, the light rises
/// as far as the unclipped pixels around its footprint allow.
pub(super) fn clipped_lights(transport: &Transport, data: &DataTerm, column_norms: &[f64], share: f64) -> Vec<bool> {
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

/// A lighting solve's result.
pub struct Solved {
    /// The env map, texel-major RGB.
    pub env: Vec<f64>,
    /// L-BFGS objective evaluations.
    pub evaluations: usize,
    /// Why L-BFGS stopped (a spent budget or a failed line search keeps the
    /// best map found).
    pub termination: Option<Termination>,
}

/// Two neighbouring texels, the area weight of their difference, the
/// factor that makes it relative to their local level, and its edge.
pub(super) struct Pair {
    pub(super) i: usize,
    pub(super) j: usize,
    pub(super) area: f64,
    pub(super) relative: f64,
    /// The squared difference (of the pair's relative difference) past
    /// which the penalty turns linear; 0: quadratic.
    pub(super) edge_sq: f64,
}

/// The smoothness prior over an env map's neighbour pairs.
pub(super) struct Prior {
    pub(super) pairs: Vec<Pair>,
    pub(super) lambda: f64,
    /// The weight of a difference's chromatic part ([`Smoothness::chroma`]).
    pub(super) chroma: f64,
}

impl Prior {
    /// Returns the prior's value at the env map `x` (texel-major RGB) and
    /// adds its gradient to `g`. A pair's penalty is `lambda area s` with
    /// `s = q (3 m^2 + chroma |d - m|^2)` (`q` its relative factor, `d` its
    /// RGB difference, `m` the mean of `d`'s channels: `s = q |d|^2` at
    /// `chroma` 1) while that is small against `3 edge^2` (the pair's),
    /// and `lambda area 6 edge^2 (sqrt(1 + s / (3 edge^2)) - 1)` in
    /// general: the same at small differences, linear in `sqrt(s)` at
    /// large ones.
    pub(super) fn add_value_and_gradient(&self, x: &[f64], g: &mut [f64]) -> f64 {
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
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Vec2;

    /// Solves for a map every texel of which one pixel reads directly (one
    /// sample per texel centre, `throughput(texel)`), from a constant start
    /// in at most `max_iters` iterations of `method`, and checks it comes
    /// back to within `tolerance`.
    fn recovers_a_map_seen_whole(
        throughput: impl Fn(usize) -> f32,
        max_iters: usize,
        method: LightingMethod,
        tolerance: f64,
    ) {
        let (w, h) = (8, 4);
        let truth: Vec<f64> = (0..w * h * 3).map(|i| 0.5 + (i % 7) as f64 * 0.3).collect();
        let uv: Vec<Vec2> = (0..w * h)
            .map(|t| Vec2::new(((t % w) as f32 + 0.5) / w as f32, ((t / w) as f32 + 0.5) / h as f32))
            .collect();
        let segment: Vec<u32> = (0..uv.len() as u32).collect();
        let throughputs: Vec<[f32; 3]> = (0..uv.len()).map(|t| [throughput(t); 3]).collect();
        let transport = Transport::new(&segment, &uv, &throughputs, uv.len(), w, h);
        let mut target = vec![[0.0; 3]; uv.len()];
        transport.apply(&truth, &mut target);
        let solved = solve(
            &transport,
            &DataTerm::exact(target.clone(), vec![[1.0; 3]; uv.len()]),
            LightingSolve {
                smoothness: Smoothness::quadratic(0.0),
                relative_smoothness: false,
                floor_of_level: 0.0,
                clipped_light_share: 1.0,
                max_iters,
                method,
            },
            &vec![1.0; w * h * 3],
        )
        .expect("a solve");
        assert!(solved.evaluations > 0);
        for (a, b) in solved.env.iter().zip(&truth) {
            assert!((a - b).abs() < tolerance, "{a} vs {b}");
        }
    }

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
    fn a_clipped_pixel_bounds_its_texel_from_below_only() {
        // Each pixel reads one texel; texel 9's true radiance is 5, but its
        // pixel was clipped at 2. As a target the clip pulls the texel down
        // to 2; as a lower bound it leaves the texel wherever the rest
        // puts it (here, the start's 5), and pushes a texel below the
        // bound up to at least it.
        let (w, h) = (8, 4);
        let uv: Vec<Vec2> = (0..w * h)
            .map(|t| Vec2::new(((t % w) as f32 + 0.5) / w as f32, ((t / w) as f32 + 0.5) / h as f32))
            .collect();
        let segment: Vec<u32> = (0..uv.len() as u32).collect();
        let transport = Transport::new(&segment, &uv, &vec![[1.0; 3]; uv.len()], uv.len(), w, h);
        let mut target = vec![[1.0; 3]; uv.len()];
        target[9] = [2.0; 3];
        let texel_9 = |at_least: bool, start: f64| {
            let mut data = DataTerm::exact(target.clone(), vec![[1.0; 3]; uv.len()]);
            data.at_least[9] = at_least;
            let mut x0 = vec![1.0; w * h * 3];
            x0[27..30].iter_mut().for_each(|v| *v = start);
            let settings = LightingSolve {
                smoothness: Smoothness::quadratic(0.0),
                relative_smoothness: false,
                floor_of_level: 0.0,
                clipped_light_share: 1.0,
                max_iters: 200,
                method: LightingMethod::LeastSquares,
            };
            solve(&transport, &data, settings, &x0).expect("a solve").env[27]
        };
        assert!(
            (texel_9(false, 5.0) - 2.0).abs() < 1e-3,
            "a target: {}",
            texel_9(false, 5.0)
        );
        assert!(
            (texel_9(true, 5.0) - 5.0).abs() < 1e-3,
            "a bound: {}",
            texel_9(true, 5.0)
        );
        // (Anywhere at or above the bound costs nothing.)
        assert!(texel_9(true, 0.5) > 2.0 - 1e-3, "raised: {}", texel_9(true, 0.5));
    }

    #[test]
    fn a_light_seen_through_clipped_pixels_rises_as_far_as_the_rest_allows() {
        // Each pixel reads one texel of a map of 1s; texel 9 holds a light of
        // 100, which its own pixel (clipped at 2) bounds from below only, and
        // one more pixel reads at 5 % beside texel 10 (a rough lobe's tail:
        // 0.95 + 5 = 5.95). Under a strong prior the light stays near its
        // bound; free of it, the tail's pixel sets it.
        let (w, h) = (8, 4);
        let centre = |t: usize| Vec2::new(((t % w) as f32 + 0.5) / w as f32, ((t / w) as f32 + 0.5) / h as f32);
        let mut uv: Vec<Vec2> = (0..w * h).map(centre).collect();
        let mut segment: Vec<u32> = (0..uv.len() as u32).collect();
        let mut throughput = vec![[1.0f32; 3]; uv.len()];
        let tail = (w * h) as u32;
        uv.extend([centre(9), centre(10)]);
        segment.extend([tail, tail]);
        throughput.extend([[0.05; 3], [0.95; 3]]);
        let transport = Transport::new(&segment, &uv, &throughput, w * h + 1, w, h);
        let mut target = vec![[1.0; 3]; w * h + 1];
        target[9] = [2.0; 3];
        target[w * h] = [5.95; 3];
        let mut data = DataTerm::exact(target, vec![[1.0; 3]; w * h + 1]);
        data.at_least[9] = true;
        let light = |share: f64| {
            let settings = LightingSolve {
                smoothness: Smoothness::quadratic(1.0),
                relative_smoothness: false,
                floor_of_level: 0.0,
                clipped_light_share: share,
                max_iters: 500,
                method: LightingMethod::LeastSquares,
            };
            solve(&transport, &data, settings, &vec![1.0; w * h * 3])
                .expect("a solve")
                .env[27]
        };
        let lights = clipped_lights(&transport, &data, &transport.weighted_column_norms(&data.weight), 0.5);
        assert_eq!(lights.iter().filter(|&&l| l).count(), 1, "one light texel");
        assert!(lights[9], "the clipped pixel's texel");
        assert!((light(0.5) - 100.0).abs() < 1.0, "free: {}", light(0.5));
        assert!(light(1.0) < 10.0, "held by the prior: {}", light(1.0));
    }

    #[test]
    fn a_floor_keeps_a_texel_the_data_drive_dark_above_it() {
        // One texel of the truth is black: without a floor the solve
        // recovers it, with one it stops at the floor of the start's level (1).
        let (w, h) = (8, 4);
        let truth: Vec<f64> = (0..w * h * 3).map(|i| if i / 3 == 9 { 0.0 } else { 1.0 }).collect();
        let uv: Vec<Vec2> = (0..w * h)
            .map(|t| Vec2::new(((t % w) as f32 + 0.5) / w as f32, ((t / w) as f32 + 0.5) / h as f32))
            .collect();
        let segment: Vec<u32> = (0..uv.len() as u32).collect();
        let transport = Transport::new(&segment, &uv, &vec![[1.0; 3]; uv.len()], uv.len(), w, h);
        let mut target = vec![[0.0; 3]; uv.len()];
        transport.apply(&truth, &mut target);
        let dark = |floor_of_level: f64| {
            let settings = LightingSolve {
                smoothness: Smoothness::quadratic(1e-9),
                relative_smoothness: true,
                floor_of_level,
                clipped_light_share: 1.0,
                max_iters: 500,
                method: LightingMethod::LeastSquares,
            };
            let x = solve(
                &transport,
                &DataTerm::exact(target.clone(), vec![[1.0; 3]; uv.len()]),
                settings,
                &vec![1.0; w * h * 3],
            )
            .expect("a solve")
            .env;
            [x[27], x[28], x[29]]
        };
        for v in dark(0.0) {
            assert!(v.abs() < 1e-3, "no floor: {v}");
        }
        for v in dark(FLOOR_OF_LEVEL) {
            assert!((v - FLOOR_OF_LEVEL).abs() < 1e-3, "floor: {v}");
        }
    }

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
        // the linear part).
        // Each with the channels apart and with colour 8 times stiffer; and
        // with each pair's edge of its own, from near-quadratic (1e9) to
        // far past the bend.
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
            let mut g = vec![0.0; x.len()];
            prior.add_value_and_gradient(&x, &mut g);
            let h_step = 1e-6;
            for k in 0..x.len() {
                let at = |dx: f64| {
                    let mut y = x.clone();
                    y[k] += dx;
                    prior.add_value_and_gradient(&y, &mut vec![0.0; x.len()])
                };
                let fd = (at(h_step) - at(-h_step)) / (2.0 * h_step);
                assert!(
                    (fd - g[k]).abs() < 1e-6 * fd.abs().max(1.0),
                    "edge^2 {edge_sq}, chroma {chroma}, x[{k}]: {} vs {fd}",
                    g[k]
                );
            }
            pairs = prior.pairs;
        }
    }

    #[test]
    fn an_edge_keeps_a_blurred_step_sharper_than_a_quadratic_prior() {
        // Each pixel sees three neighbouring texels of a row (a lobe wider
        // than a texel); the truth is a bright band on a dark ground. At
        // the same weight, the quadratic prior spreads the band's edges,
        // the edged one keeps them.
        let (w, h) = (32, 16);
        let truth: Vec<f64> = (0..w * h)
            .flat_map(|t| [if (8..16).contains(&(t % w)) { 10.0 } else { 1.0 }; 3])
            .collect();
        let (mut segment, mut uv) = (Vec::new(), Vec::new());
        for t in 0..w * h {
            for dc in [-1.0, 0.0, 1.0] {
                segment.push(t as u32);
                let col = (t % w) as f32 + 0.5 + dc;
                uv.push(Vec2::new(
                    col.rem_euclid(w as f32) / w as f32,
                    ((t / w) as f32 + 0.5) / h as f32,
                ));
            }
        }
        let throughput = vec![[1.0 / 3.0; 3]; segment.len()];
        let transport = Transport::new(&segment, &uv, &throughput, w * h, w, h);
        let mut target = vec![[0.0; 3]; w * h];
        transport.apply(&truth, &mut target);
        let error = |edge: f64| {
            let settings = LightingSolve {
                smoothness: Smoothness {
                    edge,
                    ..Smoothness::quadratic(0.3)
                },
                relative_smoothness: false,
                floor_of_level: 0.0,
                clipped_light_share: 1.0,
                max_iters: 2000,
                method: LightingMethod::LeastSquares,
            };
            let x = solve(
                &transport,
                &DataTerm::exact(target.clone(), vec![[1.0; 3]; w * h]),
                settings,
                &vec![2.0; w * h * 3],
            )
            .expect("a solve")
            .env;
            (x.iter().zip(&truth).map(|(a, b)| (a - b).powi(2)).sum::<f64>() / x.len() as f64).sqrt()
        };
        let (quadratic, edged) = (error(0.0), error(0.05));
        assert!(
            edged < 0.5 * quadratic,
            "RMS error {edged} with an edge, {quadratic} without"
        );
    }

    #[test]
    fn the_solve_is_the_same_at_any_exposure() {
        // Each pixel reads its texel and half of the next, through a noisy
        // target weighted relatively (1 / level^2, as the estimate weighs):
        // a photo and a start 1000 times brighter or darker give the same
        // map times 1000 or over it, the data and the prior in the same
        // balance.
        let (w, h) = (8, 4);
        let n = w * h;
        let uv: Vec<Vec2> = (0..2 * n)
            .map(|k| {
                let t = (k / 2 + k % 2) % n;
                Vec2::new(((t % w) as f32 + 0.5) / w as f32, ((t / w) as f32 + 0.5) / h as f32)
            })
            .collect();
        let segment: Vec<u32> = (0..2 * n as u32).map(|k| k / 2).collect();
        let throughputs: Vec<[f32; 3]> = (0..2 * n).map(|k| [1.0 - 0.5 * (k % 2) as f32; 3]).collect();
        let transport = Transport::new(&segment, &uv, &throughputs, n, w, h);
        let truth: Vec<f64> = (0..n * 3).map(|i| 0.2 + ((i * 37) % 11) as f64 * 0.4).collect();
        let mut clean = vec![[0.0; 3]; n];
        transport.apply(&truth, &mut clean);
        let settings = LightingSolve {
            smoothness: Smoothness {
                weight: 0.3,
                edge: 0.05,
                chroma: 2.0,
                edge_evidence: 0.5,
            },
            relative_smoothness: true,
            floor_of_level: FLOOR_OF_LEVEL,
            clipped_light_share: 1.0,
            max_iters: 300,
            method: LightingMethod::LeastSquares,
        };
        let at = |scale: f64| -> Vec<f64> {
            let target: Vec<[f64; 3]> = (clean.iter().enumerate())
                .map(|(p, t)| {
                    std::array::from_fn(|c| scale * t[c] * (1.0 + 0.2 * (((p * 3 + c) * 7) % 5) as f64 / 4.0))
                })
                .collect();
            let weight = target
                .iter()
                .map(|t| t.map(|v| 1.0 / (v + 0.05 * scale).powi(2)))
                .collect();
            let x0 = vec![scale; n * 3];
            let env = solve(&transport, &DataTerm::exact(target, weight), settings, &x0)
                .expect("a solve")
                .env;
            env.iter().map(|v| v / scale).collect()
        };
        let one = at(1.0);
        for scale in [1e-3, 1e3] {
            for (a, b) in at(scale).iter().zip(&one) {
                assert!((a - b).abs() < 1e-4 * b, "x{scale}: {a} against {b} at 1");
            }
        }
    }

    #[test]
    fn solve_recovers_a_map_the_transport_sees_whole() {
        recovers_a_map_seen_whole(|_| 1.0, 500, LightingMethod::LeastSquares, 1e-3);
    }

    #[test]
    fn adam_steps_recover_it_too_more_slowly() {
        let adam = LightingMethod::Adam {
            steps_per_iteration: 10,
            rate: 0.05,
        };
        recovers_a_map_seen_whole(|_| 1.0, 100, adam, 1e-2);
    }

    #[test]
    fn solve_converges_fast_when_texels_are_seen_with_very_different_strengths() {
        // Throughputs from 1e-3 to 1e3 (a texel in a lobe's tail next to one
        // at its peak): curvatures 1e6 apart, which unpreconditioned L-BFGS
        // does not resolve in 20 iterations.
        let throughput = |t: usize| 10f32.powf(-3.0 + 6.0 * ((t * 13) % 32) as f32 / 31.0);
        recovers_a_map_seen_whole(throughput, 20, LightingMethod::LeastSquares, 1e-3);
    }
}
