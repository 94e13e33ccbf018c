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
//! - **Step**: SysTick at 200 Hz; the main loop sleeps (WFI) until the tick, runs one
//!   [`FlightCore::step`], measures it with the DWT cycle counter and reports it in
//!   25 MHz ticks (40 ns, the QEMU board's unit) through `set_step_ticks`. A step that
//!   ends after the next tick has come counts one overrun per tick that came.
//! - **Boot**: the boot policy every board shares (`ssis::bsp::boot`): the calibration
//!   table's two stored copies in the last flash sector (`CALIB` in `memory.x`,
//!   0x081E_0000; the newest good copy, else the other, else `CalibrationTable::DEFAULT`
//!   with the defaulted flag set in every output frame), the flight core, the power-on
//!   built-in test. This board implements `ssis::bsp::Board` ([`board::Stm32h7`]).
//! - **Watchdog**: the IWDG (50 ms) starts first thing and is fed once per step.
//! - **SRAM ECC**: the AXI SRAM, SRAM1–4 and the TCMs correct single-bit errors in
//!   hardware; the RAMECC monitors' flags are enabled at boot and polled once a step
//!   ([`board::ecc`]), their counts added to the core's counters and event log.
//! - **Log**: defmt over RTT (a panic-free RTT channel, [`board::rtt_write`]): at boot
//!   (reset reason, clock, table), every 10 s (counters, stack high-water).
//! - **Panics**: none. The release build links only if the optimiser has proved every
//!   panic unreachable (`panic: never`, README "No panics, stack overflow");
//!   `bash scripts/panic-paths --board stm32h7` lists the callers if one appears. A setup
//!   failure is logged and the CPU parks ([`park`]) until the watchdog resets it.
//! - **Stack guard**: the stack sits at the bottom of DTCM (`memory.x`: 0x2000_0000 up to
//!   0x2001_0000, the statics above it), so an overflow runs off the start of RAM, away
//!   from the statics, into MPU region 0 (0x1FFF_0000..0x2000_0000, no-access; reserved
//!   address space on the STM32H743, below it only the system memory at 0x1FF0_0000..
//!   0x1FF2_0000, which stays readable). The first push below the stack faults; the
//!   HardFault entry moves the stack pointer back to the top, logs `stack overflow: …`
//!   and parks until the watchdog resets the unit. A guard of 64 KiB is larger than any
//!   stack frame of this firmware, so no frame can jump over it.
#![no_std]
#![no_main]
#![deny(unsafe_code)] // allowed in `board` only
#![deny(clippy::unwrap_used, clippy::expect_used, clippy::panic, clippy::indexing_slicing)]

use core::convert::Infallible;

use ssis::bsp::boot::{self, BootReport};
use ssis::bsp::Board;
use ssis::flight::{FlightCore, FogLinks, Links, Profile};
use ssis_firmware::cortex_m7;

// `panic: never`: the release build links only if the optimiser has proved every panic
// unreachable (README "No panics, stack overflow"); debug builds and the `allow-panic`
// feature (for `scripts/panic-paths`) log `panic` and park until the watchdog resets.
ssis_firmware::cortex_m7_runtime!(sink: board::rtt_write, stop: board::halt, panic: never);

/// Steps between two status logs (10 s of 5 ms steps).
const LOG_EVERY_STEPS: u32 = 2_000;

#[cortex_m_rt::entry]
fn main() -> ! {
    cortex_m7::guard_below_stack(0x1FFF_0000, 16);
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

/// The main loop, on the booted core.
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

    let mut links = Links {
        fog: FogLinks::Bus(board::FOG_RX.port()),
        star: board::ST_RX.reader(),
        out: board::OUT_TX.frame_port(),
    };
    let mut window = Window::default();
    let mut steps: u32 = 0;
    board::ecc::enable();
    let mut handled = hw.ticks();
    loop {
        handled = board::wait_for_tick(handled);
        let t0 = board::cycles();
        let _ = core.step(&mut links);
        let cycles = board::cycles().wrapping_sub(t0);
        // The unit's state changes, after the step's output frame (docs/ICD.md "Event
        // frame"); only when there is one to send.
        core.send_events(&mut links.out);
        board::start_tx();
        // A ring whose borrow flag is corrupted takes no byte again
        // (`ssis::link::ring_faults`): the IWDG, no longer fed, resets the unit.
        if ssis::link::ring_faults() == 0 {
            hw.feed_watchdog();
        }

        // The deadline of a step is the next tick: every tick that came while it ran is
        // an overrun (the next wait then returns at once with the latest tick). Bounded:
        // a stall of more than 5 s counts as 1000.
        let late = hw.ticks().wrapping_sub(handled);
        for _ in 0..late.min(1_000) {
            core.note_overrun();
        }
        // Wall time of the step, interrupts included; the u16 field saturates at 2.6 ms.
        let ticks = cycles.checked_div(hw.cycles_per_tick).unwrap_or(cycles);
        core.set_step_ticks(u16::try_from(ticks).unwrap_or(u16::MAX));
        window.add(ticks);
        // The SRAM ECC's flags, once a step: counted and logged in the core.
        let ecc = board::ecc::poll();
        if ecc.corrected != 0 || ecc.uncorrected != 0 {
            core.note_sram_ecc(ecc.corrected, ecc.uncorrected);
            defmt::warn!("SRAM ECC: {}", ecc);
        }

        steps = steps.wrapping_add(1);
        if steps.is_multiple_of(LOG_EVERY_STEPS) {
            log_status(core, handled.checked_div(1_000_000 / profile.dt_us.max(1)).unwrap_or(0), &window);
            window = Window::default();
        }
    }
}

/// Step times over one log window, in 25 MHz ticks.
#[derive(Default)]
struct Window {
    n: u32,
    sum: u64,
    max: u32,
}

impl Window {
    fn add(&mut self, ticks: u32) {
        self.n = self.n.saturating_add(1);
        self.sum = self.sum.saturating_add(u64::from(ticks));
        self.max = self.max.max(ticks);
    }
}

/// The 10-second status line.
fn log_status(core: &FlightCore, uptime_s: u32, w: &Window) {
    let c = core.counters();
    let out = core.last_output();
    defmt::info!(
        "t {} s: step ticks mean {} max {} | overruns {} | fog rejected {} missing {} stale {} | st accepted {} rejected {} gated {} | out dropped {} io errors {} | rx overflow fog {} st {} uart errors {} | flags {=u8:#04x}",
        uptime_s,
        w.sum.checked_div(u64::from(w.n)).unwrap_or(0),
        w.max,
        c.overruns,
        c.fog_frames_rejected,
        c.fog_samples_missing,
        c.fog_samples_stale,
        c.st_frames_accepted,
        c.st_frames_rejected,
        c.st_updates_gated,
        c.output_dropped,
        c.io_errors,
        board::FOG_RX.overflows(),
        board::ST_RX.overflows(),
        board::uart_errors(),
        out.flags
    );
    defmt::info!("stack high-water {} bytes", cortex_m7::stack_high_water());
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
