//! `L_rgb`: L1 between the rendered and the photographed radiance at the
//! probe's pixels (inside the mask). In HDR a plain L1 is dominated by the
//! few highlight pixels, so the variants compress the range first.

use autodiff::Var;
use render::colour::luminance;
use render::image_io::{Mask, RgbImage};
use serde::Deserialize;

use super::{Input, Term, TermContext};
use crate::error::{Error, Result};

/// The photo's mean luminance inside its mask: the `level` of
/// [`ImageTerms`](super::ImageTerms). Fails when the sizes differ or the
/// mask is empty.
pub fn mask_mean_luminance(image: &RgbImage, mask: &Mask) -> Result<f64> {
    if (image.width, image.height) != (mask.width, mask.height) {
        return Err(Error::invalid(
            "mask",
            format!(
                "is {}x{} but the image is {}x{}",
                mask.width, mask.height, image.width, image.height
            ),
        ));
    }
    if mask.count() == 0 {
        return Err(Error::invalid("mask", "is empty: no pixel marks the probe"));
    }
    let sum: f64 = image
        .pixels
        .iter()
        .zip(&mask.inside)
        .filter(|(_, m)| **m)
        .map(|(p, _)| luminance(p.map(|c| c as f64)))
        .sum();
    Ok(sum / mask.count() as f64)
}

/// The HDR regularisation constant of the relative and log variants, as a
/// fraction of the photo's level: errors of pixels darker than this are
/// not amplified further (noise).
pub const DARK_FRACTION: f64 = 0.05;

/// How the rendered and photographed radiance are compared.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum RgbVariant {
    /// `|r - t| / (lum(t) + eps)`: each pixel's error relative to its own
    /// brightness (the estimate's choice), eps = 0.05 level.
    Relative,
    /// `|r - t| / level`: the paper's L1, in units of the photo's level.
    Plain,
    /// `|ln(eps + r) - ln(eps + t)|`, eps = 0.05 level: the relative L1
    /// integrated (its first-order expansion about t), symmetric in over-
    /// and under-estimates.
    Log,
    /// `|m(r) - m(t)|` with `m(x) = x / (level + x)` (Reinhard): bounded, so
    /// a highlight counts at most as much as a saturated pixel.
    Tonemapped,
}

/// L1 on RGB inside the mask: `sum_p s_p sum_c |f(r) - f(t)| / (3 sum_p s_p)`
/// with `f` and the pixel scale `s_p` (the data weight, divided by the
/// pixel's brightness for the relative variant) from the [`RgbVariant`].
///
/// Applies when the phase renders ([`TermContext::image`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct RgbL1 {
    variant: RgbVariant,
}

impl RgbL1 {
    /// The L1 of `variant`.
    pub fn new(variant: RgbVariant) -> Self {
        RgbL1 { variant }
    }

    /// Relative L1 (the estimate's data term).
    pub fn relative() -> Self {
        Self::new(RgbVariant::Relative)
    }

    /// L1 of log radiance.
    pub fn log() -> Self {
        Self::new(RgbVariant::Log)
    }

    /// The variant.
    pub fn variant(&self) -> RgbVariant {
        self.variant
    }

    /// `f` of the variant on the tape.
    fn compress<'t>(&self, x: Var<'t, f64>, level: f64) -> Var<'t, f64> {
        match self.variant {
            RgbVariant::Relative => x,
            RgbVariant::Plain => x * (1.0 / level),
            RgbVariant::Log => (x + DARK_FRACTION * level).ln(),
            RgbVariant::Tonemapped => x / (x + level),
        }
    }
}

impl Term for RgbL1 {
    fn name(&self) -> &str {
        match self.variant {
            RgbVariant::Relative => "rgb_l1",
            RgbVariant::Plain => "rgb_l1_plain",
            RgbVariant::Log => "rgb_l1_log",
            RgbVariant::Tonemapped => "rgb_l1_tonemapped",
        }
    }

    fn reads(&self) -> &'static [Input] {
        &[Input::Image]
    }

    fn evaluate<'t>(&self, ctx: &TermContext<'_, 't>) -> Result<Option<Var<'t, f64>>> {
        let Some(image) = &ctx.image else { return Ok(None) };
        let (tape, level, target) = (ctx.tape, image.level(), image.target());
        let eps = DARK_FRACTION * level;
        let scale: Vec<f64> = match self.variant {
            RgbVariant::Relative => image
                .weight()
                .iter()
                .zip(target)
                .map(|(w, t)| w / (luminance(*t) + eps))
                .collect(),
            _ => image.weight().to_vec(),
        };
        // No usable pixel: nothing to compare (the mask terms pull the probe back).
        let scale_sum: f64 = scale.iter().sum::<f64>().max(1e-30);
        let scale = tape.constant(&scale);
        let rendered = image.rendered();
        let per_channel = (0..3).map(|c| {
            let t: Vec<f64> = target.iter().map(|t| t[c]).collect();
            let error = self.compress(rendered[c], level) - self.compress(tape.constant(&t), level);
            (error.abs() * scale).sum()
        });
        let sum = per_channel.reduce(|a, b| a + b).expect("three channels");
        Ok(Some(sum * (1.0 / (3.0 * scale_sum))))
    }
}
