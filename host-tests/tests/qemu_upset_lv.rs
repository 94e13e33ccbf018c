//! The upset campaign on the launch-vehicle firmware in QEMU (`ssis_runner::upset` with
//! `Flown::LaunchVehicle`, `ssis-qemu-upset scenarios/lv-ascent.toml`): a small sample of
//! every population in `ssis-fw-lv-test` mid-ascent, each classed against truth and the
//! in-process `LvCore`'s undisturbed frames by the launch vehicle's judgement (a
//! navigation frame claims a good solution without `NAV_FAULT` and `ACCEL_FAULT`). The
//! full campaign and its figures are in docs/UPSET-CAMPAIGN-QEMU-LV.md; this checks the
//! machinery: the step's code is found, every flip lands where its population says, the
//! bounds come from the undisturbed run, and no flip is silent (a reset mid-ascent is
//! followed by the navigation's resume, which flags an attitude it cannot back).

use std::path::Path;

use ssis_runner::qemu_lv::{build_firmware, LvScenario};
use ssis_runner::upset::{run_flown_mix, step_code_of, Flown, Mix, Outcome, UpsetOptions, LV_BOUND_FLOOR};

#[test]
fn upset_sample_on_the_launch_vehicle_in_qemu() {
    let elf = build_firmware().expect("ssis-fw-lv-test builds");
    let code = step_code_of(&elf, "10FlightCore9step_with17h").expect("step code");
    assert!(code.ranges.iter().any(|r| (r.0..r.1).contains(&code.entry)), "{code:?}");

    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios/lv-ascent.toml");
    let mut sc = LvScenario::from_file(&path).expect("scenario");
    sc.duration_s = 2.5;
    let o = UpsetOptions { first_s: 1.0, quiet_s: 0.1, window_s: 0.3, gap_s: 0.05, ..UpsetOptions::new(elf, 6, 5) };
    let c = run_flown_mix(Flown::LaunchVehicle(&sc), &o, &Mix::all(), |f| {
        eprintln!(
            "{} at step {}: {} -> {} {:?} {:?}",
            f.population.name(),
            f.step,
            f.target.describe(),
            f.outcome.name(),
            f.nav_worst,
            f.events
        )
    })
    .expect("campaign");
    assert_eq!(c.flips.len(), 6);
    for f in &c.flips {
        assert!(f.outcome != Outcome::Silent, "silent: {f:?}\n{}", c.report());
        if let Outcome::Crash(why) = &f.outcome {
            assert!(f.reset_cause.is_some(), "a crash without a reset: {why} ({f:?})");
        }
    }
    assert_eq!(c.failed_flights, 0, "{}", c.report());
    // The bounds: twice the undisturbed flight's largest errors, floored.
    let b = c.lv.expect("the launch vehicle's bounds");
    for (k, floor) in LV_BOUND_FLOOR.iter().enumerate() {
        assert!(b.undisturbed_max[k].is_finite() && b.undisturbed_max[k] > 0.0, "{b:?}");
        assert_eq!(b.bound[k], (2.0 * b.undisturbed_max[k]).max(*floor), "{b:?}");
    }
    let dt_s = 0.00125;
    for f in &c.flips {
        assert!(f.step >= 800 && f.step as f64 * dt_s <= 2.5, "{f:?}");
        assert!(f.nav_worst.is_some(), "{f:?}");
        assert_eq!(c.out_of_reach(f), None);
    }
    let doc = c.document("ssis-qemu-upset scenarios/lv-ascent.toml --flips 6");
    assert!(doc.contains("claims a good solution") && doc.contains("| silent | "), "{doc}");
}
