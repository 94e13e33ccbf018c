//! Star-tracker frame (kind 0x20, 34 bytes): one attitude solution with its time tag.
//!
//! | off | size | field | type | scaling |
//! |---|---|---|---|---|
//! | 0 | 2 | sync | `EB 90` | |
//! | 2 | 1 | kind | `0x20` | |
//! | 3 | 1 | flags | u8 | [`flags`] bits; bits 2–7 zero |
//! | 4 | 2 | counter | u16 | frame counter, wraps |
//! | 6 | 8 | time_tag | u64 | µs of unit time at which the quaternion holds |
//! | 14 | 16 | q0..q3 | 4 × i32 | star-tracker frame in 2ECS, scalar first, LSB 2^-31 |
//! | 30 | 4 | crc | u32 | CRC-32C over bytes 0..30 |
//!
//! A quaternion whose norm differs from 1 by more than [`NORM_TOLERANCE`] is rejected.

use super::{counts_i32, kind, DecodeError, FieldReader, FieldWriter, Frame};

/// Length of a star-tracker frame in bytes.
pub const FRAME_LEN: usize = 34;

/// LSB of a quaternion component: 2^-31.
pub const Q_LSB: f64 = 1.0 / 2_147_483_648.0;

/// Largest accepted |‖q‖ − 1| of a received quaternion.
pub const NORM_TOLERANCE: f64 = 1e-6;

/// Bits of the star-tracker flags byte.
pub mod flags {
    /// The attitude solution is valid.
    pub const VALID: u8 = 1 << 0;
    /// The tracker is in high-rate mode.
    pub const HIGH_RATE: u8 = 1 << 1;
    /// Reserved bits: must be zero, else the frame is rejected.
    pub const RESERVED: u8 = 0xFC;
}

/// One star-tracker solution as carried on the link (raw counts).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, bytemuck::AnyBitPattern)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub struct StarFrame {
    /// Flag bits ([`flags`]).
    pub flags: u8,
    /// Frame counter (wraps).
    pub counter: u16,
    /// Unit time at which the quaternion holds, µs.
    pub time_us: u64,
    /// Quaternion of the star-tracker frame in 2ECS, scalar first, counts of [`Q_LSB`].
    pub q_counts: [i32; 4],
}

/// A [`StarFrame`] as a queue of the state stores it: the same fields without padding
/// ([`crate::state::Ring`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, bytemuck::Pod, bytemuck::Zeroable)]
#[repr(C)]
pub struct StarSlot {
    time_us: u64,
    q_counts: [i32; 4],
    counter: u16,
    flags: u8,
    _pad: [u8; 5],
}

impl From<StarFrame> for StarSlot {
    #[inline(always)]
    fn from(f: StarFrame) -> Self {
        StarSlot { time_us: f.time_us, q_counts: f.q_counts, counter: f.counter, flags: f.flags, _pad: [0; 5] }
    }
}

impl From<StarSlot> for StarFrame {
    #[inline(always)]
    fn from(s: StarSlot) -> Self {
        StarFrame { flags: s.flags, counter: s.counter, time_us: s.time_us, q_counts: s.q_counts }
    }
}

impl StarFrame {
    /// Frame length in bytes (same as [`Frame::LEN`]).
    pub const LEN: usize = FRAME_LEN;
    /// LSB of a quaternion component: 2^-31.
    pub const Q_LSB: f64 = Q_LSB;

    /// A frame from a physical quaternion (scalar first): components rounded to the
    /// nearest count and saturated (so +1.0 encodes as 1 − 2^-31); NaN gives 0.
    /// `flags` are taken as they are.
    pub fn from_physical(flags: u8, counter: u16, time_us: u64, q: [f64; 4]) -> Self {
        StarFrame { flags, counter, time_us, q_counts: q.map(|c| counts_i32(c, Q_LSB)) }
    }

    /// The quaternion, scalar first (as sent, not renormalised).
    pub fn quaternion(&self) -> [f64; 4] {
        self.q_counts.map(|c| f64::from(c) * Q_LSB)
    }

    /// Whether the tracker flags its attitude solution valid.
    pub fn valid(&self) -> bool {
        self.flags & flags::VALID != 0
    }

    /// Whether the tracker is in high-rate mode.
    pub fn high_rate(&self) -> bool {
        self.flags & flags::HIGH_RATE != 0
    }

    /// The frame's bytes.
    pub fn to_bytes(&self) -> [u8; Self::LEN] {
        let mut out = [0u8; Self::LEN];
        // Cannot fail: `out` is exactly one frame long.
        let _ = self.encode_into(&mut out);
        out
    }
}

/// Whether quaternion counts have a norm within [`NORM_TOLERANCE`] of 1.
///
/// The sum of squares is exact in integers and compared with the squared bounds in
/// integers, so the test is the same on every machine. Each square is at most 2⁶², so
/// only four components of −2³¹ reach 2⁶⁴: the sum saturates there, far beyond the
/// upper bound.
pub fn norm_ok(q_counts: &[i32; 4]) -> bool {
    // (2^31)^2; the bounds are integers already (multiples of 2^10 near 2^62), so the
    // casts are exact.
    const SCALE: f64 = 2_147_483_648.0 * 2_147_483_648.0;
    const LO: u64 = ((1.0 - NORM_TOLERANCE) * (1.0 - NORM_TOLERANCE) * SCALE) as u64;
    const HI: u64 = ((1.0 + NORM_TOLERANCE) * (1.0 + NORM_TOLERANCE) * SCALE) as u64;
    let sum = q_counts.iter().fold(0u64, |sum, &c| {
        let a = u64::from(c.unsigned_abs());
        sum.saturating_add(a * a)
    });
    (LO..=HI).contains(&sum)
}

impl Frame for StarFrame {
    const KIND: u8 = kind::STAR;
    const LEN: usize = FRAME_LEN;

    fn write_fields(&self, w: &mut FieldWriter<'_>) {
        w.u8(self.flags);
        w.u16(self.counter);
        w.u64(self.time_us);
        for c in self.q_counts {
            w.i32(c);
        }
    }

    fn read_fields(r: &mut FieldReader<'_>) -> Result<Self, DecodeError> {
        let flags = r.u8()?;
        let counter = r.u16()?;
        let time_us = r.u64()?;
        let q_counts = [r.i32()?, r.i32()?, r.i32()?, r.i32()?];
        if flags & flags::RESERVED != 0 || !norm_ok(&q_counts) {
            return Err(DecodeError::BadField);
        }
        Ok(StarFrame { flags, counter, time_us, q_counts })
    }
}
