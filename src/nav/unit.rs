//! The launch-vehicle navigation stage with its links: accelerometer frames in (one
//! multi-drop link carrying the three accelerometers, told apart by `accel_id`), GNSS
//! fix frames in (their own link), navigation output frames out.
//!
//! The stage's work is split in two, so the heavy filter arithmetic never sits between
//! a sample and its output frame:
//!
//! - [`NavUnit::step`], once per integrated FOG sample with the body angle increment of
//!   that sample (the FOG compensation and combination are the flight step's,
//!   [`crate::flight`]; the firmware calls it from the hook of
//!   [`crate::flight::FlightCore::step_with`]); per call it:
//!   1. drains the accelerometer link into per-accelerometer queues and takes one sample
//!      of each: the one whose counter the unit time names (the last step's counter plus
//!      the steps since, by the flight core's sample clock; the oldest when the last
//!      step's time is unsealed), older frames dropped as stale, newer ones left for
//!      their steps; a missing or faulty one holds the previous compensated increment
//!      for the step and raises [`flags::ACCEL_FAULT`];
//!   2. compensates the three increments ([`crate::calib::accel::AccelCompensator`]);
//!   3. runs the strapdown step ([`AidedNav::step_deferred`]: attitude, velocity,
//!      position; no covariance work);
//!   4. drains the GNSS link; the newest valid fix, if any, is held for the filter work
//!      (its time tag is not used: a fix is applied as of the step it arrives in, so the
//!      link latency is not compensated);
//!   5. emits one [`NavOutputFrame`].
//! - [`NavUnit::filter_work`], once per flight step after the step's output frames: the
//!   held fix's update ([`AidedNav::gnss_update`], ~67,000 instructions on the
//!   Cortex-M7, which first propagates the covariance), else the covariance propagation
//!   when due ([`AidedNav::propagate`], every 80 steps, ~54,000). A fix used here shows
//!   as [`flags::GNSS_UPDATED`] in the next output frame (whose state includes it).
//!
//! Both run to completion in the same 1.25 ms period (the firmware counts an overrun
//! when they do not, `src/bin/ssis-fw-lv`); the split only keeps the filter out of the
//! sample-to-output latency. The navigation state is the same as with the covariance
//! work done inside the step: the filter reads the state as of the last step either way.
//!
//! The accelerometer samples are taken in step with the FOG samples: an accelerometer
//! frame is taken for the step whose time its counter names, so a frame left in a link
//! over a gap or a reset is never taken for a later step (the state and its time tag
//! stay one).

use nalgebra::Vector3;

use super::gnss::{AidedNav, GnssConfig, GnssError, GnssFix};
use super::{NavError, NavState};
use crate::calib::accel::{AccelCompensator, N_ACCEL};
use crate::frames::accel::{AccelFrame, AccelSlot};
use crate::frames::decoder::StreamDecoder;
use crate::frames::gnss::GnssFrame;
use crate::frames::navout::{flags, NavOutputFrame};
use crate::frames::Frame;
use crate::link::{drain, write_frame, RxLink, TxLink};
use crate::state::{Flag, Maybe, Ring};
use crate::state_map::{state_struct, StateField};

/// Accelerometer samples a queue holds ahead of the step.
pub const ACCEL_QUEUE: usize = 8;
/// Bytes read from the accelerometer link per step at most (four frames per sensor).
pub const MAX_ACCEL_BYTES_PER_STEP: usize = 4 * N_ACCEL * AccelFrame::LEN;
/// Bytes read from the GNSS link per step at most (two frames).
pub const MAX_GNSS_BYTES_PER_STEP: usize = 2 * GnssFrame::LEN;
/// No fix used for longer than this: [`flags::GNSS_OUTAGE`], µs.
pub const GNSS_OUTAGE_US: u64 = 2_000_000;

/// The links of the navigation stage.
pub struct NavLinks<A, G, O> {
    /// The three accelerometers (one multi-drop link).
    pub accel: A,
    /// The GNSS receiver.
    pub gnss: G,
    /// Navigation output.
    pub out: O,
}

/// Counters of the stage: declared with the unit's in [`crate::telemetry::counters`].
pub use crate::telemetry::counters::{NavCounter, NavCounters};

/// What one step produced.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NavStepOutput {
    /// Flag bits ([`flags`]).
    pub flags: u8,
    /// State after the step.
    pub state: NavState,
}

/// Steps over which the running means of the increments ([`NavUnit::step`]) average:
/// 256 × 1.25 ms = 0.32 s, many periods of the airframe's vibration (11–47 Hz, left in
/// the mean at 2–5 % of its amplitude), short beside the thrust's and the pitch
/// program's changes, so a reset's bridge ([`super::snapshot`]) extrapolates the
/// motion, not one phase of a vibration.
pub const MEAN_STEPS: f64 = 256.0;

/// Steps summed into one block of the bridge's window ([`NavUnit::step`]; the bridge's
/// fit, [`super::snapshot`]): 10 ms.
pub const BLOCK_STEPS: u32 = 8;
/// Blocks in the bridge's window: 48 × 8 steps = 0.48 s, five periods of the airframe's
/// slowest vibration (11 Hz), short beside the roll and pitch programs' changes.
pub const WINDOW_BLOCKS: usize = 48;

/// The three accelerometers' sample queues (an array of the state needs `Pod`
/// elements, which a ring is not).
#[derive(Clone, Copy, bytemuck::AnyBitPattern)]
struct AccelQueues {
    x: Ring<AccelSlot, ACCEL_QUEUE>,
    y: Ring<AccelSlot, ACCEL_QUEUE>,
    z: Ring<AccelSlot, ACCEL_QUEUE>,
}

impl AccelQueues {
    /// Accelerometer `i`'s queue, if `i < 3`.
    #[inline(always)]
    fn get_mut(&mut self, i: usize) -> Option<&mut Ring<AccelSlot, ACCEL_QUEUE>> {
        match i {
            0 => Some(&mut self.x),
            1 => Some(&mut self.y),
            2 => Some(&mut self.z),
            _ => None,
        }
    }

    /// The three in order, mutable.
    #[inline(always)]
    fn iter_mut(&mut self) -> core::array::IntoIter<&mut Ring<AccelSlot, ACCEL_QUEUE>, N_ACCEL> {
        [&mut self.x, &mut self.y, &mut self.z].into_iter()
    }
}

/// A fix held for the filter work, with the unit time of its step, µs.
#[derive(Debug, Clone, Copy, PartialEq, bytemuck::AnyBitPattern)]
struct PendingFix {
    fix: GnssFix,
    t_us: u64,
}

state_struct! {
    /// The navigation stage. Every bit pattern of it is a value (`crate::state`: the
    /// derive below and the declaration's proof); [`NavUnit::state_map`] names its fields
    /// for the upset campaigns. Declared once ([`crate::state_map::state_struct!`]): a
    /// field's `reset(Keep)` (or `reset(Part)`: the fields the stage inside keeps) puts
    /// it in the reset snapshot's record ([`NavKept`], [`super::snapshot`]).
    #[derive(Clone, Copy, bytemuck::AnyBitPattern)]
    pub struct NavUnit {
        pub(super) nav: AidedNav = AidedNav::new(state, dt_s, cfg)?, map(AidedNav::STATE_MAP), reset(Part);
        comp: AccelCompensator = comp;
        dt_s: f64 = dt_s;
        accel_dec: StreamDecoder<AccelFrame, 32> = StreamDecoder::new();
        accel_q: AccelQueues = AccelQueues { x: Ring::new(), y: Ring::new(), z: Ring::new() };
        gnss_dec: StreamDecoder<GnssFrame, 64> = StreamDecoder::new();
        /// The last compensated velocity increment (held over a missing sample), m/s.
        pub(super) last_dv_m_s: Vector3<f64> = Vector3::zeros(), reset(Keep);
        last_fix_us: Maybe<u64> = Maybe::none();
        /// The newest valid fix not yet used.
        pending_fix: Maybe<PendingFix> = Maybe::none();
        /// A fix has been applied since the last output frame.
        updated_since_output: Flag = Flag::CLEAR;
        rx_scratch: [u8; 64] = [0; 64];
        out_buf: [u8; NavOutputFrame::LEN] = [0; NavOutputFrame::LEN];
        /// The output frame counter (it goes on over a reset, past the lost samples).
        pub(super) out_counter: u16 = 0, reset(Keep);
        counters: NavCounters = NavCounters::default();
        /// The accelerometer sample counter of the last step (the first accelerometer's
        /// frame taken, else the one before plus one; `None` until a frame is taken). The
        /// snapshot's header carries it: a resume bridges from it ([`NavUnit::resume`]).
        pub(super) accel_counter: Maybe<u16> = Maybe::none();
        /// Running mean of the body angle increment per step ([`MEAN_STEPS`]), rad.
        pub(super) mean_dtheta_rad: Vector3<f64> = Vector3::zeros(), reset(Keep);
        /// Running mean of the compensated velocity increment per step, m/s.
        pub(super) mean_dv_m_s: Vector3<f64> = Vector3::zeros(), reset(Keep);
        /// Running mean of |α − ᾱ|², rad² (the spread a bridge does not know).
        pub(super) spread_dtheta_rad2: f64 = 0.0, reset(Keep);
        /// Running mean of |υ − ῡ|², (m/s)².
        pub(super) spread_dv_m2_s2: f64 = 0.0, reset(Keep);
        /// The window's guard: the XOR of the bit patterns of every block of the ring
        /// (each folded to 32 bits, [`fold`]) and of the ring's next index, kept as
        /// each block is written (from its own value, never recomputed from the ring).
        /// A bit of the ring, its index or the guard flipped after the write (in RAM,
        /// before a record seals it) leaves them disagreeing, and the window backs no
        /// attitude ([`super::snapshot`]). Single flips only: the same bit flipped in
        /// two 32-bit words of the ring (adjacent words among them) cancels in the fold.
        pub(super) window_xor: u32 = 0, reset(Keep);
        /// The bridge's window ([`super::snapshot`]): the body angle increments summed
        /// over blocks of [`BLOCK_STEPS`] steps, a ring of [`WINDOW_BLOCKS`], rad.
        pub(super) blocks_rad: [[f64; 3]; WINDOW_BLOCKS] = [[0.0; 3]; WINDOW_BLOCKS], reset(Keep);
        /// The block being summed, rad.
        pub(super) block_rad: [f64; 3] = [0.0; 3], reset(Keep);
        /// Steps summed into it.
        pub(super) block_steps: u32 = 0, reset(Keep);
        /// The ring's oldest block (the next one written).
        pub(super) block_next: u32 = 0, reset(Keep);
        /// Blocks of measured increments in the ring (up to [`WINDOW_BLOCKS`]; none after
        /// a bridge: the window restarts on measured increments).
        pub(super) blocks_filled: u32 = 0, reset(Keep);
        /// The attitude is not confirmed: a resume's bridge could not back it (the
        /// window not full, the gap or the fit's residual too large, [`super::snapshot`]).
        /// Every output frame carries [`flags::ATTITUDE_UNCONFIRMED`] until a pad
        /// initialisation builds the unit again; kept over a further reset.
        pub(super) att_unconfirmed: Flag = Flag::CLEAR, reset(Keep);
        /// Resumed from a snapshot whose last accelerometer sample had this counter; the
        /// samples since are bridged at the first step that takes a frame.
        pub(super) resume_from: Maybe<u16> = Maybe::none();
        /// The unit time of the resumed snapshot's last step, µs (its record's): the
        /// steps since it tell the counter of the sample the resume bridges to.
        pub(super) resume_t_us: u64 = 0;
        /// Steps waited since the resume for an accelerometer frame.
        pub(super) resume_wait: u32 = 0;
        /// What the last resume bridged.
        pub(super) bridged: Maybe<BridgeReport> = Maybe::none();
        /// The unit time of the last step's increment, µs: an increment whose time lies
        /// more than one step after it spans samples the flight core bridged
        /// ([`NavUnit::step`]). Sealed by its complement `last_t_inv_us`
        /// (both zero until the first step, and after a reset: unsealed, no span).
        pub(super) last_t_us: u64 = 0;
        /// `!last_t_us` while it holds a time: a flipped bit of either unseals it, and the
        /// span falls back to the accelerometer counter's gap (`NavUnit::steps_by_time`).
        pub(super) last_t_inv_us: u64 = 0;
        /// The navigation is lost (a snapshot refused after a reset, or too old at its
        /// first sample): the state is held and flagged [`flags::NAV_FAULT`] until a pad
        /// initialisation builds the unit again ([`super::snapshot`]).
        pub(super) lost: Flag = Flag::CLEAR;
    }
    snapshot {
        /// The fields of the stage a reset snapshot carries ([`super::snapshot`]), in
        /// declaration order down to the filter and the strapdown.
        record: NavKept
    }
    constructor
    /// A stage starting from `state` (pad alignment) with step `dt_s`.
    pub fn new(state: NavState, dt_s: f64, comp: AccelCompensator, cfg: GnssConfig) -> Result<Self, NavError> => Ok {}
}

/// Takes the sample with counter `expected` from an accelerometer's queue (any, the
/// oldest, when `None`): older frames are dropped as stale (counted in `stale`), a newer
/// one is left queued for its own step.
#[inline(always)]
fn take_sample(q: &mut Ring<AccelSlot, ACCEL_QUEUE>, expected: Option<u16>, stale: &mut u32) -> Option<AccelSlot> {
    // Bounded by the queue length.
    for _ in 0..ACCEL_QUEUE {
        let f = q.pop_front()?;
        let Some(e) = expected else { return Some(f) };
        let age = e.wrapping_sub(AccelFrame::from(f).counter);
        if age == 0 {
            return Some(f);
        }
        if age >= 0x8000 {
            // Room is certain: it was just taken out.
            let _ = q.push_front(f);
            return None;
        }
        *stale = stale.saturating_add(1);
    }
    None
}

/// What a resume's bridge over a reset did ([`super::snapshot`]).
#[derive(Debug, Clone, Copy, PartialEq, bytemuck::AnyBitPattern)]
pub struct BridgeReport {
    /// Samples lost over the reset and bridged.
    pub steps: u32,
    /// The bridge's 1σ position error growth it added to the covariance (3-D), m.
    pub sigma_pos_m: f64,
    /// The bridge's 1σ velocity error growth (3-D), m/s.
    pub sigma_vel_m_s: f64,
    /// The bridge's stated attitude error (3-D), rad: what its fit over the window
    /// cannot know ([`super::snapshot`]); infinite when it had no fit.
    pub att_bound_rad: f64,
}

/// Most samples a resume bridges (0.5 s at 1.25 ms): the snapshot period (80 steps in
/// the firmware) plus a reset and boot, with margin; older, the snapshot is stale.
pub const MAX_BRIDGE_STEPS: u16 = 400;

impl AidedNav {
    /// Adds a bridge's error growth over `n` steps to the covariance: the velocity
    /// increments' per-step spread `s_dv_m2_s2` (3-D mean square) as a random walk of the
    /// velocity (and so of the position), and the attitude's stated bound
    /// `att_bound_rad` (module documentation).
    #[inline(never)]
    pub(super) fn add_bridge_growth(&mut self, n: u16, att_bound_rad: f64, s_dv_m2_s2: f64) -> BridgeReport {
        let steps = u32::from(n);
        let n = f64::from(n);
        let dt = self.nav.dt_s();
        // The attitude's stated bound as a 1σ per axis (bound²/3 each); none when the
        // bridge had no fit (the frames flag the attitude unconfirmed instead).
        let qa = if att_bound_rad.is_finite() { att_bound_rad * att_bound_rad / 3.0 } else { 0.0 };
        let qv = s_dv_m2_s2 / 3.0;
        for i in 0..3 {
            let add = |p: &mut Self, r: usize, c: usize, v: f64| {
                if let Some(x) = p.p.get_mut((r, c)) {
                    *x += v;
                }
            };
            add(self, i, i, qa);
            add(self, 3 + i, 3 + i, n * qv);
            add(self, 6 + i, 6 + i, n * n * n * dt * dt * qv / 3.0);
            add(self, 3 + i, 6 + i, n * n * dt * qv / 2.0);
            add(self, 6 + i, 3 + i, n * n * dt * qv / 2.0);
        }
        BridgeReport {
            steps,
            sigma_pos_m: crate::math::sqrt(n * n * n * dt * dt * s_dv_m2_s2 / 3.0),
            sigma_vel_m_s: crate::math::sqrt(n * s_dv_m2_s2),
            att_bound_rad,
        }
    }
}

impl NavUnit {
    /// Where each field of the unit lies in the value, down to the filter and the
    /// strapdown: the upset campaign names the field a flipped bit belongs to
    /// ([`crate::state_map`]). Nothing in a step reads it.
    pub fn state_map() -> &'static [StateField] {
        Self::STATE_MAP
    }

    /// Whether the navigation is lost (a refused or stale snapshot after a reset): the
    /// state is held and every output frame carries [`flags::NAV_FAULT`] until the unit
    /// is built again from a pad initialisation block.
    pub fn lost(&self) -> bool {
        self.lost.get()
    }

    /// Whether a resume waits for its first accelerometer sample to bridge the reset.
    pub fn resume_pending(&self) -> bool {
        self.resume_from.is_some()
    }

    /// The accelerometer sample counter of the snapshot a pending resume bridges from.
    pub fn resumed_from(&self) -> Option<u16> {
        self.resume_from.get()
    }

    /// What the last resume bridged (the samples lost over the reset), if one did.
    pub fn bridged(&self) -> Option<BridgeReport> {
        self.bridged.get()
    }

    /// Counters.
    pub fn counters(&self) -> NavCounters {
        self.counters
    }

    /// The aided navigation (state, filter figures).
    pub fn nav(&self) -> &AidedNav {
        &self.nav
    }

    /// One step: `dtheta_body_rad` is the sample's body angle increment, `time_us` the
    /// unit time at its end.
    pub fn step<A: RxLink, G: RxLink, O: TxLink>(
        &mut self,
        dtheta_body_rad: &Vector3<f64>,
        time_us: u64,
        links: &mut NavLinks<A, G, O>,
    ) -> NavStepOutput {
        let mut fl = 0u8;
        // 1. Accelerometer frames.
        let (dec, queues) = (&mut self.accel_dec, &mut self.accel_q);
        let mut rejected = 0u32;
        let rep = drain(&mut links.accel, MAX_ACCEL_BYTES_PER_STEP, &mut self.rx_scratch, |bytes| {
            dec.push_slice(bytes, |r| match r {
                Ok(f) => {
                    if let Some(q) = queues.get_mut(usize::from(f.accel_id)) {
                        q.push_back_overwrite(f.into());
                    }
                }
                Err(_) => rejected = rejected.saturating_add(1),
            })
        });
        self.counters.add(NavCounter::IoErrors, rep.io_errors);
        // The counter this step's sample carries by the unit time (the core's sample
        // clock): the last step's counter (after a resume, the snapshot's) plus the
        // steps since, when that time is sealed. A frame older is stale (queued before a
        // gap or a reset) and dropped, a newer one waits for its step.
        let last_counter = self.accel_counter.get();
        let resuming = self.resume_from.is_some();
        let by_time = self.steps_by_time(time_us);
        let base = if resuming { self.resume_from.get() } else { last_counter };
        let expected = base.zip(by_time).map(|(c, n)| c.wrapping_add(n.min(u64::from(u16::MAX)) as u16));
        let mut raw = [0.0; N_ACCEL];
        let mut temps = [0.0; N_ACCEL];
        let mut complete = true;
        let mut counter: Option<u16> = None;
        for ((q, r), t) in self.accel_q.iter_mut().zip(raw.iter_mut()).zip(temps.iter_mut()) {
            let f = take_sample(q, expected, &mut rejected).map(AccelFrame::from);
            if let (None, Some(f)) = (counter, f) {
                counter = Some(f.counter);
            }
            match f {
                Some(f) if !f.device_fault() => {
                    *r = f.dv_m_s();
                    *t = f.temperature_degc();
                }
                _ => complete = false,
            }
        }
        self.counters.add(NavCounter::AccelFramesRejected, rejected);
        // Samples the flight core bridged into this one increment (lost on every link):
        // by the time, or, the last time unsealed (a flipped bit), by the accelerometer
        // counter's gap (1 without a frame). Not at the step a resume bridges (its gap is
        // the snapshot's), nor at the first step.
        let spanned = match (resuming, by_time, counter.zip(last_counter)) {
            (true, _, _) => 1,
            (false, Some(n), _) => n,
            (false, None, Some((c, p))) => u64::from(c.wrapping_sub(p).max(1)),
            (false, None, None) => 1,
        };
        // A resume settles on a frame of its step only (the time and the counter agree).
        let navigating = self.settle_resume(counter);
        if self.resume_from.is_none() {
            self.accel_counter.set(counter.or(expected).or_else(|| last_counter.map(|c| c.wrapping_add(1))));
        }
        // 2. Compensation (or hold).
        let [x, y, z] = raw;
        let dv = if complete { self.comp.compensate(&Vector3::new(x, y, z), &temps, self.dt_s) } else { None };
        let dv = match dv {
            Some(v) => {
                self.last_dv_m_s = v;
                v
            }
            None => {
                fl |= flags::ACCEL_FAULT;
                self.counters.add(NavCounter::AccelStepsHeld, 1);
                self.last_dv_m_s
            }
        };
        // 3. Navigation (strapdown only; the covariance work is `filter_work`'s).
        // An increment spanning n > 1 samples (n − 1 lost, bridged by the core) is n
        // strapdown steps, the angle spread evenly, the lost ones on the mean velocity
        // increment ([`NavUnit::spanned_bridged`]); more than MAX_BRIDGE_STEPS: lost.
        let n = if spanned > 1 + u64::from(MAX_BRIDGE_STEPS) {
            self.lost = Flag::SET;
            0
        } else {
            spanned as u16
        };
        let each = if n > 1 { dtheta_body_rad / f64::from(n) } else { *dtheta_body_rad };
        let mean_dv = self.mean_dv_m_s;
        let mut stepped = navigating && n > 0;
        // Bounded: at most MAX_BRIDGE_STEPS + 1 strapdown steps.
        for m in 1..=n {
            if !stepped {
                break;
            }
            let v = if m < n { &mean_dv } else { &dv };
            if self.nav.step_deferred(&each, v).is_err() {
                self.counters.add(NavCounter::NavFaults, 1);
                stepped = false;
            }
        }
        if !stepped {
            fl |= flags::NAV_FAULT;
        } else if n > 1 {
            self.spanned_bridged(n - 1);
        } else {
            self.track_means(dtheta_body_rad, &dv);
            self.track_window(dtheta_body_rad);
        }
        if self.att_unconfirmed.get() {
            fl |= flags::ATTITUDE_UNCONFIRMED;
        }
        // 4. GNSS: hold the newest valid fix for the filter work.
        let mut newest: Option<GnssFix> = None;
        let gdec = &mut self.gnss_dec;
        let mut superseded = 0u32;
        let mut rejected = 0u32;
        let rep = drain(&mut links.gnss, MAX_GNSS_BYTES_PER_STEP, &mut self.rx_scratch, |bytes| {
            gdec.push_slice(bytes, |r| match r {
                Ok(f) => {
                    if let Some(fix) = f.fix() {
                        if newest.replace(fix).is_some() {
                            superseded += 1;
                        }
                    }
                }
                Err(_) => rejected = rejected.saturating_add(1),
            })
        });
        self.counters.add(NavCounter::IoErrors, rep.io_errors);
        self.counters.add(NavCounter::GnssFramesRejected, rejected);
        // A fix is held only for a state it is valid for (not while the state waits for
        // its bridge or is lost).
        if let Some(fix) = newest.filter(|_| navigating) {
            if self.pending_fix.take().is_some() {
                superseded += 1;
            }
            self.pending_fix = Maybe::some(PendingFix { fix, t_us: time_us });
        }
        self.counters.add(NavCounter::GnssFixesSuperseded, superseded);
        if self.updated_since_output.take() {
            fl |= flags::GNSS_UPDATED;
        }
        let outage = match self.last_fix_us.get() {
            Some(t) => time_us.saturating_sub(t) > GNSS_OUTAGE_US,
            None => true,
        };
        if outage {
            fl |= flags::GNSS_OUTAGE;
        }
        // 5. Output.
        let state = *self.nav.state();
        let frame = NavOutputFrame::from_physical(
            fl,
            self.out_counter,
            time_us,
            &state,
            self.nav.sigma_pos_vel(),
            self.nav.counts(),
        );
        self.out_counter = self.out_counter.wrapping_add(1);
        let ok = frame.encode_into(&mut self.out_buf).is_ok() && write_frame(&mut links.out, &self.out_buf);
        if !ok {
            self.counters.add(NavCounter::OutputDropped, 1);
        }
        NavStepOutput { flags: fl, state }
    }

    /// The heavy filter work, once per flight step after its output frames: the held
    /// fix's update (which propagates the covariance first), else the covariance
    /// propagation when [`AidedNav::propagation_due`]; at most one of each per call.
    pub fn filter_work(&mut self) -> FilterWork {
        if self.lost.get() || self.resume_from.is_some() {
            return FilterWork::None;
        }
        if let Some(PendingFix { fix, t_us }) = self.pending_fix.take() {
            return match self.nav.gnss_update(&fix) {
                Ok(()) => {
                    self.updated_since_output = Flag::SET;
                    self.last_fix_us = Maybe::some(t_us);
                    FilterWork::Updated
                }
                Err(e) => FilterWork::Refused(e),
            };
        }
        if self.nav.propagation_due() {
            self.nav.propagate();
            return FilterWork::Propagated;
        }
        FilterWork::None
    }
}

impl NavUnit {
    /// The running means and spreads of the increments ([`MEAN_STEPS`]).
    #[inline(always)]
    fn track_means(&mut self, dtheta_rad: &Vector3<f64>, dv_m_s: &Vector3<f64>) {
        const W: f64 = 1.0 / MEAN_STEPS;
        let (eth, ev) = (dtheta_rad - self.mean_dtheta_rad, dv_m_s - self.mean_dv_m_s);
        self.mean_dtheta_rad += eth * W;
        self.mean_dv_m_s += ev * W;
        self.spread_dtheta_rad2 += (eth.norm_squared() - self.spread_dtheta_rad2) * W;
        self.spread_dv_m2_s2 += (ev.norm_squared() - self.spread_dv_m2_s2) * W;
    }

    /// The bridge's window: `dtheta_rad` summed into the current block, a full block
    /// into the ring ([`BLOCK_STEPS`], [`WINDOW_BLOCKS`]).
    #[inline(always)]
    pub(super) fn track_window(&mut self, dtheta_rad: &Vector3<f64>) {
        for (b, d) in self.block_rad.iter_mut().zip(dtheta_rad.iter()) {
            *b += d;
        }
        self.block_steps = self.block_steps.saturating_add(1);
        if self.block_steps >= BLOCK_STEPS {
            let i = self.block_next as usize % WINDOW_BLOCKS;
            let next = ((i + 1) % WINDOW_BLOCKS) as u32;
            // The guard, from its own value: the old block and index out, the new in.
            let mut x = self.window_xor ^ self.block_next ^ next;
            if let Some(slot) = self.blocks_rad.get_mut(i) {
                for (old, new) in slot.iter().zip(self.block_rad.iter()) {
                    x ^= fold(old.to_bits() ^ new.to_bits());
                }
                *slot = self.block_rad;
            }
            self.window_xor = x;
            self.block_rad = [0.0; 3];
            self.block_steps = 0;
            self.block_next = next;
            self.blocks_filled = self.blocks_filled.saturating_add(1).min(WINDOW_BLOCKS as u32);
        }
    }

    /// Steps of the sample clock from the last step's time to `time_us` (1 normally;
    /// more when the flight core bridged samples lost on every link into this increment,
    /// [`crate::flight::FlightCore::step_with`]); after a resume, from the snapshot's
    /// time (its record's, sealed with its state). `None` when the last time is unsealed
    /// (it and its complement disagree: a flipped bit; or no step yet). Records this
    /// step's time, sealed.
    #[inline(always)]
    fn steps_by_time(&mut self, time_us: u64) -> Option<u64> {
        let (t, sealed) = (self.last_t_us, self.last_t_inv_us == !self.last_t_us && self.last_t_us != 0);
        self.last_t_us = time_us;
        self.last_t_inv_us = !time_us;
        let dt_us = u64::from((self.dt_s * 1e6) as u32);
        if dt_us == 0 {
            return None;
        }
        if self.resume_from.is_some() {
            // Modulo 2^16, as the counters: the sample clock's index and the FOG counter
            // agree modulo 2^16, also after a cold start of the core (its snapshot
            // refused), whose clock starts again at the FOG counter.
            let (now, then) = (time_us / dt_us, self.resume_t_us / dt_us);
            return Some(u64::from((now as u16).wrapping_sub(then as u16)));
        }
        sealed.then(|| time_us.saturating_sub(t).saturating_add(dt_us / 2) / dt_us)
    }

    /// After a step whose increment spanned `lost` + 1 samples ([`NavUnit::step`]): the
    /// lost steps' error growth into the covariance, as a resume's bridge's
    /// ([`super::snapshot`]); the core's held increment backs no attitude, so it is
    /// flagged unconfirmed, as after a resume's bridge without a fit; the window starts
    /// again on measured increments; the frame counter goes on past the lost samples.
    #[inline(never)]
    fn spanned_bridged(&mut self, lost: u16) {
        let _ = self.nav.add_bridge_growth(lost, f64::INFINITY, self.spread_dv_m2_s2);
        self.att_unconfirmed = Flag::SET;
        self.blocks_filled = 0;
        self.block_steps = 0;
        self.block_rad = [0.0; 3];
        self.out_counter = self.out_counter.wrapping_add(lost);
    }

    /// Whether the attitude is unconfirmed since a resume ([`flags::ATTITUDE_UNCONFIRMED`]).
    pub fn attitude_unconfirmed(&self) -> bool {
        self.att_unconfirmed.get()
    }
}

/// What one [`NavUnit::filter_work`] did.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub enum FilterWork {
    /// Nothing was due.
    None,
    /// The covariance was propagated.
    Propagated,
    /// A fix was applied (after the propagation it needs).
    Updated,
    /// A fix was refused (gate, bad values, singular innovation covariance); the
    /// covariance was propagated first unless the fix itself was bad.
    Refused(GnssError),
}

/// A 64-bit pattern folded to 32 bits (its halves XORed): a single bit flipped in it
/// flips one bit of the fold (the window's guard, `NavUnit::window_xor`).
#[inline(always)]
pub(super) fn fold(bits: u64) -> u32 {
    (bits ^ (bits >> 32)) as u32
}
