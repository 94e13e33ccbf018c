//! Calibration table: binary and TOML forms round-trip; every corruption is refused;
//! host tools name the file, line and field and never overwrite good data.

use proptest::prelude::*;
use ssis::calib::binary::{decode, encode, TABLE_LEN};
use ssis::calib::{CalibrationTable, Estimator, Field, FieldError, FogTerm, ObserverGains, TableError};
use ssis_common::table;

fn sample_table() -> CalibrationTable {
    let mut t = CalibrationTable::DEFAULT;
    t.revision = 42;
    t.fog[0].bias_rad_s = 1.5e-6;
    t.fog[1].scale_factor_error = -2e-5;
    t.fog[2].thermal_t_rad_s = [1e-8, -2e-10, 3e-12];
    t.fog[3].thermal_g_rad_s_per_degc_s = 4e-6;
    t.fog[3].thermal_tg_rad_s_per_degc2_s = -1e-7;
    t.misalignment.d42_rad = 1e-4;
    t.misalignment.d13_rad = -3e-5;
    t.st_mount_q = [0.5f64.sqrt(), 0.0, 0.5f64.sqrt(), 0.0];
    t.observer.gains_override = Some(ObserverGains::critically_damped(60.0, 0.25));
    t.observer.estimator = Estimator::Mekf;
    t.observer.initial_drift_sigma_deg_h = 0.5;
    t.observer.acquisition_s = 720.0;
    t
}

#[test]
fn binary_round_trip() {
    let t = sample_table();
    let b = encode(&t);
    assert_eq!(b.len(), TABLE_LEN);
    assert_eq!(decode(&b), Ok(t));
    assert_eq!(decode(&encode(&CalibrationTable::DEFAULT)), Ok(CalibrationTable::DEFAULT));
}

#[test]
fn an_estimator_code_this_format_does_not_define_is_refused() {
    let mut b = encode(&sample_table());
    assert_eq!(b[477], Estimator::Mekf.code());
    for code in [2u8, 0x80, 0xFF] {
        b[477] = code;
        let crc = ssis::calib::binary::CRC32.checksum(&b[..TABLE_LEN - 4]);
        b[TABLE_LEN - 4..].copy_from_slice(&crc.to_le_bytes());
        assert_eq!(decode(&b), Err(TableError::BadFlags), "estimator code {code}");
    }
}

#[test]
fn a_toml_table_without_the_estimator_fields_flies_the_observer() {
    let text = table::to_toml(&CalibrationTable::DEFAULT).expect("toml");
    let old: String = text
        .lines()
        .filter(|l| !l.starts_with("estimator") && !l.starts_with("initial_drift_sigma_deg_h"))
        .map(|l| format!("{l}\n"))
        .collect();
    assert_ne!(old, text, "the TOML names the new fields");
    let t = table::parse_toml(&old, "mem").expect("parse");
    assert_eq!(t.observer.estimator, Estimator::Luenberger);
    assert_eq!(t.observer.initial_drift_sigma_deg_h, 0.1);
}

#[test]
fn a_toml_table_without_the_acquisition_time_flies_its_override_throughout() {
    let mut t = CalibrationTable::DEFAULT;
    t.observer.gains_override = Some(ObserverGains::critically_damped(60.0, 0.25));
    let text = table::to_toml(&t).expect("toml");
    let old: String = text.lines().filter(|l| !l.starts_with("acquisition_s")).map(|l| format!("{l}\n")).collect();
    assert_ne!(old, text, "the TOML names the acquisition time");
    assert_eq!(table::parse_toml(&old, "mem").expect("parse"), t);
    assert_eq!(t.observer.acquisition_s, 0.0);
}

#[test]
fn an_acquisition_time_outside_0_to_7200_s_is_refused() {
    for v in [-1.0, 7200.5, f64::NAN, f64::INFINITY] {
        let mut t = sample_table();
        t.observer.acquisition_s = v;
        assert_eq!(t.validate(), Err(TableError::Field(FieldError::new(Field::Acquisition, v))), "acquisition_s = {v}");
    }
}

#[test]
fn toml_round_trip() {
    let t = sample_table();
    let text = table::to_toml(&t).expect("toml");
    assert!(text.starts_with("format = \"ssis-calibration-table/1\""), "{text}");
    assert_eq!(table::parse_toml(&text, "mem").expect("parse"), t);
}

#[test]
fn every_single_and_double_bit_flip_is_refused() {
    let b = encode(&sample_table());
    let bits = TABLE_LEN * 8;
    for i in 0..bits {
        let mut c = b;
        c[i / 8] ^= 1 << (i % 8);
        assert!(decode(&c).is_err(), "single flip {i} accepted");
    }
    // All double flips within the first 96 bytes and a stride over the rest (the CRC-32
    // detects every 2-bit error at this length; the stride keeps the test fast).
    for i in (0..bits).step_by(7) {
        for j in (i + 1..bits).step_by(13) {
            let mut c = b;
            c[i / 8] ^= 1 << (i % 8);
            c[j / 8] ^= 1 << (j % 8);
            assert!(decode(&c).is_err(), "double flip {i},{j} accepted");
        }
    }
}

#[test]
fn every_truncation_is_refused() {
    let b = encode(&sample_table());
    for n in 0..TABLE_LEN {
        assert_eq!(decode(&b[..n]), Err(TableError::Truncated), "truncation to {n}");
    }
}

#[test]
fn invalid_values_refused_even_with_good_crc() {
    let mut t = sample_table();
    t.fog[1].bias_rad_s = f64::NAN;
    let mut buf = [0u8; TABLE_LEN];
    // encode_into does not validate (a lab may want to see a bad table), decode does.
    ssis::calib::binary::encode_into(&t, &mut buf).expect("encode");
    assert_eq!(decode(&buf), Err(TableError::Field(FieldError::new(Field::Fog(1, FogTerm::Bias), f64::NAN))));
    let mut t = sample_table();
    t.misalignment.d21_rad = 0.2;
    ssis::calib::binary::encode_into(&t, &mut buf).expect("encode");
    assert_eq!(decode(&buf), Err(TableError::Field(FieldError::new(Field::D21, 0.2))));
    // γ (FOG4's angle) NaN or infinite: a NaN passes every `>` range test, so it needs
    // its own check (the calib fuzz target found a table with γ = NaN accepted).
    for g in [f64::NAN, f64::INFINITY, f64::NEG_INFINITY] {
        let mut t = sample_table();
        t.gamma_rad = g;
        ssis::calib::binary::encode_into(&t, &mut buf).expect("encode");
        assert_eq!(decode(&buf), Err(TableError::Field(FieldError::new(Field::Gamma, g))), "gamma {g}");
    }
}

#[test]
fn toml_errors_name_line_and_field() {
    let text = table::to_toml(&sample_table()).expect("toml");
    let broken = text.replacen("revision = 42", "revision = \"forty-two\"", 1);
    let e = table::parse_toml(&broken, "cal.toml").expect_err("refused").to_string();
    assert!(e.contains("cal.toml") && e.contains("line") && e.contains("revision"), "{e}");
    let unknown = text.replacen("revision = 42", "revision = 42\nrevison_typo = 1", 1);
    let e = table::parse_toml(&unknown, "cal.toml").expect_err("refused").to_string();
    assert!(e.contains("revison_typo"), "{e}");
    let wrong_format = text.replacen("ssis-calibration-table/1", "ssis-calibration-table/9", 1);
    let e = table::parse_toml(&wrong_format, "cal.toml").expect_err("refused").to_string();
    assert!(e.contains("format"), "{e}");
}

#[test]
fn a_refused_table_never_overwrites_good_data() {
    let dir = std::env::temp_dir().join(format!("ssis-table-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("dir");
    let path = dir.join("cal.bin");
    table::write_binary(&path, &sample_table()).expect("write");
    let good = std::fs::read(&path).expect("read");
    let mut bad = sample_table();
    bad.fog[0].scale_factor_error = f64::INFINITY;
    assert!(table::write_binary(&path, &bad).is_err());
    assert_eq!(std::fs::read(&path).expect("read"), good);
    assert_eq!(table::read_binary(&path).expect("decode"), sample_table());
    std::fs::remove_dir_all(&dir).ok();
}

/// A caller can tell the kinds of refusal apart without reading the message: the file that
/// is not there, the format of another version, a field out of range (which field), a
/// refused write; each message still names the file.
#[test]
fn table_file_errors_say_their_kind() {
    use ssis_common::table::TableFileError;
    let dir = std::env::temp_dir().join(format!("ssis-table-kinds-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("dir");
    match table::read_toml(&dir.join("none.toml")) {
        Err(TableFileError::Io { path, source }) => {
            assert!(path.ends_with("none.toml"), "{path}");
            assert_eq!(source.kind(), std::io::ErrorKind::NotFound);
        }
        other => panic!("{other:?}"),
    }
    let text = table::to_toml(&sample_table()).expect("toml");
    let wrong_format = text.replacen("ssis-calibration-table/1", "ssis-calibration-table/9", 1);
    match table::parse_toml(&wrong_format, "cal.toml") {
        Err(TableFileError::Format { origin, found }) => {
            assert_eq!((origin.as_str(), found.as_str()), ("cal.toml", "ssis-calibration-table/9"));
        }
        other => panic!("{other:?}"),
    }
    let mut bad = sample_table();
    bad.fog[2].bias_rad_s = f64::NAN;
    let path = dir.join("bad.toml");
    std::fs::write(&path, table::to_toml(&bad).expect("toml")).expect("written");
    match table::read_toml(&path) {
        Err(e @ TableFileError::Refused { reason: TableError::Field(f), .. }) => {
            assert_eq!(f.field, Field::Fog(2, FogTerm::Bias), "{e}");
            assert!(e.to_string().contains("bad.toml"), "{e}");
        }
        other => panic!("{other:?}"),
    }
    assert!(matches!(
        table::write_binary(&dir.join("b.bin"), &bad),
        Err(TableFileError::Refused { origin: None, reason: TableError::Field(_) })
    ));
    std::fs::remove_dir_all(&dir).ok();
}

proptest! {
    #[test]
    fn random_bytes_never_decode_as_a_table(bytes in proptest::collection::vec(any::<u8>(), 0..600)) {
        // Random data essentially never carries the magic and a matching CRC.
        if let Ok(t) = decode(&bytes) {
            prop_assert!(t.validate().is_ok());
        }
    }
}

/// The value at a field's path (`fog[0].thermal_t_rad_s[1]`) under `[table]` of a TOML form.
fn toml_value_at(doc: &toml::Value, path: &str) -> Option<f64> {
    let mut v = doc.get("table")?;
    for part in path.split('.') {
        let (key, idx) = match part.split_once('[') {
            Some((k, rest)) => (k, Some(rest.trim_end_matches(']').parse::<usize>().ok()?)),
            None => (part, None),
        };
        v = v.get(key)?;
        if let Some(i) = idx {
            v = v.get(i)?;
        }
    }
    v.as_float()
}

#[test]
fn every_field_in_storage_order_with_its_toml_name() {
    let t = sample_table();
    let stored = ssis::calib::binary::fields(&t);
    let doc: toml::Value = toml::from_str(&table::to_toml(&t).expect("toml")).expect("parses");
    let all: Vec<Field> = Field::all().collect();
    // The star tracker's two LFE figures ride in the gain override's first two slots
    // (flag bit 1): the last two fields, after the storage order.
    let (slots, lfe) = all.split_at(stored.len());
    assert_eq!(lfe.len(), 2);
    for f in lfe {
        assert!(toml_value_at(&doc, &f.to_string()).is_some(), "{f} in the TOML form");
        let mut u = t;
        f.set(&mut u, 0.25);
        assert_eq!(f.get(&u), 0.25, "{f}");
    }
    for (k, f) in slots.iter().enumerate() {
        assert_eq!(f.get(&t).to_bits(), stored[k].to_bits(), "{f} is not storage slot {k}");
        assert_eq!(toml_value_at(&doc, &f.to_string()).map(f64::to_bits), Some(stored[k].to_bits()), "{f}");
        // Setting it changes that slot only.
        let mut u = t;
        f.set(&mut u, 0.123);
        let after = ssis::calib::binary::fields(&u);
        for (j, (a, b)) in stored.iter().zip(after).enumerate() {
            assert_eq!(a.to_bits() == b.to_bits(), j != k, "setting {f} changed slot {j}");
        }
        // The nominal table is inside every range.
        assert!(f.spec().admits(f.get(&CalibrationTable::DEFAULT)) || f.is_gain(), "{f}");
    }
}

#[test]
fn implausible_values_are_refused_naming_field_value_and_range() {
    // The turntable run read as noise: ARW 0.48 °/√h and RRW 53,954 °/h/√h.
    for (field, v, must) in [
        (Field::Arw, 0.48, ["observer.arw_deg_sqrt_h", "0.48", "0.0005 … 0.05 °/√h"]),
        (Field::Rrw, 53_954.0, ["observer.rrw_deg_h_sqrt_h", "53954", "0.0001 … 0.1 °/h/√h"]),
        (Field::Fog(2, FogTerm::Bias), 1e-3, ["fog[2].bias_rad_s", "206.26", "-100 … 100 °/h"]),
    ] {
        let mut t = sample_table();
        field.set(&mut t, v);
        let e = t.validate().expect_err("refused");
        assert_eq!(e, TableError::Field(FieldError::new(field, v)));
        let text = e.to_string();
        for m in must {
            assert!(text.contains(m), "`{text}` lacks `{m}`");
        }
        // Writing it is refused too, with the same words.
        let w = table::to_toml(&t).map(|s| table::parse_toml(&s, "x.toml"));
        let msg = format!("{:#}", w.expect("serialises").expect_err("refused on read"));
        assert!(msg.contains("x.toml") && msg.contains(&field.to_string()), "{msg}");
    }
}
