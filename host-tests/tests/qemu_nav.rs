//! The launch-vehicle navigation on the target CPU: the
//! `ssis-navbench` binary runs 8,000 steps of accelerometer compensation + aided
//! strapdown step (covariance propagation every 80 steps) and 10 GNSS updates under
//! QEMU with `-icount shift=0`; instruction counts per step from SysTick.
//!
//! This is the navigation's cost alone: the flight step does not run the navigation
//! yet, so the full launch-vehicle step (frames, links, output) is not measured here.

use std::time::Duration;

use ssis_runner::qemu::{build_target_bin, run_bare_with, INSTR_PER_TICK};

#[test]
fn nav_instructions_per_step_on_target() {
    let elf = build_target_bin("ssis-navbench").expect("navbench builds");
    let (code, log) = run_bare_with(&elf, Duration::from_secs(120), true).expect("QEMU runs navbench");
    for l in &log {
        println!("target: {l}");
    }
    assert_eq!(code, Some(0), "navbench exit code (a step or update was refused)");
    let line = log.iter().find(|l| l.starts_with("navbench ")).expect("navbench result line");
    let v: Vec<u64> = line.split_whitespace().filter_map(|w| w.parse().ok()).collect();
    let [steps, step_ticks, max_step, fixes, fix_ticks, max_fix, failures] = v[..] else {
        panic!("unexpected result line: {line}")
    };
    assert_eq!(failures, 0);
    let mean_step = step_ticks as f64 * INSTR_PER_TICK / steps as f64;
    let max_step_i = max_step as f64 * INSTR_PER_TICK;
    let mean_fix = fix_ticks as f64 * INSTR_PER_TICK / fixes as f64;
    let max_fix_i = max_fix as f64 * INSTR_PER_TICK;
    println!(
        "navigation on target: mean {mean_step:.0} instructions per 1.25 ms step (max {max_step_i:.0}, a step with the \
         covariance propagation), GNSS update mean {mean_fix:.0} (max {max_fix_i:.0}) instructions"
    );
    // Budget: a step and a GNSS update together within 1.25 ms of a 300 MHz Cortex-M7 at
    // one instruction per cycle (375,000 instructions).
    assert!(max_step_i + max_fix_i < 375_000.0, "navigation over budget: {max_step_i} + {max_fix_i}");
}
