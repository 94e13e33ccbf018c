//! The launch-vehicle firmware (`ssis-fw-lv`) in QEMU at its 1.25 ms
//! step, fed by the ascent simulator over five emulated UARTs in lockstep with the
//! instruction counter on (`-icount shift=0`). A shortened ascent (12 s, GNSS outage
//! 5–8 s) so CI stays fast; the full 600 s run is the benchmark (`BENCHMARKS.md`).
//! Needs `qemu-system-arm`; builds the firmware.

use std::path::Path;

use ssis_runner::qemu_lv::{build_firmware, run_qemu_lv, LvOptions, LvScenario};

#[test]
fn lv_firmware_keeps_1_25_ms_and_matches_the_host_replay() {
    let elf = build_firmware().expect("ssis-fw-lv builds");
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios/lv-ascent.toml");
    let mut sc = LvScenario::from_file(&path).expect("scenario");
    sc.duration_s = 12.0;
    if let Some(g) = sc.gnss.as_mut() {
        g.outages_s = vec![[5.0, 8.0]];
    }
    let s = run_qemu_lv(&sc, &LvOptions { elf, progress: false }).expect("QEMU run");
    println!("{}", s.report());
    assert_eq!(s.exit_code, Some(0), "firmware did not end cleanly");
    assert_eq!(s.steps, 9_600);
    // One flight and one navigation frame per step, each bit-identical to the replay's.
    assert_eq!(s.flight_frames, s.steps);
    assert_eq!(s.nav_frames, s.steps);
    assert_eq!(s.bad_bytes, 0);
    assert_eq!((s.flight_equal, s.flight_differing), (s.steps, 0), "flight output frames differ");
    assert_eq!((s.nav_equal, s.nav_differing), (s.steps, 0), "navigation output frames differ");
    // Zero overruns (the unit's counter), and the worst period (step + filter work), in
    // counted instructions, inside the 1.25 ms period (31,250 SysTick ticks).
    assert_eq!(s.overruns, 0);
    assert_eq!(s.period_ticks_budget, 31_250);
    let worst = s.period_ticks.iter().map(|t| t.max).max().unwrap_or(0);
    assert!(worst > 0 && worst < s.period_ticks_budget, "worst period {worst} ticks");
    // The heavy work happened and was measured: covariance propagations every 80 steps
    // (those carrying a GNSS update propagate inside it), GNSS updates at 1 Hz outside
    // the outage; the last period's figures come only in the END report.
    let [none, prop, upd] = s.period_ticks;
    assert!(none.n > 9_000 && prop.n >= 100 && upd.n >= 8, "{:?}", s.period_ticks);
    // A covariance propagation adds some 50,000 instructions (1,300 ticks) to its period;
    // a step alone is about 6,000 (150 ticks).
    assert!(prop.mean() > none.mean() + 1_000.0 && upd.mean() > prop.mean(), "{:?}", s.period_ticks);
    // The firmware's own report: the step alone stays flat when the filter works.
    let fw = s.firmware_times.map(|t| t.expect("END report of every kind"));
    assert_eq!(fw.iter().map(|t| t.periods).sum::<u64>(), s.steps);
    assert!(fw[1].step_max <= fw[0].step_max + 10, "step with a propagation after it: {:?}", fw);
    assert!(s.log.iter().any(|l| l == "watchdog_warnings 0"), "{:?}", s.log);
    assert!(s.log.iter().any(|l| l.contains(" overruns 0 ") && l.contains("rx_overflows 0")), "{:?}", s.log);
    // Fixes: 12 at 1 Hz less the three in the outage (5, 6, 7 s), all used.
    assert_eq!(s.fixes, (8, 0), "the 12 s fix's update follows the last frame");
    assert!(s.log.iter().any(|l| l.contains("fixes_used 9 fixes_refused 0")), "{:?}", s.log);
    // Aided navigation against truth (ideal sensors would be millimetres; these carry
    // the paper's FOG and the assumed accelerometer errors and 5 m GNSS noise).
    assert!(s.max_err.0 < 10.0 && s.max_err.1 < 0.2, "navigation error {:?}", s.max_err);
}
