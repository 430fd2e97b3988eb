//! A study's rows summed up per setting: mean errors, poses found, median
//! wall time, peak memory, and which settings lie on the Pareto front of
//! time against error.

use crate::relight::Sphere;

use super::record::{Row, csv_text};

/// One setting over every scene it ran on.
#[derive(Clone, Debug, PartialEq)]
pub struct VariantSummary {
    /// The knob family.
    pub family: String,
    /// The setting.
    pub variant: String,
    /// Runs.
    pub runs: usize,
    /// Runs that ended in an error.
    pub failed: usize,
    /// Mean angular error per sphere (mirror, shiny, diffuse) over the runs that succeeded.
    pub angular_deg: [f64; 3],
    /// Runs whose pose was found, of those that searched for it.
    pub poses_found: usize,
    /// Runs that searched for the pose (and did not fail).
    pub poses_sought: usize,
    /// Median wall time per image, seconds.
    pub median_wall_s: f64,
    /// The largest peak resident memory, MB.
    pub peak_mb: Option<f64>,
    /// Per sphere: whether no other setting is both as fast and as accurate
    /// and better in one of the two.
    pub pareto: [bool; 3],
}

/// The summaries of `rows`, one per variant in the order first run; the
/// Pareto front is drawn among the families not in `apart` (those given
/// what the others search for, the true pose, solve an easier problem).
pub fn summarize(rows: &[Row], apart: &[&str]) -> Vec<VariantSummary> {
    let order = first_seen(rows, |r| &r.variant);
    let mut summaries: Vec<VariantSummary> = order
        .iter()
        .map(|&variant| {
            let runs: Vec<&Row> = rows.iter().filter(|r| r.variant == variant).collect();
            let errors: Vec<[f64; 3]> = runs.iter().filter_map(|r| r.angular()).collect();
            let angular_deg =
                std::array::from_fn(|k| errors.iter().map(|e| e[k]).sum::<f64>() / errors.len().max(1) as f64);
            let mut walls: Vec<f64> = runs.iter().map(|r| r.wall_s).collect();
            walls.sort_by(f64::total_cmp);
            let median_wall_s = if walls.is_empty() { 0.0 } else { median(&walls) };
            VariantSummary {
                family: runs[0].family.clone(),
                variant: variant.to_string(),
                runs: runs.len(),
                failed: runs.len() - errors.len(),
                angular_deg: if errors.is_empty() { [f64::NAN; 3] } else { angular_deg },
                poses_found: runs.iter().filter(|r| r.pose_found == Some(true)).count(),
                poses_sought: runs.iter().filter(|r| r.pose_found.is_some()).count(),
                median_wall_s,
                peak_mb: runs.iter().filter_map(|r| r.peak_mb).reduce(f64::max),
                pareto: [false; 3],
            }
        })
        .collect();
    for k in 0..3 {
        let points: Vec<(f64, f64)> = summaries
            .iter()
            .map(|s| match apart.contains(&s.family.as_str()) {
                true => (f64::NAN, f64::NAN),
                false => (s.median_wall_s, s.angular_deg[k]),
            })
            .collect();
        for (s, &(t, e)) in summaries.iter_mut().zip(&points) {
            s.pareto[k] = e.is_finite()
                && !points
                    .iter()
                    .any(|&(t2, e2)| e2.is_finite() && t2 <= t && e2 <= e && (t2 < t || e2 < e));
        }
    }
    summaries
}

/// The summaries as CSV.
pub fn to_csv(summaries: &[VariantSummary]) -> String {
    let mut text = String::from(
        "family,variant,runs,failed,mirror_deg,shiny_deg,diffuse_deg,poses_found,poses_sought,median_wall_s,peak_mb,\
         pareto_mirror,pareto_shiny,pareto_diffuse\n",
    );
    for s in summaries {
        let fields = [
            csv_text(&s.family),
            csv_text(&s.variant),
            s.runs.to_string(),
            s.failed.to_string(),
            format!("{:.4}", s.angular_deg[0]),
            format!("{:.4}", s.angular_deg[1]),
            format!("{:.4}", s.angular_deg[2]),
            s.poses_found.to_string(),
            s.poses_sought.to_string(),
            format!("{:.3}", s.median_wall_s),
            s.peak_mb.map(|m| format!("{m:.1}")).unwrap_or_default(),
            s.pareto[0].to_string(),
            s.pareto[1].to_string(),
            s.pareto[2].to_string(),
        ];
        text += &fields.join(",");
        text.push('\n');
    }
    text
}

/// The summaries as a Markdown table; `*` marks a point on the front.
pub fn to_markdown(summaries: &[VariantSummary]) -> String {
    let names = Sphere::ALL.map(Sphere::name).join(" / ");
    let mut text = format!(
        "| family | setting | runs | mean angular error, {names} (deg) | poses found | median wall (s) | peak MB |\n\
         |---|---|---|---|---|---|---|\n"
    );
    for s in summaries {
        let errors: Vec<String> = (0..3)
            .map(|k| format!("{:.2}{}", s.angular_deg[k], if s.pareto[k] { "*" } else { "" }))
            .collect();
        let failed = match s.failed {
            0 => String::new(),
            n => format!(" ({n} failed)"),
        };
        text += &format!(
            "| {} | {} | {}{} | {} | {} | {:.2} | {} |\n",
            s.family,
            s.variant,
            s.runs,
            failed,
            errors.join(" / "),
            match s.poses_sought {
                0 => "- (given)".to_string(),
                n => format!("{} / {n}", s.poses_found),
            },
            s.median_wall_s,
            s.peak_mb.map(|m| format!("{m:.0}")).unwrap_or_else(|| "-".into()),
        );
    }
    text += "\n`*`: on the Pareto front of median wall time against that sphere's mean error, among the \
             settings that search for the pose.\n";
    text
}

/// The settings of `families` and the default, summed up apart per probe
/// family (each row's `probe`), probe families in the order first run:
/// what a modelling choice buys on which probe. No front is drawn.
pub fn by_probe(rows: &[Row], families: &[&str], default: &str) -> Vec<(String, Vec<VariantSummary>)> {
    first_seen(rows, |r| &r.probe)
        .into_iter()
        .map(|probe| {
            let kept: Vec<Row> = (rows.iter())
                .filter(|r| r.probe == probe && (r.variant == default || families.contains(&r.family.as_str())))
                .cloned()
                .collect();
            let mut summaries = summarize(&kept, families);
            summaries.iter_mut().for_each(|s| s.pareto = [false; 3]);
            (probe.to_string(), summaries)
        })
        .filter(|(_, summaries)| summaries.iter().any(|s| s.variant != default))
        .collect()
}

/// [`by_probe`]'s groups as CSV: [`to_csv`]'s columns after a `probe` column.
pub fn by_probe_csv(groups: &[(String, Vec<VariantSummary>)]) -> String {
    let mut text = String::new();
    for (probe, summaries) in groups {
        let table = to_csv(summaries);
        let mut lines = table.lines();
        let header = lines.next().unwrap_or_default();
        if text.is_empty() {
            text = format!("probe,{header}\n");
        }
        lines.for_each(|line| text += &format!("{},{line}\n", csv_text(probe)));
    }
    text
}

/// [`by_probe`]'s groups as one Markdown table, a probe family per block.
pub fn by_probe_markdown(groups: &[(String, Vec<VariantSummary>)]) -> String {
    let names = Sphere::ALL.map(Sphere::name).join(" / ");
    let mut text = format!(
        "| probe | setting | runs | mean angular error, {names} (deg) | poses found | median wall (s) |\n\
         |---|---|---|---|---|---|\n"
    );
    for (probe, summaries) in groups {
        for s in summaries {
            text += &format!(
                "| {probe} | {} | {} | {:.2} / {:.2} / {:.2} | {} / {} | {:.2} |\n",
                s.variant,
                s.runs,
                s.angular_deg[0],
                s.angular_deg[1],
                s.angular_deg[2],
                s.poses_found,
                s.poses_sought,
                s.median_wall_s
            );
        }
    }
    text
}

/// One perturbation at one strength (or an ablation) over every scene.
#[derive(Clone, Debug, PartialEq)]
pub struct StabilitySummary {
    /// The perturbation.
    pub family: String,
    /// The setting.
    pub variant: String,
    /// Its graded level (0: the photo as it is).
    pub level: usize,
    /// Its strength in its own unit.
    pub strength: f64,
    /// Runs that happened.
    pub runs: usize,
    /// Scenes that could not take the perturbation.
    pub skipped: usize,
    /// Runs that ended in an error (or a panic).
    pub failed: usize,
    /// Runs that ended with a warning.
    pub warned: usize,
    /// Runs whose map or pose held a value that is not finite.
    pub non_finite: usize,
    /// Runs whose pose was found, of those that searched for it.
    pub poses_found: usize,
    /// Runs that searched for the pose and did not fail.
    pub poses_sought: usize,
    /// Median angular error per sphere (mirror, shiny, diffuse), degrees.
    pub median_deg: [f64; 3],
    /// 90th percentile (nearest rank) per sphere, degrees.
    pub p90_deg: [f64; 3],
}

/// The distinct values of `key` over `rows`, in the order first seen.
pub(super) fn first_seen<'a>(rows: impl IntoIterator<Item = &'a Row>, key: fn(&Row) -> &str) -> Vec<&'a str> {
    let mut seen: Vec<&str> = Vec::new();
    for row in rows {
        let value = key(row);
        if !seen.contains(&value) {
            seen.push(value);
        }
    }
    seen
}

/// The median of sorted `values` (NaN for none).
pub(super) fn median(values: &[f64]) -> f64 {
    match values.len() {
        0 => f64::NAN,
        n if n % 2 == 1 => values[n / 2],
        n => 0.5 * (values[n / 2 - 1] + values[n / 2]),
    }
}

/// The `q` quantile of `values` by nearest rank (NaN for none).
fn quantile(values: &mut [f64], q: f64) -> f64 {
    if values.is_empty() {
        return f64::NAN;
    }
    values.sort_by(f64::total_cmp);
    let rank = (q * values.len() as f64).ceil().max(1.0) as usize;
    values[rank - 1]
}

/// The stability summaries of `rows`, one per variant in the order first run.
pub fn summarize_stability(rows: &[Row]) -> Vec<StabilitySummary> {
    let order = first_seen(rows, |r| &r.variant);
    order
        .iter()
        .map(|&variant| {
            let all: Vec<&Row> = rows.iter().filter(|r| r.variant == variant).collect();
            let ran: Vec<&Row> = all.iter().copied().filter(|r| r.skipped.is_none()).collect();
            let errors: Vec<[f64; 3]> = ran.iter().filter_map(|r| r.angular()).collect();
            let at =
                |q: f64| std::array::from_fn(|k| quantile(&mut errors.iter().map(|e| e[k]).collect::<Vec<_>>(), q));
            StabilitySummary {
                family: all[0].family.clone(),
                variant: variant.to_string(),
                level: all[0].level.unwrap_or(0),
                strength: all[0].strength.unwrap_or(0.0),
                runs: ran.len(),
                skipped: all.len() - ran.len(),
                failed: ran.iter().filter(|r| r.error.is_some()).count(),
                warned: ran.iter().filter(|r| r.warning.is_some()).count(),
                non_finite: ran.iter().filter(|r| r.non_finite).count(),
                poses_found: ran.iter().filter(|r| r.pose_found == Some(true)).count(),
                poses_sought: ran.iter().filter(|r| r.pose_found.is_some()).count(),
                median_deg: at(0.5),
                p90_deg: at(0.9),
            }
        })
        .collect()
}

/// The stability summaries as CSV.
pub fn stability_csv(summaries: &[StabilitySummary]) -> String {
    let mut text = String::from(
        "perturbation,variant,level,strength,runs,skipped,failed,warned,non_finite,poses_found,poses_sought,\
         median_mirror_deg,median_shiny_deg,median_diffuse_deg,p90_mirror_deg,p90_shiny_deg,p90_diffuse_deg\n",
    );
    for s in summaries {
        let mut fields = vec![
            csv_text(&s.family),
            csv_text(&s.variant),
            s.level.to_string(),
            format!("{}", s.strength),
            s.runs.to_string(),
            s.skipped.to_string(),
            s.failed.to_string(),
            s.warned.to_string(),
            s.non_finite.to_string(),
            s.poses_found.to_string(),
            s.poses_sought.to_string(),
        ];
        fields.extend(s.median_deg.iter().chain(&s.p90_deg).map(|v| format!("{v:.4}")));
        text += &fields.join(",");
        text.push('\n');
    }
    text
}

/// The stability summaries as a Markdown table.
pub fn stability_markdown(summaries: &[StabilitySummary]) -> String {
    let names = Sphere::ALL.map(Sphere::name).join(" / ");
    let mut text = format!(
        "| perturbation | setting | runs | poses found | median angular error, {names} (deg) | 90th percentile (deg) | \
         errors | warnings | non-finite | skipped |\n|---|---|---|---|---|---|---|---|---|---|\n"
    );
    let three = |v: &[f64; 3]| v.iter().map(|x| format!("{x:.2}")).collect::<Vec<_>>().join(" / ");
    let share = |n: usize, of: usize| match of {
        0 => "-".to_string(),
        _ => format!("{n} ({:.0} %)", 100.0 * n as f64 / of as f64),
    };
    for s in summaries {
        text += &format!(
            "| {} | {} | {} | {} / {} | {} | {} | {} | {} | {} | {} |\n",
            s.family,
            s.variant,
            s.runs,
            s.poses_found,
            s.poses_sought,
            three(&s.median_deg),
            three(&s.p90_deg),
            share(s.failed, s.runs),
            share(s.warned, s.runs),
            s.non_finite,
            s.skipped,
        );
    }
    text
}

#[cfg(test)]
mod tests {
    use super::*;

    fn row(variant: &str, wall_s: f64, mirror: f64) -> Row {
        Row {
            mirror_deg: Some(mirror),
            shiny_deg: Some(1.0),
            diffuse_deg: Some(1.0),
            pose_found: Some(mirror < 5.0),
            wall_s,
            peak_mb: Some(wall_s * 10.0),
            ..Row::unscored("s", "f", variant, 1)
        }
    }

    #[test]
    fn the_front_holds_what_nothing_beats_in_both_time_and_error() {
        let rows = [
            row("fast", 1.0, 6.0),
            row("slow-and-worse", 5.0, 7.0),
            row("default", 2.0, 4.0),
            row("default", 4.0, 4.0),
            row("best", 8.0, 3.0),
        ];
        let s = summarize(&rows, &[]);
        assert_eq!(
            s.iter().map(|s| s.variant.as_str()).collect::<Vec<_>>(),
            ["fast", "slow-and-worse", "default", "best"]
        );
        assert_eq!(s[2].median_wall_s, 3.0);
        assert_eq!(s[2].runs, 2);
        assert_eq!(s[2].peak_mb, Some(40.0));
        assert_eq!(
            s.iter().map(|s| s.pareto[0]).collect::<Vec<_>>(),
            [true, false, true, true]
        );
        // Shiny errors tie everywhere: only the fastest is on that front.
        assert_eq!(
            s.iter().map(|s| s.pareto[1]).collect::<Vec<_>>(),
            [true, false, false, false]
        );
        // A family apart (given the true pose) is never on the front.
        let apart = summarize(&rows, &["f"]);
        assert!(apart.iter().all(|s| !s.pareto.contains(&true)));
        let table = to_markdown(&s);
        assert!(
            table.contains("| f | default | 2 | 4.00* / 1.00 / 1.00 | 2 / 2 | 3.00 | 40 |"),
            "{table}"
        );
        assert_eq!(to_csv(&s).lines().count(), 5);
    }

    #[test]
    fn modelling_choices_are_tabled_per_probe_family_beside_the_default() {
        let on = |probe: &str, family: &str, variant: &str, mirror: f64| Row {
            probe: probe.into(),
            family: family.into(),
            ..row(variant, 2.0, mirror)
        };
        let rows = [
            on("can", "default", "default", 3.0),
            on("can", "model", "model=no_shadows", 9.0),
            on("can", "quality", "quality=fast", 5.0),
            on("sphere", "default", "default", 1.0),
            on("sphere", "model", "model=no_shadows", 1.0),
            on("sphere", "model", "model=no_shadows", 2.0),
            on("ring", "default", "default", 4.0),
        ];
        let groups = by_probe(&rows, &["model"], "default");
        // The ring ran no modelling choice: no block of its own.
        assert_eq!(
            groups.iter().map(|g| g.0.as_str()).collect::<Vec<_>>(),
            ["can", "sphere"]
        );
        assert_eq!(groups[0].1.len(), 2, "the quality preset is no modelling choice");
        assert_eq!(groups[1].1[1].angular_deg[0], 1.5);
        let table = by_probe_markdown(&groups);
        assert!(
            table.contains("| can | model=no_shadows | 1 | 9.00 / 1.00 / 1.00 | 0 / 1 | 2.00 |"),
            "{table}"
        );
        let csv = by_probe_csv(&groups);
        assert!(csv.starts_with("probe,family,variant,"), "{csv}");
        assert_eq!(csv.lines().count(), 5);
    }

    #[test]
    fn stability_rows_give_medians_percentiles_and_counts() {
        let mut rows: Vec<Row> = (0..10).map(|k| row("noise=0.1", 1.0, k as f64)).collect();
        rows[0].error = Some("no".into());
        rows[0].mirror_deg = None;
        rows[1].warning = Some("border".into());
        rows[2].skipped = Some("too small".into());
        rows.iter_mut().for_each(|r| {
            r.family = "noise".into();
            r.level = Some(3);
            r.strength = Some(0.1);
        });
        let s = &summarize_stability(&rows)[0];
        assert_eq!((s.runs, s.skipped, s.failed, s.warned, s.level), (9, 1, 1, 1, 3));
        // Mirror errors 1, 3, 4, ..., 9: median the 4th of 8, 90th percentile the 8th.
        assert_eq!((s.median_deg[0], s.p90_deg[0]), (5.0, 9.0));
        assert_eq!((s.poses_found, s.poses_sought), (4, 9));
        let table = stability_markdown(&summarize_stability(&rows));
        assert!(table.contains("| noise | noise=0.1 | 9 | 4 / 9 | 5.00 / 1.00 / 1.00 | 9.00 / 1.00 / 1.00 | 1 (11 %) | 1 (11 %) | 0 | 1 |"), "{table}");
        assert_eq!(stability_csv(&summarize_stability(&rows)).lines().count(), 2);
    }

    #[test]
    fn a_setting_that_always_failed_has_no_errors_and_is_off_the_front() {
        let mut failed = row("broken", 0.5, 1.0);
        failed.mirror_deg = None;
        failed.error = Some("no".into());
        let s = summarize(&[failed, row("default", 2.0, 4.0)], &[]);
        assert_eq!(s[0].failed, 1);
        assert!(s[0].angular_deg[0].is_nan() && !s[0].pareto[0]);
        assert!(s[1].pareto[0]);
    }
}
