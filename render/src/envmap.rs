//! The environment map: distant lighting as an equirectangular (latitude-longitude) radiance image.
//!
//! Convention (FORMATS.md): a unit direction d = (x, y, z), pointing from the scene towards where
//! the light comes from, sits at `u = atan2(x, -z) / (2 pi)` wrapped into [0, 1) and
//! `v = acos(y) / pi`; column = u * width, row = v * height, row 0 is straight up (+Y). Texel
//! (row i, column j) holds the radiance at u = (j + 0.5) / width, v = (i + 0.5) / height.

use std::f32::consts::PI;
use std::path::Path;

use autodiff::Real;
use glam::{Vec2, Vec3};

use crate::error::{RenderError, Result};
use crate::image_io::RgbImage;
use crate::lookup::env_taps;

/// The (u, v) in [0, 1) x [0, 1] of a unit direction.
pub fn direction_to_uv(direction: Vec3) -> Vec2 {
    let u = direction.x.atan2(-direction.z) / (2.0 * PI);
    // atan2 is in (-pi, pi]: wrap the negative half; `u + 1` can round to exactly 1 for tiny -u.
    let u = if u < 0.0 { u + 1.0 } else { u };
    let u = if u >= 1.0 { 0.0 } else { u };
    let v = direction.y.clamp(-1.0, 1.0).acos() / PI;
    Vec2::new(u, v)
}

/// The unit direction at (u, v); the inverse of [`direction_to_uv`].
pub fn uv_to_direction(uv: Vec2) -> Vec3 {
    let phi = 2.0 * PI * uv.x;
    let theta = PI * uv.y;
    let (sin_theta, cos_theta) = theta.sin_cos();
    let (sin_phi, cos_phi) = phi.sin_cos();
    // x = sin(theta) sin(phi), z = -sin(theta) cos(phi) so that atan2(x, -z) = phi.
    Vec3::new(sin_theta * sin_phi, cos_theta, -sin_theta * cos_phi)
}

/// Relative size (to the brightest texel) of negative values taken as compression ringing by [`EnvMap::read`].
pub const RINGING_TOLERANCE: f32 = 1e-3;

/// Linear-radiance RGB environment map, `width = 2 * height`, row-major with row 0 at +Y.
#[derive(Clone, Debug, PartialEq)]
pub struct EnvMap {
    width: usize,
    height: usize,
    radiance: Vec<[f32; 3]>,
}

impl EnvMap {
    /// An env map from its texels; fails unless `width = 2 x height > 0`, the length matches and
    /// every value is finite and non-negative.
    pub fn new(width: usize, height: usize, radiance: Vec<[f32; 3]>) -> Result<Self> {
        if height == 0 || width != 2 * height {
            return Err(RenderError::value(
                "size",
                format!("width {width} is not 2 x height {height}"),
            ));
        }
        if radiance.len() != width * height {
            return Err(RenderError::value(
                "radiance",
                format!("{} texels for a {width}x{height} map", radiance.len()),
            ));
        }
        let image = RgbImage::new(width, height, radiance);
        if let Some(rule) = image.first_invalid(|v| v.is_finite() && v >= 0.0, "is not finite and >= 0") {
            return Err(RenderError::value("radiance", rule));
        }
        Ok(Self {
            width,
            height,
            radiance: image.pixels,
        })
    }

    /// A map of `height` rows where every texel holds `radiance`.
    pub fn constant(height: usize, radiance: [f32; 3]) -> Self {
        assert!(height > 0, "EnvMap::constant: height must be > 0");
        Self {
            width: 2 * height,
            height,
            radiance: vec![radiance; 2 * height * height],
        }
    }

    /// Reads a lat-long OpenEXR env map, rejecting non-2:1 sizes, missing channels and NaN, infinite or negative texels.
    ///
    /// Lossy EXR codecs (DWAA/DWAB) ring slightly below zero next to bright texels (the project's
    /// own courtyard.exr goes down to -0.003 next to values of 55): negatives no larger than
    /// [`RINGING_TOLERANCE`] x the brightest value are set to 0; larger ones are an error.
    pub fn read(path: impl AsRef<Path>) -> Result<Self> {
        let path = path.as_ref();
        let mut image = RgbImage::read_exr(path)?;
        let brightest = image.pixels.iter().flatten().copied().fold(0.0f32, f32::max);
        let ringing = -RINGING_TOLERANCE * brightest;
        image
            .pixels
            .iter_mut()
            .flatten()
            .filter(|v| **v < 0.0 && **v >= ringing)
            .for_each(|v| *v = 0.0);
        Self::new(image.width, image.height, image.pixels).map_err(|e| e.in_file(path))
    }

    /// Writes the map as a float RGB OpenEXR with ZIP compression.
    pub fn write(&self, path: impl AsRef<Path>) -> Result<()> {
        self.to_image().write_exr(path)
    }

    /// The map as a plain image (for previews).
    pub fn to_image(&self) -> RgbImage {
        RgbImage::new(self.width, self.height, self.radiance.clone())
    }

    /// Number of columns (= 2 x height).
    pub fn width(&self) -> usize {
        self.width
    }

    /// Number of rows.
    pub fn height(&self) -> usize {
        self.height
    }

    /// All texels, row-major.
    pub fn radiance(&self) -> &[[f32; 3]] {
        &self.radiance
    }

    /// The texel at (row, col).
    pub fn texel(&self, row: usize, col: usize) -> [f32; 3] {
        self.radiance[row * self.width + col]
    }

    /// The direction through the centre of texel (row, col).
    pub fn texel_direction(&self, row: usize, col: usize) -> Vec3 {
        uv_to_direction(Vec2::new(
            (col as f32 + 0.5) / self.width as f32,
            (row as f32 + 0.5) / self.height as f32,
        ))
    }

    /// Solid angle (sr) of any texel of `row`: (2 pi / width) (cos theta_top - cos theta_bottom).
    pub fn texel_solid_angle(&self, row: usize) -> f32 {
        let theta = |r: usize| PI * r as f32 / self.height as f32;
        2.0 * PI / self.width as f32 * (theta(row).cos() - theta(row + 1).cos())
    }

    /// Bilinear lookup of the radiance arriving from `direction` (unit), wrapping in u and clamping in v.
    pub fn lookup(&self, direction: Vec3) -> [f32; 3] {
        self.lookup_uv(direction_to_uv(direction))
    }

    /// Bilinear lookup at (u, v), wrapping in u and clamping in v; texel centres are at +0.5.
    pub fn lookup_uv(&self, uv: Vec2) -> [f32; 3] {
        let x = uv.x * self.width as f32 - 0.5;
        let y = (uv.y * self.height as f32 - 0.5).clamp(0.0, (self.height - 1) as f32);
        let (x0, y0) = (x.floor(), y.floor());
        let (fx, fy) = (x - x0, y - y0);
        let w = self.width as i64;
        let col0 = (x0 as i64).rem_euclid(w) as usize;
        let col1 = (x0 as i64 + 1).rem_euclid(w) as usize;
        let row0 = y0 as usize;
        let row1 = (row0 + 1).min(self.height - 1);
        let mut out = [0.0; 3];
        for (row, wy) in [(row0, 1.0 - fy), (row1, fy)] {
            for (col, wx) in [(col0, 1.0 - fx), (col1, fx)] {
                let t = self.texel(row, col);
                for c in 0..3 {
                    out[c] += wx * wy * t[c];
                }
            }
        }
        out
    }

    /// Box-filters the map down to `height` rows (and 2 x `height` columns),
    /// keeping its power (see [`resample`]).
    pub fn downsample(&self, height: usize) -> Self {
        assert!(
            height > 0 && height <= self.height,
            "EnvMap::downsample: cannot go from {} to {height} rows",
            self.height
        );
        let width = 2 * height;
        let texels: Vec<f32> = self.radiance.iter().flatten().copied().collect();
        let resampled = resample(&texels, (self.width, self.height), (width, height));
        Self {
            width,
            height,
            radiance: resampled.chunks_exact(3).map(|t| [t[0], t[1], t[2]]).collect(),
        }
    }
}

/// A texel-major RGB map of size `from` (width, height) at size `to`, in the
/// precision it comes in: box-filtered down, each new texel the
/// solid-angle-weighted mean of the old texels it overlaps (fractional
/// overlaps allowed), which keeps the total power (a light finer than the
/// new texels keeps its energy); bilinear up, with the lookup's taps
/// ([`env_taps`]). One way or the other in both directions: a size that
/// grows in one and shrinks in the other is refused.
pub fn resample<T: Real>(texels: &[T], from: (usize, usize), to: (usize, usize)) -> Vec<T> {
    assert_eq!(
        texels.len(),
        from.0 * from.1 * 3,
        "resample: a {}x{} map needs {} values",
        from.0,
        from.1,
        from.0 * from.1 * 3
    );
    if from == to {
        return texels.to_vec();
    }
    let down = to.0 <= from.0 && to.1 <= from.1;
    assert!(
        down || (to.0 >= from.0 && to.1 >= from.1),
        "resample: {}x{} to {}x{} neither grows nor shrinks",
        from.0,
        from.1,
        to.0,
        to.1
    );
    let mut out = vec![T::zero(); to.0 * to.1 * 3];
    if down {
        // Weights are separable: overlap in u (uniform), times overlap in cos(theta) (solid angle).
        let col_weights = overlaps(from.0, to.0, |x| x);
        let row_weights = overlaps(from.1, to.1, |v| (PI * v).cos());
        for &(new_row, old_row, wy) in &row_weights {
            for &(new_col, old_col, wx) in &col_weights {
                let (old, new) = ((old_row * from.0 + old_col) * 3, (new_row * to.0 + new_col) * 3);
                let w = T::c((wx * wy) as f64);
                for c in 0..3 {
                    out[new + c] += w * texels[old + c];
                }
            }
        }
        return out;
    }
    for r in 0..to.1 {
        for c in 0..to.0 {
            let u = (c as f32 + 0.5) / to.0 as f32;
            let v = (r as f32 + 0.5) / to.1 as f32;
            let (taps, weights) = env_taps(Vec2::new(u, v), from.0, from.1);
            for ch in 0..3 {
                out[(r * to.0 + c) * 3 + ch] = taps
                    .iter()
                    .zip(&weights)
                    .map(|(&t, &w)| T::c(w as f64) * texels[t as usize * 3 + ch])
                    .fold(T::neg_zero(), |sum, x| sum + x);
            }
        }
    }
    out
}

/// For a resampling from `old` to `new` cells of [0, 1] with measure `|cdf(b) - cdf(a)|`, the
/// triples (new cell, old cell, share of the new cell's measure that the old cell covers).
fn overlaps(old: usize, new: usize, cdf: impl Fn(f32) -> f32) -> Vec<(usize, usize, f32)> {
    let measure = |a: f32, b: f32| (cdf(b) - cdf(a)).abs();
    let mut out = Vec::new();
    for n in 0..new {
        let (a, b) = (n as f32 / new as f32, (n + 1) as f32 / new as f32);
        let total = measure(a, b);
        let first = ((a * old as f32).floor() as usize).min(old - 1);
        let last = ((b * old as f32).ceil() as usize).clamp(first + 1, old);
        for o in first..last {
            let (oa, ob) = (o as f32 / old as f32, (o + 1) as f32 / old as f32);
            let (lo, hi) = (a.max(oa), b.min(ob));
            if hi > lo {
                out.push((n, o, measure(lo, hi) / total));
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use approx::assert_abs_diff_eq;

    #[test]
    fn mapping_at_poles_and_seam() {
        // -Z is the centre of the seam-free side: atan2(0, 1) = 0, so u = 0 (column 0's left edge).
        assert_vec_close!(direction_to_uv(Vec3::new(0.0, 0.0, -1.0)), Vec2::new(0.0, 0.5), 1e-6);
        assert_vec_close!(direction_to_uv(Vec3::X), Vec2::new(0.25, 0.5), 1e-6);
        assert_vec_close!(direction_to_uv(Vec3::Z), Vec2::new(0.5, 0.5), 1e-6);
        assert_vec_close!(direction_to_uv(-Vec3::X), Vec2::new(0.75, 0.5), 1e-6);
        assert_abs_diff_eq!(direction_to_uv(Vec3::Y).y, 0.0, epsilon = 1e-6);
        assert_abs_diff_eq!(direction_to_uv(-Vec3::Y).y, 1.0, epsilon = 1e-6);
        // Just left of the seam wraps to u close to 1, never to 1 itself.
        let u = direction_to_uv(Vec3::new(-1e-9, 0.0, -1.0)).x;
        assert!((0.0..1.0).contains(&u));
        let u = direction_to_uv(Vec3::new(-1e-3, 0.0, -1.0)).x;
        assert!(u > 0.999 && u < 1.0);
    }

    #[test]
    fn uv_round_trip() {
        for i in 0..50 {
            for j in 1..50 {
                let uv = Vec2::new(i as f32 / 50.0, j as f32 / 50.0);
                let back = direction_to_uv(uv_to_direction(uv));
                assert_vec_close!(back, uv, 1e-5);
            }
        }
    }

    #[test]
    fn texel_solid_angles_sum_to_4_pi() {
        let env = EnvMap::constant(16, [1.0; 3]);
        let total: f64 = (0..16).map(|r| env.texel_solid_angle(r) as f64 * 32.0).sum();
        assert_abs_diff_eq!(total, 4.0 * std::f64::consts::PI, epsilon = 1e-4);
    }

    #[test]
    fn bilinear_lookup_hits_texel_centres_and_wraps() {
        let radiance: Vec<[f32; 3]> = (0..32).map(|i| [i as f32, 0.0, 1.0]).collect();
        let env = EnvMap::new(8, 4, radiance).unwrap();
        assert_eq!(env.lookup(env.texel_direction(1, 3)), env.texel(1, 3));
        // Half way between the last and the first column of row 2 (the seam).
        let mid = env.lookup_uv(Vec2::new(0.0, 2.5 / 4.0));
        assert_abs_diff_eq!(mid[0], 0.5 * (env.texel(2, 7)[0] + env.texel(2, 0)[0]), epsilon = 1e-5);
        // Clamped in v: above the first row's centre is the first row.
        assert_abs_diff_eq!(
            env.lookup_uv(Vec2::new(3.5 / 8.0, 0.0))[0],
            env.texel(0, 3)[0],
            epsilon = 1e-5
        );
    }

    #[test]
    fn downsampling_preserves_power_and_constants() {
        let radiance: Vec<[f32; 3]> = (0..24 * 48).map(|i| [(i % 7) as f32, (i % 5) as f32, 1.0]).collect();
        let env = EnvMap::new(48, 24, radiance).unwrap();
        let power = |e: &EnvMap| -> f64 {
            (0..e.height())
                .flat_map(|r| (0..e.width()).map(move |c| (r, c)))
                .map(|(r, c)| e.texel(r, c)[0] as f64 * e.texel_solid_angle(r) as f64)
                .sum()
        };
        for new_height in [12, 10, 7, 1] {
            let small = env.downsample(new_height);
            assert_eq!((small.width(), small.height()), (2 * new_height, new_height));
            assert_abs_diff_eq!(power(&small), power(&env), epsilon = 1e-3 * power(&env));
            for t in small.radiance() {
                assert_abs_diff_eq!(t[2], 1.0, epsilon = 1e-5);
            }
        }
    }

    #[test]
    fn resampling_up_reads_the_map_as_its_lookup_does() {
        let (w, h) = (16, 8);
        let radiance: Vec<[f32; 3]> = (0..w * h)
            .map(|i| [(i % 7) as f32, (i % 5) as f32 + 0.5, 1.0])
            .collect();
        let env = EnvMap::new(w, h, radiance.clone()).unwrap();
        let texels: Vec<f64> = radiance.iter().flatten().map(|&v| v as f64).collect();
        let (to_w, to_h) = (40, 20);
        let up = resample(&texels, (w, h), (to_w, to_h));
        for r in 0..to_h {
            for c in 0..to_w {
                let uv = Vec2::new((c as f32 + 0.5) / to_w as f32, (r as f32 + 0.5) / to_h as f32);
                let want = env.lookup(uv_to_direction(uv));
                for ch in 0..3 {
                    let got = up[(r * to_w + c) * 3 + ch];
                    assert_abs_diff_eq!(got, want[ch] as f64, epsilon = 1e-4);
                }
            }
        }
        assert_eq!(resample(&texels, (w, h), (w, h)), texels, "the same size as it is");
    }

    #[test]
    fn rejects_bad_shapes_and_values() {
        let e = EnvMap::new(300, 128, vec![[0.0; 3]; 300 * 128]).unwrap_err();
        assert!(e.to_string().contains("width 300 is not 2 x height 128"), "{e}");
        let mut radiance = vec![[0.0; 3]; 8];
        radiance[5][1] = -1.0;
        let e = EnvMap::new(4, 2, radiance).unwrap_err();
        assert!(e.to_string().contains("(row 1, col 1) channel G = -1"), "{e}");
    }
}
