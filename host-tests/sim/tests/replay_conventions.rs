//! A recorded log written in the wrong convention is named before it is replayed
//! (`ssis_sim::conventions`, docs/RECORDED-LOG.md "Conventions"): star-tracker
//! quaternions conjugated or scalar last, FOG columns in degrees or as rates, star-tracker
//! tags written on arrival; for the launch vehicle, accelerometers in g or as rates, FOGs
//! in degrees, GNSS positions in km, two axes swapped. Each variant of the committed
//! Basilisk and launch-vehicle logs is made the way a careless converter would make it;
//! `ssis-sim replay` (and `--check`) exit 1 and name the convention, the clean logs pass,
//! and the logs are byte-identical afterwards.

#[path = "../../tests/hostile_common/mod.rs"]
mod hostile_common;

use std::f64::consts::PI;
use std::path::{Path, PathBuf};

use hostile_common::{has_documented_keys, json_of, run, Scratch};

const EXE: &str = env!("CARGO_BIN_EXE_ssis-sim");

fn example(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../examples/basilisk").join(name)
}

/// A column's index by name.
type Column<'a> = dyn Fn(&str) -> usize + 'a;

/// The committed log with `f` applied to every data row's fields (by column name).
fn variant(f: &dyn Fn(&mut Vec<String>, &Column)) -> String {
    let text = std::fs::read_to_string(example("leo-nadir-280s.csv")).expect("the committed log");
    let lines: Vec<&str> = text.lines().collect();
    let header: Vec<&str> = lines[2].split(',').collect();
    let col = |name: &str| header.iter().position(|h| *h == name).expect("column");
    let mut out: String = lines[..3].iter().map(|l| format!("{l}\n")).collect();
    for l in &lines[3..] {
        let mut v: Vec<String> = l.split(',').map(String::from).collect();
        f(&mut v, &col);
        out.push_str(&v.join(","));
        out.push('\n');
    }
    out
}

fn num(s: &str) -> f64 {
    s.parse().expect("number")
}

/// Star-tracker quaternion columns rewritten by `f` on the rows that carry a solution.
fn star_variant(f: fn([String; 4]) -> [String; 4]) -> String {
    variant(&|v, col| {
        let c = ["st_q0", "st_q1", "st_q2", "st_q3"].map(col);
        if !v[c[0]].is_empty() {
            let q = f(c.map(|i| v[i].clone()));
            for (i, x) in c.iter().zip(q) {
                v[*i] = x;
            }
        }
    })
}

/// Every FOG increment column multiplied by `k`.
fn fog_variant(k: f64) -> String {
    variant(&|v, col| {
        for i in 0..4 {
            let c = col(&format!("fog{i}_dtheta_rad"));
            if !v[c].is_empty() {
                v[c] = format!("{:e}", num(&v[c]) * k);
            }
        }
    })
}

/// `ssis-sim replay [--check] LOG --table T`: exit code and report; the log unchanged.
fn replay(s: &Scratch, log: &Path, check: bool) -> (Option<i32>, String) {
    let before = std::fs::read(log).expect("log");
    let table = example("table.toml");
    let mut args = vec!["replay", log.to_str().unwrap(), "--table", table.to_str().unwrap()];
    if check {
        args.push("--check");
    }
    let r = run(EXE, &s.dir, &args);
    println!("{}{}", r.stdout, r.stderr);
    assert!(!r.stderr.contains("panicked"), "{}", r.stderr);
    assert_eq!(std::fs::read(log).expect("log"), before, "{}: the log was changed", log.display());
    (r.code, r.stdout)
}

fn found(text: &str) -> Vec<&str> {
    text.lines().filter(|l| l.starts_with("FOUND")).collect()
}

#[test]
fn each_wrong_convention_is_named_and_the_clean_log_passes() {
    let s = Scratch::new("conventions");
    let clean = example("leo-nadir-280s.csv");
    let (code, text) = replay(&s, &clean, true);
    assert_eq!(code, Some(0), "{text}");
    assert!(text.contains("no convention found wrong"), "{text}");
    assert!(text.contains("as_logged") && text.contains("<- fits"), "{text}");
    // The time tags are fitted and found right: the line gives the offset and its 1σ.
    let tags = text.lines().find(|l| l.contains("time tags: offset")).expect("a time-tag fit");
    println!("clean log: {tags}");

    let cases: Vec<(&str, String, &[&str])> = vec![
        (
            "conjugate",
            star_variant(|[w, x, y, z]| {
                let neg = |a: String| format!("{:e}", -num(&a));
                [w, neg(x), neg(y), neg(z)]
            }),
            &["star-tracker quaternions read conjugated"],
        ),
        ("scalar-last", star_variant(|[w, x, y, z]| [x, y, z, w]), &["star-tracker quaternions read scalar last"]),
        ("degrees", fog_variant(180.0 / std::f64::consts::PI), &["FOG columns look like degrees"]),
        ("rates", fog_variant(1.0 / 0.005), &["FOG columns look like rates in rad/s"]),
        (
            "tag-on-arrival",
            variant(&|v, col| {
                let (st, t) = (col("st_t_s"), col("t_s"));
                if !v[st].is_empty() {
                    v[st] = v[t].clone();
                }
            }),
            &["star-tracker time tags are", "after the instant"],
        ),
    ];
    for (name, text, must) in &cases {
        let log = s.file(&format!("{name}.csv"), text);
        let (code, out) = replay(&s, &log, true);
        assert_eq!(code, Some(1), "{name}: {out}");
        let f = found(&out);
        assert_eq!(f.len(), 1, "{name}: one finding expected:\n{out}");
        for m in *must {
            assert!(f[0].contains(m), "{name}: the finding lacks `{m}`:\n{out}");
        }
        assert!(out.contains("FOG check not run"), "{name}: {out}");
    }
    // Truth conjugated: named, and the FOG check still runs on the tracker (clean).
    let log = s.file(
        "truth-conjugate.csv",
        variant(&|v, col| {
            for c in ["true_q1", "true_q2", "true_q3"].map(col) {
                if !v[c].is_empty() {
                    v[c] = format!("{:e}", -num(&v[c]));
                }
            }
        }),
    );
    let (code, out) = replay(&s, &log, true);
    assert_eq!(code, Some(1), "{out}");
    let f = found(&out);
    assert_eq!(f.len(), 1, "{out}");
    assert!(f[0].contains("truth quaternions read conjugated"), "{out}");
    assert!(out.contains("clean: every FOG"), "the FOG check runs on the tracker: {out}");
    // A tag written on arrival is found at the log's latency (50 ms), within 3σ.
    let log = s.path("tag-on-arrival.csv");
    let (_, out) = replay(&s, &log, true);
    let line = out.lines().find(|l| l.contains("time tags: offset")).expect("a time-tag fit");
    let fields: Vec<&str> = line.split_whitespace().collect();
    let at = fields.iter().position(|f| *f == "offset").expect("offset") + 1;
    let (off_ms, se_ms) = (num(fields[at]), num(fields[at + 2]));
    println!("tag on arrival: {line}");
    assert!((off_ms + 50.0).abs() <= 3.0 * se_ms.max(1.0), "offset {off_ms} ± {se_ms} ms, the log's latency is 50 ms");
}

#[test]
fn the_replay_json_has_every_documented_key() {
    let s = Scratch::new("conventions-json");
    let log = example("leo-nadir-280s.csv");
    let table = example("table.toml");
    let args = ["replay", log.to_str().unwrap(), "--table", table.to_str().unwrap(), "--json"];
    has_documented_keys(&json_of(EXE, &s, &args, true), "ssis-sim replay");
}

#[test]
fn a_replay_of_a_log_in_the_wrong_convention_exits_1_and_says_so() {
    let s = Scratch::new("conventions-replay");
    let log = s.file("scalar-last.csv", star_variant(|[w, x, y, z]| [x, y, z, w]));
    let (code, out) = replay(&s, &log, false);
    assert_eq!(code, Some(1), "{out}");
    assert!(out.contains("the log breaks a convention"), "{out}");
    assert_eq!(found(&out).len(), 1, "{out}");
}

#[test]
fn a_fog_flipped_from_power_on_leaves_the_conventions_checkable_and_the_replay_names_its_isolation() {
    let s = Scratch::new("conventions-flip");
    let log = s.file(
        "fog4-flipped.csv",
        variant(&|v, col| {
            let c = col("fog3_dtheta_rad");
            v[c] = format!("{:e}", -num(&v[c]));
        }),
    );
    let (code, out) = replay(&s, &log, true);
    assert_eq!(code, Some(1), "{out}");
    // The tracker's conventions are judged on the three FOGs that agree with it.
    assert!(out.contains("against FOG1 FOG2 FOG3 ("), "{out}");
    assert!(out.contains("no convention found wrong"), "{out}");
    let f = found(&out);
    assert_eq!(f.len(), 1, "{out}");
    assert!(f[0].contains("FOG4") && f[0].contains("reversed polarity"), "{out}");
    // The replay: the unit isolates it at power-on and the report says when.
    let (code, out) = replay(&s, &log, false);
    assert_eq!(code, Some(0), "the unit handles it: {out}");
    let line = out.lines().find(|l| l.contains("FOG4 isolated by the fault logic at")).expect("isolation named");
    let t_s = num(line.split(" at ").nth(1).and_then(|r| r.split_whitespace().next()).expect("time"));
    assert!(t_s < 5.0, "FOG4 isolated at {t_s} s: {out}");
    // The unit's event log, as its event frames carried it: the timeline names the
    // mounting check's verdict and the isolation, at the time the evidence gives.
    let timeline: Vec<&str> = out.lines().skip_while(|l| !l.starts_with("events (")).collect();
    let event = |name: &str, detail: &str| {
        timeline.iter().find(|l| l.split_whitespace().nth(2) == Some(name) && l.contains(detail)).map(|l| {
            let t = l.split_whitespace().next().expect("a time");
            num(t)
        })
    };
    let iso_s = event("isolated", "FOG4").unwrap_or_else(|| panic!("no isolation in the timeline: {out}"));
    let verdict_s = event("mount_verdict", "FOG4 reversed").unwrap_or_else(|| panic!("no verdict: {out}"));
    assert!((iso_s - t_s).abs() <= 0.0051, "timeline {iso_s} s, evidence {t_s} s: {out}");
    assert!(verdict_s <= iso_s, "the verdict ({verdict_s} s) comes before the isolation ({iso_s} s): {out}");
    assert!(event("isolated", "FOG1").is_none() && event("parity_alarm", "").is_none(), "{out}");
}

/// The committed launch-vehicle log with `f` applied to every data row (by column name).
fn lv_variant(f: &dyn Fn(&mut Vec<String>, &Column)) -> String {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../examples/lv-ascent/ascent-20s.csv");
    let text = std::fs::read_to_string(path).expect("the committed launch-vehicle log");
    let lines: Vec<&str> = text.lines().collect();
    let at = lines.iter().position(|l| !l.starts_with('#')).expect("header");
    let header: Vec<&str> = lines[at].split(',').collect();
    let col = |name: &str| header.iter().position(|h| *h == name).expect("column");
    let mut out: String = lines[..=at].iter().map(|l| format!("{l}\n")).collect();
    for l in &lines[at + 1..] {
        let mut v: Vec<String> = l.split(',').map(String::from).collect();
        f(&mut v, &col);
        out.push_str(&v.join(","));
        out.push('\n');
    }
    out
}

/// Columns `names` multiplied by `k` where they hold a value.
fn scaled(v: &mut [String], col: &Column, names: &[&str], k: f64) {
    for c in names.iter().map(|n| col(n)) {
        if !v[c].is_empty() {
            v[c] = format!("{:e}", num(&v[c]) * k);
        }
    }
}

#[test]
fn a_launch_vehicle_log_in_the_wrong_units_is_named() {
    let s = Scratch::new("conventions-lv");
    let clean = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../examples/lv-ascent/ascent-20s.csv");
    let (code, out) = replay(&s, &clean, false);
    assert_eq!(code, Some(0), "{out}");
    assert!(out.contains("no convention found wrong"), "{out}");
    const ACC: [&str; 3] = ["acc0_dv_m_s", "acc1_dv_m_s", "acc2_dv_m_s"];
    let cases: Vec<(&str, String, &str)> = vec![
        ("acc-in-g", lv_variant(&|v, c| scaled(v, c, &ACC, 1.0 / 9.806_65)), "accelerometer columns look like g·s"),
        ("acc-rates", lv_variant(&|v, c| scaled(v, c, &ACC, 800.0)), "accelerometer columns look like m/s² rates"),
        (
            "fog-degrees",
            lv_variant(&|v, c| scaled(v, c, &["fog0_dtheta_rad", "fog1_dtheta_rad", "fog2_dtheta_rad"], 180.0 / PI)),
            "FOG columns look like degrees",
        ),
        (
            "gnss-km",
            lv_variant(&|v, c| scaled(v, c, &["gnss_x_m", "gnss_y_m", "gnss_z_m"], 1e-3)),
            "GNSS positions (gnss_x_m …) look like kilometres",
        ),
        (
            "acc-x-y-swapped",
            lv_variant(&|v, c| v.swap(c("acc0_dv_m_s"), c("acc1_dv_m_s"))),
            "no unit of the increments explains it",
        ),
    ];
    for (name, text, must) in &cases {
        let log = s.file(&format!("{name}.csv"), text);
        let (code, out) = replay(&s, &log, false);
        assert_eq!(code, Some(1), "{name}: {out}");
        let f = found(&out);
        assert_eq!(f.len(), 1, "{name}: one finding expected:\n{out}");
        assert!(f[0].contains(must), "{name}: the finding lacks `{must}`:\n{out}");
    }
}
