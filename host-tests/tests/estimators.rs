//! The two estimators side by side (the paper's eq. (6) observer, the default, and the
//! MEKF the table may select), on the same flights, seed for seed:
//!
//! - steady-state accuracy on the 2 h Earth-pointing-plus-slews scenario and on the
//!   paper's Fig. 7 case: the attitude error 3σ (|mean| + 3 std per axis after settling)
//!   of each, their ratio, and each against the Farrenkopf limit for the table's noise
//!   figures (`ssis_sim::replay::farrenkopf_1sigma_arcsec`: right after an update, and
//!   averaged over the update period, which is what a statistic taken every step
//!   approaches);
//! - accuracy readiness from a cold start with the paper's pre-calibration random bias
//!   (±0.3 °/h 3σ per FOG): the time after which the attitude error stays, on every axis
//!   and to the end of the run, within twice that estimator's steady-state 3σ (3 × the
//!   per-axis RMS over every seed in the last third of the runs, when the observer's
//!   drift estimate has settled too).
//!
//! The figures are printed; `cargo test --release --test estimators -- --nocapture`
//! gives them (BENCHMARKS.md records them). The readiness statistics over 20 seeds are an
//! ignored test: `cargo test --release --test estimators -- --ignored --nocapture`.

use std::path::Path;

use ssis::calib::{CalibrationTable, Estimator};
use ssis::flight::Profile;
use ssis_sim::harness::run;
use ssis_sim::replay::farrenkopf_1sigma_arcsec;
use ssis_sim::scenario::Scenario;

/// Steady state of an estimator on one scenario (its seed replaced by `seed` if given):
/// 3σ per axis, ″.
fn steady_3sigma(path: &str, estimator: Estimator, seed: Option<u64>) -> [f64; 3] {
    let mut sc = Scenario::from_file(&Path::new(env!("CARGO_MANIFEST_DIR")).join(path)).expect("scenario");
    sc.table.estimator = Some(estimator);
    if let Some(k) = seed {
        sc.seed = k;
    }
    run(&sc, |_| {}).expect("run").accuracy.att.three_sigma()
}

/// The Farrenkopf limit 3σ of a scenario's table: (after an update, period mean), ″.
fn limit_3sigma(path: &str) -> ([f64; 3], [f64; 3]) {
    let sc = Scenario::from_file(&Path::new(env!("CARGO_MANIFEST_DIR")).join(path)).expect("scenario");
    let t = sc.unit_table(&CalibrationTable::DEFAULT).expect("table");
    let l = farrenkopf_1sigma_arcsec(&t.observer, &t.axes(), Profile::SPACECRAFT.dt_s(), 0.0);
    (l.posterior_arcsec.map(|x| 3.0 * x), l.period_mean_arcsec.map(|x| 3.0 * x))
}

fn f3(v: [f64; 3]) -> String {
    format!("{:>7.3} {:>7.3} {:>7.3}", v[0], v[1], v[2])
}

/// Both estimators on `path` (with `seeds`, or the scenario's own seed; each axis's 3σ
/// averaged over them), printed; returns (observer, MEKF, limit after update, period-mean
/// limit), 3σ ″.
fn side_by_side(path: &'static str, seeds: &[u64]) -> ([f64; 3], [f64; 3], [f64; 3], [f64; 3]) {
    let seeds: Vec<Option<u64>> = if seeds.is_empty() { vec![None] } else { seeds.iter().map(|&k| Some(k)).collect() };
    let avg = |e: Estimator| {
        let runs: Vec<[f64; 3]> = seeds.iter().map(|&k| steady_3sigma(path, e, k)).collect();
        [0, 1, 2].map(|a| runs.iter().map(|r| r[a]).sum::<f64>() / runs.len() as f64)
    };
    let (lu, mk) = std::thread::scope(|s| {
        let lu = s.spawn(|| avg(Estimator::Luenberger));
        let mk = s.spawn(|| avg(Estimator::Mekf));
        (lu.join().expect("observer"), mk.join().expect("MEKF"))
    });
    let (post, mean) = limit_3sigma(path);
    let ratio = |a: [f64; 3], b: [f64; 3]| [0, 1, 2].map(|k| a[k] / b[k]);
    println!("{path}, seeds {seeds:?}: attitude error 3σ after settling, ″ (x y z)");
    println!("  observer (eq. 6)             {}", f3(lu));
    println!("  MEKF                         {}", f3(mk));
    println!("  MEKF / observer              {}", f3(ratio(mk, lu)));
    println!("  Farrenkopf 3σ after update   {}", f3(post));
    println!("  Farrenkopf 3σ period mean    {}", f3(mean));
    println!("  observer / limit (after, mean) {} | {}", f3(ratio(lu, post)), f3(ratio(lu, mean)));
    println!("  MEKF / limit (after, mean)     {} | {}", f3(ratio(mk, post)), f3(ratio(mk, mean)));
    (lu, mk, post, mean)
}

#[test]
fn on_two_hours_of_earth_pointing_the_estimators_agree_within_ten_percent() {
    // The limit ratios are printed; one 100-min run estimates a 3σ from few independent
    // samples (the scenario's seed 2 gives 1.11 on y for both, seeds 3–5 at most 1.06):
    // the ignored test below holds the limit over four seeds.
    let (lu, mk, _, _) = side_by_side("scenarios/earth-pointing-2h.toml", &[]);
    for k in 0..3 {
        assert!((mk[k] / lu[k] - 1.0).abs() <= 0.10, "axis {k}: MEKF {:.3}″ vs observer {:.3}″", mk[k], lu[k]);
    }
}

#[test]
#[ignore = "4 seeds × 2 h × 2 estimators: about a minute in release"]
fn over_four_seeds_of_earth_pointing_both_estimators_are_within_1_1_of_the_limit() {
    let (lu, mk, _, mean) = side_by_side("scenarios/earth-pointing-2h.toml", &[2, 3, 4, 5]);
    for k in 0..3 {
        assert!((mk[k] / lu[k] - 1.0).abs() <= 0.10, "axis {k}: MEKF {:.3}″ vs observer {:.3}″", mk[k], lu[k]);
        for (name, v) in [("observer", lu[k]), ("MEKF", mk[k])] {
            assert!(v <= 1.1 * mean[k], "axis {k}: {name} {v:.3}″ > 1.1 × the limit {:.3}″", mean[k]);
        }
    }
}

#[test]
fn on_the_fig7_case_the_mekf_reaches_the_limit() {
    // The observer flies this case on the paper's "given performance" gains (τ = 60 s),
    // not the steady-state Kalman gains: it is printed beside the MEKF, not held to it.
    let (_, mk, _, mean) = side_by_side("scenarios/fig7-bias.toml", &[]);
    for k in 0..3 {
        assert!(mk[k] <= 1.1 * mean[k], "axis {k}: MEKF {:.3}″ > 1.1 × the limit {:.3}″", mk[k], mean[k]);
    }
}

/// A cold start (scenarios/cold-start.toml: orbital rate, the paper's gyro noise and
/// pre-calibration random bias, 0.3 °/h 3σ per FOG, a 20″ (3σ) tracker at 4 Hz; the
/// table states that bias, 0.1 °/h 1σ per FOG, 0.0913 °/h per axis through the
/// combination) of
/// seed `seed` for `duration_s`.
fn cold_start(seed: u64, duration_s: f64, estimator: Estimator) -> Scenario {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios/cold-start.toml");
    let mut sc = Scenario::from_file(&path).expect("scenario");
    sc.seed = seed;
    sc.duration_s = duration_s;
    sc.settle_s = steady_from_s(duration_s);
    sc.table.estimator = Some(estimator);
    sc
}

/// One run's attitude error every step: (t, |err| per axis), ″.
fn errors(sc: &Scenario) -> Vec<(f64, [f64; 3])> {
    let mut v = Vec::with_capacity((sc.duration_s / 0.005) as usize + 1);
    run(sc, |r| v.push((r.t_s, r.att_err_arcsec.map(f64::abs)))).expect("run");
    v
}

/// The steady state of a run of `duration_s`: its last third, from this time, s.
fn steady_from_s(duration_s: f64) -> f64 {
    duration_s * 2.0 / 3.0
}

/// Accuracy readiness of `estimator` over `seeds`: its steady-state 3σ per axis (3 × RMS
/// pooled over the seeds in [`steady_from_s`]) and each seed's time after which
/// every axis stays within twice that, s.
fn readiness(estimator: Estimator, seeds: std::ops::Range<u64>, duration_s: f64) -> ([f64; 3], Vec<f64>) {
    let seeds: Vec<u64> = seeds.collect();
    let runs: Vec<Vec<(f64, [f64; 3])>> = std::thread::scope(|s| {
        let (a, b) = seeds.split_at(seeds.len() / 2);
        let hs: Vec<_> = [a, b]
            .into_iter()
            .map(|part| {
                s.spawn(move || part.iter().map(|&k| errors(&cold_start(k, duration_s, estimator))).collect::<Vec<_>>())
            })
            .collect();
        hs.into_iter().flat_map(|h| h.join().expect("thread")).collect()
    });
    let (mut sum_sq, mut n) = ([0.0; 3], 0.0);
    for (_, e) in runs.iter().flatten().filter(|(t, _)| *t >= steady_from_s(duration_s)) {
        for k in 0..3 {
            sum_sq[k] += e[k] * e[k];
        }
        n += 1.0;
    }
    let ss = sum_sq.map(|s| 3.0 * (s / n).sqrt());
    let ready = runs
        .iter()
        .map(|r| r.iter().filter(|(_, e)| (0..3).any(|k| e[k] > 2.0 * ss[k])).map(|(t, _)| *t).fold(0.0, f64::max))
        .collect();
    (ss, ready)
}

/// Both estimators' readiness over `seeds`, printed; returns (observer, MEKF) times, s.
fn readiness_side_by_side(seeds: std::ops::Range<u64>, duration_s: f64) -> (Vec<f64>, Vec<f64>) {
    let mut out = Vec::new();
    for (name, e) in [("observer (eq. 6)", Estimator::Luenberger), ("MEKF", Estimator::Mekf)] {
        let (ss, mut ready) = readiness(e, seeds.clone(), duration_s);
        let mean = ready.iter().sum::<f64>() / ready.len() as f64;
        ready.sort_by(f64::total_cmp);
        let median = ready[ready.len() / 2];
        let max = ready[ready.len() - 1];
        println!(
            "{name}: steady 3σ {}″; within 2× of it from a cold start after mean {mean:.1} s, median {median:.1} s, \
             max {max:.1} s over {} seeds",
            f3(ss),
            ready.len()
        );
        out.push(ready);
    }
    let mk = out.pop().unwrap_or_default();
    let lu = out.pop().unwrap_or_default();
    (lu, mk)
}

fn mean(v: &[f64]) -> f64 {
    v.iter().sum::<f64>() / v.len() as f64
}

#[test]
fn from_a_cold_start_the_mekf_is_ready_three_times_sooner() {
    let (lu, mk) = readiness_side_by_side(0..4, 2400.0);
    assert!(mk.iter().all(|&t| t <= 120.0), "MEKF readiness {mk:?} s, goal ≤ 120 s");
    assert!(3.0 * mean(&mk) <= mean(&lu), "MEKF {:.1} s vs observer {:.1} s: not 3× sooner", mean(&mk), mean(&lu));
}

#[test]
#[ignore = "20 seeds × 90 min × 2 estimators: about three minutes in release"]
fn readiness_over_twenty_seeds() {
    let (lu, mk) = readiness_side_by_side(0..20, 5400.0);
    assert!(mk.iter().all(|&t| t <= 120.0), "MEKF readiness {mk:?} s, goal ≤ 120 s");
    assert!(3.0 * mean(&mk) <= mean(&lu), "MEKF {:.1} s vs observer {:.1} s: not 3× sooner", mean(&mk), mean(&lu));
}

#[test]
fn through_a_ten_minute_outage_the_mekf_reports_its_own_error() {
    // 16 seeds of the cold start, star tracker off from 300 s to 900 s: at the end of the
    // outage the RMS error over seeds and axes (48 samples) against the mean reported 1σ.
    // The process noise and the bias prior are the combination's (σ² (SᵀS)⁻¹, 5/6 per
    // axis for the four FOGs): ratio 0.82 here (0.76 with one FOG's figures per axis).
    // 48 samples know the RMS to about 10 %, so this asserts only that the reported 1σ
    // is not optimistic (≤ 1.20); the 20 % goal is asserted from steady state on 72
    // samples for both estimators (tests/faults.rs). After the return the error is back
    // within 6″ in 30 s.
    const SEEDS: u64 = 16;
    let (end_s, back_s) = (900.0, 930.0);
    let one = |seed: u64| {
        let mut sc = cold_start(seed, back_s, Estimator::Mekf);
        sc.star_tracker.outages = vec![[300.0, end_s]];
        let (mut at_end, mut worst_after) = (None, 0.0f64);
        let s = run(&sc, |r| {
            if at_end.is_none() && r.t_s >= end_s - 0.005 {
                at_end = Some((r.att_err_arcsec, r.out.att_sigma_rad.map(|x| x * 206_264.806_247_096_36)));
            }
            if r.t_s >= back_s - 5.0 {
                worst_after = r.att_err_arcsec.iter().fold(worst_after, |m, e| m.max(e.abs()));
            }
        })
        .expect("run");
        (at_end.expect("outage end reached"), worst_after, s.counters.st_updates_gated)
    };
    let runs: Vec<_> = std::thread::scope(|s| {
        let hs: Vec<_> = [0..SEEDS / 2, SEEDS / 2..SEEDS]
            .into_iter()
            .map(|part| s.spawn(move || part.map(one).collect::<Vec<_>>()))
            .collect();
        hs.into_iter().flat_map(|h| h.join().expect("thread")).collect()
    });
    let n = (3 * runs.len()) as f64;
    let rms = (runs.iter().flat_map(|((e, _), _, _)| e.iter().map(|x| x * x)).sum::<f64>() / n).sqrt();
    let sigma = runs.iter().flat_map(|((_, s), _, _)| s.iter().copied()).sum::<f64>() / n;
    let worst = runs.iter().map(|(_, w, _)| *w).fold(0.0, f64::max);
    let gated: u32 = runs.iter().map(|(_, _, g)| *g).sum();
    println!(
        "MEKF, 10-min outage, {SEEDS} seeds: at its end RMS error {rms:.2}″, reported 1σ {sigma:.2}″ (ratio {:.3}); \
         worst error 25-30 s after the return {worst:.2}″; frames gated {gated}",
        rms / sigma
    );
    assert!(rms / sigma <= 1.20, "RMS {rms:.2}″ against the reported {sigma:.2}″: optimistic");
    assert!(worst <= 6.0, "error {worst:.2}″ 25-30 s after the return");
}
