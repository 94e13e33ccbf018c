//! How well the unit's output follows the truth, and how well it could: what the harness
//! (a scenario in-process), the QEMU runner and the replay of a recorded log all measure.
//!
//! - [`Evaluator`] compares each output ([`Observed`], from a `StepOutput` or a decoded
//!   output frame) with the truth of the sample it integrated ([`TruthSample`], found by
//!   the output's time tag), giving a [`Record`] per step and the [`Accuracy`] of a run.
//! - [`farrenkopf_1sigma_arcsec`] and [`loop_1sigma_arcsec`] give the estimation
//!   [`Limit`] of a unit on its sensors' noise figures.
//!
//! Errors are measured in the instrument frame:
//! - attitude error e = rotation vector of Λ_true⁻¹ ∘ Λ_est, arcsec per axis;
//! - rate error = drift estimate Δω̂ − the systematic rate error the unit really has
//!   (its compensated, combined, noise-free gyro rate minus the true rate): what is left
//!   of the output rate's error once the FOGs' white noise is set aside.

use std::collections::VecDeque;

use nalgebra::{Matrix3, Quaternion, Vector3, Vector4};
use ssis::calib::{CalibrationTable, ObserverConfig, ObserverGains, N_FOG};
use ssis::combination::{Combiner, FogSet};
use ssis::flight::{flags, health, Profile, StepOutput};
use ssis::frames::output::OutputFrame;
use ssis::math::rotvec_from_quat;
use ssis_common::stats::AxisStats;
use ssis_common::{ARCSEC_PER_RAD, DEG_H_PER_RAD_S};

/// Truth of one FOG sample, kept until the unit's output for it comes out.
#[derive(Debug, Clone, Copy)]
pub struct TruthSample {
    /// Sample number (its end is at n·Δt).
    pub n: u64,
    /// Λ at the sample's end.
    pub q: Quaternion<f64>,
    /// True body increment over the sample, rad.
    pub dtheta: Vector3<f64>,
    /// Noise-free raw increments compensated with the unit's table, rad.
    pub m_sys: Vector4<f64>,
    /// True body rate at the sample's end, rad/s.
    pub rate: Vector3<f64>,
}

/// The unit's output of one step, from a `StepOutput` or a decoded output frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Observed {
    /// Time tag, µs.
    pub time_us: u64,
    /// Λ.
    pub q: Quaternion<f64>,
    /// Drift estimate, rad/s.
    pub drift_rad_s: Vector3<f64>,
    /// Flag bits.
    pub flags: u8,
    /// Star-tracker status bits.
    pub st_status: u8,
    /// FOGs combined.
    pub fogs_used: FogSet,
    /// Step time reported by the board, ticks.
    pub step_ticks: u16,
    /// Fault-logic bits (held temperatures, isolated FOGs; `docs/ICD.md`).
    pub fdi: u8,
    /// The unit's attitude-error 1σ per axis, rad (infinite: unknown).
    pub att_sigma_rad: [f64; 3],
    /// The unit's drift-error 1σ per axis, rad/s (infinite: unknown).
    pub drift_sigma_rad_s: [f64; 3],
}

impl From<&StepOutput> for Observed {
    fn from(o: &StepOutput) -> Self {
        Observed {
            time_us: o.time_us,
            q: o.q,
            drift_rad_s: o.drift_rad_s,
            flags: o.flags,
            st_status: o.st_status,
            fogs_used: o.fogs_used,
            step_ticks: 0,
            fdi: o.fdi,
            att_sigma_rad: o.att_sigma_rad,
            drift_sigma_rad_s: o.drift_sigma_rad_s,
        }
    }
}

impl From<&OutputFrame> for Observed {
    fn from(f: &OutputFrame) -> Self {
        let [w, x, y, z] = f.quaternion();
        let mut used = 0u8;
        for (i, h) in f.fog_health.iter().enumerate() {
            if h & health::USED != 0 {
                used |= 1 << i;
            }
        }
        Observed {
            time_us: f.time_us,
            q: Quaternion::new(w, x, y, z),
            drift_rad_s: Vector3::from(f.drift_rad_s()),
            flags: f.flags,
            st_status: f.st_status,
            fogs_used: FogSet(used),
            step_ticks: f.counters.step_ticks,
            fdi: f.fdi,
            att_sigma_rad: f.att_sigma_rad(),
            drift_sigma_rad_s: f.drift_sigma_rad_s(),
        }
    }
}

/// One step as seen by the harness.
#[derive(Debug, Clone, Copy)]
pub struct Record {
    /// Time tag of the output (end of the integrated sample), s.
    pub t_s: f64,
    /// Truth Λ at that time.
    pub q_true: Quaternion<f64>,
    /// What the unit said.
    pub out: Observed,
    /// Attitude error, arcsec (ICS).
    pub att_err_arcsec: [f64; 3],
    /// Systematic rate error of the combined gyros, rad/s (what Δω̂ should be).
    pub drift_sys_rad_s: [f64; 3],
    /// Δω̂ − drift_sys, °/h.
    pub rate_err_deg_h: [f64; 3],
    /// True body rate, rad/s.
    pub rate_true_rad_s: [f64; 3],
}

/// Columns of the per-step CSV log written by `ssis-sim run` and `ssis-qemu`.
pub const CSV_HEADER: [&str; 17] = [
    "t_s",
    "q0",
    "q1",
    "q2",
    "q3",
    "err_x_arcsec",
    "err_y_arcsec",
    "err_z_arcsec",
    "drift_x_deg_h",
    "drift_y_deg_h",
    "drift_z_deg_h",
    "rate_err_x_deg_h",
    "rate_err_y_deg_h",
    "rate_err_z_deg_h",
    "flags",
    "st_status",
    "step_ticks",
];

impl Record {
    /// The record as one CSV row, in the order of [`CSV_HEADER`].
    pub fn csv_row(&self) -> [String; 17] {
        let d = self.out.drift_rad_s * DEG_H_PER_RAD_S;
        [
            self.t_s,
            self.out.q.w,
            self.out.q.i,
            self.out.q.j,
            self.out.q.k,
            self.att_err_arcsec[0],
            self.att_err_arcsec[1],
            self.att_err_arcsec[2],
            d.x,
            d.y,
            d.z,
            self.rate_err_deg_h[0],
            self.rate_err_deg_h[1],
            self.rate_err_deg_h[2],
            f64::from(self.out.flags),
            f64::from(self.out.st_status),
            f64::from(self.out.step_ticks),
        ]
        .map(|v| v.to_string())
    }
}

/// Compares outputs with the truth of the samples they integrated.
pub struct Evaluator {
    past: VecDeque<TruthSample>,
    combiner: Combiner,
    dt_us: u64,
    settle_s: f64,
    /// Attitude error after settling, arcsec.
    pub att: AxisStats,
    /// Rate error after settling, °/h.
    pub rate: AxisStats,
    /// Time the unit first reported convergence, s.
    pub converged_at_s: Option<f64>,
}

impl Evaluator {
    /// What the evaluation found, with the unit's last drift estimate.
    pub fn accuracy(&self, drift_final_rad_s: [f64; 3]) -> Accuracy {
        Accuracy {
            settle_s: self.settle_s,
            att: self.att,
            rate: self.rate,
            converged_at_s: self.converged_at_s,
            drift_final_rad_s,
        }
    }

    /// For a unit flying `table` in `profile`, statistics from `settle_s` on.
    pub fn for_unit(table: &CalibrationTable, profile: &Profile, settle_s: f64) -> Self {
        Evaluator {
            past: VecDeque::new(),
            combiner: Combiner::new(&table.axes()),
            dt_us: u64::from(profile.dt_us),
            settle_s,
            att: AxisStats::default(),
            rate: AxisStats::default(),
            converged_at_s: None,
        }
    }

    /// Keeps the truth of a sample sent to the unit.
    pub fn push_truth(&mut self, t: TruthSample) {
        self.past.push_back(t);
        if self.past.len() > 256 {
            self.past.pop_front();
        }
    }

    /// Compares one output; `None` if its sample is unknown (no sample integrated yet).
    pub fn evaluate(&mut self, out: &Observed) -> Option<Record> {
        let k = out.time_us / self.dt_us;
        // Truth samples have one number each, the newest most often asked for.
        let p = self.past.iter().rev().find(|p| p.n == k)?;
        let dt_s = self.dt_us as f64 * 1e-6;
        let e = rotvec_from_quat(&(p.q.conjugate() * out.q)) * ARCSEC_PER_RAD;
        let body_sys = self.combiner.combine(&p.m_sys, out.fogs_used).unwrap_or(p.dtheta);
        let drift_sys: Vector3<f64> = (body_sys - p.dtheta) / dt_s;
        let rerr = (out.drift_rad_s - drift_sys) * DEG_H_PER_RAD_S;
        let rec = Record {
            t_s: k as f64 * dt_s,
            q_true: p.q,
            out: *out,
            att_err_arcsec: [e.x, e.y, e.z],
            drift_sys_rad_s: [drift_sys.x, drift_sys.y, drift_sys.z],
            rate_err_deg_h: [rerr.x, rerr.y, rerr.z],
            rate_true_rad_s: [p.rate.x, p.rate.y, p.rate.z],
        };
        if self.converged_at_s.is_none() && out.flags & flags::CONVERGED != 0 {
            self.converged_at_s = Some(rec.t_s);
        }
        if rec.t_s >= self.settle_s {
            self.att.push(rec.att_err_arcsec);
            self.rate.push(rec.rate_err_deg_h);
        }
        Some(rec)
    }
}

/// How well a run followed the truth after settling; both runners (in-process and QEMU)
/// report it alike.
#[derive(Debug, Clone, Default)]
pub struct Accuracy {
    /// Statistics start, s.
    pub settle_s: f64,
    /// Attitude error after settling, arcsec.
    pub att: AxisStats,
    /// Rate error after settling, °/h.
    pub rate: AxisStats,
    /// Time the observer first reported convergence, s.
    pub converged_at_s: Option<f64>,
    /// Last drift estimate, rad/s.
    pub drift_final_rad_s: [f64; 3],
}

impl Accuracy {
    /// The error part of a report.
    pub fn table(&self) -> String {
        use std::fmt::Write;
        let mut s = String::new();
        let f3 = |v: [f64; 3], p: usize| format!("{:>9.p$} {:>9.p$} {:>9.p$}", v[0], v[1], v[2], p = p);
        let _ = writeln!(s, "after settling at {:.0} s:                 x         y         z", self.settle_s);
        let _ = writeln!(s, "  attitude error 3σ (|mean|+3std), ″ {}", f3(self.att.three_sigma(), 2));
        let _ = writeln!(s, "  attitude error max, ″              {}", f3(self.att.max_abs(), 2));
        let _ = writeln!(s, "  rate error 3σ, °/h                 {}", f3(self.rate.three_sigma(), 4));
        let drift = self.drift_final_rad_s.map(|d| d * DEG_H_PER_RAD_S);
        let _ = writeln!(s, "  drift estimate at end, °/h         {}", f3(drift, 4));
        match self.converged_at_s {
            Some(t) => {
                let _ = writeln!(s, "  observer converged at {t:.1} s");
            }
            None => {
                let _ = writeln!(s, "  observer never reported convergence");
            }
        }
        s
    }
}

/// The estimation limit of a unit (Farrenkopf 1978): the steady-state per-axis Kalman
/// filter of attitude and drift on the table's noise figures, star-tracker updates every
/// `st_period_s`, propagated every `dt_s`; the FOGs' angle random walk per body axis is
/// scaled by the least-squares combination of the table's axes (diag (SᵀS)⁻¹: 5/6 for
/// three orthogonal gyros and one equally inclined). Returns the attitude error 1σ per
/// axis, arcsec: right after an update (Farrenkopf's figure), averaged over the update
/// period (as the harness samples it, every step), and averaged over the period when each
/// solution arrives `latency_s` after the instant it holds (no estimator can use it before:
/// the newest information is then latency_s to latency_s + period old).
pub fn farrenkopf_1sigma_arcsec(
    cfg: &ObserverConfig,
    axes: &[Vector3<f64>; N_FOG],
    dt_s: f64,
    latency_s: f64,
) -> Limit {
    loop_1sigma_arcsec(cfg, axes, dt_s, latency_s, None)
}

/// The steady-state attitude error 1σ per axis, arcsec, of the per-axis loop of
/// [`farrenkopf_1sigma_arcsec`] (the same figures: after an update, period mean, period
/// mean with latency) with fixed `gains` (K_B, K_U of eq. (6), first axis's) instead of
/// the Kalman gains: the update is the Joseph form
/// P⁺ = (I − K H) P⁻ (I − K H)ᵀ + K R Kᵀ, K = [K_B, −K_U]ᵀ, H = [1 0], which is the
/// covariance of a fixed-gain observer for any gains (and the Kalman filter's for its own).
/// `None`: the Kalman gains, the limit itself.
pub fn loop_1sigma_arcsec(
    cfg: &ObserverConfig,
    axes: &[Vector3<f64>; N_FOG],
    dt_s: f64,
    latency_s: f64,
    gains: Option<ObserverGains>,
) -> Limit {
    let mut sts = Matrix3::zeros();
    for s in axes {
        sts += s * s.transpose();
    }
    let inv = sts.try_inverse().unwrap_or_else(Matrix3::identity);
    let deg = std::f64::consts::PI / 180.0;
    let su2 = (cfg.rrw_deg_h_sqrt_h * deg / 3600.0 / 60.0).powi(2);
    let r = (cfg.st_sigma_arcsec / ARCSEC_PER_RAD).powi(2);
    let per_update = (cfg.st_period_s / dt_s).round().max(1.0) as usize;
    let per_axis = [0, 1, 2].map(|k| {
        let sv2 = (cfg.arw_deg_sqrt_h * deg / 60.0).powi(2) * inv[(k, k)];
        // P = [[p11, p12], [p12, p22]] of (attitude, drift); θ̇ = −b + noise. Propagated
        // over h: F = [[1, −h], [0, 1]], Q = [[σv²h + σu²h³/3, −σu²h²/2], [., σu²h]].
        let prop = |(p11, p12, p22): (f64, f64, f64), h: f64| {
            (
                p11 - 2.0 * h * p12 + h * h * p22 + sv2 * h + su2 * h.powi(3) / 3.0,
                p12 - h * p22 - su2 * h * h / 2.0,
                p22 + su2 * h,
            )
        };
        let update = |(p11, p12, p22): (f64, f64, f64)| match gains {
            None => {
                let s = p11 + r;
                (p11 - p11 * p11 / s, p12 - p11 * p12 / s, p22 - p12 * p12 / s)
            }
            Some(g) => {
                let (k1, k2) = (g.k_b[0], -g.k_u_per_s[0]);
                (
                    (1.0 - k1) * (1.0 - k1) * p11 + k1 * k1 * r,
                    (1.0 - k1) * (p12 - k2 * p11) + k1 * k2 * r,
                    p22 - 2.0 * k2 * p12 + k2 * k2 * (p11 + r),
                )
            }
        };
        // The drift's time constant is hours: iterate the update period until steady.
        let t = per_update as f64 * dt_s;
        let mut p = update((r, 0.0, su2 * 1e4));
        for _ in 0..2_000_000 {
            let next = update(prop(p, t));
            let done = (next.0 - p.0).abs() <= 1e-15 * p.0 && (next.2 - p.2).abs() <= 1e-12 * p.2;
            p = next;
            if done {
                break;
            }
        }
        let post = p.0;
        let mut sum = 0.0;
        for j in 0..per_update {
            p = prop(p, dt_s);
            if j + 1 == per_update {
                p = update(p);
            }
            sum += p.0;
        }
        let mean = sum / per_update as f64;
        // With latency: the same period, every age moved by the latency.
        let mut q = p;
        for _ in 0..(latency_s.max(0.0) / dt_s).round().min(1e6) as usize {
            q = prop(q, dt_s);
        }
        let mut late_sum = 0.0;
        for _ in 0..per_update {
            late_sum += q.0;
            q = prop(q, dt_s);
        }
        let late = late_sum / per_update as f64;
        (post.sqrt() * ARCSEC_PER_RAD, mean.sqrt() * ARCSEC_PER_RAD, late.sqrt() * ARCSEC_PER_RAD)
    });
    Limit {
        posterior_arcsec: per_axis.map(|p| p.0),
        period_mean_arcsec: per_axis.map(|p| p.1),
        latency_mean_arcsec: per_axis.map(|p| p.2),
        latency_s,
        lfe: if gains.is_none() && cfg.lfe() { Some(lfe_1sigma_arcsec(cfg, &inv, dt_s, latency_s)) } else { None },
    }
}

/// The estimation limit of [`farrenkopf_1sigma_arcsec`] when the star tracker has the
/// table's low-frequency error (LFE) and the filter estimates it: the steady-state per-axis
/// Kalman filter of x = (attitude error, drift error, LFE), the LFE a first-order
/// Gauss–Markov process (1σ `st_lfe_sigma_arcsec`, correlation time `st_lfe_tau_s`) seen
/// with the attitude, H = [1 0 1]: the model `ssis::observer::mekf` flies. `n` is
/// (SᵀS)⁻¹ of the table's axes. Returns (after an update, period mean with latency), 1σ
/// per axis, arcsec.
fn lfe_1sigma_arcsec(cfg: &ObserverConfig, n: &Matrix3<f64>, dt_s: f64, latency_s: f64) -> ([f64; 3], [f64; 3]) {
    let deg = std::f64::consts::PI / 180.0;
    let su2 = (cfg.rrw_deg_h_sqrt_h * deg / 3600.0 / 60.0).powi(2);
    let r = (cfg.st_sigma_arcsec / ARCSEC_PER_RAD).powi(2);
    let sc2 = (cfg.st_lfe_sigma_arcsec / ARCSEC_PER_RAD).powi(2);
    let per_update = (cfg.st_period_s / dt_s).round().max(1.0) as usize;
    let per_axis = [0, 1, 2].map(|k| {
        let sv2 = (cfg.arw_deg_sqrt_h * deg / 60.0).powi(2) * n[(k, k)];
        let prop = |p: &Matrix3<f64>, h: f64| {
            let phi = (-h / cfg.st_lfe_tau_s).exp();
            let f = Matrix3::new(1.0, -h, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, phi);
            let q12 = -su2 * h * h / 2.0;
            let q = Matrix3::new(
                sv2 * h + su2 * h.powi(3) / 3.0,
                q12,
                0.0,
                q12,
                su2 * h,
                0.0,
                0.0,
                0.0,
                sc2 * (1.0 - phi * phi),
            );
            f * p * f.transpose() + q
        };
        let update = |p: &Matrix3<f64>| {
            let h = Vector3::new(1.0, 0.0, 1.0);
            let u = p * h;
            let s = h.dot(&u) + r;
            let post = p - u * u.transpose() / s;
            (post + post.transpose()) * 0.5
        };
        let t = per_update as f64 * dt_s;
        let mut p = update(&Matrix3::from_diagonal(&Vector3::new(r + sc2, su2 * 1e4, sc2)));
        for _ in 0..2_000_000 {
            let next = update(&prop(&p, t));
            let done = (next[(0, 0)] - p[(0, 0)]).abs() <= 1e-15 * p[(0, 0)]
                && (next[(1, 1)] - p[(1, 1)]).abs() <= 1e-12 * p[(1, 1)];
            p = next;
            if done {
                break;
            }
        }
        let post = p[(0, 0)];
        let mut q = p;
        for _ in 0..(latency_s.max(0.0) / dt_s).round().min(1e6) as usize {
            q = prop(&q, dt_s);
        }
        let mut late_sum = 0.0;
        for _ in 0..per_update {
            late_sum += q[(0, 0)];
            q = prop(&q, dt_s);
        }
        let late = late_sum / per_update as f64;
        (post.sqrt() * ARCSEC_PER_RAD, late.sqrt() * ARCSEC_PER_RAD)
    });
    (per_axis.map(|p| p.0), per_axis.map(|p| p.1))
}

/// The estimation limit, attitude 1σ per axis.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Limit {
    /// Right after a star-tracker update (Farrenkopf's steady-state figure), arcsec.
    pub posterior_arcsec: [f64; 3],
    /// Averaged over the update period, arcsec.
    pub period_mean_arcsec: [f64; 3],
    /// Averaged over the update period with the solutions' latency, arcsec: the bound for
    /// an every-step statistic on these sensors.
    pub latency_mean_arcsec: [f64; 3],
    /// The star tracker's latency it was computed for, s.
    pub latency_s: f64,
    /// With the table's star-tracker low-frequency error estimated (the MEKF's 9 states):
    /// the limit after an update and averaged over the period with the latency, arcsec;
    /// `None` for a white tracker.
    pub lfe: Option<([f64; 3], [f64; 3])>,
}
