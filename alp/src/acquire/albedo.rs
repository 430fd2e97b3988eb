//! The albedo texture that re-renders the views best at a fixed roughness,
//! solved exactly: the observations are linear in the texels
//! ([`super::observation`]), so the unbiased squared error of the two
//! halves, `sum w (Ja x + Aa - t)(Jb x + Ab - t)`, plus a quadratic
//! smoothness prior is a quadratic in the texels, minimized by conjugate
//! gradients on its normal equations, per channel. No step size and no
//! random walk: a texel's value is its data's least-squares answer, pulled
//! towards its neighbours by as much as the prior outweighs what the views
//! tell of it (so texels no view saw take their neighbours' values).
//! Bounds by an active set: texels whose solution leaves [0, 1] are held at
//! the bound and the rest solved again.

use rayon::prelude::*;
use render::colour::LUMINANCE;

use super::observation::{Observations, grid_neighbours, grid_pairs, texel_taps};

/// What the solve trades.
#[derive(Clone, Copy, Debug)]
pub(crate) struct AlbedoSolve {
    /// Weight of the prior `sum over neighbouring texels (a_k - a_l)^2`,
    /// over the number of pairs: against the data, whose weight per texel
    /// is about 1 over the texel count on a well-seen texel, so that 0.1
    /// pulls a well-seen texel towards its neighbours at about a fifth of
    /// its data's weight (higher: smoother, blurs printed detail).
    pub(crate) smoothness: f64,
    /// Most conjugate-gradient iterations per solve.
    pub(crate) iterations: usize,
}

/// A weak pull of every texel towards this value (weight `RIDGE` over the
/// texel count): keeps the system definite where nothing else holds a
/// texel, without moving any texel the data or the prior sees.
const RIDGE_VALUE: f64 = 0.7;
const RIDGE: f64 = 1e-4;

/// Conjugate gradients stop when the residual's norm falls by this factor.
const TOLERANCE: f64 = 1e-5;

/// Rounds of the active set: a solve, then solves with the texels out of
/// range held at their bounds.
const BOUND_ROUNDS: usize = 3;

/// One half's observations at a texture size, as a sparse matrix by
/// pixel (its rows) and by texel (its columns).
struct Half {
    row_start: Vec<usize>,
    row_entries: Vec<(u32, [f32; 3])>,
    column_start: Vec<usize>,
    column_entries: Vec<(u32, [f32; 3])>,
}

impl Half {
    /// The rows of half `half` of `obs` at `width` x `height` texels: per
    /// pixel, the texels its hits' bilinear taps read, with their slopes.
    fn new(obs: &Observations, half: u8, width: usize, height: usize) -> Self {
        let rows: Vec<Vec<(u32, [f32; 3])>> = (0..obs.pixels.len())
            .into_par_iter()
            .map(|p| {
                let mut entries: Vec<(u32, [f32; 3])> = Vec::new();
                for hit in obs.hits_of(p).iter().filter(|h| h.half == half) {
                    for (texel, w) in texel_taps(hit.uv, width, height) {
                        if w > 0.0 {
                            entries.push((texel as u32, hit.slope.map(|s| s * w)));
                        }
                    }
                }
                entries.sort_unstable_by_key(|e| e.0);
                let mut merged: Vec<(u32, [f32; 3])> = Vec::with_capacity(entries.len());
                for (texel, slope) in entries {
                    match merged.last_mut() {
                        Some(last) if last.0 == texel => (0..3).for_each(|c| last.1[c] += slope[c]),
                        _ => merged.push((texel, slope)),
                    }
                }
                merged
            })
            .collect();
        let mut row_start = Vec::with_capacity(rows.len() + 1);
        row_start.push(0);
        for r in &rows {
            row_start.push(row_start.last().copied().unwrap_or(0) + r.len());
        }
        let row_entries: Vec<(u32, [f32; 3])> = rows.into_iter().flatten().collect();
        // The transpose, by counting sort.
        let mut column_start = vec![0usize; width * height + 1];
        for e in &row_entries {
            column_start[e.0 as usize + 1] += 1;
        }
        for k in 0..width * height {
            column_start[k + 1] += column_start[k];
        }
        let mut next = column_start.clone();
        let mut column_entries = vec![(0u32, [0.0f32; 3]); row_entries.len()];
        for p in 0..row_start.len() - 1 {
            for e in &row_entries[row_start[p]..row_start[p + 1]] {
                column_entries[next[e.0 as usize]] = (p as u32, e.1);
                next[e.0 as usize] += 1;
            }
        }
        Half {
            row_start,
            row_entries,
            column_start,
            column_entries,
        }
    }

    /// Per pixel, its row times `x`.
    fn rows_times(&self, x: &[[f64; 3]]) -> Vec<[f64; 3]> {
        (0..self.row_start.len() - 1)
            .into_par_iter()
            .map(|p| {
                let mut u = [0.0; 3];
                for (texel, slope) in &self.row_entries[self.row_start[p]..self.row_start[p + 1]] {
                    for c in 0..3 {
                        u[c] += slope[c] as f64 * x[*texel as usize][c];
                    }
                }
                u
            })
            .collect()
    }

    /// Per texel, its column times `u` (per pixel).
    fn columns_times(&self, u: &[[f64; 3]], k: usize) -> [f64; 3] {
        let mut y = [0.0; 3];
        for (p, slope) in &self.column_entries[self.column_start[k]..self.column_start[k + 1]] {
            for c in 0..3 {
                y[c] += slope[c] as f64 * u[*p as usize][c];
            }
        }
        y
    }

    /// Per texel, the sum of its column's squared slopes times the pixels' weights.
    fn weighted_squares(&self, weight: &[f64], k: usize) -> [f64; 3] {
        let mut y = [0.0; 3];
        for (p, slope) in &self.column_entries[self.column_start[k]..self.column_start[k + 1]] {
            for c in 0..3 {
                y[c] += weight[*p as usize] * (slope[c] as f64).powi(2);
            }
        }
        y
    }
}

/// The quadratic at one texture size.
pub(crate) struct AlbedoSystem<'a> {
    obs: &'a Observations,
    width: usize,
    height: usize,
    halves: [Half; 2],
    weight: Vec<f64>,
    /// Per texel, both halves' `sum w J^2`: the data's curvature there, as
    /// if the halves agreed (the preconditioner's and the coverage's).
    data_diagonal: Vec<[f64; 3]>,
    settings: AlbedoSolve,
}

/// A solve's result.
pub(crate) struct AlbedoFit {
    /// Texel-major RGB.
    pub(crate) albedo: Vec<[f64; 3]>,
    /// The data term (unbiased relative squared error, view mean) at the solution.
    pub(crate) data: f64,
    /// The prior's value (mean squared difference of neighbouring texels).
    pub(crate) smoothness: f64,
    /// Conjugate-gradient iterations, all rounds and channels' most.
    pub(crate) iterations: usize,
    /// Whether the quadratic was definite along every direction the solve
    /// took: where the views' noise outweighs what they tell of single
    /// texels, the unbiased error's curvature is negative along some
    /// (texels finer than the views resolve), and the solve stops there.
    pub(crate) definite: bool,
    /// Per texel, how much the views tell of it against an average texel
    /// (the data's curvature times the texel count, luminance-weighted).
    pub(crate) information: Vec<f64>,
}

impl<'a> AlbedoSystem<'a> {
    pub(crate) fn new(obs: &'a Observations, width: usize, height: usize, settings: AlbedoSolve) -> Self {
        let halves = [0, 1].map(|h| Half::new(obs, h, width, height));
        let weight: Vec<f64> = obs.pixels.iter().map(|p| p.weight).collect();
        let data_diagonal = (0..width * height)
            .into_par_iter()
            .map(|k| {
                let (a, b) = (
                    halves[0].weighted_squares(&weight, k),
                    halves[1].weighted_squares(&weight, k),
                );
                std::array::from_fn(|c| a[c] + b[c])
            })
            .collect();
        AlbedoSystem {
            obs,
            width,
            height,
            halves,
            weight,
            data_diagonal,
            settings,
        }
    }

    fn texels(&self) -> usize {
        self.width * self.height
    }

    /// The prior's weight per squared difference.
    fn prior_weight(&self) -> f64 {
        let (w, h) = (self.width, self.height);
        let pairs = (w.saturating_sub(1) * h + w * h.saturating_sub(1)).max(1);
        self.settings.smoothness / pairs as f64
    }

    /// The data's residuals `A + J x - t` of both halves, per pixel.
    fn residuals(&self, x: &[[f64; 3]]) -> [Vec<[f64; 3]>; 2] {
        [0, 1].map(|h| {
            let mut u = self.halves[h].rows_times(x);
            for (r, p) in u.iter_mut().zip(&self.obs.pixels) {
                for (c, rc) in r.iter_mut().enumerate() {
                    *rc += p.offset[h][c] as f64 - p.target[c] as f64;
                }
            }
            u
        })
    }

    /// `sum_p w_p (Ja_p ua_b + Jb_p u_a)` per texel: the data's Hessian
    /// times x (with `u` the rows times x) or its gradient (with `u` the residuals).
    fn data_product(&self, u: &[Vec<[f64; 3]>; 2]) -> Vec<[f64; 3]> {
        let weighted =
            |h: usize| -> Vec<[f64; 3]> { u[h].iter().zip(&self.weight).map(|(r, &w)| r.map(|v| v * w)).collect() };
        let (wa, wb) = (weighted(0), weighted(1));
        (0..self.texels())
            .into_par_iter()
            .map(|k| {
                let (a, b) = (
                    self.halves[0].columns_times(&wb, k),
                    self.halves[1].columns_times(&wa, k),
                );
                std::array::from_fn(|c| a[c] + b[c])
            })
            .collect()
    }

    /// The prior's and the ridge's Hessian times `x`, added into `y`.
    fn add_prior_product(&self, x: &[[f64; 3]], y: &mut [[f64; 3]]) {
        let (w, h) = (self.width, self.height);
        let (lambda, ridge) = (2.0 * self.prior_weight(), 2.0 * RIDGE / self.texels() as f64);
        y.par_iter_mut().enumerate().for_each(|(k, yk)| {
            for n in grid_neighbours(k, w, h).into_iter().flatten() {
                for c in 0..3 {
                    yk[c] += lambda * (x[k][c] - x[n][c]);
                }
            }
            for c in 0..3 {
                yk[c] += ridge * x[k][c];
            }
        });
    }

    /// The Hessian times `x`.
    fn hessian_times(&self, x: &[[f64; 3]]) -> Vec<[f64; 3]> {
        let u = [0, 1].map(|h| self.halves[h].rows_times(x));
        let mut y = self.data_product(&u);
        self.add_prior_product(x, &mut y);
        y
    }

    /// The objective's gradient at `x`.
    fn gradient(&self, x: &[[f64; 3]]) -> Vec<[f64; 3]> {
        let mut g = self.data_product(&self.residuals(x));
        self.add_prior_product(x, &mut g);
        let ridge = 2.0 * RIDGE / self.texels() as f64;
        g.iter_mut()
            .for_each(|gk| gk.iter_mut().for_each(|v| *v -= ridge * RIDGE_VALUE));
        g
    }

    /// The Jacobi preconditioner's diagonal (positive).
    fn diagonal(&self) -> Vec<[f64; 3]> {
        let (w, h) = (self.width, self.height);
        let lambda = 2.0 * self.prior_weight();
        let ridge = 2.0 * RIDGE / self.texels() as f64;
        (0..self.texels())
            .into_par_iter()
            .map(|k| {
                let degree = grid_neighbours(k, w, h).iter().flatten().count() as f64;
                self.data_diagonal[k].map(|d| d + lambda * degree + ridge)
            })
            .collect()
    }

    /// Minimizes from `start` (texel-major RGB at this size) within [0, 1].
    pub(crate) fn solve(&self, start: &[[f64; 3]]) -> AlbedoFit {
        let n = self.texels();
        assert_eq!(start.len(), n, "AlbedoSystem::solve: one start value per texel");
        let mut x: Vec<[f64; 3]> = start.iter().map(|v| v.map(|c| c.clamp(0.0, 1.0))).collect();
        let mut free = vec![[true; 3]; n];
        let diagonal = self.diagonal();
        let (mut iterations, mut definite) = (0, true);
        for _ in 0..BOUND_ROUNDS {
            let (round, round_definite) = self.conjugate_gradients(&mut x, &free, &diagonal);
            iterations += round;
            definite &= round_definite;
            let mut changed = false;
            for (xk, fk) in x.iter_mut().zip(free.iter_mut()) {
                for c in 0..3 {
                    if fk[c] && !(0.0..=1.0).contains(&xk[c]) {
                        xk[c] = xk[c].clamp(0.0, 1.0);
                        fk[c] = false;
                        changed = true;
                    }
                }
            }
            if !changed {
                break;
            }
        }
        // Anything a last round left out of range (none, but for non-finite input).
        x.iter_mut().for_each(|xk| {
            xk.iter_mut()
                .for_each(|v| *v = if v.is_finite() { v.clamp(0.0, 1.0) } else { RIDGE_VALUE })
        });
        let residuals = self.residuals(&x);
        let data: f64 = (0..self.obs.pixels.len())
            .map(|p| (0..3).map(|c| residuals[0][p][c] * residuals[1][p][c]).sum::<f64>() * self.weight[p] / 3.0)
            .sum();
        let information = self
            .data_diagonal
            .iter()
            .map(|d| (0..3).map(|c| LUMINANCE[c] * d[c] / 2.0).sum::<f64>() * n as f64)
            .collect();
        AlbedoFit {
            smoothness: self.smoothness_of(&x),
            albedo: x,
            data,
            iterations,
            definite,
            information,
        }
    }

    /// The mean squared difference of neighbouring texels, over channels.
    fn smoothness_of(&self, x: &[[f64; 3]]) -> f64 {
        let (w, h) = (self.width, self.height);
        let (mut sum, mut pairs) = (0.0, 0usize);
        for k in 0..w * h {
            for n in grid_pairs(k, w, h).into_iter().flatten() {
                sum += (0..3).map(|c| (x[k][c] - x[n][c]).powi(2)).sum::<f64>() / 3.0;
                pairs += 1;
            }
        }
        sum / pairs.max(1) as f64
    }

    /// Preconditioned conjugate gradients on the texels `free` (per
    /// channel) from `x`, the others held; each channel stops at its own
    /// tolerance, or where its curvature is not positive (the unbiased
    /// data term's Hessian need not be definite where noise dominates).
    /// Returns the iterations of the slowest channel, and whether no
    /// direction of non-positive curvature was met.
    fn conjugate_gradients(&self, x: &mut [[f64; 3]], free: &[[bool; 3]], diagonal: &[[f64; 3]]) -> (usize, bool) {
        let mask = |v: &mut Vec<[f64; 3]>| {
            v.iter_mut()
                .zip(free)
                .for_each(|(vk, fk)| (0..3).for_each(|c| vk[c] = if fk[c] { vk[c] } else { 0.0 }))
        };
        let mut r: Vec<[f64; 3]> = self.gradient(x).iter().map(|g| g.map(|v| -v)).collect();
        mask(&mut r);
        let precondition = |r: &[[f64; 3]]| -> Vec<[f64; 3]> {
            r.iter()
                .zip(diagonal)
                .map(|(rk, dk)| std::array::from_fn(|c| rk[c] / dk[c]))
                .collect()
        };
        let dot = |a: &[[f64; 3]], b: &[[f64; 3]]| -> [f64; 3] {
            let mut s = [0.0; 3];
            for (ak, bk) in a.iter().zip(b) {
                for c in 0..3 {
                    s[c] += ak[c] * bk[c];
                }
            }
            s
        };
        let mut z = precondition(&r);
        let mut p = z.clone();
        let mut rz = dot(&r, &z);
        let r0 = dot(&r, &r).map(f64::sqrt);
        let mut active = r0.map(|v| v > 0.0);
        let mut definite = true;
        let mut iterations = 0;
        while iterations < self.settings.iterations && active.iter().any(|&a| a) {
            iterations += 1;
            let mut hp = self.hessian_times(&p);
            mask(&mut hp);
            let php = dot(&p, &hp);
            let mut alpha = [0.0; 3];
            for c in 0..3 {
                if active[c] && php[c] > 0.0 {
                    alpha[c] = rz[c] / php[c];
                } else {
                    definite &= !active[c];
                    active[c] = false;
                }
            }
            for k in 0..x.len() {
                for c in 0..3 {
                    x[k][c] += alpha[c] * p[k][c];
                    r[k][c] -= alpha[c] * hp[k][c];
                }
            }
            let norm = dot(&r, &r).map(f64::sqrt);
            z = precondition(&r);
            let rz_next = dot(&r, &z);
            for c in 0..3 {
                if norm[c] <= TOLERANCE * r0[c] {
                    active[c] = false;
                }
                let beta = if rz[c] > 0.0 { rz_next[c] / rz[c] } else { 0.0 };
                for k in 0..p.len() {
                    p[k][c] = if active[c] { z[k][c] + beta * p[k][c] } else { 0.0 };
                }
            }
            rz = rz_next;
        }
        (iterations, definite)
    }
}

#[cfg(test)]
mod tests {
    use glam::Vec2;
    use render::sampling::Rng;

    use super::*;
    use crate::acquire::observation::{HitSlope, PixelObservation};

    /// `pixels` random observations of a `width` x `height` albedo, each
    /// pixel with a few hits per half at random texture coordinates.
    fn random_observations(pixels: usize, seed: u64) -> Observations {
        let mut rng = Rng::new(seed, 0);
        let mut obs = Observations::default();
        obs.hit_start.push(0);
        for _ in 0..pixels {
            obs.pixels.push(PixelObservation {
                target: std::array::from_fn(|_| rng.next_f32()),
                weight: 0.5 + rng.next_f32() as f64,
                offset: std::array::from_fn(|_| std::array::from_fn(|_| 0.2 * rng.next_f32())),
            });
            for half in 0..2u8 {
                for _ in 0..3 {
                    obs.hits.push(HitSlope {
                        uv: Vec2::new(rng.next_f32(), rng.next_f32()),
                        slope: std::array::from_fn(|_| rng.next_f32()),
                        half,
                    });
                }
            }
            obs.hit_start.push(obs.hits.len());
        }
        obs
    }

    /// The objective: the data's unbiased error, the prior and the ridge.
    fn objective(system: &AlbedoSystem, x: &[[f64; 3]]) -> f64 {
        let r = system.residuals(x);
        let data: f64 = (0..r[0].len())
            .map(|p| system.weight[p] * (0..3).map(|c| r[0][p][c] * r[1][p][c]).sum::<f64>())
            .sum();
        let (w, h) = (system.width, system.height);
        let mut prior = 0.0;
        for k in 0..w * h {
            let (col, row) = (k % w, k / w);
            for n in [(col + 1 < w).then(|| k + 1), (row + 1 < h).then(|| k + w)]
                .into_iter()
                .flatten()
            {
                prior += (0..3).map(|c| (x[k][c] - x[n][c]).powi(2)).sum::<f64>();
            }
        }
        let ridge: f64 = x.iter().flat_map(|v| v.iter()).map(|v| (v - RIDGE_VALUE).powi(2)).sum();
        data + system.prior_weight() * prior + RIDGE / system.texels() as f64 * ridge
    }

    #[test]
    fn the_gradient_and_the_hessian_match_central_differences() {
        let obs = random_observations(40, 3);
        let system = AlbedoSystem::new(
            &obs,
            4,
            3,
            AlbedoSolve {
                smoothness: 0.3,
                iterations: 10,
            },
        );
        let mut rng = Rng::new(4, 0);
        let x: Vec<[f64; 3]> = (0..12)
            .map(|_| std::array::from_fn(|_| rng.next_f32() as f64))
            .collect();
        let v: Vec<[f64; 3]> = (0..12)
            .map(|_| std::array::from_fn(|_| rng.next_f32() as f64 - 0.5))
            .collect();
        let g = system.gradient(&x);
        let hv = system.hessian_times(&v);
        let h = 1e-5;
        let step = |s: f64| -> Vec<[f64; 3]> {
            x.iter()
                .zip(&v)
                .map(|(a, b)| std::array::from_fn(|c| a[c] + s * b[c]))
                .collect()
        };
        for k in 0..12 {
            for c in 0..3 {
                let at = |s: f64| {
                    let mut y = x.clone();
                    y[k][c] += s;
                    objective(&system, &y)
                };
                let fd = (at(h) - at(-h)) / (2.0 * h);
                assert!(
                    (fd - g[k][c]).abs() < 1e-6 * (1.0 + fd.abs()),
                    "gradient {k} {c}: {fd} vs {}",
                    g[k][c]
                );
            }
        }
        let (gp, gm) = (system.gradient(&step(h)), system.gradient(&step(-h)));
        for k in 0..12 {
            for c in 0..3 {
                let fd = (gp[k][c] - gm[k][c]) / (2.0 * h);
                assert!(
                    (fd - hv[k][c]).abs() < 1e-6 * (1.0 + fd.abs()),
                    "Hessian {k} {c}: {fd} vs {}",
                    hv[k][c]
                );
            }
        }
    }

    #[test]
    fn noise_free_views_give_back_the_albedo() {
        // Both halves alike (no noise), targets made from a known albedo.
        let mut obs = random_observations(300, 7);
        let truth: Vec<[f64; 3]> = (0..16).map(|k| [0.1 + 0.05 * k as f64, 0.8, 0.3]).collect();
        for p in 0..obs.pixels.len() {
            let (a, b) = (obs.hit_start[p], obs.hit_start[p + 1]);
            let (first, second) = obs.hits[a..b].split_at_mut((b - a) / 2);
            second.copy_from_slice(first);
            second.iter_mut().for_each(|h| h.half = 1);
            let offset = obs.pixels[p].offset[0];
            obs.pixels[p].offset = [offset; 2];
        }
        for p in 0..obs.pixels.len() {
            let mut value = obs.pixels[p].offset[0].map(|o| o as f64);
            for hit in obs.hits_of(p).iter().filter(|h| h.half == 0) {
                for (texel, w) in texel_taps(hit.uv, 4, 4) {
                    for c in 0..3 {
                        value[c] += (w * hit.slope[c]) as f64 * truth[texel][c];
                    }
                }
            }
            obs.pixels[p].target = value.map(|v| v as f32);
        }
        let system = AlbedoSystem::new(
            &obs,
            4,
            4,
            AlbedoSolve {
                smoothness: 1e-6,
                iterations: 500,
            },
        );
        let fit = system.solve(&vec![[0.5; 3]; 16]);
        assert!(fit.definite);
        for (k, (got, want)) in fit.albedo.iter().zip(&truth).enumerate() {
            for (c, (g, w)) in got.iter().zip(want).enumerate() {
                assert!((g - w).abs() < 1e-3, "texel {k} {c}: {g} vs {w}");
            }
        }
        assert!(fit.data.abs() < 1e-6, "data {}", fit.data);
    }
}
