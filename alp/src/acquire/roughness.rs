//! The roughness texture, by search: a texel's roughness shows only in how
//! its reflections blur, which no gradient of a few noisy samples tells
//! reliably. Every view is observed ([`super::observation`]) at each of a
//! ladder of uniform roughnesses, with the same pixels and primary rays;
//! the texture is cut into cells, and each cell's pixels are fitted by one
//! albedo per channel at each rung (a 1-D least squares, unbiased as the
//! albedo solve's). A cell takes the rung whose fit leaves the least error,
//! its neighbours' errors added at a weight (the smoothness: neighbours'
//! evidence pooled, not their answers averaged), refined between rungs by a
//! parabola through the errors.

use render::image_io::RgbImage;
use render::probe::Texture;

use super::material::fill;
use super::observation::{Budget, Observations, Placed, grid_neighbours, grid_pairs, observe, texel_taps};

/// What the search trades.
#[derive(Clone, Copy, Debug)]
pub(crate) struct RoughnessSearch {
    /// Rungs of the ladder, spaced evenly in log roughness.
    pub(crate) rungs: usize,
    /// The ladder's ends.
    pub(crate) least: f64,
    pub(crate) most: f64,
    /// Cells across and down.
    pub(crate) cells: [usize; 2],
    /// Weight of each of a cell's 4 neighbours' errors in its choice.
    pub(crate) smoothness: f64,
}

/// The search's answer.
pub(crate) struct RoughnessFit {
    /// The roughness per cell (in every channel), filled where no pixel saw a cell.
    pub(crate) roughness: RgbImage,
    /// The mean albedo of the cells' fits at their best rungs
    /// (pixel-weighted): the bounce's second point in the albedo's
    /// observation, and where its solve starts.
    pub(crate) mean_albedo: [f32; 3],
    /// The data term of every cell at its own best rung (unbiased relative
    /// squared error, view mean): what the placements are judged by.
    pub(crate) data: f64,
    /// The mean absolute difference of neighbouring cells' roughness.
    pub(crate) variation: f64,
}

impl RoughnessSearch {
    /// The ladder's rungs.
    pub(crate) fn ladder(&self) -> Vec<f64> {
        let n = self.rungs.max(2);
        (0..n)
            .map(|j| self.least * (self.most / self.least).powf(j as f64 / (n - 1) as f64))
            .collect()
    }
}

/// Per cell and channel, the sums that fit one albedo `a` to the cell's
/// pixels: the error `s0 - a s1 + a^2 s2`.
#[derive(Clone, Copy, Default)]
struct CellSums {
    s: [[f64; 3]; 3],
}

impl CellSums {
    /// The albedo in [0, 1] that minimizes the error, and the error.
    fn best(&self, c: usize) -> (f64, f64) {
        let [s0, s1, s2] = [self.s[0][c], self.s[1][c], self.s[2][c]];
        let a = if s2 > 0.0 {
            (s1 / (2.0 * s2)).clamp(0.0, 1.0)
        } else {
            0.0
        };
        (a, s0 - a * s1 + a * a * s2)
    }
}

/// The sums of every cell of `obs` (each pixel in the cell of its first hit).
fn cell_sums(obs: &Observations, cells: [usize; 2]) -> (Vec<CellSums>, Vec<f64>) {
    let mut sums = vec![CellSums::default(); cells[0] * cells[1]];
    let mut seen = vec![0.0; sums.len()];
    for (p, pixel) in obs.pixels.iter().enumerate() {
        let hits = obs.hits_of(p);
        let Some(first) = hits.first() else { continue };
        let cell = texel_taps(first.uv, cells[0], cells[1])
            .iter()
            .max_by(|a, b| a.1.total_cmp(&b.1))
            .expect("four taps")
            .0;
        let mut slope = [[0.0f64; 3]; 2];
        for hit in hits {
            for (s, &v) in slope[hit.half as usize].iter_mut().zip(&hit.slope) {
                *s += v as f64;
            }
        }
        let w = pixel.weight;
        let r: [[f64; 3]; 2] =
            [0, 1].map(|h| std::array::from_fn(|c| pixel.target[c] as f64 - pixel.offset[h][c] as f64));
        let terms: [[f64; 3]; 3] = [
            std::array::from_fn(|c| r[0][c] * r[1][c]),
            std::array::from_fn(|c| r[0][c] * slope[1][c] + r[1][c] * slope[0][c]),
            std::array::from_fn(|c| slope[0][c] * slope[1][c]),
        ];
        for (sum, term) in sums[cell].s.iter_mut().zip(terms) {
            for (s, t) in sum.iter_mut().zip(term) {
                *s += w * t;
            }
        }
        seen[cell] += w;
    }
    (sums, seen)
}

/// Searches the roughness of `placed`'s probe; `progress` hears the rungs done.
pub(crate) fn search(
    placed: &Placed,
    settings: &RoughnessSearch,
    budget: &Budget,
    bounce_albedo: [f32; 3],
    progress: &dyn Fn(usize),
) -> RoughnessFit {
    let ladder = settings.ladder();
    let [cw, ch] = settings.cells.map(|c| c.max(1));
    let cells = cw * ch;
    // Per rung, per cell: the error at the cell's best albedo, and that albedo.
    let mut error = vec![vec![0.0f64; ladder.len()]; cells];
    let mut albedo_at = vec![vec![[0.0f64; 3]; ladder.len()]; cells];
    let mut seen = vec![0.0; cells];
    for (j, &r) in ladder.iter().enumerate() {
        let obs = observe(placed, &Texture::constant([r as f32; 3]), bounce_albedo, budget);
        let (sums, weights) = cell_sums(&obs, [cw, ch]);
        for (k, cell) in sums.iter().enumerate() {
            let best = [0, 1, 2].map(|c| cell.best(c));
            albedo_at[k][j] = best.map(|b| b.0);
            error[k][j] = best.iter().map(|b| b.1).sum::<f64>() / 3.0;
        }
        seen = weights;
        progress(j + 1);
    }
    // Each cell's errors with its neighbours' pooled in.
    let pooled: Vec<Vec<f64>> = (0..cells)
        .map(|k| {
            let neighbours = grid_neighbours(k, cw, ch);
            (0..ladder.len())
                .map(|j| {
                    error[k][j] + settings.smoothness * neighbours.iter().flatten().map(|&n| error[n][j]).sum::<f64>()
                })
                .collect()
        })
        .collect();
    let log_ladder: Vec<f64> = ladder.iter().map(|r| r.ln()).collect();
    let mut roughness = vec![0.0f64; cells];
    let mut pooled_seen = vec![0.0f64; cells];
    for k in 0..cells {
        pooled_seen[k] = seen[k]
            + grid_neighbours(k, cw, ch)
                .iter()
                .flatten()
                .map(|&n| seen[n])
                .sum::<f64>();
        roughness[k] = refined_minimum(&log_ladder, &pooled[k]).exp();
    }
    let (mut data, mut weight_sum, mut mean_albedo) = (0.0, 0.0, [0.0f64; 3]);
    for k in 0..cells {
        let j = (0..ladder.len())
            .min_by(|&a, &b| error[k][a].total_cmp(&error[k][b]))
            .expect("rungs");
        data += error[k][j];
        weight_sum += seen[k];
        (0..3).for_each(|c| mean_albedo[c] += seen[k] * albedo_at[k][j][c]);
    }
    let mean_albedo = mean_albedo.map(|a| (a / weight_sum.max(f64::MIN_POSITIVE)) as f32);
    // Cells no pixel (nor a neighbour's) saw take the nearest seen values.
    let seen_around: Vec<f32> = pooled_seen.iter().map(|&s| (s > 0.0) as u8 as f32).collect();
    let filled = fill(
        &RgbImage::new(cw, ch, roughness.iter().map(|&r| [r as f32; 3]).collect()),
        &seen_around,
    );
    let variation = {
        let (mut sum, mut pairs) = (0.0, 0usize);
        for k in 0..cells {
            for n in grid_pairs(k, cw, ch).into_iter().flatten() {
                sum += (filled.pixels[k][0] - filled.pixels[n][0]).abs() as f64;
                pairs += 1;
            }
        }
        sum / pairs.max(1) as f64
    };
    RoughnessFit {
        roughness: filled,
        mean_albedo,
        data,
        variation,
    }
}

/// The minimum of the function sampled at `x` (increasing) with values
/// `y`: at the least sample, moved to the vertex of the parabola through
/// it and its two neighbours when that parabola opens upwards (kept within
/// the neighbours).
fn refined_minimum(x: &[f64], y: &[f64]) -> f64 {
    let j = (0..y.len()).min_by(|&a, &b| y[a].total_cmp(&y[b])).expect("samples");
    if j == 0 || j + 1 == y.len() {
        return x[j];
    }
    let (x0, x1, x2) = (x[j - 1], x[j], x[j + 1]);
    let (y0, y1, y2) = (y[j - 1], y[j], y[j + 1]);
    let d0 = (y1 - y0) / (x1 - x0);
    let d1 = (y2 - y1) / (x2 - x1);
    let curvature = (d1 - d0) / (x2 - x0);
    if curvature.is_nan() || curvature <= 0.0 {
        return x1;
    }
    // The parabola's vertex: where its slope, d0 at the middle of [x0, x1] rising at 2 curvature, is 0.
    let vertex = (x0 + x1) / 2.0 - d0 / (2.0 * curvature);
    vertex.clamp(x0, x2)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_parabola_finds_a_quadratics_minimum_between_samples() {
        let x: Vec<f64> = (0..6).map(|i| i as f64 * 0.5).collect();
        let y: Vec<f64> = x.iter().map(|v| (v - 1.3).powi(2) + 2.0).collect();
        assert!((refined_minimum(&x, &y) - 1.3).abs() < 1e-12);
        // At an end: the end.
        let y: Vec<f64> = x.iter().map(|v| v * 3.0).collect();
        assert_eq!(refined_minimum(&x, &y), 0.0);
    }

    #[test]
    fn a_cells_albedo_is_its_least_squares_within_bounds() {
        // Error (t - a s)^2 with t = 0.3, s = 0.5 in both halves: a = 0.6, error 0.
        let sums = CellSums {
            s: [[0.09; 3], [2.0 * 0.3 * 0.5; 3], [0.25; 3]],
        };
        let (a, e) = sums.best(0);
        assert!((a - 0.6).abs() < 1e-12 && e.abs() < 1e-12);
        // t = 0.9: a = 1.8 clamps to 1.
        let sums = CellSums {
            s: [[0.81; 3], [2.0 * 0.9 * 0.5; 3], [0.25; 3]],
        };
        assert_eq!(sums.best(1).0, 1.0);
    }
}
