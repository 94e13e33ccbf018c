//! Board: QEMU `mps2-an500` (Cortex-M7, FPv5-D16). Everything that touches hardware is
//! here; the flight core knows only the link traits.
//!
//! - CMSDK APB UARTs (QEMU `hw/char/cmsdk-apb-uart.c`), RX interrupt-driven into
//!   [`RxRing`]s; the output is written from a [`TxRing`] by [`pump_tx`].
//!   | UART | base | RX/TX IRQ | use |
//!   |---|---|---|---|
//!   | 0 | 0x4000_4000 | 0 / 1 | output frames (TX), control frames (RX) |
//!   | 1 | 0x4000_5000 | 2 / 3 | FOG bus: all four FOGs, told apart by `fog_id` |
//!   | 2 | 0x4000_6000 | 4 / 5 | star tracker (RX) |
//! - SysTick at 25 MHz: the step tick (5 ms = 125,000 ticks) and the step-time measure.
//! - CMSDK APB watchdog (QEMU `hw/watchdog/cmsdk-apb-watchdog.c`, 0x4000_8000, clocked
//!   at 25 MHz, interrupt wired to NMI): the main loop feeds it on every pass; after one
//!   timeout without a feed the NMI logs a warning, after a second one the watchdog
//!   resets the unit (QEMU: its `-action watchdog=` choice).
//! - Semihosting: defmt log output and the exit code of a QEMU run.
//! - A painted stack for the high-water mark.
#![allow(unsafe_code)]

use core::sync::atomic::{AtomicBool, AtomicU32, Ordering};

use cortex_m::peripheral::syst::SystClkSource;
use cortex_m::peripheral::{NVIC, SYST};
use cortex_m_rt::exception;
use ssis::link::{RxRing, TxRing};

/// SysTick clock of the board, Hz (QEMU mps2: SYSCLK 25 MHz).
pub const SYSCLK_HZ: u32 = 25_000_000;

/// FOG bus receive buffer (four FOG frames per step, several steps of margin).
pub static FOG_RX: RxRing<512> = RxRing::new();
/// Star-tracker receive buffer.
pub static ST_RX: RxRing<256> = RxRing::new();
/// Control receive buffer (UART0 RX).
pub static CTL_RX: RxRing<64> = RxRing::new();
/// Output transmit buffer (two output frames).
pub static OUT_TX: TxRing<256> = TxRing::new();

/// SysTick interrupts since start.
static TICKS: AtomicU32 = AtomicU32::new(0);

const UART_BASE: [usize; 3] = [0x4000_4000, 0x4000_5000, 0x4000_6000];
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

/// Brings up the UARTs, their interrupts and the step tick of `step_us`.
pub fn init(mut syst: SYST, step_us: u32) {
    for uart in 0..3 {
        write(uart, BAUDDIV, 16);
        write(uart, CTRL, CTRL_TX_EN | CTRL_RX_EN | CTRL_RX_INT_EN);
    }
    syst.set_clock_source(SystClkSource::Core);
    syst.set_reload(SYSCLK_HZ / 1_000_000 * step_us - 1);
    syst.clear_current();
    syst.enable_interrupt();
    syst.enable_counter();
    for irq in [0u16, 2, 4] {
        // SAFETY: the handlers below only touch the critical-section rings.
        unsafe { NVIC::unmask(Irq(irq)) };
    }
}

/// Ticks of the step period (the SysTick reload + 1).
pub fn ticks_per_step() -> u32 {
    SYST::get_reload() + 1
}

/// SysTick current value (counts down from the reload).
pub fn systick_now() -> u32 {
    SYST::get_current()
}

/// SysTick interrupts so far.
pub fn ticks() -> u32 {
    TICKS.load(Ordering::Acquire)
}

/// Sends what fits of the output buffer; never waits.
pub fn pump_tx() {
    // Bounded by the ring's size.
    for _ in 0..256 {
        if read(0, STATE) & STATE_TX_FULL != 0 {
            break;
        }
        match OUT_TX.pop() {
            Some(b) => write(0, DATA, u32::from(b)),
            None => break,
        }
    }
}

/// Moves received bytes of `uart` into `ring` and clears the interrupt.
fn rx_isr<const N: usize>(uart: usize, ring: &RxRing<N>) {
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

/// Main-loop backstop: drains any receive register still full (costs two reads per
/// UART when idle).
pub fn poll_rx() {
    cortex_m::interrupt::free(|_| {
        rx_isr(0, &CTL_RX);
        rx_isr(1, &FOG_RX);
        rx_isr(2, &ST_RX);
    });
}

#[derive(Clone, Copy)]
struct Irq(u16);

// SAFETY: the numbers are this board's external interrupt lines.
unsafe impl cortex_m::interrupt::InterruptNumber for Irq {
    fn number(self) -> u16 {
        self.0
    }
}

#[exception]
fn SysTick() {
    TICKS.fetch_add(1, Ordering::Release);
}

/// External interrupts arrive here (no device crate): dispatch on the IRQ number.
#[exception]
unsafe fn DefaultHandler(irqn: i16) {
    match irqn {
        0 => rx_isr(0, &CTL_RX),
        2 => rx_isr(1, &FOG_RX),
        4 => rx_isr(2, &ST_RX),
        _ => {}
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

/// First watchdog timeout: the main loop has not fed it for one period. Logged and
/// counted; it is not cleared here, so if the loop does not recover the watchdog resets
/// the unit at the second timeout.
#[exception]
unsafe fn NonMaskableInt() {
    WATCHDOG_WARNINGS.fetch_add(1, Ordering::Relaxed);
    defmt::warn!("watchdog: the main loop has not run for one watchdog period; reset at the next");
}

// HardFault (every fault lands here: BusFault, MemManage and UsageFault are not enabled,
// so they escalate). A stack overflow faults with the stack pointer below the stack's
// bottom, where the MPU guard (`guard_stack`) lets nothing be pushed, so the handler must not use that stack: this entry
// (no prologue) moves MSP back to the top of the stack region, whose contents are no longer
// needed (the handler never returns), and passes the old MSP, PSP and EXC_RETURN on.
core::arch::global_asm!(
    ".section .HardFault.user, \"ax\"",
    ".global HardFault",
    ".type HardFault,%function",
    ".thumb_func",
    "HardFault:",
    "mrs r0, msp",
    "mrs r1, psp",
    "mov r2, lr",
    "ldr r3, =_stack_start",
    "msr msp, r3",
    "b {report}",
    ".ltorg",
    ".size HardFault, . - HardFault",
    report = sym fault_report,
);

/// Logs the fault and ends the run with failure. `msp`/`psp` are the stack pointers when
/// the fault was taken (after the processor's attempt to push the exception frame).
extern "C" fn fault_report(msp: u32, psp: u32, exc_return: u32) -> ! {
    logger_take_over();
    let sp = if exc_return & 0b100 != 0 { psp } else { msp };
    let bottom = core::ptr::addr_of!(_stack_end) as u32;
    let top = core::ptr::addr_of!(_stack_start) as u32;
    // SAFETY: the System Control Block's fault status and address registers, always mapped.
    let (cfsr, hfsr, mmfar, bfar) = unsafe {
        (
            core::ptr::read_volatile(0xE000_ED28 as *const u32),
            core::ptr::read_volatile(0xE000_ED2C as *const u32),
            core::ptr::read_volatile(0xE000_ED34 as *const u32),
            core::ptr::read_volatile(0xE000_ED38 as *const u32),
        )
    };
    // Stacking error (CFSR.STKERR or MSTKERR: the MPU guard below the stack refused the
    // exception frame), or a stack pointer within one exception frame (at most 26 words
    // with the FP context) of the bottom or below it.
    let stacking_error = cfsr & (1 << 12 | 1 << 4) != 0;
    if stacking_error || sp < bottom.saturating_add(112) {
        defmt::error!(
            "stack overflow: hard fault with sp {=u32:#010x} below the stack {=u32:#010x}..{=u32:#010x} (cfsr {=u32:#010x} hfsr {=u32:#010x} mmfar {=u32:#010x})",
            sp,
            bottom,
            top,
            cfsr,
            hfsr,
            mmfar
        );
    } else {
        // The exception frame was pushed: its return address is the faulting instruction.
        // SAFETY: sp lies inside the stack region with a whole frame above it (checked).
        let pc =
            if sp <= top.saturating_sub(32) { unsafe { core::ptr::read_volatile((sp + 24) as *const u32) } } else { 0 };
        defmt::error!(
            "hard fault: pc {=u32:#010x} sp {=u32:#010x} (cfsr {=u32:#010x} hfsr {=u32:#010x} mmfar {=u32:#010x} bfar {=u32:#010x})",
            pc,
            sp,
            cfsr,
            hfsr,
            mmfar,
            bfar
        );
    }
    exit(false)
}

/// The release firmware links only if no panic path remains (README "No panics"): the
/// handler calls a symbol that exists nowhere, so the link fails unless the optimiser has
/// proved every panic unreachable and the handler was discarded. `scripts/panic-paths`
/// lists the callers when it fails.
#[cfg(not(any(debug_assertions, feature = "allow-panic")))]
#[panic_handler]
fn panic(_info: &core::panic::PanicInfo) -> ! {
    extern "Rust" {
        #[link_name = "\n\nERROR(ssis): a panic path remains in the release firmware. List the callers with `bash scripts/panic-paths` (README: No panics, stack overflow).\n"]
        fn a_panic_path_remains_in_the_release_firmware() -> !;
    }
    // SAFETY: never called: the symbol is undefined, so a firmware that could reach this
    // handler does not link.
    unsafe { a_panic_path_remains_in_the_release_firmware() }
}

/// Debug builds (overflow checks, no optimisation to remove the bounds checks) and the
/// `allow-panic` diagnosis build: log and end the run with failure.
#[cfg(any(debug_assertions, feature = "allow-panic"))]
#[panic_handler]
fn panic(_info: &core::panic::PanicInfo) -> ! {
    defmt::error!("panic");
    exit(false)
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

const MPU_RNR: usize = 0xE000_ED98;
const MPU_RBAR: usize = 0xE000_ED9C;
const MPU_RASR: usize = 0xE000_EDA0;
const MPU_CTRL: usize = 0xE000_ED94;

/// Stack guard (memory.x puts the stack at the bottom of RAM, 0x2000_0000): MPU region 0
/// makes the 256 MiB below RAM, 0x1000_0000..0x2000_0000, no-access and never-execute, so
/// the first push past the stack's bottom is a fault (reported by `HardFault`), not a
/// write. Needed because QEMU's mps2-an500 does not fault there by itself (measured: a
/// runaway recursion went 8 MiB below 0x2000_0000 unchecked). Everything else keeps the
/// default memory map (PRIVDEFENA); the fault handlers run with the MPU off (HFNMIENA 0).
pub fn guard_stack() {
    let w = |a: usize, v: u32| {
        // SAFETY: the Cortex-M7's MPU registers, always mapped; region 0 covers no memory
        // this firmware uses.
        unsafe { core::ptr::write_volatile(a as *mut u32, v) }
    };
    w(MPU_RNR, 0);
    w(MPU_RBAR, 0x1000_0000);
    // XN, AP = no access, SIZE = 2^(27+1) bytes, enabled.
    w(MPU_RASR, 1 << 28 | 27 << 1 | 1);
    // ENABLE, PRIVDEFENA.
    w(MPU_CTRL, 1 << 2 | 1);
    cortex_m::asm::dsb();
    cortex_m::asm::isb();
}

const PAINT: u32 = 0x5AFE_C0DE;

extern "C" {
    static __sheap: u32;
    static _ram_start: u32;
    static _stack_start: u32;
    static _stack_end: u32;
    static _calib_start: u8;
}

/// Paints the stack region below the current stack pointer (less a margin), from the
/// stack's bottom (`_stack_end`, memory.x), so [`stack_high_water`] can tell how deep the
/// stack went.
pub fn paint_stack() {
    let start = core::ptr::addr_of!(_stack_end) as usize;
    let sp = cortex_m::register::msp::read() as usize;
    let mut p = start;
    // Bounded: from the bottom of the stack to 256 bytes below the stack pointer.
    while p + 4 <= sp.saturating_sub(256) {
        // SAFETY: [bottom, sp − 256) is unused stack.
        unsafe { core::ptr::write_volatile(p as *mut u32, PAINT) };
        p += 4;
    }
}

/// Deepest stack use so far, bytes.
pub fn stack_high_water() -> u32 {
    let start = core::ptr::addr_of!(_stack_end) as usize;
    let top = core::ptr::addr_of!(_stack_start) as usize;
    let mut p = start;
    while p < top {
        // SAFETY: inside the stack region, word aligned.
        if unsafe { core::ptr::read_volatile(p as *const u32) } != PAINT {
            break;
        }
        p += 4;
    }
    (top - p) as u32
}

/// RAM taken by statics (.data + .bss + .uninit), bytes.
pub fn static_ram() -> u32 {
    (core::ptr::addr_of!(__sheap) as usize - core::ptr::addr_of!(_ram_start) as usize) as u32
}

/// The stored calibration table region (4 KiB at `_calib_start`: two copies, `ssis::calib::store`).
pub fn calib_bytes() -> &'static [u8] {
    // SAFETY: the CALIB region of memory.x, 4 KiB, always mapped, read-only here.
    unsafe { core::slice::from_raw_parts(core::ptr::addr_of!(_calib_start), ssis::calib::store::REGION_LEN) }
}

/// The defmt logger: frames over semihosting stdout, as `defmt-semihosting` writes them,
/// without its panics. An NMI or fault that logs while a log is open (both unmaskable)
/// cannot share the frame: its message is dropped and counted, never interleaved.
#[defmt::global_logger]
struct Logger;

struct LogState {
    restore: critical_section::RestoreState,
    encoder: defmt::Encoder,
    out: Option<cortex_m_semihosting::hio::HostStream>,
}

struct LogCell(core::cell::UnsafeCell<LogState>);

// SAFETY: touched only by the logger functions below, with `LOG_TAKEN` as the lock inside
// a critical section; a nested acquire never touches the state.
unsafe impl Sync for LogCell {}

static LOG: LogCell = LogCell(core::cell::UnsafeCell::new(LogState {
    restore: critical_section::RestoreState::invalid(),
    encoder: defmt::Encoder::new(),
    out: None,
}));
/// A frame is open.
static LOG_TAKEN: AtomicBool = AtomicBool::new(false);
/// Nested frames open (acquired while one was open), being dropped.
static LOG_NESTED: AtomicU32 = AtomicU32::new(0);
/// Log messages dropped because they arrived while another was open.
static LOG_DROPPED: AtomicU32 = AtomicU32::new(0);

fn log_out(out: &mut Option<cortex_m_semihosting::hio::HostStream>, bytes: &[u8]) {
    if out.is_none() {
        *out = cortex_m_semihosting::hio::hstdout().ok();
    }
    if let Some(h) = out {
        let _ = h.write_all(bytes);
    }
}

// SAFETY: acquire/release pair up as defmt requires; see `LogCell`.
unsafe impl defmt::Logger for Logger {
    fn acquire() {
        // SAFETY: released in `release` (or at once, for a nested frame).
        let restore = unsafe { critical_section::acquire() };
        if LOG_TAKEN.load(Ordering::Relaxed) {
            LOG_NESTED.fetch_add(1, Ordering::Relaxed);
            // SAFETY: the outer frame keeps its own critical section open.
            unsafe { critical_section::release(restore) };
            return;
        }
        LOG_TAKEN.store(true, Ordering::Relaxed);
        // SAFETY: the lock is ours (taken above, interrupts masked).
        let s = unsafe { &mut *LOG.0.get() };
        s.restore = restore;
        let LogState { encoder, out, .. } = s;
        encoder.start_frame(|b| log_out(out, b));
    }

    unsafe fn flush() {}

    unsafe fn release() {
        if LOG_NESTED.load(Ordering::Relaxed) > 0 {
            LOG_NESTED.fetch_sub(1, Ordering::Relaxed);
            LOG_DROPPED.fetch_add(1, Ordering::Relaxed);
            return;
        }
        if !LOG_TAKEN.load(Ordering::Relaxed) {
            return;
        }
        // SAFETY: the lock is ours.
        let s = unsafe { &mut *LOG.0.get() };
        let LogState { encoder, out, restore } = s;
        encoder.end_frame(|b| log_out(out, b));
        let restore = *restore;
        LOG_TAKEN.store(false, Ordering::Relaxed);
        // SAFETY: pairs with the acquire of this frame.
        unsafe { critical_section::release(restore) };
    }

    unsafe fn write(bytes: &[u8]) {
        if LOG_NESTED.load(Ordering::Relaxed) > 0 || !LOG_TAKEN.load(Ordering::Relaxed) {
            return;
        }
        // SAFETY: the lock is ours.
        let s = unsafe { &mut *LOG.0.get() };
        let LogState { encoder, out, .. } = s;
        encoder.write(bytes, |b| log_out(out, b));
    }
}

/// For the fault handler, which never returns: abandons a frame the fault interrupted (its
/// bytes end with a frame delimiter) so the fault's own message is written whole.
fn logger_take_over() {
    cortex_m::interrupt::disable();
    if LOG_TAKEN.load(Ordering::Relaxed) {
        // SAFETY: the interrupted frame's owner never runs again; interrupts are masked.
        let s = unsafe { &mut *LOG.0.get() };
        log_out(&mut s.out, &[0]);
        s.encoder = defmt::Encoder::new();
        LOG_NESTED.store(0, Ordering::Relaxed);
        LOG_TAKEN.store(false, Ordering::Relaxed);
    }
}

/// Log messages dropped because an NMI or fault logged while another was open.
pub fn log_dropped() -> u32 {
    LOG_DROPPED.load(Ordering::Relaxed)
}
