//! Each setting against the reference setting (the default, or the photo
//! unperturbed) scene by scene: the mean and standard error of the
//! per-scene change in each sphere's angular error, and the median
//! per-scene time ratio. Scenes differ far more than settings do, so a
//! change is judged against the noise of these paired differences, not by
//! comparing two means.

use crate::relight::Sphere;

use super::record::{Row, csv_text};
use super::summary::{first_seen, median};

/// How many standard errors a mean change must exceed to be called past
/// the noise of the scene set (about 95 % two-sided).
pub const PAST_NOISE: f64 = 2.0;

/// One setting against the reference, over the scenes both succeeded on.
#[derive(Clone, Debug, PartialEq)]
pub struct Paired {
    /// The knob family or perturbation.
    pub family: String,
    /// The setting.
    pub variant: String,
    /// Scenes with an angular error under both.
    pub scenes: usize,
    /// Per sphere (mirror, shiny, diffuse): the mean of the setting's error
    /// minus the reference's, degrees.
    pub mean_deg: [f64; 3],
    /// Per sphere: the standard error of that mean (NaN below 2 scenes).
    pub stderr_deg: [f64; 3],
    /// The median of the setting's wall time over the reference's.
    pub time_ratio: f64,
}

impl Paired {
    /// Whether sphere `k`'s mean change exceeds [`PAST_NOISE`] standard errors.
    pub fn past_noise(&self, k: usize) -> bool {
        self.mean_deg[k].abs() > PAST_NOISE * self.stderr_deg[k]
    }
}

/// Every setting of `rows` but `reference`, in the order first run, paired
/// with `reference` on each scene; settings sharing no scene are left out.
pub fn paired(rows: &[Row], reference: &str) -> Vec<Paired> {
    let runs: Vec<&Row> = rows.iter().filter(|r| r.variant != reference).collect();
    each_against(&runs, |_, scene| {
        rows.iter().find(|r| r.variant == reference && r.scene == scene)
    })
}

/// Every setting of `rows` paired with the same setting's run on the same
/// scene in `before` (an earlier build's rows): what a change of the code
/// did, setting by setting. Settings `before` never ran are left out.
pub fn against_before(rows: &[Row], before: &[Row]) -> Vec<Paired> {
    let runs: Vec<&Row> = rows.iter().collect();
    each_against(&runs, |variant, scene| {
        before.iter().find(|r| r.variant == variant && r.scene == scene)
    })
}

/// Each setting of `runs`, in the order first run, against the reference
/// run `reference_on(setting, scene)` finds, over the scenes both scored.
fn each_against<'a>(runs: &[&Row], reference_on: impl Fn(&str, &str) -> Option<&'a Row>) -> Vec<Paired> {
    first_seen(runs.iter().copied(), |r| &r.variant)
        .into_iter()
        .filter_map(|variant| {
            let of_variant: Vec<&Row> = runs.iter().copied().filter(|r| r.variant == variant).collect();
            let pairs: Vec<([f64; 3], f64)> = (of_variant.iter())
                .filter_map(|r| {
                    let reference = reference_on(variant, &r.scene)?;
                    let (ours, theirs) = (r.angular()?, reference.angular()?);
                    Some((
                        std::array::from_fn(|k| ours[k] - theirs[k]),
                        r.wall_s / reference.wall_s,
                    ))
                })
                .collect();
            let n = pairs.len();
            (n > 0).then(|| {
                let mean_deg: [f64; 3] = std::array::from_fn(|k| pairs.iter().map(|p| p.0[k]).sum::<f64>() / n as f64);
                let stderr_deg = std::array::from_fn(|k| {
                    let squares: f64 = pairs.iter().map(|p| (p.0[k] - mean_deg[k]).powi(2)).sum();
                    match n {
                        1 => f64::NAN,
                        _ => (squares / (n - 1) as f64 / n as f64).sqrt(),
                    }
                });
                let mut ratios: Vec<f64> = pairs.iter().map(|p| p.1).filter(|r| r.is_finite()).collect();
                ratios.sort_by(f64::total_cmp);
                Paired {
                    family: of_variant[0].family.clone(),
                    variant: variant.to_string(),
                    scenes: n,
                    mean_deg,
                    stderr_deg,
                    time_ratio: median(&ratios),
                }
            })
        })
        .collect()
}

/// The paired changes as CSV.
pub fn to_csv(all: &[Paired]) -> String {
    let mut text = String::from(
        "family,variant,scenes,mirror_change_deg,mirror_stderr_deg,shiny_change_deg,shiny_stderr_deg,\
         diffuse_change_deg,diffuse_stderr_deg,time_ratio\n",
    );
    for p in all {
        let mut fields = vec![csv_text(&p.family), csv_text(&p.variant), p.scenes.to_string()];
        for k in 0..3 {
            fields.push(format!("{:.4}", p.mean_deg[k]));
            fields.push(format!("{:.4}", p.stderr_deg[k]));
        }
        fields.push(format!("{:.3}", p.time_ratio));
        text += &fields.join(",");
        text.push('\n');
    }
    text
}

/// The paired changes as a Markdown table, changes past the noise in bold;
/// `reference` names the runs they are paired with, in Markdown.
pub fn to_markdown(all: &[Paired], reference: &str) -> String {
    let names = Sphere::ALL.map(Sphere::name).join(" / ");
    let mut text = format!(
        "| family | setting | scenes | change in angular error against {reference}, {names} (deg, mean +- s.e.) | \
         time ratio (median) |\n|---|---|---|---|---|\n"
    );
    for p in all {
        let changes: Vec<String> = (0..3)
            .map(|k| {
                let change = format!("{:+.2} +- {:.2}", p.mean_deg[k], p.stderr_deg[k]);
                match p.past_noise(k) {
                    true => format!("**{change}**"),
                    false => change,
                }
            })
            .collect();
        text += &format!(
            "| {} | {} | {} | {} | {:.2} |\n",
            p.family,
            p.variant,
            p.scenes,
            changes.join(" / "),
            p.time_ratio
        );
    }
    text += &format!(
        "\nEach setting's error minus that of {reference} on the same scene; bold: past {PAST_NOISE} standard errors.\n"
    );
    text
}

#[cfg(test)]
mod tests {
    use super::*;

    fn row(scene: &str, variant: &str, mirror: f64, wall_s: f64) -> Row {
        Row {
            mirror_deg: Some(mirror),
            shiny_deg: Some(1.0),
            diffuse_deg: Some(1.0),
            wall_s,
            ..Row::unscored(scene, "f", variant, 1)
        }
    }

    #[test]
    fn changes_are_paired_by_scene_and_judged_by_their_standard_error() {
        let rows = [
            row("a", "default", 1.0, 10.0),
            row("b", "default", 9.0, 20.0),
            row("c", "default", 5.0, 10.0),
            // Much worse on average but scattered: within the noise.
            row("a", "noisy", 1.0, 5.0),
            row("b", "noisy", 15.0, 10.0),
            row("c", "noisy", 5.0, 5.0),
            // Slightly worse on every scene: past the noise.
            row("a", "steady", 1.5, 30.0),
            row("b", "steady", 9.4, 60.0),
            row("c", "steady", 5.6, 40.0),
            // Only on a scene the default did not score.
            row("d", "alone", 1.0, 1.0),
        ];
        let all = paired(&rows, "default");
        assert_eq!(
            all.iter().map(|p| p.variant.as_str()).collect::<Vec<_>>(),
            ["noisy", "steady"]
        );
        let (noisy, steady) = (&all[0], &all[1]);
        assert_eq!(noisy.scenes, 3);
        assert!((noisy.mean_deg[0] - 2.0).abs() < 1e-12);
        // Differences 0, 6, 0: s.d. sqrt(12), s.e. 2.
        assert!((noisy.stderr_deg[0] - 2.0).abs() < 1e-12);
        assert!(!noisy.past_noise(0));
        assert_eq!(noisy.time_ratio, 0.5);
        assert!(steady.past_noise(0) && !steady.past_noise(1), "{steady:?}");
        assert_eq!(steady.time_ratio, 3.0);
        let table = to_markdown(&all, "`default`");
        assert!(
            table.contains("| f | noisy | 3 | +2.00 +- 2.00 / +0.00 +- 0.00 / +0.00 +- 0.00 | 0.50 |"),
            "{table}"
        );
        assert!(table.contains("| f | steady | 3 | **+0.50 +- 0.06** /"), "{table}");
        assert_eq!(to_csv(&all).lines().count(), 3);
    }

    #[test]
    fn each_setting_is_paired_with_its_own_earlier_run() {
        // Scene, setting, mirror error, wall: "new" is a setting the earlier
        // run does not have, "gone" one this run does not.
        let rows = [
            ("a", "default", 2.0, 5.0),
            ("b", "default", 3.0, 6.0),
            ("a", "fast", 4.0, 1.0),
            ("a", "new", 1.0, 1.0),
        ]
        .map(|(scene, variant, mirror, wall)| row(scene, variant, mirror, wall));
        let before = [
            ("a", "default", 1.0, 10.0),
            ("b", "default", 1.0, 12.0),
            ("a", "fast", 5.0, 2.0),
            ("a", "gone", 1.0, 1.0),
        ]
        .map(|(scene, variant, mirror, wall)| row(scene, variant, mirror, wall));
        let all = against_before(&rows, &before);
        assert_eq!(
            all.iter().map(|p| p.variant.as_str()).collect::<Vec<_>>(),
            ["default", "fast"]
        );
        let (default, fast) = (&all[0], &all[1]);
        // Differences 1 and 2: mean 1.5, s.d. sqrt(0.5), s.e. 0.5.
        assert_eq!((default.scenes, default.time_ratio), (2, 0.5));
        assert!((default.mean_deg[0] - 1.5).abs() < 1e-12 && (default.stderr_deg[0] - 0.5).abs() < 1e-12);
        assert_eq!((fast.scenes, fast.mean_deg[0], fast.time_ratio), (1, -1.0, 0.5));
    }

    #[test]
    fn a_failed_run_drops_its_scene_from_the_pairs() {
        let mut failed = row("b", "other", 2.0, 1.0);
        failed.mirror_deg = None;
        failed.error = Some("no".into());
        let rows = [
            row("a", "default", 1.0, 1.0),
            row("b", "default", 1.0, 1.0),
            row("a", "other", 2.0, 2.0),
            failed,
        ];
        let all = paired(&rows, "default");
        assert_eq!(all[0].scenes, 1);
        assert!(all[0].stderr_deg[0].is_nan() && !all[0].past_noise(0));
    }
}
