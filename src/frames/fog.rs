//! FOG sample frame (kind 0x10, 18 bytes): one angle increment and temperature per
//! sample interval from one fibre-optic gyro.
//!
//! | off | size | field | type | scaling |
//! |---|---|---|---|---|
//! | 0 | 2 | sync | `EB 90` | |
//! | 2 | 1 | kind | `0x10` | |
//! | 3 | 1 | fog_id | u8 | 0..=3 |
//! | 4 | 2 | counter | u16 | sample counter, wraps |
//! | 6 | 1 | status | u8 | [`status`] bits; bits 4–7 zero |
//! | 7 | 4 | dtheta | i32 | LSB 2^-36 rad |
//! | 11 | 2 | temperature | i16 | LSB 1/256 °C |
//! | 13 | 1 | reserved | u8 | zero |
//! | 14 | 4 | crc | u32 | CRC-32C over bytes 0..14 |

use super::{counts_i16, counts_i32, kind, DecodeError, FieldReader, FieldWriter, Frame};

/// Length of a FOG frame in bytes.
pub const FRAME_LEN: usize = 18;

/// Highest valid FOG id (FOG1..FOG4 are ids 0..=3).
pub const MAX_FOG_ID: u8 = 3;

/// Bits of the FOG status byte.
pub mod status {
    /// Light-source fault.
    pub const LIGHT_SOURCE_FAULT: u8 = 1 << 0;
    /// Closed-loop lock lost.
    pub const LOOP_LOCK_LOST: u8 = 1 << 1;
    /// Temperature sensor fault.
    pub const TEMP_SENSOR_FAULT: u8 = 1 << 2;
    /// Self-test running.
    pub const SELF_TEST: u8 = 1 << 3;
    /// Reserved bits: must be zero, else the frame is rejected.
    pub const RESERVED: u8 = 0xF0;
}

/// One FOG sample as carried on the link (raw counts).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, bytemuck::AnyBitPattern)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub struct FogFrame {
    /// FOG id, 0..=3.
    pub fog_id: u8,
    /// Sample counter (wraps).
    pub counter: u16,
    /// Status bits ([`status`]).
    pub status: u8,
    /// Angle increment over the sample interval, counts of [`FogFrame::DTHETA_LSB_RAD`].
    pub dtheta_counts: i32,
    /// Temperature, counts of [`FogFrame::TEMP_LSB_DEGC`].
    pub temperature_counts: i16,
}

/// A [`FogFrame`] as a queue of the state stores it: the same fields without padding
/// ([`crate::state::Ring`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, bytemuck::Pod, bytemuck::Zeroable)]
#[repr(C)]
pub struct FogSlot {
    dtheta_counts: i32,
    counter: u16,
    temperature_counts: i16,
    fog_id: u8,
    status: u8,
    _pad: [u8; 2],
}

impl FogSlot {
    /// The frame's sample counter.
    #[inline(always)]
    pub fn counter(&self) -> u16 {
        self.counter
    }
}

impl From<FogFrame> for FogSlot {
    #[inline(always)]
    fn from(f: FogFrame) -> Self {
        FogSlot {
            dtheta_counts: f.dtheta_counts,
            counter: f.counter,
            temperature_counts: f.temperature_counts,
            fog_id: f.fog_id,
            status: f.status,
            _pad: [0; 2],
        }
    }
}

impl From<FogSlot> for FogFrame {
    #[inline(always)]
    fn from(s: FogSlot) -> Self {
        FogFrame {
            fog_id: s.fog_id,
            counter: s.counter,
            status: s.status,
            dtheta_counts: s.dtheta_counts,
            temperature_counts: s.temperature_counts,
        }
    }
}

impl FogFrame {
    /// Frame length in bytes (same as [`Frame::LEN`]).
    pub const LEN: usize = FRAME_LEN;
    /// LSB of the angle increment: 2^-36 rad.
    pub const DTHETA_LSB_RAD: f64 = 1.0 / 68_719_476_736.0;
    /// LSB of the temperature: 1/256 °C.
    pub const TEMP_LSB_DEGC: f64 = 1.0 / 256.0;

    /// A frame from physical values: increments rounded to the nearest count and
    /// saturated to the field's range; NaN gives 0. `fog_id` and `status` are taken as
    /// they are.
    pub fn from_physical(fog_id: u8, counter: u16, status: u8, dtheta_rad: f64, temperature_degc: f64) -> Self {
        FogFrame {
            fog_id,
            counter,
            status,
            dtheta_counts: counts_i32(dtheta_rad, Self::DTHETA_LSB_RAD),
            temperature_counts: counts_i16(temperature_degc, Self::TEMP_LSB_DEGC),
        }
    }

    /// Angle increment over the sample interval, rad.
    pub fn dtheta_rad(&self) -> f64 {
        f64::from(self.dtheta_counts) * Self::DTHETA_LSB_RAD
    }

    /// FOG temperature, °C.
    pub fn temperature_degc(&self) -> f64 {
        f64::from(self.temperature_counts) * Self::TEMP_LSB_DEGC
    }

    /// Whether the status reports a device fault (light source, loop lock or
    /// temperature sensor).
    pub fn device_fault(&self) -> bool {
        self.status & (status::LIGHT_SOURCE_FAULT | status::LOOP_LOCK_LOST | status::TEMP_SENSOR_FAULT) != 0
    }

    /// The frame's bytes.
    pub fn to_bytes(&self) -> [u8; Self::LEN] {
        let mut out = [0u8; Self::LEN];
        // Cannot fail: `out` is exactly one frame long.
        let _ = self.encode_into(&mut out);
        out
    }
}

impl Frame for FogFrame {
    const KIND: u8 = kind::FOG;
    const LEN: usize = FRAME_LEN;

    fn write_fields(&self, w: &mut FieldWriter<'_>) {
        w.u8(self.fog_id);
        w.u16(self.counter);
        w.u8(self.status);
        w.i32(self.dtheta_counts);
        w.i16(self.temperature_counts);
        w.u8(0);
    }

    fn read_fields(r: &mut FieldReader<'_>) -> Result<Self, DecodeError> {
        let fog_id = r.u8()?;
        let counter = r.u16()?;
        let status = r.u8()?;
        let dtheta_counts = r.i32()?;
        let temperature_counts = r.i16()?;
        let reserved = r.u8()?;
        if fog_id > MAX_FOG_ID || status & status::RESERVED != 0 || reserved != 0 {
            return Err(DecodeError::BadField);
        }
        Ok(FogFrame { fog_id, counter, status, dtheta_counts, temperature_counts })
    }
}
