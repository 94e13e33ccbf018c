//! The launch vehicle's side of the campaign (`ssis-fw-lv-test` on an ascent scenario):
//! the undisturbed flight from the in-process [`LvCore`] on the same bytes, the bytes a
//! step sends (FOG bus, accelerometer bus, GNSS receiver) and the judgement of a
//! navigation output frame.
//!
//! A navigation frame **claims a good solution** when it carries neither
//! [`flags::NAV_FAULT`] (the step refused, the state held, or the navigation lost after a
//! reset) nor [`flags::ACCEL_FAULT`] (the accelerometer increment missing or refused, the
//! last one held); [`flags::GNSS_OUTAGE`] alone is free inertial navigation, still a
//! solution the unit stands behind, with its σ grown; [`flags::ATTITUDE_UNCONFIRMED`]
//! (a resume whose bridge could not back the attitude) withdraws the attitude from the
//! claim, so such a frame is judged on its position and velocity only. A frame is
//! **beyond the bound**
//! when its position error against truth exceeds max(2 × the undisturbed flight's largest
//! position error, 3 × the frame's own position σ), its velocity error max(2 × the
//! undisturbed largest, 3 × its velocity σ), or its attitude error 2 × the undisturbed
//! largest attitude error (the frame carries no attitude σ), each floored at
//! [`FLOOR`] so that a quantity the undisturbed run carries almost exactly is not
//! judged on its rounding. The flight output frame (UART0, the core's attitude) is
//! compared with the undisturbed one: changed or not, and while it claims a good
//! attitude (converged, not degraded, no parity alarm) its attitude within
//! max(20″, its own 3σ) of the undisturbed frame's.

use anyhow::Result;
use ssis::calib::CalibrationTable;
use ssis::flight::Profile;
use ssis::frames::control::{command, ControlFrame};
use ssis::frames::navout::{flags, NavOutputFrame};
use ssis::frames::output::OutputFrame;
use ssis::frames::Frame;
use ssis::nav::init::PadInit;
use ssis::nav::unit::FilterWork;
use ssis::telemetry::events::EventRecord;
use ssis_common::downlink::{Down, Downlink};
use ssis_sim::lv::angle_between;
use ssis_sim::lv_replay::{pad_init, AscentSensors, LvCore, LvScenario, LvStepBytes};

/// Floors of the bounds: position m, velocity m/s, attitude ″.
pub const FLOOR: [f64; 3] = [1.0, 0.01, 20.0];

/// The undisturbed ascent.
pub(super) struct LvFlight {
    /// The pad initialisation block (flash).
    pub init: PadInit,
    /// Every step's bytes and truth.
    pub steps: Vec<LvStepBytes>,
    /// Every step's navigation output frame (the last of the period), by step.
    pub nav: Vec<Option<NavOutputFrame>>,
    /// Every step's pass does filter work after its outputs (covariance propagation,
    /// GNSS update).
    pub filter_work: Vec<bool>,
    /// The bounds: position m, velocity m/s, attitude ″ ([`FLOOR`] or twice the
    /// undisturbed flight's largest error).
    pub bound: [f64; 3],
    /// The undisturbed flight's largest errors against truth: m, m/s, ″.
    pub undisturbed_max: [f64; 3],
}

/// The undisturbed ascent `sc`: its steps, the in-process unit's flight and navigation
/// frames and events.
pub(super) fn record(sc: &LvScenario) -> Result<(LvFlight, Vec<Option<OutputFrame>>, Vec<EventRecord>)> {
    let profile = Profile::LAUNCH_VEHICLE;
    let mut sensors = AscentSensors::new(sc);
    let init = pad_init(sensors.initial());
    let mut core = LvCore::new(&CalibrationTable::DEFAULT, &init)?;
    let n_steps = (sc.duration_s / profile.dt_s()).round() as u64;
    let (mut steps, mut nav, mut frames, mut events) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
    let mut filter_work = Vec::new();
    let mut worst = [0.0f64; 3];
    for n in 1..=n_steps {
        let b = sensors.step(n);
        let period = core.period(&b);
        events.extend(std::iter::from_fn(|| core.take_event()));
        let mut frame = None;
        Downlink::new().push(&period.flight, |d| {
            if let Down::Output(f) = d {
                frame = Some(f);
            }
        });
        let f = period.nav.chunks_exact(NavOutputFrame::LEN).last().and_then(|f| NavOutputFrame::decode(f).ok());
        if let (Some(f), Some(t)) = (f.as_ref(), b.truth.as_ref()) {
            let e = errors(f, t);
            for (w, e) in worst.iter_mut().zip(e) {
                *w = w.max(e);
            }
        }
        frames.push(frame);
        nav.push(f);
        filter_work.push(period.work != FilterWork::None);
        steps.push(b);
    }
    let bound = [0, 1, 2].map(|k| (2.0 * worst[k]).max(FLOOR[k]));
    Ok((LvFlight { init, steps, nav, filter_work, bound, undisturbed_max: worst }, frames, events))
}

/// A navigation frame's errors against truth: position m, velocity m/s, attitude ″.
fn errors(f: &NavOutputFrame, t: &ssis::nav::NavState) -> [f64; 3] {
    let s = f.state();
    [
        (s.r_e_m - t.r_e_m).norm(),
        (s.v_e_m_s - t.v_e_m_s).norm(),
        angle_between(&s.q_eb, &t.q_eb) * ssis_common::ARCSEC_PER_RAD,
    ]
}

/// Whether a navigation frame claims a good solution (module doc).
pub(super) fn claims(f: &NavOutputFrame) -> bool {
    f.flags & (flags::NAV_FAULT | flags::ACCEL_FAULT) == 0
}

/// A navigation frame judged: changed from the undisturbed one, its errors, whether
/// beyond the bound and by how much (the largest ratio of an error to its bound).
pub(super) struct NavVerdict {
    pub changed: bool,
    pub claims: bool,
    pub errors: [f64; 3],
    pub ratio: f64,
}

impl LvFlight {
    /// Judges navigation frame `f` (its step from its time tag).
    pub(super) fn judge(&self, f: &NavOutputFrame) -> Option<NavVerdict> {
        let dt_us = u64::from(Profile::LAUNCH_VEHICLE.dt_us);
        let i = (f.time_tag_us / dt_us).checked_sub(1)? as usize;
        let reference = self.nav.get(i).copied().flatten();
        let changed = reference.is_none_or(|r| r.to_bytes() != f.to_bytes());
        let truth = self.steps.get(i)?.truth?;
        let errors = errors(f, &truth);
        let sigma = [3.0 * f.sigma_pos_m(), 3.0 * f.sigma_vel_m_s(), 0.0];
        // An unconfirmed attitude is not claimed: position and velocity only.
        let judged = if f.flags & flags::ATTITUDE_UNCONFIRMED != 0 { 2 } else { 3 };
        let ratio = (0..judged)
            .map(|k| {
                let e = errors[k];
                if e.is_finite() {
                    e / self.bound[k].max(sigma[k])
                } else {
                    f64::INFINITY
                }
            })
            .fold(0.0, f64::max);
        Some(NavVerdict { changed, claims: claims(f), errors, ratio })
    }

    /// Sends step `i`'s bytes (UART1 FOG bus, UART3 accelerometer bus, UART4 GNSS) and
    /// returns the STEP naming the byte totals (`totals`: FOG, accelerometer, GNSS).
    pub(super) fn send(
        &self,
        unit: &mut crate::qemu::Unit,
        i: usize,
        totals: &mut [u32; 3],
    ) -> std::io::Result<ControlFrame> {
        use std::io::Write;
        let b = self.steps.get(i).ok_or_else(|| std::io::Error::other("no such step"))?;
        for (k, (uart, bytes)) in [(1usize, &b.fog), (3, &b.accel), (4, &b.gnss)].into_iter().enumerate() {
            unit.uarts[uart].write_all(bytes)?;
            totals[k] = totals[k].wrapping_add(bytes.len() as u32);
        }
        Ok(ControlFrame {
            command: command::STEP,
            fog_bytes: totals[0],
            st_bytes: totals[1],
            arg: (totals[2] & 0xFFFF) as u16,
        })
    }
}

/// The navigation frame's σ in physical units.
trait Sigmas {
    fn sigma_pos_m(&self) -> f64;
    fn sigma_vel_m_s(&self) -> f64;
}

impl Sigmas for NavOutputFrame {
    fn sigma_pos_m(&self) -> f64 {
        f64::from(self.sigma_pos_counts) * ssis::frames::navout::SIGMA_POS_LSB_M
    }

    fn sigma_vel_m_s(&self) -> f64 {
        f64::from(self.sigma_vel_counts) * ssis::frames::navout::SIGMA_VEL_LSB_M_S
    }
}
