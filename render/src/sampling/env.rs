//! Importance sampling of an env map: a piecewise-constant 2D distribution over the lat-long
//! texels (pbrt-v4, section 12.5.2 "Image Infinite Lights"), pdf converted to solid angle.
//!
//! In (u, v) the density is constant per texel: p(u, v) = W H P(texel). Since
//! d(omega) = 2 pi^2 sin(theta) du dv (theta = pi v), the solid-angle pdf is
//! p(omega) = p(u, v) / (2 pi^2 sin theta).

use std::f32::consts::PI;

use glam::{Vec2, Vec3};

use crate::envmap::{EnvMap, direction_to_uv, uv_to_direction};
use crate::sampling::Distribution1D;

/// Luminance of linear Rec. 709 RGB.
fn luminance(rgb: [f32; 3]) -> f64 {
    0.2126 * rgb[0] as f64 + 0.7152 * rgb[1] as f64 + 0.0722 * rgb[2] as f64
}

/// A direction drawn from an [`EnvSampler`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EnvSample {
    /// Unit direction towards the light (world).
    pub direction: Vec3,
    /// Its solid-angle pdf.
    pub pdf: f32,
}

/// Samples directions proportionally to luminance x texel solid angle (~ sin theta) of an env map.
#[derive(Clone, Debug)]
pub struct EnvSampler {
    width: usize,
    height: usize,
    /// Marginal over rows.
    rows: Distribution1D,
    /// Conditional over the columns of each row.
    columns: Vec<Distribution1D>,
}

impl EnvSampler {
    /// Builds the sampler of `env`; a black map falls back to sampling by solid angle.
    pub fn new(env: &EnvMap) -> Self {
        let (width, height) = (env.width(), env.height());
        let mut columns = Vec::with_capacity(height);
        let mut row_weights = Vec::with_capacity(height);
        for row in 0..height {
            let weights: Vec<f64> = env.radiance()[row * width..(row + 1) * width]
                .iter()
                .map(|&t| luminance(t))
                .collect();
            row_weights.push(weights.iter().sum::<f64>() * env.texel_solid_angle(row) as f64);
            columns.push(Distribution1D::new(&weights));
        }
        if row_weights.iter().all(|&w| w == 0.0) {
            row_weights = (0..height).map(|row| env.texel_solid_angle(row) as f64).collect();
        }
        Self {
            width,
            height,
            rows: Distribution1D::new(&row_weights),
            columns,
        }
    }

    /// Draws a direction from uniform `u` in [0, 1)^2.
    pub fn sample(&self, u: Vec2) -> EnvSample {
        let (row, fy) = self.rows.sample(u.x);
        let (col, fx) = self.columns[row].sample(u.y);
        let uv = Vec2::new(
            (col as f32 + fx) / self.width as f32,
            (row as f32 + fy) / self.height as f32,
        );
        let direction = uv_to_direction(uv);
        EnvSample {
            direction,
            pdf: self.pdf_at(row, col, (PI * uv.y).sin()),
        }
    }

    /// Solid-angle pdf that [`EnvSampler::sample`] returns `direction` (unit).
    pub fn pdf(&self, direction: Vec3) -> f32 {
        let uv = direction_to_uv(direction);
        let row = ((uv.y * self.height as f32) as usize).min(self.height - 1);
        let col = ((uv.x * self.width as f32) as usize).min(self.width - 1);
        // sqrt(x^2 + z^2) keeps its precision near the poles, unlike sqrt(1 - y^2).
        let sin_theta = Vec2::new(direction.x, direction.z).length();
        self.pdf_at(row, col, sin_theta)
    }

    fn pdf_at(&self, row: usize, col: usize, sin_theta: f32) -> f32 {
        if sin_theta <= 0.0 {
            return 0.0;
        }
        let pmf = self.rows.pmf(row) * self.columns[row].pmf(col);
        let pdf_uv = pmf * (self.width * self.height) as f64;
        (pdf_uv / (2.0 * std::f64::consts::PI * std::f64::consts::PI * sin_theta as f64)) as f32
    }
}
