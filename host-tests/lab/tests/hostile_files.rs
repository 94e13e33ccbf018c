//! `ssis-lab` against a careless user: outputs onto inputs (however spelt), existing
//! files without `--force`, closed pipes, and `--json` (docs/JSON.md). Every refusal
//! leaves every file of the directory byte-identical.

#[path = "../../tests/hostile_common/mod.rs"]
mod hostile;
use hostile::*;

const LAB: &str = env!("CARGO_BIN_EXE_ssis-lab");

/// A directory with a small session (576 rows) and a model v1.
fn lab_dir(name: &str) -> Scratch {
    let s = Scratch::new(name);
    succeeds(LAB, &s, &["simulate", "thermal", "s.csv", "--seed", "3"], &[]);
    succeeds(LAB, &s, &["init", "m.v1.toml", "--terms", "bias,scale_factor,misalignment,thermal_t1"], &[]);
    s
}

#[test]
fn report_onto_its_session_is_refused() {
    let s = lab_dir("report-session");
    let args = ["report", "--model", "m.v1.toml", "--session", "s.csv", "--out"];
    for out in ["s.csv", "./x/../s.csv", "./s.csv"] {
        let a: Vec<&str> = args.iter().copied().chain([out]).collect();
        refused(LAB, &s, &a, &[out, "input s.csv"]);
    }
}

#[test]
fn report_onto_a_link_to_its_model_is_refused() {
    let s = lab_dir("report-link");
    std::os::unix::fs::symlink("m.v1.toml", s.path("page.html")).unwrap();
    std::fs::hard_link(s.path("s.csv"), s.path("hard.html")).unwrap();
    let base = ["report", "--model", "m.v1.toml", "--session", "s.csv", "--out"];
    refused(LAB, &s, &[&base[..], &["page.html"]].concat(), &["page.html", "input m.v1.toml"]);
    refused(LAB, &s, &[&base[..], &["hard.html"]].concat(), &["hard.html", "input s.csv"]);
}

#[test]
fn export_onto_its_model_is_refused() {
    let s = lab_dir("export-model");
    succeeds(LAB, &s, &["add", "temp_rate", "--model", "m.v1.toml", "--session", "s.csv"], &[]);
    refused(LAB, &s, &["export", "--model", "m.v2.toml", "--toml", "m.v2.toml"], &["m.v2.toml", "input"]);
    // A base table named as `--toml` is updated in place (as `ssis-cal --table` is); as
    // `--bin` it stays an input.
    succeeds(LAB, &s, &["export", "--model", "m.v2.toml", "--toml", "base.toml"], &[]);
    succeeds(
        LAB,
        &s,
        &["export", "--model", "m.v2.toml", "--base", "base.toml", "--toml", "base.toml"],
        &["base.toml"],
    );
    refused(
        LAB,
        &s,
        &["export", "--model", "m.v2.toml", "--base", "base.toml", "--bin", "base.toml"],
        &["base.toml", "input"],
    );
    // One file named twice as output.
    refused(
        LAB,
        &s,
        &["export", "--model", "m.v2.toml", "--toml", "cal.x", "--bin", "./cal.x"],
        &["cal.x", "same file as the output"],
    );
}

#[test]
fn simulate_onto_an_existing_file_needs_force() {
    let s = lab_dir("simulate-existing");
    s.file("notes.csv", "my own notes\n");
    refused(LAB, &s, &["simulate", "magnetic", "notes.csv"], &["notes.csv", "exists", "--force"]);
    // Also the lab's own earlier session: a named output is never silently replaced.
    refused(LAB, &s, &["simulate", "thermal", "s.csv", "--seed", "4"], &["s.csv", "exists"]);
    succeeds(LAB, &s, &["simulate", "magnetic", "notes.csv", "--force"], &["notes.csv"]);
    assert_ne!(std::fs::read(s.path("notes.csv")).unwrap(), b"my own notes\n");
}

#[test]
fn import_onto_its_log_is_refused() {
    let s = lab_dir("import-log");
    s.file("log.csv", "t_s,q0\n");
    refused(LAB, &s, &["import", "qemu-csv", "log.csv", "--out", "log.csv"], &["log.csv", "input"]);
    std::os::unix::fs::symlink(s.path("log.csv"), s.path("alias.csv")).unwrap();
    refused(LAB, &s, &["import", "qemu-csv", "log.csv", "--out", "alias.csv"], &["alias.csv", "input log.csv"]);
}

#[test]
fn init_never_replaces_a_model_even_with_force() {
    let s = lab_dir("init-model");
    refused(LAB, &s, &["init", "m.v1.toml", "--force"], &["m.v1.toml", "exists"]);
}

#[test]
fn compare_plots_replace_only_our_own() {
    let s = lab_dir("compare-plots");
    std::fs::create_dir_all(s.path("plots")).unwrap();
    s.file("plots/residual-fog0.svg", "<svg><text>a drawing of mine</text></svg>");
    let args = ["compare", "--model", "m.v1.toml", "--session", "s.csv", "--plots", "plots"];
    refused(LAB, &s, &args, &["plots/residual-fog0.svg", "not recognisably"]);
    succeeds(LAB, &s, &[&args[..], &["--force"]].concat(), &["plots/residual-fog0.svg"]);
    // Now ours: a second run replaces it without --force.
    succeeds(LAB, &s, &args, &["plots/residual-fog0.svg"]);
}

#[test]
fn closed_pipe_ends_diagnose_compare_quietly() {
    let s = lab_dir("pipe-diagnose");
    for lines in [0, 1] {
        closed_pipe(LAB, &s, &["diagnose", "--model", "m.v1.toml", "--session", "s.csv"], lines);
        closed_pipe(LAB, &s, &["compare", "--model", "m.v1.toml", "--session", "s.csv"], lines);
        closed_pipe(LAB, &s, &["diagnose", "--model", "m.v1.toml", "--session", "s.csv", "--json"], lines);
    }
}

/// The model versions beside `m.v1.toml`: each parses, versions 1..=n with no gap, and
/// nothing else but the session and the plots `add` writes after its version (whether it
/// gets to them before the closed pipe ends it depends on when the reader exits).
fn versions_consistent(s: &Scratch) -> usize {
    let mut versions = Vec::new();
    for name in s.snapshot().into_keys() {
        let n = name.to_string_lossy().to_string();
        if n.ends_with(".toml") {
            let m = ssis_lab::model::Model::read(&s.dir.join(&name)).expect("a whole model");
            assert_eq!(n, format!("m.v{}.toml", m.version), "version {} in {n}", m.version);
            versions.push(m.version);
        } else {
            let plot = n == "m.history.svg" || n == "m.history-fogs.svg" || n.ends_with(".allan.svg");
            assert!(n == "s.csv" || plot, "unexpected file {n}");
        }
    }
    versions.sort();
    assert_eq!(versions, (1..=versions.len() as u32).collect::<Vec<_>>(), "versions {versions:?}");
    versions.len()
}

#[test]
fn closed_pipe_during_add_leaves_a_consistent_model_set() {
    let s = lab_dir("pipe-add");
    closed_pipe(LAB, &s, &["add", "temp_rate", "--model", "m.v1.toml", "--session", "s.csv"], 0);
    assert_eq!(versions_consistent(&s), 2, "the version is written before anything is printed");
    // aging makes the held-out RMS of this session worse: --force writes it anyway.
    closed_pipe(LAB, &s, &["add", "aging", "--model", "m.v2.toml", "--session", "s.csv", "--force"], 1);
    assert_eq!(versions_consistent(&s), 3);
}

#[test]
fn json_diagnose_compare_add() {
    let s = lab_dir("json");
    let d = json_of(LAB, &s, &["diagnose", "--model", "m.v1.toml", "--session", "s.csv", "--json"], true);
    has_documented_keys(&d, "ssis-lab diagnose");
    assert_eq!(at(&d, "/command"), "diagnose");
    assert_eq!(at(&d, "/diagnosis/candidates/0/rank"), 1);
    assert_eq!(at(&d, "/diagnosis/most_significant"), "temp_rate");
    assert!(at(&d, "/diagnosis/candidates/0/p_value").as_f64().unwrap() < 1e-6);
    assert!(at(&d, "/diagnosis/candidates/0/after_deg_h").as_f64().unwrap() > 0.0);
    let c = json_of(LAB, &s, &["compare", "--model", "m.v1.toml", "--session", "s.csv", "--json"], true);
    has_documented_keys(&c, "ssis-lab compare");
    let fog0 = at(&c, "/fit/fogs/0");
    for key in ["rms_error_deg_h", "rms_residual_deg_h", "max_abs_residual_deg_h", "explained_fraction"] {
        assert!(fog0[key].is_number(), "{key} in {fog0}");
    }
    let a = json_of(LAB, &s, &["add", "temp_rate", "--model", "m.v1.toml", "--session", "s.csv", "--json"], true);
    has_documented_keys(&a, "ssis-lab add");
    assert_eq!(at(&a, "/added/version"), 2);
    assert!(at(&a, "/added/pooled_after_deg_h").as_f64() < at(&a, "/added/pooled_before_deg_h").as_f64());
    assert_eq!(at(&a, "/history").as_array().unwrap().len(), 2);
    let written = at(&a, "/files_written").as_array().unwrap();
    assert!(written.iter().any(|w| w == "m.v2.toml"), "{written:?}");
    // A refusal in JSON mode: still one object, with the error naming the file.
    let r = json_of(LAB, &s, &["simulate", "thermal", "s.csv", "--json"], false);
    assert!(at(&r, "/error").as_str().unwrap().contains("s.csv"));
}

/// The session `from` with column `name` mapped by `f`, as `out`.
fn with_column(s: &Scratch, from: &str, out: &str, name: &str, f: impl Fn(f64) -> f64) {
    let text = std::fs::read_to_string(s.path(from)).unwrap();
    let mut lines = text.lines();
    let header = lines.next().unwrap();
    let k = header.split(',').position(|c| c == name).unwrap();
    let mut o = format!("{header}\n");
    for l in lines {
        let mut v: Vec<String> = l.split(',').map(String::from).collect();
        v[k] = format!("{:e}", f(v[k].parse::<f64>().unwrap()));
        o.push_str(&v.join(","));
        o.push('\n');
    }
    s.file(out, o);
}

/// A FOG column with its sign flipped, or in °/h or °/s under a rad/s name, is refused by
/// every command that reads a turntable session (the reference of FOG0 and FOG1 changes with
/// the azimuth), naming the file, the column and what it looks like; nothing is written.
/// A column in °/h is beyond the FOG's measuring range there. A static session cannot tell
/// a unit from a bias: the same column in °/s there passes.
#[test]
fn a_flipped_or_misunit_fog_column_is_refused() {
    let s = lab_dir("bad-fog-column");
    succeeds(LAB, &s, &["simulate", "sin2psi", "turns.csv", "--seed", "3"], &[]);
    succeeds(LAB, &s, &["init", "b.v1.toml", "--terms", "bias"], &[]);
    let deg_h = 180.0 / std::f64::consts::PI * 3600.0;
    with_column(&s, "turns.csv", "flipped.csv", "fog0_rad_s", |v| -v);
    with_column(&s, "turns.csv", "deg_h.csv", "fog0_rad_s", |v| v * deg_h);
    with_column(&s, "turns.csv", "deg_s.csv", "fog1_rad_s", |v| v.to_degrees());
    for (file, column, says) in [
        ("flipped.csv", "column 2 (`fog0_rad_s`)", "sign looks flipped"),
        ("deg_h.csv", "column 2 (`fog0_rad_s`)", "measuring range"),
        ("deg_s.csv", "column 3 (`fog1_rad_s`)", "°/s, not rad/s"),
    ] {
        let must = [file, column, says];
        refused(LAB, &s, &["compare", "--model", "b.v1.toml", "--session", file], &must);
        refused(LAB, &s, &["diagnose", "--model", "b.v1.toml", "--session", file], &must);
        refused(LAB, &s, &["add", "scale_factor", "--model", "b.v1.toml", "--session", file], &must);
        refused(LAB, &s, &["report", "--model", "b.v1.toml", "--session", file, "--out", "r.html"], &must);
    }
    // The sessions as written pass, and so does the static one with FOG2 (up: its reference
    // is the constant vertical Earth rate) in °/s: a bias of some 660 °/h.
    succeeds(LAB, &s, &["diagnose", "--model", "b.v1.toml", "--session", "turns.csv"], &[]);
    succeeds(LAB, &s, &["diagnose", "--model", "m.v1.toml", "--session", "s.csv"], &[]);
    with_column(&s, "s.csv", "static_deg_s.csv", "fog2_rad_s", |v| v.to_degrees());
    succeeds(LAB, &s, &["compare", "--model", "m.v1.toml", "--session", "static_deg_s.csv"], &[]);
}

/// A session with a gap in time (200 rows of 5 min missing) is read, but every command
/// that reads it says so on stderr: the file, the number of gaps, the time missing and
/// where the largest is; the page of `report` says it too.
#[test]
fn a_gap_in_time_is_stated() {
    let s = lab_dir("gap");
    let text = std::fs::read_to_string(s.path("s.csv")).unwrap();
    let lines: Vec<&str> = text.lines().collect();
    let kept: Vec<&str> = lines[..101].iter().chain(&lines[301..]).copied().collect();
    s.file("gap.csv", kept.join("\n") + "\n");
    let must = ["gap.csv", "1 gap(s) in time", "60000.0 s missing", "after t = 30000 s"];
    for args in [
        &["compare", "--model", "m.v1.toml", "--session", "gap.csv"][..],
        &["diagnose", "--model", "m.v1.toml", "--session", "gap.csv"][..],
    ] {
        let r = succeeds(LAB, &s, args, &[]);
        println!("{}", r.stderr.trim());
        for m in must {
            assert!(r.stderr.contains(m), "{args:?}: stderr lacks `{m}`: {}", r.stderr);
        }
    }
    let r = succeeds(LAB, &s, &["add", "temp_rate", "--model", "m.v1.toml", "--session", "gap.csv"], &[]);
    assert!(r.stderr.contains("1 gap(s) in time"), "add: {}", r.stderr);
    succeeds(LAB, &s, &["report", "--model", "m.v1.toml", "--session", "gap.csv", "--out", "r.html"], &[]);
    let page = std::fs::read_to_string(s.path("r.html")).unwrap();
    assert!(page.contains("1 gap(s) in time"), "the report does not say so");
    // The session without the gap: no note.
    let r = succeeds(LAB, &s, &["diagnose", "--model", "m.v1.toml", "--session", "s.csv"], &[]);
    assert!(!r.stderr.contains("gap"), "{}", r.stderr);
}
