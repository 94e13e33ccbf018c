//! Loosely coupled GNSS aiding: the
//! 600 s ascent with the paper's FOG figures and the assumed accelerometer figures,
//! free-inertial against GNSS-aided (1 Hz, 5 m / 0.1 m/s per axis) with a 30 s outage.

use nalgebra::Vector3;
use ssis::nav::gnss::{AidedNav, GnssError, GnssFix};
use ssis_sim::accel::AccelSpec;
use ssis_sim::fog::FogSpec;
use ssis_sim::gnss::GnssSpec;
use ssis_sim::launch::LaunchProfile;
use ssis_sim::lv::{filter_config, run, AscentRecord};

const OUTAGE: [f64; 2] = [300.0, 330.0];

#[test]
fn aided_ascent_with_outage() {
    let rec = AscentRecord::record(LaunchProfile::default(), 1.25e-3, 600.0);
    let fog = FogSpec::paper_post_calibration();
    let acc = AccelSpec::typical_pendulous();
    let cfg = filter_config(&fog, &acc);
    let spec = GnssSpec { outages_s: vec![OUTAGE], ..GnssSpec::default() };
    let seed = 1;
    let free = run(&rec, Some(&fog), Some(&acc), None, seed, 1.0);
    let aided = run(&rec, Some(&fog), Some(&acc), Some((&spec, &cfg)), seed, 1.0);
    let at = |v: &[ssis_sim::lv::NavError], t: f64| v[(t.round() as usize) - 1];
    println!("| t, s | free: position m, velocity m/s | aided: position m, velocity m/s | filter 1σ: m, m/s |");
    for t in [60.0, 120.0, 180.0, 240.0, 299.0, 300.0, 310.0, 320.0, 330.0, 340.0, 360.0, 420.0, 480.0, 540.0, 600.0] {
        let (f, a) = (at(&free.errors, t), at(&aided.errors, t));
        let (sp, sv) = aided.sigma[(t.round() as usize) - 1];
        println!("| {t:.0} | {:.2}, {:.4} | {:.2}, {:.4} | {sp:.2}, {sv:.4} |", f.pos_m, f.vel_m_s, a.pos_m, a.vel_m_s);
    }
    let before = at(&aided.errors, OUTAGE[0] - 1.0);
    let end_outage = at(&aided.errors, OUTAGE[1]);
    let (sp_end, sv_end) = aided.sigma[OUTAGE[1] as usize - 1];
    let last = at(&aided.errors, 600.0);
    let free_last = at(&free.errors, 600.0);
    let worst_after = aided
        .errors
        .iter()
        .filter(|e| e.t_s >= OUTAGE[1] + 30.0)
        .fold((0.0f64, 0.0f64), |m, e| (m.0.max(e.pos_m), m.1.max(e.vel_m_s)));
    println!(
        "fixes used {}, refused {}; outage growth: position {:.2} → {:.2} m, velocity {:.4} → {:.4} m/s (filter 1σ at outage end {sp_end:.2} m, {sv_end:.4} m/s); \
         worst from 30 s after the outage: {:.2} m, {:.4} m/s; at 600 s aided {:.2} m / {:.4} m/s, free {:.2} m / {:.4} m/s",
        aided.fixes.0, aided.fixes.1, before.pos_m, end_outage.pos_m, before.vel_m_s, end_outage.vel_m_s, worst_after.0, worst_after.1,
        last.pos_m, last.vel_m_s, free_last.pos_m, free_last.vel_m_s
    );
    // Every fix outside the outage is used: 600 − 30 fixes.
    assert_eq!(aided.fixes, (570, 0));
    // Aiding bounds the error: at 600 s at least 10x below free-inertial in both.
    assert!(last.pos_m * 10.0 < free_last.pos_m && last.vel_m_s * 10.0 < free_last.vel_m_s);
    // Within the GNSS noise (5 m, 0.1 m/s per axis; 3D 3σ ≈ 26 m, 0.52 m/s) after
    // re-acquisition.
    assert!(worst_after.0 < 26.0 && worst_after.1 < 0.52, "{worst_after:?}");
    // The filter's own uncertainty covers the outage's error growth (3σ).
    assert!(end_outage.pos_m < 3.0 * sp_end && end_outage.vel_m_s < 3.0 * sv_end);
}

/// Bad and implausible fixes are refused and leave the state alone.
#[test]
fn refuses_bad_and_gated_fixes() {
    let p = LaunchProfile::default();
    let st = ssis::nav::NavState { q_eb: p.q0(), v_e_m_s: Vector3::zeros(), r_e_m: p.pad_ecef_m() };
    let cfg = filter_config(&FogSpec::paper_post_calibration(), &AccelSpec::typical_pendulous());
    let mut a = AidedNav::new(st, 1.25e-3, cfg).expect("init");
    let good = GnssFix { r_e_m: st.r_e_m, v_e_m_s: st.v_e_m_s, sigma_pos_m: 5.0, sigma_vel_m_s: 0.1 };
    let nan = GnssFix { r_e_m: Vector3::new(f64::NAN, 0.0, 0.0), ..good };
    assert_eq!(a.gnss_update(&nan), Err(GnssError::BadFix));
    assert_eq!(a.gnss_update(&GnssFix { sigma_pos_m: 0.0, ..good }), Err(GnssError::BadFix));
    let jump = GnssFix { r_e_m: st.r_e_m + Vector3::new(1_000.0, 0.0, 0.0), ..good };
    assert_eq!(a.gnss_update(&jump), Err(GnssError::Gated));
    assert_eq!(*a.state(), st);
    assert_eq!(a.counts(), (0, 3));
    assert_eq!(a.gnss_update(&good), Ok(()));
    assert_eq!(a.counts(), (1, 3));
}

/// The attitude coupling and feedback: from a 78″ initial attitude error, with ideal
/// sensors and exact fixes (σ 1 m, 0.01 m/s declared), the thrust makes the tilt
/// observable and the filter removes the error (measured: 0.25″ after 200 s). A sign
/// error in −[f×] or in the feedback would make it grow.
#[test]
fn attitude_error_converges_under_thrust() {
    let rec = AscentRecord::record(LaunchProfile::default(), 1.25e-3, 200.0);
    let mut cfg = filter_config(&FogSpec::paper_post_calibration(), &AccelSpec::typical_pendulous());
    cfg.init_att_rad = 5e-4;
    let mut init = rec.initial;
    let err0 = Vector3::new(2e-4, -3e-4, 1e-4);
    init.q_eb = ssis::math::quat_from_rotvec(&err0) * init.q_eb;
    let mut a = AidedNav::new(init, 1.25e-3, cfg).expect("init");
    let mut last = 0.0;
    for (k, ((dth, dv), tr)) in rec.increments.iter().zip(&rec.truth).enumerate() {
        a.step(dth, dv).expect("step");
        if (k + 1) % 800 == 0 {
            let fix = GnssFix { r_e_m: tr.r_e_m, v_e_m_s: tr.v_e_m_s, sigma_pos_m: 1.0, sigma_vel_m_s: 0.01 };
            a.gnss_update(&fix).expect("fix");
        }
        last = ssis_sim::lv::angle_between(&a.state().q_eb, &tr.q_eb);
    }
    let arc = ssis_common::ARCSEC_PER_RAD;
    println!("attitude error {:.1}″ → {:.2}″ after 200 s", err0.norm() * arc, last * arc);
    assert!(last * arc < 2.0, "attitude error {:.2}″ after 200 s", last * arc);
}
