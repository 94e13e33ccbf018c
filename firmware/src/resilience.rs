//! What a Cortex-M7 board keeps against upsets and resets, besides the flight core's own
//! checks: the reset snapshot in RAM the reset does not clear, and the background CRC
//! of the code in flash.
//!
//! - **Snapshot** ([`snapshot`]): one [`Snapshot`] in the layout's SNAP region, RAM no
//!   section is placed in (`memory.x`: neither cortex-m-rt's start-up nor QEMU's system
//!   reset, which rewrites every ELF load segment including `.uninit`, clears it),
//!   written by the main loop every
//!   [`SNAPSHOT_STEPS`] through [`FlightCore::snapshot_into`] and read at boot by
//!   [`resume`], which hands it to [`FlightCore::resume`] (check word, table, plausibility; its
//!   age at the first sample) and spoils it, so one snapshot is resumed at most once. A
//!   watchdog reset or a HardFault (which resets the unit: [`reset`]) comes back
//!   aligned, where it was; a cold start or a bad snapshot aligns on the star tracker.
//! - **Code check** ([`CodeCheck`]): CRC-32C of the image in flash, the vector table
//!   through `.rodata`, taken at boot as the reference and then recomputed in slices of
//!   [`CODE_SLICE`] bytes every [`CODE_STEPS`] steps (a pass about 170 s at 5 ms for the
//!   128 KiB image); a difference is logged (`code_corrupt` in the event
//!   log, counted) and reported. On the target flash is not what an upset changes (the
//!   CPU reads it through ECC and caches); a reset re-reads it.
//! - **Rings** ([`reset_on_ring_fault`]): a corrupted borrow flag of a link's ring
//!   (`ssis::link::ring_faults`) resets the unit after a snapshot.
#![allow(unsafe_code)]

use ssis::flight::snapshot::Snapshot;
use ssis::flight::FlightCore;

/// Steps between two snapshots (400 ms at 5 ms): a snapshot costs about 1,200
/// instructions (its 104 words written and checksummed, the mean increment since the
/// one before), some 15 a step spread this thin (BENCHMARKS.md). The resume bridges
/// the snapshot's age (up to this period and the time the unit was down) on that mean
/// increment, corrected by the turn's trend, at the same accuracy at any phase of the
/// period (`tests/resume.rs`).
pub const SNAPSHOT_STEPS: u32 = 80;

extern "C" {
    /// The SNAP region of the layout (`memory.x`): RAM no section is placed in.
    static mut _snapshot_start: u32;
    static _snapshot_len: u8;
}

/// The snapshot in RAM the reset does not clear (the layout's SNAP region), as plain
/// words (any bit pattern is a value: `Snapshot` holds only `u32`s). Only the main loop
/// calls this, once, so the reference is unique; a layout whose region is too small
/// gets `None`.
pub fn snapshot() -> Option<&'static mut Snapshot> {
    let len = core::ptr::addr_of!(_snapshot_len) as usize;
    if len < core::mem::size_of::<Snapshot>() {
        return None;
    }
    // SAFETY: the SNAP region is word-aligned RAM of at least `size_of::<Snapshot>()`
    // bytes (checked), used by nothing else; `Snapshot` is `repr(C)` u32 words, valid for
    // any bit pattern (RAM after a cold start holds some pattern; its CRC judges it); the
    // main loop takes this reference once and no interrupt touches it.
    unsafe { Some(&mut *(core::ptr::addr_of_mut!(_snapshot_start) as *mut Snapshot)) }
}

/// At boot, with the core just built: resumes it from the snapshot if that passes its
/// checks, and spoils the snapshot either way (it is rewritten within
/// [`SNAPSHOT_STEPS`] once the unit is aligned). Logged on the board's log and in the
/// core's event log.
#[inline(never)]
pub fn resume(core: &mut FlightCore, snap: &mut Snapshot) {
    match core.resume(snap) {
        Ok(()) => defmt::warn!("reset: resumed from the snapshot taken at sample {}", snap.index()),
        Err(e) => defmt::info!("no snapshot resumed ({}): aligning on the star tracker", e),
    }
    snap.invalidate();
}

/// A receive or transmit ring whose borrow flag is corrupted takes no byte again
/// ([`ssis::link::ring_faults`]; the FOG intake or the output link lost for good): the
/// main loop calls this on the first such fault, which logs it, runs `save` (the
/// snapshot: the core's own state is intact and guarded) and resets the unit, whose rings
/// start empty and which resumes from the snapshot.
#[inline(never)]
#[cold]
pub fn reset_on_ring_fault(save: impl FnOnce()) -> ! {
    defmt::error!(
        "a ring's borrow flag is corrupted ({} failed borrows): snapshot and reset",
        ssis::link::ring_faults()
    );
    save();
    reset()
}

/// Resets the unit (SYSRESETREQ): the HardFault's way out, so an upset of the program
/// counter or the stack pointer costs a reset and a resume, not the rest of the flight.
pub fn reset() -> ! {
    cortex_m::peripheral::SCB::sys_reset()
}

/// Bytes of flash the code check reads a slice.
pub const CODE_SLICE: usize = 64;
/// Steps from one slice to the next: 4 bytes a step on average, the 128 KiB image in
/// about 170 s at 5 ms. A slice every [`CODE_STEPS`] (not a few bytes every step) spends
/// the per-call overhead once for 64 bytes; the flash changes far more rarely than the
/// state in RAM (module doc).
pub const CODE_STEPS: u32 = 16;

extern "C" {
    static __vector_table: u32;
    static __erodata: u32;
}

/// The flash image the code check covers: the vector table through `.rodata`.
fn code_image() -> &'static [u8] {
    let start = core::ptr::addr_of!(__vector_table) as usize;
    let end = core::ptr::addr_of!(__erodata) as usize;
    // SAFETY: [vector table, end of .rodata) is the firmware's own image in flash,
    // mapped and never written.
    unsafe { core::slice::from_raw_parts(start as *const u8, end.saturating_sub(start)) }
}

/// The CRC-32C register at the start of a pass.
const CRC_INIT: u32 = crc::CRC_32_ISCSI.init;

/// CRC-32C of `bytes` continued from register `r` (the register after them): the
/// frames' four-bytes-a-pass CRC, whose tables it shares, out of line
/// ([`ssis::frames::crc32c_register`]).
fn crc_on(r: u32, bytes: &[u8]) -> u32 {
    ssis::frames::crc32c_register(r, bytes)
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
    /// Takes the reference CRC of the image now (at boot: about 4 instructions a byte).
    #[inline(never)]
    pub fn new() -> Self {
        let image = code_image();
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

impl Default for CodeCheck {
    fn default() -> Self {
        Self::new()
    }
}
