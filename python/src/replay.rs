//! `replay`: a recorded spacecraft log (docs/RECORDED-LOG.md) through the flight core on
//! the library's replay function (`ssis_sim::replay::replay`, what `ssis-sim replay`
//! runs; a spacecraft CSV log streamed as it is read, `ssis_sim::streamed`), with the
//! conventions check first, as the command line does. Returns per-step (or every N-th)
//! arrays and the JSON values `ssis-sim replay --json` prints under `replay` and
//! `conventions`.

use std::path::{Path, PathBuf};

use numpy::IntoPyArray;
use pyo3::prelude::*;
use pyo3::types::PyDict;
use ssis::flight::Profile;
use ssis::frames::output::OutputFrame;
use ssis_common::ARCSEC_PER_RAD;
use ssis_sim::harness::Record;
use ssis_sim::recorded::{self, LogStream, LogUnit};
use ssis_sim::replay::{farrenkopf_1sigma_arcsec, replay as replay_log, LogInfo};
use ssis_sim::streamed::{self, Streamed};
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

impl Series {
    /// Room for `n` more frames, so that a long replay's arrays are not copied as they
    /// grow.
    fn reserve(&mut self, n: usize) {
        self.t_s.reserve(n);
        self.flags.reserve(n);
        self.q.reserve(4 * n);
        for v in [&mut self.rate_rad_s, &mut self.drift_rad_s, &mut self.att_sigma_arcsec, &mut self.att_err_arcsec] {
            v.reserve(3 * n);
        }
    }

    /// Output frame `f` and its record against truth.
    fn push(&mut self, f: &OutputFrame, r: Option<&Record>) {
        self.t_s.push(f.time_us as f64 * 1e-6);
        self.q.extend_from_slice(&f.quaternion());
        self.rate_rad_s.extend_from_slice(&f.rate_rad_s());
        self.drift_rad_s.extend_from_slice(&f.drift_rad_s());
        self.flags.push(f.flags);
        self.att_sigma_arcsec.extend(f.att_sigma_rad().map(|v| v * ARCSEC_PER_RAD));
        self.att_err_arcsec.extend_from_slice(&r.map_or([f64::NAN; 3], |r| r.att_err_arcsec));
    }
}

/// Steps a CSV log of `path` may hold, from its size and its first 64 kB (for progress).
fn estimated_steps(path: &Path) -> u64 {
    use std::io::Read;
    let len = std::fs::metadata(path).map_or(0, |m| m.len());
    let mut head = Vec::new();
    let _ = std::fs::File::open(path).and_then(|f| f.take(1 << 16).read_to_end(&mut head));
    let lines = head.iter().filter(|&&b| b == b'\n').count().max(1) as u64;
    len * lines / (head.len().max(1) as u64)
}

/// Replays `logs` (one CSV, or link captures) with `table`; statistics from `settle_s`.
/// The arrays keep every `every`-th output frame (none with `every` = 0). A spacecraft
/// CSV log is read as it is replayed (`ssis_sim::streamed`, bounded memory).
/// Returns `(arrays, replay_json, conventions_json)`.
#[pyfunction]
#[pyo3(signature = (logs, table = None, settle_s = 60.0, progress = None, every = 1))]
fn replay<'py>(
    py: Python<'py>,
    logs: Vec<PathBuf>,
    table: Option<&PyTable>,
    settle_s: f64,
    progress: Option<Bound<'py, PyAny>>,
    every: u64,
) -> PyResult<(Bound<'py, PyDict>, String, String)> {
    let table = PyTable::table(table);
    let dt_us = Profile::SPACECRAFT.dt_us;
    let mut s = Series::default();
    let mut done = 0u64;
    let streamed = match logs.as_slice() {
        [p] if recorded::is_csv(p) => {
            let stream = LogStream::open(p).map_err(err)?;
            (stream.unit == LogUnit::Spacecraft).then_some((stream, estimated_steps(p)))
        }
        _ => None,
    };
    let (st, mut bar) = match streamed {
        Some((stream, total)) => {
            let mut bar = Progress::new(progress, total);
            // The frames kept, from the log's size (an estimate: the arrays may still grow).
            if let Some(n) = total.checked_div(every) {
                s.reserve(usize::try_from(n + 1).unwrap_or(0));
            }
            let st = streamed::replay_stream(
                stream,
                &table,
                settle_s,
                |_| {},
                |f, r| {
                    done += 1;
                    if every > 0 && (done - 1).is_multiple_of(every) {
                        s.push(f, r);
                    }
                    bar.tick(done);
                },
            )
            .map_err(err)?;
            (st, bar)
        }
        None => {
            let rec = recorded::read_log(&logs).map_err(err)?;
            if rec.unit == LogUnit::LaunchVehicle {
                return Err(err(anyhow::anyhow!(
                    "{}: a launch-vehicle log; ssis.replay replays the spacecraft unit's (ssis-sim replay runs both)",
                    rec.origin
                )));
            }
            let conventions = conventions::check_conventions(&rec, &table, dt_us).map_err(err)?;
            let mut bar = Progress::new(progress, rec.steps.len() as u64);
            let summary = replay_log(&rec, &table, settle_s, |f, r| {
                done += 1;
                if every > 0 && (done - 1).is_multiple_of(every) {
                    s.push(f, r);
                }
                bar.tick(done);
            })
            .map_err(err)?;
            let st = Streamed { summary, conventions, info: LogInfo::of(&rec), st_latency_s: rec.st_latency_s(dt_us) };
            (st, bar)
        }
    };
    bar.end(done);
    bar.finish()?;
    let dt = Profile::SPACECRAFT;
    let limit = farrenkopf_1sigma_arcsec(&table.observer, &table.axes(), dt.dt_s(), st.st_latency_s);
    let mut v = json::replay_summary(&st.summary);
    json::add_limit_and_damage(&mut v, &limit, &st.info.problems);
    let d = PyDict::new(py);
    d.set_item("t_s", s.t_s.into_pyarray(py))?;
    d.set_item("q", s.q.into_pyarray(py))?;
    d.set_item("rate_rad_s", s.rate_rad_s.into_pyarray(py))?;
    d.set_item("drift_rad_s", s.drift_rad_s.into_pyarray(py))?;
    d.set_item("flags", s.flags.into_pyarray(py))?;
    d.set_item("att_sigma_arcsec", s.att_sigma_arcsec.into_pyarray(py))?;
    d.set_item("att_err_arcsec", s.att_err_arcsec.into_pyarray(py))?;
    d.set_item("report", st.summary.report_on(&st.info, Some(limit)) + &st.conventions.report())?;
    Ok((d, v.to_string(), json::conventions(&st.conventions).to_string()))
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(replay, m)?)
}
