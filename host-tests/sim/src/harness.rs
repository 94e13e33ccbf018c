//! The harness: simulator → frames → links → `FlightCore::step()` → output frames,
//! compared with truth. [`Simulation`] makes each step's bytes and truth; [`Evaluator`]
//! compares the unit's output with the truth of the sample it integrated (by its time
//! tag); [`run`] drives the core in-process through mock links. The QEMU runner
//! (`ssis_runner::qemu`) uses the same two pieces with the firmware in place of the core.
//!
//! Errors are measured in the instrument frame:
//! - attitude error e = rotation vector of Λ_true⁻¹ ∘ Λ_est, arcsec per axis;
//! - rate error = drift estimate Δω̂ − the systematic rate error the unit really has
//!   (its compensated, combined, noise-free gyro rate minus the true rate): what is left
//!   of the output rate's error once the FOGs' white noise is set aside.

use std::collections::VecDeque;

use anyhow::Result;
use nalgebra::{Quaternion, Vector3, Vector4};
use rand::SeedableRng;
use rand_chacha::ChaCha20Rng;
use ssis::calib::{CalibrationTable, N_FOG};
use ssis::combination::{Combiner, FogSet};
use ssis::compensation::compensate_increment;
use ssis::flight::{flags, health, Counters, FlightCore, FogLinks, Links, Profile, StepOutput};
use ssis::frames::output::OutputFrame;
use ssis::math::rotvec_from_quat;
use ssis::telemetry::events::EventRecord;

use crate::fog::FogModel;
use crate::scenario::Scenario;
use crate::star::StarModel;
use crate::truth::Truth;
use ssis_common::downlink::{records, Down, Downlink};
use ssis_common::mock::{LinkStats, MockLink, MockSink};
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

/// What the simulator sends in one step.
#[derive(Debug, Clone)]
pub struct StepInput {
    /// Step number, from 1.
    pub n: u64,
    /// One frame per FOG slot (only fitted slots are to be sent).
    pub fog_frames: [[u8; ssis::frames::fog::FogFrame::LEN]; N_FOG],
    /// The FOG slots whose frame arrives in this step (a recorded log may lack some).
    pub present: FogSet,
    /// Star-tracker bytes delivered in this step.
    pub st_bytes: Vec<u8>,
    /// Truth of this step's sample (a recorded log may have none).
    pub truth: Option<TruthSample>,
}

/// The simulated world of a scenario: truth, sensors, and the unit's table.
pub struct Simulation {
    /// The scenario.
    pub sc: Scenario,
    /// The unit's profile.
    pub profile: Profile,
    /// The table the unit flies with.
    pub table: CalibrationTable,
    /// Steps in the scenario.
    pub steps: u64,
    truth: Truth,
    fogs: FogModel,
    star: StarModel,
    rng: ChaCha20Rng,
    n: u64,
}

impl Simulation {
    /// Sets up the world of `sc`.
    pub fn new(sc: &Scenario) -> Result<Self> {
        let mut rng = ChaCha20Rng::seed_from_u64(sc.seed);
        let profile = sc.profile.profile();
        let truth = Truth::new(sc.motion.clone());
        let fogs = FogModel::new(&sc.fog, &mut rng);
        let table = sc.unit_table(&fogs.truth)?;
        let star = StarModel::new(&sc.star_tracker, profile.dt_us, table.st_mount());
        let steps = (sc.duration_s / profile.dt_s()).round() as u64;
        Ok(Simulation { sc: sc.clone(), profile, table, steps, truth, fogs, star, rng, n: 0 })
    }

    /// Λ at t = 0 (for units aligned on the pad).
    pub fn initial_q(&self) -> Quaternion<f64> {
        self.truth.quaternion()
    }

    /// Whether the unit aligns by other means than the star tracker.
    pub fn needs_pad_alignment(&self) -> bool {
        !self.profile.star_tracker || !self.sc.star_tracker.enabled
    }

    /// Mounts the FOGs as `m` says (an integration error; from power-on when called
    /// before the first step).
    pub fn mount_fogs(&mut self, m: crate::fog::Mounting) {
        self.fogs.mount(m);
    }

    /// Turn-on FOG biases drawn, rad/s.
    pub fn fog_random_bias_rad_s(&self) -> [f64; N_FOG] {
        self.fogs.random_bias_rad_s()
    }

    /// The next step's bytes and truth, or `None` at the end.
    pub fn next_step(&mut self) -> Option<StepInput> {
        if self.n >= self.steps {
            return None;
        }
        self.n += 1;
        let n = self.n;
        let dt_s = self.profile.dt_s();
        let ts = self.truth.advance(dt_s);
        let now_us = n * u64::from(self.profile.dt_us);
        let sample = self.fogs.sample(&ts.dtheta_rad, ts.t_s, dt_s, &mut self.rng);
        let st_bytes = self.star.step(n, now_us, &ts.q, &ts.rate_rad_s, &mut self.rng);
        let table = &self.table;
        let m_sys = Vector4::from_fn(|i, _| {
            compensate_increment(&table.fog[i], sample.raw_sys_rad[i], dt_s, sample.t_degc, sample.g_degc_s)
        });
        Some(StepInput {
            n,
            fog_frames: sample.frames.map(|f| f.to_bytes()),
            present: FogSet(0x0F),
            st_bytes: if self.profile.star_tracker { st_bytes } else { Vec::new() },
            truth: Some(TruthSample { n, q: ts.q, dtheta: ts.dtheta_rad, m_sys, rate: ts.rate_rad_s }),
        })
    }
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

/// One step of `core` on mock links: ticks the links, sends this step's frames (FOG i's
/// only if `fogs` contains it) and the star tracker's, and steps. The bytes the core
/// wrote stay in `out_link` for the caller.
pub fn step_on_mock_links(
    core: &mut FlightCore,
    fog_links: &mut [MockLink; N_FOG],
    star_link: &mut MockLink,
    out_link: &mut MockSink,
    input: &StepInput,
    fogs: FogSet,
) -> StepOutput {
    for l in fog_links.iter_mut() {
        l.tick();
    }
    star_link.tick();
    for (i, (link, f)) in fog_links.iter_mut().zip(input.fog_frames.iter()).enumerate() {
        if fogs.contains(i) && input.present.contains(i) {
            link.send(f);
        }
    }
    star_link.send(&input.st_bytes);
    let mut links = Links { fog: FogLinks::PerFog(fog_links.each_mut()), star: star_link, out: out_link };
    core.step(&mut links)
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

    /// For the unit of `sim`.
    pub fn new(sim: &Simulation) -> Self {
        Evaluator::for_unit(&sim.table, &sim.profile, sim.sc.settle_s)
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

/// What a run measured.
#[derive(Debug, Clone)]
pub struct Summary {
    /// Scenario name.
    pub name: String,
    /// Steps run.
    pub steps: u64,
    /// Simulated time, s.
    pub duration_s: f64,
    /// How well the run followed the truth.
    pub accuracy: Accuracy,
    /// The core's counters at the end.
    pub counters: Counters,
    /// Output frames decoded from the output link.
    pub frames_out: u64,
    /// Bytes of the output link in no frame (should be 0).
    pub frames_out_bad: u64,
    /// The unit's events as its event frames carried them, and the records it lost.
    pub events: (Vec<EventRecord>, u16),
    /// Output frames whose decoded content disagrees with the step's output.
    pub frames_out_mismatch: u64,
    /// What the FOG links did.
    pub fog_links: [LinkStats; N_FOG],
    /// What the star-tracker link did.
    pub star_link: LinkStats,
    /// Turn-on FOG biases drawn, °/h.
    pub fog_random_bias_deg_h: [f64; N_FOG],
    /// The run was stopped before this step (interrupted): the figures are partial.
    pub stopped_at_step: Option<u64>,
    /// The FOGs the unit has.
    pub fogs: FogSet,
    /// Whether the unit has a star tracker and the scenario enables it.
    pub star_tracker: bool,
}

/// Runs `sc` through the in-process core, calling `on_step` with every step's record.
pub fn run(sc: &Scenario, on_step: impl FnMut(&Record)) -> Result<Summary> {
    run_until(sc, || false, on_step)
}

/// [`run`], stopping early (a partial summary, [`Summary::stopped_at_step`]) once `stop`
/// returns true; it is asked before every step.
pub fn run_until(sc: &Scenario, mut stop: impl FnMut() -> bool, mut on_step: impl FnMut(&Record)) -> Result<Summary> {
    let mut sim = Simulation::new(sc)?;
    let mut eval = Evaluator::new(&sim);
    let profile = sim.profile;
    let mut core = FlightCore::new(profile, &sim.table, false).map_err(|e| anyhow::anyhow!("core: {e:?}"))?;
    if sim.needs_pad_alignment() {
        core.align(sim.initial_q());
    }
    let seed = sc.seed.wrapping_mul(0x9E37_79B9_7F4A_7C15);
    let mut fog_links = [0u64, 1, 2, 3].map(|i| MockLink::new(sc.links.fog, seed ^ (i + 1)));
    let mut star_link = MockLink::new(sc.links.star, seed ^ 99);
    let mut out_link = MockSink::default();
    let mut downlink = Downlink::new();
    let mut event_frames = Vec::new();
    let (mut frames_out, mut mismatch) = (0u64, 0u64);
    let mut last = None;
    let mut stopped_at_step = None;
    while let Some(input) = sim.next_step() {
        if stop() {
            stopped_at_step = Some(input.n - 1);
            break;
        }
        if let Some(t) = input.truth {
            eval.push_truth(t);
        }
        let out = step_on_mock_links(&mut core, &mut fog_links, &mut star_link, &mut out_link, &input, profile.fogs);
        last = Some(out);
        // The event log's records, as the firmware sends them after the step.
        core.send_events(&mut out_link);

        // Output frames: decode what the core wrote and check it is this step's output.
        let bytes = std::mem::take(&mut out_link.bytes);
        downlink.push(&bytes, |d| match d {
            Down::Output(f) => {
                frames_out += 1;
                if !frame_matches(&f, &out) {
                    mismatch += 1;
                }
            }
            Down::Events(e) => event_frames.push(e),
            Down::Report(_) => {}
        });
        if let Some(rec) = eval.evaluate(&Observed::from(&out)) {
            on_step(&rec);
        }
    }
    Ok(Summary {
        name: sc.name.clone(),
        steps: sim.steps,
        duration_s: sc.duration_s,
        accuracy: eval.accuracy(last.map(|o| [o.drift_rad_s.x, o.drift_rad_s.y, o.drift_rad_s.z]).unwrap_or_default()),
        counters: core.counters(),
        frames_out,
        frames_out_bad: downlink.bad_bytes(),
        events: records(&event_frames),
        frames_out_mismatch: mismatch,
        fog_links: [0, 1, 2, 3].map(|i| fog_links[i].stats()),
        star_link: star_link.stats(),
        fog_random_bias_deg_h: sim.fog_random_bias_rad_s().map(|b| b * DEG_H_PER_RAD_S),
        stopped_at_step,
        fogs: profile.fogs,
        star_tracker: profile.star_tracker && sc.star_tracker.enabled,
    })
}

/// Whether a decoded output frame carries `out` (to the frame's quantisation).
pub fn frame_matches(f: &OutputFrame, out: &StepOutput) -> bool {
    let q = f.quaternion();
    let dq = [out.q.w - q[0], out.q.i - q[1], out.q.j - q[2], out.q.k - q[3]];
    f.time_us == out.time_us && dq.iter().all(|d| d.abs() < 1e-9) && f.fog_health == out.fog_health
}

impl Summary {
    /// The sources that delivered nothing, in words (empty when every source delivered): a
    /// FOG link that dropped every byte, a star tracker none of whose frames the unit
    /// accepted, or no step evaluated after settling. A run with any has no accuracy figure
    /// to report (its 3σ would print as 0.00″).
    pub fn silent_sources(&self) -> Vec<String> {
        let mut out = Vec::new();
        for (i, l) in self.fog_links.iter().enumerate().filter(|(i, _)| self.fogs.contains(*i)) {
            if l.sent > 0 && l.dropped == l.sent {
                out.push(format!(
                    "FOG{i}'s link delivered nothing: all {} bytes dropped (links.fog.drop_prob)",
                    l.sent
                ));
            }
        }
        if self.star_tracker && self.counters.st_frames_accepted == 0 {
            let l = &self.star_link;
            out.push(format!(
                "the star tracker delivered no frame the unit accepted ({} bytes sent, {} dropped, {} frames rejected)",
                l.sent, l.dropped, self.counters.st_frames_rejected
            ));
        }
        if self.accuracy.att.count() == 0 {
            out.push(format!("no step was evaluated after settling at {:.0} s", self.accuracy.settle_s));
        }
        out
    }

    /// A report a person can read.
    pub fn report(&self) -> String {
        use std::fmt::Write;
        let mut s = String::new();
        let _ = writeln!(s, "scenario  {}  ({:.0} s simulated, {} steps)", self.name, self.duration_s, self.steps);
        if let Some(n) = self.stopped_at_step {
            let _ = writeln!(
                s,
                "INTERRUPTED after {n} of {} steps ({:.1} s of {:.0} s): the figures below are partial",
                self.steps,
                self.duration_s * n as f64 / self.steps.max(1) as f64,
                self.duration_s
            );
        }
        s.push_str(&self.accuracy.table());
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
