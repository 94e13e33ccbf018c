//! Frame corruption through the flight stream decoder: 100,000 trials of
//! corrupted frames between intact ones (`ssis_sim::corrupt`); the 10^8-trial figure is
//! `ssis-corrupt-bench` (BENCHMARKS.md).

use ssis_sim::corrupt::{corrupt, run_trials, Corruption};

#[test]
fn corrupted_frames_are_refused_and_the_decoder_resynchronises() {
    let n = 100_000;
    let r = run_trials(n, 6);
    println!("{}", r.table());
    let t = r.total();
    assert_eq!(t.trials, n);
    for (k, kind) in Corruption::ALL.iter().enumerate() {
        let c = r.by_kind(k);
        assert!(c.trials >= n / 6 - 8, "{kind:?}");
        if kind.guaranteed_by_crc() {
            // 1-5 bit errors and bursts up to 32 bits: the CRC-32C detects every one.
            assert_eq!(c.corrupted_accepted, 0, "{kind:?}");
            assert_eq!(c.next_lost, 0, "{kind:?}");
        }
    }
    // Resynchronisation within one frame: the second intact frame after a corrupted one
    // is always decoded, and an intact frame is only ever lost inside an accepted
    // candidate (a CRC collision), never otherwise.
    assert_eq!(t.second_lost, 0);
    assert_eq!(t.lost_without_collision, 0);
    assert!(t.next_lost <= t.corrupted_accepted + t.recovered);
    // The other kinds can collide: a damaged candidate passes the CRC-32C with probability
    // about 2^-32 (and must then pass the field checks). Over the ~66,700 such trials the
    // expected count is ~1.6e-5; one is a weaker check than the CRC's.
    assert_eq!(t.corrupted_accepted, 0, "{} corrupted frames accepted", t.corrupted_accepted);
}

#[test]
fn corruptions_always_change_the_frame() {
    use rand::SeedableRng;
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(1);
    let frame: Vec<u8> = (0..79u8).collect();
    for kind in Corruption::ALL {
        for _ in 0..2_000 {
            let c = corrupt(&mut rng, &frame, kind);
            assert_ne!(c, frame, "{kind:?}");
            match kind {
                Corruption::Truncation => assert!(c.len() < frame.len()),
                Corruption::Insertion => assert!(c.len() > frame.len() && c[0] == frame[0]),
                _ => assert_eq!(c.len(), frame.len()),
            }
        }
    }
}
