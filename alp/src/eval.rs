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

use crate::error::Result;
use crate::relight::{RelightSettings, RelitSpheres, Sphere, evaluation_region, relight};

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
    /// Pose errors, when an estimated pose was given.
    #[serde(flatten)]
    pub pose: Option<PoseErrors>,
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

impl SceneTruth {
    /// Reads `camera.json` and `gt_env.exr` of a scene folder.
    pub fn read(scene: &Path) -> Result<Self> {
        let camera = Camera::read(scene_file(scene, "camera.json")?)?;
        let env = EnvMap::read(scene_file(scene, "gt_env.exr")?)?;
        Ok(Self { camera, env })
    }
}

/// Evaluates an estimated env map (and optionally an estimated pose) against a scene's truth.
pub fn evaluate_scene(
    scene: &Path,
    estimate: &EnvMap,
    estimated_pose: Option<&Pose>,
    settings: &RelightSettings,
) -> Result<EvalReport> {
    let truth = SceneTruth::read(scene)?;
    let pose = match estimated_pose {
        Some(est) => Some(pose_errors(est, &Pose::read(scene_file(scene, "pose.json")?)?)),
        None => None,
    };
    let [mirror, shiny, diffuse] = relighting_errors(estimate, &truth.env, &truth.camera, settings)?;
    Ok(EvalReport {
        scene: scene.display().to_string(),
        mirror,
        shiny,
        diffuse,
        speckle: speckle(estimate),
        pose,
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
            pose: None,
        };
        assert_eq!(
            report.to_json_line(),
            r#"{"scene":"s","mirror":{"angular_deg":1.0,"si_rmse":0.5},"shiny":{"angular_deg":1.0,"si_rmse":0.5},"diffuse":{"angular_deg":1.0,"si_rmse":0.5},"speckle":[0.25,0.0,0.5]}"#
        );
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
    }
}
