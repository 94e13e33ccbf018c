//! The background CRC of the code in flash: CRC-32C of the image (the board's
//! [`StepBoard::code_image`](super::exec::StepBoard::code_image), on the Cortex-M7
//! boards the vector table through `.rodata`), taken at boot as the reference and then
//! recomputed in slices of [`CODE_SLICE`] bytes every [`CODE_STEPS`] steps. A
//! difference is logged (`code_corrupt` in the event log, counted, and the defmt log)
//! and the executive resets the unit (snapshot, then the board's reset): a reset
//! reloads the image (QEMU's system reset rewrites every load segment; on the target
//! the CPU reads flash through ECC and caches, and a reset refetches it).
//!
//! When: a pass reads `len / CODE_SLICE` slices, one every `CODE_STEPS` steps. For
//! `ssis-fw` (130,664 B at 5 ms) 2,042 slices, a pass of 32,672 steps, **163 s**; for
//! `ssis-fw-lv` (128,324 B at 1.25 ms) 2,006 slices, **40 s**. A byte changed at a
//! random time and place is found at the end of the pass that next reads it: after one
//! pass on average, **two passes at worst** (changed just behind the read position):
//! the reset follows within 327 s (`ssis-fw`), 80 s (`ssis-fw-lv`).

use crate::flight::FlightCore;

/// Bytes of flash the code check reads a slice.
pub const CODE_SLICE: usize = 64;
/// Steps from one slice to the next: 4 bytes a step on average. A slice every
/// [`CODE_STEPS`] (not a few bytes every step) spends the per-call overhead once for 64
/// bytes; the flash changes far more rarely than the state in RAM.
pub const CODE_STEPS: u32 = 16;

/// The CRC-32C register at the start of a pass.
const CRC_INIT: u32 = crc::CRC_32_ISCSI.init;

/// CRC-32C of `bytes` continued from register `r` (the frames' four-bytes-a-pass CRC,
/// whose tables it shares: [`crate::frames::crc32c_register`]).
fn crc_on(r: u32, bytes: &[u8]) -> u32 {
    crate::frames::crc32c_register(r, bytes)
}

/// The background CRC of the code in flash (module doc).
pub struct CodeCheck {
    image: &'static [u8],
    reference: u32,
    pos: usize,
    /// The CRC-32C register over the bytes read so far in this pass.
    partial: u32,
    /// Steps since the last slice.
    tick: u32,
    mismatches: u32,
}

impl CodeCheck {
    /// Takes the reference CRC of `image` now (at boot: about 4 instructions a byte).
    #[inline(never)]
    pub fn new(image: &'static [u8]) -> Self {
        let reference = crc_on(CRC_INIT, image);
        CodeCheck { image, reference, pos: 0, partial: CRC_INIT, tick: 0, mismatches: 0 }
    }

    /// A step: one slice every [`CODE_STEPS`]; at the end of a pass, whether the image
    /// still has its reference CRC (`Some(false)`: it changed; logged and counted in
    /// `core`).
    #[inline(always)]
    pub fn step(&mut self, core: &mut FlightCore) -> Option<bool> {
        self.tick = self.tick.wrapping_add(1);
        if self.tick < CODE_STEPS {
            return None;
        }
        self.tick = 0;
        self.slice(core)
    }

    #[inline(never)]
    fn slice(&mut self, core: &mut FlightCore) -> Option<bool> {
        let end = (self.pos + CODE_SLICE).min(self.image.len());
        if let Some(bytes) = self.image.get(self.pos..end) {
            self.partial = crc_on(self.partial, bytes);
        }
        self.pos = end;
        if end < self.image.len() {
            return None;
        }
        self.pos = 0;
        let crc = core::mem::replace(&mut self.partial, CRC_INIT);
        let same = crc == self.reference;
        if !same {
            self.mismatches = self.mismatches.saturating_add(1);
            core.note_code_corrupt();
            #[cfg(target_os = "none")]
            defmt::error!("code check: flash CRC register {=u32:#010x}, {=u32:#010x} at boot", crc, self.reference);
        }
        Some(same)
    }

    /// Bytes covered and the reference CRC register (CRC-32C before its final XOR).
    pub fn image(&self) -> (usize, u32) {
        (self.image.len(), self.reference)
    }

    /// Passes that found the CRC changed.
    pub fn mismatches(&self) -> u32 {
        self.mismatches
    }
}
