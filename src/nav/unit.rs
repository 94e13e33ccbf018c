//! The launch-vehicle navigation stage with its links: accelerometer frames in (one
//! multi-drop link carrying the three accelerometers, told apart by `accel_id`), GNSS
//! fix frames in (their own link), navigation output frames out.
//!
//! [`NavUnit::step`] is meant to be called once per integrated FOG sample with the body
//! angle increment of that sample (the FOG compensation and combination are the flight
//! step's, [`crate::flight`]); per call it:
//!
//! 1. drains the accelerometer link into per-accelerometer queues and takes one sample of
//!    each (oldest first); a missing or faulty one holds the previous compensated
//!    increment for the step and raises [`flags::ACCEL_FAULT`];
//! 2. compensates the three increments ([`crate::calib::accel::AccelCompensator`]);
//! 3. runs the aided strapdown step ([`AidedNav::step`]);
//! 4. drains the GNSS link; the newest valid fix, if any, is applied now (the frame's
//!    time tag is not used: a fix is applied at the step it arrives in, so the link
//!    latency is not compensated);
//! 5. emits one [`NavOutputFrame`].
//!
//! Not yet called by [`crate::flight::FlightCore::step`]; the accelerometer samples are
//! assumed to be taken in step with the FOG samples (their counters are not matched).

use heapless::Deque;
use nalgebra::Vector3;

use super::gnss::{AidedNav, GnssConfig, GnssFix};
use super::{NavError, NavState};
use crate::calib::accel::{AccelCompensator, N_ACCEL};
use crate::frames::accel::AccelFrame;
use crate::frames::decoder::StreamDecoder;
use crate::frames::gnss::GnssFrame;
use crate::frames::navout::{flags, NavOutputFrame};
use crate::frames::Frame;
use crate::link::{drain, write_frame, RxLink, TxLink};

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

/// Counters of the stage (saturating).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct NavCounters {
    /// Accelerometer frames rejected by the decoder (CRC, kind, field).
    pub accel_frames_rejected: u32,
    /// Steps in which at least one accelerometer sample was missing or faulty.
    pub accel_steps_held: u32,
    /// GNSS frames rejected by the decoder.
    pub gnss_frames_rejected: u32,
    /// Navigation steps refused (state held).
    pub nav_faults: u32,
    /// Output frames that could not be written.
    pub output_dropped: u32,
    /// Link driver errors.
    pub io_errors: u32,
}

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
    accel_q: [Deque<AccelFrame, ACCEL_QUEUE>; N_ACCEL],
    gnss_dec: StreamDecoder<GnssFrame, 64>,
    last_dv_m_s: Vector3<f64>,
    last_fix_us: Option<u64>,
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
            accel_q: [Deque::new(), Deque::new(), Deque::new()],
            gnss_dec: StreamDecoder::new(),
            last_dv_m_s: Vector3::zeros(),
            last_fix_us: None,
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
        let rep = drain(&mut links.accel, MAX_ACCEL_BYTES_PER_STEP, &mut self.rx_scratch, |bytes| {
            dec.push_slice(bytes, |r| {
                if let Ok(f) = r {
                    if let Some(q) = queues.get_mut(usize::from(f.accel_id)) {
                        if q.is_full() {
                            let _ = q.pop_front();
                        }
                        let _ = q.push_back(f);
                    }
                }
            })
        });
        self.counters.io_errors = self.counters.io_errors.saturating_add(rep.io_errors);
        self.counters.accel_frames_rejected = self.accel_dec.stats().rejected();
        let mut raw = [0.0; N_ACCEL];
        let mut temps = [0.0; N_ACCEL];
        let mut complete = true;
        for ((q, r), t) in self.accel_q.iter_mut().zip(raw.iter_mut()).zip(temps.iter_mut()) {
            match q.pop_front() {
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
                self.counters.accel_steps_held = self.counters.accel_steps_held.saturating_add(1);
                self.last_dv_m_s
            }
        };
        // 3. Navigation.
        if self.nav.step(dtheta_body_rad, &dv).is_err() {
            fl |= flags::NAV_FAULT;
            self.counters.nav_faults = self.counters.nav_faults.saturating_add(1);
        }
        // 4. GNSS.
        let mut newest: Option<GnssFix> = None;
        let gdec = &mut self.gnss_dec;
        let rep = drain(&mut links.gnss, MAX_GNSS_BYTES_PER_STEP, &mut self.rx_scratch, |bytes| {
            gdec.push_slice(bytes, |r| {
                if let Ok(f) = r {
                    if let Some(fix) = f.fix() {
                        newest = Some(fix);
                    }
                }
            })
        });
        self.counters.io_errors = self.counters.io_errors.saturating_add(rep.io_errors);
        self.counters.gnss_frames_rejected = self.gnss_dec.stats().rejected();
        if let Some(fix) = newest {
            if self.nav.gnss_update(&fix).is_ok() {
                fl |= flags::GNSS_UPDATED;
                self.last_fix_us = Some(time_us);
            }
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
            self.counters.output_dropped = self.counters.output_dropped.saturating_add(1);
        }
        NavStepOutput { flags: fl, state }
    }
}
