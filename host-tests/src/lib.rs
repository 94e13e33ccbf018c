//! Host side of the ssis flight core: the simulator that makes the sensor data, the
//! mock links that carry it byte by byte, and the harness that drives the very same
//! `FlightCore::step()` the firmware runs and compares its output with truth.
//!
//! - [`sim::truth`]: rigid-body motion (orbital-rate Earth pointing, slews, the paper's
//!   360° calibration maneuver, coning) with optional flexible-appendage modes.
//! - [`sim::fog`]: FOG error model with every term of the calibration table, the paper's
//!   triad error form (eq. 4), angle random walk, random and wandering bias.
//! - [`sim::star`]: star tracker (eq. 5): noise, mounting misalignment, rate, latency.
//! - [`sim::launch`]: launch-vehicle ascent truth (vertical rise, pitch program, stagings,
//!   vibration) with exact body increments, for the navigation (issue 7).
//! - [`mock`]: links that delay, drop, split and corrupt bytes.
//! - [`scenario`]: scenarios as TOML files a user can write.
//! - [`harness`]: runs a scenario through the core and measures the errors.
//! - [`faults`]: fault injection into the frames (failed gyros, a lying star tracker,
//!   bit errors) and the scores of the fault-injection campaign (issue 6).
//! - [`lv`]: launch-vehicle navigation studies (free-inertial error growth, issue 7).
//! - [`qemu`], [`qemu_lv`]: the firmware in QEMU (spacecraft; launch vehicle at 1.25 ms).
//! - [`lab`]: the model lab: fits, diagnoses and extends the FOG error model on ground-test
//!   sessions and exports the calibration table (`docs/LAB.md`).

pub mod corrupt;
pub mod faults;
pub mod harness;
pub mod lab;
pub mod lv;
pub mod methods;
pub mod mock;
pub mod plot;
pub mod qemu;
pub mod qemu_lv;
pub mod scenario;
pub mod sim;
pub mod stats;
pub mod table;

/// Arcseconds per radian.
pub const ARCSEC_PER_RAD: f64 = 180.0 * 3600.0 / std::f64::consts::PI;
/// (°/h) per (rad/s).
pub const DEG_H_PER_RAD_S: f64 = 180.0 / std::f64::consts::PI * 3600.0;
