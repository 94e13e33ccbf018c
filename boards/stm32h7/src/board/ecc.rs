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

/// One monitor's registers (RM0433 §3.4.4): 0x20 bytes each, monitor m (from 1) at
/// 0x20 × m from its unit's base (the unit's interrupt enable takes the first 0x20).
#[repr(C)]
struct Monitor {
    /// MxCR: interrupt enables for SEDC (bit 2), DED (3), DEBW (4); error latching,
    /// ECCELEN (5).
    cr: u32,
    /// MxSR: single error detected and corrected (bit 0), double error detected (1),
    /// double error on a byte write (2); cleared by writing 0.
    sr: u32,
    /// MxFAR: the failing address.
    far: u32,
    /// MxFDRL, MxFDRH, MxFECR, reserved.
    _rest: [u32; 5],
}
const _: () = assert!(core::mem::size_of::<Monitor>() == 0x20);

/// What [`enable`] writes to every MxCR: ECCELEN | ECCDEBWIE | ECCDEIE | ECCSEIE.
const CR_ENABLE: u32 = 0b1111 << 2;
/// MxSR's SEDCF.
const SR_CORRECTED: u32 = 1 << 0;
/// MxSR's DEDF | DEBWDF.
const SR_UNCORRECTED: u32 = 0b11 << 1;

/// Register `field` (its offset in [`Monitor`]) of monitor `m` (from 1) of the unit at
/// `base`.
const fn reg(base: usize, m: usize, field: usize) -> *mut u32 {
    (base + core::mem::size_of::<Monitor>() * m + field) as *mut u32
}
const CR: usize = core::mem::offset_of!(Monitor, cr);
const SR: usize = core::mem::offset_of!(Monitor, sr);
const FAR: usize = core::mem::offset_of!(Monitor, far);

fn read(reg: *const u32) -> u32 {
    // SAFETY: a RAMECC register of the STM32H743 (RM0433 memory map), always mapped.
    unsafe { core::ptr::read_volatile(reg) }
}

fn write(reg: *mut u32, v: u32) {
    // SAFETY: as in `read`; writes only the RAMECC's own control and status bits.
    unsafe { core::ptr::write_volatile(reg, v) }
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
            write(reg(base, m, CR), CR_ENABLE);
            write(reg(base, m, SR), 0);
        }
    }
}

/// Reads and clears every monitor's flags: what was found since the last call.
pub fn poll() -> EccErrors {
    let mut e = EccErrors::default();
    for (base, monitors) in UNITS {
        for m in 1..=monitors {
            let sr = read(reg(base, m, SR));
            if sr & (SR_CORRECTED | SR_UNCORRECTED) == 0 {
                continue;
            }
            e.address = read(reg(base, m, FAR));
            write(reg(base, m, SR), 0);
            if sr & SR_CORRECTED != 0 {
                e.corrected = e.corrected.saturating_add(1);
            }
            if sr & SR_UNCORRECTED != 0 {
                e.uncorrected = e.uncorrected.saturating_add(1);
            }
        }
    }
    e
}
