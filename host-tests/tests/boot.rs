//! The boot policy every board shares (`ssis::bsp::boot`), on the STM32H7 board's
//! calibration flash: the `CALIB` region of `boards/stm32h7/memory.x` (one 128 KiB flash
//! sector), erased, with the two-copy image (`ssis-sim table to-image`) programmed at its
//! start, as the board's README does it. The board hands the whole sector to the policy.

use ssis::bsp::boot::{boot, BootEvent, BootReport};
use ssis::bsp::Board;
use ssis::calib::store::{self, Slot, Source, StoreError};
use ssis::calib::CalibrationTable;
use ssis::flight::FlightCore;
use ssis::flight::Profile;

/// `(origin, length)` of the `CALIB` region in `boards/stm32h7/memory.x`.
fn stm32h7_calib_region() -> (u32, usize) {
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../boards/stm32h7/memory.x");
    let text = std::fs::read_to_string(path).expect("boards/stm32h7/memory.x");
    let line =
        text.lines().map(str::trim).find(|l| l.starts_with("CALIB") && l.contains("ORIGIN")).expect("a CALIB region");
    let field = |name: &str| {
        let v = line.split(name).nth(1).expect("field").trim_start_matches([' ', '=']);
        v.split([',', ' ']).next().expect("value").to_owned()
    };
    let origin = u32::from_str_radix(field("ORIGIN").trim_start_matches("0x"), 16).expect("hex origin");
    let len = field("LENGTH");
    let len = match len.strip_suffix('K') {
        Some(k) => k.parse::<usize>().expect("KiB") * 1024,
        None => len.parse().expect("bytes"),
    };
    (origin, len)
}

/// The STM32H7 as the boot policy sees it: its calibration sector.
struct Stm32h7Flash {
    sector: Vec<u8>,
}

impl Stm32h7Flash {
    /// An erased sector with `image` programmed at its start.
    fn programmed(image: &[u8]) -> Self {
        let (origin, len) = stm32h7_calib_region();
        assert_eq!((origin, len), (0x081E_0000, 128 * 1024), "the layout this test was written for");
        let mut sector = vec![0xFF; len];
        sector[..image.len()].copy_from_slice(image);
        Stm32h7Flash { sector }
    }
}

impl Board for Stm32h7Flash {
    fn calib_area(&self) -> &[u8] {
        &self.sector
    }

    fn feed_watchdog(&mut self) {}

    fn ticks(&self) -> u32 {
        0
    }

    fn stop(&mut self, ok: bool) -> ! {
        panic!("the board stopped (ok {ok})")
    }
}

/// Boots on `board` and returns what the main loop would be handed: the core's table
/// and the boot report.
fn boot_on(board: &mut Stm32h7Flash, profile: Profile, other_defaulted: bool) -> (CalibrationTable, BootReport) {
    boot(board, profile, other_defaulted, |_, core: &mut FlightCore, report| (*core.table(), *report))
        .expect("the unit flies")
}

/// A valid table told apart from the default one.
fn table() -> CalibrationTable {
    CalibrationTable { revision: 42, ..CalibrationTable::DEFAULT }
}

#[test]
fn a_damaged_copy_a_flies_on_copy_b_and_names_a_as_refused() {
    let t = table();
    let mut image = store::image(&t).to_vec();
    image[Slot::A.offset() + 200] ^= 0x04;
    let mut board = Stm32h7Flash::programmed(&image);
    let (flown, b) = boot_on(&mut board, Profile::SPACECRAFT, false);
    assert_eq!(b.loaded.source, Source::Stored(Slot::B), "flies on copy B");
    assert_eq!(b.loaded.slot_errors, [Some(StoreError::BadCrc), None]);
    assert!(!b.defaulted, "copy B is the stored table, not the default");
    assert_eq!(flown, t);
    assert_eq!(b.bit, Ok(()));
    let events: Vec<BootEvent> = b.events().collect();
    assert_eq!(events, [BootEvent::CopyRefused(Slot::A, StoreError::BadCrc)]);
    let log: Vec<String> = events.iter().map(ToString::to_string).collect();
    assert_eq!(log, ["calibration copy A refused (BadCrc)"], "the boot log names copy A");
}

#[test]
fn both_copies_good_fly_without_a_word() {
    let mut board = Stm32h7Flash::programmed(&store::image(&table()));
    let (_, b) = boot_on(&mut board, Profile::SPACECRAFT, false);
    assert_eq!(b.loaded.source, Source::Stored(Slot::A));
    assert_eq!(b.events().count(), 0);
    assert!(!b.defaulted);
}

#[test]
fn an_erased_sector_flies_on_the_default_table_flagged() {
    let mut board = Stm32h7Flash::programmed(&[]);
    let (flown, b) = boot_on(&mut board, Profile::SPACECRAFT, false);
    assert_eq!(b.loaded.source, Source::Default);
    assert!(b.defaulted);
    assert_eq!(flown, CalibrationTable::DEFAULT);
    let log: Vec<String> = b.events().map(|e| e.to_string()).collect();
    assert_eq!(
        log,
        [
            "calibration copy A refused (BadMagic)",
            "calibration copy B refused (BadMagic)",
            "no calibration copy passed: flying on the default table"
        ]
    );
}

#[test]
fn another_defaulted_table_flags_the_output_too() {
    // The launch vehicle's accelerometer section fell back to the ideal one.
    let mut board = Stm32h7Flash::programmed(&store::image(&table()));
    let (flown, b) = boot_on(&mut board, Profile::LAUNCH_VEHICLE, true);
    assert_eq!(b.loaded.source, Source::Stored(Slot::A));
    assert!(b.defaulted);
    assert_eq!(flown, table());
}

/// A copy whose CRCs are good but whose table holds an implausible number (the issue's
/// turntable run read as noise: RRW 53,954 °/h/√h) is refused before activation; the
/// boot log names the field, its value and the range, and the unit flies on the other copy.
#[test]
fn a_copy_with_an_implausible_field_is_refused_at_boot_naming_it() {
    use ssis::calib::{Field, FieldError, TableError};
    let good = table();
    let mut bad = good;
    bad.revision = 43;
    bad.observer.rrw_deg_h_sqrt_h = 53_954.0;
    let mut image = store::image(&good).to_vec();
    // Copy A: the bad table, newer generation, intact record.
    image[..store::RECORD_LEN].copy_from_slice(&store::encode_record(&bad, 2));
    let mut board = Stm32h7Flash::programmed(&image);
    let (flown, b) = boot_on(&mut board, Profile::SPACECRAFT, false);
    let refusal = StoreError::Table(TableError::Field(FieldError::new(Field::Rrw, 53_954.0)));
    assert_eq!(b.loaded.slot_errors, [Some(refusal), None]);
    assert_eq!((flown, b.loaded.source, b.defaulted), (good, Source::Stored(Slot::B), false));
    let log: Vec<String> = b.events().map(|e| e.to_string()).collect();
    assert_eq!(log.len(), 1);
    for m in ["copy A refused", "observer.rrw_deg_h_sqrt_h", "53954", "0.0001 … 0.1 °/h/√h"] {
        assert!(log[0].contains(m), "`{}` lacks `{m}`", log[0]);
    }
    // Both copies implausible: the default table flies, flagged.
    let mut board = Stm32h7Flash::programmed(&store::image(&bad));
    let (flown, b) = boot_on(&mut board, Profile::SPACECRAFT, false);
    assert_eq!((flown, b.defaulted), (CalibrationTable::DEFAULT, true));
    assert_eq!(b.loaded.slot_errors, [Some(refusal); 2]);
}
