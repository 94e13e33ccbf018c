//! The calibration methods of `ssis-cal`, on arrays or on a session: the overlapping
//! Allan deviation and its noise terms, the misalignment turns (first method), the SINS
//! reversals (second method), the thermal ANOVA, the magnetic sensitivity and the orbital
//! calibration on telemetry. Each returns the JSON value `ssis-cal … --json` prints under the
//! method's key (ssis_methods::json).

use std::path::PathBuf;

use pyo3::prelude::*;
use ssis::calib::{CalibrationTable, GAMMA_NOMINAL_RAD};
use ssis_common::update;
use ssis_methods::{allan, json, magnetic, misalign_sins, misalign_turns, orbital, thermal_anova};

use crate::core::floats;
use crate::lab::session_of;
use crate::table::PyTable;
use crate::{err, SsisError};

/// Allan deviation of `rate_rad_s` sampled every `dt_s`, 8 τ per decade, and its noise
/// terms (the JSON of `ssis-cal allan`).
#[pyfunction]
fn allan_json(rate_rad_s: &Bound<'_, PyAny>, dt_s: f64) -> PyResult<String> {
    let r = floats(rate_rad_s, "rate_rad_s", "a 1-D float array of rates, rad/s")?;
    if !(dt_s.is_finite() && dt_s > 0.0) {
        return Err(SsisError::new_err(format!("dt_s: {dt_s} is not a sampling interval (s > 0)")));
    }
    if let Some(k) = r.iter().position(|w| !w.is_finite()) {
        return Err(SsisError::new_err(format!("rate_rad_s: sample {k} is {} (every rate must be a number)", r[k])));
    }
    let pts = allan::overlapping_adev(&r, dt_s, 8).map_err(|e| err(e.context("rate_rad_s")))?;
    let nt = allan::noise_terms(&pts).map_err(|e| err(e.context("rate_rad_s")))?;
    Ok(json::allan(&pts, &nt).to_string())
}

/// `ssis-cal allan SESSION --fog FOG`: the static session's rates of one FOG.
#[pyfunction]
fn allan_session_json(session: &Bound<'_, PyAny>, fog: usize) -> PyResult<String> {
    let s = session_of(session)?;
    let rates = allan::static_rates(&s, fog).map_err(err)?;
    let pts = allan::overlapping_adev(&rates, s.median_dt_s(), 8).map_err(|e| err(e.context(s.file.clone())))?;
    let nt = allan::noise_terms(&pts).map_err(|e| err(e.context(s.file.clone())))?;
    Ok(json::allan(&pts, &nt).to_string())
}

/// `ssis-cal turns SESSION [--table T]`: δ12 … δ43 from three calibration turns (γ from
/// `table`, else nominal).
#[pyfunction]
#[pyo3(signature = (session, table = None))]
fn turns_json(session: &Bound<'_, PyAny>, table: Option<&PyTable>) -> PyResult<String> {
    let s = session_of(session)?;
    let (turns, lat) = misalign_turns::turns_from_session(&s).map_err(err)?;
    let gamma = table.map_or(GAMMA_NOMINAL_RAD, |t| t.doc.table.gamma_rad);
    let r = misalign_turns::solve(&turns, lat, gamma).map_err(err)?;
    Ok(json::turns(&turns, &r).to_string())
}

/// `ssis-cal sins SESSION [--table T]`: the triad's six angles from SINS reversals,
/// started from `table`'s misalignment and scale factors (else nominal).
#[pyfunction]
#[pyo3(signature = (session, table = None))]
fn sins_json(session: &Bound<'_, PyAny>, table: Option<&PyTable>) -> PyResult<String> {
    let s = session_of(session)?;
    let (m0, gamma, scale, from) = match table {
        Some(t) => {
            let t = &t.doc.table;
            let scale = [t.fog[0].scale_factor_error, t.fog[1].scale_factor_error, t.fog[2].scale_factor_error];
            (t.misalignment, t.gamma_rad, scale, "the table's")
        }
        None => (CalibrationTable::DEFAULT.misalignment, GAMMA_NOMINAL_RAD, [0.0; 3], "nominal"),
    };
    let revs = misalign_sins::reversals_from_session(&s, scale).map_err(err)?;
    let r = misalign_sins::solve(&revs, &m0, gamma).map_err(err)?;
    Ok(json::sins(&m0, from, &r).to_string())
}

/// `ssis-cal thermal --session S --fog FOG`: the two-factor ANOVA (Tables 1–2) of a chamber
/// session sorted into Table 1's T × G levels, and the thermal model when it is worth
/// building.
#[pyfunction]
#[pyo3(signature = (session, fog = 0))]
fn thermal_json(session: &Bound<'_, PyAny>, fog: usize) -> PyResult<String> {
    let s = session_of(session)?;
    let levels = thermal_anova::Levels::default();
    let window_s = (2.0 * s.median_dt_s()).max(60.0);
    let c = thermal_anova::chamber_cells(&s, fog, &levels, window_s).map_err(err)?;
    let t_lo = levels.t_degc.iter().copied().fold(f64::INFINITY, f64::min);
    let t_hi = levels.t_degc.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    let shape = (levels.t_degc.len(), levels.g_degc_min.len());
    let (a, model) =
        thermal_anova::analyse_and_fit_levels(&c.cells, &c.samples, shape, (t_lo + t_hi) / 2.0).map_err(err)?;
    Ok(json::thermal(&a, model.as_ref()).to_string())
}

/// `ssis-cal magnetic --unscreened U --screened S`: the eq. (1)/(2) fits and the magnetic
/// sensitivity, the field from the sessions' field columns.
#[pyfunction]
fn magnetic_json(unscreened: &Bound<'_, PyAny>, screened: &Bound<'_, PyAny>) -> PyResult<String> {
    let (u, s) = (session_of(unscreened)?, session_of(screened)?);
    let r = magnetic::analyse(&u, &s).map_err(err)?;
    let b0 = u.field_nt.as_ref().map(|f| {
        let psi = u.column("psi_rad").map_or(0.0, |p| p[0]);
        ssis_session::field_nwu_nt(f[0], psi)
    });
    Ok(json::magnetic(&r, b0).to_string())
}

/// `ssis-cal orbital --output O --star S --table T`: zero bias, scale factors and
/// star-tracker mount from a flight's output-link and star-tracker-link captures, and the
/// table flown with the fields found set (what the command line writes into T).
#[pyfunction]
fn orbital_json(output: PathBuf, star: PathBuf, table: &PyTable) -> PyResult<(String, PyTable)> {
    let tel = orbital::Telemetry::read(&output, &star).map_err(err)?;
    let flown = &table.doc;
    let r = orbital::calibrate(&tel, &flown.table, &orbital::Settings::default())
        .map_err(|e| err(e.context(format!("{} and {} with the table given", output.display(), star.display()))))?;
    let tau = orbital::observer_time_constant_s(&flown.table).map_err(err)?;
    if let Some(t_m) = r.settles_after_first_maneuver(&tel) {
        return Err(SsisError::new_err(format!(
            "{}: the observer settles (convergence + 5τ, τ = {tau:.0} s) only after the first maneuver at \
             {t_m:.0} s: no steady part before the maneuvers; fly a longer hold",
            output.display()
        )));
    }
    let origin = update::Origin {
        command: "ssis.cal.orbital".into(),
        session: format!("{} + {}", output.display(), star.display()),
        model: None,
    };
    let (doc, _) = update::apply(flown, &r.table, &r.fields_set(), &origin).map_err(err)?;
    Ok((json::orbital(&r, tau).to_string(), PyTable { doc }))
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(orbital_json, m)?)?;
    m.add_function(wrap_pyfunction!(thermal_json, m)?)?;
    m.add_function(wrap_pyfunction!(magnetic_json, m)?)?;
    m.add_function(wrap_pyfunction!(allan_json, m)?)?;
    m.add_function(wrap_pyfunction!(allan_session_json, m)?)?;
    m.add_function(wrap_pyfunction!(turns_json, m)?)?;
    m.add_function(wrap_pyfunction!(sins_json, m)?)
}
