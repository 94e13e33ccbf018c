//! The three links, all 921 600 Bd 8N1, interrupt-driven: USART1 TX (framed output,
//! from [`OUT_TX`]), USART2 RX (the FOG RS-485 bus, into [`FOG_RX`]), USART3 RX (the star
//! tracker, into [`ST_RX`]).

use core::sync::atomic::{AtomicU32, Ordering};

use cortex_m::interrupt::free;
use ssis::link::{RxRing, TxRing};
use stm32h7::stm32h743v::{self as pac, interrupt, usart1};

use super::clocks::{HSI_HZ, PCLK_HZ};

/// All three links.
const BAUD: u32 = 921_600;
/// USARTDIV (RM0433 48.5.7, oversampling by 16, PRESC = 1): kernel clock / baud,
/// rounded to the nearest, for the PLL clock tree (100 MHz APB: 109, 917 431 Bd,
/// -0.45 %) and the HSI fallback (64 MHz APB: 69, 927 536 Bd, +0.64 %).
pub(super) const BRR_PLL: u16 = usart_div(PCLK_HZ, BAUD);
pub(super) const BRR_HSI: u16 = usart_div(HSI_HZ, BAUD);

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

/// FOG bus receive buffer: 512 bytes = 5.6 ms at 921 600 Bd, more than a step at full line rate.
pub static FOG_RX: RxRing<512> = RxRing::new();
/// Star-tracker receive buffer.
pub static ST_RX: RxRing<512> = RxRing::new();
/// Output transmit buffer: three output frames (`docs/ICD.md`).
pub static OUT_TX: TxRing<256> = TxRing::new();

/// Receive errors (framing, noise, parity, hardware overrun) on USART2 and USART3.
static UART_ERRORS: AtomicU32 = AtomicU32::new(0);

/// Pins (see README): PB6 = USART1_TX, PD6 = USART2_RX, PB11 = USART3_RX, all AF7
/// (RM0433 11.4 GPIOx_MODER = 0b10 alternate, GPIOx_AFRL/AFRH = 7). The receive pins
/// get the pull-up (GPIOx_PUPDR = 0b01): an unplugged line stays idle instead of
/// floating into framing errors.
pub(super) fn pins(rcc: &pac::RCC, gpiob: &pac::GPIOB, gpiod: &pac::GPIOD) {
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
pub(super) fn usart_start(u: &usart1::RegisterBlock, brr: u16, rx: bool) {
    u.cr1.write(|w| w.ue().disabled());
    u.brr.write(|w| w.brr().bits(brr));
    u.cr1.write(|w| {
        let w = w.fifoen().set_bit().m0().clear_bit().m1().clear_bit().pce().clear_bit().over8().clear_bit();
        let w = if rx { w.re().enabled().rxneie().enabled() } else { w.te().enabled() };
        w.ue().enabled()
    });
}

/// UART receive errors so far.
pub fn uart_errors() -> u32 {
    UART_ERRORS.load(Ordering::Relaxed)
}

/// The USARTs' registers, for their interrupts and [`start_tx`]. Set up in [`init`](super::init)
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
