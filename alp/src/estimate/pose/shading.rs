//! The turn of a patterned probe about its axis, told by its shading: the
//! photo divided by the probe's albedo is, at the right turn, the lighting's
//! reflection alone; at a wrong turn the label's edges stay in it (the
//! photo's) and appear in it (the model's, divided out where the photo has
//! none). The chromatic total variation of `log(photo / albedo)` over
//! neighbouring probe pixels measures this without any lighting: the
//! coarse map that ranks turns by colour bakes a label into its light and
//! can rank a turn 20 to 150 degrees off first (docs/results/benchmark.md 12.6).

use glam::{Vec2, Vec3};
use rayon::prelude::*;
use render::accel::Accel;
use render::pose::Pose;

use super::hypotheses;
use crate::estimate::Probe;
use crate::estimate::photo::Photo;
use crate::estimate::settings::OrientationSettings;
use crate::objective::mask_mean_luminance;

/// The label variation of a probe's turns in one photo: the mesh's BVH in
/// its own frame (a pose moves the camera's rays, not the mesh), and the
/// photo's blocks it reads.
pub(in crate::estimate) struct LabelVariation<'a> {
    probe: &'a Probe<'a>,
    photo: &'a Photo,
    accel: Accel,
    /// The side (pixels) of the blocks compared
    /// (`OrientationSettings::label_block_px`).
    block: usize,
    /// The blocks read (column, row of blocks): every pixel inside the
    /// mask and not clipped.
    blocks: Vec<(usize, usize)>,
    /// Each block's mean photo colour.
    photo_means: Vec<[f32; 3]>,
    /// Added to the photo's channels before the log: a dark pixel's noise
    /// would otherwise dominate (a fraction of the mask's mean level).
    dark: f32,
}

/// The share of the mask's mean level added to the photo's channels before
/// their log.
const DARK_SHARE: f64 = 0.01;
/// Added to the albedo's channels before their log (albedos are in [0, 1]).
const DARK_ALBEDO: f32 = 0.01;
/// Where a pixel's albedo is sampled (2x2): averaged over the pixel, as
/// the photo is.
const SUBPIXELS: [Vec2; 4] = [
    Vec2::new(0.25, 0.25),
    Vec2::new(0.75, 0.25),
    Vec2::new(0.25, 0.75),
    Vec2::new(0.75, 0.75),
];
/// Where the full-circle scan samples a pixel's albedo: its centre, a
/// quarter of the rays; the scan's lowest minima are scored again with
/// `SUBPIXELS`.
const CENTRE: [Vec2; 1] = [Vec2::new(0.5, 0.5)];

impl<'a> LabelVariation<'a> {
    pub(in crate::estimate) fn new(
        probe: &'a Probe<'a>,
        photo: &'a Photo,
        clipped: &[bool],
        o: &OrientationSettings,
    ) -> crate::error::Result<Self> {
        let (w, h) = (photo.mask.width, photo.mask.height);
        let block = o.label_block_px.max(1);
        let usable = |i: usize| photo.mask.inside[i] && !clipped[i];
        let blocks: Vec<(usize, usize)> = (0..h / block)
            .flat_map(|by| (0..w / block).map(move |bx| (bx, by)))
            .filter(|&(bx, by)| block_pixels(block, bx, by, w).all(usable))
            .collect();
        let photo_means = blocks
            .iter()
            .map(|&(bx, by)| {
                let mut sum = [0.0f32; 3];
                for i in block_pixels(block, bx, by, w) {
                    (0..3).for_each(|c| sum[c] += photo.image.pixels[i][c]);
                }
                sum.map(|v| v / (block * block) as f32)
            })
            .collect();
        let level = mask_mean_luminance(&photo.image, &photo.mask)?;
        Ok(LabelVariation {
            probe,
            photo,
            accel: Accel::new(&probe.asset.mesh),
            block,
            blocks,
            photo_means,
            dark: (DARK_SHARE * level) as f32,
        })
    }

    /// The probe's albedo averaged over pixel `i` at the pose `to_mesh`
    /// inverts, with Schlick's Fresnel (towards white at grazing, as the
    /// photo is); None where a ray misses the probe.
    fn albedo(&self, i: usize, to_mesh: &glam::Mat4, subpixels: &[Vec2]) -> Option<[f32; 3]> {
        let (camera, mesh) = (&self.photo.camera, &self.probe.asset.mesh);
        let w = self.photo.mask.width;
        let mut albedo = [0.0f32; 3];
        for &offset in subpixels {
            let (origin, direction) = camera.primary_ray((i / w) as u32, (i % w) as u32, offset);
            let (o, d) = (to_mesh.transform_point3(origin), to_mesh.transform_vector3(direction));
            let hit = self.accel.closest_hit(o, d, f32::INFINITY)?;
            let t = hit.triangle as usize;
            let f0 = self
                .probe
                .asset
                .albedo
                .lookup(mesh.interpolate(&mesh.uvs, t, hit.barycentric));
            let normal = mesh.interpolate(&mesh.normals, t, hit.barycentric).normalize_or_zero();
            let grazing = (1.0 - normal.dot(d.normalize()).abs()).clamp(0.0, 1.0).powi(5);
            (0..3).for_each(|c| albedo[c] += f0[c] + (1.0 - f0[c]) * grazing);
        }
        Some(albedo.map(|a| a / subpixels.len() as f32))
    }

    /// The mean over neighbouring block pairs (right and below) of the L1
    /// difference of the chromatic part of `log(photo / albedo)`: each
    /// block's log ratio less its mean over the channels. Infinite when no
    /// pair is read.
    pub(in crate::estimate) fn at(&self, pose: &Pose) -> f64 {
        self.sampled_at(pose, &SUBPIXELS)
    }

    /// The label variation at `pose` with each pixel's albedo averaged
    /// over `subpixels`.
    fn sampled_at(&self, pose: &Pose, subpixels: &[Vec2]) -> f64 {
        let to_mesh = pose.to_world().inverse();
        let w = self.photo.mask.width;
        let block = self.block;
        let (bw, bh) = (w / block, self.photo.mask.height / block);
        let mut chroma = vec![None; bw * bh];
        for (&(bx, by), photo) in self.blocks.iter().zip(&self.photo_means) {
            // A block read whole: none of its rays misses the probe.
            let albedo = block_pixels(block, bx, by, w).try_fold([0.0f32; 3], |mut sum, i| {
                let a = self.albedo(i, &to_mesh, subpixels)?;
                (0..3).for_each(|c| sum[c] += a[c] / (block * block) as f32);
                Some(sum)
            });
            if let Some(albedo) = albedo {
                let log = [0, 1, 2].map(|c| (photo[c] + self.dark).ln() - (albedo[c] + DARK_ALBEDO).ln());
                let mean = (log[0] + log[1] + log[2]) / 3.0;
                chroma[by * bw + bx] = Some(Vec3::from(log.map(|l| l - mean)));
            }
        }
        let (mut sum, mut pairs) = (0.0f64, 0usize);
        for (k, a) in chroma.iter().enumerate() {
            let Some(a) = a else { continue };
            let right = (k % bw + 1 < bw).then(|| chroma[k + 1]).flatten();
            let below = chroma.get(k + bw).copied().flatten();
            for b in [right, below].into_iter().flatten() {
                sum += (*a - b).abs().element_sum() as f64;
                pairs += 1;
            }
        }
        match pairs {
            0 => f64::INFINITY,
            n => sum / n as f64,
        }
    }

    /// The turn (degrees, about the probe's axis) of `pose` of least label
    /// variation: every `OrientationSettings::label_scan_deg` round the
    /// circle with each pixel read at its centre; the scan's
    /// `OrientationSettings::label_rescored` lowest minima scored again with
    /// every subpixel, then halving steps about the best down to
    /// `OrientationSettings::yaw_refine_deg`.
    pub(in crate::estimate) fn best_turn(&self, pose: &Pose, o: &OrientationSettings) -> LabelTurn {
        let mesh = &self.probe.asset.mesh;
        let at = |turn: f32| self.at(&hypotheses::turned(pose, mesh, turn));
        let step = o.label_scan_deg.max(o.yaw_refine_deg);
        let scan: Vec<f32> = (0..(360.0 / step).ceil() as usize).map(|k| k as f32 * step).collect();
        let centred: Vec<f64> = scan
            .par_iter()
            .map(|&t| self.sampled_at(&hypotheses::turned(pose, mesh, t), &CENTRE))
            .collect();
        let minima = lowest_minima(&centred, o.label_rescored.max(1));
        let scores: Vec<f64> = minima.par_iter().map(|&k| at(scan[k])).collect();
        let mut scored = minima.len();
        let (mut best, mut score) = minima
            .iter()
            .zip(&scores)
            .min_by(|a, b| a.1.total_cmp(b.1))
            .map(|(&k, &s)| (scan[k], s))
            .expect("at least one turn");
        let mut step = 0.5 * step;
        while step >= o.yaw_refine_deg {
            let (lower, upper) = rayon::join(|| at(best - step), || at(best + step));
            scored += 2;
            for (t, s) in [(best - step, lower), (best + step, upper)] {
                if s < score {
                    (best, score) = (t, s);
                }
            }
            step *= 0.5;
        }
        LabelTurn {
            turn: best,
            variation: score,
            scored,
        }
    }
}

/// The indices of `scores`' `count` lowest local minima round the circle
/// (a plateau's first), lowest first.
fn lowest_minima(scores: &[f64], count: usize) -> Vec<usize> {
    let n = scores.len();
    let mut minima: Vec<usize> = (0..n)
        .filter(|&k| scores[k] < scores[(k + n - 1) % n] && scores[k] <= scores[(k + 1) % n])
        .collect();
    if minima.is_empty() {
        // A flat circle: its first turn.
        minima = (0..n.min(1)).collect();
    }
    minima.sort_by(|&a, &b| scores[a].total_cmp(&scores[b]));
    minima.truncate(count);
    minima
}

/// A turn found by its label variation.
pub(in crate::estimate) struct LabelTurn {
    /// Degrees about the probe's axis.
    pub(in crate::estimate) turn: f32,
    /// Its label variation.
    pub(in crate::estimate) variation: f64,
    /// The turns scored with every subpixel.
    pub(in crate::estimate) scored: usize,
}

/// The row-major indices of the pixels of block (`bx`, `by`), `side`
/// pixels square, in an image `w` wide.
fn block_pixels(side: usize, bx: usize, by: usize, w: usize) -> impl Iterator<Item = usize> {
    (0..side * side).map(move |k| (by * side + k / side) * w + bx * side + k % side)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::estimate::Settings;
    use crate::estimate::testing::{can_in_the_courtyard, probe_of};

    #[test]
    fn a_label_s_turn_is_told_by_the_shading_alone() {
        // The procedural can (red and white label, a bare window), 5,000 px:
        // from its pose turned 100 deg and moved a pixel (the outline's
        // fit), the scan finds the turn back.
        let (asset, truth, photo) = can_in_the_courtyard(240, 180, Vec3::new(0.0, 0.12, 0.3));
        let probe = probe_of(&asset);
        let clipped = vec![false; photo.camera.pixel_count()];
        let o = Settings::default().orientation;
        let label = LabelVariation::new(&probe, &photo, &clipped, &o).expect("a mask");
        let off = hypotheses::turned(&truth, &asset.mesh, 100.0);
        let off = Pose::new(off.rotation, off.scale, off.translation + Vec3::new(3e-4, 0.0, 0.0));
        let found = label.best_turn(&off, &o);
        let (turn, score) = (found.turn, found.variation);
        let back = (turn + 100.0 + 180.0).rem_euclid(360.0) - 180.0;
        assert!(back.abs() < 2.0, "turned {turn} deg: {back} deg from the truth");
        // The measure at the found turn against the start's: the label's
        // edges divided out.
        assert!(score < 0.8 * label.at(&off), "{score} vs {}", label.at(&off));
        // The scan read at the pixels' centres, its minima scored again in
        // full: no turn of the scan's grid scores lower in full, at a
        // tenth of the full scores.
        let step = o.label_scan_deg;
        let full = (0..(360.0 / step).ceil() as usize)
            .map(|k| label.at(&hypotheses::turned(&off, &asset.mesh, k as f32 * step)))
            .fold(f64::INFINITY, f64::min);
        assert!(score <= full, "{score} against the full scan's {full}");
        assert!(
            found.scored <= (360.0 / step) as usize / 10,
            "{} full scores",
            found.scored
        );
    }

    #[test]
    fn the_lowest_minima_go_round_the_circle() {
        // Minima at 0 (by its neighbour 5 round the circle) and 3; a
        // plateau counts once, by its first turn.
        assert_eq!(lowest_minima(&[1.0, 2.0, 3.0, 0.5, 4.0, 2.0], 4), vec![3, 0]);
        assert_eq!(lowest_minima(&[1.0, 2.0, 3.0, 0.5, 4.0, 2.0], 1), vec![3]);
        assert_eq!(lowest_minima(&[2.0, 1.0, 1.0, 3.0], 4), vec![1]);
        // A flat circle, or a single turn: its first.
        assert_eq!(lowest_minima(&[f64::INFINITY; 3], 2), vec![0]);
        assert_eq!(lowest_minima(&[7.0], 2), vec![0]);
    }
}
