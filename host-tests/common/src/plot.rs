//! Plots of a run (SVG, no fonts needed): attitude error and drift estimate over time.

use std::path::Path;

use anyhow::Result;
use plotters::prelude::*;

/// One plotted sample: time, attitude error per axis (″), drift-estimate error (°/h).
#[derive(Debug, Clone, Copy)]
pub struct PlotPoint {
    /// Time, s.
    pub t_s: f64,
    /// Attitude error, arcsec.
    pub att_arcsec: [f64; 3],
    /// Rate (drift-estimate) error, °/h.
    pub rate_deg_h: [f64; 3],
}

/// Writes a two-panel SVG of `points` to `path` (through [`crate::output`]).
pub fn write_svg(path: &Path, title: &str, points: &[PlotPoint]) -> Result<()> {
    let series: Vec<Series> = points.iter().map(|p| (p.t_s, p.att_arcsec, p.rate_deg_h)).collect();
    write_svg_panels(
        path,
        title,
        ["attitude error, arcsec (x red, y green, z blue)", "rate (drift estimate) error, deg/h"],
        &series,
    )
}

/// One plotted sample of [`write_svg_panels`]: time, s; the top panel's three values; the
/// bottom panel's.
pub type Series = (f64, [f64; 3], [f64; 3]);

/// Writes a two-panel SVG of three curves per panel (x red, y green, z blue) over time,
/// each panel under its caption, to `path` (through [`crate::output`]).
pub fn write_svg_panels(path: &Path, title: &str, captions: [&str; 2], points: &[Series]) -> Result<()> {
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, (1100, 800)).into_drawing_area();
        root.fill(&WHITE)?;
        let root = root.titled(title, ("sans-serif", 22))?;
        let (top, bottom) = root.split_vertically(400);
        let t_max = points.last().map_or(1.0, |p| p.0.max(1.0));
        panel(&top, captions[0], t_max, points, |p| p.1)?;
        panel(&bottom, captions[1], t_max, points, |p| p.2)?;
        root.present()?;
    }
    crate::output::write(path, svg.as_bytes())
}

fn panel<DB: DrawingBackend>(
    area: &DrawingArea<DB, plotters::coord::Shift>,
    caption: &str,
    t_max: f64,
    points: &[Series],
    pick: impl Fn(&Series) -> [f64; 3],
) -> Result<()>
where
    DB::ErrorType: 'static,
{
    let lim = points.iter().flat_map(|p| pick(p).map(f64::abs)).fold(1e-9, f64::max) * 1.1;
    let mut chart = ChartBuilder::on(area)
        .caption(caption, ("sans-serif", 16))
        .margin(10)
        .x_label_area_size(30)
        .y_label_area_size(60)
        .build_cartesian_2d(0.0..t_max, -lim..lim)
        .map_err(|e| anyhow::anyhow!("{e}"))?;
    chart.configure_mesh().x_desc("time, s").draw().map_err(|e| anyhow::anyhow!("{e}"))?;
    for (k, color) in [RED, GREEN, BLUE].iter().enumerate() {
        chart
            .draw_series(LineSeries::new(points.iter().map(|p| (p.0, pick(p)[k])), color))
            .map_err(|e| anyhow::anyhow!("{e}"))?;
    }
    Ok(())
}
