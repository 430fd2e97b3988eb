//! The photo stage: the HDR image, the probe's mask and the camera, checked
//! to agree; the pixels clipped by the sensor; and the working image, the
//! photo box-filtered when its mask holds more pixels than time and memory
//! allow. Everything after this stage reads the photo through [`Photo`].

use render::camera::Camera;
use render::image_io::{Mask, PhotoEncoding, RgbImage};

use super::settings::PhotoSettings;
use crate::error::{Error, Result};

/// The photo and what is known about it.
#[derive(Clone)]
pub struct Photo {
    /// Linear RGB.
    pub image: RgbImage,
    /// The probe's segmentation.
    pub mask: Mask,
    /// The camera that took it.
    pub camera: Camera,
    /// How its values were stored: linear HDR, or display-referred sRGB
    /// decoded to linear (8-bit values are intervals, white is clipped).
    pub encoding: PhotoEncoding,
}

impl Photo {
    /// Checks that image, mask and camera agree and that the mask is usable.
    pub fn new(image: RgbImage, mask: Mask, camera: Camera) -> Result<Self> {
        let (w, h) = (camera.width as usize, camera.height as usize);
        if (image.width, image.height) != (w, h) {
            return Err(Error::invalid(
                "image",
                format!("is {}x{} but the camera is {w}x{h}", image.width, image.height),
            ));
        }
        if (mask.width, mask.height) != (w, h) {
            return Err(Error::invalid(
                "mask",
                format!("is {}x{} but the camera is {w}x{h}", mask.width, mask.height),
            ));
        }
        if mask.count() < 16 {
            return Err(Error::invalid(
                "mask",
                format!("marks {} pixels: too few to estimate anything from", mask.count()),
            ));
        }
        if image
            .pixels
            .iter()
            .any(|p| p.iter().any(|c| !c.is_finite() || *c < 0.0))
        {
            return Err(Error::invalid("image", "holds NaN, infinite or negative radiance"));
        }
        Ok(Photo {
            image,
            mask,
            camera,
            encoding: PhotoEncoding::Linear,
        })
    }

    /// The photo blurred by `blur_px` beyond its pixels' box (a Gaussian's
    /// standard deviation): every render of the probe through its camera
    /// spreads each pixel's rays by it.
    pub fn with_blur(self, blur_px: f32) -> Result<Self> {
        let camera = self.camera.with_footprint(blur_px)?;
        Ok(Photo { camera, ..self })
    }

    /// The photo with another mask, checked as [`Photo::new`] checks it.
    pub fn with_mask(self, mask: Mask) -> Result<Self> {
        Ok(Photo::new(self.image, mask, self.camera)?.with_encoding(self.encoding))
    }

    /// The photo, its values stored as `encoding` says.
    pub fn with_encoding(self, encoding: PhotoEncoding) -> Self {
        Photo { encoding, ..self }
    }

    /// The radiance one stored level spans at the (linear) value `v`: 0
    /// for linear HDR; for sRGB of `bits` bits, `d linear / d encoded` over
    /// `2^bits - 1` (IEC 61966-2-1), the width of the interval an 8-bit
    /// value stands for.
    pub fn level_step(&self, v: f64) -> f64 {
        match self.encoding {
            PhotoEncoding::Linear => 0.0,
            PhotoEncoding::Srgb { bits } => {
                let levels = ((1u32 << bits) - 1) as f64;
                let slope = match v <= 0.003_130_8 {
                    true => 1.0 / 12.92,
                    false => 2.4 / 1.055 * v.powf(1.4 / 2.4),
                };
                slope / levels
            }
        }
    }

    /// The photo box-filtered by `factor` (at least 1, not necessarily
    /// whole), with its clipped pixels (`clipped`, one flag per pixel):
    /// each pixel the mean over a `factor x factor` square of the photo
    /// (the pixels it cuts count by the area they share with it), in the
    /// mask when at least half of the square is, clipped when any of it is
    /// (a mean over a clipped pixel is no measurement either). The squares
    /// are centred on the photo's centre; what makes no whole square is
    /// cropped, evenly from both sides. The camera keeps its centre of
    /// projection and gets a focal length `factor` times shorter in pixels:
    /// a point projects into the square it projected into, at the same
    /// place in it, and a pixel of the render is the mean over the photo's
    /// square.
    pub fn downsampled(&self, factor: f64, clipped: &[bool]) -> Result<(Photo, Vec<bool>)> {
        let (w, h) = (self.camera.width as usize, self.camera.height as usize);
        let blocks = |n: usize| match factor >= 1.0 {
            true => (n as f64 / factor).floor() as usize,
            false => 0,
        };
        let (bw, bh) = (blocks(w), blocks(h));
        if bw == 0 || bh == 0 || clipped.len() != w * h {
            return Err(Error::invalid(
                "downsampling",
                format!(
                    "factor {factor} for {w}x{h} pixels ({} clipped flags): not at least 1, or no whole square",
                    clipped.len()
                ),
            ));
        }
        // Per square along one axis of `n` pixels: each pixel it overlaps
        // and by how much.
        let spans = |n: usize, blocks: usize| -> Vec<Vec<(usize, f64)>> {
            let first = 0.5 * (n as f64 - blocks as f64 * factor);
            (0..blocks)
                .map(|b| {
                    let (lo, hi) = (first + b as f64 * factor, first + (b + 1) as f64 * factor);
                    (lo.floor() as usize..(hi.ceil() as usize).min(n))
                        .map(|j| (j, hi.min(j as f64 + 1.0) - lo.max(j as f64)))
                        .collect()
                })
                .collect()
        };
        let (columns, rows) = (spans(w, bw), spans(h, bh));
        let half_height = (self.camera.fov_y_deg.to_radians() * 0.5).tan() * (bh as f64 * factor / h as f64) as f32;
        // A blur spans fewer of the wider pixels.
        let camera = Camera::new(
            bw as u32,
            bh as u32,
            2.0 * half_height.atan().to_degrees(),
            self.camera.origin,
            self.camera.target,
            self.camera.up,
        )?
        .with_footprint(self.camera.footprint_px / factor as f32)?;
        let area = factor * factor;
        let mut pixels = Vec::with_capacity(bw * bh);
        let (mut inside, mut clipped_blocks) = (Vec::with_capacity(bw * bh), Vec::with_capacity(bw * bh));
        for row in &rows {
            for column in &columns {
                let (mut sum, mut marked, mut any_clipped) = ([0.0f64; 3], 0.0, false);
                for &(y, wy) in row {
                    for &(x, wx) in column {
                        let (i, weight) = (y * w + x, wy * wx);
                        (0..3).for_each(|c| sum[c] += weight * self.image.pixels[i][c] as f64);
                        marked += weight * self.mask.inside[i] as u8 as f64;
                        any_clipped |= clipped[i];
                    }
                }
                pixels.push(sum.map(|v| (v / area) as f32));
                inside.push(2.0 * marked >= area);
                clipped_blocks.push(any_clipped);
            }
        }
        let photo = Photo::new(RgbImage::new(bw, bh, pixels), Mask::new(bw, bh, inside), camera)?;
        Ok((photo.with_encoding(self.encoding), clipped_blocks))
    }
}

/// The factor by which a photo whose mask holds `mask_pixels` is
/// box-filtered to hold about `budget` (1: as it is; `budget` 0: never).
pub fn working_factor(mask_pixels: usize, budget: usize) -> f64 {
    match budget {
        0 => 1.0,
        _ => (mask_pixels as f64 / budget as f64).sqrt().max(1.0),
    }
}

/// How many of the mask's pixels lie on the image's outermost rows and
/// columns.
pub fn mask_on_border(mask: &Mask) -> usize {
    let (w, h) = (mask.width, mask.height);
    (0..w * h)
        .filter(|&i| mask.inside[i] && (i % w == 0 || i % w == w - 1 || i / w == 0 || i / w == h - 1))
        .count()
}

/// Pixels at the photo's clipping level. In linear HDR: when many mask
/// pixels share the maximum value of a channel, the sensor saturated there.
/// In sRGB: a channel at or above `PhotoSettings::srgb_clip` (white, which
/// an 8-bit photo cannot pass), and the pixels within
/// `PhotoSettings::srgb_clip_ringing_px` of one that are themselves above
/// half of it: a JPEG rings about a clipped highlight, and its edge comes
/// out below white.
pub(super) fn clipped_pixels(photo: &Photo, settings: &PhotoSettings) -> Vec<bool> {
    match photo.encoding {
        PhotoEncoding::Linear => clipped_at_maximum(photo, settings),
        PhotoEncoding::Srgb { .. } => clipped_at_white(photo, settings),
    }
}

fn clipped_at_maximum(photo: &Photo, settings: &PhotoSettings) -> Vec<bool> {
    let mut clipped = vec![false; photo.mask.inside.len()];
    for c in 0..3 {
        let max = photo
            .image
            .pixels
            .iter()
            .zip(&photo.mask.inside)
            .filter(|(_, m)| **m)
            .map(|(p, _)| p[c])
            .fold(0.0f32, f32::max);
        let at_max: Vec<usize> = (0..clipped.len())
            .filter(|&i| photo.mask.inside[i] && photo.image.pixels[i][c] >= settings.clip_level * max)
            .collect();
        if at_max.len() * settings.clip_one_in > photo.mask.count() {
            at_max.into_iter().for_each(|i| clipped[i] = true);
        }
    }
    clipped
}

fn clipped_at_white(photo: &Photo, settings: &PhotoSettings) -> Vec<bool> {
    let (w, h) = (photo.image.width, photo.image.height);
    let peak = |i: usize| photo.image.pixels[i].into_iter().fold(0.0f32, f32::max);
    let white: Vec<bool> = (0..w * h).map(|i| peak(i) >= settings.srgb_clip).collect();
    let r = settings.srgb_clip_ringing_px as i64;
    (0..w * h)
        .map(|i| {
            let (x, y) = ((i % w) as i64, (i / w) as i64);
            white[i]
                || (peak(i) >= 0.5 * settings.srgb_clip
                    && (-r..=r).any(|dy| {
                        (-r..=r).any(|dx| {
                            let (u, v) = (x + dx, y + dy);
                            (0..w as i64).contains(&u)
                                && (0..h as i64).contains(&v)
                                && white[v as usize * w + u as usize]
                        })
                    }))
        })
        .collect()
}

/// Whether pixel `p` (covered by the probe to `coverage`) is data: on the
/// probe ([`on_probe`]) and not clipped.
pub(super) fn usable_pixel(clipped: &[bool], p: u32, coverage: f32) -> bool {
    on_probe(coverage) && !clipped[p as usize]
}

/// Whether a pixel covered by the probe to `coverage` is wholly on the
/// probe (a partly covered pixel mixes in the background), whatever the
/// photo's mask says: the posed probe's outline is the photo's.
pub(super) fn on_probe(coverage: f32) -> bool {
    coverage >= 1.0
}

/// Which of the probe's pixels a lighting fit reads.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Pixels {
    /// Every pixel.
    All,
    /// Those whose row and column sum to an even number: half the samples,
    /// transport and solve of the whole, spread evenly over the probe.
    Checkerboard,
    /// The others: what a fit on the checkerboard held out.
    HeldOut,
}

impl Pixels {
    /// Whether the fit reads pixel `p` of an image `width` wide.
    pub(super) fn keeps(self, p: u32, width: u32) -> bool {
        match self {
            Pixels::All => true,
            Pixels::Checkerboard => (p % width + p / width).is_multiple_of(2),
            Pixels::HeldOut => !(p % width + p / width).is_multiple_of(2),
        }
    }

    /// The nearest pixels the fit also reads around pixel `p` of a
    /// `width x height` image (row-major indices): the 4-neighbours, or
    /// on a checkerboard the diagonal ones.
    pub(super) fn neighbours(self, p: usize, width: usize, height: usize) -> [Option<usize>; 4] {
        let (x, y) = ((p % width) as isize, (p / width) as isize);
        let at = |dx: isize, dy: isize| {
            let (u, v) = (x + dx, y + dy);
            ((0..width as isize).contains(&u) && (0..height as isize).contains(&v))
                .then(|| v as usize * width + u as usize)
        };
        match self {
            Pixels::All => [at(-1, 0), at(1, 0), at(0, -1), at(0, 1)],
            Pixels::Checkerboard | Pixels::HeldOut => [at(-1, -1), at(1, -1), at(-1, 1), at(1, 1)],
        }
    }
}

/// The connected pieces of the pixels `inside` of a `width x height` image
/// (row-major), over the 4-neighbours or, with `diagonals`, the 8: each
/// pixel's piece, numbered in the order of their first pixels (None
/// outside).
pub(super) fn pieces(inside: &[bool], width: usize, height: usize, diagonals: bool) -> Vec<Option<usize>> {
    let mut piece = vec![None; inside.len()];
    let mut count = 0;
    for start in 0..inside.len() {
        if !inside[start] || piece[start].is_some() {
            continue;
        }
        piece[start] = Some(count);
        let mut stack = vec![start];
        while let Some(i) = stack.pop() {
            let diagonal = diagonals.then(|| Pixels::Checkerboard.neighbours(i, width, height));
            for j in Pixels::All
                .neighbours(i, width, height)
                .into_iter()
                .chain(diagonal.into_iter().flatten())
            {
                if let Some(j) = j
                    && inside[j]
                    && piece[j].is_none()
                {
                    piece[j] = Some(count);
                    stack.push(j);
                }
            }
        }
        count += 1;
    }
    piece
}

/// The photo as the estimate works on it: box-filtered when its mask holds
/// more pixels than the budget (`Settings::working_mask_pixels`), with the
/// clipped pixels of what it works on.
pub struct WorkingPhoto {
    /// The box filter's factor (1: the photo as it is).
    pub factor: f64,
    /// The box-filtered photo (None: the photo as it is).
    pub photo: Option<Photo>,
    /// Clipped pixels of the working photo, one flag per pixel.
    pub clipped: Vec<bool>,
}

impl WorkingPhoto {
    /// `full` brought to a mask of about `PhotoSettings::working_mask_pixels`.
    pub fn new(full: &Photo, settings: &PhotoSettings) -> Result<Self> {
        let factor = working_factor(full.mask.count(), settings.working_mask_pixels);
        let (photo, clipped) = match factor > 1.0 {
            false => (None, clipped_pixels(full, settings)),
            true => {
                let (photo, clipped) = full.downsampled(factor, &clipped_pixels(full, settings))?;
                (Some(photo), clipped)
            }
        };
        Ok(WorkingPhoto { factor, photo, clipped })
    }

    /// The photo worked on: the box-filtered one, or `full` itself.
    pub fn photo<'a>(&'a self, full: &'a Photo) -> &'a Photo {
        self.photo.as_ref().unwrap_or(full)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pieces_join_by_four_neighbours_or_by_eight() {
        // A 4 x 3 image: (0, 0) and (1, 1) touch at a corner only; (3, 2) stands alone.
        let mut inside = vec![false; 12];
        [0, 5, 11].iter().for_each(|&i| inside[i] = true);
        assert_eq!(
            pieces(&inside, 4, 3, false)
                .iter()
                .flatten()
                .copied()
                .collect::<Vec<_>>(),
            vec![0, 1, 2]
        );
        let eight = pieces(&inside, 4, 3, true);
        assert_eq!(
            (eight[0], eight[5], eight[11], eight[1]),
            (Some(0), Some(0), Some(1), None)
        );
    }
    use glam::Vec2;
    use glam::Vec3;

    #[test]
    fn a_photo_box_filtered_keeps_every_point_in_its_square() {
        // Sizes and factors that crop an even, an odd and no margin, and
        // squares that cut pixels anywhere; a 60 deg view, tried to its
        // corners.
        for (w, h, factor) in [
            (64, 48, 2.0),
            (65, 49, 2.0),
            (64, 48, 3.0),
            (66, 50, 4.0),
            (64, 48, 1.37),
        ] {
            let camera = Camera::new(w, h, 60.0, Vec3::new(0.1, 0.3, 0.5), Vec3::ZERO, Vec3::Y).unwrap();
            let (w, h) = (w as usize, h as usize);
            // Red is the pixel's column plus 100 times its row; green and
            // blue are constant.
            let pixels: Vec<[f32; 3]> = (0..w * h).map(|i| [(i % w + 100 * (i / w)) as f32, 1.0, 2.0]).collect();
            let inside: Vec<bool> = (0..w * h).map(|i| i % w < w / 2).collect();
            let clipped: Vec<bool> = (0..w * h).map(|i| i % w == w - 1).collect();
            let photo = Photo::new(RgbImage::new(w, h, pixels), Mask::new(w, h, inside), camera).unwrap();
            let (small, small_clipped) = photo.downsampled(factor, &clipped).unwrap();
            let (bw, bh) = ((w as f64 / factor) as usize, (h as f64 / factor) as usize);
            assert_eq!((small.camera.width as usize, small.camera.height as usize), (bw, bh));
            // Where the squares start in the photo.
            let origin = 0.5
                * Vec2::new(
                    (w as f64 - bw as f64 * factor) as f32,
                    (h as f64 - bh as f64 * factor) as f32,
                );
            let to_photo = |p: Vec2| origin + factor as f32 * p;
            for (b, &value) in small.image.pixels.iter().enumerate() {
                let centre = to_photo(Vec2::new((b % bw) as f32 + 0.5, (b / bw) as f32 + 0.5));
                // The mean of the pixels' columns (rows) over the square's
                // span, by 4096 samples across it: red's mean over the square.
                let mean_index = |start: f32| {
                    (0..4096)
                        .map(|k| (start as f64 + (k as f64 + 0.5) / 4096.0 * factor).floor())
                        .sum::<f64>()
                        / 4096.0
                };
                let corner = centre - 0.5 * factor as f32;
                let expected = mean_index(corner.x) + 100.0 * mean_index(corner.y);
                assert!(
                    (value[0] as f64 - expected).abs() < 0.1,
                    "square {b}: {value:?}, not {expected}"
                );
                assert!((value[1] - 1.0).abs() < 1e-6 && (value[2] - 2.0).abs() < 1e-6);
                assert_eq!(
                    small.mask.inside[b],
                    centre.x <= (w / 2) as f32,
                    "square {b} at {centre}"
                );
                let last = to_photo(Vec2::new((b % bw + 1) as f32, 0.0)).x;
                assert_eq!(small_clipped[b], last > (w - 1) as f32, "square {b} ends at {last}");
            }
            // A world point projects into the square it projected into, at
            // the same place in it.
            for (u, v) in [(0.5, 0.5), (0.02, 0.03), (0.97, 0.02), (0.03, 0.98), (0.98, 0.97)] {
                let full = Vec2::new(u * w as f32, v * h as f32);
                let point = camera.origin + 0.4 * camera.direction_through(full);
                let expected = (full - origin) / factor as f32;
                let found = small.camera.project(point).unwrap();
                assert!(
                    (found - expected).length() < 1e-4,
                    "{w}x{h} by {factor}: ({u}, {v}) projects to {found}, not {expected}"
                );
            }
        }
    }

    #[test]
    fn mask_pixels_on_the_border_are_counted_on_all_four_sides_and_only_there() {
        let (w, h) = (6, 5);
        let count = |marked: &[usize]| {
            let mut inside = vec![false; w * h];
            marked.iter().for_each(|&i| inside[i] = true);
            mask_on_border(&Mask::new(w, h, inside))
        };
        // The interior, then one pixel on each side, then a corner.
        assert_eq!(count(&[7, 8, 9, 13, 14, 15, 19, 20, 21]), 0);
        assert_eq!(count(&[2, 6, 11, 27]), 4);
        assert_eq!(count(&[0, 14]), 1);
    }

    #[test]
    fn an_srgb_photo_s_white_and_the_bright_pixels_ringing_about_it_are_clipped() {
        // A 32x8 photo of 0.3 grey, white at (6, 4), a JPEG's ring of 0.8
        // about it and a bright pixel of 0.8 far away.
        let (w, h) = (32, 8);
        let mut pixels = vec![[0.3f32; 3]; w * h];
        pixels[4 * w + 6] = [1.0, 0.95, 1.0];
        pixels[4 * w + 7] = [0.8; 3];
        pixels[3 * w + 5] = [0.8; 3];
        pixels[4 * w + 5] = [0.2; 3];
        pixels[w + 1] = [0.8; 3];
        let camera = Camera::new(w as u32, h as u32, 40.0, Vec3::Z, Vec3::ZERO, Vec3::Y).expect("camera");
        let photo = Photo::new(RgbImage::new(w, h, pixels), Mask::new(w, h, vec![true; w * h]), camera).expect("photo");
        let settings = crate::estimate::Settings::default().photo;
        let flags = clipped_pixels(&photo.clone().with_encoding(PhotoEncoding::Srgb { bits: 8 }), &settings);
        let clipped: Vec<usize> = (0..w * h).filter(|&i| flags[i]).collect();
        assert_eq!(clipped, vec![3 * w + 5, 4 * w + 6, 4 * w + 7]);
        // In linear HDR, one pixel at the maximum is no clipping.
        assert!(!clipped_pixels(&photo, &settings).contains(&true));
    }

    #[test]
    fn a_box_filtered_photo_keeps_its_encoding_and_its_blur_in_its_wider_pixels() {
        let camera = Camera::new(40, 30, 40.0, Vec3::Z, Vec3::ZERO, Vec3::Y).expect("camera");
        let photo = Photo::new(
            RgbImage::filled(40, 30, [0.5; 3]),
            Mask::new(40, 30, vec![true; 1200]),
            camera,
        )
        .expect("photo")
        .with_encoding(PhotoEncoding::Srgb { bits: 8 })
        .with_blur(1.5)
        .expect("a blur");
        let (small, _) = photo.downsampled(2.0, &[false; 1200]).expect("box-filtered");
        assert_eq!(small.encoding, PhotoEncoding::Srgb { bits: 8 });
        assert!((small.camera.footprint_px - 0.75).abs() < 1e-6);
        assert!(photo.with_blur(-1.0).is_err());
    }

    #[test]
    fn an_8_bit_level_spans_the_radiance_the_srgb_curve_gives_it() {
        let camera = Camera::new(4, 4, 40.0, Vec3::Z, Vec3::ZERO, Vec3::Y).expect("camera");
        let photo = Photo::new(
            RgbImage::filled(4, 4, [0.5; 3]),
            Mask::new(4, 4, vec![true; 16]),
            camera,
        )
        .expect("photo");
        assert_eq!(photo.level_step(0.5), 0.0);
        let srgb = photo.with_encoding(PhotoEncoding::Srgb { bits: 8 });
        let decode = |e: f64| match e <= 0.040_45 {
            true => e / 12.92,
            false => ((e + 0.055) / 1.055).powf(2.4),
        };
        for code in [3.0, 40.0, 128.0, 250.0] {
            let v = decode(code / 255.0);
            let span = decode((code + 0.5) / 255.0) - decode((code - 0.5) / 255.0);
            assert!(
                (srgb.level_step(v) - span).abs() < 0.02 * span,
                "code {code}: {} against {span}",
                srgb.level_step(v)
            );
        }
    }

    #[test]
    fn the_working_factor_brings_the_mask_to_the_budget() {
        assert_eq!(working_factor(40_000, 40_000), 1.0);
        assert_eq!(working_factor(10_000, 40_000), 1.0);
        assert_eq!(working_factor(160_000, 40_000), 2.0);
        assert!((working_factor(50_000, 40_000) - 1.25f64.sqrt()).abs() < 1e-12);
        assert_eq!(working_factor(10_000_000, 0), 1.0);
    }

    #[test]
    fn a_fit_on_part_of_the_pixels_compares_each_with_its_nearest_kept_neighbours() {
        let (width, height) = (5usize, 4usize);
        for pixels in [Pixels::All, Pixels::Checkerboard] {
            let kept = |p: usize| pixels.keeps(p as u32, width as u32);
            let count = (0..width * height).filter(|&p| kept(p)).count();
            assert_eq!(count, if pixels == Pixels::All { 20 } else { 10 }, "{pixels:?}");
            for p in (0..width * height).filter(|&p| kept(p)) {
                let (x, y) = ((p % width) as i64, (p / width) as i64);
                let found: Vec<usize> = pixels.neighbours(p, width, height).into_iter().flatten().collect();
                // Every kept pixel in the image at the nearest distance, and nothing else.
                let nearest = |q: usize| {
                    let (u, v) = ((q % width) as i64, (q / width) as i64);
                    (u - x).pow(2) + (v - y).pow(2) == if pixels == Pixels::All { 1 } else { 2 }
                };
                let expected: Vec<usize> = (0..width * height).filter(|&q| kept(q) && nearest(q)).collect();
                let mut sorted = found.clone();
                sorted.sort();
                assert_eq!(sorted, expected, "{pixels:?}: pixel {p}");
            }
        }
    }
}
