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
//! edge (`SHARP_EDGE_PX`), is the blur's reading.
//!
//! A reading is a guess until the photo checks it: a mirror's limb, or one
//! reflecting large bright panels, reads soft on a sharp photo. So the
//! output map's blur is the photo's choice (`blur_by_photo`): at the
//! found pose the lighting is fitted on half the probe's pixels (a
//! checkerboard) under each candidate blur -- none, and the reading --
//! and judged on the other half, the probe's own rendered edges (its
//! limb, rims, a label's edges) among them. A blurred model explains a
//! sharp photo's edges only by sharpening its map where a map can, and not
//! at all where the edge is the probe's; a sharp model explains a soft
//! photo only by blurring its map, and not at the probe's edges. The blur
//! is kept only if it lowers the held-out error in more blocks of pixels
//! than an even split would by a margin in standard errors (blocks as the
//! unit: neighbouring pixels' errors go together; each pixel's error from
//! two independent renders, free of their Monte Carlo noise). The renders then spread each pixel's rays by it
//! (`Camera::footprint_px`), so that a soft photo is explained rather
//! than fought.

use std::collections::HashMap;

use glam::Vec2;
use render::colour::luminance;
use render::integrator::RenderSettings;
use render::pose::Pose;
use render::sampling::EnvSampler;
use serde::Serialize;

use super::Probe;
use super::lighting::{FitRequest, LightingPurpose, LightingTerms, env_from_texels, fit_lighting, pixel_errors};
use super::outline::outline_points;
use super::photo::{Photo, Pixels};
use super::report::{PhaseReport, resident_mb};
use super::settings::{BlurSettings, LightModel, Settings};
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

/// One blur the lighting was fitted under at the found pose.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct BlurCandidate {
    /// The blur, a Gaussian's standard deviation in the photo's pixels.
    pub blur_px: f32,
    /// The held-out pixels' median weighted squared error (relative, summed
    /// over the channels), over the pixels every candidate read.
    pub held_out_error: f64,
}

/// The photo's choice of blur at the found pose (`blur_by_photo`).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct BlurChoice {
    /// Every blur fitted, none first.
    pub candidates: Vec<BlurCandidate>,
    /// The blur kept, pixels.
    pub blur_px: f32,
    /// The blocks of pixels whose held-out error the reading lowers, over
    /// an even split, in standard errors of a sign test:
    /// `(2 k - n) / sqrt(n)` (positive: the photo prefers the blur; kept
    /// from `BlurSettings::test_margin_se`).
    pub margin_se: f64,
    /// The blocks of pixels (`BlurSettings::test_block_px` a side) the
    /// margin was measured over, n.
    pub blocks: usize,
    /// Those whose error the reading lowers, k.
    pub blocks_for_blur: usize,
}

impl BlurChoice {
    /// The check's account as a phase of the report (`blur_test`), begun
    /// at `started`: each candidate's held-out error and the margin.
    pub(super) fn phase_report(&self, started: std::time::Instant) -> PhaseReport {
        let mut loss: std::collections::BTreeMap<String, f64> = (self.candidates.iter())
            .map(|c| (format!("held_out_error_at_{:.2}_px", c.blur_px), c.held_out_error))
            .collect();
        loss.insert("margin_se".into(), self.margin_se);
        PhaseReport {
            name: "blur_test".into(),
            iterations: 0,
            evaluations: self.candidates.len(),
            wall_s: started.elapsed().as_secs_f64(),
            loss,
            per_iteration: Vec::new(),
            psnr_db: None,
            pose: None,
            termination: None,
            resident_mb: resident_mb(),
        }
    }
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

/// What [`blur_by_photo`] fits at: the probe, the photo as the estimate
/// works on it with a sharp camera (its pixels `factor` of the photo's),
/// its clipped pixels, the found pose, and the pose's map at the searches'
/// size `work` (it guides the light samples and starts each solve).
pub(super) struct BlurTestInput<'a> {
    pub(super) probe: &'a Probe<'a>,
    pub(super) photo: &'a Photo,
    pub(super) factor: f64,
    pub(super) clipped: &'a [bool],
    pub(super) pose: &'a Pose,
    pub(super) map: &'a [f64],
    pub(super) work: (usize, usize),
}

/// The blur the photo chooses between none and `reading_px` (pixels of
/// the photo), see the module's description: the lighting fitted on a
/// checkerboard of the probe's pixels under each, with the pose searches'
/// samples and solve, and judged on the pixels held out.
pub(super) fn blur_by_photo(input: &BlurTestInput, reading_px: f32, settings: &Settings) -> Result<BlurChoice> {
    let lighting = &settings.lighting;
    let terms = LightingTerms::quadratic(lighting.smoothness, lighting.method)?;
    let sampler = EnvSampler::new(&env_from_texels(input.map, input.work.0, input.work.1)?);
    // The bounce off the probe adds little at an edge and costs a third of the tracing.
    let model = LightModel {
        interreflection: false,
        ..lighting.model
    };
    let sampling = model.sampling(Some(&sampler));
    let spp = (lighting.final_spp(
        settings.photo.blur.test_spp,
        input.photo.mask.count(),
        sampling.strategies(),
    ))
    .min(settings.photo.blur.test_spp);
    let errors_under = |blur_px: f32| -> Result<HashMap<u32, f64>> {
        let photo = input.photo.clone().with_blur(blur_px / input.factor as f32)?;
        let fitted_on = FitRequest {
            size: input.work,
            render: RenderSettings {
                spp,
                seed: settings.seed.wrapping_add(81),
            },
            sampling,
            terms: &terms,
            purpose: LightingPurpose::Output,
            pixels: Pixels::Checkerboard,
            start: Some(input.map),
            max_iters: lighting.lean_solve_iters,
            term_values: false,
        };
        let (probe, clipped, pose) = (input.probe, input.clipped, input.pose);
        let fit = fit_lighting(probe, &photo, clipped, pose, &fitted_on, lighting)?;
        let held_out = FitRequest {
            pixels: Pixels::HeldOut,
            ..fitted_on
        };
        let errors = pixel_errors(probe, &photo, clipped, pose, &held_out, &fit.env, lighting)?;
        Ok(errors.into_iter().collect())
    };
    let sharp = errors_under(0.0)?;
    let blurred = errors_under(reading_px)?;
    // Per block of pixels, the held-out error the blur takes away, over
    // the pixels both models read. A pixel's error is heavy-tailed (a
    // highlight a pixel off weighs as a hundred dark ones), so the blocks
    // vote: a sign test, robust to a few pixels that neither model explains.
    let block = settings.photo.blur.test_block_px.max(1) as u32;
    let width = input.photo.camera.width;
    let mut gains: HashMap<u32, f64> = HashMap::new();
    let (mut sharp_errors, mut blurred_errors) = (Vec::new(), Vec::new());
    for (&p, &e0) in &sharp {
        if let Some(&e1) = blurred.get(&p) {
            let key = (p / width) / block * width.div_ceil(block) + (p % width) / block;
            *gains.entry(key).or_default() += e0 - e1;
            sharp_errors.push(e0);
            blurred_errors.push(e1);
        }
    }
    let blocks = gains.len();
    let for_blur = gains.values().filter(|&&g| g > 0.0).count();
    let margin_se = match blocks {
        0 => 0.0,
        n => (2.0 * for_blur as f64 - n as f64) / (n as f64).sqrt(),
    };
    let blur_px = match margin_se >= settings.photo.blur.test_margin_se {
        true => reading_px,
        false => 0.0,
    };
    Ok(BlurChoice {
        candidates: vec![
            BlurCandidate {
                blur_px: 0.0,
                held_out_error: median(sharp_errors),
            },
            BlurCandidate {
                blur_px: reading_px,
                held_out_error: median(blurred_errors),
            },
        ],
        blur_px,
        margin_se,
        blocks,
        blocks_for_blur: for_blur,
    })
}

/// The median of `values` (0 when empty).
fn median(mut values: Vec<f64>) -> f64 {
    values.sort_by(f64::total_cmp);
    match values.len() {
        0 => 0.0,
        n => values[n / 2],
    }
}

/// The edge widths fitted, narrowest first.
fn edge_widths() -> Vec<f32> {
    let (narrowest, factor, widest) = WIDTHS_PX;
    std::iter::successors(Some(narrowest), |s| Some(s * factor))
        .take_while(|&s| s <= widest)
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
    use crate::estimate::testing::{photo_of, probe_of};
    use crate::study::perturb::blurred;
    use glam::{Quat, Vec3};
    use render::camera::Camera;
    use render::envmap::EnvMap;
    use render::pose::Pose;

    #[test]
    fn the_photo_keeps_a_blur_only_where_there_is_one_even_when_its_edges_read_soft() {
        // The can under the studio's large bright panels, whose reflections
        // make its sharp photo's edges read soft.
        let asset = render::procedural::SodaCan::default().build();
        let truth = Pose::new(Quat::from_rotation_y(0.3), 1.0, Vec3::ZERO);
        let camera = Camera::new(
            240,
            180,
            40.0,
            Vec3::new(0.0, 0.12, 0.32),
            Vec3::new(0.0, 0.06, 0.0),
            Vec3::Y,
        )
        .expect("camera");
        let env_path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../assets/envmaps/studio.exr");
        let env = EnvMap::read(env_path).expect("bundled env map").downsample(32);
        let sharp = photo_of(&asset, &truth, camera, &env, 16);
        let probe = probe_of(&asset);
        let settings = Settings::default();
        let work = (64, 32);
        let clipped = vec![false; sharp.camera.pixel_count()];
        // The map the check starts from: the lighting at the pose, without blur.
        let map: Vec<f64> = env
            .downsample(work.1)
            .radiance()
            .iter()
            .flat_map(|t| t.map(|v| v as f64))
            .collect();
        let choose = |photo: &Photo, reading: f32| {
            let input = BlurTestInput {
                probe: &probe,
                photo,
                factor: 1.0,
                clipped: &clipped,
                pose: &truth,
                map: &map,
                work,
            };
            blur_by_photo(&input, reading, &settings).expect("a choice")
        };
        // Read 1.5 px soft, the sharp photo keeps none.
        let choice = choose(&sharp, 1.5);
        assert_eq!(choice.blur_px, 0.0, "{choice:?}");
        // Blurred by 1.5 px, it keeps the blur.
        let soft = blurred(&sharp, 1.5).expect("blurred");
        let choice = choose(&soft, 1.5);
        assert_eq!(choice.blur_px, 1.5, "{choice:?}");
        assert!(choice.margin_se >= settings.photo.blur.test_margin_se);
    }

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
