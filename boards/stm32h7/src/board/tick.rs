//! The step tick (SysTick, one interrupt per step), the DWT cycle counter (the
//! executive's clock), and sleeping until the next tick.

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

/// The tick count; when it is still `handled`, sleeps once until the next interrupt
/// first (the executive's wait calls again).
pub fn sleep_unless(handled: u32) -> u32 {
    // Check and sleep with interrupts masked, so that a tick landing between the two is
    // not slept through: WFI still wakes on the pending interrupt, whose handler runs as
    // soon as `free` unmasks.
    free(|_| {
        let now = TICKS.load(Ordering::Acquire);
        if now == handled {
            cortex_m::asm::wfi();
        }
    });
    TICKS.load(Ordering::Acquire)
}

#[exception]
fn SysTick() {
    TICKS.fetch_add(1, Ordering::Release);
}
