//! The `--json` form of `ssis-lab`'s summaries (docs/JSON.md): the figures the text
//! shows, in engineering units named in the keys.

use ssis_common::cli::{json, Value};
use ssis_common::DEG_H_PER_RAD_S;

use super::diagnose::Diagnosis;
use super::fit::{AddOutcome, Comparison};
use super::model::{Kind, Model};

fn dh(v: f64) -> f64 {
    v * DEG_H_PER_RAD_S
}

/// The coefficients of every term of `model`, per FOG, with the regressors' names and units.
fn coefficients(model: &Model, kinds: &[Kind]) -> Value {
    let mut out = Vec::new();
    for (t, k) in kinds.iter().enumerate() {
        for (fog, c) in model.terms[t].coef.iter().enumerate() {
            let labels = k.regressor_labels(fog);
            let regs: Vec<Value> =
                c.iter().zip(&labels).map(|(v, (n, u))| json!({"name": n, "value": v, "unit": u})).collect();
            out.push(json!({"term": k.label(), "fog": fog, "coefficients": regs}));
        }
    }
    Value::Array(out)
}

/// `compare`: per FOG error, residual, largest residual, explained fraction, held-out RMS.
pub fn comparison(c: &Comparison, model: &str, session: &str, evaluated: bool) -> Value {
    let f = &c.fitted;
    let fogs: Vec<Value> = f
        .summary
        .iter()
        .enumerate()
        .map(|(i, x)| {
            json!({
                "fog": i,
                "rms_error_deg_h": dh(x.rms_error_rad_s),
                "rms_residual_deg_h": dh(x.rms_residual_rad_s),
                "max_abs_residual_deg_h": dh(x.max_abs_residual_rad_s),
                "explained_fraction": x.explained,
                "held_out_rms_deg_h": c.held_out_rad_s.get(i).map(|v| dh(*v)),
            })
        })
        .collect();
    json!({
        "model": model,
        "session": session,
        "samples": f.sample.of_rows,
        "evaluated": evaluated,
        "terms": f.model.kinds().iter().map(Kind::label).collect::<Vec<_>>(),
        "fogs": fogs,
        "not_identified": f.not_identified,
        "coefficients": coefficients(&f.model, &f.model.kinds()),
    })
}

/// `diagnose`: the candidates in rank order, the terms not tested, the T × G ANOVA.
pub fn diagnosis(d: &Diagnosis) -> Value {
    let candidates: Vec<Value> = d
        .candidates
        .iter()
        .enumerate()
        .map(|(r, c)| {
            json!({
                "rank": r + 1,
                "candidate": c.kind.label(),
                "p_value": c.p_value,
                "before_deg_h": dh(c.before_rad_s),
                "after_deg_h": dh(c.after_rad_s),
                "drop_fraction": 1.0 - c.after_rad_s / c.before_rad_s,
                "removed_deg_h": dh(c.removed_rad_s().0),
                "removed_1sigma_deg_h": [dh(c.removed_rad_s().1), dh(c.removed_rad_s().2)],
                "origin": c.origin,
                "significant": c.significant,
            })
        })
        .collect();
    let skipped: Vec<Value> = d.skipped.iter().map(|(k, why)| json!({"candidate": k, "why": why})).collect();
    let f = |x: (f64, usize, usize, f64)| json!({"f": x.0, "nu1": x.1, "nu2": x.2, "p_value": x.3});
    let anova: Vec<Value> = d
        .anova
        .iter()
        .map(|a| {
            json!({
                "fog": a.fog,
                "cells": a.cells,
                "t_edges_degc": a.t_edges_degc,
                "g_edges_degc_min": a.g_edges_degc_s.map(|g| g * 60.0),
                "f_t": f(a.f_t),
                "f_g": f(a.f_g),
                "f_tg": f(a.f_tg),
            })
        })
        .collect();
    let det = &d.detectable;
    let terms: Vec<Value> = det
        .terms
        .iter()
        .map(|t| {
            json!({
                "term": t.term,
                "unit": t.unit.0,
                "min_detectable": t.worst_eng(),
                "per_fog": t.per_fog.iter().map(|v| v.map(|v| v * t.unit.1)).collect::<Vec<_>>(),
                "not_identifiable": t.not_identifiable,
            })
        })
        .collect();
    let sinusoid = det.sinusoid.as_ref().map(|s| {
        let sum = s.summary();
        json!({
            "period_s": s.period_s,
            "amplitude_deg_h": s.amp_rad_s.iter().map(|&a| dh(a)).collect::<Vec<_>>(),
            "searched_period_s": [s.searched_s.0, s.searched_s.1],
            "base_share": s.base_share,
            "min_detectable_deg_h": sum.map(|x| dh(x.0)),
            "over_period_s": sum.map(|x| [x.1, x.2]),
        })
    });
    json!({
        "detectable": {
            "power": crate::detectable::POWER,
            "alpha_per_fog": det.alpha_per_fog,
            "terms": terms,
            "sinusoid": sinusoid,
        },
        "fdr_level": d.fdr_level,
        "train_samples": d.n_train,
        "test_samples": d.n_test,
        "candidates": candidates,
        "most_significant": d.significant().next().map(|c| c.kind.label()),
        "skipped": skipped,
        "anova": anova,
    })
}

/// `add`: held-out RMS per FOG before and after, the new term's coefficients.
pub fn added(out: &AddOutcome, kind: &Kind, path: &str) -> Value {
    let fogs: Vec<Value> = out
        .before_rad_s
        .iter()
        .zip(&out.after_rad_s)
        .enumerate()
        .map(|(i, (b, a))| json!({"fog": i, "before_deg_h": dh(*b), "after_deg_h": dh(*a)}))
        .collect();
    let t = out.model.terms.len() - 1;
    let mut only = out.model.clone();
    only.terms = vec![out.model.terms[t].clone()];
    json!({
        "term": kind.label(),
        "model": path,
        "version": out.model.version,
        "fogs": fogs,
        "pooled_before_deg_h": dh(super::fit::pooled(&out.before_rad_s)),
        "pooled_after_deg_h": dh(super::fit::pooled(&out.after_rad_s)),
        "not_identified": out.not_identified,
        "coefficients": coefficients(&only, std::slice::from_ref(kind)),
    })
}

/// One row of a model's history: version, pooled and per-FOG held-out RMS, terms.
pub fn history_row(version: u32, pooled_deg_h: f64, per_fog_deg_h: &[f64], terms: &str) -> Value {
    json!({"version": version, "held_out_rms_deg_h": pooled_deg_h, "per_fog_deg_h": per_fog_deg_h, "terms": terms})
}
