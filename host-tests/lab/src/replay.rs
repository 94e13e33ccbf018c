//! Replay of a session through the flight core: the round trip from the lab to flight.
//!
//! Each session row becomes one FOG frame per FOG ([`ssis::frames::fog::FogFrame`]): the
//! sample counter k = t/Δt (the row covers ((k−1)Δt, kΔt], the core's timing convention),
//! the angle increment ω_raw·Δt in counts of 2^-36 rad with the rounding carried from
//! sample to sample as a FOG's own counter does (so quantisation never accumulates), the
//! temperature in counts of 1/256 °C. The frames go byte by byte over ideal mock links into
//! [`FlightCore::step`], the very code the firmware runs: the core decodes them, estimates
//! T and G = dT/dt itself (its α-β tracker, `t_rate_filter_s`), compensates with the table
//! (`src/compensation.rs`), combines the FOGs by least squares over the table's axes and
//! integrates. Without star-tracker frames the observer's drift estimate Δω (eq. 6) stays
//! zero, so the output rate is the compensated, combined gyro rate.
//!
//! The core's step is the session's sample interval (the profile's geometry and range are
//! the unit's: four FOGs as [`Profile::SPACECRAFT`], three as [`Profile::LAUNCH_VEHICLE`]):
//! one row is one step. That needs equally spaced rows and increments that fit the frame's
//! i32 field (|ω|·Δt < 2^-5 rad: 1.79 °/s at 1-s rows, the spacecraft's 10 °/s at 3 ms).

use nalgebra::Vector3;
use ssis::calib::CalibrationTable;
use ssis::combination::FogSet;
use ssis::flight::{health, FlightCore, FogLinks, Links, Profile};
use ssis::frames::decoder::StreamDecoder;
use ssis::frames::fog::FogFrame;
use ssis::frames::output::OutputFrame;

use super::session::Session;
use super::{LabError, LabResult};
use ssis_common::mock::{MockLink, MockSink};

/// What the core said for every row of a session.
#[derive(Debug, Clone)]
pub struct Replay {
    /// The core's step (the session's sample interval), µs.
    pub dt_us: u32,
    /// The profile the core ran.
    pub profile: Profile,
    /// Output rate of the ICS per row, rad/s (`StepOutput::rate_rad_s`).
    pub rate_rad_s: Vec<[f64; 3]>,
    /// Output rate minus the session's reference rate, per row, rad/s.
    pub error_rad_s: Vec<[f64; 3]>,
    /// Steps in which not every fitted FOG was used (missing, rejected, out of range).
    pub steps_degraded: usize,
    /// Output frames decoded from the core's output link.
    pub frames_out: u64,
    /// Output frames that failed to decode (should be 0).
    pub frames_out_bad: u64,
}

impl Replay {
    /// RMS over `rows` (all when `None`) of the error's norm |ω_out − ω_ref|, rad/s.
    pub fn rms_error_rad_s(&self, rows: Option<&[usize]>) -> f64 {
        let sq = |e: &[f64; 3]| e[0] * e[0] + e[1] * e[1] + e[2] * e[2];
        let (sum, n) = match rows {
            Some(r) => (r.iter().map(|&j| sq(&self.error_rad_s[j])).sum::<f64>(), r.len()),
            None => (self.error_rad_s.iter().map(sq).sum::<f64>(), self.error_rad_s.len()),
        };
        (sum / n.max(1) as f64).sqrt()
    }
}

/// The core's profile for a session with `n_fog` FOGs at step `dt_us`.
pub fn profile_for(n_fog: usize, dt_us: u32) -> LabResult<Profile> {
    let base = match n_fog {
        4 => Profile::SPACECRAFT,
        3 => Profile::LAUNCH_VEHICLE,
        n => return Err(LabError::Numeric(format!("the flight core takes 3 or 4 FOGs, the session has {n}"))),
    };
    Ok(Profile { dt_us, fogs: if n_fog == 4 { FogSet::ALL } else { FogSet::TRIAD }, star_tracker: false, ..base })
}

/// Replays `session` through a [`FlightCore`] flying `table`.
pub fn replay(session: &Session, table: &CalibrationTable) -> LabResult<Replay> {
    replay_with(session, table, None)
}

/// [`replay`], keeping every byte the core wrote on its output link in `capture` (what a
/// logger on that link records).
pub fn replay_with(
    session: &Session,
    table: &CalibrationTable,
    mut capture: Option<&mut Vec<u8>>,
) -> LabResult<Replay> {
    let t = session.t_s();
    let n = t.len();
    let file = &session.file;
    let dt_s = session.median_dt_s();
    let dt_us_f = (dt_s * 1e6).round();
    if !(1.0..=f64::from(u32::MAX)).contains(&dt_us_f) {
        return Err(LabError::Numeric(format!("{file}: sample interval {dt_s} s is not a core step (1 µs .. 71 min)")));
    }
    let dt_us = dt_us_f as u32;
    let dt_s = f64::from(dt_us) * 1e-6;
    let n_fog = session.fogs.len();
    let profile = profile_for(n_fog, dt_us)?;
    // Sample counters, checked: equally spaced rows.
    let k0 = (t[0] / dt_s).round();
    for (j, &tj) in t.iter().enumerate() {
        if ((tj / dt_s) - (k0 + j as f64)).abs() > 1e-6 {
            return Err(LabError::Numeric(format!(
                "{file}: row {} at t = {tj} s is not on the grid k·{dt_s} s of the first row: the core replays \
                 equally spaced rows only",
                j + 1
            )));
        }
    }
    let limit_rad = f64::from(i32::MAX) * FogFrame::DTHETA_LSB_RAD;
    let mut core = FlightCore::new(profile, table, false)
        .map_err(|e| LabError::Numeric(format!("the flight core refuses the table: {e:?}")))?;
    // A ground session replays tables that are not calibrated yet (the lab's starting
    // model): the gyros disagree by far more than the parity fault logic allows a
    // calibrated unit, and it would isolate one. The replay is about compensation.
    core.disable_parity_fdi();
    let mut links = Links {
        fog: FogLinks::PerFog([0, 1, 2, 3].map(|_| MockLink::ideal())),
        star: MockLink::ideal(),
        out: MockSink::default(),
    };
    let mut out_dec: StreamDecoder<OutputFrame, 256> = StreamDecoder::new();
    let (mut frames_out, mut frames_out_bad) = (0u64, 0u64);
    let mut total_rad = vec![0.0f64; n_fog];
    let mut sent_counts = vec![0i64; n_fog];
    let mut rate_rad_s = Vec::with_capacity(n);
    let mut error_rad_s = Vec::with_capacity(n);
    let mut steps_degraded = 0;
    for j in 0..n {
        let k = k0 as u64 + j as u64;
        let FogLinks::PerFog(fog_links) = &mut links.fog else { unreachable!("built per FOG") };
        for (i, fog) in session.fogs.iter().enumerate() {
            let dtheta = fog.rate_rad_s[j] * dt_s;
            if dtheta.abs() >= limit_rad {
                return Err(LabError::Numeric(format!(
                    "{file}: row {}: FOG{i} turns {dtheta:.3e} rad in one sample, more than a FOG frame carries \
                     ({limit_rad:.4} rad): replay needs a shorter sample interval",
                    j + 1
                )));
            }
            total_rad[i] += dtheta;
            let now = (total_rad[i] / FogFrame::DTHETA_LSB_RAD).round() as i64;
            let temp = fog.t_degc.as_ref().map_or(table.fog[i].t_ref_degc, |c| c[j]);
            let mut f = FogFrame::from_physical(i as u8, k as u16, 0, 0.0, temp);
            f.dtheta_counts = (now - sent_counts[i]) as i32;
            sent_counts[i] = now;
            fog_links[i].tick();
            fog_links[i].send(&f.to_bytes());
        }
        let out = core.step(&mut links);
        if out.time_us != k * u64::from(dt_us) {
            return Err(LabError::Numeric(format!(
                "{file}: row {}: the core integrated the sample ending at {} µs, expected {} µs",
                j + 1,
                out.time_us,
                k * u64::from(dt_us)
            )));
        }
        if (0..n_fog).any(|i| out.fog_health[i] & health::USED == 0) {
            steps_degraded += 1;
        }
        let bytes = std::mem::take(&mut links.out.bytes);
        out_dec.push_slice(&bytes, |r| match r {
            Ok(_) => frames_out += 1,
            Err(_) => frames_out_bad += 1,
        });
        if let Some(c) = capture.as_mut() {
            c.extend_from_slice(&bytes);
        }
        let w = out.rate_rad_s;
        let e = w - Vector3::from(session.ref_rad_s[j]);
        rate_rad_s.push([w.x, w.y, w.z]);
        error_rad_s.push([e.x, e.y, e.z]);
    }
    Ok(Replay { dt_us, profile, rate_rad_s, error_rad_s, steps_degraded, frames_out, frames_out_bad })
}
