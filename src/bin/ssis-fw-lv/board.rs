//! Board of the launch-vehicle firmware: QEMU `mps2-an500` (Cortex-M7, FPv5-D16), all
//! five CMSDK APB UARTs (QEMU `hw/arm/mps2.c`, `hw/char/cmsdk-apb-uart.c`), RX
//! interrupt-driven into [`RxRing`]s, TX written from [`TxRing`]s by [`pump_tx`]:
//!
//! | UART | base | RX / TX IRQ | RX | TX |
//! |---|---|---|---|---|
//! | 0 | 0x4000_4000 | 0 / 1 | control frames (test equipment) | flight output frames (kind 0x30) |
//! | 1 | 0x4000_5000 | 2 / 3 | FOG bus: FOG1..FOG3, told apart by `fog_id` | — |
//! | 2 | 0x4000_6000 | 4 / 5 | — | navigation output frames (kind 0x31) |
//! | 3 | 0x4000_7000 | 18 / 19 | accelerometer bus: X, Y, Z, told apart by `accel_id` | — |
//! | 4 | 0x4000_9000 | 20 / 21 | GNSS receiver (kind 0x21) | — |
//!
//! SysTick at 25 MHz: the step tick (1.25 ms = 31,250 ticks) and the step-time measure.
//! The watchdog, the painted stack and the semihosting exit are as on the spacecraft
//! board (`src/bin/ssis-fw/board.rs`); the memory map is `link/lv/memory.x`.
#![allow(unsafe_code)]

use core::sync::atomic::{AtomicU32, Ordering};

use cortex_m::peripheral::syst::SystClkSource;
use cortex_m::peripheral::{NVIC, SYST};
use cortex_m_rt::exception;
use ssis::calib::accel::TABLE_LEN as ACCEL_TABLE_LEN;
use ssis::link::{RxRing, TxRing};
use ssis::nav::init::BLOCK_LEN as INIT_BLOCK_LEN;

/// SysTick clock of the board, Hz (QEMU mps2: SYSCLK 25 MHz).
pub const SYSCLK_HZ: u32 = 25_000_000;

/// Control receive buffer (UART0 RX).
pub static CTL_RX: RxRing<64> = RxRing::new();
/// FOG bus receive buffer (three 16-byte frames per 1.25 ms step, ten steps of margin).
pub static FOG_RX: RxRing<512> = RxRing::new();
/// Accelerometer bus receive buffer (three 16-byte frames per step).
pub static ACCEL_RX: RxRing<512> = RxRing::new();
/// GNSS receive buffer (45-byte frames, 1 Hz).
pub static GNSS_RX: RxRing<256> = RxRing::new();
/// The star-tracker link of the flight core: the launch vehicle has none, so nothing
/// ever fills it.
pub static NO_STAR_RX: RxRing<4> = RxRing::new();
/// Flight output transmit buffer (UART0, 79-byte frames).
pub static OUT_TX: TxRing<256> = TxRing::new();
/// Navigation output transmit buffer (UART2, 64-byte frames).
pub static NAV_TX: TxRing<256> = TxRing::new();

/// SysTick interrupts since start.
static TICKS: AtomicU32 = AtomicU32::new(0);

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

/// Brings up the UARTs, their receive interrupts (UART2 only transmits) and the step
/// tick of `step_us`.
pub fn init(mut syst: SYST, step_us: u32) {
    for uart in 0..UART_BASE.len() {
        write(uart, BAUDDIV, 16);
        let rx = if uart == 2 { 0 } else { CTRL_RX_EN | CTRL_RX_INT_EN };
        write(uart, CTRL, CTRL_TX_EN | rx);
    }
    syst.set_clock_source(SystClkSource::Core);
    syst.set_reload(SYSCLK_HZ / 1_000_000 * step_us - 1);
    syst.clear_current();
    syst.enable_interrupt();
    syst.enable_counter();
    for (uart, irq) in UART_RX_IRQ.into_iter().enumerate() {
        if uart != 2 {
            // SAFETY: the handlers below only touch the critical-section rings.
            unsafe { NVIC::unmask(Irq(irq)) };
        }
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

/// Sends what fits of `ring` on `uart`; never waits.
fn pump<const N: usize>(uart: usize, ring: &TxRing<N>) {
    // Bounded by the ring's size.
    for _ in 0..N {
        if read(uart, STATE) & STATE_TX_FULL != 0 {
            break;
        }
        match ring.pop() {
            Some(b) => write(uart, DATA, u32::from(b)),
            None => break,
        }
    }
}

/// Sends what fits of both output buffers; never waits.
pub fn pump_tx() {
    pump(0, &OUT_TX);
    pump(2, &NAV_TX);
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

/// Main-loop backstop: drains any receive register still full.
pub fn poll_rx() {
    cortex_m::interrupt::free(|_| {
        rx_isr(0, &CTL_RX);
        rx_isr(1, &FOG_RX);
        rx_isr(3, &ACCEL_RX);
        rx_isr(4, &GNSS_RX);
    });
}

/// Receive overflows of every ring (bytes dropped because a ring was full).
pub fn rx_overflows() -> u32 {
    FOG_RX.overflows().saturating_add(ACCEL_RX.overflows()).saturating_add(GNSS_RX.overflows())
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
        18 => rx_isr(3, &ACCEL_RX),
        20 => rx_isr(4, &GNSS_RX),
        _ => {}
    }
}

const WDOG_BASE: usize = 0x4000_8000;
const WDOG_LOAD: usize = 0x000;
const WDOG_CONTROL: usize = 0x008;
const WDOG_INTCLR: usize = 0x00C;
const WDOG_LOCK: usize = 0xC00;
const WDOG_UNLOCK_KEY: u32 = 0x1ACC_E551;
const WDOG_INTEN_RESEN: u32 = 0b11;

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
    wdog_write(WDOG_CONTROL, WDOG_INTEN_RESEN);
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

/// First watchdog timeout: logged and counted; a second one resets the unit.
#[exception]
unsafe fn NonMaskableInt() {
    WATCHDOG_WARNINGS.fetch_add(1, Ordering::Relaxed);
    defmt::warn!("watchdog: the main loop has not run for one watchdog period; reset at the next");
}

#[exception]
unsafe fn HardFault(_frame: &cortex_m_rt::ExceptionFrame) -> ! {
    defmt::error!("hard fault");
    exit(false)
}

/// Ends a QEMU run with the given outcome (semihosting).
pub fn exit(success: bool) -> ! {
    let code =
        if success { cortex_m_semihosting::debug::EXIT_SUCCESS } else { cortex_m_semihosting::debug::EXIT_FAILURE };
    cortex_m_semihosting::debug::exit(code);
    loop {
        cortex_m::asm::wfi();
    }
}

const PAINT: u32 = 0x5AFE_C0DE;

extern "C" {
    static mut __sheap: u32;
    static _stack_start: u32;
    static _calib_start: u8;
    static _lvdata_start: u8;
}

/// Paints the free RAM between the statics and the stack pointer (less 256 bytes), so
/// [`stack_high_water`] can tell how deep the stack went.
pub fn paint_stack() {
    let start = core::ptr::addr_of_mut!(__sheap) as usize;
    let sp = cortex_m::register::msp::read() as usize;
    let mut p = start;
    // Bounded: from the end of the statics to 256 bytes below the stack pointer.
    while p + 4 <= sp.saturating_sub(256) {
        // SAFETY: [start, sp − 256) is unused RAM between the statics and the stack.
        unsafe { core::ptr::write_volatile(p as *mut u32, PAINT) };
        p += 4;
    }
}

/// Deepest stack use so far, bytes.
pub fn stack_high_water() -> u32 {
    let start = core::ptr::addr_of_mut!(__sheap) as usize;
    let top = core::ptr::addr_of!(_stack_start) as usize;
    let mut p = start;
    while p < top {
        // SAFETY: inside RAM, word aligned.
        if unsafe { core::ptr::read_volatile(p as *const u32) } != PAINT {
            break;
        }
        p += 4;
    }
    (top - p) as u32
}

/// RAM taken by statics (.data + .bss), bytes.
pub fn static_ram() -> u32 {
    (core::ptr::addr_of_mut!(__sheap) as usize - 0x2000_0000) as u32
}

/// The stored FOG table region (two copies, `ssis::calib::store`).
pub fn calib_bytes() -> &'static [u8] {
    // SAFETY: the CALIB region of link/lv/memory.x, 4 KiB, always mapped, read-only here.
    unsafe { core::slice::from_raw_parts(core::ptr::addr_of!(_calib_start), ssis::calib::store::REGION_LEN) }
}

/// Offset of the pad initialisation block in the LVDATA region.
pub const INIT_OFFSET: usize = 0x100;

/// The accelerometer section (LVDATA + 0).
pub fn accel_table_bytes() -> &'static [u8] {
    // SAFETY: the LVDATA region of link/lv/memory.x (4 KiB), always mapped, read-only here.
    unsafe { core::slice::from_raw_parts(core::ptr::addr_of!(_lvdata_start), ACCEL_TABLE_LEN) }
}

/// The pad initialisation block (LVDATA + [`INIT_OFFSET`]).
pub fn init_block_bytes() -> &'static [u8] {
    // SAFETY: as above; INIT_OFFSET + the block's length is inside the 4 KiB region.
    unsafe { core::slice::from_raw_parts(core::ptr::addr_of!(_lvdata_start).wrapping_add(INIT_OFFSET), INIT_BLOCK_LEN) }
}
