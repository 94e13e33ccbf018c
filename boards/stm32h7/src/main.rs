//! `ssis-fw-stm32h7`: the ssis flight core on an STM32H743ZI (Cortex-M7), spacecraft
//! profile (four FOGs on one RS-485 bus, star tracker, 5 ms steps).
//!
//! What it does:
//! - **Clock**: 400 MHz core (PLL1) from the 8 MHz HSE in bypass mode (the ST-LINK MCO of
//!   a NUCLEO-H743ZI; a flight board's oscillator likewise). If the HSE is not ready
//!   within 10 ms, PLL1 runs from the 64 MHz HSI instead and the boot log says so. Set up
//!   register by register through the PAC ([`board::init`]), every wait bounded: if the
//!   supply, voltage scale, flash latency, PLL lock or clock switch does not come within
//!   10 ms, the core stays on the 64 MHz HSI, the boot log names the step, and the output
//!   frames carry the defaulted flag.
//! - **Links**, all 921 600 Bd 8N1, interrupt-driven:
//!   USART1 TX = framed output, from a `TxRing<256>` drained by the TX-FIFO-not-full
//!   interrupt; USART2 RX = the FOG RS-485 bus (all four FOGs, told apart by `fog_id`)
//!   into an `RxRing<512>`; USART3 RX = star tracker into an `RxRing<512>`.
//! - **Loop**: the executive every board and mission share (`ssis::bsp::exec::run`,
//!   the mission `ssis::bsp::exec::Spacecraft`); this board supplies what differs
//!   ([`board::Stm32h7`], `ssis::bsp::exec::StepBoard`). SysTick at 200 Hz; the loop
//!   sleeps (WFI) until the tick, runs one [`FlightCore::step`], measures the pass with
//!   the DWT cycle counter and reports it in 25 MHz ticks (40 ns, the QEMU board's unit)
//!   through `set_step_ticks`. Each tick that came and went without a step counts one
//!   overrun.
//! - **After each step**, on the executive's one schedule: a slice of the table scrub
//!   (the table in RAM against its CRC, restored from the calibration sector), a slice
//!   of the code check (CRC-32C of the image in flash), the SRAM ECC poll, and every 80
//!   steps the reset snapshot in the SNAP region of DTCM (`memory.x`), which a reset
//!   does not clear: a watchdog reset, a HardFault or a corrupted ring's reset comes
//!   back aligned, where it was. After a power-on or brown-out the region is cleared
//!   before it is read.
//! - **Boot**: the boot policy every board shares (`ssis::bsp::boot`): the calibration
//!   table's two stored copies in the last flash sector (`CALIB` in `memory.x`,
//!   0x081E_0000; the newest good copy, else the other, else `CalibrationTable::DEFAULT`
//!   with the defaulted flag set in every output frame), the flight core, the power-on
//!   built-in test. This board implements `ssis::bsp::Board` ([`board::Stm32h7`]).
//! - **Watchdog**: the IWDG (50 ms) starts first thing; the executive feeds it only
//!   after a step that completed within its deadline (5 ms on the cycle counter).
//! - **SRAM ECC**: the AXI SRAM, SRAM1–4 and the TCMs correct single-bit errors in
//!   hardware; the RAMECC monitors' flags are enabled at boot and polled once a step
//!   ([`board::ecc`]) by the executive, their counts added to the core's counters and
//!   event log.
//! - **Log**: defmt over RTT (a panic-free RTT channel, [`board::rtt_write`]): at boot
//!   (reset reason, clock, table), every 10 s (counters, stack high-water).
//! - **Panics**: none. The release build links only if the optimiser has proved every
//!   panic unreachable (`panic: never`, README "No panics, stack overflow");
//!   `bash scripts/panic-paths --board stm32h7` lists the callers if one appears. A setup
//!   failure is logged and the CPU parks ([`park`]) until the watchdog resets it; a
//!   HardFault resets the unit (SYSRESETREQ) and it resumes from its snapshot.
//! - **Below the stack**: the stack sits at the bottom of DTCM (`memory.x`: 0x2000_0000 up to
//!   0x2001_0000, the statics above it), so an overflow runs off the start of RAM, away
//!   from the statics, into MPU region 0 (0x1FFF_0000..0x2000_0000, no-access; reserved
//!   address space on the STM32H743, below it only the system memory at 0x1FF0_0000..
//!   0x1FF2_0000, which stays readable). The first push below the stack faults; the
//!   HardFault entry moves the stack pointer back to the top, logs `stack overflow: …`
//!   and resets the unit. A no-access region of 64 KiB is larger than any stack frame
//!   of this firmware, so no frame can jump over it.
#![no_std]
#![no_main]
#![deny(unsafe_code)] // allowed in `board` only
#![deny(clippy::unwrap_used, clippy::expect_used, clippy::panic, clippy::indexing_slicing)]

use core::convert::Infallible;

use ssis::bsp::boot::{self, BootReport};
use ssis::bsp::exec::{self, Spacecraft};
use ssis::bsp::Board;
use ssis::flight::{FlightCore, FogLinks, Links, Profile};
use ssis_firmware::cortex_m7;

// `panic: never`: the release build links only if the optimiser has proved every panic
// unreachable (README "No panics, stack overflow"); debug builds and the `allow-panic`
// feature (for `scripts/panic-paths`) log `panic` and park until the watchdog resets.
ssis_firmware::cortex_m7_runtime!(sink: board::rtt_write, stop: board::halt, fault: board::fault_reset, panic: never);

#[cortex_m_rt::entry]
fn main() -> ! {
    cortex_m7::protect_below_stack(0x1FFF_0000, 16);
    cortex_m7::paint_stack();
    let profile = Profile::SPACECRAFT;
    let mut hw = match board::init(profile.dt_us) {
        Ok(hw) => hw,
        Err(e) => {
            defmt::error!("board setup failed: {}", e);
            park()
        }
    };
    // A setup wait that timed out leaves the unit on its fallback (HSI clock, or the
    // watchdog's reset timing): it flies, and its output frames carry the defaulted flag.
    if let Some(t) = hw.timeout {
        defmt::error!("board setup: {} did not become ready; flying on the fallback, flagged", t);
    }
    let fallback = hw.timeout.is_some();
    match boot::boot(&mut hw, profile, fallback, |hw, core, report| fly(hw, core, report, profile)) {
        Ok(never) => match never {},
        Err(e) => {
            defmt::error!("cannot fly: {}", e);
            hw.stop(false)
        }
    }
}

/// The mission set up on the booted core, then the executive.
fn fly(hw: &mut board::Stm32h7, core: &mut FlightCore, report: &BootReport, profile: Profile) -> Infallible {
    hw.feed_watchdog();
    defmt::info!(
        "ssis-fw-stm32h7 up: reset {}, core {} Hz from {}, table revision {} (defaulted {}), step {} us",
        hw.reset_reason,
        hw.core_hz,
        hw.clock,
        core.table().revision,
        report.defaulted,
        profile.dt_us
    );
    let links = Links {
        fog: FogLinks::Bus(board::FOG_RX.port()),
        star: board::ST_RX.reader(),
        out: board::OUT_TX.frame_port(),
    };
    exec::run(hw, &mut Spacecraft::new(links), core)
}

/// Where the firmware stops when it cannot fly: interrupts stay as they are, the CPU
/// sleeps, nothing more is sent.
///
/// Why this and not a panic or an immediate retry: a unit that could not set itself up must
/// not emit output frames of unknown quality; silence on the output link is what the
/// consumer already treats as a failed unit (and switches to its redundant one). The
/// error has just been logged, and the probe can still read the log and the state
/// (panic-probe would instead end the probe session). The IWDG, started before any
/// fallible setup step, is no longer fed, so ~50 ms later the unit resets and tries
/// again: a transient fault (a slow oscillator, a single-event upset) recovers, a
/// permanent one stays silent, with its error in the log at every attempt.
fn park() -> ! {
    loop {
        cortex_m::asm::wfi();
    }
}

/// Everything that touches hardware (`board/`: one file per job).
mod board;
