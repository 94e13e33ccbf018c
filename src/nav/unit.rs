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
//!      of each (oldest first); a missing or faulty one holds the previous compensated
//!      increment for the step and raises [`flags::ACCEL_FAULT`];
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
//! The accelerometer samples are assumed to be taken in step with the FOG samples (their
//! counters are not matched).

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
use crate::state::Ring;

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

/// The navigation stage.
pub struct NavUnit {
    nav: AidedNav,
    comp: AccelCompensator,
    dt_s: f64,
    accel_dec: StreamDecoder<AccelFrame, 32>,
    accel_q: [Ring<AccelSlot, ACCEL_QUEUE>; N_ACCEL],
    gnss_dec: StreamDecoder<GnssFrame, 64>,
    last_dv_m_s: Vector3<f64>,
    last_fix_us: Option<u64>,
    /// The newest valid fix not yet used, with the unit time of its step, µs.
    pending_fix: Option<(GnssFix, u64)>,
    /// A fix has been applied since the last output frame.
    updated_since_output: bool,
    rx_scratch: [u8; 64],
    out_buf: [u8; NavOutputFrame::LEN],
    out_counter: u16,
    counters: NavCounters,
}

impl NavUnit {
    /// A stage starting from `state` (pad alignment) with step `dt_s`.
    pub fn new(state: NavState, dt_s: f64, comp: AccelCompensator, cfg: GnssConfig) -> Result<Self, NavError> {
        Ok(NavUnit {
            nav: AidedNav::new(state, dt_s, cfg)?,
            comp,
            dt_s,
            accel_dec: StreamDecoder::new(),
            accel_q: [Ring::new(), Ring::new(), Ring::new()],
            gnss_dec: StreamDecoder::new(),
            last_dv_m_s: Vector3::zeros(),
            last_fix_us: None,
            pending_fix: None,
            updated_since_output: false,
            rx_scratch: [0; 64],
            out_buf: [0; NavOutputFrame::LEN],
            out_counter: 0,
            counters: NavCounters::default(),
        })
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
        self.counters.add(NavCounter::AccelFramesRejected, rejected);
        let mut raw = [0.0; N_ACCEL];
        let mut temps = [0.0; N_ACCEL];
        let mut complete = true;
        for ((q, r), t) in self.accel_q.iter_mut().zip(raw.iter_mut()).zip(temps.iter_mut()) {
            match q.pop_front().map(AccelFrame::from) {
                Some(f) if !f.device_fault() => {
                    *r = f.dv_m_s();
                    *t = f.temperature_degc();
                }
                _ => complete = false,
            }
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
        if self.nav.step_deferred(dtheta_body_rad, &dv).is_err() {
            fl |= flags::NAV_FAULT;
            self.counters.add(NavCounter::NavFaults, 1);
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
        if let Some(fix) = newest {
            if self.pending_fix.replace((fix, time_us)).is_some() {
                superseded += 1;
            }
        }
        self.counters.add(NavCounter::GnssFixesSuperseded, superseded);
        if core::mem::take(&mut self.updated_since_output) {
            fl |= flags::GNSS_UPDATED;
        }
        let outage = match self.last_fix_us {
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
        if let Some((fix, t_us)) = self.pending_fix.take() {
            return match self.nav.gnss_update(&fix) {
                Ok(()) => {
                    self.updated_since_output = true;
                    self.last_fix_us = Some(t_us);
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
