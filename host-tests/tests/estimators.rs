//! The two estimators side by side (the paper's eq. (6) observer, the default, and the
//! MEKF the table may select), on the same flights, seed for seed:
//!
//! - steady-state accuracy on the 2 h Earth-pointing-plus-slews scenario and on the
//!   paper's Fig. 7 case: the attitude error 3σ (|mean| + 3 std per axis after settling)
//!   of each seed and estimator, the mean over the seeds with its standard error, the
//!   estimators' ratio, and each against the estimation limit for the scenario's sensors
//!   (`ssis_sim::replay::farrenkopf_1sigma_arcsec` with the tracker's latency: the
//!   Farrenkopf steady state averaged over the update period with every age moved by the
//!   latency, the bound for a statistic taken every step when no estimator can use a
//!   solution before it arrives; docs/RECORDED-LOG.md). On the Fig. 7 case the observer
//!   flies two stages: the paper's τ = 60 s gains for the table's acquisition time, then
//!   the steady-state Kalman gains; the τ = 60 s gains alone are shown beside, and their
//!   steady state computed (`ssis_sim::replay::loop_1sigma_arcsec`);
//! - accuracy readiness from a cold start with the paper's pre-calibration random bias
//!   (±0.3 °/h 3σ per FOG): the time after which the attitude error stays, on every axis
//!   and to the end of the run, within twice that estimator's steady-state 3σ (3 × the
//!   per-axis RMS over every seed in the last third of the runs, when the observer's
//!   drift estimate has settled too).
//!
//! **Spread of a 3σ figure.** One run's 3σ is a standard deviation estimated from
//! correlated samples (5-ms steps, correlated over the loop's time constants): its
//! relative spread is about 1/√(2 N_eff) for N_eff independent samples, and N_eff is far
//! fewer than the steps (the tests print the spread over the seeds and the N_eff it
//! implies). The mean of N seeds' figures has a standard error of the seeds' standard
//! deviation over √N; that is what the 10 % and 1.1× are judged on.
//!
//! The figures are printed; `cargo test --release --test estimators -- --nocapture`
//! gives them (BENCHMARKS.md records them). The full figures (more seeds) and the
//! readiness statistics over 20 seeds are ignored tests:
//! `cargo test --release --test estimators -- --ignored --nocapture`.

use std::path::Path;

use ssis::calib::{CalibrationTable, Estimator, ObserverGains};
use ssis::flight::Profile;
use ssis::observer::steady_state_gains;
use ssis_sim::harness::run;
use ssis_sim::replay::{farrenkopf_1sigma_arcsec, loop_1sigma_arcsec};
use ssis_sim::scenario::Scenario;

/// Fig. 7: the paper's zero bias, inertial hold, 1800 s (statistics from 900 s).
const FIG7: &str = "scenarios/fig7-bias.toml";
/// 2 h of Earth pointing with three slews (statistics from 1200 s).
const EARTH: &str = "scenarios/earth-pointing-2h.toml";

/// What flies.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Flown {
    /// The eq. (6) observer as the table says (two stages where it sets an acquisition).
    Observer,
    /// The eq. (6) observer on the table's override gains throughout (acquisition 0).
    OneStage,
    /// The MEKF.
    Mekf,
}

impl Flown {
    fn name(self) -> &'static str {
        match self {
            Flown::Observer => "observer (eq. 6)",
            Flown::OneStage => "observer, τ = 60 s gains only",
            Flown::Mekf => "MEKF",
        }
    }
}

fn load(path: &str) -> Scenario {
    Scenario::from_file(&Path::new(env!("CARGO_MANIFEST_DIR")).join(path)).expect("scenario")
}

/// Steady state of one run: 3σ per axis, ″.
fn steady_3sigma(path: &str, flown: Flown, seed: u64) -> [f64; 3] {
    let mut sc = load(path);
    sc.seed = seed;
    sc.table.estimator = Some(if flown == Flown::Mekf { Estimator::Mekf } else { Estimator::Luenberger });
    if flown == Flown::OneStage {
        if let Some(o) = sc.table.observer.as_mut() {
            o.acquisition_s = 0.0;
        }
    }
    run(&sc, |_| {}).expect("run").accuracy.att.three_sigma()
}

/// The table the scenario's unit flies, the scenario's tracker latency (s) and the
/// limit 3σ per axis for its sensors (period mean with that latency), ″.
fn limit_3sigma(path: &str) -> (CalibrationTable, f64, [f64; 3]) {
    let sc = load(path);
    let t = sc.unit_table(&CalibrationTable::DEFAULT).expect("table");
    let latency_s = sc.star_tracker.latency_ms * 1e-3;
    let l = farrenkopf_1sigma_arcsec(&t.observer, &t.axes(), Profile::SPACECRAFT.dt_s(), latency_s);
    (t, latency_s, l.latency_mean_arcsec.map(|x| 3.0 * x))
}

fn f3(v: [f64; 3]) -> String {
    format!("{:>7.3} {:>7.3} {:>7.3}", v[0], v[1], v[2])
}

/// Per axis over runs: (mean, standard deviation over the runs).
fn mean_sd(runs: &[[f64; 3]]) -> ([f64; 3], [f64; 3]) {
    let n = runs.len() as f64;
    let m = [0, 1, 2].map(|a| runs.iter().map(|r| r[a]).sum::<f64>() / n);
    let sd = [0, 1, 2].map(|a| (runs.iter().map(|r| (r[a] - m[a]).powi(2)).sum::<f64>() / (n - 1.0).max(1.0)).sqrt());
    (m, sd)
}

/// Side by side on `path` over `seeds`: each run's 3σ, printed with the pooled figures;
/// returns the mean 3σ over the seeds per axis of each of `flown` (in order) and the limit.
fn side_by_side(path: &str, seeds: &[u64], flown: &[Flown]) -> (Vec<[f64; 3]>, [f64; 3]) {
    // Every (flown, seed) run, shared out over the two cores.
    let jobs: Vec<(Flown, u64)> = flown.iter().flat_map(|&f| seeds.iter().map(move |&k| (f, k))).collect();
    let done: Vec<((Flown, u64), [f64; 3])> = std::thread::scope(|s| {
        let hs: Vec<_> = [0, 1]
            .map(|half| {
                let mine: Vec<(Flown, u64)> = jobs.iter().copied().skip(half).step_by(2).collect();
                s.spawn(move || mine.into_iter().map(|(f, k)| ((f, k), steady_3sigma(path, f, k))).collect::<Vec<_>>())
            })
            .into_iter()
            .collect();
        hs.into_iter().flat_map(|h| h.join().expect("thread")).collect()
    });
    let of = |f: Flown| -> Vec<[f64; 3]> {
        seeds.iter().map(|&k| done.iter().find(|(j, _)| *j == (f, k)).map(|(_, v)| *v).expect("run")).collect()
    };
    let (_, latency_s, limit) = limit_3sigma(path);
    println!("{path}, {} seeds: attitude error 3σ after settling (|mean| + 3 std per axis), ″ (x y z)", seeds.len());
    println!("  seed  {}", flown.iter().map(|f| format!("{:<26}", f.name())).collect::<Vec<_>>().join(" | "));
    for (i, k) in seeds.iter().enumerate() {
        let row: Vec<String> = flown.iter().map(|&f| f3(of(f)[i])).collect();
        println!("  {k:>4}  {}", row.join(" | "));
    }
    let mut pooled = Vec::new();
    for &f in flown {
        let runs = of(f);
        let (m, sd) = mean_sd(&runs);
        let se = sd.map(|x| x / (runs.len() as f64).sqrt());
        // One run's relative spread s/m ≈ 1/√(2 N_eff): the independent samples per run.
        let n_eff = [0, 1, 2].map(|a| 0.5 * (m[a] / sd[a]).powi(2));
        println!(
            "  {:<30} mean {} ± {} (standard error); one run's spread {} % → N_eff ≈ {:.0} / {:.0} / {:.0}",
            f.name(),
            f3(m),
            f3(se),
            f3([0, 1, 2].map(|a| 100.0 * sd[a] / m[a])),
            n_eff[0],
            n_eff[1],
            n_eff[2]
        );
        pooled.push(m);
    }
    println!("  limit 3σ (period mean, tracker latency {:.3} s) {}", latency_s, f3(limit));
    for (&f, m) in flown.iter().zip(&pooled) {
        println!("  {:<30} / limit {}", f.name(), f3([0, 1, 2].map(|a| m[a] / limit[a])));
    }
    if let (Some(lu), Some(mk)) =
        (flown.iter().position(|&f| f == Flown::Observer), flown.iter().position(|&f| f == Flown::Mekf))
    {
        println!("  MEKF / observer (means)          {}", f3([0, 1, 2].map(|a| pooled[mk][a] / pooled[lu][a])));
    }
    (pooled, limit)
}

/// The goal: the two estimators' mean 3σ within 10 % of each other and
/// each ≤ 1.1 × the limit, per axis.
fn assert_side_by_side(what: &str, lu: [f64; 3], mk: [f64; 3], limit: [f64; 3]) {
    for k in 0..3 {
        assert!((mk[k] / lu[k] - 1.0).abs() <= 0.10, "{what}, axis {k}: MEKF {:.3}″ vs observer {:.3}″", mk[k], lu[k]);
        for (name, v) in [("observer", lu[k]), ("MEKF", mk[k])] {
            assert!(v <= 1.1 * limit[k], "{what}, axis {k}: {name} {v:.3}″ > 1.1 × the limit {:.3}″", limit[k]);
        }
    }
}

#[test]
fn the_paper_gains_alone_cannot_hold_the_fig7_attitude_within_ten_percent_of_the_limit() {
    // The per-axis steady state of eq. (6) with fixed gains (Joseph form per update, the
    // gyros' random walks between), on the Fig. 7 table's sensors, 50 ms latency.
    let (t, latency_s, _) = limit_3sigma(FIG7);
    let dt = Profile::SPACECRAFT.dt_s();
    let one =
        |g: Option<ObserverGains>| loop_1sigma_arcsec(&t.observer, &t.axes(), dt, latency_s, g).latency_mean_arcsec[0];
    let kalman = one(None);
    let paper = t.observer.gains_override.expect("the Fig. 7 table overrides the gains");
    let steady = steady_state_gains(&t.observer).expect("gains");
    println!("Fig. 7 table, attitude 1σ per axis in steady state (period mean, {latency_s} s latency):");
    println!("  Kalman limit                              {kalman:.3}″");
    for (name, g) in [
        ("τ = 60 s, K_B 0.00833, K_U 6.94e-5 /s", paper),
        ("steady-state gains (second stage)", steady),
        ("critically damped τ = 30 s", ObserverGains::critically_damped(30.0, 0.25)),
        ("critically damped τ = 120 s", ObserverGains::critically_damped(120.0, 0.25)),
    ] {
        let s = one(Some(g));
        println!("  {name:<40}  {s:.3}″  ({:.3} × the limit)", s / kalman);
    }
    let r = one(Some(paper)) / kalman;
    assert!(r > 1.2 && r < 1.23, "τ = 60 s gains: {r:.3} × the limit");
    // The steady-state gains are the Kalman gains for one gyro's ARW; the four FOGs'
    // least squares leave 5/6 of it per axis, which the limit counts: 0.2 % above.
    let r2 = one(Some(steady)) / kalman;
    assert!(r2 < 1.005, "steady-state gains: {r2:.4} × the limit");
}

#[test]
fn on_the_fig7_case_the_estimators_agree_within_ten_percent_and_reach_the_limit() {
    // Eight seeds: one 900-s window's 3σ spreads by about 8 %, the mean of eight by 3 %.
    let (p, limit) = side_by_side(FIG7, &(1..=8).collect::<Vec<_>>(), &[Flown::Observer, Flown::Mekf]);
    assert_side_by_side("Fig. 7", p[0], p[1], limit);
}

#[test]
fn on_two_hours_of_earth_pointing_the_estimators_agree_within_ten_percent_and_reach_the_limit() {
    // Four seeds of 2 h (the scenario's own seed 2 and three more).
    let (p, limit) = side_by_side(EARTH, &[2, 3, 4, 5], &[Flown::Observer, Flown::Mekf]);
    assert_side_by_side("earth-pointing-2h", p[0], p[1], limit);
}

#[test]
#[ignore = "32 seeds of Fig. 7 × 3 and 16 seeds of 2 h × 2: a few minutes in release"]
fn side_by_side_full_figures() {
    let seeds: Vec<u64> = (1..=32).collect();
    let (p, limit) = side_by_side(FIG7, &seeds, &[Flown::Observer, Flown::Mekf, Flown::OneStage]);
    assert_side_by_side("Fig. 7", p[0], p[1], limit);
    let seeds: Vec<u64> = (2..=17).collect();
    let (p, limit) = side_by_side(EARTH, &seeds, &[Flown::Observer, Flown::Mekf]);
    assert_side_by_side("earth-pointing-2h", p[0], p[1], limit);
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
