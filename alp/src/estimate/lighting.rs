//! The lighting phase at a fixed pose. The rendered image is linear in the
//! environment map: each light sample reads four texels (bilinear) with a
//! throughput. Recording that sparse transport once turns the phase into a
//! regularised, non-negative linear least-squares problem, solved with
//! bounded L-BFGS on cheap sparse products instead of thousands of noisy
//! Adam steps through the renderer (ARCHITECTURE.md).

use glam::Vec3;
use optim::{Bounds, Lbfgs, Solver};
use render::envmap::direction_to_uv;

/// One light sample: its pixel, throughput, and the four texels it reads.
#[derive(Clone, Copy, Debug)]
struct Tap {
    segment: u32,
    throughput: [f32; 3],
    texel: [u32; 4],
    weight: [f32; 4],
}

/// The linear map from an env map (texel-major RGB at `width x height`) to
/// the probe's pixels.
#[derive(Clone, Debug)]
pub struct Transport {
    /// Env map columns.
    pub width: usize,
    /// Env map rows.
    pub height: usize,
    /// Number of pixels (segments).
    pub pixels: usize,
    taps: Vec<Tap>,
}

/// The four texels and weights of a bilinear lookup at direction `d`
/// (FORMATS.md: texel centres at +0.5, wrap in u, clamp in v).
pub fn bilinear_taps(d: Vec3, width: usize, height: usize) -> ([u32; 4], [f32; 4]) {
    let uv = direction_to_uv(d);
    let x = uv.x * width as f32 - 0.5;
    let y = (uv.y * height as f32 - 0.5).clamp(0.0, (height - 1) as f32);
    let (x0, y0) = (x.floor(), y.floor());
    let (fx, fy) = (x - x0, y - y0);
    let c0 = (x0 as i64).rem_euclid(width as i64) as usize;
    let c1 = (c0 + 1) % width;
    let r0 = y0 as usize;
    let r1 = (r0 + 1).min(height - 1);
    let t = |r: usize, c: usize| (r * width + c) as u32;
    (
        [t(r0, c0), t(r0, c1), t(r1, c0), t(r1, c1)],
        [(1.0 - fx) * (1.0 - fy), fx * (1.0 - fy), (1.0 - fx) * fy, fx * fy],
    )
}

impl Transport {
    /// The transport of light samples (`segments`, directions, throughputs)
    /// onto a `width x height` env map.
    pub fn new(
        segment: &[u32],
        wi: &[Vec3],
        throughput: &[[f32; 3]],
        pixels: usize,
        width: usize,
        height: usize,
    ) -> Self {
        assert!(
            width == 2 * height && height > 0,
            "Transport: env maps are 2:1, got {width}x{height}"
        );
        let taps = segment
            .iter()
            .zip(wi)
            .zip(throughput)
            .map(|((&segment, &d), &throughput)| {
                let (texel, weight) = bilinear_taps(d, width, height);
                Tap {
                    segment,
                    throughput,
                    texel,
                    weight,
                }
            })
            .collect();
        Transport {
            width,
            height,
            pixels,
            taps,
        }
    }

    /// Number of env map values (texels x 3).
    pub fn unknowns(&self) -> usize {
        self.width * self.height * 3
    }

    /// The pixels' radiance under `env` (texel-major RGB).
    pub fn apply(&self, env: &[f64], out: &mut [[f64; 3]]) {
        out.iter_mut().for_each(|p| *p = [0.0; 3]);
        for tap in &self.taps {
            let px = &mut out[tap.segment as usize];
            for (&t, &w) in tap.texel.iter().zip(&tap.weight) {
                for c in 0..3 {
                    px[c] += (tap.throughput[c] * w) as f64 * env[t as usize * 3 + c];
                }
            }
        }
    }

    /// `grad += A^T residual` for per-pixel RGB residuals.
    pub fn apply_transpose(&self, residual: &[[f64; 3]], grad: &mut [f64]) {
        for tap in &self.taps {
            let r = residual[tap.segment as usize];
            for (&t, &w) in tap.texel.iter().zip(&tap.weight) {
                for c in 0..3 {
                    grad[t as usize * 3 + c] += (tap.throughput[c] * w) as f64 * r[c];
                }
            }
        }
    }

    /// How often each texel is read, weighted by the samples' throughput
    /// luminance, normalised to a maximum of 1: the paper's confidence map.
    pub fn confidence(&self) -> Vec<f32> {
        let mut freq = vec![0.0f64; self.width * self.height];
        for tap in &self.taps {
            let lum = (0.2126 * tap.throughput[0] + 0.7152 * tap.throughput[1] + 0.0722 * tap.throughput[2]) as f64;
            for (&t, &w) in tap.texel.iter().zip(&tap.weight) {
                freq[t as usize] += w as f64 * lum;
            }
        }
        let max = freq.iter().cloned().fold(0.0, f64::max).max(1e-30);
        freq.iter().map(|&f| (f / max) as f32).collect()
    }
}

/// Settings of the lighting solve.
#[derive(Clone, Copy, Debug)]
pub struct LightingSolve {
    /// Weight of the smoothness term (relative to the data term, scale-free).
    pub smoothness: f64,
    /// L-BFGS iterations at most.
    pub max_iters: usize,
}

/// Solves `min_x>=0 sum_p w_p |A x - b_p|^2 / sum w + lambda R(x)` where
/// `R` penalises squared differences of neighbouring texels (area-weighted,
/// divided by the target's mean square so that `lambda` is scale-free):
/// texels the probe sees poorly are filled from confident neighbours.
/// Returns the env map (texel-major RGB) and the L-BFGS evaluation count.
pub fn solve(
    transport: &Transport,
    target: &[[f64; 3]],
    weight: &[f64],
    settings: LightingSolve,
    x0: &[f64],
) -> (Vec<f64>, usize) {
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
    let lambda = settings.smoothness / mean_sq.max(1e-30) / (w * h) as f64;
    // Neighbour pairs with their area weight sin(theta).
    let mut pairs = Vec::with_capacity(2 * w * h);
    for r in 0..h {
        let area = (std::f64::consts::PI * (r as f64 + 0.5) / h as f64).sin();
        for c in 0..w {
            let i = r * w + c;
            pairs.push((i, r * w + (c + 1) % w, area));
            if r + 1 < h {
                pairs.push((i, (r + 1) * w + c, area));
            }
        }
    }
    let mut rendered = vec![[0.0; 3]; transport.pixels];
    let mut residual = vec![[0.0; 3]; transport.pixels];
    let mut objective = |x: &[f64], g: &mut [f64]| -> f64 {
        transport.apply(x, &mut rendered);
        let mut f = 0.0;
        for p in 0..transport.pixels {
            for c in 0..3 {
                let r = rendered[p][c] - target[p][c];
                f += weight[p] * r * r;
                residual[p][c] = 2.0 * weight[p] * r / weight_sum;
            }
        }
        f /= weight_sum;
        g.iter_mut().for_each(|v| *v = 0.0);
        transport.apply_transpose(&residual, g);
        for &(i, j, a) in &pairs {
            for c in 0..3 {
                let d = x[i * 3 + c] - x[j * 3 + c];
                f += lambda * a * d * d;
                g[i * 3 + c] += 2.0 * lambda * a * d;
                g[j * 3 + c] -= 2.0 * lambda * a * d;
            }
        }
        f
    };
    let n = transport.unknowns();
    let bounds = Bounds::uniform(n, 0.0, f64::INFINITY).expect("valid bounds");
    let mut lbfgs = Lbfgs::builder()
        .bounds(bounds)
        .max_iters(settings.max_iters)
        .grad_tol(1e-12)
        .build()
        .expect("valid L-BFGS settings");
    match lbfgs.minimize(&mut objective, x0.to_vec()) {
        Ok(state) => (state.best_x, state.evals),
        Err(_) => (x0.to_vec(), 0),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use render::envmap::{EnvMap, uv_to_direction};

    #[test]
    fn taps_reproduce_the_scalar_lookup() {
        let (w, h) = (16, 8);
        let texels: Vec<[f32; 3]> = (0..w * h).map(|i| [i as f32, (i % 5) as f32, 1.0]).collect();
        let env = EnvMap::new(w, h, texels.clone()).expect("env");
        for k in 0..200 {
            let d = uv_to_direction(glam::Vec2::new((k as f32 * 0.37).fract(), (k as f32 * 0.61).fract()));
            let (t, wt) = bilinear_taps(d, w, h);
            let got: f32 = t.iter().zip(&wt).map(|(&t, &wt)| texels[t as usize][0] * wt).sum();
            assert!(
                (got - env.lookup(d)[0]).abs() < 1e-3,
                "{d}: {got} vs {}",
                env.lookup(d)[0]
            );
        }
    }

    #[test]
    fn solve_recovers_a_map_the_transport_sees_whole() {
        // Every texel read directly (one sample per texel centre): the solve
        // must give the map back.
        let (w, h) = (8, 4);
        let truth: Vec<f64> = (0..w * h * 3).map(|i| 0.5 + (i % 7) as f64 * 0.3).collect();
        let mut wi = Vec::new();
        for r in 0..h {
            for c in 0..w {
                wi.push(uv_to_direction(glam::Vec2::new(
                    (c as f32 + 0.5) / w as f32,
                    (r as f32 + 0.5) / h as f32,
                )));
            }
        }
        let segment: Vec<u32> = (0..wi.len() as u32).collect();
        let transport = Transport::new(&segment, &wi, &vec![[1.0; 3]; wi.len()], wi.len(), w, h);
        let mut target = vec![[0.0; 3]; wi.len()];
        transport.apply(&truth, &mut target);
        let (x, evals) = solve(
            &transport,
            &target,
            &vec![1.0; wi.len()],
            LightingSolve {
                smoothness: 0.0,
                max_iters: 500,
            },
            &vec![1.0; w * h * 3],
        );
        assert!(evals > 0);
        for (a, b) in x.iter().zip(&truth) {
            assert!((a - b).abs() < 1e-3, "{a} vs {b}");
        }
    }
}
