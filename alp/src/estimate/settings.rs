//! Every number the estimate can be told, and the quality presets.

use std::sync::Arc;

use render::pose::Pose;
use serde::Serialize;

use super::lighting::Smoothness;
use crate::objective::Objective;

/// Speed against accuracy.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Quality {
    /// Fewer starts, iterations and samples.
    Fast,
    /// The setting the project's figures are measured at.
    Default,
    /// More of everything.
    Best,
}

/// `n` yaw starts evenly around the probe's axis. The paper's code uses four
/// within +-54 degrees of front-facing, which assumes the photographer faced
/// the probe's front; a probe seen from any side needs the whole circle.
pub(super) fn yaws(n: usize) -> Vec<f32> {
    (0..n).map(|k| -180.0 + 360.0 * (k as f32 + 0.5) / n as f32).collect()
}

/// Everything the estimation can be told.
#[derive(Clone, Debug, Serialize)]
pub struct Settings {
    /// The preset the numbers below came from.
    pub quality: Quality,
    /// Seed of every random choice.
    pub seed: u64,
    /// Output env map size (width, height), width = 2 x height.
    pub env_size: (usize, usize),
    /// Orientation starts: yaw about the probe's axis, degrees.
    pub starts_deg: Vec<f32>,
    /// Axis hypotheses whose turns are ranked, at most.
    pub axes_kept: usize,
    /// Adam iterations of the silhouette phase per start, and of the
    /// polish of the chosen pose and of its rival ([`polish_silhouette`]).
    pub silhouette_iters: usize,
    /// Joint rounds after the search: the pose by Adam on the whole
    /// objective under the map solved at the pose so far, then the map at
    /// the new pose. None by default: that map explains the photo best at
    /// the very pose it was solved at, and with the searched pose now
    /// 0.17 px off in the image on average, the first Adam step only
    /// leaves it. With 2 rounds at default
    /// quality, every pose phase of the suite of 18 kept its start (the
    /// outputs are byte-identical without them, 2.4 s sooner; the same at
    /// fast quality on 6 scenes); at best quality 3 rounds moved 2 poses of
    /// 3, both for the worse (the tilted courtyard can's diffuse error 0.42
    /// -> 3.31 deg, the upright studio can's turn 1.2 -> 6.0 deg).
    pub rounds: usize,
    /// Adam iterations on the pose per round.
    pub pose_iters: usize,
    /// Samples per pixel while fitting the pose.
    pub spp_pose: u32,
    /// Samples per pixel of the pilot map that guides the final transport's
    /// env-map samples (0: no pilot, BRDF samples alone). Transport noise
    /// is what the converged solve fits last: a small bright light that a
    /// pixel's lobe finds by a few BRDF samples gives it too much or too
    /// little, and the solve puts the difference in the texels around the
    /// light, in the colours of the pixels that saw it (a red rim from a
    /// can's label). Sampling the light where the pilot map has it (MIS)
    /// takes most of that noise out. At the true pose of the suite's 18
    /// Mitsuba twins (smoothness 1e-3, the floor of the lighting solve
    /// with MIS): BRDF samples at 128 spp, 5.15 / 1.11 / 0.89 deg
    /// mirror / shiny / diffuse; pilot 32 spp, then MIS at 128, 4.46 /
    /// 1.02 / 0.74 (the upright studio can 8.52 -> 4.51 in mirror); pilot
    /// 16, MIS at 64, 4.53 / 1.04 / 0.78, and 4.41 / 0.99 / 0.70 with the
    /// final solve started from the pilot's map (relative smoothness and
    /// floor at its level) instead of coarse to fine.
    pub spp_pilot: u32,
    /// The step (degrees) of a line search over the lean of the searched
    /// pose towards the view ray (`hypotheses::leaned`, the turn of the axis the
    /// outline tells least; see `pose_line_search`): leans of 0 and of a step
    /// either way, steps doubling while the score rises (up to
    /// `lean_reach_deg`), then the vertex of the parabola through the best
    /// three. Each lean is scored by the data term's weighted error (dB)
    /// of the lighting solved there, from the pilot map, with MIS guided by
    /// it (`spp_lean`). 0: no search; none either when the pose is known
    /// or there is no pilot map (`spp_pilot` 0).
    /// On the suite's 18 Mitsuba twins (default quality, step 0.3): 4.89 /
    /// 1.11 / 0.75 deg mirror / shiny / diffuse without the search; 4.73 /
    /// 1.01 / 0.75 with the earlier one (leans of 0.3 either way and the
    /// vertex, within two steps, scored by the pilot's own PSNR: it leaned
    /// the lying courtyard cap the wrong way, 5.10 -> 6.32 in mirror, on a
    /// gain of 0.58 dB, and the lying studio can too little, its axis 0.70
    /// deg off); 4.68 / 0.99 / 0.65 with this search scored by PSNR (a
    /// tilted sunset cap leaned wrong: a sun's highlight is most of the
    /// squared error, and it moves with the lean); 4.50 / 0.89 / 0.59 by
    /// the weighted error (the lying studio can's axis 0.70 -> 0.17 deg,
    /// the lying courtyard cap's 0.47 -> 0.09, the mean axis error 0.22 ->
    /// 0.13 deg). The gains of the leans kept were 0.57 to 5.1 dB, of
    /// those not kept 0.21 at most. Its 4 to 7 solves cost time: wall
    /// median 5.55 -> 7.83 s (twins) and 5.87 -> 7.81 s (the suite's own
    /// scenes, where 4.99 / 1.02 / 0.75 -> 4.80 / 0.89 / 0.61). Line
    /// searches over the lateral position after it (image right, then up,
    /// 0.25 px steps) took the twins to 4.47 / 0.91 / 0.59 at nearly twice
    /// the time: not done.
    pub lean_step_deg: f32,
    /// The score (dB) by which a pose a line search moved to (the size's,
    /// the lean's) must beat the searched one, and a rival the search's
    /// choice: the candidates' samples move with the pose, and a small
    /// gain is noise. (With both polished on to their outlines' optimum,
    /// a cap's two ends tied to 0.002 dB with its mask a pixel too wide,
    /// and the wrong one was kept; a tie now keeps the search's choice. On
    /// the suite's 36 masks a pixel off, the margin changed which poses
    /// fail, not how many: 28 found either way.)
    pub search_margin_db: f64,
    /// How far (degrees) the lean search may lean the searched pose either way.
    pub lean_reach_deg: f32,
    /// A probe whose mask holds at most this many pixels is refined by the
    /// photo before the rival test ([`refine_by_photo`]): the chosen pose
    /// and its rival each, by rounds of line searches over the lean, the
    /// sway and (a probe with a pattern) the turn, in place of the one lean
    /// search. A small probe's outline pins its pose least, and its solves
    /// cost least. 0: never. (A can 27 px wide, the suite's upright
    /// courtyard can with the camera 3 times as far, came out end for end:
    /// the outline left each end's axis about 2 deg off, so the photo
    /// judged the ends at poses it explained worse than the truth, 39.2 and
    /// 42.2 dB against 49.4 for the pilot maps.)
    pub photo_refine_px: usize,
    /// The step (pixels) of a line search over the probe's size in the
    /// photo (`hypotheses::rescaled`: its outline grown by that many pixels at the
    /// mask's radius, the centre kept), before the rival test (the rivals
    /// grown as the chosen pose was) and scored as the lean's, on a
    /// checkerboard half of the pixels: a mask a pixel too
    /// wide or too narrow (a segmentation's usual error) makes the
    /// outline's pose too large or too small, which turns every normal of
    /// the probe by the angle a pixel spans at its radius. 0 (every
    /// quality's default; `alp estimate --size-search` sets 0.5): no search.
    /// On the suite's 18 Mitsuba twins at default quality with masks grown
    /// by a pixel (`tools/eval_suite.py --mask-error 1`), 7.11 / 2.00 /
    /// 1.37 deg mirror / shiny / diffuse without it, 5.92 / 1.62 / 1.03 at
    /// 0.5 (it shrank 14 of the 18 outlines, by 0.2 to 2 px, and grew 2);
    /// with masks shrunk by a pixel, 6.18 / 1.97 / 1.41 -> 6.00 / 2.01 /
    /// 1.22 only (it grew 7 outlines, shrank 6: its scores, each a solve of
    /// 50 iterations on half the pixels, are noisy next to the gain);
    /// with the exact masks it kept the outline in 10 of 13 scenes (the
    /// lying studio can shrank by 2 px: 5.89 -> 7.11 deg in mirror), 4.92
    /// -> 4.99 deg in mirror on those 13, at about 2 s more a run: off
    /// unless the mask is known to be rough. (Those figures are from
    /// binaries before the outline's polish. With it, ahead of the rival
    /// test rather than after it: masks a pixel too wide 5.51 / 1.58 /
    /// 1.14 deg and 16 of 18 poses, against 5.57 / 1.59 / 1.18 and 15, the
    /// lying courtyard cap's ends judged at the size the photo shows, its
    /// right one kept; a pixel too narrow 5.80 / 1.93 / 1.11 against 5.80
    /// / 1.99 / 1.17, 14 poses either way.)
    pub size_step_px: f32,
    /// How far (pixels) the size search may grow or shrink the outline.
    pub size_reach_px: f32,
    /// Samples per pixel (per strategy) of each lean's lighting solve. At
    /// 8 rather than 16 on the suite's 18 Mitsuba twins: 4.85 / 1.17 /
    /// 0.85 deg against 4.68 / 0.99 / 0.65 (both scored by PSNR).
    pub spp_lean: u32,
    /// Samples per pixel of the final lighting solve (per strategy: with
    /// a pilot, each hit has a BRDF and an env-map sample). BRDF samples
    /// alone, the studio can at its true pose: 12.2/2.0/2.7 deg at 64,
    /// 9.7/1.1/1.3 at 128, 7.4/0.8/0.6 at 256. With the pilot, at the true
    /// pose of the suite's 18 Mitsuba twins (smoothness 3e-4): 4.30 / 0.78
    /// / 0.55 deg mirror / shiny / diffuse at 64 (pilot 16), 4.20 / 0.77 /
    /// 0.52 at 96, 4.27 / 0.79 / 0.55 with a pilot of 32. With the edged
    /// final smoothness (`alp eval --spp 256`): 3.92 / 0.73 / 0.48 at 64, 3.79 / 0.72
    /// / 0.45 at 128 (mean run 2.8 -> 5.0 s with the 8-byte transport;
    /// 3.65 / 0.70 / 0.47 at 256, 11.1 s before it): default 128, best 256.
    pub spp_final: u32,
    /// Working env map height (None: from the probe's roughness), at
    /// most 181 rows (a map of at most [`lighting::MAX_TEXELS`] texels).
    pub working_height: Option<usize>,
    /// Weight of the quadratic smoothness (scale-free) of the pilot's and
    /// the leans' maps. Less lets the lights be sharper (shiny and diffuse
    /// spheres), more keeps what the probe sees poorly from noise
    /// (mirror). As the final map's, at the true pose of the suite's 18
    /// Mitsuba twins (pilot and MIS): 4.40 / 0.99 / 0.70 deg mirror /
    /// shiny / diffuse at 1e-3, 4.30 / 0.78 / 0.55 at 3e-4, 4.66 / 0.71 /
    /// 0.47 at 1e-4 (and 5.15 / 1.12 / 0.66 there with colour differences
    /// between neighbours penalised 10 times more than grey ones: colour is
    /// no smoother than radiance).
    pub smoothness: f64,
    /// The final map's smoothness, linear past an edge: sharp where the
    /// data show an edge, so it can be stronger elsewhere than a quadratic
    /// one. At the true pose of the 18 twins, the final map (with the
    /// kept pilot, 3e-4 quadratic): 4.30 / 0.78 / 0.55 deg mirror / shiny
    /// / diffuse at 3e-4 quadratic, in 83 evaluations of the final solve
    /// on average; **4.02 / 0.74 / 0.46 at 1e-3 with an edge of 0.05**, in
    /// 150. The pilot and the final map with the same prior:
    ///
    /// | weight | edge | mirror / shiny / diffuse (deg) |
    /// |---|---|---|
    /// | 3e-4 | 0.3 | 4.27 / 0.75 / 0.50 |
    /// | 3e-4 | 0.1 | 4.32 / 0.71 / 0.45 |
    /// | 3e-4 | 0.03 | 4.92 / 0.70 / 0.48 |
    /// | 1e-3 | quadratic | 4.37 / 0.99 / 0.70 |
    /// | 1e-3 | 0.1 | 4.07 / 0.84 / 0.54 |
    /// | 1e-3 | 0.05 | 4.04 / 0.76 / 0.47 |
    /// | 1e-3 | 0.03 | 4.10 / 0.73 / 0.44 |
    /// | 1e-3 | 0.01 | 4.75 / 0.72 / 0.48 |
    /// | 2e-3 | 0.03 | 3.99 / 0.81 / 0.49 |
    /// | 3e-3 | 0.03 | 4.04 / 0.89 / 0.53 |
    ///
    /// (Past the edge a difference costs in proportion to `weight *
    /// edge`: too small a product leaves noise.) Those were at 64 spp; at
    /// 128 (default quality), the kept pilot and 1e-3, the final map's
    /// noise is less and a smaller edge sharpens the lights for the shiny
    /// and diffuse spheres, not for the mirror:
    ///
    /// | edge | true pose | pose estimated (wall median) |
    /// |---|---|---|
    /// | 0.1 | 3.87 / 0.80 / 0.52 | |
    /// | **0.05** | **3.79 / 0.72 / 0.45** | **4.10 / 0.90 / 0.61 (7.9 s)** |
    /// | 0.03 | 3.78 / 0.66 / 0.40 | 4.09 / 0.85 / 0.56 (8.8 s) |
    /// | 0.02 | 3.86 / 0.63 / 0.36 | |
    /// | 0.01 | 4.22 / 0.62 / 0.34 | |
    ///
    /// 0.03 took 10 % more CPU time, and the caps' wall median 9.9 s of
    /// the 10 s a photo may take: the default keeps 0.05, whose shiny and
    /// diffuse errors are within their targets. The pilot and the leans
    /// keep the quadratic prior, whose solves take half the evaluations.
    /// So does the fast quality's final map, from 8 samples per pixel: on
    /// our own 18 scenes, estimated pose, 6.15 / 1.52 / 1.23 deg and a wall
    /// median of 2.30 s with the edge, against 6.01 / 1.48 / 1.14 and
    /// 2.02 s without.
    pub final_smoothness: Smoothness,
    /// The loss the pose phases minimise; its smoothness weight is the
    /// lighting solves' while the pose is searched.
    #[serde(skip)]
    pub objective: Arc<Objective>,
    /// The probe's pose when it is known (the lighting alone is estimated).
    #[serde(skip)]
    pub known_pose: Option<Pose>,
    /// Mask pixels the estimate works on at most: a photo whose mask holds
    /// more is box-filtered by the factor that brings it to about that many
    /// ([`Photo::downsampled`]; 0: never). Time and memory grow with the
    /// mask's pixels, and so does accuracy: the suite's 18 Mitsuba twins
    /// (7.6k to 51k mask pixels) box-filtered by 2 went from 4.34 / 0.87 /
    /// 0.53 to 6.48 / 2.05 / 1.53 deg mirror / shiny / diffuse and from 17
    /// to 15 poses found. The budget is what time and memory allow: at
    /// 40k, the suite's two larger probes (43k, 51k) went 3.18 -> 3.0 and
    /// 5.86 -> 5.5 deg mirror, 11.5 -> 11.7 s and 22.1 -> 17.7 s; a
    /// 1920x1080 photo of the can (75k) 41.5 s, 1067 MB -> 18.5 s, 674 MB,
    /// 6.47 / 1.82 / 0.89 -> 5.01 / 1.32 / 0.56 deg (the photo as it is
    /// had its final samples cut to fit [`FINAL_SAMPLE_BUDGET`]).
    pub working_mask_pixels: usize,
}

impl Settings {
    /// How many phases a run is expected to have before the mask is seen:
    /// one axis hypothesis (the upright one) with every start turned from
    /// it, per joint round a lighting solve and a pose phase, then the
    /// pilot map's solve and the final one (only these when the pose is
    /// known). The run adds to it as it learns more (see
    /// [`estimate_with_progress`]).
    pub fn phase_count(&self) -> usize {
        let output = 1 + (self.spp_pilot > 0) as usize;
        match self.known_pose {
            Some(_) => output,
            None => 1 + self.starts_deg.len() + 2 * self.rounds + output,
        }
    }

    /// The preset for `quality`.
    pub fn new(quality: Quality) -> Self {
        let (starts_deg, axes_kept, silhouette_iters, rounds, pose_iters, spp_pose) = match quality {
            Quality::Fast => (yaws(4), 2, 40, 0, 15, 1),
            Quality::Default => (yaws(8), 3, 50, 0, 20, 2),
            Quality::Best => (yaws(12), 4, 100, 0, 40, 4),
        };
        let (spp_pilot, spp_lean, spp_final, lean_step_deg) = match quality {
            Quality::Fast => (8, 8, 8, 0.0),
            Quality::Default => (16, 16, 128, 0.3),
            Quality::Best => (32, 32, 256, 0.3),
        };
        let final_smoothness = match quality {
            Quality::Fast => Smoothness::quadratic(3e-4),
            Quality::Default | Quality::Best => Smoothness {
                weight: 1e-3,
                edge: 0.05,
            },
        };
        Settings {
            quality,
            seed: 0,
            env_size: (256, 128),
            starts_deg,
            axes_kept,
            silhouette_iters,
            rounds,
            pose_iters,
            spp_pose,
            spp_pilot,
            lean_step_deg,
            search_margin_db: 0.3,
            lean_reach_deg: 2.4,
            photo_refine_px: PHOTO_REFINE_PX,
            size_step_px: 0.0,
            size_reach_px: 2.0,
            spp_lean,
            spp_final,
            working_height: None,
            smoothness: 3e-4,
            final_smoothness,
            objective: Arc::new(Objective::paper_default()),
            known_pose: None,
            working_mask_pixels: WORKING_MASK_PIXELS,
        }
    }
}

/// The default of [`Settings::working_mask_pixels`].
pub const WORKING_MASK_PIXELS: usize = 40_000;

/// The default of [`Settings::photo_refine_px`]: small probes' masks (the
/// suite's scenes with the camera 3 to 5 times as far) hold 440 to 4,800
/// pixels, where the refinement took the wall median from 1.9 to 3.9 s
/// (20 variants: 17 -> 19 poses found, 7.88 -> 7.11 deg mirror); the
/// suite's own 7,600 to 40,000, where it costs as much again as the whole
/// run (a lean's score takes 0.4 s at 13,000 px): refined at every size,
/// the suite's 18 twins with masks a pixel too wide found 16 poses rather
/// than 14 (6.81 / 1.92 / 1.60 deg against 7.04 / 1.96 / 1.63) at a wall
/// median of 22.3 s rather than 11.1.
pub const PHOTO_REFINE_PX: usize = 5_000;
