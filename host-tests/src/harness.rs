//! The harness: simulator → frames → mock links → `FlightCore::step()` → output frames,
//! compared with truth.
//!
//! Errors are measured in the instrument frame:
//! - attitude error e = rotation vector of Λ_true⁻¹ ∘ Λ_est, arcsec per axis;
//! - rate error = drift estimate Δω̂ − the systematic rate error the unit really has
//!   (its compensated, combined, noise-free gyro rate minus the true rate): what is left
//!   of the output rate's error once the FOGs' white noise is set aside.

use anyhow::Result;
use nalgebra::{Quaternion, Vector3, Vector4};
use rand::SeedableRng;
use rand_chacha::ChaCha20Rng;
use ssis::calib::{CalibrationTable, N_FOG};
use ssis::compensation::compensate_increment;
use ssis::flight::{Counters, FlightCore, FogLinks, Links, StepOutput};
use ssis::frames::decoder::StreamDecoder;
use ssis::frames::output::OutputFrame;
use ssis::math::rotvec_from_quat;

use crate::mock::{LinkStats, MockLink, MockSink};
use crate::scenario::Scenario;
use crate::sim::fog::FogModel;
use crate::sim::star::StarModel;
use crate::sim::truth::Truth;
use crate::stats::AxisStats;
use crate::{ARCSEC_PER_RAD, DEG_H_PER_RAD_S};

/// One step of a run as seen by the harness.
#[derive(Debug, Clone, Copy)]
pub struct Record {
    /// Time tag of the step's output (end of the integrated sample), s.
    pub t_s: f64,
    /// Truth Λ.
    pub q_true: Quaternion<f64>,
    /// The core's output of the step.
    pub out: StepOutput,
    /// Attitude error, arcsec (ICS).
    pub att_err_arcsec: [f64; 3],
    /// Systematic rate error of the combined gyros, rad/s (what Δω̂ should be).
    pub drift_sys_rad_s: [f64; 3],
    /// Δω̂ − drift_sys, °/h.
    pub rate_err_deg_h: [f64; 3],
    /// True body rate, rad/s.
    pub rate_true_rad_s: [f64; 3],
}

/// Truth of one sample, kept until the core's output for it comes out.
struct PastStep {
    n: u64,
    q: Quaternion<f64>,
    dtheta: Vector3<f64>,
    m_sys: Vector4<f64>,
    rate: Vector3<f64>,
}

/// What a run measured.
#[derive(Debug, Clone)]
pub struct Summary {
    /// Scenario name.
    pub name: String,
    /// Steps run.
    pub steps: u64,
    /// Simulated time, s.
    pub duration_s: f64,
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
    /// The core's counters at the end.
    pub counters: Counters,
    /// Output frames decoded from the output link.
    pub frames_out: u64,
    /// Output frames that failed to decode (should be 0).
    pub frames_out_bad: u64,
    /// Output frames whose decoded content disagrees with the step's output.
    pub frames_out_mismatch: u64,
    /// What the FOG links did.
    pub fog_links: [LinkStats; N_FOG],
    /// What the star-tracker link did.
    pub star_link: LinkStats,
    /// Turn-on FOG biases drawn, °/h.
    pub fog_random_bias_deg_h: [f64; N_FOG],
}

/// Runs `sc`, calling `on_step` with every step's record.
pub fn run(sc: &Scenario, mut on_step: impl FnMut(&Record)) -> Result<Summary> {
    let mut rng = ChaCha20Rng::seed_from_u64(sc.seed);
    let profile = sc.profile.profile();
    let dt_s = profile.dt_s();
    let mut truth = Truth::new(sc.motion.clone());
    let mut fogs = FogModel::new(&sc.fog, &mut rng);
    let table: CalibrationTable = sc.unit_table(&fogs.truth)?;
    let mut core = FlightCore::new(profile, &table, false).map_err(|e| anyhow::anyhow!("core: {e:?}"))?;
    if !profile.star_tracker || !sc.star_tracker.enabled {
        core.align(truth.quaternion());
    }
    let mut star = StarModel::new(&sc.star_tracker, profile.dt_us, table.st_mount());
    let seed = sc.seed.wrapping_mul(0x9E37_79B9_7F4A_7C15);
    let mut fog_links = [0u64, 1, 2, 3].map(|i| MockLink::new(sc.links.fog, seed ^ (i + 1)));
    let mut star_link = MockLink::new(sc.links.star, seed ^ 99);
    let mut out_link = MockSink::default();
    let mut out_dec: StreamDecoder<OutputFrame, 256> = StreamDecoder::new();
    let steps = (sc.duration_s / dt_s).round() as u64;
    let mut att = AxisStats::default();
    let mut rate = AxisStats::default();
    let mut converged_at = None;
    let (mut frames_out, mut frames_bad, mut mismatch) = (0u64, 0u64, 0u64);
    let mut last = None;
    let mut past: std::collections::VecDeque<PastStep> = std::collections::VecDeque::new();
    for n in 1..=steps {
        for l in fog_links.iter_mut() {
            l.tick();
        }
        star_link.tick();
        let ts = truth.advance(dt_s);
        let now_us = n * u64::from(profile.dt_us);
        let sample = fogs.sample(&ts.dtheta_rad, ts.t_s, dt_s, &mut rng);
        for (i, (link, f)) in fog_links.iter_mut().zip(sample.frames.iter()).enumerate() {
            if profile.fogs.contains(i) {
                link.send(&f.to_bytes());
            }
        }
        let st_bytes = star.step(n, now_us, &ts.q, &ts.rate_rad_s, &mut rng);
        if profile.star_tracker {
            star_link.send(&st_bytes);
        }
        let out = {
            let mut links =
                Links { fog: FogLinks::PerFog(fog_links.each_mut()), star: &mut star_link, out: &mut out_link };
            core.step(&mut links)
        };
        last = Some(out);

        // Output frames: decode what the core wrote and check it is this step's output.
        let bytes = std::mem::take(&mut out_link.bytes);
        out_dec.push_slice(&bytes, |r| match r {
            Ok(f) => {
                frames_out += 1;
                if !frame_matches(&f, &out) {
                    mismatch += 1;
                }
            }
            Err(_) => frames_bad += 1,
        });

        // Truth of the sample this step integrated (by its time tag: links may delay).
        let m_sys = Vector4::from_fn(|i, _| {
            compensate_increment(&table.fog[i], sample.raw_sys_rad[i], dt_s, sample.t_degc, sample.g_degc_s)
        });
        past.push_back(PastStep { n, q: ts.q, dtheta: ts.dtheta_rad, m_sys, rate: ts.rate_rad_s });
        if past.len() > 64 {
            past.pop_front();
        }
        let k = out.time_us / u64::from(profile.dt_us);
        let Some(p) = past.iter().find(|p| p.n == k) else {
            // No sample integrated yet (links still delivering the first frames).
            continue;
        };
        let e = rotvec_from_quat(&(p.q.conjugate() * out.q)) * ARCSEC_PER_RAD;
        let body_sys = core.combiner().combine(&p.m_sys, out.fogs_used).unwrap_or(p.dtheta);
        let drift_sys: Vector3<f64> = (body_sys - p.dtheta) / dt_s;
        let rerr = (out.drift_rad_s - drift_sys) * DEG_H_PER_RAD_S;
        let rec = Record {
            t_s: k as f64 * dt_s,
            q_true: p.q,
            out,
            att_err_arcsec: [e.x, e.y, e.z],
            drift_sys_rad_s: [drift_sys.x, drift_sys.y, drift_sys.z],
            rate_err_deg_h: [rerr.x, rerr.y, rerr.z],
            rate_true_rad_s: [p.rate.x, p.rate.y, p.rate.z],
        };
        if converged_at.is_none() && out.flags & ssis::flight::flags::CONVERGED != 0 {
            converged_at = Some(rec.t_s);
        }
        if rec.t_s >= sc.settle_s {
            att.push(rec.att_err_arcsec);
            rate.push(rec.rate_err_deg_h);
        }
        on_step(&rec);
    }
    Ok(Summary {
        name: sc.name.clone(),
        steps,
        duration_s: sc.duration_s,
        settle_s: sc.settle_s,
        att,
        rate,
        converged_at_s: converged_at,
        drift_final_rad_s: last.map(|o| [o.drift_rad_s.x, o.drift_rad_s.y, o.drift_rad_s.z]).unwrap_or_default(),
        counters: core.counters(),
        frames_out,
        frames_out_bad: frames_bad,
        frames_out_mismatch: mismatch,
        fog_links: [0, 1, 2, 3].map(|i| fog_links[i].stats()),
        star_link: star_link.stats(),
        fog_random_bias_deg_h: fogs.random_bias_rad_s().map(|b| b * DEG_H_PER_RAD_S),
    })
}

/// Whether a decoded output frame carries `out` (to the frame's quantisation).
pub fn frame_matches(f: &OutputFrame, out: &StepOutput) -> bool {
    let q = f.quaternion();
    let dq = [out.q.w - q[0], out.q.i - q[1], out.q.j - q[2], out.q.k - q[3]];
    f.time_us == out.time_us && dq.iter().all(|d| d.abs() < 1e-9) && f.fog_health == out.fog_health
}

impl Summary {
    /// A report a person can read.
    pub fn report(&self) -> String {
        use std::fmt::Write;
        let mut s = String::new();
        let f3 = |v: [f64; 3], p: usize| format!("{:>9.p$} {:>9.p$} {:>9.p$}", v[0], v[1], v[2], p = p);
        let _ = writeln!(s, "scenario  {}  ({:.0} s simulated, {} steps)", self.name, self.duration_s, self.steps);
        let _ = writeln!(s, "after settling at {:.0} s:                 x         y         z", self.settle_s);
        let _ = writeln!(s, "  attitude error 3σ (|mean|+3std), ″ {}", f3(self.att.three_sigma(), 2));
        let _ = writeln!(s, "  attitude error max, ″              {}", f3(self.att.max_abs(), 2));
        let _ = writeln!(s, "  rate error 3σ, °/h                 {}", f3(self.rate.three_sigma(), 4));
        let _ = writeln!(
            s,
            "  drift estimate at end, °/h         {}",
            f3(self.drift_final_rad_s.map(|d| d * DEG_H_PER_RAD_S), 4)
        );
        match self.converged_at_s {
            Some(t) => {
                let _ = writeln!(s, "  observer converged at {t:.1} s");
            }
            None => {
                let _ = writeln!(s, "  observer never reported convergence");
            }
        }
        let c = &self.counters;
        let _ = writeln!(
            s,
            "frames: out {} (bad {}, mismatched {}); FOG rejected {}, missing {}; star accepted {}, rejected {}, gated {}; output dropped {}",
            self.frames_out,
            self.frames_out_bad,
            self.frames_out_mismatch,
            c.fog_frames_rejected,
            c.fog_samples_missing,
            c.st_frames_accepted,
            c.st_frames_rejected,
            c.st_updates_gated,
            c.output_dropped
        );
        s
    }
}
