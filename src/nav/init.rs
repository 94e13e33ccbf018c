//! The launch-vehicle unit's initialisation block: the pad alignment (initial navigation
//! state q_eb, v_e, r_e) and the GNSS filter's tuning, as the ground equipment loads it
//! before lift-off. Stored in its own flash region beside the accelerometer section
//! (`src/bin/ssis-fw-lv`); under QEMU the runner loads it with `-device loader`.
//!
//! Binary form, little-endian, [`BLOCK_LEN`] bytes:
//!
//! | off | size | field |
//! |---|---|---|
//! | 0 | 4 | magic `SSPI` |
//! | 4 | 2 | format version (1) |
//! | 6 | 2 | payload length (8 × [`N_F64`]) |
//! | 8 | 4 | revision |
//! | 12 | 8 × 20 | q_eb (w, x, y, z), v_e m/s (x, y, z), r_e m (x, y, z), then the [`GnssConfig`] fields in declaration order |
//! | 172 | 4 | CRC-32/ISO-HDLC over bytes 0..172 |
//!
//! Accepted only if every value is finite, ‖q_eb‖ is within 1e-6 of 1, the position is
//! outside [`wgs84::MIN_RADIUS_M`], every tuning figure is ≥ 0 and the gate > 0.

use nalgebra::{Quaternion, Vector3};

use super::gnss::GnssConfig;
use super::{wgs84, NavState};
use crate::calib::section::{self, SectionError};

/// Magic bytes.
pub const MAGIC: [u8; 4] = *b"SSPI";
/// Format version.
pub const FORMAT_VERSION: u16 = 1;
/// f64 fields: 4 + 3 + 3 of the state, 10 of the tuning.
pub const N_F64: usize = 20;
/// Binary length: header 12, fields, CRC-32 4.
pub const BLOCK_LEN: usize = section::section_len(N_F64);

/// Why a block was refused.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub enum InitError {
    /// Wrong length or declared payload length.
    Length,
    /// Wrong magic.
    Magic,
    /// Unknown format version.
    Version,
    /// CRC mismatch.
    Crc,
    /// A value is out of range (see the module documentation).
    Value,
}

impl From<SectionError> for InitError {
    fn from(e: SectionError) -> Self {
        match e {
            SectionError::Length => InitError::Length,
            SectionError::Magic => InitError::Magic,
            SectionError::Version => InitError::Version,
            SectionError::Crc => InitError::Crc,
        }
    }
}

/// Pad alignment and filter tuning.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PadInit {
    /// Block revision.
    pub revision: u32,
    /// Initial navigation state.
    pub state: NavState,
    /// GNSS filter tuning.
    pub gnss: GnssConfig,
}

impl PadInit {
    /// The f64 fields in storage order.
    pub fn fields(&self) -> [f64; N_F64] {
        let s = &self.state;
        let g = &self.gnss;
        [
            s.q_eb.w,
            s.q_eb.i,
            s.q_eb.j,
            s.q_eb.k,
            s.v_e_m_s.x,
            s.v_e_m_s.y,
            s.v_e_m_s.z,
            s.r_e_m.x,
            s.r_e_m.y,
            s.r_e_m.z,
            g.init_att_rad,
            g.init_vel_m_s,
            g.init_pos_m,
            g.init_accel_bias_m_s2,
            g.init_gyro_bias_rad_s,
            g.arw_rad_sqrt_s,
            g.vrw_m_s_sqrt_s,
            g.accel_bias_rw_m_s2_sqrt_s,
            g.gyro_bias_rw_rad_s_sqrt_s,
            g.gate_sigma,
        ]
    }

    fn from_fields(revision: u32, f: &[f64; N_F64]) -> Self {
        let [qw, qx, qy, qz, vx, vy, vz, rx, ry, rz, a, v, p, ba, bg, arw, vrw, barw, bgrw, gate] = *f;
        PadInit {
            revision,
            state: NavState {
                q_eb: Quaternion::new(qw, qx, qy, qz),
                v_e_m_s: Vector3::new(vx, vy, vz),
                r_e_m: Vector3::new(rx, ry, rz),
            },
            gnss: GnssConfig {
                init_att_rad: a,
                init_vel_m_s: v,
                init_pos_m: p,
                init_accel_bias_m_s2: ba,
                init_gyro_bias_rad_s: bg,
                arw_rad_sqrt_s: arw,
                vrw_m_s_sqrt_s: vrw,
                accel_bias_rw_m_s2_sqrt_s: barw,
                gyro_bias_rw_rad_s_sqrt_s: bgrw,
                gate_sigma: gate,
            },
        }
    }

    /// Checks every value (module documentation).
    pub fn validate(&self) -> Result<(), InitError> {
        let f = self.fields();
        if !f.iter().all(|v| v.is_finite()) {
            return Err(InitError::Value);
        }
        if (self.state.q_eb.norm() - 1.0).abs() > 1e-6 {
            return Err(InitError::Value);
        }
        if self.state.r_e_m.norm_squared() < wgs84::MIN_RADIUS_M * wgs84::MIN_RADIUS_M {
            return Err(InitError::Value);
        }
        let tuning = f.get(10..).unwrap_or(&[]);
        if tuning.iter().any(|v| *v < 0.0) || self.gnss.gate_sigma <= 0.0 {
            return Err(InitError::Value);
        }
        Ok(())
    }

    /// Binary form ([`crate::calib::section`]).
    pub fn to_bytes(&self) -> [u8; BLOCK_LEN] {
        let mut out = [0u8; BLOCK_LEN];
        section::encode(MAGIC, FORMAT_VERSION, self.revision, &self.fields(), &mut out);
        out
    }

    /// Decodes and validates a block: length, magic, version, declared payload length,
    /// CRC, values.
    pub fn from_bytes(bytes: &[u8]) -> Result<Self, InitError> {
        let (revision, f) = section::decode::<N_F64>(bytes, MAGIC, FORMAT_VERSION)?;
        let p = PadInit::from_fields(revision, &f);
        p.validate()?;
        Ok(p)
    }
}
