//! What breaks methods, done to a photo at a given strength (`alp study
//! stability`): a mask a few pixels off, sensor noise, clipped highlights, a
//! wrong exposure, a probe cut by the border, a small probe, blur.

use render::camera::Camera;
use render::image_io::{Mask, RgbImage};
use render::sampling::Rng;

use crate::error::{Error, Result};
use crate::estimate::Photo;
use crate::synth::standard_normal;

/// The photo's mask grown (`pixels` > 0) or shrunk (< 0) by a disk of that radius.
pub fn mask_grown(photo: &Photo, pixels: i32) -> Result<Photo> {
    let (w, h) = (photo.mask.width as i64, photo.mask.height as i64);
    let r = pixels.unsigned_abs() as i64;
    let grow = pixels > 0;
    let inside = &photo.mask.inside;
    let changed: Vec<bool> = (0..w * h)
        .map(|p| {
            let (x, y) = (p % w, p / w);
            // Grown: inside when any pixel within r is; shrunk: when all are
            // (pixels beyond the image count as outside).
            let mut any = false;
            let mut all = true;
            for dy in -r..=r {
                for dx in -r..=r {
                    if dx * dx + dy * dy > r * r {
                        continue;
                    }
                    let (xx, yy) = (x + dx, y + dy);
                    let v = xx >= 0 && yy >= 0 && xx < w && yy < h && inside[(yy * w + xx) as usize];
                    any |= v;
                    all &= v;
                }
            }
            if grow { any } else { all }
        })
        .collect();
    let mask = Mask::new(w as usize, h as usize, changed);
    Photo::new(photo.image.clone(), mask, photo.camera)
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
    let level = peaks[k.min(peaks.len() - 1)];
    let mut image = photo.image.clone();
    image.pixels.iter_mut().flatten().for_each(|v| *v = v.min(level));
    Photo::new(image, photo.mask.clone(), photo.camera)
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
