//! Significance grows with the data: the noise model's tests use every row of a session,
//! not a sample of them. A static chamber session at 10 Hz (400,000 rows, 11.1 h: ten times
//! the rows a pass keeps for plots) with white noise (ARW 0.005 °/√h, 0.95 °/h a sample) and
//! a temperature-rate effect of 0.05 °/h per °C/min over ±0.5 °C/min ramps: about 12 σ on
//! every row, about 4 σ on a tenth of them (before Bonferroni over the FOGs and the
//! false-discovery rate over the candidates).
//!
//! Figures print with `cargo test --release -p ssis-lab --test long_session -- --nocapture`.

use rand::SeedableRng;
use rand_distr::{Distribution, Normal};
use ssis_lab::diagnose::{diagnose, Options};
use ssis_lab::model::{Catalog, Kind, Model};
use ssis_lab::session::session_from_columns;
use ssis_lab::stream::DEFAULT_KEEP;

mod common;
use common::dh;

const ROWS: usize = 400_000;
const DT_S: f64 = 0.1;

/// Columns of the session: time, four rates, four temperatures, ψ, latitude.
fn session_columns(seed: u64, g_deg_h_per_degc_min: f64) -> (Vec<String>, Vec<Vec<f64>>) {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let n01 = Normal::new(0.0, 1.0).unwrap();
    let rad_s = 1.0 / dh(1.0);
    let white = 0.005 * 60.0 / DT_S.sqrt() * rad_s;
    let lat = 50.0f64.to_radians();
    let w = ssis_lab::session::earth_rate_ics(0.0, lat);
    let axes = ssis_lab::session::nominal_axes();
    let mut names = vec!["t_s".to_string()];
    names.extend((0..4).map(|i| format!("fog{i}_rad_s")));
    names.extend((0..4).map(|i| format!("fog{i}_t_degc")));
    names.extend(["psi_rad", "lat_rad"].map(String::from));
    let mut cols = vec![Vec::with_capacity(ROWS); names.len()];
    // Triangle between 15 and 35 °C at ±0.5 °C/min (80-min period).
    let period_s = 4800.0;
    let g = g_deg_h_per_degc_min * 60.0 * rad_s; // rad/s per °C/s
    for j in 0..ROWS {
        let t = (j + 1) as f64 * DT_S;
        let ph = (t % period_s) / period_s;
        let (temp, rate_degc_s) =
            if ph < 0.5 { (15.0 + 40.0 * ph, 0.5 / 60.0) } else { (35.0 - 40.0 * (ph - 0.5), -0.5 / 60.0) };
        cols[0].push(t);
        for i in 0..4 {
            let earth = axes[i].x * w[0] + axes[i].y * w[1] + axes[i].z * w[2];
            let bias = 0.05 * (i as f64 + 1.0) * rad_s;
            let a1 = 0.02 * rad_s * (temp - 25.0);
            cols[1 + i].push(earth + bias + a1 + g * rate_degc_s + white * n01.sample(&mut rng));
            cols[5 + i].push(temp + 0.002 * n01.sample(&mut rng));
        }
        cols[9].push(0.0);
        cols[10].push(lat);
    }
    (names, cols)
}

/// The long session's effect is ranked first and significant; with every row the tests
/// have the power that 40,000 kept rows lack.
#[test]
fn long_session_keeps_its_power() {
    const { assert!(ROWS >= 10 * DEFAULT_KEEP, "the session must be long beside the rows a pass keeps") };
    let (names, cols) = session_columns(7, 0.05);
    let s = session_from_columns("long-temp-rate", names, &cols).unwrap();
    let model = Model::new(&[Kind::Catalog(Catalog::Bias), Kind::Catalog(Catalog::ThermalT1)]);
    let d = diagnose(&model, &s, &Options::default()).unwrap();
    for c in d.candidates.iter().take(3) {
        println!(
            "{:<14} p {:.2e} removed {:.4} deg/h {}",
            c.kind.label(),
            c.p_value,
            dh(c.removed_rad_s().0),
            if c.significant { "SIGNIFICANT" } else { "" }
        );
    }
    let first = &d.candidates[0];
    assert_eq!(first.kind, Kind::Catalog(Catalog::TempRate), "temp_rate not ranked first");
    assert!(first.significant, "temp_rate not significant on {} rows: p = {:.2e}", ROWS, first.p_value);
    assert!(first.p_value < 1e-8, "temp_rate p = {:.2e}: every row should give ~12 sigma", first.p_value);
}
