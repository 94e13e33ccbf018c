//! `FlightCore.step`: one 5-ms step of the spacecraft unit's flight core, fed as the
//! simulator and the replay feed it: each FOG's increment encoded in its frame
//! (`FogFrame::from_physical`, NaN = the frame does not arrive), the star tracker's
//! solution in its frame at its time tag, all on mock links, then `FlightCore::step`.

use numpy::{IntoPyArray, PyReadonlyArray1};
use pyo3::prelude::*;
use pyo3::types::PyDict;
use ssis::calib::{CalibrationTable, N_FOG};
use ssis::combination::FogSet;
use ssis::flight::{Counter, Counters, FlightCore, FogLinks, Links, Profile, StepOutput};
use ssis::frames::fog::FogFrame;
use ssis::frames::star::{self, StarFrame};
use ssis_common::downlink::{self, Down, Downlink};
use ssis_common::mock::{MockLink, MockSink};
use ssis_common::ARCSEC_PER_RAD;
use ssis_sim::harness::StepInput;

use crate::table::PyTable;
use crate::{err, SsisError};

/// One step's frames from physical values: FOG frames numbered from counter 1 (NaN: the
/// frame is not sent), a star-tracker frame at its tag; what the simulator's and the
/// replay's `StepInput` carry. Shared by the in-process core and the QEMU unit.
pub(crate) struct Encoder {
    table: CalibrationTable,
    n: u64,
    st_counter: u16,
}

/// A step's arguments as Python passes them: increments, `(tag_t_s, q)`, temperatures.
pub(crate) type StepArgs<'a, 'py> =
    (&'a PyReadonlyArray1<'py, f64>, Option<(f64, PyReadonlyArray1<'py, f64>)>, Option<PyReadonlyArray1<'py, f64>>);

impl Encoder {
    pub(crate) fn new(table: CalibrationTable) -> Self {
        Encoder { table, n: 0, st_counter: 0 }
    }

    /// Steps encoded.
    pub(crate) fn steps(&self) -> u64 {
        self.n
    }

    /// The next step's input (no truth).
    pub(crate) fn encode(&mut self, (dtheta, star, temps): StepArgs<'_, '_>, star_valid: bool) -> PyResult<StepInput> {
        let dtheta = slice::<N_FOG>(dtheta, "fog_dtheta_rad")?;
        let temps = match &temps {
            Some(t) => slice::<N_FOG>(t, "temperature_degc")?,
            None => std::array::from_fn(|i| self.table.fog[i].t_ref_degc),
        };
        let mut st_bytes = Vec::new();
        if let Some((tag_s, q)) = star {
            let q = slice::<4>(&q, "star q")?;
            if !(tag_s.is_finite() && tag_s >= 0.0) {
                return Err(SsisError::new_err(format!("star: tag_t_s {tag_s} is not a time of the unit (s ≥ 0)")));
            }
            self.st_counter = self.st_counter.wrapping_add(1);
            let flags = if star_valid { star::flags::VALID } else { 0 };
            let f = StarFrame::from_physical(flags, self.st_counter, (tag_s * 1e6).round() as u64, q);
            st_bytes.extend_from_slice(&f.to_bytes());
        }
        self.n += 1;
        let counter = (self.n % 65_536) as u16;
        let mut present = 0u8;
        let fog_frames = std::array::from_fn(|i| {
            if dtheta[i].is_finite() {
                present |= 1 << i;
                FogFrame::from_physical(i as u8, counter, 0, dtheta[i], temps[i]).to_bytes()
            } else {
                [0; FogFrame::LEN]
            }
        });
        Ok(StepInput { n: self.n, fog_frames, present: FogSet(present), st_bytes, truth: None })
    }
}

/// The spacecraft unit's flight core, in-process.
#[pyclass(module = "ssis._ssis", name = "FlightCore")]
pub struct PyFlightCore {
    core: FlightCore,
    enc: Encoder,
    fog: MockLink,
    star: MockLink,
    out: MockSink,
    down: Downlink,
    last: Counters,
}

/// Every unit counter with its (Debug) name and value, in declaration order.
fn counter_list(c: &Counters) -> Vec<(String, u32)> {
    Counter::ALL.iter().map(|&k| (format!("{k:?}"), c.get(k))).collect()
}

pub(crate) fn slice<const N: usize>(a: &PyReadonlyArray1<'_, f64>, what: &str) -> PyResult<[f64; N]> {
    let s = a.as_slice().map_err(|e| SsisError::new_err(format!("{what}: {e}")))?;
    <[f64; N]>::try_from(s).map_err(|_| SsisError::new_err(format!("{what}: {} values, expected {N}", s.len())))
}

/// A step's events (the unit's event log, as its event frames carry it) as dicts: `time_s`,
/// `seq`, `event`, `a`, `b`, `details` (docs/JSON.md, `events`).
pub(crate) fn event_dicts<'py>(
    py: Python<'py>,
    frames: &[ssis::frames::event::EventFrame],
) -> PyResult<Vec<Bound<'py, PyDict>>> {
    let (records, _) = downlink::records(frames);
    records
        .iter()
        .map(|r| {
            let d = PyDict::new(py);
            d.set_item("time_s", r.time_us as f64 * 1e-6)?;
            d.set_item("seq", r.seq)?;
            d.set_item("event", r.event.name())?;
            d.set_item("a", r.a)?;
            d.set_item("b", r.b)?;
            d.set_item("details", downlink::details(r))?;
            Ok(d)
        })
        .collect()
}

fn output_dict<'py>(
    py: Python<'py>,
    o: &StepOutput,
    events: Vec<Bound<'py, PyDict>>,
    counters_moved: Vec<(String, u32)>,
) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    d.set_item("time_s", o.time_us as f64 * 1e-6)?;
    d.set_item("q", vec![o.q.w, o.q.i, o.q.j, o.q.k].into_pyarray(py))?;
    d.set_item("rate_rad_s", o.rate_rad_s.as_slice().to_vec().into_pyarray(py))?;
    d.set_item("drift_rad_s", o.drift_rad_s.as_slice().to_vec().into_pyarray(py))?;
    d.set_item("att_sigma_arcsec", o.att_sigma_rad.map(|v| v * ARCSEC_PER_RAD).to_vec().into_pyarray(py))?;
    d.set_item("drift_sigma_rad_s", o.drift_sigma_rad_s.to_vec().into_pyarray(py))?;
    d.set_item("parity_rad", o.parity_rad)?;
    d.set_item("flags", o.flags)?;
    d.set_item("st_status", o.st_status)?;
    d.set_item("fog_health", o.fog_health.to_vec())?;
    d.set_item("fogs_used", o.fogs_used.0)?;
    d.set_item("fdi", o.fdi)?;
    d.set_item("events", events)?;
    d.set_item("counters_moved", counters_moved)?;
    Ok(d)
}

#[pymethods]
impl PyFlightCore {
    /// The core with `table` (default: the nominal table).
    #[new]
    #[pyo3(signature = (table = None))]
    fn new(table: Option<&PyTable>) -> PyResult<Self> {
        let t = PyTable::table(table);
        let core = FlightCore::new(Profile::SPACECRAFT, &t, false).map_err(|e| err(anyhow::anyhow!("core: {e:?}")))?;
        Ok(PyFlightCore {
            last: core.counters(),
            core,
            enc: Encoder::new(t),
            fog: MockLink::ideal(),
            star: MockLink::ideal(),
            out: MockSink::default(),
            down: Downlink::new(),
        })
    }

    /// Step period, s.
    #[getter]
    fn dt_s(&self) -> f64 {
        Profile::SPACECRAFT.dt_s()
    }

    /// Steps taken.
    #[getter]
    fn steps(&self) -> u64 {
        self.enc.steps()
    }

    /// Aligns the attitude to `q` (Λ, scalar first), as a pad alignment does.
    fn align(&mut self, q: PyReadonlyArray1<'_, f64>) -> PyResult<()> {
        let q = slice::<4>(&q, "q")?;
        self.core.align(nalgebra::Quaternion::new(q[0], q[1], q[2], q[3]));
        Ok(())
    }

    /// One step: `fog_dtheta_rad` the four FOGs' raw increments over the step (NaN: the
    /// sample does not arrive), `star` = `(tag_t_s, q)` a star-tracker solution arriving
    /// in this step (q = Λ*, scalar first, the instant `tag_t_s` of unit time), optional
    /// `temperature_degc` per FOG (default: each FOG's reference temperature).
    #[pyo3(signature = (fog_dtheta_rad, star = None, temperature_degc = None, star_valid = true))]
    fn step<'py>(
        &mut self,
        py: Python<'py>,
        fog_dtheta_rad: PyReadonlyArray1<'py, f64>,
        star: Option<(f64, PyReadonlyArray1<'py, f64>)>,
        temperature_degc: Option<PyReadonlyArray1<'py, f64>>,
        star_valid: bool,
    ) -> PyResult<Bound<'py, PyDict>> {
        let input = self.enc.encode((&fog_dtheta_rad, star, temperature_degc), star_valid)?;
        let mut bytes = Vec::with_capacity(N_FOG * FogFrame::LEN);
        for (i, f) in input.fog_frames.iter().enumerate() {
            if input.present.contains(i) {
                bytes.extend_from_slice(f);
            }
        }
        self.fog.send(&bytes);
        self.star.send(&input.st_bytes);
        let mut links = Links { fog: FogLinks::Bus(&mut self.fog), star: &mut self.star, out: &mut self.out };
        let o = self.core.step(&mut links);
        // The event frame the board sends after the step's output frame, when a record waits.
        self.core.send_events(&mut self.out);
        let mut frames = Vec::new();
        self.down.push(&self.out.bytes, |d| {
            if let Down::Events(f) = d {
                frames.push(f);
            }
        });
        self.out.bytes.clear();
        let events = event_dicts(py, &frames)?;
        let now = self.core.counters();
        let counters_moved = Counter::ALL
            .iter()
            .filter_map(|&k| {
                let d = now.get(k).saturating_sub(self.last.get(k));
                (d > 0).then(|| (format!("{k:?}"), d))
            })
            .collect();
        self.last = now;
        output_dict(py, &o, events, counters_moved)
    }

    /// The unit's counters, by name.
    fn counters(&self) -> Vec<(String, u32)> {
        counter_list(&self.core.counters())
    }
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<PyFlightCore>()
}
