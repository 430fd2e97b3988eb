//! The studies' SVG charts (plotters): one panel per relit sphere.

use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};

use crate::error::{Error, Result};
use crate::relight::Sphere;

use super::summary::{StabilitySummary, VariantSummary};

/// Chart size, pixels: three panels side by side, and the legend.
const SIZE: (u32, u32) = (1500, 520);

/// The legend's width at the chart's right, pixels.
const LEGEND_WIDTH: u32 = 190;

/// The Pareto front's colour.
const FRONT_GREY: RGBColor = RGBColor(150, 150, 150);

/// The colour of an earlier run's front (`--before`).
const BEFORE_GREY: RGBColor = RGBColor(60, 60, 60);

/// The series' colours, in family order: one per perturbation of the
/// stability study, no two alike.
const PALETTE: [RGBColor; 14] = [
    RGBColor(31, 119, 180),
    RGBColor(255, 127, 14),
    RGBColor(44, 160, 44),
    RGBColor(214, 39, 40),
    RGBColor(148, 103, 189),
    RGBColor(140, 86, 75),
    RGBColor(227, 119, 194),
    RGBColor(23, 190, 207),
    RGBColor(188, 189, 34),
    RGBColor(127, 127, 127),
    RGBColor(0, 0, 128),
    RGBColor(128, 0, 0),
    RGBColor(0, 128, 128),
    RGBColor(255, 215, 0),
];

fn drawing(e: impl std::fmt::Display) -> Error {
    Error::invalid("chart", format!("drawing failed: {e}"))
}

/// A line of the legend: its label and how its sample is drawn.
struct Entry {
    label: String,
    colour: RGBColor,
    width: u32,
    dashed: bool,
}

impl Entry {
    fn line(label: &str, colour: RGBColor) -> Self {
        Entry {
            label: label.into(),
            colour,
            width: 2,
            dashed: false,
        }
    }
}

/// One legend for the panels, in its own strip: it hides no data.
fn draw_legend(area: &DrawingArea<SVGBackend, plotters::coord::Shift>, entries: &[Entry]) -> Result<()> {
    const ROW: i32 = 20;
    for (i, e) in entries.iter().enumerate() {
        let y = 60 + ROW * i as i32;
        let style = e.colour.stroke_width(e.width);
        let segments: &[(i32, i32)] = match e.dashed {
            true => &[(0, 9), (14, 24)],
            false => &[(0, 24)],
        };
        for &(a, b) in segments {
            area.draw(&PathElement::new(vec![(8 + a, y), (8 + b, y)], style))
                .map_err(drawing)?;
        }
        area.draw(&Text::new(e.label.clone(), (40, y - 7), ("sans-serif", 13)))
            .map_err(drawing)?;
    }
    Ok(())
}

/// The 1-2-5 values of each decade from `lo` to `hi`: a log axis's labels
/// (plotters labels a log axis from its first power of ten on).
fn one_two_five(lo: f64, hi: f64) -> Vec<f64> {
    let first = lo.log10().floor() as i32;
    let last = hi.log10().ceil() as i32;
    (first..=last)
        .flat_map(|e| [1.0, 2.0, 5.0].map(|m| m * 10f64.powi(e)))
        .filter(|v| (lo..=hi).contains(v))
        .collect()
}

/// Whether a label at pixel `p` keeps clear of those at `placed` (a label
/// is about 90 x 12 pixels).
fn clear_of(p: (i32, i32), placed: &[(i32, i32)]) -> bool {
    placed.iter().all(|q| (p.0 - q.0).abs() > 90 || (p.1 - q.1).abs() > 12)
}

/// Mean angular error against median wall time per image, a panel per
/// sphere: one series per knob family (its settings and the default one,
/// in order of time; the families in `apart` without the default: they
/// are no knob turned from it), the Pareto front dashed, the default
/// labelled. An earlier run's front and default (`before`, may be empty)
/// beside them, thin and dark.
pub fn speed_accuracy_svg(
    summaries: &[VariantSummary],
    default_variant: &str,
    apart: &[&str],
    before: &[VariantSummary],
) -> Result<String> {
    let mut families: Vec<&str> = Vec::new();
    for s in summaries {
        if s.variant != default_variant && !families.contains(&s.family.as_str()) {
            families.push(&s.family);
        }
    }
    let default = summaries.iter().find(|s| s.variant == default_variant);
    let before_default = before.iter().find(|s| s.variant == default_variant);
    let everything = || summaries.iter().chain(before);
    let walls: Vec<f64> = everything().map(|s| s.median_wall_s).filter(|&t| t > 0.0).collect();
    let (t_lo, t_hi) = walls
        .iter()
        .fold((f64::INFINITY, 0.0f64), |(lo, hi), &t| (lo.min(t), hi.max(t)));
    let (t_lo, t_hi) = match t_lo.is_finite() {
        true => (t_lo / 1.3, t_hi * 1.3),
        false => (0.1, 10.0),
    };
    let mut legend = vec![Entry {
        dashed: true,
        width: 5,
        ..Entry::line("Pareto front", FRONT_GREY)
    }];
    if !before.is_empty() {
        legend.push(Entry {
            dashed: true,
            ..Entry::line("Pareto front before", BEFORE_GREY)
        });
    }
    legend.extend(
        families
            .iter()
            .enumerate()
            .map(|(i, f)| Entry::line(f, PALETTE[i % PALETTE.len()])),
    );
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, SIZE).into_drawing_area();
        root.fill(&WHITE).map_err(drawing)?;
        let (panels, key) = root.split_horizontally(SIZE.0 - LEGEND_WIDTH);
        draw_legend(&key, &legend)?;
        for (k, panel) in panels.split_evenly((1, 3)).iter().enumerate() {
            let point = |s: &VariantSummary| (s.median_wall_s.max(t_lo), s.angular_deg[k]);
            let errors: Vec<f64> = everything()
                .map(|s| s.angular_deg[k])
                .filter(|e| e.is_finite())
                .collect();
            let e_hi = errors.iter().cloned().fold(0.0f64, f64::max).max(1e-3) * 1.15;
            let mut chart = ChartBuilder::on(panel)
                .caption(format!("{} sphere", Sphere::ALL[k].name()), ("sans-serif", 20))
                .margin(12)
                .x_label_area_size(45)
                .y_label_area_size(55)
                .build_cartesian_2d((t_lo..t_hi).log_scale(), 0.0..e_hi)
                .map_err(drawing)?;
            chart
                .configure_mesh()
                .x_labels(30)
                .x_label_formatter(&|_| String::new())
                .x_desc("median wall time per image (s)")
                .y_desc("mean angular error (deg)")
                .draw()
                .map_err(drawing)?;
            // The front first, wide and grey: the families' lines run over it.
            let mut front: Vec<&VariantSummary> = summaries.iter().filter(|s| s.pareto[k]).collect();
            front.sort_by(|a, b| a.median_wall_s.total_cmp(&b.median_wall_s));
            chart
                .draw_series(DashedLineSeries::new(
                    front.iter().map(|s| point(s)),
                    8,
                    5,
                    FRONT_GREY.stroke_width(5),
                ))
                .map_err(drawing)?;
            let mut front_before: Vec<(f64, f64)> = before.iter().filter(|s| s.pareto[k]).map(point).collect();
            front_before.sort_by(|a, b| a.0.total_cmp(&b.0));
            chart
                .draw_series(DashedLineSeries::new(
                    front_before.iter().copied(),
                    6,
                    4,
                    BEFORE_GREY.stroke_width(2),
                ))
                .map_err(drawing)?;
            chart
                .draw_series(
                    front_before
                        .iter()
                        .map(|&p| Circle::new(p, 3, BEFORE_GREY.stroke_width(1))),
                )
                .map_err(drawing)?;
            for (i, family) in families.iter().enumerate() {
                let colour = PALETTE[i % PALETTE.len()];
                let mut members: Vec<(f64, f64)> = summaries
                    .iter()
                    .filter(|s| s.family == *family || (s.variant == default_variant && !apart.contains(family)))
                    .filter(|s| s.angular_deg[k].is_finite())
                    .map(point)
                    .collect();
                members.sort_by(|a, b| a.0.total_cmp(&b.0));
                chart
                    .draw_series(LineSeries::new(members.clone(), colour.stroke_width(2)))
                    .map_err(drawing)?;
                chart
                    .draw_series(members.iter().map(|&p| Circle::new(p, 4, colour.filled())))
                    .map_err(drawing)?;
            }
            let area = chart.plotting_area();
            for v in one_two_five(t_lo, t_hi) {
                let (x, y) = area.map_coordinate(&(v, 0.0));
                root.draw(&PathElement::new(vec![(x, y), (x, y + 5)], BLACK))
                    .map_err(drawing)?;
                let style = TextStyle::from(("sans-serif", 12)).pos(Pos::new(HPos::Center, VPos::Top));
                root.draw(&Text::new(format!("{v}"), (x, y + 7), style))
                    .map_err(drawing)?;
            }
            // The front's settings by name where there is room (the default's first).
            // Labels sit 3 px below their point; the default's 16 px above and 9 right of it.
            let mut placed: Vec<(i32, i32)> = default
                .map(|d| area.map_coordinate(&point(d)))
                .into_iter()
                .flat_map(|(x, y)| [(x, y), (x + 9, y - 19)])
                .collect();
            let mut named = Vec::new();
            for s in front.iter().filter(|s| s.variant != default_variant) {
                let at = area.map_coordinate(&point(s));
                if clear_of(at, &placed) {
                    placed.push(at);
                    named.push(EmptyElement::at(point(s)) + Text::new(s.variant.clone(), (6, 3), ("sans-serif", 11)));
                }
            }
            chart.draw_series(named).map_err(drawing)?;
            if let Some(d) = default.filter(|d| d.angular_deg[k].is_finite()) {
                chart
                    .draw_series([EmptyElement::at(point(d))
                        + Circle::new((0, 0), 7, BLACK.stroke_width(2))
                        + Text::new("default", (9, -16), ("sans-serif", 14))])
                    .map_err(drawing)?;
            }
            if let Some(d) = before_default.filter(|d| d.angular_deg[k].is_finite()) {
                chart
                    .draw_series([EmptyElement::at(point(d))
                        + Circle::new((0, 0), 7, BEFORE_GREY.stroke_width(1))
                        + Text::new("default before", (9, 4), ("sans-serif", 12))])
                    .map_err(drawing)?;
            }
        }
        root.present().map_err(drawing)?;
    }
    Ok(svg)
}

/// The median angular error against the perturbation's graded level, a
/// panel per sphere: one line per perturbation from the photo as it is
/// (level 0) through its strengths (an ablation: one step).
pub fn stability_svg(summaries: &[StabilitySummary]) -> Result<String> {
    let base = summaries.iter().find(|s| s.level == 0);
    let mut families: Vec<&str> = Vec::new();
    for s in summaries.iter().filter(|s| s.level > 0) {
        if !families.contains(&s.family.as_str()) {
            families.push(&s.family);
        }
    }
    let top_level = summaries.iter().map(|s| s.level).max().unwrap_or(1).max(1);
    let legend: Vec<Entry> = families
        .iter()
        .enumerate()
        .map(|(i, f)| Entry::line(f, PALETTE[i % PALETTE.len()]))
        .collect();
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, SIZE).into_drawing_area();
        root.fill(&WHITE).map_err(drawing)?;
        let (panels, key) = root.split_horizontally(SIZE.0 - LEGEND_WIDTH);
        draw_legend(&key, &legend)?;
        for (k, panel) in panels.split_evenly((1, 3)).iter().enumerate() {
            let e_hi = summaries
                .iter()
                .map(|s| s.median_deg[k])
                .filter(|e| e.is_finite())
                .fold(0.0f64, f64::max)
                .max(1e-3)
                * 1.15;
            let mut chart = ChartBuilder::on(panel)
                .caption(format!("{} sphere", Sphere::ALL[k].name()), ("sans-serif", 20))
                .margin(12)
                .x_label_area_size(45)
                .y_label_area_size(55)
                .build_cartesian_2d(-0.2..top_level as f64 + 0.2, 0.0..e_hi)
                .map_err(drawing)?;
            chart
                .configure_mesh()
                .x_labels(top_level + 1)
                .x_label_formatter(&|x| match x.round() as usize {
                    0 => "none".into(),
                    l => format!("{l}"),
                })
                .x_desc("strength (graded level)")
                .y_desc("median angular error (deg)")
                .draw()
                .map_err(drawing)?;
            for (i, family) in families.iter().enumerate() {
                let colour = PALETTE[i % PALETTE.len()];
                let mut points: Vec<(f64, f64)> = base
                    .into_iter()
                    .chain(summaries.iter().filter(|s| s.family == *family))
                    .filter(|s| s.median_deg[k].is_finite())
                    .map(|s| (s.level as f64, s.median_deg[k]))
                    .collect();
                points.sort_by(|a, b| a.0.total_cmp(&b.0));
                let style = colour.stroke_width(2);
                chart
                    .draw_series(LineSeries::new(points.clone(), style))
                    .map_err(drawing)?;
                chart
                    .draw_series(points.iter().map(|&p| Circle::new(p, 3, colour.filled())))
                    .map_err(drawing)?;
            }
        }
        root.present().map_err(drawing)?;
    }
    Ok(svg)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn summary(family: &str, variant: &str, wall: f64, error: f64, pareto: bool) -> VariantSummary {
        VariantSummary {
            family: family.into(),
            variant: variant.into(),
            runs: 2,
            failed: 0,
            angular_deg: [error, error / 2.0, error / 4.0],
            poses_found: 2,
            poses_sought: 2,
            median_wall_s: wall,
            peak_mb: None,
            pareto: [pareto; 3],
        }
    }

    #[test]
    fn a_log_axis_is_labelled_at_one_two_five() {
        assert_eq!(one_two_five(1.5, 52.0), [2.0, 5.0, 10.0, 20.0, 50.0]);
        assert_eq!(one_two_five(0.3, 1.0), [0.5, 1.0]);
        assert!(clear_of((0, 0), &[(91, 0), (0, 13)]) && !clear_of((0, 0), &[(50, 5)]));
    }

    #[test]
    fn the_stability_chart_has_a_line_per_perturbation_from_the_photo_as_it_is() {
        let summary = |family: &str, level: usize, median: f64| StabilitySummary {
            family: family.into(),
            variant: format!("{family}={level}"),
            level,
            strength: level as f64,
            runs: 2,
            skipped: 0,
            failed: 0,
            warned: 0,
            non_finite: 0,
            poses_found: 2,
            poses_sought: 2,
            median_deg: [median; 3],
            p90_deg: [median * 2.0; 3],
        };
        let s = [
            summary("unperturbed", 0, 3.0),
            summary("noise", 1, 3.5),
            summary("noise", 2, 4.0),
            summary("noise", 3, 6.0),
            summary("one_start", 1, 5.0),
        ];
        let svg = stability_svg(&s).expect("a chart");
        for text in ["noise", "one_start", "strength (graded level)", "none"] {
            assert!(svg.contains(text), "no `{text}`");
        }
        let stroke = |c: RGBColor| format!("stroke=\"#{:02X}{:02X}{:02X}\"", c.0, c.1, c.2);
        let lines = |c: RGBColor, points: usize| {
            svg.lines()
                .filter(|l| l.starts_with("<polyline") && l.contains(&stroke(c)))
                .filter_map(|l| l.split("points=\"").nth(1)?.split('"').next())
                .filter(|p| p.split_whitespace().count() == points)
                .count()
        };
        assert_eq!(lines(PALETTE[0], 4), 3, "noise: none and three levels, in each panel");
        assert_eq!(lines(PALETTE[1], 3), 0);
    }

    #[test]
    fn an_earlier_runs_front_and_default_are_drawn_beside_this_runs() {
        let now = [
            summary("default", "default", 5.0, 3.0, true),
            summary("quality", "quality=fast", 2.0, 4.0, true),
        ];
        let before = [
            summary("default", "default", 10.0, 3.0, true),
            summary("quality", "quality=fast", 4.0, 4.0, true),
        ];
        let without = speed_accuracy_svg(&now, "default", &[], &[]).expect("a chart");
        let with = speed_accuracy_svg(&now, "default", &[], &before).expect("a chart");
        let grey = format!(
            "stroke=\"#{:02X}{:02X}{:02X}\"",
            BEFORE_GREY.0, BEFORE_GREY.1, BEFORE_GREY.2
        );
        assert!(!without.contains(&grey) && !without.contains("Pareto front before"));
        assert!(
            with.contains(&grey) && with.contains("Pareto front before") && with.contains(">\ndefault before\n<"),
            "{with}"
        );
        // The time axis reaches the earlier run's 10 s.
        assert!(with.contains(">\n10\n<") && !without.contains(">\n10\n<"));
    }

    #[test]
    fn the_chart_has_a_series_per_family_the_front_and_the_default() {
        let s = [
            summary("default", "default", 5.0, 3.0, true),
            summary("quality", "quality=fast", 2.0, 4.0, true),
            summary("quality", "quality=best", 12.0, 2.5, true),
            summary("threads", "threads=1", 9.0, 3.0, false),
            summary("outside", "outside=1", 20.0, 3.5, false),
            summary("outside", "outside=2", 40.0, 3.2, false),
        ];
        let svg = speed_accuracy_svg(&s, "default", &["outside"], &[]).expect("a chart");
        assert!(svg.starts_with("<svg") && svg.trim_end().ends_with("</svg>"));
        for text in [
            "mirror sphere",
            "diffuse sphere",
            "quality",
            "threads",
            "Pareto front",
            "default",
            // The front's settings by name, the time axis labelled 1-2-5 (1.5 s to 52 s).
            ">\nquality=fast\n<",
            ">\nquality=best\n<",
            ">\n2\n<",
            ">\n5\n<",
            ">\n50\n<",
        ] {
            assert!(svg.contains(text), "no `{text}` in the chart");
        }
        assert!(!svg.contains(">\nthreads=1\n<"), "a setting off the front is named");
        // The quality family's line through fast, default and best in each
        // of the three panels (its legend's sample has two points).
        let polylines_of = |colour: RGBColor, points: usize| {
            let stroke = format!("stroke=\"#{:02X}{:02X}{:02X}\"", colour.0, colour.1, colour.2);
            svg.lines()
                .filter(|l| l.starts_with("<polyline") && l.contains(&stroke))
                .filter_map(|l| l.split("points=\"").nth(1)?.split('"').next())
                .filter(|p| p.split_whitespace().count() == points)
                .count()
        };
        assert_eq!(polylines_of(PALETTE[0], 3), 3, "{svg}");
        // The threads family: one setting and the default; the outside
        // method's two settings alone.
        assert_eq!(polylines_of(PALETTE[1], 3), 0);
        assert_eq!(polylines_of(PALETTE[2], 3), 0);
    }
}
