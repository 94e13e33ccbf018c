//! The configuration registers the executive checks on this board
//! (`ssis_firmware::regcheck`; addresses from RM0433's memory map): SysTick, the vector
//! table, the USARTs' interrupt enables (all of NVIC_ISER1: one enabled that should not
//! be does not restore, and resets) and priorities, the USARTs' control (CR1 without
//! TXFNFIE, which the output path sets and clears, and CR3) and baud rate, the MPU's
//! guard region below the stack and its control, the IWDG's prescaler and reload
//! (unlocked for the check, protected after). The SysTick's two and the USARTs' CR1 lead
//! the list: the executive checks them at every pass. The IWDG has no early warning: a stopped
//! SysTick stops the steps and is recovered by the IWDG's reset (50 ms).

use ssis_firmware::regcheck::{mpu_region, select, Entry, CORE, MPU_CTRL, NVIC_IPR, NVIC_ISER, TICK};

/// USART1, USART2, USART3 (RM0433 2.3.2).
const USART: [u32; 3] = [0x4001_1000, 0x4000_4400, 0x4000_4800];
/// USART_CR1 bits the board sets once (UE, RE, TE, RXFNEIE, PCE, M0, OVER8, M1, FIFOEN).
const CR1_KEPT: u32 = 1 | 1 << 2 | 1 << 3 | 1 << 5 | 1 << 10 | 1 << 12 | 1 << 15 | 1 << 28 | 1 << 29;
/// The IWDG (RM0433 45.4): key, prescaler, reload.
const IWDG: u32 = 0x5800_4800;

/// The entries checked at every pass (`StepBoard::check_pass`): the SysTick's two and
/// the USARTs' CR1.
pub(super) const PASS_ENTRIES: usize = 5;

/// The list (module doc).
pub(super) const REGISTERS: [Entry; 23] = {
    let r0 = mpu_region(0);
    [
        TICK[0],
        TICK[1],
        (USART[0], CR1_KEPT),
        (USART[1], CR1_KEPT),
        (USART[2], CR1_KEPT),
        CORE[0],
        CORE[1],
        (NVIC_ISER + 4, u32::MAX),
        // USART1..3 are interrupts 37..39: priority bytes 1..3 of NVIC_IPR9.
        (NVIC_IPR + 36, 0xFFFF_FF00),
        (USART[0] + 0x08, u32::MAX),
        (USART[0] + 0x0C, 0xFFFF),
        (USART[1] + 0x08, u32::MAX),
        (USART[1] + 0x0C, 0xFFFF),
        (USART[2] + 0x08, u32::MAX),
        (USART[2] + 0x0C, 0xFFFF),
        r0[0],
        r0[1],
        r0[2],
        (MPU_CTRL, 0b111),
        select(IWDG, 0x5555),
        (IWDG + 0x04, 0b111),
        (IWDG + 0x08, 0x0FFF),
        select(IWDG, 0),
    ]
};
