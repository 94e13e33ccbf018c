//! The lab and the flight unit: a table fitted by the lab, replayed through
//! `FlightCore::step()`, cuts the error by the factor the lab predicted; the firmware's own
//! logs (a capture of its output link, the per-step CSV of `ssis-qemu`) read as sessions.
//!
//! Figures print with `cargo test --test flight -- --nocapture`.

use ssis::calib::CalibrationTable;
use ssis_common::DEG_H_PER_RAD_S;
use ssis_lab::fit::{fit_model, residuals, Fitted};
use ssis_lab::model::{Catalog, Kind, Model};
use ssis_lab::session::{read_session, Session};
use ssis_lab::simulate::generate;
use ssis_lab::stream::{prepare, Prepared};

mod common;
use common::{dh, scratch, session};

/// (d) round trip to flight. The lab fits the onboard terms on a thermal rate-table
/// session, exports the table (through its binary and TOML files, as the firmware gets it),
/// and the same session is replayed through `FlightCore::step()` (`lab::replay`: one FOG
/// frame per FOG per row, mock links), once with the starting table (nominal, no error
/// terms) and once with the exported one. The core's output body rate is compared with the
/// session's reference rate; the error must fall by the factor the lab predicted.
///
/// The lab's prediction at body level: the core combines the FOGs by least squares over the
/// table's axes, ω̂ = H⁺ m, so with the starting table its error is H₀⁺ y (y the FOG errors
/// the lab sees, y_i = ω_i,raw − s_i⁰·ω_ref) and with the exported one H⁺ (r_i / (1 + k_i))
/// (r the lab's residual). What the lab cannot see and the core adds: the frame's
/// quantisation (2^-36 rad, carried; 1/256 °C) and the core's own T and G (its α-β tracker,
/// τ = 30 s, where the lab fits a line over 60 s). Tolerances:
/// - the error before: 1e-6 relative (quantisation only, ~1e-12 of the error here);
/// - row by row, |core error − lab's predicted error| ≤ 0.02 °/h RMS. The white noise is
///   common to both and cancels; what is left is the two G estimates, which differ by up to
///   ~1e-3 °C/s at the chamber's ramp corners (the tracker's lag to G changing by 0.5 °C/min
///   over 10 min), g·ΔG ≈ 0.03–0.06 °/h there and ~0 elsewhere. A control replays the table
///   with g zeroed: it must exceed twice the bound, so the check can see a wrong term;
/// - the fall factor (RMS before / after): 0.5 %. After compensation the error is the
///   white-noise floor (0.42 °/h per FOG per 0.5-s row, 0.67 °/h for the body rate); the
///   0.02 °/h above adds in quadrature, < 0.05 % of it.
///
/// The per-FOG check keeps the exact mapping test: `compensate_rate` with the lab's own T
/// and G reproduces the lab's residual to 1 %.
#[test]
fn d_round_trip_to_flight() {
    let dir = scratch("flight");
    let (sim, s) = session(&dir, "replay", 5, true);
    let kinds: Vec<Kind> =
        ["bias", "scale_factor", "misalignment", "thermal_t1", "thermal_t2", "temp_rate", "t_times_g"]
            .iter()
            .map(|k| Kind::parse_arg(k).unwrap())
            .collect();
    let fitted = fit_model(&Model::new(&kinds), &s).unwrap();
    assert!(fitted.not_identified.is_empty(), "{:?}", fitted.not_identified);
    largest_residual_from_extremes(&s, &kinds);
    let e = ssis_lab::export::to_table(&fitted.model, &ssis::calib::CalibrationTable::DEFAULT).unwrap();
    assert!(e.not_applied.is_empty());
    // Through both file forms, as the firmware would get it.
    let (tp, bp) = (dir.join("cal.toml"), dir.join("cal.bin"));
    ssis_common::table::write_toml(&tp, &e.table).unwrap();
    ssis_common::table::write_binary(&bp, &e.table).unwrap();
    let table = ssis_common::table::read_binary(&bp).unwrap();
    assert_eq!(table, ssis_common::table::read_toml(&tp).unwrap());
    let prep = prepare(&s, &fitted.model).unwrap();
    let residual = residuals(&fitted.model, &s).unwrap();
    let floor = sim.truth.noise_rad_s;

    per_fog_through_compensation(&s, &fitted, &table, &prep, floor);
    through_the_core(&s, &table, &prep, &residual);
}

/// The session is longer than the kept rows: the largest |residual| comes from the pass's
/// extremes (reading again only the first segments whose bound they cannot beat) and must
/// equal a full second pass's.
fn largest_residual_from_extremes(s: &Session, kinds: &[Kind]) {
    use ssis_lab::fit::{complete, fit_digest, max_abs_residuals, max_proof, spec_for};
    let model = Model::new(kinds);
    let d = ssis_lab::stream::digest(s.into(), &spec_for(&model, &[], 10), None).unwrap();
    let f = fit_digest(&model, &d).unwrap();
    let proof = max_proof(&d, &f.model).unwrap().expect("no extremes");
    let fast = complete(f.clone(), s, &d).unwrap();
    let scanned = max_abs_residuals(s.into(), &d, &f.model, usize::MAX).unwrap();
    println!(
        "  largest |residual| over {} rows, deg/h: from the extremes + {} of {} segments ({} rows) read again \
         {:?}, full second pass {:?}",
        s.len(),
        proof.segments_to_read(),
        proof.bound[0].len(),
        proof.rows_to_read(),
        fast.summary.iter().map(|x| dh(x.max_abs_residual_rad_s)).collect::<Vec<_>>(),
        scanned.iter().map(|v| dh(*v)).collect::<Vec<_>>()
    );
    assert!(proof.segments_to_read() < proof.bound[0].len(), "the extremes saved nothing");
    for (a, b) in fast.summary.iter().zip(&scanned) {
        assert!((a.max_abs_residual_rad_s / b - 1.0).abs() < 1e-9, "{} vs {b}", a.max_abs_residual_rad_s);
    }
}

/// Per FOG: the exported table in the flight compensation, with the lab's T and G.
fn per_fog_through_compensation(s: &Session, fitted: &Fitted, table: &CalibrationTable, prep: &Prepared, floor: f64) {
    use nalgebra::Vector3;
    let axes = table.axes();
    let nominal = ssis_session::nominal_axes();
    for fog in 0..4 {
        let t = s.fogs[fog].t_degc.as_ref().unwrap();
        let g = prep.g_degc_s[fog].as_ref().unwrap();
        let (mut before, mut after) = (0.0, 0.0);
        for j in 0..s.len() {
            let w = Vector3::from(s.ref_rad_s[j]);
            let raw = s.fogs[fog].rate_rad_s[j];
            let comp = ssis::compensation::compensate_rate(&table.fog[fog], raw, t[j], g[j]);
            before += (raw - nominal[fog].dot(&w)).powi(2);
            after += (comp - axes[fog].dot(&w)).powi(2);
        }
        let n = s.len() as f64;
        let (fb, fa) = ((before / n).sqrt(), (after / n).sqrt());
        let (lb, la) = (fitted.summary[fog].rms_error_rad_s, fitted.summary[fog].rms_residual_rad_s);
        println!(
            "  FOG{fog}: lab {:.4} -> {:.4} deg/h (x{:.2}), compensate_rate {:.4} -> {:.4} deg/h (x{:.2}), \
             after differs {:.3} %, floor {:.4}",
            dh(lb),
            dh(la),
            lb / la,
            dh(fb),
            dh(fa),
            fb / fa,
            100.0 * (fa / la - 1.0),
            dh(floor)
        );
        assert!((fb / lb - 1.0).abs() < 1e-9, "the error before compensation differs");
        assert!((fa / la - 1.0).abs() <= 0.01, "FOG{fog}: flight residual differs from the lab's by more than 1 %");
    }
}

/// Through the flight core (frames, links, step()): the error falls as the lab predicted,
/// row by row and as a whole.
fn through_the_core(s: &Session, table: &CalibrationTable, prep: &Prepared, residual: &[Vec<f64>]) {
    use nalgebra::{Matrix3x4, Matrix4x3, Vector3, Vector4};
    let axes = table.axes();
    let nominal = ssis_session::nominal_axes();
    let start = ssis_lab::replay::replay(s, &ssis::calib::CalibrationTable::DEFAULT).unwrap();
    let done = ssis_lab::replay::replay(s, table).unwrap();
    for r in [&start, &done] {
        assert_eq!(r.steps_degraded, 0, "the core did not use every FOG in every step");
        assert_eq!((r.frames_out, r.frames_out_bad), (s.len() as u64, 0), "output frames");
    }
    // The lab's prediction, projected through the combination.
    let pinv = |h: &[Vector3<f64>; 4]| -> Matrix3x4<f64> {
        let h = Matrix4x3::from_rows(&h.map(|a| a.transpose()));
        (h.transpose() * h).try_inverse().unwrap() * h.transpose()
    };
    let (p0, p1) = (pinv(&nominal), pinv(&axes));
    let predicted: Vec<Vector3<f64>> = (0..s.len())
        .map(|j| p1 * Vector4::from_fn(|i, _| residual[i][j] / (1.0 + table.fog[i].scale_factor_error)))
        .collect();
    let n = s.len() as f64;
    let lb =
        ((0..s.len()).map(|j| (p0 * Vector4::from_fn(|i, _| prep.y[i][j])).norm_squared()).sum::<f64>() / n).sqrt();
    let la = (predicted.iter().map(|v| v.norm_squared()).sum::<f64>() / n).sqrt();
    // Row by row: the core's error minus the lab's predicted error (the noise is common to both).
    let differs = |r: &ssis_lab::replay::Replay| -> (f64, f64) {
        let d: Vec<f64> = predicted.iter().zip(&r.error_rad_s).map(|(p, e)| (Vector3::from(*e) - p).norm()).collect();
        ((d.iter().map(|x| x * x).sum::<f64>() / n).sqrt(), d.iter().fold(0.0f64, |m, x| m.max(*x)))
    };
    let (diff_rms, diff_max) = differs(&done);
    // Control: the same table without its temperature-rate term must be told apart.
    let mut no_g = *table;
    for f in no_g.fog.iter_mut() {
        f.thermal_g_rad_s_per_degc_s = 0.0;
    }
    let (control_rms, _) = differs(&ssis_lab::replay::replay(s, &no_g).unwrap());
    println!(
        "  row by row, core error minus the lab's predicted error: RMS {:.5} deg/h, max {:.5} deg/h \
         (control, table without g: RMS {:.5} deg/h)",
        dh(diff_rms),
        dh(diff_max),
        dh(control_rms)
    );
    let (fb, fa) = (start.rms_error_rad_s(None), done.rms_error_rad_s(None));
    let (lab_fall, flight_fall) = (lb / la, fb / fa);
    println!(
        "  body rate |error| RMS over {} rows of {} s through FlightCore::step(): lab predicts {:.4} -> {:.4} deg/h \
         (x{:.3}), core {:.4} -> {:.4} deg/h (x{:.3}); fall differs {:+.3} %",
        s.len(),
        f64::from(done.dt_us) * 1e-6,
        dh(lb),
        dh(la),
        lab_fall,
        dh(fb),
        dh(fa),
        flight_fall,
        100.0 * (flight_fall / lab_fall - 1.0)
    );
    assert!((fb / lb - 1.0).abs() < 1e-6, "error before: core {} vs lab {} deg/h", dh(fb), dh(lb));
    let row_tol = 0.02 / DEG_H_PER_RAD_S;
    assert!(diff_rms <= row_tol, "core and lab differ row by row by {:.4} deg/h RMS", dh(diff_rms));
    assert!(control_rms > 2.0 * row_tol, "the row-by-row check cannot see a missing g term");
    assert!(lab_fall > 3.0, "the session shows no real fall (x{lab_fall:.2})");
    assert!(
        (flight_fall / lab_fall - 1.0).abs() <= 0.005,
        "the core's fall x{flight_fall:.3} differs from the lab's x{lab_fall:.3} by more than 0.5 %"
    );
}

/// The firmware's output link as a session. A static turntable session (1-s
/// rows, ψ = 0) is replayed through `FlightCore::step()` with the nominal table and every
/// byte of its output link kept, as a logger on the link would; one frame in 97 gets a byte
/// flipped. `read_output_capture` must count those frames as bad (not fail), leave exactly
/// them out (the counter gaps say so), carry every other frame's rate to within the frame's
/// LSB (2^-30 rad/s), and `compare` on it must find the unit's residual bias per axis: the
/// mean of the core's own error over the same rows, to 1e-9 rad/s.
#[test]
fn h_output_capture_as_a_session() {
    use ssis_lab::framelog::{read_output_capture, Turntable};
    use ssis_lab::simulate::{Hidden, Motion, Spec, Thermal};
    let dir = scratch("capture");
    let spec = Spec {
        seed: 9,
        dt_s: 1.0,
        rows: 3600,
        motion: Motion::Turntable { dwell_rows: 1_000_000, screened: vec![false] },
        thermal: Thermal::Constant(23.0),
        field_columns: false,
        field: ssis_lab::session::FieldModel::default(),
        hidden: Hidden::None,
    };
    let path = dir.join("static.csv");
    generate(&spec).write_csv(&path).unwrap();
    let s = read_session(&path, None).unwrap();
    let mut bytes = Vec::new();
    let r = ssis_lab::replay::replay_with(&s, &ssis::calib::CalibrationTable::DEFAULT, Some(&mut bytes)).unwrap();
    let len = ssis::frames::output::OutputFrame::LEN;
    assert_eq!(bytes.len(), s.len() * len);
    let corrupted: Vec<usize> = (0..s.len()).filter(|k| k % 97 == 5).collect();
    for &k in &corrupted {
        bytes[k * len + 40] ^= 0x5A;
    }
    let cap = dir.join("output-link.bin");
    std::fs::write(&cap, &bytes).unwrap();
    let lat = ssis_lab::simulate::KHARKOV_LAT_RAD;
    let (imported, rep) =
        read_output_capture(&cap, &Turntable { psi_rad: 0.0, lat_rad: lat, table_rate_rad_s: 0.0 }).unwrap();
    println!("{rep}");
    assert_eq!(rep.frames as usize, s.len() - corrupted.len(), "frames decoded");
    assert!(rep.bad_frames as usize >= corrupted.len(), "bad frames not counted");
    assert_eq!(rep.missing as usize, corrupted.len(), "gaps by the counter");
    assert_eq!(imported.len(), s.len() - corrupted.len());
    let kept: Vec<usize> = (0..s.len()).filter(|k| !corrupted.contains(k)).collect();
    let lsb = ssis::frames::output::RATE_LSB_RAD_S;
    for (j, &k) in kept.iter().enumerate() {
        assert!((imported.t_s()[j] - s.t_s()[k]).abs() < 1e-9);
        for a in 0..3 {
            assert!((imported.fogs[a].rate_rad_s[j] - r.rate_rad_s[k][a]).abs() <= lsb / 2.0 + 1e-15);
        }
    }
    let c = ssis_lab::fit::compare(&Model::new(&[Kind::Catalog(Catalog::Bias)]), &imported, false, 10, None).unwrap();
    let t = c.fitted.model.kinds().iter().position(|k| *k == Kind::Catalog(Catalog::Bias)).unwrap();
    for a in 0..3 {
        let mean = kept.iter().map(|&k| r.error_rad_s[k][a]).sum::<f64>() / kept.len() as f64;
        let fitted = c.fitted.model.terms[t].coef[a][0];
        println!(
            "  axis {a}: residual bias of the unit {:.5} deg/h, from the capture {:.5} deg/h",
            dh(mean),
            dh(fitted)
        );
        assert!((fitted - mean).abs() < 1e-9, "axis {a}: {fitted} vs {mean}");
    }
}

/// The per-step CSV that `ssis-qemu` and `ssis-sim run --csv` write
/// (`harness::CSV_HEADER`), from an in-process run of an Earth-pointing scenario with a star
/// tracker: the reference rate from the truth attitude is the truth's constant rate (to
/// 1e-12 rad/s), and measured − reference is the rate of the attitude error,
/// (e_k − e_{k−1})/Δt, within the second-order terms |ω|(|e_{k−1}| + |e_k|)/2 + |e_{k−1}||e_k|/Δt
/// of log(exp(−e_{k−1}) exp(ωΔt) exp(e_k)). A truncated line is refused with its line and column.
#[test]
fn i_qemu_csv_as_a_session() {
    use ssis_sim::harness::{run, CSV_HEADER};
    let dir = scratch("qemu-csv");
    let sc: ssis_sim::scenario::Scenario = toml::from_str(
        r#"
name = "lab-log"
profile = "spacecraft"
duration_s = 60
seed = 4
[motion]
base_rate_deg_s = [0.0, -0.0638, 0.0]
[fog]
arw_deg_sqrt_h = 0.005
random_bias_3sigma_deg_h = 0.05
[star_tracker]
rate_hz = 4
sigma_3sigma_arcsec = 20
[table]
source = "nominal"
"#,
    )
    .unwrap();
    let mut text = CSV_HEADER.join(",") + "\n";
    let mut errors = Vec::new();
    let mut truth_rate = Vec::new();
    let mut n = 0u64;
    run(&sc, |rec| {
        n += 1;
        if n.is_multiple_of(20) {
            text.push_str(&rec.csv_row().join(","));
            text.push('\n');
            errors.push(rec.att_err_arcsec);
            truth_rate.push(rec.rate_true_rad_s);
        }
    })
    .unwrap();
    let path = dir.join("flight.csv");
    std::fs::write(&path, &text).unwrap();
    let (s, rep) = ssis_lab::framelog::read_qemu_csv(&path).unwrap();
    println!("{rep}");
    assert_eq!(s.len(), errors.len() - 1);
    let t = s.t_s();
    let (mut worst_ref, mut worst_err) = (0.0f64, 0.0f64);
    for j in 0..s.len() {
        let dt = t[j] - if j == 0 { t[0] - 0.1 } else { t[j - 1] };
        let (e0, e1) = (
            nalgebra::Vector3::from(errors[j]) / ssis_common::ARCSEC_PER_RAD,
            nalgebra::Vector3::from(errors[j + 1]) / ssis_common::ARCSEC_PER_RAD,
        );
        // Second-order (BCH) terms of log(exp(−e0) exp(ωΔt) exp(e1)) beyond ωΔt + e1 − e0.
        let w = nalgebra::Vector3::from(truth_rate[j + 1]);
        let bound = w.norm() * (e0.norm() + e1.norm()) / 2.0 + e0.norm() * e1.norm() / dt + 1e-12;
        for a in 0..3 {
            worst_ref = worst_ref.max((s.ref_rad_s[j][a] - truth_rate[j + 1][a]).abs());
            let off = (s.fogs[a].rate_rad_s[j] - s.ref_rad_s[j][a] - (e1[a] - e0[a]) / dt).abs();
            worst_err = worst_err.max(off / bound);
        }
    }
    println!(
        "  reference vs truth rate: {worst_ref:.2e} rad/s; measured - reference vs d(error)/dt: at most {worst_err:.2} \
         of the second-order bound"
    );
    assert!(worst_ref < 1e-12, "reference rate {worst_ref}");
    assert!(worst_err <= 1.0, "measured - reference off by {worst_err} x the second-order bound");
    // The session works in the lab: a bias fit per body axis.
    let f = fit_model(&Model::new(&[Kind::Catalog(Catalog::Bias)]), &s).unwrap();
    println!(
        "  body-rate error RMS from the attitude, deg/h: {:?}",
        f.summary.iter().map(|x| (dh(x.rms_error_rad_s) * 1e3).round() / 1e3).collect::<Vec<_>>()
    );
    // A truncated line is refused.
    let bad = dir.join("truncated.csv");
    let cut = text.lines().take(10).collect::<Vec<_>>().join("\n");
    std::fs::write(&bad, cut.rsplit_once(',').unwrap().0).unwrap();
    let e = ssis_lab::framelog::read_qemu_csv(&bad).unwrap_err().to_string();
    println!("  {e}");
    assert!(e.contains("line 10") && e.contains("column 17") && e.contains("truncated"), "{e}");
}
