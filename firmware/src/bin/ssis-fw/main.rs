//! `ssis-fw`: the spacecraft unit's flight firmware on the QEMU `mps2-an500` board; the
//! firmware itself is [`firmware`], shared with its test build `ssis-fw-test`.
//!
//! A flight build: control frames (LOCKSTEP, STEP, END, STALL) are counted and ignored,
//! and with the `test-hooks` feature it does not link (`ssis_firmware::mps2_test_hooks!`,
//! README "Flight build and test build").
#![no_std]
#![no_main]
#![deny(clippy::unwrap_used, clippy::expect_used, clippy::indexing_slicing, clippy::panic)]

mod firmware;
