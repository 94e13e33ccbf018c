//! One self-contained HTML page of a session's loop: the fit, the diagnosis, the history
//! of model versions, with the SVG plots inline (no scripts, no external resources).

use super::diagnose::Diagnosis;
use super::fit::{AddStep, Fitted, KeptTimes};
use super::plot::{history_svg, overlay_svg, residual_svg};
use super::LabResult;
use ssis_common::DEG_H_PER_RAD_S;

/// Escapes text for HTML.
pub fn esc(s: &str) -> String {
    s.replace('&', "&amp;").replace('<', "&lt;").replace('>', "&gt;").replace('"', "&quot;")
}

/// The page. `history` is (version, pooled held-out RMS, °/h) per model version; `steps`
/// the residuals before and after each `add` of the history, at the kept rows `kept`.
pub fn render(
    file: &str,
    fitted: &Fitted,
    diag: &Diagnosis,
    history: &[(u32, f64)],
    steps: &[AddStep],
    kept: &KeptTimes,
) -> LabResult<String> {
    let mut h = String::new();
    let m = &fitted.model;
    h.push_str("<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">");
    h.push_str(&format!("<title>ssis-lab: {}</title>", esc(file)));
    h.push_str(
        "<style>body{font-family:sans-serif;margin:2em;max-width:1100px}table{border-collapse:collapse;margin:1em 0}\
         td,th{border:1px solid #999;padding:3px 8px;text-align:right}th{background:#eee}td.l{text-align:left}\
         .sig{color:#a00;font-weight:bold}</style></head><body>\n",
    );
    h.push_str(&format!(
        "<h1>Model lab: {}</h1><p>{} samples, {} FOGs; model version {} with terms: {}.</p>\n",
        esc(file),
        fitted.sample.of_rows,
        fitted.summary.len(),
        m.version,
        esc(&m.kinds().iter().map(|k| k.label()).collect::<Vec<_>>().join(", "))
    ));
    for n in &fitted.notes {
        h.push_str(&format!("<p><b>Note:</b> {}</p>\n", esc(n)));
    }
    h.push_str("<h2>Fit</h2><table><tr><th>FOG</th><th>error RMS, °/h</th><th>residual RMS, °/h</th>");
    h.push_str("<th>max |residual|, °/h</th><th>explained</th><th>held-out RMS, °/h</th></tr>\n");
    for (i, s) in fitted.summary.iter().enumerate() {
        h.push_str(&format!(
            "<tr><td>{i}</td><td>{:.4}</td><td>{:.4}</td><td>{:.4}</td><td>{:.1} %</td><td>{:.4}</td></tr>\n",
            s.rms_error_rad_s * DEG_H_PER_RAD_S,
            s.rms_residual_rad_s * DEG_H_PER_RAD_S,
            s.max_abs_residual_rad_s * DEG_H_PER_RAD_S,
            100.0 * s.explained,
            diag.base_rms_rad_s.get(i).copied().unwrap_or(f64::NAN) * DEG_H_PER_RAD_S
        ));
    }
    h.push_str("</table>\n");
    if !fitted.not_identified.is_empty() {
        h.push_str(&format!(
            "<p>Not identifiable in this session (left at zero): {}.</p>\n",
            esc(&fitted.not_identified.join(", "))
        ));
    }
    h.push_str(&format!(
        "<h2>Diagnosis</h2><p>Held-out tests under the fitted noise model (GLS F-test and held-out direction test; {} \
         training, {} test samples), Benjamini–Hochberg at {} %.</p>\n",
        diag.n_train,
        diag.n_test,
        100.0 * diag.fdr_level
    ));
    if diag.significant().next().is_none() {
        h.push_str("<p><b>No significant missing effect.</b></p>\n");
    }
    h.push_str("<table><tr><th>rank</th><th>candidate</th><th>origin</th><th>p</th>");
    h.push_str(&format!(
        "<th>held-out before, °/h</th><th>after, °/h</th><th>significant at {} %</th></tr>\n",
        100.0 * diag.fdr_level
    ));
    for (r, c) in diag.candidates.iter().enumerate() {
        h.push_str(&format!(
            "<tr><td>{}</td><td class=\"l\">{}</td><td class=\"l\">{}</td><td>{:.2e}</td><td>{:.4}</td><td>{:.4}</td>\
             <td class=\"{}\">{}</td></tr>\n",
            r + 1,
            esc(&c.kind.label()),
            esc(&c.origin),
            c.p_value,
            c.before_rad_s * DEG_H_PER_RAD_S,
            c.after_rad_s * DEG_H_PER_RAD_S,
            if c.significant { "sig" } else { "l" },
            if c.significant { "yes" } else { "no" }
        ));
    }
    h.push_str("</table>\n");
    for a in &diag.anova {
        // As the command line prints it: ratio, degrees of freedom, p, critical values.
        let f = |name: &str, (r, d1, d2, p): (f64, usize, usize, f64)| {
            format!(
                "{name} = {r:.2} (ν {d1}, {d2}; p {p:.2e}; critical 5 % {:.2}, 1 % {:.2})",
                crate::diagnose::f_critical(0.05, d1, d2),
                crate::diagnose::f_critical(0.01, d1, d2)
            )
        };
        h.push_str(&format!(
            "<p>FOG{} two-factor ANOVA (T × G, {} cells): {}, {}, {}</p>\n",
            a.fog,
            a.cells,
            f("F_T", a.f_t),
            f("F_G", a.f_g),
            f("F_TG", a.f_tg)
        ));
    }
    h.push_str(&format!(
        "<h2>What this session could have shown</h2><p>Minimum detectable effect: the size found significant \
         with {:.0} % probability on any one FOG (α {:.1e} per candidate and FOG, under each FOG's noise model).</p>\n\
         <table><tr><th>candidate</th><th>minimum detectable</th><th>unit</th></tr>\n",
        100.0 * crate::detectable::POWER,
        diag.detectable.alpha_per_fog
    ));
    for t in &diag.detectable.terms {
        let (v, u) = match (t.worst_eng(), &t.not_identifiable) {
            (Some(v), _) => (format!("{v:.3e}"), t.unit.0.to_string()),
            (None, Some(why)) => ("not identifiable".into(), why.clone()),
            (None, None) => ("not identifiable".into(), String::new()),
        };
        h.push_str(&format!(
            "<tr><td class=\"l\">{}</td><td>{}</td><td class=\"l\">{}</td></tr>\n",
            esc(&t.term),
            esc(&v),
            esc(&u)
        ));
    }
    h.push_str("</table>\n");
    if let Some(sc) = &diag.detectable.sinusoid {
        h.push_str(&format!("<div>{}</div>\n", super::plot::detectable_svg(sc)?));
    }
    if history.len() > 1 {
        h.push_str("<h2>History</h2><table><tr><th>version</th><th>term added</th><th>held-out RMS, °/h</th></tr>\n");
        for (v, r) in history {
            let added = steps.iter().find(|s| s.to == *v).map_or("", |s| s.added.as_str());
            h.push_str(&format!("<tr><td>{v}</td><td class=\"l\">{}</td><td>{r:.4}</td></tr>\n", esc(added)));
        }
        h.push_str("</table>\n");
        h.push_str(&history_svg("held-out RMS by model version", history)?);
    }
    if !steps.is_empty() {
        h.push_str(
            "<h2>Residuals before and after each add</h2><p>Per FOG, the residual of the version before (grey) and \
             after (colour), each version's terms fitted on every row, as means over windows of the time shown; \
             the dashed lines are the white-noise floor at that averaging time (±σ₁√(Δt/τ), σ₁ from the Allan \
             deviation of the residual after at one sample). What lies outside the band before and inside it after \
             is what the term removed.</p>\n",
        );
        for st in steps {
            h.push_str(&format!("<div>{}</div>\n", overlay_svg(st, kept)?));
        }
    }
    h.push_str("<h2>Residuals</h2>\n");
    let kept = fitted.sample.residual.first().map_or(0, Vec::len);
    if fitted.sample.of_rows > kept {
        h.push_str(&format!(
            "<p>The plots show {kept} of the {} samples (a systematic sample); the largest residual is over {} \
             samples.</p>\n",
            fitted.sample.of_rows, fitted.max_over_rows
        ));
    }
    for fog in 0..fitted.summary.len() {
        h.push_str(&format!("<div>{}</div>\n", residual_svg(file, fitted, fog)?));
    }
    h.push_str("</body></html>\n");
    Ok(h)
}
