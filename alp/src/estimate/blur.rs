//! The photo's blur, from the probe's own edges: defocus, motion, a lens or
//! a JPEG's demosaicing spread each pixel's light over its neighbours, the
//! probe's highlights and its outline with it. Across the mask's outline,
//! where the photo shows a clear edge, its profile is a step blurred by
//! the pixel's footprint: `a + b Phi((t - t0) / s)` along the normal. Each
//! such profile is fitted (the edge's place `t0` and width `s` on a grid,
//! `a` and `b` in closed form). The one width that leaves the least of
//! the clear edges' profiles unexplained, summed over them (a single edge's
//! best width is noisy: a highlight beside it fits a narrow step), less
//! the width a sharp photo's own pixels and the profile's sampling give an
//! edge (`SHARP_EDGE_PX`), is the blur. The renders of the probe
//! then spread each pixel's rays by it (`Camera::footprint_px`), so that
//! a soft photo is explained rather than fought.

use glam::Vec2;
use render::colour::luminance;
use render::image_io::Mask;
use render::silhouette::distance_transform;
use serde::Serialize;

use super::photo::Photo;
use super::settings::BlurSettings;
use crate::error::Result;
use crate::objective::mask_mean_luminance;

/// Samples of a profile per pixel.
const STEPS_PER_PX: f32 = 4.0;

/// The width (standard deviation, pixels) of a sharp edge's profile: a
/// pixel's box (variance 1/12) sampled between pixel centres by bilinear
/// interpolation (a tent, variance 1/6) gives 0.5; the probe's own soft
/// edges add to it. Measured on the train split's sharp photos (their
/// best widths, docs/results/benchmark.md 16.3).
pub const SHARP_EDGE_PX: f32 = 0.55;

/// The edge widths fitted (standard deviations, pixels): from the
/// narrowest by this factor to the widest.
const WIDTHS_PX: (f32, f32, f32) = (0.3, 1.08, 3.2);

/// What the photo's edges tell of its blur.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct BlurEstimate {
    /// The blur beyond the pixels' box, a Gaussian's standard deviation in
    /// the photo's pixels.
    pub blur_px: f32,
    /// The width (a Gaussian's standard deviation, pixels) that fits the
    /// clear edges' profiles best.
    pub edge_width_px: f32,
    /// The clear edges it was measured on.
    pub edges: usize,
}

/// The blur of `photo` (see the module's description); a blur of 0 when
/// fewer than `BlurSettings::min_edges` clear edges show.
pub fn photo_blur(photo: &Photo, settings: &BlurSettings) -> Result<BlurEstimate> {
    let dark = settings.dark_level * mask_mean_luminance(&photo.image, &photo.mask)?;
    let widths = edge_widths();
    // Per clear edge, the share of its profile's variance each width leaves.
    let fits: Vec<Vec<f64>> = outline_points(&photo.mask)
        .into_iter()
        .step_by(settings.every_nth.max(1))
        .filter_map(|(at, normal)| edge_fit(photo, at, normal, &widths, settings, dark))
        .collect();
    let edges = fits.len();
    if edges < settings.min_edges {
        return Ok(BlurEstimate {
            blur_px: 0.0,
            edge_width_px: 0.0,
            edges,
        });
    }
    // The one width that leaves the least over every clear edge, refined by
    // a parabola in log width.
    let total: Vec<f64> = (0..widths.len()).map(|k| fits.iter().map(|f| f[k]).sum()).collect();
    let best = (0..total.len())
        .min_by(|&a, &b| total[a].total_cmp(&total[b]))
        .expect("widths");
    let log_width = match best > 0 && best + 1 < total.len() {
        true => {
            let (a, b, c) = (total[best - 1], total[best], total[best + 1]);
            let denominator = a - 2.0 * b + c;
            let shift = if denominator > 0.0 {
                0.5 * (a - c) / denominator
            } else {
                0.0
            };
            widths[best].ln() + shift as f32 * WIDTHS_PX.1.ln()
        }
        false => widths[best].ln(),
    };
    let width = log_width.exp();
    Ok(BlurEstimate {
        blur_px: (width * width - SHARP_EDGE_PX * SHARP_EDGE_PX).max(0.0).sqrt(),
        edge_width_px: width,
        edges,
    })
}

/// The edge widths fitted, narrowest first.
fn edge_widths() -> Vec<f32> {
    let (narrowest, factor, widest) = WIDTHS_PX;
    std::iter::successors(Some(narrowest), |s| Some(s * factor))
        .take_while(|&s| s <= widest)
        .collect()
}

/// The mask's outline as points and outward normals: one per pixel whose
/// centre lies within half a pixel of it, projected on to it along the
/// gradient of the signed distance.
fn outline_points(mask: &Mask) -> Vec<(Vec2, Vec2)> {
    let (w, h) = (mask.width, mask.height);
    let outside: Vec<bool> = mask.inside.iter().map(|&m| !m).collect();
    let to_inside = distance_transform(&mask.inside, w, h);
    let to_outside = distance_transform(&outside, w, h);
    // Negative inside, positive outside; the outline at 0, half a pixel
    // beyond the centres of the mask's edge pixels.
    let signed: Vec<f32> = (0..w * h)
        .map(|p| match mask.inside[p] {
            true => 0.5 - to_outside[p],
            false => to_inside[p] - 0.5,
        })
        .collect();
    let at_px = |x: i64, y: i64| signed[y.clamp(0, h as i64 - 1) as usize * w + x.clamp(0, w as i64 - 1) as usize];
    (0..w * h)
        .filter(|&p| mask.inside[p] && signed[p] >= -0.5)
        .filter_map(|p| {
            let (x, y) = ((p % w) as i64, (p / w) as i64);
            let gradient = Vec2::new(at_px(x + 1, y) - at_px(x - 1, y), at_px(x, y + 1) - at_px(x, y - 1));
            let normal = gradient.try_normalize()?;
            Some((Vec2::new(x as f32 + 0.5, y as f32 + 0.5) - signed[p] * normal, normal))
        })
        .collect()
}

/// Across the outline at `at` along `normal`, where the photo shows a
/// clear edge: the share of its profile's variance (its luminance over its
/// mean plus `dark`, within `BlurSettings::reach_px`) that a step of each
/// of `widths` leaves, at its best place within `BlurSettings::place_px`.
/// An edge is clear when at its best width its step is at least
/// `BlurSettings::min_contrast` and it leaves at most
/// `BlurSettings::max_residual`. None otherwise, or where the profile
/// leaves the image.
fn edge_fit(
    photo: &Photo,
    at: Vec2,
    normal: Vec2,
    widths: &[f32],
    settings: &BlurSettings,
    dark: f64,
) -> Option<Vec<f64>> {
    let n = (settings.reach_px * STEPS_PER_PX).round() as i64;
    let t: Vec<f32> = (-n..=n).map(|k| k as f32 / STEPS_PER_PX).collect();
    let profile: Vec<f64> = t
        .iter()
        .map(|&t| bilinear(photo, at + t * normal).map(luminance))
        .collect::<Option<_>>()?;
    let level = profile.iter().sum::<f64>() / profile.len() as f64 + dark;
    let v: Vec<f64> = profile.iter().map(|p| p / level).collect();
    let mean = v.iter().sum::<f64>() / v.len() as f64;
    let variance: f64 = v.iter().map(|x| (x - mean).powi(2)).sum();
    if variance <= 0.0 {
        return None;
    }
    let phi = |x: f32| 0.5 * (1.0 + erf((x as f64) / std::f64::consts::SQRT_2));
    let places = (settings.place_px * STEPS_PER_PX) as i64;
    // Per width: the least residual over the places, and the step's height there.
    let fitted: Vec<(f64, f64)> = widths
        .iter()
        .map(|&s| {
            (-places..=places)
                .filter_map(|k| {
                    let t0 = k as f32 / STEPS_PER_PX;
                    let shape: Vec<f64> = t.iter().map(|&t| phi((t - t0) / s)).collect();
                    let m = shape.iter().sum::<f64>() / shape.len() as f64;
                    let sxx: f64 = shape.iter().map(|x| (x - m).powi(2)).sum();
                    let sxy: f64 = shape.iter().zip(&v).map(|(x, y)| (x - m) * (y - mean)).sum();
                    (sxx > 0.0).then(|| ((variance - sxy * sxy / sxx) / variance, sxy / sxx))
                })
                .min_by(|a, b| a.0.total_cmp(&b.0))
                .unwrap_or((1.0, 0.0))
        })
        .collect();
    let (residual, height) = fitted.iter().copied().min_by(|a, b| a.0.total_cmp(&b.0))?;
    (height.abs() >= settings.min_contrast && residual <= settings.max_residual)
        .then(|| fitted.into_iter().map(|(r, _)| r).collect())
}

/// The photo at pixel coordinates `p` (x right, y down), bilinear between
/// pixel centres; None beyond the outermost centres.
fn bilinear(photo: &Photo, p: Vec2) -> Option<[f64; 3]> {
    let (w, h) = (photo.image.width, photo.image.height);
    let (x, y) = (p.x - 0.5, p.y - 0.5);
    if w < 2 || h < 2 || !(x >= 0.0 && y >= 0.0 && x < (w - 1) as f32 && y < (h - 1) as f32) {
        return None;
    }
    let (i, j) = (x as usize, y as usize);
    let (fx, fy) = ((x - i as f32) as f64, (y - j as f32) as f64);
    let at = |i: usize, j: usize| photo.image.pixels[j * w + i].map(|v| v as f64);
    let (a, b, c, d) = (at(i, j), at(i + 1, j), at(i, j + 1), at(i + 1, j + 1));
    Some(std::array::from_fn(|k| {
        (1.0 - fy) * ((1.0 - fx) * a[k] + fx * b[k]) + fy * ((1.0 - fx) * c[k] + fx * d[k])
    }))
}

/// The error function (Abramowitz and Stegun 7.1.26, within 1.5e-7).
fn erf(x: f64) -> f64 {
    let t = 1.0 / (1.0 + 0.327_591_1 * x.abs());
    let poly =
        t * (0.254_829_592 + t * (-0.284_496_736 + t * (1.421_413_741 + t * (-1.453_152_027 + t * 1.061_405_429))));
    (1.0 - poly * (-x * x).exp()).copysign(x)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::estimate::settings::Settings;
    use crate::estimate::testing::can_in_the_courtyard;
    use crate::study::perturb::blurred;
    use glam::Vec3;

    #[test]
    fn a_blurred_photo_s_blur_is_found_on_the_probe_s_edges_and_a_sharp_one_s_is_none() {
        let (_, _, sharp) = can_in_the_courtyard(240, 180, Vec3::new(0.0, 0.12, 0.32));
        let settings = Settings::default().photo.blur;
        let found = |photo: &Photo| photo_blur(photo, &settings).expect("a blur");
        let none = found(&sharp);
        assert!(
            none.edges >= settings.min_edges && none.blur_px < settings.min_blur_px,
            "{none:?}"
        );
        for sigma in [1.0, 1.5] {
            let estimate = found(&blurred(&sharp, sigma).expect("blurred"));
            assert!((estimate.blur_px - sigma).abs() < 0.4, "blur {sigma}: {estimate:?}");
        }
    }
}
