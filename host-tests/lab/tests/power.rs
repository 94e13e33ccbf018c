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
//! `POWER_VERBOSE=1` (each miss's lines). Two probes of the terms' statement, also
//! `--ignored`: `null_spread` (on null sessions, whether the information Xᵀ Σ̂⁻¹ X the
//! statement uses over-states the GLS estimate's real precision: the null F's mean) and
//! `effect_spread` (at the stated size, the effect FOG's information against the null
//! session's, its F and the F-test's predicted and measured power).

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
    let seed0 = env_num("POWER_SEED0", 0);
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

/// The configurations `POWER_CONFIGS` picks of `all` (comma-separated indices; all when unset).
fn env_configs(all: &[(f64, f64, bool)]) -> Vec<(f64, f64, bool)> {
    match std::env::var("POWER_CONFIGS") {
        Ok(v) => v.split(',').filter_map(|i| all.get(i.trim().parse::<usize>().ok()?).copied()).collect(),
        Err(_) => all.to_vec(),
    }
}

/// A whole number from the environment, `default` when unset.
fn env_num(var: &str, default: u64) -> u64 {
    std::env::var(var).ok().and_then(|v| v.parse().ok()).unwrap_or(default)
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
    let configs = env_configs(&all);
    let seeds = env_num("POWER_SEEDS", 12);
    // POWER_PERIODS: the sinusoid's periods, s; POWER_OPT: multiples of the optimal test's
    // MDE tried on white data (empty: none).
    let list = |var: &str, default: &[f64]| -> Vec<f64> {
        std::env::var(var).map_or(default.to_vec(), |v| v.split(',').filter_map(|x| x.trim().parse().ok()).collect())
    };
    study(&configs, &list("POWER_PERIODS", &[600.0, 2400.0, 9000.0]), seeds, &list("POWER_OPT", &[1.0, 1.3]));
}

/// The spread of the candidates' GLS estimates on null sessions against what their
/// information predicts: with no effect, ĉᵀ I ĉ / q (the F statistic times the whitened
/// residual's mean square) has mean 1 when I = Xᵀ Σ̂⁻¹ X is the estimate's real precision,
/// r > 1 when the noise model over-states it by r. `POWER_CONFIGS`, `POWER_SEEDS`,
/// `POWER_SEED0` as in [`full_sweep`] (seeds 40 by default); every FOG of every null session
/// counts.
#[test]
#[ignore]
fn null_spread() {
    let all = [(60.0, 24.0, false), (60.0, 24.0, true)];
    let configs = env_configs(&all);
    let (seeds, seed0) = (env_num("POWER_SEEDS", 40), env_num("POWER_SEED0", 0));
    let opt = Options::default();
    for (dt_s, hours, wander) in configs {
        let mut per: Vec<(String, Vec<f64>)> = Vec::new();
        for seed in seed0..seed0 + seeds {
            let spec =
                PowerSpec { seed: 1000 + seed, dt_s, hours, effect: PowerEffect::Column, size: 0.0, fog: 0, wander };
            let d = diagnose(&model(PowerEffect::Column), &session(&power_session(&spec)), &opt).unwrap();
            for c in d.candidates.iter().filter(|c| !matches!(c.kind, Kind::Sinusoid(_))) {
                let l = c.kind.label();
                let i = per.iter().position(|(k, _)| *k == l).unwrap_or_else(|| {
                    per.push((l.clone(), Vec::new()));
                    per.len() - 1
                });
                per[i].1.extend(c.per_fog.iter().flatten().map(|t| t.f));
            }
        }
        println!("{dt_s} s, {hours} h, {}:", if wander { "coloured" } else { "white" });
        for (l, v) in &per {
            let m = mean(v);
            let sd = (v.iter().map(|x| (x - m) * (x - m)).sum::<f64>() / (v.len().max(2) - 1) as f64).sqrt();
            let se = sd / (v.len().max(1) as f64).sqrt();
            println!("  {l:<20} null mean F {m:.3} ± {se:.3} (n {})", v.len());
            // The information must not over-state the estimate's precision.
            assert!(m <= 1.0 + 3.0 * se, "{l}: the null F's mean {m:.3} ± {se:.3} is above 1");
        }
    }
}

/// The probes' arguments: the 24-h white and coloured configurations (`POWER_CONFIGS`),
/// one effect (`POWER_EFFECTS`, default the user column), `POWER_SEEDS` seeds from
/// `POWER_SEED0`.
fn probe_args() -> (Vec<(f64, f64, bool)>, PowerEffect, u64, u64) {
    let all = [(60.0, 24.0, false), (60.0, 24.0, true)];
    let only = std::env::var("POWER_EFFECTS").unwrap_or_else(|_| "supply_v".into());
    let e = effects(&[]).into_iter().find(|e| label(*e).contains(only.as_str())).unwrap();
    (env_configs(&all), e, env_num("POWER_SEEDS", 40), env_num("POWER_SEED0", 0))
}

/// The column's test at the stated size against what its statement assumed: per seed the
/// null session's information I₀ of the effect FOG (the statement's), the session with the
/// effect at the stated size's information I₁ and F, and the F-test's power predicted from
/// each (λ* I₁/I₀ against λ*). `POWER_CONFIGS`, `POWER_SEEDS`, `POWER_SEED0`,
/// `POWER_EFFECTS` (one effect) as in [`full_sweep`].
#[test]
#[ignore]
fn effect_spread() {
    use ssis_lab::detectable::ncx2_sf;
    use statrs::distribution::{ChiSquared, ContinuousCDF};
    let (configs, e, seeds, seed0) = probe_args();
    let opt = Options::default();
    let info = |d: &Diagnosis, fog: usize| {
        let c = d.candidates.iter().find(|c| c.kind.label() == label(e))?;
        c.per_fog.get(fog)?.as_ref().map(|t| (t.info[0], t.f, t.p_f))
    };
    for (dt_s, hours, wander) in configs {
        let (mut ratio, mut f1, mut lam, mut p_null, mut p_eff, mut hit, mut pf_hit) =
            (Vec::new(), Vec::new(), Vec::new(), Vec::new(), Vec::new(), Tally::default(), Tally::default());
        for seed in seed0..seed0 + seeds {
            let fog = (seed % 4) as usize;
            let spec = PowerSpec { seed: 1000 + seed, dt_s, hours, effect: e, size: 0.0, fog, wander };
            let d0 = diagnose(&model(e), &session(&power_session(&spec)), &opt).unwrap();
            let (Some(c), Some((i0, _, _))) = (stated(&d0, e, fog), info(&d0, fog)) else { continue };
            let alpha = d0.detectable.alpha_per_fog;
            let l_star = lambda_required(1, alpha, POWER);
            let crit = ChiSquared::new(1.0).unwrap().inverse_cdf(1.0 - alpha);
            let d1 = diagnose(&model(e), &session(&power_session(&PowerSpec { size: c, ..spec })), &opt).unwrap();
            let Some((i1, f, pf)) = info(&d1, fog) else { continue };
            ratio.push(i1 / i0);
            f1.push(f);
            lam.push(l_star);
            p_null.push(ncx2_sf(crit, 1.0, l_star));
            p_eff.push(ncx2_sf(crit, 1.0, l_star * i1 / i0));
            hit.add(found(&d1, e, hours * 3600.0));
            pf_hit.add(pf <= alpha);
            println!(
                "  seed {seed} fog {fog}: I1/I0 {:.3} F {f:.1} (λ* {l_star:.1}) p_F {pf:.1e} α {alpha:.1e}",
                i1 / i0
            );
        }
        println!(
            "{dt_s} s, {hours} h, {}: I1/I0 mean {:.3} (min {:.3}); F at the stated size mean {:.1} (1 + λ* = {:.1}); \
             F-test power predicted from I0 {:.3}, from I1 {:.3}; p_F ≤ α {pf_hit}; found {hit}",
            if wander { "coloured" } else { "white" },
            mean(&ratio),
            ratio.iter().copied().fold(f64::INFINITY, f64::min),
            mean(&f1),
            1.0 + mean(&lam),
            mean(&p_null),
            mean(&p_eff),
        );
        // The noise model of the session with the effect must not take it up as wander.
        assert!(mean(&ratio) >= 0.95, "the effect's information falls to {:.3} of the null's", mean(&ratio));
    }
}

/// Wilson 95 % interval of `hit` of `n`.
fn wilson(hit: usize, n: usize) -> (f64, f64) {
    let (n, p, z) = (n.max(1) as f64, hit as f64 / n.max(1) as f64, 1.96f64);
    let c = (p + z * z / (2.0 * n)) / (1.0 + z * z / n);
    let h = z * (p * (1.0 - p) / n + z * z / (4.0 * n * n)).sqrt() / (1.0 + z * z / n);
    (c - h, c + h)
}

/// What decides a hit at the stated size: the GLS fit is linear, so with the same noise the
/// effect session's standardised estimate z₁ = ĉ √I is the null session's z₀ plus √λ* (the
/// stated size's non-centrality; exactly when the two sessions' noise models agree), and
/// the F-test rejects when (z₀ + √λ*)² ≥ F_crit · s², s² its denominator. Per seed, on
/// every FOG of the null session: z₀, s², and the hit that predicts; on the effect FOG
/// (`POWER_RUN=1`) the effect session's z₁, s², I₁ and whether the diagnosis found it.
/// Every FOG of a null session is one draw of the prediction (four a seed).
/// `POWER_CONFIGS`, `POWER_SEEDS`, `POWER_SEED0`, `POWER_EFFECTS` as in [`full_sweep`].
#[test]
#[ignore]
fn coupling() {
    use ssis_lab::diagnose::f_critical;
    let (configs, e, seeds, seed0) = probe_args();
    let run = std::env::var("POWER_RUN").is_ok();
    let opt = Options::default();
    let test = |d: &Diagnosis, fog: usize| {
        let c = d.candidates.iter().find(|c| c.kind.label() == label(e))?;
        c.per_fog.get(fog)?.clone()
    };
    for (dt_s, hours, wander) in configs {
        let (mut z0s, mut s2s, mut pred_all, mut pred_eff, mut found_eff, mut agree) =
            (Vec::new(), Vec::new(), Tally::default(), Tally::default(), Tally::default(), Tally::default());
        let mut shift = Vec::new();
        for seed in seed0..seed0 + seeds {
            let fog_e = (seed % 4) as usize;
            let spec = PowerSpec { seed: 1000 + seed, dt_s, hours, effect: e, size: 0.0, fog: fog_e, wander };
            let d0 = diagnose(&model(e), &session(&power_session(&spec)), &opt).unwrap();
            let alpha = d0.detectable.alpha_per_fog;
            let mut line = format!("  seed {seed} α {alpha:.2e}:");
            let mut pred_e = None;
            for fog in 0..4 {
                let Some(t) = test(&d0, fog) else { continue };
                // The stated size's non-centrality on this FOG, c² I₀.
                let Some(c) = stated(&d0, e, fog) else { continue };
                let l_star = c * c * t.info[0];
                line.push_str(&format!(" λ {l_star:.2}"));
                let z0 = t.coef[0] * t.info[0].sqrt();
                let crit = f_critical(alpha, 1, t.df2);
                let hit = z0 + l_star.sqrt() >= (crit * t.mse).sqrt();
                z0s.push(t.coef[0] * t.info[0].sqrt());
                s2s.push(t.mse);
                pred_all.add(hit);
                if fog == fog_e {
                    pred_e = Some(hit);
                    pred_eff.add(hit);
                }
                line.push_str(&format!(" fog{fog} z0 {z0:+.2} s² {:.3}{}", t.mse, if hit { "" } else { " MISS" }));
            }
            if run {
                if let (Some(c), Some(t0)) = (stated(&d0, e, fog_e), test(&d0, fog_e)) {
                    let l_star = c * c * t0.info[0];
                    let d1 =
                        diagnose(&model(e), &session(&power_session(&PowerSpec { size: c, ..spec })), &opt).unwrap();
                    if let Some(t1) = test(&d1, fog_e) {
                        let z1 = t1.coef[0] * t1.info[0].sqrt();
                        let z0 = t0.coef[0] * t0.info[0].sqrt();
                        let hit = found(&d1, e, hours * 3600.0);
                        found_eff.add(hit);
                        agree.add(Some(hit) == pred_e);
                        shift.push(z1 - z0 - l_star.sqrt());
                        line.push_str(&format!(
                            " | effect fog{fog_e}: z1 {z1:+.2} (z0 + √λ* {:+.2}) I1/I0 {:.3} s² {:.3} α1 {:.2e} {}",
                            z0 + l_star.sqrt(),
                            t1.info[0] / t0.info[0],
                            t1.mse,
                            d1.detectable.alpha_per_fog,
                            if hit { "found" } else { "MISSED" }
                        ));
                    }
                }
            }
            println!("{line}");
        }
        let sd = |v: &[f64]| {
            let m = mean(v);
            (m, (v.iter().map(|x| (x - m) * (x - m)).sum::<f64>() / (v.len().max(2) - 1) as f64).sqrt())
        };
        let (zm, zs) = sd(&z0s);
        let (sm, ss) = sd(&s2s);
        let (lo, hi) = wilson(pred_all.hit, pred_all.n);
        println!(
            "{dt_s} s, {hours} h, {}: null z0 = ĉ√I mean {zm:+.3} sd {zs:.3} (n {}); s² mean {sm:.3} sd {ss:.3}; \
             predicted at the stated size: every FOG {pred_all} (Wilson {:.1}–{:.1} %), effect FOG {pred_eff}",
            if wander { "coloured" } else { "white" },
            z0s.len(),
            100.0 * lo,
            100.0 * hi
        );
        if run {
            let (hm, hs) = sd(&shift);
            println!("  effect sessions: found {found_eff}, prediction agrees {agree}; z1 − z0 − √λ* mean {hm:+.3} sd {hs:.3}");
        }
    }
}
