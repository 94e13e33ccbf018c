//! Monte Carlo campaigns of the spacecraft unit (docs/MONTE-CARLO.md): a campaign is data
//! (a TOML file, [`campaign`]), run i is a pure function of (campaign, i) ([`run`]: the
//! draw of its dispersions and faults, the open-loop flight through the simulator and the
//! flight core) and its result is the ECSS knowledge-error indices per axis ([`indices`]),
//! which the closed loop (Basilisk, on the Python side) computes with the same code.
//! The Python package's `ssis._ssis.mc_*` functions are this crate; the distribution over
//! workers, the Parquet store and the budget report are the Python side's (`ssis.mc`).

pub mod campaign;
pub mod indices;
pub mod run;

pub use campaign::Campaign;
pub use indices::{IndexSpec, Indices};
pub use run::{draw, run, Draw, RunOutput};
