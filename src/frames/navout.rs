//! Navigation output frame (kind 0x31, 66 bytes): the launch-vehicle unit's navigation
//! state after each step (attitude, velocity, position in ECEF).
//!
//! | off | size | field | type | scaling |
//! |---|---|---|---|---|
//! | 0 | 2 | sync | `EB 90` | |
//! | 2 | 1 | kind | `0x31` | |
//! | 3 | 1 | flags | u8 | [`flags`] bits; bits 4–7 sent as zero |
//! | 4 | 2 | counter | u16 | frame counter, wraps |
//! | 6 | 8 | time_tag | u64 | µs of unit time at the end of the step |
//! | 14 | 16 | q0..q3 | 4 × i32 | body in ECEF, scalar first, LSB 2^-31 |
//! | 30 | 12 | v x,y,z | 3 × i32 | ECEF velocity, LSB 2^-16 m/s (±32,768 m/s) |
//! | 42 | 12 | r x,y,z | 3 × i32 | ECEF position, LSB 2^-8 m (±8,388 km) |
//! | 54 | 2 | sigma_pos | u16 | filter position 1σ (3-D), LSB 0.01 m |
//! | 56 | 2 | sigma_vel | u16 | filter velocity 1σ (3-D), LSB 0.001 m/s |
//! | 58 | 2 | fixes_used | u16 | GNSS fixes used (saturating) |
//! | 60 | 2 | fixes_refused | u16 | GNSS fixes refused (saturating) |
//! | 62 | 4 | crc | u32 | CRC-32C over bytes 0..62 |
//!
//! At 1.25 ms the frame is 51,200 bytes/s (512 kbit/s with start and stop bits). The
//! decoder checks only the envelope: every field value is accepted.

use nalgebra::{Quaternion, Vector3};

use super::{counts_i32, counts_u16, kind, DecodeError, FieldReader, FieldWriter, Frame};

/// Navigation state at the end of a step (what [`NavOutputFrame`] carries; the
/// navigation, `crate::nav`, computes it).
#[derive(Debug, Clone, Copy, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
#[repr(C)]
pub struct NavState {
    /// Attitude of the body frame in ECEF (unit quaternion).
    pub q_eb: Quaternion<f64>,
    /// Velocity relative to the Earth, ECEF components, m/s.
    pub v_e_m_s: Vector3<f64>,
    /// Position, ECEF, m.
    pub r_e_m: Vector3<f64>,
}

/// Length of a navigation output frame in bytes.
pub const FRAME_LEN: usize = 66;
const _: () = assert!(FRAME_LEN == 3 + 1 + 2 + 8 + 16 + 12 + 12 + 2 + 2 + 2 + 2 + 4);

/// LSB of a quaternion component: 2^-31.
pub const Q_LSB: f64 = 1.0 / 2_147_483_648.0;
/// LSB of a velocity component: 2^-16 m/s.
pub const VEL_LSB_M_S: f64 = 1.0 / 65_536.0;
/// LSB of a position component: 2^-8 m.
pub const POS_LSB_M: f64 = 1.0 / 256.0;
/// LSB of the position sigma: 0.01 m.
pub const SIGMA_POS_LSB_M: f64 = 0.01;
/// LSB of the velocity sigma: 0.001 m/s.
pub const SIGMA_VEL_LSB_M_S: f64 = 0.001;

/// Bits of the flags byte.
pub mod flags {
    /// A GNSS fix was applied since the previous frame (by the filter work after the
    /// previous step, `crate::nav::unit`): this frame's state is the first to include it.
    pub const GNSS_UPDATED: u8 = 1 << 0;
    /// No GNSS fix used for more than 2 s: free inertial.
    pub const GNSS_OUTAGE: u8 = 1 << 1;
    /// A navigation step was refused (non-finite increment or state); the state was held.
    pub const NAV_FAULT: u8 = 1 << 2;
    /// Accelerometer data missing or faulty in this step.
    pub const ACCEL_FAULT: u8 = 1 << 3;
    /// The attitude is not confirmed: a resume after a reset could not back it (its
    /// bridge over the lost samples had no fit, or one whose stated error is too large,
    /// `crate::nav::snapshot`); position and velocity stand. Held until a pad
    /// initialisation.
    pub const ATTITUDE_UNCONFIRMED: u8 = 1 << 4;
}

/// The navigation output as carried on the link (raw counts).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub struct NavOutputFrame {
    /// Flag bits ([`flags`]).
    pub flags: u8,
    /// Frame counter (wraps).
    pub counter: u16,
    /// µs of unit time at the end of the step.
    pub time_tag_us: u64,
    /// q_eb, scalar first, counts of [`Q_LSB`].
    pub q_counts: [i32; 4],
    /// ECEF velocity, counts of [`VEL_LSB_M_S`].
    pub v_counts: [i32; 3],
    /// ECEF position, counts of [`POS_LSB_M`].
    pub r_counts: [i32; 3],
    /// Position 1σ, counts of [`SIGMA_POS_LSB_M`].
    pub sigma_pos_counts: u16,
    /// Velocity 1σ, counts of [`SIGMA_VEL_LSB_M_S`].
    pub sigma_vel_counts: u16,
    /// GNSS fixes used.
    pub fixes_used: u16,
    /// GNSS fixes refused.
    pub fixes_refused: u16,
}

impl NavOutputFrame {
    /// Frame length in bytes (same as [`Frame::LEN`]).
    pub const LEN: usize = FRAME_LEN;

    /// A frame from the navigation state and the filter's figures (rounded to the
    /// nearest count and saturated; NaN gives 0; counts above 65,535 saturate).
    pub fn from_physical(
        flags: u8,
        counter: u16,
        time_tag_us: u64,
        state: &NavState,
        sigma_pos_vel: (f64, f64),
        fixes: (u32, u32),
    ) -> Self {
        let q = state.q_eb;
        let v = state.v_e_m_s;
        let r = state.r_e_m;
        let sat = |n: u32| u16::try_from(n).unwrap_or(u16::MAX);
        NavOutputFrame {
            flags,
            counter,
            time_tag_us,
            q_counts: [q.w, q.i, q.j, q.k].map(|c| counts_i32(c, Q_LSB)),
            v_counts: [v.x, v.y, v.z].map(|c| counts_i32(c, VEL_LSB_M_S)),
            r_counts: [r.x, r.y, r.z].map(|c| counts_i32(c, POS_LSB_M)),
            sigma_pos_counts: counts_u16(sigma_pos_vel.0, SIGMA_POS_LSB_M),
            sigma_vel_counts: counts_u16(sigma_pos_vel.1, SIGMA_VEL_LSB_M_S),
            fixes_used: sat(fixes.0),
            fixes_refused: sat(fixes.1),
        }
    }

    /// The navigation state it carries.
    pub fn state(&self) -> NavState {
        let [w, i, j, k] = self.q_counts.map(|c| f64::from(c) * Q_LSB);
        let [vx, vy, vz] = self.v_counts.map(|c| f64::from(c) * VEL_LSB_M_S);
        let [rx, ry, rz] = self.r_counts.map(|c| f64::from(c) * POS_LSB_M);
        NavState {
            q_eb: Quaternion::new(w, i, j, k),
            v_e_m_s: Vector3::new(vx, vy, vz),
            r_e_m: Vector3::new(rx, ry, rz),
        }
    }

    /// The frame's bytes.
    pub fn to_bytes(&self) -> [u8; Self::LEN] {
        let mut out = [0u8; Self::LEN];
        // Cannot fail: `out` is exactly one frame long.
        let _ = self.encode_into(&mut out);
        out
    }
}

impl Frame for NavOutputFrame {
    const KIND: u8 = kind::NAV_OUTPUT;
    const LEN: usize = FRAME_LEN;

    fn write_fields(&self, w: &mut FieldWriter<'_>) {
        w.u8(self.flags);
        w.u16(self.counter);
        w.u64(self.time_tag_us);
        for c in self.q_counts.iter().chain(self.v_counts.iter()).chain(self.r_counts.iter()) {
            w.i32(*c);
        }
        w.u16(self.sigma_pos_counts);
        w.u16(self.sigma_vel_counts);
        w.u16(self.fixes_used);
        w.u16(self.fixes_refused);
    }

    fn read_fields(r: &mut FieldReader<'_>) -> Result<Self, DecodeError> {
        let flags = r.u8()?;
        let counter = r.u16()?;
        let time_tag_us = r.u64()?;
        let q_counts = [r.i32()?, r.i32()?, r.i32()?, r.i32()?];
        let v_counts = [r.i32()?, r.i32()?, r.i32()?];
        let r_counts = [r.i32()?, r.i32()?, r.i32()?];
        Ok(NavOutputFrame {
            flags,
            counter,
            time_tag_us,
            q_counts,
            v_counts,
            r_counts,
            sigma_pos_counts: r.u16()?,
            sigma_vel_counts: r.u16()?,
            fixes_used: r.u16()?,
            fixes_refused: r.u16()?,
        })
    }
}
