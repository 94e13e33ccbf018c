//! Fuzz target: the command link — the telecommand decoder (single frame and stream) and
//! what the unit does with what it decodes (authentication, sequence, the table upload
//! through the two-copy store on a flash in RAM, a flight core switching tables).
//!
//! The first byte chooses fix-ups per 98-byte frame of the rest, so that the fuzzer
//! reaches the checks behind the CRC and the MAC: bit 0 writes sync and kind, bit 1 the
//! CRC-32C, bit 2 seals the frame under the unit's key (MAC, then CRC); bits 3–7 choose
//! the size of the pieces the bytes arrive in. Whatever is decoded must re-encode to the
//! same bytes; whatever the link does, the table the store loads is the old one or the
//! one the core flies, and the core flies the old one unless a table was activated.
#![no_main]

use std::sync::OnceLock;

use ssis::calib::store::{self, CalibFlash, RamFlash};
use ssis::calib::CalibrationTable;
use ssis::flight::{FlightCore, Profile};
use ssis::frames::telecommand::{Telecommand, CRC32C, CRC_COVERED_LEN, FRAME_LEN};
use ssis::frames::{Frame, SYNC};
use ssis::telecommand::auth::{seal, Key};
use ssis::telecommand::{CommandLink, Outcome};

const KEY: Key = Key { id: 1, bytes: [0x42; 32] };

fn fix(frame: &mut [u8], mode: u8) {
    if mode & 1 != 0 && frame.len() >= 3 {
        frame[..2].copy_from_slice(&SYNC);
        frame[2] = Telecommand::KIND;
    }
    if frame.len() < FRAME_LEN {
        return;
    }
    if mode & 4 != 0 {
        // Seal what the fields say (if they decode at all once the CRC is right).
        let crc = CRC32C.checksum(&frame[..CRC_COVERED_LEN]);
        frame[CRC_COVERED_LEN..FRAME_LEN].copy_from_slice(&crc.to_le_bytes());
        if let Ok(tc) = Telecommand::decode(&frame[..FRAME_LEN]) {
            frame[..FRAME_LEN].copy_from_slice(&seal(&KEY, tc).to_bytes());
        }
    }
    if mode & 2 != 0 {
        let crc = CRC32C.checksum(&frame[..CRC_COVERED_LEN]);
        frame[CRC_COVERED_LEN..FRAME_LEN].copy_from_slice(&crc.to_le_bytes());
    }
}

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    let Some((&mode, rest)) = data.split_first() else { return };
    let mut bytes = rest.to_vec();
    for frame in bytes.chunks_mut(FRAME_LEN) {
        fix(frame, mode);
    }
    if let Ok(tc) = Telecommand::decode(&bytes) {
        assert_eq!(tc.to_bytes().as_slice(), bytes.as_slice(), "decode accepted bytes its encoder would not send");
    }
    let old = CalibrationTable { revision: 1, ..CalibrationTable::DEFAULT };
    // The unit as it boots, built once (a flight core takes milliseconds to build).
    static UNIT: OnceLock<(FlightCore, RamFlash, CommandLink)> = OnceLock::new();
    let (core, flash, link) = UNIT.get_or_init(|| {
        let core = FlightCore::new(Profile::SPACECRAFT, &old, false).expect("the default table flies");
        (core, RamFlash::new(&store::image(&old)), CommandLink::new(&KEY.to_record()))
    });
    let (mut core, mut flash, mut link) = (core.clone(), flash.clone(), link.clone());
    let piece = usize::from(mode >> 3) + 1;
    let mut activated = 0;
    for p in bytes.chunks(piece) {
        link.receive(p, &mut core, &mut flash, |o| {
            if o == (Outcome::Accepted { activated: true }) {
                activated += 1;
            }
        });
        let _ = link.take_report();
    }
    let loaded = store::load(flash.region());
    assert!(
        loaded.table == old || loaded.table == *core.table(),
        "the store holds a table the unit neither had nor flies"
    );
    if activated == 0 {
        assert_eq!(*core.table(), old);
    } else {
        assert!(core.table().revision > old.revision);
        assert_eq!(loaded.table, *core.table());
    }
});
