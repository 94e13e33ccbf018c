//! The paper's ground and orbital calibration methods (Zlatkin et al.), each
//! reproduced on simulated data with known truth and measured against the paper's figures.
//!
//! Capabilities (one file per method; the CLI is `ssis-cal`, the tests `tests/methods.rs`):
//! - [`magnetic`]: magnetic sensitivity: f_x(ψ) = δΩ_x + S_x sin(ψ + Δφ_x),
//!   f_y(ψ) = δΩ_y + S_y cos(ψ + Δφ_y) (eq. 1) over 25 azimuth positions, unscreened minus
//!   screened (eq. 2); the "dipole tilt" Earth-field model, its projection into the ICS,
//!   the angle α_j between field and sensitive axis (eq. 3) and the predicted phase
//!   Δφ = −arctg(B0Y/B0X) (the Kharkov example).
//! - [`thermal_anova`]: the two-factor analysis of variance of Tables 1–2 (temperature ×
//!   gradient, unbalanced cells), F-ratios, degrees of freedom, critical values at q = 5 %
//!   and 1 %, the decision whether a thermal model is worth building, and the 3rd-order
//!   polynomial model in T and G fitted only when it is.
//! - [`allan`]: overlapping Allan deviation of a static session; angle random walk, bias
//!   instability and rate random walk with confidence intervals; log-log plot.
//! - [`misalign_turns`]: misalignment, first method: the eight angles δ12 … δ43 by least
//!   squares from three calibration turns with Earth rate.
//!
//! - [`misalign_sins`]: misalignment, second method: the six angles of the orthogonal
//!   triad from the SINS algorithm over flat turns and 180° reversals in three
//!   installations, started from the first method's angles (Gauss–Newton).
//! - [`orbital`]: orbital calibration on the unit's telemetry (output and star-tracker
//!   frames): zero bias from the observer of eq. (6) averaged over its steady part, scale
//!   factors from 360° maneuvers under star-tracker reference, and the FOG-to-star-tracker
//!   misalignment by recursive least squares.
//!
//! - [`wiring`]: before the misalignment methods fit angles, each FOG column's polarity and
//!   channel against the table's rotation (a FOG mounted backwards or two cables swapped
//!   is refused, named, instead of yielding wrong angles).
//!
//! Shared here: writing session CSV files (`docs/SESSION-FORMAT.md`) and simple SVG plots;
//! [`json`] is the `--json` form of each method's summary.

pub mod allan;
pub mod json;
pub mod magnetic;
pub mod misalign_sins;
pub mod misalign_turns;
pub mod orbital;
pub mod thermal_anova;
pub mod wiring;

use std::fmt::Write as _;
use std::path::Path;

use anyhow::{anyhow, Result};
use plotters::prelude::*;

/// Writes a session CSV: `comment` lines (without `#`), the header, then one row per entry.
/// Atomic (temporary file and rename).
pub fn write_session_csv(path: &Path, comment: &[String], header: &[&str], rows: &[Vec<f64>]) -> Result<()> {
    let mut s = String::with_capacity(rows.len() * header.len() * 14 + 256);
    for c in comment {
        let _ = writeln!(s, "# {c}");
    }
    s.push_str(&header.join(","));
    s.push('\n');
    for r in rows {
        for (k, v) in r.iter().enumerate() {
            if k > 0 {
                s.push(',');
            }
            let _ = write!(s, "{v:e}");
        }
        s.push('\n');
    }
    Ok(ssis_common::table::write_atomic(path, s.as_bytes())?)
}

/// One curve of an [`xy_svg`] plot.
pub struct Series {
    /// Legend text.
    pub label: String,
    /// Points (x, y).
    pub points: Vec<(f64, f64)>,
    /// Draw markers only (measurements) instead of a line (model).
    pub markers: bool,
}

/// Writes a one-panel SVG plot of `series` to `path` (atomic, under the output rules of
/// `ssis_common::output`).
pub fn xy_svg(path: &Path, title: &str, x_label: &str, y_label: &str, series: &[Series]) -> Result<()> {
    let all = series.iter().flat_map(|s| s.points.iter().copied());
    let (mut x0, mut x1, mut y0, mut y1) = (f64::INFINITY, f64::NEG_INFINITY, f64::INFINITY, f64::NEG_INFINITY);
    for (x, y) in all.filter(|(x, y)| x.is_finite() && y.is_finite()) {
        x0 = x0.min(x);
        x1 = x1.max(x);
        y0 = y0.min(y);
        y1 = y1.max(y);
    }
    if x0.partial_cmp(&x1) != Some(std::cmp::Ordering::Less) {
        x1 = x0 + 1.0;
    }
    if y0.partial_cmp(&y1) != Some(std::cmp::Ordering::Less) {
        y0 -= 1.0;
        y1 += 1.0;
    }
    let pad = 0.05 * (y1 - y0);
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, (900, 560)).into_drawing_area();
        root.fill(&WHITE).map_err(|e| anyhow!("{e}"))?;
        let mut chart = ChartBuilder::on(&root)
            .caption(title, ("sans-serif", 18))
            .margin(12)
            .x_label_area_size(36)
            .y_label_area_size(70)
            .build_cartesian_2d(x0..x1, (y0 - pad)..(y1 + pad))
            .map_err(|e| anyhow!("{e}"))?;
        chart.configure_mesh().x_desc(x_label).y_desc(y_label).draw().map_err(|e| anyhow!("{e}"))?;
        let colors = [RED, BLUE, GREEN, MAGENTA, CYAN, BLACK];
        for (k, s) in series.iter().enumerate() {
            let c = colors[k % colors.len()];
            let pts = s.points.iter().copied().filter(|(x, y)| x.is_finite() && y.is_finite());
            if s.markers {
                chart
                    .draw_series(pts.map(|p| Circle::new(p, 3, c.filled())))
                    .map_err(|e| anyhow!("{e}"))?
                    .label(s.label.clone())
                    .legend(move |(x, y)| Circle::new((x + 10, y), 3, c.filled()));
            } else {
                chart
                    .draw_series(LineSeries::new(pts, c))
                    .map_err(|e| anyhow!("{e}"))?
                    .label(s.label.clone())
                    .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], c));
            }
        }
        chart
            .configure_series_labels()
            .background_style(WHITE.mix(0.8))
            .border_style(BLACK)
            .draw()
            .map_err(|e| anyhow!("{e}"))?;
        root.present().map_err(|e| anyhow!("{e}"))?;
    }
    ssis_common::output::write(path, svg.as_bytes())
}

/// Least squares x = argmin |A x − b| (SVD), with the covariance factor (AᵀA)⁻¹.
pub fn lstsq(
    a: &nalgebra::DMatrix<f64>,
    b: &nalgebra::DVector<f64>,
) -> Result<(nalgebra::DVector<f64>, nalgebra::DMatrix<f64>)> {
    let ata = a.transpose() * a;
    let atb = a.transpose() * b;
    let chol = ata.clone().cholesky().ok_or_else(|| anyhow!("least squares: normal matrix not positive definite"))?;
    Ok((chol.solve(&atb), chol.inverse()))
}
