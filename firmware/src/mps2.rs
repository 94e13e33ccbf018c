//! Board: QEMU `mps2-an500` (Cortex-M7, FPv5-D16), for both flight firmwares (the
//! spacecraft `ssis-fw` and the launch-vehicle `ssis-fw-lv`) and the on-target tests.
//! A firmware brings its mission (`ssis::bsp::exec::Mission`), its [`UartMap`] and its memory budget (`memory.x` or
//! `link/memory-lv.x`); everything that touches hardware is here, and the flight core
//! knows only the link traits.
//!
//! - Five CMSDK APB UARTs (QEMU `hw/arm/mps2.c`, `hw/char/cmsdk-apb-uart.c`); which ring
//!   each one's RX feeds and TX drains is the firmware's [`UartMap`]. RX is
//!   interrupt-driven (the `DefaultHandler` of [`mps2_firmware!`](crate::mps2_firmware)),
//!   TX written by [`pump_tx`] from the main loop.
//!   | UART | base | RX / TX IRQ |
//!   |---|---|---|
//!   | 0 | 0x4000_4000 | 0 / 1 |
//!   | 1 | 0x4000_5000 | 2 / 3 |
//!   | 2 | 0x4000_6000 | 4 / 5 |
//!   | 3 | 0x4000_7000 | 18 / 19 |
//!   | 4 | 0x4000_9000 | 20 / 21 |
//! - SysTick at 25 MHz: the step tick and the step-time measure ([`Stopwatch`]).
//! - CMSDK APB watchdog (QEMU `hw/watchdog/cmsdk-apb-watchdog.c`, 0x4000_8000, clocked
//!   at 25 MHz, interrupt wired to NMI): the executive feeds it only after a step
//!   completed within its deadline (`ssis::bsp::exec`); after one timeout without a feed the NMI logs a warning, after a second one the watchdog
//!   resets the unit (QEMU: its `-action watchdog=` choice).
//! - Stack guard: both layouts put the stack at the bottom of RAM (0x2000_0000), and
//!   [`start`] makes the 256 MiB below it no-access (`cortex_m7::protect_below_stack`):
//!   QEMU's mps2-an500 does not fault there by itself (measured: a runaway recursion went
//!   8 MiB below 0x2000_0000 unchecked).
//! - Semihosting: the defmt log ([`semihosting_sink`]) and the exit code of a QEMU run
//!   ([`exit`]).
//! - Configuration registers (`crate::regcheck`): SysTick, the vector table, the UARTs
//!   and their interrupts, the MPU, the watchdog, kept at start-up ([`Mps2Unit::start`])
//!   and checked by the executive every `REGISTER_STEPS` and by the watchdog's NMI.
//! - The executive's board ([`Mps2Unit`], `ssis::bsp::exec::StepBoard`): the pacing
//!   ([`Pacer`]: the timer, or, test builds only, lockstep driven by control frames),
//!   the clock, the snapshot region and the code image (`crate::resilience`).
#![allow(unsafe_code)]

use core::cell::UnsafeCell;
use core::sync::atomic::{AtomicU32, Ordering};

use cortex_m::peripheral::syst::SystClkSource;
use cortex_m::peripheral::{NVIC, SYST};
use heapless::Deque;

use crate::cortex_m7;
use ssis::bsp::exec::{StepBoard, Wait};
use ssis::bsp::Board;
use ssis::flight::snapshot::Snapshots;
use ssis::flight::FlightCore;
use ssis::frames::control::{command, ControlFrame};
use ssis::frames::decoder::StreamDecoder;
use ssis::link::{drain, RxRing, RxRingReader, TxRing};

/// SysTick clock of the board, Hz (QEMU mps2: SYSCLK 25 MHz).
pub const SYSCLK_HZ: u32 = 25_000_000;

/// Where a UART's received bytes go (an [`RxRing`]).
pub trait RxSink: Sync {
    /// Stores one received byte (from the interrupt).
    fn push(&self, byte: u8);
}

impl<const N: usize> RxSink for RxRing<N> {
    fn push(&self, byte: u8) {
        RxRing::push(self, byte);
    }
}

/// Where a UART's bytes to send come from (a [`TxRing`]).
pub trait TxSource: Sync {
    /// The next byte to send.
    fn pop(&self) -> Option<u8>;
    /// Whether nothing is waiting.
    fn is_empty(&self) -> bool;
    /// Most bytes it holds (bounds one pump).
    fn capacity(&self) -> usize;
}

impl<const N: usize> TxSource for TxRing<N> {
    fn pop(&self) -> Option<u8> {
        TxRing::pop(self)
    }

    fn is_empty(&self) -> bool {
        TxRing::is_empty(self)
    }

    fn capacity(&self) -> usize {
        N
    }
}

/// What one UART does: the ring its RX feeds, the ring its TX drains (either may be
/// absent; a UART with neither is left off).
#[derive(Clone, Copy)]
pub struct Uart {
    /// Received bytes go here (RX and its interrupt enabled).
    pub rx: Option<&'static dyn RxSink>,
    /// Bytes to send come from here.
    pub tx: Option<&'static dyn TxSource>,
}

impl Uart {
    /// A UART the firmware does not use.
    pub const OFF: Uart = Uart { rx: None, tx: None };
}

/// A firmware's use of the five UARTs, by UART number.
pub type UartMap = [Uart; 5];

const UART_BASE: [usize; 5] = [0x4000_4000, 0x4000_5000, 0x4000_6000, 0x4000_7000, 0x4000_9000];
/// RX interrupt numbers of the UARTs (TX is one more).
const UART_RX_IRQ: [u16; 5] = [0, 2, 4, 18, 20];
const DATA: usize = 0x00;
const STATE: usize = 0x04;
const CTRL: usize = 0x08;
const INTSTATUS: usize = 0x0C;
const BAUDDIV: usize = 0x10;
const STATE_TX_FULL: u32 = 1 << 0;
const STATE_RX_FULL: u32 = 1 << 1;
const CTRL_TX_EN: u32 = 1 << 0;
const CTRL_RX_EN: u32 = 1 << 1;
const CTRL_RX_INT_EN: u32 = 1 << 3;
const INT_RX: u32 = 1 << 1;

fn reg(uart: usize, off: usize) -> *mut u32 {
    (UART_BASE.get(uart).copied().unwrap_or(UART_BASE[0]) + off) as *mut u32
}

fn read(uart: usize, off: usize) -> u32 {
    // SAFETY: a CMSDK UART register of this board, 4-byte aligned, always mapped.
    unsafe { core::ptr::read_volatile(reg(uart, off)) }
}

fn write(uart: usize, off: usize, v: u32) {
    // SAFETY: as in `read`.
    unsafe { core::ptr::write_volatile(reg(uart, off), v) }
}

#[derive(Clone, Copy)]
struct Irq(u16);

// SAFETY: the numbers are this board's external interrupt lines.
unsafe impl cortex_m::interrupt::InterruptNumber for Irq {
    fn number(self) -> u16 {
        self.0
    }
}

/// SysTick interrupts since start.
static TICKS: AtomicU32 = AtomicU32::new(0);

/// First thing in `main`: the stack guard below RAM (0x1000_0000..0x2000_0000, where
/// both layouts put the stack's bottom), the first 256 KiB of flash read-only (the
/// image; both layouts put their written regions, calibration and key or LV data, at
/// 0x4_0000 and above) and the stack painted for the high-water mark.
pub fn start() {
    cortex_m7::protect_below_stack(0x1000_0000, 28);
    cortex_m7::protect_image(18);
    cortex_m7::paint_stack();
}

/// Brings up the UARTs of `map`, their receive interrupts and the step tick of `step_us`.
pub fn init(mut syst: SYST, step_us: u32, map: &UartMap) {
    for (uart, u) in map.iter().enumerate() {
        if u.rx.is_none() && u.tx.is_none() {
            continue;
        }
        write(uart, BAUDDIV, 16);
        let rx = if u.rx.is_some() { CTRL_RX_EN | CTRL_RX_INT_EN } else { 0 };
        write(uart, CTRL, CTRL_TX_EN | rx);
    }
    syst.set_clock_source(SystClkSource::Core);
    syst.set_reload(SYSCLK_HZ / 1_000_000 * step_us - 1);
    syst.clear_current();
    syst.enable_interrupt();
    syst.enable_counter();
    for (u, irq) in map.iter().zip(UART_RX_IRQ) {
        if u.rx.is_some() {
            // SAFETY: the handler (`on_irq`) only touches the critical-section rings.
            unsafe { NVIC::unmask(Irq(irq)) };
        }
    }
}

/// Moves received bytes of `uart` into `ring` and clears the interrupt.
fn rx_isr(uart: usize, ring: &dyn RxSink) {
    // Clear first, then drain: a byte that lands after the clear raises the interrupt
    // again, so none is left sitting in the (one-byte) receive register unseen.
    write(uart, INTSTATUS, INT_RX);
    // Bounded: QEMU's CMSDK UART holds one byte; real ones a few.
    for _ in 0..16 {
        if read(uart, STATE) & STATE_RX_FULL == 0 {
            break;
        }
        ring.push((read(uart, DATA) & 0xFF) as u8);
    }
}

/// External interrupt `irqn` (the `DefaultHandler`; no device crate): a UART's RX.
pub fn on_irq(map: &UartMap, irqn: i16) {
    for (uart, (u, irq)) in map.iter().zip(UART_RX_IRQ).enumerate() {
        if i32::from(irq) == i32::from(irqn) {
            if let Some(ring) = u.rx {
                rx_isr(uart, ring);
            }
        }
    }
}

/// Main-loop backstop: drains any receive register still full (two reads per UART when
/// idle).
pub fn poll_rx(map: &UartMap) {
    cortex_m::interrupt::free(|_| {
        for (uart, u) in map.iter().enumerate() {
            if let Some(ring) = u.rx {
                rx_isr(uart, ring);
            }
        }
    });
}

/// Sends what fits of every TX ring of `map`; never waits.
pub fn pump_tx(map: &UartMap) {
    for (uart, u) in map.iter().enumerate() {
        let Some(ring) = u.tx else { continue };
        // Bounded by the ring's size.
        for _ in 0..ring.capacity() {
            if read(uart, STATE) & STATE_TX_FULL != 0 {
                break;
            }
            match ring.pop() {
                Some(b) => write(uart, DATA, u32::from(b)),
                None => break,
            }
        }
    }
}

/// Whether every TX ring of `map` is empty.
pub fn tx_idle(map: &UartMap) -> bool {
    map.iter().all(|u| u.tx.is_none_or(|r| r.is_empty()))
}

/// The SysTick handler's work.
pub fn on_systick() {
    TICKS.fetch_add(1, Ordering::Release);
}

/// SysTick interrupts so far.
pub fn ticks() -> u32 {
    TICKS.load(Ordering::Acquire)
}

/// Ticks of the step period (the SysTick reload + 1).
pub fn ticks_per_step() -> u32 {
    SYST::get_reload() + 1
}

/// The board's clock ([`StepBoard::clock`]): SysTick ticks (40 ns) since start, wrapping;
/// it stands still while the SysTick counter is disabled.
pub fn clock() -> u32 {
    let p = ticks_per_step();
    let (mut n, mut c) = (ticks(), SYST::get_current());
    // A tick between the two reads: read again (bounded: one retry).
    if ticks() != n {
        (n, c) = (ticks(), SYST::get_current());
    }
    n.wrapping_mul(p).wrapping_add(p.saturating_sub(1).saturating_sub(c))
}

/// A point in time for [`Stopwatch::ticks`]: SysTick interrupts and the counter value.
#[derive(Clone, Copy)]
pub struct Stopwatch {
    n0: u32,
    c0: u32,
}

impl Stopwatch {
    /// Now.
    pub fn start() -> Self {
        Stopwatch { n0: ticks(), c0: SYST::get_current() }
    }

    /// SysTick ticks (40 ns) since the start.
    pub fn ticks(&self) -> u32 {
        let (n1, c1) = (ticks(), SYST::get_current());
        // SysTick counts down; each interrupt in between adds a period.
        let e = i64::from(n1.wrapping_sub(self.n0)) * i64::from(ticks_per_step()) + i64::from(self.c0) - i64::from(c1);
        u32::try_from(e.max(0)).unwrap_or(u32::MAX)
    }
}

const WDOG_BASE: usize = 0x4000_8000;
const WDOG_LOAD: usize = 0x000;
const WDOG_CONTROL: usize = 0x008;
const WDOG_INTCLR: usize = 0x00C;
const WDOG_LOCK: usize = 0xC00;
const WDOG_UNLOCK_KEY: u32 = 0x1ACC_E551;
const WDOG_INTEN: u32 = 1 << 0;
const WDOG_RESEN: u32 = 1 << 1;

/// Watchdog warnings (first timeouts, each an NMI) since start.
static WATCHDOG_WARNINGS: AtomicU32 = AtomicU32::new(0);

fn wdog_write(off: usize, v: u32) {
    // SAFETY: a register of the board's watchdog, a 32-bit MMIO location.
    unsafe { core::ptr::write_volatile((WDOG_BASE + off) as *mut u32, v) }
}

/// Starts the watchdog with `timeout_us` per stage (warning NMI, then reset).
pub fn watchdog_start(timeout_us: u32) {
    wdog_write(WDOG_LOCK, WDOG_UNLOCK_KEY);
    wdog_write(WDOG_LOAD, SYSCLK_HZ / 1_000_000 * timeout_us);
    wdog_write(WDOG_CONTROL, WDOG_INTEN | WDOG_RESEN);
    wdog_write(WDOG_LOCK, 0);
}

/// Feeds the watchdog: clears a pending warning and reloads the counter.
pub fn watchdog_feed() {
    wdog_write(WDOG_LOCK, WDOG_UNLOCK_KEY);
    wdog_write(WDOG_INTCLR, 1);
    wdog_write(WDOG_LOCK, 0);
}

/// Watchdog warnings so far.
pub fn watchdog_warnings() -> u32 {
    WATCHDOG_WARNINGS.load(Ordering::Relaxed)
}

/// The NMI handler's work: the main loop has not fed the watchdog for one period.
/// Logged and counted; not cleared here, so if the loop does not recover the watchdog
/// resets the unit at the second timeout.
pub fn on_watchdog_warning() {
    WATCHDOG_WARNINGS.fetch_add(1, Ordering::Relaxed);
    // A stopped step tick stops the steps and the executive's register check with them:
    // restored from here (`regcheck`).
    crate::regcheck::verify_in_nmi(&REGISTERS);
    defmt::warn!("watchdog: the main loop has not run for one watchdog period; reset at the next");
}

/// A flight firmware's way out of a HardFault (logged first): a reset
/// (`resilience::reset`, SYSRESETREQ; QEMU resets the machine), after which the unit
/// resumes from its snapshot (`resilience`).
pub fn fault_reset(_ok: bool) -> ! {
    defmt::error!("hard fault: resetting the unit");
    crate::resilience::reset()
}

/// Ends a QEMU run with the given outcome (semihosting); on hardware it would not
/// return either.
pub fn exit(success: bool) -> ! {
    let code =
        if success { cortex_m_semihosting::debug::EXIT_SUCCESS } else { cortex_m_semihosting::debug::EXIT_FAILURE };
    cortex_m_semihosting::debug::exit(code);
    loop {
        cortex_m::asm::wfi();
    }
}

struct HostOut(UnsafeCell<Option<cortex_m_semihosting::hio::HostStream>>);

// SAFETY: written only by the logger with its lock held (interrupts masked), or by the
// fault handler after it took the logger over.
unsafe impl Sync for HostOut {}

static HOST_OUT: HostOut = HostOut(UnsafeCell::new(None));

/// The log's output: defmt frames over semihosting stdout, as `defmt-semihosting`
/// writes them (the host runner decodes them).
pub fn semihosting_sink(bytes: &[u8]) {
    // SAFETY: see `HostOut`.
    let out = unsafe { &mut *HOST_OUT.0.get() };
    if out.is_none() {
        *out = cortex_m_semihosting::hio::hstdout().ok();
    }
    if let Some(h) = out {
        let _ = h.write_all(bytes);
    }
}

extern "C" {
    static _calib_start: u8;
    static _key_start: u8;
    static _lvdata_start: u8;
}

/// The stored calibration table region (4 KiB at `_calib_start`: two copies,
/// `calib::store`).
pub fn calib_area() -> &'static [u8] {
    // SAFETY: the CALIB region of the layout, 4 KiB, always mapped. Written only by
    // `CalibRegion` from the main loop, which holds no slice of it across a write.
    unsafe { core::slice::from_raw_parts(core::ptr::addr_of!(_calib_start), ssis::calib::store::REGION_LEN) }
}

/// The command key's record in the protected KEY region (`memory.x`, at `_key_start`;
/// `telecommand::auth`). The firmware never writes it.
pub fn key_area() -> &'static [u8] {
    // SAFETY: the KEY region of the spacecraft layout, at least this long, always
    // mapped, never written by the firmware.
    unsafe { core::slice::from_raw_parts(core::ptr::addr_of!(_key_start), ssis::telecommand::auth::KEY_RECORD_LEN) }
}

/// The calibration region as flash the command link writes (`calib::store::stage` and
/// `commit`). On QEMU's mps2 the region is RAM: an erase writes `FF`, a program writes
/// the bytes, each byte by a volatile store, so a reset between two leaves exactly the
/// bytes written before it (what a power loss does to NOR flash, byte for byte).
pub struct CalibRegion;

impl CalibRegion {
    fn write(offset: usize, bytes: impl Iterator<Item = u8>) {
        let base = core::ptr::addr_of!(_calib_start) as *mut u8;
        for (i, b) in bytes.enumerate() {
            // SAFETY: offset + i < REGION_LEN (checked by the callers): inside the CALIB
            // region, mapped and writable on this board; no slice of it is held now.
            unsafe { core::ptr::write_volatile(base.wrapping_add(offset + i), b) }
        }
    }
}

impl ssis::calib::store::CalibFlash for CalibRegion {
    fn region(&self) -> &[u8] {
        calib_area()
    }

    fn erase(&mut self, slot: ssis::calib::store::Slot) -> Result<(), ssis::calib::store::FlashError> {
        Self::write(slot.offset(), core::iter::repeat_n(0xFF, ssis::calib::store::SLOT_STRIDE));
        Ok(())
    }

    fn program(&mut self, offset: usize, bytes: &[u8]) -> Result<(), ssis::calib::store::FlashError> {
        use ssis::calib::store::FlashError;
        let end = offset.checked_add(bytes.len()).ok_or(FlashError::OutOfRange)?;
        let at = calib_area().get(offset..end).ok_or(FlashError::OutOfRange)?;
        if at.iter().any(|&b| b != 0xFF) {
            return Err(FlashError::NotErased);
        }
        Self::write(offset, bytes.iter().copied());
        Ok(())
    }
}

/// `len` bytes at `offset` in the launch-vehicle layout's LVDATA region
/// (`link/memory-lv.x`, 4 KiB: the accelerometer section and the pad initialisation
/// block); empty if they would not fit.
pub fn lvdata(offset: usize, len: usize) -> &'static [u8] {
    if offset.saturating_add(len) > 4096 {
        return &[];
    }
    // SAFETY: inside the 4 KiB LVDATA region (checked), always mapped, read-only here.
    unsafe { core::slice::from_raw_parts(core::ptr::addr_of!(_lvdata_start).wrapping_add(offset), len) }
}

/// The [`Board`] methods every mps2 board value shares: its table area, watchdog,
/// tick and way out, the same for the boot policy's [`Mps2`] and the flight's
/// [`Mps2Unit`].
macro_rules! mps2_board {
    () => {
        fn calib_area(&self) -> &[u8] {
            calib_area()
        }

        fn feed_watchdog(&mut self) {
            watchdog_feed();
        }

        fn ticks(&self) -> u32 {
            ticks()
        }

        fn stop(&mut self, ok: bool) -> ! {
            exit(ok)
        }
    };
}

/// The board as the boot policy and main loop see it.
pub struct Mps2;

impl Board for Mps2 {
    mps2_board!();
}

/// Count, sum and worst of a time in SysTick ticks (the executive's).
pub use ssis::bsp::exec::Times;

/// Bytes of the control line's receive ring (control frames and telecommands).
pub const CTL_RX_LEN: usize = 256;

/// Whether this build honours the control frames (LOCKSTEP, STEP, END, STALL, TICK_STOP): only a
/// test build (`test-hooks`, the binaries that invoke [`mps2_test_hooks!`](crate::mps2_test_hooks)).
pub const TEST_HOOKS: bool = cfg!(feature = "test-hooks");

#[cfg(feature = "test-hooks")]
extern "C" {
    /// Defined only by [`mps2_test_hooks!`](crate::mps2_test_hooks), which the test
    /// binaries invoke and the flight firmwares do not: a flight firmware built with
    /// `test-hooks` refers to it from [`Pacer::new`] and fails to link, naming the cause.
    #[link_name = "ERROR(ssis): test hooks in a flight firmware. ssis-fw and ssis-fw-lv never have the test-hooks feature; build ssis-fw-test or ssis-fw-lv-test (README: Flight build and test build)"]
    static TEST_HOOKS_BUILD: u8;
}

/// Marks a binary as a test build, allowed the test hooks: defines the symbol that
/// [`Pacer`] refers to in a `test-hooks` build. Invoked by the test builds of the
/// firmwares (`ssis-fw-test`, `ssis-fw-lv-test`), never by a flight firmware, so a flight
/// firmware built with `test-hooks` does not link (the check is the linker's, as the
/// no-panic proof is).
#[macro_export]
macro_rules! mps2_test_hooks {
    () => {
        #[allow(unsafe_code)]
        #[used]
        #[export_name = "ERROR(ssis): test hooks in a flight firmware. ssis-fw and ssis-fw-lv never have the test-hooks feature; build ssis-fw-test or ssis-fw-lv-test (README: Flight build and test build)"]
        static SSIS_TEST_HOOKS_BUILD: u8 = 1;
    };
}

/// Paces the executive's loop ([`ssis::bsp::exec`]): on the timer (one step per SysTick,
/// a missed tick an overrun), or, in a test build ([`TEST_HOOKS`]), in lockstep (test
/// equipment: one step per STEP control frame, once the bytes it names have arrived),
/// ending the run on END. Control frames arrive on the UART whose RX feeds `ctl`; a
/// flight build counts each one
/// ([`Counter::ControlIgnored`](ssis::telemetry::Counter::ControlIgnored)) and acts on
/// none, so it keeps stepping on its timer whatever arrives.
pub struct Pacer {
    map: &'static UartMap,
    ctl: RxRingReader<'static, CTL_RX_LEN>,
    decoder: StreamDecoder<ControlFrame, 32>,
    steps_due: Deque<ControlFrame, 8>,
    scratch: [u8; 128],
    lockstep: bool,
    end: bool,
    stall: bool,
    /// The tick of the last step on the timer.
    handled: u32,
    /// The tick seen at the last wait.
    seen: u32,
}

impl Pacer {
    /// Paces a loop whose UARTs are `map` and whose control frames land in `ctl`.
    pub fn new(map: &'static UartMap, ctl: &'static RxRing<CTL_RX_LEN>) -> Self {
        #[cfg(feature = "test-hooks")]
        // SAFETY: a one-byte static defined by `mps2_test_hooks!`; read once, only so
        // that a binary without it does not link.
        let _ = unsafe { core::ptr::read_volatile(core::ptr::addr_of!(TEST_HOOKS_BUILD)) };
        Pacer {
            map,
            ctl: ctl.reader(),
            decoder: StreamDecoder::new(),
            steps_due: Deque::new(),
            scratch: [0; 128],
            lockstep: false,
            end: false,
            stall: false,
            handled: ticks(),
            seen: ticks(),
        }
    }

    /// The executive's wait ([`StepBoard::wait`]): takes what the UARTs received and the
    /// control frames, and says what is due. In lockstep (test build), the next STEP
    /// frame once `arrived(frame)` says its bytes are in; on the timer, a new tick (with
    /// the ticks missed since the last step). A flight build counts every control frame
    /// in `core` and ignores it. Every byte of the control line also goes to `on_line`
    /// (the command link's telecommands share it), before the control frames it
    /// completes are acted on. With nothing due, sleeps until the next interrupt. In a
    /// test build a STALL control frame stops the loop here (the fault being injected:
    /// the watchdog, no longer fed, resets the unit); END, once every output ring is
    /// empty, ends the run.
    pub fn wait(
        &mut self,
        core: &mut FlightCore,
        arrived: impl Fn(&ControlFrame) -> bool,
        mut on_line: impl FnMut(&mut FlightCore, &[u8]),
    ) -> Wait {
        poll_rx(self.map);
        let now = ticks();
        let tick = now != self.seen;
        self.seen = now;
        let Pacer { ctl, decoder, steps_due, scratch, lockstep, end, stall, .. } = self;
        let _ = drain(ctl, CTL_RX_LEN, scratch, |bytes| {
            on_line(core, bytes);
            decoder.push_slice(bytes, |r| {
                let Ok(c) = r else { return };
                if !TEST_HOOKS {
                    core.note_control_ignored();
                    return;
                }
                match c.command {
                    command::LOCKSTEP => *lockstep = true,
                    command::STEP => {
                        let _ = steps_due.push_back(c);
                    }
                    command::END => *end = true,
                    command::STALL => *stall = true,
                    command::TICK_STOP => stop_tick(),
                    _ => {}
                }
            });
        });
        // A flight build never sets the three (`TEST_HOOKS` false above): testing
        // `TEST_HOOKS` first leaves their code out of its image.
        if TEST_HOOKS && self.stall {
            stall_here();
        }
        if TEST_HOOKS && self.lockstep {
            if let Some(c) = self.steps_due.front() {
                if arrived(c) {
                    let _ = self.steps_due.pop_front();
                    return Wait::Lockstep;
                }
            }
        }
        if TEST_HOOKS && self.end {
            pump_tx(self.map);
            return if tx_idle(self.map) { Wait::End } else { Wait::Idle { lockstep: true, tick } };
        }
        if !(TEST_HOOKS && self.lockstep) && now != self.handled {
            let missed = now.wrapping_sub(self.handled).saturating_sub(1);
            self.handled = now;
            return Wait::Tick { missed };
        }
        cortex_m::asm::wfi();
        Wait::Idle { lockstep: TEST_HOOKS && self.lockstep, tick }
    }

    /// Whether the runner switched to lockstep.
    pub fn lockstep(&self) -> bool {
        self.lockstep
    }
}

/// The TICK_STOP test hook: the SysTick's enable bit cleared by the guest's own store,
/// as an upset of its control word would leave it (the register check and the watchdog
/// must bring the tick back).
#[inline(never)]
#[cold]
fn stop_tick() {
    defmt::error!("test hook: SysTick stopped on command");
    // SAFETY: a read-modify-write of the SysTick control word by the only code that runs
    // here (the main loop); the test of a stopped tick.
    unsafe { (*SYST::PTR).csr.modify(|c| c & !1) };
}

/// The STALL test hook: the loop stops for good, feeding nothing.
#[inline(never)]
#[cold]
fn stall_here() -> ! {
    defmt::error!("test hook: main loop stalled on command");
    loop {
        cortex_m::asm::nop();
    }
}

/// What a firmware on this board does with its control line besides the control frames
/// (the spacecraft's command link; nothing on the launch vehicle).
pub trait ControlLine {
    /// Bytes received on the control line, before the control frames they complete.
    fn receive(&mut self, _core: &mut FlightCore, _bytes: &[u8]) {}

    /// After a step: what the line has to send (a command report).
    fn after_step(&mut self) {}

    /// Checks the command key against its record; true when it was restored.
    fn check_key(&mut self) -> bool {
        false
    }

    /// Its end-of-run figures (test builds, at END).
    fn report(&self) {}
}

impl ControlLine for () {}

/// The board in the executive's loop ([`ssis::bsp::exec::StepBoard`]): the pacing, the
/// UARTs of `map`, the watchdog, the clock (SysTick), the layout's snapshot region and
/// code image, and the firmware's control line `L`. The QEMU board has no memory-error
/// source (its RAM has no ECC).
pub struct Mps2Unit<L> {
    pacer: Pacer,
    map: &'static UartMap,
    /// The firmware's control line.
    pub line: L,
    arrived: fn(&ControlFrame) -> bool,
    rx_overflows: fn() -> u32,
    snap: Option<&'static mut Snapshots>,
}

impl<L: ControlLine> Mps2Unit<L> {
    /// The board with its UARTs `map` (brought up, with the step tick of `step_us`), its
    /// control frames in `ctl`, `arrived` (whether a STEP frame's bytes are in), the
    /// bytes its receive rings dropped (`rx_overflows`, for the end report), the line
    /// `line` and the watchdog started at `watchdog_steps` steps a stage (warning, then
    /// reset). Takes the snapshot region (call once).
    #[allow(clippy::too_many_arguments)]
    pub fn start(
        syst: SYST,
        step_us: u32,
        watchdog_steps: u32,
        map: &'static UartMap,
        ctl: &'static RxRing<CTL_RX_LEN>,
        arrived: fn(&ControlFrame) -> bool,
        rx_overflows: fn() -> u32,
        line: L,
    ) -> Self {
        let snap = crate::resilience::snapshot();
        init(syst, step_us, map);
        watchdog_start(watchdog_steps.saturating_mul(step_us));
        crate::regcheck::build(&REGISTERS);
        Mps2Unit { pacer: Pacer::new(map, ctl), map, line, arrived, rx_overflows, snap }
    }

    /// Whether the runner switched to lockstep.
    pub fn lockstep(&self) -> bool {
        self.pacer.lockstep()
    }
}

impl<L> Board for Mps2Unit<L> {
    mps2_board!();
}

impl<L: ControlLine> StepBoard for Mps2Unit<L> {
    fn wait(&mut self, core: &mut FlightCore) -> Wait {
        let Mps2Unit { pacer, line, arrived, .. } = self;
        pacer.wait(core, *arrived, |core, bytes| line.receive(core, bytes))
    }

    fn clock(&self) -> u32 {
        clock()
    }

    fn period(&self) -> u32 {
        ticks_per_step()
    }

    fn send(&mut self) {
        pump_tx(self.map);
    }

    fn after_step(&mut self, _core: &mut FlightCore, _busy: u32) {
        self.line.after_step();
    }

    fn snapshots(&mut self) -> Option<&mut Snapshots> {
        self.snap.as_deref_mut()
    }

    fn code_image(&self) -> &'static [u8] {
        crate::resilience::code_image()
    }

    fn check_key(&mut self) -> bool {
        self.line.check_key()
    }

    fn watchdog_warnings(&self) -> u32 {
        watchdog_warnings()
    }

    fn check_pass(&mut self) -> ssis::bsp::exec::RegisterCheck {
        crate::regcheck::verify_pass(&REGISTERS, PASS_ENTRIES)
    }

    fn check_registers(&mut self) -> ssis::bsp::exec::RegisterCheck {
        crate::regcheck::verify(&REGISTERS)
    }

    fn report(&mut self, core: &FlightCore) {
        self.line.report();
        report(core, (self.rx_overflows)());
    }

    fn reset(&mut self) -> ! {
        crate::resilience::reset()
    }
}

/// The entries of [`REGISTERS`] checked at every pass (`StepBoard::check_pass`): the
/// SysTick's two and the control words of the links' UARTs 0–2.
const PASS_ENTRIES: usize = 5;

/// The configuration registers the executive checks (`crate::regcheck`), as [`init`],
/// [`start`] and [`watchdog_start`] leave them: SysTick, the vector table, the
/// interrupt enables of UARTs 0–2 (all 32 bits: one enabled that should not be does
/// not restore, and resets) and the priorities of the UARTs' interrupts, the five
/// UARTs' control and baud divider (the unused ones off), then the MPU's two regions
/// and control, then the watchdog (load, control; unlocked for the check and locked
/// after). The same list for every firmware on the board.
const REGISTERS: [crate::regcheck::Entry; 30] = {
    let [b0, b1, b2, b3, b4] = UART_BASE;
    use crate::regcheck::{mpu_region, select, CORE, MPU_CTRL, NVIC_IPR, NVIC_ISER, TICK};
    let (r0, r1) = (mpu_region(0), mpu_region(1));
    [
        TICK[0],
        TICK[1],
        ((b0 + CTRL) as u32, 0x7F),
        ((b1 + CTRL) as u32, 0x7F),
        ((b2 + CTRL) as u32, 0x7F),
        CORE[0],
        CORE[1],
        (NVIC_ISER, u32::MAX),
        (NVIC_IPR, u32::MAX),
        (NVIC_IPR + 4, u32::MAX),
        (NVIC_IPR + 16, u32::MAX),
        (NVIC_IPR + 20, u32::MAX),
        ((b0 + BAUDDIV) as u32, 0x000F_FFFF),
        ((b1 + BAUDDIV) as u32, 0x000F_FFFF),
        ((b2 + BAUDDIV) as u32, 0x000F_FFFF),
        ((b3 + CTRL) as u32, 0x7F),
        ((b3 + BAUDDIV) as u32, 0x000F_FFFF),
        ((b4 + CTRL) as u32, 0x7F),
        ((b4 + BAUDDIV) as u32, 0x000F_FFFF),
        r0[0],
        r0[1],
        r0[2],
        r1[0],
        r1[1],
        r1[2],
        (MPU_CTRL, 0b111),
        select((WDOG_BASE + WDOG_LOCK) as u32, WDOG_UNLOCK_KEY),
        ((WDOG_BASE + WDOG_LOAD) as u32, u32::MAX),
        ((WDOG_BASE + WDOG_CONTROL) as u32, WDOG_INTEN | WDOG_RESEN),
        select((WDOG_BASE + WDOG_LOCK) as u32, 0),
    ]
};

/// The end-of-run figures every firmware logs after its own: stack, statics, watchdog,
/// dropped log messages and the flight core's counters (`rx_overflows`: bytes dropped
/// by full receive rings). The one place the main loops read `FlightCore::counters`.
pub fn report(core: &FlightCore, rx_overflows: u32) {
    defmt::info!(
        "stack_high_water_bytes {} static_ram_bytes {}",
        cortex_m7::stack_high_water(),
        cortex_m7::static_ram()
    );
    defmt::info!("watchdog_warnings {}", watchdog_warnings());
    defmt::info!("log_dropped {}", cortex_m7::LOG.dropped());
    let c = core.counters();
    defmt::info!(
        "counters fog_rejected {} fog_missing {} fog_stale {} st_accepted {} st_rejected {} overruns {} out_dropped {} rx_overflows {}",
        c.fog_frames_rejected,
        c.fog_samples_missing,
        c.fog_samples_stale,
        c.st_frames_accepted,
        c.st_frames_rejected,
        c.overruns,
        c.output_dropped,
        rx_overflows
    );
}

/// Generates what a flight firmware on this board defines once in its binary: the
/// exception handlers (SysTick, the UARTs' RX interrupts dispatched by `$uarts`, a
/// `static` [`UartMap`], and the watchdog's NMI) and the Cortex-M7 runtime with the
/// link-time no-panic proof ([`cortex_m7_runtime!`](crate::cortex_m7_runtime) with
/// `panic: never`).
#[macro_export]
macro_rules! mps2_firmware {
    ($uarts:path) => {
        $crate::cortex_m7_runtime!(
            sink: $crate::mps2::semihosting_sink,
            stop: $crate::mps2::exit,
            fault: $crate::mps2::fault_reset,
            panic: never
        );

        #[cortex_m_rt::exception]
        fn SysTick() {
            $crate::mps2::on_systick();
        }

        /// External interrupts arrive here (no device crate): the UARTs' RX.
        #[cortex_m_rt::exception]
        unsafe fn DefaultHandler(irqn: i16) {
            $crate::mps2::on_irq(&$uarts, irqn);
        }

        /// First watchdog timeout.
        #[cortex_m_rt::exception]
        unsafe fn NonMaskableInt() {
            $crate::mps2::on_watchdog_warning();
        }
    };
}
