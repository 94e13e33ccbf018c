//! The `--json` form of a run's summary (docs/JSON.md), shared by `ssis-sim run` and
//! `ssis-qemu`: the figures the text shows, in the units named in the keys.

use ssis_common::cli::{json, Value};
use ssis_common::DEG_H_PER_RAD_S;

use super::harness::{Accuracy, Summary};

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
