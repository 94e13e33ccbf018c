//! `ssis-cal` against a careless user: a mistyped `--table`, plots onto inputs, default
//! plots over files that are not ours, a table kept when the method fails, closed pipes,
//! `--json` (docs/JSON.md). Every refusal leaves every file byte-identical.

#[path = "../../tests/hostile_common/mod.rs"]
mod hostile;
use hostile::*;

const CAL: &str = env!("CARGO_BIN_EXE_ssis-cal");

/// A directory with a 3-hour static session (1-s means) and a calibration table.
fn cal_dir(name: &str) -> Scratch {
    let s = Scratch::new(name);
    succeeds(CAL, &s, &["simulate", "static", "st.csv", "--hours", "3"], &[]);
    let t = ssis_common::table::to_toml(&ssis::calib::CalibrationTable::DEFAULT).unwrap();
    s.file("cal.toml", t);
    s
}

#[test]
fn a_missing_table_is_refused_without_new_table() {
    let s = cal_dir("missing-table");
    refused(CAL, &s, &["allan", "--session", "st.csv", "--table", "typo.toml"], &["typo.toml", "--new-table"]);
    refused(CAL, &s, &["turns", "--session", "st.csv", "--table", "typo.toml"], &["typo.toml", "--new-table"]);
    succeeds(CAL, &s, &["allan", "--session", "st.csv", "--table", "new.toml", "--new-table"], &[]);
    let t = ssis_common::table::read_toml(&s.path("new.toml")).unwrap();
    assert_eq!(t.revision, ssis::calib::CalibrationTable::DEFAULT.revision.wrapping_add(1));
}

#[test]
fn new_table_over_an_existing_table_is_refused() {
    let s = cal_dir("new-over-existing");
    refused(CAL, &s, &["allan", "--session", "st.csv", "--table", "cal.toml", "--new-table"], &["cal.toml", "exists"]);
}

#[test]
fn the_table_is_updated_in_place_and_kept_when_the_method_fails() {
    let s = cal_dir("table-kept");
    succeeds(CAL, &s, &["allan", "--session", "st.csv", "--table", "cal.toml"], &["cal.toml", "allan.svg"]);
    // FOG3 is not in the session: the method fails, the table stays as it was.
    refused(CAL, &s, &["allan", "--session", "st.csv", "--fog", "3", "--table", "cal.toml"], &["st.csv", "FOG3"]);
}

#[test]
fn outputs_onto_the_session_are_refused() {
    let s = cal_dir("plot-session");
    refused(CAL, &s, &["allan", "--session", "st.csv", "--plot", "st.csv"], &["st.csv", "input"]);
    refused(CAL, &s, &["allan", "--session", "st.csv", "--plot", "./no/../st.csv"], &["./no/../st.csv", "input"]);
    std::os::unix::fs::symlink("st.csv", s.path("plot.svg")).unwrap();
    refused(CAL, &s, &["allan", "--session", "st.csv", "--plot", "plot.svg"], &["plot.svg", "input st.csv"]);
    // The table to update may not be the session either.
    refused(CAL, &s, &["allan", "--session", "st.csv", "--table", "./st.csv"], &["./st.csv", "input st.csv"]);
}

#[test]
fn a_default_plot_replaces_only_our_own() {
    let s = cal_dir("default-plot");
    s.file("allan.svg", "<svg><text>my figure</text></svg>");
    refused(CAL, &s, &["allan", "--session", "st.csv"], &["allan.svg", "not recognisably"]);
    succeeds(CAL, &s, &["allan", "--session", "st.csv", "--force"], &["allan.svg"]);
    // Ours now (its title): the next run replaces it without --force.
    succeeds(CAL, &s, &["allan", "--session", "st.csv"], &["allan.svg"]);
    // A plot at another name is the user's: not replaced without --force, even if ours.
    succeeds(CAL, &s, &["allan", "--session", "st.csv", "--plot", "fig.svg"], &[]);
    refused(CAL, &s, &["allan", "--session", "st.csv", "--plot", "fig.svg"], &["fig.svg", "exists"]);
}

#[test]
fn simulate_onto_an_existing_session_needs_force() {
    let s = cal_dir("simulate-existing");
    refused(CAL, &s, &["simulate", "static", "st.csv", "--hours", "1"], &["st.csv", "exists", "--force"]);
    succeeds(CAL, &s, &["simulate", "static", "st.csv", "--hours", "1", "--force"], &["st.csv"]);
}

#[test]
fn closed_pipe_ends_allan_quietly() {
    let s = cal_dir("pipe-allan");
    for lines in [0, 1] {
        closed_pipe(CAL, &s, &["allan", "--session", "st.csv", "--plot", "p.svg", "--force"], lines);
    }
    closed_pipe(CAL, &s, &["allan", "--session", "st.csv", "--table", "cal.toml"], 1);
    // The table is either updated whole or left as it was.
    ssis_common::table::read_toml(&s.path("cal.toml")).unwrap();
}

#[test]
fn json_allan() {
    let s = cal_dir("json");
    let v = json_of(CAL, &s, &["allan", "--session", "st.csv", "--table", "cal.toml", "--json"], true);
    has_documented_keys(&v, "ssis-cal allan");
    has_documented_keys(&v, "ssis-cal METHOD --table");
    assert_eq!(at(&v, "/command"), "allan");
    let arw = at(&v, "/allan/arw_deg_sqrt_h/value").as_f64().unwrap();
    assert!((arw - 0.005).abs() < 0.001, "ARW {arw} °/√h (truth 0.005)");
    assert!(at(&v, "/allan/points/0/tau_s").is_number());
    // This short static session bounds the rate random walk from above only.
    assert!(at(&v, "/allan/rrw_deg_h_sqrt_h/upper_bound_95").is_number());
    assert_eq!(at(&v, "/table/path"), "cal.toml");
    assert_eq!(at(&v, "/table/revision"), 1);
    let written = at(&v, "/files_written").as_array().unwrap();
    assert_eq!(written.len(), 2, "{written:?}");
}

#[test]
fn json_of_every_ground_method_has_the_documented_keys() {
    let s = Scratch::new("json-methods");
    succeeds(CAL, &s, &["simulate", "turns", "t.csv"], &[]);
    succeeds(CAL, &s, &["simulate", "sins", "r.csv"], &[]);
    succeeds(CAL, &s, &["simulate", "magnetic", "u.csv", "sc.csv"], &[]);
    let runs: [(&str, &[&str]); 4] = [
        ("ssis-cal turns", &["turns", "--session", "t.csv"]),
        ("ssis-cal sins", &["sins", "--session", "r.csv"]),
        ("ssis-cal magnetic", &["magnetic", "--unscreened", "u.csv", "--screened", "sc.csv"]),
        ("ssis-cal thermal", &["thermal", "--simulate", "batch-i"]),
    ];
    for (name, args) in runs {
        let v = json_of(CAL, &s, &[args, &["--json"]].concat(), true);
        has_documented_keys(&v, name);
    }
}
