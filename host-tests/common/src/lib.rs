//! What every host crate shares: the unit conversions, the mock links that carry bytes
//! between the simulator and the flight core, the calibration table's files, plots and
//! running statistics.
//!
//! - [`keyfile`]: the command key's file (the ground's copy of the unit's key).
//! - [`mock`]: links that delay, drop, split and corrupt bytes.
//! - [`table`]: the calibration table as TOML, binary and two-copy image files.
//! - [`plot`]: plots of a run (SVG).
//! - [`stats`]: running error statistics per axis.

pub mod keyfile;
pub mod mock;
pub mod plot;
pub mod stats;
pub mod table;

/// Arcseconds per radian.
pub const ARCSEC_PER_RAD: f64 = 180.0 * 3600.0 / std::f64::consts::PI;
/// (°/h) per (rad/s).
pub const DEG_H_PER_RAD_S: f64 = 180.0 / std::f64::consts::PI * 3600.0;
