//! The fixed-rate flight step: read what arrived on every link, compensate, combine,
//! integrate, observe, emit one output frame.
//!
//! [`FlightCore::step`] is what the timer tick calls (firmware) and what the host harness
//! calls in replay; it is the same code. It never waits on a link, never allocates, never
//! panics; every byte, frame or sample it could not use is counted and flagged in the
//! output frame (see `docs/ICD.md` for the health and status bits).
//!
//! The step reads in data-flow order; each stage is one type of its own module:
//! intake ([`FogIntake`], [`StarIntake`]) → integrity, per channel ([`ChannelMonitor`]) →
//! compensation ([`ThermalTracker`], [`compensate_increment`]) → integrity, parity
//! ([`ParityMonitor`]) → combination ([`Combiner`]) → attitude ([`Attitude`]) →
//! observer ([`Observer`]) → telemetry ([`Telemetry`]).
//!
//! Two profiles ([`Profile`]): the spacecraft unit (four FOGs + star tracker, 5 ms,
//! ±10 °/s) and the launch-vehicle unit (three FOGs, 1.25 ms, ±100 °/s).
//!
//! Timing convention: unit time is the FOG sample clock. The sample with counter k covers
//! ((k−1)Δt, kΔt] of unit time (counters unwrapped from u16); the step that integrates it
//! emits the time tag kΔt and Λ(kΔt). Star-tracker time tags are in the same time.

use nalgebra::{Quaternion, Vector3, Vector4};

use crate::attitude::{Attitude, Coning};
use crate::calib::{CalibrationTable, FogCal, N_FOG};
use crate::combination::{Combiner, FogSet};
use crate::compensation::{compensate_increment, ThermalTracker};
use crate::frames::event::{EventFrame, RECORDS};
use crate::frames::fog::{status, FogFrame};
use crate::frames::star::StarFrame;
use crate::frames::Frame;
use crate::intake::{FogIntake, Pending, StarIntake};
use crate::integrity::channel::ChannelMonitor;
use crate::integrity::mounting::{MountCheck, MountState, MountVerdict};
use crate::integrity::parity::{FdiState, ParityMonitor, SampleVerdict};
use crate::link::{OutPort, RxLink, RxPort, StarPort};
use crate::observer::{GainError, Observer, UpdateError};
use crate::telemetry::events::{Event, EventLog, EventRecord, StatusBits};
use crate::telemetry::{page, Telemetry, WordAligned};

pub use crate::intake::{
    FogLinks, FOG_QUEUE, MAX_RX_BYTES_PER_STEP, MAX_WAIT_STEPS, ST_MAX_LEAD_US, ST_OUTAGE_US, ST_PENDING,
};
pub use crate::telemetry::{flags, health, st_status, Counter, Counters, FogCounter, FogCounters, StepOutput};

/// Steps of attitude history for star-tracker latency (64 × 5 ms = 320 ms).
pub const HISTORY: usize = 64;
/// Bytes read from a link per chunk: a step's four FOG frames on the bus (72 bytes, a
/// multiple of 4, so runs stay word-aligned). A frame split across two chunks is
/// decoded byte by byte instead of in place (`StreamDecoder::push_slice`).
const RX_CHUNK: usize = 4 * FogFrame::LEN;

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

/// What one FOG gave for one sample.
#[derive(Debug, Clone, Copy, PartialEq)]
enum FogValue {
    /// No sample arrived.
    Missing,
    /// The sample arrived but is not used (device fault, stuck, out of range).
    Refused,
    /// The compensated increment, rad.
    Used(f64),
}

/// One FOG's sample after intake, the channel checks and compensation.
#[derive(Debug, Clone, Copy, PartialEq)]
struct FogTaken {
    /// Health bits ([`health`]).
    health: u8,
    value: FogValue,
}

/// One sample of every fitted FOG.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Sample {
    /// Compensated increments, rad (0 for a FOG not used).
    dtheta: Vector4<f64>,
    /// FOGs to combine.
    used: FogSet,
    /// Health bits per FOG ([`health`]).
    health: [u8; N_FOG],
}

/// The flight core: all state of one unit, stage by stage.
///
/// `repr(C)` in this order: the state every step touches first, the large stages last,
/// so the hot fields sit within the M7's short load offsets of one base address.
#[repr(C)]
#[derive(Clone)]
pub struct FlightCore {
    profile: Profile,
    last_body_dtheta: Vector3<f64>,
    attitude: Attitude,
    mount: Quaternion<f64>,
    thermal: [ThermalTracker; N_FOG],
    channel_monitors: [ChannelMonitor; N_FOG],
    telemetry: Telemetry,
    last_output: StepOutput,
    /// Chunk buffer for draining the links (kept, so a step does not clear one).
    rx_scratch: WordAligned<RX_CHUNK>,
    fog_intake: FogIntake,
    table: CalibrationTable,
    combiner: Combiner,
    /// Parity fault logic (`None` without four FOGs).
    fdi: Option<ParityMonitor>,
    star_intake: StarIntake,
    /// Flags that hold for the whole flight: star tracker in use, table defaulted, BIT failed.
    fixed_flags: u8,
    /// FOGs whose temperature sensor has failed (bit i).
    temp_failed_bits: u8,
    observer: Observer<HISTORY>,
    /// CRC-32 of the table in use (its binary form's last four bytes; not touched by the
    /// step, so after the hot state).
    table_crc: u32,
    /// The mounting check from power-on (`None` without four FOGs, a star tracker and
    /// the parity logic).
    mounting: Option<MountCheck>,
    /// FOG channel k flies on the table's axis `fog_map[k]` (identity unless the
    /// mounting check found two FOGs swapped).
    fog_map: [usize; N_FOG],
    /// The log of state changes not yet sent (rarely touched: last).
    events: EventLog,
}

impl FlightCore {
    /// Builds the core for `profile` from `table` (`table_defaulted` = the stored table
    /// was invalid and `table` is the default; flagged in every output frame).
    pub fn new(profile: Profile, table: &CalibrationTable, table_defaulted: bool) -> Result<Self, CoreError> {
        let combiner = checked_combiner(profile, table, &IDENTITY_MAP)?;
        let mut observer = Observer::from_config(&table.observer)?;
        observer.set_noise(&flying_noise(&combiner, profile.fogs));
        let dt = profile.dt_s();
        let noise_rad = sample_noise_rad(table, dt);
        let fdi = parity_monitor(profile, &combiner, noise_rad, dt);
        let mounting = (profile.star_tracker && fdi.is_some()).then(|| {
            let st_sigma_rad = table.observer.st_sigma_arcsec * core::f64::consts::PI / 180.0 / 3600.0;
            MountCheck::new(table.axes(), st_sigma_rad, noise_rad, profile.dt_us)
        });
        Ok(FlightCore {
            mounting,
            fog_map: IDENTITY_MAP,
            profile,
            table: *table,
            table_crc: table_crc(table),
            fixed_flags: if profile.star_tracker { flags::ST_IN_USE } else { 0 }
                | if table_defaulted { flags::TABLE_DEFAULTED } else { 0 },
            rx_scratch: WordAligned([0; RX_CHUNK]),
            fog_intake: FogIntake::new(profile.fogs),
            star_intake: StarIntake::new(),
            channel_monitors: [ChannelMonitor::new(noise_rad); N_FOG],
            thermal: [ThermalTracker::new(dt, table.t_rate_filter_s); N_FOG],
            fdi,
            temp_failed_bits: 0,
            combiner,
            last_body_dtheta: Vector3::zeros(),
            attitude: Attitude::new(Quaternion::identity(), Coning::ThreeSample),
            mount: table.st_mount(),
            observer,
            telemetry: Telemetry::new(),
            last_output: StepOutput::START,
            events: EventLog::new(),
        })
    }

    /// Whether the core would fly on `table` ([`FlightCore::switch_table`] would take it):
    /// its fitted FOGs span 3-D space and the observer's gains can be computed.
    pub fn check_table(profile: Profile, table: &CalibrationTable) -> Result<(), CoreError> {
        checked_combiner(profile, table, &IDENTITY_MAP)?;
        crate::observer::steady_state(&table.observer)?;
        Ok(())
    }

    /// Whether a table may be switched now: not while a parity alarm stands (its
    /// isolation fit runs on the table it began with).
    pub fn ready_for_table(&self) -> bool {
        !self.fdi.as_ref().is_some_and(|m| m.alarm())
    }

    /// Switches to `table` between two steps: compensation, combination, the parity
    /// monitor's geometry, the star-tracker mount, the temperature-rate filter and the
    /// observer's gains take the new values from the next step on; the attitude, the
    /// drift estimate, the histories, the counters, an isolated FOG and the flags stay.
    /// So the attitude changes only by what the new values imply. Refused (nothing
    /// changed) if [`FlightCore::check_table`] refuses `table`.
    pub fn switch_table(&mut self, table: &CalibrationTable) -> Result<(), CoreError> {
        let combiner = checked_combiner(self.profile, table, &self.fog_map)?;
        self.observer.retune(&table.observer)?;
        let dt = self.profile.dt_s();
        let noise_rad = sample_noise_rad(table, dt);
        self.install_geometry(combiner, noise_rad);
        for m in self.channel_monitors.iter_mut() {
            m.set_noise(noise_rad);
        }
        for t in self.thermal.iter_mut() {
            t.set_time_constant(dt, table.t_rate_filter_s);
        }
        self.mount = table.st_mount();
        self.table = *table;
        self.table_crc = table_crc(table);
        let revision = u16::try_from(table.revision).unwrap_or(u16::MAX);
        self.events.log(self.last_output.time_us, Event::TableSwitched, 0, revision);
        Ok(())
    }

    /// Flies on `combiner` from the next sample: the parity logic on its geometry, taking
    /// over an isolated FOG and the counters from the one before.
    fn install_geometry(&mut self, combiner: Combiner, noise_rad: f64) {
        let dt = self.profile.dt_s();
        let mut fdi = parity_monitor(self.profile, &combiner, noise_rad, dt);
        if let (Some(new), Some(old)) = (fdi.as_mut(), self.fdi.as_ref()) {
            new.carry_from(old);
        }
        self.fdi = fdi;
        self.combiner = combiner;
        self.observer.set_noise(&flying_noise(&self.combiner, self.flying()));
    }

    /// The FOGs the combination flies on: the fitted ones less an isolated one.
    fn flying(&self) -> FogSet {
        match self.fdi.as_ref().and_then(ParityMonitor::isolated) {
            Some(i) => self.profile.fogs.without(i),
            None => self.profile.fogs,
        }
    }

    /// FOG `i` has just been isolated at unit time `now_us`: its share leaves the drift
    /// estimate ([`Observer::remove_drift_share`]), and the estimators' noise follows
    /// the triad that flies from now on.
    fn on_isolation(&mut self, i: usize, now_us: u64) {
        if let Some(fdi) = self.fdi.as_ref() {
            let (share, cov) = (fdi.drift_share_rad_s(i), fdi.drift_share_cov_rad2_s2(i));
            self.observer.remove_drift_share(now_us, &share, &cov);
        }
        self.observer.set_noise(&flying_noise(&self.combiner, self.flying()));
    }

    /// CRC-32 of the table in use (the last four bytes of its binary form).
    pub fn table_crc(&self) -> u32 {
        self.table_crc
    }

    /// Command link and board: one more event of counter `c` (the telecommand counters;
    /// the counters the core derives itself are not changed by it).
    pub fn note(&mut self, c: Counter) {
        self.telemetry.counters.bump(c);
    }

    /// Logs `event` with details `a`, `b` at the unit time of the last step (the command
    /// link's outcomes; the core logs its own state changes).
    pub fn log_event(&mut self, event: Event, a: u8, b: u16) {
        self.events.log(self.last_output.time_us, event, a, b);
    }

    /// Board: the watchdog warned (the main loop missed a watchdog period).
    pub fn note_watchdog_warning(&mut self) {
        self.log_event(Event::WatchdogWarning, 0, 0);
    }

    /// The event log (records not yet sent).
    pub fn events(&self) -> &EventLog {
        &self.events
    }

    /// Takes the oldest record not yet sent (host tools that read the log directly).
    pub fn take_event(&mut self) -> Option<EventRecord> {
        self.events.pop()
    }

    /// Board, after the step: sends the oldest records not yet sent (up to four) in one
    /// event frame on `out`; nothing when there is none. Records the link does not take
    /// stay for the next call. Returns whether a frame was sent.
    pub fn send_events<O: OutPort>(&mut self, out: &mut O) -> bool {
        if self.events.is_empty() {
            return false;
        }
        let mut frame =
            EventFrame { lost: u16::try_from(self.events.lost()).unwrap_or(u16::MAX), records: [None; RECORDS] };
        for (slot, r) in frame.records.iter_mut().zip(self.events.pending()) {
            *slot = Some(*r);
        }
        let n = frame.iter().count();
        let mut scratch = [0u8; EventFrame::LEN];
        let sent = out.send_frame(&mut scratch, EventFrame::LEN, |buf| frame.encode_into(buf).is_ok());
        if sent {
            self.events.drop_sent(n);
        }
        sent
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

    /// Counters so far (the fault logic's and the observer's included).
    pub fn counters(&self) -> Counters {
        let mut c = self.telemetry.counters;
        for &k in [Counter::FdiAlarms, Counter::FdiTransients, Counter::FdiIsolations, Counter::StReacquired].iter() {
            c.add(k, self.counter(k));
        }
        c
    }

    /// Counter `c` so far. The parity fault logic and the observer keep their own counts;
    /// the others are the telemetry stage's.
    pub fn counter(&self, c: Counter) -> u32 {
        let fdi = || self.fdi.as_ref().map(|m| m.counters()).unwrap_or_default();
        match c {
            Counter::FdiAlarms => fdi().alarms,
            Counter::FdiTransients => fdi().transients,
            Counter::FdiIsolations => fdi().isolations,
            Counter::StReacquired => self.observer.stats().reacquired,
            Counter::TableRevision => self.table.revision,
            Counter::TableCrcLow => self.table_crc & 0xFFFF,
            Counter::TableCrcHigh => self.table_crc >> 16,
            _ => self.telemetry.counters.get(c),
        }
    }

    /// The counter that the output frame's page `id` carries ([`page`]).
    fn page_value(&self, id: u8) -> u32 {
        match page::entry(id) {
            Some(page::Entry::Fog(i, c)) => self.telemetry.counters.fog.get(i).map_or(0, |f| f.get(c)),
            Some(page::Entry::Unit(c)) => self.counter(c),
            None => 0,
        }
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
        self.mounting = None;
    }

    /// The mounting check from power-on (`None` when the unit has none).
    pub fn mounting(&self) -> Option<&MountCheck> {
        self.mounting.as_ref()
    }

    /// The table axis each FOG channel flies on (identity unless two FOGs were found
    /// swapped).
    pub fn fog_map(&self) -> [usize; N_FOG] {
        self.fog_map
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
        self.telemetry.counters.bump(Counter::Overruns);
    }

    /// Board: a control frame arrived and was ignored (a flight build has no test hooks).
    pub fn note_control_ignored(&mut self) {
        self.telemetry.counters.bump(Counter::ControlIgnored);
    }

    /// Board: how long the previous step took, in board ticks (goes into the frame).
    pub fn set_step_ticks(&mut self, ticks: u16) {
        self.telemetry.set_step_ticks(ticks);
    }

    /// One fixed step. Reads every link, integrates the FOG samples that are due,
    /// observes, writes one output frame.
    ///
    /// Each step integrates, in order, every sample that is complete (usually one; more
    /// after a delay, catching up) and emits the time tag of the last ([`FogIntake`]
    /// decides which sample is due and how long an owed one is waited for). With no FOG
    /// data at all for longer, the interval is bridged with the last body increment so
    /// time and attitude keep moving.
    pub fn step<F: RxPort, S: StarPort, O: OutPort>(&mut self, links: &mut Links<F, S, O>) -> StepOutput {
        self.step_with(links, |_, _| {})
    }

    /// [`FlightCore::step`], handing each body angle increment the attitude integrates
    /// (combined and compensated, rad) to `on_increment` with the unit time at its end
    /// (µs): once per sample, none when no sample came, more than one when the step
    /// catches up. The launch-vehicle navigation runs on them ([`crate::nav::unit`]); a
    /// caller with no use for them calls `step`, where the empty hook compiles away.
    pub fn step_with<F: RxPort, S: StarPort, O: OutPort>(
        &mut self,
        links: &mut Links<F, S, O>,
        mut on_increment: impl FnMut(u64, &Vector3<f64>),
    ) -> StepOutput {
        let dt_s = self.profile.dt_s();
        // Intake: the FOG links into the per-FOG sample queues.
        self.fog_intake.receive(&mut links.fog, &mut self.rx_scratch.0, &mut self.telemetry.counters);
        let mut fog_health = [0u8; N_FOG];
        let mut used = FogSet(0);
        let mut parity_rad = 0.0;
        let mut rate_dtheta = Vector3::zeros();
        let mut integrated = 0u32;
        let mut degraded = false;
        // Bounded: at most one pass per queued sample.
        for _ in 0..FOG_QUEUE {
            let Some(target) = self.fog_intake.next_sample(&mut self.telemetry.counters) else { break };
            let lost = self.fog_intake.take_lost();
            if lost > 0 {
                // Samples lost on every link: turn through them on the last body
                // increment, as a bridge does, so the attitude and its history keep up
                // with the clock (skipping them would drop their rotation).
                let held = self.last_body_dtheta - self.observer.drift_rad_s() * dt_s;
                let _ = self.attitude.bridge(&held, lost);
                let span_end_us = self.fog_intake.time_us(self.profile.dt_us);
                self.observer.record(span_end_us, self.attitude.quaternion());
                on_increment(span_end_us, &(self.last_body_dtheta * f64::from(lost)));
            }
            // Intake, channel checks, compensation.
            let mut sample = self.take_sample(target, dt_s);
            let time_us = self.fog_intake.time_us(self.profile.dt_us);
            // Integrity: the mounting check (from power-on) sees every sample of the four.
            let isolated = self.fdi.as_ref().is_some_and(|m| m.isolated().is_some());
            if let Some(m) = self.mounting.as_mut().filter(|m| m.checking() && !isolated) {
                m.on_sample(&sample.dtheta, sample.used == FogSet::ALL, time_us);
            }
            // Integrity: the parity check may drop a spike or an isolated FOG.
            parity_rad = self.check_parity(&mut sample, time_us);
            degraded |= self.fdi.as_ref().is_some_and(|m| m.alarm());
            for (acc, bits) in fog_health.iter_mut().zip(sample.health) {
                *acc |= bits;
            }
            used = sample.used;
            degraded |= sample.used != self.profile.fogs;
            // Combination.
            let body = match self.combiner.combine(&sample.dtheta, sample.used) {
                Ok(v) => v,
                Err(_) => {
                    // No usable gyro set in this sample: hold the last body increment.
                    degraded = true;
                    self.last_body_dtheta
                }
            };
            self.last_body_dtheta = body;
            // Attitude, on the gyros corrected by the observer's drift estimate.
            rate_dtheta = body - self.observer.drift_rad_s() * dt_s;
            let _ = self.attitude.step(&rate_dtheta);
            self.observer.record(time_us, self.attitude.quaternion());
            on_increment(time_us, &body);
            integrated += 1;
            self.fog_intake.integrated();
            if self.fog_intake.bridged() {
                // A bridged sample (no FOG data): one per step.
                break;
            }
        }
        if integrated == 0 {
            // Nothing integrated: the output rate is the last body increment, corrected.
            rate_dtheta = self.last_body_dtheta - self.observer.drift_rad_s() * dt_s;
            self.fog_intake.waited_a_step();
            degraded = true;
            for (i, h) in fog_health.iter_mut().enumerate() {
                *h = if self.profile.fogs.contains(i) { health::MISSING } else { health::EXCLUDED };
            }
        }
        let now_us = self.fog_intake.time_us(self.profile.dt_us);

        // Observer: the star-tracker frames due by now.
        let st = match links.star.link() {
            Some(star) if self.profile.star_tracker => self.observe_star(star, now_us),
            _ => 0,
        };

        // Telemetry.
        let mut status_flags = self.fixed_flags;
        let mut fdi_bits = 0u8;
        if let Some(fdi) = &self.fdi {
            match fdi.state() {
                FdiState::Alarm => status_flags |= flags::FDI_ALARM,
                FdiState::Isolated(i) => fdi_bits |= 0x10 << i,
                FdiState::Watching => {}
            }
        }
        fdi_bits |= self.temp_failed_bits;
        if degraded || st & st_status::OUTAGE != 0 && self.observer.aligned() {
            status_flags |= flags::DEGRADED;
        }
        if self.observer.converged() {
            status_flags |= flags::CONVERGED;
        }
        if self.telemetry.output_dropped_last() {
            status_flags |= flags::OUTPUT_DROPPED;
        }
        let (att_sigma_rad, drift_sigma_rad_s) = self.observer.sigmas(now_us);
        let out = StepOutput {
            time_us: now_us,
            q: self.attitude.quaternion(),
            rate_rad_s: rate_dtheta / dt_s,
            drift_rad_s: self.observer.drift_rad_s(),
            parity_rad,
            fog_health,
            st_status: st,
            flags: status_flags,
            fogs_used: used,
            fdi: fdi_bits,
            att_sigma_rad,
            drift_sigma_rad_s,
        };
        self.last_output = out;
        // Paged by the sample clock (not the frame counter), so a replay of the same
        // data pages the same counters in the same frames.
        let page_id = (self.fog_intake.index() as u32 % u32::from(page::COUNT)) as u8;
        let page_value = self.page_value(page_id);
        self.telemetry.emit(&mut links.out, &out, page_id, page_value);
        let o = &self.last_output;
        let status = StatusBits { flags: o.flags, st_status: o.st_status, fdi: o.fdi };
        self.events.on_status(status, o.time_us, &self.fog_map);
        out
    }

    /// Takes sample `target` from every fitted FOG that has it: intake, channel checks,
    /// compensation.
    fn take_sample(&mut self, target: u16, dt_s: f64) -> Sample {
        let fitted = self.profile.fogs;
        let gap = self.fog_intake.begin(target);
        let limit_rad = self.profile.rate_limit_rad_s * dt_s;
        let mut dtheta = [0.0f64; N_FOG];
        let mut health_bits = [health::EXCLUDED; N_FOG];
        let mut used = 0u8;
        let mut present = 0u8;
        let stages = self.channel_monitors.iter_mut().zip(self.thermal.iter_mut()).zip(&self.table.fog);
        for (i, (((monitor, thermal), cal), (d, h))) in
            stages.zip(dtheta.iter_mut().zip(health_bits.iter_mut())).enumerate()
        {
            let bit = 1u8 << i;
            if fitted.0 & bit == 0 {
                continue;
            }
            let arrival = self.fog_intake.take(i, target, &mut self.telemetry.counters);
            let taken = match arrival.frame {
                None => FogTaken { health: arrival.health, value: FogValue::Missing },
                Some(frame) => {
                    let counters = &mut self.telemetry.counters;
                    let taken = check_and_compensate(i, &frame, monitor, thermal, cal, dt_s, limit_rad, counters);
                    FogTaken { health: arrival.health | taken.health, value: taken.value }
                }
            };
            if taken.health & health::USED != 0 && monitor.temp_failed() {
                self.temp_failed_bits |= bit;
            }
            *h = taken.health | gap;
            match taken.value {
                FogValue::Missing => {}
                FogValue::Refused => present |= bit,
                FogValue::Used(v) => {
                    present |= bit;
                    *d = v;
                    used |= bit;
                }
            }
        }
        self.fog_intake.end(FogSet(present));
        Sample { dtheta: Vector4::from(dtheta), used: FogSet(used), health: health_bits }
    }

    /// Integrity, parity: checks a sample of all four FOGs and drops a spike, or the
    /// isolated FOG, from it. Returns the parity residual, rad (0 unless all four were
    /// there and none is isolated).
    fn check_parity(&mut self, sample: &mut Sample, time_us: u64) -> f64 {
        let Some(fdi) = self.fdi.as_mut() else { return 0.0 };
        let was_isolated = fdi.isolated().is_some();
        let mut parity_rad = 0.0;
        let drop = match fdi.isolated() {
            Some(i) => Some(i),
            None if sample.used == FogSet::ALL => {
                parity_rad = self.combiner.parity(&sample.dtheta);
                match fdi.on_sample(&sample.dtheta, parity_rad, self.last_body_dtheta.norm_squared(), time_us) {
                    SampleVerdict::Use => None,
                    SampleVerdict::Drop(i) | SampleVerdict::Isolate(i) => {
                        self.telemetry.counters.bump_fog(i, FogCounter::Spikes);
                        Some(i)
                    }
                }
            }
            None => {
                fdi.on_partial_sample();
                // A fitted gyro refused by its own checks during an alarm is the faulty one.
                let refused = self.profile.fogs.0 & !sample.used.0;
                if fdi.alarm() && refused.count_ones() == 1 {
                    let i = refused.trailing_zeros() as usize;
                    fdi.isolate_failed_channel(i);
                    Some(i)
                } else {
                    None
                }
            }
        };
        let newly = if was_isolated { None } else { fdi.isolated() };
        if let Some(i) = newly {
            // Isolated in this sample: its share leaves the drift estimate too.
            self.on_isolation(i, time_us);
        }
        if let Some(i) = drop {
            sample.used = sample.used.without(i);
            if let Some(h) = sample.health.get_mut(i) {
                *h = (*h & !health::USED) | health::EXCLUDED;
            }
        }
        parity_rad
    }

    /// Observer: drains the star-tracker link and applies every valid frame whose time
    /// tag the propagated attitude has reached; later ones wait (up to [`ST_PENDING`]).
    /// Returns the star-tracker status bits.
    fn observe_star<S: RxLink>(&mut self, star: &mut S, now_us: u64) -> u8 {
        let mut status = self.star_intake.receive(star, &mut self.rx_scratch.0, &mut self.telemetry.counters);
        // Bounded: at most ST_PENDING frames are examined.
        for _ in 0..ST_PENDING {
            match self.star_intake.next_due(now_us, &mut self.telemetry.counters) {
                Pending::Due(f) => status |= self.apply_star(&f, now_us),
                Pending::Refused => status |= st_status::REFUSED,
                Pending::Wait => break,
            }
        }
        let aligned = self.observer.aligned();
        if aligned && self.mounting.as_ref().is_none_or(MountCheck::clear_to_report) {
            status |= st_status::ALIGNED;
        }
        status | self.star_intake.outage(now_us, aligned, &mut self.telemetry.counters)
    }

    /// One star-tracker frame into the observer (or, while a parity alarm stands, into
    /// the fault logic); returns status bits.
    fn apply_star(&mut self, f: &StarFrame, now_us: u64) -> u8 {
        let counters = &mut self.telemetry.counters;
        if !f.valid() {
            counters.bump(Counter::StFramesRejected);
            return st_status::REFUSED;
        }
        if self.star_intake.repeats(f) {
            counters.bump(Counter::StFrozen);
            return st_status::REFUSED;
        }
        let [w, x, y, z] = f.quaternion();
        let q = Quaternion::new(w, x, y, z);
        let isolated = self.fdi.as_ref().is_some_and(|m| m.isolated().is_some());
        if let Some(m) = self.mounting.as_mut().filter(|m| m.checking() && !isolated) {
            let before = m.state();
            // Eq. (5): Λ* taken to the ICS.
            let verdict = m.on_frame(f.time_us, &(q * self.mount.conjugate()));
            match (before, m.state()) {
                (MountState::Checking, MountState::Watching { unverified }) => {
                    self.telemetry.counters.add(Counter::MountUnverified, unverified.count_ones());
                    self.events.log(now_us, Event::MountUnverified, unverified, 0);
                }
                (_, MountState::Undecided { .. }) => {
                    self.telemetry.counters.bump(Counter::MountUndecided);
                    self.events.log(now_us, Event::MountUndecided, 0, 0);
                }
                _ => {}
            }
            if let Some(v) = verdict {
                self.act_on_mounting(v, now_us);
                // The attitude at this frame's tag was propagated on the wrong gyro up to
                // the present: the observer aligns on the next frame instead.
                self.star_intake.used(now_us);
                return st_status::LISTENED;
            }
        }
        let counters = &mut self.telemetry.counters;
        if let Some(fdi) = self.fdi.as_mut().filter(|m| m.listening()) {
            // A FOG is faulty: the observer listens, the fault logic uses the mismatch.
            return match self.observer.listen(f.time_us, &q, &self.mount) {
                Ok(m) => {
                    self.star_intake.used(now_us);
                    if let Some(iso) = fdi.on_mismatch(&m.e_rad, m.var_rad2) {
                        self.observer.remove_drift(&mut self.attitude, now_us, iso.since_us, &iso.drift_rad_s);
                        self.on_isolation(iso.fog, now_us);
                    }
                    st_status::LISTENED
                }
                Err(e) => {
                    counters.bump(star_refusal(e));
                    st_status::REFUSED
                }
            };
        }
        let reacquired = self.observer.stats().reacquired;
        match self.observer.update(&mut self.attitude, now_us, f.time_us, &q, &self.mount) {
            Ok(_) => {
                self.star_intake.used(now_us);
                counters.bump(Counter::StFramesAccepted);
                if self.observer.stats().reacquired != reacquired {
                    st_status::UPDATED | st_status::REACQUIRED
                } else {
                    st_status::UPDATED
                }
            }
            Err(UpdateError::Gated) => {
                counters.bump(Counter::StUpdatesGated);
                st_status::REFUSED
            }
            Err(e) => {
                counters.bump(star_refusal(e));
                st_status::REFUSED
            }
        }
    }
}

impl FlightCore {
    /// Acts on the mounting check's verdict: a reversed FOG (or one alone at odds with
    /// the tracker) is isolated, a swapped pair flown on the corrected assignment; the
    /// observer starts again, so nothing of the wrong gyro stays in the attitude or the
    /// drift estimate (the unit has not reported aligned yet).
    fn act_on_mounting(&mut self, v: MountVerdict, now_us: u64) {
        let channel = |i: usize| u16::try_from(i + 1).unwrap_or(0);
        let (kind, fogs) = match v {
            MountVerdict::Flipped(i) => (1, channel(i)),
            MountVerdict::Swapped(i, j) => (2, channel(i) | channel(j) << 4),
            MountVerdict::Unexplained(i) => (3, channel(i)),
        };
        self.events.log(now_us, Event::MountVerdict, kind, fogs);
        match v {
            MountVerdict::Flipped(i) | MountVerdict::Unexplained(i) => {
                if self.fdi.as_mut().is_some_and(|m| m.isolate_mounted_wrong(i)) {
                    self.telemetry.counters.bump(Counter::MountIsolated);
                }
            }
            MountVerdict::Swapped(i, j) => {
                let mut map = self.fog_map;
                if let (Some(&a), Some(&b)) = (map.get(i), map.get(j)) {
                    map = map.map(|k| {
                        if k == a {
                            b
                        } else if k == b {
                            a
                        } else {
                            k
                        }
                    });
                }
                if let Ok(combiner) = checked_combiner(self.profile, &self.table, &map) {
                    self.fog_map = map;
                    // Flagged in every frame from now on; kept with the fixed flags so
                    // the step does not compare the maps (a 16-byte memcmp, ~120
                    // instructions a step).
                    self.fixed_flags &= !flags::FOGS_REMAPPED;
                    if map != IDENTITY_MAP {
                        self.fixed_flags |= flags::FOGS_REMAPPED;
                    }
                    let noise_rad = sample_noise_rad(&self.table, self.profile.dt_s());
                    self.install_geometry(combiner, noise_rad);
                    self.telemetry.counters.bump(Counter::MountSwapped);
                }
            }
        }
        self.observer.restart();
        self.observer.set_noise(&flying_noise(&self.combiner, self.flying()));
    }
}

/// N = (SᵀS)⁻¹ of the combination of `set` on `combiner` ([`crate::observer::mekf::noise_of`]);
/// the identity if `set` cannot be combined (the estimators keep one FOG's figures).
fn flying_noise(combiner: &Combiner, set: FogSet) -> nalgebra::Matrix3<f64> {
    combiner.solution(set).map_or_else(|_| nalgebra::Matrix3::identity(), crate::observer::mekf::noise_of)
}

/// FOG channel k on the table's axis k: the mounting the table describes.
const IDENTITY_MAP: [usize; N_FOG] = [0, 1, 2, 3];

/// The table's axes in the order the FOG channels fly on them (`map[k]` for channel k).
fn mounted_axes(table: &CalibrationTable, map: &[usize; N_FOG]) -> [Vector3<f64>; N_FOG] {
    let axes = table.axes();
    map.map(|k| axes.get(k).copied().unwrap_or_else(Vector3::zeros))
}

/// The counter of a star-tracker frame the observer could not use (not gated): older
/// than the attitude history is a late frame and newer than it an early one (the unit's
/// clock, not the frame, is off); only a bad quaternion is a bad frame.
fn star_refusal(e: UpdateError) -> Counter {
    match e {
        UpdateError::Stale => Counter::StFramesLate,
        UpdateError::Future => Counter::StFramesEarly,
        UpdateError::Gated | UpdateError::BadQuaternion => Counter::StFramesRejected,
    }
}

/// The combiner of `table`'s geometry, if the profile's FOGs span 3-D space with it.
fn checked_combiner(profile: Profile, table: &CalibrationTable, map: &[usize; N_FOG]) -> Result<Combiner, CoreError> {
    let combiner = Combiner::new(&mounted_axes(table, map));
    match combiner.solution(profile.fogs) {
        Ok(_) => Ok(combiner),
        Err(_) => Err(CoreError::Geometry),
    }
}

/// σ₁: the ARW's angle noise in one sample of `dt_s` (the table's noise figure), rad.
fn sample_noise_rad(table: &CalibrationTable, dt_s: f64) -> f64 {
    table.observer.arw_deg_sqrt_h * core::f64::consts::PI / 180.0 / 60.0 * crate::math::sqrt(dt_s)
}

/// The parity fault logic for the profile (four FOGs) on `combiner`'s geometry.
fn parity_monitor(profile: Profile, combiner: &Combiner, noise_rad: f64, dt_s: f64) -> Option<ParityMonitor> {
    match (profile.fogs == FogSet::ALL, combiner.solution(FogSet::ALL), combiner.triads()) {
        (true, Ok(all), Some(triads)) => ParityMonitor::new(combiner.parity_vector(), all, triads, noise_rad, dt_s),
        _ => None,
    }
}

/// CRC-32 of `table`'s binary form (its last four bytes: what the table store and the
/// command link name a table by).
pub fn table_crc(table: &CalibrationTable) -> u32 {
    let bytes = crate::calib::binary::encode(table);
    bytes.last_chunk::<4>().map_or(0, |c| u32::from_le_bytes(*c))
}

/// FOG `i`'s frame through the channel checks (integrity) and compensation.
#[allow(clippy::too_many_arguments)]
#[inline]
fn check_and_compensate(
    i: usize,
    frame: &FogFrame,
    monitor: &mut ChannelMonitor,
    thermal: &mut ThermalTracker,
    cal: &FogCal,
    dt_s: f64,
    limit_rad: f64,
    counters: &mut Counters,
) -> FogTaken {
    let stuck = monitor.stuck(frame);
    let temp_was_failed = monitor.temp_failed();
    let reading_degc = monitor.temperature(frame, thermal.predicted_degc(dt_s));
    if monitor.temp_failed() && !temp_was_failed {
        counters.bump_fog(i, FogCounter::TempFailures);
    }
    let t = thermal.update(reading_degc, dt_s);
    let refused = |c: FogCounter, health: u8, counters: &mut Counters| {
        counters.bump_fog(i, c);
        FogTaken { health, value: FogValue::Refused }
    };
    if frame.status & (status::LIGHT_SOURCE_FAULT | status::LOOP_LOCK_LOST) != 0 {
        return refused(FogCounter::DeviceFault, health::DEVICE_FAULT, counters);
    }
    if stuck {
        return refused(FogCounter::Stuck, health::STUCK, counters);
    }
    let dtheta = compensate_increment(cal, frame.dtheta_rad(), dt_s, t.t_degc, t.g_degc_s);
    if !dtheta.is_finite() || dtheta.abs() > limit_rad {
        return refused(FogCounter::OutOfRange, health::OUT_OF_RANGE, counters);
    }
    FogTaken { health: health::USED, value: FogValue::Used(dtheta) }
}
