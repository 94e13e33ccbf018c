//! The board seam: what a flight firmware needs of its board, and the policy every board
//! shares.
//!
//! A firmware is one board plus one mission. A board implements [`Board`] (the
//! calibration flash, the watchdog, the step tick, how the unit stops) and the firmware
//! boots through [`boot::boot`], the one boot policy of every board: the two-copy table,
//! the power-on built-in test, the flagged default, the flight core. It then flies in
//! [`exec::run`], the one fixed-rate loop of every board and mission (the executive:
//! wait, step, outputs, the after-step work on one schedule, overruns, the watchdog fed
//! only by a step within its deadline), to which the board adds what differs
//! ([`exec::StepBoard`]: its pacing, clock, memory areas, memory-error source, reset)
//! and the mission its step ([`exec::Mission`]). The code check ([`code::CodeCheck`])
//! is one of its after-step jobs.
//!
//! Why these are here, in the portable core, and the board code is not: they are
//! safe, portable code whose behaviour matters (which table flies, what is flagged), so
//! they are tested on the host (`host-tests/tests/boot.rs` boots on the STM32H7's flash
//! layout; the unit tests beside the code). What touches the hardware (registers, linker
//! symbols, the MPU, semihosting, the defmt logger, the panic handler) needs `unsafe` and
//! the Cortex-M crates, which this crate forbids and does not depend on: it is the
//! `ssis-firmware` crate (`firmware/src/`: `cortex_m7`, `mps2`, `harness`) and the board
//! crates (`boards/stm32h7`).

pub mod boot;
pub mod code;
pub mod exec;

/// What the boot policy and a main loop need of a board.
pub trait Board {
    /// The calibration flash area: the two-copy table store (`calib::store`,
    /// [`crate::calib::store::REGION_LEN`] bytes) at its start, the rest not read.
    fn calib_area(&self) -> &[u8];

    /// Restarts the watchdog's count-down (once per pass of the main loop).
    fn feed_watchdog(&mut self);

    /// Step ticks (SysTick interrupts) since the tick started.
    fn ticks(&self) -> u32;

    /// Stops the unit for good: under QEMU the run ends with `ok` as its outcome; on
    /// hardware the CPU parks, emitting nothing, until the watchdog resets it.
    fn stop(&mut self, ok: bool) -> !;
}
