//! Every discrete choice the photo made, with the margin it won by: the
//! chosen pose against its rival (another end, a half turn, where the
//! probe's symmetry does not make them alike), the blur, each
//! light brighter than the sensor. A choice won by less than its noise is
//! a guess the photo could not settle: it goes into `report.json`'s
//! `warnings`, which `alp estimate` prints.

use serde::Serialize;

use super::blur::BlurChoice;
use super::lighting::{ClippedLight, PowerTold};
use super::pose::uncertainty::PoseUncertainty;
use super::report::RivalReport;
use super::settings::Settings;

/// One choice and its evidence.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Decision {
    /// What was chosen between: `rival` (the searched pose or its rival),
    /// `blur` (the blur read or none), `clipped_light` (a light's power
    /// told or only bounded).
    pub name: &'static str,
    /// What was kept.
    pub chosen: String,
    /// By how much the kept option beat the other, in `unit` (negative:
    /// it lost, and was kept by the rule that a change must win by the
    /// noise).
    pub margin: f64,
    /// The margin's noise, in `unit`: below it the photo did not decide.
    pub noise: f64,
    /// The unit of both.
    pub unit: &'static str,
}

impl Decision {
    /// Whether the photo decided it: the margin beyond its noise.
    pub fn decided(&self) -> bool {
        self.margin >= self.noise
    }
}

/// What the choices were made from.
pub(super) struct Choices<'a> {
    pub(super) rival: Option<&'a RivalReport>,
    pub(super) blur: Option<&'a BlurChoice>,
    pub(super) clipped_lights: &'a [ClippedLight],
    pub(super) pose_uncertainty: Option<&'a PoseUncertainty>,
}

/// The choices' decisions, and a warning for each the photo did not settle
/// (and for a part of the pose it tells to no better than
/// `PoseSearchSettings::warn_sigma_px`).
pub(super) fn decisions(choices: &Choices, settings: &Settings) -> (Vec<Decision>, Vec<String>) {
    let mut decisions = Vec::new();
    // The choice is against the rivals the probe's own symmetry does not
    // make alike: the kept pose (the searched one, or the rival if it won
    // and is no twin of it) against the best of them.
    if let Some((rival, distinct_db)) = choices.rival.and_then(|r| r.distinct_db.map(|d| (r, d))) {
        let (chosen, margin) = match rival.kept_rival && !rival.alike {
            true => ("rival", rival.rival_db - rival.chosen_db),
            false => {
                let kept_db = if rival.kept_rival {
                    rival.rival_db
                } else {
                    rival.chosen_db
                };
                ("searched", kept_db - distinct_db)
            }
        };
        decisions.push(Decision {
            name: "rival",
            chosen: chosen.into(),
            margin: if margin.is_nan() { f64::INFINITY } else { margin },
            noise: settings.pose_search.search_margin_db,
            unit: "dB",
        });
    }
    if let Some(blur) = choices.blur {
        let kept = blur.blur_px > 0.0;
        decisions.push(Decision {
            name: "blur",
            chosen: format!("{:.2} px", blur.blur_px),
            margin: if kept { blur.margin_se } else { -blur.margin_se },
            noise: settings.photo.blur.test_margin_se,
            unit: "standard errors",
        });
    }
    for light in choices.clipped_lights {
        let bounded = light.power_told == PowerTold::LowerBound;
        decisions.push(Decision {
            name: "clipped_light",
            chosen: match bounded {
                true => "lower_bound".into(),
                false => "fitted".into(),
            },
            margin: if bounded { 0.0 } else { 1.0 },
            noise: 1.0,
            unit: "told (1) or bounded (0)",
        });
    }
    let mut warnings: Vec<String> = (decisions.iter())
        .filter(|d| !d.decided() && d.name != "clipped_light")
        .map(warning)
        .collect();
    // The lights held only by their bounds, in one warning.
    let bounded: Vec<&ClippedLight> = (choices.clipped_lights.iter())
        .filter(|l| l.power_told == PowerTold::LowerBound)
        .collect();
    if !bounded.is_empty() {
        let share: f64 = bounded.iter().map(|l| l.share_of_map).sum();
        warnings.push(format!(
            "clipped lights: {} light(s) brighter than the sensor, {:.0} % of the map's power, are only lower \
             bounds (their pixels are clipped and nothing else in the photo tells them): the map holds at least that",
            bounded.len(),
            100.0 * share
        ));
    }
    if let Some(uncertainty) = choices.pose_uncertainty {
        let carried = match settings.lighting.pose_draw_axes {
            0 => "the map is solved at the found pose and may be warped where it is off",
            _ => "the map is solved over the poses it cannot tell apart",
        };
        for (part, px) in &uncertainty.sigma_px {
            if *px >= settings.pose_search.warn_sigma_px {
                warnings.push(format!(
                    "pose: the photo tells its {part} only to {:.2} (one deviation moves the probe {px:.1} px): \
                     {carried}",
                    uncertainty.sigma[part].unwrap_or(f64::NAN)
                ));
            }
        }
    }
    (decisions, warnings)
}

/// The warning for a choice the photo did not settle.
fn warning(d: &Decision) -> String {
    match d.name {
        "rival" => format!(
            "rival: the {} pose won by {:.2} dB, within the searches' noise of {:.2} dB: \
             the probe may be the other way round (another end or a half turn)",
            d.chosen, d.margin, d.noise
        ),
        _ => format!(
            "blur: {} kept by {:.1} standard errors, under {:.1}: the photo hardly tells its blur",
            d.chosen, d.margin, d.noise
        ),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_choice_won_within_its_noise_is_a_warning() {
        let settings = Settings::default();
        let rival = |chosen_db, rival_db: f64, kept_rival| RivalReport {
            rival_axis: [0.0, 1.0, 0.0],
            chosen_db,
            rival_db,
            kept_rival,
            alike: false,
            distinct_db: Some(rival_db),
        };
        let at = |r: &RivalReport| {
            decisions(
                &Choices {
                    rival: Some(r),
                    blur: None,
                    clipped_lights: &[],
                    pose_uncertainty: None,
                },
                &settings,
            )
        };
        let (d, w) = at(&rival(12.0, 11.0, false));
        assert_eq!((d[0].chosen.as_str(), d[0].margin), ("searched", 1.0));
        assert!(w.is_empty());
        // The rival a tenth of a dB better, not by the margin: kept the
        // searched pose, with a warning.
        let (d, w) = at(&rival(12.0, 12.1, false));
        assert!((d[0].margin + 0.1).abs() < 1e-9);
        assert_eq!(w.len(), 1, "{w:?}");
        assert!(w[0].starts_with("rival"));
        // A rival that could not be scored is no doubt.
        let (d, w) = at(&rival(12.0, f64::NEG_INFINITY, false));
        assert!(d[0].decided() && w.is_empty());
        // Nor is one the probe's symmetry makes alike (a ring's other end).
        let alike = RivalReport {
            alike: true,
            distinct_db: None,
            ..rival(12.0, 12.1, false)
        };
        let (d, w) = at(&alike);
        assert!(d.is_empty() && w.is_empty(), "{d:?} {w:?}");
        // A twin (a cap's half turn) kept by 0.4 dB, the other end 1.5 dB
        // behind the searched pose: the choice is against the other end.
        let twin = RivalReport {
            alike: true,
            distinct_db: Some(10.5),
            ..rival(12.0, 12.4, true)
        };
        let (d, w) = at(&twin);
        assert_eq!(d[0].chosen, "searched");
        assert!((d[0].margin - 1.9).abs() < 1e-9 && w.is_empty(), "{d:?}");
    }
}
