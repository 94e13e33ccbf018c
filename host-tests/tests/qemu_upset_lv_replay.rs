//! The launch-vehicle firmware's silent register flips of its QEMU upset campaign, replayed
//! alone (a binary of its own, so its flights do not share the cores with the campaign
//! sample's).

use std::path::Path;

use ssis_runner::qemu_lv::{build_firmware, LvScenario};
use ssis_runner::upset::{run_flown_injection, Flip, Flown, Outcome, Target, UpsetOptions, DEVICE_REGS};

/// One line per replayed flip on standard error.
fn show(what: &str, f: &Flip) {
    eprintln!(
        "{what} at step {}: {} worst {:?} reset {:?} events {:?}",
        f.step,
        f.outcome.name(),
        f.nav_worst,
        f.reset_cause,
        f.events
    )
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
        let o =
            UpsetOptions { first_s, quiet_s: 0.1, window_s: 1.0, gap_s: 0.05, ..UpsetOptions::new(elf.clone(), 2, 38) };
        let t = Target::Device { reg: reg(name), bit };
        let c = run_flown_injection(Flown::LaunchVehicle(&sc), &o, t, |f| show(&format!("{name} bit {bit}"), f))
            .expect("campaign");
        for f in &c.flips {
            assert_ne!(f.outcome, Outcome::Silent, "{name} bit {bit}: {f:?}\n{}", c.report());
        }
    }
}

/// A watchdog reset mid-ascent, forced: the test build's STALL stops the main loop at a
/// chosen instant (the flips' signature: a handler-stack flip at 5.22 s, a SysTick reload
/// flip at 5.16 s, both ended in a watchdog reset). The unit resumes its navigation from
/// the snapshot; no navigation frame may claim a good solution beyond its bound.
#[test]
fn a_watchdog_reset_mid_ascent_resumes_within_the_bound() {
    let elf = build_firmware().expect("ssis-fw-lv-test builds");
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios/lv-ascent.toml");
    let mut sc = LvScenario::from_file(&path).expect("scenario");
    let first_s: f64 = std::env::var("SSIS_LV_STALL_AT").ok().and_then(|s| s.parse().ok()).unwrap_or(5.22);
    sc.duration_s = first_s + 2.0;
    let o = UpsetOptions { first_s, quiet_s: 0.1, window_s: 1.0, gap_s: 0.0, ..UpsetOptions::new(elf, 1, 38) };
    let c = run_flown_injection(Flown::LaunchVehicle(&sc), &o, Target::Stall, |f| show("stall", f)).expect("campaign");
    assert_eq!(c.flips.len(), 1);
    for f in &c.flips {
        assert!(f.reset_cause.is_some(), "the stalled loop was not reset: {f:?}");
        assert_ne!(f.outcome, Outcome::Silent, "{f:?}\n{}", c.report());
    }
}

/// The SysTick's interrupt enable (TICKINT) and clock source (CLKSOURCE) cleared mid-step,
/// mid-ascent: the executive's check of the tick's registers before its next wait restores
/// them at the loop's next wake (`register_restored`); no reset, no frame beyond its
/// bound. (Before that check the watchdog's warning restored them, and its second timeout
/// could reset the unit: the campaign's two silent flips. Whether the warning comes
/// first here depends on the runner's pace, as QEMU warps the idle guest's time, so it is
/// not asserted.)
#[test]
fn a_tick_stopped_by_its_control_word_runs_again_at_the_next_pass() {
    let elf = build_firmware().expect("ssis-fw-lv-test builds");
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios/lv-ascent.toml");
    let mut sc = LvScenario::from_file(&path).expect("scenario");
    let reg = DEVICE_REGS.iter().position(|d| d.name == "SYST_CSR").expect("listed") as u8;
    for bit in [1u8, 2] {
        let first_s = 6.03;
        sc.duration_s = first_s + 2.0;
        let o =
            UpsetOptions { first_s, quiet_s: 0.1, window_s: 1.0, gap_s: 0.05, ..UpsetOptions::new(elf.clone(), 2, 38) };
        let t = Target::Device { reg, bit };
        let c = run_flown_injection(Flown::LaunchVehicle(&sc), &o, t, |f| show(&format!("SYST_CSR bit {bit}"), f))
            .expect("campaign");
        assert_eq!(c.flips.len(), 2);
        for f in &c.flips {
            assert!(f.reset_cause.is_none(), "bit {bit}: reset {f:?}");
            assert!(f.events.iter().any(|e| e == "register_restored"), "bit {bit}: not restored: {f:?}");
            assert!(matches!(f.outcome, Outcome::Masked | Outcome::Tolerated), "bit {bit}: {f:?}\n{}", c.report());
        }
    }
}
