//! The clock tree: 400 MHz from PLL1, fed by the 8 MHz HSE (bypass) or, when the HSE
//! does not start, the 64 MHz HSI; the dividers are checked at compile time.

use cortex_m::peripheral::DWT;
use stm32h7::stm32h743v as pac;

use super::{wait, Timeout};

/// HSE frequency (NUCLEO-H743ZI: 8 MHz from the ST-LINK MCO).
const HSE_HZ: u32 = 8_000_000;
/// The HSE is an external clock signal (bypass), not a crystal.
const HSE_BYPASS: bool = true;
/// HSI frequency: the clock the MCU resets on (RCC_CR.HSIDIV = 1 after reset).
pub(super) const HSI_HZ: u32 = 64_000_000;
/// Longest wait for the HSE before falling back to the HSI, in HSI cycles (10 ms).
const HSE_TIMEOUT_CYCLES: u32 = 640_000;

/// Core clock: the most the STM32H743 (rev V) runs at in voltage scale 1.
pub(super) const CORE_HZ: u32 = 400_000_000;
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
pub(super) const PCLK_HZ: u32 = HCLK_HZ / 2;
/// Flash wait states at 200 MHz AXI in VOS1 (RM0433 table 17: 185-210 MHz: LATENCY
/// = 2, WRHIGHFREQ = 2).
const FLASH_LATENCY: u8 = 2;
const FLASH_WRHIGHFREQ: u8 = 2;

const _: () = assert!(HSE_HZ / PLL_M_HSE >= 8_000_000 && HSE_HZ / PLL_M_HSE <= 16_000_000);
const _: () = assert!(HSI_HZ / PLL_M_HSI >= 8_000_000 && HSI_HZ / PLL_M_HSI <= 16_000_000);
const _: () = assert!(PLL_N_HSE * (HSE_HZ / PLL_M_HSE) == VCO_HZ && PLL_N_HSI * (HSI_HZ / PLL_M_HSI) == VCO_HZ);
const _: () = assert!(PLL_N_HSE >= 4 && PLL_N_HSE <= 512 && PLL_N_HSI >= 4 && PLL_N_HSI <= 512);
const _: () = assert!(VCO_HZ >= 192_000_000 && VCO_HZ <= 960_000_000 && VCO_HZ / PLL_P == CORE_HZ);

/// Turns the HSE on and waits for it at most [`HSE_TIMEOUT_CYCLES`]. Leaves it on if
/// it is ready, off otherwise (RCC_CR.HSEBYP, HSEON, HSERDY).
pub(super) fn hse_starts(rcc: &pac::RCC) -> bool {
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
pub(super) fn clocks_400mhz(pwr: &pac::PWR, flash: &pac::FLASH, rcc: &pac::RCC, hse: bool) -> Result<(), Timeout> {
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
