//! Per-channel checks of one FOG, every sample (issue 6 part 1).
//!
//! Capabilities:
//! - **stuck output**: the same raw angle increment [`STUCK_SAMPLES`] times in a row.
//!   A working FOG's increment carries white noise of thousands of LSB (ARW 0.005 °/√h
//!   is 1e-7 rad in 5 ms; the LSB is 2^-36 rad), so a repeat is a failed loop or a
//!   frozen interface; the check is off when the table's noise figure is too small to
//!   tell (ideal-sensor simulations);
//! - **temperature sensor failure**: the FOG reports it (status bit), or the reading
//!   leaves the plausible range, or it jumps by more than [`TEMP_JUMP_DEGC`] from the
//!   α-β tracker's prediction. The gyro stays in use: its thermal compensation goes on
//!   with the last good temperature estimate and G = 0 (latched: a sensor that lied once
//!   is not trusted again in this run).
//!
//! Missing frames, CRC and format errors, NaN and out-of-range values are checked where
//! they arise (link, decoder, [`crate::flight`]); all are counted per FOG
//! ([`FogCounters`]) and reach the output frame.

use crate::compensation::TempRateEstimator;
use crate::frames::fog::{status, FogFrame};

/// Identical raw increments in a row that make a FOG "stuck" (40 × 5 ms = 200 ms).
pub const STUCK_SAMPLES: u16 = 40;
/// The stuck check needs the per-sample noise to be at least this many LSB.
pub const STUCK_MIN_NOISE_LSB: f64 = 50.0;
/// Plausible FOG temperature range, °C (outside: the sensor has failed).
pub const TEMP_RANGE_DEGC: (f64, f64) = (-60.0, 100.0);
/// A temperature reading this far from the tracker's prediction has failed, °C (no
/// housing changes temperature by degrees in one sample).
pub const TEMP_JUMP_DEGC: f64 = 3.0;

const TEMP_MIN_COUNTS: i16 = (TEMP_RANGE_DEGC.0 * 256.0) as i16;
const TEMP_MAX_COUNTS: i16 = (TEMP_RANGE_DEGC.1 * 256.0) as i16;

/// Per-FOG counters (saturating), sent in the output frame's counter page.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct FogCounters {
    /// Frames rejected (CRC, format, wrong id).
    pub rejected: u32,
    /// Samples that did not arrive in time.
    pub missing: u32,
    /// Samples not finite or outside the measuring range after compensation.
    pub out_of_range: u32,
    /// Samples refused because the output is stuck.
    pub stuck: u32,
    /// Samples with the FOG's own fault bits set (light source, loop lock).
    pub device_fault: u32,
    /// Temperature sensor failures (0 or 1: latched).
    pub temp_failures: u32,
    /// Samples the parity check dropped as spikes.
    pub spikes: u32,
}

/// What the channel checks found in one sample.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ChannelVerdict {
    /// The raw increment is stuck: do not use the sample.
    pub stuck: bool,
    /// Temperature sensor failed (now or before): T is the held estimate, G = 0.
    pub temp_failed: bool,
    /// Temperature for compensation, °C.
    pub t_degc: f64,
    /// Temperature rate G for compensation, °C/s.
    pub g_degc_s: f64,
}

/// The checks' memory for one FOG.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ChannelMonitor {
    last_counts: i32,
    same_run: u16,
    stuck_enabled: bool,
    temp_failed: bool,
    temp: TempRateEstimator,
}

impl ChannelMonitor {
    /// A monitor for samples every `dt_s`, temperature tracker time constant `tau_s`,
    /// expected per-sample noise `noise_rad` (1σ; the stuck check is off below
    /// [`STUCK_MIN_NOISE_LSB`]).
    pub fn new(dt_s: f64, tau_s: f64, noise_rad: f64) -> Self {
        ChannelMonitor {
            last_counts: 0,
            same_run: 0,
            stuck_enabled: noise_rad >= STUCK_MIN_NOISE_LSB * FogFrame::DTHETA_LSB_RAD,
            temp_failed: false,
            temp: TempRateEstimator::new(dt_s, tau_s),
        }
    }

    /// Checks one sample and tracks its temperature.
    pub fn check(&mut self, frame: &FogFrame, dt_s: f64) -> ChannelVerdict {
        if frame.dtheta_counts == self.last_counts {
            self.same_run = self.same_run.saturating_add(1);
        } else {
            self.same_run = 0;
            self.last_counts = frame.dtheta_counts;
        }
        let stuck = self.stuck_enabled && self.same_run >= STUCK_SAMPLES - 1;
        if !self.temp_failed {
            let c = frame.temperature_counts;
            if frame.status & status::TEMP_SENSOR_FAULT == 0 && (TEMP_MIN_COUNTS..=TEMP_MAX_COUNTS).contains(&c) {
                if let Some((t_degc, g_degc_s)) =
                    self.temp.update_within(frame.temperature_degc(), dt_s, TEMP_JUMP_DEGC)
                {
                    return ChannelVerdict { stuck, temp_failed: false, t_degc, g_degc_s };
                }
            }
            self.temp_failed = true;
        }
        ChannelVerdict { stuck, temp_failed: true, t_degc: self.temp.estimate().0, g_degc_s: 0.0 }
    }

    /// Whether the temperature sensor has failed.
    pub fn temp_failed(&self) -> bool {
        self.temp_failed
    }
}
