//! Table updates that keep what they cannot improve, and per-field differences.
//!
//! A tool (`ssis-lab export`, every `ssis-cal … --table`) proposes a table and names the
//! fields its session identifies; [`apply`] copies exactly those from the proposal onto the
//! base, bit for bit, keeps every other field of the base bit for bit, raises the revision
//! to the base's + 1 (it never goes back), records the [`Origin`] of each field it set as a
//! `[[provenance]]` entry, and checks the result's ranges. [`render`] prints the
//! change field by field in engineering units (°/h, ppm, ″, °/h per °C, …); [`diff`]
//! compares two tables (`ssis-sim table diff`).

use anyhow::{anyhow, Result};
use ssis::calib::{CalibrationTable, Field};

use crate::table::{significant, Provenance, TableDoc};

/// Where an update's values come from.
#[derive(Debug, Clone, PartialEq)]
pub struct Origin {
    /// The command (`ssis-lab export`, `ssis-cal allan`, …).
    pub command: String,
    /// The session or telemetry file(s), as given.
    pub session: String,
    /// The model file and its version, for an export.
    pub model: Option<(String, u32)>,
}

/// One field's old and new value, table units.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Change {
    /// The field.
    pub field: Field,
    /// Its value before (in the base, or table A).
    pub old: f64,
    /// Its value after (or in table B).
    pub new: f64,
}

impl Change {
    /// Whether the value changed (bit for bit).
    pub fn changed(&self) -> bool {
        self.old.to_bits() != self.new.to_bits()
    }
}

/// `base` with the `set` fields taken from `proposed`, everything else kept bit for bit,
/// revision base + 1, the provenance of the set fields replaced by `origin`'s. Refused (the
/// field named) when the result is outside a plausible range, or the revision would wrap.
pub fn apply(
    base: &TableDoc,
    proposed: &CalibrationTable,
    set: &[Field],
    origin: &Origin,
) -> Result<(TableDoc, Vec<Change>)> {
    let mut table = base.table;
    let revision =
        base.table.revision.checked_add(1).ok_or_else(|| anyhow!("the base table's revision is the last one"))?;
    table.revision = revision;
    let mut changes = Vec::new();
    for f in Field::all().filter(|f| set.contains(f)) {
        let (old, new) = (f.get(&base.table), f.get(proposed));
        f.set(&mut table, new);
        changes.push(Change { field: f, old, new });
    }
    table.validate().map_err(|e| anyhow!("the updated table is refused: {e}"))?;
    let names: Vec<String> = changes.iter().map(|c| c.field.to_string()).collect();
    let mut provenance: Vec<Provenance> =
        base.provenance.iter().filter(|p| !names.contains(&p.field)).cloned().collect();
    provenance.extend(names.into_iter().map(|field| Provenance {
        field,
        command: origin.command.clone(),
        session: origin.session.clone(),
        model: origin.model.as_ref().map(|m| m.0.clone()),
        model_version: origin.model.as_ref().map(|m| m.1),
        revision,
    }));
    let index = |p: &Provenance| Field::all().position(|f| f.to_string() == p.field).unwrap_or(usize::MAX);
    provenance.sort_by_key(index);
    Ok((TableDoc { table, provenance }, changes))
}

/// Every field that differs between `a` and `b` (bit for bit; a gain override present in
/// one only counts as all its fields differing).
pub fn diff(a: &CalibrationTable, b: &CalibrationTable) -> Vec<Change> {
    let gains_differ = a.observer.gains_override.is_some() != b.observer.gains_override.is_some();
    Field::all()
        .map(|field| Change { field, old: field.get(a), new: field.get(b) })
        .filter(|c| c.changed() || (gains_differ && c.field.is_gain()))
        .collect()
}

/// One line per change: the field, old → new and the difference, engineering units;
/// unchanged fields say so.
pub fn render(changes: &[Change]) -> String {
    let width = changes.iter().map(|c| c.field.to_string().len()).max().unwrap_or(0);
    let mut out = String::new();
    for c in changes {
        let s = c.field.spec();
        let (old, new) = (c.old * s.eng_per_unit, c.new * s.eng_per_unit);
        let unit = if s.eng_unit.is_empty() { String::new() } else { format!(" {}", s.eng_unit) };
        let tail = if c.changed() {
            format!("{} → {}{unit}  (Δ {})", significant(old), significant(new), significant(new - old))
        } else {
            format!("{}{unit}  (unchanged)", significant(new))
        };
        out.push_str(&format!("  {:<width$}  {tail}\n", c.field.to_string()));
    }
    out
}

/// `render`'s lines with, beside each changed field whose value a tool had set, who set it
/// (the base's provenance).
fn with_provenance(rendered: &str, base: &TableDoc, changes: &[Change]) -> String {
    rendered
        .lines()
        .zip(changes)
        .map(|(line, c)| {
            if !c.changed() {
                return format!("{line}\n");
            }
            let field = c.field.to_string();
            match base.provenance.iter().find(|p| p.field == field) {
                Some(p) => {
                    let model = p.model.as_ref().map_or(String::new(), |m| {
                        format!(", model {m}{}", p.model_version.map_or(String::new(), |v| format!(" version {v}")))
                    });
                    format!("{line}  [was set by {} from {}{model}]\n", p.command, p.session)
                }
                None => format!("{line}\n"),
            }
        })
        .collect()
}

/// The star-tracker mount as an angle: how far the updated `st_mount_q` turns from the
/// base's, in ″ (a quaternion's components alone say little); empty when it did not change.
fn mount_turn(base: &TableDoc, updated: &TableDoc) -> String {
    let (a, b) = (base.table.st_mount_q, updated.table.st_mount_q);
    if a == b {
        return String::new();
    }
    let dot: f64 = a.iter().zip(&b).map(|(x, y)| x * y).sum::<f64>().abs();
    let norm = (a.iter().map(|x| x * x).sum::<f64>() * b.iter().map(|x| x * x).sum::<f64>()).sqrt();
    let turn = 2.0 * (dot / norm).clamp(-1.0, 1.0).acos() * crate::ARCSEC_PER_RAD;
    format!("  st_mount_q turns the star-tracker mount by {turn:.2} ″ from the base's\n")
}

/// The report of an update: the revision, the origin, each field set, and how many kept.
pub fn report(base: &TableDoc, updated: &TableDoc, changes: &[Change], origin: &Origin) -> String {
    let model = origin.model.as_ref().map_or(String::new(), |(m, v)| format!(", model {m} version {v}"));
    let changed = changes.iter().filter(|c| c.changed()).count();
    format!(
        "table update by {} from {}{model}: revision {} → {}; {} field(s) set ({changed} changed), the other {} kept bit for bit:\n{}",
        origin.command,
        origin.session,
        base.table.revision,
        updated.table.revision,
        changes.len(),
        ssis::calib::field::N_FIELDS - changes.len(),
        with_provenance(&render(changes), base, changes)
    ) + &mount_turn(base, updated)
}
