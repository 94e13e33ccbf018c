//! Frames: round trips, field checks, the CRC, the layouts at the ICD's offsets and the
//! ICD's example frames.

use proptest::prelude::*;
use ssis::frames::event::EventFrame;
use ssis::frames::fog::{self, FogFrame};
use ssis::frames::output::{self, OutputCounters, OutputFrame};
use ssis::frames::star::{self, StarFrame};
use ssis::frames::{body_crc, header_crc, kind, DecodeError, EncodeError, Frame, CRC32C, SYNC};
use ssis::telemetry::events::{Event, EventRecord};

mod frames_common;
use frames_common::*;

// ---------------------------------------------------------------------------------------
// CRC, lengths, envelope

#[test]
fn crc_check_value() {
    assert_eq!(CRC32C.checksum(b"123456789"), 0xE306_9283);
    // The flight tables from the register's initial value, as if there were no header.
    assert_eq!(body_crc(0xFFFF_FFFF, b"123456789"), 0xE306_9283);
}

#[test]
fn lengths_and_kinds() {
    assert_eq!((FogFrame::LEN, <FogFrame as Frame>::LEN, <FogFrame as Frame>::KIND), (18, 18, 0x10));
    assert_eq!((StarFrame::LEN, <StarFrame as Frame>::LEN, <StarFrame as Frame>::KIND), (34, 34, 0x20));
    assert_eq!((OutputFrame::LEN, <OutputFrame as Frame>::LEN, <OutputFrame as Frame>::KIND), (97, 97, 0x30));
    assert_eq!([kind::FOG, kind::STAR, kind::OUTPUT], [0x10, 0x20, 0x30]);
}

#[test]
fn encode_into_checks_the_buffer() {
    let f = FogFrame::from_physical(1, 2, 0, 1e-6, 20.0);
    let mut small = [0u8; 17];
    assert_eq!(f.encode_into(&mut small), Err(EncodeError::BufferTooSmall));
    let mut big = [0xAAu8; 22];
    assert_eq!(f.encode_into(&mut big), Ok(18));
    assert_eq!(&big[..18], &f.to_bytes());
    assert_eq!(&big[18..], &[0xAA; 4]);
}

#[test]
fn decode_checks_length_sync_kind_crc() {
    let b = FogFrame::from_physical(1, 2, 0, 1e-6, 20.0).to_bytes();
    assert_eq!(FogFrame::decode(&b[..17]), Err(DecodeError::BadLength));
    let mut long = b.to_vec();
    long.push(0);
    assert_eq!(FogFrame::decode(&long), Err(DecodeError::BadLength));
    let mut s = b;
    s[1] = 0x91;
    reseal(&mut s);
    assert_eq!(FogFrame::decode(&s), Err(DecodeError::BadSync));
    let mut k = b;
    k[2] = kind::STAR;
    reseal(&mut k);
    assert_eq!(FogFrame::decode(&k), Err(DecodeError::BadKind));
    let mut c = b;
    c[8] ^= 0x04;
    assert_eq!(FogFrame::decode(&c), Err(DecodeError::BadCrc));
    let mut c2 = b;
    c2[17] ^= 0x80;
    assert_eq!(FogFrame::decode(&c2), Err(DecodeError::BadCrc));
    // The CRC is little-endian over bytes 0..14.
    assert_eq!(u32::from_le_bytes([b[14], b[15], b[16], b[17]]), CRC32C.checksum(&b[..14]));
    assert_eq!(FogFrame::decode(&b).map(|f| f.to_bytes()), Ok(b));
}

/// The CRC-32C's Hamming distance at every frame length of the ICD: no error pattern of
/// 1 to d − 1 bits anywhere in the frame (data and CRC) leaves the CRC valid, d = 8 for
/// the 14 covered bytes of the FOG, accelerometer and control frames and d = 6 for the
/// others (docs/ICD.md, Common rules). The CRC is linear, so a pattern is undetected
/// exactly when the syndromes of its bits (the CRC change a single bit causes; a CRC
/// bit's own is itself) XOR to zero: 1 and 2 bits directly, 3 as a pair's XOR equal to a
/// single syndrome, 4 as two pairs with the same XOR, 5 as a triple's XOR equal to a
/// pair's, 6 as two triples with the same XOR, 7 as a quadruple's XOR equal to a
/// triple's (an overlap of the two sets is an error of lower weight, already excluded).
#[test]
fn hamming_distance_of_the_crc_at_every_frame_length() {
    use std::collections::HashSet;
    for (frames, covered, d) in [
        ("FOG, accelerometer, control", 14, 8),
        ("star tracker, command report", 30, 6),
        ("GNSS", 43, 6),
        ("navigation output", 62, 6),
        ("output", OutputFrame::LEN - 4, 6),
        ("event", EventFrame::LEN - 4, 6),
        ("telecommand", ssis::frames::telecommand::CRC_COVERED_LEN, 6),
    ] {
        let base = vec![0u8; covered];
        let c0 = CRC32C.checksum(&base);
        let mut h: Vec<u32> = (0..covered * 8)
            .map(|bit| {
                let mut b = base.clone();
                b[bit / 8] ^= 1 << (bit % 8);
                CRC32C.checksum(&b) ^ c0
            })
            .collect();
        h.extend((0..32).map(|j| 1u32 << j));
        let n = h.len();
        assert!(h.iter().all(|&x| x != 0), "{frames}: a 1-bit error is missed");
        let singles: HashSet<u32> = h.iter().copied().collect();
        assert_eq!(singles.len(), n, "{frames}: a 2-bit error is missed");
        let mut pairs: HashSet<u32> = HashSet::with_capacity(n * n / 2);
        for i in 0..n {
            for j in i + 1..n {
                let x = h[i] ^ h[j];
                assert!(!singles.contains(&x), "{frames}: a 3-bit error is missed ({i}, {j})");
                assert!(pairs.insert(x), "{frames}: a 4-bit error is missed ({i}, {j})");
            }
        }
        let mut triples: HashSet<u32> = HashSet::new();
        for i in 0..n {
            for j in i + 1..n {
                let x = h[i] ^ h[j];
                for hk in &h[j + 1..] {
                    let y = x ^ hk;
                    assert!(!pairs.contains(&y), "{frames}: a 5-bit error is missed ({i}, {j})");
                    if d > 6 {
                        assert!(triples.insert(y), "{frames}: a 6-bit error is missed ({i}, {j})");
                    }
                }
            }
        }
        if d > 7 {
            for i in 0..n {
                for j in i + 1..n {
                    for k in j + 1..n {
                        let x = h[i] ^ h[j] ^ h[k];
                        for hl in &h[k + 1..] {
                            assert!(!triples.contains(&(x ^ hl)), "{frames}: a 7-bit error is missed ({i}, {j}, {k})");
                        }
                    }
                }
            }
        }
        println!("{frames}: CRC-32C over {covered} bytes + CRC ({n} bits): every error of 1 to {} bits detected (Hamming distance >= {d})", d - 1);
    }
}

// ---------------------------------------------------------------------------------------
// FOG frame

#[test]
fn fog_layout_is_little_endian_at_the_icd_offsets() {
    let f = FogFrame { fog_id: 2, counter: 0xA1B2, status: 0x05, dtheta_counts: -2, temperature_counts: 0x0C0D };
    let b = f.to_bytes();
    assert_eq!(&b[..3], &[0xEB, 0x90, 0x10]);
    assert_eq!(b[3], 2);
    assert_eq!(&b[4..6], &[0xB2, 0xA1]);
    assert_eq!(b[6], 0x05);
    assert_eq!(&b[7..11], &[0xFE, 0xFF, 0xFF, 0xFF]);
    assert_eq!(&b[11..13], &[0x0D, 0x0C]);
    assert_eq!(b[13], 0);
    assert_eq!(FogFrame::decode(&b), Ok(f));
}

#[test]
fn fog_fields_out_of_range_are_rejected() {
    let good = FogFrame::from_physical(3, 7, fog::status::SELF_TEST, 1e-6, -40.0);
    assert!(FogFrame::decode(&good.to_bytes()).is_ok());
    let bad_id = FogFrame { fog_id: 4, ..good };
    assert_eq!(FogFrame::decode(&bad_id.to_bytes()), Err(DecodeError::BadField));
    for bit in 4..8 {
        let bad_status = FogFrame { status: 1 << bit, ..good };
        assert_eq!(FogFrame::decode(&bad_status.to_bytes()), Err(DecodeError::BadField));
    }
    let mut reserved = good.to_bytes();
    reserved[13] = 1;
    reseal(&mut reserved);
    assert_eq!(FogFrame::decode(&reserved), Err(DecodeError::BadField));
}

#[test]
fn fog_physical_scaling_rounds_and_saturates() {
    assert_eq!(FogFrame::DTHETA_LSB_RAD, 2f64.powi(-36));
    assert_eq!(FogFrame::TEMP_LSB_DEGC, 1.0 / 256.0);
    let lsb = FogFrame::DTHETA_LSB_RAD;
    let f = FogFrame::from_physical(0, 0, 0, 2.4 * lsb, 25.5);
    assert_eq!((f.dtheta_counts, f.temperature_counts), (2, 6528));
    assert_eq!(f.temperature_degc(), 25.5);
    assert_eq!(FogFrame::from_physical(0, 0, 0, -2.6 * lsb, -0.6 / 256.0).dtheta_counts, -3);
    assert_eq!(FogFrame::from_physical(0, 0, 0, 2.5 * lsb, 0.0).dtheta_counts, 3);
    let sat = FogFrame::from_physical(0, 0, 0, 1.0, 1000.0);
    assert_eq!((sat.dtheta_counts, sat.temperature_counts), (i32::MAX, i16::MAX));
    let sat = FogFrame::from_physical(0, 0, 0, f64::NEG_INFINITY, -1000.0);
    assert_eq!((sat.dtheta_counts, sat.temperature_counts), (i32::MIN, i16::MIN));
    let nan = FogFrame::from_physical(0, 0, 0, f64::NAN, f64::NAN);
    assert_eq!((nan.dtheta_counts, nan.temperature_counts), (0, 0));
    assert!(FogFrame::from_physical(0, 0, fog::status::LOOP_LOCK_LOST, 0.0, 0.0).device_fault());
    assert!(!FogFrame::from_physical(0, 0, fog::status::SELF_TEST, 0.0, 0.0).device_fault());
}

// ---------------------------------------------------------------------------------------
// Star-tracker frame

#[test]
fn star_layout_and_flags() {
    let f = StarFrame::from_physical(star::flags::VALID, 0x0102, 0x0807_0605_0403_0201, [0.5, -0.5, 0.5, -0.5]);
    let b = f.to_bytes();
    assert_eq!(&b[..6], &[0xEB, 0x90, 0x20, 0x01, 0x02, 0x01]);
    assert_eq!(&b[6..14], &[1, 2, 3, 4, 5, 6, 7, 8]);
    assert_eq!(&b[14..18], &0x4000_0000i32.to_le_bytes());
    assert_eq!(&b[18..22], &(-0x4000_0000i32).to_le_bytes());
    assert_eq!(u32::from_le_bytes(b[30..34].try_into().unwrap()), CRC32C.checksum(&b[..30]));
    let d = StarFrame::decode(&b).expect("decodes");
    assert_eq!(d, f);
    assert!(d.valid() && !d.high_rate());
    assert_eq!(d.quaternion(), [0.5, -0.5, 0.5, -0.5]);
    let hr = StarFrame { flags: star::flags::HIGH_RATE, ..f };
    assert!(!hr.valid() && hr.high_rate());
    for bit in 2..8 {
        let bad = StarFrame { flags: 1 << bit, ..f };
        assert_eq!(StarFrame::decode(&bad.to_bytes()), Err(DecodeError::BadField));
    }
}

#[test]
fn star_norm_check() {
    let one = 2f64.powi(31);
    let at = |n: f64| StarFrame { flags: 1, counter: 0, time_us: 0, q_counts: [(n * one).round() as i32, 0, 0, 0] };
    let split = |n: f64| {
        let c = (n * one / 2.0).round() as i32;
        StarFrame { flags: 1, counter: 0, time_us: 0, q_counts: [c, -c, c, -c] }
    };
    for n in [1.0 - 0.99e-6, 0.9999995, 0.999_999_999] {
        assert!(StarFrame::decode(&at(n).to_bytes()).is_ok(), "norm {n}");
    }
    for n in [1.0 - 1.01e-6, 0.5, 0.0] {
        assert_eq!(StarFrame::decode(&at(n).to_bytes()), Err(DecodeError::BadField), "norm {n}");
    }
    for n in [1.0 + 0.99e-6, 1.0 - 0.99e-6, 1.0] {
        assert!(StarFrame::decode(&split(n).to_bytes()).is_ok(), "norm {n}");
    }
    for n in [1.0 + 1.01e-6, 1.0 - 1.01e-6, 1.5] {
        assert_eq!(StarFrame::decode(&split(n).to_bytes()), Err(DecodeError::BadField), "norm {n}");
    }
    let big = StarFrame { flags: 0, counter: 0, time_us: 0, q_counts: [i32::MIN; 4] };
    assert_eq!(StarFrame::decode(&big.to_bytes()), Err(DecodeError::BadField));
    // +1 saturates to 1 − 2^-31 and is accepted.
    let id = StarFrame::from_physical(1, 0, 0, [1.0, 0.0, 0.0, 0.0]);
    assert_eq!(id.q_counts, [i32::MAX, 0, 0, 0]);
    assert!(StarFrame::decode(&id.to_bytes()).is_ok());
    let nan = StarFrame::from_physical(1, 0, 0, [f64::NAN, 1.0, 0.0, -1.0]);
    assert_eq!(nan.q_counts, [0, i32::MAX, 0, i32::MIN]); // −1 is exact
    assert!(star::norm_ok(&[0, 0, i32::MAX, 0]));
}

// ---------------------------------------------------------------------------------------
// Output frame

#[test]
fn output_layout_offsets() {
    let f = OutputFrame {
        flags: 0x1F,
        counter: 0x0102,
        time_us: 0x1112_1314_1516_1718,
        q_counts: [0x21, 0x22, 0x23, 0x24],
        rate_counts: [0x31, 0x32, 0x33],
        drift_counts: [0x41, 0x42, 0x43],
        parity_counts: 0x51,
        fog_health: [0x61, 0x62, 0x63, 0x64],
        st_status: 0x71,
        counters: OutputCounters::from_array([0x81, 0x82, 0x83, 0x84, 0x85, 0x86, 0x87]),
        fdi: 0x91,
        page_id: 0x92,
        page_value: 0x9394,
        att_sigma_counts: [0xA1, 0xA2, 0xA3],
        drift_sigma_counts: [0xB1, 0xB2, 0xB3],
    };
    let b = f.to_bytes();
    assert_eq!(b.len(), 97);
    assert_eq!(&b[..6], &[0xEB, 0x90, 0x30, 0x1F, 0x02, 0x01]);
    assert_eq!(&b[6..14], &0x1112_1314_1516_1718u64.to_le_bytes());
    let word = |off: usize| i32::from_le_bytes(b[off..off + 4].try_into().unwrap());
    assert_eq!([14, 18, 22, 26].map(word), [0x21, 0x22, 0x23, 0x24]);
    assert_eq!([30, 34, 38].map(word), [0x31, 0x32, 0x33]);
    assert_eq!([42, 46, 50].map(word), [0x41, 0x42, 0x43]);
    assert_eq!(word(54), 0x51);
    assert_eq!(&b[58..63], &[0x61, 0x62, 0x63, 0x64, 0x71]);
    let half = |off: usize| u16::from_le_bytes([b[off], b[off + 1]]);
    assert_eq!([63, 65, 67, 69, 71, 73, 75].map(half), [0x81, 0x82, 0x83, 0x84, 0x85, 0x86, 0x87]);
    assert_eq!(&b[77..79], &[0x91, 0x92]);
    assert_eq!(half(79), 0x9394);
    assert_eq!([81, 83, 85, 87, 89, 91].map(half), [0xA1, 0xA2, 0xA3, 0xB1, 0xB2, 0xB3]);
    assert_eq!(word(93) as u32, CRC32C.checksum(&b[..93]));
    assert_eq!(OutputFrame::decode(&b), Ok(f));
    assert_eq!(f.counters.step_ticks, 0x87);
    assert_eq!(f.counters.to_array(), [0x81, 0x82, 0x83, 0x84, 0x85, 0x86, 0x87]);
}

#[test]
fn output_physical_scaling() {
    let f = OutputFrame::from_physical(
        output::flags::ST_IN_USE | output::flags::DEGRADED,
        5,
        1_000,
        [f64::NAN, 0.6, -0.8, 2.0],
        [0.001, -3.0, f64::INFINITY],
        [1e-7, -1e-7, f64::NAN],
        1e-9,
        [1, 2, 4, 8],
        0x1F,
        [1, 2, 3, 4, 5, 6, 7],
    );
    assert_eq!(f.q_counts[0], 0);
    assert_eq!(f.q_counts[3], i32::MAX);
    assert_eq!(f.rate_counts[1], i32::MIN);
    assert_eq!(f.rate_counts[2], i32::MAX);
    assert_eq!(f.drift_counts[2], 0);
    let q = f.quaternion();
    assert!((q[1] - 0.6).abs() <= output::Q_LSB / 2.0 && (q[2] + 0.8).abs() <= output::Q_LSB / 2.0);
    assert!((f.rate_rad_s()[0] - 0.001).abs() <= output::RATE_LSB_RAD_S / 2.0);
    assert!((f.drift_rad_s()[0] - 1e-7).abs() <= output::DRIFT_LSB_RAD_S / 2.0);
    assert!((f.parity_rad() - 1e-9).abs() <= output::PARITY_LSB_RAD / 2.0);
    assert!(f.flag(output::flags::ST_IN_USE) && f.flag(output::flags::DEGRADED));
    assert!(!f.flag(output::flags::CONVERGED));
    assert_eq!(f.counters.overruns, 6);
    assert_eq!(OutputFrame::decode(&f.to_bytes()), Ok(f));
    // The 1σ fields: unknown until set; 0.01″ and 1e-4 °/h counts; infinite (not
    // aligned) and beyond the range saturate to "unknown", NaN gives 0.
    assert_eq!(f.att_sigma_counts, [output::SIGMA_UNKNOWN; 3]);
    assert_eq!(f.att_sigma_rad(), [f64::INFINITY; 3]);
    let mut s = f;
    let arcsec = std::f64::consts::PI / 180.0 / 3600.0;
    // 1 °/h is 1″/s.
    s.set_sigmas([1.0 * arcsec, f64::INFINITY, f64::NAN], [0.3 * arcsec, 1.0, 0.0]);
    assert_eq!(s.att_sigma_counts, [100, u16::MAX, 0]);
    assert_eq!(s.drift_sigma_counts, [3_000, u16::MAX, 0]);
    assert!((s.att_sigma_rad()[0] / arcsec - 1.0).abs() < 1e-12);
    assert!((s.drift_sigma_rad_s()[0] / arcsec - 0.3).abs() < 1e-12);
    assert_eq!(OutputFrame::decode(&s.to_bytes()), Ok(s));
}

// ---------------------------------------------------------------------------------------
// Event frame

/// The ICD's example: the unit aligned at 12.345 s, then isolated FOG3 at 40 s.
fn icd_event_example() -> EventFrame {
    let r = |time_us, seq, event, a| EventRecord { time_us, seq, event, a, b: 0 };
    EventFrame {
        lost: 0,
        records: [Some(r(12_345_000, 7, Event::Aligned, 0)), Some(r(40_000_000, 8, Event::Isolated, 3)), None, None],
    }
}

#[test]
fn event_golden_bytes_and_layout() {
    let b = icd_event_example().to_bytes();
    assert_eq!((EventFrame::LEN, <EventFrame as Frame>::KIND, kind::EVENT), (60, 0x32, 0x32));
    assert_eq!(
        hex_block(&b),
        "EB 90 32 02 07 00 00 00 A8 5E BC 00 00 00 00 00\n\
         01 00 00 00 00 5A 62 02 00 00 00 00 06 03 00 00\n\
         00 00 00 00 00 00 00 00 00 00 00 00 00 00 00 00\n\
         00 00 00 00 00 00 00 00 34 41 22 63"
    );
    // count at 3, seq at 4, lost at 6, record k at 8 + 12k: time, code, a, b.
    assert_eq!((b[3], u16::from_le_bytes([b[4], b[5]]), u16::from_le_bytes([b[6], b[7]])), (2, 7, 0));
    assert_eq!(u64::from_le_bytes(b[20..28].try_into().unwrap()), 40_000_000);
    assert_eq!((b[28], b[29]), (Event::Isolated.code(), 3));
    assert_eq!(u32::from_le_bytes(b[56..60].try_into().unwrap()), CRC32C.checksum(&b[..56]));
    let back = EventFrame::decode(&b).expect("decodes");
    let seqs: Vec<(u16, Event)> = back.iter().map(|r| (r.seq, r.event)).collect();
    assert_eq!(seqs, [(7, Event::Aligned), (8, Event::Isolated)]);
    assert_eq!(back, icd_event_example());
}

#[test]
fn event_fields_out_of_range_are_rejected() {
    let good = icd_event_example().to_bytes();
    let bad = |edit: &dyn Fn(&mut [u8; 60])| {
        let mut b = good;
        edit(&mut b);
        reseal(&mut b);
        EventFrame::decode(&b)
    };
    assert_eq!(bad(&|b| b[3] = 0), Err(DecodeError::BadField), "no record");
    assert_eq!(bad(&|b| b[3] = 5), Err(DecodeError::BadField), "more than four");
    assert_eq!(bad(&|b| b[16] = 0), Err(DecodeError::BadField), "code 0 is no event");
    assert_eq!(bad(&|b| b[16] = 0xEE), Err(DecodeError::BadField), "unknown code");
    assert_eq!(bad(&|b| b[40] = 1), Err(DecodeError::BadField), "a byte past the count");
    assert_eq!(bad(&|b| b[3] = 3), Err(DecodeError::BadField), "a third record of code 0");
    assert!(bad(&|b| b[6] = 9).is_ok_and(|f| f.lost == 9));
}

#[test]
fn event_frames_and_output_frames_share_one_stream() {
    use ssis_common::downlink::{Down, Downlink};
    let out = icd_output_example().to_bytes();
    let ev = icd_event_example().to_bytes();
    let mut stream = Vec::new();
    for k in 0..5 {
        stream.extend_from_slice(&out);
        if k % 2 == 1 {
            stream.extend_from_slice(&ev);
        }
    }
    stream.extend_from_slice(&[0x00, 0xEB, 0x90, 0x32, 0x01]);
    let mut link = Downlink::new();
    let (mut outputs, mut events) = (0, 0);
    // Fed in odd-sized chunks, so frames split across pushes.
    for chunk in stream.chunks(37) {
        link.push(chunk, |d| match d {
            Down::Output(_) => outputs += 1,
            Down::Events(e) => events += e.iter().count(),
            Down::Report(_) => panic!("no report was sent"),
        });
    }
    assert_eq!((outputs, events), (5, 4));
    assert_eq!(link.bad_bytes(), 1, "the leading 00 of the tail; the rest may start a frame");
}

// ---------------------------------------------------------------------------------------
// ICD example frames (docs/ICD.md must show exactly these bytes)

const ICD: &str = include_str!("../../docs/ICD.md");

#[test]
fn icd_example_frames() {
    let fog = hex_block(&icd_fog_example().to_bytes());
    let star = hex_block(&icd_star_example().to_bytes());
    let out = hex_block(&icd_output_example().to_bytes());
    let ev = hex_block(&icd_event_example().to_bytes());
    println!("FOG:\n{fog}\nSTAR:\n{star}\nOUTPUT:\n{out}\nEVENT:\n{ev}");
    assert_eq!(fog, "EB 90 10 01 02 01 00 E3 36 1A 00 80 19 00 AD 60\nBD 86");
    for (name, hex) in [("FOG", &fog), ("star-tracker", &star), ("output", &out), ("event", &ev)] {
        assert!(ICD.contains(hex.as_str()), "docs/ICD.md lacks the {name} example:\n{hex}");
    }
    assert!(ICD.contains("## Links and UART mapping") && ICD.contains("| UART1 | 0x4000_5000 |"));
    assert!(ICD.contains("## Control frame (kind 0x40, 18 bytes)"));
    assert!(ICD.contains("## Calibration table\n\nSee docs/CALIBRATION.md."));
    assert!(ICD.contains("0xE3069283"));
}

// ---------------------------------------------------------------------------------------
// Property tests

proptest! {
    #![proptest_config(ProptestConfig { cases: 512, ..ProptestConfig::default() })]

    #[test]
    fn fog_round_trip(f in fog_frame()) {
        prop_assert_eq!(FogFrame::decode(&f.to_bytes()), Ok(f));
        prop_assert_eq!(bytes_of(&f), f.to_bytes().to_vec());
        let p = FogFrame::from_physical(f.fog_id, f.counter, f.status, f.dtheta_rad(), f.temperature_degc());
        prop_assert_eq!(p, f);
    }

    #[test]
    fn star_round_trip(f in star_frame()) {
        prop_assert_eq!(StarFrame::decode(&f.to_bytes()), Ok(f));
        let p = StarFrame::from_physical(f.flags, f.counter, f.time_us, f.quaternion());
        prop_assert_eq!(p, f);
    }

    #[test]
    fn star_from_physical_is_within_half_an_lsb(q in unit_quaternion(), t in any::<u64>()) {
        let f = StarFrame::from_physical(star::flags::VALID, 0, t, q);
        let back = f.quaternion();
        for (a, b) in q.iter().zip(back.iter()) {
            // +1.0 saturates to 1 − 2^-31: one LSB.
            prop_assert!((a - b).abs() <= star::Q_LSB, "{a} {b}");
        }
        prop_assert_eq!(StarFrame::decode(&f.to_bytes()), Ok(f));
    }

    #[test]
    fn star_raw_counts_decode_iff_norm_is_close(
        q in any::<[i32; 4]>(), flags in 0u8..4, counter in any::<u16>(), t in any::<u64>()
    ) {
        let f = StarFrame { flags, counter, time_us: t, q_counts: q };
        let n = f.quaternion().iter().map(|c| c * c).sum::<f64>().sqrt();
        let r = StarFrame::decode(&f.to_bytes());
        if (n - 1.0).abs() > 1.0001e-6 {
            prop_assert_eq!(r, Err(DecodeError::BadField));
        } else if (n - 1.0).abs() < 0.9999e-6 {
            prop_assert_eq!(r, Ok(f));
        }
    }

    #[test]
    fn output_round_trip(f in output_frame()) {
        prop_assert_eq!(OutputFrame::decode(&f.to_bytes()), Ok(f));
        let mut p = OutputFrame::from_physical(
            f.flags, f.counter, f.time_us, f.quaternion(), f.rate_rad_s(), f.drift_rad_s(),
            f.parity_rad(), f.fog_health, f.st_status, f.counters.to_array(),
        );
        (p.fdi, p.page_id, p.page_value) = (f.fdi, f.page_id, f.page_value);
        p.set_sigmas(f.att_sigma_rad(), f.drift_sigma_rad_s());
        prop_assert_eq!(p, f);
    }

    #[test]
    fn fog_from_physical_never_panics(d in any::<f64>(), t in any::<f64>()) {
        let f = FogFrame::from_physical(0, 0, 0, d, t);
        if d.is_nan() { prop_assert_eq!(f.dtheta_counts, 0); }
        if d.is_finite() && d.abs() < 1e-3 {
            prop_assert!((f.dtheta_rad() - d).abs() <= FogFrame::DTHETA_LSB_RAD / 2.0);
        }
        prop_assert_eq!(FogFrame::decode(&f.to_bytes()), Ok(f));
    }
}

proptest! {
    /// The flight code's four-bytes-a-pass CRC (`frames::body_crc`) equals the `crc`
    /// crate's CRC-32/ISCSI over header and body, for every kind and any body length
    /// (lengths not a multiple of four take the one-byte tail).
    #[test]
    fn body_crc_equals_the_crc_crate(kind_byte in any::<u8>(), body in proptest::collection::vec(any::<u8>(), 0..200)) {
        let mut whole = SYNC.to_vec();
        whole.push(kind_byte);
        whole.extend_from_slice(&body);
        prop_assert_eq!(body_crc(header_crc(kind_byte), &body), CRC32C.checksum(&whole));
    }
}
