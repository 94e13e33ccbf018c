//! `ssis-sim` against a careless user: `table to-bin A A`, `run S.toml --csv S.toml`, the
//! same through `./x/../` and links, existing files without `--force`, closed pipes,
//! `--json` (docs/JSON.md). Every refusal leaves every file byte-identical.

#[path = "../../tests/hostile_common/mod.rs"]
mod hostile;
use hostile::*;

const SIM: &str = env!("CARGO_BIN_EXE_ssis-sim");

/// A directory with a 5-s scenario and a table.
fn sim_dir(name: &str) -> Scratch {
    let s = Scratch::new(name);
    s.file("s.toml", "name = \"tiny\"\nprofile = \"spacecraft\"\nduration_s = 5\nseed = 1\nsettle_s = 1\n");
    succeeds(SIM, &s, &["table", "new", "a.toml"], &[]);
    s
}

#[test]
fn table_conversion_onto_its_input_is_refused() {
    let s = sim_dir("to-bin");
    refused(SIM, &s, &["table", "to-bin", "a.toml", "a.toml"], &["a.toml", "input"]);
    refused(SIM, &s, &["table", "to-bin", "a.toml", "./x/../a.toml"], &["./x/../a.toml", "input a.toml"]);
    refused(SIM, &s, &["table", "to-image", "a.toml", "a.toml"], &["a.toml", "input"]);
    std::os::unix::fs::symlink("a.toml", s.path("a.bin")).unwrap();
    refused(SIM, &s, &["table", "to-bin", "a.toml", "a.bin"], &["a.bin", "input a.toml"]);
}

#[test]
fn table_new_and_to_bin_need_force_over_a_file() {
    let s = sim_dir("table-existing");
    refused(SIM, &s, &["table", "new", "a.toml"], &["a.toml", "exists", "--force"]);
    s.file("a.bin", "keep me");
    refused(SIM, &s, &["table", "to-bin", "a.toml", "a.bin"], &["a.bin", "exists", "--force"]);
    succeeds(SIM, &s, &["table", "to-bin", "a.toml", "a.bin", "--force"], &["a.bin"]);
    ssis_common::table::read_binary(&s.path("a.bin")).unwrap();
}

#[test]
fn run_csv_onto_its_scenario_is_refused() {
    let s = sim_dir("run-scenario");
    refused(SIM, &s, &["run", "s.toml", "--csv", "s.toml"], &["s.toml", "input"]);
    std::fs::create_dir_all(s.path("out")).unwrap();
    refused(SIM, &s, &["run", "s.toml", "--csv", "out/../s.toml"], &["out/../s.toml", "input s.toml"]);
    std::os::unix::fs::symlink(s.path("s.toml"), s.path("out/log.csv")).unwrap();
    refused(SIM, &s, &["run", "s.toml", "--csv", "out/log.csv"], &["out/log.csv", "input s.toml"]);
    // A directory is not a file to write.
    refused(SIM, &s, &["run", "s.toml", "--csv", "out"], &["out", "directory"]);
}

#[test]
fn run_csv_over_an_existing_file_needs_force() {
    let s = sim_dir("run-existing");
    s.file("log.csv", "precious\n");
    refused(SIM, &s, &["run", "s.toml", "--csv", "log.csv"], &["log.csv", "exists", "--force"]);
    succeeds(SIM, &s, &["run", "s.toml", "--csv", "log.csv", "--force"], &["log.csv"]);
    let text = std::fs::read_to_string(s.path("log.csv")).unwrap();
    assert!(text.starts_with("t_s,"), "{}", &text[..40.min(text.len())]);
}

#[test]
fn closed_pipe_ends_run_and_show_quietly() {
    let s = sim_dir("pipe");
    for lines in [0, 1] {
        closed_pipe(SIM, &s, &["run", "s.toml"], lines);
        closed_pipe(SIM, &s, &["table", "show", "a.toml"], lines);
        closed_pipe(SIM, &s, &["run", "s.toml", "--csv", "o.csv", "--force"], lines);
    }
}

#[test]
fn json_run() {
    let s = sim_dir("json");
    let v = json_of(SIM, &s, &["run", "s.toml", "--csv", "o.csv", "--json"], true);
    has_documented_keys(&v, "ssis-sim run");
    has_documented_keys(&json_of(SIM, &s, &["gains", "--json"], true), "ssis-sim gains");
    assert_eq!(at(&v, "/command"), "run");
    assert_eq!(at(&v, "/run/steps"), 1000);
    assert_eq!(at(&v, "/run/accuracy/attitude_error_3sigma_arcsec").as_array().unwrap().len(), 3);
    assert!(at(&v, "/run/counters/fog_samples_missing").is_u64());
    assert_eq!(at(&v, "/files_written/0"), "o.csv");
    let r = json_of(SIM, &s, &["table", "to-bin", "a.toml", "a.toml", "--json"], false);
    assert!(at(&r, "/error").as_str().unwrap().contains("a.toml"));
}

/// Ctrl-C during `run --csv`: the process ends, the log's temporary file is removed and
/// every file that was there is untouched.
#[test]
fn ctrl_c_leaves_no_temporary() {
    let s = sim_dir("ctrl-c");
    s.file("long.toml", "name = \"long\"\nprofile = \"spacecraft\"\nduration_s = 36000\nseed = 1\nsettle_s = 1\n");
    let before = s.snapshot();
    let mut child = std::process::Command::new(SIM)
        .current_dir(&s.dir)
        .args(["run", "long.toml", "--csv", "long.csv"])
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::null())
        .spawn()
        .unwrap();
    let partial = || s.snapshot().into_keys().any(|p| p.to_string_lossy().contains(".partial"));
    let t0 = std::time::Instant::now();
    while !partial() && t0.elapsed().as_secs() < 10 {
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
    assert!(partial(), "no temporary file while the run writes its log");
    let kill = std::process::Command::new("kill").args(["-INT", &child.id().to_string()]).status().unwrap();
    assert!(kill.success());
    let status = child.wait().unwrap();
    println!("run after SIGINT: {status:?}");
    no_temporaries(&s);
    let after = s.snapshot();
    for (p, bytes) in &before {
        assert_eq!(after.get(p), Some(bytes), "{} changed", p.display());
    }
}
