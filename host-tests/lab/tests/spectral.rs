//! A periodic bias that follows no column, found by the spectral search on the training
//! blocks' real times and judged on the test blocks: periods from 5 min to 6 h that do not
//! divide the block length, sessions of several lengths, amplitude 5× the single-line
//! fit's σ on the training half, on every FOG.
//!
//! The frequency of a line of that size cannot be known to 1 % at every period: its
//! Cramér–Rao bound on the training blocks is σ_f ≈ 1 / (2π σ_t √λ) (σ_t the spread of the
//! training rows' times, λ = 25 per FOG pooled over the FOGs), so a line of period P is
//! within 1 % of its frequency at 2σ only when 2 σ_f P < 1 %: about P < 1 h on a 10-h
//! session. The test asserts ≥ 95 % on the sessions where the bound allows 1 % and prints
//! every session.
//!
//! A session longer than the pass keeps (the 12-h one at 1 s) is searched and tested on the
//! means of runs of rows, every row counted.
//!
//! Figures print with `cargo test --release -p ssis-lab --test spectral -- --nocapture`.

use ssis_common::DEG_H_PER_RAD_S;
use ssis_lab::diagnose::{diagnose, Options};
use ssis_lab::model::{Catalog, Kind, Model};
use ssis_lab::session::session_from_columns;
use ssis_lab::simulate::{power_session, PowerEffect, PowerSpec};

#[test]
fn periodic_bias_found_at_its_frequency() {
    // (sample interval s, hours): blocks of 1 h, 1.2 h and 1.6 h.
    let lengths: [(f64, f64); 3] = [(1.0, 10.0), (1.0, 12.0), (2.0, 16.0)];
    let periods: [f64; 8] = [310.0, 700.0, 1300.0, 2450.0, 4100.0, 7000.0, 13_000.0, 21_600.0];
    let model = Model::new(&[Kind::Catalog(Catalog::Bias), Kind::Catalog(Catalog::ThermalT1)]);
    let (mut n, mut found, mut floor_ok) = (0, 0, 0);
    let (mut n_all, mut found_all) = (0, 0);
    for (li, &(dt, hours)) in lengths.iter().enumerate() {
        for (pi, &period_s) in periods.iter().enumerate() {
            let block_s = hours * 3600.0 / 10.0;
            let x = block_s / period_s;
            assert!(x.fract().min(1.0 - x.fract()) > 0.01, "the period divides the block");
            if period_s > hours * 3600.0 / 1.5 {
                continue;
            }
            let rows = hours * 3600.0 / dt;
            let sigma = 0.005 * 60.0 / dt.sqrt() / DEG_H_PER_RAD_S;
            let amp = 5.0 * sigma * (2.0 / (rows / 2.0)).sqrt();
            let spec = PowerSpec {
                seed: 7000 + 100 * li as u64 + pi as u64,
                dt_s: dt,
                hours,
                effect: PowerEffect::Sinusoid { period_s },
                size: amp,
                fog: 4,
                wander: false,
            };
            let p = power_session(&spec);
            let cols: Vec<Vec<f64>> =
                (0..p.sim.header.len()).map(|k| p.sim.rows.iter().map(|r| r[k]).collect()).collect();
            let s = session_from_columns("periodic.csv", p.sim.header.clone(), &cols).unwrap();
            let d = diagnose(&model, &s, &Options::default()).unwrap();
            let hit = d
                .candidates
                .iter()
                .find(|c| c.significant && matches!(c.kind, Kind::Sinusoid(f) if (f * period_s - 1.0).abs() < 0.01));
            let lines: Vec<String> = d
                .candidates
                .iter()
                .filter_map(|c| match c.kind {
                    Kind::Sinusoid(f) => Some(format!("{:.1} s p {:.1e}", 1.0 / f, c.p_value)),
                    _ => None,
                })
                .collect();
            // Cramér–Rao: training rows spread over the session (σ_t ≈ 1.1 span/√12).
            let sigma_t = 1.1 * hours * 3600.0 / 12f64.sqrt();
            let sigma_f = 1.0 / (2.0 * std::f64::consts::PI * sigma_t * (25.0f64 * 4.0).sqrt());
            let resolvable = 2.0 * sigma_f * period_s < 0.01;
            let ratio = hit.map(|c| c.after_rad_s / sigma);
            n_all += 1;
            found_all += usize::from(hit.is_some());
            if resolvable {
                n += 1;
                if let Some(r) = ratio {
                    found += 1;
                    floor_ok += usize::from(r <= 1.01);
                }
            }
            println!(
                "{hours:>4} h at {dt} s, period {period_s:>6} s{}, amplitude {:.4} °/h: {} held-out/floor {}; lines {lines:?}",
                if resolvable { "" } else { " (1 % beyond the Cramér–Rao bound)" },
                amp * DEG_H_PER_RAD_S,
                if hit.is_some() { "found" } else { "MISSED" },
                ratio.map_or("-".into(), |r| format!("{r:.4}"))
            );
        }
    }
    println!(
        "found within 1 % and significant in {found} of {n} where the bound allows 1 % ({found_all} of {n_all} in all); \
         held-out RMS within 1 % of the floor in {floor_ok}"
    );
    assert!(found as f64 >= 0.95 * n as f64, "found {found} of {n}");
    assert_eq!(floor_ok, found);
}
