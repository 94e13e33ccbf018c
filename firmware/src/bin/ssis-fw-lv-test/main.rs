//! `ssis-fw-lv-test`: the test build of `ssis-fw-lv`, the same firmware ([`firmware`]) with its
//! test hooks: it honours the control frames LOCKSTEP, STEP, END and STALL. What the QEMU
//! runner and tests run; never flown (README "Flight build and test build"). Built only
//! with `test-hooks`.
#![no_std]
#![no_main]
#![deny(clippy::unwrap_used, clippy::expect_used, clippy::indexing_slicing, clippy::panic)]

#[path = "../ssis-fw-lv/firmware.rs"]
mod firmware;

ssis_firmware::mps2_test_hooks!();
