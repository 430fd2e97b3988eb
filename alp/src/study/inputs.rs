//! The inputs people have: a scene's photo and mask as a person brings
//! them rather than as a renderer's coverage makes them -- a mask traced by
//! hand, a segmenter's mask, a soft photo, an 8-bit JPEG, a box drawn round
//! the probe. Each is drawn per scene from a seed ([`draw`]) and written
//! beside the scene's own files ([`write()`], `alp synth inputs`), so that the
//! benchmark runs the estimate on them as on the exact ones.

use std::path::Path;

use render::image_io::{Mask, RgbImage};
use render::sampling::Rng;
use serde::Serialize;

use super::perturb;
use crate::error::{Error, Result};
use crate::estimate::Photo;
use crate::output::write_files_atomically;

/// The mask traced by hand.
pub const TRACED_MASK: &str = "mask_traced.png";
/// The mask a segmenter gives.
pub const SEGMENTER_MASK: &str = "mask_segmenter.png";
/// The photo blurred.
pub const BLURRED_IMAGE: &str = "image_blur.exr";
/// The photo as an 8-bit sRGB JPEG.
pub const JPEG_IMAGE: &str = "image.jpg";
/// The box round the probe, `x0,y0,x1,y1` (`alp estimate --box`).
pub const BOX: &str = "box.txt";
/// What was drawn ([`Draws`]); written last: its presence means the rest is there.
pub const DRAWS: &str = "inputs.json";

/// How far a traced outline strays, pixels either way.
pub const TRACE_REACH_PX: f32 = 2.0;
/// The blur's standard deviation is drawn from this range, pixels.
pub const BLUR_PX: [f32; 2] = [0.5, 2.0];
/// The JPEG's quality is drawn from this range.
pub const JPEG_QUALITY: [u8; 2] = [80, 95];
/// The share of the probe's pixels the JPEG's exposure clips is drawn from this range.
pub const JPEG_CLIP_SHARE: [f32; 2] = [0.005, 0.03];
/// Each side of the box lies this far outside the probe, pixels (drawn per side).
pub const BOX_MARGIN_PX: [f32; 2] = [2.0, 10.0];

/// What was drawn for a scene (`inputs.json`).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Draws {
    /// The seed everything was drawn from.
    pub seed: u64,
    /// The traced outline's largest offset either way, pixels.
    pub trace_reach_px: f32,
    /// The blur's standard deviation, pixels.
    pub blur_px: f32,
    /// The JPEG's quality.
    pub jpeg_quality: u8,
    /// The share of the probe's pixels its exposure brings to white.
    pub jpeg_clip_share: f32,
    /// The box's margins round the probe (left, top, right, bottom), pixels.
    pub box_margins_px: [f32; 4],
    /// The box, `[x0, y0, x1, y1]`.
    pub probe_box: [u32; 4],
}

/// A scene's inputs as people have them.
pub struct PeopleInputs {
    /// What was drawn.
    pub draws: Draws,
    /// The mask traced by hand.
    pub traced: Mask,
    /// The segmenter's mask.
    pub segmenter: Mask,
    /// The photo blurred.
    pub blurred: RgbImage,
    /// The photo's JPEG file.
    pub jpeg: Vec<u8>,
}

/// The inputs people would have of `photo` (its mask exact), drawn from `seed`.
pub fn draw(photo: &Photo, seed: u64) -> Result<PeopleInputs> {
    let mut rng = Rng::new(seed, 0x1a9e);
    let mut uniform = |range: [f32; 2]| range[0] + (range[1] - range[0]) * rng.next_f32();
    let blur_px = uniform(BLUR_PX);
    let jpeg_quality = uniform([JPEG_QUALITY[0] as f32, JPEG_QUALITY[1] as f32 + 1.0]).floor() as u8;
    let jpeg_clip_share = uniform(JPEG_CLIP_SHARE);
    let box_margins_px = [(); 4].map(|_| uniform(BOX_MARGIN_PX));
    let probe_box = perturb::probe_box(&photo.mask, box_margins_px)
        .ok_or_else(|| Error::invalid("mask", "is empty: no probe to draw inputs round"))?;
    let traced = perturb::mask_traced(photo, TRACE_REACH_PX, seed)?.mask;
    let segmenter = perturb::mask_segmented(photo)?.mask;
    let blurred = perturb::blurred(photo, blur_px)?.image;
    let (_, jpeg) = perturb::jpeg(photo, jpeg_quality.min(JPEG_QUALITY[1]), jpeg_clip_share as f64)?;
    Ok(PeopleInputs {
        draws: Draws {
            seed,
            trace_reach_px: TRACE_REACH_PX,
            blur_px,
            jpeg_quality: jpeg_quality.min(JPEG_QUALITY[1]),
            jpeg_clip_share,
            box_margins_px,
            probe_box,
        },
        traced,
        segmenter,
        blurred,
        jpeg,
    })
}

/// Writes `inputs` into the scene folder `dir`, all files or none.
pub fn write(dir: &Path, inputs: &PeopleInputs) -> Result<()> {
    let [x0, y0, x1, y1] = inputs.draws.probe_box;
    let draws = serde_json::to_string_pretty(&inputs.draws)
        .map_err(|e| render::RenderError::io(dir.join(DRAWS), "serialise", e))?;
    let text = |path: &Path, contents: String| {
        std::fs::write(path, contents).map_err(|e| render::RenderError::io(path, "write", e).into())
    };
    let (traced, segmenter, blurred, jpeg, boxed, drawn) = (
        dir.join(TRACED_MASK),
        dir.join(SEGMENTER_MASK),
        dir.join(BLURRED_IMAGE),
        dir.join(JPEG_IMAGE),
        dir.join(BOX),
        dir.join(DRAWS),
    );
    write_files_atomically(vec![
        (&traced, Box::new(|p| Ok(inputs.traced.write_png(p)?))),
        (&segmenter, Box::new(|p| Ok(inputs.segmenter.write_png(p)?))),
        (&blurred, Box::new(|p| Ok(inputs.blurred.write_exr(p)?))),
        (&jpeg, Box::new(|p| write_bytes(p, &inputs.jpeg))),
        (&boxed, Box::new(|p| text(p, format!("{x0},{y0},{x1},{y1}\n")))),
        (&drawn, Box::new(|p| text(p, draws + "\n"))),
    ])
}

fn write_bytes(path: &Path, bytes: &[u8]) -> Result<()> {
    std::fs::write(path, bytes).map_err(|e| render::RenderError::io(path, "write", e).into())
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Vec3;
    use render::camera::Camera;

    /// A 48x40 photo of a lit disk of radius 10 in its mask.
    fn testing_photo() -> Photo {
        let (w, h) = (48, 40);
        let disk = |p: usize| ((p % w) as f32 - 20.0).hypot((p / w) as f32 - 18.0) < 10.0;
        let pixels = (0..w * h)
            .map(|p| match disk(p) {
                true => [1.0 + (p % 5) as f32, 2.0, 0.5],
                false => [0.2, 0.1, 0.1],
            })
            .collect();
        let camera = Camera::new(w as u32, h as u32, 40.0, Vec3::Z, Vec3::ZERO, Vec3::Y).expect("camera");
        let mask = Mask::new(w, h, (0..w * h).map(disk).collect());
        Photo::new(RgbImage::new(w, h, pixels), mask, camera).expect("photo")
    }

    #[test]
    fn the_draws_stay_in_their_ranges_and_the_same_seed_draws_the_same() {
        let photo = testing_photo();
        let a = draw(&photo, 5).expect("inputs");
        let b = draw(&photo, 5).expect("inputs");
        assert_eq!(a.draws, b.draws);
        assert_eq!(a.traced, b.traced);
        let d = &a.draws;
        assert!((BLUR_PX[0]..=BLUR_PX[1]).contains(&d.blur_px));
        assert!((JPEG_QUALITY[0]..=JPEG_QUALITY[1]).contains(&d.jpeg_quality));
        assert!(
            d.box_margins_px
                .iter()
                .all(|m| (BOX_MARGIN_PX[0]..=BOX_MARGIN_PX[1]).contains(m))
        );
        assert_ne!(draw(&photo, 6).expect("inputs").draws, a.draws);
    }
}
