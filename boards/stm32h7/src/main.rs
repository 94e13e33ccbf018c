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
//! - **Boot**: the boot policy every board shares (`ssis::bsp::boot`): the calibration
//!   table's two stored copies in the last flash sector (`CALIB` in `memory.x`,
//!   0x081E_0000; the newest good copy, else the other, else `CalibrationTable::DEFAULT`
//!   with the defaulted flag set in every output frame), the flight core, the power-on
//!   built-in test. This board implements `ssis::bsp::Board` ([`board::Stm32h7`]).
//! - **Watchdog**: the IWDG (50 ms) starts first thing and is fed once per step.
//! - **Log**: defmt over RTT (a panic-free RTT channel, [`board::rtt_write`]): at boot
//!   (reset reason, clock, table), every 10 s (counters, stack high-water).
//! - **Panics**: no `unwrap`/`expect`/`panic!` in this firmware or the flight core; the
//!   only panic paths left are the HAL's asserts in the clock and USART setup, before the
//!   first step (`bash scripts/panic-paths --board stm32h7` lists them). A panic, or a
//!   setup failure, is logged and the CPU parks ([`park`]) until the watchdog resets it.
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
use ssis::bsp::{cortex_m7, Board};
use ssis::flight::{FlightCore, FogLinks, Links, Profile};
use ssis::frames::output::OutputFrame;

// `panic: log`, not `never`: the HAL's clock and USART setup (`rcc::Rcc::freeze`,
// `serial()`) keep asserts on registers they read back, which no optimiser can remove,
// so the link-time proof cannot hold with it (README "No panics, stack overflow"). A
// panic logs `panic` and parks; the watchdog then resets the unit.
ssis::cortex_m7_runtime!(sink: board::rtt_write, stop: board::halt, panic: log);

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
    match boot::boot(&mut hw, profile, false, |hw, core, report| fly(hw, core, report, profile)) {
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
        if hw.hse { "HSE" } else { "HSI (HSE did not start)" },
        core.table().revision,
        report.defaulted,
        profile.dt_us
    );

    let mut links = Links {
        fog: FogLinks::Bus(board::FOG_RX.reader()),
        star: board::ST_RX.reader(),
        out: board::OUT_TX.frame_writer(OutputFrame::LEN),
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

    use core::cell::RefCell;
    use core::sync::atomic::{AtomicU32, Ordering};

    use cortex_m::interrupt::{free, Mutex};
    use cortex_m::peripheral::syst::SystClkSource;
    use cortex_m::peripheral::{DWT, NVIC};
    use cortex_m_rt::exception;
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
    /// Output transmit buffer: three 83-byte output frames.
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
        /// Start of the `CALIB` region (memory.x): the calibration sector.
        static _calib_start: u8;
        /// Its end.
        static _calib_end: u8;
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
    pub struct Stm32h7 {
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

    impl ssis::bsp::Board for Stm32h7 {
        fn calib_area(&self) -> &[u8] {
            calib_sector()
        }

        fn feed_watchdog(&mut self) {
            self.watchdog.feed();
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

    /// Brings up the watchdog, clocks, UARTs and their interrupts, and the step tick of
    /// `step_us`.
    pub fn init(step_us: u32) -> Result<Stm32h7, SetupError> {
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
            // Nothing holds a borrow yet (the interrupts are still masked).
            if let Ok(mut slot) = OUT_UART.borrow(cs).try_borrow_mut() {
                *slot = Some(out);
            }
            if let Ok(mut slot) = FOG_UART.borrow(cs).try_borrow_mut() {
                *slot = Some(fog);
            }
            if let Ok(mut slot) = ST_UART.borrow(cs).try_borrow_mut() {
                *slot = Some(st);
            }
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
        Ok(Stm32h7 { watchdog, cycles_per_tick: (core_hz / STEP_TICK_HZ).max(1), core_hz, hse, reset_reason })
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

    /// The log's output (the logger of `ssis::cortex_m7_runtime!`): `bytes` into the RTT
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
