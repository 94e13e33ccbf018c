//! `replay`: a recorded spacecraft log (docs/RECORDED-LOG.md) through the flight core on
//! the library's replay function (`ssis_sim::replay::replay`, what `ssis-sim replay`
//! runs), with the conventions check first, as the command line does. Returns per-step
//! arrays and the JSON values `ssis-sim replay --json` prints under `replay` and
//! `conventions`.

use std::path::PathBuf;

use numpy::IntoPyArray;
use pyo3::prelude::*;
use pyo3::types::PyDict;
use ssis::flight::Profile;
use ssis_common::ARCSEC_PER_RAD;
use ssis_sim::recorded::{self, LogUnit};
use ssis_sim::replay::{farrenkopf_1sigma_arcsec, replay as replay_log};
use ssis_sim::{conventions, json};

use crate::table::PyTable;
use crate::{err, Progress};

/// Per-step series, flat (n × width, reshaped on the Python side).
#[derive(Default)]
struct Series {
    t_s: Vec<f64>,
    q: Vec<f64>,
    rate_rad_s: Vec<f64>,
    drift_rad_s: Vec<f64>,
    flags: Vec<u8>,
    att_sigma_arcsec: Vec<f64>,
    att_err_arcsec: Vec<f64>,
}

/// Replays `logs` (one CSV, or link captures) with `table`; statistics from `settle_s`.
/// Returns `(arrays, replay_json, conventions_json)`.
#[pyfunction]
#[pyo3(signature = (logs, table = None, settle_s = 60.0, progress = None))]
fn replay<'py>(
    py: Python<'py>,
    logs: Vec<PathBuf>,
    table: Option<&PyTable>,
    settle_s: f64,
    progress: Option<Bound<'py, PyAny>>,
) -> PyResult<(Bound<'py, PyDict>, String, String)> {
    let table = PyTable::table(table);
    let dt_us = Profile::SPACECRAFT.dt_us;
    let rec = recorded::read_log(&logs).map_err(err)?;
    if rec.unit == LogUnit::LaunchVehicle {
        return Err(err(anyhow::anyhow!(
            "{}: a launch-vehicle log; ssis.replay replays the spacecraft unit's (ssis-sim replay runs both)",
            rec.origin
        )));
    }
    let conv = conventions::check_conventions(&rec, &table, dt_us).map_err(err)?;
    let mut s = Series::default();
    let mut bar = Progress::new(progress, rec.steps.len() as u64);
    let mut done = 0u64;
    let summary = replay_log(&rec, &table, settle_s, |f, r| {
        done += 1;
        s.t_s.push(f.time_us as f64 * 1e-6);
        s.q.extend_from_slice(&f.quaternion());
        s.rate_rad_s.extend_from_slice(&f.rate_rad_s());
        s.drift_rad_s.extend_from_slice(&f.drift_rad_s());
        s.flags.push(f.flags);
        s.att_sigma_arcsec.extend(f.att_sigma_rad().map(|v| v * ARCSEC_PER_RAD));
        s.att_err_arcsec.extend_from_slice(&r.map_or([f64::NAN; 3], |r| r.att_err_arcsec));
        bar.tick(done);
    })
    .map_err(err)?;
    bar.finish()?;
    let dt = Profile::SPACECRAFT;
    let limit = farrenkopf_1sigma_arcsec(&table.observer, &table.axes(), dt.dt_s(), rec.st_latency_s(dt.dt_us));
    let mut v = json::replay_summary(&summary);
    json::add_limit_and_damage(&mut v, &limit, &rec.problems);
    let d = PyDict::new(py);
    d.set_item("t_s", s.t_s.into_pyarray(py))?;
    d.set_item("q", s.q.into_pyarray(py))?;
    d.set_item("rate_rad_s", s.rate_rad_s.into_pyarray(py))?;
    d.set_item("drift_rad_s", s.drift_rad_s.into_pyarray(py))?;
    d.set_item("flags", s.flags.into_pyarray(py))?;
    d.set_item("att_sigma_arcsec", s.att_sigma_arcsec.into_pyarray(py))?;
    d.set_item("att_err_arcsec", s.att_err_arcsec.into_pyarray(py))?;
    d.set_item("report", summary.report(&rec, Some(limit)) + &conv.report())?;
    Ok((d, v.to_string(), json::conventions(&conv).to_string()))
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(replay, m)?)
}
