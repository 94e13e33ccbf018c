//! Accelerometer sample frame (kind 0x11, 18 bytes): one velocity increment and
//! temperature per sample interval from one pendulous accelerometer (launch-vehicle
//! unit: three, AK-30 class, ±85 m/s²).
//!
//! The layout is the FOG frame's with the velocity increment in place of the angle
//! increment, so the same envelope, decoder and link code serve both.
//!
//! | off | size | field | type | scaling |
//! |---|---|---|---|---|
//! | 0 | 2 | sync | `EB 90` | |
//! | 2 | 1 | kind | `0x11` | |
//! | 3 | 1 | accel_id | u8 | 0..=2 (X, Y, Z) |
//! | 4 | 2 | counter | u16 | sample counter, wraps |
//! | 6 | 1 | status | u8 | [`status`] bits; bits 3–7 zero |
//! | 7 | 4 | dv | i32 | LSB 2^-28 m/s (±8 m/s per sample) |
//! | 11 | 2 | temperature | i16 | LSB 1/256 °C |
//! | 13 | 1 | reserved | u8 | zero |
//! | 14 | 4 | crc | u32 | CRC-32C over bytes 0..14 |
//!
//! At 1.25 ms the full range ±85 m/s² is ±0.106 m/s per sample (2.9e7 counts); one LSB,
//! 3.7e-9 m/s, is 3e-6 m/s² over a step, far below the accelerometer's own noise.

use super::{counts_i16, counts_i32, kind, DecodeError, FieldReader, FieldWriter, Frame};

/// Length of an accelerometer frame in bytes.
pub const FRAME_LEN: usize = 18;

/// Highest valid accelerometer id (X, Y, Z are ids 0..=2).
pub const MAX_ACCEL_ID: u8 = 2;

/// Bits of the accelerometer status byte.
pub mod status {
    /// Servo (rebalance loop) fault: the pendulum is not held at null.
    pub const SERVO_FAULT: u8 = 1 << 0;
    /// Over-range: the input exceeded the measuring range during the interval.
    pub const OVER_RANGE: u8 = 1 << 1;
    /// Temperature sensor fault.
    pub const TEMP_SENSOR_FAULT: u8 = 1 << 2;
    /// Reserved bits: must be zero, else the frame is rejected.
    pub const RESERVED: u8 = 0xF8;
}

/// One accelerometer sample as carried on the link (raw counts).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, bytemuck::AnyBitPattern)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub struct AccelFrame {
    /// Accelerometer id, 0..=2.
    pub accel_id: u8,
    /// Sample counter (wraps).
    pub counter: u16,
    /// Status bits ([`status`]).
    pub status: u8,
    /// Velocity increment over the interval, counts of [`AccelFrame::DV_LSB_M_S`].
    pub dv_counts: i32,
    /// Temperature, counts of [`AccelFrame::TEMP_LSB_DEGC`].
    pub temperature_counts: i16,
}

/// An [`AccelFrame`] as a queue of the navigation stores it: the same fields without
/// padding ([`crate::state::Ring`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, bytemuck::Pod, bytemuck::Zeroable)]
#[repr(C)]
pub struct AccelSlot {
    dv_counts: i32,
    counter: u16,
    temperature_counts: i16,
    accel_id: u8,
    status: u8,
    _pad: [u8; 2],
}

impl From<AccelFrame> for AccelSlot {
    #[inline(always)]
    fn from(f: AccelFrame) -> Self {
        AccelSlot {
            dv_counts: f.dv_counts,
            counter: f.counter,
            temperature_counts: f.temperature_counts,
            accel_id: f.accel_id,
            status: f.status,
            _pad: [0; 2],
        }
    }
}

impl From<AccelSlot> for AccelFrame {
    #[inline(always)]
    fn from(s: AccelSlot) -> Self {
        AccelFrame {
            accel_id: s.accel_id,
            counter: s.counter,
            status: s.status,
            dv_counts: s.dv_counts,
            temperature_counts: s.temperature_counts,
        }
    }
}

impl AccelFrame {
    /// Frame length in bytes (same as [`Frame::LEN`]).
    pub const LEN: usize = FRAME_LEN;
    /// LSB of the velocity increment: 2^-28 m/s.
    pub const DV_LSB_M_S: f64 = 1.0 / 268_435_456.0;
    /// LSB of the temperature: 1/256 °C.
    pub const TEMP_LSB_DEGC: f64 = 1.0 / 256.0;

    /// A frame from physical values: the increment rounded to the nearest count and
    /// saturated to the field's range; NaN gives 0. `accel_id` and `status` are taken as
    /// they are.
    pub fn from_physical(accel_id: u8, counter: u16, status: u8, dv_m_s: f64, temperature_degc: f64) -> Self {
        AccelFrame {
            accel_id,
            counter,
            status,
            dv_counts: counts_i32(dv_m_s, Self::DV_LSB_M_S),
            temperature_counts: counts_i16(temperature_degc, Self::TEMP_LSB_DEGC),
        }
    }

    /// Velocity increment over the interval, m/s.
    pub fn dv_m_s(&self) -> f64 {
        f64::from(self.dv_counts) * Self::DV_LSB_M_S
    }

    /// Accelerometer temperature, °C.
    pub fn temperature_degc(&self) -> f64 {
        f64::from(self.temperature_counts) * Self::TEMP_LSB_DEGC
    }

    /// Whether the status reports a device fault (servo or temperature sensor).
    pub fn device_fault(&self) -> bool {
        self.status & (status::SERVO_FAULT | status::TEMP_SENSOR_FAULT) != 0
    }

    /// The frame's bytes.
    pub fn to_bytes(&self) -> [u8; Self::LEN] {
        let mut out = [0u8; Self::LEN];
        // Cannot fail: `out` is exactly one frame long.
        let _ = self.encode_into(&mut out);
        out
    }
}

impl Frame for AccelFrame {
    const KIND: u8 = kind::ACCEL;
    const LEN: usize = FRAME_LEN;

    fn write_fields(&self, w: &mut FieldWriter<'_>) {
        w.u8(self.accel_id);
        w.u16(self.counter);
        w.u8(self.status);
        w.i32(self.dv_counts);
        w.i16(self.temperature_counts);
        w.u8(0);
    }

    fn read_fields(r: &mut FieldReader<'_>) -> Result<Self, DecodeError> {
        let accel_id = r.u8()?;
        let counter = r.u16()?;
        let status = r.u8()?;
        let dv_counts = r.i32()?;
        let temperature_counts = r.i16()?;
        let reserved = r.u8()?;
        if accel_id > MAX_ACCEL_ID || status & status::RESERVED != 0 || reserved != 0 {
            return Err(DecodeError::BadField);
        }
        Ok(AccelFrame { accel_id, counter, status, dv_counts, temperature_counts })
    }
}
