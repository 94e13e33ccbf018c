//! Accelerometer frames (kind 0x11), the accelerometer calibration section and its
//! compensation.

use nalgebra::Vector3;
use rand::SeedableRng;
use rand_chacha::ChaCha20Rng;
use ssis::calib::accel::{AccelTable, AccelTableError, TABLE_LEN};
use ssis::frames::accel::{AccelFrame, MAX_ACCEL_ID};
use ssis::frames::decoder::StreamDecoder;
use ssis::frames::fog::FogFrame;
use ssis::frames::{kind, DecodeError, Frame};
use ssis_sim::accel::{AccelModel, AccelSpec};

#[test]
fn layout_and_icd_example() {
    assert_eq!((AccelFrame::LEN, <AccelFrame as Frame>::KIND), (18, 0x11));
    assert_ne!(kind::ACCEL, kind::FOG);
    // docs/ICD.md example: X accelerometer, counter 258, 0.0125 m/s (10 m/s² over
    // 1.25 ms), 25.5 °C.
    let f = AccelFrame::from_physical(0, 258, 0, 0.0125, 25.5);
    assert_eq!(f.dv_counts, 3_355_443);
    let b = f.to_bytes();
    assert_eq!(
        b,
        [0xEB, 0x90, 0x11, 0x00, 0x02, 0x01, 0x00, 0x33, 0x33, 0x33, 0x00, 0x80, 0x19, 0x00, 0x70, 0x3D, 0x24, 0x88]
    );
    assert_eq!(AccelFrame::decode(&b), Ok(f));
    assert!((f.dv_m_s() - 0.0125).abs() <= 0.5 * AccelFrame::DV_LSB_M_S);
    assert_eq!(f.temperature_degc(), 25.5);
    // A FOG frame's bytes are not an accelerometer frame, and the reverse.
    let fog = FogFrame::from_physical(0, 258, 0, 1e-5, 25.5).to_bytes();
    assert_eq!(AccelFrame::decode(&fog), Err(DecodeError::BadKind));
    assert_eq!(FogFrame::decode(&b), Err(DecodeError::BadKind));
}

#[test]
fn fields_out_of_range_are_rejected_and_values_saturate() {
    let ok = AccelFrame::from_physical(MAX_ACCEL_ID, 1, 0, -0.05, -10.0);
    assert_eq!(AccelFrame::decode(&ok.to_bytes()), Ok(ok));
    for bad in [AccelFrame { accel_id: 3, ..ok }, AccelFrame { status: 0x08, ..ok }, AccelFrame { status: 0x80, ..ok }]
    {
        assert_eq!(AccelFrame::decode(&bad.to_bytes()), Err(DecodeError::BadField), "{bad:?}");
    }
    let mut reserved = ok.to_bytes();
    reserved[13] = 1;
    let crc = ssis::frames::CRC32C.checksum(&reserved[..14]).to_le_bytes();
    reserved[14..].copy_from_slice(&crc);
    assert_eq!(AccelFrame::decode(&reserved), Err(DecodeError::BadField));
    assert_eq!(AccelFrame::from_physical(0, 0, 0, 1e3, 0.0).dv_counts, i32::MAX);
    assert_eq!(AccelFrame::from_physical(0, 0, 0, -1e3, 0.0).dv_counts, i32::MIN);
    assert_eq!(AccelFrame::from_physical(0, 0, 0, f64::NAN, 0.0).dv_counts, 0);
    assert!(AccelFrame { status: 1, ..ok }.device_fault());
    assert!(!AccelFrame { status: 2, ..ok }.device_fault());
}

/// A stream of 300 frames with garbage between them, some frames corrupted (one bit
/// flipped), some FOG frames interleaved: every intact accelerometer frame comes out,
/// in order, and the rejections are counted.
#[test]
fn stream_decoder_with_corruption() {
    let mut stream = Vec::new();
    let mut expected = Vec::new();
    let mut corrupted = 0u32;
    let mut fogs = 0u32;
    let mut x: u32 = 12345;
    let mut next = || {
        x ^= x << 13;
        x ^= x >> 17;
        x ^= x << 5;
        x
    };
    for k in 0..300u16 {
        let f = AccelFrame::from_physical((k % 3) as u8, k, 0, f64::from(k) * 1e-4 - 0.01, 20.0);
        let mut b = f.to_bytes();
        match next() % 10 {
            0 => {
                let bit = next() as usize % (8 * 16);
                b[bit / 8] ^= 1 << (bit % 8);
                corrupted += 1;
            }
            1 => {
                stream.extend_from_slice(&FogFrame::from_physical(1, k, 0, 1e-6, 20.0).to_bytes());
                fogs += 1;
                expected.push(f);
            }
            2 => {
                // Garbage with a false sync.
                stream.extend_from_slice(&[0xEB, 0x90, 0x11, 0x42, 0x00]);
                expected.push(f);
            }
            _ => expected.push(f),
        }
        stream.extend_from_slice(&b);
    }
    let mut dec: StreamDecoder<AccelFrame, 64> = StreamDecoder::new();
    let mut got = Vec::new();
    // Fed in uneven chunks, as a UART would deliver it.
    for chunk in stream.chunks(7) {
        dec.push_slice(chunk, |r| {
            if let Ok(f) = r {
                got.push(f);
            }
        });
    }
    let s = dec.stats();
    println!("{} frames sent, {corrupted} corrupted, {fogs} FOG frames interleaved: {s:?}", 300);
    assert_eq!(got, expected);
    assert_eq!(s.frames_ok as usize, expected.len());
    // Each FOG frame is seen as sync + wrong kind; each corrupted frame is rejected
    // (CRC, or sync/kind when the flip hit the header, or hunted over).
    assert!(s.kind_errors >= fogs, "{s:?}");
    assert!(s.rejected() + s.bytes_skipped > 0);
}

fn table_with_errors() -> AccelTable {
    let mut rng = ChaCha20Rng::seed_from_u64(7);
    AccelModel::new(&AccelSpec::typical_pendulous(), &mut rng).truth
}

#[test]
fn table_binary_round_trip_and_refusals() {
    let t = AccelTable { revision: 42, ..table_with_errors() };
    let b = t.to_bytes();
    assert_eq!(b.len(), TABLE_LEN);
    assert_eq!(&b[..4], b"SSCA");
    assert_eq!(AccelTable::from_bytes(&b), Ok(t));
    assert_eq!(AccelTable::from_bytes(&b[..TABLE_LEN - 1]), Err(AccelTableError::Length));
    for i in [0usize, 4, 12, 100, TABLE_LEN - 1] {
        let mut c = b;
        c[i] ^= 0x10;
        assert!(AccelTable::from_bytes(&c).is_err(), "flip at {i} accepted");
    }
    let mut c = b;
    c[50] ^= 0x01;
    assert_eq!(AccelTable::from_bytes(&c), Err(AccelTableError::Crc));
    let mut bad = t;
    bad.misalignment.y_rad[1] = 0.02;
    assert_eq!(bad.validate(), Err(AccelTableError::Value));
    assert_eq!(AccelTable::from_bytes(&bad.to_bytes()), Err(AccelTableError::Value));
    bad = t;
    bad.accel[2].bias_m_s2 = f64::NAN;
    assert_eq!(bad.compensator().err(), Some(AccelTableError::Value));
}

/// The compensation inverts the model: with the model's own errors as the table, no
/// noise, and a 600-step run of large specific forces, the compensated increment equals
/// the true one to the frame quantisation (2^-28 m/s) plus the k2 inversion residual.
#[test]
fn compensation_inverts_the_model() {
    let mut rng = ChaCha20Rng::seed_from_u64(7);
    let spec = AccelSpec { vrw_ug_sqrt_hz: 0.0, ..AccelSpec::typical_pendulous() };
    let mut model = AccelModel::new(&spec, &mut rng);
    let comp = model.truth.compensator().expect("table");
    let ideal = AccelTable::IDEAL.compensator().expect("ideal");
    let dt = 1.25e-3;
    let (mut worst, mut worst_uncomp) = (0.0f64, 0.0f64);
    let (mut sum_true, mut sum_comp) = (Vector3::zeros(), Vector3::zeros());
    for k in 1..=600 {
        let t = f64::from(k) * dt;
        let f = Vector3::new(80.0 * (3.0 * t).cos(), -40.0 + 30.0 * t, 60.0 * (7.0 * t).sin());
        let dv = f * dt;
        let frames = model.sample(&dv, t, dt, &mut rng);
        let raw = Vector3::new(frames[0].dv_m_s(), frames[1].dv_m_s(), frames[2].dv_m_s());
        let temps = frames.map(|fr| fr.temperature_degc());
        let c = comp.compensate(&raw, &temps, dt).expect("dt");
        let u = ideal.compensate(&raw, &temps, dt).expect("dt");
        worst = worst.max((c - dv).amax());
        worst_uncomp = worst_uncomp.max((u - dv).amax());
        sum_true += dv;
        sum_comp += c;
    }
    println!(
        "per step: compensated {worst:.3e} m/s, uncompensated {worst_uncomp:.3e} m/s; summed over 600 steps: {:.3e} m/s",
        (sum_comp - sum_true).amax()
    );
    assert!(worst < 4.0 * AccelFrame::DV_LSB_M_S, "compensated step error {worst}");
    assert!((sum_comp - sum_true).amax() < 4.0 * AccelFrame::DV_LSB_M_S, "quantisation accumulates");
    assert!(worst_uncomp > 100.0 * worst, "the errors drawn are too small to test anything");
    assert_eq!(comp.compensate(&Vector3::zeros(), &[20.0; 3], 0.0), None);
}
