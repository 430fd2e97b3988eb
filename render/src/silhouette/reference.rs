//! The reference (photo) mask: its exact Euclidean distance transform and barycenter, computed once.

use glam::DVec2;

use crate::error::{RenderError, Result};
use crate::image_io::Mask;

/// A reference mask prepared for the mask losses.
#[derive(Clone, Debug)]
pub struct ReferenceMask {
    mask: Mask,
    distance: Vec<f32>,
    area: usize,
    barycenter: DVec2,
}

impl ReferenceMask {
    /// Prepares `mask`; fails when it marks no pixel.
    pub fn new(mask: &Mask) -> Result<Self> {
        let barycenter = mask_barycenter(mask).ok_or_else(|| {
            RenderError::value(
                "mask",
                format!(
                    "the {}x{} reference mask is empty: no pixel marks the probe",
                    mask.width, mask.height
                ),
            )
        })?;
        Ok(Self {
            distance: distance_transform(&mask.inside, mask.width, mask.height),
            area: mask.count(),
            barycenter,
            mask: mask.clone(),
        })
    }

    /// The mask.
    pub fn mask(&self) -> &Mask {
        &self.mask
    }

    /// Per pixel (row-major), the Euclidean distance in pixels from its centre to the nearest
    /// centre of a mask pixel (0 inside the mask).
    pub fn distance(&self) -> &[f32] {
        &self.distance
    }

    /// Number of mask pixels.
    pub fn area(&self) -> usize {
        self.area
    }

    /// Mean pixel-centre position of the mask pixels (x right, y down, pixels).
    pub fn barycenter(&self) -> DVec2 {
        self.barycenter
    }

    /// Fails unless the mask is `width x height`.
    pub(crate) fn check_size(&self, width: usize, height: usize) -> Result<()> {
        if (self.mask.width, self.mask.height) != (width, height) {
            return Err(RenderError::value(
                "mask",
                format!(
                    "reference mask is {}x{}, the camera renders {width}x{height}",
                    self.mask.width, self.mask.height
                ),
            ));
        }
        Ok(())
    }
}

/// Mean pixel-centre position (x right, y down, pixels) of the pixels of `mask`; `None` if empty.
pub fn mask_barycenter(mask: &Mask) -> Option<DVec2> {
    let mut sum = DVec2::ZERO;
    let mut count = 0usize;
    for (i, _) in mask.inside.iter().enumerate().filter(|(_, m)| **m) {
        sum += DVec2::new((i % mask.width) as f64 + 0.5, (i / mask.width) as f64 + 0.5);
        count += 1;
    }
    (count > 0).then(|| sum / count as f64)
}

/// Exact Euclidean distance transform: for every pixel the distance (pixels) from its centre to
/// the nearest centre of an `inside` pixel; infinite everywhere when none is.
///
/// Felzenszwalb & Huttenlocher (2012), "Distance Transforms of Sampled Functions": the squared
/// distance is separable, `min_(i,j) (x - i)^2 + (y - j)^2 + f(i, j)`, so a 1D lower envelope of
/// parabolas along the columns and then along the rows gives it in O(pixels).
pub fn distance_transform(inside: &[bool], width: usize, height: usize) -> Vec<f32> {
    assert_eq!(
        inside.len(),
        width * height,
        "distance_transform: {} flags for a {width}x{height} image",
        inside.len()
    );
    let mut d2: Vec<f64> = inside.iter().map(|&m| if m { 0.0 } else { f64::INFINITY }).collect();
    let mut envelope = Envelope::default();
    let mut line = Vec::new();
    for col in 0..width {
        line.clear();
        line.extend((0..height).map(|row| d2[row * width + col]));
        envelope.transform(&mut line);
        for (row, &v) in line.iter().enumerate() {
            d2[row * width + col] = v;
        }
    }
    for row in d2.chunks_mut(width) {
        envelope.transform(row);
    }
    d2.into_iter().map(|v| v.sqrt() as f32).collect()
}

/// Scratch space of the 1D squared distance transform.
#[derive(Default)]
struct Envelope {
    /// Positions of the parabolas of the lower envelope.
    site: Vec<usize>,
    /// Boundaries between consecutive envelope parabolas.
    bound: Vec<f64>,
}

impl Envelope {
    /// `f[q] <- min_p (q - p)^2 + f[p]` in place; infinite samples are not parabolas (an all
    /// infinite line stays infinite).
    fn transform(&mut self, f: &mut [f64]) {
        self.site.clear();
        self.bound.clear();
        for q in 0..f.len() {
            if !f[q].is_finite() {
                continue;
            }
            let h = f[q] + (q * q) as f64;
            // Intersection of parabola q with the envelope's last parabola.
            let mut s = f64::NEG_INFINITY;
            while let Some(&p) = self.site.last() {
                s = (h - (f[p] + (p * p) as f64)) / (2.0 * (q - p) as f64);
                if s > *self.bound.last().unwrap_or(&f64::NEG_INFINITY) {
                    break;
                }
                self.site.pop();
                self.bound.pop();
                s = f64::NEG_INFINITY;
            }
            // `bound[k]` is where parabola k starts winning.
            self.site.push(q);
            self.bound
                .push(if self.site.len() == 1 { f64::NEG_INFINITY } else { s });
        }
        if self.site.is_empty() {
            return;
        }
        let values: Vec<f64> = self.site.iter().map(|&p| f[p]).collect();
        let mut k = 0;
        for (q, out) in f.iter_mut().enumerate() {
            while k + 1 < self.site.len() && self.bound[k + 1] <= q as f64 {
                k += 1;
            }
            let p = self.site[k];
            *out = (q as f64 - p as f64).powi(2) + values[k];
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn distance_transform_matches_brute_force() {
        let (w, h) = (23, 17);
        let inside: Vec<bool> = (0..w * h)
            .map(|i| autodiff::gradcheck::unit_hash(i as u64 + 7) < 0.04)
            .collect();
        let dt = distance_transform(&inside, w, h);
        for (i, &got) in dt.iter().enumerate() {
            let (x, y) = ((i % w) as f64, (i / w) as f64);
            let want = (0..w * h)
                .filter(|&j| inside[j])
                .map(|j| ((x - (j % w) as f64).powi(2) + (y - (j / w) as f64).powi(2)).sqrt())
                .fold(f64::INFINITY, f64::min);
            assert!((got as f64 - want).abs() < 1e-5, "pixel {i}: {got} vs {want}");
        }
    }

    #[test]
    fn distance_transform_literal_values() {
        // One site at (row 1, col 0) of a 3x2 image.
        let inside = [false, false, false, true, false, false];
        let dt = distance_transform(&inside, 3, 2);
        let want = [1.0, 2f32.sqrt(), 5f32.sqrt(), 0.0, 1.0, 2.0];
        for (a, b) in dt.iter().zip(want) {
            assert!((a - b).abs() < 1e-6, "{dt:?}");
        }
        assert!(distance_transform(&[false; 4], 2, 2).iter().all(|v| v.is_infinite()));
    }

    #[test]
    fn empty_reference_is_an_error() {
        let e = ReferenceMask::new(&Mask::new(4, 3, vec![false; 12])).unwrap_err();
        assert_eq!(e.field_name(), Some("mask"), "{e}");
    }
}
