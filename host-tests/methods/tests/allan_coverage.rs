//! The Allan noise terms' 95 % statements cover the truth over a Monte Carlo of sessions,
//! including the sessions too short to resolve the rate random walk (then a bound).

use ssis_methods::allan::{self, Estimate};

/// Whether the statement `e` holds for `truth`: inside the interval, or under the bound.
fn covers(e: &Estimate, truth: f64) -> bool {
    match *e {
        Estimate::Resolved { lo, hi, .. } => lo <= truth && truth <= hi,
        Estimate::UpperBound(b) => truth <= b,
    }
}

/// 2-h sessions at 10 Hz, ARW 0.005 °/√h, no flicker (B = 0), RRW `rrw`: how many of
/// `seeds` sessions' RRW, B and ARW statements hold, and how many resolved RRW.
fn campaign(rrw: f64, seeds: u64) -> ([usize; 3], usize) {
    let (arw, tau0, n) = (0.005, 0.1, 2 * 3600 * 10);
    let mut hold = [0usize; 3];
    let mut resolved = 0;
    for seed in 1..=seeds {
        let rates = allan::simulate_static(arw, rrw, 0.3, tau0, n, 1000 + seed);
        let pts = allan::overlapping_adev(&rates, tau0, 8).expect("adev");
        let nt = allan::noise_terms(&pts).expect("terms");
        let ok = [
            covers(&nt.rrw_deg_h_sqrt_h, rrw),
            covers(&nt.bias_instability_deg_h, 0.0),
            covers(&nt.arw_deg_sqrt_h, arw),
        ];
        for (h, o) in hold.iter_mut().zip(ok) {
            *h += usize::from(o);
        }
        resolved += usize::from(nt.rrw_deg_h_sqrt_h.value().is_some());
        if !ok.iter().all(|&o| o) {
            println!(
                "RRW {rrw} seed {seed}: RRW {}, B {}, ARW {}",
                nt.rrw_deg_h_sqrt_h.text(4),
                nt.bias_instability_deg_h.text(4),
                nt.arw_deg_sqrt_h.text(5)
            );
        }
    }
    (hold, resolved)
}

#[test]
fn rrw_and_bias_instability_statements_cover_the_truth_on_2_h_sessions() {
    const SEEDS: u64 = 40;
    for rrw in [0.01, 0.1] {
        let (hold, resolved) = campaign(rrw, SEEDS);
        println!(
            "RRW {rrw} °/h/√h, {SEEDS} 2-h sessions at 10 Hz: RRW statement holds {}, B {}, ARW {}; RRW resolved {resolved}",
            hold[0], hold[1], hold[2]
        );
        // ≥ 90 % of the seeds (the statements are at 95 %).
        for (what, h) in ["RRW", "B", "ARW"].iter().zip(hold) {
            assert!(h * 10 >= SEEDS as usize * 9, "RRW {rrw}: the {what} statement holds in {h} of {SEEDS}");
        }
    }
}

#[test]
fn nan_and_a_bad_interval_are_refused_with_their_place() {
    let mut r = allan::simulate_static(0.005, 0.01, 0.3, 0.1, 1000, 1);
    r[17] = f64::NAN;
    let e = allan::overlapping_adev(&r, 0.1, 8).expect_err("NaN refused").to_string();
    assert!(e.contains("sample 17"), "{e}");
    r[17] = 0.0;
    assert!(allan::overlapping_adev(&r, 0.0, 8).is_err());
}
