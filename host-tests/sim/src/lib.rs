//! The simulator: truth motion, sensor models and frame encoders (the core's own), the
//! scenarios a user writes, and the harness that drives the very same `FlightCore::step()`
//! the firmware runs and compares its output with truth.
//!
//! - [`truth`]: rigid-body motion (orbital-rate Earth pointing, slews, the paper's 360°
//!   calibration maneuver, coning) with optional flexible-appendage modes.
//! - [`fog`]: FOG error model with every term of the calibration table, the paper's triad
//!   error form (eq. 4), angle random walk, random and wandering bias.
//! - [`star`]: star tracker (eq. 5): noise, mounting misalignment, rate, latency.
//! - [`sensors`]: the FOGs and the star tracker of a run on one random stream (the
//!   harness's and the Python package's Basilisk module's).
//! - [`accel`], [`gnss`]: accelerometers and GNSS fixes for the launch-vehicle navigation.
//! - [`launch`]: launch-vehicle ascent truth (vertical rise, pitch program, stagings,
//!   vibration) with exact body increments.
//! - [`scenario`]: scenarios as TOML files a user can write.
//! - [`accuracy`]: the unit's output against truth (per step and over a run) and the
//!   estimation limit of its sensors.
//! - [`harness`]: runs a scenario through the core and measures the errors.
//! - [`json`]: the `--json` form of a run's summary (docs/JSON.md).
//! - [`corrupt`]: frame corruption trials against the stream decoder.
//! - [`lv`]: launch-vehicle navigation studies (free-inertial error growth).
//! - [`lv_replay`]: the launch-vehicle unit's host side (ascent sensors as link bytes, a
//!   recorded log as the same bytes, the firmware's period, judging its navigation output).
//! - [`recorded`], [`replay`], [`check`]: recorded logs (`docs/RECORDED-LOG.md`) replayed through the core.
//! - [`conventions`]: a log's quaternion form, FOG units and time tags checked against its data.
//! - [`sc_record`]: a spacecraft recorded log written from a scenario.
//! - [`streamed`]: a spacecraft CSV log replayed while it is read, in bounded memory.

pub mod accel;
pub mod accuracy;
pub mod check;
pub mod conventions;
pub mod corrupt;
pub mod fog;
pub mod gnss;
pub mod harness;
pub mod json;
pub mod launch;
pub mod lv;
pub mod lv_replay;
pub mod recorded;
pub mod replay;
pub mod sc_record;
pub mod scenario;
pub mod sensors;
pub mod star;
pub mod streamed;
pub mod truth;
