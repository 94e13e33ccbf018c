//! The harness: simulator → frames → links → `FlightCore::step()` → output frames,
//! compared with truth. [`Simulation`] makes each step's bytes and truth; the
//! [`Evaluator`] (`crate::accuracy`) compares the unit's output with the truth of the
//! sample it integrated (by its time tag); [`run`] drives the core in-process through mock
//! links. The QEMU runner (`ssis_runner::qemu`) uses the same two pieces with the firmware
//! in place of the core.

use anyhow::Result;
use nalgebra::{Quaternion, Vector4};
use ssis::calib::{CalibrationTable, N_FOG};
use ssis::combination::FogSet;
use ssis::compensation::compensate_increment;
use ssis::flight::{Counters, FlightCore, FogLinks, Links, Profile, StepOutput};
use ssis::frames::output::OutputFrame;
use ssis::telemetry::events::EventRecord;

pub use crate::accuracy::{Accuracy, Evaluator, Observed, Record, TruthSample, CSV_HEADER};
use crate::scenario::Scenario;
use crate::sensors::{SensorStep, Sensors};
use crate::star::StarModel;
use crate::truth::Truth;
use ssis_common::downlink::{records, Down, Downlink};
use ssis_common::mock::{LinkStats, MockLink, MockSink};
use ssis_common::DEG_H_PER_RAD_S;

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
    sensors: Sensors,
    n: u64,
}

impl Simulation {
    /// Sets up the world of `sc`.
    pub fn new(sc: &Scenario) -> Result<Self> {
        let profile = sc.profile.profile();
        let truth = Truth::new(sc.motion.clone());
        let mut table = CalibrationTable::DEFAULT;
        let sensors = Sensors::new(&sc.fog, sc.seed, |fogs| {
            table = sc.unit_table(&fogs.truth)?;
            anyhow::Ok(StarModel::new(&sc.star_tracker, profile.dt_us, table.st_mount()))
        })?;
        let steps = (sc.duration_s / profile.dt_s()).round() as u64;
        Ok(Simulation { sc: sc.clone(), profile, table, steps, truth, sensors, n: 0 })
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
        self.sensors.fogs.mount(m);
    }

    /// Turn-on FOG biases drawn, rad/s.
    pub fn fog_random_bias_rad_s(&self) -> [f64; N_FOG] {
        self.sensors.fogs.random_bias_rad_s()
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
        let SensorStep { fog: sample, st_bytes } = self.sensors.step(n, now_us, dt_s, &ts);
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

impl Evaluator {
    /// For the unit of `sim`.
    pub fn new(sim: &Simulation) -> Self {
        Evaluator::for_unit(&sim.table, &sim.profile, sim.sc.settle_s)
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
