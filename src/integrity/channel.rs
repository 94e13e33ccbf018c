//! Per-channel checks of one FOG, every sample.
//!
//! Capabilities:
//! - **stuck output**: the same raw angle increment [`STUCK_SAMPLES`] times in a row.
//!   A working FOG's increment carries white noise of thousands of LSB (ARW 0.005 °/√h
//!   is 1e-7 rad in 5 ms; the LSB is 2^-36 rad), so a repeat is a failed loop or a
//!   frozen interface; the check is off when the table's noise figure is too small to
//!   tell (ideal-sensor simulations);
//! - **temperature sensor failure**: the FOG reports it (status bit), or the reading
//!   leaves the plausible range, or it jumps by more than [`TEMP_JUMP_DEGC`] from the
//!   temperature tracker's prediction ([`crate::compensation::ThermalTracker`]). The
//!   gyro stays in use: compensation goes on with the last good temperature estimate
//!   and G = 0 (latched: a sensor that lied once is not trusted again in this run).
//!
//! Missing frames, CRC and format errors, NaN and out-of-range values are checked where
//! they arise (link, decoder, intake, compensation); all are counted per FOG
//! ([`crate::telemetry::FogCounters`]) and reach the output frame.

use crate::frames::fog::{status, FogFrame};
use crate::state::Flag;

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

/// The checks' memory for one FOG.
#[derive(Debug, Clone, Copy, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
#[repr(C)]
pub struct ChannelMonitor {
    last_counts: i32,
    same_run: u16,
    stuck_enabled: Flag,
    temp_failed: Flag,
}

impl ChannelMonitor {
    /// A monitor for an expected per-sample noise `noise_rad` (1σ; the stuck check is off
    /// below [`STUCK_MIN_NOISE_LSB`]).
    pub fn new(noise_rad: f64) -> Self {
        ChannelMonitor {
            last_counts: 0,
            same_run: 0,
            stuck_enabled: Flag::new(noise_rad >= STUCK_MIN_NOISE_LSB * FogFrame::DTHETA_LSB_RAD),
            temp_failed: Flag::CLEAR,
        }
    }

    /// A new table's noise figure: the stuck check on or off as [`ChannelMonitor::new`]
    /// decides; the memory of the checks stays.
    pub fn set_noise(&mut self, noise_rad: f64) {
        self.stuck_enabled = ChannelMonitor::new(noise_rad).stuck_enabled;
    }

    /// Whether the sample's raw increment is stuck (do not use the sample).
    #[inline]
    pub fn stuck(&mut self, frame: &FogFrame) -> bool {
        if frame.dtheta_counts == self.last_counts {
            self.same_run = self.same_run.saturating_add(1);
        } else {
            self.same_run = 0;
            self.last_counts = frame.dtheta_counts;
        }
        self.stuck_enabled.get() && self.same_run >= STUCK_SAMPLES - 1
    }

    /// Judges the sample's temperature reading against `predicted_degc` (the tracker's
    /// prediction, `None` before the first reading): the reading, °C, if the sensor is
    /// trusted; `None` once it has failed (latched).
    #[inline]
    pub fn temperature(&mut self, frame: &FogFrame, predicted_degc: Option<f64>) -> Option<f64> {
        if self.temp_failed.get() {
            return None;
        }
        let c = frame.temperature_counts;
        if frame.status & status::TEMP_SENSOR_FAULT == 0 && (TEMP_MIN_COUNTS..=TEMP_MAX_COUNTS).contains(&c) {
            let t = frame.temperature_degc();
            if predicted_degc.is_none_or(|p| (t - p).abs() <= TEMP_JUMP_DEGC) {
                return Some(t);
            }
        }
        self.temp_failed = Flag::SET;
        None
    }

    /// Whether the temperature sensor has failed.
    pub fn temp_failed(&self) -> bool {
        self.temp_failed.get()
    }
}
