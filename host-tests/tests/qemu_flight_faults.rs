//! The flight build (`ssis-fw`, paced on its own SysTick, no lockstep) under a fault of its
//! loop in QEMU (`ssis_runner::flight_build::loop_fault_on_flight_build`: `-icount`, the
//! gdbstub, `-action watchdog=reset`; the calibration table loaded, no sensor input): the
//! SysTick's enable bit cleared, the loop stalled in a branch to itself, or PRIMASK set. The loop must
//! stop stepping, the watchdog reset the unit (its raw interrupt status still set at the
//! reset: a timeout that no feed followed), and the unit step again after the reset. A
//! firmware that restores the SysTick's control word itself (a register check) passes
//! the stopped tick without a reset if it steps again with the tick enabled.
//! Not covered here: the attitude after the reset (no sensor frames are fed).

use std::path::Path;

use ssis_runner::flight_build::{loop_fault_on_flight_build, LoopFault};
use ssis_sim::scenario::Scenario;

fn fault(f: LoopFault) {
    let elf = ssis_runner::qemu::build_flight_firmware().expect("flight firmware builds");
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios/qemu-flight.toml");
    let sc = Scenario::from_file(&path).expect("scenario");
    let table = ssis_sim::harness::Simulation::new(&sc).expect("simulation").table;
    let c = loop_fault_on_flight_build(&elf, &table, f, 400, 100).expect("run");
    println!(
        "{f:?}: frames before {}, between fault and reset {}, reset {}, warnings {}, watchdog pending {}, frames after {}",
        c.frames_before, c.frames_faulted, c.reset, c.warnings, c.watchdog_pending, c.frames_after
    );
    for l in c.log.iter().filter(|l| !l.is_empty()).take(12) {
        println!("  log: {l}");
    }
    assert!(c.frames_before >= 400);
    if f == LoopFault::TickStopped && c.tick_restored {
        // A register check restored the tick: recovered without a reset.
        println!("recovered by a register restore, {} frames after the fault", c.frames_faulted);
        return;
    }
    assert!(c.reset, "the unit reset: {:?}", c.log.iter().rev().take(5).collect::<Vec<_>>());
    assert!(c.watchdog_pending || c.warnings > 0, "reset by the watchdog");
    assert!(c.frames_faulted <= 1, "the loop stopped stepping: {} frames", c.frames_faulted);
    assert!(c.frames_after >= 100, "stepping again after the reset: {} frames", c.frames_after);
}

#[test]
fn a_flight_build_with_its_tick_stopped_is_reset_by_the_watchdog() {
    fault(LoopFault::TickStopped);
}

#[test]
fn a_flight_build_whose_loop_stalls_is_reset_by_the_watchdog() {
    fault(LoopFault::Stall);
}

#[test]
fn a_flight_build_with_its_interrupts_masked_is_reset_by_the_watchdog() {
    fault(LoopFault::InterruptsMasked);
}
