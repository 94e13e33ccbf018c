//! SRAM ECC (RM0433 §3.3 "Embedded SRAM", §3.4 "RAM ECC monitoring", RAMECC): the
//! STM32H743's AXI SRAM, SRAM1–4, ITCM and DTCM carry ECC in hardware (single-error
//! correction, double-error detection), always on; what the firmware enables is the
//! reporting. [`enable`] turns on, in every monitor of the three RAMECC units, the
//! latching of the failing address (ECCELEN) and the flags of single errors corrected
//! (SEDCF), double errors detected (DEDF) and double errors on a byte write (DEBWDF), and
//! their interrupt enables (the global GIE stays off: the flags are polled by the
//! executive, so an upset storm cannot starve the step). [`poll`] reads the flags once a step,
//! clears them and returns the counts, which the executive adds to the core's counters
//! (`sram_ecc_corrected`, `sram_ecc_uncorrected`, event `sram_ecc`).
//!
//! | unit | base | monitors (RM0433 Table 11) |
//! |---|---|---|
//! | RAMECC1 (D1) | 0x5200_9000 | AXI SRAM, ITCM, DTCM0, DTCM1, ETM RAM |
//! | RAMECC2 (D2) | 0x4802_3000 | SRAM1_0, SRAM1_1, SRAM2_0, SRAM2_1, SRAM3 |
//! | RAMECC3 (D3) | 0x5802_7000 | SRAM4, backup SRAM |
//!
//! Built, not run: no STM32H743 was at hand (README).

/// Each RAMECC unit: base address and number of monitors.
const UNITS: [(usize, usize); 3] = [(0x5200_9000, 5), (0x4802_3000, 5), (0x5802_7000, 2)];
/// Monitor m's registers (m from 1): control, status, failing address.
const fn mcr(base: usize, m: usize) -> usize {
    base + 0x20 * m
}
const MSR: usize = 0x04;
const MFAR: usize = 0x08;
/// MxCR: interrupt enables for SEDC, DED, DEBW; error latching.
const ECCSEIE: u32 = 1 << 2;
const ECCDEIE: u32 = 1 << 3;
const ECCDEBWIE: u32 = 1 << 4;
const ECCELEN: u32 = 1 << 5;
/// MxSR: single error detected and corrected, double error detected, double error on a
/// byte write (cleared by writing 0).
const SEDCF: u32 = 1 << 0;
const DEDF: u32 = 1 << 1;
const DEBWDF: u32 = 1 << 2;

fn read(addr: usize) -> u32 {
    // SAFETY: a RAMECC register of the STM32H743 (RM0433 memory map), always mapped.
    unsafe { core::ptr::read_volatile(addr as *const u32) }
}

fn write(addr: usize, v: u32) {
    // SAFETY: as in `read`; writes only the RAMECC's own control and status bits.
    unsafe { core::ptr::write_volatile(addr as *mut u32, v) }
}

/// ECC errors found by one [`poll`].
#[derive(Debug, Default, Clone, Copy, defmt::Format)]
pub struct EccErrors {
    /// Single errors detected and corrected.
    pub corrected: u32,
    /// Double errors detected (not correctable), on a read or a byte write.
    pub uncorrected: u32,
    /// The failing address of the last error found (0: none).
    pub address: u32,
}

/// Enables error latching and the error flags of every monitor (module doc).
pub fn enable() {
    for (base, monitors) in UNITS {
        for m in 1..=monitors {
            write(mcr(base, m), ECCELEN | ECCSEIE | ECCDEIE | ECCDEBWIE);
            write(mcr(base, m) + MSR, 0);
        }
    }
}

/// Reads and clears every monitor's flags: what was found since the last call.
pub fn poll() -> EccErrors {
    let mut e = EccErrors::default();
    for (base, monitors) in UNITS {
        for m in 1..=monitors {
            let sr = read(mcr(base, m) + MSR);
            if sr & (SEDCF | DEDF | DEBWDF) == 0 {
                continue;
            }
            e.address = read(mcr(base, m) + MFAR);
            write(mcr(base, m) + MSR, 0);
            if sr & SEDCF != 0 {
                e.corrected = e.corrected.saturating_add(1);
            }
            if sr & (DEDF | DEBWDF) != 0 {
                e.uncorrected = e.uncorrected.saturating_add(1);
            }
        }
    }
    e
}
