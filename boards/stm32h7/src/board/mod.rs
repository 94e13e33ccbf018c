//! Everything that touches hardware: clocks, UARTs, the tick, the watchdog, the
//! calibration sector, the RTT log channel. The flight core sees only the rings.
//!
//! | module | job |
//! |---|---|
//! | [`clocks`] | the 400 MHz clock tree from the HSE (or the HSI), every wait bounded |
//! | [`uart`] | pins, the three USARTs, their interrupts and rings |
//! | [`tick`] | SysTick (the step), the DWT cycle counter, sleeping until the tick |
//! | [`watchdog`] | the IWDG |
//! | [`calib`] | the calibration flash sector |
//! | [`rtt`] | the panic-free RTT channel of the defmt log |
//! | [`ecc`] | the SRAM ECC's error reporting (RAMECC), polled once a step |
//! | [`regs`] | the configuration registers the executive checks and restores |
//!
//! Here: the board's type ([`Stm32h7`], `ssis::bsp::Board` and the executive's
//! `ssis::bsp::exec::StepBoard`), its bring-up ([`init`]) and what can go wrong in it.
#![allow(unsafe_code)]

mod calib;
mod clocks;
pub mod ecc;
mod regs;
mod rtt;
mod tick;
mod uart;
mod watchdog;

use cortex_m::peripheral::syst::SystClkSource;
use cortex_m::peripheral::{DWT, NVIC};
use ssis::bsp::exec::{MemoryErrors, StepBoard, Wait};
use ssis::flight::snapshot::Snapshots;
use ssis::flight::FlightCore;
use ssis_firmware::cortex_m7;
use stm32h7::stm32h743v::{self as pac, Interrupt};

pub use rtt::rtt_write;
pub use tick::{cycles, ticks};
pub use uart::{start_tx, uart_errors, FOG_RX, OUT_TX, ST_RX};

/// Longest wait for a ready flag other than the HSE's (supply, voltage scale, flash
/// latency, PLL lock, clock switch, watchdog registers), in core cycles: 10 ms on the HSI (the
/// core runs on it during every wait), each far above the datasheet's worst case.
const READY_TIMEOUT_CYCLES: u32 = 640_000;

/// What can fail in [`init`] so that the unit cannot fly.
#[derive(defmt::Format)]
pub enum SetupError {
    /// The peripherals were already taken (init called twice).
    PeripheralsTaken,
    /// The step period does not fit the 24-bit SysTick at this core clock.
    StepPeriod,
}

/// A ready flag that did not come within [`READY_TIMEOUT_CYCLES`]. The unit then
/// flies on the fallback clock (the 64 MHz HSI, no PLL) or with the watchdog's reset
/// timing, logs this, and flags its output frames as running on defaults.
#[derive(Clone, Copy, defmt::Format)]
pub enum Timeout {
    /// PWR_CSR1.ACTVOSRDY after the LDO supply configuration (PWR_CR3).
    Supply,
    /// PWR_D3CR.VOSRDY after selecting voltage scale 1.
    VoltageScale,
    /// FLASH_ACR read-back of the new LATENCY/WRHIGHFREQ.
    FlashLatency,
    /// RCC_CR.PLL1RDY.
    Pll1Lock,
    /// RCC_CFGR.SWS after selecting PLL1 as system clock.
    ClockSwitch,
    /// IWDG_SR.PVU/RVU after writing the prescaler and reload.
    Watchdog,
}

/// Where the core clock comes from.
#[derive(Clone, Copy, PartialEq, Eq, defmt::Format)]
pub enum ClockSource {
    /// PLL1 from the HSE: 400 MHz.
    HsePll,
    /// PLL1 from the HSI (the HSE did not start): 400 MHz.
    HsiPll,
    /// The HSI itself, 64 MHz (a step of the PLL setup timed out).
    Hsi,
}

/// The board once set up; the UARTs and the tick live in their interrupts.
pub struct Stm32h7 {
    iwdg: pac::IWDG,
    /// Core cycles per step-time tick.
    pub cycles_per_tick: u32,
    /// Core clock, Hz.
    pub core_hz: u32,
    /// Where the core clock comes from.
    pub clock: ClockSource,
    /// A setup wait that timed out (the unit flies on its fallback, flagged).
    pub timeout: Option<Timeout>,
    /// Why the MCU last reset.
    pub reset_reason: &'static str,
    /// Core cycles in one step period.
    period_cycles: u32,
    /// The tick of the last step.
    handled: u32,
    /// The snapshot in the layout's SNAP region.
    snap: Option<&'static mut Snapshots>,
    /// Step times of the status log's window.
    window: ssis::bsp::exec::Times,
    /// Steps since start.
    steps: u32,
    /// Step period, µs.
    step_us: u32,
}

/// Steps between two status logs (10 s of 5 ms steps).
const LOG_EVERY_STEPS: u32 = 2_000;

impl StepBoard for Stm32h7 {
    fn wait(&mut self, _core: &mut FlightCore) -> Wait {
        let now = tick::sleep_unless(self.handled);
        if now == self.handled {
            return Wait::Idle { lockstep: false, tick: false };
        }
        let missed = now.wrapping_sub(self.handled).saturating_sub(1);
        self.handled = now;
        Wait::Tick { missed }
    }

    fn clock(&self) -> u32 {
        cycles()
    }

    fn period(&self) -> u32 {
        self.period_cycles
    }

    fn to_ticks(&self, clock: u32) -> u32 {
        clock.checked_div(self.cycles_per_tick).unwrap_or(clock)
    }

    fn send(&mut self) {
        start_tx();
    }

    fn after_step(&mut self, core: &mut FlightCore, busy: u32) {
        self.window.push(self.to_ticks(busy));
        self.steps = self.steps.wrapping_add(1);
        if self.steps.is_multiple_of(LOG_EVERY_STEPS) {
            let uptime_s = self.handled.checked_div(1_000_000 / self.step_us.max(1)).unwrap_or(0);
            log_status(core, uptime_s, &self.window);
            self.window = ssis::bsp::exec::Times::default();
        }
    }

    fn snapshots(&mut self) -> Option<&mut Snapshots> {
        self.snap.as_deref_mut()
    }

    fn code_image(&self) -> &'static [u8] {
        ssis_firmware::resilience::code_image()
    }

    fn check_pass(&mut self) -> ssis::bsp::exec::RegisterCheck {
        ssis_firmware::regcheck::verify_pass(&regs::REGISTERS, regs::PASS_ENTRIES)
    }

    fn check_registers(&mut self) -> ssis::bsp::exec::RegisterCheck {
        ssis_firmware::regcheck::verify(&regs::REGISTERS)
    }

    fn memory_errors(&mut self) -> MemoryErrors {
        let e = ecc::poll();
        if e.corrected != 0 || e.uncorrected != 0 {
            defmt::warn!("SRAM ECC: {}", e);
        }
        MemoryErrors { corrected: e.corrected, uncorrected: e.uncorrected }
    }

    fn reset(&mut self) -> ! {
        ssis_firmware::resilience::reset()
    }
}

/// The 10-second status line.
fn log_status(core: &FlightCore, uptime_s: u32, w: &ssis::bsp::exec::Times) {
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
        FOG_RX.overflows(),
        ST_RX.overflows(),
        uart_errors(),
        out.flags
    );
    defmt::info!("stack high-water {} bytes", cortex_m7::stack_high_water());
}

impl ssis::bsp::Board for Stm32h7 {
    fn calib_area(&self) -> &[u8] {
        calib::calib_sector()
    }

    fn feed_watchdog(&mut self) {
        // RM0433 45.4.1 IWDG_KR: 0xAAAA reloads the counter.
        self.iwdg.kr.write(|w| w.key().reset());
    }

    fn ticks(&self) -> u32 {
        ticks()
    }

    fn stop(&mut self, ok: bool) -> ! {
        halt(ok)
    }
}

/// Stops for good: the CPU parks (`crate::park`) until the watchdog resets the unit.
pub fn halt(_ok: bool) -> ! {
    crate::park()
}

/// The HardFault's way out (logged first): a reset (SYSRESETREQ), after which the unit
/// resumes from its snapshot.
pub fn fault_reset(_ok: bool) -> ! {
    ssis_firmware::resilience::reset()
}

/// Polls `ready` until it holds or [`READY_TIMEOUT_CYCLES`] core cycles have passed
/// (DWT cycle counter, enabled first thing in [`init`]).
fn wait(ready: impl Fn() -> bool, what: Timeout) -> Result<(), Timeout> {
    let t0 = DWT::cycle_count();
    loop {
        if ready() {
            return Ok(());
        }
        if DWT::cycle_count().wrapping_sub(t0) >= READY_TIMEOUT_CYCLES {
            return Err(what);
        }
    }
}

/// Brings up the watchdog, clocks, UARTs and their interrupts, and the step tick of
/// `step_us`. Register-level, through the PAC (names as in RM0433); every wait is
/// bounded ([`wait`]).
pub fn init(step_us: u32) -> Result<Stm32h7, SetupError> {
    let (Some(mut cp), Some(dp)) = (cortex_m::Peripherals::take(), pac::Peripherals::take()) else {
        return Err(SetupError::PeripheralsTaken);
    };
    DWT::unlock(); // the STM32H7 locks the DWT after a power cycle
    cp.DCB.enable_trace();
    cp.DWT.enable_cycle_counter();

    // Watchdog first: a setup step that hangs or fails now ends in a reset. It keeps
    // counting through a debugger halt unless frozen (DBGMCU_APB4FZ1.DBG_IWDG1),
    // which only matters with a probe attached.
    dp.DBGMCU.apb4fz1.modify(|_, w| w.dbg_iwdg1().set_bit());
    let watchdog = watchdog::watchdog_start(&dp.IWDG);

    // Caches: safe here with no DMA; RAM is DTCM (never cached), peripherals are
    // device memory. The D-cache serves the constants in flash.
    cp.SCB.enable_icache();
    cp.SCB.enable_dcache(&mut cp.CPUID);

    let reset_reason = reset_reason(&dp.RCC);
    let hse = clocks::hse_starts(&dp.RCC);
    let clocks = clocks::clocks_400mhz(&dp.PWR, &dp.FLASH, &dp.RCC, hse);
    let (clock, core_hz, brr) = match clocks {
        Ok(()) if hse => (ClockSource::HsePll, clocks::CORE_HZ, uart::BRR_PLL),
        Ok(()) => (ClockSource::HsiPll, clocks::CORE_HZ, uart::BRR_PLL),
        Err(_) => (ClockSource::Hsi, clocks::HSI_HZ, uart::BRR_HSI),
    };
    let timeout = clocks.err().or(watchdog.err());

    uart::pins(&dp.RCC, &dp.GPIOB, &dp.GPIOD);
    // RM0433 8.7.43/8.7.40 RCC_APB2ENR.USART1EN, RCC_APB1LENR.USART2EN/USART3EN; the
    // read-back makes sure the clock is on before the first register access.
    dp.RCC.apb2enr.modify(|_, w| w.usart1en().enabled());
    dp.RCC.apb1lenr.modify(|_, w| w.usart2en().enabled().usart3en().enabled());
    let _ = dp.RCC.apb1lenr.read();
    uart::usart_start(&dp.USART1, brr, false);
    uart::usart_start(&dp.USART2, brr, true);
    uart::usart_start(&dp.USART3, brr, true);

    let reload = u64::from(core_hz) * u64::from(step_us) / 1_000_000;
    let reload = u32::try_from(reload)
        .ok()
        .and_then(|r| r.checked_sub(1))
        .filter(|r| *r <= 0x00FF_FFFF)
        .ok_or(SetupError::StepPeriod)?;
    let mut syst = cp.SYST;
    syst.set_clock_source(SystClkSource::Core);
    syst.set_reload(reload);
    syst.clear_current();
    syst.enable_interrupt();
    syst.enable_counter();

    // The snapshot region survives a reset but not a power cycle: after a power-on or
    // brown-out it holds no snapshot, and is written before it is read, so its ECC
    // check bits are set (RAM with ECC read before any write may report errors).
    let mut snap = ssis_firmware::resilience::snapshot();
    if matches!(reset_reason, "power-on" | "brown-out") {
        if let Some(s) = snap.as_deref_mut() {
            *s = Snapshots::default();
        }
    }
    ecc::enable();

    for irq in [Interrupt::USART1, Interrupt::USART2, Interrupt::USART3] {
        // SAFETY: the handlers touch only the rings, the atomics and their own
        // USART's registers (CR1 behind critical sections), all set up above.
        unsafe { NVIC::unmask(irq) };
    }
    ssis_firmware::regcheck::build(&regs::REGISTERS);
    Ok(Stm32h7 {
        iwdg: dp.IWDG,
        cycles_per_tick: (core_hz / tick::STEP_TICK_HZ).max(1),
        core_hz,
        clock,
        timeout,
        reset_reason,
        period_cycles: reload.saturating_add(1),
        handled: ticks(),
        snap,
        window: ssis::bsp::exec::Times::default(),
        steps: 0,
        step_us,
    })
}

/// The cause of the last reset from RCC_RSR (RM0433 8.4.4), most specific first;
/// then clears the flags (RMVF).
fn reset_reason(rcc: &pac::RCC) -> &'static str {
    let r = rcc.rsr.read();
    let name = if r.iwdg1rstf().bit_is_set() {
        "IWDG"
    } else if r.wwdg1rstf().bit_is_set() {
        "watchdog"
    } else if r.lpwrrstf().bit_is_set() {
        "low-power"
    } else if r.porrstf().bit_is_set() {
        "power-on"
    } else if r.borrstf().bit_is_set() {
        "brown-out"
    } else if r.sftrstf().bit_is_set() {
        "software"
    } else if r.pinrstf().bit_is_set() {
        "pin"
    } else if r.cpurstf().bit_is_set() {
        "software"
    } else {
        "other"
    };
    rcc.rsr.modify(|_, w| w.rmvf().clear());
    name
}
