//! A session's columns: the role of each header name ([`classify`]), the physical range of
//! its values ([`physical_range`]), and the refusal that names file, line and column
//! ([`SessionError`]).

/// What went wrong with a session file.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SessionErrorKind {
    /// The file cannot be opened or read.
    Io,
    /// The file has no header line.
    Empty,
    /// The header has no data rows after it.
    NoRows,
    /// A column name with a unit the lab does not accept.
    Units,
    /// A column the session needs is absent.
    MissingColumn,
    /// A column name given twice, or a malformed name.
    BadHeader,
    /// A value that is not a number (or not finite).
    BadNumber,
    /// A line with fewer or more fields than the header.
    FieldCount,
    /// A value that is a number but not acceptable (time not increasing).
    BadValue,
    /// A number outside its physical range (a rate beyond the FOG's measuring range, a
    /// temperature outside −100…+150 °C, an absurd magnitude).
    OutOfRange,
    /// The last line has no line end: the file may have been cut while it was written.
    Truncated,
    /// Not UTF-8 text (a UTF-16 byte-order mark).
    Encoding,
}

/// The FOG's measuring range, rad/s: ±100 °/s, that of the launch-vehicle unit, the larger
/// of the two units' (`ssis::flight::Profile`). A session's FOG rates (or increments over
/// their interval) and reference rates beyond it are refused.
pub const MEASURING_RANGE_RAD_S: f64 = 100.0 * std::f64::consts::PI / 180.0;

/// The temperatures a session may hold, °C (a FOG or chamber outside is a wrong column or
/// unit: kelvin, a sensor fault code).
pub const TEMPERATURE_RANGE_DEGC: (f64, f64) = (-100.0, 150.0);

/// Largest magnitude of any value of any column: beyond it a number is a corrupted field
/// (`1e300`), whatever the column's unit.
pub const ABSURD_MAGNITUDE: f64 = 1e12;

/// `v` as a person reads it: plain between 10⁻⁴ and 10⁷ (four decimals at most), else with
/// an exponent (`1e300`).
pub(crate) fn readable(v: f64) -> String {
    if v == 0.0 || (1e-4..1e7).contains(&v.abs()) {
        let s = format!("{v:.4}");
        s.trim_end_matches('0').trim_end_matches('.').to_string()
    } else {
        format!("{v:e}")
    }
}

/// The physical range of a column of `role`, in its unit, and the words that say why.
pub fn physical_range(role: Role) -> ((f64, f64), &'static str) {
    let r = MEASURING_RANGE_RAD_S;
    match role {
        Role::FogRate(_) => ((-r, r), "the FOG's measuring range, ±100 °/s"),
        Role::TableRate | Role::Reference(_) => ((-r, r), "the FOG's measuring range, ±100 °/s (a reference rate)"),
        Role::FogTemp(_) => (TEMPERATURE_RANGE_DEGC, "−100 … +150 °C"),
        Role::Lat => {
            let h = std::f64::consts::FRAC_PI_2;
            ((-h, h), "±π/2 rad (a latitude in degrees?)")
        }
        Role::Field(_) => ((-1e7, 1e7), "±10⁷ nT (10 mT; the Earth's field is about 5·10⁴ nT)"),
        _ => ((-ABSURD_MAGNITUDE, ABSURD_MAGNITUDE), "±10¹² in any unit"),
    }
}

/// A refused session: file, line, column and what is wrong.
#[derive(Debug, Clone, thiserror::Error)]
#[error("{file}{}{}: {message}", line_text(*.line), column_text(.column))]
pub struct SessionError {
    /// What went wrong.
    pub kind: SessionErrorKind,
    /// The file as given.
    pub file: String,
    /// 1-based line number (1 = the header); 0 when the file could not be opened or read
    /// as a whole (then the message names no line).
    pub line: u64,
    /// 1-based column number and header name, when one column is at fault.
    pub column: Option<(usize, String)>,
    /// Plain words.
    pub message: String,
}

fn line_text(line: u64) -> String {
    if line == 0 {
        String::new()
    } else {
        format!(": line {line}")
    }
}

fn column_text(c: &Option<(usize, String)>) -> String {
    match c {
        Some((k, name)) => format!(", column {k} (`{name}`)"),
        None => String::new(),
    }
}

/// The role of one column, from its header name.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Role {
    /// `t_s`: sample time, s (the end of the sample interval).
    Time,
    /// `fogN_rad_s`: raw rate of FOG N, rad/s (mean over the sample interval).
    FogRate(usize),
    /// `fogN_rad`: raw angle increment of FOG N over the sample interval, rad.
    FogIncrement(usize),
    /// `fogN_t_degc`: temperature of FOG N, °C.
    FogTemp(usize),
    /// `table_rate_rad_s`: turntable rate about its axis (= ICS Z_P, vertical), rad/s.
    TableRate,
    /// `psi_rad`: azimuth of X_P from north (clockwise), rad.
    Psi,
    /// `lat_rad`: latitude, rad.
    Lat,
    /// `ref_x_rad_s` … : reference angular rate of the ICS in ICS components, rad/s.
    Reference(usize),
    /// `b_x_nt` …: magnetic induction in ICS components, nT.
    Field(usize),
    /// Any other column: kept for expressions and correlation checks.
    Extra,
}

/// Unit suffixes recognised as units (so `psi_deg` is refused, not taken as a user column).
const OTHER_UNITS: [&str; 22] = [
    "s", "ms", "us", "min", "h", "rad", "mrad", "deg", "arcsec", "rad_s", "deg_s", "deg_h", "rpm", "nt", "ut", "mt",
    "t", "gauss", "g", "degc", "k", "degf",
];

/// Classifies a header name; `Err` says why the name (its unit) is refused.
pub fn classify(name: &str) -> Result<Role, (SessionErrorKind, String)> {
    let units = |what: &str| Err((SessionErrorKind::Units, what.to_string()));
    if name == "t_s" {
        return Ok(Role::Time);
    }
    if let Some(rest) = name.strip_prefix("fog") {
        let digits: String = rest.chars().take_while(|c| c.is_ascii_digit()).collect();
        if let Ok(i) = digits.parse::<usize>() {
            return match &rest[digits.len()..] {
                "_rad_s" => Ok(Role::FogRate(i)),
                "_rad" => Ok(Role::FogIncrement(i)),
                "_t_degc" => Ok(Role::FogTemp(i)),
                _ => {
                    units("a FOG column is `fogN_rad_s` (rate), `fogN_rad` (increment) or `fogN_t_degc` (temperature)")
                }
            };
        }
    }
    let fixed: [(&str, &str, Role); 10] = [
        ("t", "_s", Role::Time),
        ("table_rate", "_rad_s", Role::TableRate),
        ("psi", "_rad", Role::Psi),
        ("lat", "_rad", Role::Lat),
        ("ref_x", "_rad_s", Role::Reference(0)),
        ("ref_y", "_rad_s", Role::Reference(1)),
        ("ref_z", "_rad_s", Role::Reference(2)),
        ("b_x", "_nt", Role::Field(0)),
        ("b_y", "_nt", Role::Field(1)),
        ("b_z", "_nt", Role::Field(2)),
    ];
    for (stem, unit, role) in fixed {
        if name == format!("{stem}{unit}") {
            return Ok(role);
        }
        // A reserved quantity in another unit is refused rather than taken as a user column.
        if let Some(u) = name.strip_prefix(stem).and_then(|r| r.strip_prefix('_')) {
            if OTHER_UNITS.contains(&u) {
                return units(&format!("`{stem}` is given in `{stem}{unit}`, not `{name}`"));
            }
        }
    }
    let ok_ident = name.chars().next().is_some_and(|c| c.is_ascii_lowercase() || c == '_')
        && name.chars().all(|c| c.is_ascii_lowercase() || c.is_ascii_digit() || c == '_');
    if !ok_ident {
        return Err((
            SessionErrorKind::BadHeader,
            "a user column name is lower-case letters, digits and `_` (it is a variable in expressions)".into(),
        ));
    }
    Ok(Role::Extra)
}
