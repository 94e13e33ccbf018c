//! The model lab (`ssis-lab`): sessions (read, or from arrays), models (init, read,
//! write), and compare, diagnose, add, export and report, on a session file (streamed, as
//! the command line does) or a session in memory. Each returns the JSON value `ssis-lab …
//! --json` prints (ssis_lab::json); `add` and `export` return the new model or table
//! rather than writing it, and the caller writes it where it wants.

use std::path::PathBuf;

use numpy::{IntoPyArray, PyArray1};
use pyo3::prelude::*;
use pyo3::types::PyBytes;
use ssis_common::update;
use ssis_common::DEG_H_PER_RAD_S;
use ssis_lab::diagnose::{candidate_terms, diagnose_digest, diagnose_with_progress, Options};
use ssis_lab::fit::{add_steps, complete, fit_digest, held_out_many, pooled, spec_for, DEFAULT_BLOCKS};
use ssis_lab::model::{Kind, Model};
use ssis_lab::session::{read_session, session_from_columns, Session};
use ssis_lab::stream::{digest, Source};
use ssis_lab::{export, json, report};

use crate::core::floats;
use crate::table::PyTable;
use crate::{err, SsisError};

fn lab_err(e: ssis_lab::LabError) -> PyErr {
    SsisError::new_err(e.to_string())
}

/// A ground-test session (docs/SESSION-FORMAT.md) in memory.
#[pyclass(module = "ssis._ssis", name = "Session")]
#[derive(Clone)]
pub struct PySession {
    pub(crate) s: Session,
}

#[pymethods]
impl PySession {
    /// `Session()`: an empty session (what an unpickled session starts from).
    #[new]
    fn new() -> Self {
        let s = Session {
            file: String::new(),
            names: Vec::new(),
            cols: Vec::new(),
            roles: Vec::new(),
            fogs: Vec::new(),
            ref_rad_s: Vec::new(),
            field_nt: None,
            lines: Vec::new(),
        };
        PySession { s }
    }

    /// Reads and checks a session file (errors name the file, line and column).
    #[staticmethod]
    fn read(path: PathBuf) -> PyResult<Self> {
        read_session(&path, None).map(|s| PySession { s }).map_err(|e| SsisError::new_err(e.to_string()))
    }

    /// A session from columns named as in a session file (`t_s`, `fog0_rate_rad_s`, …),
    /// checked as a file is (`name` stands for the file in messages).
    #[staticmethod]
    #[pyo3(signature = (names, columns, name = "(arrays)".to_string()))]
    fn from_arrays(names: Vec<String>, columns: Vec<Bound<'_, PyAny>>, name: String) -> PyResult<Self> {
        if names.len() != columns.len() {
            return Err(SsisError::new_err(format!(
                "{name}: columns: {} names and {} columns (one column per name)",
                names.len(),
                columns.len()
            )));
        }
        let cols = columns
            .iter()
            .zip(&names)
            .map(|(c, n)| floats(c, &format!("{name}: column `{n}`"), "a 1-D float array"))
            .collect::<PyResult<Vec<_>>>()?;
        if let Some(k) = cols.iter().position(|c| c.len() != cols[0].len()) {
            return Err(SsisError::new_err(format!(
                "{name}: column `{}` has {} values and `{}` {}: every column needs one value per row",
                names[k],
                cols[k].len(),
                names[0],
                cols[0].len()
            )));
        }
        session_from_columns(&name, names, &cols)
            .map(|s| PySession { s })
            .map_err(|e| SsisError::new_err(e.to_string()))
    }

    /// Column names, in file order.
    #[getter]
    fn names(&self) -> Vec<String> {
        self.s.names.clone()
    }

    /// The file (or name) it came from.
    #[getter]
    fn file(&self) -> String {
        self.s.file.clone()
    }

    /// Median sample interval, s.
    #[getter]
    fn median_dt_s(&self) -> f64 {
        self.s.median_dt_s()
    }

    fn __len__(&self) -> usize {
        self.s.len()
    }

    /// Column `name` as an array.
    fn column<'py>(&self, py: Python<'py>, name: &str) -> PyResult<Bound<'py, PyArray1<f64>>> {
        let c = self.s.column(name).ok_or_else(|| {
            SsisError::new_err(format!("{}: no column `{name}` (columns: {})", self.s.file, self.s.names.join(", ")))
        })?;
        Ok(c.to_vec().into_pyarray(py))
    }

    /// The session's CSV text (what `write` writes).
    fn to_csv(&self) -> String {
        ssis_lab::session::session_csv(&self.s)
    }

    /// The pickled form: every column and derived series, exact.
    fn __getstate__<'py>(&self, py: Python<'py>) -> Bound<'py, PyBytes> {
        PyBytes::new(py, &session_state(&self.s))
    }

    fn __setstate__(&mut self, state: &[u8]) -> PyResult<()> {
        self.s = session_from_state(state)
            .ok_or_else(|| SsisError::new_err("state: not a pickled Session of this version of ssis"))??;
        Ok(())
    }

    fn __copy__(&self) -> Self {
        self.clone()
    }

    fn __deepcopy__(&self, _memo: &Bound<'_, PyAny>) -> Self {
        self.clone()
    }

    fn __repr__(&self) -> String {
        let t = self.s.t_s();
        format!(
            "Session({:?}, rows={}, t_s={}…{}, columns={})",
            self.s.file,
            self.s.len(),
            t.first().copied().unwrap_or(f64::NAN),
            t.last().copied().unwrap_or(f64::NAN),
            self.s.names.len()
        )
    }
}

/// A session's pickled form: its file name, names, columns and derived series, as
/// length-prefixed little-endian words.
fn session_state(s: &Session) -> Vec<u8> {
    let mut b = Vec::new();
    let put = |b: &mut Vec<u8>, v: u64| b.extend_from_slice(&v.to_le_bytes());
    let text = |b: &mut Vec<u8>, t: &str| {
        put(b, t.len() as u64);
        b.extend_from_slice(t.as_bytes());
    };
    let floats = |b: &mut Vec<u8>, v: &[f64]| {
        put(b, v.len() as u64);
        for x in v {
            b.extend_from_slice(&x.to_le_bytes());
        }
    };
    b.extend_from_slice(b"SSISSE01");
    text(&mut b, &s.file);
    put(&mut b, s.names.len() as u64);
    for (n, c) in s.names.iter().zip(&s.cols) {
        text(&mut b, n);
        floats(&mut b, c);
    }
    put(&mut b, s.fogs.len() as u64);
    for f in &s.fogs {
        floats(&mut b, &f.rate_rad_s);
        put(&mut b, u64::from(f.t_degc.is_some()));
        floats(&mut b, f.t_degc.as_deref().unwrap_or(&[]));
    }
    floats(&mut b, &s.ref_rad_s.iter().flatten().copied().collect::<Vec<_>>());
    put(&mut b, u64::from(s.field_nt.is_some()));
    floats(&mut b, &s.field_nt.iter().flatten().flatten().copied().collect::<Vec<_>>());
    put(&mut b, s.lines.len() as u64);
    for l in &s.lines {
        put(&mut b, *l);
    }
    b
}

/// The session of [`session_state`]'s bytes (`None`: not such bytes; an error: the header
/// no longer parses).
fn session_from_state(b: &[u8]) -> Option<PyResult<Session>> {
    let mut r = Reader { b, at: 0 };
    if r.bytes(8)? != b"SSISSE01" {
        return None;
    }
    let file = r.text()?;
    let n = r.u64()? as usize;
    let (mut names, mut cols) = (Vec::new(), Vec::new());
    for _ in 0..n {
        names.push(r.text()?);
        cols.push(r.floats()?);
    }
    let nf = r.u64()? as usize;
    let mut fogs = Vec::new();
    for _ in 0..nf {
        let rate_rad_s = r.floats()?;
        let has_t = r.u64()? == 1;
        let t = r.floats()?;
        fogs.push(ssis_session::FogData { rate_rad_s, t_degc: has_t.then_some(t) });
    }
    let triples = |v: Vec<f64>| v.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect::<Vec<_>>();
    let ref_rad_s = triples(r.floats()?);
    let has_field = r.u64()? == 1;
    let field = triples(r.floats()?);
    let nl = r.u64()? as usize;
    let lines = (0..nl).map(|_| r.u64()).collect::<Option<Vec<_>>>()?;
    let header = match ssis_session::Header::parse(&file, names.clone(), 1) {
        Ok(h) => h,
        Err(e) => return Some(Err(SsisError::new_err(e.to_string()))),
    };
    Some(Ok(Session {
        file,
        names,
        cols,
        roles: header.roles,
        fogs,
        ref_rad_s,
        field_nt: has_field.then_some(field),
        lines,
    }))
}

/// Reads [`session_state`]'s words.
struct Reader<'a> {
    b: &'a [u8],
    at: usize,
}

impl Reader<'_> {
    fn bytes(&mut self, n: usize) -> Option<&[u8]> {
        let s = self.b.get(self.at..self.at.checked_add(n)?)?;
        self.at += n;
        Some(s)
    }

    fn u64(&mut self) -> Option<u64> {
        self.bytes(8).map(|s| u64::from_le_bytes(std::array::from_fn(|i| s[i])))
    }

    fn text(&mut self) -> Option<String> {
        let n = self.u64()? as usize;
        self.bytes(n).and_then(|s| String::from_utf8(s.to_vec()).ok())
    }

    fn floats(&mut self) -> Option<Vec<f64>> {
        let n = self.u64()? as usize;
        let s = self.bytes(n.checked_mul(8)?)?;
        Some(s.chunks_exact(8).map(|c| f64::from_le_bytes(std::array::from_fn(|i| c[i]))).collect())
    }
}

/// A session argument: a path (streamed, as the command line reads it) or a `Session`.
enum Src {
    File(PathBuf),
    Memory(Session),
}

impl Src {
    fn of(o: &Bound<'_, PyAny>) -> PyResult<Src> {
        if let Ok(s) = o.extract::<PyRef<'_, PySession>>() {
            return Ok(Src::Memory(s.s.clone()));
        }
        o.extract::<PathBuf>().map(Src::File).map_err(|_| SsisError::new_err("session: a path or an ssis.lab.Session"))
    }

    fn source(&self) -> Source<'_> {
        match self {
            Src::File(p) => Source::File(p),
            Src::Memory(s) => Source::Memory(s),
        }
    }

    fn name(&self) -> String {
        match self {
            Src::File(p) => p.display().to_string(),
            Src::Memory(s) => s.file.clone(),
        }
    }
}

/// A session argument read whole (the calibration methods work on a session in memory).
pub(crate) fn session_of(o: &Bound<'_, PyAny>) -> PyResult<Session> {
    match Src::of(o)? {
        Src::Memory(s) => Ok(s),
        Src::File(p) => read_session(&p, None).map_err(|e| SsisError::new_err(e.to_string())),
    }
}

/// The FOG error model (`ssis-error-model/1`).
#[pyclass(module = "ssis._ssis", name = "Model")]
#[derive(Clone)]
pub struct PyModel {
    m: Model,
}

#[pymethods]
impl PyModel {
    /// Version 1 with the given terms (catalog names, `sinusoid:F_HZ`, or expressions)
    /// and no coefficients, as `ssis-lab init`; a bare word close to a catalog name is a
    /// typo, refused with the nearest name, not taken as an expression.
    #[staticmethod]
    #[pyo3(signature = (terms, t_ref_degc = 25.0, g_window_s = 0.0))]
    fn init(terms: Vec<String>, t_ref_degc: f64, g_window_s: f64) -> PyResult<Self> {
        let kinds = terms.iter().map(|t| checked_term(t.trim())).collect::<PyResult<Vec<_>>>()?;
        for (what, v) in [("t_ref_degc", t_ref_degc), ("g_window_s", g_window_s)] {
            if !v.is_finite() || (what == "g_window_s" && v < 0.0) {
                return Err(SsisError::new_err(format!("{what}: {v} is not a finite value (g_window_s ≥ 0)")));
            }
        }
        let mut m = Model::new(&kinds);
        m.t_ref_degc = t_ref_degc;
        m.g_window_s = g_window_s;
        m.note = "v1: starting model".into();
        Ok(PyModel { m })
    }

    /// Reads a model file.
    #[staticmethod]
    fn read(path: PathBuf) -> PyResult<Self> {
        Model::read(&path).map(|m| PyModel { m }).map_err(lab_err)
    }

    /// Writes the model; the lab never overwrites a model, so an existing file is refused.
    fn write(&self, path: PathBuf) -> PyResult<()> {
        if path.exists() {
            return Err(SsisError::new_err(format!("{} exists: the lab never overwrites a model", path.display())));
        }
        ssis_lab::write_atomic(&path, self.m.to_toml().as_bytes()).map_err(lab_err)
    }

    /// The TOML text.
    fn to_toml(&self) -> String {
        self.m.to_toml()
    }

    /// The model's version.
    #[getter]
    fn version(&self) -> u32 {
        self.m.version
    }

    /// Its terms' labels, in order.
    #[getter]
    fn terms(&self) -> Vec<String> {
        self.m.kinds().iter().map(Kind::label).collect()
    }

    /// `Model()`: version 1 with no terms (what an unpickled model starts from).
    #[new]
    fn new() -> Self {
        PyModel { m: Model::new(&[]) }
    }

    /// Whether the model has coefficients (fitted, or written in its file).
    #[getter]
    fn fitted(&self) -> bool {
        has_coefficients(&self.m)
    }

    /// The pickled form: the model's TOML text (exact).
    fn __getstate__(&self) -> String {
        self.m.to_toml()
    }

    fn __setstate__(&mut self, state: &str) -> PyResult<()> {
        self.m = Model::parse(state, "(pickled model)").map_err(lab_err)?;
        Ok(())
    }

    fn __copy__(&self) -> Self {
        self.clone()
    }

    fn __deepcopy__(&self, _memo: &Bound<'_, PyAny>) -> Self {
        self.clone()
    }

    fn __eq__(&self, o: &PyModel) -> bool {
        self.m.to_toml() == o.m.to_toml()
    }

    fn __repr__(&self) -> String {
        let fitted = if self.fitted() { "True" } else { "False" };
        format!("Model(version={}, terms={:?}, fitted={fitted})", self.m.version, self.terms())
    }
}

fn has_coefficients(m: &Model) -> bool {
    m.fit.is_some() || m.terms.iter().any(|t| !t.coef.is_empty())
}

/// A term as `ssis-lab init` takes it: a bare word close to a catalog name is refused with
/// the nearest name.
fn checked_term(arg: &str) -> PyResult<Kind> {
    let kind = Kind::parse_arg(arg).map_err(|e| SsisError::new_err(format!("terms: {e}")))?;
    if let Kind::Expr(_) = &kind {
        let catalog = ssis_lab::model::catalog_names();
        let bare = !arg.is_empty() && arg.chars().all(|c| c.is_ascii_alphanumeric() || c == '_');
        if bare && !ssis_lab::model::FOG_VARIABLES.contains(&arg) {
            let hint = ssis_lab::model::did_you_mean(arg, catalog.split(", "));
            if !hint.is_empty() {
                return Err(SsisError::new_err(format!(
                    "terms: `{arg}` is not a term of the catalog ({catalog}, sinusoid:F_HZ){hint} \
                     (an expression over session columns is a term too)"
                )));
            }
        }
    }
    Ok(kind)
}

/// A bar over the session file's bytes on standard error (the command line's; drawn only
/// on a terminal), when `progress`.
fn bar(progress: bool, what: &str, src: &Src) -> Option<indicatif::ProgressBar> {
    progress.then(|| {
        let pb = indicatif::ProgressBar::new(0);
        if let Ok(style) =
            indicatif::ProgressStyle::with_template("{prefix} {msg} {bar:30} {bytes}/{total_bytes} {bytes_per_sec}")
        {
            pb.set_style(style);
        }
        pb.set_prefix(what.to_string());
        pb.set_message(src.name());
        pb
    })
}

/// `ssis-lab compare`: the model fitted (or evaluated) on the session.
#[pyfunction]
#[pyo3(signature = (model, session, evaluate = false, blocks = DEFAULT_BLOCKS, progress = false))]
fn compare_json(
    model: &PyModel,
    session: &Bound<'_, PyAny>,
    evaluate: bool,
    blocks: usize,
    progress: bool,
) -> PyResult<String> {
    let src = Src::of(session)?;
    let pb = bar(progress, "comparing on", &src);
    let c = ssis_lab::fit::compare(&model.m, src.source(), evaluate, blocks, pb.as_ref()).map_err(lab_err);
    pb.inspect(|b| b.finish_and_clear());
    let c = c?;
    Ok(json::comparison(&c, "", &src.name(), evaluate).to_string())
}

/// `ssis-lab diagnose`: the candidate missing effects ranked by their held-out F-test.
#[pyfunction]
#[pyo3(signature = (model, session, level = 0.01, blocks = DEFAULT_BLOCKS, progress = false))]
fn diagnose_json(
    model: &PyModel,
    session: &Bound<'_, PyAny>,
    level: f64,
    blocks: usize,
    progress: bool,
) -> PyResult<String> {
    let src = Src::of(session)?;
    let opt = Options { n_blocks: blocks, fdr_level: level, ..Options::default() };
    let pb = bar(progress, "diagnosing on", &src);
    let d = diagnose_with_progress(&model.m, src.source(), &opt, pb.as_ref()).map_err(lab_err);
    pb.inspect(|b| b.finish_and_clear());
    let d = d?;
    Ok(json::diagnosis(&d).to_string())
}

/// `ssis-lab add`: the next version with one more term; its held-out gain as JSON.
#[pyfunction]
#[pyo3(signature = (model, term, session, blocks = DEFAULT_BLOCKS))]
fn add_json(model: &PyModel, term: &str, session: &Bound<'_, PyAny>, blocks: usize) -> PyResult<(PyModel, String)> {
    let src = Src::of(session)?;
    let kind = checked_term(term.trim())?;
    let mut out = ssis_lab::fit::add_term(&model.m, &kind, src.source(), blocks).map_err(lab_err)?;
    out.model.version = model.m.version + 1;
    out.model.note = format!("v{}: v{} + {}", out.model.version, model.m.version, kind.label());
    let v = json::added(&out, &kind, "");
    Ok((PyModel { m: out.model }, v.to_string()))
}

/// The model with every term fitted on every row of the session (what `compare` reports,
/// as a model to export or write).
#[pyfunction]
fn fit(model: &PyModel, session: &Bound<'_, PyAny>) -> PyResult<PyModel> {
    let src = Src::of(session)?;
    let f = ssis_lab::fit::fit_model(&model.m, src.source()).map_err(lab_err)?;
    Ok(PyModel { m: f.model })
}

/// Held-out RMS per FOG, °/h, of each model on the session (the history `ssis-lab add`
/// prints), and the pooled figure.
#[pyfunction]
#[pyo3(signature = (models, session, blocks = DEFAULT_BLOCKS))]
fn held_out_deg_h(models: Vec<PyModel>, session: &Bound<'_, PyAny>, blocks: usize) -> PyResult<Vec<(f64, Vec<f64>)>> {
    let src = Src::of(session)?;
    let ms: Vec<Model> = models.into_iter().map(|m| m.m).collect();
    let r = held_out_many(&ms, src.source(), blocks, None).map_err(lab_err)?;
    Ok(r.iter().map(|v| (pooled(v) * DEG_H_PER_RAD_S, v.iter().map(|x| x * DEG_H_PER_RAD_S).collect())).collect())
}

/// `ssis-lab export`: the calibration table from the model's onboard terms over `base`
/// (default: the nominal table), with provenance; `(table, json, text)`.
#[pyfunction]
#[pyo3(signature = (model, base = None, model_name = "(model)".to_string()))]
fn export_json(model: &PyModel, base: Option<&PyTable>, model_name: String) -> PyResult<(PyTable, String, String)> {
    let m = &model.m;
    if !has_coefficients(m) {
        return Err(SsisError::new_err(format!(
            "model: {model_name} has no coefficients: fit it first with ssis.lab.fit(model, session) (or \
             ssis.lab.add); ssis.lab.compare reports a fit and leaves the model as it is"
        )));
    }
    let base_doc = base
        .map_or_else(|| ssis_common::table::TableDoc::new(ssis::calib::CalibrationTable::DEFAULT), |b| b.doc.clone());
    let e = export::to_table(m, &base_doc.table).map_err(lab_err)?;
    let origin = update::Origin {
        command: "ssis-lab export".into(),
        session: m.fit.as_ref().map_or_else(|| "(coefficients as written in the model)".into(), |f| f.session.clone()),
        model: Some((model_name, m.version)),
    };
    let (doc, changes) = update::apply(&base_doc, &e.table, &e.set, &origin).map_err(err)?;
    let text = update::report(&base_doc, &doc, &changes, &origin);
    let not_applied: Vec<_> = e.not_applied.iter().map(|(k, why)| serde_json::json!({"term": k, "why": why})).collect();
    let not_identified = m.fit.as_ref().map(|f| f.not_identified.clone()).unwrap_or_default();
    let v =
        serde_json::json!({"applied_onboard": e.applied, "not_applied": not_applied, "not_identified": not_identified});
    Ok((PyTable { doc }, v.to_string(), text))
}

/// `ssis-lab report`: one HTML page of the fit, the diagnosis and the history of
/// `versions` (default: the model alone), returned as text.
#[pyfunction]
#[pyo3(signature = (model, session, versions = None, blocks = DEFAULT_BLOCKS))]
fn report_html(
    model: &PyModel,
    session: &Bound<'_, PyAny>,
    versions: Option<Vec<PyModel>>,
    blocks: usize,
) -> PyResult<String> {
    let src = Src::of(session)?;
    let m = &model.m;
    let versions: Vec<(u32, Model)> =
        versions.unwrap_or_else(|| vec![model.clone()]).into_iter().map(|v| (v.m.version, v.m)).collect();
    let opt = Options { n_blocks: blocks, ..Options::default() };
    let source = src.source();
    let mut terms = candidate_terms(&source.header().map_err(lab_err)?);
    terms.extend(versions.iter().flat_map(|(_, v)| v.kinds()));
    let dg = digest(source, &spec_for(m, &terms, opt.n_blocks), None).map_err(lab_err)?;
    let kept = ssis_lab::fit::KeptTimes { t_s: dg.kept.t_s.clone(), dt_s: dg.dt_s * dg.kept.stride.max(1) as f64 };
    let steps = add_steps(&versions, &dg).map_err(lab_err)?;
    let f = complete(fit_digest(m, &dg).map_err(lab_err)?, source, &dg).map_err(lab_err)?;
    let d = diagnose_digest(m, &dg, &opt).map_err(lab_err)?;
    let models: Vec<Model> = versions.iter().map(|v| v.1.clone()).collect();
    let rms = held_out_many(&models, source, blocks, None).map_err(lab_err)?;
    let h: Vec<(u32, f64)> = versions.iter().zip(rms).map(|((v, _), r)| (*v, pooled(&r) * DEG_H_PER_RAD_S)).collect();
    report::render(&src.name(), &f, &d, &h, &steps, &kept).map_err(lab_err)
}

/// `ssis-lab simulate PRESET OUT`: writes a session with known effects (the hidden one
/// unless `hidden=False`) to `out` (refused where a file exists); returns the white-noise
/// floor, °/h.
#[pyfunction]
#[pyo3(signature = (preset, out, seed = 1, hidden = true))]
fn simulate(preset: &str, out: PathBuf, seed: u64, hidden: bool) -> PyResult<f64> {
    let Some(spec) = ssis_lab::simulate::preset(preset, seed, hidden) else {
        return Err(SsisError::new_err(format!(
            "unknown preset `{preset}`: magnetic, thermal, asymmetry, sin2psi, flight, replay"
        )));
    };
    if out.exists() {
        return Err(SsisError::new_err(format!("{}: exists; the lab writes a new session file only", out.display())));
    }
    let sim = ssis_lab::simulate::generate(&spec);
    sim.write_csv(&out).map_err(lab_err)?;
    Ok(sim.truth.noise_rad_s * DEG_H_PER_RAD_S)
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<PySession>()?;
    m.add_class::<PyModel>()?;
    m.add_function(wrap_pyfunction!(compare_json, m)?)?;
    m.add_function(wrap_pyfunction!(diagnose_json, m)?)?;
    m.add_function(wrap_pyfunction!(add_json, m)?)?;
    m.add_function(wrap_pyfunction!(fit, m)?)?;
    m.add_function(wrap_pyfunction!(held_out_deg_h, m)?)?;
    m.add_function(wrap_pyfunction!(export_json, m)?)?;
    m.add_function(wrap_pyfunction!(report_html, m)?)?;
    m.add_function(wrap_pyfunction!(simulate, m)?)
}
