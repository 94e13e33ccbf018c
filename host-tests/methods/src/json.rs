//! The `--json` form of each `ssis-cal` method's summary (docs/JSON.md): the figures the
//! text shows, in the units named in the keys.

use ssis_common::cli::{json, Value};
use ssis_common::{ARCSEC_PER_RAD, DEG_H_PER_RAD_S};

use super::{allan, magnetic, misalign_sins, misalign_turns, orbital, thermal_anova};

fn dh(v: f64) -> f64 {
    v * DEG_H_PER_RAD_S
}

fn interval(v: (f64, f64, f64)) -> Value {
    json!({"value": v.0, "ci95_low": v.1, "ci95_high": v.2})
}

/// An Allan noise term: resolved (value and 95 % interval) or only a 95 % upper bound.
fn estimate(e: &allan::Estimate) -> Value {
    match *e {
        allan::Estimate::Resolved { value, lo, hi } => interval((value, lo, hi)),
        allan::Estimate::UpperBound(u) => json!({"upper_bound_95": u}),
    }
}

/// `magnetic`: the eq. (1)/(2) fits per FOG and the site's field.
pub fn magnetic(r: &magnetic::MagneticResult, field_nt: Option<[f64; 3]>) -> Value {
    let fit = |f: &magnetic::SinusoidFit| {
        json!({
            "offset_deg_h": dh(f.offset_rad_s),
            "amplitude_deg_h": dh(f.amplitude_rad_s),
            "phase_deg": f.phase_rad.to_degrees(),
            "phase_sigma_deg": f.phase_sigma_rad.to_degrees(),
            "rms_deg_h": dh(f.rms_rad_s),
        })
    };
    let fogs: Vec<Value> = ["X", "Y"]
        .iter()
        .enumerate()
        .map(|(k, name)| {
            json!({
                "fog": name,
                "unscreened": fit(&r.unscreened[k]),
                "screened": fit(&r.screened[k]),
                "difference": fit(&r.magnetic[k]),
            })
        })
        .collect();
    json!({
        "fogs": fogs,
        "positions": r.psi_rad.len(),
        "field_ocs_nt": field_nt,
        "predicted_phase_deg": field_nt.map(|b| magnetic::predicted_phase_rad(b).to_degrees()),
    })
}

/// `thermal`: the F-tests of Table 2 and the model when it is built.
pub fn thermal(a: &thermal_anova::Anova, model: Option<&thermal_anova::ThermalModel>) -> Value {
    let test = |t: &thermal_anova::FTest| {
        json!({
            "f": t.f, "nu1": t.nu1, "nu2": t.nu2, "critical_5_percent": t.crit_5,
            "critical_1_percent": t.crit_1, "p_value": t.p,
            "significant_5_percent": t.significant_5(), "significant_1_percent": t.significant_1(),
        })
    };
    let model = model.map(|m| {
        json!({
            "t_ref_degc": m.t_ref_degc,
            "bias_deg_h": dh(m.bias_rad_s),
            "a1_deg_h_per_degc": dh(m.a_rad_s[0]),
            "a2_deg_h_per_degc2": dh(m.a_rad_s[1]),
            "a3_deg_h_per_degc3": dh(m.a_rad_s[2]),
            "g_deg_h_per_degc_min": dh(m.g_rad_s_per_degc_s) / 60.0,
            "h_deg_h_per_degc2_min": dh(m.h_rad_s_per_degc2_s) / 60.0,
            "rms_deg_h": dh(m.rms_rad_s),
        })
    });
    json!({
        "cells": a.n_cells,
        "per_cell": a.n_per_cell,
        "f_t": test(&a.t),
        "f_g": test(&a.g),
        "f_tg": test(&a.tg),
        "model_built": model.is_some(),
        "model": model,
    })
}

/// `allan`: the deviation per τ and the noise terms with their 95 % intervals.
pub fn allan(points: &[allan::AdevPoint], nt: &allan::NoiseTerms) -> Value {
    let pts: Vec<Value> = points
        .iter()
        .map(|p| {
            json!({
                "tau_s": p.tau_s,
                "adev_deg_h": dh(p.adev_rad_s),
                "ci95_low_deg_h": dh(p.ci95_rad_s.0),
                "ci95_high_deg_h": dh(p.ci95_rad_s.1),
            })
        })
        .collect();
    json!({
        "points": pts,
        "arw_deg_sqrt_h": estimate(&nt.arw_deg_sqrt_h),
        "bias_instability_deg_h": estimate(&nt.bias_instability_deg_h),
        "bias_instability_tau_s": nt.tau_min_s,
        "rrw_deg_h_sqrt_h": estimate(&nt.rrw_deg_h_sqrt_h),
    })
}

/// `turns`: the turns found and the eight angles of the first method.
pub fn turns(turns: &[misalign_turns::Turn], r: &misalign_turns::TurnsResult) -> Value {
    let t: Vec<Value> = turns
        .iter()
        .map(|t| {
            json!({
                "up": (["X", "Y", "Z"][t.up]),
                "psi0_deg": t.psi0_rad.to_degrees(),
                "turn_deg": t.theta_t_rad.to_degrees(),
                "table_rate_deg_s": t.omega_rad_s.to_degrees(),
            })
        })
        .collect();
    let angles = misalign_turns::ANGLE_NAMES
        .iter()
        .zip(misalign_turns::angles(&r.misalignment))
        .map(|(n, v)| (format!("{n}_arcsec"), json!(v * ARCSEC_PER_RAD)));
    json!({
        "turns": t,
        "angles": Value::Object(angles.collect()),
        "residual_rms_arcsec": rms_arcsec(&r.residual_rad),
    })
}

/// `sins`: the six triad angles, start and estimate, and the residuals.
pub fn sins(start: &ssis::calib::Misalignment, from: &str, r: &misalign_sins::SinsResult) -> Value {
    let (a0, a1) = (misalign_sins::triad_angles(start), misalign_sins::triad_angles(&r.misalignment));
    let angles: Vec<Value> = misalign_sins::TRIAD_NAMES
        .iter()
        .enumerate()
        .map(|(k, n)| {
            json!({
                "angle": n,
                "start_arcsec": a0[k] * ARCSEC_PER_RAD,
                "estimate_arcsec": a1[k] * ARCSEC_PER_RAD,
                "sigma_arcsec": finite(r.sigma_rad[k] * ARCSEC_PER_RAD),
            })
        })
        .collect();
    json!({
        "start": from,
        "angles": angles,
        "iterations": r.iterations,
        "reversals": r.residual_rad.len() / 2,
        "residual_rms_start_arcsec": rms_arcsec(&r.residual_start_rad),
        "residual_rms_arcsec": rms_arcsec(&r.residual_rad),
    })
}

/// `orbital`: bias, scale factors and star-tracker mount.
pub fn orbital(r: &orbital::OrbitalResult, tau_s: f64) -> Value {
    let b = &r.bias;
    let v3 = |v: &nalgebra::Vector3<f64>, k: f64| [v.x * k, v.y * k, v.z * k];
    json!({
        "maneuvers": r.maneuvers.len(),
        "observer_tau_s": tau_s,
        "bias": {
            "window_s": [b.window_s.0, b.window_s.1],
            "drift_deg_h": v3(&b.drift_rad_s, DEG_H_PER_RAD_S),
            "drift_sigma_deg_h": v3(&b.sigma_rad_s, DEG_H_PER_RAD_S),
            "fog_delta_deg_h": b.fog_delta_rad_s.map(dh),
        },
        "scale_factor_delta_percent": r.scale.as_ref().map(|s| s.dk.map(|x| x * 100.0)),
        "mount": r.mount.as_ref().map(|m| json!({
            "eta_arcsec": v3(&m.eta_rad, ARCSEC_PER_RAD),
            "eta_norm_arcsec": m.eta_rad.norm() * ARCSEC_PER_RAD,
            "star_frame_pairs": m.samples,
        })),
        "unexplained_arcsec_per_rad": r.unexplained_rad_per_rad.iter().map(|v| v * ARCSEC_PER_RAD).collect::<Vec<_>>(),
    })
}

fn rms_arcsec(v: &[f64]) -> f64 {
    (v.iter().map(|x| x * x).sum::<f64>() / v.len().max(1) as f64).sqrt() * ARCSEC_PER_RAD
}

/// A number, or null where it is not finite (JSON has no NaN).
fn finite(v: f64) -> Option<f64> {
    v.is_finite().then_some(v)
}
