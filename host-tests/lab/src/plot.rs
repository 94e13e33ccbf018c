//! Plots (SVG through plotters, no fonts needed): residuals against each quantity a
//! session has, and the held-out RMS across model versions.

use std::path::Path;

use plotters::prelude::*;

use super::fit::Fitted;
use super::{LabError, LabResult};
use ssis_common::DEG_H_PER_RAD_S;

/// The FOGs' colours (FOG0…FOG3): blue, vermilion, bluish green, reddish purple of the
/// Okabe–Ito set, darkened where needed so each has a contrast of at least 3:1 on white
/// (WCAG 2.1's minimum for graphics; `fog_colours_are_readable_on_white`).
pub const FOG_COLOURS: [(u8, u8, u8); 4] = [(0, 114, 178), (196, 78, 0), (0, 128, 92), (170, 68, 136)];

/// The colour of FOG `fog` in every plot.
pub fn fog_colour(fog: usize) -> RGBColor {
    let (r, g, b) = FOG_COLOURS[fog % FOG_COLOURS.len()];
    RGBColor(r, g, b)
}

/// WCAG 2.1 contrast ratio of an sRGB colour against white.
pub fn contrast_on_white((r, g, b): (u8, u8, u8)) -> f64 {
    let lin = |c: u8| {
        let c = f64::from(c) / 255.0;
        if c <= 0.04045 {
            c / 12.92
        } else {
            ((c + 0.055) / 1.055).powf(2.4)
        }
    };
    let l = 0.2126 * lin(r) + 0.7152 * lin(g) + 0.0722 * lin(b);
    1.05 / (l + 0.05)
}

fn perr(e: impl std::fmt::Display) -> LabError {
    LabError::Numeric(format!("plot: {e}"))
}

/// Residual of FOG `fog` against every quantity of the session (at the rows the pass kept:
/// every row of a session up to [`super::stream::DEFAULT_KEEP`] samples), as an SVG string.
pub fn residual_svg(file: &str, fitted: &Fitted, fog: usize) -> LabResult<String> {
    // A quantity constant over the session (ψ and the rate of a static run) would give an
    // empty panel: it is left out and named in the title.
    let (axes, constant): (Vec<_>, Vec<_>) = fitted.sample.axes[fog].iter().partition(|(_, x)| {
        let (lo, hi) = x.iter().fold((f64::MAX, f64::MIN), |(a, b), &v| (a.min(v), b.max(v)));
        hi - lo > 1e-9 * hi.abs().max(lo.abs()).max(1.0)
    });
    let note = if constant.is_empty() {
        String::new()
    } else {
        let names: Vec<&str> = constant.iter().map(|(l, _)| l.as_str()).collect();
        format!("; constant in this session, not plotted: {}", names.join("; "))
    };
    let res: Vec<f64> = fitted.sample.residual[fog].iter().map(|v| v * DEG_H_PER_RAD_S).collect();
    let stride = res.len().div_ceil(4000).max(1);
    let mut svg = String::new();
    {
        let rows = axes.len().div_ceil(2) as u32;
        let root = SVGBackend::with_string(&mut svg, (1000, 260 * rows + 40)).into_drawing_area();
        root.fill(&WHITE).map_err(perr)?;
        let root = root
            .titled(
                &format!("{file}: FOG{fog} residual, °/h (model v{}){note}", fitted.model.version),
                ("sans-serif", 18),
            )
            .map_err(perr)?;
        let areas = root.split_evenly((rows as usize, 2));
        let lim = res.iter().fold(1e-9f64, |m, v| m.max(v.abs())) * 1.05;
        for ((label, x), area) in axes.into_iter().zip(areas.iter()) {
            let (lo, hi) = x.iter().fold((f64::MAX, f64::MIN), |(a, b), &v| (a.min(v), b.max(v)));
            let (lo, hi) = if hi > lo { (lo, hi) } else { (lo - 1.0, hi + 1.0) };
            let mut chart = ChartBuilder::on(area)
                .margin(8)
                .x_label_area_size(30)
                .y_label_area_size(55)
                .caption(label.as_str(), ("sans-serif", 14))
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

/// A chart by model version: versions `v0..=v1` on x (`x_axis`: its description and
/// how many labels, each from `label`), held-out residual RMS 0..`vmax` °/h on y.
fn version_chart<'a, 'b>(
    root: &'a DrawingArea<SVGBackend<'b>, plotters::coord::Shift>,
    title: &str,
    (v0, v1): (u32, u32),
    vmax: f64,
    x_axis: (&str, usize),
    label: &dyn Fn(&f64) -> String,
) -> LabResult<
    ChartContext<
        'a,
        SVGBackend<'b>,
        Cartesian2d<plotters::coord::types::RangedCoordf64, plotters::coord::types::RangedCoordf64>,
    >,
> {
    let mut chart = ChartBuilder::on(root)
        .margin(14)
        .caption(title, ("sans-serif", 16))
        .x_label_area_size(40)
        .y_label_area_size(60)
        .build_cartesian_2d((f64::from(v0) - 0.5)..(f64::from(v1) + 0.5), 0.0..vmax)
        .map_err(perr)?;
    chart
        .configure_mesh()
        .x_desc(x_axis.0)
        .y_desc("held-out residual RMS, °/h")
        .x_labels(x_axis.1)
        .x_label_formatter(label)
        .draw()
        .map_err(perr)?;
    Ok(chart)
}

/// Held-out RMS (pooled over FOGs, °/h) per model version, as an SVG string.
pub fn history_svg(title: &str, points: &[(u32, f64)]) -> LabResult<String> {
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, (800, 420)).into_drawing_area();
        root.fill(&WHITE).map_err(perr)?;
        let vmax = points.iter().fold(1e-9f64, |m, p| m.max(p.1)) * 1.1;
        let (v0, v1) = (points.first().map_or(1, |p| p.0), points.last().map_or(1, |p| p.0));
        let label = |x: &f64| if (x - x.round()).abs() < 1e-6 { format!("v{}", x.round()) } else { String::new() };
        let mut chart = version_chart(&root, title, (v0, v1), vmax, ("model version", points.len().max(2)), &label)?;
        chart.draw_series(LineSeries::new(points.iter().map(|p| (p.0 as f64, p.1)), &RED)).map_err(perr)?;
        chart.draw_series(points.iter().map(|p| Circle::new((p.0 as f64, p.1), 4, RED.filled()))).map_err(perr)?;
        root.present().map_err(perr)?;
    }
    Ok(svg)
}

/// An Allan deviation curve: (τ s, σ_A rad/s) per cluster size.
pub type AllanCurve = Vec<(f64, f64)>;

/// Allan deviation of the residual before and after an `add`, per FOG, with the white-noise
/// floor σ₁ √(Δt/τ) of the residual after (log-log, °/h against s), as an SVG string.
/// `curves[fog]` = (before, after), each (τ s, σ_A rad/s); `floor[fog]` = σ₁ rad/s at `dt_s`.
pub fn allan_svg(title: &str, curves: &[(AllanCurve, AllanCurve)], floor: &[f64], dt_s: f64) -> LabResult<String> {
    use ssis_common::DEG_H_PER_RAD_S as DH;
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, (800, 520)).into_drawing_area();
        root.fill(&WHITE).map_err(perr)?;
        let all = || curves.iter().flat_map(|(a, b)| a.iter().chain(b.iter()));
        let (t0, t1) = all().fold((f64::MAX, f64::MIN), |(a, b), p| (a.min(p.0), b.max(p.0)));
        let (y0, y1) = all().fold((f64::MAX, f64::MIN), |(a, b), p| (a.min(p.1 * DH), b.max(p.1 * DH)));
        if !(t0 < t1 && y0 > 0.0 && y0 < y1) {
            return Err(LabError::Numeric("too few samples for an Allan deviation".into()));
        }
        let mut chart = ChartBuilder::on(&root)
            .margin(12)
            .caption(title, ("sans-serif", 16))
            .x_label_area_size(35)
            .y_label_area_size(70)
            .build_cartesian_2d((t0..t1).log_scale(), ((y0 * 0.5)..(y1 * 2.0)).log_scale())
            .map_err(perr)?;
        chart
            .configure_mesh()
            .x_desc("averaging time tau, s")
            .y_desc("Allan deviation of the residual, °/h")
            .draw()
            .map_err(perr)?;
        for (fog, ((before, after), f)) in curves.iter().zip(floor).enumerate() {
            let c = fog_colour(fog).to_rgba();
            let dashed = before.iter().map(|p| (p.0, p.1 * DH)).collect::<Vec<_>>();
            chart
                .draw_series(DashedLineSeries::new(dashed, 6, 4, c.stroke_width(1)))
                .map_err(perr)?
                .label(format!("FOG{fog} before"))
                .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 16, y)], c));
            chart
                .draw_series(LineSeries::new(after.iter().map(|p| (p.0, p.1 * DH)), c.stroke_width(2)))
                .map_err(perr)?
                .label(format!("FOG{fog} after"))
                .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 16, y)], c.stroke_width(2)));
            let fl = after.iter().map(|p| (p.0, f * DH * (dt_s / p.0).sqrt())).collect::<Vec<_>>();
            chart.draw_series(LineSeries::new(fl, BLACK.mix(0.35))).map_err(perr)?;
        }
        chart.configure_series_labels().background_style(WHITE.mix(0.8)).border_style(BLACK).draw().map_err(perr)?;
        root.present().map_err(perr)?;
    }
    Ok(svg)
}

/// The history of model versions per FOG, as an SVG string: held-out RMS (°/h) of each FOG
/// per version, the x axis labelled with the version and the term it added, and the
/// white-noise floor (grey). `rows` = (version, per-FOG held-out RMS °/h, the term added).
pub fn history_fogs_svg(title: &str, rows: &[(u32, Vec<f64>, String)], floor_deg_h: f64) -> LabResult<String> {
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, (900, 480)).into_drawing_area();
        root.fill(&WHITE).map_err(perr)?;
        let vmax = rows.iter().flat_map(|r| r.1.iter()).fold(floor_deg_h, |m, v| m.max(*v)) * 1.15;
        let (v0, v1) = (rows.first().map_or(1, |r| r.0), rows.last().map_or(1, |r| r.0));
        let label = |x: &f64| {
            let v = x.round() as u32;
            rows.iter()
                .find(|r| r.0 == v && (x - v as f64).abs() < 1e-6)
                .map_or(String::new(), |r| format!("v{v} {}", r.2))
        };
        let mut chart =
            version_chart(&root, title, (v0, v1), vmax, ("model version, term added", 2 * (rows.len() + 1)), &label)?;
        let n_fog = rows.iter().map(|r| r.1.len()).max().unwrap_or(0);
        for fog in 0..n_fog {
            let c = fog_colour(fog).to_rgba();
            let pts: Vec<(f64, f64)> = rows.iter().filter_map(|r| r.1.get(fog).map(|v| (r.0 as f64, *v))).collect();
            chart
                .draw_series(LineSeries::new(pts.clone(), c.stroke_width(2)))
                .map_err(perr)?
                .label(format!("FOG{fog}"))
                .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 16, y)], c.stroke_width(2)));
            chart.draw_series(pts.iter().map(|p| Circle::new(*p, 3, c.filled()))).map_err(perr)?;
        }
        let fl = vec![(v0 as f64 - 0.5, floor_deg_h), (v1 as f64 + 0.5, floor_deg_h)];
        chart
            .draw_series(LineSeries::new(fl, BLACK.mix(0.4)))
            .map_err(perr)?
            .label(format!("white-noise floor {floor_deg_h:.4} °/h"))
            .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 16, y)], BLACK.mix(0.4)));
        chart.configure_series_labels().background_style(WHITE.mix(0.8)).border_style(BLACK).draw().map_err(perr)?;
        root.present().map_err(perr)?;
    }
    Ok(svg)
}

/// A duration in the unit that reads best: "0.5 s", "20 s", "12 min", "1.5 h".
fn duration_text(s: f64) -> String {
    if s < 120.0 {
        let v = format!("{s:.3}");
        format!("{} s", v.trim_end_matches('0').trim_end_matches('.'))
    } else if s < 7200.0 {
        format!("{:.0} min", s / 60.0)
    } else {
        format!("{:.1} h", s / 3600.0)
    }
}

/// Means of `x` over consecutive windows of `w` values (the last, shorter one dropped).
fn window_means(x: &[f64], w: usize) -> Vec<f64> {
    x.chunks_exact(w.max(1)).map(|c| c.iter().sum::<f64>() / c.len() as f64).collect()
}

/// The residuals before and after one `add` overlaid, one panel per FOG: means over
/// windows of about 1/200 of the session (°/h against hours), the version before in grey,
/// after in the FOG's colour, and the white-noise floor ±σ₁√(Δt/τ) at that window (dashed),
/// σ₁ the Allan deviation of the residual after at one kept row. As an SVG string.
pub fn overlay_svg(step: &super::fit::AddStep, kept: &super::fit::KeptTimes) -> LabResult<String> {
    let n_fog = step.before_rad_s.len().min(step.after_rad_s.len());
    let rows = kept.t_s.len();
    let w = (rows / 200).max(1);
    let tau_s = w as f64 * kept.dt_s;
    let t_h = window_means(&kept.t_s, w).iter().map(|t| t / 3600.0).collect::<Vec<_>>();
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, (1000, 230 * n_fog.div_ceil(2) as u32 + 40)).into_drawing_area();
        root.fill(&WHITE).map_err(perr)?;
        let title = format!(
            "v{} → v{} ({}): residual, °/h, means over {}",
            step.from,
            step.to,
            step.added,
            duration_text(tau_s)
        );
        let root = root.titled(&title, ("sans-serif", 18)).map_err(perr)?;
        let areas = root.split_evenly((n_fog.div_ceil(2), 2));
        for (fog, area) in areas.iter().enumerate().take(n_fog) {
            let b: Vec<f64> = window_means(&step.before_rad_s[fog], w).iter().map(|v| v * DEG_H_PER_RAD_S).collect();
            let a: Vec<f64> = window_means(&step.after_rad_s[fog], w).iter().map(|v| v * DEG_H_PER_RAD_S).collect();
            let sigma1 = super::noise::allan_deviation(&step.after_rad_s[fog], kept.dt_s).first().map_or(0.0, |p| p.1);
            let floor = sigma1 * DEG_H_PER_RAD_S * (kept.dt_s / tau_s).sqrt();
            let lim = b.iter().chain(&a).fold(floor, |m, v| m.max(v.abs())) * 1.15;
            let (t0, t1) = (t_h.first().copied().unwrap_or(0.0), t_h.last().copied().unwrap_or(1.0));
            let (t0, t1) = if t1 > t0 { (t0, t1) } else { (t0 - 1.0, t1 + 1.0) };
            let rms = |v: &[f64]| (v.iter().map(|x| x * x).sum::<f64>() / v.len().max(1) as f64).sqrt();
            let caption = format!(
                "FOG{fog}: RMS v{} {:.4} (grey) → v{} {:.4} °/h; floor ±{floor:.4} (dashed)",
                step.from,
                rms(&b),
                step.to,
                rms(&a)
            );
            let mut chart = ChartBuilder::on(area)
                .margin(8)
                .x_label_area_size(30)
                .y_label_area_size(60)
                .caption(caption, ("sans-serif", 14))
                .build_cartesian_2d(t0..t1, -lim..lim)
                .map_err(perr)?;
            chart
                .configure_mesh()
                .x_desc("time, h")
                .y_desc("°/h")
                .x_labels(6)
                .y_labels(5)
                .y_label_formatter(&|v| format!("{:.2}", if v.abs() < 0.005 { 0.0 } else { *v }))
                .draw()
                .map_err(perr)?;
            let c = fog_colour(fog).to_rgba();
            chart
                .draw_series(LineSeries::new(
                    t_h.iter().copied().zip(b.iter().copied()),
                    BLACK.mix(0.35).stroke_width(2),
                ))
                .map_err(perr)?;
            chart
                .draw_series(LineSeries::new(t_h.iter().copied().zip(a.iter().copied()), c.stroke_width(2)))
                .map_err(perr)?;
            for sign in [-1.0, 1.0] {
                let fl = vec![(t0, sign * floor), (t1, sign * floor)];
                chart.draw_series(DashedLineSeries::new(fl, 6, 4, BLACK.stroke_width(1))).map_err(perr)?;
            }
        }
        root.present().map_err(perr)?;
    }
    Ok(svg)
}

/// Writes an SVG string atomically.
pub fn write_svg(path: &Path, svg: &str) -> LabResult<()> {
    super::write_atomic(path, svg.as_bytes())
}

/// The minimum detectable sinusoid amplitude against period (log–log), as an SVG string.
pub fn detectable_svg(c: &super::detectable::SinusoidCurve) -> LabResult<String> {
    let pts: Vec<(f64, f64)> = c
        .period_s
        .iter()
        .zip(&c.amp_rad_s)
        .filter(|(p, a)| p.is_finite() && a.is_finite() && **p > 0.0 && **a > 0.0)
        .map(|(p, a)| (*p, a * DEG_H_PER_RAD_S))
        .collect();
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, (900, 380)).into_drawing_area();
        root.fill(&WHITE).map_err(perr)?;
        if pts.len() >= 2 {
            let (x0, x1) = (pts[0].0, pts[pts.len() - 1].0.max(pts[0].0 * 1.01));
            let (lo, hi) = pts.iter().fold((f64::MAX, f64::MIN), |(a, b), p| (a.min(p.1), b.max(p.1)));
            let (lo, hi) = (lo / 1.5, hi.max(lo * 1.01) * 1.5);
            let mut chart = ChartBuilder::on(&root)
                .margin(10)
                .x_label_area_size(40)
                .y_label_area_size(70)
                .caption(
                    "minimum detectable sinusoid amplitude (80 % detection, any one FOG) against period",
                    ("sans-serif", 16),
                )
                .build_cartesian_2d((x0..x1).log_scale(), (lo..hi).log_scale())
                .map_err(perr)?;
            chart
                .configure_mesh()
                .x_desc("period, s")
                .y_desc("amplitude, °/h")
                .label_style(("sans-serif", 12))
                .draw()
                .map_err(perr)?;
            chart.draw_series(LineSeries::new(pts.clone(), fog_colour(0).stroke_width(2))).map_err(perr)?;
        }
        root.present().map_err(perr)?;
    }
    Ok(svg)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fog_colours_are_readable_on_white() {
        for (fog, c) in FOG_COLOURS.iter().enumerate() {
            let r = contrast_on_white(*c);
            assert!(r >= 3.0, "FOG{fog} colour {c:?}: contrast {r:.2} on white, under 3:1");
        }
        // The check can fail: plotters' Palette99 yellow (FOG2's former colour) is under it.
        assert!(contrast_on_white((255, 225, 25)) < 3.0);
    }
}
