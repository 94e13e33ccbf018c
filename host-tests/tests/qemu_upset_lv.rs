//! The upset campaign on the launch-vehicle firmware in QEMU (`ssis_runner::upset` with
//! `Flown::LaunchVehicle`, `ssis-qemu-upset scenarios/lv-ascent.toml`): a small sample of
//! every population in `ssis-fw-lv-test` mid-ascent, each classed against truth and the
//! in-process `LvCore`'s undisturbed frames by the launch vehicle's judgement (a
//! navigation frame claims a good solution without `NAV_FAULT` and `ACCEL_FAULT`). The
//! full campaign and its figures are in docs/UPSET-CAMPAIGN-QEMU-LV.md; this checks the
//! machinery: the step's code is found, every flip lands where its population says, the
//! bounds come from the undisturbed run, and no flip is silent without a reset (a reset
//! mid-ascent is followed by the navigation's resume, whose attitude is the campaign
//! document's open finding).

use std::path::Path;

use ssis_runner::qemu_lv::{build_firmware, LvScenario};
use ssis_runner::upset::{
    run_flown_injection, run_flown_mix, step_code_of, Flown, Mix, Outcome, Target, UpsetOptions, DEVICE_REGS,
    LV_BOUND_FLOOR,
};

#[test]
fn upset_sample_on_the_launch_vehicle_in_qemu() {
    let elf = build_firmware().expect("ssis-fw-lv-test builds");
    let code = step_code_of(&elf, "10FlightCore9step_with17h").expect("step code");
    assert!(code.ranges.iter().any(|r| (r.0..r.1).contains(&code.entry)), "{code:?}");

    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios/lv-ascent.toml");
    let mut sc = LvScenario::from_file(&path).expect("scenario");
    sc.duration_s = 2.5;
    let o = UpsetOptions {
        elf,
        flips: 6,
        seed: 5,
        first_s: 1.0,
        quiet_s: 0.1,
        window_s: 0.3,
        gap_s: 0.05,
        register_share: -1.0,
        max_wall_s: None,
        forced_reset: false,
    };
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
        if f.outcome == Outcome::Silent {
            assert!(f.reset_cause.is_some(), "silent without a reset: {f:?}\n{}", c.report());
        }
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
        match f.target {
            Target::Stack { addr, .. } => assert!(addr < c.stack_top, "{f:?}"),
            Target::Static { addr, .. } => assert!((c.statics.0..c.statics.1).contains(&addr), "{f:?}"),
            Target::Core { reg, bit } => assert!((reg < 16 || reg == 25) && bit < 32, "{f:?}"),
            Target::Fpu { reg, bit } => assert!((26..=42).contains(&reg) && bit < 64, "{f:?}"),
            Target::Double { addr, words, .. } => {
                let end = addr + if words { 8 } else { 4 };
                assert!(end <= c.stack_top || (c.statics.0..=c.statics.1).contains(&end), "{f:?}");
            }
            Target::Device { reg, bit } => {
                let d = DEVICE_REGS.get(usize::from(reg)).expect("a listed register");
                assert!(d.mask & (1 << bit) != 0, "{f:?}");
            }
            Target::SnapshotReset { .. } | Target::Reset => {}
            Target::TickStopped | Target::Stall => panic!("no loop fault in a flip campaign: {f:?}"),
        }
        if f.outcome == Outcome::Masked {
            assert!(f.events.is_empty() && f.recovery_s.is_none(), "{f:?}");
        }
    }
    let doc = c.document("ssis-qemu-upset scenarios/lv-ascent.toml --flips 6");
    assert!(doc.contains("claims a good solution") && doc.contains("| silent | "), "{doc}");
}

/// The device-register flips the 500-flip campaign found silent, each replayed at a few
/// drawn instants mid-ascent: the SysTick reload's bit 19 (the tick period 2^19 cycles
/// longer) and one interrupt enable of NVIC_ISER0 cleared. No navigation frame may claim
/// a good solution beyond its bound.
#[test]
fn the_campaigns_silent_register_flips_replayed() {
    let elf = build_firmware().expect("ssis-fw-lv-test builds");
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios/lv-ascent.toml");
    let mut sc = LvScenario::from_file(&path).expect("scenario");
    let reg = |name: &str| DEVICE_REGS.iter().position(|d| d.name == name).expect("listed") as u8;
    let only = std::env::var("SSIS_LV_REPLAY").ok();
    for (name, bit, first_s) in [("SYST_RVR", 19u8, 5.1575), ("NVIC_ISER0", 7, 8.2075)] {
        if only.as_deref().is_some_and(|o| o != name) {
            continue;
        }
        sc.duration_s = first_s + 3.0;
        let o = UpsetOptions {
            elf: elf.clone(),
            flips: 2,
            seed: 38,
            first_s,
            quiet_s: 0.1,
            window_s: 1.0,
            gap_s: 0.05,
            register_share: -1.0,
            max_wall_s: None,
            forced_reset: false,
        };
        let t = Target::Device { reg: reg(name), bit };
        let c = run_flown_injection(Flown::LaunchVehicle(&sc), &o, t, |f| {
            eprintln!(
                "{name} bit {bit} at step {}: {} worst {:?} reset {:?} events {:?}",
                f.step,
                f.outcome.name(),
                f.nav_worst,
                f.reset_cause,
                f.events
            )
        })
        .expect("campaign");
        for f in &c.flips {
            assert_ne!(f.outcome, Outcome::Silent, "{name} bit {bit}: {f:?}\n{}", c.report());
        }
    }
}
