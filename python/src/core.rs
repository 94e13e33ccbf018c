//! `FlightCore.step` and `FlightCore.run`: 5-ms steps of the spacecraft unit's flight
//! core, fed as the replay feeds it: each step's FOG samples and star-tracker solution go
//! through the replay's encoder (`ssis_sim::replay::Encoder`, the same frames a recorded
//! log gives) onto mock links, then `FlightCore::step`. Every argument is checked here
//! (shape, dtype, length, finite time tags, unit quaternions) and refused with its name.

use numpy::{IntoPyArray, PyArrayMethods, PyReadonlyArray1, PyReadonlyArray2, PyUntypedArrayMethods};
use pyo3::prelude::*;
use pyo3::types::{PyBytes, PyDict, PyList, PyTuple};
use ssis::calib::{CalibrationTable, N_FOG};
use ssis::flight::{Counter, Counters, FlightCore, FogLinks, Links, Profile, StepOutput};
use ssis::frames::fog::FogFrame;
use ssis_common::downlink::{self, Down, Downlink};
use ssis_common::mock::{MockLink, MockSink};
use ssis_common::ARCSEC_PER_RAD;
use ssis_sim::harness::StepInput;
use ssis_sim::recorded::{FogSample, LogStep, StarSample};
use ssis_sim::replay::Encoder as LogEncoder;

use crate::table::PyTable;
use crate::{err, SsisError};

/// How far from 1 the norm of a quaternion given to the unit may be.
const UNIT_NORM_TOL: f64 = 1e-6;

/// A short description of a Python value for messages: an array's shape and dtype, else
/// its type.
pub(crate) fn describe(o: &Bound<'_, PyAny>) -> String {
    if let (Ok(shape), Ok(dtype)) = (o.getattr("shape"), o.getattr("dtype")) {
        return format!("an array of shape {shape} and dtype {dtype}");
    }
    let n = match o.len() {
        Ok(n) if o.is_instance_of::<PyTuple>() || o.is_instance_of::<PyList>() => format!(" of {n} items"),
        _ => String::new(),
    };
    match o.get_type().name() {
        Ok(t) => format!("a `{t}`{n}"),
        Err(_) => "a value of another type".into(),
    }
}

/// `o` as a 1-D sequence of floats (a float64 array, or a list or tuple of numbers);
/// `what` names the argument and `expected` its shape in the message.
pub(crate) fn floats(o: &Bound<'_, PyAny>, what: &str, expected: &str) -> PyResult<Vec<f64>> {
    if let Ok(a) = o.extract::<PyReadonlyArray1<'_, f64>>() {
        return Ok(a.as_array().iter().copied().collect());
    }
    if o.hasattr("dtype").unwrap_or(false) {
        return Err(SsisError::new_err(format!("{what}: expected {expected}, got {}", describe(o))));
    }
    o.extract::<Vec<f64>>().map_err(|_| SsisError::new_err(format!("{what}: expected {expected}, got {}", describe(o))))
}

/// `o` as exactly `N` floats.
pub(crate) fn fixed<const N: usize>(o: &Bound<'_, PyAny>, what: &str) -> PyResult<[f64; N]> {
    let expected = format!("{N} floats (a 1-D array of shape ({N},))");
    let v = floats(o, what, &expected)?;
    let n = v.len();
    <[f64; N]>::try_from(v).map_err(|_| SsisError::new_err(format!("{what}: {n} values, expected {expected}")))
}

/// `q` checked to be a unit quaternion (finite, |q| = 1 within 1e-6).
pub(crate) fn unit_quaternion(q: [f64; 4], what: &str) -> PyResult<[f64; 4]> {
    let norm = q.iter().map(|v| v * v).sum::<f64>().sqrt();
    if !(norm.is_finite() && (norm - 1.0).abs() <= UNIT_NORM_TOL) {
        return Err(SsisError::new_err(format!(
            "{what}: |q| = {norm} for q = {q:?}: a unit quaternion (scalar first, |q| = 1 within {UNIT_NORM_TOL}) is needed"
        )));
    }
    Ok(q)
}

/// A star-tracker time tag checked to be a time of the unit.
fn star_tag_us(tag_s: f64, what: &str) -> PyResult<u64> {
    if !(tag_s.is_finite() && (0.0..1.8e13).contains(&tag_s)) {
        return Err(SsisError::new_err(format!(
            "{what}: time tag {tag_s} s is not a time of the unit (finite, s ≥ 0)"
        )));
    }
    Ok((tag_s * 1e6).round() as u64)
}

/// One step's input, checked.
pub(crate) struct StepIn {
    pub(crate) dtheta_rad: [f64; N_FOG],
    pub(crate) star: Option<(u64, [f64; 4])>,
    pub(crate) temps_degc: Option<[f64; N_FOG]>,
    pub(crate) star_valid: bool,
}

/// A step's arguments as the package's `step` passes them to either unit: the tuple
/// `(fog_dtheta_rad, star, temperature_degc, star_valid)`.
impl<'a, 'py> FromPyObject<'a, 'py> for StepIn {
    type Error = PyErr;

    fn extract(args: Borrowed<'a, 'py, PyAny>) -> PyResult<Self> {
        type Args<'py> = (Bound<'py, PyAny>, Option<Bound<'py, PyAny>>, Option<Bound<'py, PyAny>>, Bound<'py, PyAny>);
        let (dtheta, star, temps, star_valid) = args.extract::<Args<'py>>().map_err(|_| {
            SsisError::new_err(format!(
                "step: expected a tuple of 4 (fog_dtheta_rad, star, temperature_degc, star_valid), got {}",
                describe(&args)
            ))
        })?;
        let star_valid = star_valid
            .extract::<bool>()
            .map_err(|_| SsisError::new_err(format!("star_valid: expected a bool, got {}", describe(&star_valid))))?;
        StepIn::parse(&dtheta, star.as_ref(), temps.as_ref(), star_valid)
    }
}

impl StepIn {
    /// A step's arguments: increments, `(tag_t_s, q)`, temperatures.
    fn parse(
        dtheta: &Bound<'_, PyAny>,
        star: Option<&Bound<'_, PyAny>>,
        temps: Option<&Bound<'_, PyAny>>,
        star_valid: bool,
    ) -> PyResult<StepIn> {
        let dtheta_rad = fixed::<N_FOG>(dtheta, "fog_dtheta_rad")?;
        let star = match star.filter(|s| !s.is_none()) {
            None => None,
            Some(s) => {
                let (tag, q) = s.extract::<(f64, Bound<'_, PyAny>)>().map_err(|_| {
                    SsisError::new_err(format!(
                        "star: expected a tuple (tag_t_s, q) with q 4 floats, got {}",
                        describe(s)
                    ))
                })?;
                Some((star_tag_us(tag, "star")?, unit_quaternion(fixed::<4>(&q, "star q")?, "star q")?))
            }
        };
        let temps_degc = match temps.filter(|t| !t.is_none()) {
            None => None,
            Some(t) => {
                let v = fixed::<N_FOG>(t, "temperature_degc")?;
                if let Some(k) = v.iter().position(|x| !x.is_finite()) {
                    return Err(SsisError::new_err(format!("temperature_degc: FOG {k}'s is {}", v[k])));
                }
                Some(v)
            }
        };
        Ok(StepIn { dtheta_rad, star, temps_degc, star_valid })
    }
}

/// One step's frames from physical values, by the replay's encoder: FOG frames numbered
/// from counter 1 (NaN: the frame is not sent), a star-tracker frame at its tag. Shared by
/// the in-process core and the QEMU unit.
pub(crate) struct Encoder {
    enc: LogEncoder,
    t_ref_degc: [f64; N_FOG],
}

impl Encoder {
    pub(crate) fn new(table: &CalibrationTable) -> Self {
        Encoder::resumed(table, 0, 0)
    }

    fn resumed(table: &CalibrationTable, steps: u64, st_counter: u16) -> Self {
        Encoder {
            enc: LogEncoder::resumed(table, Profile::SPACECRAFT.dt_us, steps, st_counter),
            t_ref_degc: std::array::from_fn(|i| table.fog[i].t_ref_degc),
        }
    }

    /// Steps encoded.
    pub(crate) fn steps(&self) -> u64 {
        self.enc.steps()
    }

    /// The next step's input (no truth).
    pub(crate) fn encode(&mut self, s: &StepIn) -> StepInput {
        let temps = s.temps_degc.unwrap_or(self.t_ref_degc);
        let step = LogStep {
            fog: std::array::from_fn(|i| {
                let d = s.dtheta_rad[i];
                d.is_finite().then_some(FogSample { dtheta_rad: d, t_degc: temps[i], status: 0 })
            }),
            accel: Default::default(),
            st: s.star.map(|(time_us, q)| StarSample { time_us, valid: s.star_valid, q }).into_iter().collect(),
            gnss: Vec::new(),
            truth: None,
        };
        self.enc.encode(&step)
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
    d.set_item("fog_health", o.fog_health.map(u32::from).to_vec())?;
    d.set_item("fogs_used", o.fogs_used.0)?;
    d.set_item("fdi", o.fdi)?;
    d.set_item("events", events)?;
    d.set_item("counters_moved", counters_moved)?;
    Ok(d)
}

/// The pickled form's first bytes (the format; the build is checked by the core's size
/// and the package version that follow).
const STATE_MAGIC: &[u8; 8] = b"SSISFC01";

/// Bytes of `b` from `*at`, advancing it; a short state is refused.
fn take<'a>(b: &'a [u8], at: &mut usize, n: usize) -> PyResult<&'a [u8]> {
    let s = b
        .get(*at..at.saturating_add(n))
        .ok_or_else(|| SsisError::new_err("state: truncated (not a pickled FlightCore of this build)"))?;
    *at += n;
    Ok(s)
}

fn take_u64(b: &[u8], at: &mut usize) -> PyResult<u64> {
    let s = take(b, at, 8)?;
    Ok(u64::from_le_bytes(std::array::from_fn(|i| s[i])))
}

impl PyFlightCore {
    fn with(core: FlightCore, enc: Encoder) -> Self {
        PyFlightCore {
            last: core.counters(),
            core,
            enc,
            fog: MockLink::ideal(),
            star: MockLink::ideal(),
            out: MockSink::default(),
            down: Downlink::new(),
        }
    }

    /// One step of the core on `input`; the output and the event frames it sent after it
    /// (at most one per step).
    fn step_input(&mut self, input: &StepInput) -> (StepOutput, Vec<ssis::frames::event::EventFrame>) {
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
        // The output frame is `o`; the event frame the board sends after it, when a record
        // waits, is decoded.
        self.out.bytes.clear();
        self.core.send_events(&mut self.out);
        let mut frames = Vec::new();
        if !self.out.bytes.is_empty() {
            self.down.push(&self.out.bytes, |d| {
                if let Down::Events(f) = d {
                    frames.push(f);
                }
            });
            self.out.bytes.clear();
        }
        (o, frames)
    }

    /// The full state: the core's bytes (every field but the table takes any bit pattern),
    /// the table as TOML, the encoder's counters.
    fn state(&self) -> PyResult<Vec<u8>> {
        let size = std::mem::size_of::<FlightCore>();
        let table = ssis_common::table::to_toml(self.core.table()).map_err(|e| err(e.into()))?;
        let mut b = Vec::with_capacity(size + table.len() + 64);
        b.extend_from_slice(STATE_MAGIC);
        b.extend_from_slice(&(size as u64).to_le_bytes());
        let version = env!("CARGO_PKG_VERSION").as_bytes();
        b.extend_from_slice(&(version.len() as u64).to_le_bytes());
        b.extend_from_slice(version);
        b.extend_from_slice(&(table.len() as u64).to_le_bytes());
        b.extend_from_slice(table.as_bytes());
        // SAFETY: reads the core's `size` bytes as they are (a `repr(C)` value with no
        // pointers: every field but the table takes any bit pattern, the table is carried
        // as TOML and not read back from these bytes).
        let raw = unsafe { std::slice::from_raw_parts((&raw const self.core).cast::<u8>(), size) };
        b.extend_from_slice(raw);
        b.extend_from_slice(&self.enc.steps().to_le_bytes());
        b.extend_from_slice(&self.enc.enc.st_counter().to_le_bytes());
        Ok(b)
    }

    fn from_state(b: &[u8]) -> PyResult<Self> {
        let size = std::mem::size_of::<FlightCore>();
        let mut at = 0;
        let other = || SsisError::new_err("state: pickled by another build of ssis (its FlightCore differs)");
        if take(b, &mut at, 8)? != STATE_MAGIC {
            return Err(SsisError::new_err("state: not a pickled FlightCore"));
        }
        if take_u64(b, &mut at)? != size as u64 {
            return Err(other());
        }
        let n = take_u64(b, &mut at)? as usize;
        if take(b, &mut at, n)? != env!("CARGO_PKG_VERSION").as_bytes() {
            return Err(other());
        }
        let n = take_u64(b, &mut at)? as usize;
        let text = std::str::from_utf8(take(b, &mut at, n)?).map_err(|_| other())?;
        let table = ssis_common::table::parse_toml(text, "(pickled table)").map_err(|e| err(e.into()))?;
        let mut core =
            FlightCore::new(Profile::SPACECRAFT, &table, false).map_err(|e| err(anyhow::anyhow!("core: {e:?}")))?;
        let raw = take(b, &mut at, size)?;
        let keep = FlightCore::TABLE_BYTES;
        // SAFETY: writes every byte but the table's: those fields take any bit pattern
        // (`FlightCore`'s `AnyBitPattern` list); the table is the one just built.
        unsafe {
            let dst = (&raw mut core).cast::<u8>();
            std::ptr::copy_nonoverlapping(raw.as_ptr(), dst, keep.start);
            std::ptr::copy_nonoverlapping(raw.as_ptr().add(keep.end), dst.add(keep.end), size - keep.end);
        }
        let steps = take_u64(b, &mut at)?;
        let st = take(b, &mut at, 2)?;
        let st_counter = u16::from_le_bytes([st[0], st[1]]);
        Ok(PyFlightCore::with(core, Encoder::resumed(&table, steps, st_counter)))
    }
}

#[pymethods]
impl PyFlightCore {
    /// The core with `table` (default: the nominal table).
    #[new]
    #[pyo3(signature = (table = None))]
    fn new(table: Option<&PyTable>) -> PyResult<Self> {
        let t = PyTable::table(table);
        let core = FlightCore::new(Profile::SPACECRAFT, &t, false).map_err(|e| err(anyhow::anyhow!("core: {e:?}")))?;
        Ok(PyFlightCore::with(core, Encoder::new(&t)))
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

    /// Aligns the attitude to `q` (Λ, scalar first, a unit quaternion), as a pad
    /// alignment does.
    fn align(&mut self, q: &Bound<'_, PyAny>) -> PyResult<()> {
        let q = unit_quaternion(fixed::<4>(q, "q")?, "q")?;
        self.core.align(nalgebra::Quaternion::new(q[0], q[1], q[2], q[3]));
        Ok(())
    }

    /// One step from `(fog_dtheta_rad, star, temperature_degc, star_valid)` ([`StepIn`]):
    /// the four FOGs' raw increments over the step (NaN: the sample does not arrive), a
    /// star-tracker solution `(tag_t_s, q)` arriving in this step or `None` (q = Λ*, scalar
    /// first, the instant `tag_t_s` of unit time), the temperature per FOG or `None` (each
    /// FOG's reference temperature), whether the tracker flags its solution valid.
    fn step<'py>(&mut self, py: Python<'py>, args: StepIn) -> PyResult<Bound<'py, PyDict>> {
        let input = self.enc.encode(&args);
        let (o, frames) = self.step_input(&input);
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

    /// N steps from arrays, stepped in Rust: `fog_dtheta_rad` (N, 4) (NaN: the sample does
    /// not arrive), `star_t_s` (N,) the tag of a star-tracker solution arriving in step k
    /// (NaN: none), `star_q` (N, 4) its quaternion (rows without a solution are not read),
    /// optional `temperature_degc` (N, 4) and `star_valid` (N,). Returns per-step arrays
    /// (the fields of `step`, one row per step) and the events, each with its `step`.
    #[pyo3(signature = (fog_dtheta_rad, star_t_s = None, star_q = None, temperature_degc = None, star_valid = None))]
    fn run<'py>(
        &mut self,
        py: Python<'py>,
        fog_dtheta_rad: &Bound<'py, PyAny>,
        star_t_s: Option<&Bound<'py, PyAny>>,
        star_q: Option<&Bound<'py, PyAny>>,
        temperature_degc: Option<&Bound<'py, PyAny>>,
        star_valid: Option<&Bound<'py, PyAny>>,
    ) -> PyResult<Bound<'py, PyDict>> {
        let dtheta = matrix(fog_dtheta_rad, "fog_dtheta_rad", None)?;
        let n = dtheta.len() / N_FOG;
        let none = |o: Option<&Bound<'py, PyAny>>| o.filter(|o| !o.is_none()).cloned();
        let (star_t, star_q) = match (none(star_t_s), none(star_q)) {
            (None, None) => (vec![f64::NAN; n], Vec::new()),
            (Some(t), Some(q)) => (floats_n(&t, "star_t_s", n)?, matrix(&q, "star_q", Some(n))?),
            _ => return Err(SsisError::new_err("star_t_s and star_q: give both (or neither)")),
        };
        let temps = none(temperature_degc).map(|t| matrix(&t, "temperature_degc", Some(n))).transpose()?;
        let valid: Vec<bool> = match none(star_valid) {
            None => vec![true; n],
            Some(v) => {
                let f = floats_n(&v, "star_valid", n)?;
                f.iter().map(|x| *x != 0.0).collect()
            }
        };
        // Every row checked before the first step (a refused run leaves the core as it was).
        let mut inputs = Vec::with_capacity(n);
        for k in 0..n {
            let row = |m: &[f64]| -> [f64; 4] { std::array::from_fn(|i| m[4 * k + i]) };
            let star = if star_t[k].is_nan() {
                None
            } else {
                let what = format!("star_q[{k}]");
                Some((star_tag_us(star_t[k], &format!("star_t_s[{k}]"))?, unit_quaternion(row(&star_q), &what)?))
            };
            let temps_degc = temps.as_ref().map(|t| row(t));
            if let Some(t) = temps_degc.filter(|t| t.iter().any(|x| !x.is_finite())) {
                return Err(SsisError::new_err(format!("temperature_degc[{k}]: {t:?} is not finite")));
            }
            inputs.push(StepIn { dtheta_rad: row(&dtheta), star, temps_degc, star_valid: valid[k] });
        }
        let mut s = RunSeries::with_capacity(n);
        let mut events = Vec::new();
        for (k, i) in inputs.iter().enumerate() {
            let input = self.enc.encode(i);
            let (o, frames) = self.step_input(&input);
            s.push(&o);
            if !frames.is_empty() {
                for d in event_dicts(py, &frames)? {
                    d.set_item("step", k)?;
                    events.push(d);
                }
            }
        }
        self.last = self.core.counters();
        s.into_dict(py, events)
    }

    /// The unit's counters, by name.
    fn counters(&self) -> Vec<(String, u32)> {
        counter_list(&self.core.counters())
    }

    /// The full state (pickle): the core, its table and the step count; a core restored
    /// from it continues bit for bit as this one would.
    fn __getstate__<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyBytes>> {
        Ok(PyBytes::new(py, &self.state()?))
    }

    fn __setstate__(&mut self, state: &[u8]) -> PyResult<()> {
        *self = PyFlightCore::from_state(state)?;
        Ok(())
    }

    fn __copy__(&self) -> PyResult<Self> {
        PyFlightCore::from_state(&self.state()?)
    }

    fn __deepcopy__(&self, _memo: &Bound<'_, PyAny>) -> PyResult<Self> {
        self.__copy__()
    }

    fn __repr__(&self) -> String {
        let o = self.core.last_output();
        format!(
            "FlightCore(steps={}, time_s={:.3}, flags=0x{:02x}, st_status=0x{:02x}, table_crc=0x{:08x})",
            self.enc.steps(),
            o.time_us as f64 * 1e-6,
            o.flags,
            o.st_status,
            self.core.table_crc()
        )
    }
}

/// `o` as a C-ordered (rows, 4) float64 array, flat; `rows` checked when given.
fn matrix(o: &Bound<'_, PyAny>, what: &str, rows: Option<usize>) -> PyResult<Vec<f64>> {
    let shape = rows.map_or("(N, 4)".to_string(), |n| format!("({n}, 4)"));
    let bad = || SsisError::new_err(format!("{what}: expected a float64 array of shape {shape}, got {}", describe(o)));
    let a = o.extract::<PyReadonlyArray2<'_, f64>>().map_err(|_| bad())?;
    let [r, c] = [a.shape()[0], a.shape()[1]];
    if c != 4 || rows.is_some_and(|n| n != r) {
        return Err(bad());
    }
    Ok(a.as_array().iter().copied().collect())
}

/// `o` as exactly `n` floats.
fn floats_n(o: &Bound<'_, PyAny>, what: &str, n: usize) -> PyResult<Vec<f64>> {
    let expected = format!("a 1-D array of shape ({n},)");
    let v = floats(o, what, &expected)?;
    if v.len() != n {
        return Err(SsisError::new_err(format!("{what}: {} values, expected {expected}", v.len())));
    }
    Ok(v)
}

/// `run`'s per-step series.
struct RunSeries {
    time_s: Vec<f64>,
    q: Vec<f64>,
    rate_rad_s: Vec<f64>,
    drift_rad_s: Vec<f64>,
    att_sigma_arcsec: Vec<f64>,
    drift_sigma_rad_s: Vec<f64>,
    parity_rad: Vec<f64>,
    flags: Vec<u8>,
    st_status: Vec<u8>,
    fog_health: Vec<u8>,
    fogs_used: Vec<u8>,
    fdi: Vec<u8>,
}

impl RunSeries {
    fn with_capacity(n: usize) -> Self {
        RunSeries {
            time_s: Vec::with_capacity(n),
            q: Vec::with_capacity(4 * n),
            rate_rad_s: Vec::with_capacity(3 * n),
            drift_rad_s: Vec::with_capacity(3 * n),
            att_sigma_arcsec: Vec::with_capacity(3 * n),
            drift_sigma_rad_s: Vec::with_capacity(3 * n),
            parity_rad: Vec::with_capacity(n),
            flags: Vec::with_capacity(n),
            st_status: Vec::with_capacity(n),
            fog_health: Vec::with_capacity(4 * n),
            fogs_used: Vec::with_capacity(n),
            fdi: Vec::with_capacity(n),
        }
    }

    fn push(&mut self, o: &StepOutput) {
        self.time_s.push(o.time_us as f64 * 1e-6);
        self.q.extend_from_slice(&[o.q.w, o.q.i, o.q.j, o.q.k]);
        self.rate_rad_s.extend_from_slice(o.rate_rad_s.as_slice());
        self.drift_rad_s.extend_from_slice(o.drift_rad_s.as_slice());
        self.att_sigma_arcsec.extend(o.att_sigma_rad.map(|v| v * ARCSEC_PER_RAD));
        self.drift_sigma_rad_s.extend_from_slice(&o.drift_sigma_rad_s);
        self.parity_rad.push(o.parity_rad);
        self.flags.push(o.flags);
        self.st_status.push(o.st_status);
        self.fog_health.extend_from_slice(&o.fog_health);
        self.fogs_used.push(o.fogs_used.0);
        self.fdi.push(o.fdi);
    }

    fn into_dict<'py>(self, py: Python<'py>, events: Vec<Bound<'py, PyDict>>) -> PyResult<Bound<'py, PyDict>> {
        let n = self.time_s.len();
        let d = PyDict::new(py);
        let shaped = |v: Vec<f64>, w: usize| v.into_pyarray(py).reshape([n, w]);
        d.set_item("time_s", self.time_s.into_pyarray(py))?;
        d.set_item("q", shaped(self.q, 4)?)?;
        d.set_item("rate_rad_s", shaped(self.rate_rad_s, 3)?)?;
        d.set_item("drift_rad_s", shaped(self.drift_rad_s, 3)?)?;
        d.set_item("att_sigma_arcsec", shaped(self.att_sigma_arcsec, 3)?)?;
        d.set_item("drift_sigma_rad_s", shaped(self.drift_sigma_rad_s, 3)?)?;
        d.set_item("parity_rad", self.parity_rad.into_pyarray(py))?;
        d.set_item("flags", self.flags.into_pyarray(py))?;
        d.set_item("st_status", self.st_status.into_pyarray(py))?;
        d.set_item("fog_health", self.fog_health.into_pyarray(py).reshape([n, 4])?)?;
        d.set_item("fogs_used", self.fogs_used.into_pyarray(py))?;
        d.set_item("fdi", self.fdi.into_pyarray(py))?;
        d.set_item("events", events)?;
        Ok(d)
    }
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<PyFlightCore>()
}
