//! The `--json` form of a run's summary (docs/JSON.md), shared by `ssis-sim run` and
//! `ssis-qemu`: the figures the text shows, in the units named in the keys.

use ssis_common::cli::{json, Value};
use ssis_common::DEG_H_PER_RAD_S;

use crate::accuracy::Accuracy;
use crate::harness::Summary;

/// The errors against truth after settling.
pub fn accuracy(a: &Accuracy) -> Value {
    json!({
        "settle_s": a.settle_s,
        "samples": a.att.count(),
        "attitude_error_3sigma_arcsec": a.att.three_sigma(),
        "attitude_error_max_arcsec": a.att.max_abs(),
        "rate_error_3sigma_deg_h": a.rate.three_sigma(),
        "drift_estimate_end_deg_h": a.drift_final_rad_s.map(|d| d * DEG_H_PER_RAD_S),
        "observer_converged_at_s": a.converged_at_s,
    })
}

/// `ssis-sim run`: the run, its errors, what the links and the core counted.
pub fn run_summary(s: &Summary, wall_s: f64) -> Value {
    let c = &s.counters;
    json!({
        "scenario": s.name,
        "duration_s": s.duration_s,
        "steps": s.steps,
        "wall_s": wall_s,
        "accuracy": accuracy(&s.accuracy),
        "frames_out": s.frames_out,
        "frames_out_bad": s.frames_out_bad,
        "frames_out_mismatched": s.frames_out_mismatch,
        "events": ssis_common::downlink::events_json(&s.events.0),
        "events_lost": s.events.1,
        "counters": {
            "fog_frames_rejected": c.fog_frames_rejected,
            "fog_samples_missing": c.fog_samples_missing,
            "st_frames_accepted": c.st_frames_accepted,
            "st_frames_rejected": c.st_frames_rejected,
            "st_updates_gated": c.st_updates_gated,
            "output_dropped": c.output_dropped,
        },
        "fog_random_bias_deg_h": s.fog_random_bias_deg_h,
    })
}

/// A recorded log's damage, each kind counted with its first places.
pub fn damage(p: &crate::recorded::Problems) -> Value {
    let mut m = ssis_common::cli::serde_json::Map::new();
    for (name, d) in p.kinds() {
        m.insert(name.into(), json!({"count": d.count, "first": d.first}));
    }
    Value::Object(m)
}

/// The unit's own evidence on a replayed log.
pub fn evidence(e: &crate::replay::Evidence) -> Value {
    let c = e.last.map(|f| f.counters);
    json!({
        "st_residual_3sigma_arcsec": e.st_residual.three_sigma(),
        "st_residual_mean_arcsec": e.st_residual.mean(),
        "st_residual_frames": e.st_residual.count(),
        "parity_mean_rad": e.parity.mean()[0],
        "parity_std_rad": e.parity.std()[0],
        "st_frames_accepted": c.map(|c| c.st_frames_accepted),
        "st_frames_rejected": c.map(|c| c.st_frames_rejected),
        "st_updates_gated": c.map(|c| c.st_updates_gated),
        "fog_samples_missing": c.map(|c| c.fog_samples_missing),
        "drift_estimate_end_deg_h": e.last.map(|f| f.drift_rad_s().map(|d| d * DEG_H_PER_RAD_S)),
        "fogs": e.fogs.iter().map(|u| json!({
            "used": u.used,
            "missing": u.missing,
            "refused": u.refused,
            "excluded": u.excluded,
            "isolated_at_s": u.isolated_at_us.map(|t| t as f64 * 1e-6),
        })).collect::<Vec<_>>(),
        "fogs_remapped_at_s": e.remapped_at_us.map(|t| t as f64 * 1e-6),
    })
}

/// The estimation limits of a replay (`ssis_sim::accuracy::farrenkopf_1sigma_arcsec`) as
/// `/replay` keys, 3σ, and the log's damage: what `ssis-sim replay` and `ssis-qemu
/// --replay` add to [`replay_summary`].
pub fn add_limit_and_damage(v: &mut Value, limit: &crate::accuracy::Limit, p: &crate::recorded::Problems) {
    v["farrenkopf_att_3sigma_arcsec"] = json!(limit.posterior_arcsec.map(|x| 3.0 * x));
    v["limit_period_mean_att_3sigma_arcsec"] = json!(limit.period_mean_arcsec.map(|x| 3.0 * x));
    v["limit_latency_mean_att_3sigma_arcsec"] = json!(limit.latency_mean_arcsec.map(|x| 3.0 * x));
    v["st_latency_s"] = json!(limit.latency_s);
    v["damage"] = damage(p);
}

/// `ssis-sim replay`: the replay, its errors against truth (if any) and the evidence.
pub fn replay_summary(s: &crate::replay::ReplaySummary) -> Value {
    json!({
        "log": s.origin,
        "duration_s": s.duration_s,
        "steps": s.steps,
        "frames_out": s.frames_out,
        "output_hash": format!("{:016x}", s.hash),
        "accuracy": accuracy(&s.accuracy),
        "evidence": evidence(&s.evidence),
        "events": ssis_common::downlink::events_json(&s.events.0),
        "events_lost": s.events.1,
    })
}

/// `ssis-sim replay --check`: per channel what it carries, its polarity and scale.
pub fn check_report(r: &crate::check::CheckReport) -> Value {
    let fogs: Vec<Value> = r
        .fogs
        .iter()
        .map(|f| {
            json!({
                "channel": f.channel,
                "carries_fog": f.carries + 1,
                "polarity": f.polarity,
                "scale": f.scale,
                "scale_se": f.scale_se,
                "axis_off_arcsec": f.axis_off_arcsec,
            })
        })
        .collect();
    json!({
        "windows": r.windows,
        "excitation_arcsec": r.excitation_arcsec,
        "parity_rms_rad": r.parity_rms_rad,
        "parity_best": r.parity_best,
        "fogs": fogs,
        "findings": r.findings,
        "clean": r.findings.is_empty(),
    })
}

/// The conventions check (`docs/JSON.md`, replay: `conventions`).
pub fn conventions(r: &crate::conventions::ConventionReport) -> Value {
    let forms: Vec<Value> = r
        .forms
        .iter()
        .map(|f| {
            json!({
                "form": f.form.name(),
                "rms_arcsec": f.rms_arcsec,
                "fog_scale": f.scale,
                "fog_scale_se": f.scale_se,
            })
        })
        .collect();
    let tags = r.tags.map(|t| {
        json!({
            "offset_s": t.offset_s,
            "offset_se_s": t.offset_se_s,
            "windows": t.windows,
            "rms_at_zero_arcsec": t.rms_at_zero_arcsec,
            "rms_fitted_arcsec": t.rms_fitted_arcsec,
        })
    });
    json!({
        "pairs": r.pairs,
        "motion_rms_arcsec": r.motion_rms_arcsec,
        "forms": forms,
        "best_form": r.best.name(),
        "truth_forms": r.truth.iter().map(|f| json!({"form": f.form.name(), "rms_arcsec": f.rms_arcsec})).collect::<Vec<_>>(),
        "time_tags": tags,
        "findings": r.findings,
        "unchecked": r.unchecked,
        "clean": r.findings.is_empty(),
        "span_s": r.span_s,
    })
}

/// `ssis-sim replay` and `ssis-qemu --replay` on a launch-vehicle log: the errors
/// against truth (if any) and the unit's own evidence, from its navigation output frames.
pub fn lv_replay_summary(s: &crate::lv_replay::LvReplaySummary<'_>, rec: &crate::recorded::Recorded) -> Value {
    let e = &s.evidence;
    let err = |x: &crate::lv_replay::NavErrorAt| json!({"t_s": x.t_s, "position_m": x.pos_m, "velocity_m_s": x.vel_m_s, "attitude_arcsec": x.att_arcsec});
    let last = e.last;
    json!({
        "log": rec.origin,
        "unit": rec.unit.name(),
        "duration_s": s.duration_s,
        "steps": s.steps,
        "flight_frames_out": s.flight_frames,
        "nav_frames_out": e.frames,
        "output_hash": format!("{:016x}", s.hash),
        "truth": {
            "frames_scored": e.scored,
            "at_times": e.at_times.iter().map(err).collect::<Vec<_>>(),
            "end": e.end.as_ref().map(err),
            "max": e.end.as_ref().map(|_| err(&e.max)),
        },
        "evidence": {
            "gnss_innovations": e.innov_pos_m.count(),
            "gnss_innovation_position_max_m": e.innov_pos_m.max_abs(),
            "gnss_innovation_position_std_m": e.innov_pos_m.std(),
            "gnss_innovation_velocity_max_m_s": e.innov_vel_m_s.max_abs(),
            "gnss_innovation_velocity_std_m_s": e.innov_vel_m_s.std(),
            "fixes_used": last.map(|f| f.fixes_used),
            "fixes_refused": last.map(|f| f.fixes_refused),
            "frames_after_update": e.updated_frames,
            "frames_in_gnss_outage": e.outage_steps,
            "frames_accel_missing_or_faulty": e.accel_fault_steps,
            "frames_nav_step_refused": e.nav_fault_steps,
        },
        "damage": damage(&rec.problems),
    })
}

/// The conventions check of a launch-vehicle log (`docs/JSON.md`, replay: `conventions`).
pub fn lv_conventions(r: &crate::conventions::LvConventionReport) -> Value {
    json!({
        "reference": r.reference.0,
        "reference_positions": r.reference.1,
        "span_s": r.span_s,
        "units": r.fits.iter().map(|f| json!({"units": f.what, "rms_m": f.rms_m})).collect::<Vec<_>>(),
        "fog_truth_scale": r.fog_truth_scale.map(|(k, _)| k),
        "fog_truth_scale_se": r.fog_truth_scale.map(|(_, se)| se),
        "findings": r.findings,
        "unchecked": r.unchecked,
        "clean": r.findings.is_empty(),
    })
}
