//! GNSS fix frame (kind 0x21) and navigation output frame (kind 0x31) of the
//! launch-vehicle unit: layouts against the `docs/ICD.md` examples
//! (computed independently of the Rust code), round trips, validity rules, a GNSS stream
//! with corruption through the stream decoder.

use nalgebra::{Quaternion, Vector3};
use ssis::frames::decoder::StreamDecoder;
use ssis::frames::gnss::{status, GnssFrame};
use ssis::frames::navout::{flags, NavOutputFrame, POS_LSB_M, Q_LSB, VEL_LSB_M_S};
use ssis::frames::{kind, DecodeError, Frame};
use ssis::nav::gnss::GnssFix;
use ssis::nav::NavState;

fn hex(s: &str) -> Vec<u8> {
    s.split_whitespace().map(|b| u8::from_str_radix(b, 16).expect("hex")).collect()
}

fn example_fix() -> GnssFix {
    GnssFix {
        r_e_m: Vector3::new(2_000_000.0, 4_000_000.5, 4_500_000.25),
        v_e_m_s: Vector3::new(-100.0, 250.5, 7000.125),
        sigma_pos_m: 5.0,
        sigma_vel_m_s: 0.1,
    }
}

#[test]
fn gnss_icd_example_and_validity() {
    assert_eq!((GnssFrame::LEN, <GnssFrame as Frame>::KIND, kind::GNSS), (47, 0x21, 0x21));
    let f = GnssFrame::from_physical(status::FIX_VALID | status::FIX_3D, 7, 12, 600_000_000, &example_fix());
    let b = f.to_bytes();
    let expected = hex(
        "EB 90 21 03 07 00 0C 00 46 C3 23 00 00 00 00 00 80 84 1E 80 00 09 3D 40 20 AA 44 00 00 9C FF 00 80 FA 00 \
         00 20 58 1B F4 01 64 00 8A 05 3B 8B",
    );
    assert_eq!(b.to_vec(), expected);
    assert_eq!(GnssFrame::decode(&b), Ok(f));
    assert_eq!(f.fix(), Some(example_fix()));
    // Not valid, or receiver fault: decodes, but no fix.
    assert_eq!(GnssFrame { status: status::FIX_3D, ..f }.fix(), None);
    assert_eq!(GnssFrame { status: status::FIX_VALID | status::RECEIVER_FAULT, ..f }.fix(), None);
    // A zero sigma is read as one LSB.
    let z = GnssFrame { sigma_pos_counts: 0, sigma_vel_counts: 0, ..f }.fix().expect("fix");
    assert!(z.sigma_pos_m > 0.0 && z.sigma_vel_m_s > 0.0);
    // Reserved bits are refused.
    let bad = GnssFrame { status: 0x08 | status::FIX_VALID, ..f };
    assert_eq!(GnssFrame::decode(&bad.to_bytes()), Err(DecodeError::BadField));
    // NaN encodes as 0 and sigmas saturate.
    let nan = GnssFix { r_e_m: Vector3::new(f64::NAN, 0.0, 0.0), sigma_pos_m: 1e9, ..example_fix() };
    let g = GnssFrame::from_physical(1, 0, 0, 0, &nan);
    assert_eq!((g.r_counts[0], g.sigma_pos_counts), (0, u16::MAX));
}

#[test]
fn gnss_stream_with_corruption() {
    let mut stream = Vec::new();
    let mut expected = Vec::new();
    for k in 0..200u16 {
        let mut fix = example_fix();
        fix.r_e_m.x += f64::from(k) * 7.5;
        let f = GnssFrame::from_physical(status::FIX_VALID, k, 9, u64::from(k) * 1_000_000, &fix);
        let mut b = f.to_bytes();
        if k % 7 == 3 {
            b[20] ^= 0x40; // corrupted: CRC error
        } else {
            expected.push(f);
        }
        if k % 11 == 5 {
            stream.extend_from_slice(&[0xEB, 0x90, 0x21, 0x01, 0x02]); // a false start
        }
        stream.extend_from_slice(&b);
    }
    let mut dec: StreamDecoder<GnssFrame, 64> = StreamDecoder::new();
    let mut got = Vec::new();
    for chunk in stream.chunks(13) {
        dec.push_slice(chunk, |r| {
            if let Ok(f) = r {
                got.push(f);
            }
        });
    }
    let s = dec.stats();
    println!("{s:?}");
    assert_eq!(got, expected);
    assert!(s.crc_errors >= 200 / 7, "{s:?}");
}

#[test]
fn nav_output_icd_example_and_round_trip() {
    assert_eq!((NavOutputFrame::LEN, <NavOutputFrame as Frame>::KIND, kind::NAV_OUTPUT), (66, 0x31, 0x31));
    let fix = example_fix();
    let st = NavState { q_eb: Quaternion::new(0.5, -0.5, 0.5, 0.5), v_e_m_s: fix.v_e_m_s, r_e_m: fix.r_e_m };
    let f = NavOutputFrame::from_physical(flags::GNSS_UPDATED, 9, 1_250_000, &st, (1.5, 0.05), (570, 0));
    let b = f.to_bytes();
    let expected = hex(
        "EB 90 31 01 09 00 D0 12 13 00 00 00 00 00 00 00 00 40 00 00 00 C0 00 00 00 40 00 00 00 40 00 00 9C FF 00 \
         80 FA 00 00 20 58 1B 00 80 84 1E 80 00 09 3D 40 20 AA 44 96 00 32 00 3A 02 00 00 17 D1 36 5D",
    );
    assert_eq!(b.to_vec(), expected);
    assert_eq!(NavOutputFrame::decode(&b), Ok(f));
    let back = f.state();
    assert!((back.r_e_m - st.r_e_m).amax() <= 0.5 * POS_LSB_M);
    assert!((back.v_e_m_s - st.v_e_m_s).amax() <= 0.5 * VEL_LSB_M_S);
    assert!((back.q_eb.coords - st.q_eb.coords).amax() <= Q_LSB);
    // Counters saturate at 65,535.
    let big = NavOutputFrame::from_physical(0, 0, 0, &st, (0.0, 0.0), (70_000, 1));
    assert_eq!((big.fixes_used, big.fixes_refused), (u16::MAX, 1));
    // A GNSS frame is not a navigation output frame.
    let g = GnssFrame::from_physical(1, 0, 0, 0, &fix).to_bytes();
    assert_eq!(NavOutputFrame::decode(&g), Err(DecodeError::BadLength));
}
