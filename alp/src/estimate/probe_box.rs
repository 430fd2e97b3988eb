//! A box round the probe instead of its mask (`alp estimate --box`): the
//! photo inside the box is split into probe and background by a watershed
//! from markers: every pixel joins whichever seed it is reached from over
//! the lowest ridge (the largest change of colour between neighbours along
//! the path; ties by the summed change), the box's own border seeding the
//! background and the pixels of colours the background round the box does
//! not have seeding the probe. A hole in the probe (a ring's) comes out
//! filled: the outline fit reads it as the probe's own outline. The largest step,
//! not the sum: a metal's reflection sweeps smoothly from bright to the
//! background's own colour towards its limb, which a summed distance hands
//! to the background. The mask this gives is a first outline only:
//! the estimate fits the probe's known shape to it and the photo decides
//! the rest (the refinement's size and place searches), as with a mask
//! traced by hand.

use std::cmp::Reverse;
use std::collections::BinaryHeap;

use render::image_io::{Mask, RgbImage};

use super::photo::{Pixels, pieces};
use super::settings::BoxSettings;
use crate::error::{Error, Result};

/// A box round the probe, pixel edges: columns `x0..x1`, rows `y0..y1`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ProbeBox {
    /// First column inside.
    pub x0: usize,
    /// First row inside.
    pub y0: usize,
    /// One past the last column inside.
    pub x1: usize,
    /// One past the last row inside.
    pub y1: usize,
}

/// The fewest pixels a box may be across either way.
const MIN_SIDE_PX: usize = 8;

impl ProbeBox {
    /// The box `x0,y0,x1,y1` (pixel edges, as `alp synth inputs` writes
    /// `box.txt`) in a `width` x `height` photo ([`ProbeBox::new`]).
    pub fn parse(text: &str, width: usize, height: usize) -> Result<Self> {
        let malformed = || {
            Error::invalid(
                "--box",
                format!("`{text}` is not x0,y0,x1,y1 (four whole pixel numbers)"),
            )
        };
        let values: Vec<usize> = text
            .split(',')
            .map(|v| v.trim().parse::<usize>())
            .collect::<std::result::Result<_, _>>()
            .map_err(|_| malformed())?;
        let corners = <[usize; 4]>::try_from(values).map_err(|_| malformed())?;
        ProbeBox::new(corners, width, height)
    }

    /// The box of `[x0, y0, x1, y1]` in a `width` x `height` photo: inside
    /// the photo and at least 8 pixels across each way.
    pub fn new([x0, y0, x1, y1]: [usize; 4], width: usize, height: usize) -> Result<Self> {
        let bad = |rule: String| Error::invalid("--box", rule);
        if x1 > width || y1 > height {
            return Err(bad(format!(
                "{x0},{y0},{x1},{y1} reaches outside the {width}x{height} photo"
            )));
        }
        if x1 < x0 + MIN_SIDE_PX || y1 < y0 + MIN_SIDE_PX {
            return Err(bad(format!(
                "{x0},{y0},{x1},{y1} must have x1 >= x0 + {MIN_SIDE_PX} and y1 >= y0 + {MIN_SIDE_PX} (pixels)"
            )));
        }
        Ok(ProbeBox { x0, y0, x1, y1 })
    }

    fn width(&self) -> usize {
        self.x1 - self.x0
    }

    fn height(&self) -> usize {
        self.y1 - self.y0
    }
}

/// The probe's first outline in `image` from the box `probe_box`: the pixels
/// reached from the probe's seeds over a lower ridge of colour than from the
/// box's border, the largest piece kept. The probe's seeds are the pixels
/// whose colour is unlike any of the background's round the box (a band
/// `BoxSettings::ring_px` wide outside it, or the box's own border where it
/// meets the photo's edge); a probe that shows only the background's colours
/// is seeded by an ellipse at the box's centre. Never empty.
pub fn mask_in_box(image: &RgbImage, probe_box: &ProbeBox, settings: &BoxSettings) -> Result<Mask> {
    let region = Region::new(image, probe_box, settings.dark_floor)?;
    let (w, h) = (region.w, region.h);
    // The background's colours: the band round the box, within the photo.
    let ring = settings.ring_px;
    let (gx0, gy0) = (probe_box.x0.saturating_sub(ring), probe_box.y0.saturating_sub(ring));
    let (gx1, gy1) = (
        (probe_box.x1 + ring).min(image.width),
        (probe_box.y1 + ring).min(image.height),
    );
    let mut background: Vec<[f64; 3]> = Vec::new();
    for y in gy0..gy1 {
        for x in gx0..gx1 {
            let in_box = (probe_box.x0..probe_box.x1).contains(&x) && (probe_box.y0..probe_box.y1).contains(&y);
            let photo_edge = x == 0 || y == 0 || x + 1 == image.width || y + 1 == image.height;
            if !in_box || (photo_edge && region.on_border((y - probe_box.y0) * w + x - probe_box.x0)) {
                background.push(region.log_colour_of(image.pixels[y * image.width + x]));
            }
        }
    }
    let stride = background.len().div_ceil(settings.background_colours.max(1)).max(1);
    let background: Vec<[f64; 3]> = background.into_iter().step_by(stride).collect();
    let unlike_background = |c: &[f64; 3]| {
        background
            .iter()
            .all(|b| colour_distance(b, c) > settings.unlike_background)
    };
    // Seeds: the border (background), the pixels unlike the background
    // (probe), else the centre's ellipse.
    let mut label: Vec<u8> = (0..w * h)
        .map(
            |i| match (region.on_border(i), unlike_background(&region.log_colour[i])) {
                (true, _) => BACKGROUND,
                (false, true) => PROBE,
                (false, false) => UNLABELLED,
            },
        )
        .collect();
    if !label.contains(&PROBE) {
        let (cx, cy) = (0.5 * w as f64, 0.5 * h as f64);
        let (rx, ry) = (
            (settings.centre_seed * cx).max(0.5),
            (settings.centre_seed * cy).max(0.5),
        );
        for i in (0..w * h).filter(|&i| !region.on_border(i)) {
            let (dx, dy) = (((i % w) as f64 + 0.5 - cx) / rx, ((i / w) as f64 + 0.5 - cy) / ry);
            if dx * dx + dy * dy <= 1.0 {
                label[i] = PROBE;
            }
        }
        // The centre pixel however small the ellipse is.
        label[(h / 2) * w + w / 2] = PROBE;
    }
    Ok(region.probe_mask(image, watershed(&region, label)))
}

/// Labels of the watershed.
const UNLABELLED: u8 = u8::MAX;
const BACKGROUND: u8 = 0;
const PROBE: u8 = 1;

/// A rectangle of the photo, its colours as logarithms above a floor: a
/// step is a ratio, alike in shadow and in light, and the floor (a share
/// of the rectangle's mean level) keeps dark noise from cutting.
struct Region {
    x0: usize,
    y0: usize,
    w: usize,
    h: usize,
    floor: f64,
    log_colour: Vec<[f64; 3]>,
}

impl Region {
    fn new(image: &RgbImage, rect: &ProbeBox, dark_floor: f64) -> Result<Self> {
        let (w, h) = (rect.width(), rect.height());
        let pixel = |i: usize| image.pixels[(rect.y0 + i / w) * image.width + rect.x0 + i % w];
        let level = (0..w * h)
            .map(|i| pixel(i).iter().map(|&v| v as f64).sum::<f64>() / 3.0)
            .sum::<f64>();
        if !level.is_finite() {
            return Err(Error::invalid("image", "has a non-finite value round the probe"));
        }
        let floor = (dark_floor * level / (w * h) as f64).max(f64::MIN_POSITIVE);
        let mut region = Region {
            x0: rect.x0,
            y0: rect.y0,
            w,
            h,
            floor,
            log_colour: Vec::new(),
        };
        region.log_colour = (0..w * h).map(|i| region.log_colour_of(pixel(i))).collect();
        Ok(region)
    }

    fn log_colour_of(&self, rgb: [f32; 3]) -> [f64; 3] {
        rgb.map(|v| (v.max(0.0) as f64 + self.floor).ln())
    }

    fn on_border(&self, i: usize) -> bool {
        let (x, y) = (i % self.w, i / self.w);
        x == 0 || y == 0 || x == self.w - 1 || y == self.h - 1
    }

    /// The photo's pixel index of the region's pixel `i` (photo `width`).
    fn photo_index(&self, i: usize, width: usize) -> usize {
        (self.y0 + i / self.w) * width + self.x0 + i % self.w
    }

    /// The largest piece labelled [`PROBE`], as a mask of the photo.
    fn probe_mask(&self, image: &RgbImage, label: Vec<u8>) -> Mask {
        let (w, h) = (self.w, self.h);
        let probe: Vec<bool> = label.iter().map(|&l| l == PROBE).collect();
        let piece = pieces(&probe, w, h, false);
        let mut sizes: Vec<usize> = Vec::new();
        for &k in piece.iter().flatten() {
            if k == sizes.len() {
                sizes.push(0);
            }
            sizes[k] += 1;
        }
        let mut inside = vec![false; image.width * image.height];
        if let Some(largest) = (0..sizes.len()).max_by_key(|&k| sizes[k]) {
            for i in (0..w * h).filter(|&i| piece[i] == Some(largest)) {
                inside[self.photo_index(i, image.width)] = true;
            }
        }
        Mask::new(image.width, image.height, inside)
    }
}

fn colour_distance(p: &[f64; 3], q: &[f64; 3]) -> f64 {
    ((p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2) + (p[2] - q[2]).powi(2)).sqrt()
}

/// The watershed from the seeds `label` holds: each unlabelled pixel takes
/// the label of the seed it is reached from over the lowest [`Ridge`].
fn watershed(region: &Region, mut label: Vec<u8>) -> Vec<u8> {
    let (w, h) = (region.w, region.h);
    let mut ridge = vec![Ridge::UNREACHED; w * h];
    let mut queue = BinaryHeap::new();
    for i in (0..w * h).filter(|&i| label[i] != UNLABELLED) {
        ridge[i] = Ridge::SEED;
        queue.push((Reverse(Ridge::SEED), i));
    }
    while let Some((Reverse(r), i)) = queue.pop() {
        if r > ridge[i] {
            continue;
        }
        for j in neighbours(i, w, h) {
            let through = r.then(colour_distance(&region.log_colour[i], &region.log_colour[j]));
            if through < ridge[j] {
                (ridge[j], label[j]) = (through, label[i]);
                queue.push((Reverse(through), j));
            }
        }
    }
    label
}

/// The 4-neighbours of pixel `i` in a `w` x `h` grid.
fn neighbours(i: usize, w: usize, h: usize) -> impl Iterator<Item = usize> {
    Pixels::All.neighbours(i, w, h).into_iter().flatten()
}

/// How hard a path is to take: its highest colour step, then the sum of
/// its steps (all finite, never NaN).
#[derive(Clone, Copy, PartialEq)]
struct Ridge {
    highest: f64,
    sum: f64,
}

impl Ridge {
    const SEED: Ridge = Ridge { highest: 0.0, sum: 0.0 };
    const UNREACHED: Ridge = Ridge {
        highest: f64::INFINITY,
        sum: f64::INFINITY,
    };

    /// The path one step of `step` further.
    fn then(self, step: f64) -> Ridge {
        Ridge {
            highest: self.highest.max(step),
            sum: self.sum + step,
        }
    }
}

impl Eq for Ridge {}

impl PartialOrd for Ridge {
    fn partial_cmp(&self, other: &Self) -> Option<std::cmp::Ordering> {
        Some(self.cmp(other))
    }
}

impl Ord for Ridge {
    fn cmp(&self, other: &Self) -> std::cmp::Ordering {
        self.highest
            .total_cmp(&other.highest)
            .then(self.sum.total_cmp(&other.sum))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::estimate::settings::Settings;

    #[test]
    fn boxes_are_parsed_and_bad_ones_named() {
        let b = ProbeBox::parse("10, 20,40,60", 100, 80).expect("a box");
        assert_eq!(
            b,
            ProbeBox {
                x0: 10,
                y0: 20,
                x1: 40,
                y1: 60
            }
        );
        for bad in [
            "10,20,40",
            "10,20,40,60,1",
            "a,b,c,d",
            "-1,0,20,20",
            "10,20,101,60",
            "10,20,15,60",
        ] {
            let err = ProbeBox::parse(bad, 100, 80).expect_err(bad).to_string();
            assert!(err.contains("--box"), "{bad}: {err}");
        }
    }

    /// A disc of `radius` at (`cx`, `cy`) on a background with a gradient
    /// and a stripe, the disc shaded from dark to bright (a metal's
    /// reflection) with a rim nearly the background's colour.
    fn disc_photo(cx: f32, cy: f32, radius: f32) -> (RgbImage, Mask) {
        let (w, h) = (96, 80);
        let mut image = RgbImage::filled(w, h, [0.0; 3]);
        let mut inside = vec![false; w * h];
        for y in 0..h {
            for x in 0..w {
                let (px, py) = (x as f32 + 0.5, y as f32 + 0.5);
                let r = ((px - cx).powi(2) + (py - cy).powi(2)).sqrt();
                let background = [0.4 + 0.004 * px, 0.5, 0.6 - 0.003 * py];
                let stripe = if (20..24).contains(&y) { 0.3 } else { 0.0 };
                image.pixels[y * w + x] = if r < radius {
                    inside[y * w + x] = true;
                    let t = (px - cx) / radius;
                    [1.5 + t, 1.2 + 0.8 * t, 0.3]
                } else {
                    background.map(|v| v + stripe)
                };
            }
        }
        (image, Mask::new(w, h, inside))
    }

    #[test]
    fn the_probe_in_a_loose_box_is_found_to_within_a_pixel() {
        let (image, truth) = disc_photo(50.0, 42.0, 18.0);
        let probe_box = ProbeBox::new([25, 18, 78, 66], 96, 80).expect("a box");
        let mask = mask_in_box(&image, &probe_box, &Settings::default().photo.probe_box).expect("a mask");
        let wrong = mask.inside.iter().zip(&truth.inside).filter(|(a, b)| a != b).count();
        // The disc's outline has about 2 pi 18 = 113 pixels.
        assert!(wrong <= 10, "{wrong} pixels wrong");
    }

    #[test]
    fn a_box_of_plain_background_still_gives_a_mask_at_its_centre() {
        let image = RgbImage::filled(40, 40, [0.5; 3]);
        let probe_box = ProbeBox::new([5, 5, 35, 35], 40, 40).expect("a box");
        let mask = mask_in_box(&image, &probe_box, &Settings::default().photo.probe_box).expect("a mask");
        assert!(mask.inside[20 * 40 + 20]);
        assert!(!mask.inside[0] && !mask.inside[5 * 40 + 5]);
    }
}
