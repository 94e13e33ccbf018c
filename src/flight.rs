//! The fixed-rate flight step: read what arrived on every link, compensate, combine,
//! integrate, observe, emit one output frame.
//!
//! [`FlightCore::step`] is what the timer tick calls (firmware) and what the host harness
//! calls in replay; it is the same code. It never waits on a link, never allocates, never
//! panics; every byte, frame or sample it could not use is counted and flagged in the
//! output frame (see `docs/ICD.md` for the health and status bits).
//!
//! Two profiles ([`Profile`]): the spacecraft unit (four FOGs + star tracker, 5 ms,
//! ±10 °/s) and the launch-vehicle unit (three FOGs, 1.25 ms, ±100 °/s).
//!
//! Timing convention: unit time is the FOG sample clock. The sample with counter k covers
//! ((k−1)Δt, kΔt] of unit time (counters unwrapped from u16); the step that integrates it
//! emits the time tag kΔt and Λ(kΔt). Star-tracker time tags are in the same time.

use heapless::Deque;
use nalgebra::{Quaternion, Vector3, Vector4};

use crate::attitude::{Attitude, Coning};
use crate::calib::{CalibrationTable, FogCal, N_FOG};
use crate::combination::{Combiner, FogSet};
use crate::compensation::compensate_increment;
use crate::frames::decoder::StreamDecoder;
use crate::frames::fog::{status, FogFrame};
use crate::frames::output::{page, OutputFrame};
use crate::frames::star::StarFrame;
use crate::frames::Frame;
use crate::integrity::channel::{ChannelMonitor, FogCounters};
use crate::integrity::parity::{FdiState, ParityMonitor, SampleVerdict};
use crate::link::{drain, write_frame, RxLink, TxLink};
use crate::observer::{GainError, Observer, UpdateError};

/// Steps of attitude history for star-tracker latency (64 × 5 ms = 320 ms).
pub const HISTORY: usize = 64;
/// Receive bytes read per link per step at most (four FOG frames' worth).
pub const MAX_RX_BYTES_PER_STEP: usize = 128;
/// Star-tracker silence after which the output flags an outage, µs.
pub const ST_OUTAGE_US: u64 = 2_000_000;

/// Operating profile of the unit.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Profile {
    /// Step period, µs.
    pub dt_us: u32,
    /// FOGs fitted.
    pub fogs: FogSet,
    /// Measuring range, rad/s; a FOG reporting more is out of range for that step.
    pub rate_limit_rad_s: f64,
    /// Whether a star tracker is fitted.
    pub star_tracker: bool,
}

impl Profile {
    /// Spacecraft unit (SSIS): four FOGs, star tracker, 5 ms, ±10 °/s.
    pub const SPACECRAFT: Profile = Profile {
        dt_us: 5_000,
        fogs: FogSet::ALL,
        rate_limit_rad_s: 10.0 * core::f64::consts::PI / 180.0,
        star_tracker: true,
    };
    /// Launch-vehicle unit (SIS): three FOGs, 1.25 ms, ±100 °/s.
    pub const LAUNCH_VEHICLE: Profile = Profile {
        dt_us: 1_250,
        fogs: FogSet::TRIAD,
        rate_limit_rad_s: 100.0 * core::f64::consts::PI / 180.0,
        star_tracker: false,
    };

    /// Step period, s.
    pub fn dt_s(&self) -> f64 {
        f64::from(self.dt_us) * 1e-6
    }
}

/// How the FOGs are wired.
pub enum FogLinks<F> {
    /// One link per FOG slot (FOG1..FOG4); frames must carry the slot's `fog_id`.
    PerFog([F; N_FOG]),
    /// One multi-drop (RS-485-style) bus carrying every FOG's frames, told apart by
    /// their `fog_id`.
    Bus(F),
}

/// The links of one unit: the FOGs, the star tracker, the output.
/// FOG slots the profile does not fit are never read.
pub struct Links<F, S, O> {
    /// FOG1..FOG4.
    pub fog: FogLinks<F>,
    /// Star tracker.
    pub star: S,
    /// Framed output.
    pub out: O,
}

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
}

/// Output-frame flag bits (defined with the frame, `docs/ICD.md`).
pub use crate::frames::output::flags;

/// Counters carried in the output frame (saturating).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Counters {
    /// FOG frames rejected by the decoders (all FOGs).
    pub fog_frames_rejected: u32,
    /// FOG samples that did not arrive in time (all FOGs).
    pub fog_samples_missing: u32,
    /// Star-tracker frames that updated the observer.
    pub st_frames_accepted: u32,
    /// Star-tracker frames rejected (decoder, invalid flag, stale, too far ahead).
    pub st_frames_rejected: u32,
    /// Star-tracker frames refused by the observer's gate.
    pub st_updates_gated: u32,
    /// Steps that overran their deadline (reported by the board).
    pub overruns: u32,
    /// Output frames that could not be written.
    pub output_dropped: u32,
    /// Link driver errors.
    pub io_errors: u32,
    /// FOG frames that arrived too late for their sample and were discarded.
    pub fog_samples_stale: u32,
    /// Per FOG ([`FogCounters`]).
    pub fog: [FogCounters; N_FOG],
    /// Star-tracker frames refused as frozen (the same quaternion as the previous one).
    pub st_frozen: u32,
    /// Star-tracker outages begun (after alignment).
    pub st_outages: u32,
}

/// Everything one step produced, in physical units (the output frame is its encoding).
#[derive(Debug, Clone, Copy, PartialEq)]
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
}

/// Why the core could not be built.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub enum CoreError {
    /// The observer gains could not be computed from the table's figures.
    Gains(GainError),
    /// The fitted FOGs do not span 3-D space with this table's geometry.
    Geometry,
}

impl From<GainError> for CoreError {
    fn from(e: GainError) -> Self {
        CoreError::Gains(e)
    }
}

struct FogChannel {
    decoder: StreamDecoder<FogFrame, 32>,
    queue: Deque<FogFrame, FOG_QUEUE>,
    monitor: ChannelMonitor,
    /// Decoder rejections already counted.
    rejected_seen: u32,
    /// Frames rejected (by the decoder, or for a wrong FOG id) since the last sample taken.
    rejected_new: u32,
    /// This FOG's counters.
    counters: FogCounters,
}

/// Bytes read from a link per chunk.
const RX_CHUNK: usize = 64;
/// FOG samples a channel holds ahead of the step (absorbs jitter and late links).
pub const FOG_QUEUE: usize = 8;
/// Steps a sample is waited for when a FOG that delivered the previous one owes it.
pub const MAX_WAIT_STEPS: u32 = 2;
/// Star-tracker frames held until the attitude reaches their time tag.
pub const ST_PENDING: usize = 4;
/// A star-tracker time tag further ahead of the unit's time than this is refused, µs.
pub const ST_MAX_LEAD_US: u64 = 1_000_000;

/// Where the unit is in the FOG sample sequence.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct SampleClock {
    /// Counter of the next sample to integrate (None before the first frame).
    expected: Option<u16>,
    /// Index of the last integrated sample since start (its end time is index × Δt).
    index: u64,
}

impl SampleClock {
    /// End time of the last integrated sample, µs: index × Δt. The product cannot
    /// overflow in any flight (2^64 µs is 585,000 years), so it wraps instead of
    /// saturating (a 64-bit saturating multiply costs a dozen instructions on the M7).
    #[inline]
    fn time_us(&self, dt_us: u32) -> u64 {
        self.index.wrapping_mul(u64::from(dt_us))
    }
}

/// A byte buffer on a word boundary: the ring copies in and out of it then run word by
/// word (a byte array can land at any offset in [`FlightCore`], and a misaligned copy of
/// the 83-byte output frame cost ~180 instructions a step more on the M7).
#[repr(C, align(4))]
struct WordAligned<const N: usize>([u8; N]);

/// The flight core: all state of one unit.
pub struct FlightCore {
    profile: Profile,
    table: CalibrationTable,
    /// Flags that hold for the whole flight: star tracker in use, table defaulted, BIT failed.
    fixed_flags: u8,
    combiner: Combiner,
    mount: Quaternion<f64>,
    attitude: Attitude,
    observer: Observer<HISTORY>,
    /// Parity fault logic (`None` without four FOGs).
    fdi: Option<ParityMonitor>,
    fog: [FogChannel; N_FOG],
    bus_decoder: StreamDecoder<FogFrame, 32>,
    bus_rejected_seen: u32,
    clock: SampleClock,
    last_present: FogSet,
    waited: u32,
    gap: bool,
    st_decoder: StreamDecoder<StarFrame, 64>,
    /// Chunk buffer for draining the links (kept, so a step does not clear one).
    rx_scratch: WordAligned<RX_CHUNK>,
    /// The output frame's bytes (kept, so a step does not clear them).
    out_buf: WordAligned<{ OutputFrame::LEN }>,
    st_pending: Deque<StarFrame, ST_PENDING>,
    st_rejected_seen: u32,
    last_st_update_us: Option<u64>,
    last_st_q_counts: [i32; 4],
    in_outage: bool,
    /// FOGs whose temperature sensor has failed (bit i).
    temp_failed_bits: u8,
    last_body_dtheta: Vector3<f64>,
    counters: Counters,
    out_counter: u16,
    step_ticks: u16,
    output_dropped_last: bool,
    last_output: StepOutput,
}

impl FlightCore {
    /// Builds the core for `profile` from `table` (`table_defaulted` = the stored table
    /// was invalid and `table` is the default; flagged in every output frame).
    pub fn new(profile: Profile, table: &CalibrationTable, table_defaulted: bool) -> Result<Self, CoreError> {
        let combiner = Combiner::new(&table.axes());
        if combiner.solution(profile.fogs).is_err() {
            return Err(CoreError::Geometry);
        }
        let observer = Observer::from_config(&table.observer)?;
        let dt = profile.dt_s();
        // σ₁: the ARW's angle noise in one sample (the table's noise figure).
        let noise_rad = table.observer.arw_deg_sqrt_h * core::f64::consts::PI / 180.0 / 60.0 * crate::math::sqrt(dt);
        let fdi = match (profile.fogs == FogSet::ALL, combiner.solution(FogSet::ALL), combiner.triads()) {
            (true, Ok(all), Some(triads)) => ParityMonitor::new(combiner.parity_vector(), all, triads, noise_rad, dt),
            _ => None,
        };
        let channel = |_: usize| FogChannel {
            decoder: StreamDecoder::new(),
            queue: Deque::new(),
            monitor: ChannelMonitor::new(dt, table.t_rate_filter_s, noise_rad),
            rejected_seen: 0,
            rejected_new: 0,
            counters: FogCounters::default(),
        };
        Ok(FlightCore {
            profile,
            table: *table,
            fixed_flags: if profile.star_tracker { flags::ST_IN_USE } else { 0 }
                | if table_defaulted { flags::TABLE_DEFAULTED } else { 0 },
            combiner,
            mount: table.st_mount(),
            attitude: Attitude::new(Quaternion::identity(), Coning::ThreeSample),
            observer,
            fdi,
            fog: [channel(0), channel(1), channel(2), channel(3)],
            bus_decoder: StreamDecoder::new(),
            bus_rejected_seen: 0,
            clock: SampleClock { expected: None, index: 0 },
            last_present: profile.fogs,
            waited: 0,
            gap: false,
            st_decoder: StreamDecoder::new(),
            rx_scratch: WordAligned([0; RX_CHUNK]),
            out_buf: WordAligned([0; OutputFrame::LEN]),
            st_pending: Deque::new(),
            st_rejected_seen: 0,
            last_st_update_us: None,
            last_st_q_counts: [0; 4],
            in_outage: false,
            temp_failed_bits: 0,
            last_body_dtheta: Vector3::zeros(),
            counters: Counters::default(),
            out_counter: 0,
            step_ticks: 0,
            output_dropped_last: false,
            last_output: StepOutput {
                time_us: 0,
                q: Quaternion::identity(),
                rate_rad_s: Vector3::zeros(),
                drift_rad_s: Vector3::zeros(),
                parity_rad: 0.0,
                fog_health: [0; N_FOG],
                st_status: 0,
                flags: 0,
                fogs_used: FogSet(0),
                fdi: 0,
            },
        })
    }

    /// Sets the attitude (pad alignment without a star tracker) and marks it aligned.
    pub fn align(&mut self, q: Quaternion<f64>) {
        self.attitude.set_quaternion(q);
        self.observer.set_aligned();
    }

    /// The profile in use.
    pub fn profile(&self) -> &Profile {
        &self.profile
    }

    /// The calibration table in use.
    pub fn table(&self) -> &CalibrationTable {
        &self.table
    }

    /// Records a failed power-on built-in test: flagged in every output frame from now on.
    pub fn note_bit_failure(&mut self) {
        self.fixed_flags |= flags::BIT_FAILED;
    }

    /// Counters so far.
    pub fn counters(&self) -> Counters {
        let mut c = self.counters;
        for (slot, ch) in c.fog.iter_mut().zip(&self.fog) {
            *slot = ch.counters;
        }
        c
    }

    /// The observer (gains, statistics).
    pub fn observer(&self) -> &Observer<HISTORY> {
        &self.observer
    }

    /// The combiner (geometry, parity vector).
    pub fn combiner(&self) -> &Combiner {
        &self.combiner
    }

    /// Turns the parity fault logic off, for ground replays of sessions on a table that
    /// is not calibrated yet (the gyros disagree by more than a calibrated unit's
    /// parity allows). Never in flight: the per-channel checks stay on.
    pub fn disable_parity_fdi(&mut self) {
        self.fdi = None;
    }

    /// The parity fault logic (`None` without four FOGs).
    pub fn fdi(&self) -> Option<&ParityMonitor> {
        self.fdi.as_ref()
    }

    /// Output of the last step.
    pub fn last_output(&self) -> &StepOutput {
        &self.last_output
    }

    /// Board: the previous step overran its deadline.
    pub fn note_overrun(&mut self) {
        self.counters.overruns = self.counters.overruns.saturating_add(1);
    }

    /// Board: how long the previous step took, in board ticks (goes into the frame).
    pub fn set_step_ticks(&mut self, ticks: u16) {
        self.step_ticks = ticks;
    }

    /// One fixed step. Reads every link, integrates the FOG samples that are due,
    /// observes, writes one output frame.
    ///
    /// Unit time is the FOG sample clock: the FOGs are sampled on the unit's sync pulse
    /// and number their samples, so a sample's end is at index × Δt however its frames
    /// were delayed on the links. Each step integrates, in order, every sample that is
    /// complete (usually one; more after a delay, catching up) and emits the time tag of
    /// the last. A sample still owed by a FOG that delivered the previous one is waited
    /// for up to [`MAX_WAIT_STEPS`] steps; then it is integrated with the FOGs that have
    /// it, the others flagged missing. With no FOG data at all for longer, the interval
    /// is bridged with the last body increment so time and attitude keep moving.
    pub fn step<F: RxLink, S: RxLink, O: TxLink>(&mut self, links: &mut Links<F, S, O>) -> StepOutput {
        self.step_with(links, |_, _| {})
    }

    /// [`FlightCore::step`], handing each body angle increment the attitude integrates
    /// (combined and compensated, rad) to `on_increment` with the unit time at its end
    /// (µs): once per sample, none when no sample came, more than one when the step
    /// catches up. The launch-vehicle navigation runs on them ([`crate::nav::unit`]); a
    /// caller with no use for them calls `step`, where the empty hook compiles away.
    pub fn step_with<F: RxLink, S: RxLink, O: TxLink>(
        &mut self,
        links: &mut Links<F, S, O>,
        mut on_increment: impl FnMut(u64, &Vector3<f64>),
    ) -> StepOutput {
        let dt_s = self.profile.dt_s();
        self.receive_fogs(&mut links.fog);
        let mut fog_health = [0u8; N_FOG];
        let mut used = FogSet(0);
        let mut parity_rad = 0.0;
        let mut corrected = Vector3::zeros();
        let mut integrated = 0u32;
        let mut degraded = false;
        // Bounded: at most one pass per queued sample.
        for _ in 0..FOG_QUEUE {
            let Some(target) = self.next_sample() else { break };
            let (m, mut u, mut h) = self.take_sample(target, dt_s);
            let t_us = self.clock.time_us(self.profile.dt_us);
            parity_rad = 0.0;
            if let Some(fdi) = self.fdi.as_mut() {
                let drop = match fdi.isolated() {
                    Some(i) => Some(i),
                    None if u == FogSet::ALL => {
                        parity_rad = self.combiner.parity(&m);
                        match fdi.on_sample(&m, parity_rad, self.last_body_dtheta.norm_squared(), t_us) {
                            SampleVerdict::Use => None,
                            SampleVerdict::Drop(i) | SampleVerdict::Isolate(i) => {
                                if let Some(ch) = self.fog.get_mut(i) {
                                    ch.counters.spikes = ch.counters.spikes.saturating_add(1);
                                }
                                Some(i)
                            }
                        }
                    }
                    None => {
                        fdi.on_partial_sample();
                        // A fitted gyro refused by its own checks during an alarm is the
                        // faulty one.
                        let refused = self.profile.fogs.0 & !u.0;
                        if fdi.alarm() && refused.count_ones() == 1 {
                            let i = refused.trailing_zeros() as usize;
                            fdi.isolate_failed_channel(i);
                            Some(i)
                        } else {
                            None
                        }
                    }
                };
                if let Some(i) = drop {
                    u = u.without(i);
                    if let Some(hi) = h.get_mut(i) {
                        *hi = (*hi & !health::USED) | health::EXCLUDED;
                    }
                }
                degraded |= fdi.alarm();
            }
            for (acc, bits) in fog_health.iter_mut().zip(h) {
                *acc |= bits;
            }
            used = u;
            degraded |= u != self.profile.fogs;
            let body = match self.combiner.combine(&m, u) {
                Ok(v) => v,
                Err(_) => {
                    // No usable gyro set in this sample: hold the last body increment.
                    degraded = true;
                    self.last_body_dtheta
                }
            };
            self.last_body_dtheta = body;
            corrected = body - self.observer.drift_rad_s() * dt_s;
            let _ = self.attitude.step(&corrected);
            self.observer.record(t_us, self.attitude.quaternion());
            on_increment(t_us, &body);
            integrated += 1;
            self.waited = 0;
            if self.last_present.0 == 0 {
                // A bridged sample (no FOG data): one per step.
                break;
            }
        }
        if integrated == 0 {
            // Nothing integrated: the output rate is the last body increment, corrected.
            corrected = self.last_body_dtheta - self.observer.drift_rad_s() * dt_s;
            self.waited = self.waited.saturating_add(1);
            degraded = true;
            for (i, h) in fog_health.iter_mut().enumerate() {
                *h = if self.profile.fogs.contains(i) { health::MISSING } else { health::EXCLUDED };
            }
        }
        let now_us = self.clock.time_us(self.profile.dt_us);

        let st = if self.profile.star_tracker { self.read_star(&mut links.star, now_us) } else { 0 };

        let mut fl = self.fixed_flags;
        let mut fdi_bits = 0u8;
        if let Some(fdi) = &self.fdi {
            match fdi.state() {
                FdiState::Alarm => fl |= flags::FDI_ALARM,
                FdiState::Isolated(i) => fdi_bits |= 0x10 << i,
                FdiState::Watching => {}
            }
        }
        fdi_bits |= self.temp_failed_bits;
        if degraded || st & st_status::OUTAGE != 0 && self.observer.aligned() {
            fl |= flags::DEGRADED;
        }
        if self.observer.converged() {
            fl |= flags::CONVERGED;
        }
        if self.output_dropped_last {
            fl |= flags::OUTPUT_DROPPED;
        }
        let out = StepOutput {
            time_us: now_us,
            q: self.attitude.quaternion(),
            rate_rad_s: corrected / dt_s,
            drift_rad_s: self.observer.drift_rad_s(),
            parity_rad,
            fog_health,
            st_status: st,
            flags: fl,
            fogs_used: used,
            fdi: fdi_bits,
        };
        self.last_output = out;
        self.emit(&mut links.out, &out);
        out
    }

    /// Drains the FOG links (or the bus) into the per-FOG sample queues.
    fn receive_fogs<F: RxLink>(&mut self, fog_links: &mut FogLinks<F>) {
        let fitted = self.profile.fogs;
        match fog_links {
            FogLinks::PerFog(links) => {
                let rx_scratch = &mut self.rx_scratch.0;
                for (i, (ch, link)) in self.fog.iter_mut().zip(links.iter_mut()).enumerate() {
                    if !fitted.contains(i) {
                        continue;
                    }
                    let FogChannel { decoder, queue, rejected_seen, rejected_new, .. } = ch;
                    let rep = drain(link, MAX_RX_BYTES_PER_STEP, rx_scratch, |bytes| {
                        decoder.push_slice(bytes, |r| {
                            if let Ok(f) = r {
                                if usize::from(f.fog_id) == i {
                                    enqueue(queue, f);
                                } else {
                                    *rejected_new = rejected_new.saturating_add(1);
                                }
                            }
                        });
                    });
                    let total = decoder.stats().rejected();
                    *rejected_new = rejected_new.saturating_add(total.saturating_sub(*rejected_seen));
                    *rejected_seen = total;
                    self.counters.io_errors = self.counters.io_errors.saturating_add(rep.io_errors);
                }
            }
            FogLinks::Bus(link) => {
                let decoder = &mut self.bus_decoder;
                let channels = &mut self.fog;
                let rep = drain(link, N_FOG * MAX_RX_BYTES_PER_STEP, &mut self.rx_scratch.0, |bytes| {
                    decoder.push_slice(bytes, |r| {
                        if let Ok(f) = r {
                            let i = usize::from(f.fog_id);
                            if let Some(ch) = channels.get_mut(i).filter(|_| fitted.contains(i)) {
                                enqueue(&mut ch.queue, f);
                            }
                        }
                    });
                });
                self.counters.io_errors = self.counters.io_errors.saturating_add(rep.io_errors);
                let rejected = self.bus_decoder.stats().rejected();
                let new_rej = rejected.saturating_sub(self.bus_rejected_seen);
                self.bus_rejected_seen = rejected;
                self.counters.fog_frames_rejected = self.counters.fog_frames_rejected.saturating_add(new_rej);
            }
        }
    }

    /// Counter of the next sample to integrate now, or `None` to wait for it.
    fn next_sample(&mut self) -> Option<u16> {
        let fitted = self.profile.fogs;
        if self.waited < MAX_WAIT_STEPS && self.fog.iter().all(|ch| ch.queue.is_empty()) {
            // Nothing queued (the usual case once this step's sample is taken).
            return None;
        }
        let fogs = || self.fog.iter().enumerate().filter(move |(i, _)| fitted.contains(*i)).map(|(_, ch)| ch);
        let Some(e) = self.clock.expected else {
            // Before the first sample: start at the oldest one waiting, if any.
            let first = fogs().filter_map(|ch| ch.queue.front().map(|f| f.counter)).min()?;
            self.clock.index = u64::from(first).saturating_sub(1);
            self.clock.expected = Some(first);
            return Some(first);
        };
        // Per FOG: has sample e queued, has only newer ones (e lost), or has nothing yet.
        // A FOG's frames arrive in counter order, so the first queued frame that is not
        // older than e decides (older ones are discarded as stale by `take_sample`).
        let mut have = 0u8;
        let mut past = 0u8;
        let mut oldest_newer: Option<u16> = None;
        for (i, ch) in self.fog.iter().enumerate() {
            let bit = 1u8 << i;
            if fitted.0 & bit == 0 {
                continue;
            }
            let Some(front) = ch.queue.front() else { continue };
            let mut ahead = front.counter.wrapping_sub(e);
            if ahead >= 0x8000 {
                // Stale frames first (rare): look past them.
                match ch.queue.iter().map(|f| f.counter.wrapping_sub(e)).find(|&d| d < 0x8000) {
                    Some(d) => ahead = d,
                    None => continue,
                }
            }
            if ahead == 0 {
                have |= bit;
            } else {
                past |= bit;
                if oldest_newer.is_none_or(|o| ahead < o.wrapping_sub(e)) {
                    oldest_newer = Some(e.wrapping_add(ahead));
                }
            }
        }
        let owed = self.last_present.0 & fitted.0 & !(have | past);
        if have == 0 && past != 0 && (owed == 0 || self.waited >= MAX_WAIT_STEPS) {
            // Sample e was lost on every link: jump to the oldest newer one.
            let o = oldest_newer?;
            let lost = o.wrapping_sub(e);
            self.counters.fog_samples_missing =
                self.counters.fog_samples_missing.saturating_add(u32::from(lost).saturating_mul(fitted.count()));
            self.clock.index = self.clock.index.saturating_add(u64::from(lost));
            self.clock.expected = Some(o);
            self.gap = true;
            return Some(o);
        }
        if have != 0 && (owed == 0 || self.waited >= MAX_WAIT_STEPS) {
            return Some(e);
        }
        if have == 0 && past == 0 && self.waited >= MAX_WAIT_STEPS {
            // No FOG data at all: bridge this sample so time keeps moving.
            return Some(e);
        }
        None
    }

    /// Takes sample `target` from every fitted FOG that has it and compensates it.
    /// Returns the compensated increments, the FOGs that gave one, and health bits.
    fn take_sample(&mut self, target: u16, dt_s: f64) -> (Vector4<f64>, FogSet, [u8; N_FOG]) {
        let fitted = self.profile.fogs;
        let gap = if core::mem::take(&mut self.gap) { health::COUNTER_GAP } else { 0 };
        self.clock.index = self.clock.index.saturating_add(1);
        self.clock.expected = Some(target.wrapping_add(1));
        let mut m = [0.0f64; N_FOG];
        let mut health_bits = [health::EXCLUDED; N_FOG];
        let mut used = 0u8;
        let mut present = 0u8;
        let limit_rad = self.profile.rate_limit_rad_s * dt_s;
        for (i, ((ch, cal), (mi, hi))) in
            self.fog.iter_mut().zip(&self.table.fog).zip(m.iter_mut().zip(health_bits.iter_mut())).enumerate()
        {
            let bit = 1u8 << i;
            if fitted.0 & bit == 0 {
                continue;
            }
            let (h, taken) = take_one(ch, cal, target, dt_s, limit_rad, &mut self.counters);
            if h & health::USED != 0 && ch.monitor.temp_failed() {
                self.temp_failed_bits |= bit;
            }
            *hi = h | gap;
            if let Some(dtheta) = taken {
                present |= bit;
                if let Some(d) = dtheta {
                    *mi = d;
                    used |= bit;
                }
            }
        }
        self.last_present = FogSet(present);
        (Vector4::from(m), FogSet(used), health_bits)
    }

    /// Drains the star-tracker link and applies every valid frame whose time tag the
    /// propagated attitude has reached; later ones wait (up to [`ST_PENDING`]).
    fn read_star<S: RxLink>(&mut self, star: &mut S, now_us: u64) -> u8 {
        let mut status = 0u8;
        let decoder = &mut self.st_decoder;
        let pending = &mut self.st_pending;
        let mut overflow = 0u32;
        let mut arrived = false;
        let rep = drain(star, MAX_RX_BYTES_PER_STEP, &mut self.rx_scratch.0, |bytes| {
            decoder.push_slice(bytes, |r| {
                if let Ok(f) = r {
                    arrived = true;
                    if pending.is_full() {
                        let _ = pending.pop_front();
                        overflow += 1;
                    }
                    let _ = pending.push_back(f);
                }
            });
        });
        self.counters.io_errors = self.counters.io_errors.saturating_add(rep.io_errors);
        if arrived {
            status |= st_status::FRAME;
        }
        // The decoder's counts change only with bytes.
        let decoded_rej = if rep.bytes > 0 { self.st_decoder.stats().rejected() } else { self.st_rejected_seen };
        let new_rej = decoded_rej.saturating_sub(self.st_rejected_seen).saturating_add(overflow);
        self.st_rejected_seen = decoded_rej;
        if new_rej > 0 {
            status |= st_status::REFUSED;
            self.counters.st_frames_rejected = self.counters.st_frames_rejected.saturating_add(new_rej);
        }
        // Bounded: at most ST_PENDING frames are examined.
        for _ in 0..ST_PENDING {
            let Some(f) = self.st_pending.front().copied() else { break };
            if f.time_us > now_us {
                if f.time_us - now_us > ST_MAX_LEAD_US {
                    let _ = self.st_pending.pop_front();
                    status |= st_status::REFUSED;
                    self.counters.st_frames_rejected = self.counters.st_frames_rejected.saturating_add(1);
                    continue;
                }
                break;
            }
            let _ = self.st_pending.pop_front();
            status |= self.apply_star(&f, now_us);
        }
        if self.observer.aligned() {
            status |= st_status::ALIGNED;
        }
        let silent = match self.last_st_update_us {
            Some(t) => now_us.saturating_sub(t) > ST_OUTAGE_US,
            None => true,
        };
        if silent {
            status |= st_status::OUTAGE;
            if !self.in_outage && self.observer.aligned() {
                self.counters.st_outages = self.counters.st_outages.saturating_add(1);
            }
        }
        self.in_outage = silent;
        status
    }

    /// One star-tracker frame into the observer; returns status bits.
    fn apply_star(&mut self, f: &StarFrame, now_us: u64) -> u8 {
        if !f.valid() {
            self.counters.st_frames_rejected = self.counters.st_frames_rejected.saturating_add(1);
            return st_status::REFUSED;
        }
        if f.q_counts == self.last_st_q_counts {
            // A frozen tracker repeats its last solution; a live one never does (noise).
            self.counters.st_frozen = self.counters.st_frozen.saturating_add(1);
            return st_status::REFUSED;
        }
        self.last_st_q_counts = f.q_counts;
        let [w, x, y, z] = f.quaternion();
        let q = Quaternion::new(w, x, y, z);
        if let Some(fdi) = self.fdi.as_mut().filter(|m| m.listening()) {
            // A FOG is faulty: the observer listens, the fault logic uses the mismatch.
            return match self.observer.listen(f.time_us, &q, &self.mount) {
                Ok((e, var)) => {
                    self.last_st_update_us = Some(now_us);
                    if let Some(iso) = fdi.on_mismatch(&e, var) {
                        self.observer.remove_drift(&mut self.attitude, now_us, iso.since_us, &iso.drift_rad_s);
                    }
                    st_status::LISTENED
                }
                Err(_) => {
                    self.counters.st_frames_rejected = self.counters.st_frames_rejected.saturating_add(1);
                    st_status::REFUSED
                }
            };
        }
        let reacquired = self.observer.stats().reacquired;
        match self.observer.update(&mut self.attitude, now_us, f.time_us, &q, &self.mount) {
            Ok(_) => {
                self.last_st_update_us = Some(now_us);
                self.counters.st_frames_accepted = self.counters.st_frames_accepted.saturating_add(1);
                if self.observer.stats().reacquired != reacquired {
                    st_status::UPDATED | st_status::REACQUIRED
                } else {
                    st_status::UPDATED
                }
            }
            Err(UpdateError::Gated) => {
                self.counters.st_updates_gated = self.counters.st_updates_gated.saturating_add(1);
                st_status::REFUSED
            }
            Err(_) => {
                self.counters.st_frames_rejected = self.counters.st_frames_rejected.saturating_add(1);
                st_status::REFUSED
            }
        }
    }

    /// Encodes and writes the output frame; a link that cannot take it is counted.
    fn emit<O: TxLink>(&mut self, out: &mut O, o: &StepOutput) {
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
        // Paged by the sample clock (not the frame counter), so a replay of the same
        // data pages the same counters in the same frames.
        frame.page_id = (self.clock.index as u32 % u32::from(page::COUNT)) as u8;
        frame.page_value = sat(self.page_counter(frame.page_id));
        self.out_counter = self.out_counter.wrapping_add(1);
        let ok = frame.encode_into(&mut self.out_buf.0).is_ok() && write_frame(out, &self.out_buf.0);
        self.output_dropped_last = !ok;
        if !ok {
            self.counters.output_dropped = self.counters.output_dropped.saturating_add(1);
        }
    }
}

impl FlightCore {
    /// The counter that the output frame's page `id` carries ([`page`]).
    fn page_counter(&self, id: u8) -> u32 {
        let c = &self.counters;
        if id < page::FDI_ALARMS {
            let Some(f) = self.fog.get(usize::from(id / page::PER_FOG)).map(|ch| &ch.counters) else { return 0 };
            return match id % page::PER_FOG {
                page::FOG_REJECTED => f.rejected,
                page::FOG_MISSING => f.missing,
                page::FOG_OUT_OF_RANGE => f.out_of_range,
                page::FOG_STUCK => f.stuck,
                page::FOG_DEVICE_FAULT => f.device_fault,
                page::FOG_TEMP_FAILURES => f.temp_failures,
                _ => f.spikes,
            };
        }
        let fdi = self.fdi.as_ref().map(|m| m.counters()).unwrap_or_default();
        match id {
            page::FDI_ALARMS => fdi.alarms,
            page::FDI_TRANSIENTS => fdi.transients,
            page::FDI_ISOLATIONS => fdi.isolations,
            page::ST_FROZEN => c.st_frozen,
            page::ST_REACQUIRED => self.observer.stats().reacquired,
            page::ST_OUTAGES => c.st_outages,
            page::IO_ERRORS => c.io_errors,
            page::OUTPUT_DROPPED => c.output_dropped,
            page::FOG_STALE => c.fog_samples_stale,
            _ => 0,
        }
    }
}

/// One FOG's part of [`FlightCore::take_sample`]: takes sample `target` from the channel's
/// queue (discarding older ones as stale, leaving a newer one queued) and compensates it.
/// Returns the health bits and, if the sample was there, the compensated increment
/// (`None` inside when the FOG reports a fault or the value is out of range).
fn take_one(
    ch: &mut FogChannel,
    cal: &FogCal,
    target: u16,
    dt_s: f64,
    limit_rad: f64,
    counters: &mut Counters,
) -> (u8, Option<Option<f64>>) {
    let mut h = 0u8;
    let fc = &mut ch.counters;
    let new_rej = core::mem::take(&mut ch.rejected_new);
    if new_rej > 0 {
        h |= health::REJECTED;
        counters.fog_frames_rejected = counters.fog_frames_rejected.saturating_add(new_rej);
        fc.rejected = fc.rejected.saturating_add(new_rej);
    }
    let mut stale = 0u32;
    let mut frame = None;
    // Bounded by the queue length.
    for _ in 0..FOG_QUEUE {
        let Some(f) = ch.queue.pop_front() else { break };
        let age = target.wrapping_sub(f.counter);
        if age == 0 {
            frame = Some(f);
            break;
        }
        if age >= 0x8000 {
            // Newer than the target: it waits for its own step (room is certain: it was
            // just taken out).
            let _ = ch.queue.push_front(f);
            break;
        }
        stale += 1;
    }
    if stale > 0 {
        h |= health::COUNTER_GAP;
        counters.fog_samples_stale = counters.fog_samples_stale.saturating_add(stale);
    }
    match frame {
        None => {
            counters.fog_samples_missing = counters.fog_samples_missing.saturating_add(1);
            fc.missing = fc.missing.saturating_add(1);
            (h | health::MISSING, None)
        }
        Some(frame) => {
            let temp_was_failed = ch.monitor.temp_failed();
            let v = ch.monitor.check(&frame, dt_s);
            if v.temp_failed && !temp_was_failed {
                fc.temp_failures = fc.temp_failures.saturating_add(1);
            }
            if frame.status & (status::LIGHT_SOURCE_FAULT | status::LOOP_LOCK_LOST) != 0 {
                fc.device_fault = fc.device_fault.saturating_add(1);
                (h | health::DEVICE_FAULT, Some(None))
            } else if v.stuck {
                fc.stuck = fc.stuck.saturating_add(1);
                (h | health::STUCK, Some(None))
            } else {
                let dtheta = compensate_increment(cal, frame.dtheta_rad(), dt_s, v.t_degc, v.g_degc_s);
                if !dtheta.is_finite() || dtheta.abs() > limit_rad {
                    fc.out_of_range = fc.out_of_range.saturating_add(1);
                    (h | health::OUT_OF_RANGE, Some(None))
                } else {
                    (h | health::USED, Some(Some(dtheta)))
                }
            }
        }
    }
}

/// Queues a FOG sample; a full queue drops its oldest (late backlog).
fn enqueue(queue: &mut Deque<FogFrame, FOG_QUEUE>, f: FogFrame) {
    if queue.is_full() {
        let _ = queue.pop_front();
    }
    let _ = queue.push_back(f);
}
