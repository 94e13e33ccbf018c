//! The streaming decoder against random bytes, bit flips, truncated and spliced frames and
//! garbage: no panic, no bad frame accepted, resync within a frame, every byte accounted for.

use proptest::prelude::*;
use ssis::frames::decoder::{DecoderStats, StreamDecoder};
use ssis::frames::fog::FogFrame;
use ssis::frames::output::OutputFrame;
use ssis::frames::star::StarFrame;
use ssis::frames::{DecodeError, CRC32C};

mod frames_common;
use frames_common::*;

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
        let mut dec: StreamDecoder<StarFrame, 34> = StreamDecoder::new();
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
    let real = FogFrame { fog_id: 1, counter: 0x0042, status: 0, dtheta_counts: 0, temperature_counts: 0x0100 };
    // Candidate = tail (7 bytes) ++ r[0..11]: its dθ is r[0..4], its temperature r[4..6],
    // its reserved byte r[6] (the real frame's status, 0) and its CRC r[7..11], the real
    // frame's dθ, which any value may take: choose it to be the candidate's CRC.
    let tail = [0xEB, 0x90, 0x10, 0x00, 0x42, 0x17, 0x00];
    let mut cand = tail.to_vec();
    cand.extend_from_slice(&real.to_bytes()[..7]);
    let real = FogFrame { dtheta_counts: i32::from_le_bytes(CRC32C.checksum(&cand).to_le_bytes()), ..real };
    let next = FogFrame { counter: 0x0043, ..real };
    let r = real.to_bytes();
    let mut input = vec![0x55; 5];
    input.extend(tail);
    input.extend(r);
    input.extend(next.to_bytes());
    let fed = feed_new::<FogFrame>(&input);
    check_invariants(&input, &fed);
    let oks = fed.oks();
    assert_eq!(oks.len(), 2, "{:?}", fed.results);
    assert_ne!(oks[0], real);
    assert_eq!(&oks[0].to_bytes()[7..], &r[..11]);
    assert_eq!(oks[1], next);
    assert!(check_frame_after_garbage(&input[..5 + 7], &real));
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
        // The CRC-32C detects every pattern of up to 7 flipped bits in a FOG frame.
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
            .filter(|k| input[k * StarFrame::LEN..(k + 1) * StarFrame::LEN] == original[k * StarFrame::LEN..(k + 1) * StarFrame::LEN])
            .count();
        prop_assert_eq!(fed.oks().len(), intact);
    }

    #[test]
    fn truncated_frames_yield_nothing(f in output_frame(), n in 0usize..OutputFrame::LEN) {
        let b = f.to_bytes();
        let fed = feed_new::<OutputFrame>(&b[..n]);
        prop_assert!(fed.results.is_empty());
        check_invariants(&b[..n], &fed);
    }

    #[test]
    fn spliced_frame_is_recovered(a in fog_frame(), b in fog_frame(), n in 1usize..FogFrame::LEN) {
        // A prefix of one frame, then a whole frame.
        let prefix = a.to_bytes()[..n].to_vec();
        check_frame_after_garbage(&prefix, &b);
    }

    #[test]
    fn spliced_output_frame_is_recovered(a in output_frame(), b in output_frame(), n in 1usize..OutputFrame::LEN) {
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
        let mut a: StreamDecoder<FogFrame, 18> = StreamDecoder::new();
        let mut b: StreamDecoder<FogFrame, 18> = StreamDecoder::new();
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
    let mut d: StreamDecoder<FogFrame, 36> = StreamDecoder::new();
    let mut out = Vec::new();
    for &b in input {
        if let Some(r) = d.push(b) {
            out.push(r);
        }
    }
    (out, d.stats())
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
        let mut d: StreamDecoder<FogFrame, 36> = StreamDecoder::new();
        let mut got = Vec::new();
        for c in input.chunks(chunk) {
            d.push_slice(c, |r| got.push(r));
        }
        prop_assert_eq!(got, want);
        prop_assert_eq!(d.stats(), want_stats);
    }
}
