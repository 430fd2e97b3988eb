//! The regularised, non-negative linear least-squares solve for the env map
//! over a recorded [`Transport`], by bounded L-BFGS, with a smoothness prior
//! and a floor for texels the data drive dark; and the map pyramid of a
//! coarse-to-fine solve.

use optim::{Bounds, Lbfgs, Solver, Termination};
use serde::Serialize;

use render::transport::{PullBackScratch, Transport};

use crate::error::{Error, Result};

/// The 2:1 map sizes of a coarse-to-fine solve ending at `size`: heights
/// doubling from `coarsest` (or `size` itself when not larger).
pub fn pyramid(size: (usize, usize), coarsest: usize) -> Vec<(usize, usize)> {
    let mut heights = vec![size.1];
    while heights[0] / 2 >= coarsest && heights[0] % 2 == 0 {
        heights.insert(0, heights[0] / 2);
    }
    heights.into_iter().map(|h| (2 * h, h)).collect()
}

/// The smoothness prior of a lighting solve: neighbouring texels'
/// differences, penalised quadratically up to `edge` and linearly beyond.
#[derive(Clone, Copy, Debug, Serialize)]
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
}

impl Smoothness {
    /// Quadratic smoothness of `weight`.
    pub fn quadratic(weight: f64) -> Self {
        Smoothness { weight, edge: 0.0 }
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
    /// L-BFGS iterations at most.
    pub max_iters: usize,
}

/// Texels darker than this fraction of the start's mean level count as
/// that level in the relative smoothness (no division by zero radiance).
pub(super) const DARK_LEVEL: f64 = 0.05;

/// The output map's least radiance of a texel, as a fraction of the
/// start's local level (grey): no direction of a scene is black,
/// and a texel the data drive to zero has no colour, which a mirror shows
/// 90 degrees off (the dark ring a solve leaves around a light sharper
/// than the probe's lobes resolve).
pub const FLOOR_OF_LEVEL: f64 = 0.02;

/// Solves `min_x>=0 sum_p w_p |A x - b_p|^2 / sum w + lambda R(x)` where
/// `R` penalises squared differences of neighbouring texels (area-weighted,
/// relative to the local level of the start `x0`, divided by the
/// target's mean square so that `lambda` is scale-free, and growing only
/// linearly past the smoothness's edge): texels the probe sees poorly are
/// filled from confident neighbours. The bound is
/// `floor_of_level` times that level.
/// An error only where L-BFGS refuses its inputs; a solve that stops short
/// of convergence says how in [`Solved::termination`].
pub fn solve(
    transport: &Transport,
    target: &[[f64; 3]],
    weight: &[f64],
    settings: LightingSolve,
    x0: &[f64],
) -> Result<Solved> {
    let (w, h) = (transport.width, transport.height);
    assert_eq!(target.len(), transport.pixels, "solve: one target per pixel");
    assert_eq!(x0.len(), transport.unknowns(), "solve: the start has the wrong size");
    let weight_sum: f64 = weight.iter().sum::<f64>().max(1e-30);
    let mean_sq = target
        .iter()
        .zip(weight)
        .map(|(t, &wt)| wt * (t[0] * t[0] + t[1] * t[1] + t[2] * t[2]) / 3.0)
        .sum::<f64>()
        / weight_sum;
    let lambda = settings.smoothness.weight / mean_sq.max(1e-30) / (w * h) as f64;
    // Differences may count relative to the local radiance level of the
    // start (a bright light's edge is no rougher than a dark wall's texture).
    let level: Vec<f64> = x0
        .chunks_exact(3)
        .map(|t| 0.2126 * t[0] + 0.7152 * t[1] + 0.0722 * t[2])
        .collect();
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
            let j = r * w + (c + 1) % w;
            pairs.push(Pair {
                i,
                j,
                area,
                relative: relative(i, j),
            });
            if r + 1 < h {
                let j = (r + 1) * w + c;
                pairs.push(Pair {
                    i,
                    j,
                    area,
                    relative: relative(i, j),
                });
            }
        }
    }
    let prior = Prior {
        pairs,
        lambda,
        edge_sq: (settings.smoothness.edge * (mean_level + floor)).powi(2),
    };
    // Jacobi preconditioning, x = s * y with s = 1 / sqrt(diag of the
    // Hessian): a texel that a thousand pixels see and one only the
    // smoothness reaches differ in curvature by orders of magnitude, and
    // L-BFGS on x crawls along the flat ones. Bounds stay y >= 0.
    let mut curvature: Vec<f64> = transport
        .weighted_column_norms(weight)
        .iter()
        .map(|h| 2.0 * h / weight_sum)
        .collect();
    for p in &prior.pairs {
        for c in 0..3 {
            curvature[p.i * 3 + c] += 2.0 * lambda * p.area * p.relative;
            curvature[p.j * 3 + c] += 2.0 * lambda * p.area * p.relative;
        }
    }
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
            |p, px| std::array::from_fn(|c| 2.0 * weight[p] * (px[c] - target[p][c]) / weight_sum),
            &mut rendered,
            g,
            &mut scratch,
        );
        let mut f = 0.0;
        for p in 0..transport.pixels {
            for c in 0..3 {
                let r = rendered[p][c] - target[p][c];
                f += weight[p] * r * r;
            }
        }
        f /= weight_sum;
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
    Ok(Solved {
        env: state.best_x.iter().zip(&scale).map(|(y, s)| y * s).collect(),
        evaluations: state.evals,
        termination: state.termination,
    })
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

/// Two neighbouring texels, the area weight of their difference and the
/// factor that makes it relative to their local level.
pub(super) struct Pair {
    pub(super) i: usize,
    pub(super) j: usize,
    pub(super) area: f64,
    pub(super) relative: f64,
}

/// The smoothness prior over an env map's neighbour pairs.
pub(super) struct Prior {
    pub(super) pairs: Vec<Pair>,
    pub(super) lambda: f64,
    /// The squared difference (of a pair's relative difference `q |d|^2`)
    /// past which the penalty turns linear: the smoothness's edge times the
    /// start's mean level (plus its dark floor), squared; 0: quadratic.
    pub(super) edge_sq: f64,
}

impl Prior {
    /// Returns the prior's value at the env map `x` (texel-major RGB) and
    /// adds its gradient to `g`. A pair's penalty is `lambda area q |d|^2`
    /// (`q` its relative factor, `d` its RGB difference) while that is
    /// small against `3 edge^2`, and `lambda area 6 edge^2 (sqrt(1 + q
    /// |d|^2 / (3 edge^2)) - 1)` in general: the same at small
    /// differences, linear in `|d|` at large ones.
    pub(super) fn add_value_and_gradient(&self, x: &[f64], g: &mut [f64]) -> f64 {
        let mut f = 0.0;
        for p in &self.pairs {
            let d: [f64; 3] = std::array::from_fn(|c| x[p.i * 3 + c] - x[p.j * 3 + c]);
            let sq = p.relative * (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
            let slope = match self.edge_sq > 0.0 {
                true => {
                    let root = (1.0 + sq / (3.0 * self.edge_sq)).sqrt();
                    f += self.lambda * p.area * 6.0 * self.edge_sq * (root - 1.0);
                    1.0 / root
                }
                false => {
                    f += self.lambda * p.area * sq;
                    1.0
                }
            };
            for c in 0..3 {
                let dg = 2.0 * self.lambda * p.area * p.relative * slope * d[c];
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
    /// in at most `max_iters` L-BFGS iterations, and checks it comes back.
    fn recovers_a_map_seen_whole(throughput: impl Fn(usize) -> f32, max_iters: usize) {
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
            &target,
            &vec![1.0; uv.len()],
            LightingSolve {
                smoothness: Smoothness::quadratic(0.0),
                relative_smoothness: false,
                floor_of_level: 0.0,
                max_iters,
            },
            &vec![1.0; w * h * 3],
        )
        .expect("a solve");
        assert!(solved.evaluations > 0);
        for (a, b) in solved.env.iter().zip(&truth) {
            assert!((a - b).abs() < 1e-3, "{a} vs {b}");
        }
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
                max_iters: 500,
            };
            let x = solve(
                &transport,
                &target,
                &vec![1.0; uv.len()],
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
            });
        }
        // Quadratic, and with two edges: the pairs' `q |d|^2 / (3 edge^2)`
        // runs from 0.005 to 0.9 with the first (near-quadratic pairs to the
        // bend) and from 0.5 to 90 with the second (the bend to far into
        // the linear part).
        for edge_sq in [0.0, 5.0, 0.05] {
            let prior = Prior {
                pairs: std::mem::take(&mut pairs),
                lambda: 0.7,
                edge_sq,
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
                    "edge^2 {edge_sq}, x[{k}]: {} vs {fd}",
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
                smoothness: Smoothness { weight: 0.3, edge },
                relative_smoothness: false,
                floor_of_level: 0.0,
                max_iters: 2000,
            };
            let x = solve(&transport, &target, &vec![1.0; w * h], settings, &vec![2.0; w * h * 3])
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
    fn solve_recovers_a_map_the_transport_sees_whole() {
        recovers_a_map_seen_whole(|_| 1.0, 500);
    }

    #[test]
    fn solve_converges_fast_when_texels_are_seen_with_very_different_strengths() {
        // Throughputs from 1e-3 to 1e3 (a texel in a lobe's tail next to one
        // at its peak): curvatures 1e6 apart, which unpreconditioned L-BFGS
        // does not resolve in 20 iterations.
        recovers_a_map_seen_whole(|t| 10f32.powf(-3.0 + 6.0 * ((t * 13) % 32) as f32 / 31.0), 20);
    }
}
