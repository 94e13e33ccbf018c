//! The background check of the calibration table in RAM, as cFS's checksum application
//! checks its tables: a few dozen bytes a step between two flight steps
//! ([`FlightCore::background`]), the whole table every 5 s ([`PASS_STEPS`]), against the CRC-32C of
//! its binary form taken when it was loaded or activated. A table that differs is restored from the two-copy
//! store in flash (`calib::store`: the newest good copy), and what the step builds from
//! it (the combiner, the parity logic, the observer's gains, the mount) is rebuilt from
//! the restored table; logged `table_restored`, counted. The attitude flown on the
//! corrupt table since the last good check cannot be backed: the frames are flagged
//! degraded for [`HOLD_STEPS`] after a restore (for good if no stored copy is good).
//!
//! The step itself never runs any of this: the board calls [`FlightCore::background`]
//! after each step, so a replay that does not call it (the host's golden flights) is
//! unchanged, and a call that finds nothing wrong changes no output.

use super::FlightCore;
use crate::calib::binary::{self, TABLE_LEN};
use crate::calib::{store, CalibrationTable};
use crate::frames;
use crate::telemetry::events::Event;
#[cfg(test)]
use crate::telemetry::Counter;

/// Bytes of the table's binary form the CRC covers.
const BODY_LEN: usize = TABLE_LEN - 4;
/// Bytes checked per step.
const SLICE: usize = 32;
/// Slices of a pass.
const SLICES: usize = BODY_LEN.div_ceil(SLICE);
/// Steps per pass: the whole table every 5 s at 5 ms (encoding it is the pass's first
/// step, its slices the next ones, then nothing until the next pass). The encoding costs
/// some 8,000 instructions, 40 a step at one pass a second; every 5 s, 8. The table is
/// 504 bytes of the 32 KiB of RAM, and the step reads it directly only for the FOGs'
/// calibration (what is derived from it, the combiner, the gains, the mount, is in the
/// state guard's blocks, checked every step): at the order of 10 upsets a year in the
/// 32 KiB in LEO, one in the table every 6 years or so (every few weeks in the South
/// Atlantic Anomaly's flux), found within 5 s (2.5 s on average) instead of 1 s.
pub const PASS_STEPS: u16 = 1000;
/// Steps the frames stay flagged degraded after a restore (1 s at 5 ms).
pub const HOLD_STEPS: u16 = 200;

/// The register of CRC-32C (the frames' CRC, [`frames::body_crc`], whose tables it
/// shares) at the start of a pass.
const CRC_INIT: u32 = crc::CRC_32_ISCSI.init;

/// CRC-32C of `bytes` continued from register `r` (the register after them).
fn crc_on(r: u32, bytes: &[u8]) -> u32 {
    frames::crc32c_register(r, bytes)
}

/// Where the background check of the table is.
#[derive(Clone, Copy, bytemuck::AnyBitPattern)]
pub(super) struct TableScrub {
    /// The table's binary form up to its CRC, encoded at the start of a pass.
    body: [u8; BODY_LEN],
    /// The CRC-32C register over the bytes checked so far in this pass (a plain word: a
    /// `crc::Digest` holds a reference, which a flipped bit would make wild).
    partial: u32,
    /// The CRC-32C of the table's binary form when it was installed ([`TableScrub::seal`]):
    /// what each pass must find.
    reference: u32,
    /// Step within the pass (0: encode).
    tick: u16,
    /// Steps left of the degraded flag after a restore (`u16::MAX`: for good).
    hold: u16,
}

impl TableScrub {
    /// Whether the output is flagged degraded after a restore (the timed hold, or for
    /// good); the flags that hold for the whole flight are the core's `fixed_flags`.
    #[inline(always)]
    pub(super) fn degraded(&self) -> bool {
        self.hold != 0
    }

    pub(super) fn new() -> Self {
        TableScrub { body: [0; BODY_LEN], partial: CRC_INIT, reference: 0, tick: 0, hold: 0 }
    }

    /// Checking `table` ([`TableScrub::seal`]).
    pub(super) fn of(table: &CalibrationTable) -> Self {
        let mut s = TableScrub::new();
        s.seal(table);
        s
    }

    /// `table` is the one in use from now on: its CRC is what the passes check, and the
    /// pass starts again.
    pub(super) fn seal(&mut self, table: &CalibrationTable) {
        let _ = binary::encode_body_into(table, &mut self.body);
        self.reference = crc_on(CRC_INIT, &self.body) ^ crc::CRC_32_ISCSI.xorout;
        self.tick = 0;
    }
}

impl FlightCore {
    /// The background work between two steps, a slice a call (the board calls it after
    /// every step): the table in RAM against its CRC, restored from `calib_region` (the
    /// two-copy store, [`store::REGION_LEN`] bytes of flash) when it differs (module
    /// doc). Returns true when it restored a table. Inline: most calls only count the
    /// step (no slice due, no hold running) and return.
    #[inline(always)]
    pub fn background(&mut self, calib_region: &[u8]) -> bool {
        let s = &mut self.scrub;
        let tick = s.tick;
        s.tick = if tick + 1 >= PASS_STEPS { 0 } else { tick + 1 };
        // No hold counting down: 0 (none) or u16::MAX (for good).
        if usize::from(tick) > SLICES && s.hold.wrapping_add(1) <= 1 {
            return false;
        }
        self.background_slice(tick, calib_region)
    }

    /// [`FlightCore::background`]'s step `tick` of the pass with work due: the hold
    /// counted down, the table encoded (step 0) or a slice checked.
    #[inline(never)]
    fn background_slice(&mut self, tick: u16, calib_region: &[u8]) -> bool {
        let s = &mut self.scrub;
        if s.hold > 0 && s.hold != u16::MAX {
            s.hold -= 1;
        }
        let s = &mut self.scrub;
        match usize::from(tick) {
            0 => {
                let _ = binary::encode_body_into(&self.table, &mut s.body);
                s.partial = CRC_INIT;
                false
            }
            k if k <= SLICES => {
                let from = (k - 1) * SLICE;
                if let Some(bytes) = s.body.get(from..(from + SLICE).min(BODY_LEN)) {
                    s.partial = crc_on(s.partial, bytes);
                }
                if k < SLICES {
                    return false;
                }
                s.partial ^ crc::CRC_32_ISCSI.xorout != s.reference && self.restore_table(calib_region)
            }
            _ => false,
        }
    }

    /// The table in RAM differs from its CRC: flies the newest good stored copy, all
    /// that is built from it rebuilt; degraded for [`HOLD_STEPS`]. With no good copy (or
    /// one the core refuses) it flies on as it was, degraded for good.
    #[inline(never)]
    fn restore_table(&mut self, calib_region: &[u8]) -> bool {
        let loaded = store::load(calib_region);
        let now_us = self.last_output.time_us;
        let restored = !loaded.defaulted() && self.install_table(&loaded.table).is_ok();
        let revision = u16::try_from(loaded.table.revision).unwrap_or(u16::MAX);
        self.scrub.hold = if restored { HOLD_STEPS } else { u16::MAX };
        let b = if restored { revision } else { 0 };
        self.events.record(&mut self.telemetry.counters, now_us, Event::TableRestored, u8::from(restored), b);
        restored
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::flight::Profile;
    use crate::telemetry::events::Event;

    #[test]
    fn a_changed_table_is_found_within_a_pass_and_restored_from_the_store() {
        let table = CalibrationTable::DEFAULT;
        let region = store::image(&table);
        let mut core = FlightCore::new(Profile::SPACECRAFT, &table, false).unwrap();
        let combiner = core.combiner;
        for _ in 0..3 * PASS_STEPS {
            assert!(!core.background(&region), "an intact table is left as it is");
        }
        assert!(!core.scrub.degraded());
        // One bit of a FOG's misalignment: the combiner built from it changes too.
        core.table.misalignment.d12_rad = f64::from_bits(core.table.misalignment.d12_rad.to_bits() ^ (1 << 40));
        core.combiner = crate::combination::Combiner::new(&[nalgebra::Vector3::x(); 4]);
        let at = (0..PASS_STEPS).position(|_| core.background(&region));
        assert!(at.is_some(), "found within one pass");
        assert_eq!(binary::encode(&core.table), binary::encode(&table));
        assert_eq!(core.combiner, combiner, "the combiner is rebuilt from the restored table");
        assert_eq!(core.counter(Counter::TablesRestored), 1);
        let e = core.events.pending().last().unwrap();
        assert_eq!((e.event, e.a), (Event::TableRestored, 1));
        assert!(core.scrub.degraded(), "degraded after the restore");
        for _ in 0..HOLD_STEPS {
            assert!(!core.background(&region), "found once");
        }
        assert!(!core.scrub.degraded(), "and no longer after the hold");
        for _ in 0..PASS_STEPS {
            assert!(!core.background(&region), "found once");
        }
        // No good copy in the store: it flies on, degraded for good.
        core.table.gamma_rad += 1e-6;
        let blank = [0xFFu8; store::REGION_LEN];
        let restored = (0..PASS_STEPS).filter(|_| core.background(&blank)).count();
        assert_eq!(restored, 0);
        assert_eq!(core.counter(Counter::TablesRestored), 2);
        for _ in 0..3 * PASS_STEPS {
            core.background(&blank);
        }
        assert!(core.scrub.degraded());
    }
}
