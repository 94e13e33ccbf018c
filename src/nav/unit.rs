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
//!      position; no covariance work); 2 and 3 computed twice and compared (below);
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
//!
//! **Protection against upsets.** What a step computes is kept only when it is computed
//! twice alike, and the state it keeps is checked before the next step uses it:
//!
//! | what | how | when | on a mismatch |
//! |---|---|---|---|
//! | the step's navigation part: compensation of the three increments (or the held one), the strapdown step(s), the running means and spreads, the window's block sum | computed twice (`run`) from the same state, saved first into the guard's shadow; the results (52 words: [`NavUnit::TWIN_WORDS`]) and outcomes compared bit for bit | every step | a third run from the saved state decides (the result it agrees with is kept; counted, `nav_twin_mismatches`); no two alike: the step refused, the state as before the step, [`flags::NAV_FAULT`], counted (`nav_faults`) |
//! | the state those runs advance: the strapdown's q, v, r, increment history, gravity term, step count and setup (Δt, corrections, Earth rotation), the filter's biases, pending sum and steps, the unit's held increment, means, spreads, block and its steps | a shadow copy and checksum ([`crate::shadow`], as the flight core's guard, `crate::flight::guard`), sealed after the step's navigation part and after the filter work | checked at the start of every step, and before the filter work when it is due | restored bit for bit from the shadow (counted, `nav_state_restored`); neither copy good: the navigation lost |
//! | the covariance P (225 words) | its own shadow, sealed when the filter work or a bridge changed it | as the state | as the state |
//! | the bridge's window (48 blocks) | `window_xor`: the XOR of the ring's half-words rotated by their position ([`window_word`]) | when a resume's bridge fits the window ([`super::snapshot`]) | no fit: the attitude flagged unconfirmed |
//!
//! A register corrupted inside one run (an interrupt's stack frame upset, a spilled
//! value flipped) changes that run's result only: outvoted. A bit flipped in the state in
//! RAM between two steps is restored before it is flown. The links' I/O (draining the
//! accelerometer and GNSS links, writing the output frame) is done once: the frame is
//! built from the state after its seal. Not covered: a bit flipped in a value both runs
//! read (the increments as the flight core hands them, the accelerometer frames taken
//! from the queues, the accelerometer compensator's table, the filter tuning), and a
//! register corrupted between the seal and the frame's encoding (the frame wrong, the
//! state not: the next step's check finds the state intact). Cost: the navigation part
//! runs twice, the 52 words are walked six times and the covariance once a step (about
//! 10,000 instructions more a step in QEMU, `docs/LAUNCH-VEHICLE.md`); 2.2 KiB of RAM for
//! the shadows and 1.3 KiB of stack for the runs' results.

use nalgebra::Vector3;

use super::gnss::{AidedNav, GnssConfig, GnssError, GnssFix, N_X};
use super::{NavError, NavState};
use crate::calib::accel::{AccelCompensator, N_ACCEL};
use crate::frames::accel::{AccelFrame, AccelSlot};
use crate::frames::decoder::StreamDecoder;
use crate::frames::gnss::GnssFrame;
use crate::frames::navout::{flags, NavOutputFrame};
use crate::frames::Frame;
use crate::link::{drain, write_frame, RxLink, TxLink};
use crate::shadow::{Check, CheckWord, Pass, Shadow, Sum, Visit};
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
        /// The window's guard: the XOR of the ring's 32-bit half-words, half-word j
        /// (the low then the high half of each f64, in the ring's storage order)
        /// rotated left by (j + 1) mod 32 ([`window_word`]), and of the ring's next index
        /// rotated by 16 ([`window_index`]), kept as each block is written (from its own
        /// value, never recomputed from the ring). A bit of the ring, its index or the
        /// guard flipped after the write (in RAM, before a record seals it) leaves them
        /// disagreeing, and the window backs no attitude ([`super::snapshot`]). Two
        /// flips of the ring cancel only when they land on the same bit of the guard:
        /// bit c of half-word j and bit c' of half-word j' with c + j ≡ c' + j'
        /// (mod 32); never two adjacent bits (of a half-word, or bits 31 and 32 of an
        /// f64: 30 apart), nor the same bit of two adjacent 32-bit words (1 apart) or of
        /// two adjacent f64 (2 apart).
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
        /// The navigation state's guard between steps (module documentation): shadows
        /// of the strapdown state, the filter's biases and pending sum, the unit's
        /// running means and block, and of the covariance.
        pub(super) guard: NavGuard = NavGuard::default();
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
        self.step_inner(dtheta_body_rad, time_us, links, TwinUpset::NONE)
    }

    /// [`NavUnit::step`] with a bit of the step's duplicated part flipped in the runs
    /// `upset` names (tests: a register corrupted in one computation). Not in flight
    /// builds (the `test-hooks` feature).
    #[cfg(feature = "test-hooks")]
    pub fn step_upset<A: RxLink, G: RxLink, O: TxLink>(
        &mut self,
        dtheta_body_rad: &Vector3<f64>,
        time_us: u64,
        links: &mut NavLinks<A, G, O>,
        upset: TwinUpset,
    ) -> NavStepOutput {
        self.step_inner(dtheta_body_rad, time_us, links, upset)
    }

    #[inline(always)]
    fn step_inner<A: RxLink, G: RxLink, O: TxLink>(
        &mut self,
        dtheta_body_rad: &Vector3<f64>,
        time_us: u64,
        links: &mut NavLinks<A, G, O>,
        upset: TwinUpset,
    ) -> NavStepOutput {
        let mut fl = 0u8;
        // 0. The state as the last step (or filter work) sealed it, restored if a bit of
        // it flipped since.
        let was_sealed = self.guard_check();
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
        // 2–3. Compensation (or hold) and navigation (strapdown only; the covariance
        // work is `filter_work`'s), computed twice from the same state and compared
        // (module documentation). An increment spanning n > 1 samples (n − 1 lost,
        // bridged by the core) is n strapdown steps, the angle spread evenly, the lost
        // ones on the mean velocity increment ([`NavUnit::spanned_bridged`]); more than
        // MAX_BRIDGE_STEPS: lost.
        let n = if spanned > 1 + u64::from(MAX_BRIDGE_STEPS) {
            self.lost = Flag::SET;
            0
        } else {
            spanned as u16
        };
        let input = TwinInput { raw, temps, complete, dtheta_rad: *dtheta_body_rad, n, navigating };
        let (verdict, mismatch) = self.twin_step(&input, upset);
        if mismatch {
            self.counters.add(NavCounter::TwinMismatches, 1);
        }
        let stepped = match verdict {
            Some(run) => {
                if run & RUN_HELD != 0 {
                    fl |= flags::ACCEL_FAULT;
                    self.counters.add(NavCounter::AccelStepsHeld, 1);
                }
                if run & RUN_REFUSED != 0 {
                    self.counters.add(NavCounter::NavFaults, 1);
                }
                run & RUN_STEPPED != 0
            }
            None => {
                // No two computations agree: the step refused, the state held.
                if !complete {
                    fl |= flags::ACCEL_FAULT;
                }
                self.counters.add(NavCounter::NavFaults, 1);
                false
            }
        };
        if !stepped {
            fl |= flags::NAV_FAULT;
        } else if n > 1 {
            self.spanned_bridged(n - 1);
        } else {
            self.flush_block();
        }
        // Sealed before the output reads it: the covariance too when a bridge (the
        // resume's or the span's) changed it, or nothing was sealed.
        self.guard_seal(!was_sealed || (stepped && n > 1) || (resuming && navigating));
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
        // The state and covariance the work reads, checked first when it is due (a bit
        // flipped since the step's seal is not sealed into the filter's result).
        if self.pending_fix.is_some() || self.nav.propagation_due() {
            self.guard_check();
        }
        let work = self.filter_work_unsealed();
        if work != FilterWork::None {
            // The state (the fix's feedback, the pending sum) and the covariance changed.
            self.guard_seal(true);
        }
        work
    }

    #[inline(always)]
    fn filter_work_unsealed(&mut self) -> FilterWork {
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
    /// A full block ([`BLOCK_STEPS`] steps summed) into the ring, its guard updated.
    #[inline(always)]
    fn flush_block(&mut self) {
        if self.block_steps >= BLOCK_STEPS {
            let i = self.block_next as usize % WINDOW_BLOCKS;
            let next = ((i + 1) % WINDOW_BLOCKS) as u32;
            // The guard, from its own value: the old block and index out, the new in.
            let mut x = self.window_xor ^ window_index(self.block_next) ^ window_index(next);
            if let Some(slot) = self.blocks_rad.get_mut(i) {
                for ((old, new), a) in slot.iter().zip(self.block_rad.iter()).zip(0..) {
                    x ^= window_word(old.to_bits() ^ new.to_bits(), 3 * i + a);
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

/// Word `k` of the window's ring (block i, axis a: k = 3i + a, its bit pattern
/// `bits`) as the window's guard holds it: its low half-word (j = 2k) rotated left by
/// (j + 1) mod 32, its high one (j = 2k + 1) by (j + 1) mod 32, XORed
/// (`NavUnit::window_xor`).
#[inline(always)]
pub(super) fn window_word(bits: u64, k: usize) -> u32 {
    let j = (2 * k) as u32;
    (bits as u32).rotate_left((j + 1) % 32) ^ ((bits >> 32) as u32).rotate_left((j + 2) % 32)
}

/// The ring's next index as the window's guard holds it: rotated left by 16.
#[inline(always)]
pub(super) fn window_index(next: u32) -> u32 {
    next.rotate_left(16)
}

/// Words of the navigation state the guard keeps between steps ([`Twin::visit`]): the
/// strapdown's 27, the filter's 10 (biases, pending sum and steps) and the unit's 15
/// (held increment, running means and spreads, the block being summed and its steps).
const STATE_WORDS: usize = 52;
/// Words of the covariance.
const P_WORDS: usize = N_X * N_X;
/// [`NavGuard::sealed`]'s value once the shadows hold the state (a flipped bit reads as
/// not sealed: the state is saved again unchecked, at worst one check missed).
const SEALED: u32 = 0x5EA1_ED00;

/// The navigation state's guard between steps ([`NavUnit::step`], module documentation).
#[derive(Clone, Copy, Default, bytemuck::AnyBitPattern)]
pub(super) struct NavGuard {
    state: Shadow<STATE_WORDS>,
    p: Shadow<P_WORDS>,
    /// [`SEALED`] when both shadows hold the live values (not after a unit is built or
    /// resumed: its first step saves them unchecked).
    pub(super) sealed: u32,
}

/// The fields a step advances, borrowed from the unit (all but the guard's): the runs of
/// the step's duplicated part compute on them in place, and the guard walks them.
struct Live<'a> {
    nav: &'a mut AidedNav,
    last_dv_m_s: &'a mut Vector3<f64>,
    mean_dtheta_rad: &'a mut Vector3<f64>,
    mean_dv_m_s: &'a mut Vector3<f64>,
    spread_dtheta_rad2: &'a mut f64,
    spread_dv_m2_s2: &'a mut f64,
    block_rad: &'a mut [f64; 3],
    block_steps: &'a mut u32,
}

/// The words of the state a step advances, in a fixed order ([`STATE_WORDS`]; one
/// compiled walk: through a [`Pass`]).
#[inline(never)]
fn visit<V: Visit>(l: &mut Live<'_>, v: &mut V) {
    let a = &mut *l.nav;
    a.nav.visit(v);
    v.f64s(a.accel_bias_m_s2.as_mut_slice());
    v.f64s(a.gyro_bias_rad_s.as_mut_slice());
    v.f64s(a.sum_dv_e_m_s.as_mut_slice());
    v.u32(&mut a.pending_steps);
    v.f64s(l.last_dv_m_s.as_mut_slice());
    v.f64s(l.mean_dtheta_rad.as_mut_slice());
    v.f64s(l.mean_dv_m_s.as_mut_slice());
    v.f64(l.spread_dtheta_rad2);
    v.f64(l.spread_dv_m2_s2);
    v.f64s(l.block_rad);
    v.u32(l.block_steps);
}

/// Saves the state `l` into `sh` (one compiled copy for the seal and the runs).
#[inline(never)]
fn save_state(l: &mut Live<'_>, sh: &mut Shadow<STATE_WORDS>) {
    sh.save_pass(|p| visit(l, p));
}

/// Restores the state `l` from `sh`.
#[inline(never)]
fn restore_state(l: &mut Live<'_>, sh: &Shadow<STATE_WORDS>) {
    sh.restore_pass(|p| visit(l, p));
}

/// The checksum of the words `visit` walks.
#[inline(never)]
fn sum_of(visit: impl FnOnce(&mut Pass<'_>)) -> CheckWord {
    let mut pass = Pass::Sum(Sum::default());
    visit(&mut pass);
    match pass {
        Pass::Sum(s) => s.0,
        _ => CheckWord::ZERO,
    }
}

/// What a run of the step's duplicated part reads besides the state.
struct TwinInput {
    raw: [f64; N_ACCEL],
    temps: [f64; N_ACCEL],
    /// Every accelerometer's sample taken and sound.
    complete: bool,
    dtheta_rad: Vector3<f64>,
    /// Strapdown steps of the increment (0: none, the navigation lost).
    n: u16,
    navigating: bool,
}

/// A run's outcome bits: the previous increment held (no compensated one) ...
const RUN_HELD: u8 = 1;
/// ... a strapdown step refused ([`NavError`]) ...
const RUN_REFUSED: u8 = 2;
/// ... the state stepped.
const RUN_STEPPED: u8 = 4;

/// One run of the step's duplicated part on the state `l`: the compensation of the three
/// increments (or the previous one held), the `n` strapdown steps
/// ([`AidedNav::step_deferred`]'s arithmetic), and after a single step the running means
/// ([`MEAN_STEPS`]) and the window's block (the unit writes a full one into the ring
/// after the runs agree, `NavUnit::flush_block`). Its outcome bits ([`RUN_HELD`] ...).
#[inline(never)]
fn run(l: &mut Live<'_>, comp: &AccelCompensator, dt_s: f64, inp: &TwinInput) -> u8 {
    let mut out = 0;
    let [x, y, z] = inp.raw;
    let dv = if inp.complete { comp.compensate(&Vector3::new(x, y, z), &inp.temps, dt_s) } else { None };
    let dv = match dv {
        Some(v) => {
            *l.last_dv_m_s = v;
            v
        }
        None => {
            out |= RUN_HELD;
            *l.last_dv_m_s
        }
    };
    let (n, dtheta_rad) = (inp.n, &inp.dtheta_rad);
    let each = if n > 1 { dtheta_rad / f64::from(n) } else { *dtheta_rad };
    let mean_dv = *l.mean_dv_m_s;
    let mut stepped = inp.navigating && n > 0;
    let mut parts = l.nav.step_parts();
    // Bounded: at most MAX_BRIDGE_STEPS + 1 strapdown steps.
    for m in 1..=n {
        if !stepped {
            break;
        }
        let v = if m < n { &mean_dv } else { &dv };
        if parts.step(&each, v).is_err() {
            out |= RUN_REFUSED;
            stepped = false;
        }
    }
    if stepped {
        out |= RUN_STEPPED;
        if n <= 1 {
            const W: f64 = 1.0 / MEAN_STEPS;
            let (eth, ev) = (dtheta_rad - *l.mean_dtheta_rad, dv - *l.mean_dv_m_s);
            *l.mean_dtheta_rad += eth * W;
            *l.mean_dv_m_s += ev * W;
            *l.spread_dtheta_rad2 += (eth.norm_squared() - *l.spread_dtheta_rad2) * W;
            *l.spread_dv_m2_s2 += (ev.norm_squared() - *l.spread_dv_m2_s2) * W;
            for (b, d) in l.block_rad.iter_mut().zip(dtheta_rad.iter()) {
                *b += d;
            }
            *l.block_steps = l.block_steps.saturating_add(1);
        }
    }
    out
}

/// A bit flipped in runs of the step's duplicated part ([`NavUnit::step_upset`]: tests
/// of a register corrupted in one computation).
#[cfg(feature = "test-hooks")]
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct TwinUpset {
    /// The runs it hits: bit r for run r (0 and 1 the compared pair, 2 the deciding one).
    pub runs: u8,
    /// The word of the run's result ([`NavUnit::TWIN_WORDS`] of them, the guard's order).
    pub word: usize,
    /// The bit of that word flipped in run 0; run r flips bit (`bit` + r) mod 64 (two
    /// runs hit never agree).
    pub bit: u32,
}

/// No upset (flight builds have no other).
#[cfg(not(feature = "test-hooks"))]
#[derive(Clone, Copy)]
struct TwinUpset;

impl TwinUpset {
    /// No run hit.
    #[cfg(feature = "test-hooks")]
    pub const NONE: TwinUpset = TwinUpset { runs: 0, word: 0, bit: 0 };
    #[cfg(not(feature = "test-hooks"))]
    const NONE: TwinUpset = TwinUpset;

    /// The flip into run `r`'s result, if it hits that run.
    #[inline(always)]
    fn apply(self, r: usize, l: &mut Live<'_>) {
        #[cfg(feature = "test-hooks")]
        if self.runs & (1 << r) != 0 {
            visit(l, &mut crate::shadow::Flip::new(self.word, (self.bit + r as u32) % 64));
        }
        #[cfg(not(feature = "test-hooks"))]
        let _ = (self, r, l);
    }
}

impl NavUnit {
    /// Words of the state a step computes twice and the guard keeps between steps.
    pub const TWIN_WORDS: usize = STATE_WORDS;

    /// The state a step advances, borrowed ([`Live`]), and the guard.
    #[inline(always)]
    fn split(&mut self) -> (Live<'_>, &mut NavGuard) {
        let NavUnit {
            nav,
            last_dv_m_s,
            mean_dtheta_rad,
            mean_dv_m_s,
            spread_dtheta_rad2,
            spread_dv_m2_s2,
            block_rad,
            block_steps,
            guard,
            ..
        } = self;
        let l = Live {
            nav,
            last_dv_m_s,
            mean_dtheta_rad,
            mean_dv_m_s,
            spread_dtheta_rad2,
            spread_dv_m2_s2,
            block_rad,
            block_steps,
        };
        (l, guard)
    }

    /// The step's duplicated part ([`run`]) twice from the state as it is now (saved
    /// first into the guard's shadow, which each later run starts from), the results
    /// compared bit for bit (state and outcome); on a mismatch a third run decides: the
    /// state is the result it agrees with. The agreed outcome, `None` when no two runs
    /// agree (the state as it was); and whether the first two disagreed.
    #[inline(never)]
    fn twin_step(&mut self, inp: &TwinInput, upset: TwinUpset) -> (Option<u8>, bool) {
        let (comp, dt_s) = (self.comp, self.dt_s);
        let (mut l, guard) = self.split();
        let pre = &mut guard.state;
        save_state(&mut l, pre);
        let mut w = [Shadow::<STATE_WORDS>::default(); 3];
        let mut out = [0u8; 3];
        // Bounded: three runs at most; the third only when the first two disagree.
        for r in 0..3 {
            if r > 0 {
                restore_state(&mut l, pre);
            }
            let o = run(&mut l, &comp, dt_s, inp);
            upset.apply(r, &mut l);
            if let (Some(wr), Some(or)) = (w.get_mut(r), out.get_mut(r)) {
                save_state(&mut l, wr);
                *or = o;
            }
            let [w0, w1, w2] = &w;
            let [o0, o1, o2] = out;
            if r == 1 && o1 == o0 && w1.same_words(w0) {
                return (Some(o1), false);
            }
            if r == 2 {
                if (o2 == o0 && w2.same_words(w0)) || (o2 == o1 && w2.same_words(w1)) {
                    return (Some(o2), true);
                }
                restore_state(&mut l, pre);
                return (None, true);
            }
        }
        (None, true)
    }

    /// Start of a step: the state and the covariance checked against their shadows
    /// and restored bit for bit on a mismatch (counted); a block neither copy can
    /// restore loses the navigation. Whether they were sealed (else nothing checked).
    #[inline(never)]
    fn guard_check(&mut self) -> bool {
        if self.guard.sealed != SEALED {
            return false;
        }
        let (mut l, guard) = self.split();
        let state = guard.state.check(sum_of(|p| visit(&mut l, p)));
        if state == Check::Restore {
            restore_state(&mut l, &guard.state);
        }
        let p_words = self.nav.p.as_mut_slice();
        let p = self.guard.p.check(sum_of(|s| s.f64s(p_words)));
        if p == Check::Restore {
            let p_words = self.nav.p.as_mut_slice();
            self.guard.p.restore_pass(|r| r.f64s(p_words));
        }
        for c in [state, p] {
            match c {
                Check::Restore => self.counters.add(NavCounter::StateRestored, 1),
                Check::Lost => self.lost = Flag::SET,
                Check::Intact | Check::ShadowRepaired => {}
            }
        }
        true
    }

    /// The state saved into its shadow, and the covariance with it when `p_too`; sealed.
    #[inline(never)]
    fn guard_seal(&mut self, p_too: bool) {
        let (mut l, guard) = self.split();
        save_state(&mut l, &mut guard.state);
        if p_too || self.guard.sealed != SEALED {
            let p_words = self.nav.p.as_mut_slice();
            self.guard.p.save_pass(|s| s.f64s(p_words));
        }
        self.guard.sealed = SEALED;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The window's guard sees every double pattern of the upset campaigns: two adjacent
    /// bits of one f64 (bits 31 and 32 among them), the same bit of the two halves of one
    /// f64 (adjacent 32-bit words), the same bit of two adjacent f64; and the guard's own
    /// bit with the same bit of the ring's first word.
    #[test]
    fn window_guard_sees_the_double_patterns() {
        let n = 3 * WINDOW_BLOCKS;
        let delta = |flips: &[(usize, u32)]| flips.iter().fold(0u32, |g, &(k, b)| g ^ window_word(1u64 << b, k));
        for k in 0..n {
            for b in 0..64 {
                if b < 63 {
                    assert_ne!(delta(&[(k, b), (k, b + 1)]), 0, "word {k} bits {b}, {}", b + 1);
                }
                if b < 32 {
                    assert_ne!(delta(&[(k, b), (k, b + 32)]), 0, "word {k} halves, bit {b}");
                    if k + 1 < n {
                        assert_ne!(delta(&[(k, b + 32), (k + 1, b)]), 0, "words {k}, {} (32-bit) bit {b}", k + 1);
                    }
                }
                if k + 1 < n {
                    assert_ne!(delta(&[(k, b), (k + 1, b)]), 0, "words {k}, {} bit {b}", k + 1);
                }
            }
        }
        for b in 0..32 {
            assert_ne!(delta(&[(0, b)]) ^ (1 << b), 0, "guard and first word, bit {b}");
        }
    }
}
