//! Calibration table integrity: the two-copy store of the table's flash
//! region. Every 1- and 2-bit flip and every truncation of a stored record, and of the bare
//! binary table inside it, is refused; a bad copy falls back to the other, then to the
//! flagged default table; an update switches atomically at every byte of its write.

use ssis::calib::binary::{self, TABLE_LEN};
use ssis::calib::store::{
    self, decode_record, encode_record, load, prepare_update, Slot, Source, StoreError, RECORD_LEN, REGION_LEN,
    SLOT_STRIDE,
};
use ssis::calib::{CalibrationTable, Field, FieldError, FogTerm, ObserverGains, TableError};

fn sample_table() -> CalibrationTable {
    let mut t = CalibrationTable::DEFAULT;
    t.revision = 42;
    t.fog[0].bias_rad_s = 1.5e-6;
    t.fog[1].scale_factor_error = -2e-5;
    t.fog[2].thermal_t_rad_s = [1e-8, -2e-10, 3e-12];
    t.fog[3].thermal_g_rad_s_per_degc_s = 4e-6;
    t.misalignment.d42_rad = 1e-4;
    t.st_mount_q = [0.5f64.sqrt(), 0.0, 0.5f64.sqrt(), 0.0];
    t.observer.gains_override = Some(ObserverGains::critically_damped(60.0, 0.25));
    t
}

fn other_table() -> CalibrationTable {
    let mut t = sample_table();
    t.revision = 43;
    t.fog[0].bias_rad_s = -2.5e-6;
    t.misalignment.d13_rad = 7e-5;
    t
}

fn flip(buf: &mut [u8], bit: usize) {
    buf[bit / 8] ^= 1 << (bit % 8);
}

/// Every pair of distinct bits of `good` flipped, `check` called on each corrupted copy
/// (split over two threads); returns the number of pairs tried.
fn every_double_flip(good: &[u8], check: impl Fn(&[u8]) -> bool + Sync) -> u64 {
    let bits = good.len() * 8;
    let tried = std::sync::atomic::AtomicU64::new(0);
    std::thread::scope(|s| {
        for part in 0..2 {
            let (check, tried) = (&check, &tried);
            s.spawn(move || {
                let mut c = good.to_vec();
                let mut n = 0u64;
                // Rows interleaved so both threads get about the same number of pairs.
                for i in (part..bits).step_by(2) {
                    flip(&mut c, i);
                    for j in i + 1..bits {
                        flip(&mut c, j);
                        assert!(check(&c), "double flip {i},{j} accepted");
                        flip(&mut c, j);
                        n += 1;
                    }
                    flip(&mut c, i);
                }
                tried.fetch_add(n, std::sync::atomic::Ordering::Relaxed);
            });
        }
    });
    tried.into_inner()
}

#[test]
fn record_round_trip_and_image() {
    let t = sample_table();
    let r = encode_record(&t, 7);
    assert_eq!(RECORD_LEN, 500);
    assert_eq!(decode_record(&r), Ok((t, 7)));
    let img = store::image(&t);
    assert_eq!(img.len(), REGION_LEN);
    let l = load(&img);
    assert_eq!((l.table, l.source, l.generation, l.slot_errors), (t, Source::Stored(Slot::A), 1, [None, None]));
    assert!(!l.defaulted());
    // Erased flash past the records.
    assert!(img[RECORD_LEN..SLOT_STRIDE].iter().all(|&b| b == 0xFF));
    assert!(img[SLOT_STRIDE + RECORD_LEN..].iter().all(|&b| b == 0xFF));
}

#[test]
fn every_single_bit_flip_of_a_record_is_refused() {
    let r = encode_record(&sample_table(), 1);
    let mut c = r;
    for i in 0..RECORD_LEN * 8 {
        flip(&mut c, i);
        assert!(decode_record(&c).is_err(), "flip {i} accepted");
        flip(&mut c, i);
    }
}

#[test]
fn every_double_bit_flip_of_a_record_is_refused() {
    let r = encode_record(&sample_table(), 1);
    let t0 = std::time::Instant::now();
    let n = every_double_flip(&r, |c| decode_record(c).is_err());
    let bits = (RECORD_LEN * 8) as u64;
    assert_eq!(n, bits * (bits - 1) / 2);
    eprintln!("{n} double flips of a {RECORD_LEN}-byte record refused in {:.1} s", t0.elapsed().as_secs_f64());
}

#[test]
fn every_double_bit_flip_of_the_bare_table_is_refused() {
    let b = binary::encode(&sample_table());
    let t0 = std::time::Instant::now();
    let n = every_double_flip(&b, |c| binary::decode(c).is_err());
    let bits = (TABLE_LEN * 8) as u64;
    assert_eq!(n, bits * (bits - 1) / 2);
    eprintln!("{n} double flips of the {TABLE_LEN}-byte table refused in {:.1} s", t0.elapsed().as_secs_f64());
}

#[test]
fn every_truncation_of_a_record_is_refused() {
    let r = encode_record(&sample_table(), 1);
    for n in 0..RECORD_LEN {
        assert_eq!(decode_record(&r[..n]), Err(StoreError::Truncated), "truncation to {n}");
    }
    // Bytes after the record are not read.
    let mut longer = r.to_vec();
    longer.extend_from_slice(&[0xA5; 9]);
    assert_eq!(decode_record(&longer), Ok((sample_table(), 1)));
}

#[test]
fn every_truncation_of_the_region_falls_back_or_defaults() {
    let t = sample_table();
    let img = store::image(&t);
    for n in 0..=REGION_LEN {
        let l = load(&img[..n]);
        if n < RECORD_LEN {
            assert!(l.defaulted(), "{n}");
            assert_eq!(l.table, CalibrationTable::DEFAULT);
            assert_eq!(l.slot_errors, [Some(StoreError::Truncated); 2]);
        } else if n < SLOT_STRIDE + RECORD_LEN {
            assert_eq!((l.table, l.source), (t, Source::Stored(Slot::A)), "{n}");
            assert_eq!(l.slot_errors, [None, Some(StoreError::Truncated)]);
        } else {
            assert_eq!((l.table, l.source, l.bad_copies()), (t, Source::Stored(Slot::A), 0), "{n}");
        }
    }
}

#[test]
fn every_single_bit_flip_of_the_region_still_loads_the_table() {
    let t = sample_table();
    let img = store::image(&t);
    let mut c = img;
    for i in 0..REGION_LEN * 8 {
        flip(&mut c, i);
        let l = load(&c);
        assert_eq!(l.table, t, "flip {i}");
        let byte = i / 8;
        let in_a = byte < RECORD_LEN;
        let in_b = (SLOT_STRIDE..SLOT_STRIDE + RECORD_LEN).contains(&byte);
        let expected = if in_a { Source::Stored(Slot::B) } else { Source::Stored(Slot::A) };
        assert_eq!(l.source, expected, "flip {i}");
        assert_eq!(l.bad_copies(), u32::from(in_a || in_b), "flip {i}");
        flip(&mut c, i);
    }
}

#[test]
fn one_flip_in_each_copy_gives_the_flagged_default() {
    let img = store::image(&sample_table());
    let bits = RECORD_LEN * 8;
    let mut c = img;
    let mut n = 0;
    for i in (0..bits).step_by(5) {
        flip(&mut c, i);
        for j in (0..bits).step_by(11) {
            let jb = SLOT_STRIDE * 8 + j;
            flip(&mut c, jb);
            let l = load(&c);
            assert!(l.defaulted() && l.table == CalibrationTable::DEFAULT && l.bad_copies() == 2, "{i},{j}");
            flip(&mut c, jb);
            n += 1;
        }
        flip(&mut c, i);
    }
    assert!(n > 50_000);
}

#[test]
fn fallback_order() {
    let (old, new) = (sample_table(), other_table());
    let erased = [0xFFu8; REGION_LEN];
    let l = load(&erased);
    assert!(l.defaulted());
    assert_eq!(l.slot_errors, [Some(StoreError::BadMagic); 2]);
    let mut region = erased;
    region[SLOT_STRIDE..SLOT_STRIDE + RECORD_LEN].copy_from_slice(&encode_record(&old, 5));
    assert_eq!((load(&region).table, load(&region).source), (old, Source::Stored(Slot::B)));
    region[..RECORD_LEN].copy_from_slice(&encode_record(&new, 6));
    assert_eq!((load(&region).table, load(&region).generation), (new, 6));
    // The newer copy damaged: the older one flies.
    region[100] ^= 0x10;
    let l = load(&region);
    assert_eq!((l.table, l.source, l.slot_errors[0]), (old, Source::Stored(Slot::B), Some(StoreError::BadCrc)));
    // An intact record around a refused table (NaN) is refused by the table's checks.
    let mut bad = new;
    bad.fog[2].bias_rad_s = f64::NAN;
    region[..RECORD_LEN].copy_from_slice(&encode_record(&bad, 9));
    let l = load(&region);
    assert_eq!(
        (l.table, l.slot_errors[0]),
        (old, Some(StoreError::Table(TableError::Field(FieldError::new(Field::Fog(2, FogTerm::Bias), f64::NAN)))))
    );
    // Generation 0 is never written and never accepted.
    region[..RECORD_LEN].copy_from_slice(&encode_record(&new, 0));
    assert_eq!(load(&region).slot_errors[0], Some(StoreError::BadGeneration));
}

/// Writes `record` into `slot` of `region` one byte at a time; after every byte (a power
/// loss there) `check` sees the region. `rest` is what the slot held beyond the written
/// bytes (the old record, or erased flash).
fn write_with_power_loss(
    region: &mut [u8; REGION_LEN],
    slot: Slot,
    record: &[u8; RECORD_LEN],
    mut check: impl FnMut(usize, &[u8]),
) {
    let at = slot.offset();
    for k in 0..RECORD_LEN {
        region[at + k] = record[k];
        check(k + 1, region);
    }
}

#[test]
fn an_update_switches_atomically_at_every_byte() {
    let (old, new) = (sample_table(), other_table());
    for erase_first in [false, true] {
        let mut region = store::image(&old);
        // First write: the slot not holding the active copy, newer generation.
        let u = prepare_update(&region, &new).expect("update");
        assert_eq!((u.slot, u.generation), (Slot::B, 2));
        if erase_first {
            region[SLOT_STRIDE..].fill(0xFF);
            assert_eq!(load(&region).table, old);
        }
        write_with_power_loss(&mut region, u.slot, &u.record, |k, r| {
            let l = load(r);
            let want = if k == RECORD_LEN { new } else { old };
            assert_eq!(l.table, want, "first write, power lost after {k} bytes");
            assert!(!l.defaulted());
        });
        // Second write restores two copies of the new table.
        let u2 = prepare_update(&region, &new).expect("update");
        assert_eq!((u2.slot, u2.generation), (Slot::A, 3));
        if erase_first {
            region[..SLOT_STRIDE].fill(0xFF);
        }
        write_with_power_loss(&mut region, u2.slot, &u2.record, |k, r| {
            assert_eq!(load(r).table, new, "second write, power lost after {k} bytes");
        });
        let l = load(&region);
        assert_eq!((l.table, l.source, l.generation, l.bad_copies()), (new, Source::Stored(Slot::A), 3, 0));
    }
}

#[test]
fn an_invalid_table_is_never_prepared() {
    let region = store::image(&sample_table());
    let mut bad = other_table();
    bad.fog[1].scale_factor_error = f64::INFINITY;
    let refused = |f: Field, v: f64| Err(StoreError::Table(TableError::Field(FieldError::new(f, v))));
    assert_eq!(prepare_update(&region, &bad), refused(Field::Fog(1, FogTerm::ScaleFactor), f64::INFINITY));
    bad = other_table();
    bad.misalignment.d21_rad = 0.3;
    assert_eq!(prepare_update(&region, &bad), refused(Field::D21, 0.3));
    // On an empty region the first table goes to slot A, generation 1.
    let u = prepare_update(&[0xFF; REGION_LEN], &other_table()).expect("update");
    assert_eq!((u.slot, u.generation), (Slot::A, 1));
    // The generation does not wrap.
    let mut region = [0xFFu8; REGION_LEN];
    region[..RECORD_LEN].copy_from_slice(&encode_record(&sample_table(), u32::MAX));
    assert_eq!(prepare_update(&region, &other_table()), Err(StoreError::GenerationExhausted));
}
