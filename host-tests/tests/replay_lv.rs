//! Launch-vehicle recorded logs through the launch-vehicle unit's code path on the host
//! (`docs/RECORDED-LOG.md`, `ssis_sim::lv_replay`): the committed example log within the
//! documented GNSS-aided errors; a log written from the scenario replays to the scenario's
//! own output; a capture (with CRC failures) replays like the CSV; logs for the wrong unit
//! are refused with a message naming what is wrong. (`ssis-sim replay` on damaged
//! launch-vehicle logs: `sim/tests/replay_lv_files.rs`; in QEMU: `qemu_replay_lv.rs`.)

mod hostile_common;

use std::path::{Path, PathBuf};

use hostile_common::Scratch;

use ssis::calib::CalibrationTable;
use ssis::frames::accel::AccelFrame;
use ssis::frames::fog::FogFrame;
use ssis::frames::gnss::GnssFrame;
use ssis_sim::lv_replay::{
    pad_for, pad_init, replay_lv, write_log, AscentSensors, LogOptions, LvCore, LvFeed, LvScenario,
};
use ssis_sim::recorded::{self, LogUnit, Recorded};
use ssis_sim::replay::OutputHash;

fn example() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../examples/lv-ascent/ascent-20s.csv")
}

fn scenario() -> LvScenario {
    LvScenario::from_file(&Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios/lv-ascent.toml")).expect("scenario")
}

/// The output hash of a host replay of `rec` from its own initial state.
fn hash_of(rec: &Recorded) -> u64 {
    let init = pad_for(rec, None).expect("initial state");
    replay_lv(rec, &CalibrationTable::DEFAULT, &init, |_, _| {}).expect("replays").hash
}

#[test]
fn committed_log_replays_within_the_documented_aided_errors() {
    let rec = recorded::read_log(&[example()]).expect("reads");
    assert_eq!(rec.unit, LogUnit::LaunchVehicle);
    assert!(rec.problems.is_clean(), "the committed log is clean:\n{}", rec.problems.report());
    let init = pad_for(&rec, None).expect("the log's initial state");
    let s = replay_lv(&rec, &CalibrationTable::DEFAULT, &init, |_, _| {}).expect("replays");
    println!("{}", s.report(&rec));
    let e = &s.evidence;
    assert_eq!((s.steps, s.flight_frames, e.frames), (16_000, 16_000, 16_000));
    assert_eq!(e.scored, 200, "truth every 0.1 s");
    // docs/LAUNCH-VEHICLE.md, GNSS-aided (1 Hz, 5 m and 0.1 m/s), FOGs and
    // accelerometers: RMS over 10 draws at 60 s, its first tabulated time, 1.16 m,
    // 0.042 m/s and 20.9″; the aided errors settle within seconds and the attitude error
    // grows with time, so over these 20 s one draw stays within 3× those.
    let (pos_rms_m, vel_rms_m_s, att_rms_arcsec) = (1.16, 0.042, 20.9);
    let max = e.max;
    let end = e.end.expect("truth at the end");
    println!(
        "max {:.3} m {:.4} m/s {:.2}″; at 20 s {:.3} m {:.4} m/s {:.2}″; bounds {:.2} m {:.3} m/s {:.1}″",
        max.pos_m,
        max.vel_m_s,
        max.att_arcsec,
        end.pos_m,
        end.vel_m_s,
        end.att_arcsec,
        3.0 * pos_rms_m,
        3.0 * vel_rms_m_s,
        3.0 * att_rms_arcsec
    );
    assert!(max.pos_m <= 3.0 * pos_rms_m, "position error {:.3} m", max.pos_m);
    assert!(max.vel_m_s <= 3.0 * vel_rms_m_s, "velocity error {:.4} m/s", max.vel_m_s);
    assert!(max.att_arcsec <= 3.0 * att_rms_arcsec, "attitude error {:.2}″", max.att_arcsec);
    // The unit's own figures agree: the end errors within 3× the filter's 1σ, every fix
    // used (the 20 s one after the last frame), innovations of the receiver's 5 m.
    let last = e.last.expect("frames");
    let sigma_pos_m = f64::from(last.sigma_pos_counts) * 0.01;
    let sigma_vel_m_s = f64::from(last.sigma_vel_counts) * 0.001;
    assert!(
        end.pos_m <= 3.0 * sigma_pos_m && end.vel_m_s <= 3.0 * sigma_vel_m_s,
        "{end:?} against 1σ {sigma_pos_m} m, {sigma_vel_m_s} m/s"
    );
    assert_eq!((last.fixes_used, last.fixes_refused), (19, 0));
    assert_eq!(e.innov_pos_m.count(), 20);
    assert!(e.innov_pos_m.std().iter().all(|s| *s > 2.0 && *s < 10.0), "{:?}", e.innov_pos_m.std());
    assert_eq!((e.accel_fault_steps, e.nav_fault_steps), (0, 0));
}

#[test]
fn a_log_written_from_the_scenario_replays_to_the_scenarios_own_output() {
    let d = Scratch::new("replay-lv-written");
    let sc = scenario();
    let steps = 2_400; // 3 s: three fixes
    let mut bytes = Vec::new();
    write_log(&sc, LogOptions { steps, truth_every: 1, full: true }, &mut bytes).expect("written");
    let log = d.file("ascent-3s.csv", &bytes);
    let rec = recorded::read_log(&[log]).expect("reads");
    assert!(rec.problems.is_clean(), "{}", rec.problems.report());
    // The scenario itself, through the same unit.
    let mut sensors = AscentSensors::new(&sc);
    let mut unit = LvCore::new(&CalibrationTable::DEFAULT, &pad_init(sensors.initial())).expect("unit");
    let mut h = OutputHash::default();
    for n in 1..=steps {
        let p = unit.period(&sensors.step(n));
        h.write(&p.flight);
        h.write(&p.nav);
    }
    assert_eq!(hash_of(&rec), h.value(), "the log and the scenario give different output frames");
}

#[test]
fn a_capture_with_crc_failures_replays_like_the_csv() {
    let d = Scratch::new("replay-lv-capture");
    let mut rec = recorded::read_log(&[example()]).expect("reads");
    rec.steps.truncate(4_000); // 5 s: five fixes
                               // The links logged apart, and all merged by a logger in arrival order.
    let (mut fog, mut acc, mut gnss, mut merged) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
    let mut feed = LvFeed::new(&rec);
    while let Some(b) = feed.next_step() {
        fog.extend_from_slice(&b.fog);
        acc.extend_from_slice(&b.accel);
        gnss.extend_from_slice(&b.gnss);
        merged.extend(b.fog.iter().chain(&b.accel).chain(&b.gnss));
    }
    assert_eq!(gnss.len(), 5 * GnssFrame::LEN, "fixes at 1 … 5 s");
    let init = pad_for(&rec, None).expect("the CSV's initial state");
    let replay = |paths: &[PathBuf]| {
        let mut cap = recorded::read_log(paths).expect("reads");
        assert_eq!(cap.unit, LogUnit::LaunchVehicle);
        assert!(cap.init.is_none(), "a capture carries no initial state");
        assert!(pad_for(&cap, None).is_err_and(|e| e.to_string().contains("--pad")));
        cap.init = Some(init.state);
        cap
    };
    let merged = replay(&[d.file("merged.bin", &merged)]);
    assert!(merged.problems.is_clean(), "{}", merged.problems.report());
    assert_eq!(hash_of(&merged), hash_of(&rec), "capture and CSV give different outputs");
    // One bit flipped in every 101st FOG frame, the 7th accelerometer frame and the 2nd
    // GNSS frame; a GNSS frame repeated (its tag does not advance).
    let mut fog_bad = fog.clone();
    let mut flipped = 0u64;
    for k in (0..fog_bad.len() / FogFrame::LEN).step_by(101) {
        fog_bad[k * FogFrame::LEN + 9] ^= 0x04;
        flipped += 1;
    }
    let mut acc_bad = acc.clone();
    acc_bad[6 * AccelFrame::LEN + 8] ^= 0x80;
    let mut gnss_bad = gnss.clone();
    gnss_bad[GnssFrame::LEN + 20] ^= 0x01;
    gnss_bad.extend_from_slice(&gnss[2 * GnssFrame::LEN..3 * GnssFrame::LEN]);
    let files = [d.file("fog.bin", &fog_bad), d.file("acc.bin", &acc_bad), d.file("gnss.bin", &gnss_bad)];
    let before: Vec<Vec<u8>> = files.iter().map(|p| std::fs::read(p).expect("read")).collect();
    let bad = replay(&files);
    println!("{}", bad.problems.report());
    assert_eq!(bad.problems.crc_failures.count, flipped + 2);
    assert_eq!(bad.problems.gnss_time_backward.count, 1);
    assert_eq!(bad.fog_samples() as u64 + flipped, 3 * 4_000);
    let s = replay_lv(&bad, &CalibrationTable::DEFAULT, &init, |_, _| {}).expect("replays");
    println!("{}", s.report(&bad));
    // The unit holds the lost accelerometer sample for its step; the lost fix is not used
    // (of five, the 5 s one is applied after the last frame).
    assert_eq!(s.evidence.accel_fault_steps, 1);
    assert_eq!(s.evidence.last.map(|f| f.fixes_used), Some(3));
    let after: Vec<Vec<u8>> = files.iter().map(|p| std::fs::read(p).expect("read")).collect();
    assert_eq!(before, after, "the captures changed");
}

#[test]
fn logs_for_the_wrong_unit_are_refused_naming_what_is_wrong() {
    let d = Scratch::new("replay-lv-wrong-unit");
    // The committed spacecraft log with its time compressed to 1.25 ms.
    let sc_log =
        std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("../examples/basilisk/leo-nadir-280s.csv"))
            .expect("the spacecraft log");
    let mut lines: Vec<String> = sc_log.lines().take(1_003).map(String::from).collect();
    for l in lines.iter_mut().skip(3) {
        let (t, rest) = l.split_once(',').expect("t_s first");
        *l = format!("{},{rest}", t.parse::<f64>().expect("t_s") / 4.0);
    }
    let fast = d.file("spacecraft-at-1.25ms.csv", lines.join("\n") + "\n");
    let e = recorded::read_log(&[fast]).expect_err("refused").to_string();
    println!("{e}");
    assert!(e.contains("1.2500 ms apart") && e.contains("launch-vehicle") && e.contains("acc0_dv_m_s"), "{e}");
    // The launch-vehicle log without its accelerometer columns.
    let text = std::fs::read_to_string(example()).expect("the log");
    let header = text.lines().nth(2).expect("header");
    let keep: Vec<usize> =
        header.split(',').enumerate().filter(|(_, h)| !h.starts_with("acc")).map(|(i, _)| i).collect();
    let cut: String = text
        .lines()
        .take(1_003)
        .map(|l| {
            if l.starts_with('#') {
                return format!("{l}\n");
            }
            let v: Vec<&str> = l.split(',').collect();
            keep.iter().map(|&i| v[i]).collect::<Vec<_>>().join(",") + "\n"
        })
        .collect();
    let no_acc = d.file("no-accelerometers.csv", cut);
    let e = recorded::read_log(&[no_acc]).expect_err("refused").to_string();
    println!("{e}");
    assert!(e.contains("no-accelerometers.csv: line 3") && e.contains("no accelerometer column"), "{e}");
    // A launch-vehicle log given to the spacecraft unit's reader.
    let e = recorded::read(&[example()], ssis::flight::Profile::SPACECRAFT.dt_us).expect_err("refused").to_string();
    assert!(e.contains("launch-vehicle log") && e.contains("spacecraft unit only"), "{e}");
}
