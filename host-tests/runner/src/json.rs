//! The `--json` form of `ssis-qemu`'s summaries (docs/JSON.md): the figures the text
//! shows, in the units named in the keys.

use ssis_common::cli::{json, Value};
use ssis_common::ARCSEC_PER_RAD;

use ssis::telemetry::Counter;

use super::qemu::{Pacing, QemuSummary};
use super::qemu_lv::LvSummary;

/// A spacecraft run on `ssis-fw`.
pub fn qemu_summary(s: &QemuSummary) -> Value {
    let c = &s.last_frame.counters;
    json!({
        "scenario": s.name,
        "duration_s": s.duration_s,
        "steps": s.steps,
        "wall_s": s.wall_s,
        "accuracy": ssis_sim::json::accuracy(&s.accuracy),
        "fog_frames_in": s.fog_frames_in,
        "st_frames_in": s.st_frames_in,
        "frames_out": s.frames_out,
        "frames_out_bad_bytes": s.frames_out_bad,
        "unit_counters": {
            "fog_frames_rejected": c.fog_frames_rejected,
            "fog_samples_missing": c.fog_samples_missing,
            "st_frames_accepted": c.st_frames_accepted,
            "st_frames_rejected": c.st_frames_rejected,
            "st_updates_gated": c.st_updates_gated,
            "overruns": c.overruns,
            "st_frames_late": s.paged_counter(Counter::StFramesLate),
            "st_frames_early": s.paged_counter(Counter::StFramesEarly),
        },
        "pacing": match s.host.mode {
            Pacing::Lockstep => "lockstep",
            Pacing::Paced => "paced_lockstep",
            Pacing::RealTime => "real_time",
        },
        "host_late_steps": s.host.late_steps,
        "host_late_max_s": s.host.late_max_s,
        "host_out_lag_max_s": s.host.out_lag_max_s,
        "host_late_pct": s.host.late_pct(s.steps, u64::from(c.overruns)),
        "step_time_unit": if s.icount { "instructions" } else { "systick_ticks_40ns" },
        "step_time_mean": s.step_ticks_mean,
        "step_time_max": s.step_ticks_max,
        "step_counts": s.step_counts,
        "events": ssis_common::downlink::events_json(&ssis_common::downlink::records(&s.event_frames).0),
        "events_identical": s.events_match(),
        "frames_identical": s.equal_frames,
        "frames_different": s.differing_frames,
        "firmware_log": s.log,
        "qemu_exit_code": s.exit_code,
    })
}

/// A launch-vehicle ascent on `ssis-fw-lv`.
pub fn lv_summary(s: &LvSummary) -> Value {
    json!({
        "scenario": s.name,
        "duration_s": s.duration_s,
        "steps": s.steps,
        "wall_s": s.wall_s,
        "frames_in_fog_accel_gnss": s.frames_in,
        "flight_frames": s.flight_frames,
        "nav_frames": s.nav_frames,
        "bad_bytes": s.bad_bytes,
        "flight_frames_identical": s.flight_equal,
        "flight_frames_different": s.flight_differing,
        "nav_frames_identical": s.nav_equal,
        "nav_frames_different": s.nav_differing,
        "overruns": s.overruns,
        "max_position_error_m": s.max_err.0,
        "max_velocity_error_m_s": s.max_err.1,
        "max_attitude_error_arcsec": s.max_err.2 * ARCSEC_PER_RAD,
        "final_position_error_m": s.final_err.0,
        "final_velocity_error_m_s": s.final_err.1,
        "final_attitude_error_arcsec": s.final_err.2 * ARCSEC_PER_RAD,
        "gnss_fixes_used": s.fixes.0,
        "gnss_fixes_refused": s.fixes.1,
        "firmware_log": s.log,
        "qemu_exit_code": s.exit_code,
        "clean": s.clean(),
    })
}
