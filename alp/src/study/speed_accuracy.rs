//! `alp study speed-accuracy`: the knobs that trade time for accuracy, each
//! swept on its own from the default setting.

use crate::error::{Error, Result};
use crate::estimate::settings::ADAM_LIGHTING;
use crate::estimate::settings::{LightModel, yaws};
use crate::estimate::{Quality, Settings};

use super::{Apply, Method, Variant};

/// The knob families, in the order swept and charted.
pub const FAMILIES: [&str; 10] = [
    "quality",
    "spp",
    "starts",
    "map",
    "model",
    "pose-draws",
    "lighting",
    "threads",
    "true-pose",
    "mitsuba",
];

/// The families that are no knob turned from the default setting: the
/// lighting alone at the true pose, and the outside method (their chart
/// lines do not pass through the default).
pub const APART: [&str; 2] = ["true-pose", "mitsuba"];

/// The families of modelling choices, tabled per probe family beside the
/// default (`model.md`): what each buys on which probe.
pub const MODELLING: [&str; 3] = ["map", "model", "pose-draws"];

/// Adam iterations of the outside method's settings.
pub const MITSUBA_ITERS: [usize; 2] = [200, 1000];

/// The settings of `family` (the default setting not among them): every
/// quality preset; the searches' and the final solve's samples per pixel
/// halved and doubled or more; 1 to 12 orientation starts; fixed working
/// map resolutions against the automatic one; the light transport without
/// one bounce of inter-reflection, without the probe's shadows on itself,
/// and with BRDF samples alone instead of MIS; the output map solved over
/// poses drawn within the pose's uncertainty (`K` = 3 or 5 poses, and 3 at
/// twice the spread) instead of the found pose alone; the paper's Adam lighting
/// solve; 1 and 2 threads (the default runs at the study's `threads`); the
/// lighting alone at the true pose (`true-pose`); and the outside method,
/// Mitsuba 3 fitting the map by Adam at the true pose (`mitsuba`).
pub fn family(name: &str, threads: usize) -> Result<Vec<Variant>> {
    let ours = |id: String, apply: Apply| Variant::estimate(name, id, threads, move |s, pose| apply(s, pose));
    let variants = match name {
        "quality" => [Quality::Fast, Quality::Best]
            .into_iter()
            .map(|q| {
                let id = format!("quality={}", if q == Quality::Fast { "fast" } else { "best" });
                ours(id, Box::new(move |s, _| *s = Settings::new(q)))
            })
            .collect(),
        "spp" => {
            let search = [8, 32].map(|n| {
                ours(
                    format!("spp_search={n}"),
                    Box::new(move |s, _| {
                        s.lighting.spp_pilot = n;
                        s.lighting.spp_lean = n;
                    }),
                )
            });
            let last =
                [32, 512].map(|n| ours(format!("spp_final={n}"), Box::new(move |s, _| s.lighting.spp_final = n)));
            search.into_iter().chain(last).collect()
        }
        "starts" => [1, 2, 4, 12]
            .into_iter()
            .map(|n| {
                ours(
                    format!("starts={n}"),
                    Box::new(move |s, _| s.orientation.starts_deg = yaws(n)),
                )
            })
            .collect(),
        "map" => [16, 32, 64]
            .into_iter()
            .map(|h| {
                ours(
                    format!("map_height={h}"),
                    Box::new(move |s, _| s.lighting.working_height = Some(h)),
                )
            })
            .collect(),
        "model" => {
            let without = |id: &str, change: fn(&mut LightModel)| {
                ours(
                    format!("model={id}"),
                    Box::new(move |s, _| change(&mut s.lighting.model)),
                )
            };
            vec![
                without("no_interreflection", |m| m.interreflection = false),
                without("no_shadows", |m| m.shadows = false),
                without("bsdf_only", |m| m.mis = false),
            ]
        }
        "pose-draws" => {
            let draws = |axes: usize, spread: f64| {
                ours(
                    format!("pose_draws={}x{spread}", 1 + 2 * axes),
                    Box::new(move |s, _| {
                        s.lighting.pose_draw_axes = axes;
                        s.pose_search.uncertainty_scale *= spread;
                    }),
                )
            };
            vec![draws(1, 1.0), draws(2, 1.0), draws(1, 2.0)]
        }
        "lighting" => vec![ours(
            "lighting=adam".into(),
            Box::new(|s, _| s.lighting.method = ADAM_LIGHTING),
        )],
        "threads" => [1, 2]
            .into_iter()
            .filter(|&n| n != threads)
            .map(|n| Variant::estimate(name, format!("threads={n}"), n, |_, _| {}))
            .collect(),
        "true-pose" => vec![ours(
            "pose=true".into(),
            Box::new(|s, truth| s.known_pose = Some(*truth)),
        )],
        "mitsuba" => MITSUBA_ITERS
            .iter()
            .map(|&iters| Variant {
                family: name.into(),
                id: format!("mitsuba_adam={iters}"),
                threads,
                method: Method::MitsubaAdam { iters },
                perturbation: None,
            })
            .collect(),
        other => {
            return Err(Error::invalid(
                "--families",
                format!("`{other}` is not one of {}", FAMILIES.join(", ")),
            ));
        }
    };
    Ok(variants)
}

/// The default setting, then every setting of `families`.
pub fn sweep(families: &[String], threads: usize) -> Result<Vec<Variant>> {
    let mut variants = vec![Variant::default_setting(threads)];
    for name in families {
        variants.extend(family(name, threads)?);
    }
    Ok(variants)
}

#[cfg(test)]
mod tests {
    use super::*;
    use render::pose::Pose;

    #[test]
    fn every_family_changes_the_setting_it_names_and_ids_are_unique() {
        let all: Vec<String> = FAMILIES.iter().map(|f| f.to_string()).collect();
        let variants = sweep(&all, 2).expect("a sweep");
        let mut ids: Vec<&str> = variants.iter().map(|v| v.id.as_str()).collect();
        ids.sort();
        ids.dedup();
        assert_eq!(ids.len(), variants.len(), "ids repeat");
        let default = serde_json::to_string(&Settings::default()).expect("json");
        for v in &variants[1..] {
            let Method::Estimate(apply) = &v.method else {
                assert_eq!(v.family, "mitsuba");
                continue;
            };
            let mut s = Settings::default();
            apply(&mut s, &Pose::IDENTITY);
            let changed =
                serde_json::to_string(&s).expect("json") != default || v.threads != 2 || s.known_pose.is_some();
            assert!(changed, "{} changes nothing", v.id);
        }
        assert_eq!(variants.iter().filter(|v| v.family == "threads").count(), 1);
        assert!(sweep(&["colour".into()], 2).is_err());
    }
}
