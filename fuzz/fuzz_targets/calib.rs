//! Fuzz target: the calibration table's binary parse and the two-copy store's loader.
//!
//! The first byte chooses fix-ups so that the fuzzer reaches the checks behind the CRCs:
//! bit 0 writes a valid table header and CRC-32 over the first `TABLE_LEN` bytes; bit 1
//! does the same for a table inside a record and the record's header and CRC-32. Whatever
//! is accepted must pass `validate` and survive a round trip.
#![no_main]

use ssis::calib::binary::{self, CRC32, FORMAT_VERSION, MAGIC, PAYLOAD_LEN, TABLE_LEN};
use ssis::calib::store::{self, RECORD_HEADER_LEN, RECORD_LEN, RECORD_MAGIC, RECORD_VERSION};

fn fix_table(t: &mut [u8]) {
    t[..4].copy_from_slice(&MAGIC);
    t[4..6].copy_from_slice(&FORMAT_VERSION.to_le_bytes());
    t[6..8].copy_from_slice(&(PAYLOAD_LEN as u16).to_le_bytes());
    let crc = CRC32.checksum(&t[..TABLE_LEN - 4]);
    t[TABLE_LEN - 4..TABLE_LEN].copy_from_slice(&crc.to_le_bytes());
}

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    let Some((&mode, rest)) = data.split_first() else { return };
    let mut bytes = rest.to_vec();
    if mode & 1 != 0 && bytes.len() >= TABLE_LEN {
        fix_table(&mut bytes);
    }
    if mode & 2 != 0 && bytes.len() >= RECORD_LEN {
        bytes[..4].copy_from_slice(&RECORD_MAGIC);
        bytes[4..6].copy_from_slice(&RECORD_VERSION.to_le_bytes());
        bytes[6..8].copy_from_slice(&(TABLE_LEN as u16).to_le_bytes());
        fix_table(&mut bytes[RECORD_HEADER_LEN..]);
        let crc = CRC32.checksum(&bytes[..RECORD_LEN - 4]);
        bytes[RECORD_LEN - 4..RECORD_LEN].copy_from_slice(&crc.to_le_bytes());
    }
    if let Ok(t) = binary::decode(&bytes) {
        assert_eq!(t.validate(), Ok(()));
        assert_eq!(binary::decode(&binary::encode(&t)), Ok(t));
    }
    if let Ok((t, g)) = store::decode_record(&bytes) {
        assert_eq!(t.validate(), Ok(()));
        assert!(g >= 1);
        assert_eq!(store::decode_record(&store::encode_record(&t, g)), Ok((t, g)));
    }
    let l = store::load(&bytes);
    match l.source {
        store::Source::Stored(slot) => {
            assert_eq!(store::decode_slot(&bytes, slot), Ok((l.table, l.generation)));
            assert_eq!(l.slot_errors[usize::from(slot == store::Slot::B)], None);
        }
        store::Source::Default => {
            assert!(l.slot_errors.iter().all(Option::is_some));
            assert_eq!(l.table, ssis::calib::CalibrationTable::DEFAULT);
        }
    }
});
