//! Done-when (c): compensation inverts the simulator's error model (every term of the
//! table) to ≤ 1e-9 rad/s; the four-axis and every three-axis combination recover the
//! body rate over a misaligned geometry; the parity residual vanishes for consistent
//! data and sees a single-FOG error.

use nalgebra::{Vector3, Vector4};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha20Rng;
use ssis::calib::{CalibrationTable, FogCal, Misalignment, GAMMA_NOMINAL_RAD};
use ssis::combination::{Combiner, FogSet};
use ssis::compensation::{compensate_rate, TempRateEstimator};

fn arcsec(x: f64) -> f64 {
    x / 206_264.806
}

/// A table with every term non-zero.
fn full_table(rng: &mut ChaCha20Rng) -> CalibrationTable {
    let mut t = CalibrationTable::DEFAULT;
    for f in t.fog.iter_mut() {
        *f = FogCal {
            bias_rad_s: rng.random_range(-5e-6..5e-6),
            scale_factor_error: rng.random_range(-1e-3..1e-3),
            t_ref_degc: 25.0,
            thermal_t_rad_s: [
                rng.random_range(-1e-7..1e-7),
                rng.random_range(-1e-8..1e-8),
                rng.random_range(-1e-9..1e-9),
            ],
            thermal_g_rad_s_per_degc_s: rng.random_range(-1e-5..1e-5),
            thermal_tg_rad_s_per_degc2_s: rng.random_range(-1e-6..1e-6),
        };
    }
    let mut a = || arcsec(rng.random_range(-300.0..300.0));
    t.misalignment = Misalignment {
        d12_rad: a(),
        d13_rad: a(),
        d21_rad: a(),
        d23_rad: a(),
        d31_rad: a(),
        d32_rad: a(),
        d42_rad: a(),
        d43_rad: a(),
    };
    t
}

#[test]
fn compensation_inverts_the_error_model() {
    let mut rng = ChaCha20Rng::seed_from_u64(7);
    let mut worst = 0.0f64;
    for _ in 0..200 {
        let t = full_table(&mut rng);
        let axes = t.axes();
        let w =
            Vector3::new(rng.random_range(-0.17..0.17), rng.random_range(-0.17..0.17), rng.random_range(-0.17..0.17));
        let temp = rng.random_range(10.0..40.0);
        let g = rng.random_range(-0.01..0.01);
        for (i, f) in t.fog.iter().enumerate() {
            // The simulator's model (sim::fog): (1+k) s·ω + drift(T, G).
            let raw = (1.0 + f.scale_factor_error) * axes[i].dot(&w) + f.drift_rad_s(temp, g);
            let back = compensate_rate(f, raw, temp, g);
            worst = worst.max((back - axes[i].dot(&w)).abs());
        }
    }
    println!("worst compensation residual {worst:.2e} rad/s");
    assert!(worst <= 1e-9, "compensation residual {worst} rad/s");
}

#[test]
fn every_combination_recovers_the_body_rate() {
    let mut rng = ChaCha20Rng::seed_from_u64(11);
    for _ in 0..100 {
        let t = full_table(&mut rng);
        let axes = t.axes();
        let comb = Combiner::new(&axes);
        let w = Vector3::new(rng.random_range(-0.2..0.2), rng.random_range(-0.2..0.2), rng.random_range(-0.2..0.2));
        let m = Vector4::from_fn(|i, _| axes[i].dot(&w));
        let sets = [FogSet::ALL, FogSet(0b1110), FogSet(0b1101), FogSet(0b1011), FogSet(0b0111)];
        for s in sets {
            let mut mm = m;
            // Garbage in the excluded slot must not leak into the solution.
            for i in 0..4 {
                if !s.contains(i) {
                    mm[i] = 1e3;
                }
            }
            let got = comb.combine(&mm, s).expect("geometry spans 3-D");
            assert!((got - w).norm() < 1e-15 * 1e3 + 1e-14, "set {s:?}: {got} vs {w}");
        }
        assert!(comb.parity(&m).abs() < 1e-15, "parity of consistent data {}", comb.parity(&m));
        // A single-FOG error shows in the parity residual with gain |v_i|.
        let v = comb.parity_vector();
        for i in 0..4 {
            let mut bad = m;
            bad[i] += 1e-6;
            let p = comb.parity(&bad);
            assert!((p - v[i] * 1e-6).abs() < 1e-15 && v[i].abs() > 0.4, "fog {i}: parity {p}, v {v}");
        }
        assert!(comb.combine(&m, FogSet(0b0011)).is_err(), "two FOGs cannot make a rate");
    }
}

#[test]
fn nominal_geometry_is_the_papers() {
    // FOG4 equally inclined to FOG1..3, opposite to (1,1,1)/√3 (γ = 125°15'52").
    let s = Misalignment::default().axes(GAMMA_NOMINAL_RAD);
    let e4 = -Vector3::new(1.0, 1.0, 1.0).normalize();
    assert!((s[3] - e4).norm() < 1e-9, "s4 = {}", s[3]);
    for (i, e) in [Vector3::x(), Vector3::y(), Vector3::z()].iter().enumerate() {
        assert!((s[i] - e).norm() < 1e-15);
    }
    // First-order forms quoted in the paper's calibration equations (second-order terms
    // are ~(8·1e-4)²/2 = 3e-7; a wrong sign or index would show at 1e-4).
    let d = 1e-4;
    let m = Misalignment {
        d12_rad: d,
        d13_rad: 2.0 * d,
        d21_rad: 3.0 * d,
        d23_rad: 4.0 * d,
        d31_rad: 5.0 * d,
        d32_rad: 6.0 * d,
        d42_rad: 7.0 * d,
        d43_rad: 8.0 * d,
    };
    let s = m.axes(GAMMA_NOMINAL_RAD);
    let lin =
        [Vector3::new(1.0, 2.0 * d, -d), Vector3::new(-4.0 * d, 1.0, 3.0 * d), Vector3::new(6.0 * d, -5.0 * d, 1.0)];
    for i in 0..3 {
        assert!((s[i] - lin[i]).norm() < 1e-6, "fog {}: {} vs {}", i + 1, s[i], lin[i]);
    }
    let (cg, sg, cg2, sg2) = (0.816497, 0.577350, 0.577351, 0.408248);
    let s4 = -Vector3::new(cg2, cg2, sg)
        + Vector3::new(-sg2, -sg2, cg) * 7.0 * d
        + Vector3::new(1.0, -1.0, 0.0) * cg2 * 8.0 * d;
    assert!((s[3] - s4).norm() < 2e-6, "fog 4: {} vs {}", s[3], s4);
}

#[test]
fn temperature_rate_estimator_tracks_a_ramp() {
    // 0.25 °C/min (the paper's gradient level) seen through 1/256 °C quantisation at 5 ms.
    let dt = 0.005;
    let mut est = TempRateEstimator::new(dt, 30.0);
    let g_true = 0.25 / 60.0;
    let mut worst: f64 = 0.0;
    for k in 0..(600.0 / dt) as usize {
        let t = 20.0 + g_true * k as f64 * dt;
        let q = (t * 256.0).round() / 256.0;
        let g = est.update(q, dt).g_degc_s;
        if k as f64 * dt > 300.0 {
            worst = worst.max((g - g_true).abs());
        }
    }
    println!("G error after 300 s: {worst:.2e} °C/s");
    assert!(worst < 0.05 * g_true, "G estimate off by {worst} °C/s");
}
