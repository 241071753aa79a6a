//! SVG plots for the benchmarks (plotters, SVG backend only: no fonts or system libraries).

use std::path::Path;

use anyhow::{Result, anyhow};
use plotters::prelude::*;

/// One measured variant: its cost on the two x axes and its error.
pub struct Point {
    pub label: String,
    /// Points of one series share a colour; series named "... by share" are joined by a line.
    pub series: String,
    /// The left and right panels' x values (e.g. bytes and product time).
    pub x: [f64; 2],
    pub rel_l2: f64,
}

/// Reads one coordinate of a point.
type Axis = dyn Fn(&Point) -> f64;

const COLOURS: [RGBColor; 6] = [
    RGBColor(31, 119, 180),
    RGBColor(214, 39, 40),
    RGBColor(44, 160, 44),
    RGBColor(148, 103, 189),
    RGBColor(255, 127, 14),
    RGBColor(23, 190, 207),
];

/// Error against bytes (left) and against product time (right), both log-log.
pub fn plot_codecs(path: &Path, title: &str, points: &[Point]) -> Result<()> {
    plot_error(
        path,
        title,
        points,
        ["stored bytes", "CPU product time of the batch, s"],
    )
}

/// Error against `x[0]` (left) and `x[1]` (right), named by `x_names`, both log-log. Exact
/// variants (zero error) cannot sit on a log axis and are listed in the caption instead.
pub fn plot_error(path: &Path, title: &str, points: &[Point], x_names: [&str; 2]) -> Result<()> {
    let shown: Vec<&Point> = points.iter().filter(|p| p.rel_l2 > 0.0).collect();
    if shown.is_empty() {
        return Err(anyhow!("nothing to plot: every variant is exact"));
    }
    let exact: Vec<&str> = points
        .iter()
        .filter(|p| p.rel_l2 <= 0.0)
        .map(|p| p.label.as_str())
        .collect();
    let range = |f: &Axis| {
        let (lo, hi) = shown
            .iter()
            .map(|p| f(p))
            .fold((f64::INFINITY, 0.0f64), |(lo, hi), v| {
                (lo.min(v), hi.max(v))
            });
        (lo / 1.5)..(hi * 1.5)
    };
    let err = range(&|p| p.rel_l2);
    let mut series: Vec<&str> = Vec::new();
    for p in &shown {
        if !series.contains(&p.series.as_str()) {
            series.push(&p.series);
        }
    }

    let root = SVGBackend::new(path, (1400, 620)).into_drawing_area();
    root.fill(&WHITE).map_err(plot_err)?;
    let caption = if exact.is_empty() {
        title.to_string()
    } else {
        format!("{title} — exact, not drawn: {}", exact.join(", "))
    };
    let root = root
        .titled(&caption, ("sans-serif", 18))
        .map_err(plot_err)?;
    let panels = root.split_evenly((1, 2));
    let axes: [(&str, &Axis); 2] = [
        (x_names[0], &|p: &Point| p.x[0]),
        (x_names[1], &|p: &Point| p.x[1]),
    ];
    for (k_panel, (panel, (x_name, x_of))) in panels.iter().zip(axes).enumerate() {
        let mut chart = ChartBuilder::on(panel)
            .margin(16)
            .x_label_area_size(44)
            .y_label_area_size(64)
            .build_cartesian_2d(range(x_of).log_scale(), err.clone().log_scale())
            .map_err(plot_err)?;
        chart
            .configure_mesh()
            .x_desc(x_name)
            .y_desc("E_ind relative L2 error")
            .x_labels(6)
            .x_label_formatter(&|v| format!("{v:.1e}"))
            .y_label_formatter(&|v| format!("{v:.0e}"))
            .draw()
            .map_err(plot_err)?;
        for (k, name) in series.iter().enumerate() {
            let colour = COLOURS[k % COLOURS.len()];
            let mut members: Vec<&&Point> = shown.iter().filter(|p| p.series == *name).collect();
            members.sort_by(|a, b| x_of(a).total_cmp(&x_of(b)));
            let xy: Vec<(f64, f64)> = members.iter().map(|p| (x_of(p), p.rel_l2)).collect();
            // A sweep is a curve in bytes; in time its points are just points.
            if k_panel == 0 && name.ends_with("by share") {
                chart
                    .draw_series(LineSeries::new(xy.clone(), colour.stroke_width(2)))
                    .map_err(plot_err)?;
            }
            chart
                .draw_series(
                    xy.iter()
                        .map(|&(x, y)| Circle::new((x, y), 4, colour.filled())),
                )
                .map_err(plot_err)?
                .label(*name)
                .legend(move |(x, y)| Circle::new((x + 8, y), 4, colour.filled()));
            // Labels only where they do not pile up: the named codecs and reordering rows.
            if !name.ends_with("by share") {
                chart
                    .draw_series(members.iter().map(|p| {
                        Text::new(
                            p.label.clone(),
                            (x_of(p), p.rel_l2),
                            ("sans-serif", 12).into_font().color(&BLACK),
                        )
                    }))
                    .map_err(plot_err)?;
            }
        }
        chart
            .configure_series_labels()
            .position(SeriesLabelPosition::UpperRight)
            .background_style(WHITE.mix(0.8))
            .border_style(BLACK)
            .draw()
            .map_err(plot_err)?;
    }
    root.present().map_err(plot_err)?;
    Ok(())
}

fn plot_err<E: std::fmt::Display>(e: E) -> anyhow::Error {
    anyhow!("drawing the plot: {e}")
}
