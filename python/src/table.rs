//! The calibration table: default, read (TOML, binary or image, as `ssis-sim table show`),
//! write (TOML with provenance, never over an existing file unless `force`), diff (as
//! `ssis-sim table diff`), and every field by its documented name (docs/CALIBRATION.md).

use std::path::PathBuf;

use pyo3::prelude::*;
use ssis::calib::CalibrationTable;
use ssis_common::table::{self, TableDoc};

use crate::err;

/// A calibration table and the provenance of the fields tools set.
#[pyclass(module = "ssis._ssis", name = "Table")]
#[derive(Clone)]
pub struct PyTable {
    pub(crate) doc: TableDoc,
}

impl PyTable {
    pub(crate) fn table(t: Option<&PyTable>) -> CalibrationTable {
        t.map_or(CalibrationTable::DEFAULT, |t| t.doc.table)
    }
}

fn field(name: &str) -> PyResult<ssis::calib::Field> {
    table::field_named(name).ok_or_else(|| {
        err(anyhow::anyhow!("`{name}` is not a field of the table (docs/CALIBRATION.md: e.g. fog[0].bias_rad_s)"))
    })
}

#[pymethods]
impl PyTable {
    /// `Table()`: the nominal table (as `Table.default()`).
    #[new]
    fn new() -> Self {
        PyTable::default()
    }

    /// The nominal table (nominal geometry, the paper's observer figures).
    #[staticmethod]
    fn default() -> Self {
        PyTable { doc: TableDoc::new(CalibrationTable::DEFAULT) }
    }

    /// A table from the text of a TOML table file (with its provenance), checked as a
    /// file is; `origin` names it in messages.
    #[staticmethod]
    #[pyo3(signature = (text, origin = "(text)".to_string()))]
    fn from_toml(text: &str, origin: String) -> PyResult<Self> {
        table::parse_doc(text, &origin).map(|doc| PyTable { doc }).map_err(|e| err(e.into()))
    }

    /// Reads a table (.toml with its provenance, .bin or .img), checked as the unit checks it.
    #[staticmethod]
    fn read(path: PathBuf) -> PyResult<Self> {
        let is_toml = path.extension().is_some_and(|e| e == "toml");
        let doc = if is_toml { table::read_doc(&path) } else { table::read_any(&path).map(|(t, _)| TableDoc::new(t)) };
        doc.map(|doc| PyTable { doc }).map_err(|e| err(e.into()))
    }

    /// The TOML form (with engineering units in comments).
    fn to_toml(&self) -> PyResult<String> {
        table::doc_to_toml(&self.doc).map_err(|e| err(e.into()))
    }

    /// Writes the table: `.toml` (with provenance), `.bin` (binary) or `.img` (flash
    /// image), by the file's extension (another is refused); refuses an existing file
    /// unless `force`.
    #[pyo3(signature = (path, force = false))]
    fn write(&self, path: PathBuf, force: bool) -> PyResult<()> {
        let ext = path.extension().and_then(|e| e.to_str()).unwrap_or("");
        if !matches!(ext, "toml" | "bin" | "img") {
            return Err(err(anyhow::anyhow!(
                "path: {}: the extension names the format: .toml, .bin or .img (not `{ext}`)",
                path.display()
            )));
        }
        if path.exists() && !force {
            return Err(err(anyhow::anyhow!("{}: exists (force=True replaces it)", path.display())));
        }
        self.doc.table.validate().map_err(|e| err(anyhow::anyhow!("{}: table refused: {e}", path.display())))?;
        let r = match path.extension().and_then(|e| e.to_str()) {
            Some("bin") => table::write_binary(&path, &self.doc.table),
            Some("img") => table::write_image(&path, &self.doc.table),
            _ => table::write_doc(&path, &self.doc),
        };
        r.map_err(|e| err(e.into()))
    }

    /// Every field's documented name, in storage order.
    #[staticmethod]
    fn fields() -> Vec<String> {
        ssis::calib::Field::all().map(|f| f.to_string()).collect()
    }

    /// The value of field `name` in its SI unit (the table's).
    fn get(&self, name: &str) -> PyResult<f64> {
        Ok(field(name)?.get(&self.doc.table))
    }

    /// Sets field `name` (SI unit); refused outside the field's plausible range.
    fn set(&mut self, name: &str, value: f64) -> PyResult<()> {
        let f = field(name)?;
        if !value.is_finite() {
            return Err(err(anyhow::anyhow!("value: field `{name}` set to {value}: a finite number is needed")));
        }
        if !f.spec().admits(value) {
            let s = f.spec();
            return Err(err(anyhow::anyhow!(
                "field `{name}`: {value} {} ({} {}) is outside its plausible range {} … {} {}",
                s.unit,
                value * s.eng_per_unit,
                s.eng_unit,
                s.eng_range.0,
                s.eng_range.1,
                s.eng_unit
            )));
        }
        f.set(&mut self.doc.table, value);
        Ok(())
    }

    /// The four FOGs' calibrated sensitive axes in the instrument frame (rows), exact.
    fn axes(&self) -> Vec<[f64; 3]> {
        self.doc.table.axes().iter().map(|a| [a.x, a.y, a.z]).collect()
    }

    /// The table's revision.
    #[getter]
    fn revision(&self) -> u32 {
        self.doc.table.revision
    }

    #[setter]
    fn set_revision(&mut self, v: u32) {
        self.doc.table.revision = v;
    }

    /// CRC-32 of the binary form (what the unit reports).
    #[getter]
    fn crc(&self) -> u32 {
        ssis::flight::table_crc(&self.doc.table)
    }

    /// The fields that differ between `a` and `b` (bit for bit), as
    /// `(name, value_a, value_b)` in SI units, and the text `ssis-sim table diff` prints.
    #[staticmethod]
    fn diff(a: &PyTable, b: &PyTable) -> (Vec<(String, f64, f64)>, String) {
        let ch = ssis_common::update::diff(&a.doc.table, &b.doc.table);
        let list = ch.iter().map(|c| (c.field.to_string(), c.old, c.new)).collect();
        (list, ssis_common::update::render(&ch))
    }

    fn __eq__(&self, o: &PyTable) -> bool {
        ssis_common::update::diff(&self.doc.table, &o.doc.table).is_empty()
            && self.doc.table.revision == o.doc.table.revision
    }

    /// The pickled form: the TOML text with provenance (exact: each value in the shortest
    /// form that reads back to the same `f64`).
    fn __getstate__(&self) -> PyResult<String> {
        self.to_toml()
    }

    fn __setstate__(&mut self, state: &str) -> PyResult<()> {
        self.doc = table::parse_doc(state, "(pickled table)").map_err(|e| err(e.into()))?;
        Ok(())
    }

    fn __copy__(&self) -> Self {
        self.clone()
    }

    fn __deepcopy__(&self, _memo: &Bound<'_, PyAny>) -> Self {
        self.clone()
    }

    fn _repr_html_(&self) -> String {
        format!(
            "<b>ssis.Table</b> revision {}, CRC-32 <code>0x{:08x}</code>, {} fields set by tools",
            self.doc.table.revision,
            ssis::flight::table_crc(&self.doc.table),
            self.doc.provenance.len()
        )
    }

    fn __repr__(&self) -> String {
        format!("Table(revision={}, crc=0x{:08x})", self.doc.table.revision, ssis::flight::table_crc(&self.doc.table))
    }
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<PyTable>()
}
