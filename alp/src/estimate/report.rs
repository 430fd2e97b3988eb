//! What an estimate returns and what `report.json` holds: the settings used,
//! every hypothesis, start and phase in order, and the log that a progress
//! bar follows while the phases run.

use render::envmap::EnvMap;
use render::image_io::{Mask, RgbImage};
use render::pose::Pose;
use serde::Serialize;

use super::blur::{BlurChoice, BlurEstimate};
use super::decisions::Decision;
use super::lighting::ClippedLight;
use super::pose::uncertainty::PoseUncertainty;

use super::photo::Photo;
use super::settings::Settings;
use crate::objective::TermReport;

/// The estimate.
pub struct Estimate {
    /// The environment map at the output size.
    pub env: EnvMap,
    /// Sampling confidence of each texel in [0, 1] (grey), output size.
    pub confidence: EnvMap,
    /// The standard deviation of each texel and channel (Laplace, scaled by
    /// `LightingSettings::uncertainty_scale`), output size.
    pub uncertainty: EnvMap,
    /// The probe's pose.
    pub pose: Pose,
    /// The photo re-rendered with the estimate.
    pub rerender: RgbImage,
    /// The probe's outline at the found pose (the pixels it covers at
    /// least half of): the mask the photo decided on, `mask_found.png`.
    pub outline: Mask,
    /// The account of the run.
    pub report: Report,
}

/// What `report.json` holds.
#[derive(Clone, Debug, Serialize)]
pub struct Report {
    /// The settings used.
    pub settings: Settings,
    /// The probe's reflectance model ([`render::bsdf::Bsdf::name`]).
    pub bsdf: &'static str,
    /// Every axis hypothesis.
    pub axes: Vec<AxisReport>,
    /// Every start.
    pub starts: Vec<StartReport>,
    /// The index of the start kept (none when the pose was given).
    pub chosen_start: Option<usize>,
    /// The test of the chosen pose against its rival (none without one):
    /// a probe symmetric about its axis whose other end's outline fits
    /// nearly as well, or one with a pattern whose best other end or best
    /// half turn ranked close (`OrientationSettings::rival_rank_deg`; of two such, the one
    /// that scored higher). The phases `lighting_rival` carry every pose
    /// judged.
    pub rival: Option<RivalReport>,
    /// The size line search (none unless asked for: `size_step_px` above
    /// 0, `alp estimate --size-search`; nor when the pose was given or
    /// there is no pilot map).
    pub size: Option<LineSearchReport>,
    /// The lean line search (none when the pose was given, with no pilot
    /// map, or with `lean_step_deg` 0, as at fast quality). After a rival
    /// test, its first candidate is the kept pose's score there (phase
    /// `lighting_rival`).
    pub lean: Option<LineSearchReport>,
    /// The photo's refinement of a small probe's chosen pose and of its
    /// rival (`Settings::photo_refine_px`), each line search in order; the
    /// lean search is then left out.
    pub photo_refinement: Vec<RefinementStep>,
    /// How far the pose can move before the photo tells, per part in the
    /// camera's frame (none when the pose was given).
    pub pose_uncertainty: Option<PoseUncertainty>,
    /// Working env map resolution (width, height) of the output map's
    /// solve, set by `min_roughness`.
    pub working_resolution: (usize, usize),
    /// The pose searches' map resolution: the working one, at most
    /// `LightingSettings::search_height` rows.
    pub search_resolution: (usize, usize),
    /// The smallest roughness of the probe, which set it.
    pub min_roughness: f32,
    /// The probe's axis, mesh coordinates: what the search turns the probe
    /// about (`symmetry::axis_to_y`). The poses of `axes`, `starts` and
    /// `phases` are of the mesh turned to put it along +Y (the mesh as it
    /// is when its axis is +Y); `pose.json` is of the mesh as it is.
    pub probe_axis: [f32; 3],
    /// Mask pixels on the photo's border: the probe may go on beyond it
    /// (the start and the axis hypotheses allow for that:
    /// [`initial_pose`](super::pose::hypotheses::initial_pose), [`axis_hypotheses`](super::pose::hypotheses::axis_hypotheses)), and what lies
    /// beyond is unseen.
    pub mask_on_border_pixels: usize,
    /// The photo as the estimate worked on it.
    pub working_image: WorkingImage,
    /// Pixels excluded as clipped (over-exposed), of the working image.
    pub clipped_pixels: usize,
    /// The lights seen only through clipped pixels, brightest first: each
    /// one's direction, power and whether the photo tells that power or
    /// only a lower bound of it.
    pub clipped_lights: Vec<ClippedLight>,
    /// The photo's blur: given (`--blur`), or read on the probe's edges
    /// (`estimate::blur`); the pose searches' renders spread their pixels'
    /// rays by a reading from `BlurSettings::min_blur_px`.
    pub blur: BlurEstimate,
    /// The photo's check of the reading at the found pose (none when the
    /// blur was given, read below `BlurSettings::test_from_px`, or there
    /// is no pilot map): each blur's held-out error and the margin.
    pub blur_choice: Option<BlurChoice>,
    /// The blur the output map's renders model, pixels.
    pub blur_px: f32,
    /// Samples per pixel and pose of the final lighting solve: the
    /// settings' shared among `final_poses`, or fewer for a probe so large
    /// in the photo that they would overrun
    /// `LightingSettings::final_sample_budget`.
    pub final_spp: u32,
    /// The poses the output map explains the photo at, each with its share
    /// of the data term: the found pose, and poses along the principal
    /// axes of its uncertainty that move the probe in the image by
    /// `LightingSettings::pose_draw_from_px` or more.
    pub final_poses: Vec<(PoseRecord, f64)>,
    /// Every discrete choice the photo made, with its margin and noise.
    pub decisions: Vec<Decision>,
    /// The choices the photo did not settle, and the parts of the pose it
    /// tells poorly, in words (`alp estimate` prints them).
    pub warnings: Vec<String>,
    /// The objective's terms by phase.
    pub objective: ObjectiveReport,
    /// Every phase, in order.
    pub phases: Vec<PhaseReport>,
    /// Final re-rendering PSNR inside the mask, dB.
    pub psnr_db: f64,
    /// Total wall time, seconds.
    pub wall_s: f64,
}

/// The photo as the estimate worked on it (see
/// `PhotoSettings::working_mask_pixels`).
#[derive(Clone, Debug, Serialize)]
pub struct WorkingImage {
    /// The box filter's factor (1: the photo as it is).
    pub factor: f64,
    /// Width and height, pixels.
    pub size: (usize, usize),
    /// Pixels in its mask.
    pub mask_pixels: usize,
}

/// One phase's account in the report.
#[derive(Clone, Debug, Serialize)]
pub struct PhaseReport {
    /// Which phase.
    pub name: String,
    /// Optimiser iterations.
    pub iterations: usize,
    /// Objective evaluations.
    pub evaluations: usize,
    /// Wall time, seconds.
    pub wall_s: f64,
    /// The objective's terms at the end (unweighted).
    pub loss: std::collections::BTreeMap<String, f64>,
    /// Per iteration of a pose phase: every term's weight, value and
    /// weighted gradient norm (empty for lighting solves).
    pub per_iteration: Vec<Vec<TermReport>>,
    /// Re-rendering PSNR inside the mask, dB (when the phase renders).
    pub psnr_db: Option<f64>,
    /// The pose a pose phase ended at.
    pub pose: Option<PoseRecord>,
    /// Why the phase's solver stopped (a spent budget or a failed line
    /// search keeps the best point found).
    pub termination: Option<String>,
    /// The process's resident memory as the phase ended, MB (where the
    /// system tells it): flat from one phase of a kind to the next.
    pub resident_mb: Option<f64>,
}

/// The terms each phase evaluated, in order: their values are in the
/// phases' reports (the pose phases' `loss` and `per_iteration`, the
/// `lighting_final` phase's `loss`).
#[derive(Clone, Debug, Serialize)]
pub struct ObjectiveReport {
    /// The pose phases' terms.
    pub pose: Vec<String>,
    /// The lighting phase's terms.
    pub lighting: Vec<String>,
    /// How the lighting terms were minimised: `exact` (compiled to the
    /// least-squares solve) or `tape`.
    pub lighting_solve: &'static str,
}

impl ObjectiveReport {
    /// The account of `objective`, its lighting terms minimised exactly or not.
    pub fn new(objective: &crate::objective::Objective, exact: bool) -> Self {
        use crate::objective::Phase;
        let names = |phase| objective.names_in(phase).into_iter().map(String::from).collect();
        ObjectiveReport {
            pose: names(Phase::Pose),
            lighting: names(Phase::Lighting),
            lighting_solve: if exact { "exact" } else { "tape" },
        }
    }
}

/// The process's resident set size, MB (Linux `/proc/self/status`; None elsewhere).
pub fn resident_mb() -> Option<f64> {
    status_mb("VmRSS:")
}

/// The process's peak resident set size since it started or since
/// [`reset_peak_resident`], MB (Linux; None elsewhere).
pub fn peak_resident_mb() -> Option<f64> {
    status_mb("VmHWM:")
}

/// Restarts [`peak_resident_mb`] from the present resident size (Linux
/// 4.0 and later; elsewhere the peak stays the process's).
pub fn reset_peak_resident() {
    let _ = std::fs::write("/proc/self/clear_refs", "5");
}

/// A `/proc/self/status` field in kB, as MB.
fn status_mb(field: &str) -> Option<f64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with(field))?;
    let kb: f64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb / 1024.0)
}

/// A pose in the report: rotation quaternion (x, y, z, w), scale, translation (m).
#[derive(Clone, Copy, Debug, Serialize)]
pub struct PoseRecord {
    /// Unit quaternion, x y z w.
    pub rotation: [f32; 4],
    /// Uniform scale.
    pub scale: f32,
    /// World translation, metres.
    pub translation: [f32; 3],
}

impl From<&Pose> for PoseRecord {
    fn from(pose: &Pose) -> Self {
        PoseRecord {
            rotation: pose.rotation.to_array(),
            scale: pose.scale,
            translation: pose.translation.to_array(),
        }
    }
}

/// One axis hypothesis's account.
#[derive(Clone, Debug, Serialize)]
pub struct AxisReport {
    /// The hypothesis: where the probe's axis (mesh +Y) points, world.
    pub axis: [f32; 3],
    /// The axis after the silhouette phase.
    pub fitted_axis: [f32; 3],
    /// Silhouette loss after that phase.
    pub silhouette_loss: f64,
    /// For an outline twin of a fitted axis (`hypotheses::outline_twins`), the
    /// index of that axis.
    pub twin_of: Option<usize>,
    /// Whether its turns were ranked.
    pub kept: bool,
}

/// One orientation start's account.
#[derive(Clone, Debug, Serialize)]
pub struct StartReport {
    /// The axis hypothesis it was turned from (index into the report's axes).
    pub axis: usize,
    /// The start's yaw about that axis, degrees.
    pub yaw_deg: f32,
    /// Silhouette loss of the turned pose (after its refit, if any).
    pub silhouette_loss: f64,
    /// Whether the turn changed the silhouette enough to be refitted.
    pub refitted: bool,
    /// Re-rendering PSNR after its quick lighting solve, dB.
    pub psnr_db: f64,
    /// Mean RGB angle between re-render and photo after that solve,
    /// degrees: what ranks the starts.
    pub rgb_angle_deg: f64,
    /// Mean relative squared error of that re-render: what ranks starts
    /// whose colour errors tie (a probe of one colour).
    pub relative_error: f64,
    /// Whether the start refines the best yaw (else one of the grid).
    pub refinement: bool,
}

impl WorkingImage {
    /// The account of `photo`, box-filtered by `factor`.
    pub(super) fn of(photo: &Photo, factor: f64) -> Self {
        WorkingImage {
            factor,
            size: (photo.mask.width, photo.mask.height),
            mask_pixels: photo.mask.count(),
        }
    }
}

/// The test of the search's choice against its rival: the pose searches'
/// measure ([`LineSearchReport::tried`]) at each, from its own pilot map.
#[derive(Clone, Debug, Serialize)]
pub struct RivalReport {
    /// Where the rival's axis (mesh +Y) points, world.
    pub rival_axis: [f32; 3],
    /// The search's choice's score, dB (higher is better).
    pub chosen_db: f64,
    /// The rival's score, dB (minus infinity, written as null, where it
    /// could not be scored).
    pub rival_db: f64,
    /// Whether the rival scored higher by `Settings::search_margin_db`, and was kept.
    pub kept_rival: bool,
    /// Whether this rival differs from the chosen pose by a turn that maps
    /// the probe on to itself (a ring's other end, any turn of a ball of
    /// one metal, a cap's half turn where its grooves come back): both
    /// render the same photo, and the test only picks the better polished
    /// of two fits.
    pub alike: bool,
    /// The best score (dB) of the rivals that are not alike, the ones a
    /// choice was made against (null when every rival is alike).
    pub distinct_db: Option<f64>,
}

/// A line search's account over one parameter of the pose (the lean's
/// in degrees, see `Settings::lean_step_deg`; the size's in pixels, see
/// `Settings::size_step_px`).
#[derive(Clone, Debug, Serialize)]
pub struct LineSearchReport {
    /// Every value tried and its score (the data term's weighted error,
    /// -dB: higher is better; minus infinity, written as null, where it
    /// could not be scored), in order.
    pub tried: Vec<(f32, f64)>,
    /// The value kept (0: the searched pose).
    pub kept: f32,
}

/// One line search of the photo's refinement (`PhotoJudge::refine`).
#[derive(Clone, Debug, Serialize)]
pub struct RefinementStep {
    /// The pose refined: "chosen" or "rival".
    pub candidate: &'static str,
    /// The direction searched: "lean", "sway" or "turn" (degrees).
    pub direction: &'static str,
    /// The search.
    pub search: LineSearchReport,
}

/// The phases done so far, each announced as it ends with the count done
/// and the count now expected.
pub(super) struct PhaseLog<'a> {
    pub(super) phases: Vec<PhaseReport>,
    pub(super) expected: usize,
    pub(super) on_phase: &'a mut dyn FnMut(&PhaseReport, usize, usize),
}

impl<'a> PhaseLog<'a> {
    /// An empty log that expects `expected` phases.
    pub(super) fn new(expected: usize, on_phase: &'a mut dyn FnMut(&PhaseReport, usize, usize)) -> Self {
        PhaseLog {
            phases: Vec::new(),
            expected,
            on_phase,
        }
    }

    pub(super) fn push(&mut self, phase: PhaseReport) {
        self.expected = self.expected.max(self.phases.len() + 1);
        (self.on_phase)(&phase, self.phases.len() + 1, self.expected);
        self.phases.push(phase);
    }

    /// The run found `more` phases to do than planned.
    pub(super) fn expect_more(&mut self, more: usize) {
        self.expected += more;
    }

    /// The run found `fewer` phases to do than planned.
    pub(super) fn expect_fewer(&mut self, fewer: usize) {
        self.expected = self.expected.saturating_sub(fewer).max(self.phases.len());
    }
}

#[cfg(all(test, target_os = "linux"))]
mod tests {
    use super::*;

    #[test]
    fn the_peak_restarts_below_a_freed_allocation() {
        let before = resident_mb().expect("Linux tells the resident size");
        let big = vec![1u8; 256 << 20];
        assert!(std::hint::black_box(&big).iter().step_by(4096).all(|&b| b == 1));
        let with = peak_resident_mb().expect("and its peak");
        drop(big);
        reset_peak_resident();
        let after = peak_resident_mb().expect("the peak again");
        assert!(with > before + 200.0, "peak {with} MB, resident {before} MB before");
        assert!(
            after < with - 200.0,
            "the peak stayed at {after} MB after the reset ({with} MB)"
        );
    }
}
