//! `ssis-fw-stm32h7`: the ssis flight core on an STM32H743ZI (Cortex-M7), spacecraft
//! profile (four FOGs on one RS-485 bus, star tracker, 5 ms steps).
//!
//! What it does:
//! - **Clock**: 400 MHz core from the 8 MHz HSE in bypass mode (the ST-LINK MCO of a
//!   NUCLEO-H743ZI; a flight board's oscillator likewise). If the HSE is not ready within
//!   10 ms, the 64 MHz HSI is used instead and the boot log says so.
//! - **Links**, all 921 600 Bd 8N1, interrupt-driven:
//!   USART1 TX = framed output, from a `TxRing<256>` drained by the TX-FIFO-not-full
//!   interrupt; USART2 RX = the FOG RS-485 bus (all four FOGs, told apart by `fog_id`)
//!   into an `RxRing<512>`; USART3 RX = star tracker into an `RxRing<512>`.
//! - **Step**: SysTick at 200 Hz; the main loop sleeps (WFI) until the tick, runs one
//!   [`FlightCore::step`], measures it with the DWT cycle counter and reports it in
//!   25 MHz ticks (40 ns, the QEMU board's unit) through `set_step_ticks`. A step that
//!   ends after the next tick has come counts one overrun per tick that came.
//! - **Calibration table**: read from the last flash sector (`CALIB` in `memory.x`,
//!   0x081E_0000) with `binary::decode`; if refused, `CalibrationTable::DEFAULT` with the
//!   defaulted flag (set in every output frame).
//! - **Watchdog**: the IWDG (50 ms) starts first thing and is fed once per step.
//! - **Log**: defmt over RTT: at boot (reset reason, clock, table), every 10 s (counters).
//! - No `unwrap`/`expect`/`panic!`: a setup failure is logged and the CPU parks ([`park`]).
#![no_std]
#![no_main]
#![deny(unsafe_code)] // allowed in `board` only
#![deny(clippy::unwrap_used, clippy::expect_used, clippy::panic, clippy::indexing_slicing)]

use defmt_rtt as _;
use panic_probe as _;

use ssis::calib::{binary, CalibrationTable};
use ssis::flight::{FlightCore, FogLinks, Links, Profile};
use ssis::frames::output::OutputFrame;

/// Steps between two status logs (10 s of 5 ms steps).
const LOG_EVERY_STEPS: u32 = 2_000;

#[cortex_m_rt::entry]
fn main() -> ! {
    let profile = Profile::SPACECRAFT;
    let mut hw = match board::init(profile.dt_us) {
        Ok(hw) => hw,
        Err(e) => {
            defmt::error!("board setup failed: {}", e);
            park()
        }
    };

    let (table, defaulted) = match binary::decode(board::calib_bytes()) {
        Ok(t) => (t, false),
        Err(e) => {
            defmt::warn!("calibration table at {=u32:#x} refused ({}): default table", board::calib_addr(), e);
            (CalibrationTable::DEFAULT, true)
        }
    };
    let (core, defaulted) = match FlightCore::new(profile, &table, defaulted) {
        Ok(c) => (Ok(c), defaulted),
        Err(e) => {
            defmt::warn!("flight core refused table revision {} ({}): default table", table.revision, e);
            (FlightCore::new(profile, &CalibrationTable::DEFAULT, true), true)
        }
    };
    let mut core = match core {
        Ok(c) => c,
        Err(e) => {
            defmt::error!("flight core refused the default table: {}", e);
            park()
        }
    };
    // Power-on built-in test: logged and flagged in every output frame on failure.
    if let Err(e) = ssis::bit::power_on() {
        defmt::error!("built-in test failed: {}", e);
        core.note_bit_failure();
    }
    hw.feed_watchdog();
    defmt::info!(
        "ssis-fw-stm32h7 up: reset {}, core {} Hz from {}, table revision {} (defaulted {}), step {} us",
        hw.reset_reason,
        hw.core_hz,
        if hw.hse { "HSE" } else { "HSI (HSE did not start)" },
        core.table().revision,
        defaulted,
        profile.dt_us
    );

    let mut links = Links {
        fog: FogLinks::Bus(board::FOG_RX.reader()),
        star: board::ST_RX.reader(),
        out: board::OUT_TX.frame_writer(OutputFrame::LEN),
    };
    let mut window = Window::default();
    let mut steps: u32 = 0;
    let mut handled = board::ticks();
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
        let late = board::ticks().wrapping_sub(handled);
        for _ in 0..late.min(1_000) {
            core.note_overrun();
        }
        // Wall time of the step, interrupts included; the u16 field saturates at 2.6 ms.
        let ticks = cycles / hw.cycles_per_tick;
        core.set_step_ticks(u16::try_from(ticks).unwrap_or(u16::MAX));
        window.add(ticks);

        steps = steps.wrapping_add(1);
        if steps.is_multiple_of(LOG_EVERY_STEPS) {
            log_status(&core, handled / (1_000_000 / profile.dt_us), &window);
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
/// calibration sector. The flight core sees only the rings.
mod board {
    #![allow(unsafe_code)]

    use core::cell::RefCell;
    use core::sync::atomic::{AtomicU32, Ordering};

    use cortex_m::interrupt::{free, Mutex};
    use cortex_m::peripheral::syst::SystClkSource;
    use cortex_m::peripheral::{DWT, NVIC};
    use cortex_m_rt::exception;
    use ssis::calib::binary::TABLE_LEN;
    use ssis::link::{RxRing, TxRing};
    use stm32h7xx_hal::gpio::Pull;
    use stm32h7xx_hal::independent_watchdog::IndependentWatchdog;
    use stm32h7xx_hal::nb;
    use stm32h7xx_hal::pac::{self, interrupt, Interrupt, USART1, USART2, USART3};
    use stm32h7xx_hal::prelude::*;
    use stm32h7xx_hal::rcc::ResetReason;
    use stm32h7xx_hal::serial::{self, NoRx, NoTx, Rx, Tx};

    /// HSE frequency (NUCLEO-H743ZI: 8 MHz from the ST-LINK MCO).
    const HSE_HZ: u32 = 8_000_000;
    /// The HSE is an external clock signal (bypass), not a crystal.
    const HSE_BYPASS: bool = true;
    /// Longest wait for the HSE before falling back to the HSI, in HSI cycles (10 ms).
    const HSE_TIMEOUT_CYCLES: u32 = 640_000;
    /// Core clock: the most the STM32H743 (rev V) runs at in voltage scale 1.
    const CORE_HZ: u32 = 400_000_000;
    /// All three links.
    const BAUD: u32 = 921_600;
    /// Unit of the step time in the output frame (the QEMU board's SysTick, 40 ns).
    const STEP_TICK_HZ: u32 = 25_000_000;
    /// Watchdog timeout: 10 steps, and more than the boot takes before the first feed.
    const WATCHDOG_MS: u32 = 50;

    /// FOG bus receive buffer: 512 bytes = 5.6 ms at 921 600 Bd, more than a step at full line rate.
    pub static FOG_RX: RxRing<512> = RxRing::new();
    /// Star-tracker receive buffer.
    pub static ST_RX: RxRing<512> = RxRing::new();
    /// Output transmit buffer: three 79-byte output frames.
    pub static OUT_TX: TxRing<256> = TxRing::new();

    /// SysTick interrupts since start.
    static TICKS: AtomicU32 = AtomicU32::new(0);
    /// Receive errors (framing, noise, parity, hardware overrun) on USART2 and USART3.
    static UART_ERRORS: AtomicU32 = AtomicU32::new(0);
    /// The UART halves, handed to their interrupts.
    static OUT_UART: Mutex<RefCell<Option<Tx<USART1>>>> = Mutex::new(RefCell::new(None));
    static FOG_UART: Mutex<RefCell<Option<Rx<USART2>>>> = Mutex::new(RefCell::new(None));
    static ST_UART: Mutex<RefCell<Option<Rx<USART3>>>> = Mutex::new(RefCell::new(None));

    extern "C" {
        /// Start of the `CALIB` region (memory.x): the stored calibration table.
        static _calib_start: [u8; TABLE_LEN];
    }

    /// What can fail in [`init`].
    #[derive(defmt::Format)]
    pub enum SetupError {
        /// The peripherals were already taken (init called twice).
        PeripheralsTaken,
        /// The HAL refused the configuration of this UART.
        Uart(&'static str),
        /// The step period does not fit the 24-bit SysTick at this core clock.
        StepPeriod,
    }

    /// The board once set up; the UARTs and the tick live in their interrupts.
    pub struct Board {
        watchdog: IndependentWatchdog,
        /// Core cycles per step-time tick.
        pub cycles_per_tick: u32,
        /// Core clock, Hz.
        pub core_hz: u32,
        /// Whether the core clock comes from the HSE (else the HSI).
        pub hse: bool,
        /// Why the MCU last reset.
        pub reset_reason: &'static str,
    }

    impl Board {
        /// Restarts the watchdog's count-down.
        pub fn feed_watchdog(&mut self) {
            self.watchdog.feed();
        }
    }

    /// Brings up the watchdog, clocks, UARTs and their interrupts, and the step tick of
    /// `step_us`.
    pub fn init(step_us: u32) -> Result<Board, SetupError> {
        let (Some(mut cp), Some(dp)) = (cortex_m::Peripherals::take(), pac::Peripherals::take()) else {
            return Err(SetupError::PeripheralsTaken);
        };
        // Watchdog first: a setup step that hangs (the HAL waits without a bound for
        // each clock to become ready) or fails now ends in a reset. It keeps counting
        // through a debugger halt unless frozen, which only matters with a probe attached.
        dp.DBGMCU.apb4fz1.modify(|_, w| w.dbg_iwdg1().set_bit());
        let mut watchdog = IndependentWatchdog::new(dp.IWDG);
        watchdog.start(WATCHDOG_MS.millis());

        DWT::unlock(); // the STM32H7 locks the DWT after a power cycle
        cp.DCB.enable_trace();
        cp.DWT.enable_cycle_counter();
        // Caches: safe here with no DMA; RAM is DTCM (never cached), peripherals are
        // device memory. The D-cache serves the constants in flash.
        cp.SCB.enable_icache();
        cp.SCB.enable_dcache(&mut cp.CPUID);

        let hse = hse_starts(&dp.RCC);
        let pwrcfg = dp.PWR.constrain().freeze();
        let mut rcc = dp.RCC.constrain();
        let reset_reason = reset_name(rcc.get_reset_reason());
        let rcc = if hse {
            let rcc = rcc.use_hse(HSE_HZ.Hz());
            if HSE_BYPASS {
                rcc.bypass_hse()
            } else {
                rcc
            }
        } else {
            rcc
        };
        let ccdr = rcc.sys_ck(CORE_HZ.Hz()).freeze(pwrcfg, &dp.SYSCFG);
        let core_hz = ccdr.clocks.c_ck().raw();

        // Pins: see README (NUCLEO-H743ZI headers). Pull-ups keep an unplugged receive
        // line idle instead of floating into framing errors.
        let gpiob = dp.GPIOB.split(ccdr.peripheral.GPIOB);
        let gpiod = dp.GPIOD.split(ccdr.peripheral.GPIOD);
        let out_tx = gpiob.pb6.into_alternate::<7>();
        let fog_rx = gpiod.pd6.into_alternate::<7>().internal_resistor(Pull::Up);
        let st_rx = gpiob.pb11.into_alternate::<7>().internal_resistor(Pull::Up);

        let config = serial::config::Config::new(BAUD.Hz()); // 8 data bits, no parity, 1 stop
        let (out, _) = dp
            .USART1
            .serial((out_tx, NoRx), config, ccdr.peripheral.USART1, &ccdr.clocks)
            .map_err(|_| SetupError::Uart("USART1"))?
            .split();
        let (_, mut fog) = dp
            .USART2
            .serial((NoTx, fog_rx), config, ccdr.peripheral.USART2, &ccdr.clocks)
            .map_err(|_| SetupError::Uart("USART2"))?
            .split();
        let (_, mut st) = dp
            .USART3
            .serial((NoTx, st_rx), config, ccdr.peripheral.USART3, &ccdr.clocks)
            .map_err(|_| SetupError::Uart("USART3"))?
            .split();
        fog.listen();
        st.listen();
        free(|cs| {
            OUT_UART.borrow(cs).replace(Some(out));
            FOG_UART.borrow(cs).replace(Some(fog));
            ST_UART.borrow(cs).replace(Some(st));
        });

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
            // SAFETY: the handlers touch only the rings, the atomics and the UART halves,
            // all behind critical sections, and the halves are in place (above).
            unsafe { NVIC::unmask(irq) };
        }
        Ok(Board { watchdog, cycles_per_tick: (core_hz / STEP_TICK_HZ).max(1), core_hz, hse, reset_reason })
    }

    /// Turns the HSE on and waits for it at most [`HSE_TIMEOUT_CYCLES`] (the HAL would
    /// wait forever). Leaves it on if it is ready, off otherwise.
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

    fn reset_name(r: ResetReason) -> &'static str {
        match r {
            ResetReason::PowerOnReset => "power-on",
            ResetReason::PinReset => "pin",
            ResetReason::BrownoutReset => "brown-out",
            ResetReason::SystemReset | ResetReason::CpuReset => "software",
            ResetReason::IndependentWatchdogReset => "IWDG",
            ResetReason::WindowWatchdogReset | ResetReason::GenericWatchdogReset => "watchdog",
            _ => "other",
        }
    }

    /// The stored calibration table's bytes (validated by `binary::decode`).
    pub fn calib_bytes() -> &'static [u8] {
        // SAFETY: memory.x reserves the CALIB region (one 128 KiB flash sector, always
        // mapped) for the table; the firmware never writes it, so it does not change
        // while borrowed. Erased flash reads as 0xFF, which `decode` refuses.
        unsafe { &_calib_start }
    }

    /// Address of the stored calibration table.
    pub fn calib_addr() -> u32 {
        calib_bytes().as_ptr() as u32
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

    /// Starts sending what the step wrote into [`OUT_TX`] (enables the TX interrupt).
    pub fn start_tx() {
        free(|cs| {
            if let Ok(mut slot) = OUT_UART.borrow(cs).try_borrow_mut() {
                if let Some(tx) = slot.as_mut().filter(|_| !OUT_TX.is_empty()) {
                    tx.listen();
                }
            }
        });
    }

    #[exception]
    fn SysTick() {
        TICKS.fetch_add(1, Ordering::Release);
    }

    /// Output: fills the TX FIFO from the ring; stops listening once the ring is empty.
    #[interrupt]
    fn USART1() {
        free(|cs| {
            let Ok(mut slot) = OUT_UART.borrow(cs).try_borrow_mut() else { return };
            let Some(tx) = slot.as_mut() else { return };
            // Bounded by the ring's contents.
            while tx.is_txe() {
                match OUT_TX.pop() {
                    // Cannot be refused: the FIFO has room (checked above).
                    Some(b) => {
                        let _ = tx.write(b);
                    }
                    None => {
                        tx.unlisten();
                        break;
                    }
                }
            }
        });
    }

    #[interrupt]
    fn USART2() {
        receive(&FOG_UART, &FOG_RX);
    }

    #[interrupt]
    fn USART3() {
        receive(&ST_UART, &ST_RX);
    }

    /// Moves what the UART's RX FIFO holds into `ring`, counting (and so clearing) the
    /// error flags.
    fn receive<U>(uart: &Mutex<RefCell<Option<Rx<U>>>>, ring: &RxRing<512>)
    where
        Rx<U>: stm32h7xx_hal::hal::serial::Read<u8, Error = serial::Error>,
    {
        free(|cs| {
            let Ok(mut slot) = uart.borrow(cs).try_borrow_mut() else { return };
            let Some(rx) = slot.as_mut() else { return };
            // Bounded: the 16-byte FIFO plus its error flags (each read clears one).
            for _ in 0..32 {
                match rx.read() {
                    Ok(b) => ring.push(b),
                    Err(nb::Error::WouldBlock) => break,
                    Err(nb::Error::Other(_)) => {
                        UART_ERRORS.fetch_add(1, Ordering::Relaxed);
                    }
                }
            }
        });
    }
}
