//! The model lab finds what the model lacks: one hidden effect per session found, added and
//! removed; no false discoveries on sessions without one; a user expression for an effect
//! outside the catalog.
//!
//! Figures print with `cargo test --test effects -- --nocapture`.

use ssis_lab::diagnose::{diagnose, Options};
use ssis_lab::fit::{add_term, held_out_many, pooled, DEFAULT_BLOCKS};
use ssis_lab::model::{Catalog, Kind};
use ssis_lab::session::nominal_axes;
use ssis_lab::simulate::{hidden_effect_rad_s, preset, SimSession};

mod common;
use common::{dh, scratch, session, starting_model};

/// (a) one hidden effect per session: diagnose ranks it first, `add` cuts the held-out RMS
/// by ≥ 50 % to within 20 % of the noise floor, coefficients within 10 %.
fn hidden_effect(name: &str, term: Catalog, truth_of: impl Fn(&SimSession, usize) -> Vec<f64>) {
    let dir = scratch(&format!("hidden-{name}"));
    let (sim, s) = session(&dir, name, 7, true);
    let model = starting_model(name);
    let d = diagnose(&model, &s, &Options::default()).unwrap();
    println!("{name}: {} rows, noise floor {:.4} deg/h", s.len(), dh(sim.truth.noise_rad_s));
    for (rank, c) in d.candidates.iter().enumerate().take(5) {
        println!(
            "  rank {} {:<40} p {:.2e} held-out {:.4} -> {:.4} deg/h {}",
            rank + 1,
            c.kind.label(),
            c.p_value,
            dh(c.before_rad_s),
            dh(c.after_rad_s),
            if c.significant { "significant" } else { "" }
        );
    }
    assert_eq!(d.candidates[0].kind, Kind::Catalog(term), "{name}: the true effect is not ranked first");
    assert!(d.candidates[0].significant);
    // The systematic part the term removes on the test blocks against the true effect's RMS
    // there, after what the starting model absorbs of it (fitted on the training blocks: a
    // noise-free session whose error is the hidden effect alone), pooled over FOGs.
    let hidden = hidden_effect_rad_s(&preset(name, 7, true).unwrap());
    let mut effect_only = s.clone();
    let axes = nominal_axes();
    for (fog, h) in hidden.iter().enumerate() {
        effect_only.fogs[fog].rate_rad_s =
            s.ref_rad_s.iter().zip(h).map(|(w, v)| axes[fog].dot(&nalgebra::Vector3::from(*w)) + v).collect();
    }
    let per_fog = held_out_many(std::slice::from_ref(&model), &effect_only, DEFAULT_BLOCKS, None).unwrap().remove(0);
    let (true_rms, (removed, lo, hi)) = (pooled(&per_fog), d.candidates[0].removed_rad_s());
    println!(
        "  removed {:.4} deg/h (1 sigma {:.4} .. {:.4}), true effect RMS on the test blocks {:.4} deg/h ({:+.1} %)",
        dh(removed),
        dh(lo),
        dh(hi),
        dh(true_rms),
        100.0 * (removed / true_rms - 1.0)
    );
    assert!((removed / true_rms - 1.0).abs() <= 0.2, "{name}: removed {removed:e} vs true {true_rms:e} rad/s");
    let out = add_term(&model, &Kind::Catalog(term), &s, DEFAULT_BLOCKS).unwrap();
    let floor = sim.truth.noise_rad_s;
    let t = out.model.kinds().iter().position(|k| *k == Kind::Catalog(term)).unwrap();
    for fog in 0..s.fogs.len() {
        let (b, a) = (out.before_rad_s[fog], out.after_rad_s[fog]);
        let fitted = &out.model.terms[t].coef[fog];
        let truth = truth_of(&sim, fog);
        let scale = truth.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        let err: Vec<f64> = fitted.iter().zip(&truth).map(|(f, t)| (f - t) / scale).collect();
        println!(
            "  FOG{fog}: held-out {:.4} -> {:.4} deg/h (cut {:.0} %, {:.2} x floor), coef {:?} truth {:?} err {:?}",
            dh(b),
            dh(a),
            100.0 * (1.0 - a / b),
            a / floor,
            fitted,
            truth,
            err
        );
        assert!(a <= 0.5 * b, "{name} FOG{fog}: cut {:.1} % < 50 %", 100.0 * (1.0 - a / b));
        assert!(a <= 1.2 * floor, "{name} FOG{fog}: {:.3} x the noise floor", a / floor);
        assert!(err.iter().all(|e| e.abs() <= 0.10), "{name} FOG{fog}: coefficient error {err:?}");
    }
    println!("  pooled held-out {:.4} -> {:.4} deg/h", dh(pooled(&out.before_rad_s)), dh(pooled(&out.after_rad_s)));
}

#[test]
fn a_hidden_magnetic() {
    hidden_effect("magnetic", Catalog::Magnetic, |s, i| s.truth.magnetic_rad_s_per_nt[i].to_vec());
}

#[test]
fn a_hidden_temp_rate() {
    hidden_effect("thermal", Catalog::TempRate, |s, i| vec![s.truth.g[i]]);
}

#[test]
fn a_hidden_asymmetry() {
    hidden_effect("asymmetry", Catalog::SfAsymmetry, |s, i| vec![s.truth.k_asym[i]]);
}

/// (b) no missing effect: 20 sessions (the three kinds in turn, hidden effect off),
/// `diagnose` finds nothing significant on at least 19.
#[test]
fn b_no_false_discovery() {
    let dir = scratch("null");
    let mut clean = 0;
    for seed in 0..20u64 {
        let name = ["magnetic", "thermal", "asymmetry"][seed as usize % 3];
        let (_, s) = session(&dir, name, 100 + seed, false);
        let d = diagnose(&starting_model(name), &s, &Options::default()).unwrap();
        let sig: Vec<String> = d.significant().map(|c| format!("{} (p {:.1e})", c.kind.label(), c.p_value)).collect();
        let best = &d.candidates[0];
        println!(
            "seed {seed:>2} {name:<10} smallest p {:.2e} ({}) significant: {sig:?}",
            best.p_value,
            best.kind.label()
        );
        if sig.is_empty() {
            clean += 1;
        }
    }
    println!("no significant missing effect on {clean} of 20 sessions");
    assert!(clean >= 19, "false discoveries on {} of 20 sessions", 20 - clean);
}

/// (c) a user expression recovers an effect outside the catalog: sin 2ψ.
#[test]
fn c_user_expression() {
    let dir = scratch("expr");
    let (sim, s) = session(&dir, "sin2psi", 11, true);
    let model = starting_model("sin2psi");
    let d = diagnose(&model, &s, &Options::default()).unwrap();
    println!("sin2psi session, top candidate of the catalog + residual search: {}", d.candidates[0].kind.label());
    let kind = Kind::parse_arg("sin(2*psi_rad)").unwrap();
    let out = add_term(&model, &kind, &s, DEFAULT_BLOCKS).unwrap();
    let t = out.model.terms.len() - 1;
    for fog in 0..4 {
        let (f, truth) = (out.model.terms[t].coef[fog][0], sim.truth.sin2psi_rad_s[fog]);
        println!(
            "  FOG{fog}: coef {:.5} deg/h, truth {:.5} deg/h, error {:.2} %; held-out {:.4} -> {:.4} deg/h (floor {:.4})",
            dh(f),
            dh(truth),
            100.0 * (f - truth) / truth,
            dh(out.before_rad_s[fog]),
            dh(out.after_rad_s[fog]),
            dh(sim.truth.noise_rad_s)
        );
        assert!(((f - truth) / truth).abs() <= 0.10, "FOG{fog}: expression coefficient off by more than 10 %");
    }
}
