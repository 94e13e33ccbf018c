//! What every host crate shares: the unit conversions, the mock links that carry bytes
//! between the simulator and the flight core, the calibration table's files, plots and
//! running statistics, and what every tool's `main` shares.
//!
//! - [`keyfile`]: the command key's file (the ground's copy of the unit's key).
//! - [`mock`]: links that delay, drop, split and corrupt bytes.
//! - [`table`]: the calibration table as TOML (with per-field provenance), binary and
//!   two-copy image files.
//! - [`update`]: table updates that keep what they cannot improve; per-field differences.
//! - [`plot`]: plots of a run (SVG).
//! - [`stats`]: running error statistics per axis.
//! - [`output`]: every file a tool writes: never onto an input, never half-written.
//! - [`downlink`]: the output link's frame kinds decoded from one stream; the event timeline.
//! - [`cli`]: a tool's process: closed pipes, Ctrl-C, `--json`, the exit status.
//! - [`names`]: "did you mean" for a mistyped name or key.

pub mod cli;
pub mod downlink;
pub mod keyfile;
pub mod mock;
pub mod names;
pub mod output;
pub mod plot;
pub mod stats;
pub mod table;
pub mod update;

/// Arcseconds per radian.
pub const ARCSEC_PER_RAD: f64 = 180.0 * 3600.0 / std::f64::consts::PI;
/// (°/h) per (rad/s).
pub const DEG_H_PER_RAD_S: f64 = 180.0 / std::f64::consts::PI * 3600.0;
