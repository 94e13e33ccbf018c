//! The calibration table's readable TOML form on the host, and its binary form on disk.
//!
//! The TOML is a `format` line and the serde form of [`ssis::calib::CalibrationTable`]
//! under `[table]`; the binary is [`ssis::calib::binary`], and the flash image of the table
//! region (two copies) is [`ssis::calib::store`]. Reading names the file, line and field
//! that is wrong; writing goes through a temporary file and a rename, so a failed write
//! never leaves a half-written table where a good one was.

use std::path::Path;

use anyhow::{bail, Context, Result};
use serde::{Deserialize, Serialize};
use ssis::calib::{binary, store, CalibrationTable};

/// TOML format tag written at the top of every table file.
pub const TOML_FORMAT: &str = "ssis-calibration-table/1";

#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct TableFile {
    format: String,
    table: CalibrationTable,
}

/// Parses the TOML form; `origin` names the source in errors.
pub fn parse_toml(text: &str, origin: &str) -> Result<CalibrationTable> {
    let f: TableFile = toml::from_str(text).map_err(|e| anyhow::anyhow!("{origin}: {e}"))?;
    if f.format != TOML_FORMAT {
        bail!("{origin}: field `format`: expected \"{TOML_FORMAT}\", found \"{}\"", f.format);
    }
    f.table.validate().map_err(|e| anyhow::anyhow!("{origin}: table refused: {e:?}"))?;
    Ok(f.table)
}

/// The TOML form of `t`.
pub fn to_toml(t: &CalibrationTable) -> Result<String> {
    let f = TableFile { format: TOML_FORMAT.to_string(), table: *t };
    Ok(toml::to_string_pretty(&f)?)
}

/// Reads a TOML table file.
pub fn read_toml(path: &Path) -> Result<CalibrationTable> {
    let text = std::fs::read_to_string(path).with_context(|| format!("cannot read {}", path.display()))?;
    parse_toml(&text, &path.display().to_string())
}

/// Reads a binary table file.
pub fn read_binary(path: &Path) -> Result<CalibrationTable> {
    let bytes = std::fs::read(path).with_context(|| format!("cannot read {}", path.display()))?;
    binary::decode(&bytes).map_err(|e| anyhow::anyhow!("{}: table refused: {e:?}", path.display()))
}

/// Writes `bytes` to `path` atomically (temporary file + rename).
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<()> {
    let tmp = path.with_extension("partial");
    std::fs::write(&tmp, bytes).with_context(|| format!("cannot write {}", tmp.display()))?;
    std::fs::rename(&tmp, path).with_context(|| format!("cannot replace {}", path.display()))?;
    Ok(())
}

/// Writes the TOML form.
pub fn write_toml(path: &Path, t: &CalibrationTable) -> Result<()> {
    t.validate().map_err(|e| anyhow::anyhow!("table refused: {e:?}"))?;
    write_atomic(path, to_toml(t)?.as_bytes())
}

/// Writes the binary form.
pub fn write_binary(path: &Path, t: &CalibrationTable) -> Result<()> {
    t.validate().map_err(|e| anyhow::anyhow!("table refused: {e:?}"))?;
    write_atomic(path, &binary::encode(t))
}

/// Writes the flash image of the table region: `t` in both slots (generation 1), the rest
/// erased (what the QEMU board loads at its CALIB region, 0x0002_0000).
pub fn write_image(path: &Path, t: &CalibrationTable) -> Result<()> {
    t.validate().map_err(|e| anyhow::anyhow!("table refused: {e:?}"))?;
    write_atomic(path, &store::image(t))
}

/// Reads a flash image the way the firmware does: the table it would fly with, refused
/// (an error) only if no copy passes; refused copies are reported in the second value.
pub fn read_image(path: &Path) -> Result<(CalibrationTable, store::Loaded)> {
    let bytes = std::fs::read(path).with_context(|| format!("cannot read {}", path.display()))?;
    let loaded = store::load(&bytes);
    if loaded.defaulted() {
        bail!("{}: no copy passed (A: {:?}, B: {:?})", path.display(), loaded.slot_errors[0], loaded.slot_errors[1]);
    }
    Ok((loaded.table, loaded))
}
