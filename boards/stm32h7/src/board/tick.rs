//! The step tick (SysTick, one interrupt per step), the DWT cycle counter, and sleeping
//! until the next tick.

use core::sync::atomic::{AtomicU32, Ordering};

use cortex_m::interrupt::free;
use cortex_m::peripheral::DWT;
use cortex_m_rt::exception;

/// Unit of the step time in the output frame (the QEMU board's SysTick, 40 ns).
pub(super) const STEP_TICK_HZ: u32 = 25_000_000;

/// SysTick interrupts since start.
static TICKS: AtomicU32 = AtomicU32::new(0);

/// SysTick interrupts so far.
pub fn ticks() -> u32 {
    TICKS.load(Ordering::Acquire)
}

/// Core cycles (DWT CYCCNT, wraps every 10.7 s at 400 MHz).
pub fn cycles() -> u32 {
    DWT::cycle_count()
}

/// Sleeps until the tick count differs from `handled`; returns the new count.
pub fn wait_for_tick(handled: u32) -> u32 {
    loop {
        // Check and sleep with interrupts masked, so that a tick landing between the
        // two is not slept through: WFI still wakes on the pending interrupt, whose
        // handler runs as soon as `free` unmasks.
        let now = free(|_| {
            let now = TICKS.load(Ordering::Acquire);
            if now == handled {
                cortex_m::asm::wfi();
            }
            now
        });
        if now != handled {
            return now;
        }
    }
}

#[exception]
fn SysTick() {
    TICKS.fetch_add(1, Ordering::Release);
}
