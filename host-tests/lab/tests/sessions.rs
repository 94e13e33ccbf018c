//! Sessions as the lab reads them: every line form a logger writes, refusals naming line and
//! column, and increment sessions equal to rate sessions.

use ssis_lab::diagnose::{diagnose, Options};
use ssis_lab::fit::{add_term, DEFAULT_BLOCKS};
use ssis_lab::model::{Catalog, Kind};
use ssis_lab::session::read_session;
use ssis_lab::simulate::{generate, preset};

mod common;
use common::{dh, scratch, starting_model};

/// (e) the reader's line forms: CRLF, comment, blank and very long lines, spaces around
/// fields and no final newline read as the plain file does; an extra, a missing or a
/// non-finite field refused with its line and column wherever the line is.
#[test]
fn e_reader_line_forms() {
    let dir = scratch("line-forms");
    let rows: Vec<String> = (1..=6).map(|k| format!("{k},{}e-5,2{k}.5,0,-0.87", k + 10)).collect();
    let plain = format!("t_s,fog0_rad_s,fog0_t_degc,psi_rad,lat_rad\n{}\n", rows.join("\n"));
    let read = |name: &str, text: &str| {
        let path = dir.join(format!("{name}.csv"));
        std::fs::write(&path, text).unwrap();
        read_session(&path, None).map(|s| s.cols).map_err(|e| e.to_string())
    };
    let want = read("plain", &plain).unwrap();
    assert_eq!(want[1][5], 16e-5);
    let long_comment = format!("# {}", "x".repeat(3 << 20));
    let same: [(&str, String); 4] = [
        ("crlf", plain.replace('\n', "\r\n")),
        ("comments", plain.replace("\n3,", &format!("\n# note\n\n \t\n{long_comment}\n3,"))),
        ("spaces", plain.replace(",", " ,\t").replace("\n4", "\n  4")),
        ("signs", plain.replace("-0.87", "-0.870").replace("e-5", "E-05")),
    ];
    // A last line without its line end may have been cut inside a number: refused.
    let cut = read("no-final-newline", plain.trim_end()).expect_err("a last line without a newline is refused");
    assert!(cut.contains("truncated") && cut.contains("line 7"), "{cut}");
    for (name, text) in &same {
        let got = read(name, text).unwrap_or_else(|e| panic!("{name}: {e}"));
        let bits = |c: &Vec<Vec<f64>>| c.iter().flatten().map(|v| v.to_bits()).collect::<Vec<_>>();
        assert_eq!(bits(&got), bits(&want), "{name}");
    }
    // Constant columns (a value repeated is taken from the row before, not parsed again):
    // each value still the one its own bytes give, a change or a bad value in one seen.
    let mut text = String::from("t_s,fog0_rad_s,fog0_t_degc,psi_rad,lat_rad\n");
    let mut expect = Vec::new();
    for k in 1..=300 {
        let psi = if k < 150 {
            "0.1250000000000"
        } else if k < 200 {
            "0.1250000000001"
        } else {
            "0.125"
        };
        let lat = if k % 97 == 0 { "0.87000000000000000001" } else { "0.870" };
        text.push_str(&format!("{k},1.5e-5,25.0,{psi},{lat}\n"));
        expect.push([psi.parse::<f64>().unwrap(), lat.parse::<f64>().unwrap()]);
    }
    let got = read("repeats", &text).unwrap();
    for (j, [psi, lat]) in expect.iter().enumerate() {
        assert_eq!((got[3][j].to_bits(), got[4][j].to_bits()), (psi.to_bits(), lat.to_bits()), "row {j}");
    }
    let e = read("repeats-bad", &text.replace("\n250,1.5e-5,25.0,0.125,", "\n250,1.5e-5,25.0,0.125x,")).unwrap_err();
    assert!(e.contains("line 251") && e.contains("column 4") && e.contains("not a number"), "{e}");
    let refused: [(&str, String, &[&str]); 4] = [
        ("extra-field", plain.replace("\n3,", "\n3,7,"), &["line 4", "column 5", "the header only 5"]),
        ("missing-field", plain.replace(",23.5", ""), &["line 4", "column 5", "truncated"]),
        ("inf", plain.replace("15e-5", "inf"), &["line 6", "column 2", "not a finite number"]),
        ("last-line", plain.replace("6,16e-5", "6,16e-5x"), &["line 7", "column 2", "not a number"]),
    ];
    for (name, text, must) in &refused {
        let e = read(name, text).unwrap_err();
        for m in *must {
            assert!(e.contains(m), "{name}: message lacks `{m}`: {e}");
        }
    }
}

/// Increment sessions (`fogN_rad`: the angle over (t_{k−1}, t_k], the first row dropped). The
/// thermal session with its rates written as increments must give, streamed from the file,
/// the same samples (to 1e-12 relative), diagnosis and fit (to 1e-9) as the rate session
/// without its first row, and find the hidden temperature-rate effect; mixing a FOG's rate and increment
/// columns, or fewer than three rows, is refused.
#[test]
fn j_increment_sessions() {
    let dir = scratch("increments");
    let sim = generate(&preset("thermal", 21, true).unwrap());
    let fog_cols: Vec<usize> =
        (0..4).map(|i| sim.header.iter().position(|h| *h == format!("fog{i}_rad_s")).unwrap()).collect();
    // The rate session without its first row, and the increment session with all rows.
    let mut rates = sim.clone();
    rates.rows.remove(0);
    let mut inc = sim.clone();
    for &c in &fog_cols {
        inc.header[c] = inc.header[c].replace("_rad_s", "_rad");
    }
    let dt: Vec<f64> =
        (0..sim.rows.len()).map(|j| sim.rows[j][0] - if j == 0 { 0.0 } else { sim.rows[j - 1][0] }).collect();
    for (j, row) in inc.rows.iter_mut().enumerate() {
        for &c in &fog_cols {
            row[c] *= dt[j];
        }
    }
    let (rp, ip) = (dir.join("rates.csv"), dir.join("increments.csv"));
    rates.write_csv(&rp).unwrap();
    inc.write_csv(&ip).unwrap();
    let (a, b) = (read_session(&rp, None).unwrap(), read_session(&ip, None).unwrap());
    assert_eq!(b.len(), sim.rows.len() - 1);
    assert_eq!(a.len(), b.len());
    let mut worst = 0.0f64;
    for i in 0..4 {
        for j in 0..a.len() {
            worst = worst.max(((a.fogs[i].rate_rad_s[j] - b.fogs[i].rate_rad_s[j]) / a.fogs[i].rate_rad_s[j]).abs());
        }
    }
    println!(
        "increment session: {} rows -> {} samples; rates differ by at most {worst:.1e} relative",
        sim.rows.len(),
        b.len()
    );
    assert!(worst < 1e-12);
    let model = starting_model("thermal");
    let (da, db) =
        (diagnose(&model, &rp, &Options::default()).unwrap(), diagnose(&model, &ip, &Options::default()).unwrap());
    println!(
        "  top candidate: rates {} (p {:.2e}), increments {} (p {:.2e})",
        da.candidates[0].kind.label(),
        da.candidates[0].p_value,
        db.candidates[0].kind.label(),
        db.candidates[0].p_value
    );
    assert_eq!(db.candidates[0].kind, Kind::Catalog(Catalog::TempRate));
    assert!(db.candidates[0].significant);
    assert_eq!(da.candidates.len(), db.candidates.len());
    for (x, y) in da.candidates.iter().zip(&db.candidates) {
        assert_eq!(x.kind, y.kind);
        assert!(
            (x.after_rad_s / y.after_rad_s - 1.0).abs() < 1e-9,
            "{}: {} vs {}",
            x.kind.label(),
            x.after_rad_s,
            y.after_rad_s
        );
    }
    let (oa, ob) = (
        add_term(&model, &Kind::Catalog(Catalog::TempRate), &rp, DEFAULT_BLOCKS).unwrap(),
        add_term(&model, &Kind::Catalog(Catalog::TempRate), &ip, DEFAULT_BLOCKS).unwrap(),
    );
    for fog in 0..4 {
        let (x, y) = (oa.model.terms[4].coef[fog][0], ob.model.terms[4].coef[fog][0]);
        println!(
            "  FOG{fog}: g from rates {x:.6e}, from increments {y:.6e}; held-out {:.4} -> {:.4} deg/h",
            dh(ob.before_rad_s[fog]),
            dh(ob.after_rad_s[fog])
        );
        assert!((x / y - 1.0).abs() < 1e-9);
        assert!(ob.after_rad_s[fog] <= 0.5 * ob.before_rad_s[fog]);
    }
    // Refusals.
    let text = std::fs::read_to_string(&ip).unwrap();
    let mixed = text.replacen("fog1_rad,", "fog1_rad_s,", 1).replacen("fog2_rad,", "fog1_rad,", 1);
    std::fs::write(dir.join("mixed.csv"), &mixed).unwrap();
    let e = read_session(&dir.join("mixed.csv"), None).unwrap_err().to_string();
    println!("  {e}");
    assert!(e.contains("line 1") && e.contains("both as rate and increment"), "{e}");
    let short: String = text.lines().take(3).map(|l| format!("{l}\n")).collect();
    std::fs::write(dir.join("short.csv"), short).unwrap();
    let e = read_session(&dir.join("short.csv"), None).unwrap_err().to_string();
    println!("  {e}");
    assert!(e.contains("fewer than 3 data rows"), "{e}");
}

/// The field columns of `simulate magnetic` are in the session's frame: at every azimuth
/// their components along the session's north and west (from its Earth rate) are the site's.
#[test]
fn magnetic_preset_field_frame() {
    let b0_nt = ssis_lab::simulate::b0_nwu_nt(ssis_lab::session::FieldModel::default());
    let dir = common::scratch("field-frame");
    let (_, s) = common::session(&dir, "magnetic", 4, true);
    let psi = s.column("psi_rad").unwrap();
    let field = s.field_nt.as_ref().unwrap();
    let mut azimuths = std::collections::BTreeSet::new();
    for (r, f) in field.iter().enumerate() {
        let w = s.ref_rad_s[r];
        let h = w[0].hypot(w[1]);
        let (n, we) = ([w[0] / h, w[1] / h], [-w[1] / h, w[0] / h]);
        let (bn, bw) = (n[0] * f[0] + n[1] * f[1], we[0] * f[0] + we[1] * f[1]);
        if bn.hypot(bw) < 1000.0 {
            continue; // inside the screen (1 % of the field)
        }
        azimuths.insert(psi[r].to_degrees().round() as i64);
        // The columns carry 5 nT of noise.
        assert!((bn - b0_nt[0]).abs() < 30.0, "row {r}: north {bn}");
        assert!((bw - b0_nt[1]).abs() < 30.0, "row {r}: west {bw}");
    }
    println!("field frame checked at {} azimuths", azimuths.len());
    assert!(azimuths.len() >= 24);
}

/// A level turntable without a screened run cannot separate magnetic sensitivity from
/// bias, scale factor and misalignment: `diagnose` names the terms and the screened turn.
#[test]
fn confounded_magnetic_names_terms_and_experiment() {
    use ssis_lab::simulate::Motion;
    let mut spec = preset("magnetic", 6, true).unwrap();
    spec.motion = Motion::Turntable { dwell_rows: 3, screened: vec![false, false, false, false] };
    let sim = generate(&spec);
    let dir = scratch("confounded");
    let path = dir.join("unscreened.csv");
    sim.write_csv(&path).unwrap();
    let s = read_session(&path, None).unwrap();
    let d = diagnose(&starting_model("magnetic"), &s, &Options::default()).unwrap();
    let c = d.candidates.iter().find(|c| c.kind.label() == "magnetic").expect("magnetic tested on some FOG");
    for (fog, w) in &c.untested {
        println!("magnetic, FOG{fog}: {w}");
    }
    let why = c.untested.iter().find(|(f, _)| *f == 0).map(|(_, w)| w.clone());
    let why = why.expect("FOG0's magnetic term should be reported as confounded without a screened run");
    for must in ["mixed with", "misalignment", "screened turn", "eq. 2"] {
        assert!(why.contains(must), "reason lacks `{must}`: {why}");
    }
}

/// `simulate magnetic` writes the real field (WMM2025 at Kharkov on 2025-001) by default and
/// the paper's dipole tilt with `--field paper`: the field columns of the first row, back to
/// (north, west, up).
#[test]
fn magnetic_preset_field_model() {
    let dir = common::scratch("field-model");
    let lab = |args: &[&str]| {
        let out =
            std::process::Command::new(env!("CARGO_BIN_EXE_ssis-lab")).current_dir(&dir).args(args).output().unwrap();
        assert!(out.status.success(), "{args:?}: {}", String::from_utf8_lossy(&out.stderr));
        String::from_utf8_lossy(&out.stdout).to_string()
    };
    for (args, want, name) in [
        (&["simulate", "magnetic", "w.csv"][..], [19345.0, -3141.0, -47630.0], "WMM2025"),
        (&["simulate", "magnetic", "p.csv", "--field", "paper"][..], [21846.0, 5959.0, -42343.0], "dipole"),
    ] {
        let said = lab(args);
        println!("{}", said.trim());
        assert!(said.contains(name), "the field model is not stated: {said}");
        let s = read_session(&dir.join(args[2]), None).unwrap();
        let b = ssis_lab::session::field_nwu_nt(s.field_nt.as_ref().unwrap()[0], s.column("psi_rad").unwrap()[0]);
        // The columns carry 5 nT of noise.
        assert!(b.iter().zip(want).all(|(x, w)| (x - w).abs() < 30.0), "{args:?}: field {b:?}, want {want:?}");
    }
}
