//! The upset campaign on the firmware in QEMU (`ssis_runner::upset`, `ssis-qemu-upset`):
//! a small sample of every population (the state, double-bit patterns, device and system
//! registers, the snapshot before a reset, the receive interrupt, the snapshot write) in
//! `ssis-fw-test` through QEMU's gdbstub at random instructions after convergence, each
//! classed against truth and the in-process core's undisturbed frames. The full campaign
//! and its figures are in docs/UPSET-CAMPAIGN-QEMU.md; this checks the machinery: the
//! step's code is found, every flip lands where its population says, and none is silent.

use std::path::Path;

use ssis_runner::qemu::build_firmware;
use ssis_runner::upset::{run_campaign_mix, step_code, Mix, Outcome, UpsetOptions};
use ssis_sim::scenario::Scenario;

#[test]
fn upset_sample_in_qemu() {
    let elf = build_firmware().expect("firmware");
    let code = step_code(&elf).expect("step code");
    assert!(code.ranges.iter().any(|r| (r.0..r.1).contains(&code.entry)), "{code:?}");
    assert!(code.caller.0 <= code.entry && code.entry < code.caller.1, "{code:?}");

    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios/qemu-flight.toml");
    let mut sc = Scenario::from_file(&path).expect("scenario");
    sc.duration_s = 15.0;
    let o = UpsetOptions { quiet_s: 0.25, window_s: 1.0, gap_s: 0.25, ..UpsetOptions::new(elf, 8, 3) };
    let c = run_campaign_mix(&sc, &o, &Mix::all(), |f| {
        eprintln!(
            "{} at step {}: {} -> {} {:?}",
            f.population.name(),
            f.step,
            f.target.describe(),
            f.outcome.name(),
            f.events
        )
    })
    .expect("campaign");
    assert_eq!(c.flips.len(), 8);
    // None of the sample's flips is silent, and no unit stopped without a reset (a
    // reset not back within the bound in this short window is a crash of the table,
    // not a unit stopped for good; docs/UPSET-CAMPAIGN-QEMU.md).
    assert_eq!(c.silent(), 0, "{}", c.report());
    for f in &c.flips {
        if let Outcome::Crash(why) = &f.outcome {
            assert!(f.reset_cause.is_some(), "a crash without a reset: {why} ({f:?})");
        }
    }
    // Every flip was placed: no flight failed in the runner.
    assert_eq!(c.failed_flights, 0, "{}", c.report());
    for f in &c.flips {
        assert!(f.step >= 2400 && f.step as f64 * 0.005 <= 15.0, "{f:?}");
        let longest = c.path_lens.iter().map(|(_, l)| *l).max().unwrap_or(0);
        assert!((f.instr as usize) < longest, "{f:?}");
        assert_eq!(c.out_of_reach(f), None);
    }
    let doc = c.document("ssis-qemu-upset --flips 6");
    assert!(doc.contains("| masked | ") && doc.contains("| silent | ") && doc.contains("| population |"), "{doc}");
}
