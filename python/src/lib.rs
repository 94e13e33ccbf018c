//! `ssis._ssis`: the native half of the Python package `ssis` (python/ssis/ is the other
//! half: the classes users see, the type stubs and the Basilisk module).
//!
//! A thin layer over the host libraries, the same code paths as the command lines:
//! - [`table`]: the calibration table (ssis_common::table, ssis_common::update);
//! - [`core`]: `FlightCore::step` fed one step's FOG increments and star-tracker solution
//!   as frames on mock links, exactly as the simulator and the replay feed it;
//! - [`replay`]: `ssis_sim::replay::replay` of a recorded log, per-step arrays and the
//!   summary `ssis-sim replay --json` prints (from the same `ssis_sim::json` functions);
//! - [`cal`]: the calibration methods of `ssis-cal` (Allan deviation on arrays or a
//!   session, turns, SINS), their `--json` values;
//! - [`lab`]: the model lab (`ssis-lab` init, compare, diagnose, add, export, report);
//! - [`mc`]: Monte Carlo campaigns (`ssis_mc`): validate, draw and fly run i, the indices.
//!
//! Summaries cross as JSON text (the tools' `--json` form, docs/JSON.md), parsed on the
//! Python side; per-step series cross as numpy arrays. Every error is raised as
//! `ssis.SsisError` with the library's message, which names the file, line and field as
//! the command line's does.

use pyo3::prelude::*;

mod cal;
mod core;
mod lab;
mod mc;
mod qemu;
mod replay;
mod sim;
mod table;

pyo3::create_exception!(
    _ssis,
    SsisError,
    pyo3::exceptions::PyValueError,
    "An error of the ssis libraries (bad input: file, line and field named in the message)."
);

/// The library error as `SsisError`, its whole chain of context (as the tools print it).
pub(crate) fn err(e: anyhow::Error) -> PyErr {
    SsisError::new_err(format!("{e:#}"))
}

/// Calls `progress(done, total)` when it is given; a callback's exception is kept for the
/// end of the work (the libraries' loops cannot be cut short).
pub(crate) struct Progress<'py> {
    cb: Option<Bound<'py, PyAny>>,
    total: u64,
    every: u64,
    failed: Option<PyErr>,
}

impl<'py> Progress<'py> {
    pub(crate) fn new(cb: Option<Bound<'py, PyAny>>, total: u64) -> Self {
        Progress { cb, total, every: (total / 200).max(1), failed: None }
    }

    /// Reports `done` (every 0.5 % of the total, and at the end).
    pub(crate) fn tick(&mut self, done: u64) {
        if self.failed.is_some() || !(done.is_multiple_of(self.every) || done == self.total) {
            return;
        }
        if let Some(cb) = &self.cb {
            if let Err(e) = cb.call1((done, self.total)) {
                self.failed = Some(e);
            }
        }
    }

    /// Reports the end, `done` of `done` (the total was an estimate when the log was read
    /// as it was replayed).
    pub(crate) fn end(&mut self, done: u64) {
        if self.total != done {
            self.total = done;
            self.tick(done);
        }
    }

    /// The callback's first exception, if any.
    pub(crate) fn finish(self) -> PyResult<()> {
        self.failed.map_or(Ok(()), Err)
    }
}

#[pymodule]
fn _ssis(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("SsisError", m.py().get_type::<SsisError>())?;
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    table::register(m)?;
    core::register(m)?;
    replay::register(m)?;
    cal::register(m)?;
    lab::register(m)?;
    mc::register(m)?;
    qemu::register(m)?;
    sim::register(m)?;
    Ok(())
}
