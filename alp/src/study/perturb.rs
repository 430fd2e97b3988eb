//! What breaks methods, done to a photo at a given strength (`alp study
//! stability`): a mask a few pixels off, sensor noise, clipped highlights, a
//! wrong exposure, a probe cut by the border, a small probe, blur, a JPEG,
//! a box in place of the mask.

use render::camera::Camera;
use render::image_io::{Mask, PhotoEncoding, RgbImage};
use render::sampling::Rng;
use render::silhouette::distance_transform;

use crate::error::{Error, Result};
use crate::estimate::Photo;
use crate::estimate::probe_box::{ProbeBox, mask_in_box};
use crate::estimate::settings::BoxSettings;
use crate::synth::standard_normal;

/// The photo's mask grown (`pixels` > 0) or shrunk (< 0) by a disk of that radius.
pub fn mask_grown(photo: &Photo, pixels: i32) -> Result<Photo> {
    let offset = pixels as f32;
    with_mask(photo, outline_moved(&photo.mask, |_| offset))
}

/// The photo's mask as a person traces it: each stretch of its outline
/// moved out (> 0) or in by up to `reach` pixels (a pixel changes sides
/// when its centre is within the offset of the outline), the offset varying
/// smoothly along the outline, sector by sector: a random field over the
/// image, uniform in [-reach, reach] at knots a third of the probe's extent
/// apart, bilinear between them, from `seed`.
pub fn mask_traced(photo: &Photo, reach: f32, seed: u64) -> Result<Photo> {
    let mask = &photo.mask;
    let Some([x0, y0, x1, y1]) = bounding_box(mask) else {
        return Err(Error::invalid("mask", "is empty: there is no outline to trace"));
    };
    let spacing = ((x1 - x0).max(y1 - y0) as f32 / 3.0).max(2.0);
    let (cols, rows) = (
        ((x1 - x0) as f32 / spacing).ceil() as usize + 2,
        ((y1 - y0) as f32 / spacing).ceil() as usize + 2,
    );
    let mut rng = Rng::new(seed, 0x7ace);
    let knots: Vec<f32> = (0..cols * rows).map(|_| reach * (2.0 * rng.next_f32() - 1.0)).collect();
    // Knots start a spacing before the box, so every pixel near the
    // outline lies between four of them.
    let origin = (x0 as f32 - spacing, y0 as f32 - spacing);
    let field = |p: usize| {
        let gx = (((p % mask.width) as f32 - origin.0) / spacing).clamp(0.0, (cols - 1) as f32 - 1e-3);
        let gy = (((p / mask.width) as f32 - origin.1) / spacing).clamp(0.0, (rows - 1) as f32 - 1e-3);
        let (i, j) = (gx as usize, gy as usize);
        let (fx, fy) = (gx - i as f32, gy - j as f32);
        let at = |i: usize, j: usize| knots[j * cols + i];
        (1.0 - fy) * ((1.0 - fx) * at(i, j) + fx * at(i + 1, j))
            + fy * ((1.0 - fx) * at(i, j + 1) + fx * at(i + 1, j + 1))
    };
    // The outline lies half a pixel beyond the centres of the mask's edge
    // pixels: moved by `o`, it takes in the centres within `o + 1/2` of them.
    let field = |p: usize| {
        let o = field(p);
        o + 0.5 * o.signum()
    };
    with_mask(photo, outline_moved(mask, field))
}

/// Radius (pixels) of the disk a segmenter's mask is opened by: how much
/// of a corner it rounds off.
const SEGMENTER_ROUNDING_PX: f32 = 3.0;

/// The photo's mask as a segmenter gives it: grown by a pixel and its
/// corners rounded (opened by a disk of `SEGMENTER_ROUNDING_PX`).
pub fn mask_segmented(photo: &Photo) -> Result<Photo> {
    let grown = outline_moved(&photo.mask, |_| 1.0);
    let eroded = outline_moved(&grown, |_| -SEGMENTER_ROUNDING_PX);
    with_mask(photo, outline_moved(&eroded, |_| SEGMENTER_ROUNDING_PX))
}

/// The photo written as an 8-bit sRGB JPEG of `quality`, exposed so that
/// `clip_share` of the probe's pixels (by their brightest channel) reach
/// white, and read back: the photo as the estimate then sees it (linear, in
/// [0, 1]) and the file's bytes.
pub fn jpeg(photo: &Photo, quality: u8, clip_share: f64) -> Result<(Photo, Vec<u8>)> {
    let level = brightest_share_level(photo, clip_share)?;
    let bytes = photo.image.encode_jpeg(1.0 / level, quality)?;
    let image = RgbImage::decode_jpeg(&bytes)?;
    let decoded = Photo::new(image, photo.mask.clone(), photo.camera)?;
    Ok((decoded.with_encoding(PhotoEncoding::Srgb { bits: 8 }), bytes))
}

/// The box a person draws round the probe: its mask's bounding box
/// (`[x0, y0, x1, y1]`, pixel edges, x1 and y1 past the last pixel) grown by
/// `margins` pixels (left, top, right, bottom), within the image. None for
/// an empty mask.
pub fn probe_box(mask: &Mask, margins: [f32; 4]) -> Option<[u32; 4]> {
    let [x0, y0, x1, y1] = bounding_box(mask)?;
    let grow = |v: usize, by: f32, limit: usize| (v as f32 + by).round().clamp(0.0, limit as f32) as u32;
    Some([
        grow(x0, -margins[0], mask.width),
        grow(y0, -margins[1], mask.height),
        grow(x1 + 1, margins[2], mask.width),
        grow(y1 + 1, margins[3], mask.height),
    ])
}

/// The photo with the mask `alp estimate --box` finds in its probe's box
/// grown by `margin` pixels each way (`estimate::probe_box`).
pub fn boxed(photo: &Photo, margin: f32, settings: &BoxSettings) -> Result<Photo> {
    let corners = probe_box(&photo.mask, [margin; 4])
        .ok_or_else(|| Error::invalid("mask", "is empty: there is no probe to draw a box round"))?;
    let probe_box = ProbeBox::new(corners.map(|c| c as usize), photo.mask.width, photo.mask.height)?;
    let found = mask_in_box(&photo.image, &probe_box, settings)?;
    with_mask(photo, found)
}

/// The first and last columns and rows the mask marks, `[x0, y0, x1, y1]`.
fn bounding_box(mask: &Mask) -> Option<[usize; 4]> {
    let w = mask.width;
    let marked = || (0..mask.inside.len()).filter(|&p| mask.inside[p]);
    let (x0, x1) = (marked().map(|p| p % w).min()?, marked().map(|p| p % w).max()?);
    let (y0, y1) = (marked().map(|p| p / w).min()?, marked().map(|p| p / w).max()?);
    Some([x0, y0, x1, y1])
}

/// The mask's outline moved out by `offset(pixel)` pixels where it is
/// positive (a pixel joins when an inside pixel's centre is within that
/// distance: dilation by a disk) and in where it is negative (a pixel
/// leaves when an outside pixel's centre, or the image's border beyond it,
/// is within that distance: erosion by a disk).
fn outline_moved(mask: &Mask, offset: impl Fn(usize) -> f32) -> Mask {
    let (w, h) = (mask.width, mask.height);
    let to_inside = distance_transform(&mask.inside, w, h);
    let outside: Vec<bool> = mask.inside.iter().map(|&m| !m).collect();
    let to_outside = distance_transform(&outside, w, h);
    let inside = (0..w * h)
        .map(|p| {
            let (x, y) = (p % w, p / w);
            let to_border = (x + 1).min(y + 1).min(w - x).min(h - y) as f32;
            let d = offset(p);
            match mask.inside[p] {
                true => d >= 0.0 || to_outside[p].min(to_border) > -d,
                false => d > 0.0 && to_inside[p] <= d,
            }
        })
        .collect();
    Mask::new(w, h, inside)
}

/// The photo with another mask.
fn with_mask(photo: &Photo, mask: Mask) -> Result<Photo> {
    photo.clone().with_mask(mask)
}

/// Multiplicative Gaussian noise of relative spread `sigma` on every
/// channel (floored at 0), from `seed`.
pub fn noisy(photo: &Photo, sigma: f32, seed: u64) -> Result<Photo> {
    let mut image = photo.image.clone();
    for (p, rgb) in image.pixels.iter_mut().enumerate() {
        let mut rng = Rng::new(seed, p as u64);
        for v in rgb.iter_mut() {
            *v *= (1.0 + sigma * standard_normal(&mut rng)).max(0.0);
        }
    }
    Photo::new(image, photo.mask.clone(), photo.camera)
}

/// The photo clipped at the level that saturates `share` of the probe's
/// pixels (by their brightest channel), as a sensor clips highlights.
pub fn clipped(photo: &Photo, share: f64) -> Result<Photo> {
    let level = brightest_share_level(photo, share)?;
    let mut image = photo.image.clone();
    image.pixels.iter_mut().flatten().for_each(|v| *v = v.min(level));
    Photo::new(image, photo.mask.clone(), photo.camera)
}

/// The level that `share` of the probe's pixels reach or pass, by their
/// brightest channel.
fn brightest_share_level(photo: &Photo, share: f64) -> Result<f32> {
    let mut peaks: Vec<f32> = photo
        .image
        .pixels
        .iter()
        .zip(&photo.mask.inside)
        .filter(|(_, inside)| **inside)
        .map(|(p, _)| p[0].max(p[1]).max(p[2]))
        .collect();
    peaks.sort_by(f32::total_cmp);
    let k = ((1.0 - share) * peaks.len() as f64).floor() as usize;
    match peaks.get(k.min(peaks.len().saturating_sub(1))) {
        Some(&level) if level > 0.0 => Ok(level),
        _ => Err(Error::invalid(
            "photo",
            "the probe's pixels are black: nothing to expose for",
        )),
    }
}

/// The photo's radiance times `scale` (a wrong exposure).
pub fn exposed(photo: &Photo, scale: f32) -> Result<Photo> {
    let mut image = photo.image.clone();
    image.pixels.iter_mut().flatten().for_each(|v| *v *= scale);
    Photo::new(image, photo.mask.clone(), photo.camera)
}

/// The photo cropped evenly from its four sides (keeping its aspect and
/// its camera's centre of projection) until `share` of the mask's pixels
/// lie outside: the probe cut by the border. An error when the photo
/// cannot be cut so (no crop leaves that share, or nothing is left).
pub fn cut_by_border(photo: &Photo, share: f64) -> Result<Photo> {
    let (w, h) = (photo.camera.width as usize, photo.camera.height as usize);
    let total = photo.mask.count();
    let kept = |mx: usize, my: usize| -> usize {
        (my..h - my)
            .map(|y| (mx..w - mx).filter(|&x| photo.mask.inside[y * w + x]).count())
            .sum()
    };
    let margins = |mx: usize| (mx, (mx as f64 * h as f64 / w as f64).round() as usize);
    let target = ((1.0 - share) * total as f64).round() as usize;
    // The least margin that leaves at most the target.
    let found = (1..w / 2)
        .map(margins)
        .find(|&(mx, my)| 2 * my < h && kept(mx, my) <= target);
    let Some((mx, my)) = found.filter(|&(mx, my)| w - 2 * mx >= 8 && h - 2 * my >= 8) else {
        return Err(Error::invalid(
            "border",
            format!("no even crop of the {w}x{h} photo cuts {share} of its mask"),
        ));
    };
    let (cw, ch) = (w - 2 * mx, h - 2 * my);
    let mut pixels = Vec::with_capacity(cw * ch);
    let mut inside = Vec::with_capacity(cw * ch);
    for y in my..h - my {
        pixels.extend_from_slice(&photo.image.pixels[y * w + mx..y * w + w - mx]);
        inside.extend_from_slice(&photo.mask.inside[y * w + mx..y * w + w - mx]);
    }
    let half = (photo.camera.fov_y_deg.to_radians() * 0.5).tan() * ch as f32 / h as f32;
    let c = &photo.camera;
    let camera = Camera::new(
        cw as u32,
        ch as u32,
        2.0 * half.atan().to_degrees(),
        c.origin,
        c.target,
        c.up,
    )?;
    Photo::new(RgbImage::new(cw, ch, pixels), Mask::new(cw, ch, inside), camera)
}

/// The photo box-filtered until its mask is at most `rows` pixels tall; an
/// error when it already is (the photo would be the one as it is).
pub fn small(photo: &Photo, rows: usize) -> Result<Photo> {
    let w = photo.mask.width;
    let marked: Vec<usize> = (0..photo.mask.height)
        .filter(|y| photo.mask.inside[y * w..(y + 1) * w].contains(&true))
        .collect();
    let tall = marked.last().map_or(0, |last| last + 1 - marked[0]);
    if tall <= rows {
        return Err(Error::invalid(
            "small",
            format!("the probe is {tall} px tall already, not more than {rows}"),
        ));
    }
    let no_clip = vec![false; photo.image.pixels.len()];
    Ok(photo.downsampled(tall as f64 / rows as f64, &no_clip)?.0)
}

/// The photo blurred by a Gaussian pixel filter of `sigma` pixels (the
/// mask as it was).
pub fn blurred(photo: &Photo, sigma: f32) -> Result<Photo> {
    let (w, h) = (photo.image.width, photo.image.height);
    let radius = (3.0 * sigma).ceil() as i64;
    let kernel: Vec<f32> = (-radius..=radius)
        .map(|d| (-(d * d) as f32 / (2.0 * sigma * sigma)).exp())
        .collect();
    let pass = |src: &[[f32; 3]], along_x: bool| -> Vec<[f32; 3]> {
        (0..w * h)
            .map(|p| {
                let (x, y) = ((p % w) as i64, (p / w) as i64);
                let (mut sum, mut norm) = ([0.0f32; 3], 0.0f32);
                for (k, d) in (-radius..=radius).enumerate() {
                    let (xx, yy) = if along_x { (x + d, y) } else { (x, y + d) };
                    if xx < 0 || yy < 0 || xx >= w as i64 || yy >= h as i64 {
                        continue;
                    }
                    let v = src[yy as usize * w + xx as usize];
                    (0..3).for_each(|c| sum[c] += kernel[k] * v[c]);
                    norm += kernel[k];
                }
                sum.map(|s| s / norm)
            })
            .collect()
    };
    let pixels = pass(&pass(&photo.image.pixels, true), false);
    Photo::new(RgbImage::new(w, h, pixels), photo.mask.clone(), photo.camera)
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Vec3;

    /// A 40x30 photo: a 10x10 bright square at (x 5..15, y 10..20) in the mask.
    fn photo() -> Photo {
        let (w, h) = (40, 30);
        let square = |p: usize| (5..15).contains(&(p % w)) && (10..20).contains(&(p / w));
        let pixels = (0..w * h)
            .map(|p| {
                if square(p) {
                    [1.0 + (p % 7) as f32, 2.0, 3.0]
                } else {
                    [0.1; 3]
                }
            })
            .collect();
        let mask = Mask::new(w, h, (0..w * h).map(square).collect());
        let camera =
            Camera::new(w as u32, h as u32, 40.0, Vec3::new(0.0, 0.0, 1.0), Vec3::ZERO, Vec3::Y).expect("camera");
        Photo::new(RgbImage::new(w, h, pixels), mask, camera).expect("photo")
    }

    #[test]
    fn the_mask_grows_and_shrinks_by_a_disk() {
        let p = photo();
        assert_eq!(mask_grown(&p, 1).expect("grown").mask.count(), 100 + 4 * 10);
        assert_eq!(mask_grown(&p, -1).expect("shrunk").mask.count(), 64);
        assert_eq!(mask_grown(&p, -2).expect("shrunk").mask.count(), 36);
    }

    #[test]
    fn a_traced_mask_strays_both_ways_within_its_reach_and_only_near_the_outline() {
        let p = photo();
        let to_edge = |q: usize| {
            let (x, y) = ((q % 40) as f32 + 0.5, (q / 40) as f32 + 0.5);
            let (dx, dy) = ((5.0 - x).max(x - 15.0), (10.0 - y).max(y - 20.0));
            match dx <= 0.0 && dy <= 0.0 {
                true => -dx.max(dy),
                false => dx.max(0.0).hypot(dy.max(0.0)),
            }
        };
        let (mut grown, mut shrunk) = (0, 0);
        for seed in 0..6 {
            let t = mask_traced(&p, 2.0, seed).expect("traced");
            for q in 0..p.mask.inside.len() {
                if t.mask.inside[q] != p.mask.inside[q] {
                    assert!(
                        to_edge(q) <= 2.5,
                        "seed {seed}: pixel {q} changed {} px from the outline",
                        to_edge(q)
                    );
                    match t.mask.inside[q] {
                        true => grown += 1,
                        false => shrunk += 1,
                    }
                }
            }
        }
        assert!(grown > 10 && shrunk > 10, "grown {grown}, shrunk {shrunk}");
        assert_eq!(mask_traced(&p, 0.0, 3).expect("traced").mask, p.mask);
    }

    #[test]
    fn a_segmenter_s_mask_is_a_pixel_wider_with_its_corners_rounded() {
        let p = photo();
        let s = mask_segmented(&p).expect("segmented");
        let at = |x: usize, y: usize| s.mask.inside[y * 40 + x];
        // The square's sides moved out a pixel; its corners cut.
        assert!(at(4, 15) && at(15, 15) && at(10, 9) && at(10, 20));
        assert!(!at(3, 15) && !at(4, 9) && !at(5, 9) && !at(15, 9) && !at(4, 20) && !at(15, 20));
        assert!(s.mask.count() > 100 && s.mask.count() < 144);
    }

    #[test]
    fn a_jpeg_reaches_white_on_the_share_asked_for_and_keeps_the_colours() {
        // A 64x48 photo, its probe a 32x32 square of one colour whose
        // rightmost 8 columns are 4 times as bright.
        let (w, h) = (64, 48);
        let square = |p: usize| (16..48).contains(&(p % w)) && (8..40).contains(&(p / w));
        let pixels = (0..w * h)
            .map(|p| match (square(p), p % w >= 40) {
                (true, false) => [1.0, 0.5, 0.125],
                (true, true) => [4.0, 2.0, 0.5],
                _ => [0.1; 3],
            })
            .collect();
        let camera = Camera::new(w as u32, h as u32, 40.0, Vec3::Z, Vec3::ZERO, Vec3::Y).expect("camera");
        let p = Photo::new(
            RgbImage::new(w, h, pixels),
            Mask::new(w, h, (0..w * h).map(square).collect()),
            camera,
        )
        .expect("photo");
        let (j, bytes) = jpeg(&p, 92, 0.2).expect("jpeg");
        assert_eq!(&bytes[..2], &[0xff, 0xd8], "a JPEG file");
        assert!(j.image.pixels.iter().flatten().all(|v| (0.0..=1.0).contains(v)));
        // The bright quarter at white in red, the rest a quarter of it.
        let at = |x: usize, y: usize| j.image.pixels[y * w + x];
        assert!(
            at(44, 24)[0] > 0.95 && (at(44, 24)[1] - 0.5).abs() < 0.05,
            "{:?}",
            at(44, 24)
        );
        let dim = at(28, 24);
        assert!(
            (dim[0] - 0.25).abs() < 0.03 && (dim[1] / dim[2] - 4.0).abs() < 0.6,
            "{dim:?}"
        );
    }

    #[test]
    fn the_probe_s_box_has_its_margins_within_the_image() {
        let p = photo();
        assert_eq!(probe_box(&p.mask, [1.0, 2.0, 3.0, 4.0]), Some([4, 8, 18, 24]));
        assert_eq!(probe_box(&p.mask, [10.0, 20.0, 30.0, 20.0]), Some([0, 0, 40, 30]));
        assert_eq!(probe_box(&Mask::new(4, 4, vec![false; 16]), [1.0; 4]), None);
    }

    #[test]
    fn a_box_round_the_square_finds_the_square() {
        let p = photo();
        let settings = crate::estimate::settings::Settings::default().photo.probe_box;
        assert_eq!(boxed(&p, 3.0, &settings).expect("boxed").mask, p.mask);
    }

    #[test]
    fn clipping_saturates_the_share_asked_for() {
        let c = clipped(&photo(), 0.2).expect("clipped");
        let top = c.image.pixels.iter().map(|p| p[0]).fold(0.0f32, f32::max);
        let at_top = c
            .image
            .pixels
            .iter()
            .zip(&c.mask.inside)
            .filter(|(p, i)| **i && p[0] == top)
            .count();
        assert!((20..=30).contains(&at_top), "{at_top} of 100 pixels at the clip");
    }

    #[test]
    fn a_border_cut_leaves_the_rest_of_the_mask_and_keeps_the_view() {
        let p = photo();
        let c = cut_by_border(&p, 0.3).expect("cut");
        let share = 1.0 - c.mask.count() as f64 / p.mask.count() as f64;
        assert!((0.3..0.45).contains(&share), "cut {share}");
        assert!(c.camera.width < 40 && c.camera.fov_y_deg < 40.0);
        // The crop is centred: the photo's centre ray is unchanged.
        assert_eq!((c.camera.origin, c.camera.target), (p.camera.origin, p.camera.target));
        assert!(cut_by_border(&p, 1.0).is_err());
    }

    #[test]
    fn small_blur_noise_and_exposure_do_what_they_say() {
        let p = photo();
        let s = small(&p, 5).expect("small");
        assert!(s.mask.height < 20 && s.mask.count() > 0 && s.mask.count() <= 36);
        assert!(small(&p, 10).is_err(), "10 px tall already");
        let b = blurred(&p, 1.0).expect("blurred");
        let total = |q: &Photo| q.image.pixels.iter().map(|v| v[1] as f64).sum::<f64>();
        assert!((total(&b) - total(&p)).abs() < 1e-2 * total(&p), "blur keeps the light");
        assert!(b.image.pixels[10 * 40 + 4][1] > 0.1, "and spreads it");
        let n = noisy(&p, 0.1, 3).expect("noisy");
        let spread = n
            .image
            .pixels
            .iter()
            .zip(&p.image.pixels)
            .map(|(a, b)| (a[1] / b[1] - 1.0).powi(2) as f64)
            .sum::<f64>()
            / 1200.0;
        assert!((spread.sqrt() - 0.1).abs() < 0.01, "noise {}", spread.sqrt());
        assert_eq!(exposed(&p, 2.0).expect("exposed").image.pixels[0], [0.2; 3]);
    }
}
