//! `ssis-faults --out` over an existing document: refused before the campaign runs.

#[path = "../../tests/hostile_common/mod.rs"]
mod hostile;
use hostile::*;

const FAULTS: &str = env!("CARGO_BIN_EXE_ssis-faults");

#[test]
fn out_over_an_existing_file_needs_force() {
    let s = Scratch::new("faults-out");
    s.file("campaign.md", "# my notes\n");
    refused(FAULTS, &s, &["--seeds", "1", "--out", "campaign.md"], &["campaign.md", "exists", "--force"]);
    std::fs::create_dir_all(s.path("d")).unwrap();
    refused(FAULTS, &s, &["--seeds", "1", "--out", "d"], &["d", "directory"]);
}

const UPSET: &str = env!("CARGO_BIN_EXE_ssis-upset");

#[test]
fn upset_out_over_an_existing_file_needs_force_and_a_bad_scenario_is_named() {
    let s = Scratch::new("upset-out");
    s.file("campaign.md", "# my notes\n");
    refused(UPSET, &s, &["--flips", "1", "--out", "campaign.md"], &["campaign.md", "exists", "--force"]);
    s.file("bad.toml", "name = 3\n");
    refused(UPSET, &s, &["--flips", "1", "--scenario", "bad.toml"], &["bad.toml"]);
}

#[test]
fn upset_json_carries_every_flip_with_its_field() {
    let s = Scratch::new("upset-json");
    let r = succeeds(UPSET, &s, &["--flips", "3", "--seed", "5", "--json"], &[]);
    let j: serde_json::Value = serde_json::from_str(&r.stdout).expect("one JSON object");
    assert_eq!(j["ok"], true, "{j}");
    let counts: u64 = ["masked", "tolerated", "detected_recovered", "detected_not_recovered", "silent", "crash"]
        .iter()
        .map(|k| j["counts"][k].as_u64().expect(k))
        .sum();
    assert_eq!(counts, 3, "{j}");
    let v = j["verdicts"].as_array().expect("verdicts");
    assert_eq!(v.len(), 3);
    for x in v {
        assert!(x["field"].is_string() && x["flip"]["byte"].is_u64() && x["flip_t_s"].is_f64(), "{x}");
        assert!(j["counts"].get(x["outcome"].as_str().expect("outcome")).is_some(), "{x}");
    }
}
