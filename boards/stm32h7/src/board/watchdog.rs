//! The independent watchdog (IWDG): started first thing at boot, fed once per step.

use stm32h7::stm32h743v as pac;

use super::{wait, Timeout};

/// Watchdog: the IWDG counts the LSI (32 kHz) divided by 4 (IWDG_PR = 0), so a
/// reload of 400 gives 50 ms: 10 steps, and more than the boot takes before the
/// first feed.
const WATCHDOG_MS: u32 = 50;
const WATCHDOG_RELOAD: u16 = {
    let r = WATCHDOG_MS * (32_000 / 4) / 1_000;
    assert!(r >= 1 && r <= 0x0FFF, "IWDG reload out of range");
    r as u16
};

/// Starts the IWDG with [`WATCHDOG_RELOAD`] (RM0433 45.3.2): IWDG_KR = 0xCCCC
/// (start; the LSI turns on by itself), 0x5555 (unlock PR and RLR), IWDG_PR = 0
/// (LSI / 4), IWDG_RLR, then wait until IWDG_SR.PVU and RVU clear (the values have
/// crossed into the LSI domain), then 0xAAAA (reload). If they do not clear, the
/// watchdog still runs on its reset values (512 ms).
pub(super) fn watchdog_start(iwdg: &pac::IWDG) -> Result<(), Timeout> {
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
