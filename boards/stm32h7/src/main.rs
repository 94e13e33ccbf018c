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
    let mut handled = hw.ticks();
    loop {
        handled = board::wait_for_tick(handled);
        let t0 = board::cycles();
        let _ = core.step(&mut links);
        let cycles = board::cycles().wrapping_sub(t0);
        board::start_tx();
        hw.feed_watchdog();

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

/// Everything that touches hardware: clocks, UARTs, the tick, the watchdog, the
/// calibration sector, the RTT log channel. The flight core sees only the rings.
mod board {
    #![allow(unsafe_code)]

    use core::sync::atomic::{AtomicU32, Ordering};

    use cortex_m::interrupt::free;
    use cortex_m::peripheral::syst::SystClkSource;
    use cortex_m::peripheral::{DWT, NVIC};
    use cortex_m_rt::exception;
    use ssis::link::{RxRing, TxRing};
    use stm32h7::stm32h743v::{self as pac, interrupt, usart1, Interrupt};

    /// HSE frequency (NUCLEO-H743ZI: 8 MHz from the ST-LINK MCO).
    const HSE_HZ: u32 = 8_000_000;
    /// The HSE is an external clock signal (bypass), not a crystal.
    const HSE_BYPASS: bool = true;
    /// HSI frequency: the clock the MCU resets on (RCC_CR.HSIDIV = 1 after reset).
    const HSI_HZ: u32 = 64_000_000;
    /// Longest wait for the HSE before falling back to the HSI, in HSI cycles (10 ms).
    const HSE_TIMEOUT_CYCLES: u32 = 640_000;
    /// Longest wait for any other ready flag (supply, voltage scale, flash latency, PLL
    /// lock, clock switch, watchdog registers), in core cycles: 10 ms on the HSI (the
    /// core runs on it during every wait), each far above the datasheet's worst case.
    const READY_TIMEOUT_CYCLES: u32 = 640_000;
    /// Core clock: the most the STM32H743 (rev V) runs at in voltage scale 1.
    const CORE_HZ: u32 = 400_000_000;
    /// PLL1 input divider DIVM1 and the reference clock it gives, per source: 8 MHz from
    /// the HSE (DIVM1 = 1), 16 MHz from the HSI (DIVM1 = 4); both in PLL1RGE's 8-16 MHz range.
    const PLL_M_HSE: u32 = 1;
    const PLL_M_HSI: u32 = 4;
    /// VCO 800 MHz (wide VCO, 192-960 MHz on rev V), divided by DIVP1 = 2 into 400 MHz.
    const VCO_HZ: u32 = 800_000_000;
    const PLL_P: u32 = 2;
    /// DIVN1 per source (the multiplier N; the register holds N - 1).
    const PLL_N_HSE: u32 = VCO_HZ / (HSE_HZ / PLL_M_HSE);
    const PLL_N_HSI: u32 = VCO_HZ / (HSI_HZ / PLL_M_HSI);
    /// AHB/AXI clock (HPRE = 2) and APB1..4 clocks (D1PPRE, D2PPRE1/2, D3PPRE = 2): the
    /// VOS1 maxima of 200 and 100 MHz. The USARTs' kernel clock is their APB clock
    /// (RCC_D2CCIP2R.USART16SEL and USART234578SEL at their reset value 0 = rcc_pclk).
    const HCLK_HZ: u32 = CORE_HZ / 2;
    const PCLK_HZ: u32 = HCLK_HZ / 2;
    /// Flash wait states at 200 MHz AXI in VOS1 (RM0433 table 17: 185-210 MHz: LATENCY
    /// = 2, WRHIGHFREQ = 2).
    const FLASH_LATENCY: u8 = 2;
    const FLASH_WRHIGHFREQ: u8 = 2;

    const _: () = assert!(HSE_HZ / PLL_M_HSE >= 8_000_000 && HSE_HZ / PLL_M_HSE <= 16_000_000);
    const _: () = assert!(HSI_HZ / PLL_M_HSI >= 8_000_000 && HSI_HZ / PLL_M_HSI <= 16_000_000);
    const _: () = assert!(PLL_N_HSE * (HSE_HZ / PLL_M_HSE) == VCO_HZ && PLL_N_HSI * (HSI_HZ / PLL_M_HSI) == VCO_HZ);
    const _: () = assert!(PLL_N_HSE >= 4 && PLL_N_HSE <= 512 && PLL_N_HSI >= 4 && PLL_N_HSI <= 512);
    const _: () = assert!(VCO_HZ >= 192_000_000 && VCO_HZ <= 960_000_000 && VCO_HZ / PLL_P == CORE_HZ);

    /// All three links.
    const BAUD: u32 = 921_600;
    /// USARTDIV (RM0433 48.5.7, oversampling by 16, PRESC = 1): kernel clock / baud,
    /// rounded to the nearest, for the PLL clock tree (100 MHz APB: 109, 917 431 Bd,
    /// -0.45 %) and the HSI fallback (64 MHz APB: 69, 927 536 Bd, +0.64 %).
    const BRR_PLL: u16 = usart_div(PCLK_HZ, BAUD);
    const BRR_HSI: u16 = usart_div(HSI_HZ, BAUD);

    /// USARTDIV for `baud` from `ker_hz`; refuses at compile time (it only runs in
    /// consts) a divider outside BRR's range 16..=0xFFFF or a rate more than 1 % off.
    const fn usart_div(ker_hz: u32, baud: u32) -> u16 {
        let div = (ker_hz + baud / 2) / baud;
        assert!(div >= 16 && div <= 0xFFFF, "USART divider out of range");
        let actual = ker_hz / div;
        let off = actual.abs_diff(baud);
        assert!(off * 100 <= baud, "baud rate more than 1 % off");
        div as u16
    }

    /// Unit of the step time in the output frame (the QEMU board's SysTick, 40 ns).
    const STEP_TICK_HZ: u32 = 25_000_000;
    /// Watchdog: the IWDG counts the LSI (32 kHz) divided by 4 (IWDG_PR = 0), so a
    /// reload of 400 gives 50 ms: 10 steps, and more than the boot takes before the
    /// first feed.
    const WATCHDOG_MS: u32 = 50;
    const WATCHDOG_RELOAD: u16 = {
        let r = WATCHDOG_MS * (32_000 / 4) / 1_000;
        assert!(r >= 1 && r <= 0x0FFF, "IWDG reload out of range");
        r as u16
    };

    /// FOG bus receive buffer: 512 bytes = 5.6 ms at 921 600 Bd, more than a step at full line rate.
    pub static FOG_RX: RxRing<512> = RxRing::new();
    /// Star-tracker receive buffer.
    pub static ST_RX: RxRing<512> = RxRing::new();
    /// Output transmit buffer: three output frames (`docs/ICD.md`).
    pub static OUT_TX: TxRing<256> = TxRing::new();

    /// SysTick interrupts since start.
    static TICKS: AtomicU32 = AtomicU32::new(0);
    /// Receive errors (framing, noise, parity, hardware overrun) on USART2 and USART3.
    static UART_ERRORS: AtomicU32 = AtomicU32::new(0);

    extern "C" {
        /// Start of the `CALIB` region (memory.x): the calibration sector.
        static _calib_start: u8;
        /// Its end.
        static _calib_end: u8;
    }

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
    }

    impl ssis::bsp::Board for Stm32h7 {
        fn calib_area(&self) -> &[u8] {
            calib_sector()
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
        let watchdog = watchdog_start(&dp.IWDG);

        // Caches: safe here with no DMA; RAM is DTCM (never cached), peripherals are
        // device memory. The D-cache serves the constants in flash.
        cp.SCB.enable_icache();
        cp.SCB.enable_dcache(&mut cp.CPUID);

        let reset_reason = reset_reason(&dp.RCC);
        let hse = hse_starts(&dp.RCC);
        let clocks = clocks_400mhz(&dp.PWR, &dp.FLASH, &dp.RCC, hse);
        let (clock, core_hz, brr) = match clocks {
            Ok(()) if hse => (ClockSource::HsePll, CORE_HZ, BRR_PLL),
            Ok(()) => (ClockSource::HsiPll, CORE_HZ, BRR_PLL),
            Err(_) => (ClockSource::Hsi, HSI_HZ, BRR_HSI),
        };
        let timeout = clocks.err().or(watchdog.err());

        pins(&dp.RCC, &dp.GPIOB, &dp.GPIOD);
        // RM0433 8.7.43/8.7.40 RCC_APB2ENR.USART1EN, RCC_APB1LENR.USART2EN/USART3EN; the
        // read-back makes sure the clock is on before the first register access.
        dp.RCC.apb2enr.modify(|_, w| w.usart1en().enabled());
        dp.RCC.apb1lenr.modify(|_, w| w.usart2en().enabled().usart3en().enabled());
        let _ = dp.RCC.apb1lenr.read();
        usart_start(&dp.USART1, brr, false);
        usart_start(&dp.USART2, brr, true);
        usart_start(&dp.USART3, brr, true);

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

        for irq in [Interrupt::USART1, Interrupt::USART2, Interrupt::USART3] {
            // SAFETY: the handlers touch only the rings, the atomics and their own
            // USART's registers (CR1 behind critical sections), all set up above.
            unsafe { NVIC::unmask(irq) };
        }
        Ok(Stm32h7 {
            iwdg: dp.IWDG,
            cycles_per_tick: (core_hz / STEP_TICK_HZ).max(1),
            core_hz,
            clock,
            timeout,
            reset_reason,
        })
    }

    /// Starts the IWDG with [`WATCHDOG_RELOAD`] (RM0433 45.3.2): IWDG_KR = 0xCCCC
    /// (start; the LSI turns on by itself), 0x5555 (unlock PR and RLR), IWDG_PR = 0
    /// (LSI / 4), IWDG_RLR, then wait until IWDG_SR.PVU and RVU clear (the values have
    /// crossed into the LSI domain), then 0xAAAA (reload). If they do not clear, the
    /// watchdog still runs on its reset values (512 ms).
    fn watchdog_start(iwdg: &pac::IWDG) -> Result<(), Timeout> {
        iwdg.kr.write(|w| w.key().start());
        iwdg.kr.write(|w| w.key().enable());
        iwdg.pr.write(|w| w.pr().divide_by4());
        iwdg.rlr.write(|w| w.rl().bits(WATCHDOG_RELOAD));
        let done = wait(
            || {
                let sr = iwdg.sr.read();
                sr.pvu().bit_is_clear() && sr.rvu().bit_is_clear()
            },
            Timeout::Watchdog,
        );
        iwdg.kr.write(|w| w.key().reset());
        done
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

    /// Turns the HSE on and waits for it at most [`HSE_TIMEOUT_CYCLES`]. Leaves it on if
    /// it is ready, off otherwise (RCC_CR.HSEBYP, HSEON, HSERDY).
    fn hse_starts(rcc: &pac::RCC) -> bool {
        // HSEBYP may only change while the HSE is off.
        rcc.cr.modify(|_, w| if HSE_BYPASS { w.hsebyp().bypassed() } else { w.hsebyp().not_bypassed() });
        rcc.cr.modify(|_, w| w.hseon().on());
        let t0 = DWT::cycle_count();
        while DWT::cycle_count().wrapping_sub(t0) < HSE_TIMEOUT_CYCLES {
            if rcc.cr.read().hserdy().is_ready() {
                return true;
            }
        }
        rcc.cr.modify(|_, w| w.hseon().off());
        false
    }

    /// The 400 MHz clock tree from the HSE (`hse`) or else the HSI; on a timeout the core
    /// stays on the 64 MHz HSI with every bus prescaler at 1 (the reset state).
    ///
    /// 1. Supply (RM0433 6.8.4 PWR_CR3): LDO on, bypass off, SCUEN (the NUCLEO-H743ZI's
    ///    supply; written once per power-on), then PWR_CSR1.ACTVOSRDY.
    /// 2. Voltage scale 1 (PWR_D3CR.VOS = 0b11, 400 MHz max on rev V), then VOSRDY.
    /// 3. Flash (FLASH_ACR): LATENCY and WRHIGHFREQ for 200 MHz AXI, read back.
    /// 4. PLL1 (RCC_PLLCKSELR.PLLSRC, DIVM1; RCC_PLLCFGR.PLL1RGE = 8-16 MHz, PLL1VCOSEL
    ///    = wide, no FRACN, only DIVP1EN; RCC_PLL1DIVR.DIVN1, DIVP1), RCC_CR.PLL1ON,
    ///    then PLL1RDY.
    /// 5. Prescalers (RCC_D1CFGR.D1CPRE = 1, HPRE = 2, D1PPRE = 2; RCC_D2CFGR.D2PPRE1,
    ///    D2PPRE2 = 2; RCC_D3CFGR.D3PPRE = 2), then RCC_CFGR.SW = PLL1, then SWS.
    fn clocks_400mhz(pwr: &pac::PWR, flash: &pac::FLASH, rcc: &pac::RCC, hse: bool) -> Result<(), Timeout> {
        pwr.cr3.modify(|_, w| w.scuen().set_bit().ldoen().set_bit().bypass().clear_bit());
        wait(|| pwr.csr1.read().actvosrdy().bit_is_set(), Timeout::Supply)?;
        // SAFETY: 0b11 = scale 1, a valid VOS value (RM0433 6.8.6).
        pwr.d3cr.write(|w| unsafe { w.vos().bits(0b11) });
        wait(|| pwr.d3cr.read().vosrdy().bit_is_set(), Timeout::VoltageScale)?;

        // SAFETY: values of RM0433 table 17 (LATENCY 0..=7, WRHIGHFREQ 0..=3).
        flash.acr.write(|w| unsafe { w.latency().bits(FLASH_LATENCY).wrhighfreq().bits(FLASH_WRHIGHFREQ) });
        wait(
            || {
                let acr = flash.acr.read();
                acr.latency().bits() == FLASH_LATENCY && acr.wrhighfreq().bits() == FLASH_WRHIGHFREQ
            },
            Timeout::FlashLatency,
        )?;

        let (m, n) = if hse { (PLL_M_HSE, PLL_N_HSE) } else { (PLL_M_HSI, PLL_N_HSI) };
        rcc.pllckselr.modify(|_, w| {
            let w = if hse { w.pllsrc().hse() } else { w.pllsrc().hsi() };
            // DIVM1 is 1 or 4 (const-checked above; 6 bits).
            w.divm1().bits(m as u8)
        });
        rcc.pllcfgr.modify(|_, w| {
            w.pll1rge()
                .range8()
                .pll1vcosel()
                .wide_vco()
                .pll1fracen()
                .reset()
                .divp1en()
                .enabled()
                .divq1en()
                .disabled()
                .divr1en()
                .disabled()
        });
        // SAFETY: DIVN1 = N - 1 with 4 <= N <= 512 and DIVP1 = P - 1 = 1 (even P), as
        // RM0433 8.7.12 requires (const-checked above).
        rcc.pll1divr.modify(|_, w| unsafe { w.divn1().bits((n - 1) as u16).divp1().bits((PLL_P - 1) as u8) });
        rcc.cr.modify(|_, w| w.pll1on().on());
        wait(|| rcc.cr.read().pll1rdy().is_ready(), Timeout::Pll1Lock)?;

        rcc.d1cfgr.modify(|_, w| w.d1cpre().div1().hpre().div2().d1ppre().div2());
        rcc.d2cfgr.modify(|_, w| w.d2ppre1().div2().d2ppre2().div2());
        rcc.d3cfgr.modify(|_, w| w.d3ppre().div2());
        rcc.cfgr.modify(|_, w| w.sw().pll1());
        if let Err(e) = wait(|| rcc.cfgr.read().sws().is_pll1(), Timeout::ClockSwitch) {
            // Back to the HSI and its prescalers, so the USART divider for the HSI holds.
            rcc.cfgr.modify(|_, w| w.sw().hsi());
            rcc.d1cfgr.modify(|_, w| w.d1cpre().div1().hpre().div1().d1ppre().div1());
            rcc.d2cfgr.modify(|_, w| w.d2ppre1().div1().d2ppre2().div1());
            rcc.d3cfgr.modify(|_, w| w.d3ppre().div1());
            return Err(e);
        }
        Ok(())
    }

    /// Pins (see README): PB6 = USART1_TX, PD6 = USART2_RX, PB11 = USART3_RX, all AF7
    /// (RM0433 11.4 GPIOx_MODER = 0b10 alternate, GPIOx_AFRL/AFRH = 7). The receive pins
    /// get the pull-up (GPIOx_PUPDR = 0b01): an unplugged line stays idle instead of
    /// floating into framing errors.
    fn pins(rcc: &pac::RCC, gpiob: &pac::GPIOB, gpiod: &pac::GPIOD) {
        rcc.ahb4enr.modify(|_, w| w.gpioben().enabled().gpioden().enabled());
        let _ = rcc.ahb4enr.read();
        gpiob.afrl.modify(|_, w| w.afr6().af7());
        gpiob.afrh.modify(|_, w| w.afr11().af7());
        gpiob.pupdr.modify(|_, w| w.pupdr11().pull_up());
        gpiob.moder.modify(|_, w| w.moder6().alternate().moder11().alternate());
        gpiod.afrl.modify(|_, w| w.afr6().af7());
        gpiod.pupdr.modify(|_, w| w.pupdr6().pull_up());
        gpiod.moder.modify(|_, w| w.moder6().alternate());
    }

    /// 8N1 at USARTDIV `brr` with the FIFOs on (RM0433 48.8: USART_BRR, USART_CR1 FIFOEN,
    /// M0/M1 = 0 for 8 data bits, PCE = 0, OVER8 = 0; USART_CR2.STOP = 0 at reset). A
    /// receiver (`rx`): RE and the RX-FIFO-not-empty interrupt (RXFNEIE, also raised by
    /// an overrun); else a transmitter: TE, its interrupt enabled by [`start_tx`].
    fn usart_start(u: &usart1::RegisterBlock, brr: u16, rx: bool) {
        u.cr1.write(|w| w.ue().disabled());
        u.brr.write(|w| w.brr().bits(brr));
        u.cr1.write(|w| {
            let w = w.fifoen().set_bit().m0().clear_bit().m1().clear_bit().pce().clear_bit().over8().clear_bit();
            let w = if rx { w.re().enabled().rxneie().enabled() } else { w.te().enabled() };
            w.ue().enabled()
        });
    }

    /// The calibration sector (the `CALIB` region of memory.x, one 128 KiB flash sector):
    /// the two stored copies of the table at its start (`ssis::calib::store`), checked by
    /// the boot policy. Erased flash reads as 0xFF, which the store refuses.
    fn calib_sector() -> &'static [u8] {
        let start = core::ptr::addr_of!(_calib_start);
        let len = (core::ptr::addr_of!(_calib_end) as usize).saturating_sub(start as usize);
        // SAFETY: memory.x reserves [_calib_start, _calib_end) (always mapped flash) for
        // the table; the firmware never writes it, so it does not change while borrowed.
        unsafe { core::slice::from_raw_parts(start, len) }
    }

    /// SysTick interrupts so far.
    pub fn ticks() -> u32 {
        TICKS.load(Ordering::Acquire)
    }

    /// Core cycles (DWT CYCCNT, wraps every 10.7 s at 400 MHz).
    pub fn cycles() -> u32 {
        DWT::cycle_count()
    }

    /// UART receive errors so far.
    pub fn uart_errors() -> u32 {
        UART_ERRORS.load(Ordering::Relaxed)
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

    /// The USARTs' registers, for their interrupts and [`start_tx`]. Set up in [`init`]
    /// before their interrupts are unmasked; CR1 is read-modify-written only inside
    /// critical sections.
    fn usart(p: *const usart1::RegisterBlock) -> &'static usart1::RegisterBlock {
        // SAFETY: a peripheral's fixed, always-mapped register block.
        unsafe { &*p }
    }

    /// Starts sending what the step wrote into [`OUT_TX`] (enables the USART1 TX-FIFO-
    /// not-full interrupt, USART_CR1.TXFNFIE, named TXEIE in the PAC).
    pub fn start_tx() {
        if OUT_TX.is_empty() {
            return;
        }
        free(|_| usart(pac::USART1::ptr()).cr1.modify(|_, w| w.txeie().enabled()));
    }

    #[exception]
    fn SysTick() {
        TICKS.fetch_add(1, Ordering::Release);
    }

    /// Output: fills the TX FIFO (USART_ISR.TXFNF, named TXE in the PAC) from the ring;
    /// stops listening once the ring is empty. Bounded by the FIFO's room.
    #[interrupt]
    fn USART1() {
        let u = usart(pac::USART1::ptr());
        free(|_| {
            while u.isr.read().txe().bit_is_set() {
                match OUT_TX.pop() {
                    Some(b) => u.tdr.write(|w| w.tdr().bits(u16::from(b))),
                    None => {
                        u.cr1.modify(|_, w| w.txeie().disabled());
                        break;
                    }
                }
            }
        });
    }

    #[interrupt]
    fn USART2() {
        receive(usart(pac::USART2::ptr()), &FOG_RX);
    }

    #[interrupt]
    fn USART3() {
        receive(usart(pac::USART3::ptr()), &ST_RX);
    }

    /// Moves what the USART's RX FIFO holds into `ring`, counting and clearing (USART_ICR)
    /// the error flags: overrun ORE, framing FE, noise NE, parity PE.
    fn receive(u: &usart1::RegisterBlock, ring: &RxRing<512>) {
        // Bounded: the 16-byte FIFO plus its error flags.
        for _ in 0..32 {
            let isr = u.isr.read();
            if isr.ore().bit_is_set() || isr.fe().bit_is_set() || isr.nf().bit_is_set() || isr.pe().bit_is_set() {
                UART_ERRORS.fetch_add(1, Ordering::Relaxed);
                u.icr.write(|w| w.orecf().clear().fecf().clear().ncf().clear().pecf().clear());
            }
            if isr.rxne().bit_is_clear() {
                break;
            }
            // Only the low 8 bits carry data (8N1).
            ring.push(u.rdr.read().rdr().bits() as u8);
        }
    }

    /// Bytes of the RTT up channel's buffer.
    const RTT_BUF_LEN: usize = 1024;

    /// The RTT control block the probe finds (by its `_SEGGER_RTT` symbol or by the id
    /// at its start) and reads the up channel of: SEGGER's layout, one up channel named
    /// `defmt`, no down channel.
    #[repr(C)]
    pub struct RttControlBlock {
        id: [u8; 16],
        max_up: u32,
        max_down: u32,
        up: RttChannel,
    }

    #[repr(C)]
    struct RttChannel {
        name: *const u8,
        buffer: *mut u8,
        size: u32,
        /// Written by the target.
        write: AtomicU32,
        /// Written by the probe.
        read: AtomicU32,
        flags: u32,
    }

    // SAFETY: the pointers are to statics; the buffer is written only by `rtt_write`,
    // which runs inside the logger's critical section, and read by the probe.
    unsafe impl Sync for RttControlBlock {}

    struct RttBuffer(core::cell::UnsafeCell<[u8; RTT_BUF_LEN]>);

    // SAFETY: see `RttControlBlock`.
    unsafe impl Sync for RttBuffer {}

    static RTT_BUFFER: RttBuffer = RttBuffer(core::cell::UnsafeCell::new([0; RTT_BUF_LEN]));
    static RTT_NAME: [u8; 6] = *b"defmt\0";

    /// The control block.
    #[no_mangle]
    pub static _SEGGER_RTT: RttControlBlock = RttControlBlock {
        id: *b"SEGGER RTT\0\0\0\0\0\0",
        max_up: 1,
        max_down: 0,
        up: RttChannel {
            name: RTT_NAME.as_ptr(),
            buffer: RTT_BUFFER.0.get().cast(),
            size: RTT_BUF_LEN as u32,
            write: AtomicU32::new(0),
            read: AtomicU32::new(0),
            // Non-blocking, trim: what does not fit is dropped, the unit never waits
            // for the probe (the defmt decoder resynchronises at the next frame).
            flags: 1,
        },
    };

    /// The log's output (the logger of `ssis_firmware::cortex_m7_runtime!`): `bytes` into the RTT
    /// up channel, as much as fits; never waits and never panics.
    pub fn rtt_write(bytes: &[u8]) {
        let ch = &_SEGGER_RTT.up;
        let read = ch.read.load(Ordering::Acquire) as usize;
        let mut write = ch.write.load(Ordering::Relaxed) as usize;
        if write >= RTT_BUF_LEN {
            write = 0;
        }
        let buf: *mut u8 = RTT_BUFFER.0.get().cast();
        for &b in bytes {
            let next = (write + 1) % RTT_BUF_LEN;
            if next == read {
                break;
            }
            // SAFETY: `write` < RTT_BUF_LEN (checked above, kept by the modulo).
            unsafe { buf.add(write).write_volatile(b) };
            write = next;
        }
        ch.write.store(write as u32, Ordering::Release);
    }
}
