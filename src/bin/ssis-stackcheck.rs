//! On-target test of the stack-overflow protection (issue 6, README "No panics, stack
//! overflow"): recurses until the stack runs out, under the flight firmware's own board
//! code (`ssis-fw/board.rs`: fault handler, logger, panic handler) and memory layout
//! (`memory.x`: the stack below the statics).
//!
//! Before it descends further, every level checks that the statics (all of .data, .bss
//! and .uninit, from `_ram_start` to `__sheap`) still hold what they held at the start; a
//! change is logged as `statics damaged` and ends the run. With the protection the
//! overflow is a fault below the stack's bottom: the HardFault handler logs
//! `stack overflow: …` and exits QEMU with failure, and no level ever sees the statics
//! changed. Run by `host-tests/tests/qemu.rs`; built only with `test-hooks`.
#![no_std]
#![no_main]
#![deny(clippy::unwrap_used, clippy::expect_used, clippy::indexing_slicing, clippy::panic)]

#[path = "ssis-fw/board.rs"]
#[allow(dead_code)]
mod board;

/// Known, non-zero contents in .data, so the statics are not all zeros.
static PATTERN: [u32; 16] = [0xA5A5_5A5A; 16];

/// Levels after which the run gives up (far beyond what 28 KiB can hold).
const MAX_DEPTH: u32 = 100_000;

#[allow(unsafe_code)]
fn statics() -> (usize, usize) {
    extern "C" {
        static _ram_start: u32;
        static __sheap: u32;
    }
    (core::ptr::addr_of!(_ram_start) as usize, core::ptr::addr_of!(__sheap) as usize)
}

/// A digest of every word of the statics.
#[allow(unsafe_code)]
fn statics_digest() -> u32 {
    let (lo, hi) = statics();
    let mut h: u32 = 0x811C_9DC5;
    let mut p = lo;
    while p + 4 <= hi {
        // SAFETY: inside the statics region of RAM, word aligned (cortex-m-rt aligns it).
        let w = unsafe { core::ptr::read_volatile(p as *const u32) };
        h = (h ^ w).wrapping_mul(0x0100_0193).rotate_left(5);
        p += 4;
    }
    h
}

#[inline(never)]
fn descend(depth: u32, digest: u32) -> u32 {
    // 64 bytes of locals a level, kept live across the call.
    let pad = core::hint::black_box([depth; 16]);
    if statics_digest() != digest {
        defmt::error!("statics damaged at depth {}, sp {=u32:#010x}", depth, cortex_m::register::msp::read());
        board::exit(false)
    }
    if depth >= MAX_DEPTH {
        defmt::error!("no fault after {} levels", depth);
        board::exit(false)
    }
    let below = descend(depth + 1, digest);
    pad.iter().fold(below, |a, &x| a.wrapping_add(x))
}

#[cortex_m_rt::entry]
fn main() -> ! {
    board::guard_stack();
    let (lo, hi) = statics();
    let pattern_ok = core::hint::black_box(&PATTERN).iter().all(|&w| w == 0xA5A5_5A5A);
    defmt::info!(
        "stackcheck: statics {=u32:#010x}..{=u32:#010x} ({} bytes, pattern {}), recursing from sp {=u32:#010x}",
        lo as u32,
        hi as u32,
        (hi - lo) as u32,
        pattern_ok,
        cortex_m::register::msp::read()
    );
    // The logger's statics settle after its first frame; take the digest now.
    let digest = statics_digest();
    let r = descend(0, digest);
    defmt::error!("recursion returned {}", r);
    board::exit(false)
}
