//! The configuration registers a Cortex-M7 board depends on, declared once and checked
//! against upsets ([`ssis::bsp::exec::StepBoard::check_registers`]).
//!
//! A board declares its list once, a constant in flash ([`Entry`]: an address and the
//! bits that matter; a [`select`]ion is a write made before the entries after it: the
//! MPU's region number, the watchdog's unlock key and its lock after), and at start-up,
//! after it configured its peripherals, [`build`] takes their values *read back* then
//! into RAM ([`Table`], with its check word, CRC-32C): the expected values are what the
//! board configured.
//!
//! [`verify`] reads every register; one whose bits differ is restored (read, modify,
//! write, read back) and counted; if the restore does not read back, or the table itself
//! fails its check word (so the "expected" value may be the upset one), it counts a
//! failure and the executive resets the unit. The interrupt masks (PRIMASK, BASEPRI,
//! FAULTMASK) are checked too: the firmwares never raise BASEPRI or FAULTMASK, and mask
//! interrupts only inside critical sections, so between two steps PRIMASK is clear.
//!
//! The first entries of a list, the SysTick's own two registers and the links' control
//! words, are checked at every pass of the executive as well ([`verify_pass`]): a tick an
//! upset stopped or slowed runs again at the loop's next wake (the next received byte),
//! and a link whose receiver an upset turned off receives again from then (in lockstep
//! no step comes without it, and with no step the every-64-steps check never runs). A
//! stopped SysTick (its ENABLE or TICKINT bit cleared) with no byte arriving stops the
//! steps, and with them the executive's checks. The watchdog's first timeout (an NMI, one
//! watchdog period after the last step) runs [`verify_in_nmi`]: the entries before the first selection
//! (the tick, the interrupt enables and priorities, the UARTs) restored from there, the
//! steps resume and feed the watchdog before its second timeout; had the restore not
//! held, the watchdog's second timeout resets the unit. An interrupt enabled that should
//! not be is not restored (a set-enable register cannot clear a bit); its interrupt has
//! no handler work and, if it storms, starves the loop into a watchdog reset.
#![allow(unsafe_code)]

use core::cell::UnsafeCell;
use core::sync::atomic::{AtomicU32, Ordering};

use ssis::bsp::exec::RegisterCheck;

/// Most entries a board's list holds.
pub const ENTRIES: usize = 32;

/// One entry of a board's list ([`Table`]): a register's address and the bits that
/// matter, or, with bit 0 of the address set ([`select`]), a write of the second word
/// to the address before the entries after it.
pub type Entry = (u32, u32);

/// A selection entry: `value` written to `addr` before the entries after it.
pub const fn select(addr: u32, value: u32) -> Entry {
    (addr | 1, value)
}

/// The values the board's registers held at start-up (bits of its list's masks), with
/// their check word; the list itself is a constant in flash.
#[repr(C)]
pub struct Table {
    values: [u32; ENTRIES],
    check: u32,
}

/// SysTick control and status: ENABLE, TICKINT, CLKSOURCE.
pub const SYST_CSR: u32 = 0xE000_E010;
/// SysTick reload value.
pub const SYST_RVR: u32 = 0xE000_E014;
/// SysTick current value (a write clears it; the counter reloads on the next cycle).
pub const SYST_CVR: u32 = 0xE000_E018;
/// The vector table's address.
pub const SCB_VTOR: u32 = 0xE000_ED08;
/// System handler priorities 12–15 (SysTick's in bits 24..32).
pub const SCB_SHPR3: u32 = 0xE000_ED20;
/// NVIC interrupt set-enable registers (32 interrupts a word).
pub const NVIC_ISER: u32 = 0xE000_E100;
/// NVIC interrupt priorities (four a word).
pub const NVIC_IPR: u32 = 0xE000_E400;
/// MPU control, region number, base and attributes.
pub const MPU_CTRL: u32 = 0xE000_ED94;
/// MPU region number (selects the region the next two address).
pub const MPU_RNR: u32 = 0xE000_ED98;
/// MPU region base address.
pub const MPU_RBAR: u32 = 0xE000_ED9C;
/// MPU region attributes and size.
pub const MPU_RASR: u32 = 0xE000_EDA0;

/// The entries every Cortex-M7 board keeps first, checked at every pass
/// ([`verify_pass`]): the SysTick's control (ENABLE, TICKINT, CLKSOURCE) and reload.
pub const TICK: [Entry; 2] = [(SYST_CSR, 0b111), (SYST_RVR, 0x00FF_FFFF)];

/// The entries every Cortex-M7 board keeps among the rest: the SysTick's priority, the
/// vector table's address.
pub const CORE: [Entry; 2] = [(SCB_SHPR3, 0xFF00_0000), (SCB_VTOR, 0xFFFF_FF80)];

/// MPU region `r`'s entries: the selection, its base and its attributes.
pub const fn mpu_region(r: u32) -> [Entry; 3] {
    [select(MPU_RNR, r), (MPU_RBAR, u32::MAX), (MPU_RASR, u32::MAX)]
}

fn read(addr: u32) -> u32 {
    // SAFETY: the lists hold only their board's own register addresses (constants),
    // 4-byte aligned and always mapped.
    unsafe { core::ptr::read_volatile(addr as *const u32) }
}

fn write(addr: u32, v: u32) {
    // SAFETY: as in `read`; the value is the one the board configured (or a selection of
    // its list).
    unsafe { core::ptr::write_volatile(addr as *mut u32, v) }
}

impl Table {
    /// CRC-32C register over the values.
    #[inline(never)]
    fn checksum(&self) -> u32 {
        let mut crc = crc::CRC_32_ISCSI.init;
        for v in &self.values {
            crc = ssis::frames::crc32c_register(crc, &v.to_le_bytes());
        }
        crc
    }

    /// Checks the registers of `list` (up to its first selection when `prefix`),
    /// restoring those that changed (module doc).
    #[inline(never)]
    fn verify(&self, list: &[Entry], prefix: bool) -> RegisterCheck {
        let mut out = RegisterCheck::default();
        for (&(addr, mask), &value) in list.iter().zip(&self.values) {
            if addr & 1 != 0 {
                if prefix {
                    break;
                }
                write(addr & !1, mask);
                continue;
            }
            let v = read(addr);
            if v & mask == value {
                continue;
            }
            if self.check != self.checksum() {
                out.failed += 1;
                return out;
            }
            write(addr, (v & !mask) | value);
            if addr == SYST_RVR {
                // The counter reloads from RVR only when it wraps: cleared, the restored
                // period holds from the next cycle, not after up to 2^24 cycles of the
                // upset one (the board's clock, and with it the watchdog's deadline
                // rule, would stand still meanwhile).
                write(SYST_CVR, 0);
            }
            if read(addr) & mask == value {
                out.restored += 1;
            } else {
                out.failed += 1;
            }
        }
        out
    }
}

struct Shared(UnsafeCell<Table>);

// SAFETY: written only by `build` at start-up, before the watchdog's NMI can run
// (its first timeout is a watchdog period after the start); read-only after.
unsafe impl Sync for Shared {}

static TABLE: Shared = Shared(UnsafeCell::new(Table { values: [0; ENTRIES], check: 0 }));

/// Restores made by [`verify_in_nmi`], not yet reported by [`verify`].
static NMI_RESTORED: AtomicU32 = AtomicU32::new(0);

/// Takes the values of the registers of `list` now (the selections made as they come)
/// and seals them. Call once, at start-up, after the board configured them.
#[inline(never)]
pub fn build(list: &[Entry]) {
    // SAFETY: see `Shared`: the one writer, at start-up.
    let t = unsafe { &mut *TABLE.0.get() };
    for (&(addr, mask), value) in list.iter().zip(t.values.iter_mut()) {
        if addr & 1 != 0 {
            write(addr & !1, mask);
        } else {
            *value = read(addr) & mask;
        }
    }
    t.check = t.checksum();
}

fn table() -> &'static Table {
    // SAFETY: see `Shared`: read-only after `build`.
    unsafe { &*TABLE.0.get() }
}

/// The executive's check ([`ssis::bsp::exec::StepBoard::check_registers`]; thread mode,
/// outside any critical section): every entry, then the interrupt masks; the restores
/// the NMI made since the last call are added.
pub fn verify(list: &[Entry]) -> RegisterCheck {
    let mut out = table().verify(list, false);
    // cortex-m names PRIMASK and FAULTMASK by the exceptions: `Active` is the bit
    // clear (exceptions taken), `Inactive` the bit set (masked).
    if cortex_m::register::primask::read().is_active() {
        // Expected: between steps interrupts are enabled.
    } else {
        // SAFETY: the main loop is outside every critical section here.
        unsafe { cortex_m::interrupt::enable() };
        out.restored += 1;
    }
    if cortex_m::register::basepri::read() != 0 {
        // SAFETY: no code of the firmware raises BASEPRI.
        unsafe { cortex_m::register::basepri::write(0) };
        out.restored += 1;
    }
    if cortex_m::register::faultmask::read().is_inactive() {
        // SAFETY: no code of the firmware sets FAULTMASK; clearing it only unmasks.
        unsafe { core::arch::asm!("cpsie f", options(nomem, nostack, preserves_flags)) };
        out.restored += 1;
    }
    out.restored += NMI_RESTORED.swap(0, Ordering::Relaxed);
    out
}

/// The check at every pass of the executive
/// ([`ssis::bsp::exec::StepBoard::check_pass`]; thread mode): the list's first `n`
/// entries, the SysTick's control word and reload ([`TICK`], which every board's list
/// starts with) and the links' control words the board lists after them.
pub fn verify_pass(list: &[Entry], n: usize) -> RegisterCheck {
    table().verify(list.get(..n).unwrap_or(list), true)
}

/// The watchdog warning's check (module doc): the entries before the first selection.
pub fn verify_in_nmi(list: &[Entry]) {
    let r = table().verify(list, true);
    NMI_RESTORED.fetch_add(r.restored, Ordering::Relaxed);
}
