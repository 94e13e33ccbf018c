//! Monte Carlo campaigns (`ssis_mc`, docs/MONTE-CARLO.md "The Python-visible API"): a
//! campaign checked and normalised, run i drawn and flown in open loop, and the ECSS
//! knowledge-error indices of any error series (the closed loop's too). Each call takes
//! the campaign's text and origin, so a worker needs nothing else (the scenario and table
//! files it names are read from the origin's directory); runs release the GIL.

use numpy::{IntoPyArray, PyArrayMethods, PyReadonlyArray1, PyReadonlyArray2, PyUntypedArrayMethods};
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList};
use ssis_mc::indices::Index;
use ssis_mc::run::{FaultEvent, RunOutput};
use ssis_mc::{Campaign, IndexSpec, Indices};

use crate::{err, SsisError};

fn campaign(text: &str, origin: &str) -> PyResult<Campaign> {
    Campaign::parse(text, origin).map_err(err)
}

/// `[(name, value)]` as a dict, in order.
fn dict<'py>(py: Python<'py>, v: &[(String, f64)]) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    for (k, x) in v {
        d.set_item(k, x)?;
    }
    Ok(d)
}

fn fault_dict<'py>(py: Python<'py>, f: &FaultEvent) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    let kind = serde_json::to_value(f.kind).ok().and_then(|v| v.as_str().map(String::from)).unwrap_or_default();
    d.set_item("kind", kind)?;
    d.set_item("t_s", f.t_s)?;
    d.set_item("fog", f.fog)?;
    d.set_item("duration_s", f.duration_s)?;
    Ok(d)
}

fn run_dict<'py>(py: Python<'py>, r: &RunOutput) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    d.set_item("run", r.run)?;
    d.set_item("params", dict(py, &r.params)?)?;
    d.set_item("indices", dict(py, &r.indices)?)?;
    match &r.series {
        None => d.set_item("series", py.None())?,
        Some(s) => {
            let sd = PyDict::new(py);
            sd.set_item("t_s", s.t_s.clone().into_pyarray(py))?;
            let flat: Vec<f64> = s.err_arcsec.iter().flatten().copied().collect();
            let a = flat.into_pyarray(py).reshape([s.t_s.len(), 3])?;
            sd.set_item("err_arcsec", a)?;
            d.set_item("series", sd)?;
        }
    }
    d.set_item("steps", r.steps)?;
    d.set_item("evaluated", r.evaluated)?;
    d.set_item("converged_at_s", r.converged_at_s)?;
    d.set_item("digest", format!("{:016x}", r.digest()))?;
    Ok(d)
}

/// The campaign checked and normalised, as JSON: its runs, seed, loop, the scenario it
/// flies, every quantity with its distribution resolved, the faults, the indices' spec
/// (`indices`, what `mc_indices` takes), the parameter names (`params`) and index keys
/// (`index_keys`) every run reports, in order.
#[pyfunction]
#[pyo3(signature = (text, origin = "<campaign>"))]
fn mc_validate(text: &str, origin: &str) -> PyResult<String> {
    campaign(text, origin)?.to_json().map_err(err)
}

/// What run `i` draws: `run`, `params` (name → value), `faults` (those that occur: kind,
/// t_s, fog, duration_s) and `scenario_toml` (the dispersed scenario, what a closed loop
/// flies; relative paths in it are the origin's).
#[pyfunction]
#[pyo3(signature = (text, origin, i))]
fn mc_draw<'py>(py: Python<'py>, text: &str, origin: &str, i: u64) -> PyResult<Bound<'py, PyDict>> {
    let c = campaign(text, origin)?;
    let d = ssis_mc::draw(&c, i).map_err(err)?;
    let out = PyDict::new(py);
    out.set_item("run", d.run)?;
    out.set_item("params", dict(py, &d.params)?)?;
    let faults = PyList::empty(py);
    for f in &d.faults {
        faults.append(fault_dict(py, f)?)?;
    }
    out.set_item("faults", faults)?;
    let toml = toml::to_string(&d.scenario).map_err(|e| SsisError::new_err(format!("run {i}: {e}")))?;
    out.set_item("scenario_toml", toml)?;
    Ok(out)
}

/// Flies run `i` in open loop: `run`, `params`, `indices` (key → arcsec), `series` (None,
/// or every `series_every`-th output's `t_s` (N,) and `err_arcsec` (N, 3)), `steps`,
/// `evaluated`, `converged_at_s`, `digest` (hex of every bit of the run).
#[pyfunction]
#[pyo3(signature = (text, origin, i, series_every = 0))]
fn mc_run<'py>(py: Python<'py>, text: &str, origin: &str, i: u64, series_every: u64) -> PyResult<Bound<'py, PyDict>> {
    let c = campaign(text, origin)?;
    let r = py.detach(|| ssis_mc::run(&c, i, series_every)).map_err(err)?;
    run_dict(py, &r)
}

/// [`mc_run`] for each of `runs`, the campaign read once.
#[pyfunction]
#[pyo3(signature = (text, origin, runs, series_every = 0))]
fn mc_runs<'py>(
    py: Python<'py>,
    text: &str,
    origin: &str,
    runs: Vec<u64>,
    series_every: u64,
) -> PyResult<Bound<'py, PyList>> {
    let c = campaign(text, origin)?;
    let out = PyList::empty(py);
    for i in runs {
        let r = py.detach(|| ssis_mc::run(&c, i, series_every)).map_err(err)?;
        out.append(run_dict(py, &r)?)?;
    }
    Ok(out)
}

/// `spec_json` as an [`IndexSpec`], read through `serde_json::Value`: this build has
/// serde_json's `arbitrary_precision` (defmt-decoder turns it on), under which the numbers
/// of an internally tagged enum ([`Index`]) arrive as maps and its derived `Deserialize`
/// refuses them ("invalid type: map, expected f64").
fn index_spec(spec_json: &str) -> PyResult<IndexSpec> {
    use serde_json::Value;
    let bad = |what: String| SsisError::new_err(format!("spec_json: {what}"));
    let v: Value = serde_json::from_str(spec_json).map_err(|e| bad(e.to_string()))?;
    let num =
        |o: &Value, k: &str| o.get(k).and_then(Value::as_f64).ok_or_else(|| bad(format!("`{k}`: expected a number")));
    let list = v.get("index").and_then(Value::as_array).ok_or_else(|| bad("`index`: expected a list".into()))?;
    let mut index = Vec::with_capacity(list.len());
    for x in list {
        index.push(match x.get("kind").and_then(Value::as_str) {
            Some("AKE") => Index::Ake,
            Some("RKE") => Index::Rke { window_s: num(x, "window_s")? },
            Some("KDE") => Index::Kde { window_s: num(x, "window_s")?, separation_s: num(x, "separation_s")? },
            k => return Err(bad(format!("index kind {k:?}: AKE, RKE or KDE"))),
        });
    }
    Ok(IndexSpec { from_s: num(&v, "from_s")?, time_fraction: num(&v, "time_fraction")?, index })
}

/// The indices of an error series with the spec `spec_json` (the `indices` member of
/// `mc_validate`'s JSON): `t_s` (N,) increasing, `err_arcsec` (N, 3); key → arcsec.
#[pyfunction]
fn mc_indices<'py>(
    py: Python<'py>,
    t_s: &Bound<'py, PyAny>,
    err_arcsec: &Bound<'py, PyAny>,
    spec_json: &str,
) -> PyResult<Bound<'py, PyDict>> {
    let spec = index_spec(spec_json)?;
    let t = t_s
        .extract::<PyReadonlyArray1<'_, f64>>()
        .map_err(|_| SsisError::new_err("t_s: expected a 1-D float64 array"))?;
    let e = err_arcsec
        .extract::<PyReadonlyArray2<'_, f64>>()
        .map_err(|_| SsisError::new_err("err_arcsec: expected a float64 array of shape (N, 3)"))?;
    let t: Vec<f64> = t.as_array().iter().copied().collect();
    let shape = e.shape().to_vec();
    if shape.get(1) != Some(&3) || shape.first() != Some(&t.len()) {
        return Err(SsisError::new_err(format!(
            "err_arcsec: shape {shape:?}, expected ({}, 3) (one row per time of t_s)",
            t.len()
        )));
    }
    if let Some(k) = t.iter().position(|x| !x.is_finite()) {
        return Err(SsisError::new_err(format!("t_s[{k}] = {}: not a finite time", t[k])));
    }
    if let Some(k) = t.windows(2).position(|w| w[1] <= w[0]) {
        return Err(SsisError::new_err(format!("t_s[{}] = {} after {}: times must increase", k + 1, t[k + 1], t[k])));
    }
    let flat: Vec<f64> = e.as_array().iter().copied().collect();
    let err: Vec<[f64; 3]> = flat.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect();
    if let Some(k) = err.iter().position(|r| r.iter().any(|x| !x.is_finite())) {
        return Err(SsisError::new_err(format!("err_arcsec[{k}] = {:?}: not finite", err[k])));
    }
    dict(py, &Indices::compute(&spec, &t, &err))
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(mc_validate, m)?)?;
    m.add_function(wrap_pyfunction!(mc_draw, m)?)?;
    m.add_function(wrap_pyfunction!(mc_run, m)?)?;
    m.add_function(wrap_pyfunction!(mc_runs, m)?)?;
    m.add_function(wrap_pyfunction!(mc_indices, m)?)
}
