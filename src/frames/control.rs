//! Control frame (kind 0x40, 18 bytes): test equipment → unit, on the output link's
//! receive line. It lets a runner step the unit in lockstep with a simulator and end a
//! run; only a test build (`test-hooks`) acts on it, a flight build counts and ignores it
//! (`ssis_firmware::mps2::Pacer`).
//!
//! | off | size | field | type | meaning |
//! |---|---|---|---|---|
//! | 0 | 2 | sync | `EB 90` | |
//! | 2 | 1 | kind | `0x40` | |
//! | 3 | 1 | command | u8 | [`command`] |
//! | 4 | 4 | fog_bytes | u32 | lockstep: total bytes sent on the FOG bus so far |
//! | 8 | 4 | st_bytes | u32 | lockstep: total bytes sent on the star-tracker link so far |
//! | 12 | 2 | arg | u16 | command argument (reserved, 0) |
//! | 14 | 4 | crc | u32 | CRC-32C over bytes 0..14 |
//!
//! In lockstep the unit steps once per `STEP`, after it has received the totals named.
//! `STALL` and `TICK_STOP` exist for the watchdog and stopped-tick tests.

use super::{kind, DecodeError, FieldReader, FieldWriter, Frame};

/// Length of a control frame in bytes.
pub const FRAME_LEN: usize = 18;

/// Command codes.
pub mod command {
    /// Leave timer-driven stepping; step on `STEP` only.
    pub const LOCKSTEP: u8 = 1;
    /// Step once when the byte totals have arrived (lockstep).
    pub const STEP: u8 = 2;
    /// Report and end the run (under QEMU: exit with success).
    pub const END: u8 = 3;
    /// Fault injection: stop feeding the watchdog (the main loop spins).
    pub const STALL: u8 = 4;
    /// Fault injection: the firmware clears the SysTick's enable bit itself, between
    /// two steps (a stopped tick without the debugger halting the guest around it).
    pub const TICK_STOP: u8 = 5;
}

/// One control frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub struct ControlFrame {
    /// Command ([`command`]).
    pub command: u8,
    /// Total bytes sent on the FOG bus so far.
    pub fog_bytes: u32,
    /// Total bytes sent on the star-tracker link so far.
    pub st_bytes: u32,
    /// Argument (0).
    pub arg: u16,
}

impl ControlFrame {
    /// Frame length in bytes.
    pub const LEN: usize = FRAME_LEN;

    /// The frame's bytes.
    pub fn to_bytes(&self) -> [u8; Self::LEN] {
        let mut out = [0u8; Self::LEN];
        // Cannot fail: `out` is exactly one frame long.
        let _ = self.encode_into(&mut out);
        out
    }
}

impl Frame for ControlFrame {
    const KIND: u8 = kind::CONTROL;
    const LEN: usize = FRAME_LEN;

    fn write_fields(&self, w: &mut FieldWriter<'_>) {
        w.u8(self.command);
        w.u32(self.fog_bytes);
        w.u32(self.st_bytes);
        w.u16(self.arg);
    }

    fn read_fields(r: &mut FieldReader<'_>) -> Result<Self, DecodeError> {
        let command = r.u8()?;
        if !(command::LOCKSTEP..=command::TICK_STOP).contains(&command) {
            return Err(DecodeError::BadField);
        }
        Ok(ControlFrame { command, fog_bytes: r.u32()?, st_bytes: r.u32()?, arg: r.u16()? })
    }
}
