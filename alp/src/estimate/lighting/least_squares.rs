//! The regularised, non-negative linear least-squares solve for the env map
//! over a recorded [`Transport`], by bounded L-BFGS (or, to compare, the
//! paper's many Adam steps), with a smoothness prior and a floor for texels
//! the data drive dark; and the map pyramid of a coarse-to-fine solve.

use optim::schedule::Decay;
use optim::{Adam, Bounds, Lbfgs, ParamGroup, Solver, Termination};

use render::transport::{PullBackScratch, Transport};

use crate::error::{Error, Result};
use crate::estimate::settings::LightingMethod;
use crate::objective::{DataTerm, LeastSquaresForm, MapPrior, PriorBasis, Smoothness, summed_curvature};

/// The 2:1 map sizes of a coarse-to-fine solve ending at `size`: heights
/// doubling from `coarsest` (or `size` itself when not larger).
pub fn pyramid(size: (usize, usize), coarsest: usize) -> Vec<(usize, usize)> {
    let mut heights = vec![size.1];
    while heights[0] / 2 >= coarsest && heights[0] % 2 == 0 {
        heights.insert(0, heights[0] / 2);
    }
    heights.into_iter().map(|h| (2 * h, h)).collect()
}

/// Settings of the lighting solve.
#[derive(Clone, Copy, Debug)]
pub struct LightingSolve {
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
/// linearly past the smoothness's edge; [`crate::objective::Prior`]):
/// texels the probe sees poorly are filled from confident neighbours. The
/// bound is `floor_of_level` times that level.
/// An error only where L-BFGS refuses its inputs; a solve that stops short
/// of convergence says how in [`Solved::termination`].
pub fn solve(
    transport: &Transport,
    data: &DataTerm,
    smoothness: &Smoothness,
    settings: LightingSolve,
    x0: &[f64],
) -> Result<Solved> {
    solve_with(transport, data, &[smoothness.form()], settings, x0)
}

/// [`solve`] with the priors of `priors` (each a form and its weight
/// relative to the data term's) in place of the smoothness alone.
pub fn solve_with(
    transport: &Transport,
    data: &DataTerm,
    priors: &[(LeastSquaresForm, f64)],
    settings: LightingSolve,
    x0: &[f64],
) -> Result<Solved> {
    assert_eq!(data.target.len(), transport.pixels, "solve: one target per pixel");
    assert_eq!(x0.len(), transport.unknowns(), "solve: the start has the wrong size");
    let weight = &data.weight;
    let basis = PriorBasis::new(
        transport,
        data,
        x0,
        settings.relative_smoothness,
        settings.clipped_light_share,
    );
    let priors: Vec<Box<dyn MapPrior>> = priors.iter().filter_map(|(f, w)| f.prior(&basis, *w)).collect();
    let data_norm = data.norm();
    // The data term's curvature per unknown, and the priors' per texel (at
    // small differences; alike in every channel).
    let prior_curvature = summed_curvature(&priors, transport.width * transport.height);
    let curvature: Vec<f64> = (basis.data_curvature.iter().enumerate())
        .map(|(k, d)| d + prior_curvature[k / 3])
        .collect();
    let mut rendered = vec![[0.0; 3]; transport.pixels];
    let mut scratch = PullBackScratch::default();
    let mut objective = |x: &[f64], g: &mut [f64]| -> f64 {
        g.iter_mut().for_each(|v| *v = 0.0);
        transport.apply_and_pull_back(
            x,
            |p, px| std::array::from_fn(|c| 2.0 * weight[p][c] * data.residual(p, c, px[c]) / data_norm),
            &mut rendered,
            g,
            &mut scratch,
        );
        let f = data.weighted_sq_sum(|p, c| rendered[p][c]) / data_norm;
        f + priors.iter().map(|p| p.add_value_and_gradient(x, g)).sum::<f64>()
    };
    minimise(&mut objective, &curvature, &basis, settings, x0)
}

/// Minimises `objective` (value and gradient at a map, texel-major RGB)
/// from `x0` above the floor of `settings` by its method, preconditioned by
/// the `curvature` per unknown: the loop both lighting solves share.
///
/// Jacobi preconditioning, x = s * y with s = 1 / sqrt(curvature): a texel
/// that a thousand pixels see and one only the smoothness reaches differ in
/// curvature by orders of magnitude, and L-BFGS on x crawls along the flat
/// ones. Bounds stay y >= floor / s.
pub(super) fn minimise(
    objective: &mut dyn FnMut(&[f64], &mut [f64]) -> f64,
    curvature: &[f64],
    basis: &PriorBasis,
    settings: LightingSolve,
    x0: &[f64],
) -> Result<Solved> {
    let n = x0.len();
    let scale: Vec<f64> = curvature.iter().map(|&h| 1.0 / h.max(1e-300).sqrt()).collect();
    let mut x = vec![0.0; n];
    let mut on_y = |y: &[f64], g: &mut [f64]| -> f64 {
        x.iter_mut().zip(y).zip(&scale).for_each(|((x, y), s)| *x = s * y);
        let f = objective(&x, g);
        g.iter_mut().zip(&scale).for_each(|(g, s)| *g *= s);
        f
    };
    let lower: Vec<f64> = (0..n)
        .map(|k| settings.floor_of_level * basis.level[k / 3] / scale[k])
        .collect();
    let y0 = x0
        .iter()
        .zip(&scale)
        .zip(&lower)
        .map(|((x, s), l)| (x / s).max(*l))
        .collect();
    let (best_y, evaluations, termination) = match settings.method {
        LightingMethod::LeastSquares | LightingMethod::Tape => {
            let bounds = Bounds::new(lower, vec![f64::INFINITY; n]).expect("valid bounds");
            let mut lbfgs = Lbfgs::builder()
                .bounds(bounds)
                .max_iters(settings.max_iters)
                .grad_tol(1e-12)
                .build()
                .map_err(Error::solver("lighting solve"))?;
            let state = lbfgs.minimize(&mut on_y, y0).map_err(Error::solver("lighting solve"))?;
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
                let f = on_y(&y, &mut gy);
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
                    ParamGroup::new(0..n, rate * basis.mean_level.max(1e-12))
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::objective::clipped_lights;
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
            &Smoothness::quadratic(0.0),
            LightingSolve {
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
                relative_smoothness: false,
                floor_of_level: 0.0,
                clipped_light_share: 1.0,
                max_iters: 200,
                method: LightingMethod::LeastSquares,
            };
            solve(&transport, &data, &Smoothness::quadratic(0.0), settings, &x0)
                .expect("a solve")
                .env[27]
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
                relative_smoothness: false,
                floor_of_level: 0.0,
                clipped_light_share: share,
                max_iters: 500,
                method: LightingMethod::LeastSquares,
            };
            solve(
                &transport,
                &data,
                &Smoothness::quadratic(1.0),
                settings,
                &vec![1.0; w * h * 3],
            )
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
                relative_smoothness: true,
                floor_of_level,
                clipped_light_share: 1.0,
                max_iters: 500,
                method: LightingMethod::LeastSquares,
            };
            let x = solve(
                &transport,
                &DataTerm::exact(target.clone(), vec![[1.0; 3]; uv.len()]),
                &Smoothness::quadratic(1e-9),
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
                relative_smoothness: false,
                floor_of_level: 0.0,
                clipped_light_share: 1.0,
                max_iters: 2000,
                method: LightingMethod::LeastSquares,
            };
            let x = solve(
                &transport,
                &DataTerm::exact(target.clone(), vec![[1.0; 3]; w * h]),
                &Smoothness {
                    edge,
                    ..Smoothness::quadratic(0.3)
                },
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
            let env = solve(
                &transport,
                &DataTerm::exact(target, weight),
                &Smoothness {
                    weight: 0.3,
                    edge: 0.05,
                    chroma: 2.0,
                },
                settings,
                &x0,
            )
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
