//! The evaluation metrics (FORMATS.md, "Relighting evaluation"; PAPER.md, "Evaluation protocol"):
//! per-pixel angular error and scale-invariant RMSE between spheres relit by an estimated and by
//! the ground-truth env map, and the error of an estimated pose.

use std::path::{Path, PathBuf};

use serde::Serialize;

use render::RenderError;
use render::camera::Camera;
use render::envmap::EnvMap;
use render::image_io::Mask;
use render::pose::Pose;
use render::probe::ProbeAsset;

use render::colour::luminance;
use render::envmap::resample;

use crate::error::Result;
use crate::pose_frame::{PoseFrame, PoseParts};
use crate::relight::{RelightSettings, RelitSpheres, Sphere, evaluation_region, mirror_directions, relight};

/// The angle in degrees between two RGB vectors.
///
/// Convention for zero vectors (the angle is undefined there): two black pixels agree (0 degrees);
/// one black pixel against a non-black one is 90 degrees, the largest angle two non-negative RGB
/// vectors can make, so predicting darkness where there is light counts as the worst colour.
pub fn rgb_angle_deg(a: [f32; 3], b: [f32; 3]) -> f64 {
    let a = a.map(f64::from);
    let b = b.map(f64::from);
    let norm = |v: [f64; 3]| (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
    let (na, nb) = (norm(a), norm(b));
    match (na > 0.0, nb > 0.0) {
        (false, false) => 0.0,
        (true, true) => {
            // atan2(|a x b|, a.b) keeps its precision for nearly parallel vectors, where acos does not.
            let cross = [
                a[1] * b[2] - a[2] * b[1],
                a[2] * b[0] - a[0] * b[2],
                a[0] * b[1] - a[1] * b[0],
            ];
            let dot = a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
            norm(cross).atan2(dot).to_degrees()
        }
        _ => 90.0,
    }
}

/// Mean over pixels of [`rgb_angle_deg`]`(estimate, truth)`; 0 for no pixels.
///
/// Panics when the slices differ in length (a programming error).
pub fn angular_error_deg(estimate: &[[f32; 3]], truth: &[[f32; 3]]) -> f64 {
    assert_eq!(
        estimate.len(),
        truth.len(),
        "angular_error_deg: {} estimated pixels vs {} true pixels",
        estimate.len(),
        truth.len()
    );
    if truth.is_empty() {
        return 0.0;
    }
    let sum: f64 = estimate.iter().zip(truth).map(|(&e, &t)| rgb_angle_deg(e, t)).sum();
    sum / truth.len() as f64
}

/// Scale-invariant RMSE: `min_s sqrt(mean((s est - gt)^2)) / sqrt(mean(gt^2))` over every channel
/// of every pixel.
///
/// The best scale is the least-squares `s = sum(est gt) / sum(est^2)` (0 for a black estimate,
/// which then scores 1). A black truth scores 0 (s = 0 matches it exactly).
/// Panics when the slices differ in length (a programming error).
pub fn si_rmse(estimate: &[[f32; 3]], truth: &[[f32; 3]]) -> f64 {
    assert_eq!(
        estimate.len(),
        truth.len(),
        "si_rmse: {} estimated pixels vs {} true pixels",
        estimate.len(),
        truth.len()
    );
    let pairs = || {
        estimate
            .iter()
            .flatten()
            .zip(truth.iter().flatten())
            .map(|(&e, &t)| (e as f64, t as f64))
    };
    let (est_gt, est_est, gt_gt) = pairs().fold((0.0, 0.0, 0.0), |(eg, ee, gg), (e, t)| {
        (eg + e * t, ee + e * e, gg + t * t)
    });
    if gt_gt == 0.0 {
        return 0.0;
    }
    let s = if est_est > 0.0 { est_gt / est_est } else { 0.0 };
    // The residual summed directly, not as gt.gt - (est.gt)^2 / est.est, which cancels badly.
    let residual: f64 = pairs().map(|(e, t)| (s * e - t).powi(2)).sum();
    (residual / gt_gt).sqrt()
}

/// The two relighting metrics of one sphere.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct SphereErrors {
    /// Mean per-pixel angle between RGB vectors, degrees.
    pub angular_deg: f64,
    /// Scale-invariant RMSE (relative to the truth's RMS).
    pub si_rmse: f64,
}

/// The metrics of each sphere ([`Sphere::ALL`] order) on the pixels of `region`.
pub fn compare_spheres(estimate: &RelitSpheres, truth: &RelitSpheres, region: &Mask) -> [SphereErrors; 3] {
    Sphere::ALL.map(|sphere| {
        let pick = |spheres: &RelitSpheres| -> Vec<[f32; 3]> {
            let image = spheres.image(sphere);
            assert_eq!(
                (image.width, image.height),
                (region.width, region.height),
                "compare_spheres: {} image {}x{} vs region {}x{}",
                sphere.name(),
                image.width,
                image.height,
                region.width,
                region.height
            );
            image
                .pixels
                .iter()
                .zip(&region.inside)
                .filter(|(_, inside)| **inside)
                .map(|(p, _)| *p)
                .collect()
        };
        let (est, gt) = (pick(estimate), pick(truth));
        SphereErrors {
            angular_deg: angular_error_deg(&est, &gt),
            si_rmse: si_rmse(&est, &gt),
        }
    })
}

/// Relights both maps along `scene`'s view with the same random numbers (so that identical maps
/// score exactly 0) and compares them on the [`evaluation_region`].
pub fn relighting_errors(
    estimate: &EnvMap,
    truth: &EnvMap,
    scene: &Camera,
    settings: &RelightSettings,
) -> Result<[SphereErrors; 3]> {
    let est = relight(estimate, scene, settings)?;
    let gt = relight(truth, scene, settings)?;
    Ok(compare_spheres(&est, &gt, &evaluation_region()))
}

/// The mirror sphere's error over part of the evaluation region.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct RegionErrors {
    /// Mean per-pixel angle between RGB vectors, degrees (0 for no pixels).
    pub angular_deg: f64,
    /// The share of the evaluation region's pixels it covers.
    pub share: f64,
}

/// A direction counts as seen by the probe where the estimate's confidence exceeds this.
pub const SEEN_CONFIDENCE: f32 = 0.5;

/// The mirror sphere's angular error split by what the probe saw: over the pixels whose
/// reflected direction has `confidence` above [`SEEN_CONFIDENCE`], and over the rest (where the
/// map is the prior's). `directions` are [`mirror_directions`]' of the scene.
pub fn seen_and_unseen(
    estimate: &RelitSpheres,
    truth: &RelitSpheres,
    directions: &[Option<glam::Vec3>],
    confidence: &EnvMap,
) -> [RegionErrors; 2] {
    let region = evaluation_region();
    let (est, gt) = (estimate.image(Sphere::Mirror), truth.image(Sphere::Mirror));
    // Pixels of the seen part, then of the unseen: (estimate, truth) each.
    let mut pixels: [[Vec<[f32; 3]>; 2]; 2] = Default::default();
    for (p, inside) in region.inside.iter().enumerate() {
        let Some(direction) = directions[p].filter(|_| *inside) else {
            continue;
        };
        let part = usize::from(confidence.lookup(direction)[0] <= SEEN_CONFIDENCE);
        pixels[part][0].push(est.pixels[p]);
        pixels[part][1].push(gt.pixels[p]);
    }
    let total = region.count().max(1) as f64;
    pixels.map(|[e, t]| RegionErrors {
        angular_deg: angular_error_deg(&e, &t),
        share: t.len() as f64 / total,
    })
}

/// How often the truth lies within an estimate's stated uncertainty.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Coverage {
    /// The share of texels and channels whose error is at most one
    /// standard deviation (a calibrated Gaussian: 0.68).
    pub within_1_sigma: f64,
    /// Within two (0.95).
    pub within_2_sigma: f64,
}

/// The [`Coverage`] of `uncertainty` (standard deviations at the
/// estimate's size) over the error of `estimate` against `truth`, the truth
/// box-filtered to the estimate's size.
pub fn coverage(estimate: &EnvMap, truth: &EnvMap, uncertainty: &EnvMap) -> Coverage {
    let (w, h) = (estimate.width(), estimate.height());
    let flat: Vec<f64> = truth.radiance().iter().flatten().map(|&v| v as f64).collect();
    let truth = resample(&flat, (truth.width(), truth.height()), (w, h));
    let (mut one, mut two) = (0usize, 0usize);
    let values = estimate
        .radiance()
        .iter()
        .flatten()
        .zip(uncertainty.radiance().iter().flatten());
    for ((&e, &s), t) in values.zip(&truth) {
        let error = (e as f64 - t).abs();
        one += usize::from(error <= s as f64);
        two += usize::from(error <= 2.0 * s as f64);
    }
    let n = truth.len().max(1) as f64;
    Coverage {
        within_1_sigma: one as f64 / n,
        within_2_sigma: two as f64 / n,
    }
}

/// Rows of the map the artefact shares are counted at (128 x 64 texels).
pub const ARTEFACT_ROWS: usize = 64;
/// A texel's neighbourhood for the artefact shares: a square this many texels wide.
pub const ARTEFACT_WINDOW: usize = 5;
/// A texel's chromaticity (rgb / (r + g + b)) this far (Euclidean) from its neighbourhood's
/// median counts as off-colour.
pub const ARTEFACT_CHROMA: f64 = 0.08;
/// A texel this many times darker or brighter than its neighbourhood's median luminance is a
/// hole or a spike.
pub const ARTEFACT_RATIO: f64 = 10.0;

/// Shares of a map's texels, in percent, that stand out of their neighbourhood (the map at
/// [`ARTEFACT_ROWS`] rows, [`ARTEFACT_WINDOW`]-square neighbourhoods, longitude wrapping, rows
/// ending at the poles).
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Artefacts {
    /// Chromaticity [`ARTEFACT_CHROMA`] off the neighbourhood's (per-channel) median.
    pub colour_pct: f64,
    /// Luminance below the neighbourhood's median over [`ARTEFACT_RATIO`].
    pub dark_pct: f64,
    /// Luminance above [`ARTEFACT_RATIO`] times the neighbourhood's median.
    pub bright_pct: f64,
}

/// The [`Artefacts`] of `env`.
pub fn artefacts(env: &EnvMap) -> Artefacts {
    let (w, h) = (2 * ARTEFACT_ROWS, ARTEFACT_ROWS);
    let flat: Vec<f64> = env.radiance().iter().flatten().map(|&v| v as f64).collect();
    let texels: Vec<[f64; 3]> = resample(&flat, (env.width(), env.height()), (w, h))
        .chunks_exact(3)
        .map(|t| [t[0], t[1], t[2]])
        .collect();
    let lum: Vec<f64> = texels.iter().map(|&t| luminance(t)).collect();
    let chroma: Vec<Option<[f64; 3]>> = texels
        .iter()
        .map(|t| {
            let sum = t[0] + t[1] + t[2];
            (sum > 0.0).then(|| t.map(|v| v / sum))
        })
        .collect();
    let median = |values: &mut Vec<f64>| {
        values.sort_by(f64::total_cmp);
        values[values.len() / 2]
    };
    let reach = (ARTEFACT_WINDOW / 2) as i64;
    let (mut colour, mut dark, mut bright) = (0usize, 0usize, 0usize);
    let (mut around_lum, mut around_chroma) = (Vec::new(), [Vec::new(), Vec::new(), Vec::new()]);
    for r in 0..h as i64 {
        for c in 0..w as i64 {
            around_lum.clear();
            around_chroma.iter_mut().for_each(Vec::clear);
            for rr in (r - reach).max(0)..=(r + reach).min(h as i64 - 1) {
                for dc in -reach..=reach {
                    let k = rr as usize * w + (c + dc).rem_euclid(w as i64) as usize;
                    around_lum.push(lum[k]);
                    if let Some(x) = chroma[k] {
                        (0..3).for_each(|ch| around_chroma[ch].push(x[ch]));
                    }
                }
            }
            let k = r as usize * w + c as usize;
            let level = median(&mut around_lum);
            dark += usize::from(lum[k] * ARTEFACT_RATIO < level);
            bright += usize::from(lum[k] > ARTEFACT_RATIO * level);
            if let Some(x) = chroma[k] {
                let centre: [f64; 3] = std::array::from_fn(|ch| median(&mut around_chroma[ch]));
                let off = (0..3).map(|ch| (x[ch] - centre[ch]).powi(2)).sum::<f64>().sqrt();
                colour += usize::from(off > ARTEFACT_CHROMA);
            }
        }
    }
    let pct = |n: usize| 100.0 * n as f64 / (w * h) as f64;
    Artefacts {
        colour_pct: pct(colour),
        dark_pct: pct(dark),
        bright_pct: pct(bright),
    }
}

/// A texel counts as speckle when one of its channels is more than this
/// many times the third brightest of its eight neighbours' (plus
/// [`SPECKLE_FLOOR`]): fewer than three neighbours come near it.
pub const SPECKLE_RATIO: f32 = 4.0;

/// A fraction of the channel's mean radiance added to the neighbourhood's
/// level: a texel a little above a black neighbourhood is no speckle.
pub const SPECKLE_FLOOR: f32 = 0.05;

/// The share of an env map's texels, per channel, that stand alone above
/// their neighbourhood: brighter than [`SPECKLE_RATIO`] times the third
/// brightest of their eight neighbours (longitude wraps; rows end at the
/// poles) plus [`SPECKLE_FLOOR`] of the channel's mean. Noise a solve
/// fitted where the photo tells little shows as speckle; a true map has
/// little (a sun covers a few texels, and they are neighbours).
pub fn speckle(env: &EnvMap) -> [f64; 3] {
    let (w, h) = (env.width(), env.height());
    let texels = env.radiance();
    std::array::from_fn(|c| {
        let mean = texels.iter().map(|t| t[c] as f64).sum::<f64>() / texels.len() as f64;
        let floor = SPECKLE_FLOOR * mean as f32;
        let mut alone = 0usize;
        let mut around = Vec::with_capacity(8);
        for r in 0..h {
            for col in 0..w {
                around.clear();
                for dr in -1i64..=1 {
                    for dc in -1i64..=1 {
                        let rr = r as i64 + dr;
                        if (dr, dc) == (0, 0) || rr < 0 || rr >= h as i64 {
                            continue;
                        }
                        let cc = (col as i64 + dc).rem_euclid(w as i64) as usize;
                        around.push(texels[rr as usize * w + cc][c]);
                    }
                }
                around.sort_by(|a, b| b.total_cmp(a));
                if texels[r * w + col][c] > SPECKLE_RATIO * (around[2] + floor) {
                    alone += 1;
                }
            }
        }
        alone as f64 / texels.len() as f64
    })
}

/// How far an estimated pose is from the true one.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct PoseErrors {
    /// The angle of `R_est R_gt^T`, degrees.
    pub rotation_deg: f64,
    /// The angle between the probes' mesh +Y axes in world, degrees: what counts for a probe
    /// symmetric about its axis, whose turn about the axis is not observable.
    pub axis_deg: f64,
    /// Distance between the translations (where the mesh origin lands), millimetres.
    pub translation_mm: f64,
    /// `s_est / s_gt`.
    pub scale_ratio: f64,
}

/// The error of `estimate` against `truth`.
pub fn pose_errors(estimate: &Pose, truth: &Pose) -> PoseErrors {
    let to_f64 = |q: glam::Quat| glam::DQuat::from_xyzw(q.x as f64, q.y as f64, q.z as f64, q.w as f64);
    let (est, gt) = (to_f64(estimate.rotation), to_f64(truth.rotation));
    let relative = est * gt.conjugate();
    // Angle of a unit quaternion: 2 atan2(|xyz|, |w|) (|w|: q and -q are the same rotation).
    let rotation_deg = 2.0 * relative.xyz().length().atan2(relative.w.abs()).to_degrees();
    let axis_deg = angle_deg(est * glam::DVec3::Y, gt * glam::DVec3::Y);
    let translation_mm = 1000.0 * (estimate.translation.as_dvec3() - truth.translation.as_dvec3()).length();
    PoseErrors {
        rotation_deg,
        axis_deg,
        translation_mm,
        scale_ratio: estimate.scale as f64 / truth.scale as f64,
    }
}

/// Angle between two non-zero vectors, degrees.
fn angle_deg(a: glam::DVec3, b: glam::DVec3) -> f64 {
    a.cross(b).length().atan2(a.dot(b)).to_degrees()
}

/// The report of `alp eval`, one JSON line.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct EvalReport {
    /// The scene folder, as given.
    pub scene: String,
    /// Errors of the mirror sphere.
    pub mirror: SphereErrors,
    /// Errors of the shiny sphere.
    pub shiny: SphereErrors,
    /// Errors of the diffuse sphere.
    pub diffuse: SphereErrors,
    /// The estimated map's speckle per channel ([`speckle`]).
    pub speckle: [f64; 3],
    /// The estimated map's [`artefacts`].
    pub artefacts: Artefacts,
    /// The true map's [`artefacts`], for reference.
    pub true_artefacts: Artefacts,
    /// The mirror sphere where the probe saw the map ([`seen_and_unseen`]), when the estimate's
    /// confidence was given.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub mirror_seen: Option<RegionErrors>,
    /// The mirror sphere where it did not.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub mirror_unseen: Option<RegionErrors>,
    /// How often the truth lies within the estimate's uncertainty, when given.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub uncertainty: Option<Coverage>,
    /// Pose errors, when an estimated pose was given.
    #[serde(flatten)]
    pub pose: Option<PoseErrors>,
    /// The pose's error split into its parts in the camera's frame at the
    /// true pose ([`PoseFrame`]), when an estimated pose was given.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub pose_parts: Option<PoseParts>,
}

impl EvalReport {
    /// The report as one line of JSON.
    pub fn to_json_line(&self) -> String {
        serde_json::to_string(self).expect("EvalReport holds only numbers and strings")
    }
}

/// The files of a scene folder that evaluation reads (FORMATS.md, "Scene folder").
pub struct SceneTruth {
    /// The scene camera (`camera.json`).
    pub camera: Camera,
    /// The true lighting (`gt_env.exr`).
    pub env: EnvMap,
}

/// Path of a file the scene folder must hold; fails naming the file when it is missing.
pub fn scene_file(scene: &Path, name: &str) -> Result<PathBuf> {
    let path = scene.join(name);
    if !scene.is_dir() {
        return Err(RenderError::file(scene, "is not a scene folder (no such directory)").into());
    }
    if !path.is_file() {
        return Err(RenderError::file(
            &path,
            format!("missing: a scene folder needs `{name}` for evaluation (FORMATS.md, \"Scene folder\")"),
        )
        .into());
    }
    Ok(path)
}

/// The probe a scene folder's `probe.txt` names: a procedural probe's name
/// or a probe folder relative to the scene's.
pub fn scene_probe(scene: &Path) -> Result<ProbeAsset> {
    let probe_txt = scene_file(scene, "probe.txt")?;
    let reference = std::fs::read_to_string(&probe_txt).map_err(|e| RenderError::io(&probe_txt, "read", e))?;
    let reference = reference.trim();
    if reference.is_empty() {
        return Err(RenderError::file(
            &probe_txt,
            "is empty: it names the probe (FORMATS.md, \"Scene folder\")",
        )
        .into());
    }
    match crate::probes::PROCEDURAL.contains(&reference) && !scene.join(reference).exists() {
        true => crate::probes::procedural(reference),
        false => crate::probes::load(&scene.join(reference)).map_err(|e| {
            RenderError::file(
                &probe_txt,
                format!("names the probe `{reference}`, which does not read: {e}"),
            )
            .into()
        }),
    }
}

impl SceneTruth {
    /// Reads `camera.json` and `gt_env.exr` of a scene folder.
    pub fn read(scene: &Path) -> Result<Self> {
        let camera = Camera::read(scene_file(scene, "camera.json")?)?;
        let env = EnvMap::read(scene_file(scene, "gt_env.exr")?)?;
        Ok(Self { camera, env })
    }
}

/// What an estimate brings beside its map: its pose and its confidence (`confidence.exr`).
#[derive(Clone, Copy, Debug, Default)]
pub struct EstimateExtras<'a> {
    /// The estimated pose, compared with the scene's `pose.json`.
    pub pose: Option<&'a Pose>,
    /// The estimate's confidence map, which splits the mirror's error into seen and unseen.
    pub confidence: Option<&'a EnvMap>,
    /// The estimate's uncertainty (standard deviations at the map's size).
    pub uncertainty: Option<&'a EnvMap>,
}

/// Evaluates an estimated env map (and optionally its pose and confidence) against a scene's truth.
pub fn evaluate_scene(
    scene: &Path,
    estimate: &EnvMap,
    extras: EstimateExtras,
    settings: &RelightSettings,
) -> Result<EvalReport> {
    let truth = SceneTruth::read(scene)?;
    let (pose, pose_parts) = match extras.pose {
        Some(est) => {
            let true_pose = Pose::read(scene_file(scene, "pose.json")?)?;
            let (lo, hi) = scene_probe(scene)?.mesh.bounds();
            let frame = PoseFrame::new(&truth.camera, &true_pose, 0.5 * (lo + hi), glam::Vec3::Y);
            (Some(pose_errors(est, &true_pose)), Some(frame.parts(&true_pose, est)))
        }
        None => (None, None),
    };
    let est = relight(estimate, &truth.camera, settings)?;
    let gt = relight(&truth.env, &truth.camera, settings)?;
    let [mirror, shiny, diffuse] = compare_spheres(&est, &gt, &evaluation_region());
    let split = match extras.confidence {
        Some(confidence) => Some(seen_and_unseen(
            &est,
            &gt,
            &mirror_directions(&truth.camera)?,
            confidence,
        )),
        None => None,
    };
    Ok(EvalReport {
        scene: scene.display().to_string(),
        mirror,
        shiny,
        diffuse,
        speckle: speckle(estimate),
        artefacts: artefacts(estimate),
        true_artefacts: artefacts(&truth.env),
        mirror_seen: split.map(|s| s[0]),
        mirror_unseen: split.map(|s| s[1]),
        uncertainty: extras.uncertainty.map(|u| coverage(estimate, &truth.env, u)),
        pose,
        pose_parts,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::{Quat, Vec3};

    #[test]
    fn rgb_angle_literals_and_zero_convention() {
        assert_eq!(rgb_angle_deg([1.0, 0.0, 0.0], [0.0, 1.0, 0.0]), 90.0);
        assert!((rgb_angle_deg([1.0, 1.0, 0.0], [1.0, 0.0, 0.0]) - 45.0).abs() < 1e-12);
        assert_eq!(rgb_angle_deg([0.0; 3], [0.0; 3]), 0.0);
        assert_eq!(rgb_angle_deg([0.0; 3], [0.2, 0.1, 0.0]), 90.0);
        assert_eq!(rgb_angle_deg([0.2, 0.1, 0.0], [0.0; 3]), 90.0);
        assert_eq!(rgb_angle_deg([0.3, 0.3, 0.3], [3.0, 3.0, 3.0]), 0.0);
    }

    #[test]
    fn pose_errors_of_a_turn_about_the_axis_and_a_tilt() {
        let truth = Pose::new(Quat::IDENTITY, 2.0, Vec3::new(0.1, 0.0, 0.0));
        let turned = Pose::new(
            Quat::from_rotation_y(30f32.to_radians()),
            3.0,
            Vec3::new(0.1, 0.003, 0.004),
        );
        let e = pose_errors(&turned, &truth);
        assert!((e.rotation_deg - 30.0).abs() < 1e-4, "{e:?}");
        assert!(e.axis_deg.abs() < 1e-4, "{e:?}");
        assert!((e.translation_mm - 5.0).abs() < 1e-3, "{e:?}");
        assert!((e.scale_ratio - 1.5).abs() < 1e-12);
        let tilted = Pose::new(Quat::from_rotation_x(20f32.to_radians()), 2.0, truth.translation);
        let e = pose_errors(&tilted, &truth);
        assert!(
            (e.rotation_deg - 20.0).abs() < 1e-4 && (e.axis_deg - 20.0).abs() < 1e-4,
            "{e:?}"
        );
    }

    #[test]
    fn speckle_counts_texels_that_stand_alone_in_a_channel_not_a_patch_or_a_gradient() {
        let (w, h) = (16, 8);
        let smooth: Vec<[f32; 3]> = (0..w * h).map(|i| [1.0 + (i % w) as f32 * 0.1, 1.0, 1.0]).collect();
        let env = EnvMap::new(w, h, smooth.clone()).unwrap();
        assert_eq!(speckle(&env), [0.0; 3]);
        // One texel 10 times its neighbours in green, at the seam.
        let mut spotted = smooth.clone();
        spotted[3 * w][1] = 10.0;
        let share = speckle(&EnvMap::new(w, h, spotted).unwrap());
        assert_eq!(share, [0.0, 1.0 / (w * h) as f64, 0.0]);
        // A bright 2x2 patch (a sun) is no speckle: each texel has three
        // bright neighbours.
        let mut sun = smooth;
        for r in 2..4 {
            for c in 5..7 {
                sun[r * w + c] = [50.0; 3];
            }
        }
        assert_eq!(speckle(&EnvMap::new(w, h, sun).unwrap()), [0.0; 3]);
    }

    /// A 128 x 64 map of `base` with the texels of `spots` set to theirs.
    fn map_with(base: [f32; 3], spots: &[(usize, usize, [f32; 3])]) -> EnvMap {
        let mut texels = vec![base; 128 * 64];
        for &(r, c, v) in spots {
            texels[r * 128 + c] = v;
        }
        EnvMap::new(128, 64, texels).unwrap()
    }

    #[test]
    fn artefacts_count_holes_spikes_and_off_colour_texels_alone() {
        let one = 100.0 / (128.0 * 64.0);
        let clean = artefacts(&map_with([0.5, 0.4, 0.3], &[]));
        assert_eq!((clean.colour_pct, clean.dark_pct, clean.bright_pct), (0.0, 0.0, 0.0));
        let grey = [0.5f32; 3];
        let map = map_with(
            grey,
            &[
                (10, 0, [0.04; 3]),
                (20, 64, [6.0; 3]),
                (30, 100, [0.7, 0.5, 0.3]),
                (40, 50, [0.06; 3]),
            ],
        );
        let found = artefacts(&map);
        // A hole 12.5x darker (the one 8.3x darker is not), a spike 12x brighter, a reddish texel
        // (chromaticity 0.467 against 0.333): one each. Column 0's neighbourhood wraps.
        assert!((found.dark_pct - one).abs() < 1e-9, "{found:?}");
        assert!((found.bright_pct - one).abs() < 1e-9, "{found:?}");
        assert!((found.colour_pct - one).abs() < 1e-9, "{found:?}");
        // A patch of another colour wider than half the window is no artefact, but its edge
        // texels are counted where the neighbourhood's median is still the background's.
        let patch: Vec<(usize, usize, [f32; 3])> = (30..36)
            .flat_map(|r| (60..66).map(move |c| (r, c, [0.9, 0.3, 0.3])))
            .collect();
        let inside = artefacts(&map_with(grey, &patch));
        assert!(inside.colour_pct < 36.0 * one, "{inside:?}");
    }

    #[test]
    fn coverage_counts_errors_within_one_and_two_deviations() {
        let truth = map_with([1.0; 3], &[]);
        let estimate = map_with([1.0; 3], &[(0, 0, [1.5; 3]), (0, 1, [3.0; 3])]);
        let sigma = map_with([0.4; 3], &[]);
        let c = coverage(&estimate, &truth, &sigma);
        // Errors 0.5 (within two deviations, not one) and 2.0 (neither), three channels each.
        let n = (128 * 64 * 3) as f64;
        assert!((c.within_1_sigma - (n - 6.0) / n).abs() < 1e-12, "{c:?}");
        assert!((c.within_2_sigma - (n - 3.0) / n).abs() < 1e-12, "{c:?}");
    }

    #[test]
    fn report_fields_are_the_contract() {
        let errors = SphereErrors {
            angular_deg: 1.0,
            si_rmse: 0.5,
        };
        let mut report = EvalReport {
            scene: "s".into(),
            mirror: errors,
            shiny: errors,
            diffuse: errors,
            speckle: [0.25, 0.0, 0.5],
            artefacts: Artefacts {
                colour_pct: 1.0,
                dark_pct: 0.5,
                bright_pct: 0.25,
            },
            true_artefacts: Artefacts {
                colour_pct: 0.0,
                dark_pct: 0.0,
                bright_pct: 0.0,
            },
            mirror_seen: None,
            mirror_unseen: None,
            uncertainty: None,
            pose: None,
            pose_parts: None,
        };
        assert_eq!(
            report.to_json_line(),
            r#"{"scene":"s","mirror":{"angular_deg":1.0,"si_rmse":0.5},"shiny":{"angular_deg":1.0,"si_rmse":0.5},"diffuse":{"angular_deg":1.0,"si_rmse":0.5},"speckle":[0.25,0.0,0.5],"artefacts":{"colour_pct":1.0,"dark_pct":0.5,"bright_pct":0.25},"true_artefacts":{"colour_pct":0.0,"dark_pct":0.0,"bright_pct":0.0}}"#
        );
        report.mirror_seen = Some(RegionErrors {
            angular_deg: 2.0,
            share: 0.25,
        });
        report.mirror_unseen = Some(RegionErrors {
            angular_deg: 4.0,
            share: 0.75,
        });
        assert!(report.to_json_line().contains(
            r#""mirror_seen":{"angular_deg":2.0,"share":0.25},"mirror_unseen":{"angular_deg":4.0,"share":0.75}"#
        ));
        report.pose = Some(PoseErrors {
            rotation_deg: 1.0,
            axis_deg: 2.0,
            translation_mm: 3.0,
            scale_ratio: 4.0,
        });
        assert!(
            report
                .to_json_line()
                .ends_with(r#""rotation_deg":1.0,"axis_deg":2.0,"translation_mm":3.0,"scale_ratio":4.0}"#)
        );
        report.pose_parts = Some(crate::pose_frame::PoseParts::from_array([1.0, 2.0, 3.0, 4.0, 5.0, 6.0]));
        assert!(report.to_json_line().contains(
            r#""pose_parts":{"across_x_mm":1.0,"across_y_mm":2.0,"along_mm":3.0,"in_view_deg":4.0,"lean_deg":5.0,"turn_deg":6.0}"#
        ));
    }
}
