//! What a Cortex-M7 board keeps against upsets and resets besides the flight core's own
//! checks: the memory the executive's after-step work uses (`ssis::bsp::exec`, which
//! runs it on one schedule for every board).
//!
//! - **Snapshot** ([`snapshot`]): two copies of the core's snapshot ([`Snapshots`],
//!   written in turn, so a reset that tears one write leaves the other) at the start of the layout's SNAP
//!   region, RAM no section is placed in (`memory.x`, `link/memory-lv.x`: neither
//!   cortex-m-rt's start-up nor QEMU's system reset, which rewrites every ELF load
//!   segment including `.uninit`, clears it), written by the executive every
//!   [`SNAPSHOT_STEPS`] and resumed at boot (check word, table, plausibility; its age
//!   at the first sample), then spoiled, so one snapshot is resumed at most once. A
//!   watchdog reset or a HardFault (which resets the unit: [`reset`]) comes back
//!   aligned, where it was; a cold start or a bad snapshot aligns on the star tracker.
//!   The rest of the region ([`snapshot_extra`]) is the mission's (the launch
//!   vehicle's navigation state).
//! - **Code image** ([`code_image`]): the vector table through `.rodata`, which the
//!   executive's code check (`ssis::bsp::code::CodeCheck`) covers.
#![allow(unsafe_code)]

use ssis::flight::snapshot::Snapshots;

pub use ssis::bsp::exec::SNAPSHOT_STEPS;

extern "C" {
    /// The SNAP region of the layout (`memory.x`): RAM no section is placed in.
    static mut _snapshot_start: u32;
    static _snapshot_len: u8;
}

/// The snapshot's two copies in RAM the reset does not clear (the layout's SNAP region),
/// as plain words (any bit pattern is a value: `Snapshot` holds only plain numbers).
/// Only the main loop calls this, once, so the reference is unique; a layout whose
/// region is too small gets `None`.
pub fn snapshot() -> Option<&'static mut Snapshots> {
    let len = core::ptr::addr_of!(_snapshot_len) as usize;
    if len < core::mem::size_of::<Snapshots>() {
        return None;
    }
    // SAFETY: the SNAP region is word-aligned RAM of at least `size_of::<Snapshots>()`
    // bytes (checked), used by nothing else; `Snapshots` is `repr(C)` plain numbers,
    // valid for any bit pattern (RAM after a cold start holds some pattern; each copy's
    // CRC judges it); the main loop takes this reference once and no interrupt touches it.
    unsafe { Some(&mut *(core::ptr::addr_of_mut!(_snapshot_start) as *mut Snapshots)) }
}

/// The part of the SNAP region after the core's [`Snapshots`]: the mission's extra
/// state that survives a reset (the launch vehicle's navigation), as plain words; empty
/// when the region holds no more. Only the mission takes it, once, so the reference is
/// unique.
pub fn snapshot_extra() -> &'static mut [u32] {
    let len = core::ptr::addr_of!(_snapshot_len) as usize;
    let core_words = core::mem::size_of::<Snapshots>().div_ceil(4);
    let words = (len / 4).saturating_sub(core_words);
    // SAFETY: the words after the core's snapshot inside the SNAP region (its length
    // from the layout), word-aligned RAM used by nothing else; any bit pattern is a
    // `u32`; taken once by the mission, disjoint from `snapshot`'s reference.
    unsafe { core::slice::from_raw_parts_mut(core::ptr::addr_of_mut!(_snapshot_start).wrapping_add(core_words), words) }
}

/// Resets the unit (SYSRESETREQ): the HardFault's way out, so an upset of the program
/// counter or the stack pointer costs a reset and a resume, not the rest of the flight.
pub fn reset() -> ! {
    cortex_m::peripheral::SCB::sys_reset()
}

extern "C" {
    static __vector_table: u32;
    static __erodata: u32;
}

/// The flash image the code check covers: the vector table through `.rodata`.
pub fn code_image() -> &'static [u8] {
    let start = core::ptr::addr_of!(__vector_table) as usize;
    let end = core::ptr::addr_of!(__erodata) as usize;
    // SAFETY: [vector table, end of .rodata) is the firmware's own image in flash,
    // mapped and never written.
    unsafe { core::slice::from_raw_parts(start as *const u8, end.saturating_sub(start)) }
}
