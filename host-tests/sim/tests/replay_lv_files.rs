//! `ssis-sim replay` and `ssis-sim record` on launch-vehicle logs (`docs/RECORDED-LOG.md`):
//! each kind of damage is counted and reported on its own, the log byte-identical
//! afterwards; logs for the wrong unit, and logs without an initial state, are refused
//! with a message naming the file and what is wrong.

#[path = "../../tests/hostile_common/mod.rs"]
mod hostile_common;

use std::path::{Path, PathBuf};

use hostile_common::{damage_time, has_documented_keys, json_of, refused, succeeds, Scratch};
use ssis::frames::accel::AccelFrame;
use ssis::frames::fog::FogFrame;
use ssis_sim::lv_replay::{pad_for, LvFeed};
use ssis_sim::recorded;

const EXE: &str = env!("CARGO_BIN_EXE_ssis-sim");

fn example() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../examples/lv-ascent/ascent-20s.csv")
}

/// The committed log's first `rows` data rows, with its two comments and header.
fn short_log(rows: usize) -> Vec<String> {
    std::fs::read_to_string(example()).expect("the committed log").lines().take(3 + rows).map(String::from).collect()
}

fn join(lines: &[String]) -> String {
    lines.iter().map(|l| format!("{l}\n")).collect()
}

/// The index of column `name` in the header.
fn col(lines: &[String], name: &str) -> usize {
    lines[2].split(',').position(|h| h == name).unwrap_or_else(|| panic!("no column {name}"))
}

/// Row `i` with field `c` set to `v`.
fn set(lines: &mut [String], i: usize, c: usize, v: &str) {
    let mut f: Vec<String> = lines[i].split(',').map(String::from).collect();
    f[c] = v.to_string();
    lines[i] = f.join(",");
}

/// Runs the replay on a damaged log with CSV and plot outputs: status 0, the damage named
/// with its count and only that kind, the log byte-identical afterwards.
fn damaged(case: &str, log: String, must: &[&str]) {
    let s = Scratch::new(&format!("replay-lv-{case}"));
    s.file("damaged.csv", log);
    let r = succeeds(
        EXE,
        &s,
        &["replay", "damaged.csv", "--csv", "out.csv", "--plot", "out.svg", "--every", "1"],
        &["out.csv", "out.svg"],
    );
    println!("{case}:\n{}", r.stdout);
    for m in must {
        assert!(r.stdout.contains(m), "{case}: the report lacks `{m}`:\n{}", r.stdout);
    }
    let kinds = r.stdout.lines().skip_while(|l| !l.starts_with("damage in the log")).skip(1);
    let found: Vec<&str> = kinds.take_while(|l| l.starts_with("  ")).collect();
    assert_eq!(
        found.len(),
        must.iter().filter(|m| m.contains(": ") && !m.contains(".csv")).count(),
        "{case}: {found:?}"
    );
    assert!(s.path("out.csv").exists() && s.path("out.svg").exists(), "{case}: outputs not written");
}

#[test]
fn each_kind_of_damage_on_a_launch_vehicle_log_is_counted_and_the_log_kept() {
    let base = short_log(4_000); // 5 s: fixes at 1 … 5 s
    let hdr = 3;
    // A line cut short in the middle (its sample then missing: a gap of one), and a last
    // line without its end.
    let mut l = base.clone();
    l[hdr + 100] = l[hdr + 100][..30].to_string();
    let mut text = join(&l);
    text.truncate(text.len() - 20);
    damaged(
        "truncated",
        text,
        &["truncated_lines: 2", "damaged.csv:104:", "last line without its line end", "gap_samples_missing: 1"],
    );
    // An accelerometer value that is not a number.
    let mut l = base.clone();
    set(&mut l, hdr + 10, col(&base, "acc1_dv_m_s"), "0.02x");
    damaged("bad-value", join(&l), &["bad_values: 1", "damaged.csv:14: field acc1_dv_m_s"]);
    // A repeated row, a row out of order (one sample goes backward), a gap of 10 samples.
    let mut l = base.clone();
    damage_time(&mut l, hdr);
    damaged("time", join(&l), &["repeated_samples: 1", "backward_samples: 1", "gap_samples_missing: 11"]);
    // A GNSS fix tag that goes back (the 3 s fix tagged 1.5 s).
    let mut l = base.clone();
    let g = col(&base, "gnss_t_s");
    set(&mut l, hdr + 2_399, g, "1.5");
    damaged("gnss-time", join(&l), &["gnss_time_tags_repeated_or_backward: 1", "damaged.csv:2403: gnss_t_s = 1.5 s"]);
}

#[test]
fn launch_vehicle_captures_count_crc_failures_and_need_a_pad_block() {
    let s = Scratch::new("replay-lv-capture");
    // The first 2 s of the committed log as one merged capture, every 50th frame with a
    // bit flipped.
    let mut rec = recorded::read_log(&[example()]).expect("reads");
    rec.steps.truncate(1_600);
    let pad = pad_for(&rec, None).expect("the log's initial state");
    let mut feed = LvFeed::new(&rec);
    let mut frames: Vec<Vec<u8>> = Vec::new();
    while let Some(b) = feed.next_step() {
        frames.extend(b.fog.chunks(FogFrame::LEN).map(<[u8]>::to_vec));
        frames.extend(b.accel.chunks(AccelFrame::LEN).map(<[u8]>::to_vec));
        if !b.gnss.is_empty() {
            frames.push(b.gnss);
        }
    }
    let mut flipped = 0;
    for f in frames.iter_mut().step_by(50) {
        f[5] ^= 0x20;
        flipped += 1;
    }
    s.file("links.bin", frames.concat());
    // No initial state in a capture: refused, naming --pad; with the pad block it replays.
    refused(EXE, &s, &["replay", "links.bin"], &["links.bin", "no initial state", "--pad"]);
    s.file("pad.bin", pad.to_bytes());
    let r = succeeds(EXE, &s, &["replay", "links.bin", "--pad", "pad.bin"], &[]);
    println!("{}", r.stdout);
    assert!(r.stdout.contains(&format!("frames_failing_crc: {flipped}")), "{}", r.stdout);
    assert!(r.stdout.contains("1600 navigation output frames"), "{}", r.stdout);
    // --check is the spacecraft unit's; a pad file that is not one is named.
    s.file("log.csv", std::fs::read(example()).expect("log"));
    refused(EXE, &s, &["replay", "--check", "log.csv"], &["log.csv", "launch-vehicle log"]);
    has_documented_keys(&json_of(EXE, &s, &["replay", "log.csv", "--json"], true), "ssis-sim replay LV-LOG");
    refused(EXE, &s, &["replay", "links.bin", "--pad", "log.csv"], &["log.csv", "not a pad initialisation block"]);
}

#[test]
fn record_writes_a_full_log_and_refuses_what_it_cannot_write() {
    let d = Scratch::new("replay-lv-record");
    let v = json_of(EXE, &d, &["record", &scenario(), "ascent.csv", "--duration", "0.5", "--json"], true);
    has_documented_keys(&v, "ssis-sim record");
    let text = std::fs::read_to_string(d.path("ascent.csv")).expect("written");
    assert!(text.lines().nth(2).is_some_and(|h| h.contains("acc2_t_degc") && h.contains("init_vz_m_s")), "full header");
    assert_eq!(text.lines().count(), 3 + 400);
    let sc = Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenarios/earth-pointing-2h.toml");
    refused(EXE, &d, &["record", sc.to_str().unwrap(), "x.csv"], &["earth-pointing-2h.toml", "launch-vehicle logs"]);
    refused(EXE, &d, &["record", &scenario(), "ascent.csv"], &["ascent.csv"]);
}

fn scenario() -> String {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenarios/lv-ascent.toml").display().to_string()
}
