//! A logger's own CSV as a session: columns with the logger's names and units, mapped one by
//! one onto the session's (`docs/SESSION-FORMAT.md`) and converted to its units.
//!
//! A mapping ([`Mapping::parse`]) is `TARGET=SOURCE:UNIT`: the session column (`t_s`,
//! `fog0_rad_s`, `fog1_t_degc`, `ref_x_rad_s`, `psi_rad`, `b_x_nt`, a user column, …), the
//! logger's column by its header name, and the unit the logger wrote it in, which must measure
//! what the session column measures ([`Unit::parse`]): time `s`, `ms`, `us`, `ns`, `min`, `h`;
//! rate `rad/s`, `mrad/s`, `urad/s`, `deg/s`, `deg/h`; angle `rad`, `mrad`, `urad`, `deg`,
//! `arcsec`; temperature `degc`, `k`; field `nt`, `ut`, `gauss`; a user column `1` (as
//! written). Counts with a scale are `SCALE*UNIT` (`0.00875*deg/s`: one count is 0.00875 °/s).
//!
//! A static recording has no reference columns: the session's reference form 2 is then given
//! as constants ([`super::framelog::Turntable`]: azimuth, latitude, table rate).
//!
//! The logger's file: a header line of names, then one row per sample; fields separated by
//! commas (or by `;` or tabs, whichever the header uses), names and values optionally in double
//! quotes; blank lines and lines starting with `#` skipped; a UTF-8 byte-order mark skipped.
//! Unmapped columns are not read (they may hold text) and are named in the [`ImportReport`].
//! A mapped value that is not a number, a line with another number of fields than the
//! header, and a last line without its line end (a number cut short reads as another) are
//! refused with the file, the line and the logger's column; the session's own checks (time
//! increasing, physical ranges) name the logger's line and column too.

use std::fmt;
use std::path::Path;

use super::framelog::Turntable;
use super::session::{classify, session_from_columns, Role, Session, SessionError, SessionErrorKind};
use super::{LabError, LabResult};

/// What a unit measures.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Dimension {
    /// Seconds.
    Time,
    /// Radians per second.
    Rate,
    /// Radians.
    Angle,
    /// Degrees Celsius.
    Temperature,
    /// Nanotesla.
    Field,
    /// A user column: the value as written.
    Plain,
}

impl Dimension {
    /// What a session column of `role` measures.
    pub fn of(role: Role) -> Dimension {
        match role {
            Role::Time => Dimension::Time,
            Role::FogRate(_) | Role::Reference(_) | Role::TableRate => Dimension::Rate,
            Role::FogIncrement(_) | Role::Psi | Role::Lat => Dimension::Angle,
            Role::FogTemp(_) => Dimension::Temperature,
            Role::Field(_) => Dimension::Field,
            Role::Extra => Dimension::Plain,
        }
    }

    /// Its name in messages.
    pub fn name(self) -> &'static str {
        match self {
            Dimension::Time => "time",
            Dimension::Rate => "rate",
            Dimension::Angle => "angle",
            Dimension::Temperature => "temperature",
            Dimension::Field => "field",
            Dimension::Plain => "plain",
        }
    }

    fn units(self) -> &'static str {
        match self {
            Dimension::Time => "s, ms, us, ns, min, h",
            Dimension::Rate => "rad/s, mrad/s, urad/s, deg/s, deg/h",
            Dimension::Angle => "rad, mrad, urad, deg, arcsec",
            Dimension::Temperature => "degc, k",
            Dimension::Field => "nt, ut, gauss",
            Dimension::Plain => "1",
        }
    }
}

/// Units a logger may write, by name (lower case): what they measure, and the factor and
/// offset to the session's unit.
const UNITS: [(&str, Dimension, f64, f64); 20] = {
    use std::f64::consts::PI;
    use Dimension::*;
    [
        ("s", Time, 1.0, 0.0),
        ("ms", Time, 1e-3, 0.0),
        ("us", Time, 1e-6, 0.0),
        ("ns", Time, 1e-9, 0.0),
        ("min", Time, 60.0, 0.0),
        ("h", Time, 3600.0, 0.0),
        ("rad/s", Rate, 1.0, 0.0),
        ("mrad/s", Rate, 1e-3, 0.0),
        ("urad/s", Rate, 1e-6, 0.0),
        ("deg/s", Rate, PI / 180.0, 0.0),
        ("deg/h", Rate, PI / 180.0 / 3600.0, 0.0),
        ("rad", Angle, 1.0, 0.0),
        ("mrad", Angle, 1e-3, 0.0),
        ("urad", Angle, 1e-6, 0.0),
        ("deg", Angle, PI / 180.0, 0.0),
        ("arcsec", Angle, PI / 180.0 / 3600.0, 0.0),
        ("degc", Temperature, 1.0, 0.0),
        ("k", Temperature, 1.0, -273.15),
        ("nt", Field, 1.0, 0.0),
        ("ut", Field, 1e3, 0.0),
    ]
};

/// A logger's unit: session value = scale × factor × logged value + offset.
#[derive(Debug, Clone, PartialEq)]
pub struct Unit {
    /// As the mapping wrote it (`0.00875*deg/s`).
    pub text: String,
    /// What it measures.
    pub dimension: Dimension,
    /// Factor to the session's unit, the scale of counts included.
    pub factor: f64,
    /// Offset to the session's unit (kelvin to °C).
    pub offset: f64,
}

impl Unit {
    /// Reads `[SCALE*]UNIT` (see the module text); `Err` says why not.
    pub fn parse(text: &str) -> Result<Unit, String> {
        let (scale, name) = match text.rsplit_once('*') {
            Some((s, n)) => match s.trim().parse::<f64>() {
                Ok(v) if v.is_finite() && v != 0.0 => (v, n),
                _ => return Err(format!("`{s}` in `{text}` is not a scale (a finite non-zero number)")),
            },
            None => (1.0, text),
        };
        let key = name.trim().to_ascii_lowercase();
        let (dimension, factor, offset) = if key == "1" {
            (Dimension::Plain, 1.0, 0.0)
        } else if key == "gauss" {
            (Dimension::Field, 1e5, 0.0)
        } else {
            let Some(&(_, d, f, o)) = UNITS.iter().find(|u| u.0 == key) else {
                return Err(format!(
                    "unknown unit `{name}`: time {}; rate {}; angle {}; temperature {}; field {}; a user column 1; \
                     counts as SCALE*UNIT",
                    Dimension::Time.units(),
                    Dimension::Rate.units(),
                    Dimension::Angle.units(),
                    Dimension::Temperature.units(),
                    Dimension::Field.units()
                ));
            };
            (d, f, o)
        };
        if offset != 0.0 && scale != 1.0 {
            return Err(format!("`{text}`: a scale applies to a unit without an offset (not kelvin)"));
        }
        Ok(Unit { text: text.to_string(), dimension, factor: scale * factor, offset })
    }

    /// The session's value of a logged value.
    pub fn convert(&self, v: f64) -> f64 {
        v * self.factor + self.offset
    }
}

/// One session column from one logger column.
#[derive(Debug, Clone, PartialEq)]
pub struct Mapping {
    /// The session column's name.
    pub target: String,
    /// The logger's column name, as in its header.
    pub source: String,
    /// The logger's unit of it.
    pub unit: Unit,
}

impl Mapping {
    /// Reads `TARGET=SOURCE:UNIT`, checking that the unit measures what the session column
    /// does; `Err` says why not.
    pub fn parse(spec: &str) -> LabResult<Mapping> {
        let bad = |why: String| LabError::Usage(format!("mapping `{spec}`: {why}"));
        let Some((target, rest)) = spec.split_once('=') else {
            return Err(bad("not TARGET=SOURCE:UNIT (fog0_rad_s=gyro_x:deg/s)".into()));
        };
        let Some((source, unit)) = rest.rsplit_once(':') else {
            return Err(bad("no unit: TARGET=SOURCE:UNIT (fog0_rad_s=gyro_x:deg/s)".into()));
        };
        let target = target.trim().to_string();
        let role = classify(&target).map_err(|(_, why)| bad(format!("`{target}` is no session column: {why}")))?;
        let unit = Unit::parse(unit.trim()).map_err(bad)?;
        let wanted = Dimension::of(role);
        if unit.dimension != wanted {
            return Err(bad(format!(
                "`{target}` takes a {} unit ({}), not `{}` ({})",
                wanted.name(),
                wanted.units(),
                unit.text,
                unit.dimension.name()
            )));
        }
        Ok(Mapping { target, source: source.trim().to_string(), unit })
    }
}

/// What an import mapped and read.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ImportReport {
    /// The logger's file.
    pub file: String,
    /// Each session column and where it came from, in session order.
    pub mapped: Vec<String>,
    /// The logger's columns not read (1-based number and name).
    pub unmapped: Vec<(usize, String)>,
    /// Data lines read.
    pub rows: u64,
    /// Samples in the session.
    pub samples: usize,
}

impl fmt::Display for ImportReport {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        writeln!(f, "{}: {} data lines, {} samples", self.file, self.rows, self.samples)?;
        for m in &self.mapped {
            writeln!(f, "  {m}")?;
        }
        if self.unmapped.is_empty() {
            write!(f, "every column mapped")
        } else {
            let names: Vec<String> = self.unmapped.iter().map(|(k, n)| format!("{k} `{n}`")).collect();
            write!(f, "not mapped: column {}", names.join(", column "))
        }
    }
}

/// The session's reference given by the logger's columns or by `table`, never both or neither.
fn check_reference(file: &str, maps: &[Mapping], table: Option<&Turntable>) -> LabResult<()> {
    let has = |r: fn(Role) -> bool| maps.iter().any(|m| classify(&m.target).is_ok_and(r));
    let mapped = has(|r| matches!(r, Role::Reference(_) | Role::Psi | Role::Lat | Role::TableRate));
    match (mapped, table) {
        (true, Some(_)) => Err(LabError::Usage(format!(
            "{file}: the reference is both mapped from columns and given as constants (--psi-rad, --lat-rad): give one"
        ))),
        (false, None) => Err(LabError::Usage(format!(
            "{file}: no reference: map ref_x_rad_s, ref_y_rad_s, ref_z_rad_s (or psi_rad and lat_rad) from columns, \
             or give the static position as --psi-rad and --lat-rad"
        ))),
        _ => Ok(()),
    }
}

/// Splits a line into its fields (`sep`), trimmed and without enclosing double quotes.
fn fields(line: &str, sep: char) -> Vec<&str> {
    line.split(sep)
        .map(|f| {
            let f = f.trim();
            f.strip_prefix('"').and_then(|g| g.strip_suffix('"')).unwrap_or(f)
        })
        .collect()
}

/// A logger's CSV `path` as a session, by `maps` (and the constant reference `table` where
/// the logger has none); see the module text.
pub fn read_logger_csv(path: &Path, maps: &[Mapping], table: Option<&Turntable>) -> LabResult<(Session, ImportReport)> {
    let file = path.display().to_string();
    let err = |kind, line, column: Option<(usize, String)>, message: String| {
        LabError::Session(SessionError { kind, file: file.clone(), line, column, message })
    };
    check_reference(&file, maps, table)?;
    for (k, m) in maps.iter().enumerate() {
        if maps[..k].iter().any(|o| o.target == m.target) {
            return Err(LabError::Usage(format!("{file}: `{}` is mapped twice", m.target)));
        }
    }
    let bytes = std::fs::read(path).map_err(|e| err(SessionErrorKind::Io, 0, None, format!("cannot read: {e}")))?;
    let text = std::str::from_utf8(&bytes)
        .map_err(|e| err(SessionErrorKind::Encoding, 0, None, format!("not UTF-8 text ({e})")))?;
    let text = text.strip_prefix('\u{feff}').unwrap_or(text);
    let mut lines = text.split_inclusive('\n').enumerate().map(|(k, l)| (k as u64 + 1, l));
    let kept = |l: &str| !l.trim().is_empty() && !l.trim_start().starts_with('#');
    let Some((header_line, header)) = lines.by_ref().find(|(_, l)| kept(l)) else {
        return Err(err(SessionErrorKind::Empty, 0, None, "no header line".into()));
    };
    let sep = [',', ';', '\t'].into_iter().find(|c| header.contains(*c)).unwrap_or(',');
    let names: Vec<String> = fields(header.trim_end_matches(['\r', '\n']), sep).into_iter().map(String::from).collect();
    let mut source_col = Vec::with_capacity(maps.len());
    for m in maps {
        let Some(k) = names.iter().position(|n| *n == m.source) else {
            return Err(err(
                SessionErrorKind::MissingColumn,
                header_line,
                None,
                format!("no column `{}` (mapped to `{}`); the header has `{}`", m.source, m.target, names.join("`, `")),
            ));
        };
        source_col.push(k);
    }
    let constants: Vec<(&str, f64, &str)> = table.map_or(Vec::new(), |t| {
        vec![
            ("psi_rad", t.psi_rad, "--psi-rad"),
            ("lat_rad", t.lat_rad, "--lat-rad"),
            ("table_rate_rad_s", t.table_rate_rad_s, "--table-rate-rad-s"),
        ]
    });
    let mut cols: Vec<Vec<f64>> = vec![Vec::new(); maps.len()];
    let mut src_line = Vec::new();
    for (line, l) in lines.filter(|(_, l)| kept(l)) {
        if !l.ends_with('\n') {
            let why = "the last line has no line end: the file may have been cut while it was written";
            return Err(err(SessionErrorKind::Truncated, line, None, why.into()));
        }
        let f = fields(l.trim_end_matches(['\r', '\n']), sep);
        if f.len() != names.len() {
            let why = format!("{} fields, the header has {}", f.len(), names.len());
            return Err(err(SessionErrorKind::FieldCount, line, None, why));
        }
        for ((c, &k), m) in cols.iter_mut().zip(&source_col).zip(maps) {
            let v = f[k].parse::<f64>().ok().filter(|v| v.is_finite()).ok_or_else(|| {
                let why = format!("`{}` is not a finite number (mapped to `{}`)", f[k], m.target);
                err(SessionErrorKind::BadNumber, line, Some((k + 1, names[k].clone())), why)
            })?;
            c.push(m.unit.convert(v));
        }
        src_line.push(line);
    }
    let n = src_line.len();
    let mut targets: Vec<String> = maps.iter().map(|m| m.target.clone()).collect();
    targets.extend(constants.iter().map(|c| c.0.to_string()));
    cols.extend(constants.iter().map(|c| vec![c.1; n]));
    let s = session_from_columns(&file, targets, &cols).map_err(|mut e| {
        // The session's row j is the logger's line src_line[j]; its column k a mapped one.
        if e.line == 1 {
            e.line = header_line;
        } else if let Some(&l) = e.line.checked_sub(2).and_then(|j| src_line.get(j as usize)) {
            e.line = l;
        }
        if let Some((k, target)) = e.column.take() {
            match source_col.get(k - 1) {
                Some(&c) => {
                    e.column = Some((c + 1, names[c].clone()));
                    e.message = format!("{} (mapped to `{target}`)", e.message);
                }
                None => e.message = format!("`{target}`: {}", e.message),
            }
        }
        LabError::Session(e)
    })?;
    let mut rep = ImportReport { file, rows: n as u64, samples: s.len(), ..ImportReport::default() };
    for (m, &k) in maps.iter().zip(&source_col) {
        let how = if m.unit.factor == 1.0 && m.unit.offset == 0.0 {
            String::new()
        } else if m.unit.offset == 0.0 {
            format!(", × {:.6e}", m.unit.factor)
        } else {
            format!(", {:+}", m.unit.offset)
        };
        rep.mapped.push(format!("{} <- column {} `{}` in {}{how}", m.target, k + 1, m.source, m.unit.text));
    }
    for (name, v, option) in &constants {
        rep.mapped.push(format!("{name} = {v} ({option})"));
    }
    rep.unmapped =
        names.iter().enumerate().filter(|(k, _)| !source_col.contains(k)).map(|(k, n)| (k + 1, n.clone())).collect();
    Ok((s, rep))
}
