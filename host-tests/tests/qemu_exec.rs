//! The executive's watchdog rule in QEMU (`ssis::bsp::exec`): the watchdog is fed only
//! by a step that completed within its deadline, so a loop that stops stepping is
//! reset. `ssis-fw-test` flies the two-minute QEMU scenario in lockstep, cut to
//! [`FLIGHT_S`]; at [`FAULT_S`], after convergence, the runner injects a fault of the
//! loop through QEMU's gdbstub (`ssis_runner::upset::run_injection`) and follows the
//! reset back into lockstep:
//!
//! - the SysTick's enable bit cleared (0xE000_E010 bit 0): the tick stops; the steps
//!   that the runner's STEP frames still call for take no time on the stopped clock,
//!   so none feeds the watchdog, and no idle pass sees a new tick;
//! - a stall of the main loop (the test build's STALL control frame).
//!
//! Goals: the unit resets within 100 ms, and is back within twice its nominal 3σ (the
//! undisturbed flight's, after settling) within 2 s. The reset's time is the
//! watchdog's: its cause must be the watchdog after exactly one warning (the NMI at
//! the first timeout, the reset at the second: 2 × 45 ms = 90 ms of the unit's virtual
//! time after the last feed, which came no later than the end of the step the fault
//! was injected in); a second warning would mean the loop fed it after the fault.

use std::path::Path;

use ssis_runner::qemu::build_firmware;
use ssis_runner::upset::{run_injection, Outcome, Target, UpsetOptions};
use ssis_sim::scenario::Scenario;

/// The flight, s.
const FLIGHT_S: f64 = 20.0;
/// The fault, s (the observer converges at 10.05 s).
const FAULT_S: f64 = 12.5;
/// Errors after this time make the nominal 3σ, s.
const SETTLE_S: f64 = 11.0;

fn inject(fault: Target) {
    let elf = build_firmware().expect("firmware");
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios/qemu-flight.toml");
    let mut sc = Scenario::from_file(&path).expect("scenario");
    sc.duration_s = FLIGHT_S;
    // The nominal 3σ over the undisturbed flight after convergence (the scenario's own
    // settling time is longer than this flight).
    sc.settle_s = SETTLE_S;
    let o = UpsetOptions {
        elf,
        flips: 1,
        seed: 11,
        first_s: FAULT_S,
        quiet_s: 0.5,
        window_s: 4.0,
        gap_s: 0.0,
        register_share: 0.0,
        max_wall_s: None,
        forced_reset: false,
    };
    let c = run_injection(&sc, &o, fault, |_| {}).expect("campaign");
    let f = c.flips.first().expect("one fault");
    println!(
        "{}: nominal 3σ {:.2?}″; at {:.3} s: reset ({:?}) {:?} s of the runner's steps later; aligned after {:?} s, within 2× the nominal 3σ after {:?} s, worst {:.2}″, events {:?}",
        fault.describe(),
        c.nominal_3sigma_arcsec,
        f.step as f64 * 0.005,
        f.reset_cause,
        f.reset_after_s,
        f.reset_aligned_s,
        f.reset_nominal_s,
        f.worst_arcsec,
        f.events
    );
    assert_eq!(f.target, fault);
    assert_eq!(f.outcome, Outcome::ResetRecovered, "{}", c.report());
    assert_eq!(f.reset_cause.as_deref(), Some("watchdog"), "one warning, then the reset at the second timeout");
    let back_s = f.reset_nominal_s.expect("back within twice the nominal 3σ");
    assert!(back_s <= 2.0, "within 2× the nominal 3σ after {back_s} s");
    assert!(f.events.iter().any(|e| e == "resumed"), "{:?}", f.events);
}

/// Ignored: the write to SYST_CSR through QEMU's gdbstub did not take (measured: the
/// fault classed masked, the unit stepping on); QEMU's gdbstub writes guest memory
/// with `address_space_write_rom`, which writes RAM and ROM and skips device
/// registers. The runner now refuses such a write (it reads SYST_CSR back). What
/// remains to do: stop the tick from inside the guest (a test hook), or through
/// QEMU's monitor.
#[test]
#[ignore = "QEMU's gdbstub does not write the SysTick's registers"]
fn a_stopped_tick_is_reset_by_the_watchdog_and_the_unit_resumes() {
    inject(Target::TickStopped);
}

#[test]
fn a_stalled_loop_is_reset_by_the_watchdog_and_the_unit_resumes() {
    inject(Target::Stall);
}
