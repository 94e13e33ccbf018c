//! The one on-target test harness: every test binary that runs under QEMU
//! (`ssis-selftest`, `ssis-navbench`, `ssis-stackcheck`, `ssis-stackcheck-lv`) invokes
//! [`mps2_test!`](crate::mps2_test) for its runtime (the firmware's logger and HardFault
//! report; a panic is logged as `panic` and fails the run) and ends with [`finish`]: the
//! verdict is the semihosting exit code, which `host-tests` (`qemu::run_bare`) reads with
//! the decoded defmt log.

use crate::mps2;

/// Ends the test run: logs the verdict line `<name>: pass` or `<name>: fail` and exits
/// QEMU with success or failure.
pub fn finish(name: &str, ok: bool) -> ! {
    if ok {
        defmt::info!("{=str}: pass", name);
    } else {
        defmt::error!("{=str}: fail", name);
    }
    mps2::exit(ok)
}

/// The stack-overflow test (README "No panics, stack overflow"), for the layout the
/// binary is linked with: recurses until the stack runs out. Before it descends further,
/// every level checks that the statics (all of .data, .bss and .uninit) still hold what
/// they held at the start; a change is logged as `statics damaged` and fails the run.
/// With the protection the overflow is a fault below the stack's bottom: the HardFault
/// handler logs `stack overflow: …` and exits QEMU with failure, and no level ever sees
/// the statics changed.
#[cfg(feature = "test-hooks")]
pub fn overflow_the_stack() -> ! {
    use core::sync::atomic::{AtomicU32, Ordering};

    use crate::cortex_m7;

    /// Known, non-zero contents in .data (atomics: writable, so in RAM, not in flash),
    /// so the statics are not all zeros.
    static PATTERN: [AtomicU32; 16] = [const { AtomicU32::new(0xA5A5_5A5A) }; 16];
    /// Levels after which the run gives up (far beyond what any layout's stack holds).
    const MAX_DEPTH: u32 = 100_000;

    /// A digest of every word of the statics.
    #[allow(unsafe_code)]
    fn statics_digest() -> u32 {
        let (lo, hi) = cortex_m7::statics();
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
            finish("stackcheck", false)
        }
        if depth >= MAX_DEPTH {
            defmt::error!("no fault after {} levels", depth);
            finish("stackcheck", false)
        }
        let below = descend(depth + 1, digest);
        pad.iter().fold(below, |a, &x| a.wrapping_add(x))
    }

    mps2::start();
    let (lo, hi) = cortex_m7::statics();
    let pattern_ok = core::hint::black_box(&PATTERN).iter().all(|w| w.load(Ordering::Relaxed) == 0xA5A5_5A5A);
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
    finish("stackcheck", false)
}

/// Generates the runtime of an on-target test binary on the QEMU board: the firmware's
/// logger (semihosting) and HardFault report, and a panic handler that logs `panic` and
/// fails the run ([`cortex_m7_runtime!`](crate::cortex_m7_runtime) with `panic: log`).
#[macro_export]
macro_rules! mps2_test {
    () => {
        $crate::cortex_m7_runtime!(
            sink: $crate::mps2::semihosting_sink,
            stop: $crate::mps2::exit,
            panic: log
        );
    };
}
