//! Hostile physics: the ground tools (`ssis-lab`, `ssis-cal`, `ssis-sim`, `ssis-qemu`) run as
//! a user runs them, on inputs that are well-formed but physically wrong. Each case asserts
//! the exit status, that the message names the file and line or the field, and that every
//! file in its directory before the command is byte-identical after it (a refusal writes no
//! new file either). Plus the acceptance test of table updates: an export from a thermal-only
//! session onto a base table keeps the base's misalignment, scale factors and noise figures
//! bit for bit and flies within 10 % of the base table's attitude error.
//!
//! The binaries are built once per run, in this test's profile, by `cargo build`.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use std::sync::OnceLock;

use ssis::calib::{CalibrationTable, Field, FogCal, FogTerm, Misalignment};
use ssis_common::table;
use ssis_sim::fog::{FogSpec, TemperatureSpec, TrueErrors};
use ssis_sim::scenario::{ProfileName, Scenario, TableSpec};
use ssis_sim::truth::{MotionSpec, Slew};

/// The directory of the host workspace's binaries, built once (same profile as this test).
fn bin(name: &str) -> PathBuf {
    static DIR: OnceLock<PathBuf> = OnceLock::new();
    DIR.get_or_init(|| {
        let exe = std::env::current_exe().expect("the test binary");
        let dir = exe.parent().and_then(Path::parent).expect("target/<profile>/deps/..").to_path_buf();
        let mut cmd = Command::new(env!("CARGO"));
        cmd.current_dir(env!("CARGO_MANIFEST_DIR")).args(["build", "--quiet"]);
        for b in ["ssis-lab", "ssis-cal", "ssis-sim", "ssis-qemu"] {
            cmd.args(["--bin", b]);
        }
        if dir.file_name().is_some_and(|n| n == "release") {
            cmd.arg("--release");
        }
        let status = cmd.status().expect("cargo runs");
        assert!(status.success(), "building the binaries failed");
        dir
    })
    .join(name)
}

/// A scratch directory of its own per case.
struct Scratch(PathBuf);

impl Scratch {
    fn new(case: &str) -> Self {
        let d = std::env::temp_dir().join(format!("ssis-hostile-{}-{case}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        std::fs::create_dir_all(&d).expect("scratch dir");
        Scratch(d)
    }

    fn path(&self, name: &str) -> PathBuf {
        self.0.join(name)
    }

    fn write(&self, name: &str, text: impl AsRef<[u8]>) -> PathBuf {
        let p = self.path(name);
        std::fs::write(&p, text).expect("written");
        p
    }

    /// Every file's bytes, by name.
    fn snapshot(&self) -> BTreeMap<String, Vec<u8>> {
        std::fs::read_dir(&self.0)
            .expect("lists")
            .flatten()
            .map(|e| (e.file_name().to_string_lossy().to_string(), std::fs::read(e.path()).expect("reads")))
            .collect()
    }

    /// Runs `program args` in the directory.
    fn run(&self, program: &str, args: &[&str]) -> (Option<i32>, String, Output) {
        let out = Command::new(bin(program))
            .current_dir(&self.0)
            .args(args)
            .env_remove("RUST_BACKTRACE")
            .output()
            .expect("runs");
        let text = format!("{}{}", String::from_utf8_lossy(&out.stdout), String::from_utf8_lossy(&out.stderr));
        println!("$ {program} {}\n  exit {:?}\n{}", args.join(" "), out.status.code(), indent(&text));
        (out.status.code(), text, out)
    }

    /// Runs a command that must be refused with status `code`, a message with every one of
    /// `must`, no panic, every file as it was and no file added.
    fn refused(&self, program: &str, args: &[&str], code: i32, must: &[&str]) -> String {
        let before = self.snapshot();
        let (status, text, _) = self.run(program, args);
        assert_eq!(status, Some(code), "exit status: {text}");
        assert!(!text.contains("panicked"), "a panic: {text}");
        for m in must {
            assert!(text.contains(m), "the message lacks `{m}`: {text}");
        }
        assert_eq!(self.snapshot(), before, "a file changed or was added");
        text
    }

    /// Runs a command that must succeed; files in `changed` may change or appear, every
    /// other file must be as it was.
    fn succeeds(&self, program: &str, args: &[&str], changed: &[&str]) -> String {
        let mut before = self.snapshot();
        let (status, text, _) = self.run(program, args);
        assert_eq!(status, Some(0), "exit status: {text}");
        let mut after = self.snapshot();
        for c in changed {
            before.remove(*c);
            after.remove(*c);
        }
        assert_eq!(after, before, "a file other than {changed:?} changed or was added");
        text
    }
}

impl Drop for Scratch {
    fn drop(&mut self) {
        if !std::thread::panicking() {
            let _ = std::fs::remove_dir_all(&self.0);
        }
    }
}

fn indent(s: &str) -> String {
    s.lines().map(|l| format!("    {l}\n")).collect()
}

/// A deterministic N(0, 1) stream (xorshift and Box–Muller): no dependency on a crate's
/// stream for the sessions written here.
struct Gauss(u64);

impl Gauss {
    fn uniform(&mut self) -> f64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        ((self.0 >> 11) as f64 + 0.5) / (1u64 << 53) as f64
    }

    fn next(&mut self) -> f64 {
        let (u, v) = (self.uniform(), self.uniform());
        (-2.0 * u.ln()).sqrt() * (2.0 * std::f64::consts::PI * v).cos()
    }
}

const DEG_H: f64 = std::f64::consts::PI / 180.0 / 3600.0;
const KHARKOV_LAT_RAD: f64 = 0.8735;

/// A small good session: two FOGs with temperatures on a static turntable, 12 rows.
fn small_session() -> String {
    let mut s = String::from("t_s,fog0_rad_s,fog1_rad_s,fog0_t_degc,fog1_t_degc,psi_rad,lat_rad\n");
    for k in 1..=12 {
        s.push_str(&format!("{k}0,5.72e-5,{:e},{},24.9,0,0.8735\n", 1.0e-6 * (k as f64).sin(), 25.0 + 0.01 * k as f64));
    }
    s
}

/// A bias-only model (no coefficients).
const BIAS_MODEL: &str = "format = \"ssis-error-model/1\"\nversion = 1\n\n[[term]]\nterm = \"bias\"\n";

/// A fitted bias model for four FOGs (its `coef` text given).
fn fitted_model(coef: &str, extra: &str) -> String {
    format!(
        "format = \"ssis-error-model/1\"\nversion = 2\n{extra}\n[[term]]\nterm = \"bias\"\ncoef = {coef}\n\n\
         [fit]\nsession = \"s.csv\"\nrows = 12\nheld_out_rms_deg_h = [0.01, 0.01, 0.01, 0.01]\n"
    )
}

// ------------------------------------------------------------------------ sessions (ssis-lab)

/// `ssis-lab COMMAND --model M --session S` with a bias model and the session `text`: refused
/// with every one of `must`, nothing written.
fn lab_refuses_session(case: &str, command: &str, text: impl AsRef<[u8]>, must: &[&str]) {
    let s = Scratch::new(case);
    s.write("m.toml", BIAS_MODEL);
    s.write("s.csv", text);
    s.refused("ssis-lab", &[command, "--model", "m.toml", "--session", "s.csv"], 1, must);
}

#[test]
fn lab_refuses_a_1e300_sample_naming_line_and_column() {
    let text = small_session().replace("\n70,5.72e-5,", "\n70,1e300,");
    let must = ["s.csv", "line 8", "column 2", "`fog0_rad_s`", "1e300", "measuring range"];
    lab_refuses_session("1e300", "compare", text, &must);
}

#[test]
fn lab_refuses_a_last_line_cut_inside_its_exponent() {
    // The example: `-5.72e-5` cut to `-5.72` (a value 1e5 times too large).
    let text = format!("{}130,1e-6,2e-6,25.1,24.9,0,-5.72e-5\n", small_session());
    let must = ["s.csv", "line 14", "`lat_rad`", "`-5.72`", "truncated"];
    lab_refuses_session("cut", "compare", &text[..text.len() - 4], &must);
}

#[test]
fn lab_refuses_a_rate_beyond_the_measuring_range() {
    // 3 rad/s = 172 °/s: beyond the FOG's ±100 °/s.
    let text = small_session().replace("\n50,5.72e-5,", "\n50,3.0,");
    let must = ["s.csv", "line 6", "column 2", "`fog0_rad_s`", "171.8873 °/s", "±100 °/s"];
    lab_refuses_session("range", "diagnose", text, &must);
}

#[test]
fn lab_refuses_a_temperature_outside_minus_100_to_150_degc() {
    // Kelvin in a °C column.
    let text = small_session().replace(",24.9,0,0.8735\n40,", ",298.1,0,0.8735\n40,");
    let must = ["s.csv", "line 4", "column 5", "`fog1_t_degc`", "298.1", "−100 … +150 °C"];
    lab_refuses_session("kelvin", "compare", text, &must);
}

#[test]
fn lab_reads_a_session_with_a_utf8_byte_order_mark() {
    let s = Scratch::new("bom");
    s.write("m.toml", BIAS_MODEL);
    s.write("plain.csv", small_session());
    s.write("bom.csv", [&b"\xEF\xBB\xBF"[..], small_session().as_bytes()].concat());
    let a = s.succeeds("ssis-lab", &["compare", "--model", "m.toml", "--session", "plain.csv"], &[]);
    let b = s.succeeds("ssis-lab", &["compare", "--model", "m.toml", "--session", "bom.csv"], &[]);
    assert_eq!(a.replace("plain.csv", "X"), b.replace("bom.csv", "X"), "the mark changed the result");
}

// ------------------------------------------------------------------------ models (ssis-lab)

/// `ssis-lab COMMAND --model m.toml …` (export to out.toml, or compare on a good session)
/// with a fitted model of `coef` and `extra` lines: refused with every one of `must`.
fn lab_refuses_model(case: &str, command: &str, coef: &str, extra: &str, must: &[&str]) {
    let s = Scratch::new(case);
    s.write("s.csv", small_session());
    s.write("m.toml", fitted_model(coef, extra));
    let tail: &[&str] = if command == "export" { &["--toml", "out.toml"] } else { &["--session", "s.csv"] };
    s.refused("ssis-lab", &[&[command, "--model", "m.toml"][..], tail].concat(), 1, must);
}

#[test]
fn lab_refuses_a_model_with_a_nan_coefficient() {
    let must = ["m.toml", "term 1 (`bias`)", "`coef[1][0]`", "NaN", "not a finite number"];
    lab_refuses_model("nan-coef", "export", "[[1e-7], [nan], [0.0], [0.0]]", "", &must);
}

#[test]
fn lab_refuses_a_model_whose_t_ref_is_nan() {
    let must = ["m.toml", "`t_ref_degc`", "NaN", "temperature"];
    lab_refuses_model("nan-tref", "compare", "[[1e-7], [0.0], [0.0], [0.0]]", "t_ref_degc = nan", &must);
}

#[test]
fn lab_refuses_three_coefficients_for_four_fogs() {
    let must = ["m.toml", "`coef`", "3 FOGs", "for 4", "one set per FOG"];
    lab_refuses_model("three-of-four", "export", "[[1e-7], [2e-7], [3e-7]]", "", &must);
}

#[test]
fn lab_export_refuses_an_implausible_bias_writing_nothing() {
    let must = ["m.toml", "fog[0].bias_rad_s", "206.26", "-100 … 100 °/h"];
    lab_refuses_model("export-range", "export", "[[1e-3], [0.0], [0.0], [0.0]]", "", &must);
}

// ------------------------------------------------------------------------ tables (ssis-sim)

/// A valid table's TOML with one field's line replaced (`key = value` under `[table]`).
fn table_with(key_line: &str, new_line: &str) -> String {
    let text = table::to_toml(&CalibrationTable::DEFAULT).expect("toml");
    assert!(text.contains(key_line), "{key_line} not in {text}");
    text.replacen(key_line, new_line, 1)
}

/// `ssis-sim table COMMAND cal.toml OUT` on the default table with `key_line` replaced:
/// refused with every one of `must`, nothing written.
fn sim_table_refuses(case: &str, command: &str, key_line: &str, new_line: &str, must: &[&str]) {
    let s = Scratch::new(case);
    s.write("cal.toml", table_with(key_line, new_line));
    s.refused("ssis-sim", &["table", command, "cal.toml", "out"], 1, must);
}

#[test]
fn sim_to_bin_refuses_the_turntable_rrw_naming_field_value_and_range() {
    let must = ["cal.toml", "observer.rrw_deg_h_sqrt_h", "53954", "0.0001 … 0.1 °/h/√h"];
    sim_table_refuses("rrw", "to-bin", "rrw_deg_h_sqrt_h = 0.01", "rrw_deg_h_sqrt_h = 53954.0", &must);
}

#[test]
fn sim_to_image_refuses_the_turntable_arw() {
    let must = ["cal.toml", "observer.arw_deg_sqrt_h", "0.48", "0.0005 … 0.05 °/√h"];
    sim_table_refuses("arw", "to-image", "arw_deg_sqrt_h = 0.005", "arw_deg_sqrt_h = 0.48", &must);
}

#[test]
fn sim_table_diff_reports_fields_in_engineering_units_with_exit_codes() {
    let s = Scratch::new("diff");
    s.write("a.toml", table::to_toml(&CalibrationTable::DEFAULT).expect("toml"));
    let mut t = CalibrationTable::DEFAULT;
    t.fog[2].bias_rad_s = 0.5 * DEG_H;
    t.fog[1].scale_factor_error = 250e-6;
    t.misalignment.d31_rad = 30.0 / 206_264.806_247;
    s.write("b.toml", table::to_toml(&t).expect("toml"));
    table::write_binary(&s.path("b.bin"), &t).expect("bin");
    s.succeeds("ssis-sim", &["table", "diff", "a.toml", "a.toml"], &[]);
    // Same table in two forms: identical.
    s.succeeds("ssis-sim", &["table", "diff", "b.toml", "b.bin"], &[]);
    let text = s.refused(
        "ssis-sim",
        &["table", "diff", "a.toml", "b.bin"],
        1,
        &["fog[2].bias_rad_s", "0 → 0.5 °/h", "fog[1].scale_factor_error", "0 → 250 ppm", "misalignment.d31_rad"],
    );
    assert!(text.contains("0 → 30 ″"), "{text}");
    s.refused("ssis-sim", &["table", "diff", "a.toml", "missing.toml"], 2, &["missing.toml"]);
}

#[test]
fn sim_to_bin_ignores_provenance() {
    let s = Scratch::new("provenance");
    let plain = table::to_toml(&CalibrationTable::DEFAULT).expect("toml");
    let with = format!(
        "{plain}\n[[provenance]]\nfield = \"fog[0].bias_rad_s\"\ncommand = \"ssis-lab export\"\n\
         session = \"th.csv\"\nmodel = \"m.v2.toml\"\nmodel_version = 2\nrevision = 1\n"
    );
    s.write("plain.toml", &plain);
    s.write("with.toml", &with);
    s.succeeds("ssis-sim", &["table", "to-bin", "plain.toml", "plain.bin"], &["plain.bin"]);
    s.succeeds("ssis-sim", &["table", "to-bin", "with.toml", "with.bin"], &["with.bin"]);
    assert_eq!(std::fs::read(s.path("plain.bin")).unwrap(), std::fs::read(s.path("with.bin")).unwrap());
    // A provenance entry for a field that does not exist is refused, naming it.
    s.write("typo.toml", with.replace("fog[0].bias_rad_s", "fog[0].bias_deg_h"));
    s.refused("ssis-sim", &["table", "to-bin", "typo.toml", "typo.bin"], 1, &["typo.toml", "`fog[0].bias_deg_h`"]);
}

// ------------------------------------------------------------------------ scenarios (ssis-sim, ssis-qemu)

const TINY_SCENARIO: &str = "name = \"tiny\"\nprofile = \"spacecraft\"\nduration_s = 20\nsettle_s = 5\n";

/// `ssis-sim run s.toml ARGS` on the tiny scenario with `extra` appended: refused with every
/// one of `must`, nothing written.
fn sim_scenario_refuses(case: &str, extra: &str, args: &[&str], must: &[&str]) {
    let s = Scratch::new(case);
    s.write("s.toml", format!("{TINY_SCENARIO}{extra}"));
    s.refused("ssis-sim", &[&["run", "s.toml"][..], args].concat(), 1, must);
}

#[test]
fn sim_refuses_a_probability_of_two() {
    let must = ["s.toml", "`links.fog.drop_prob` = 2", "[0, 1]"];
    sim_scenario_refuses("prob2", "[links.fog]\ndrop_prob = 2.0\n", &[], &must);
}

#[test]
fn sim_refuses_a_negative_probability() {
    let must = ["s.toml", "`links.star.bit_flip_prob` = -1"];
    sim_scenario_refuses("prob-neg", "[links.star]\nbit_flip_prob = -1.0\n", &["--csv", "out.csv"], &must);
}

#[test]
fn sim_refuses_a_zero_slew_axis() {
    let slew = "[[motion.slews]]\nstart_s = 1\nduration_s = 5\naxis = [0.0, 0.0, 0.0]\nangle_deg = 10\n";
    sim_scenario_refuses("axis", slew, &[], &["s.toml", "`motion.slews[0].axis`", "must not be zero"]);
}

#[test]
fn sim_refuses_a_number_that_is_not_finite() {
    let must = ["s.toml", "`fog.temperature.ramp_degc_per_min` = inf"];
    sim_scenario_refuses("inf", "[fog.temperature]\nramp_degc_per_min = inf\n", &[], &must);
}

#[test]
fn sim_refuses_over_30_days_without_allow_long() {
    let s = Scratch::new("long");
    s.write("s.toml", TINY_SCENARIO.replace("duration_s = 20", "duration_s = 2.6e6"));
    s.refused("ssis-sim", &["run", "s.toml"], 1, &["s.toml", "`duration_s`", "30.1 days", "--allow-long"]);
}

#[test]
fn sim_run_whose_fog_links_deliver_nothing_says_so_and_fails() {
    let s = Scratch::new("silent");
    s.write("s.toml", format!("{TINY_SCENARIO}[links.fog]\ndrop_prob = 1.0\n"));
    let text = s.refused(
        "ssis-sim",
        &["run", "s.toml"],
        3,
        &["s.toml", "FOG0's link delivered nothing", "no accuracy figure"],
    );
    assert!(text.contains("all 72000 bytes dropped"), "{text}");
}

#[test]
fn sim_run_ctrl_c_prints_the_partial_summary_and_leaves_no_partial_file() {
    let s = Scratch::new("ctrl-c");
    s.write("day.toml", "name = \"day\"\nprofile = \"spacecraft\"\nduration_s = 86400\n");
    let before = s.snapshot();
    let child = Command::new(bin("ssis-sim"))
        .current_dir(&s.0)
        .args(["run", "day.toml", "--csv", "day.csv"])
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .expect("starts");
    // Wait until the run is under way (its CSV's temporary file `.day.csv.<pid>-<n>.partial`
    // exists), then Ctrl-C.
    let partial = || {
        std::fs::read_dir(&s.0).expect("lists").flatten().any(|e| e.file_name().to_string_lossy().ends_with(".partial"))
    };
    let t0 = std::time::Instant::now();
    while !partial() && t0.elapsed().as_secs() < 10 {
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
    assert!(partial(), "no temporary file while the run writes its log");
    std::thread::sleep(std::time::Duration::from_millis(300));
    let kill = Command::new("kill").args(["-INT", &child.id().to_string()]).status().expect("kill runs");
    assert!(kill.success());
    let out = child.wait_with_output().expect("ends");
    let text = format!("{}{}", String::from_utf8_lossy(&out.stdout), String::from_utf8_lossy(&out.stderr));
    println!("{text}");
    assert_eq!(out.status.code(), Some(130), "{text}");
    for m in ["INTERRUPTED after", "of 17280000 steps", "attitude error 3σ", "no CSV written"] {
        assert!(text.contains(m), "lacks `{m}`: {text}");
    }
    assert_eq!(s.snapshot(), before, "a file was left behind");
}

#[test]
fn qemu_refuses_a_bad_scenario_before_it_builds_or_launches_anything() {
    let s = Scratch::new("qemu");
    s.write("s.toml", format!("{TINY_SCENARIO}[links.fog]\ndrop_prob = -1.0\n"));
    let text = s.refused(
        "ssis-qemu",
        &["s.toml", "--elf", "no-such.elf", "--out", "."],
        1,
        &["s.toml", "`links.fog.drop_prob` = -1"],
    );
    assert!(!text.contains("no-such.elf"), "it got as far as the firmware: {text}");
}

// ------------------------------------------------------------------------ methods (ssis-cal)

/// A session of FOG0 with the reference rate in columns, 1-s samples, `rows` rows: white
/// noise of 0.005 °/√h on top of the reference; `turn` gives the table rate about Z at row k.
fn rate_session(rows: usize, turn: impl Fn(usize) -> f64) -> String {
    let mut g = Gauss(0x2545_F491_4F6C_DD1D);
    let sigma = 0.005 / 60.0 * std::f64::consts::PI / 180.0;
    let mut s = String::from("t_s,fog0_rad_s,ref_x_rad_s,ref_y_rad_s,ref_z_rad_s\n");
    for k in 0..rows {
        let z = turn(k);
        let w = [1.0e-5, 2.0e-5, 5.6e-5 + z];
        s.push_str(&format!("{},{:.9e},{:e},{:e},{:e}\n", k + 1, w[0] + sigma * g.next(), w[0], w[1], w[2]));
    }
    s
}

#[test]
fn cal_allan_refuses_a_turntable_run_and_leaves_the_table() {
    let s = Scratch::new("allan-turns");
    s.write("turns.csv", rate_session(400, |k| if (100..300).contains(&k) { 0.1 } else { 0.0 }));
    s.write("cal.toml", table::to_toml(&CalibrationTable::DEFAULT).unwrap());
    s.refused(
        "ssis-cal",
        &["allan", "--session", "turns.csv", "--table", "cal.toml", "--plot", "a.svg"],
        1,
        &["turns.csv", "not a static session", "reference rate changes by 20626", "record a static run"],
    );
}

#[test]
fn cal_allan_reports_an_unresolved_rrw_as_a_bound_and_keeps_the_tables() {
    let s = Scratch::new("allan-bound");
    s.succeeds(
        "ssis-cal",
        &["simulate", "static", "static.csv", "--hours", "2", "--arw", "0.005", "--rrw", "0.002"],
        &["static.csv"],
    );
    let mut base = CalibrationTable::DEFAULT;
    base.revision = 7;
    base.observer.rrw_deg_h_sqrt_h = 0.004;
    s.write("cal.toml", table::to_toml(&base).unwrap());
    let text = s.succeeds(
        "ssis-cal",
        &["allan", "--session", "static.csv", "--table", "cal.toml", "--plot", "a.svg"],
        &["cal.toml", "a.svg"],
    );
    assert!(text.contains("RRW  ≤ ") && text.contains("not resolved by this session"), "{text}");
    assert!(!text.contains("[0.00000, 0.00000]"), "a zero-width interval: {text}");
    assert!(text.contains("observer.rrw_deg_h_sqrt_h kept at the base's value"), "{text}");
    let doc = table::read_doc(&s.path("cal.toml")).unwrap();
    assert_eq!(doc.table.revision, 8);
    assert_eq!(doc.table.observer.rrw_deg_h_sqrt_h.to_bits(), 0.004f64.to_bits(), "RRW changed");
    let arw = doc.table.observer.arw_deg_sqrt_h;
    assert!((arw / 0.005 - 1.0).abs() < 0.05, "ARW {arw}");
    let fields: Vec<&str> = doc.provenance.iter().map(|p| p.field.as_str()).collect();
    assert_eq!(fields, ["observer.arw_deg_sqrt_h"]);
    assert_eq!(
        (doc.provenance[0].command.as_str(), doc.provenance[0].session.as_str()),
        ("ssis-cal allan", "static.csv")
    );
}

/// A chamber session of FOG0 in Table 1's cells (T 10…40 °C, G −0.25…+0.25 °C/min), 60
/// samples of 10 s per cell, the cells 1000 s apart; `cells` chooses them.
fn chamber_session(cells: &[(usize, usize)], with_temperature: bool) -> String {
    let (t_levels, g_levels) = ([10.0, 20.0, 30.0, 40.0], [-0.25, 0.0, 0.25]);
    let mut g = Gauss(7);
    let earth = ssis_session::earth_rate_ics(0.0, KHARKOV_LAT_RAD);
    let mut s = String::from(if with_temperature {
        "t_s,fog0_rad_s,fog0_t_degc,psi_rad,lat_rad\n"
    } else {
        "t_s,fog0_rad_s,psi_rad,lat_rad\n"
    });
    let mut t = 0.0;
    for &(j, l) in cells {
        t += 1000.0;
        for k in 0..60 {
            t += 10.0;
            let gl: f64 = g_levels[l];
            let temp = t_levels[j] + gl / 60.0 * (k as f64 * 10.0 - 300.0);
            let y = (-0.005 * (temp - 25.0) + 0.3 * gl + 0.01 * g.next()) * DEG_H;
            let w = earth[0] + y;
            if with_temperature {
                s.push_str(&format!("{t},{w:.9e},{temp:.4},0,{KHARKOV_LAT_RAD}\n"));
            } else {
                s.push_str(&format!("{t},{w:.9e},0,{KHARKOV_LAT_RAD}\n"));
            }
        }
    }
    s
}

const TABLE1_CELLS: [(usize, usize); 10] =
    [(0, 1), (0, 2), (1, 0), (1, 1), (1, 2), (2, 0), (2, 1), (2, 2), (3, 0), (3, 1)];

#[test]
fn cal_thermal_runs_on_a_chamber_session_setting_only_thermal_fields() {
    let s = Scratch::new("thermal");
    s.write("chamber.csv", chamber_session(&TABLE1_CELLS, true));
    let mut base = CalibrationTable::DEFAULT;
    base.revision = 3;
    base.fog[0].scale_factor_error = 4e-4;
    base.misalignment.d12_rad = 1e-4;
    s.write("cal.toml", table::to_toml(&base).unwrap());
    let text = s.succeeds(
        "ssis-cal",
        &["thermal", "--session", "chamber.csv", "--fog", "0", "--table", "cal.toml", "--plot", "t.svg"],
        &["cal.toml", "t.svg"],
    );
    assert!(text.contains("600 rows: 600 in 10 cells") && text.contains("revision 3 → 4"), "{text}");
    assert!(text.contains("the ANOVA uses 600 of 600 rows (100.0 %)"), "{text}");
    let new = table::read_toml(&s.path("cal.toml")).unwrap();
    let changed: Vec<String> = ssis_common::update::diff(&base, &new).iter().map(|c| c.field.to_string()).collect();
    assert!(changed.iter().all(|f| f.starts_with("fog[0].thermal")), "{changed:?}");
    let a1 = new.fog[0].thermal_t_rad_s[0] / DEG_H;
    let g = new.fog[0].thermal_g_rad_s_per_degc_s / DEG_H / 60.0;
    assert!((a1 / -0.005 - 1.0).abs() < 0.2 && (g / 0.3 - 1.0).abs() < 0.1, "a1 {a1} °/h/°C, g {g} °/h per °C/min");
}

/// `ssis-cal thermal --session chamber.csv` (with `table`, when given, as `--table`) on a
/// chamber session of `cells`: refused with every one of `must`, nothing written.
fn cal_thermal_refuses(case: &str, cells: &[(usize, usize)], temperature: bool, table: Option<&str>, must: &[&str]) {
    let s = Scratch::new(case);
    s.write("chamber.csv", chamber_session(cells, temperature));
    let mut args = vec!["thermal", "--session", "chamber.csv", "--plot", "t.svg"];
    if let Some(t) = table {
        s.write("cal.toml", t);
        args.extend(["--table", "cal.toml"]);
    }
    s.refused("ssis-cal", &args, 1, must);
}

#[test]
fn cal_thermal_says_the_session_lacks_the_temperature_column() {
    let must = ["chamber.csv", "lacks `fog0_t_degc`", "temperature"];
    cal_thermal_refuses("thermal-no-t", &TABLE1_CELLS, false, None, &must);
}

#[test]
fn cal_thermal_says_the_session_lacks_a_gradient_level() {
    let cells: Vec<(usize, usize)> = TABLE1_CELLS.iter().copied().filter(|c| c.1 != 2).collect();
    let must = ["chamber.csv", "G = 0.25 °C/min", "lacks that gradient level"];
    cal_thermal_refuses("thermal-no-g", &cells, true, None, &must);
}

#[test]
fn cal_thermal_says_how_much_the_balanced_design_drops_and_why() {
    // One cell twice as long as the others: its extra 60 rows are cut.
    let s = Scratch::new("thermal-drop");
    let mut cells = TABLE1_CELLS.to_vec();
    cells.push((1, 1));
    s.write("chamber.csv", chamber_session(&cells, true));
    let text = s.succeeds("ssis-cal", &["thermal", "--session", "chamber.csv", "--plot", "t.svg"], &["t.svg"]);
    assert!(text.contains("the ANOVA uses 600 of 660 rows (90.9 %)"), "{text}");
    assert!(text.contains("smallest cell's N = 60") && text.contains("60 rows (9.1 %) dropped to balance"), "{text}");
    assert!(!text.contains("WARNING"), "{text}");
    // The lab's 48-h chamber run: most rows are cut, which is said before the ANOVA.
    s.succeeds("ssis-lab", &["simulate", "thermal", "lab.csv", "--seed", "3"], &["lab.csv"]);
    let text = s.succeeds("ssis-cal", &["thermal", "--session", "lab.csv", "--plot", "l.svg"], &["l.svg"]);
    assert!(text.contains("the ANOVA uses 72 of 576 rows (12.5 %)"), "{text}");
    assert!(text.contains("WARNING: lab.csv: the ANOVA uses less than half of the session"), "{text}");
    assert!(text.find("WARNING").unwrap() < text.find("two-factor ANOVA").unwrap(), "{text}");
}

#[test]
fn cal_thermal_takes_negative_levels_after_a_space_and_shows_commas_in_help() {
    let s = Scratch::new("thermal-levels");
    s.write("chamber.csv", chamber_session(&TABLE1_CELLS, true));
    let args = ["thermal", "--session", "chamber.csv", "--plot", "t.svg", "--g-levels-degc-min", "-0.25,0,0.25"];
    s.succeeds("ssis-cal", &args, &["t.svg"]);
    let (_, help, _) = s.run("ssis-cal", &["thermal", "--help"]);
    assert!(help.contains("[default: -0.25,0,0.25]") && help.contains("[default: 10,20,30,40]"), "{help}");
}

#[test]
fn cal_thermal_names_the_cell_with_too_few_samples() {
    let s = Scratch::new("thermal-thin");
    s.succeeds("ssis-lab", &["simulate", "thermal", "lab.csv", "--seed", "3"], &["lab.csv"]);
    let args = ["thermal", "--session", "lab.csv", "--plot", "t.svg", "--g-levels-degc-min", "-0.25,0,0.25,0.5"];
    s.refused("ssis-cal", &args, 1, &["lab.csv", "T 10 °C, G 0.5 °C/min: 1 sample(s)", "at least 2 samples"]);
}

#[test]
fn cal_refuses_bad_arguments_before_any_work() {
    let s = Scratch::new("cal-args");
    s.write("chamber.csv", chamber_session(&TABLE1_CELLS, true));
    for args in [
        &["thermal", "--session", "chamber.csv", "--fog", "4", "--plot", "t.svg"][..],
        &["thermal", "--simulate", "batch-i", "--fog", "4", "--plot", "t.svg"][..],
    ] {
        let text = s.refused("ssis-cal", args, 2, &["--fog", "4", "the unit has FOGs 0-3"]);
        assert!(!text.contains("ANOVA"), "worked before refusing: {text}");
    }
    let args = ["magnetic", "--unscreened", "u.csv", "--screened", "s.csv", "--site", "50,36", "--date", "2025-01-01"];
    let text = s.refused("ssis-cal", &args, 1, &["--date `2025-01-01`", "expected YYYY-DDD"]);
    assert!(!text.contains("u.csv"), "read the sessions before refusing the date: {text}");
}

#[test]
fn cal_allan_checks_the_table_before_it_prints_or_writes_anything() {
    let s = Scratch::new("allan-broken-table");
    s.succeeds("ssis-cal", &["simulate", "static", "st.csv", "--hours", "2"], &["st.csv"]);
    s.write("broken.toml", "format = \"ssis-calibration-table/1\"\ngarbage =\n");
    let text = s.refused("ssis-cal", &["allan", "--session", "st.csv", "--table", "broken.toml"], 1, &["broken.toml"]);
    assert!(!text.contains("ARW"), "printed figures before refusing: {text}");
    assert!(!s.path("allan.svg").exists(), "wrote its plot before refusing");
}

#[test]
fn cal_refuses_to_update_an_implausible_base_table() {
    let table = table_with("scale_factor_error = 0.0", "scale_factor_error = 0.05");
    let must = ["cal.toml", "fog[0].scale_factor_error", "50000 ppm", "-10000 … 10000 ppm"];
    cal_thermal_refuses("cal-base", &TABLE1_CELLS, true, Some(&table), &must);
}

// ------------------------------------------------------------------------ acceptance: export keeps, flies

/// The unit of the acceptance test: misaligned, scale factors of a few hundred ppm, biases of
/// a few tenths of °/h, a temperature coefficient and a temperature-rate coefficient.
fn truth_unit() -> (Misalignment, [FogCal; 4]) {
    let arcsec = 1.0 / 206_264.806_247;
    let m = Misalignment {
        d12_rad: 60.0 * arcsec,
        d13_rad: -45.0 * arcsec,
        d21_rad: 80.0 * arcsec,
        d23_rad: 30.0 * arcsec,
        d31_rad: -70.0 * arcsec,
        d32_rad: 55.0 * arcsec,
        d42_rad: 40.0 * arcsec,
        d43_rad: -65.0 * arcsec,
    };
    let fog = |b: f64, k: f64, a1: f64, g: f64| FogCal {
        bias_rad_s: b * DEG_H,
        scale_factor_error: k,
        t_ref_degc: 25.0,
        thermal_t_rad_s: [a1 * DEG_H, 0.0, 0.0],
        thermal_g_rad_s_per_degc_s: g * DEG_H,
        thermal_tg_rad_s_per_degc2_s: 0.0,
    };
    (
        m,
        [
            fog(0.3, 400e-6, 0.01, 12.0),
            fog(-0.2, -300e-6, -0.02, -15.0),
            fog(0.25, 500e-6, 0.015, 10.0),
            fog(-0.3, -350e-6, 0.02, 14.0),
        ],
    )
}

/// A thermal-chamber session of the truth unit, static at ψ = 0: 48 h of 5-min means, the
/// chamber cycling 10…40 °C (two periods, so T and G = dT/dt are not collinear).
fn thermal_session(m: &Misalignment, fogs: &[FogCal; 4]) -> String {
    let axes = m.axes(ssis::calib::GAMMA_NOMINAL_RAD);
    let w = ssis_session::earth_rate_ics(0.0, KHARKOV_LAT_RAD);
    let omega = nalgebra::Vector3::from(w);
    let temp = |t: f64| {
        25.0 + 12.0 * (2.0 * std::f64::consts::PI * t / 57_600.0).sin()
            + 3.0 * (2.0 * std::f64::consts::PI * t / 18_000.0).sin()
    };
    let rate = |t: f64| (temp(t + 1.0) - temp(t - 1.0)) / 2.0;
    let mut g = Gauss(11);
    let mut s = String::from(
        "t_s,fog0_rad_s,fog1_rad_s,fog2_rad_s,fog3_rad_s,fog0_t_degc,fog1_t_degc,fog2_t_degc,fog3_t_degc,psi_rad,lat_rad\n",
    );
    for k in 1..=576 {
        let t = k as f64 * 300.0;
        let (tc, gc) = (temp(t), rate(t));
        let y: Vec<String> = (0..4)
            .map(|i| {
                let f = &fogs[i];
                let v = (1.0 + f.scale_factor_error) * axes[i].dot(&omega)
                    + f.drift_rad_s(tc, gc)
                    + 0.0015 * DEG_H * g.next();
                format!("{v:.10e}")
            })
            .collect();
        s.push_str(&format!("{t},{},{tc:.4},{tc:.4},{tc:.4},{tc:.4},0,{KHARKOV_LAT_RAD}\n", y.join(",")));
    }
    s
}

/// Attitude error 3σ, worst axis, ″, of the truth unit flying `table_file`: 15 min with two
/// 360° slews, the chamber's temperature swing, the paper's star tracker.
fn fly(m: &Misalignment, fogs: &[FogCal; 4], table_file: &Path) -> f64 {
    let slew = |start_s: f64, axis: [f64; 3]| Slew { start_s, duration_s: 120.0, axis, angle_deg: 360.0 };
    let sc = Scenario {
        name: "acceptance".into(),
        description: String::new(),
        profile: ProfileName::Spacecraft,
        duration_s: 900.0,
        seed: 5,
        settle_s: 300.0,
        motion: MotionSpec {
            slews: vec![slew(350.0, [1.0, 0.0, 0.0]), slew(600.0, [0.0, 1.0, 1.0])],
            ..Default::default()
        },
        fog: FogSpec {
            errors: Some(TrueErrors { fog: *fogs, misalignment: *m }),
            temperature: TemperatureSpec {
                t0_degc: 28.0,
                sine_amp_degc: 3.0,
                sine_period_s: 1200.0,
                ..Default::default()
            },
            ..FogSpec::default()
        },
        star_tracker: Default::default(),
        table: TableSpec { file: Some(table_file.to_path_buf()), ..Default::default() },
        links: Default::default(),
        base_dir: PathBuf::new(),
    };
    sc.check().expect("a valid scenario");
    let summary = ssis_sim::harness::run(&sc, |_| {}).expect("runs");
    assert!(summary.silent_sources().is_empty(), "{:?}", summary.silent_sources());
    summary.accuracy.att.three_sigma().into_iter().fold(0.0, f64::max)
}

#[test]
fn export_from_a_thermal_session_keeps_the_base_and_flies_within_10_percent() {
    let s = Scratch::new("acceptance");
    let (m, fogs) = truth_unit();
    // The base: the unit's calibration so far (misalignment, scale factors, biases and
    // thermal terms from earlier campaigns) and noise figures of its own; revision 5. The new
    // chamber session re-estimates biases and thermal terms.
    let mut base = CalibrationTable::DEFAULT;
    base.revision = 5;
    base.misalignment = m;
    base.fog = fogs;
    base.observer.arw_deg_sqrt_h = 0.0049;
    base.observer.rrw_deg_h_sqrt_h = 0.012;
    base.observer.st_sigma_arcsec = 6.5;
    s.write("base.toml", table::to_toml(&base).unwrap());
    s.write("chamber.csv", thermal_session(&m, &fogs));
    s.succeeds("ssis-lab", &["init", "m.v1.toml", "--terms", "bias,thermal_t1"], &["m.v1.toml"]);
    s.succeeds(
        "ssis-lab",
        &["add", "temp_rate", "--model", "m.v1.toml", "--session", "chamber.csv"],
        &["m.v2.toml", "m.history.svg", "m.history-fogs.svg", "m.v2.allan.svg"],
    );
    let text = s.succeeds(
        "ssis-lab",
        &["export", "--model", "m.v2.toml", "--base", "base.toml", "--toml", "new.toml"],
        &["new.toml"],
    );
    assert!(text.contains("revision 5 → 6") && text.contains("fog[3].thermal_g_rad_s_per_degc_s"), "{text}");
    let kept = format!("the other {} kept bit for bit", ssis::calib::field::N_FIELDS - 16);
    assert!(text.contains("16 field(s) set") && text.contains(&kept), "{text}");
    let doc = table::read_doc(&s.path("new.toml")).unwrap();
    let new = doc.table;
    assert_eq!(new.revision, 6, "the revision only increases");
    // Every field the thermal session cannot identify is bit-identical to the base's.
    let kept =
        |f: &Field| !matches!(f, Field::Fog(_, FogTerm::Bias | FogTerm::TRef | FogTerm::ThermalT1 | FogTerm::ThermalG));
    for f in Field::all().filter(kept) {
        assert_eq!(f.get(&new).to_bits(), f.get(&base).to_bits(), "{f} changed");
    }
    // What it identifies is close to the truth, with its provenance.
    for (i, f) in fogs.iter().enumerate() {
        let (b, g) = (new.fog[i].bias_rad_s / DEG_H, new.fog[i].thermal_g_rad_s_per_degc_s / DEG_H / 60.0);
        println!(
            "FOG{i}: bias {b:.4} °/h (truth {:.4}), g {g:.4} °/h per °C/min (truth {:.4})",
            f.bias_rad_s / DEG_H,
            f.thermal_g_rad_s_per_degc_s / DEG_H / 60.0
        );
        assert!(
            (b - f.bias_rad_s / DEG_H).abs() < 0.03
                && (g / (f.thermal_g_rad_s_per_degc_s / DEG_H / 60.0) - 1.0).abs() < 0.05
        );
    }
    assert_eq!(doc.provenance.len(), 16);
    assert!(doc
        .provenance
        .iter()
        .all(|p| p.command == "ssis-lab export" && p.model_version == Some(2) && p.revision == 6));
    s.refused(
        "ssis-sim",
        &["table", "diff", "base.toml", "new.toml"],
        1,
        &["revision  5 → 6", "fog[0].bias_rad_s", "°/h per °C/min"],
    );

    // Flown: the exported table within 10 % of the base's attitude error; the table as the
    // old export wrote it (misalignment and scale factors zeroed) far from it.
    let mut zeroed = new;
    zeroed.misalignment = Misalignment::default();
    for f in zeroed.fog.iter_mut() {
        f.scale_factor_error = 0.0;
    }
    table::write_toml(&s.path("zeroed.toml"), &zeroed).unwrap();
    let e_base = fly(&m, &fogs, &s.path("base.toml"));
    let e_new = fly(&m, &fogs, &s.path("new.toml"));
    let e_zeroed = fly(&m, &fogs, &s.path("zeroed.toml"));
    println!("attitude error 3σ (worst axis): base {e_base:.2}″, exported {e_new:.2}″, zeroed geometry {e_zeroed:.2}″");
    assert!((e_new / e_base - 1.0).abs() <= 0.1, "exported {e_new:.2}″ against the base's {e_base:.2}″");
    assert!(e_zeroed > 2.0 * e_base, "the zeroed table flies too well for this test to see the difference");
}

// ------------------------------------------------------------------ real recordings (ssis-lab, ssis-cal)

/// Biases of a MEMS gyro triad at rest, °/h: the first that of a real recording (1,446 °/h,
/// about 150 times the Earth rate on its axis).
const MEMS_BIAS_DEG_H: [f64; 3] = [1446.0, -812.0, 377.0];

/// A static session of a MEMS triad at 100 Hz, `rows` rows, at ψ = 0 and latitude 50°:
/// the Earth rate along each axis, [`MEMS_BIAS_DEG_H`], and white noise of 300 °/h per sample
/// (an angle random walk of 0.5 °/√h).
fn mems_static_session(rows: usize) -> String {
    let mut g = Gauss(0x9E37_79B9_7F4A_7C15);
    let lat = 50f64.to_radians();
    let we = 15.041068;
    let earth = [we * lat.cos(), 0.0, we * lat.sin()];
    let rad_s = |deg_h: f64| deg_h.to_radians() / 3600.0;
    let mut s = String::from("t_s,fog0_rad_s,fog1_rad_s,fog2_rad_s,psi_rad,lat_rad\n");
    for k in 1..=rows {
        let w: Vec<String> =
            (0..3).map(|i| format!("{:.9e}", rad_s(MEMS_BIAS_DEG_H[i] + earth[i] + 300.0 * g.next()))).collect();
        s.push_str(&format!("{},{},0,{lat}\n", k as f64 * 0.01, w.join(",")));
    }
    s
}

/// A static recording whose gyro bias is many times the Earth rate is no unit error: a
/// constant reference cannot tell one from the other, so `ssis-lab compare` and `diagnose`
/// take it (and compare's bias is the recording's), and `ssis-cal allan` finds its ARW.
#[test]
fn a_static_mems_recording_passes_compare_diagnose_and_allan() {
    let s = Scratch::new("mems-static");
    s.write("mems.csv", mems_static_session(60_000));
    s.succeeds("ssis-lab", &["init", "m.v1.toml", "--terms", "bias"], &["m.v1.toml"]);
    let text = s.succeeds("ssis-lab", &["compare", "--model", "m.v1.toml", "--session", "mems.csv"], &[]);
    let fog0 = text.lines().find_map(|l| l.split("FOG0: b = ").nth(1)).expect("compare prints FOG0's bias");
    // compare prints the coefficient in engineering units: `b = 1444.29229 °/h`.
    let mut words = fog0.split_whitespace();
    let b_deg_h: f64 = words.next().and_then(|v| v.parse().ok()).expect("a number");
    assert_eq!(words.next(), Some("°/h"), "compare's bias in °/h: {fog0}");
    // The model's bias is the error about the reference: the gyro's own, ±1.2 °/h (1σ).
    assert!((b_deg_h - MEMS_BIAS_DEG_H[0]).abs() < 5.0, "bias {b_deg_h} °/h against {}", MEMS_BIAS_DEG_H[0]);
    s.succeeds("ssis-lab", &["diagnose", "--model", "m.v1.toml", "--session", "mems.csv"], &[]);
    let text = s.succeeds("ssis-cal", &["allan", "--session", "mems.csv", "--plot", "a.svg"], &["a.svg"]);
    let arw = text.lines().find_map(|l| l.strip_prefix("ARW")).expect("allan prints the ARW");
    let arw: f64 = arw.split_whitespace().next().and_then(|v| v.parse().ok()).expect("a number");
    assert!((arw / 0.5 - 1.0).abs() < 0.05, "ARW {arw} °/√h against 0.5");
}

/// `a` as the argument slice a command takes.
fn run(a: &[String]) -> Vec<&str> {
    a.iter().map(String::as_str).collect()
}

/// A logger's CSV: `;`-separated, quoted names, a comment, time in ms, X in counts of
/// 0.00875 °/s, Y in °/s, Z in rad/s, a temperature in K and a text column.
fn logger_csv(rows: usize) -> String {
    let mut g = Gauss(0x2545_F491_4F6C_DD1D);
    let mut s = String::from("# logger v3\n\"time_ms\";\"gx_raw\";\"gy\";\"gz\";\"board_temp\";\"status\"\n");
    for k in 1..=rows {
        let gx = (1446.0 / 3600.0 / 0.00875 + 3.0 * g.next()).round();
        let gy = (-812.0 + 300.0 * g.next()) / 3600.0;
        let gz = (377.0 + 300.0 * g.next()).to_radians() / 3600.0;
        s.push_str(&format!("{};{gx};{gy:.6};{gz:.6e};{:.4};OK\n", k * 10, 295.15 + k as f64 * 1e-4));
    }
    s
}

const LOGGER_MAP: [&str; 10] = [
    "--map",
    "t_s=time_ms:ms",
    "--map",
    "fog0_rad_s=gx_raw:0.00875*deg/s",
    "--map",
    "fog1_rad_s=gy:deg/s",
    "--map",
    "fog2_rad_s=gz:rad/s",
    "--map",
    "fog0_t_degc=board_temp:k",
];

/// `ssis-lab import csv` maps a logger's columns and units onto a session, names what it
/// mapped and what not, and the session goes through the lab; what it cannot map is refused
/// with the file, the line and the logger's column, and nothing is written.
#[test]
fn import_csv_maps_a_loggers_columns_and_units() {
    let s = Scratch::new("import-csv");
    s.write("log.csv", logger_csv(2000));
    let static_ref = ["--psi-rad", "0", "--lat-rad", "0.8735"];
    let args = |out: &str, maps: &[&str]| -> Vec<String> {
        ["import", "csv", "log.csv", "--out", out]
            .iter()
            .chain(maps)
            .chain(&static_ref)
            .map(|a| a.to_string())
            .collect()
    };
    let text = s.succeeds("ssis-lab", &run(&args("s.csv", &LOGGER_MAP)), &["s.csv"]);
    for m in [
        "log.csv: 2000 data lines, 2000 samples",
        "t_s <- column 1 `time_ms` in ms",
        "fog0_rad_s <- column 2 `gx_raw` in 0.00875*deg/s",
        "fog0_t_degc <- column 5 `board_temp` in k, -273.15",
        "lat_rad = 0.8735 (--lat-rad)",
        "not mapped: column 6 `status`",
    ] {
        assert!(text.contains(m), "the report lacks `{m}`: {text}");
    }
    let session = ssis_session::read_session(&s.path("s.csv"), None).expect("a session");
    let log = logger_csv(2000);
    let first: Vec<&str> = log.lines().nth(2).unwrap().split(';').collect();
    assert_eq!(session.t_s()[0], 0.01);
    let gx: f64 = first[1].parse().unwrap();
    assert_eq!(session.column("fog0_rad_s").unwrap()[0], gx * (0.00875 * std::f64::consts::PI / 180.0));
    assert_eq!(session.column("fog0_t_degc").unwrap()[0], first[4].parse::<f64>().unwrap() - 273.15);
    s.succeeds("ssis-lab", &["init", "m.v1.toml", "--terms", "bias"], &["m.v1.toml"]);
    s.succeeds("ssis-lab", &["compare", "--model", "m.v1.toml", "--session", "s.csv"], &[]);

    // What it cannot map.
    let mut bad = LOGGER_MAP.to_vec();
    bad[5] = "fog1_rad_s=status:deg/s";
    s.refused("ssis-lab", &run(&args("t.csv", &bad)), 1, &["log.csv", "line 3", "column 6 (`status`)", "`OK`"]);
    bad[5] = "fog1_rad_s=gyro_y:deg/s";
    s.refused("ssis-lab", &run(&args("t.csv", &bad)), 1, &["log.csv", "line 2", "no column `gyro_y`"]);
    bad[5] = "fog1_rad_s=gy:deg";
    s.refused("ssis-lab", &run(&args("t.csv", &bad)), 1, &["fog1_rad_s=gy:deg", "rate unit"]);
    bad[5] = "fog1_rad_s=gy:furlong/s";
    s.refused("ssis-lab", &run(&args("t.csv", &bad)), 1, &["unknown unit `furlong/s`"]);
    // A value the session refuses names the logger's line and column.
    let mut wrong = log.clone();
    wrong = wrong.replacen("\n30;", "\n5;", 1);
    s.write("back.csv", &wrong);
    let a: Vec<String> = args("t.csv", &LOGGER_MAP).into_iter().map(|x| x.replace("log.csv", "back.csv")).collect();
    s.refused("ssis-lab", &run(&a), 1, &["back.csv", "line 5", "column 1 (`time_ms`)", "time does not increase"]);
    s.write("cut.csv", &log[..log.len() - 1]);
    let a: Vec<String> = args("t.csv", &LOGGER_MAP).into_iter().map(|x| x.replace("log.csv", "cut.csv")).collect();
    s.refused("ssis-lab", &run(&a), 1, &["cut.csv", "line 2002", "no line end"]);
    // Never over its input.
    s.refused("ssis-lab", &run(&args("log.csv", &LOGGER_MAP)), 1, &["log.csv", "input"]);
}
