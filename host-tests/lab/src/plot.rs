//! Plots (SVG through plotters, no fonts needed): residuals against each quantity a
//! session has, and the held-out RMS across model versions.

use std::path::Path;

use plotters::prelude::*;

use super::fit::Fitted;
use super::{LabError, LabResult};
use ssis_common::DEG_H_PER_RAD_S;

fn perr(e: impl std::fmt::Display) -> LabError {
    LabError::Numeric(format!("plot: {e}"))
}

/// Residual of FOG `fog` against every quantity of the session (at the rows the pass kept:
/// every row of a session up to [`super::stream::DEFAULT_KEEP`] samples), as an SVG string.
pub fn residual_svg(file: &str, fitted: &Fitted, fog: usize) -> LabResult<String> {
    let axes = &fitted.sample.axes[fog];
    let res: Vec<f64> = fitted.sample.residual[fog].iter().map(|v| v * DEG_H_PER_RAD_S).collect();
    let stride = res.len().div_ceil(4000).max(1);
    let mut svg = String::new();
    {
        let rows = axes.len().div_ceil(2) as u32;
        let root = SVGBackend::with_string(&mut svg, (1000, 260 * rows + 40)).into_drawing_area();
        root.fill(&WHITE).map_err(perr)?;
        let root = root
            .titled(&format!("{file}: FOG{fog} residual, deg/h (model v{})", fitted.model.version), ("sans-serif", 18))
            .map_err(perr)?;
        let areas = root.split_evenly((rows as usize, 2));
        let lim = res.iter().fold(1e-9f64, |m, v| m.max(v.abs())) * 1.05;
        for ((label, x), area) in axes.iter().zip(areas.iter()) {
            let (lo, hi) = x.iter().fold((f64::MAX, f64::MIN), |(a, b), &v| (a.min(v), b.max(v)));
            let (lo, hi) = if hi > lo { (lo, hi) } else { (lo - 1.0, hi + 1.0) };
            let mut chart = ChartBuilder::on(area)
                .margin(8)
                .x_label_area_size(30)
                .y_label_area_size(55)
                .caption(label, ("sans-serif", 14))
                .build_cartesian_2d(lo..hi, -lim..lim)
                .map_err(perr)?;
            chart.configure_mesh().x_labels(6).y_labels(5).draw().map_err(perr)?;
            chart
                .draw_series(
                    x.iter().zip(&res).step_by(stride).map(|(&a, &b)| Circle::new((a, b), 2, BLUE.mix(0.5).filled())),
                )
                .map_err(perr)?;
        }
        root.present().map_err(perr)?;
    }
    Ok(svg)
}

/// Held-out RMS (pooled over FOGs, °/h) per model version, as an SVG string.
pub fn history_svg(title: &str, points: &[(u32, f64)]) -> LabResult<String> {
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, (800, 420)).into_drawing_area();
        root.fill(&WHITE).map_err(perr)?;
        let vmax = points.iter().fold(1e-9f64, |m, p| m.max(p.1)) * 1.1;
        let (v0, v1) = (points.first().map_or(1, |p| p.0), points.last().map_or(1, |p| p.0));
        let mut chart = ChartBuilder::on(&root)
            .margin(12)
            .caption(title, ("sans-serif", 16))
            .x_label_area_size(35)
            .y_label_area_size(60)
            .build_cartesian_2d((v0 as f64 - 0.5)..(v1 as f64 + 0.5), 0.0..vmax)
            .map_err(perr)?;
        chart
            .configure_mesh()
            .x_desc("model version")
            .y_desc("held-out residual RMS, deg/h")
            .x_labels(points.len().max(2))
            .draw()
            .map_err(perr)?;
        chart.draw_series(LineSeries::new(points.iter().map(|p| (p.0 as f64, p.1)), &RED)).map_err(perr)?;
        chart.draw_series(points.iter().map(|p| Circle::new((p.0 as f64, p.1), 4, RED.filled()))).map_err(perr)?;
        root.present().map_err(perr)?;
    }
    Ok(svg)
}

/// Writes an SVG string atomically.
pub fn write_svg(path: &Path, svg: &str) -> LabResult<()> {
    super::write_atomic(path, svg.as_bytes())
}
