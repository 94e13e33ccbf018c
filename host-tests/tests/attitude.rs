//! Done-when (d): computational drift of the attitude algorithm against analytic truth.
//! - 0.05° half-angle coning at 5 Hz, 200 Hz updates: ≤ 0.01″/h;
//! - 10 h of orbital-rate rotation: ≤ 1e-3″.

use nalgebra::{Quaternion, Vector3};
use ssis::attitude::{Attitude, Coning};
use ssis::math::rotvec_from_quat;
use ssis_common::ARCSEC_PER_RAD;
use ssis_sim::truth::{ConingMotion, MotionSpec, Truth};

/// Integrates `hours` of `motion` at `rate_hz` with `coning`; returns the final error, ″.
fn final_error_arcsec(motion: &MotionSpec, rate_hz: f64, hours: f64, coning: Coning) -> f64 {
    let mut truth = Truth::new(motion.clone());
    let mut att = Attitude::new(truth.quaternion(), coning);
    let dt = 1.0 / rate_hz;
    let n = (hours * 3600.0 * rate_hz).round() as u64;
    for _ in 0..n {
        let ts = truth.advance(dt);
        assert!(att.step(&ts.dtheta_rad));
    }
    let e = rotvec_from_quat(&(truth.quaternion().conjugate() * att.quaternion()));
    e.norm() * ARCSEC_PER_RAD
}

fn coning() -> MotionSpec {
    MotionSpec { coning: Some(ConingMotion { half_angle_deg: 0.05, freq_hz: 5.0 }), ..Default::default() }
}

#[test]
fn coning_drift_three_sample_below_0_01_arcsec_per_hour() {
    let m = coning();
    let none = final_error_arcsec(&m, 200.0, 1.0, Coning::None);
    let two = final_error_arcsec(&m, 200.0, 1.0, Coning::TwoSample);
    let three = final_error_arcsec(&m, 200.0, 1.0, Coning::ThreeSample);
    println!("coning 0.05° at 5 Hz, 200 Hz updates, 1 h: drift none {none:.3}″/h, two-sample {two:.4}″/h, three-sample {three:.5}″/h");
    // The terms must matter, in the order theory says.
    assert!(none > 10.0 * two, "two-sample term ineffective: {none} vs {two}");
    assert!(two > 10.0 * three, "three-sample term ineffective: {two} vs {three}");
    assert!(three <= 0.01, "coning drift {three}″/h > 0.01″/h");
}

#[test]
fn orbital_rate_ten_hours_below_1e_3_arcsec() {
    // Orbital rate (0.0638 °/s) about an axis that is not a body axis.
    let axis = Vector3::new(0.3, -0.9, 0.2).normalize() * 0.0638;
    let m = MotionSpec {
        base_rate_deg_s: [axis.x, axis.y, axis.z],
        initial_q: Some([0.9, 0.1, -0.3, 0.2]),
        ..Default::default()
    };
    // Analytic truth: Λ(t) = Λ0 ∘ q(ω t).
    let mut att = Attitude::new(Truth::new(m.clone()).quaternion(), Coning::ThreeSample);
    let q0 = att.quaternion();
    let w = axis.map(f64::to_radians);
    let dt = 0.005;
    let n = 10 * 3600 * 200;
    for _ in 0..n {
        att.step(&(w * dt));
    }
    let t = n as f64 * dt;
    let q_true: Quaternion<f64> = q0 * ssis::math::quat_from_rotvec(&(w * t));
    let e = rotvec_from_quat(&(q_true.conjugate() * att.quaternion())).norm() * ARCSEC_PER_RAD;
    println!("orbital rate, 10 h at 200 Hz: error {e:.2e}″");
    assert!(e <= 1e-3, "orbital-rate error {e}″ > 1e-3″");
}

#[test]
fn truth_generator_matches_analytic_constant_rate() {
    // The generic (RK4 + Gauss) truth path against the analytic solution, 1 h.
    let m = MotionSpec { base_rate_deg_s: [0.02, -0.05, 0.03], ..Default::default() };
    let w = Vector3::from(m.base_rate_deg_s).map(f64::to_radians);
    let mut truth = Truth::new(m);
    let mut sum = Vector3::zeros();
    for _ in 0..720_000 {
        sum += truth.advance(0.005).dtheta_rad;
    }
    let q_true = ssis::math::quat_from_rotvec(&(w * 3600.0));
    let e = rotvec_from_quat(&(q_true.conjugate() * truth.quaternion())).norm() * ARCSEC_PER_RAD;
    let de = (sum - w * 3600.0).norm() * ARCSEC_PER_RAD;
    assert!(e < 1e-4 && de < 1e-4, "truth generator off: attitude {e}″, increments {de}″");
}

/// Units in the last place between `a` and the reference `b`.
fn ulps(a: f64, b: f64) -> f64 {
    if a == b {
        return 0.0;
    }
    let ulp = f64::EPSILON * b.abs().max(f64::MIN_POSITIVE);
    ((a - b) / ulp).abs()
}

/// The flight code's sin/cos (`math::sin_cos`, written for the firmware's flash) against
/// the standard library: within 2 ulp (of the value, or of 1 near zeros of the function,
/// where the reduction's absolute error counts) over a dense sweep of ±4π and random
/// angles up to 1.6e6 rad; exact at 0 and at the built-in test's known answer sin 2;
/// NaN outside its range and for non-finite input.
#[test]
fn sin_cos_matches_std_within_two_ulp() {
    use rand::{Rng, SeedableRng};
    let mut worst = 0.0f64;
    let mut check = |x: f64| {
        let (s, c) = ssis::math::sin_cos(x);
        for (got, want) in [(s, x.sin()), (c, x.cos())] {
            let e = ulps(got, want).min(((got - want) / f64::EPSILON).abs());
            worst = worst.max(e);
            assert!(e <= 2.0, "sin_cos({x:e}): {got:e} vs {want:e} ({e:.2} ulp)");
        }
    };
    for i in -200_000..=200_000 {
        check(f64::from(i) * 4.0 * std::f64::consts::PI / 200_000.0);
    }
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
    for _ in 0..200_000 {
        check(rng.random_range(-1.6e6..1.6e6));
        check(rng.random_range(-1.0..1.0) * 1e-3);
    }
    println!("sin_cos worst {worst:.2} ulp");
    assert_eq!(ssis::math::sin_cos(0.0), (0.0, 1.0));
    assert_eq!(ssis::math::sin_cos(2.0).0.to_bits(), 0x3FED_18F6_EAD1_B446);
    for x in [f64::NAN, f64::INFINITY, -f64::INFINITY, 1e10, -2e9] {
        let (s, c) = ssis::math::sin_cos(x);
        assert!(s.is_nan() && c.is_nan(), "{x}");
    }
}
