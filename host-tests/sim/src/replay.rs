//! Replay of a recorded log (`crate::recorded`) through `FlightCore::step`, and what the
//! unit's output says about it: against truth where the log has it, and otherwise the
//! unit's own evidence (star-tracker residuals, parity residual, gated frames, drift).
//!
//! [`Feed`] turns the log into the same per-step bytes the simulator makes
//! ([`StepInput`]), so the QEMU runner streams exactly what the host replay steps on.
//! [`Evidence`] reads output frames only, so the host replay and the firmware's output
//! are judged alike.

use std::collections::VecDeque;

use std::path::{Path, PathBuf};

use anyhow::Result;
use nalgebra::{Quaternion, Vector3, Vector4};
use ssis::calib::{CalibrationTable, N_FOG};
use ssis::combination::FogSet;
use ssis::flight::{FlightCore, FogLinks, Links, Profile};
use ssis::frames::decoder::StreamDecoder;
use ssis::frames::fog::FogFrame;
use ssis::frames::output::OutputFrame;
use ssis::frames::star::{self, StarFrame};
use ssis::math::{nlerp, rotvec_from_quat};
use ssis::telemetry::events::EventRecord;

pub use crate::accuracy::{farrenkopf_1sigma_arcsec, loop_1sigma_arcsec, Limit};
use crate::accuracy::{Accuracy, Evaluator, Observed, Record, TruthSample};
use crate::harness::StepInput;
use crate::recorded::{LogStep, Recorded, StarSample};
use ssis_common::downlink::records;
use ssis_common::mock::{MockLink, MockSink};
use ssis_common::output;
use ssis_common::stats::AxisStats;
use ssis_common::{ARCSEC_PER_RAD, DEG_H_PER_RAD_S};

/// The log as the unit's links carry it, step by step.
pub struct Feed<'a> {
    rec: &'a Recorded,
    enc: Encoder,
}

impl<'a> Feed<'a> {
    /// Steps of `rec` for a unit flying `table` at `dt_us`.
    pub fn new(rec: &'a Recorded, table: &CalibrationTable, dt_us: u32) -> Feed<'a> {
        Feed { rec, enc: Encoder::new(table, dt_us) }
    }

    /// Steps in the log.
    pub fn steps(&self) -> u64 {
        self.rec.steps.len() as u64
    }

    /// The next step's bytes (FOG frames numbered from counter 1, star frames at their
    /// re-based tags) and its truth, or `None` at the end.
    pub fn next_step(&mut self) -> Option<StepInput> {
        let step = self.rec.steps.get(self.enc.n as usize)?;
        Some(self.enc.encode(step))
    }
}

/// A log's steps turned into the bytes the unit's links carry, one step after another.
pub struct Encoder {
    axes: [Vector3<f64>; N_FOG],
    dt_us: u32,
    n: u64,
    st_counter: u16,
    prev_truth: Option<Quaternion<f64>>,
}

impl Encoder {
    /// For a unit flying `table` at `dt_us`, from step 1.
    pub fn new(table: &CalibrationTable, dt_us: u32) -> Encoder {
        Encoder { axes: table.axes(), dt_us, n: 0, st_counter: 0, prev_truth: None }
    }

    /// Steps encoded so far.
    pub fn steps(&self) -> u64 {
        self.n
    }

    /// The star-tracker frame counter of the last frame encoded.
    pub fn st_counter(&self) -> u16 {
        self.st_counter
    }

    /// An encoder that continues after `steps` steps whose last star-tracker frame had
    /// counter `st_counter` (a run stopped and resumed elsewhere; no truth before it).
    pub fn resumed(table: &CalibrationTable, dt_us: u32, steps: u64, st_counter: u16) -> Encoder {
        Encoder { n: steps, st_counter, ..Encoder::new(table, dt_us) }
    }

    /// The next step's bytes (FOG frames numbered from counter 1, star frames at their
    /// re-based tags) and its truth.
    pub fn encode(&mut self, step: &LogStep) -> StepInput {
        self.n += 1;
        let n = self.n;
        let counter = (n % 65_536) as u16;
        let mut present = 0u8;
        let fog_frames: [[u8; FogFrame::LEN]; N_FOG] = std::array::from_fn(|i| match step.fog[i] {
            Some(s) => {
                present |= 1 << i;
                FogFrame::from_physical(i as u8, counter, s.status, s.dtheta_rad, s.t_degc).to_bytes()
            }
            None => [0; FogFrame::LEN],
        });
        let mut st_bytes = Vec::new();
        for s in &step.st {
            self.st_counter = self.st_counter.wrapping_add(1);
            let flags = if s.valid { star::flags::VALID } else { 0 };
            st_bytes.extend_from_slice(&StarFrame::from_physical(flags, self.st_counter, s.time_us, s.q).to_bytes());
        }
        let dt_s = f64::from(self.dt_us) * 1e-6;
        let truth = step.truth.map(|t| {
            // The body increment from consecutive truth attitudes (or the rate); the
            // FOGs' own systematic error is not in a log: the rate error is then the
            // drift estimate itself.
            let dtheta = match self.prev_truth {
                Some(p) => rotvec_from_quat(&(p.conjugate() * t.q)),
                None => t.rate_rad_s * dt_s,
            };
            let m_sys = Vector4::from_fn(|i, _| self.axes[i].dot(&dtheta));
            TruthSample { n, q: t.q, dtheta, m_sys, rate: t.rate_rad_s }
        });
        self.prev_truth = step.truth.map(|t| t.q);
        StepInput { n, fog_frames, present: FogSet(present), st_bytes, truth }
    }
}

/// The unit's own evidence on a log without truth, from its output frames: star-tracker
/// residuals against its attitude at each tag, the parity residual, gated frames, the
/// drift estimate.
#[derive(Debug, Clone)]
pub struct Evidence {
    pending: VecDeque<StarSample>,
    mount_inv: Quaternion<f64>,
    history: VecDeque<(u64, Quaternion<f64>)>,
    settle_us: u64,
    /// Star-tracker residual rotvec((Λ(t_s))⁻¹ ∘ Λ* ∘ q_bs⁻¹) after settling, arcsec (ICS).
    pub st_residual: AxisStats,
    /// Parity residual after settling, rad (first component; a scalar).
    pub parity: AxisStats,
    /// The last output frame.
    pub last: Option<OutputFrame>,
    /// What became of each FOG's samples over the whole log (from power-on).
    pub fogs: [FogUse; N_FOG],
    /// When the unit first flagged two FOGs found swapped and flew them remapped, µs.
    pub remapped_at_us: Option<u64>,
}

/// What became of one FOG's samples, from the output frames' health bits and fault-logic
/// bits.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct FogUse {
    /// Samples combined.
    pub used: u64,
    /// Steps without its sample.
    pub missing: u64,
    /// Samples refused by the channel checks: device fault, out of range, stuck.
    pub refused: u64,
    /// Steps excluded (isolated, a parity spike, not fitted).
    pub excluded: u64,
    /// When the fault logic first isolated it, µs of unit time.
    pub isolated_at_us: Option<u64>,
}

impl Evidence {
    /// For the star solutions of `rec`, the table's star-tracker mount, statistics from
    /// `settle_s` of unit time on.
    pub fn new(rec: &Recorded, table: &CalibrationTable, settle_s: f64) -> Evidence {
        let mut e = Evidence::empty(table, settle_s);
        for s in rec.steps.iter().flat_map(|s| s.st.iter()) {
            e.star(s);
        }
        e
    }

    /// For star solutions given as they arrive ([`Evidence::star`]), before the output
    /// frame of the step they arrive in.
    pub fn empty(table: &CalibrationTable, settle_s: f64) -> Evidence {
        Evidence {
            pending: VecDeque::new(),
            mount_inv: table.st_mount().conjugate(),
            history: VecDeque::new(),
            settle_us: (settle_s * 1e6) as u64,
            st_residual: AxisStats::default(),
            parity: AxisStats::default(),
            last: None,
            fogs: [FogUse::default(); N_FOG],
            remapped_at_us: None,
        }
    }

    /// Takes a star-tracker solution (kept until the output frames reach its tag; an
    /// invalid one is not compared).
    pub fn star(&mut self, s: &StarSample) {
        if s.valid {
            self.pending.push_back(*s);
        }
    }

    /// Takes one output frame of the unit.
    pub fn frame(&mut self, f: &OutputFrame) {
        let [w, x, y, z] = f.quaternion();
        let q = Quaternion::new(w, x, y, z);
        self.history.push_back((f.time_us, q));
        self.count_fogs(f);
        if self.history.len() > 512 {
            self.history.pop_front();
        }
        if f.time_us >= self.settle_us && f.fog_health.iter().any(|h| h & ssis::flight::health::USED != 0) {
            let p = f.parity_rad();
            self.parity.push([p, p, p]);
        }
        while let Some(s) = self.pending.front().copied() {
            if s.time_us > f.time_us {
                break;
            }
            self.pending.pop_front();
            if s.time_us < self.settle_us {
                continue;
            }
            if let Some(qi) = self.attitude_at(s.time_us) {
                let [a, b, c, d] = s.q;
                let q_ics = Quaternion::new(a, b, c, d) * self.mount_inv;
                let e = rotvec_from_quat(&(qi.conjugate() * q_ics)) * ARCSEC_PER_RAD;
                self.st_residual.push([e.x, e.y, e.z]);
            }
        }
        self.last = Some(*f);
    }

    /// Counts what became of each FOG's sample in frame `f`.
    fn count_fogs(&mut self, f: &OutputFrame) {
        use ssis::flight::health;
        for (i, (u, h)) in self.fogs.iter_mut().zip(f.fog_health).enumerate() {
            if h & health::USED != 0 {
                u.used += 1;
            } else if h & (health::DEVICE_FAULT | health::OUT_OF_RANGE | health::STUCK) != 0 {
                u.refused += 1;
            } else if h & health::MISSING != 0 {
                u.missing += 1;
            } else if h & health::EXCLUDED != 0 {
                u.excluded += 1;
            }
            if f.fdi & (0x10 << i) != 0 && u.isolated_at_us.is_none() {
                u.isolated_at_us = Some(f.time_us);
            }
        }
        if f.flags & ssis::frames::output::flags::FOGS_REMAPPED != 0 && self.remapped_at_us.is_none() {
            self.remapped_at_us = Some(f.time_us);
        }
    }

    /// The unit's attitude at `t_us`, interpolated between its outputs.
    fn attitude_at(&self, t_us: u64) -> Option<Quaternion<f64>> {
        let k = self.history.iter().position(|(t, _)| *t >= t_us)?;
        let (t1, q1) = self.history[k];
        if t1 == t_us || k == 0 {
            return (t1 == t_us).then_some(q1);
        }
        let (t0, q0) = self.history[k - 1];
        Some(nlerp(&q0, &q1, (t_us - t0) as f64 / (t1 - t0) as f64))
    }

    /// The evidence in words.
    pub fn report(&self) -> String {
        let mut s = String::new();
        let f3 = |v: [f64; 3], p: usize| format!("{:>9.p$} {:>9.p$} {:>9.p$}", v[0], v[1], v[2], p = p);
        s.push_str("the unit's own evidence after settling:  x         y         z\n");
        s.push_str(&format!(
            "  star-tracker residual 3σ, ″        {}  ({} frames; the tracker's noise and the attitude error together)\n",
            f3(self.st_residual.three_sigma(), 2),
            self.st_residual.count()
        ));
        s.push_str(&format!("  star-tracker residual mean, ″      {}\n", f3(self.st_residual.mean(), 2)));
        s.push_str(&format!(
            "  parity residual RMS {:.3e} rad, mean {:.3e} rad\n",
            (self.parity.std()[0].powi(2) + self.parity.mean()[0].powi(2)).sqrt(),
            self.parity.mean()[0]
        ));
        let fitted: Vec<usize> =
            (0..N_FOG).filter(|&i| self.fogs[i].used + self.fogs[i].refused + self.fogs[i].missing > 0).collect();
        if !fitted.is_empty() {
            s.push_str("  FOG samples (whole log)    used   missing   refused  excluded\n");
            for &i in &fitted {
                let u = &self.fogs[i];
                s.push_str(&format!(
                    "    FOG{}              {:>10} {:>9} {:>9} {:>9}\n",
                    i + 1,
                    u.used,
                    u.missing,
                    u.refused,
                    u.excluded
                ));
            }
            for &i in &fitted {
                let u = &self.fogs[i];
                let all = u.used + u.missing + u.refused + u.excluded;
                if u.refused * 100 > all {
                    s.push_str(&format!(
                        "  FOG{} refused {:.1} % of its samples (device fault, out of range or stuck): check its \
                         column's unit and sign (conventions, below)\n",
                        i + 1,
                        100.0 * u.refused as f64 / all.max(1) as f64
                    ));
                }
                if let Some(t) = u.isolated_at_us {
                    s.push_str(&format!(
                        "  FOG{} isolated by the fault logic at {:.2} s (`ssis-sim replay --check` names the cause)\n",
                        i + 1,
                        t as f64 * 1e-6
                    ));
                }
            }
        }
        if let Some(t) = self.remapped_at_us {
            s.push_str(&format!(
                "  two FOGs found swapped in their mounts at {:.2} s: the unit flies them remapped\n",
                t as f64 * 1e-6
            ));
        }
        if let Some(f) = &self.last {
            let c = &f.counters;
            s.push_str(&format!(
                "  star frames accepted {}, rejected {}, gated {}; drift estimate at end, °/h {}\n",
                c.st_frames_accepted,
                c.st_frames_rejected,
                c.st_updates_gated,
                f3(f.drift_rad_s().map(|d| d * DEG_H_PER_RAD_S), 4)
            ));
        }
        s
    }
}

/// What a host replay found.
#[derive(Debug, Clone)]
pub struct ReplaySummary {
    /// The log.
    pub origin: String,
    /// Steps stepped.
    pub steps: u64,
    /// Unit time covered, s.
    pub duration_s: f64,
    /// Against truth (no steps counted when the log has none).
    pub accuracy: Accuracy,
    /// The unit's own evidence.
    pub evidence: Evidence,
    /// Output frames decoded.
    pub frames_out: u64,
    /// Every output frame's bytes, in order (for comparisons with the firmware's).
    pub hash: u64,
    /// The unit's events as its event frames carried them, and the records it lost.
    pub events: (Vec<EventRecord>, u16),
}

/// Replays `rec` through `FlightCore::step` with `table` (spacecraft profile), the
/// statistics from `settle_s`; `on_frame` sees every output frame and its record against
/// truth (if the log has truth for it).
pub fn replay(
    rec: &Recorded,
    table: &CalibrationTable,
    settle_s: f64,
    mut on_frame: impl FnMut(&OutputFrame, Option<&Record>),
) -> Result<ReplaySummary> {
    let mut r = Replayer::new(table, settle_s)?;
    for step in &rec.steps {
        r.step(step, &mut on_frame);
    }
    Ok(r.finish(rec.origin.clone()))
}

/// A replay driven one log step at a time (a log read whole, or as it is read): the
/// unit's side ([`UnitSide`]: the log's step into frames, `FlightCore::step`, the output
/// link's bytes) and the reading of what it sent ([`OutputSide`]), which a streamed
/// replay runs on two threads (`crate::streamed`).
pub struct Replayer {
    /// The unit's side.
    pub unit: UnitSide,
    /// The output side.
    pub output: OutputSide,
    /// A step's bytes (reused).
    produced: Vec<u8>,
}

/// The unit: the log's steps encoded into its links' bytes, stepped, its output link's
/// bytes kept.
pub struct UnitSide {
    profile: Profile,
    core: FlightCore,
    enc: Encoder,
    fog: MockLink,
    star: MockLink,
    out: MockSink,
    bytes: Vec<u8>,
}

/// What one step of the unit sent: its output link's bytes from `start` in the buffer
/// they were appended to, the output frame's first (`output_len` bytes), then the event
/// frame if one was sent; and the step's truth.
#[derive(Debug, Clone, Copy)]
pub struct Sent {
    /// Where the step's bytes start.
    pub start: usize,
    /// Bytes of its output frame.
    pub output_len: usize,
    /// All its bytes (output and event frames).
    pub len: usize,
    /// Its truth (a log may have none).
    pub truth: Option<TruthSample>,
}

impl UnitSide {
    /// Steps the unit on `step`; its output link's bytes appended to `produced`.
    pub fn step(&mut self, step: &LogStep, produced: &mut Vec<u8>) -> Sent {
        let input = self.enc.encode(step);
        self.bytes.clear();
        for (i, f) in input.fog_frames.iter().enumerate() {
            if self.profile.fogs.contains(i) && input.present.contains(i) {
                self.bytes.extend_from_slice(f);
            }
        }
        self.fog.send(&self.bytes);
        self.star.send(&input.st_bytes);
        let mut links = Links { fog: FogLinks::Bus(&mut self.fog), star: &mut self.star, out: &mut self.out };
        self.core.step(&mut links);
        let start = produced.len();
        produced.append(&mut self.out.bytes);
        let output_len = produced.len() - start;
        self.core.send_events(&mut self.out);
        produced.append(&mut self.out.bytes);
        Sent { start, output_len, len: produced.len() - start, truth: input.truth }
    }

    /// Steps taken.
    pub fn steps(&self) -> u64 {
        self.enc.steps()
    }
}

/// The unit's output link read as the ground reads it: frames decoded, fingerprinted,
/// evaluated against truth and the unit's own evidence.
pub struct OutputSide {
    eval: Evaluator,
    evidence: Evidence,
    /// The output frames' decoder and the event frames' (each step's bytes are whole
    /// frames, the output frame first: each decoder is given its own).
    output: StreamDecoder<OutputFrame, 256>,
    events: StreamDecoder<ssis::frames::event::EventFrame, 128>,
    event_frames: Vec<ssis::frames::event::EventFrame>,
    frames_out: u64,
    hash: OutputHash,
}

impl OutputSide {
    /// Takes what the unit sent in one step of the log's `step` (`bytes` from
    /// [`UnitSide::step`]); `on_frame` sees its output frame and the record against truth.
    pub fn take(
        &mut self,
        step: &LogStep,
        sent: &Sent,
        bytes: &[u8],
        on_frame: &mut impl FnMut(&OutputFrame, Option<&Record>),
    ) {
        for s in &step.st {
            self.evidence.star(s);
        }
        if let Some(t) = sent.truth {
            self.eval.push_truth(t);
        }
        let mine = bytes.get(sent.start..sent.start + sent.len).unwrap_or_default();
        let (out, events) = mine.split_at(sent.output_len.min(mine.len()));
        // The output frames' bytes only: the hash compares them with the firmware's.
        self.hash.write(out);
        let (frames_out, evidence, eval) = (&mut self.frames_out, &mut self.evidence, &mut self.eval);
        self.output.push_slice(out, |r| {
            if let Ok(f) = r {
                *frames_out += 1;
                evidence.frame(&f);
                let rec = eval.evaluate(&Observed::from(&f));
                on_frame(&f, rec.as_ref());
            }
        });
        let event_frames = &mut self.event_frames;
        self.events.push_slice(events, |r| {
            if let Ok(f) = r {
                event_frames.push(f);
            }
        });
    }
}

impl Replayer {
    /// A unit flying `table` (spacecraft profile), statistics from `settle_s`.
    pub fn new(table: &CalibrationTable, settle_s: f64) -> Result<Replayer> {
        let profile = Profile::SPACECRAFT;
        let core = FlightCore::new(profile, table, false).map_err(|e| anyhow::anyhow!("core: {e:?}"))?;
        Ok(Replayer {
            unit: UnitSide {
                profile,
                core,
                enc: Encoder::new(table, profile.dt_us),
                fog: MockLink::ideal(),
                star: MockLink::ideal(),
                out: MockSink::default(),
                bytes: Vec::with_capacity(64),
            },
            output: OutputSide {
                eval: Evaluator::for_unit(table, &profile, settle_s),
                evidence: Evidence::empty(table, settle_s),
                output: StreamDecoder::new(),
                events: StreamDecoder::new(),
                event_frames: Vec::new(),
                frames_out: 0,
                hash: OutputHash::default(),
            },
            produced: Vec::with_capacity(256),
        })
    }

    /// Steps the unit on the log's next step; `on_frame` sees its output frame and the
    /// record against truth.
    pub fn step(&mut self, step: &LogStep, on_frame: &mut impl FnMut(&OutputFrame, Option<&Record>)) {
        self.produced.clear();
        let sent = self.unit.step(step, &mut self.produced);
        self.output.take(step, &sent, &self.produced, on_frame);
    }

    /// What the replay found, for the log named `origin`.
    pub fn finish(self, origin: String) -> ReplaySummary {
        let (u, o) = (self.unit, self.output);
        let last_drift = o.evidence.last.map(|f| f.drift_rad_s()).unwrap_or_default();
        ReplaySummary {
            origin,
            steps: u.enc.steps(),
            duration_s: u.enc.steps() as f64 * u.profile.dt_s(),
            accuracy: o.eval.accuracy(last_drift),
            evidence: o.evidence,
            frames_out: o.frames_out,
            hash: o.hash.value(),
            events: records(&o.event_frames),
        }
    }
}

/// A replay's output fingerprint (`output_hash`): XXH3-64 (seed 0) of the output bytes in
/// order, streamed. The same bytes give the same value whatever the calls' boundaries,
/// on every machine, eight bytes at a time (a byte-serial hash takes 7 % of a replay's
/// CPU: BENCHMARKS.md).
#[derive(Clone, Default)]
pub struct OutputHash(xxhash_rust::xxh3::Xxh3Default);

impl OutputHash {
    /// Adds bytes.
    pub fn write(&mut self, bytes: &[u8]) {
        self.0.update(bytes);
    }

    /// The fingerprint of the bytes so far.
    pub fn value(&self) -> u64 {
        self.0.digest()
    }
}

impl std::fmt::Debug for OutputHash {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "OutputHash({:016x})", self.value())
    }
}

/// What a replay's report says of the log itself, counted over the whole log.
#[derive(Debug, Clone)]
pub struct LogInfo {
    /// FOG samples present.
    pub fog_samples: u64,
    /// The FOG slots the log has.
    pub fogs: FogSet,
    /// Star-tracker solutions delivered.
    pub st_count: u64,
    /// Whether the log carries truth.
    pub has_truth: bool,
    /// The damage counted.
    pub problems: crate::recorded::Problems,
}

impl LogInfo {
    /// Of a log read whole.
    pub fn of(rec: &Recorded) -> LogInfo {
        LogInfo {
            fog_samples: rec.fog_samples() as u64,
            fogs: rec.fogs,
            st_count: rec.st_count() as u64,
            has_truth: rec.has_truth,
            problems: rec.problems.clone(),
        }
    }
}

impl ReplaySummary {
    /// A report a person can read.
    pub fn report(&self, rec: &Recorded, limit: Option<Limit>) -> String {
        self.report_on(&LogInfo::of(rec), limit)
    }

    /// The same, from what was counted of the log while it was read.
    pub fn report_on(&self, rec: &LogInfo, limit: Option<Limit>) -> String {
        let mut s = format!(
            "replay  {}  through FlightCore::step ({:.1} s, {} steps, {} output frames)\n",
            self.origin, self.duration_s, self.steps, self.frames_out
        );
        s.push_str(&format!(
            "log: {} FOG samples (FOGs {}), {} star-tracker solutions, truth {}\n",
            rec.fog_samples,
            fog_names(rec.fogs),
            rec.st_count,
            if rec.has_truth { "yes" } else { "no" }
        ));
        s.push_str("damage in the log (counted, skipped):\n");
        s.push_str(&rec.problems.report());
        if self.accuracy.att.count() > 0 {
            s.push_str(&self.accuracy.table());
            if let Some(l) = limit {
                let att = self.accuracy.att.three_sigma();
                // A limit's row, 3σ, and with `ratio` the attitude error's ratio to it.
                let mut row = |label: String, one_sigma: [f64; 3], ratio: bool| {
                    let v = one_sigma.map(|x| 3.0 * x);
                    s.push_str(&format!("{label:<38}{:>9.2} {:>9.2} {:>9.2}\n", v[0], v[1], v[2]));
                    if ratio {
                        let r = [0, 1, 2].map(|k| att[k] / v[k]);
                        s.push_str(&format!("{:<37}{:>9.3} {:>9.3} {:>9.3}\n", "  ratio to it", r[0], r[1], r[2]));
                    }
                };
                row("  Farrenkopf limit 3σ after update, ″".into(), l.posterior_arcsec, true);
                row("  limit 3σ averaged over a period, ″".into(), l.period_mean_arcsec, false);
                row(format!("  the same, tracker latency {:.3} s, ″", l.latency_s), l.latency_mean_arcsec, true);
                if let Some((post, late)) = l.lfe {
                    row("  with the tracker's LFE estimated: after update, ″".into(), post, false);
                    row(format!("  the same, period mean, latency {:.3} s, ″", l.latency_s), late, true);
                }
            }
        } else {
            s.push_str("no truth in the log: no error against truth\n");
        }
        s.push_str(&self.evidence.report());
        s
    }
}

/// "FOG1 FOG2 …" for a set (the ICD's names: slot i is FOG i+1).
pub fn fog_names(set: FogSet) -> String {
    (0..N_FOG).filter(|&i| set.contains(i)).map(|i| format!("FOG{}", i + 1)).collect::<Vec<_>>().join(" ")
}

/// A replay's CSV (`--csv`, one row per `every` records against truth) and its plot's
/// points (the same records).
pub struct Rows<P> {
    out: Option<(csv::Writer<output::AtomicFile>, PathBuf)>,
    every: u64,
    n: u64,
    err: Option<csv::Error>,
    points: Vec<P>,
}

impl<P> Rows<P> {
    /// Rows into `path` (none without) under `header`, every `every`-th record.
    pub fn new(path: Option<&Path>, header: &[&str], every: u64) -> Result<Rows<P>> {
        let out = match path {
            Some(p) => {
                let mut w = csv::Writer::from_writer(output::create(p)?);
                w.write_record(header)?;
                Some((w, p.to_path_buf()))
            }
            None => None,
        };
        Ok(Rows { out, every: every.max(1), n: 0, err: None, points: Vec::new() })
    }

    /// One record against truth: its CSV row and plot point, every `every`-th.
    pub fn take<R: IntoIterator<Item = T>, T: AsRef<[u8]>>(&mut self, row: impl FnOnce() -> R, point: P) {
        self.n += 1;
        if !self.n.is_multiple_of(self.every) {
            return;
        }
        if let Some((w, _)) = self.out.as_mut() {
            if let Err(e) = w.write_record(row()) {
                self.err.get_or_insert(e);
            }
        }
        self.points.push(point);
    }

    /// Commits the CSV; the plot's points.
    pub fn finish(self) -> Result<Vec<P>> {
        if let Some(e) = self.err {
            return Err(e.into());
        }
        if let Some((w, p)) = self.out {
            w.into_inner().map_err(|e| anyhow::anyhow!("{}: cannot write: {}", p.display(), e.error()))?.commit()?;
            println!("wrote {}", p.display());
        }
        Ok(self.points)
    }
}
