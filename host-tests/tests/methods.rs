//! The paper's calibration methods on simulated data with known truth.
//! `cargo test --test methods -- --nocapture` prints the measured figures.

use std::path::PathBuf;

use ssis_common::DEG_H_PER_RAD_S;
use ssis_methods::{allan, magnetic, misalign_turns, thermal_anova};
use ssis_session::read_session;

fn tmp(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("ssis-methods-{}", std::process::id()));
    std::fs::create_dir_all(&d).unwrap();
    d.join(name)
}

// ---------------------------------------------------------------- 1. magnetic

#[test]
fn magnetic_kharkov_worked_example() {
    let m = magnetic::DipoleTilt::PAPER;
    let site = m.kharkov();
    let b = m.field_ocs_nt(&site);
    println!("Kharkov B0 (dipole tilt): X {:.1} Y {:.1} Z {:.1} nT (paper 21846.0 5967.0 -42340.0)", b[0], b[1], b[2]);
    let rel = |a: f64, p: f64| ((a - p) / p).abs();
    assert!(rel(b[0], 21846.0) < 0.005, "B0X {}", b[0]);
    assert!(rel(b[1], 5967.0) < 0.005, "B0Y {}", b[1]);
    assert!(rel(b[2], -42340.0) < 0.005, "B0Z {}", b[2]);
    // The formula for ηm as printed does not give the paper's numbers (module doc).
    let printed = m.field_with_eta_nt(&site, m.eta_as_printed_rad(&site));
    println!("with ηm as printed: X {:.1} Y {:.1} Z {:.1} nT", printed[0], printed[1], printed[2]);
    assert!(rel(printed[0], 21846.0) > 0.5);
    // The phase from the paper's projections and from ours.
    let dphi_paper = magnetic::predicted_phase_rad([21846.0, 5967.0, -42340.0]).to_degrees();
    let dphi_model = magnetic::predicted_phase_rad(b).to_degrees();
    println!(
        "Δφ = −arctg(B0Y/B0X): {dphi_paper:.3}° from the paper's B0, {dphi_model:.3}° from the model (paper −15.3°)"
    );
    assert!(rel(dphi_paper, -15.3) < 0.005);
    assert!(rel(dphi_model, -15.3) < 0.005);
    // At the maximum of Δf_x (ψ_Π = 90° − Δφ, the session's ψ = −ψ_Π) the field is
    // orthogonal to FOGX: α_x = 90°.
    let psi = std::f64::consts::FRAC_PI_2 - dphi_paper.to_radians();
    let bp = magnetic::field_ics_nt([21846.0, 5967.0, -42340.0], -psi);
    let ax = magnetic::alpha_rad(bp, [1.0, 0.0, 0.0]).to_degrees();
    assert!((ax - 90.0).abs() < 1e-9, "α_x {ax}");
}

/// The real field at Kharkov from WMM2025 against IGRF-14 for 2025 (north, west, up:
/// 19,361 / −3,137 / −47,632 nT), and how far the paper's dipole tilt is from it.
#[test]
fn magnetic_wmm_field_at_kharkov() {
    let wmm = magnetic::wmm_field_nwu_nt(50.0 + 3.0 / 60.0, 36.0 + 17.0 / 60.0, 150.0, 2025, 1).unwrap();
    let igrf = [19361.0, -3137.0, -47632.0];
    let dipole = magnetic::DipoleTilt::PAPER.field_ocs_nt(&magnetic::DipoleTilt::PAPER.kharkov());
    println!("Kharkov 2025.0, nT (north, west, up): WMM {wmm:.0?}, IGRF-14 {igrf:?}, dipole tilt {dipole:.0?}");
    for k in 0..3 {
        assert!((wmm[k] - igrf[k]).abs() < 200.0, "component {k}: WMM {} vs IGRF {}", wmm[k], igrf[k]);
    }
    let off: Vec<f64> = (0..3).map(|k| (dipole[k] - wmm[k]).abs() / 1000.0).collect();
    println!("dipole tilt off by {off:.1?} µT");
    assert!(off.iter().any(|&o| o > 2.0));
}

/// One frame for the field: at every azimuth the session's field columns (written by
/// `ssis-cal simulate magnetic`) have the site's north and west components along the
/// session's own north and west (the directions its Earth rate gives, `earth_rate_ics`);
/// at ψ = 90° the Kharkov field is (−5959, 21846, −42343) nT.
#[test]
fn magnetic_field_frame_agrees_with_the_session() {
    let b = [21846.0, 5959.0, -42343.0];
    let at90 = ssis_session::field_ics_nt(b, std::f64::consts::FRAC_PI_2);
    println!("field at psi = 90 deg: {at90:?} nT");
    assert!(at90.iter().zip([-5959.0, 21846.0, -42343.0]).all(|(a, w)| (a - w).abs() < 1e-9), "{at90:?}");
    let sim = magnetic::MagneticSim::kharkov().unwrap();
    let (pu, ps) = (tmp("frame-unscreened.csv"), tmp("frame-screened.csv"));
    sim.write(&pu, &ps, 9).unwrap();
    let u = read_session(&pu, None).unwrap();
    let psi = u.column("psi_rad").unwrap();
    let field = u.field_nt.as_ref().unwrap();
    let mut seen = std::collections::BTreeSet::new();
    for (r, f) in field.iter().enumerate() {
        let w = u.ref_rad_s[r];
        let horiz = w[0].hypot(w[1]);
        let north = [w[0] / horiz, w[1] / horiz, 0.0];
        let west = [-north[1], north[0], 0.0]; // up × north
        let dot = |a: [f64; 3], b: &[f64; 3]| a.iter().zip(b).map(|(x, y)| x * y).sum::<f64>();
        let (bn, bw) = (dot(north, f), dot(west, f));
        if seen.insert((psi[r].to_degrees().round()) as i64) {
            println!("psi {:>5.1} deg: B.north {bn:>9.1}  B.west {bw:>9.1}  B_z {:>9.1} nT", psi[r].to_degrees(), f[2]);
        }
        assert!((bn - sim.b0_nt[0]).abs() < 1e-6 && (bw - sim.b0_nt[1]).abs() < 1e-6, "row {r}: {bn} {bw}");
    }
    assert!(seen.len() >= 24, "azimuths seen: {}", seen.len());
}

#[test]
fn magnetic_fit_recovers_simulated_sensitivity() {
    let sim = magnetic::MagneticSim::kharkov().unwrap();
    let (pu, ps) = (tmp("mag-unscreened.csv"), tmp("mag-screened.csv"));
    sim.write(&pu, &ps, 5).unwrap();
    let (u, s) = (read_session(&pu, None).unwrap(), read_session(&ps, None).unwrap());
    let r = magnetic::analyse(&u, &s).unwrap();
    assert_eq!(r.psi_rad.len(), 25);
    let truth = sim.truth();
    let predicted = magnetic::predicted_phase_rad(sim.b0_nt).to_degrees();
    for (k, name) in ["X", "Y"].iter().enumerate() {
        let f = r.magnetic[k];
        let (s_true, ph_true) = truth[k];
        println!(
            "FOG{name} eq.(2): ΔS {:.4} °/h (truth {:.4}), Δφ {:.2}° ± {:.2}° (truth {:.2}°, predicted {predicted:.2}°), ΔΩ {:.4} °/h",
            f.amplitude_rad_s * DEG_H_PER_RAD_S,
            s_true * DEG_H_PER_RAD_S,
            f.phase_rad.to_degrees(),
            f.phase_sigma_rad.to_degrees(),
            ph_true.to_degrees(),
            f.offset_rad_s * DEG_H_PER_RAD_S
        );
        // Within 3σ of the fit and within 5 % / 5°: the noise of 30-min means limits Δφ.
        assert!((f.amplitude_rad_s - s_true).abs() < 3.0 * f.amplitude_sigma_rad_s, "amplitude");
        assert!((f.amplitude_rad_s / s_true - 1.0).abs() < 0.05, "amplitude");
        assert!((f.phase_rad - ph_true).abs() < 3.0 * f.phase_sigma_rad, "phase");
        assert!((f.phase_rad - ph_true).abs().to_degrees() < 5.0, "phase");
        // The unscreened fit alone carries the Earth-rate leak of the 300″ axis errors.
        let u = r.unscreened[k];
        println!(
            "  unscreened eq.(1) alone: S {:.4} ± {:.4} °/h, Δφ {:.2}°",
            u.amplitude_rad_s * DEG_H_PER_RAD_S,
            u.amplitude_sigma_rad_s * DEG_H_PER_RAD_S,
            u.phase_rad.to_degrees()
        );
        assert!((u.amplitude_rad_s - s_true / (1.0 - sim.screen_residual)).abs() > 3.0 * u.amplitude_sigma_rad_s);
    }
}

/// A reversed FOG in a magnetic session: a horizontal one is seen over the azimuths, the
/// vertical one (no Earth-rate change on a level table) by its mean, 2 × 11.5 °/h off.
#[test]
fn magnetic_refuses_a_reversed_fog() {
    let sim = magnetic::MagneticSim::kharkov().unwrap();
    let (pu, ps) = (tmp("mag-rev-unscreened.csv"), tmp("mag-rev-screened.csv"));
    sim.write(&pu, &ps, 6).unwrap();
    let (u, s) = (read_session(&pu, None).unwrap(), read_session(&ps, None).unwrap());
    assert!(magnetic::analyse(&u, &s).is_ok());
    for (fog, expect) in [(0, "reads the reference reversed"), (2, "°/h off the reference")] {
        let mut bad = u.clone();
        bad.fogs[fog].rate_rad_s.iter_mut().for_each(|v| *v = -*v);
        let err = magnetic::analyse(&bad, &s).expect_err("reversed FOG accepted").to_string();
        println!("FOG{fog} reversed: {err}");
        assert!(err.contains(&format!("FOG{fog} (column `fog{fog}_rad_s`)")) && err.contains(expect), "{err}");
    }
}

// ---------------------------------------------------------------- 2. thermal

#[test]
fn thermal_table2_critical_values() {
    let nu = thermal_anova::degrees_of_freedom(4, 3, 10, thermal_anova::TABLE1_N);
    println!("paper design: ν0 {} νε {} νT {} νG {} νTG {}", nu[0], nu[1], nu[2], nu[3], nu[4]);
    assert_eq!((nu[2], nu[3], nu[4]), (3.0, 2.0, 4.0));
    let c = |a, b, q| thermal_anova::f_critical(a, b, q).unwrap();
    let ours = [
        (c(nu[2], nu[4], 0.05), 6.59),
        (c(nu[2], nu[4], 0.01), 16.69),
        (c(nu[3], nu[4], 0.05), 6.94),
        (c(nu[3], nu[4], 0.01), 18.00),
        (c(nu[4], nu[1], 0.01), 3.32),
    ];
    for (v, p) in ours {
        println!("critical {v:.3} (Table 2: {p})");
        assert!((v - p).abs() < 0.006, "{v} vs {p}");
    }
    let f_tg_5 = c(nu[4], nu[1], 0.05);
    println!("F_TG critical at 5 %: {f_tg_5:.3} (Table 2 prints 2.32)");
    assert!((f_tg_5 - 2.372).abs() < 0.002);
    // No denominator degrees of freedom give 2.32: F_0.05(4, ν) > 2.37 for every ν.
    for nu2 in [1.0, 4.0, 40.0, 400.0, 4.0e4, 4.0e6] {
        assert!(c(4.0, nu2, 0.05) > 2.37);
    }
}

fn batch_decisions(sim: &thermal_anova::BatchSim, seeds: std::ops::Range<u64>) -> (usize, Vec<thermal_anova::Anova>) {
    let mut worth = 0;
    let mut all = Vec::new();
    for seed in seeds {
        let (cells, _) = sim.simulate(seed, 0);
        let a = thermal_anova::anova(&cells, 4, 3).unwrap();
        worth += usize::from(a.model_worth_building());
        all.push(a);
    }
    (worth, all)
}

#[test]
fn thermal_batches_reach_the_papers_decisions() {
    // One run at the paper's N = 240 000 (5 ms, 20 min).
    let b1 = thermal_anova::BatchSim::batch_i();
    let (cells, samples) = b1.simulate(1, 1000);
    let (a, model) = thermal_anova::analyse_and_fit(&cells, &samples, 25.0).unwrap();
    println!(
        "batch I (N = {}): F_T {:.2} F_G {:.2} F_TG {:.1} (paper 8.17 20.42 26.02); ν = {:?}",
        a.n_per_cell, a.t.f, a.g.f, a.tg.f, a.nu
    );
    assert!(a.t.significant_5() && a.g.significant_5() && a.tg.significant_1());
    let m = model.expect("batch I: the model is worth building");
    println!(
        "batch I model: a1 {:.5} °/h/°C (truth {:.5}), g {:.4} °/h per °C/min (truth {:.4})",
        m.a_rad_s[0] * DEG_H_PER_RAD_S,
        b1.a_rad_s[0] * DEG_H_PER_RAD_S,
        m.g_rad_s_per_degc_s * DEG_H_PER_RAD_S / 60.0,
        b1.g_rad_s_per_degc_s * DEG_H_PER_RAD_S / 60.0
    );
    assert!((m.g_rad_s_per_degc_s / b1.g_rad_s_per_degc_s - 1.0).abs() < 0.2);
    assert!((m.a_rad_s[0] / b1.a_rad_s[0] - 1.0).abs() < 0.5);

    let b2 = thermal_anova::BatchSim::batch_ii();
    let (cells, samples) = b2.simulate(1, 1000);
    let (a, model) = thermal_anova::analyse_and_fit(&cells, &samples, 25.0).unwrap();
    println!(
        "batch II (N = {}): F_T {:.2} F_G {:.2} F_TG {:.1} (paper 6.03 19.51 21.69)",
        a.n_per_cell, a.t.f, a.g.f, a.tg.f
    );
    assert!(!a.t.significant_5() && a.g.significant_5() && a.tg.significant_1());
    assert!(model.is_none());

    // Decision rates over 40 seeds each; cell means of white noise do not depend on the
    // sample interval, so 0.5-s samples (N = 2400) stand for the 5-ms ones here.
    let fast = |b: thermal_anova::BatchSim| thermal_anova::BatchSim { dt_s: 0.5, n: 2400, ..b };
    let (w1, _) = batch_decisions(&fast(b1), 100..140);
    let (w2, all2) = batch_decisions(&fast(b2), 100..140);
    let g2 = all2.iter().filter(|a| a.g.significant_5()).count();
    println!("over 40 seeds: batch I model worth building {w1}/40; batch II {w2}/40 (G significant {g2}/40)");
    assert!(w1 >= 34, "batch I power {w1}/40");
    assert!(w2 <= 6, "batch II false decisions {w2}/40");
    assert!(g2 >= 34);
}

// ---------------------------------------------------------------- 3. Allan

#[test]
fn allan_recovers_arw_and_rrw() {
    // 1-s means for 300 h: the RRW part dominates from τ ≈ 3 000 s, clusters to 75 000 s.
    let (arw, rrw) = (0.005, 0.01);
    let mut est_arw = Vec::new();
    let mut est_rrw = Vec::new();
    for seed in 1..=3 {
        let rates = allan::simulate_static(arw, rrw, 0.3, 1.0, 300 * 3600, seed);
        let pts = allan::overlapping_adev(&rates, 1.0, 8).unwrap();
        let nt = allan::noise_terms(&pts).unwrap();
        let (
            allan::Estimate::Resolved { value: a, lo: a_lo, hi: a_hi },
            allan::Estimate::Resolved { value: k, lo: k_lo, hi: k_hi },
        ) = (nt.arw_deg_sqrt_h, nt.rrw_deg_h_sqrt_h)
        else {
            panic!("seed {seed}: ARW and RRW resolved over 300 h: {nt:?}");
        };
        println!(
            "seed {seed}: ARW {a:.5} [{a_lo:.5}, {a_hi:.5}] °/√h (truth {arw}), RRW {k:.4} [{k_lo:.4}, {k_hi:.4}] °/h/√h (truth {rrw}), B {} °/h at τ {:.0} s",
            nt.bias_instability_deg_h.text(4),
            nt.tau_min_s
        );
        // The confidence intervals bracket the truth.
        assert!(a_lo <= arw && arw <= a_hi);
        assert!(k_lo <= rrw && rrw <= k_hi);
        est_arw.push(a);
        est_rrw.push(k);
    }
    for a in &est_arw {
        assert!((a / arw - 1.0).abs() < 0.10, "ARW {a}");
    }
    for k in &est_rrw {
        assert!(k / rrw < 1.5 && rrw / k < 1.5, "RRW {k} not within a factor 1.5");
    }
}

// ---------------------------------------------------------------- 4. first method

#[test]
fn misalignment_first_method_on_turntable_session() {
    let truth = misalign_turns::example_truth();
    let sim = misalign_turns::TableSim::first_method(truth);
    let path = tmp("turns.csv");
    let table = sim.write(&path, 11).unwrap();
    let s = read_session(&path, None).unwrap();
    let (turns, lat) = misalign_turns::turns_from_session(&s).unwrap();
    assert_eq!(turns.len(), 3);
    let r = misalign_turns::solve(&turns, lat, table.gamma_rad).unwrap();
    let e = misalign_turns::errors_arcsec(&r.misalignment, &table.misalignment);
    let worst = e.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    println!("first method errors (″): {}", fmt8(&e));
    println!("  worst {worst:.2}″ (paper ≤ 30″, goal ≤ 10″)");
    assert!(worst <= 10.0, "worst error {worst}″");
    // The same campaign with the ICS axis exactly along the table axis: the method's floor.
    let ideal = misalign_turns::TableSim { axis_tilt_sigma_arcsec: 0.0, ..sim };
    let (rows, table) = ideal.run(11);
    let p2 = tmp("turns-ideal.csv");
    ssis_methods::write_session_csv(&p2, &[], &misalign_turns::TableSim::HEADER, &rows).unwrap();
    let s = read_session(&p2, None).unwrap();
    let (turns, lat) = misalign_turns::turns_from_session(&s).unwrap();
    let r = misalign_turns::solve(&turns, lat, table.gamma_rad).unwrap();
    let e = misalign_turns::errors_arcsec(&r.misalignment, &table.misalignment);
    let worst0 = e.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    println!("  without axis tilt: {}  worst {worst0:.2}″", fmt8(&e));
    assert!(worst0 < worst);
}

/// A FOG mounted backwards, two FOG cables swapped, or the session's turn direction written
/// the wrong way round: the first method would fit angles to them (a reversed FOG gives its
/// angles with the wrong sign and exit 0); the wiring check refuses each and names it.
#[test]
fn misalignment_methods_refuse_miswired_fogs() {
    let sim = misalign_turns::TableSim::first_method(misalign_turns::example_truth());
    let (rows, _) = sim.run(3);
    let col = |name: &str| misalign_turns::TableSim::HEADER.iter().position(|h| *h == name).unwrap();
    let variant = |name: &str, edit: &dyn Fn(&mut Vec<f64>)| {
        let mut rows = rows.clone();
        rows.iter_mut().for_each(edit);
        let p = tmp(name);
        ssis_methods::write_session_csv(&p, &[], &misalign_turns::TableSim::HEADER, &rows).unwrap();
        let s = read_session(&p, None).unwrap();
        misalign_turns::turns_from_session(&s).map(|_| ()).map_err(|e| e.to_string())
    };
    assert!(variant("wired.csv", &|_| {}).is_ok(), "the clean session is refused");
    // A logger that lost one row in a turn: the turn's angle is short by 0.35° on FOG4.
    let seg = col("segment");
    let mut gappy = rows.clone();
    let k = gappy.iter().position(|r| r[seg] == 1.0).unwrap() + 500;
    gappy.remove(k);
    let p = tmp("lost-row.csv");
    ssis_methods::write_session_csv(&p, &[], &misalign_turns::TableSim::HEADER, &gappy).unwrap();
    let err = misalign_turns::turns_from_session(&read_session(&p, None).unwrap()).map(|_| ()).unwrap_err().to_string();
    println!("lost-row.csv: {err}");
    // the file's line of the row after the gap: header 1, rows from 2 (the first row of an
    // increment session is read and dropped)
    assert!(err.contains(&format!("line {}:", k + 2)) && err.contains("samples were lost"), "{err}");
    let (f0, f1, f2, f3) = (col("fog0_rad"), col("fog1_rad"), col("fog2_rad"), col("fog3_rad"));
    let rate = col("table_rate_rad_s");
    for (name, edit, expect) in [
        (
            "fog1-reversed.csv",
            Box::new(move |r: &mut Vec<f64>| r[f1] = -r[f1]) as Box<dyn Fn(&mut Vec<f64>)>,
            vec!["FOG1 (column `fog1_rad`)", "reversed"],
        ),
        (
            "fog2-reversed.csv",
            Box::new(move |r: &mut Vec<f64>| r[f2] = -r[f2]),
            vec!["FOG2 (column `fog2_rad`)", "reversed"],
        ),
        (
            "fog3-reversed.csv",
            Box::new(move |r: &mut Vec<f64>| r[f3] = -r[f3]),
            vec!["FOG3 (column `fog3_rad`)", "reversed"],
        ),
        (
            "fog0-fog3-swapped.csv",
            Box::new(move |r: &mut Vec<f64>| r.swap(f0, f3)),
            vec![
                "FOG0 (column `fog0_rad`)",
                "follows the axis of FOG3",
                "FOG3 (column `fog3_rad`)",
                "follows the axis of FOG0",
            ],
        ),
        (
            "turned-the-other-way.csv",
            Box::new(move |r: &mut Vec<f64>| r[rate] = -r[rate]),
            vec!["every FOG reads reversed", "turn direction"],
        ),
    ] {
        let err = variant(name, &*edit).expect_err(name);
        println!("{name}: {err}");
        for e in expect {
            assert!(err.contains(e), "{name}: `{e}` not in\n{err}");
        }
        assert!(err.contains(name), "{name}: the file is not named");
    }
}

fn fmt8(v: &[f64; 8]) -> String {
    misalign_turns::ANGLE_NAMES.iter().zip(v).map(|(n, x)| format!("{n} {x:+.2}")).collect::<Vec<_>>().join("  ")
}

// ---------------------------------------------------------------- 5. second method

#[test]
fn misalignment_second_method_sins_reversals() {
    use ssis_methods::misalign_sins;
    let truth = misalign_turns::example_truth();
    // The first method's angles on this unit (its own turntable session) are the start.
    let first = misalign_turns::TableSim::first_method(truth);
    let p1 = tmp("sins-turns.csv");
    let table = first.write(&p1, 11).unwrap();
    let (turns, lat) = misalign_turns::turns_from_session(&read_session(&p1, None).unwrap()).unwrap();
    let start = misalign_turns::solve(&turns, lat, table.gamma_rad).unwrap().misalignment;
    let e0 = misalign_sins::errors_arcsec(&start, &truth);
    let sim = misalign_sins::second_method_sim(truth);
    let p2 = tmp("sins.csv");
    sim.write(&p2, 21).unwrap();
    let revs = misalign_sins::reversals_from_session(&read_session(&p2, None).unwrap(), [0.0; 3]).unwrap();
    assert_eq!(revs.len(), 6);
    let r = misalign_sins::solve(&revs, &start, table.gamma_rad).unwrap();
    let e = misalign_sins::errors_arcsec(&r.misalignment, &truth);
    let worst = e.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    let worst0 = e0.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    println!("second method: start (first method) errors ″ {}", fmt6(&e0));
    println!("               after SINS reversals  errors ″ {}", fmt6(&e));
    println!("  worst {worst:.2}″ (paper ≈ 5″), start {worst0:.2}″, {} iterations", r.iterations);
    assert!(worst <= 5.0, "worst error {worst}″");
    // δ42, δ43 are not the second method's: left as given.
    assert_eq!(r.misalignment.d42_rad, start.d42_rad);
    // From a 60″ start (the method's stated domain, ≤ 1′) it reaches the same answer.
    let far = misalign_sins::with_triad(
        &truth,
        &misalign_sins::triad_angles(&truth).map(|a| a + 60.0 / ssis_common::ARCSEC_PER_RAD),
    );
    let r2 = misalign_sins::solve(&revs, &far, table.gamma_rad).unwrap();
    let e2 = misalign_sins::errors_arcsec(&r2.misalignment, &truth);
    println!("  from +60″ on every angle: {}", fmt6(&e2));
    for (a, b) in e.iter().zip(&e2) {
        assert!((a - b).abs() < 0.05, "start dependence {a} vs {b}");
    }
}

fn fmt6(v: &[f64; 6]) -> String {
    ssis_methods::misalign_sins::TRIAD_NAMES
        .iter()
        .zip(v)
        .map(|(n, x)| format!("{n} {x:+.2}"))
        .collect::<Vec<_>>()
        .join("  ")
}

// ---------------------------------------------------------------- 6. orbital

#[test]
fn orbital_calibration_on_flight_telemetry() {
    use ssis_common::ARCSEC_PER_RAD;
    use ssis_methods::orbital;
    let t0 = std::time::Instant::now();
    // The unit: the paper's "before" biases and scale factors, a star tracker 40″/−30″/25″
    // off its table mount; it flies with the ground campaign's geometry (here the true
    // misalignment plus 3″ on every angle, the second method's size of error).
    let truth_m = misalign_turns::example_truth();
    let (fog, star) = orbital::example_unit(truth_m);
    let mut sc = orbital::calibration_flight(fog, star, 10_000.0, 600.0, 200.0);
    let mut flown = ssis::calib::CalibrationTable::DEFAULT;
    let a = misalign_turns::angles(&truth_m).map(|x| x + 3.0 / ARCSEC_PER_RAD);
    flown.misalignment = misalign_turns::from_angles(&a);
    let table_path = tmp("orbital-flown.toml");
    ssis_common::table::write_toml(&table_path, &flown).unwrap();
    sc.table.file = Some(table_path.clone());
    let cap = orbital::fly(&sc).unwrap();
    let tel = orbital::Telemetry::decode(&cap.out, &cap.star);
    assert_eq!(tel.bad_frames, (0, 0));
    assert_eq!(tel.out.len() as f64, (sc.duration_s / 0.005).round());
    let r = orbital::calibrate(&tel, &cap.table, &orbital::Settings::default()).unwrap();
    println!(
        "flight {:.0} s simulated in {:.1} s; {} maneuvers",
        sc.duration_s,
        t0.elapsed().as_secs_f64(),
        r.maneuvers.len()
    );
    assert_eq!(r.maneuvers.len(), 4);
    let tau = orbital::observer_time_constant_s(&cap.table).unwrap();
    println!("observer's slowest time constant {tau:.0} s: bias averaged from 5τ after convergence");

    let mut truth_table = ssis::calib::CalibrationTable::DEFAULT;
    let e = sc.fog.errors.unwrap();
    truth_table.fog = e.fog;
    let (d_true, dk_true, eta_true) = orbital::truth_of(&truth_table, &cap.table, &sc.star_tracker);
    // 1. bias
    let d_err = (r.bias.drift_rad_s - d_true) * DEG_H_PER_RAD_S;
    println!(
        "bias: window {:.0}-{:.0} s, estimate {:.4} {:.4} {:.4} °/h, truth {:.4} {:.4} {:.4}, error {:+.4} {:+.4} {:+.4} °/h (paper after: ±0.05 °/h 3σ)",
        r.bias.window_s.0,
        r.bias.window_s.1,
        r.bias.drift_rad_s.x * DEG_H_PER_RAD_S,
        r.bias.drift_rad_s.y * DEG_H_PER_RAD_S,
        r.bias.drift_rad_s.z * DEG_H_PER_RAD_S,
        d_true.x * DEG_H_PER_RAD_S,
        d_true.y * DEG_H_PER_RAD_S,
        d_true.z * DEG_H_PER_RAD_S,
        d_err.x,
        d_err.y,
        d_err.z
    );
    assert!(d_err.amax() <= 0.05, "bias error {d_err:?} °/h");
    // 2. scale factors
    let sc_r = r.scale.as_ref().unwrap();
    for m in &sc_r.maneuvers {
        let u = m.axis();
        println!(
            "  maneuver {:.0}-{:.0} s about ({:+.3} {:+.3} {:+.3}): |Θ_ST| {:.4}°, uᵀDu {:+.5} %",
            m.span_s.0,
            m.span_s.1,
            u.x,
            u.y,
            u.z,
            m.theta_st_rad.norm().to_degrees(),
            m.relative_error() * 100.0
        );
    }
    let dk_err: Vec<f64> = (0..4).map(|i| (sc_r.dk[i] - dk_true[i]) * 100.0).collect();
    println!(
        "scale factors Δk %: estimate {:?} truth {:?} error {:?} (paper ≤ 0.002 %)",
        sc_r.dk.map(|x| format!("{:+.5}", x * 100.0)),
        dk_true.map(|x| format!("{:+.5}", x * 100.0)),
        dk_err.iter().map(|x| format!("{x:+.5}")).collect::<Vec<_>>()
    );
    let worst_dk = dk_err.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    assert!(worst_dk <= 0.002, "scale-factor error {worst_dk} %");
    // 3. mount
    let m = r.mount.as_ref().unwrap();
    let eta_err = (m.eta_rad - eta_true) * ARCSEC_PER_RAD;
    println!(
        "mount: η̂ {:.2} {:.2} {:.2}″, truth {:.2} {:.2} {:.2}″, error {:+.2} {:+.2} {:+.2}″ (|{:.2}|″; paper ≈ 20″, goal ≤ 10″), {} pairs",
        m.eta_rad.x * ARCSEC_PER_RAD,
        m.eta_rad.y * ARCSEC_PER_RAD,
        m.eta_rad.z * ARCSEC_PER_RAD,
        eta_true.x * ARCSEC_PER_RAD,
        eta_true.y * ARCSEC_PER_RAD,
        eta_true.z * ARCSEC_PER_RAD,
        eta_err.x,
        eta_err.y,
        eta_err.z,
        eta_err.norm(),
        m.samples
    );
    assert!(eta_err.amax() <= 10.0, "mount error {eta_err:?}″");
    // The table: bias and scale per FOG, the new mount.
    let nt = &r.table;
    for i in 0..4 {
        assert_eq!(nt.fog[i].scale_factor_error, (1.0 + sc_r.dk[i]) - 1.0);
    }
    let q_true = cap.table.st_mount()
        * ssis::math::quat_from_rotvec(
            &(nalgebra::Vector3::from(sc.star_tracker.misalignment_arcsec) / ARCSEC_PER_RAD),
        );
    let q_new = nt.st_mount();
    let mount_err = ssis::math::rotvec_from_quat(&(q_true.conjugate() * q_new)).norm() * ARCSEC_PER_RAD;
    println!("table mount q_bs error {mount_err:.2}″ (before {:.2}″)", eta_true.norm() * ARCSEC_PER_RAD);
    assert!(mount_err <= 10.0);
    // 4. what scale factors and mount leave unexplained: the noise floor with this table
    let u_arcsec: Vec<f64> = r.unexplained_rad_per_rad.iter().map(|v| v * ARCSEC_PER_RAD).collect();
    println!("left unexplained per maneuver {u_arcsec:.1?}″ per radian (refused above 30)");
    assert!(u_arcsec.iter().all(|v| *v <= 10.0), "{u_arcsec:?}");
    // The same unit flown with a nominal table (no ground misalignment calibration): the
    // mount would absorb the skew part and the scale factors the rest (0.044 % off when
    // measured); the method refuses instead of writing them.
    let nominal_path = tmp("orbital-nominal.toml");
    ssis_common::table::write_toml(&nominal_path, &ssis::calib::CalibrationTable::DEFAULT).unwrap();
    sc.table.file = Some(nominal_path);
    let cap = orbital::fly(&sc).unwrap();
    let tel = orbital::Telemetry::decode(&cap.out, &cap.star);
    let err = orbital::calibrate(&tel, &cap.table, &orbital::Settings::default()).expect_err("nominal table accepted");
    println!("flown with the nominal table: {err}");
    assert!(err.to_string().contains("does not describe this unit's FOG axes"), "{err}");
    println!("whole test {:.1} s", t0.elapsed().as_secs_f64());
}

/// The same calibration flight with a star tracker that is not white: a low-frequency
/// error (LFE) of 4″ 1σ per tracker axis correlated over 300 s. The bias (the observer's
/// average over its window) and the mount (RLS on rates between consecutive frames, where
/// the LFE moves by σ √(2T/τ) ≈ 0.16″ against the white noise's 9.4″) keep their bounds.
/// The scale factors do not: each turn's angle carries the LFE's change over the 600-s
/// turn (about 1.3 σ), and four turns for four FOGs amplify it; one set of turns gave
/// 64 ppm worst against the paper's 20 ppm (BENCHMARKS.md, "Star tracker with a
/// low-frequency error"). Printed, not asserted: the session this method needs with an
/// LFE is longer (more sets of turns) than this flight.
#[test]
fn orbital_calibration_with_a_tracker_lfe() {
    use ssis_common::ARCSEC_PER_RAD;
    use ssis_methods::orbital;
    let truth_m = misalign_turns::example_truth();
    let (fog, star) = orbital::example_unit(truth_m);
    let star = ssis_sim::star::StarSpec { lfe_sigma_arcsec: 4.0, lfe_tau_s: 300.0, ..star };
    let mut sc = orbital::calibration_flight(fog, star, 10_000.0, 600.0, 200.0);
    let mut flown = ssis::calib::CalibrationTable::DEFAULT;
    flown.misalignment =
        misalign_turns::from_angles(&misalign_turns::angles(&truth_m).map(|x| x + 3.0 / ARCSEC_PER_RAD));
    let table_path = tmp("orbital-lfe-flown.toml");
    ssis_common::table::write_toml(&table_path, &flown).unwrap();
    sc.table.file = Some(table_path);
    let cap = orbital::fly(&sc).unwrap();
    let r =
        orbital::calibrate(&orbital::Telemetry::decode(&cap.out, &cap.star), &cap.table, &orbital::Settings::default())
            .unwrap();
    let mut truth_table = ssis::calib::CalibrationTable::DEFAULT;
    truth_table.fog = sc.fog.errors.unwrap().fog;
    let (d_true, dk_true, eta_true) = orbital::truth_of(&truth_table, &cap.table, &sc.star_tracker);
    let d_err = (r.bias.drift_rad_s - d_true) * DEG_H_PER_RAD_S;
    let dk = &r.scale.as_ref().unwrap().dk;
    let dk_err = (0..4).map(|i| ((dk[i] - dk_true[i]) * 100.0).abs()).fold(0.0f64, f64::max);
    let eta_err = (r.mount.as_ref().unwrap().eta_rad - eta_true) * ARCSEC_PER_RAD;
    println!(
        "tracker LFE 4″ / 300 s, {:.0} s flight: bias error {:+.4} {:+.4} {:+.4} °/h, worst scale-factor error {dk_err:.5} %, \
         mount error {:+.2} {:+.2} {:+.2}″",
        sc.duration_s, d_err.x, d_err.y, d_err.z, eta_err.x, eta_err.y, eta_err.z
    );
    assert!(d_err.amax() <= 0.05, "bias error {d_err:?} °/h");
    assert!(eta_err.amax() <= 10.0, "mount error {eta_err:?}″");
}

#[test]
fn allan_reports_an_unresolved_rate_random_walk_as_an_upper_bound() {
    // 2 h of 1-s means: the random walk of 0.002 °/h/√h is far below the white noise at
    // every τ ≤ 30 min, so the fit cannot resolve it.
    let rrw = 0.002;
    for seed in 1..=4 {
        let rates = allan::simulate_static(0.005, rrw, 0.3, 1.0, 2 * 3600, seed);
        let pts = allan::overlapping_adev(&rates, 1.0, 8).unwrap();
        let nt = allan::noise_terms(&pts).unwrap();
        println!("seed {seed}: ARW {}, RRW {}", nt.arw_deg_sqrt_h.text(5), nt.rrw_deg_h_sqrt_h.text(4));
        assert!(nt.arw_deg_sqrt_h.value().is_some(), "ARW resolved");
        match nt.rrw_deg_h_sqrt_h {
            allan::Estimate::UpperBound(b) => assert!(b >= rrw && b.is_finite(), "bound {b} below the truth"),
            r => panic!("seed {seed}: RRW {r:?} claimed resolved from 2 h"),
        }
    }
}
