//! A reset of the firmware in QEMU resumed from its snapshot, with each
//! estimator: `ssis-fw-test` flies the two-minute QEMU scenario in lockstep, is reset
//! (QEMU's `system_reset`, what its SYSRESETREQ does) at a random instruction of the pass
//! at [`RESET_S`] (anywhere from the step's entry to the loop's `wfi`, after the outputs
//! went out too), after convergence, and the runner follows it back into lockstep
//! (`ssis_runner::upset`, the unit down for `RESET_DOWN_STEPS`). The goals:
//! aligned again within 1 s, and within twice the nominal 3σ (the undisturbed flight's,
//! after settling) within 10 s with the observer, 2 s with the MEKF; never a frame
//! claiming a good attitude beyond the campaign's bound. The host's version of this is
//! tests/resume.rs; the figures of a reset in the slew are in BENCHMARKS.md.

use std::path::Path;

use ssis::calib::Estimator;
use ssis_runner::qemu::build_firmware;
use ssis_runner::upset::{run_campaign, Outcome, Target, UpsetOptions};
use ssis_sim::scenario::Scenario;

/// The reset, s (the observer converges at 10.05 s).
const RESET_S: f64 = 12.5;

#[test]
fn a_reset_in_qemu_resumes_aligned_and_within_twice_the_nominal_3sigma() {
    let elf = build_firmware().expect("firmware");
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios/qemu-flight.toml");
    for (estimator, goal_s, window_s) in [(Estimator::Luenberger, 10.0, 10.0), (Estimator::Mekf, 2.0, 4.0)] {
        let mut sc = Scenario::from_file(&path).expect("scenario");
        sc.table.estimator = Some(estimator);
        let o = UpsetOptions {
            first_s: RESET_S,
            window_s,
            gap_s: 0.0,
            register_share: 0.0,
            forced_reset: true,
            ..UpsetOptions::new(elf.clone(), 1, 7)
        };
        let c = run_campaign(&sc, &o, |_| {}).expect("campaign");
        let f = c.flips.first().expect("one reset");
        println!(
            "{estimator:?}: nominal 3σ {:.2?}″; reset at {:.3} s (instruction {}): aligned after {:?} s, within 2× the nominal 3σ after {:?} s, worst {:.2}″, events {:?}",
            c.nominal_3sigma_arcsec,
            f.step as f64 * 0.005,
            f.instr,
            f.reset_aligned_s,
            f.reset_nominal_s,
            f.worst_arcsec,
            f.events
        );
        assert_eq!(f.target, Target::Reset);
        assert_eq!(f.outcome, Outcome::ResetRecovered, "{estimator:?}: {}", c.report());
        assert_eq!(f.reset_cause.as_deref(), Some("forced (system_reset)"));
        let aligned_s = f.reset_aligned_s.expect("aligned again");
        assert!(aligned_s <= 1.0, "{estimator:?}: aligned {aligned_s} s after the reset");
        let back_s = f.reset_nominal_s.expect("back within twice the nominal 3σ");
        assert!(back_s <= goal_s, "{estimator:?}: within 2× the nominal 3σ after {back_s} s");
        assert!(f.events.iter().any(|e| e == "resumed"), "{estimator:?}: {:?}", f.events);
        assert!(!f.events.iter().any(|e| e == "snapshot_invalid"), "{estimator:?}: {:?}", f.events);
    }
}
