//! The fixed-rate flight step: read what arrived on every link, compensate, combine,
//! integrate, observe, emit one output frame.
//!
//! [`FlightCore::step`] is what the timer tick calls (firmware) and what the host harness
//! calls in replay; it is the same code. It never waits on a link, never allocates, never
//! panics; every byte, frame or sample it could not use is counted and flagged in the
//! output frame (see `docs/ICD.md` for the health and status bits).
//!
//! The step reads in data-flow order, one call per stage; each stage owns its policy:
//!
//! | stage | file | types it drives |
//! |---|---|---|
//! | FOG channels: intake, channel checks, thermal tracking, compensation; parity | `fog.rs` | [`FogIntake`], [`ChannelMonitor`], [`ThermalTracker`], [`ParityMonitor`] |
//! | combination and attitude (and samples lost on every link) | `propagate.rs` | [`Combiner`], [`Attitude`] |
//! | the star-tracker aid: frames at their tag, the mounting check, the fault logic's listening, the estimator's update | `star_aid.rs` | [`StarIntake`], [`MountCheck`], [`Observer`] |
//! | telemetry: the output and its status bits, counters, counter page, event log | `report.rs` | [`Telemetry`], [`EventLog`] |
//! | the table's geometry: combiner, parity logic, noise figures, table switch | `geometry.rs` | |
//!
//! Two profiles ([`Profile`]): the spacecraft unit (four FOGs + star tracker, 5 ms,
//! ±10 °/s) and the launch-vehicle unit (three FOGs, 1.25 ms, ±100 °/s).
//!
//! Timing convention: unit time is the FOG sample clock. The sample with counter k covers
//! ((k−1)Δt, kΔt] of unit time (counters unwrapped from u16); the step that integrates it
//! emits the time tag kΔt and Λ(kΔt). Star-tracker time tags are in the same time.

mod fog;
mod geometry;
mod guard;
mod propagate;
mod report;
mod scrub;
pub mod snapshot;
mod star_aid;
mod twin;

use guard::Block;
use propagate::Integrated;

pub use geometry::table_crc;
use geometry::{checked_combiner, flying_noise, parity_monitor, sample_noise_rad, IDENTITY_MAP};

use nalgebra::{Quaternion, Vector3};

use crate::attitude::{Attitude, Coning};
use crate::calib::{CalibrationTable, N_FOG};
use crate::combination::{Combiner, FogSet};
use crate::compensation::ThermalTracker;
use crate::frames::fog::FogFrame;
use crate::intake::{FogIntake, StarIntake};
use crate::integrity::channel::ChannelMonitor;
use crate::integrity::mounting::MountCheck;
use crate::integrity::parity::ParityMonitor;
use crate::link::{OutPort, RxPort, StarPort};
use crate::observer::{GainError, Observer};
use crate::state::{Flag, Maybe};
use crate::state_map::{state_struct, StateField};
use crate::telemetry::events::{EventLog, StatusBits};
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

/// [`Profile`] as the core stores it (every bit pattern a value: the star tracker's
/// presence as a [`Flag`]).
#[derive(Debug, Clone, Copy, PartialEq, bytemuck::AnyBitPattern)]
struct ProfileState {
    dt_us: u32,
    fogs: FogSet,
    rate_limit_rad_s: f64,
    star_tracker: Flag,
}

impl ProfileState {
    fn of(p: Profile) -> Self {
        ProfileState {
            dt_us: p.dt_us,
            fogs: p.fogs,
            rate_limit_rad_s: p.rate_limit_rad_s,
            star_tracker: Flag::new(p.star_tracker),
        }
    }

    /// Its words, for the state guard ([`guard`]): the period, the FOGs fitted, the
    /// measuring range. (The star tracker's presence is not guarded: a flip that clears
    /// it reads as a tracker outage, flagged.)
    #[inline(always)]
    pub(super) fn visit<V: crate::shadow::Visit>(&mut self, v: &mut V) {
        v.u32(&mut self.dt_us);
        let mut fogs = u64::from(self.fogs.0);
        v.word(&mut fogs);
        if V::WRITES {
            self.fogs = FogSet(u8::try_from(fogs).unwrap_or(0));
        }
        v.f64(&mut self.rate_limit_rad_s);
    }

    fn get(&self) -> Profile {
        Profile {
            dt_us: self.dt_us,
            fogs: self.fogs,
            rate_limit_rad_s: self.rate_limit_rad_s,
            star_tracker: self.star_tracker.get(),
        }
    }

    fn dt_s(&self) -> f64 {
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

state_struct! {
    /// The flight core: all state of one unit, stage by stage.
    ///
    /// `repr(C)` in this order: the state every step touches first, the large stages last,
    /// so the hot fields sit within the M7's short load offsets of one base address.
    ///
    /// Each field declared once ([`crate::state_map::state_struct!`]): its type, its value
    /// when built, and what it is to the protections: every type takes any bit pattern
    /// (issue-free upsets, [`crate::state`]) but the calibration table's (`bits(Raw)`,
    /// [`FlightCore::TABLE_BYTES`]); `map`: mapped further ([`FlightCore::state_map`]);
    /// `guard`: its blocks in the state guard ([`guard`]); `reset(Keep)`: carried over a
    /// reset in the snapshot's record ([`snapshot`]).
    #[repr(C)]
    #[derive(Clone)]
    pub struct FlightCore {
        profile: ProfileState = ProfileState::of(profile), guard(Block::Geometry);
        last_body_dtheta: Vector3<f64> = Vector3::zeros();
        attitude: Attitude = Attitude::new(Quaternion::identity(), Coning::ThreeSample),
            map(Attitude::STATE_MAP), guard(Block::Step);
        /// Λ and Δω carried twice in the step ([`twin`]).
        twin: twin::Twin = twin::Twin::of(&Quaternion::identity(), &Vector3::zeros()),
            map(twin::Twin::STATE_MAP);
        mount: Quaternion<f64> = table.st_mount(), guard(Block::Tuning);
        thermal: [ThermalTracker; N_FOG] = [ThermalTracker::new(dt, table.t_rate_filter_s); N_FOG];
        channel_monitors: [ChannelMonitor; N_FOG] = [ChannelMonitor::new(noise_rad); N_FOG], reset(Keep);
        telemetry: Telemetry = Telemetry::new();
        last_output: StepOutput = StepOutput::START;
        /// Chunk buffer for draining the links (kept, so a step does not clear one).
        rx_scratch: WordAligned<RX_CHUNK> = WordAligned([0; RX_CHUNK]);
        fog_intake: FogIntake = FogIntake::new(profile.fogs), map(FogIntake::STATE_MAP), guard(Block::Step);
        table: CalibrationTable = *table, bits(Raw);
        combiner: Combiner = combiner,
            map(Combiner::STATE_MAP), guard(Block::Geometry | Block::Without(_));
        /// Parity fault logic (`None` without four FOGs).
        fdi: Maybe<ParityMonitor> = fdi.into();
        star_intake: StarIntake = StarIntake::new(), map(StarIntake::STATE_MAP);
        /// Flags that hold for the whole flight: star tracker in use, table defaulted, BIT failed.
        fixed_flags: u8 = if profile.star_tracker { flags::ST_IN_USE } else { 0 }
            | if table_defaulted { flags::TABLE_DEFAULTED } else { 0 };
        /// FOGs whose temperature sensor has failed (bit i).
        temp_failed_bits: u8 = 0;
        observer: Observer<HISTORY> = observer,
            map(Observer::<HISTORY>::STATE_MAP), guard(Block::Steady | Block::Frame | Block::Tuning);
        /// CRC-32 of the table in use (its binary form's last four bytes; not touched by the
        /// step, so after the hot state).
        table_crc: u32 = crc;
        /// The mounting check from power-on (`None` without four FOGs, a star tracker and
        /// the parity logic).
        mounting: Maybe<MountCheck> = mounting.into();
        /// FOG channel k flies on the table's axis `fog_map[k]` (identity unless the
        /// mounting check found two FOGs swapped).
        fog_map: [usize; N_FOG] = IDENTITY_MAP;
        @shadows
        /// The shadows of the guarded state ([`guard`]).
        guard: guard::Guard;
        /// The log of state changes not yet sent (rarely touched: last).
        events: EventLog = EventLog::new(), map(EventLog::STATE_MAP);
        /// Resumed from a reset's snapshot taken at this sample index, its age not yet
        /// checked ([`snapshot`]).
        resumed_at: Maybe<u64> = Maybe::none();
        /// The snapshot's increment change per step, rad, until the resume is confirmed.
        resume_trend: [f64; 3] = [0.0; 3];
        /// The background check of the table in use ([`FlightCore::background`]).
        scrub: scrub::TableScrub = scrub::TableScrub::of(table);
    }
    guard {
        blocks: Block,
        words: GUARD_WORDS,
        parts: Guarded
    }
    snapshot {
        /// The fields that survive a reset, as the snapshot carries them ([`snapshot`]).
        record: Survivors
    }
    constructor
    /// [`FlightCore::new`] with the combiner and the table's CRC-32 it has computed: out
    /// of line, so that their deep calls (the table's encoding, the combiner's solution)
    /// do not stack on this frame, which holds the core as it is built.
    #[inline(never)]
    fn build(
        profile: Profile,
        table: &CalibrationTable,
        table_defaulted: bool,
        combiner: Combiner,
        crc: u32,
    ) -> Result<Self, CoreError> => Ok {
        let mut observer = Observer::from_config(&table.observer)?;
        observer.set_noise(&flying_noise(&combiner, profile.fogs));
        let dt = profile.dt_s();
        let noise_rad = sample_noise_rad(table, dt);
        let fdi = parity_monitor(profile, &combiner, noise_rad, dt);
        let mounting = (profile.star_tracker && fdi.is_some()).then(|| {
            let st_sigma_rad = table.observer.st_sigma_arcsec * core::f64::consts::PI / 180.0 / 3600.0;
            MountCheck::new(table.axes(), st_sigma_rad, noise_rad, profile.dt_us)
        });
    }
}

impl FlightCore {
    /// Builds the core for `profile` from `table` (`table_defaulted` = the stored table
    /// was invalid and `table` is the default; flagged in every output frame); the guard
    /// seals the state on its first check.
    pub fn new(profile: Profile, table: &CalibrationTable, table_defaulted: bool) -> Result<Self, CoreError> {
        let combiner = checked_combiner(profile, table, &IDENTITY_MAP)?;
        Self::build(profile, table, table_defaulted, combiner, table_crc(table))
    }

    /// The bytes of the core that hold the calibration table in use (offset range in the
    /// core): the part of the state that is not valid under every bit pattern (a test
    /// that writes random bytes over the core leaves them).
    pub const TABLE_BYTES: core::ops::Range<usize> = core::mem::offset_of!(FlightCore, table)
        ..core::mem::offset_of!(FlightCore, table) + core::mem::size_of::<CalibrationTable>();

    /// Where each field of the core lies in the value, down to the stages (and inside the
    /// attitude and the observer): the upset campaign names the field a flipped bit
    /// belongs to ([`crate::state_map`]). Nothing in a step reads it.
    pub fn state_map() -> &'static [StateField] {
        Self::STATE_MAP
    }

    /// CRC-32 of the table in use (the last four bytes of its binary form).
    pub fn table_crc(&self) -> u32 {
        self.table_crc
    }

    /// Sets the attitude (pad alignment without a star tracker) and marks it aligned.
    pub fn align(&mut self, q: Quaternion<f64>) {
        self.guard_touch();
        self.attitude.set_quaternion(q);
        self.observer.set_aligned();
        self.guard_seal_all();
    }

    /// The profile in use.
    pub fn profile(&self) -> Profile {
        self.profile.get()
    }

    /// The calibration table in use.
    pub fn table(&self) -> &CalibrationTable {
        &self.table
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
        self.fdi = Maybe::none();
        self.mounting = Maybe::none();
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
        on_increment: impl FnMut(u64, &Vector3<f64>),
    ) -> StepOutput {
        self.step_probed_with(links, on_increment, |_, _| {})
    }

    /// [`FlightCore::step`] with `probe` called at each numbered point of the step
    /// ([`probe`]) with the core: the host's upset campaign flips a bit of the state
    /// there, between the guard's check and its seal. Test builds only (feature
    /// `step-probe`; the flight firmware never enables it).
    #[cfg(feature = "step-probe")]
    pub fn step_probed<F: RxPort, S: StarPort, O: OutPort>(
        &mut self,
        links: &mut Links<F, S, O>,
        probe: impl FnMut(&mut FlightCore, u8),
    ) -> StepOutput {
        self.step_probed_with(links, |_, _| {}, probe)
    }

    /// The step, `probe` called at each point of [`probe`] (an empty one compiles away).
    #[inline(always)]
    fn step_probed_with<F: RxPort, S: StarPort, O: OutPort>(
        &mut self,
        links: &mut Links<F, S, O>,
        mut on_increment: impl FnMut(u64, &Vector3<f64>),
        mut probe: impl FnMut(&mut FlightCore, u8),
    ) -> StepOutput {
        // The guarded state as the last step left it (restored if a bit flipped since).
        self.guard_check();
        probe(self, probe::CHECKED);
        let dt_s = self.profile.dt_s();
        // Intake: the FOG links into the per-FOG sample queues.
        self.fog_intake.receive(&mut links.fog, &mut self.rx_scratch.0, &mut self.telemetry.counters);
        probe(self, probe::RECEIVED);
        let mut acc = Integrated::NONE;
        // Bounded: at most one pass per queued sample.
        for _ in 0..FOG_QUEUE {
            let Some(target) = self.fog_intake.next_sample(&mut self.telemetry.counters) else { break };
            // Attitude: samples lost on every link are turned through on the last increment.
            self.bridge_lost(dt_s, &mut on_increment);
            probe(self, probe::SAMPLE_DUE);
            // FOG channels: intake, channel checks, thermal tracking, compensation.
            let mut sample = self.take_sample(target, dt_s);
            let time_us = self.fog_intake.time_us(self.profile.dt_us);
            // Star-tracker aid: the mounting check (from power-on) sees every sample.
            self.mount_check_sample(&sample.dtheta, sample.used, time_us);
            // Parity: may drop a spike or an isolated FOG.
            acc.parity_rad = self.check_parity(&mut sample, time_us);
            probe(self, probe::SAMPLE_CHECKED);
            // Combination, then attitude on the gyros corrected by the drift estimate.
            let body = self.combine(&sample, &mut acc);
            self.propagate(&body, time_us, dt_s, &mut acc);
            probe(self, probe::PROPAGATED);
            on_increment(time_us, &body);
            self.fog_intake.integrated();
            if self.fog_intake.bridged() {
                // A bridged sample (no FOG data): one per step.
                break;
            }
        }
        if acc.integrated == 0 {
            self.nothing_integrated(dt_s, &mut acc);
        } else if let Some(taken_at) = self.resumed_at.get() {
            self.confirm_resume(taken_at);
        }
        probe(self, probe::INTEGRATED);
        let now_us = self.fog_intake.time_us(self.profile.dt_us);
        // Star-tracker aid: the frames due by now.
        let st = match links.star.link() {
            Some(star) if self.profile.star_tracker.get() => self.observe_star(star, now_us),
            _ => 0,
        };
        probe(self, probe::OBSERVED);
        // Λ and Δω as sealed ([`twin`]): the frame carries no flip made in the step.
        self.twin_check_rare();
        // Telemetry: the output, its status bits assembled from each stage's.
        let out = self.assemble_output(now_us, st, &acc, dt_s);
        probe(self, probe::ASSEMBLED);
        self.last_output = out;
        // Paged by the sample clock (not the frame counter), so a replay of the same
        // data pages the same counters in the same frames.
        let page_id = (self.fog_intake.index() as u32 % u32::from(page::COUNT)) as u8;
        let page_value = self.page_value(page_id);
        self.telemetry.emit(&mut links.out, &out, page_id, page_value);
        let o = &self.last_output;
        let status = StatusBits { flags: o.flags, st_status: o.st_status, fdi: o.fdi };
        self.events.on_status(status, o.time_us, &self.fog_map);
        probe(self, probe::SENT);
        self.guard_seal();
        out
    }
}

/// The numbered points of a step at which [`FlightCore::step_probed`] calls its probe, in
/// the order a step reaches them (the per-sample ones once a sample, none without one).
pub mod probe {
    /// The guard has checked the state (start of the step).
    pub const CHECKED: u8 = 0;
    /// The FOG links are read.
    pub const RECEIVED: u8 = 1;
    /// A sample is due (lost samples bridged).
    pub const SAMPLE_DUE: u8 = 2;
    /// A sample is checked (channels, parity).
    pub const SAMPLE_CHECKED: u8 = 3;
    /// A sample is combined and integrated.
    pub const PROPAGATED: u8 = 4;
    /// Every due sample is integrated.
    pub const INTEGRATED: u8 = 5;
    /// The star-tracker frames due are applied.
    pub const OBSERVED: u8 = 6;
    /// The output frame is assembled.
    pub const ASSEMBLED: u8 = 7;
    /// The output frame is sent, the events noted (just before the guard's seal).
    pub const SENT: u8 = 8;
    /// Points.
    pub const COUNT: u8 = 9;
}
