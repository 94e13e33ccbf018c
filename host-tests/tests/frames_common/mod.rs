//! What the frame tests share: encoding helpers, the decoder feed and its invariants, and
//! the proptest strategies for frames and garbage, the ICD's example frames.
#![allow(dead_code)]

use proptest::prelude::*;
use ssis::frames::decoder::{DecoderStats, StreamDecoder};
use ssis::frames::fog::FogFrame;
use ssis::frames::output::{self, OutputCounters, OutputFrame};
use ssis::frames::star::{self, StarFrame};
use ssis::frames::{DecodeError, Frame, CRC32C, CRC_LEN, SYNC};

// ---------------------------------------------------------------------------------------
// Helpers

/// Bytes of any frame through the generic encoder.
pub fn bytes_of<F: Frame>(f: &F) -> Vec<u8> {
    let mut v = vec![0u8; F::LEN];
    assert_eq!(f.encode_into(&mut v), Ok(F::LEN));
    v
}

/// Recomputes the CRC of a frame whose bytes were edited.
pub fn reseal(bytes: &mut [u8]) {
    let n = bytes.len() - CRC_LEN;
    let crc = CRC32C.checksum(&bytes[..n]).to_le_bytes();
    bytes[n..].copy_from_slice(&crc);
}

/// What a decoder returned while taking `bytes`: (index of the byte that completed it,
/// result), and its final stats.
pub struct Fed<F> {
    pub results: Vec<(usize, Result<F, DecodeError>)>,
    pub stats: DecoderStats,
    pub buffered: usize,
}

impl<F: Clone> Fed<F> {
    pub fn oks(&self) -> Vec<F> {
        self.results.iter().filter_map(|(_, r)| r.clone().ok()).collect()
    }
    pub fn errs(&self) -> Vec<DecodeError> {
        self.results.iter().filter_map(|(_, r)| r.clone().err()).collect()
    }
}

pub fn feed<F: Frame + Clone, const CAP: usize>(dec: &mut StreamDecoder<F, CAP>, bytes: &[u8]) -> Fed<F> {
    let results = bytes.iter().enumerate().filter_map(|(i, &b)| dec.push(b).map(|r| (i, r))).collect();
    Fed { results, stats: dec.stats(), buffered: dec.buffered() }
}

pub fn feed_new<F: Frame + Clone>(bytes: &[u8]) -> Fed<F> {
    let mut dec: StreamDecoder<F, 128> = StreamDecoder::new();
    feed(&mut dec, bytes)
}

/// Invariants that hold for any input: every Ok is a CRC-valid window of the input that
/// ends at the byte that completed it; counters agree with what was returned; every byte
/// is accounted for.
pub fn check_invariants<F: Frame + Clone + core::fmt::Debug>(input: &[u8], fed: &Fed<F>) {
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
pub fn check_frame_after_garbage<F: Frame + Clone + PartialEq + core::fmt::Debug>(garbage: &[u8], frame: &F) -> bool {
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

pub fn hex_block(bytes: &[u8]) -> String {
    bytes
        .chunks(16)
        .map(|c| c.iter().map(|b| format!("{b:02X}")).collect::<Vec<_>>().join(" "))
        .collect::<Vec<_>>()
        .join("\n")
}

// ---------------------------------------------------------------------------------------
// Strategies

pub fn fog_frame() -> impl Strategy<Value = FogFrame> + Clone {
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

pub fn unit_quaternion() -> impl Strategy<Value = [f64; 4]> + Clone {
    prop::array::uniform4(-1.0f64..1.0)
        .prop_filter("not near zero", |q| q.iter().map(|c| c * c).sum::<f64>() > 1e-3)
        .prop_map(|q| {
            let n = q.iter().map(|c| c * c).sum::<f64>().sqrt();
            q.map(|c| c / n)
        })
}

pub fn star_frame() -> impl Strategy<Value = StarFrame> + Clone {
    (0u8..4, any::<u16>(), any::<u64>(), unit_quaternion())
        .prop_map(|(flags, counter, time_us, q)| StarFrame::from_physical(flags, counter, time_us, q))
}

pub fn output_frame() -> impl Strategy<Value = OutputFrame> + Clone {
    (
        (any::<u8>(), any::<u16>(), any::<u64>(), any::<[i32; 4]>()),
        (any::<[i32; 3]>(), any::<[i32; 3]>(), any::<i32>()),
        (any::<[u8; 4]>(), any::<u8>(), any::<[u16; 7]>(), any::<(u8, u8, u16)>()),
        (any::<[u16; 3]>(), any::<[u16; 3]>()),
    )
        .prop_map(
            |(
                (flags, counter, time_us, q_counts),
                (rate_counts, drift_counts, parity_counts),
                (fog_health, st_status, c, (fdi, page_id, page_value)),
                (att_sigma_counts, drift_sigma_counts),
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
                    att_sigma_counts,
                    drift_sigma_counts,
                }
            },
        )
}

/// Garbage made to be hard: random bytes, sync bytes, headers of this kind, truncated
/// and corrupted frames of this kind, whole frames of other kinds.
pub fn garbage<F: Frame>(frames: impl Strategy<Value = F> + Clone) -> impl Strategy<Value = Vec<u8>> {
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

// ICD example frames (docs/ICD.md shows exactly these bytes)

pub fn icd_fog_example() -> FogFrame {
    FogFrame::from_physical(1, 258, 0, 2.5e-5, 25.5)
}

pub fn icd_star_example() -> StarFrame {
    StarFrame::from_physical(star::flags::VALID, 7, 1_000_000, [0.5, 0.5, 0.5, 0.5])
}

pub fn icd_output_example() -> OutputFrame {
    let mut f = OutputFrame::from_physical(
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
    );
    // 1.25″ on each axis, 0.0070 °/h.
    f.set_sigmas([1.25 / 206_264.806_247_096_36; 3], [0.007 * std::f64::consts::PI / 180.0 / 3600.0; 3]);
    f
}
