//! Done-when (a): the paper's Fig. 7 case. And the gain computation against NOTES.md.

use std::path::Path;

use ssis::calib::ObserverConfig;
use ssis::observer::steady_state_gains;
use ssis_host::harness::run;
use ssis_host::scenario::Scenario;
use ssis_host::sim::fog::TriadError;
use ssis_host::stats::AxisStats;

fn scenario(name: &str) -> Scenario {
    Scenario::from_file(&Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios").join(name)).expect("scenario loads")
}

/// Runs `sc` and returns (mean drift estimate over the settled part, the true value the
/// observer should find there, convergence time to within 1 % for good).
fn fig7(sc: &Scenario) -> ([f64; 3], [f64; 3], f64) {
    let mut est = AxisStats::default();
    let mut target = AxisStats::default();
    let mut outside_last = 0.0;
    let mut drift_sys_prev = [0.0; 3];
    let summary = run(sc, |r| {
        let d = [r.out.drift_rad_s.x, r.out.drift_rad_s.y, r.out.drift_rad_s.z];
        // The drift the observer can see: Δω + (−δK + δΨ) ω, from the harness's
        // systematic error of the combined gyros (white noise excluded).
        let t = r.drift_sys_rad_s;
        drift_sys_prev = t;
        if (0..3).any(|k| (d[k] - t[k]).abs() > 0.01 * t[k].abs()) {
            outside_last = r.t_s;
        }
        if r.t_s >= sc.settle_s {
            est.push(d);
            target.push(t);
        }
    })
    .expect("run");
    println!("{}", summary.report());
    (est.mean(), target.mean(), outside_last)
}

#[test]
fn fig7_bias_identified_within_1_percent_inertial_hold() {
    let sc = scenario("fig7-bias.toml");
    let truth = TriadError::FIG7.bias_rad_s;
    let (est, target, conv) = fig7(&sc);
    println!("Fig. 7, inertial hold: converged (all axes within 1 % for good) at {conv:.1} s");
    for k in 0..3 {
        let rel = (est[k] - truth[k]) / truth[k];
        println!(
            "  axis {k}: Δω = {:+.4e} rad/s, estimate {:+.4e} rad/s ({:+.3} %), observable drift {:+.4e}",
            truth[k],
            est[k],
            100.0 * rel,
            target[k]
        );
        assert!(rel.abs() <= 0.01, "axis {k}: estimate {} vs Δω {} ({:.3} %)", est[k], truth[k], 100.0 * rel);
    }
    assert!(conv < sc.settle_s, "not converged before the averaging window: {conv} s");
}

#[test]
fn fig7_bias_in_earth_pointing_shows_the_scale_factor_term() {
    // Same errors in orbital-rate Earth pointing: the observer sees Δω + (−δK + δΨ) ω,
    // and δK_y ω_orb is 1.1 % of Δω_y. The estimate must match what is observable
    // within 1 %; its offset from Δω is the scale-factor term the paper calibrates
    // separately with the 360° maneuver.
    let mut sc = scenario("fig7-bias.toml");
    sc.motion.base_rate_deg_s = [0.0, -0.0638, 0.0];
    let truth = TriadError::FIG7.bias_rad_s;
    let (est, target, conv) = fig7(&sc);
    println!("Fig. 7, Earth pointing: converged at {conv:.1} s");
    for k in 0..3 {
        let rel = (est[k] - target[k]) / target[k];
        println!(
            "  axis {k}: Δω {:+.4e}, observable {:+.4e}, estimate {:+.4e} ({:+.3} % of observable, {:+.3} % of Δω)",
            truth[k],
            target[k],
            est[k],
            100.0 * rel,
            100.0 * (est[k] - truth[k]) / truth[k]
        );
        assert!(rel.abs() <= 0.01, "axis {k}: estimate {} vs observable {}", est[k], target[k]);
    }
    // The scale-factor term is real and of the predicted size on Y: −δK_y ω_y = 0.002 · (−ω_orb).
    let predicted = 0.002 * (-0.0638f64).to_radians();
    assert!(
        (target[1] - truth[1] - predicted).abs() < 0.05 * predicted.abs(),
        "{} vs {}",
        target[1] - truth[1],
        predicted
    );
}

#[test]
fn steady_state_gains_match_notes() {
    // NOTES.md: ARW 0.005 °/√h, 20″ 3σ star tracker at 4 Hz, RRW 0.01 °/h/√h →
    // K = [0.0224, −1.24e-5 /s] (our K_U is the negated second gain).
    let g = steady_state_gains(&ObserverConfig::PAPER).expect("gains");
    println!("steady-state gains at 4 Hz: K_B {:.5}, K_U {:.4e} /s", g.k_b[0], g.k_u_per_s[0]);
    assert!((g.k_b[0] - 0.0224).abs() < 0.0005, "K_B {}", g.k_b[0]);
    assert!((g.k_u_per_s[0] - 1.24e-5).abs() < 0.03e-5, "K_U {}", g.k_u_per_s[0]);
    let bad = ObserverConfig { st_sigma_arcsec: 0.0, ..ObserverConfig::PAPER };
    assert!(steady_state_gains(&bad).is_err());
}
