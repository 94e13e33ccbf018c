//! The power study: does the size `diagnose` states as detectable hold?
//!
//! Sessions from the lab's own generator ([`power_session`]: static in the chamber, ARW
//! 0.005 °/√h, with or without a Gauss–Markov bias wander, the field turning as in orbit, a
//! supply-voltage column), one effect on one FOG: each catalog term the lab is asked about
//! (temp_rate, thermal_t1, aging, magnetic), a user column and a sinusoid. For each seed the
//! session without the effect (the same noise) is diagnosed first: its statement of the
//! minimum detectable effect ([`ssis_lab::detectable`]) is the size put in; then the
//! session with the effect at that size and at half of it is diagnosed, and the effect
//! counts as found when its candidate is significant (a sinusoid: a significant line
//! within 1 % of its frequency). On white noise the lab is also compared with the optimal
//! test on the same split: the GLS (here ordinary, the noise being white and known) F-test
//! of the true regressors on the test blocks at the lab's own level, whose minimum
//! detectable effect is computed exactly.
//!
//! `cargo test --release -p ssis-lab --test power -- --nocapture` runs a reduced study;
//! `… --test power -- --ignored --nocapture` the full sweep (effect size, period, session
//! length and sample rate; figures in BENCHMARKS.md), or a part of it: `POWER_CONFIGS=0,3`
//! (indices into its configurations), `POWER_EFFECTS=sinusoid,magnetic` (labels containing
//! a word), `POWER_SEEDS=12`, `POWER_SEED0=0` (the first seed), `POWER_PERIODS=600,2400`,
//! `POWER_OPT=1,1.3` (multiples of the optimal test's MDE tried; empty: none),
//! `POWER_VERBOSE=1` (each miss's lines).

use ssis_lab::detectable::{lambda_required, min_coef, POWER};
use ssis_lab::diagnose::{diagnose, Diagnosis, Options};
use ssis_lab::model::{Catalog, Kind, Model};
use ssis_lab::session::{session_from_columns, Session};
use ssis_lab::simulate::{power_session, PowerEffect, PowerSession, PowerSpec};

/// The session in memory.
fn session(p: &PowerSession) -> Session {
    let s = &p.sim;
    let cols: Vec<Vec<f64>> = (0..s.header.len()).map(|k| s.rows.iter().map(|r| r[k]).collect()).collect();
    session_from_columns("power.csv", s.header.clone(), &cols).unwrap()
}

fn model(e: PowerEffect) -> Model {
    let mut k = vec![Kind::Catalog(Catalog::Bias)];
    if e != PowerEffect::ThermalT1 {
        k.push(Kind::Catalog(Catalog::ThermalT1));
    }
    Model::new(&k)
}

fn label(e: PowerEffect) -> String {
    match e {
        PowerEffect::TempRate => "temp_rate".into(),
        PowerEffect::ThermalT1 => "thermal_t1".into(),
        PowerEffect::Aging => "aging".into(),
        PowerEffect::Magnetic => "magnetic".into(),
        PowerEffect::Column => "expr:supply_v".into(),
        PowerEffect::Sinusoid { period_s } => format!("sinusoid {period_s:.0} s"),
        PowerEffect::None => "none".into(),
    }
}

/// The size the diagnosis states as detectable for the effect on FOG `fog`, SI.
fn stated(d: &Diagnosis, e: PowerEffect, fog: usize) -> Option<f64> {
    match e {
        PowerEffect::Sinusoid { period_s } => d.detectable.sinusoid.as_ref()?.at(period_s),
        _ => d.detectable.terms.iter().find(|t| t.term == label(e))?.per_fog.get(fog).copied().flatten(),
    }
}

/// Whether the diagnosis finds the effect: its candidate significant; a sinusoid's, a
/// significant line within 1 % of its frequency or, where 1 % is finer than the session
/// resolves (periods beyond 1 % of the span), within half its resolution 1/(2 span).
fn found(d: &Diagnosis, e: PowerEffect, span_s: f64) -> bool {
    d.significant().any(|c| match (e, &c.kind) {
        (PowerEffect::Sinusoid { period_s }, Kind::Sinusoid(f)) => {
            (f - 1.0 / period_s).abs() < (0.01 / period_s).max(0.5 / span_s)
        }
        (PowerEffect::Sinusoid { .. }, _) => false,
        _ => c.kind.label() == label(e),
    })
}

/// The optimal test's minimum detectable effect on the same split: the true regressors of
/// the effect FOG beside the true base on the test blocks, the white noise's σ known, at
/// level `alpha`.
fn optimal_mde(p: &PowerSession, blocks: usize, alpha: f64) -> Option<f64> {
    let n = p.regressors.len();
    let test: Vec<usize> = (0..n).filter(|&j| (j * blocks / n) % 2 == 1).collect();
    let (k0, q) = (p.base[0].len(), p.regressors[0].len());
    let x = nalgebra::DMatrix::from_fn(test.len(), k0 + q, |r, c| {
        let j = test[r];
        if c < k0 {
            p.base[j][c]
        } else {
            p.regressors[j][c - k0]
        }
    });
    let g = x.transpose() * &x;
    // Schur complement of the base block: the candidate's information.
    let a = g.view((0, 0), (k0, k0)).clone_owned();
    let b = g.view((0, k0), (k0, q)).clone_owned();
    let c = g.view((k0, k0), (q, q)).clone_owned();
    let s = c - b.transpose() * a.cholesky()?.solve(&b);
    let sigma2 = p.sim.truth.noise_rad_s.powi(2);
    let info: Vec<f64> = (0..q * q).map(|i| s[(i / q, i % q)] / sigma2).collect();
    min_coef(&info, lambda_required(q, alpha, POWER))
}

#[derive(Default, Clone, Copy)]
struct Tally {
    n: usize,
    hit: usize,
}

impl Tally {
    fn add(&mut self, hit: bool) {
        self.n += 1;
        self.hit += usize::from(hit);
    }
    fn rate(&self) -> f64 {
        self.hit as f64 / self.n.max(1) as f64
    }
}

impl std::fmt::Display for Tally {
    fn fmt(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
        write!(f, "{:>3}/{:<3} {:>5.1} %", self.hit, self.n, 100.0 * self.rate())
    }
}

/// One cell of the study: `seeds` sessions of (dt, hours, wander) with effect `e`.
struct Cell {
    at_stated: Tally,
    at_half: Tally,
    /// Detection at each multiple of the optimal test's MDE.
    at_opt: Vec<(f64, Tally)>,
    null_flagged: Tally,
    stated_eng: Vec<f64>,
    opt_eng: Vec<f64>,
}

fn run_cell(e: PowerEffect, dt_s: f64, hours: f64, wander: bool, seeds: u64, opt_mult: &[f64]) -> Cell {
    let opt = Options::default();
    let mut cell = Cell {
        at_stated: Tally::default(),
        at_half: Tally::default(),
        at_opt: opt_mult.iter().map(|&m| (m, Tally::default())).collect(),
        null_flagged: Tally::default(),
        stated_eng: Vec::new(),
        opt_eng: Vec::new(),
    };
    let unit = match e {
        PowerEffect::Sinusoid { .. } => Kind::Sinusoid(1.0).eng_units(0)[0].1,
        _ => Kind::parse_arg(label(e).trim_start_matches("expr:")).map(|k| k.eng_units(0)[0].1).unwrap_or(1.0),
    };
    // POWER_SEED0: the first seed (a fresh set of draws); POWER_VERBOSE: each miss's lines.
    let seed0: u64 = std::env::var("POWER_SEED0").ok().and_then(|v| v.parse().ok()).unwrap_or(0);
    let verbose = std::env::var("POWER_VERBOSE").is_ok();
    for seed in seed0..seed0 + seeds {
        let fog = (seed % 4) as usize;
        let spec = PowerSpec { seed: 1000 + seed, dt_s, hours, effect: e, size: 0.0, fog, wander };
        let null = power_session(&spec);
        let d0 = diagnose(&model(e), &session(&null), &opt).unwrap();
        cell.null_flagged.add(d0.significant().next().is_some());
        let Some(mde) = stated(&d0, e, fog) else { continue };
        cell.stated_eng.push(mde * unit);
        let with = |size: f64| {
            let p = power_session(&PowerSpec { size, ..spec });
            let d = diagnose(&model(e), &session(&p), &opt).unwrap();
            let hit = found(&d, e, hours * 3600.0);
            if verbose && !hit {
                let lines: Vec<String> = d
                    .candidates
                    .iter()
                    .filter(|c| matches!(c.kind, Kind::Sinusoid(_)) || c.significant || c.kind.label() == label(e))
                    .map(|c| {
                        // The effect FOG's two tests and held-out RMS (both tests must reject
                        // and the RMS fall).
                        let t = c.per_fog.get(fog).and_then(|t| t.as_ref()).map_or(String::new(), |t| {
                            format!(
                                " [FOG{fog}: p_F {:.1e} p_dir {:.1e} RMS {:.4e} -> {:.4e}]",
                                t.p_f, t.p_dir, t.before_rad_s, t.after_rad_s
                            )
                        });
                        format!(
                            "{} p {:.1e}{}{t} ({})",
                            c.kind.label(),
                            c.p_value,
                            if c.significant { " *" } else { "" },
                            c.origin
                        )
                    })
                    .collect();
                println!("  miss seed {seed} size {size:.3e}: {}", lines.join("; "));
            }
            hit
        };
        cell.at_stated.add(with(mde));
        cell.at_half.add(with(0.5 * mde));
        if !wander {
            if let Some(o) = optimal_mde(&null, opt.n_blocks, d0.detectable.alpha_per_fog) {
                cell.opt_eng.push(o * unit);
                for (m, t) in cell.at_opt.iter_mut() {
                    t.add(with(*m * o));
                }
            }
        }
    }
    cell
}

fn mean(v: &[f64]) -> f64 {
    v.iter().sum::<f64>() / v.len().max(1) as f64
}

/// The effects of the study.
fn effects(periods: &[f64]) -> Vec<PowerEffect> {
    let mut v = vec![
        PowerEffect::TempRate,
        PowerEffect::ThermalT1,
        PowerEffect::Aging,
        PowerEffect::Magnetic,
        PowerEffect::Column,
    ];
    v.extend(periods.iter().map(|&p| PowerEffect::Sinusoid { period_s: p }));
    v
}

fn study(configs: &[(f64, f64, bool)], periods: &[f64], seeds: u64, opt_mult: &[f64]) -> (Tally, Tally, Tally) {
    let (mut all_stated, mut all_half, mut all_null) = (Tally::default(), Tally::default(), Tally::default());
    println!(
        "{:<20} {:>6} {:>6} {:<8} {:>11} {:>15} {:>15} {:>11}  optimal test's MDE, detection at multiples",
        "effect", "dt s", "hours", "noise", "stated MDE", "at stated", "at half", "null flagged"
    );
    // A subset: POWER_EFFECTS (labels containing any of its comma-separated words).
    let only: Vec<String> =
        std::env::var("POWER_EFFECTS").map(|v| v.split(',').map(str::to_string).collect()).unwrap_or_default();
    for &(dt, hours, wander) in configs {
        for e in effects(periods).into_iter().filter(|e| only.is_empty() || only.iter().any(|w| label(*e).contains(w)))
        {
            let c = run_cell(e, dt, hours, wander, seeds, opt_mult);
            let opt_txt = if c.opt_eng.is_empty() {
                String::new()
            } else {
                let at: Vec<String> = c.at_opt.iter().map(|(m, t)| format!("{m:.2}x: {t}")).collect();
                format!(
                    "{:.3e} (stated/optimal {:.2}); {}",
                    mean(&c.opt_eng),
                    mean(&c.stated_eng) / mean(&c.opt_eng),
                    at.join(", ")
                )
            };
            println!(
                "{:<20} {:>6} {:>6} {:<8} {:>11.3e} {} {} {}  {}",
                label(e),
                dt,
                hours,
                if wander { "coloured" } else { "white" },
                mean(&c.stated_eng),
                c.at_stated,
                c.at_half,
                c.null_flagged,
                opt_txt
            );
            all_stated.n += c.at_stated.n;
            all_stated.hit += c.at_stated.hit;
            all_half.n += c.at_half.n;
            all_half.hit += c.at_half.hit;
            all_null.n += c.null_flagged.n;
            all_null.hit += c.null_flagged.hit;
        }
    }
    println!("all cells: at the stated size {all_stated}, at half of it {all_half}; nulls flagged {all_null}");
    (all_stated, all_half, all_null)
}

/// The reduced study of the test suite: 24-h sessions of 60-s means, white and coloured,
/// each effect, six seeds.
#[test]
fn stated_sizes_hold() {
    let configs = [(60.0, 24.0, false), (60.0, 24.0, true)];
    let (stated, half, null) = study(&configs, &[2000.0], 6, &[1.3]);
    assert!(stated.rate() >= POWER, "detection at the stated size {stated}");
    assert!(half.rate() <= 0.5, "detection at half the stated size {half}");
    assert!(null.rate() <= 0.05 + 1e-9, "null sessions flagged {null}");
}

/// The full sweep (BENCHMARKS.md): sample interval and length, white and coloured, periods.
#[test]
#[ignore]
fn full_sweep() {
    // POWER_CONFIGS: comma-separated indices of the configurations below (all by default);
    // POWER_SEEDS: seeds per cell (12).
    let all = [
        (60.0, 24.0, false),
        (60.0, 24.0, true),
        (60.0, 48.0, false),
        (10.0, 10.0, false),
        (5.0, 6.0, false),
        (10.0, 10.0, true),
    ];
    let configs: Vec<(f64, f64, bool)> = match std::env::var("POWER_CONFIGS") {
        Ok(v) => v.split(',').filter_map(|i| all.get(i.trim().parse::<usize>().ok()?).copied()).collect(),
        Err(_) => all.to_vec(),
    };
    let seeds = std::env::var("POWER_SEEDS").ok().and_then(|v| v.parse().ok()).unwrap_or(12);
    // POWER_PERIODS: the sinusoid's periods, s; POWER_OPT: multiples of the optimal test's
    // MDE tried on white data (empty: none).
    let list = |var: &str, default: &[f64]| -> Vec<f64> {
        std::env::var(var).map_or(default.to_vec(), |v| v.split(',').filter_map(|x| x.trim().parse().ok()).collect())
    };
    study(&configs, &list("POWER_PERIODS", &[600.0, 2400.0, 9000.0]), seeds, &list("POWER_OPT", &[1.0, 1.3]));
}
