//! A launch-vehicle recorded log on `ssis-fw-lv` in QEMU (`ssis-qemu --replay`,
//! docs/RECORDED-LOG.md): the first 10 s of the committed example streamed in lockstep at
//! 1.25 ms, every flight and navigation output frame bit-identical to the host's replay of
//! the same bytes, and the firmware's navigation frames judged like the host's. Needs
//! `qemu-system-arm`; builds the firmware.

use std::path::Path;

use ssis::calib::CalibrationTable;
use ssis::flight::Profile;
use ssis_runner::qemu_lv::{build_firmware, run_lv, LvOptions, LvRun};
use ssis_sim::lv_replay::{pad_for, replay_lv, LvFeed, NavEvidence};
use ssis_sim::recorded;

/// Simulated seconds streamed (the whole log replays on the host in `replay_lv.rs`).
const DURATION_S: f64 = 10.0;

#[test]
fn committed_lv_log_on_the_firmware_matches_the_host_replay() {
    let elf = build_firmware().expect("ssis-fw-lv builds");
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../examples/lv-ascent/ascent-20s.csv");
    let mut rec = recorded::read_log(&[path]).expect("reads");
    let steps = (DURATION_S / Profile::LAUNCH_VEHICLE.dt_s()).round() as u64;
    rec.steps.truncate(steps as usize);
    let init = pad_for(&rec, None).expect("initial state");
    let table = CalibrationTable::DEFAULT;
    let mut feed = LvFeed::new(&rec);
    let run = LvRun { name: "ascent-20s".into(), steps, table, init, next: Box::new(move |_| feed.next_step()) };
    let mut fw = NavEvidence::new(&rec);
    let s = run_lv(run, &LvOptions { elf, progress: false }, |f| {
        fw.frame(f);
    })
    .expect("QEMU run");
    println!("{}", s.report());
    assert_eq!(s.exit_code, Some(0), "firmware did not end cleanly");
    assert_eq!(s.steps, 8_000);
    assert_eq!((s.flight_equal, s.flight_differing), (s.steps, 0), "flight output frames differ");
    assert_eq!((s.nav_equal, s.nav_differing), (s.steps, 0), "navigation output frames differ");
    assert!(s.clean(), "{}", s.report());
    // The same report from the firmware's frames as from the host's.
    let host = replay_lv(&rec, &table, &init, |_, _| {}).expect("host replay");
    println!("{}", host.report(&rec));
    let h = &host.evidence;
    assert_eq!((fw.frames, fw.scored), (h.frames, h.scored));
    assert_eq!(fw.end, h.end);
    assert_eq!(fw.max, h.max);
    assert_eq!(fw.at_times, h.at_times);
    assert_eq!(fw.last, h.last);
    assert_eq!(fw.innov_pos_m.max_abs(), h.innov_pos_m.max_abs());
    println!(
        "firmware and host: {} navigation frames, at 10 s {:.3} m, {:.4} m/s, {:.2}″",
        fw.frames,
        fw.end.map_or(0.0, |e| e.pos_m),
        fw.end.map_or(0.0, |e| e.vel_m_s),
        fw.end.map_or(0.0, |e| e.att_arcsec)
    );
}
