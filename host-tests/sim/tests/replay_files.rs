//! `ssis-sim replay` on recorded logs (`docs/RECORDED-LOG.md`): `--check` names a FOG
//! whose sign is flipped and two FOGs whose channels are swapped and passes the clean
//! log; each kind of damage is counted and reported, and the log is byte-identical
//! afterwards.

#[path = "../../tests/hostile_common/mod.rs"]
mod hostile_common;

use std::path::{Path, PathBuf};

use hostile_common::{damage_time, refused, run, succeeds, Scratch};

const EXE: &str = env!("CARGO_BIN_EXE_ssis-sim");

fn example(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../examples/basilisk").join(name)
}

/// The committed log's lines (two comments, the header, the rows).
fn log_lines() -> Vec<String> {
    std::fs::read_to_string(example("leo-nadir-280s.csv"))
        .expect("the committed log")
        .lines()
        .map(String::from)
        .collect()
}

fn join(lines: &[String]) -> String {
    lines.iter().map(|l| format!("{l}\n")).collect()
}

/// `ssis-sim replay --check`: exit code and report.
fn check(s: &Scratch, log: &Path) -> (Option<i32>, String) {
    let table = example("table.toml");
    let r = run(EXE, &s.dir, &["replay", "--check", log.to_str().unwrap(), "--table", table.to_str().unwrap()]);
    println!("{}{}", r.stdout, r.stderr);
    assert!(!r.stderr.contains("panicked"), "{}", r.stderr);
    (r.code, r.stdout)
}

#[test]
fn check_names_a_flipped_and_two_swapped_fogs_and_passes_the_clean_log() {
    let d = Scratch::new("check");
    let lines = log_lines();
    let header: Vec<&str> = lines[2].split(',').collect();
    let col = |name: &str| header.iter().position(|h| *h == name).expect("column");
    let edit = |f: &dyn Fn(&mut Vec<String>)| {
        let mut out = lines[..3].to_vec();
        for l in &lines[3..] {
            let mut v: Vec<String> = l.split(',').map(String::from).collect();
            f(&mut v);
            out.push(v.join(","));
        }
        join(&out)
    };
    let clean = d.file("clean.csv", join(&lines));
    let (dz, d0, d1) = (col("fog2_dtheta_rad"), col("fog0_dtheta_rad"), col("fog1_dtheta_rad"));
    let flipped = d.file(
        "flipped.csv",
        edit(&|v| {
            v[dz] = format!("{:e}", -v[dz].parse::<f64>().expect("number"));
        }),
    );
    let swapped = d.file("swapped.csv", edit(&|v| v.swap(d0, d1)));

    let (code, text) = check(&d, &clean);
    assert_eq!(code, Some(0), "clean log: {text}");
    assert!(text.contains("clean: every FOG"), "{text}");
    assert!(!text.contains("FOUND"), "{text}");

    let (code, text) = check(&d, &flipped);
    assert_eq!(code, Some(1), "{text}");
    let found: Vec<&str> = text.lines().filter(|l| l.starts_with("FOUND")).collect();
    assert_eq!(found.len(), 1, "{text}");
    assert!(found[0].contains("FOG3") && found[0].contains("reversed polarity"), "{text}");

    let (code, text) = check(&d, &swapped);
    assert_eq!(code, Some(1), "{text}");
    let found: Vec<&str> = text.lines().filter(|l| l.starts_with("FOUND")).collect();
    assert_eq!(found.len(), 2, "{text}");
    assert!(found[0].contains("FOG1") && found[0].contains("carries FOG2's axis"), "{text}");
    assert!(found[1].contains("FOG2") && found[1].contains("carries FOG1's axis"), "{text}");
}

/// Runs the replay on a damaged log with a CSV output: status 0, the damage named with its
/// count, the log byte-identical afterwards.
fn damaged(case: &str, log: String, must: &[&str]) {
    let s = Scratch::new(&format!("replay-{case}"));
    s.file("damaged.csv", log);
    let r = succeeds(EXE, &s, &["replay", "damaged.csv", "--settle", "5", "--csv", "out.csv"], &["out.csv"]);
    println!("{case}:\n{}", r.stdout);
    for m in must {
        assert!(r.stdout.contains(m), "{case}: the report lacks `{m}`:\n{}", r.stdout);
    }
    assert!(s.path("out.csv").exists(), "{case}: no CSV written");
}

/// The first `rows` data rows of the committed log, with the comments and header.
fn short_log(rows: usize) -> Vec<String> {
    log_lines().into_iter().take(3 + rows).collect()
}

#[test]
fn each_kind_of_damage_is_counted_and_reported_and_the_log_kept() {
    let base = short_log(2000);
    let hdr = 3;
    // A line cut short in the middle, and a last line without its end.
    let mut l = base.clone();
    l[hdr + 100] = l[hdr + 100][..40].to_string();
    let mut text = join(&l);
    text.truncate(text.len() - 30);
    damaged("truncated", text, &["truncated_lines: 2", "damaged.csv:104:", "last line without its line end"]);
    // A value that is not a number.
    let mut l = base.clone();
    l[hdr + 10] = l[hdr + 10].replacen(",65", ",6x5", 1);
    damaged("bad-value", join(&l), &["bad_values: 1", "damaged.csv:14: field fog0_counter"]);
    // A repeated row, a row out of order (one sample goes backward), a gap of 10 samples.
    let mut l = base.clone();
    damage_time(&mut l, hdr);
    damaged("time", join(&l), &["repeated_samples: 1", "backward_samples: 1", "gap_samples_missing: 11"]);
    // A counter that repeats while the time advances.
    let mut l = base.clone();
    let c0: Vec<String> = l[hdr + 20].split(',').map(String::from).collect();
    let mut c1: Vec<String> = l[hdr + 21].split(',').map(String::from).collect();
    c1[2] = c0[2].clone();
    l[hdr + 21] = c1.join(",");
    damaged("counter", join(&l), &["counter_jumps: 2"]);
    // A star-tracker tag that goes back.
    let mut l = base.clone();
    let st = l[2].split(',').position(|h| h == "st_t_s").expect("st_t_s column");
    let rows: Vec<usize> = (hdr..l.len()).filter(|&i| l[i].split(',').nth(st).is_some_and(|f| !f.is_empty())).collect();
    let first_tag = l[rows[0]].split(',').nth(st).unwrap().to_string();
    let mut v: Vec<String> = l[rows[3]].split(',').map(String::from).collect();
    v[st] = first_tag;
    l[rows[3]] = v.join(",");
    damaged("st-time", join(&l), &["st_time_tags_repeated_or_backward: 1"]);
    // Nothing usable: refused with a plain message, the log kept.
    let s = Scratch::new("replay-empty");
    s.file("header-only.csv", join(&base[..3]));
    refused(EXE, &s, &["replay", "header-only.csv"], &["header-only.csv", "nothing usable"]);
    // An output onto the log is refused before anything runs.
    let s = Scratch::new("replay-onto");
    s.file("log.csv", join(&base));
    refused(EXE, &s, &["replay", "log.csv", "--csv", "log.csv"], &["log.csv"]);
}
