//! `alp study stability`: the estimate under what breaks methods, each at
//! graded strengths, and the paper's ablations (PAPER.md: pose priors,
//! light smoothness, several starts, joint optimisation).

use std::sync::Arc;

use crate::error::{Error, Result};
use crate::estimate::Photo;
use crate::estimate::settings::{Settings, yaws};
use crate::objective::Objective;

use super::{Perturb, Perturbation, Variant, perturb};

/// The perturbations and ablations, in the order run and charted.
pub const PERTURBATIONS: [&str; 18] = [
    "mask_erode",
    "mask_dilate",
    "mask_traced",
    "mask_segmenter",
    "noise",
    "clip",
    "exposure_under",
    "exposure_over",
    "border",
    "small",
    "blur",
    "jpeg",
    "box",
    "one_start",
    "no_pose_priors",
    "no_light_smoothness",
    "joint_rounds",
    UNPERTURBED,
];

/// The photo as it is under the default settings: every line's level 0,
/// and what each perturbation is paired against.
pub const UNPERTURBED: &str = "unperturbed";

/// Seed of the added noise (the same on every scene and run).
const NOISE_SEED: u64 = 7;

/// Seed of a traced mask's strays (the same on every scene and run).
const TRACE_SEED: u64 = 11;

/// The share of the probe's pixels a JPEG's exposure brings to white.
const JPEG_CLIP_SHARE: f64 = 0.01;

/// A change of the photo at a strength.
type Change = fn(&Photo, f64) -> Result<Photo>;

/// The graded strengths of a perturbation of the photo, mildest first, and
/// the change at a strength.
fn graded(name: &str) -> Option<(Vec<f64>, Change)> {
    use perturb::*;
    Some(match name {
        "mask_erode" => (vec![1.0, 2.0, 3.0], |p, s| mask_grown(p, -(s as i32))),
        "mask_dilate" => (vec![1.0, 2.0, 3.0], |p, s| mask_grown(p, s as i32)),
        "mask_traced" => (vec![1.0, 2.0, 3.0], |p, s| mask_traced(p, s as f32, TRACE_SEED)),
        "mask_segmenter" => (vec![1.0], |p, _| mask_segmented(p)),
        "noise" => (vec![0.01, 0.03, 0.1], |p, s| noisy(p, s as f32, NOISE_SEED)),
        "clip" => (vec![0.005, 0.02, 0.05], clipped),
        "exposure_under" => (vec![0.5, 0.25, 0.1], |p, s| exposed(p, s as f32)),
        "exposure_over" => (vec![2.0, 4.0, 10.0], |p, s| exposed(p, s as f32)),
        "border" => (vec![0.1, 0.25, 0.4], cut_by_border),
        "small" => (vec![120.0, 80.0, 40.0], |p, s| small(p, s as usize)),
        "blur" => (vec![0.5, 1.0, 2.0], |p, s| blurred(p, s as f32)),
        "jpeg" => (vec![95.0, 85.0, 75.0], |p, s| Ok(jpeg(p, s as u8, JPEG_CLIP_SHARE)?.0)),
        "box" => (vec![2.0, 5.0, 10.0], |p, s| {
            boxed(p, s as f32, &Settings::default().photo.probe_box)
        }),
        _ => return None,
    })
}

/// The variants of `name` at `threads`: a perturbation of the photo at
/// each of its strengths, or an ablation (level 1); `unperturbed` is the
/// default setting on the photo as it is (level 0 of every line).
pub fn variants(name: &str, threads: usize) -> Result<Vec<Variant>> {
    if let Some((strengths, change)) = graded(name) {
        return Ok(strengths
            .iter()
            .enumerate()
            .map(|(k, &strength)| {
                let apply: Perturb = Box::new(move |photo| change(photo, strength));
                Variant {
                    perturbation: Some(Perturbation {
                        level: k + 1,
                        strength,
                        apply,
                    }),
                    ..Variant::estimate(name, format!("{name}={strength}"), threads, |_, _| {})
                }
            })
            .collect());
    }
    let ablation = |apply: super::Apply| Variant {
        perturbation: Some(Perturbation {
            level: 1,
            strength: 1.0,
            apply: Box::new(|photo| Ok(photo.clone())),
        }),
        ..Variant::estimate(name, name.to_string(), threads, move |s, pose| apply(s, pose))
    };
    Ok(match name {
        UNPERTURBED => vec![Variant {
            perturbation: Some(Perturbation {
                level: 0,
                strength: 0.0,
                apply: Box::new(|photo| Ok(photo.clone())),
            }),
            ..Variant::estimate(name, name.to_string(), threads, |_, _| {})
        }],
        "one_start" => vec![ablation(Box::new(|s, _| s.orientation.starts_deg = yaws(1)))],
        "no_pose_priors" => vec![ablation(Box::new(|s, _| {
            s.objective = Arc::new(Objective::paper_default().without(&["barycenter", "orientation"]))
        }))],
        "no_light_smoothness" => vec![ablation(Box::new(|s, _| {
            s.objective = Arc::new(Objective::paper_default().without(&["neighbour_smoothness"]));
            s.lighting.smoothness = 0.0;
            s.joint.map_smoothness = 0.0;
        }))],
        "joint_rounds" => vec![ablation(Box::new(|s, _| s.joint.rounds = 2))],
        other => {
            return Err(Error::invalid(
                "--perturbations",
                format!("`{other}` is not one of {}", PERTURBATIONS.join(", ")),
            ));
        }
    })
}

/// The photo as it is, then every variant of `names`.
pub fn sweep(names: &[String], threads: usize) -> Result<Vec<Variant>> {
    let mut all = variants(UNPERTURBED, threads)?;
    for name in names.iter().filter(|n| *n != UNPERTURBED) {
        all.extend(variants(name, threads)?);
    }
    Ok(all)
}

#[cfg(test)]
mod tests {
    use super::*;
    use render::pose::Pose;

    #[test]
    fn every_perturbation_has_graded_unique_variants_and_ablations_change_the_settings() {
        let names: Vec<String> = PERTURBATIONS.iter().map(|p| p.to_string()).collect();
        let all = sweep(&names, 2).expect("a sweep");
        let mut ids: Vec<&str> = all.iter().map(|v| v.id.as_str()).collect();
        ids.sort();
        ids.dedup();
        assert_eq!(ids.len(), all.len());
        assert_eq!(all[0].perturbation.as_ref().map(|p| p.level), Some(0));
        for v in all.iter().filter(|v| graded(&v.family).is_some()) {
            let level = v.perturbation.as_ref().expect("perturbed").level;
            assert!((1..=3).contains(&level), "{}", v.id);
        }
        let default = serde_json::to_string(&crate::estimate::Settings::default()).expect("json");
        for name in ["one_start", "no_light_smoothness", "joint_rounds"] {
            let v = &variants(name, 2).expect("an ablation")[0];
            let super::super::Method::Estimate(apply) = &v.method else {
                panic!("ours")
            };
            let mut s = crate::estimate::Settings::default();
            apply(&mut s, &Pose::IDENTITY);
            assert_ne!(serde_json::to_string(&s).expect("json"), default, "{name}");
        }
        let v = &variants("no_pose_priors", 2).expect("an ablation")[0];
        let super::super::Method::Estimate(apply) = &v.method else {
            panic!("ours")
        };
        let mut s = crate::estimate::Settings::default();
        apply(&mut s, &Pose::IDENTITY);
        let names: Vec<&str> = s.objective.terms().iter().map(|t| t.term().name()).collect();
        assert!(!names.contains(&"barycenter") && !names.contains(&"orientation") && names.contains(&"chamfer"));
        assert!(variants("rain", 2).is_err());
    }
}
