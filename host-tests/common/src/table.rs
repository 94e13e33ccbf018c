//! The calibration table's readable TOML form on the host, and its binary form on disk.
//!
//! The TOML is a `format` line, the serde form of [`ssis::calib::CalibrationTable`] under
//! `[table]` and, optionally, one `[[provenance]]` entry per field a tool set ([`Provenance`]:
//! which command, session and model version); the binary is [`ssis::calib::binary`], and
//! the flash image of the table region (two copies) is [`ssis::calib::store`]. Provenance is
//! ground-side only: the binary and the image carry the table alone, so a table converts to
//! the same bytes with or without it. Reading names the file, line and field that is wrong;
//! writing goes through a temporary file and a rename, so a failed write never leaves a
//! half-written table where a good one was (`crate::output`).

use std::path::Path;

use serde::{Deserialize, Serialize};
use ssis::calib::store::StoreError;
use ssis::calib::{binary, store, CalibrationTable, Field, TableError};

/// TOML format tag written at the top of every table file.
pub const TOML_FORMAT: &str = "ssis-calibration-table/1";

/// Why a table file could not be read or written; each names the file where there is one.
#[derive(Debug, thiserror::Error)]
pub enum TableFileError {
    /// The file cannot be read.
    #[error("cannot read {path}")]
    Io {
        /// The file.
        path: String,
        /// What the system said.
        #[source]
        source: std::io::Error,
    },
    /// Not the table's TOML form: a syntax error, an unknown, missing or mistyped key (the
    /// message names line and key).
    #[error("{origin}: {message}")]
    Syntax {
        /// The file or source.
        origin: String,
        /// The TOML reader's words.
        message: String,
    },
    /// The `format` line names another format.
    #[error("{origin}: field `format`: expected \"{TOML_FORMAT}\", found \"{found}\"")]
    Format {
        /// The file or source.
        origin: String,
        /// The format it names.
        found: String,
    },
    /// The table itself is refused (a field out of its plausible range, a bad binary).
    #[error("{}table refused: {reason}", origin.as_ref().map_or(String::new(), |o| format!("{o}: ")))]
    Refused {
        /// The file or source, when the table came from one.
        origin: Option<String>,
        /// Why: which field and value, or what of the binary form.
        reason: TableError,
    },
    /// A `[[provenance]]` entry names no field of the table.
    #[error("{origin}: provenance names `{field}`, which is not a field of the table (docs/CALIBRATION.md)")]
    Provenance {
        /// The file or source.
        origin: String,
        /// The name it gives.
        field: String,
    },
    /// A flash image in which neither copy passes.
    #[error("{path}: no copy passed (A: {:?}, B: {:?})", slots[0], slots[1])]
    NoCopy {
        /// The file.
        path: String,
        /// Why each copy was refused.
        slots: [Option<StoreError>; 2],
    },
    /// The TOML form could not be written out.
    #[error(transparent)]
    Serialize(#[from] toml::ser::Error),
    /// A file that cannot be written, or may not be ([`crate::output`]); the message names it.
    #[error("{0}")]
    Write(String),
}

/// Result of the table file functions.
pub type TableResult<T> = Result<T, TableFileError>;

/// Who set one field of a table: a `[[provenance]]` entry of the TOML form.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Provenance {
    /// The field's path under `[table]` (`fog[0].bias_rad_s`, docs/CALIBRATION.md).
    pub field: String,
    /// The command that set it (`ssis-lab export`, `ssis-cal allan`, …).
    pub command: String,
    /// The session (or telemetry) file the value came from, as given to the command.
    pub session: String,
    /// The model file, for a value exported from a model.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub model: Option<String>,
    /// The model's version.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub model_version: Option<u32>,
    /// The table revision that update wrote.
    pub revision: u32,
}

/// A table file's content: the table and the provenance of the fields tools set.
#[derive(Debug, Clone, PartialEq)]
pub struct TableDoc {
    /// The table (what the firmware gets).
    pub table: CalibrationTable,
    /// One entry per field set by a tool, in storage order.
    pub provenance: Vec<Provenance>,
}

impl TableDoc {
    /// A table with no provenance.
    pub fn new(table: CalibrationTable) -> Self {
        TableDoc { table, provenance: Vec::new() }
    }
}

#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct TableFile {
    format: String,
    table: CalibrationTable,
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    provenance: Vec<Provenance>,
}

/// The field named `name` (its path under `[table]`).
pub fn field_named(name: &str) -> Option<Field> {
    Field::all().find(|f| f.to_string() == name)
}

/// Parses the TOML form with its provenance; `origin` names the source in errors.
pub fn parse_doc(text: &str, origin: &str) -> TableResult<TableDoc> {
    let f: TableFile = toml::from_str(text)
        .map_err(|e| TableFileError::Syntax { origin: origin.to_string(), message: e.to_string() })?;
    if f.format != TOML_FORMAT {
        return Err(TableFileError::Format { origin: origin.to_string(), found: f.format });
    }
    f.table.validate().map_err(|reason| TableFileError::Refused { origin: Some(origin.to_string()), reason })?;
    if let Some(p) = f.provenance.iter().find(|p| field_named(&p.field).is_none()) {
        return Err(TableFileError::Provenance { origin: origin.to_string(), field: p.field.clone() });
    }
    Ok(TableDoc { table: f.table, provenance: f.provenance })
}

/// Parses the TOML form; `origin` names the source in errors. Provenance is checked and
/// left out.
pub fn parse_toml(text: &str, origin: &str) -> TableResult<CalibrationTable> {
    parse_doc(text, origin).map(|d| d.table)
}

/// The TOML form of `doc`, each field's value also in engineering units in a comment
/// (`bias_rad_s = 1e-6  # 0.206265 °/h`; the value itself stays in SI, what the firmware
/// loads).
pub fn doc_to_toml(doc: &TableDoc) -> TableResult<String> {
    let f = TableFile { format: TOML_FORMAT.to_string(), table: doc.table, provenance: doc.provenance.clone() };
    Ok(with_engineering_comments(&toml::to_string_pretty(&f)?, &doc.table))
}

/// Appends to each line of a field under `[table]` a comment with its value in
/// engineering units (fields whose unit is already the engineering one are left bare).
fn with_engineering_comments(text: &str, t: &CalibrationTable) -> String {
    let mut out = String::with_capacity(text.len() + text.len() / 2);
    let (mut prefix, mut fog, mut array): (Option<String>, i32, Option<(String, usize)>) = (None, -1, None);
    for line in text.lines() {
        let trimmed = line.trim();
        let mut name = None;
        if trimmed.starts_with('[') && !trimmed.starts_with("[ ") && array.is_none() {
            prefix = match trimmed {
                "[table]" => Some(String::new()),
                "[[table.fog]]" => {
                    fog += 1;
                    Some(format!("fog[{fog}]."))
                }
                "[table.misalignment]" => Some("misalignment.".into()),
                "[table.observer]" => Some("observer.".into()),
                _ => None,
            };
        } else if let Some((key, i)) = array.as_mut() {
            if trimmed == "]" {
                array = None;
            } else {
                name = Some(format!("{key}[{i}]"));
                *i += 1;
            }
        } else if let (Some(p), Some((key, value))) = (&prefix, trimmed.split_once(" = ")) {
            if value == "[" {
                array = Some((format!("{p}{key}"), 0));
            } else {
                name = Some(format!("{p}{key}"));
            }
        }
        out.push_str(line);
        if let Some(f) = name.as_deref().and_then(field_named) {
            let s = f.spec();
            if s.eng_per_unit != 1.0 && !s.eng_unit.is_empty() {
                out.push_str(&format!("  # {} {}", significant(f.get(t) * s.eng_per_unit), s.eng_unit));
            }
        }
        out.push('\n');
    }
    out
}

/// The TOML form of `t`.
pub fn to_toml(t: &CalibrationTable) -> TableResult<String> {
    doc_to_toml(&TableDoc::new(*t))
}

/// Reads a TOML table file with its provenance.
pub fn read_doc(path: &Path) -> TableResult<TableDoc> {
    let text = std::fs::read_to_string(path).map_err(|e| io(path, e))?;
    parse_doc(text.strip_prefix('\u{feff}').unwrap_or(&text), &path.display().to_string())
}

/// Reads a TOML table file (its provenance checked and left out: what `to-bin` converts).
pub fn read_toml(path: &Path) -> TableResult<CalibrationTable> {
    read_doc(path).map(|d| d.table)
}

/// Reads a table in any of its forms by the file's extension: `.img` (the flash image, as
/// the firmware loads it; the load's report comes along), `.bin`, else TOML.
pub fn read_any(path: &Path) -> TableResult<(CalibrationTable, Option<store::Loaded>)> {
    match path.extension().and_then(|e| e.to_str()) {
        Some("img") => read_image(path).map(|(t, l)| (t, Some(l))),
        Some("bin") => read_binary(path).map(|t| (t, None)),
        _ => read_toml(path).map(|t| (t, None)),
    }
}

/// Reads a binary table file.
pub fn read_binary(path: &Path) -> TableResult<CalibrationTable> {
    let bytes = std::fs::read(path).map_err(|e| io(path, e))?;
    binary::decode(&bytes)
        .map_err(|reason| TableFileError::Refused { origin: Some(path.display().to_string()), reason })
}

fn io(path: &Path, source: std::io::Error) -> TableFileError {
    TableFileError::Io { path: path.display().to_string(), source }
}

/// A table refused before it is written.
fn valid(t: &CalibrationTable) -> TableResult<()> {
    t.validate().map_err(|reason| TableFileError::Refused { origin: None, reason })
}

/// Writes `bytes` to `path` atomically (temporary file + rename) under the output rules
/// of [`crate::output`].
pub fn write_atomic(path: &Path, bytes: &[u8]) -> TableResult<()> {
    crate::output::write(path, bytes).map_err(|e| TableFileError::Write(format!("{e:#}")))
}

/// Writes the TOML form.
pub fn write_toml(path: &Path, t: &CalibrationTable) -> TableResult<()> {
    valid(t)?;
    write_atomic(path, to_toml(t)?.as_bytes())
}

/// Writes the TOML form with its provenance.
pub fn write_doc(path: &Path, doc: &TableDoc) -> TableResult<()> {
    valid(&doc.table)?;
    write_atomic(path, doc_to_toml(doc)?.as_bytes())
}

/// Writes the binary form.
pub fn write_binary(path: &Path, t: &CalibrationTable) -> TableResult<()> {
    valid(t)?;
    write_atomic(path, &binary::encode(t))
}

/// Writes the flash image of the table region: `t` in both slots (generation 1), the rest
/// erased (what the QEMU board loads at its CALIB region, the ELF's `_calib_start`).
pub fn write_image(path: &Path, t: &CalibrationTable) -> TableResult<()> {
    valid(t)?;
    write_atomic(path, &store::image(t))
}

/// Reads a flash image the way the firmware does: the table it would fly with, refused
/// (an error) only if no copy passes; refused copies are reported in the second value.
pub fn read_image(path: &Path) -> TableResult<(CalibrationTable, store::Loaded)> {
    let bytes = std::fs::read(path).map_err(|e| io(path, e))?;
    let loaded = store::load(&bytes);
    if loaded.defaulted() {
        return Err(TableFileError::NoCopy { path: path.display().to_string(), slots: loaded.slot_errors });
    }
    Ok((loaded.table, loaded))
}

/// `v` with about six significant digits (no exponent between 1e-4 and 1e7).
pub fn significant(v: f64) -> String {
    if v == 0.0 || !v.is_finite() {
        return format!("{v}");
    }
    let mag = v.abs().log10().floor() as i32;
    if (-4..7).contains(&mag) {
        let decimals = (5 - mag).max(0) as usize;
        let s = format!("{v:.decimals$}");
        if s.contains('.') {
            s.trim_end_matches('0').trim_end_matches('.').to_string()
        } else {
            s
        }
    } else {
        format!("{v:.5e}")
    }
}
