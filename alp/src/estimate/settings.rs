//! Every number the estimate can be told, one struct per stage, and the
//! quality presets as data. Each field says what it trades; the
//! measurements behind the values are in `docs/results/` (index: `docs/results.md`).

use std::sync::Arc;

use render::integrator::LightSampling;
use render::pose::Pose;
use render::sampling::EnvSampler;
use serde::Serialize;

use crate::objective::{NeighbourSmoothness, Objective, Weighting};

/// The pose methods the estimate knows (`estimate::pose::method` maps
/// each to its implementation).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum PoseMethodName {
    /// Axis hypotheses fitted to the outline, their turns ranked by colour,
    /// then the size, lean and rivals judged by the photo.
    OutlineThenPhoto,
}

/// How a lighting solve minimises its objective.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum LightingMethod {
    /// Bounded L-BFGS on the Jacobi-preconditioned problem: the exact
    /// solve, in a few hundred evaluations, where the lighting terms have
    /// its form (the default's do); else as `Tape`.
    LeastSquares,
    /// The same L-BFGS on the lighting terms recorded on a tape at every
    /// evaluation, even where the exact solve covers them: what any
    /// declared term gets, to compare.
    Tape,
    /// The paper's recipe (PAPER.md, the official code): Adam steps on the
    /// texels themselves, `steps_per_iteration` for each L-BFGS iteration
    /// the solve would have had, at `rate` times the start's mean level,
    /// decaying as the official code's `10^(-0.0002 t)`. A step moves a
    /// texel by about the rate whatever its brightness, so a light far
    /// above the mean takes many steps to reach.
    Adam {
        /// Adam steps per L-BFGS iteration of the same solve.
        steps_per_iteration: usize,
        /// The learning rate over the start's mean level.
        rate: f64,
    },
}

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

/// Everything the estimation can be told.
#[derive(Clone, Debug, Serialize)]
pub struct Settings {
    /// The preset the numbers below came from.
    pub quality: Quality,
    /// Seed of every random choice.
    pub seed: u64,
    /// Output env map size (width, height), width = 2 x height.
    pub env_size: (usize, usize),
    /// The loss: its pose terms are what the outline fits and the joint
    /// rounds minimise, its lighting terms what the output map's solve
    /// minimises (the report lists both).
    #[serde(skip)]
    pub objective: Arc<Objective>,
    /// The probe's pose when it is known (the lighting alone is estimated).
    #[serde(skip)]
    pub known_pose: Option<Pose>,
    /// The photo stage.
    pub photo: PhotoSettings,
    /// What the asset tells of its symmetry.
    pub symmetry: SymmetrySettings,
    /// Axis hypotheses and the outline's look-alikes.
    pub hypotheses: HypothesisSettings,
    /// Outline fits (and the Adam steps of every pose fit).
    pub outline: OutlineSettings,
    /// The orientation search: axes kept, starts, their ranking by colour.
    pub orientation: OrientationSettings,
    /// The lighting solves.
    pub lighting: LightingSettings,
    /// The photo-scored pose searches.
    pub pose_search: PoseSearchSettings,
    /// How the pose is found ([`PoseMethodName`]).
    pub pose_method: PoseMethodName,
    /// Joint rounds of pose and lighting after the search.
    pub joint: JointSettings,
}

/// The photo stage.
#[derive(Clone, Debug, Serialize)]
pub struct PhotoSettings {
    /// Mask pixels the estimate works on at most (a larger mask is
    /// box-filtered to about this many; 0: never): time and memory against
    /// accuracy, which grows with the mask's pixels.
    pub working_mask_pixels: usize,
    /// A channel is clipped at its maximum over the mask when more than one
    /// mask pixel in this many reaches it: fewer flags more highlights as
    /// saturated.
    pub clip_one_in: usize,
    /// A pixel within this fraction of its channel's maximum is at it.
    pub clip_level: f32,
    /// An sRGB photo's channel at or above this (linear) is clipped: white
    /// less what a JPEG's rounding and ringing take off it.
    pub srgb_clip: f32,
    /// Bright pixels this near (pixels) a clipped one in an sRGB photo are
    /// clipped too: a JPEG's ringing about a highlight.
    pub srgb_clip_ringing_px: usize,
    /// Samples per pixel of the re-render at the photo's size after working
    /// on a box-filtered photo: noise against time.
    pub rerender_spp: u32,
    /// The photo's blur, a Gaussian's standard deviation in pixels, when it
    /// is known (`alp estimate --blur`); None: measured on the probe's edges.
    pub blur_px: Option<f32>,
    /// How the blur is measured on the probe's edges.
    pub blur: BlurSettings,
    /// How a box round the probe (`alp estimate --box`) gives its first
    /// outline.
    pub probe_box: BoxSettings,
}

/// The probe's first outline from a box round it (`estimate::probe_box`).
#[derive(Clone, Debug, Serialize)]
pub struct BoxSettings {
    /// The background's colours are read in a band this wide (pixels)
    /// round the box.
    pub ring_px: usize,
    /// At most this many of them are kept (evenly spread): time against
    /// colours missed.
    pub background_colours: usize,
    /// A pixel further than this (natural-log colour distance) from every
    /// background colour seeds the probe: lower seeds more of a probe
    /// whose reflection is near the background's colours, and more of the
    /// background's own texture inside the box.
    pub unlike_background: f64,
    /// Without such pixels, the ellipse that seeds the probe at the box's
    /// centre spans this share of the box each way: larger holds a probe
    /// of dark and bright parts together, but may reach past a thin
    /// probe's outline.
    pub centre_seed: f64,
    /// Colours below this share of the box's mean level count as that
    /// level in the colour steps: dark noise does not cut the probe.
    pub dark_floor: f64,
}

/// The photo's blur measured on the probe's edges (`estimate::blur`).
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct BlurSettings {
    /// Each edge's profile runs this far (pixels) either side of the
    /// mask's outline: wide enough for the widest blur and the mask's error.
    pub reach_px: f32,
    /// The edge is looked for this far (pixels) either side of the mask's
    /// outline.
    pub place_px: f32,
    /// Every this many points of the outline are measured: time against
    /// the median's noise.
    pub every_nth: usize,
    /// An edge counts when its step is at least this share of its
    /// profile's level: weak edges (a mirror's limb against what it
    /// reflects) are all width.
    pub min_contrast: f64,
    /// An edge counts when the blurred step leaves at most this share of
    /// its profile's variance: the probe's own detail near the outline.
    pub max_residual: f64,
    /// Fewer clear edges than this tell no blur.
    pub min_edges: usize,

    /// Profiles are divided by their level plus this share of the photo's.
    pub dark_level: f64,
    /// The pose searches model a blur read from this up (pixels); below,
    /// they keep a sharp camera. Sharp photos read up to 0.9 px (a mirror's
    /// limb is soft), and a blur modelled where there is none costs more
    /// than one left out.
    pub min_blur_px: f32,
    /// A reading from this up (pixels) is checked by the photo at the
    /// found pose (`blur::blur_by_photo`); below, the output map's camera
    /// is sharp. Each check costs two lighting fits of half the pixels.
    pub test_from_px: f32,
    /// The photo keeps the blur when its held-out error is lower by this
    /// many standard errors: a false blur sharpens the map into blobs and
    /// speckle, a missed one leaves the map soft, which costs less.
    pub test_margin_se: f64,
    /// The side (pixels) of the blocks whose errors the margin counts as
    /// independent.
    pub test_block_px: usize,
    /// Samples per pixel and strategy of the check's fits and of each of
    /// its two held-out renders: the sign test over blocks is robust to
    /// their noise, and they are most of its time.
    pub test_spp: u32,
}

/// What the asset tells of its axis and symmetry.
#[derive(Clone, Debug, Serialize)]
pub struct SymmetrySettings {
    /// Spreads of the surface closer than this factor are equal: no axis
    /// stands out (a sphere).
    pub distinct_spread: f64,
    /// An axis found within this angle (degrees) of mesh +Y is +Y
    /// (faceting tilts the found axis a little).
    pub axis_is_y_deg: f64,
    /// A facet's normal line passing within this fraction of the surface's
    /// size of an axis belongs to its surface of revolution: looser admits
    /// coarser meshes, and surfaces that are not quite of revolution.
    pub on_axis: f64,
    /// An axis of revolution is one only when the next best line leaves
    /// this many times its residual (a sphere has every line).
    pub second_axis_ratio: f64,
    /// A surface this much of revolution (by area) shows one outline at
    /// every turn (a mug with a handle is 0.90).
    pub wholly_revolved: f64,
    /// Reweighted fits of the axis of revolution.
    pub reweightings: usize,
    /// The share of the surface that must be of revolution about one axis
    /// for that to be its axis (a mug's body without its handle).
    pub revolved_share: f64,
    /// Circles about the axis are binned this finely (fraction of the extent).
    pub circle_bin: f64,
    /// Samples a circle needs, over half the area, for the asset to tell.
    pub circle_min_samples: usize,
    /// Material channels within this of each other round a circle are the same.
    pub material_tolerance: f32,
    /// Circles whose material varies may hold at most this share of the area
    /// of a probe that looks alike at every turn.
    pub varied_share: f64,
    /// How far a turned facet's centre may land from another's (a share of
    /// the probe's extent) and still be on the surface
    /// (`symmetry::SelfMap`): a rival's polish leaves it a fraction of a
    /// millimetre off the exact symmetry; wider takes a shallow recess for
    /// the other end's flat.
    pub self_map_reach: f64,
    /// The share of turned facets that must land on the surface in the same
    /// material for a turn to map the probe on to itself: a can's logo, about
    /// 1.4 % of its surface by area, tells its half turn; higher takes a faceted
    /// ball for no ball.
    pub self_map_share: f64,
}

/// Axis hypotheses from the mask and the outline's look-alikes.
#[derive(Clone, Debug, Serialize)]
pub struct HypothesisSettings {
    /// Hypotheses within this angle (degrees) are one.
    pub same_axis_deg: f32,
    /// Axes scored by their outline, spread over the sphere: more miss a
    /// narrow optimum less often, at a coarse outline each (cheap).
    pub sphere_axes: usize,
    /// The best-scoring distinct axes fitted to the outline: more survive a
    /// misleading coarse score, at an outline fit each (the costly part).
    pub axes_fitted: usize,
    /// Cells across the mask's longer side of the grid the axes are scored
    /// on: finer tells close axes apart, at more cells per triangle.
    pub outline_cells: usize,
    /// An axis leaning less than this (degrees) towards or away from the
    /// camera is about its own mirror twin: its twins lean `twin_lean_deg`
    /// either way instead.
    pub upright_lean_deg: f32,
    /// The lean (degrees) of the twins of an axis that barely leans.
    pub twin_lean_deg: f32,
}

/// Outline fits: Adam on the objective's mask terms.
#[derive(Clone, Debug, Serialize)]
pub struct OutlineSettings {
    /// Adam iterations per start's fit, and of the polish of the chosen
    /// pose and its rivals: time against how near the outline's optimum.
    pub iters: usize,
    /// The share of the objective's progress (what its weight schedules
    /// follow) that the outline fits span; joint rounds share the rest.
    pub progress: f64,
    /// Per-term gradient norms are reported every this many evaluations
    /// (each costs a backward pass per term).
    pub gradient_norm_every: usize,
    /// Adam's steps: rotation quaternion, translation (per metre of
    /// depth), log scale. Larger reach further from a start, and wander more.
    pub adam_steps: [f64; 3],
    /// The polish's steps, as a share of a fit's, annealed (cosine) to
    /// `polish_last` of that: a constant step ends wandering about the
    /// optimum by about its step.
    pub polish_step: f64,
    /// See `polish_step`.
    pub polish_last: f64,
}

/// The orientation search: axes, starts turned about them, ranked by colour.
#[derive(Clone, Debug, Serialize)]
pub struct OrientationSettings {
    /// Orientation starts: yaw about the probe's axis, degrees; more find a
    /// label's turn more surely, at a lighting solve each.
    pub starts_deg: Vec<f32>,
    /// Axis hypotheses whose turns are ranked, at most.
    pub axes_kept: usize,
    /// Axes (and starts) whose silhouette loss is within this factor of the
    /// best are ranked by colour: the outline tells a lying probe from a
    /// standing one, not always which end is up.
    pub axis_keep_ratio: f64,
    /// The turns (degrees) at which each axis of a probe whose outline a
    /// turn changes (a mug's handle) is fitted.
    pub axis_fit_turns_deg: Vec<f32>,
    /// Fitted axes closer than this (degrees) are the same.
    pub same_fitted_axis_deg: f32,
    /// A turn whose silhouette loss exceeds the unturned pose's by this
    /// factor changes the outline, and is refitted.
    pub turn_refit_ratio: f64,
    /// A symmetric probe's other end is a rival while its silhouette loss is
    /// within this factor of the chosen end's: a pixel of mask error turns
    /// the two ends' order.
    pub rival_end_ratio: f64,
    /// The env map size (width, height) the starts are ranked under: coarse,
    /// so that a misplaced texture cannot be explained away by the light.
    pub ranking_size: (usize, usize),
    /// The ranking map's smoothness weight (quadratic).
    pub ranking_smoothness: f64,
    /// Samples per pixel of the ranking solves.
    pub ranking_spp: u32,
    /// RGB angles closer than this (degrees) tie; the relative error decides.
    pub rank_tie_deg: f64,
    /// Relative errors closer than this (relative) are one render's (a probe
    /// symmetric about its axis, turned): rounding and facets, not shading.
    pub same_render: f64,
    /// The best start's yaw is refined by halving steps down to this
    /// (degrees): rotation error against two rankings per halving.
    pub yaw_refine_deg: f32,
    /// The step (degrees) of the full-circle scan of a patterned probe's
    /// turn by its label variation (`shading`), refined by halving steps
    /// down to `yaw_refine_deg`: finer finds a narrow minimum, at one
    /// ray-traced albedo image per turn.
    pub label_scan_deg: f32,
    /// The side (pixels) of the blocks the label variation compares: a
    /// pose a pixel or two off (the outline's fit) keeps a label's edge
    /// within a block, against the detail a block averages away.
    pub label_block_px: usize,
    /// The scan's lowest minima (read at each pixel's centre) scored again
    /// with every subpixel: more guard against the centre-read scan ranking
    /// the best turn's minimum below others, at a full score each.
    pub label_rescored: usize,
    /// A start within this RGB angle (degrees) of the chosen one's, at the
    /// other end or half a turn away, is a rival the photo judges.
    pub rival_rank_deg: f64,
}

/// The lighting solves.
#[derive(Clone, Debug, Serialize)]
pub struct LightingSettings {
    /// How every lighting solve minimises its objective: the exact bounded
    /// least-squares solve, or the paper's many Adam steps (to compare:
    /// `alp estimate --lighting adam`, `alp study speed-accuracy`).
    pub method: LightingMethod,
    /// What the light transport of the pilot, the lean and the final fits
    /// models.
    pub model: LightModel,
    /// An sRGB photo's noise, in its stored levels (rounding and a JPEG's
    /// quantised coefficients), added to every pixel's relative error: its
    /// dark pixels' colours count less.
    pub srgb_noise_levels: f64,
    /// Samples per pixel of the pilot map, which guides the later solves'
    /// env-map samples (0: no pilot, BRDF samples alone, no photo searches).
    pub spp_pilot: u32,
    /// Samples per pixel (per strategy) of each photo-scored solve: the
    /// searches' score noise against their time.
    pub spp_lean: u32,
    /// Samples per pixel (per strategy) of the final solve: the output
    /// map's noise against time and memory.
    pub spp_final: u32,
    /// Working env map height (None: from the probe's roughness).
    pub working_height: Option<usize>,
    /// The pose searches' map height at most: they compare poses and start
    /// the output's solve, which refines what they resolve.
    pub search_height: usize,
    /// Weight of the quadratic smoothness of the pilot's and the searches'
    /// maps: sharper lights against noise where the probe sees poorly.
    pub smoothness: f64,
    /// The output map's least radiance of a texel, as a fraction of its
    /// local level: no direction is black, and a black texel has no colour.
    pub floor_of_level: f64,
    /// A texel that a clipped pixel reads most strongly, and that the
    /// photo sees more than this share through clipped pixels, is free of
    /// the smoothness prior: a light brighter than the sensor's range rises
    /// as far as the unclipped pixels allow (1: never).
    pub clipped_light_share: f64,
    /// Neighbouring pixels whose directional albedos differ by more than
    /// this (relative) lie on an edge of the probe's reflectance, which the
    /// output map's fit leaves out (a pose a fraction of a pixel off would
    /// put a label's colours in the sky).
    pub edge_contrast: f64,
    /// Samples per pixel of one pass of light samples at most: a pixel's
    /// samples are stratified within a pass, not across passes.
    pub spp_per_pass: u32,
    /// Light samples of one pass at most: a pass's memory.
    pub pass_samples: usize,
    /// Light samples of the final solve at most: its memory and time
    /// against the output map's noise, which a large probe's many pixels
    /// average down.
    pub final_sample_budget: usize,
    /// Samples per pixel of the output map's solves at least, however large
    /// the probe.
    pub least_final_spp: u32,
    /// The coarsest map height of a coarse-to-fine solve.
    pub coarsest_height: usize,
    /// L-BFGS iterations at most on the levels below the finest.
    pub coarse_level_iters: usize,
    /// L-BFGS iterations at most of a solve that makes a map.
    pub solve_iters: usize,
    /// L-BFGS iterations at most of a photo-scored solve (it starts from a
    /// nearby pose's map and only scores its pose).
    pub lean_solve_iters: usize,
    /// Factor on the Laplace standard deviations of `uncertainty.exr`, set
    /// on the train split (true pose) so that 68 % of its texels and
    /// channels lie within one deviation of the truth (larger: more
    /// covered, less telling). The errors' tails are heavier than a
    /// Gaussian's: 78 % lie within two (results 19.3).
    pub uncertainty_scale: f64,
    /// The output map explains the photo at the found pose and at poses
    /// drawn along this many principal axes of the pose's uncertainty
    /// (`pose::uncertainty`, three poses per axis), their transports
    /// stacked into one solve, the final samples shared among them (0: the
    /// found pose alone). Off: on train's traced masks the stacked map
    /// was worse than the found pose's (results 21).
    pub pose_draw_axes: usize,
    /// An axis is drawn along only if one deviation along it moves the
    /// probe this far in the image (working pixels): a doubt below it
    /// costs the map nothing, and fewer samples per pose cost a little.
    pub pose_draw_from_px: f64,
}

/// The photo-scored pose searches.
#[derive(Clone, Debug, Serialize)]
pub struct PoseSearchSettings {
    /// The step (degrees) of the line search over the lean of the pose
    /// towards the view ray, which the outline tells least (0: none):
    /// accuracy against 4 to 7 solves.
    pub lean_step_deg: f32,
    /// How far (degrees) the lean search may lean the pose either way.
    pub lean_reach_deg: f32,
    /// Whether the lean search scores its leans on half the probe's pixels
    /// (a checkerboard): half the samples, transport and solve of each,
    /// against the score's noise. (Not a small probe's refinement: its
    /// few pixels are all its score has.)
    pub lean_on_checkerboard: bool,
    /// The score (dB) by which a moved pose must beat the searched one, and
    /// a rival the chosen pose: a small gain is the samples' noise.
    pub search_margin_db: f64,
    /// A probe whose mask holds at most this many pixels is refined by the
    /// photo (lean, sway, turn) before the rival test: a small probe's
    /// outline pins its pose least, and its solves cost least (0: never).
    pub photo_refine_px: usize,
    /// Rounds at most of the photo's refinement.
    pub photo_refine_rounds: usize,
    /// The turn's step and reach in a refinement, as multiples of the
    /// lean's (a turn moves a can's surface about twice as far).
    pub turn_per_lean: f32,
    /// The step (pixels at the mask's radius) of a line search over the
    /// probe's size in the photo, for a mask a pixel or two off (0: none;
    /// `alp estimate --size-search` sets 0.5): it mends rough masks and
    /// can shrink exact ones.
    pub size_step_px: f32,
    /// How far (pixels) the size search may grow or shrink the outline.
    pub size_reach_px: f32,
    /// Outline points at most that the pose's uncertainty compares
    /// (`pose::uncertainty`): its cost grows as their cube.
    pub uncertainty_points: usize,
    /// Factor on the pose's deviations, set on the train split (traced
    /// masks) so that two of them cover the found pose's error on 80 % of
    /// photos: the outline's errors are taken as a Gaussian process, which
    /// a tracer's are not quite (results 21).
    pub uncertainty_scale: f64,
    /// A part of the pose whose one deviation moves the probe this far in
    /// the image (working pixels) is warned of, the map possibly warped
    /// there: lower warns of more photos (on train's traced masks, 1 px
    /// warned of 14 of the 19 photos failing alone and 15 of the 29 not;
    /// results 21.9).
    pub warn_sigma_px: f64,
}

/// Joint rounds after the search: the pose by Adam on the whole objective
/// under the map solved so far, then the map at the new pose.
#[derive(Clone, Debug, Serialize)]
pub struct JointSettings {
    /// Rounds (none by default: the searched pose already explains the photo
    /// best, and Adam's first steps leave it).
    pub rounds: usize,
    /// Adam iterations on the pose per round.
    pub pose_iters: usize,
    /// Samples per pixel while fitting the pose.
    pub spp: u32,
    /// Weight of the quadratic smoothness of the maps the rounds fit the
    /// pose under: a detailed map would explain a misplaced texture away
    /// and hide the pose error from the image loss.
    pub map_smoothness: f64,
}

/// The paper's lighting recipe as `alp estimate --lighting adam` runs it:
/// 4 Adam steps for each L-BFGS iteration a solve would have had (the
/// output map's: 1200), time against how far the texels get; a rate of 0.05
/// of the start's mean level, speed against the steps' noise near the
/// optimum.
pub const ADAM_LIGHTING: LightingMethod = LightingMethod::Adam {
    steps_per_iteration: 4,
    rate: 0.05,
};

/// `n` yaw starts evenly around the probe's axis. The paper's code uses four
/// within +-54 degrees of front-facing, which assumes the photographer faced
/// the probe's front; a probe seen from any side needs the whole circle.
pub fn yaws(n: usize) -> Vec<f32> {
    (0..n).map(|k| -180.0 + 360.0 * (k as f32 + 0.5) / n as f32).collect()
}

impl Default for Settings {
    /// The default quality: the setting the project's figures are measured at.
    fn default() -> Self {
        Settings {
            quality: Quality::Default,
            seed: 0,
            env_size: (256, 128),
            objective: Arc::new(Objective::paper_default()),
            known_pose: None,
            photo: PhotoSettings {
                working_mask_pixels: 40_000,
                clip_one_in: 200,
                clip_level: 0.9999,
                srgb_clip: 0.91,
                srgb_clip_ringing_px: 1,
                blur_px: None,
                blur: BlurSettings {
                    reach_px: 4.0,
                    place_px: 2.0,
                    every_nth: 2,
                    min_contrast: 0.2,
                    max_residual: 0.1,
                    min_edges: 20,
                    dark_level: 0.05,
                    min_blur_px: 1.0,
                    test_from_px: 0.3,
                    test_margin_se: 2.0,
                    test_block_px: 8,
                    test_spp: 8,
                },
                probe_box: BoxSettings {
                    ring_px: 4,
                    background_colours: 2048,
                    unlike_background: 0.3,
                    centre_seed: 0.2,
                    dark_floor: 0.02,
                },
                rerender_spp: 8,
            },
            symmetry: SymmetrySettings {
                distinct_spread: 1.05,
                axis_is_y_deg: 1.0,
                on_axis: 0.05,
                second_axis_ratio: 20.0,
                wholly_revolved: 0.98,
                reweightings: 8,
                revolved_share: 0.6,
                circle_bin: 1e-3,
                circle_min_samples: 4,
                material_tolerance: 0.01,
                varied_share: 0.01,
                self_map_reach: 0.03,
                self_map_share: 0.995,
            },
            hypotheses: HypothesisSettings {
                same_axis_deg: 15.0,
                sphere_axes: 256,
                axes_fitted: 6,
                outline_cells: 32,
                upright_lean_deg: 5.0,
                twin_lean_deg: 10.0,
            },
            outline: OutlineSettings {
                iters: 50,
                progress: 0.5,
                gradient_norm_every: 10,
                adam_steps: [0.02, 0.004, 0.005],
                polish_step: 0.25,
                polish_last: 0.05,
            },
            orientation: OrientationSettings {
                starts_deg: yaws(8),
                axes_kept: 3,
                axis_keep_ratio: 1.5,
                axis_fit_turns_deg: vec![0.0, 90.0, 180.0, 270.0],
                same_fitted_axis_deg: 5.0,
                turn_refit_ratio: 1.2,
                rival_end_ratio: 2.0,
                ranking_size: (16, 8),
                ranking_smoothness: 10.0,
                ranking_spp: 2,
                rank_tie_deg: 0.02,
                same_render: 1e-4,
                yaw_refine_deg: 0.5,
                label_scan_deg: 2.5,
                label_block_px: 3,
                label_rescored: 4,
                rival_rank_deg: 1.0,
            },
            lighting: LightingSettings {
                method: LightingMethod::LeastSquares,
                model: LightModel {
                    shadows: true,
                    interreflection: true,
                    mis: true,
                },
                srgb_noise_levels: 1.5,
                spp_pilot: 16,
                spp_lean: 16,
                spp_final: 64,
                working_height: None,
                search_height: 64,
                smoothness: 0.003,
                floor_of_level: 0.02,
                clipped_light_share: 0.5,
                edge_contrast: 0.15,
                spp_per_pass: 64,
                pass_samples: 1 << 20,
                final_sample_budget: 2 << 20,
                least_final_spp: 16,
                coarsest_height: 8,
                coarse_level_iters: 60,
                solve_iters: 300,
                lean_solve_iters: 50,
                uncertainty_scale: 0.77,
                pose_draw_axes: 0,
                pose_draw_from_px: 0.5,
            },
            pose_search: PoseSearchSettings {
                lean_step_deg: 0.3,
                lean_reach_deg: 2.4,
                lean_on_checkerboard: true,
                search_margin_db: 0.3,
                photo_refine_px: 5_000,
                photo_refine_rounds: 3,
                turn_per_lean: 2.0,
                size_step_px: 0.0,
                size_reach_px: 2.0,
                uncertainty_points: 256,
                uncertainty_scale: 3.0,
                warn_sigma_px: 1.0,
            },
            pose_method: PoseMethodName::OutlineThenPhoto,
            joint: JointSettings {
                rounds: 0,
                pose_iters: 20,
                spp: 2,
                map_smoothness: 1e-2,
            },
        }
    }
}

/// The forward model of the lighting fits (PAPER.md's image formation,
/// `render::integrator`): each part costs time and buys accuracy on some
/// probes only (`alp study speed-accuracy`, family `model`, per probe family).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
pub struct LightModel {
    /// The probe's shadows on itself, a shadow ray per light sample; off:
    /// every direction reaches every point, a convex probe's model.
    pub shadows: bool,
    /// One bounce of inter-reflection off the probe (with the shadows
    /// only): a concave probe's recesses see its rim.
    pub interreflection: bool,
    /// The lean's and the final fit's light samples drawn by MIS, a BRDF
    /// and an env-map sample guided by the pilot map; off: BRDF samples
    /// alone (the paper's estimator), noisier under small bright lights.
    pub mis: bool,
}

impl LightModel {
    /// The light sampling of this model, guided by `guide` (a map's
    /// sampler) when it draws by MIS.
    pub fn sampling<'a>(&self, guide: Option<&'a EnvSampler>) -> LightSampling<'a> {
        let sampling = match (self.mis, guide) {
            (true, Some(sampler)) => LightSampling::mis(sampler),
            _ => LightSampling::BSDF,
        };
        match (self.shadows, self.interreflection) {
            (false, _) => sampling.without_shadows(),
            (true, true) => sampling.with_bounces(1),
            (true, false) => sampling,
        }
    }
}

impl LightingSettings {
    /// Samples per pixel of the output map's solves for a probe of
    /// `mask_pixels` with `strategies` light samples per hit (2 with MIS):
    /// `spp`, or as many as `final_sample_budget` allows, but at least
    /// `least_final_spp`.
    pub fn final_spp(&self, spp: u32, mask_pixels: usize, strategies: usize) -> u32 {
        let affordable = self.final_sample_budget / (strategies * mask_pixels).max(1);
        spp.min(affordable.max(self.least_final_spp as usize) as u32)
    }

    /// Samples per pixel of one pass of light samples over `samples_per_spp`
    /// samples per sample per pixel (the mask's pixels times the strategies).
    pub fn spp_per_pass(&self, samples_per_spp: usize) -> u32 {
        (self.pass_samples / samples_per_spp.max(1)).clamp(1, self.spp_per_pass as usize) as u32
    }
}

impl Settings {
    /// The preset for `quality`.
    pub fn new(quality: Quality) -> Self {
        match quality {
            Quality::Fast => Self::fast(),
            Quality::Default => Self::default(),
            Quality::Best => Self::best(),
        }
    }

    /// Fewer starts, iterations and samples; no photo searches (no lean
    /// step) and a quadratic smoothness of the output map (weight 0.003).
    pub fn fast() -> Self {
        let d = Self::default();
        let objective = Objective::paper_default()
            .without(&["neighbour_smoothness"])
            .term(NeighbourSmoothness::quadratic().weight(0.003));
        Settings {
            quality: Quality::Fast,
            objective: Arc::new(objective),
            outline: OutlineSettings { iters: 40, ..d.outline },
            orientation: OrientationSettings {
                starts_deg: yaws(4),
                axes_kept: 2,
                ranking_spp: 1,
                ..d.orientation
            },
            lighting: LightingSettings {
                spp_pilot: 8,
                spp_lean: 8,
                spp_final: 8,
                ..d.lighting
            },
            pose_search: PoseSearchSettings {
                lean_step_deg: 0.0,
                ..d.pose_search
            },
            joint: JointSettings {
                pose_iters: 15,
                spp: 1,
                ..d.joint
            },
            ..d
        }
    }

    /// More of everything.
    pub fn best() -> Self {
        let d = Self::default();
        Settings {
            quality: Quality::Best,
            outline: OutlineSettings {
                iters: 100,
                ..d.outline
            },
            orientation: OrientationSettings {
                starts_deg: yaws(12),
                axes_kept: 4,
                ranking_spp: 4,
                ..d.orientation
            },
            lighting: LightingSettings {
                spp_pilot: 32,
                spp_lean: 32,
                spp_final: 256,
                final_sample_budget: 8 << 20,
                ..d.lighting
            },
            pose_search: PoseSearchSettings {
                lean_on_checkerboard: false,
                ..d.pose_search
            },
            joint: JointSettings {
                pose_iters: 40,
                spp: 4,
                ..d.joint
            },
            ..d
        }
    }

    /// How many phases a run is expected to have before the mask is seen:
    /// one axis hypothesis (the upright one) with every start turned from
    /// it, per joint round a lighting solve and a pose phase, then the
    /// pilot map's solve and the final one (only these when the pose is
    /// known). The run adds to it as it learns more.
    pub fn phase_count(&self) -> usize {
        let output = 1 + (self.lighting.spp_pilot > 0) as usize;
        match self.known_pose {
            Some(_) => output,
            None => 1 + self.orientation.starts_deg.len() + 2 * self.joint.rounds + output,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_light_model_picks_the_sampling_it_names() {
        let sampler = EnvSampler::new(&render::envmap::EnvMap::new(4, 2, vec![[1.0; 3]; 8]).expect("a map"));
        let full = Settings::default().lighting.model;
        let s = full.sampling(Some(&sampler));
        assert!(
            s.env.is_some() && s.shadows && s.bounces == 1,
            "the default models it all"
        );
        assert!(full.sampling(None).env.is_none(), "no guide, no MIS");
        let s = LightModel { mis: false, ..full }.sampling(Some(&sampler));
        assert!(s.env.is_none() && s.bounces == 1);
        let s = LightModel {
            interreflection: false,
            ..full
        }
        .sampling(Some(&sampler));
        assert!(s.env.is_some() && s.shadows && s.bounces == 0);
        let s = LightModel { shadows: false, ..full }.sampling(None);
        assert!(!s.shadows && s.bounces == 0, "nothing shadowed, nothing bounces");
    }

    #[test]
    fn the_presets_trade_time_for_accuracy_and_the_report_records_every_stage() {
        for quality in [Quality::Fast, Quality::Default, Quality::Best] {
            assert_eq!(Settings::new(quality).quality, quality);
        }
        let (fast, default, best) = (Settings::fast(), Settings::default(), Settings::best());
        let starts = |s: &Settings| s.orientation.starts_deg.len();
        assert!(starts(&fast) < starts(&default) && starts(&default) < starts(&best));
        assert!(fast.lighting.spp_final < default.lighting.spp_final);
        assert!(default.lighting.spp_final < best.lighting.spp_final);
        assert_eq!(fast.pose_search.lean_step_deg, 0.0, "fast quality has no lean search");
        assert!(
            default.pose_search.lean_on_checkerboard && !best.pose_search.lean_on_checkerboard,
            "best scores its leans on every pixel"
        );
        // The yaw starts spread evenly around the axis.
        let yaws = &default.orientation.starts_deg;
        assert!(yaws.windows(2).all(|w| (w[1] - w[0] - 45.0).abs() < 1e-4), "{yaws:?}");
        let json = serde_json::to_value(&default).expect("settings serialise");
        for stage in [
            "photo",
            "symmetry",
            "hypotheses",
            "outline",
            "orientation",
            "lighting",
            "pose_search",
            "joint",
        ] {
            assert!(json[stage].is_object(), "report.json's settings lack `{stage}`");
        }
        assert_eq!(json["lighting"]["spp_final"], 64);
    }
}
