//! The studies' SVG charts (plotters): one panel per relit sphere.

use plotters::prelude::*;

use crate::error::{Error, Result};
use crate::relight::Sphere;

use super::summary::{StabilitySummary, VariantSummary};

/// Chart size, pixels: three panels side by side.
const SIZE: (u32, u32) = (1500, 520);

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

/// Mean angular error against median wall time per image, a panel per
/// sphere: one series per knob family (its settings and the default one,
/// in order of time; the families in `apart` without the default: they
/// are no knob turned from it), the Pareto front dashed, the default
/// labelled.
pub fn speed_accuracy_svg(summaries: &[VariantSummary], default_variant: &str, apart: &[&str]) -> Result<String> {
    let mut families: Vec<&str> = Vec::new();
    for s in summaries {
        if s.variant != default_variant && !families.contains(&s.family.as_str()) {
            families.push(&s.family);
        }
    }
    let default = summaries.iter().find(|s| s.variant == default_variant);
    let walls: Vec<f64> = summaries.iter().map(|s| s.median_wall_s).filter(|&t| t > 0.0).collect();
    let (t_lo, t_hi) = walls
        .iter()
        .fold((f64::INFINITY, 0.0f64), |(lo, hi), &t| (lo.min(t), hi.max(t)));
    let (t_lo, t_hi) = match t_lo.is_finite() {
        true => (t_lo / 1.3, t_hi * 1.3),
        false => (0.1, 10.0),
    };
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, SIZE).into_drawing_area();
        root.fill(&WHITE).map_err(drawing)?;
        for (k, panel) in root.split_evenly((1, 3)).iter().enumerate() {
            let point = |s: &VariantSummary| (s.median_wall_s.max(t_lo), s.angular_deg[k]);
            let errors: Vec<f64> = summaries
                .iter()
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
                .x_desc("median wall time per image (s)")
                .y_desc("mean angular error (deg)")
                .draw()
                .map_err(drawing)?;
            // The front first, wide and grey: the families' lines run over it.
            let mut front: Vec<(f64, f64)> = summaries.iter().filter(|s| s.pareto[k]).map(point).collect();
            front.sort_by(|a, b| a.0.total_cmp(&b.0));
            let grey = RGBColor(150, 150, 150);
            chart
                .draw_series(DashedLineSeries::new(front, 8, 5, grey.stroke_width(5)))
                .map_err(drawing)?
                .label("Pareto front")
                .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], grey.stroke_width(5)));
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
                    .map_err(drawing)?
                    .label(*family)
                    .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], colour.stroke_width(2)));
                chart
                    .draw_series(members.iter().map(|&p| Circle::new(p, 4, colour.filled())))
                    .map_err(drawing)?;
            }
            if let Some(d) = default.filter(|d| d.angular_deg[k].is_finite()) {
                chart
                    .draw_series([EmptyElement::at(point(d))
                        + Circle::new((0, 0), 7, BLACK.stroke_width(2))
                        + Text::new("default", (9, -16), ("sans-serif", 14))])
                    .map_err(drawing)?;
            }
            chart
                .configure_series_labels()
                .position(SeriesLabelPosition::UpperRight)
                .background_style(WHITE.mix(0.85))
                .border_style(BLACK)
                .draw()
                .map_err(drawing)?;
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
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, SIZE).into_drawing_area();
        root.fill(&WHITE).map_err(drawing)?;
        for (k, panel) in root.split_evenly((1, 3)).iter().enumerate() {
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
                    .map_err(drawing)?
                    .label(*family)
                    .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], style));
                chart
                    .draw_series(points.iter().map(|&p| Circle::new(p, 3, colour.filled())))
                    .map_err(drawing)?;
            }
            chart
                .configure_series_labels()
                .position(SeriesLabelPosition::UpperLeft)
                .background_style(WHITE.mix(0.85))
                .border_style(BLACK)
                .label_font(("sans-serif", 11))
                .draw()
                .map_err(drawing)?;
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
    fn the_chart_has_a_series_per_family_the_front_and_the_default() {
        let s = [
            summary("default", "default", 5.0, 3.0, true),
            summary("quality", "quality=fast", 2.0, 4.0, true),
            summary("quality", "quality=best", 12.0, 2.5, true),
            summary("threads", "threads=1", 9.0, 3.0, false),
            summary("outside", "outside=1", 20.0, 3.5, false),
            summary("outside", "outside=2", 40.0, 3.2, false),
        ];
        let svg = speed_accuracy_svg(&s, "default", &["outside"]).expect("a chart");
        assert!(svg.starts_with("<svg") && svg.trim_end().ends_with("</svg>"));
        for text in [
            "mirror sphere",
            "diffuse sphere",
            "quality",
            "threads",
            "Pareto front",
            "default",
        ] {
            assert!(svg.contains(text), "no `{text}` in the chart");
        }
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
