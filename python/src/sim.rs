//! The simulator's sensor models and quaternion maths for Python (`ssis.basilisk` flies
//! them): `Sensors`, the FOGs and the star tracker of `ssis_sim::sensors` (the harness's,
//! on one random stream); `scenario_steps`, a scenario's per-step frames from the harness's
//! `Simulation` (the path the two must agree with); the quaternion products and rotation
//! vectors of `ssis::math`.

use std::path::PathBuf;

use nalgebra::{Quaternion, Vector3};
use numpy::{IntoPyArray, PyArray1, PyReadonlyArray1};
use pyo3::prelude::*;
use pyo3::types::{PyBytes, PyDict};
use ssis::calib::N_FOG;
use ssis::flight::Profile;
use ssis::frames::decoder::StreamDecoder;
use ssis::frames::fog::FogFrame;
use ssis::frames::star::StarFrame;
use ssis::math::{quat_from_rotvec, rotvec_from_quat};
use ssis_sim::fog::{FogSpec, TrueErrors};
use ssis_sim::harness::Simulation;
use ssis_sim::scenario::Scenario;
use ssis_sim::sensors::{SensorStep, Sensors};
use ssis_sim::star::StarSpec;
use ssis_sim::truth::TruthStep;

use crate::table::PyTable;
use crate::{err, SsisError};

/// The `N` values of a 1-D float64 array, or an error naming `what` and the count.
fn slice<const N: usize>(a: &PyReadonlyArray1<'_, f64>, what: &str) -> PyResult<[f64; N]> {
    let s = a.as_slice().map_err(|e| SsisError::new_err(format!("{what}: {e}")))?;
    <[f64; N]>::try_from(s).map_err(|_| SsisError::new_err(format!("{what}: {} values, expected {N}", s.len())))
}

fn quat(a: &PyReadonlyArray1<'_, f64>, what: &str) -> PyResult<Quaternion<f64>> {
    let [w, x, y, z] = slice::<4>(a, what)?;
    Ok(Quaternion::new(w, x, y, z))
}

fn vec3(a: &PyReadonlyArray1<'_, f64>, what: &str) -> PyResult<Vector3<f64>> {
    Ok(Vector3::from(slice::<3>(a, what)?))
}

fn q_array<'py>(py: Python<'py>, q: &Quaternion<f64>) -> Bound<'py, PyArray1<f64>> {
    vec![q.w, q.i, q.j, q.k].into_pyarray(py)
}

/// A figure of the sensors' arguments: finite and ≥ 0.
fn figure(v: f64, what: &str) -> PyResult<f64> {
    if v.is_finite() && v >= 0.0 {
        Ok(v)
    } else {
        Err(SsisError::new_err(format!("{what}: {v} is not a figure ≥ 0")))
    }
}

/// What the sensors sent in one step, as Python sees it: the FOG increments and
/// temperatures as their frames carry them (quantised), the frames' bytes, the star
/// tracker's solutions delivered in the step `(tag_t_s, q, valid)` and their bytes.
fn step_dict<'py>(py: Python<'py>, time_s: f64, s: &SensorStep) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    let f = &s.fog.frames;
    let mut frames = Vec::with_capacity(N_FOG * FogFrame::LEN);
    for fr in f {
        frames.extend_from_slice(&fr.to_bytes());
    }
    let mut stars = Vec::new();
    let mut dec: StreamDecoder<StarFrame, 256> = StreamDecoder::new();
    dec.push_slice(&s.st_bytes, |r| {
        if let Ok(fr) = r {
            stars.push((fr.time_us as f64 * 1e-6, fr.quaternion().to_vec(), fr.valid()));
        }
    });
    let stars: Vec<_> = stars.into_iter().map(|(t, q, v)| (t, q.into_pyarray(py), v)).collect();
    d.set_item("time_s", time_s)?;
    d.set_item("fog_dtheta_rad", f.map(|fr| fr.dtheta_rad()).to_vec().into_pyarray(py))?;
    d.set_item("temperature_degc", f.map(|fr| fr.temperature_degc()).to_vec().into_pyarray(py))?;
    d.set_item("raw_sys_rad", s.fog.raw_sys_rad.to_vec().into_pyarray(py))?;
    d.set_item("fog_frames", PyBytes::new(py, &frames))?;
    d.set_item("stars", stars)?;
    d.set_item("star_bytes", PyBytes::new(py, &s.st_bytes))?;
    Ok(d)
}

/// The spacecraft unit's FOGs and star tracker as the simulator models them
/// (`ssis_sim::sensors`), for a unit flying `table`: the FOGs' true errors are the table's
/// (a perfect calibration) plus a turn-on bias, bias walk and angle random walk; the
/// tracker has the table's mount, noise and period unless given.
#[pyclass(module = "ssis._ssis", name = "Sensors")]
pub struct PySensors {
    sensors: Sensors,
    n: u64,
    dt_us: u32,
}

#[pymethods]
impl PySensors {
    #[new]
    #[pyo3(signature = (
        table = None,
        seed = 1,
        arw_deg_sqrt_h = None,
        rrw_deg_h_sqrt_h = None,
        turn_on_bias_3sigma_deg_h = 0.0,
        st_sigma_3sigma_arcsec = None,
        st_period_s = None,
        st_latency_s = 0.0,
        st_outages = Vec::new(),
        st_max_rate_deg_s = 2.0,
        star_tracker = true,
    ))]
    #[allow(clippy::too_many_arguments)]
    fn new(
        table: Option<&PyTable>,
        seed: u64,
        arw_deg_sqrt_h: Option<f64>,
        rrw_deg_h_sqrt_h: Option<f64>,
        turn_on_bias_3sigma_deg_h: f64,
        st_sigma_3sigma_arcsec: Option<f64>,
        st_period_s: Option<f64>,
        st_latency_s: f64,
        st_outages: Vec<(f64, f64)>,
        st_max_rate_deg_s: f64,
        star_tracker: bool,
    ) -> PyResult<Self> {
        let t = PyTable::table(table);
        let o = &t.observer;
        let fog = FogSpec {
            arw_deg_sqrt_h: figure(arw_deg_sqrt_h.unwrap_or(o.arw_deg_sqrt_h), "arw_deg_sqrt_h")?,
            rrw_deg_h_sqrt_h: figure(rrw_deg_h_sqrt_h.unwrap_or(o.rrw_deg_h_sqrt_h), "rrw_deg_h_sqrt_h")?,
            random_bias_3sigma_deg_h: figure(turn_on_bias_3sigma_deg_h, "turn_on_bias_3sigma_deg_h")?,
            errors: Some(TrueErrors { fog: t.fog, misalignment: t.misalignment }),
            ..FogSpec::default()
        };
        let period_s = figure(st_period_s.unwrap_or(o.st_period_s), "st_period_s")?;
        if period_s <= 0.0 {
            return Err(SsisError::new_err("st_period_s: 0 is not a period"));
        }
        for (a, b) in &st_outages {
            if !(a.is_finite() && b.is_finite() && a <= b) {
                return Err(SsisError::new_err(format!("st_outages: ({a}, {b}) is not a window (t0 ≤ t1, s)")));
            }
        }
        let star = StarSpec {
            enabled: star_tracker,
            rate_hz: 1.0 / period_s,
            sigma_3sigma_arcsec: figure(
                st_sigma_3sigma_arcsec.unwrap_or(3.0 * o.st_sigma_arcsec),
                "st_sigma_3sigma_arcsec",
            )?,
            latency_ms: figure(st_latency_s, "st_latency_s")? * 1e3,
            max_rate_deg_s: figure(st_max_rate_deg_s, "st_max_rate_deg_s")?,
            outages: st_outages.iter().map(|&(a, b)| [a, b]).collect(),
            ..StarSpec::default()
        };
        let dt_us = Profile::SPACECRAFT.dt_us;
        Ok(PySensors { sensors: Sensors::with_star(&fog, &star, dt_us, t.st_mount(), seed), n: 0, dt_us })
    }

    /// Step period, s.
    #[getter]
    fn dt_s(&self) -> f64 {
        f64::from(self.dt_us) * 1e-6
    }

    /// Steps taken.
    #[getter]
    fn steps(&self) -> u64 {
        self.n
    }

    /// The FOGs' turn-on biases drawn, rad/s.
    #[getter]
    fn turn_on_bias_rad_s<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        self.sensors.fogs.random_bias_rad_s().to_vec().into_pyarray(py)
    }

    /// The next step (its end at `steps × dt_s` after the call): the truth body increment
    /// `dtheta_rad` over it, Λ `q` (scalar first) and the body rate `rate_rad_s` at its
    /// end. Returns `fog_dtheta_rad`, `temperature_degc` (as the frames carry them),
    /// `raw_sys_rad`, `fog_frames` (bytes), `stars` (`[(tag_t_s, q, valid)]` delivered in
    /// this step), `star_bytes`, `time_s`.
    fn step<'py>(
        &mut self,
        py: Python<'py>,
        dtheta_rad: PyReadonlyArray1<'py, f64>,
        q: PyReadonlyArray1<'py, f64>,
        rate_rad_s: PyReadonlyArray1<'py, f64>,
    ) -> PyResult<Bound<'py, PyDict>> {
        let ts_dtheta = vec3(&dtheta_rad, "dtheta_rad")?;
        let ts_q = quat(&q, "q")?;
        let ts_rate = vec3(&rate_rad_s, "rate_rad_s")?;
        if !(ts_dtheta.iter().chain(ts_rate.iter()).all(|v| v.is_finite())) {
            return Err(SsisError::new_err("dtheta_rad, rate_rad_s: not finite"));
        }
        let norm = ts_q.norm();
        if norm.is_nan() || (norm - 1.0).abs() >= 1e-6 {
            return Err(SsisError::new_err(format!("q: norm {norm} is not 1 (a unit quaternion, scalar first)")));
        }
        self.n += 1;
        let now_us = self.n * u64::from(self.dt_us);
        let t_s = now_us as f64 * 1e-6;
        let ts = TruthStep { t_s, dtheta_rad: ts_dtheta, q: ts_q, rate_rad_s: ts_rate };
        let s = self.sensors.step(self.n, now_us, self.dt_s(), &ts);
        step_dict(py, t_s, &s)
    }
}

/// The first `steps` steps of the scenario file `scenario` as the harness makes them
/// (`ssis_sim::harness::Simulation`): per step `n`, its truth (`dtheta_rad`, `q`,
/// `rate_rad_s`) and what the sensors sent (`fog_frames`, `star_bytes`).
#[pyfunction]
fn scenario_steps<'py>(py: Python<'py>, scenario: PathBuf, steps: u64) -> PyResult<Vec<Bound<'py, PyDict>>> {
    let sc = Scenario::from_file(&scenario).map_err(err)?;
    let mut sim = Simulation::new(&sc).map_err(err)?;
    let mut out = Vec::new();
    while let Some(s) = sim.next_step() {
        if s.n > steps {
            break;
        }
        let d = PyDict::new(py);
        d.set_item("n", s.n)?;
        if let Some(t) = &s.truth {
            d.set_item("dtheta_rad", t.dtheta.as_slice().to_vec().into_pyarray(py))?;
            d.set_item("q", q_array(py, &t.q))?;
            d.set_item("rate_rad_s", t.rate.as_slice().to_vec().into_pyarray(py))?;
        }
        d.set_item("fog_frames", PyBytes::new(py, s.fog_frames.as_flattened()))?;
        d.set_item("star_bytes", PyBytes::new(py, &s.st_bytes))?;
        out.push(d);
    }
    Ok(out)
}

/// The quaternion product a ⊗ b (scalar first; Λ_a ∘ Λ_b, the simulator's and the core's).
#[pyfunction]
fn quat_mul<'py>(
    py: Python<'py>,
    a: PyReadonlyArray1<'py, f64>,
    b: PyReadonlyArray1<'py, f64>,
) -> PyResult<Bound<'py, PyArray1<f64>>> {
    Ok(q_array(py, &(quat(&a, "a")? * quat(&b, "b")?)))
}

/// The conjugate of `q` (scalar first).
#[pyfunction]
fn quat_conj<'py>(py: Python<'py>, q: PyReadonlyArray1<'py, f64>) -> PyResult<Bound<'py, PyArray1<f64>>> {
    Ok(q_array(py, &quat(&q, "q")?.conjugate()))
}

/// The unit quaternion of the rotation vector `v`, rad (`ssis::math::quat_from_rotvec`).
#[pyfunction]
fn quat_from_rotation_vector<'py>(
    py: Python<'py>,
    v: PyReadonlyArray1<'py, f64>,
) -> PyResult<Bound<'py, PyArray1<f64>>> {
    Ok(q_array(py, &quat_from_rotvec(&vec3(&v, "v")?)))
}

/// The rotation vector of `q`, rad, the shorter way round (`ssis::math::rotvec_from_quat`).
#[pyfunction]
fn rotation_vector<'py>(py: Python<'py>, q: PyReadonlyArray1<'py, f64>) -> PyResult<Bound<'py, PyArray1<f64>>> {
    Ok(rotvec_from_quat(&quat(&q, "q")?).as_slice().to_vec().into_pyarray(py))
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<PySensors>()?;
    m.add_function(wrap_pyfunction!(scenario_steps, m)?)?;
    m.add_function(wrap_pyfunction!(quat_mul, m)?)?;
    m.add_function(wrap_pyfunction!(quat_conj, m)?)?;
    m.add_function(wrap_pyfunction!(quat_from_rotation_vector, m)?)?;
    m.add_function(wrap_pyfunction!(rotation_vector, m)?)?;
    Ok(())
}
