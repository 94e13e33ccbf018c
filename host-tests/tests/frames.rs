//! Frames and the streaming decoder: round trips, field checks, the CRC, the ICD's
//! example frames, and the decoder against random bytes, bit flips, truncated and
//! spliced frames and garbage (no panic, no bad frame accepted, resync within a frame).

use proptest::prelude::*;
use ssis::frames::decoder::{DecoderStats, StreamDecoder};
use ssis::frames::fog::{self, FogFrame};
use ssis::frames::output::{self, OutputCounters, OutputFrame};
use ssis::frames::star::{self, StarFrame};
use ssis::frames::{body_crc, header_crc, kind, DecodeError, EncodeError, Frame, CRC16, SYNC};

// ---------------------------------------------------------------------------------------
// Helpers

/// Bytes of any frame through the generic encoder.
fn bytes_of<F: Frame>(f: &F) -> Vec<u8> {
    let mut v = vec![0u8; F::LEN];
    assert_eq!(f.encode_into(&mut v), Ok(F::LEN));
    v
}

/// Recomputes the CRC of a frame whose bytes were edited.
fn reseal(bytes: &mut [u8]) {
    let n = bytes.len() - 2;
    let crc = CRC16.checksum(&bytes[..n]).to_le_bytes();
    bytes[n..].copy_from_slice(&crc);
}

/// What a decoder returned while taking `bytes`: (index of the byte that completed it,
/// result), and its final stats.
struct Fed<F> {
    results: Vec<(usize, Result<F, DecodeError>)>,
    stats: DecoderStats,
    buffered: usize,
}

impl<F: Clone> Fed<F> {
    fn oks(&self) -> Vec<F> {
        self.results.iter().filter_map(|(_, r)| r.clone().ok()).collect()
    }
    fn errs(&self) -> Vec<DecodeError> {
        self.results.iter().filter_map(|(_, r)| r.clone().err()).collect()
    }
}

fn feed<F: Frame + Clone, const CAP: usize>(dec: &mut StreamDecoder<F, CAP>, bytes: &[u8]) -> Fed<F> {
    let results = bytes.iter().enumerate().filter_map(|(i, &b)| dec.push(b).map(|r| (i, r))).collect();
    Fed { results, stats: dec.stats(), buffered: dec.buffered() }
}

fn feed_new<F: Frame + Clone>(bytes: &[u8]) -> Fed<F> {
    let mut dec: StreamDecoder<F, 128> = StreamDecoder::new();
    feed(&mut dec, bytes)
}

/// Invariants that hold for any input: every Ok is a CRC-valid window of the input that
/// ends at the byte that completed it; counters agree with what was returned; every byte
/// is accounted for.
fn check_invariants<F: Frame + Clone + core::fmt::Debug>(input: &[u8], fed: &Fed<F>) {
    for (i, r) in &fed.results {
        if let Ok(f) = r {
            let b = bytes_of(f);
            let start = i + 1 - F::LEN;
            assert_eq!(&input[start..=*i], &b[..], "accepted frame is not the input's bytes");
            assert_eq!(F::decode(&b).ok().map(|g| bytes_of(&g)), Some(b.clone()));
        }
    }
    let s = fed.stats;
    assert_eq!(s.frames_ok as usize, fed.oks().len());
    assert_eq!(s.rejected() as usize, fed.errs().len());
    let errs = fed.errs();
    let count = |e: DecodeError| errs.iter().filter(|x| **x == e).count() as u32;
    assert_eq!(s.crc_errors, count(DecodeError::BadCrc));
    assert_eq!(s.kind_errors, count(DecodeError::BadKind));
    assert_eq!(s.field_errors, count(DecodeError::BadField));
    assert_eq!(
        s.frames_ok as usize * F::LEN + s.bytes_skipped as usize + fed.buffered,
        input.len(),
        "bytes not accounted for: {s:?}, buffered {}",
        fed.buffered
    );
    assert!(fed.buffered < F::LEN);
}

/// The resync guarantee for `garbage` followed by one complete `frame`: the frame is
/// the last thing decoded, completed by the last byte; or (the one documented exception)
/// a candidate starting inside the garbage's last LEN − 1 bytes and ending inside the
/// frame passed every check and was accepted. Returns whether the exception happened.
fn check_frame_after_garbage<F: Frame + Clone + PartialEq + core::fmt::Debug>(garbage: &[u8], frame: &F) -> bool {
    let mut input = garbage.to_vec();
    input.extend(bytes_of(frame));
    let fed = feed_new::<F>(&input);
    check_invariants(&input, &fed);
    let last = input.len() - 1;
    let got = fed.results.iter().any(|(i, r)| *i == last && r.as_ref().ok() == Some(frame));
    if got {
        return false;
    }
    let swallowed = fed.results.iter().any(|(i, r)| r.is_ok() && *i >= garbage.len() && *i < last);
    assert!(swallowed, "frame after garbage lost: garbage {garbage:02X?}, results {:?}", fed.results);
    true
}

fn hex_block(bytes: &[u8]) -> String {
    bytes
        .chunks(16)
        .map(|c| c.iter().map(|b| format!("{b:02X}")).collect::<Vec<_>>().join(" "))
        .collect::<Vec<_>>()
        .join("\n")
}

// ---------------------------------------------------------------------------------------
// Strategies

fn fog_frame() -> impl Strategy<Value = FogFrame> + Clone {
    (0u8..=3, any::<u16>(), 0u8..16, any::<i32>(), any::<i16>()).prop_map(
        |(fog_id, counter, status, dtheta_counts, temperature_counts)| FogFrame {
            fog_id,
            counter,
            status,
            dtheta_counts,
            temperature_counts,
        },
    )
}

fn unit_quaternion() -> impl Strategy<Value = [f64; 4]> + Clone {
    prop::array::uniform4(-1.0f64..1.0)
        .prop_filter("not near zero", |q| q.iter().map(|c| c * c).sum::<f64>() > 1e-3)
        .prop_map(|q| {
            let n = q.iter().map(|c| c * c).sum::<f64>().sqrt();
            q.map(|c| c / n)
        })
}

fn star_frame() -> impl Strategy<Value = StarFrame> + Clone {
    (0u8..4, any::<u16>(), any::<u64>(), unit_quaternion())
        .prop_map(|(flags, counter, time_us, q)| StarFrame::from_physical(flags, counter, time_us, q))
}

fn output_frame() -> impl Strategy<Value = OutputFrame> + Clone {
    (
        (any::<u8>(), any::<u16>(), any::<u64>(), any::<[i32; 4]>()),
        (any::<[i32; 3]>(), any::<[i32; 3]>(), any::<i32>()),
        (any::<[u8; 4]>(), any::<u8>(), any::<[u16; 7]>(), any::<(u8, u8, u16)>()),
    )
        .prop_map(
            |(
                (flags, counter, time_us, q_counts),
                (rate_counts, drift_counts, parity_counts),
                (fog_health, st_status, c, (fdi, page_id, page_value)),
            )| {
                OutputFrame {
                    flags,
                    counter,
                    time_us,
                    q_counts,
                    rate_counts,
                    drift_counts,
                    parity_counts,
                    fog_health,
                    st_status,
                    counters: OutputCounters::from_array(c),
                    fdi,
                    page_id,
                    page_value,
                }
            },
        )
}

/// Garbage made to be hard: random bytes, sync bytes, headers of this kind, truncated
/// and corrupted frames of this kind, whole frames of other kinds.
fn garbage<F: Frame>(frames: impl Strategy<Value = F> + Clone) -> impl Strategy<Value = Vec<u8>> {
    let chunk = prop_oneof![
        prop::collection::vec(any::<u8>(), 0..24),
        Just(SYNC.to_vec()),
        Just(vec![SYNC[0]]),
        Just(vec![SYNC[0], SYNC[1], F::KIND]),
        Just(vec![SYNC[0], SYNC[0], SYNC[1]]),
        (frames.clone(), 1..F::LEN).prop_map(|(f, n)| bytes_of(&f)[..n].to_vec()),
        (frames, any::<prop::sample::Index>()).prop_map(|(f, i)| {
            let mut b = bytes_of(&f);
            let bit = i.index(b.len() * 8);
            b[bit / 8] ^= 1 << (bit % 8);
            b
        }),
        fog_frame().prop_map(|f| f.to_bytes().to_vec()),
        star_frame().prop_map(|f| f.to_bytes().to_vec()),
    ];
    prop::collection::vec(chunk, 0..8).prop_map(|v| v.concat())
}

// ---------------------------------------------------------------------------------------
// CRC, lengths, envelope

#[test]
fn crc_check_value() {
    assert_eq!(CRC16.checksum(b"123456789"), 0x29B1);
}

#[test]
fn lengths_and_kinds() {
    assert_eq!((FogFrame::LEN, <FogFrame as Frame>::LEN, <FogFrame as Frame>::KIND), (16, 16, 0x10));
    assert_eq!((StarFrame::LEN, <StarFrame as Frame>::LEN, <StarFrame as Frame>::KIND), (32, 32, 0x20));
    assert_eq!((OutputFrame::LEN, <OutputFrame as Frame>::LEN, <OutputFrame as Frame>::KIND), (83, 83, 0x30));
    assert_eq!([kind::FOG, kind::STAR, kind::OUTPUT], [0x10, 0x20, 0x30]);
}

#[test]
fn encode_into_checks_the_buffer() {
    let f = FogFrame::from_physical(1, 2, 0, 1e-6, 20.0);
    let mut small = [0u8; 15];
    assert_eq!(f.encode_into(&mut small), Err(EncodeError::BufferTooSmall));
    let mut big = [0xAAu8; 20];
    assert_eq!(f.encode_into(&mut big), Ok(16));
    assert_eq!(&big[..16], &f.to_bytes());
    assert_eq!(&big[16..], &[0xAA; 4]);
}

#[test]
fn decode_checks_length_sync_kind_crc() {
    let b = FogFrame::from_physical(1, 2, 0, 1e-6, 20.0).to_bytes();
    assert_eq!(FogFrame::decode(&b[..15]), Err(DecodeError::BadLength));
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
    c2[15] ^= 0x80;
    assert_eq!(FogFrame::decode(&c2), Err(DecodeError::BadCrc));
    // The CRC is little-endian over bytes 0..14.
    assert_eq!(u16::from_le_bytes([b[14], b[15]]), CRC16.checksum(&b[..14]));
    assert_eq!(FogFrame::decode(&b).map(|f| f.to_bytes()), Ok(b));
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
    assert_eq!(u16::from_le_bytes([b[30], b[31]]), CRC16.checksum(&b[..30]));
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
    };
    let b = f.to_bytes();
    assert_eq!(b.len(), 83);
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
    assert_eq!(half(81), CRC16.checksum(&b[..81]));
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
}

// ---------------------------------------------------------------------------------------
// ICD example frames (docs/ICD.md must show exactly these bytes)

const ICD: &str = include_str!("../../docs/ICD.md");

fn icd_fog_example() -> FogFrame {
    FogFrame::from_physical(1, 258, 0, 2.5e-5, 25.5)
}

fn icd_star_example() -> StarFrame {
    StarFrame::from_physical(star::flags::VALID, 7, 1_000_000, [0.5, 0.5, 0.5, 0.5])
}

fn icd_output_example() -> OutputFrame {
    OutputFrame::from_physical(
        output::flags::ST_IN_USE | output::flags::CONVERGED,
        200,
        1_000_000,
        [0.5, -0.5, 0.5, -0.5],
        [0.001, -0.002, 0.0],
        [1e-7, 0.0, -1e-7],
        1e-8,
        [0x01, 0x01, 0x01, 0x01],
        0x07,
        [0, 0, 4, 0, 0, 0, 1234],
    )
}

#[test]
fn icd_example_frames() {
    let fog = hex_block(&icd_fog_example().to_bytes());
    let star = hex_block(&icd_star_example().to_bytes());
    let out = hex_block(&icd_output_example().to_bytes());
    println!("FOG:\n{fog}\nSTAR:\n{star}\nOUTPUT:\n{out}");
    assert_eq!(fog, "EB 90 10 01 02 01 00 E3 36 1A 00 80 19 00 41 F5");
    for (name, hex) in [("FOG", &fog), ("star-tracker", &star), ("output", &out)] {
        assert!(ICD.contains(hex.as_str()), "docs/ICD.md lacks the {name} example:\n{hex}");
    }
    assert!(ICD.contains("## Links and UART mapping") && ICD.contains("| UART1 | 0x4000_5000 |"));
    assert!(ICD.contains("## Control frame (kind 0x40, 16 bytes)"));
    assert!(ICD.contains("## Calibration table\n\nSee docs/CALIBRATION.md."));
    assert!(ICD.contains("0x29B1"));
}

// ---------------------------------------------------------------------------------------
// Decoder: deterministic cases

#[test]
fn decoder_counts_every_kind_of_rejection() {
    let mut dec: StreamDecoder<FogFrame, 64> = StreamDecoder::new();
    let good = FogFrame::from_physical(0, 1, 0, 1e-6, 20.0);

    let fed = feed(&mut dec, &good.to_bytes());
    assert_eq!(fed.oks(), vec![good]);
    assert_eq!(fed.stats, DecoderStats { frames_ok: 1, ..Default::default() });

    let mut bad_crc = good.to_bytes();
    bad_crc[9] ^= 0x10;
    let fed = feed(&mut dec, &bad_crc);
    assert_eq!(fed.errs(), vec![DecodeError::BadCrc]);
    assert_eq!(fed.stats.crc_errors, 1);

    // A star-tracker frame on a FOG link: rejected at its kind byte.
    let st = StarFrame::from_physical(1, 1, 1, [1.0, 0.0, 0.0, 0.0]).to_bytes();
    let fed = feed(&mut dec, &st);
    assert!(fed.errs().contains(&DecodeError::BadKind));
    assert_eq!(fed.stats.kind_errors as usize, fed.errs().iter().filter(|e| **e == DecodeError::BadKind).count());
    dec.reset();

    let bad_field = FogFrame { fog_id: 9, ..good }.to_bytes();
    let before = dec.stats();
    let fed = feed(&mut dec, &bad_field);
    assert_eq!(fed.errs(), vec![DecodeError::BadField]);
    assert_eq!(fed.stats.field_errors, before.field_errors + 1);

    let before = dec.stats();
    let fed = feed(&mut dec, &[0x00, 0x11, 0xEB, 0x00, 0x90]);
    assert!(fed.results.is_empty());
    assert_eq!(fed.stats.bytes_skipped, before.bytes_skipped + 5);

    let fed = feed(&mut dec, &good.to_bytes());
    assert_eq!(fed.oks(), vec![good]);
    assert_eq!(fed.stats.frames_ok, 2);
}

#[test]
fn decoder_counters_saturate_not_wrap() {
    // A cheap stand-in for 2^32 events: the stats type is plain saturating u32 fields,
    // so check the arithmetic the decoder uses on them.
    let s = DecoderStats { crc_errors: u32::MAX, kind_errors: 1, field_errors: 1, ..Default::default() };
    assert_eq!(s.rejected(), u32::MAX);
}

#[test]
fn false_sync_before_a_frame_does_not_lose_it() {
    let good = FogFrame::from_physical(2, 9, 0, -3e-6, 30.0);
    // A false start: header of this kind, then a few bytes, then the real frame.
    let mut input = vec![0xEB, 0x90, 0x10, 0x00, 0x01, 0xEB];
    input.extend(good.to_bytes());
    let fed = feed_new::<FogFrame>(&input);
    assert_eq!(fed.oks(), vec![good]);
    assert_eq!(fed.errs(), vec![DecodeError::BadCrc]);
    check_invariants(&input, &fed);
}

#[test]
fn frames_split_into_any_chunks_decode_the_same() {
    let frames: Vec<StarFrame> =
        (0..5).map(|i| StarFrame::from_physical(1, i, u64::from(i) * 250_000, [0.0, 0.6, 0.0, 0.8])).collect();
    let input: Vec<u8> = frames.iter().flat_map(|f| f.to_bytes()).collect();
    for chunk in 1..=input.len() {
        let mut dec: StreamDecoder<StarFrame, 32> = StreamDecoder::new();
        let mut got = Vec::new();
        for c in input.chunks(chunk) {
            dec.push_slice(c, |r| got.push(r));
        }
        assert_eq!(got, frames.iter().map(|f| Ok(*f)).collect::<Vec<_>>(), "chunk {chunk}");
    }
}

/// The documented exception: garbage ending in `EB 90 10` and a few bytes that, with the
/// first bytes of the real frame, make a CRC-valid FOG frame. That candidate is accepted
/// (it is a frame by every check), the real frame is lost, the next one is decoded.
#[test]
fn crc_collision_straddling_garbage_and_frame_is_the_one_exception() {
    let real =
        FogFrame { fog_id: 1, counter: 0x0042, status: 0, dtheta_counts: 0x1234_5678, temperature_counts: 0x0100 };
    let next = FogFrame { counter: 0x0043, ..real };
    let r = real.to_bytes();
    // Candidate = tail (8 bytes) ++ r[0..8]; its reserved byte is r[5] (= 0) and its CRC
    // is r[6..8]. Choose the tail's counter bytes so that the CRC matches.
    let target = u16::from_le_bytes([r[6], r[7]]);
    let tail = (0..=u16::MAX)
        .map(|c| {
            let [c0, c1] = c.to_le_bytes();
            [0xEB, 0x90, 0x10, 0x00, c0, c1, 0x00, 0x00]
        })
        .find(|t| {
            let mut cand = t.to_vec();
            cand.extend_from_slice(&r[..6]);
            CRC16.checksum(&cand) == target
        })
        .expect("CRC-16 over two free bytes reaches every value");
    let mut input = vec![0x55; 5];
    input.extend(tail);
    input.extend(r);
    input.extend(next.to_bytes());
    let fed = feed_new::<FogFrame>(&input);
    check_invariants(&input, &fed);
    let oks = fed.oks();
    assert_eq!(oks.len(), 2, "{:?}", fed.results);
    assert_ne!(oks[0], real);
    assert_eq!(&oks[0].to_bytes()[8..], &r[..8]);
    assert_eq!(oks[1], next);
    assert!(check_frame_after_garbage(&input[..5 + 8], &real));
}

#[test]
fn capacity_larger_than_a_frame_works() {
    let mut dec: StreamDecoder<OutputFrame, 256> = StreamDecoder::default();
    let f = icd_output_example();
    let fed = feed(&mut dec, &[f.to_bytes(), f.to_bytes()].concat());
    assert_eq!(fed.oks(), vec![f, f]);
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

    #[test]
    fn random_bytes_never_yield_a_bad_frame(input in prop::collection::vec(any::<u8>(), 0..600)) {
        check_invariants(&input, &feed_new::<FogFrame>(&input));
        check_invariants(&input, &feed_new::<StarFrame>(&input));
        check_invariants(&input, &feed_new::<OutputFrame>(&input));
    }

    #[test]
    fn sync_rich_bytes_never_yield_a_bad_frame(
        input in prop::collection::vec(prop_oneof![Just(0xEBu8), Just(0x90u8), Just(0x10u8), any::<u8>()], 0..600)
    ) {
        check_invariants(&input, &feed_new::<FogFrame>(&input));
    }

    #[test]
    fn bit_flips_are_never_accepted(
        frames in prop::collection::vec(fog_frame(), 1..12),
        flips in prop::collection::vec(any::<prop::sample::Index>(), 1..=3),
    ) {
        // CRC-16/CCITT detects every pattern of up to 3 flipped bits in a frame.
        let mut input: Vec<u8> = frames.iter().flat_map(|f| f.to_bytes()).collect();
        let mut hit = std::collections::BTreeSet::new();
        for i in &flips {
            let bit = i.index(input.len() * 8);
            input[bit / 8] ^= 1 << (bit % 8);
            hit.insert(bit / 8 / FogFrame::LEN);
        }
        let fed = feed_new::<FogFrame>(&input);
        check_invariants(&input, &fed);
        // Flips may cancel (same bit twice): compare with what was really changed.
        let original: Vec<u8> = frames.iter().flat_map(|f| f.to_bytes()).collect();
        let damaged: Vec<usize> = (0..frames.len())
            .filter(|k| {
                let r = k * FogFrame::LEN..(k + 1) * FogFrame::LEN;
                input[r.clone()] != original[r]
            })
            .collect();
        let expect: Vec<FogFrame> =
            frames.iter().enumerate().filter(|(k, _)| !damaged.contains(k)).map(|(_, f)| *f).collect();
        prop_assert_eq!(fed.oks(), expect);
        prop_assert!(damaged.iter().all(|k| hit.contains(k)));
    }

    #[test]
    fn bit_flips_in_star_frames_are_never_accepted(
        frames in prop::collection::vec(star_frame(), 1..6),
        flips in prop::collection::vec(any::<prop::sample::Index>(), 1..=3),
    ) {
        let original: Vec<u8> = frames.iter().flat_map(|f| f.to_bytes()).collect();
        let mut input = original.clone();
        for i in &flips {
            let bit = i.index(input.len() * 8);
            input[bit / 8] ^= 1 << (bit % 8);
        }
        let fed = feed_new::<StarFrame>(&input);
        check_invariants(&input, &fed);
        for f in fed.oks() {
            prop_assert!(frames.contains(&f));
        }
        let intact = (0..frames.len())
            .filter(|k| input[k * 32..(k + 1) * 32] == original[k * 32..(k + 1) * 32])
            .count();
        prop_assert_eq!(fed.oks().len(), intact);
    }

    #[test]
    fn truncated_frames_yield_nothing(f in output_frame(), n in 0usize..79) {
        let b = f.to_bytes();
        let fed = feed_new::<OutputFrame>(&b[..n]);
        prop_assert!(fed.results.is_empty());
        check_invariants(&b[..n], &fed);
    }

    #[test]
    fn spliced_frame_is_recovered(a in fog_frame(), b in fog_frame(), n in 1usize..16) {
        // A prefix of one frame, then a whole frame.
        let prefix = a.to_bytes()[..n].to_vec();
        check_frame_after_garbage(&prefix, &b);
    }

    #[test]
    fn spliced_output_frame_is_recovered(a in output_frame(), b in output_frame(), n in 1usize..79) {
        let prefix = a.to_bytes()[..n].to_vec();
        check_frame_after_garbage(&prefix, &b);
    }

    #[test]
    fn fog_frame_after_garbage_is_decoded(g in garbage(fog_frame()), f in fog_frame()) {
        check_frame_after_garbage(&g, &f);
    }

    #[test]
    fn star_frame_after_garbage_is_decoded(g in garbage(star_frame()), f in star_frame()) {
        check_frame_after_garbage(&g, &f);
    }

    #[test]
    fn output_frame_after_garbage_is_decoded(g in garbage(output_frame()), f in output_frame()) {
        check_frame_after_garbage(&g, &f);
    }

    #[test]
    fn frames_interleaved_with_garbage_are_all_decoded(
        parts in prop::collection::vec((garbage(fog_frame()), fog_frame()), 1..6)
    ) {
        let mut input = Vec::new();
        let mut ends = Vec::new();
        for (g, f) in &parts {
            input.extend(g);
            input.extend(f.to_bytes());
            ends.push((input.len() - 1, *f));
        }
        let fed = feed_new::<FogFrame>(&input);
        check_invariants(&input, &fed);
        for (end, f) in ends {
            let got = fed.results.iter().any(|(i, r)| *i == end && r.as_ref().ok() == Some(&f));
            // Else the documented CRC-collision exception must have happened just before.
            let swallowed = fed.results.iter().any(|(i, r)| r.is_ok() && *i >= end + 1 - FogFrame::LEN && *i < end);
            prop_assert!(got || swallowed, "frame ending at {} lost", end);
        }
    }

    #[test]
    fn push_slice_equals_push(input in prop::collection::vec(any::<u8>(), 0..300), cut in 1usize..40) {
        let mut a: StreamDecoder<FogFrame, 16> = StreamDecoder::new();
        let mut b: StreamDecoder<FogFrame, 16> = StreamDecoder::new();
        let one: Vec<_> = input.iter().filter_map(|&x| a.push(x)).collect();
        let mut two = Vec::new();
        for c in input.chunks(cut) {
            b.push_slice(c, |r| two.push(r));
        }
        prop_assert_eq!(one, two);
        prop_assert_eq!(a.stats(), b.stats());
    }
}

/// Decodes `input` byte by byte with `push`, returning the results and counters.
fn feed_bytewise(input: &[u8]) -> (Vec<Result<FogFrame, DecodeError>>, DecoderStats) {
    let mut d: StreamDecoder<FogFrame, 32> = StreamDecoder::new();
    let mut out = Vec::new();
    for &b in input {
        if let Some(r) = d.push(b) {
            out.push(r);
        }
    }
    (out, d.stats())
}

proptest! {
    /// The flight code's two-bytes-a-pass CRC (`frames::body_crc`, byte-swapped tables)
    /// equals the `crc` crate's CRC-16/IBM-3740 over header and body, for every kind and
    /// any body length (odd lengths take the one-byte tail).
    #[test]
    fn body_crc_equals_the_crc_crate(kind_byte in any::<u8>(), body in proptest::collection::vec(any::<u8>(), 0..200)) {
        let mut whole = SYNC.to_vec();
        whole.push(kind_byte);
        whole.extend_from_slice(&body);
        prop_assert_eq!(body_crc(header_crc(kind_byte), &body), CRC16.checksum(&whole));
    }
}

proptest! {
    /// `push_slice` (with its in-place fast path) gives exactly what `push` gives byte by
    /// byte, whatever the chunking, on streams of frames, garbage and damaged frames.
    #[test]
    fn push_slice_equals_bytewise(
        frames in proptest::collection::vec(fog_frame(), 0..6),
        junk in proptest::collection::vec(proptest::collection::vec(any::<u8>(), 0..20), 6),
        flips in proptest::collection::vec((any::<usize>(), 0u8..8), 0..4),
        chunk in 1usize..40,
    ) {
        let mut input = Vec::new();
        for (f, j) in frames.iter().zip(junk.iter()) {
            input.extend_from_slice(j);
            input.extend_from_slice(&bytes_of(f));
        }
        if !input.is_empty() {
            for (pos, bit) in flips {
                let n = input.len();
                input[pos % n] ^= 1 << bit;
            }
        }
        let (want, want_stats) = feed_bytewise(&input);
        let mut d: StreamDecoder<FogFrame, 32> = StreamDecoder::new();
        let mut got = Vec::new();
        for c in input.chunks(chunk) {
            d.push_slice(c, |r| got.push(r));
        }
        prop_assert_eq!(got, want);
        prop_assert_eq!(d.stats(), want_stats);
    }
}
