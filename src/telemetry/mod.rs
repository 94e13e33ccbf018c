//! Telemetry: what the unit reports each step — the status bits, the counters, and the
//! output frame that carries them (`docs/ICD.md`) — and the log of its state changes
//! ([`events`]).

pub mod counters;
pub mod event_list;
pub mod events;

use nalgebra::{Quaternion, Vector3};

use crate::calib::N_FOG;
use crate::combination::FogSet;
use crate::frames::output::OutputFrame;
use crate::frames::Frame;
use crate::link::OutPort;
use crate::state::Flag;

/// Output-frame flag bits (defined with the frame, `docs/ICD.md`).
pub use crate::frames::output::flags;
pub use counters::{page, write_page_table, Counter, Counters, FogCounter, FogCounters, PAGED};

/// Per-FOG health bits (output frame).
pub mod health {
    /// The FOG's sample was used in this step's combination.
    pub const USED: u8 = 1 << 0;
    /// No sample arrived for this step.
    pub const MISSING: u8 = 1 << 1;
    /// A frame from this FOG was rejected (CRC, format, id) since the last step.
    pub const REJECTED: u8 = 1 << 2;
    /// The FOG's own status reports a fault (light source, loop lock, temperature sensor).
    pub const DEVICE_FAULT: u8 = 1 << 3;
    /// The sample counter skipped, or a stale sample was discarded (samples lost or late).
    pub const COUNTER_GAP: u8 = 1 << 4;
    /// Rate outside the measuring range.
    pub const OUT_OF_RANGE: u8 = 1 << 5;
    /// Excluded by configuration or by the fault logic (isolated, or a parity spike).
    pub const EXCLUDED: u8 = 1 << 6;
    /// The raw output is stuck (the same increment 40 samples in a row): not used.
    pub const STUCK: u8 = 1 << 7;
}

/// Star-tracker status bits (output frame).
pub mod st_status {
    /// A frame arrived in this step.
    pub const FRAME: u8 = 1 << 0;
    /// An observer update was applied in this step.
    pub const UPDATED: u8 = 1 << 1;
    /// The attitude has been aligned by the star tracker.
    pub const ALIGNED: u8 = 1 << 2;
    /// A frame was refused in this step (invalid, stale, too far ahead, gated, bad).
    pub const REFUSED: u8 = 1 << 3;
    /// No accepted frame for more than 2 s: attitude propagates on gyros alone.
    pub const OUTAGE: u8 = 1 << 4;
    /// A frame was used by the fault logic only (listening while a FOG is isolated).
    pub const LISTENED: u8 = 1 << 5;
    /// The observer re-acquired: a streak of gated frames agreed with each other.
    pub const REACQUIRED: u8 = 1 << 6;
    /// The attitude is good to use: the one validity the unit states, derived in one
    /// place (`FlightCore::attitude_valid`; `docs/ICD.md`, "Attitude valid").
    pub const VALID: u8 = 1 << 7;
}

/// Everything one step produced, in physical units (the output frame is its encoding).
#[derive(Debug, Clone, Copy, PartialEq, bytemuck::AnyBitPattern)]
pub struct StepOutput {
    /// Unit time at the end of the integrated interval, µs.
    pub time_us: u64,
    /// Λ: ICS in 2ECS.
    pub q: Quaternion<f64>,
    /// Angular rate of the ICS, drift removed, rad/s.
    pub rate_rad_s: Vector3<f64>,
    /// Drift estimate Δω, rad/s.
    pub drift_rad_s: Vector3<f64>,
    /// Parity residual of the four compensated increments, rad (0 without four FOGs).
    pub parity_rad: f64,
    /// Per-FOG health bits ([`health`]).
    pub fog_health: [u8; N_FOG],
    /// Star-tracker status bits ([`st_status`]).
    pub st_status: u8,
    /// Flag bits ([`flags`]).
    pub flags: u8,
    /// FOGs combined this step.
    pub fogs_used: FogSet,
    /// Fault-logic bits: FOG i on a held temperature (bit i), FOG i isolated (bit 4 + i).
    pub fdi: u8,
    /// The estimator's 1σ of the attitude error per ICS axis, rad (infinite: unknown,
    /// before alignment).
    pub att_sigma_rad: [f64; 3],
    /// The estimator's 1σ of the drift-estimate error per ICS axis, rad/s (infinite:
    /// unknown).
    pub drift_sigma_rad_s: [f64; 3],
}

impl StepOutput {
    /// The output before the first step.
    pub const START: StepOutput = StepOutput {
        time_us: 0,
        q: Quaternion::new(1.0, 0.0, 0.0, 0.0),
        rate_rad_s: Vector3::new(0.0, 0.0, 0.0),
        drift_rad_s: Vector3::new(0.0, 0.0, 0.0),
        parity_rad: 0.0,
        fog_health: [0; N_FOG],
        st_status: 0,
        flags: 0,
        fogs_used: FogSet(0),
        fdi: 0,
        att_sigma_rad: [f64::INFINITY; 3],
        drift_sigma_rad_s: [f64::INFINITY; 3],
    };
}

/// A byte buffer on a word boundary: the ring copies in and out of it then run word by
/// word (a byte array can land at any offset in the core, and a misaligned copy of the
/// output frame cost ~180 instructions a step more on the M7).
#[repr(C, align(4))]
#[derive(Clone, Copy, bytemuck::AnyBitPattern)]
pub(crate) struct WordAligned<const N: usize>(pub(crate) [u8; N]);

/// The telemetry stage: counters and the output link's state.
#[derive(Clone, Copy, bytemuck::AnyBitPattern)]
pub struct Telemetry {
    /// The counters (all but the observer's re-acquisitions, which it keeps itself).
    pub(crate) counters: Counters,
    out_counter: u16,
    step_ticks: u16,
    output_dropped_last: Flag,
    /// The output frame's bytes (kept, so a step does not clear them).
    out_buf: WordAligned<{ OutputFrame::LEN }>,
    /// Which fitted FOGs are lost (the lasting changes of the FOG set the unit reports).
    pub(crate) fog_set: FogSetWatch,
}

/// Samples in a row that make a change of a FOG's availability lasting: a FOG with no
/// usable sample for this many is lost, a lost one with usable samples for this many is
/// restored (40 × 5 ms = 200 ms, the stuck check's span).
pub const FOG_SET_SAMPLES: u16 = 40;

/// A change of the FOG set ([`FogSetWatch::on_sample`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FogSetChange {
    /// FOG i has had no usable sample for [`FOG_SET_SAMPLES`] in a row.
    Lost(usize),
    /// Lost FOG i has had usable samples for [`FOG_SET_SAMPLES`] in a row.
    Restored(usize),
}

/// The lasting availability of each FOG: one comparison a sample while nothing is
/// changing.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, bytemuck::AnyBitPattern)]
pub struct FogSetWatch {
    /// The last sample's usable FOGs (bits 0..8) and whether a run is counting (bit 8):
    /// a sample with the same FOGs and no run counting changes nothing.
    key: u16,
    /// FOGs lost (bit i).
    lost: u8,
    /// Per FOG, samples in a row towards a change (unusable while not lost, usable while
    /// lost).
    runs: [u16; N_FOG],
}

impl FogSetWatch {
    /// Whether a sample with usable FOGs `used` needs [`FogSetWatch::on_sample`] (the
    /// step's inline test).
    #[inline(always)]
    pub fn changing(&self, used: FogSet) -> bool {
        u16::from(used.0) != self.key
    }

    /// FOGs lost (bit i).
    pub fn lost(&self) -> u8 {
        self.lost
    }

    /// One sample: `used` the FOGs whose sample is usable, `watched` the FOGs the set is
    /// about (fitted, not isolated: an isolation is its own change). Calls `changed` for
    /// each FOG lost or restored by this sample.
    pub fn on_sample(&mut self, used: FogSet, watched: FogSet, mut changed: impl FnMut(FogSetChange)) {
        let mut counting = false;
        for (i, run) in self.runs.iter_mut().enumerate() {
            let bit = 1u8 << i;
            let lost = self.lost & bit != 0;
            if !watched.contains(i) {
                *run = 0;
                self.lost &= !bit;
                continue;
            }
            // Towards a change: unusable while available, usable while lost.
            if used.contains(i) == lost {
                *run = run.saturating_add(1);
                if *run >= FOG_SET_SAMPLES {
                    *run = 0;
                    self.lost ^= bit;
                    changed(if lost { FogSetChange::Restored(i) } else { FogSetChange::Lost(i) });
                }
            } else {
                *run = 0;
            }
            counting |= *run != 0;
        }
        self.key = u16::from(used.0) | if counting { 1 << 8 } else { 0 };
    }
}

impl Default for Telemetry {
    fn default() -> Self {
        Self::new()
    }
}

impl Telemetry {
    /// Nothing counted, nothing sent.
    pub fn new() -> Self {
        Telemetry {
            counters: Counters::default(),
            out_counter: 0,
            step_ticks: 0,
            output_dropped_last: Flag::CLEAR,
            out_buf: WordAligned([0; OutputFrame::LEN]),
            fog_set: FogSetWatch { key: u16::from(FogSet::ALL.0), lost: 0, runs: [0; N_FOG] },
        }
    }

    /// Board: how long the previous step took, in board ticks (goes into the frame).
    #[inline]
    pub fn set_step_ticks(&mut self, ticks: u16) {
        self.step_ticks = ticks;
    }

    /// Whether the previous step's output frame was dropped.
    #[inline]
    pub fn output_dropped_last(&self) -> bool {
        self.output_dropped_last.get()
    }

    /// Encodes `o` with counter page `page_id` carrying `page_value` and writes it; a
    /// link that cannot take it is counted.
    pub fn emit<O: OutPort>(&mut self, out: &mut O, o: &StepOutput, page_id: u8, page_value: u32) {
        let c = &self.counters;
        let sat = |v: u32| u16::try_from(v).unwrap_or(u16::MAX);
        let mut frame = OutputFrame::from_physical(
            o.flags,
            self.out_counter,
            o.time_us,
            [o.q.w, o.q.i, o.q.j, o.q.k],
            [o.rate_rad_s.x, o.rate_rad_s.y, o.rate_rad_s.z],
            [o.drift_rad_s.x, o.drift_rad_s.y, o.drift_rad_s.z],
            o.parity_rad,
            o.fog_health,
            o.st_status,
            [
                sat(c.fog_frames_rejected),
                sat(c.fog_samples_missing),
                sat(c.st_frames_accepted),
                sat(c.st_frames_rejected),
                sat(c.st_updates_gated),
                sat(c.overruns),
                self.step_ticks,
            ],
        );
        frame.fdi = o.fdi;
        frame.set_sigmas(o.att_sigma_rad, o.drift_sigma_rad_s);
        frame.page_id = page_id;
        frame.page_value = sat(page_value);
        self.out_counter = self.out_counter.wrapping_add(1);
        let ok = out.send_frame(&mut self.out_buf.0, OutputFrame::LEN, |buf| frame.encode_into(buf).is_ok());
        self.output_dropped_last = Flag::new(!ok);
        if !ok {
            self.counters.bump(Counter::OutputDropped);
        }
    }
}
