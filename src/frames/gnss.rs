//! GNSS fix frame (kind 0x21, 47 bytes): one position/velocity solution of the
//! launch vehicle's GNSS receiver (GPS/GLONASS), on its own RS-422 link.
//!
//! | off | size | field | type | scaling |
//! |---|---|---|---|---|
//! | 0 | 2 | sync | `EB 90` | |
//! | 2 | 1 | kind | `0x21` | |
//! | 3 | 1 | status | u8 | [`status`] bits; bits 3–7 zero |
//! | 4 | 2 | counter | u16 | fix counter, wraps |
//! | 6 | 1 | satellites | u8 | satellites in the solution |
//! | 7 | 8 | time_tag | u64 | µs of unit time at which the fix holds |
//! | 15 | 12 | r x,y,z | 3 × i32 | ECEF position, LSB 2^-8 m (±8,388 km) |
//! | 27 | 12 | v x,y,z | 3 × i32 | ECEF velocity, LSB 2^-16 m/s (±32,768 m/s) |
//! | 39 | 2 | sigma_pos | u16 | position 1σ per axis, LSB 0.01 m |
//! | 41 | 2 | sigma_vel | u16 | velocity 1σ per axis, LSB 0.001 m/s |
//! | 43 | 4 | crc | u32 | CRC-32C over bytes 0..43 |
//!
//! A frame with reserved status bits set is rejected; a frame without the
//! [`status::FIX_VALID`] bit decodes (it carries the receiver's state) but gives no fix.

use nalgebra::Vector3;

use super::{counts_i32, counts_u16, kind, DecodeError, FieldReader, FieldWriter, Frame};

/// One GNSS position/velocity fix, ECEF, the physical content of a
/// [`GnssFrame`]; the navigation applies it after the step it is valid at the end of.
#[derive(Debug, Clone, Copy, PartialEq, bytemuck::AnyBitPattern)]
pub struct GnssFix {
    /// Position, m.
    pub r_e_m: Vector3<f64>,
    /// Velocity, m/s.
    pub v_e_m_s: Vector3<f64>,
    /// Position standard deviation per axis, m.
    pub sigma_pos_m: f64,
    /// Velocity standard deviation per axis, m/s.
    pub sigma_vel_m_s: f64,
}

/// Length of a GNSS frame in bytes.
pub const FRAME_LEN: usize = 47;
const _: () = assert!(FRAME_LEN == 3 + 1 + 2 + 1 + 8 + 12 + 12 + 2 + 2 + 4);

/// LSB of a position component: 2^-8 m.
pub const POS_LSB_M: f64 = 1.0 / 256.0;
/// LSB of a velocity component: 2^-16 m/s.
pub const VEL_LSB_M_S: f64 = 1.0 / 65_536.0;
/// LSB of the position sigma: 0.01 m.
pub const SIGMA_POS_LSB_M: f64 = 0.01;
/// LSB of the velocity sigma: 0.001 m/s.
pub const SIGMA_VEL_LSB_M_S: f64 = 0.001;

/// Bits of the GNSS status byte.
pub mod status {
    /// The position/velocity solution is valid.
    pub const FIX_VALID: u8 = 1 << 0;
    /// Three-dimensional solution (not altitude-held).
    pub const FIX_3D: u8 = 1 << 1;
    /// Receiver fault (antenna, clock).
    pub const RECEIVER_FAULT: u8 = 1 << 2;
    /// Reserved bits: must be zero, else the frame is rejected.
    pub const RESERVED: u8 = 0xF8;
}

/// One GNSS fix as carried on the link (raw counts).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, bytemuck::AnyBitPattern)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub struct GnssFrame {
    /// Status bits ([`status`]).
    pub status: u8,
    /// Fix counter (wraps).
    pub counter: u16,
    /// Satellites used.
    pub satellites: u8,
    /// µs of unit time at which the fix holds.
    pub time_tag_us: u64,
    /// ECEF position, counts of [`POS_LSB_M`].
    pub r_counts: [i32; 3],
    /// ECEF velocity, counts of [`VEL_LSB_M_S`].
    pub v_counts: [i32; 3],
    /// Position 1σ, counts of [`SIGMA_POS_LSB_M`].
    pub sigma_pos_counts: u16,
    /// Velocity 1σ, counts of [`SIGMA_VEL_LSB_M_S`].
    pub sigma_vel_counts: u16,
}

impl GnssFrame {
    /// Frame length in bytes (same as [`Frame::LEN`]).
    pub const LEN: usize = FRAME_LEN;

    /// A frame from physical values (rounded to the nearest count and saturated; NaN
    /// gives 0).
    pub fn from_physical(status: u8, counter: u16, satellites: u8, time_tag_us: u64, fix: &GnssFix) -> Self {
        let r = fix.r_e_m;
        let v = fix.v_e_m_s;
        GnssFrame {
            status,
            counter,
            satellites,
            time_tag_us,
            r_counts: [r.x, r.y, r.z].map(|c| counts_i32(c, POS_LSB_M)),
            v_counts: [v.x, v.y, v.z].map(|c| counts_i32(c, VEL_LSB_M_S)),
            sigma_pos_counts: counts_u16(fix.sigma_pos_m, SIGMA_POS_LSB_M),
            sigma_vel_counts: counts_u16(fix.sigma_vel_m_s, SIGMA_VEL_LSB_M_S),
        }
    }

    /// The fix it carries, if the status says it is valid and the receiver is not in
    /// fault (a zero sigma is read as one LSB, so the filter never sees a zero variance).
    pub fn fix(&self) -> Option<GnssFix> {
        if self.status & status::FIX_VALID == 0 || self.status & status::RECEIVER_FAULT != 0 {
            return None;
        }
        let [rx, ry, rz] = self.r_counts.map(|c| f64::from(c) * POS_LSB_M);
        let [vx, vy, vz] = self.v_counts.map(|c| f64::from(c) * VEL_LSB_M_S);
        Some(GnssFix {
            r_e_m: Vector3::new(rx, ry, rz),
            v_e_m_s: Vector3::new(vx, vy, vz),
            sigma_pos_m: f64::from(self.sigma_pos_counts.max(1)) * SIGMA_POS_LSB_M,
            sigma_vel_m_s: f64::from(self.sigma_vel_counts.max(1)) * SIGMA_VEL_LSB_M_S,
        })
    }

    /// The frame's bytes.
    pub fn to_bytes(&self) -> [u8; Self::LEN] {
        let mut out = [0u8; Self::LEN];
        // Cannot fail: `out` is exactly one frame long.
        let _ = self.encode_into(&mut out);
        out
    }
}

impl Frame for GnssFrame {
    const KIND: u8 = kind::GNSS;
    const LEN: usize = FRAME_LEN;

    fn write_fields(&self, w: &mut FieldWriter<'_>) {
        w.u8(self.status);
        w.u16(self.counter);
        w.u8(self.satellites);
        w.u64(self.time_tag_us);
        for c in self.r_counts.iter().chain(self.v_counts.iter()) {
            w.i32(*c);
        }
        w.u16(self.sigma_pos_counts);
        w.u16(self.sigma_vel_counts);
    }

    fn read_fields(r: &mut FieldReader<'_>) -> Result<Self, DecodeError> {
        let status = r.u8()?;
        let counter = r.u16()?;
        let satellites = r.u8()?;
        let time_tag_us = r.u64()?;
        let r_counts = [r.i32()?, r.i32()?, r.i32()?];
        let v_counts = [r.i32()?, r.i32()?, r.i32()?];
        let sigma_pos_counts = r.u16()?;
        let sigma_vel_counts = r.u16()?;
        if status & status::RESERVED != 0 {
            return Err(DecodeError::BadField);
        }
        Ok(GnssFrame {
            status,
            counter,
            satellites,
            time_tag_us,
            r_counts,
            v_counts,
            sigma_pos_counts,
            sigma_vel_counts,
        })
    }
}
