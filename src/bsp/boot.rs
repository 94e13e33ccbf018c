//! The boot policy of every board, in one place (host-tested in
//! `host-tests/tests/boot.rs` on the STM32H7's calibration flash layout).
//!
//! 1. **Table**: the two stored copies ([`store::load`]): the newest good one, else the
//!    other, else [`CalibrationTable::DEFAULT`], flagged in every output frame. A copy is
//!    good only after its CRCs *and* [`CalibrationTable::validate`]: every field finite and
//!    within its plausible range (`calib::field`); a copy that fails is refused before it
//!    is activated, and the boot log names the field, its value and the range.
//! 2. **Flight core** built from that table. Should the core refuse a stored table
//!    that passed its checks (gains or geometry), it is built on the default table,
//!    flagged; if it refuses even that, the board cannot fly ([`BootError`]).
//! 3. **Power-on built-in test** ([`bit::power_on`]): a failure is flagged in every
//!    output frame ([`FlightCore::note_bit_failure`]); the unit still flies (the ground
//!    decides).
//!
//! The core is then lent to the firmware's main loop. What happened is kept in
//! [`BootReport`]; [`BootReport::events`] lists what the boot log says (each
//! [`BootEvent`]; on the target [`boot`] writes them with defmt).

use crate::bit::{self, BitError};
use crate::calib::store::{self, Slot, StoreError};
use crate::calib::CalibrationTable;
use crate::flight::{CoreError, FlightCore, Profile};

use super::Board;

/// How the boot went (the flight core itself is handed to the firmware's main loop).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BootReport {
    /// What the table store held: the copy in use, its generation, why a copy was refused.
    pub loaded: store::Loaded,
    /// The core refused the stored table (which passed the store's checks): it flies
    /// on the default table instead.
    pub core_refused: Option<CoreError>,
    /// The power-on built-in test's result.
    pub bit: Result<(), BitError>,
    /// The output frames carry the table-defaulted flag.
    pub defaulted: bool,
}

/// Why a board cannot fly.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub enum BootError {
    /// The flight core refused the default table.
    DefaultRefused(CoreError),
}

/// One line of the boot log.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum BootEvent {
    /// A stored copy was refused.
    CopyRefused(Slot, StoreError),
    /// Neither copy passed: the default table flies, flagged.
    NoCopyPassed,
    /// The core refused the stored table of this revision: the default flies, flagged.
    CoreRefused(u32, CoreError),
    /// The built-in test failed: flagged in every output frame.
    BitFailed(BitError),
}

impl core::fmt::Display for BootEvent {
    /// The text of the boot log's line (the target's defmt line says the same).
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            BootEvent::CopyRefused(slot, e) => write!(f, "calibration copy {slot:?} refused ({e})"),
            BootEvent::NoCopyPassed => write!(f, "no calibration copy passed: flying on the default table"),
            BootEvent::CoreRefused(rev, e) => {
                write!(f, "flight core refused table revision {rev} ({e:?}): flying on the default table")
            }
            BootEvent::BitFailed(e) => write!(f, "built-in test failed: {e:?}"),
        }
    }
}

/// Boots the flight core for `profile` on `board` (the steps in the module doc), logs
/// the boot (target) and hands the board and the core to `fly`, the firmware's main
/// loop, whose result it returns. `other_defaulted`: another table of the unit fell back to its default
/// (the launch vehicle's accelerometer section), so the output frames carry the
/// defaulted flag too.
///
/// The core (7 KB) is built once, in this function's frame, and lent to `fly`: never
/// moved, so the stack holds one copy (the stack is 28 KiB on the spacecraft board).
pub fn boot<B: Board + ?Sized, R>(
    board: &mut B,
    profile: Profile,
    other_defaulted: bool,
    fly: impl FnOnce(&mut B, &mut FlightCore, &BootReport) -> R,
) -> Result<R, BootError> {
    let loaded = store::load(board.calib_area());
    let defaulted = loaded.defaulted() || other_defaulted;
    let mut report = BootReport { loaded, core_refused: None, bit: Ok(()), defaulted };
    // Runs at most twice: the stored table, then the default one. One call site of
    // `FlightCore::new`, so its code is not duplicated in flash; no copy of the table.
    loop {
        let table = if report.core_refused.is_some() { &CalibrationTable::DEFAULT } else { &report.loaded.table };
        let mut built = FlightCore::new(profile, table, report.defaulted);
        match &mut built {
            Ok(core) => {
                report.bit = bit::power_on();
                if report.bit.is_err() {
                    core.note_bit_failure();
                }
                #[cfg(target_os = "none")]
                report.log();
                return Ok(fly(board, core, &report));
            }
            Err(e) => {
                if report.core_refused.is_some() || report.loaded.defaulted() {
                    return Err(BootError::DefaultRefused(*e));
                }
                report.core_refused = Some(*e);
                report.defaulted = true;
            }
        }
    }
}

impl BootReport {
    /// The lines of the boot log, in order (none when both copies passed and the
    /// built-in test passed).
    pub fn events(&self) -> impl Iterator<Item = BootEvent> + '_ {
        let copies = [Slot::A, Slot::B]
            .into_iter()
            .zip(self.loaded.slot_errors)
            .filter_map(|(slot, e)| e.map(|e| BootEvent::CopyRefused(slot, e)));
        let none = self.loaded.defaulted().then_some(BootEvent::NoCopyPassed);
        let refused = self.core_refused.map(|e| BootEvent::CoreRefused(self.loaded.table.revision, e));
        let bit = self.bit.err().map(BootEvent::BitFailed);
        copies.chain(none).chain(refused).chain(bit)
    }

    /// Writes [`BootReport::events`] to the defmt log (warnings; the built-in test's failure
    /// as an error).
    #[cfg(target_os = "none")]
    pub fn log(&self) {
        for e in self.events() {
            match e {
                BootEvent::CopyRefused(slot, e) => defmt::warn!("calibration copy {} refused ({})", slot, e),
                BootEvent::NoCopyPassed => defmt::warn!("no calibration copy passed: flying on the default table"),
                BootEvent::CoreRefused(rev, e) => {
                    defmt::warn!("flight core refused table revision {} ({}): flying on the default table", rev, e)
                }
                BootEvent::BitFailed(e) => defmt::error!("built-in test failed: {}", e),
            }
        }
    }
}
