//! Session files: CSV with a header naming each column and its unit (`docs/SESSION-FORMAT.md`).
//!
//! The file is streamed record by record through the `csv` crate (never read whole into a
//! string); the columns are kept as `f64` vectors. Every refusal names the file, the line
//! and, where there is one, the column (1-based, with its header name).

use std::path::Path;

use indicatif::ProgressBar;
use ssis::calib::{Misalignment, GAMMA_NOMINAL_RAD};

/// Earth rotation rate, rad/s (15.041068 °/h, the paper's ω_E).
pub const EARTH_RATE_RAD_S: f64 = 15.041_068 / 3600.0 * std::f64::consts::PI / 180.0;

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
}

/// A refused session: file, line, column and what is wrong.
#[derive(Debug, Clone, thiserror::Error)]
#[error("{file}: line {line}{}: {message}", column_text(.column))]
pub struct SessionError {
    /// What went wrong.
    pub kind: SessionErrorKind,
    /// The file as given.
    pub file: String,
    /// 1-based line number (1 = the header).
    pub line: u64,
    /// 1-based column number and header name, when one column is at fault.
    pub column: Option<(usize, String)>,
    /// Plain words.
    pub message: String,
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

/// One FOG's data.
#[derive(Debug, Clone)]
pub struct FogData {
    /// Raw rate, rad/s (from `fogN_rad_s`, or `fogN_rad` divided by the sample interval).
    pub rate_rad_s: Vec<f64>,
    /// Temperature, °C, when the session has it.
    pub t_degc: Option<Vec<f64>>,
}

/// A session in memory: every column, and the quantities the model needs.
#[derive(Debug, Clone)]
pub struct Session {
    /// The file name as given (for messages).
    pub file: String,
    /// Header names, in file order.
    pub names: Vec<String>,
    /// Column data, in file order (after dropping the first row of an increment session).
    pub cols: Vec<Vec<f64>>,
    /// Role of each column.
    pub roles: Vec<Role>,
    /// Per FOG, index = FOG number.
    pub fogs: Vec<FogData>,
    /// Reference angular rate of the ICS, ICS components, rad/s.
    pub ref_rad_s: Vec<[f64; 3]>,
    /// Magnetic induction, ICS components, nT.
    pub field_nt: Option<Vec<[f64; 3]>>,
}

impl Session {
    /// Number of samples.
    pub fn len(&self) -> usize {
        self.t_s().len()
    }

    /// True when there are no samples.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Sample times, s.
    pub fn t_s(&self) -> &[f64] {
        self.column("t_s").unwrap_or(&[])
    }

    /// A column by header name.
    pub fn column(&self, name: &str) -> Option<&[f64]> {
        let k = self.names.iter().position(|n| n == name)?;
        Some(&self.cols[k])
    }

    /// Names of user (extra) columns.
    pub fn extra_columns(&self) -> Vec<&str> {
        self.names.iter().zip(&self.roles).filter(|(_, r)| **r == Role::Extra).map(|(n, _)| n.as_str()).collect()
    }

    /// Median sample interval, s.
    pub fn median_dt_s(&self) -> f64 {
        let t = self.t_s();
        let mut d: Vec<f64> = t.windows(2).map(|w| w[1] - w[0]).collect();
        if d.is_empty() {
            return 1.0;
        }
        d.sort_by(f64::total_cmp);
        d[d.len() / 2]
    }
}

/// Nominal sensitive axes s_i of the unit (misalignment zero, γ nominal), ICS.
pub fn nominal_axes() -> [nalgebra::Vector3<f64>; 4] {
    Misalignment::default().axes(GAMMA_NOMINAL_RAD)
}

/// Earth rate in ICS for the turntable geometry of `docs/SESSION-FORMAT.md`: Z_P up,
/// X_P at azimuth ψ (from north, clockwise), so ω = (Ω_N cos ψ, Ω_N sin ψ, Ω_U), with
/// Ω_N = ω_E cos φ, Ω_U = ω_E sin φ (the paper's reference ω* = ω_E sin φ for a vertical SA).
pub fn earth_rate_ics(psi_rad: f64, lat_rad: f64) -> [f64; 3] {
    let (n, u) = (EARTH_RATE_RAD_S * lat_rad.cos(), EARTH_RATE_RAD_S * lat_rad.sin());
    [n * psi_rad.cos(), n * psi_rad.sin(), u]
}

struct Reader<'a> {
    file: &'a str,
    names: Vec<String>,
}

impl Reader<'_> {
    fn err(
        &self,
        kind: SessionErrorKind,
        line: u64,
        column: Option<usize>,
        message: impl Into<String>,
    ) -> SessionError {
        SessionError {
            kind,
            file: self.file.to_string(),
            line,
            column: column.map(|k| (k + 1, self.names.get(k).cloned().unwrap_or_default())),
            message: message.into(),
        }
    }
}

/// Reads and checks a session file. `progress`, when given, advances with the bytes read.
pub fn read_session(path: &Path, progress: Option<&ProgressBar>) -> Result<Session, SessionError> {
    let file = path.display().to_string();
    let io = |e: &dyn std::fmt::Display| SessionError {
        kind: SessionErrorKind::Io,
        file: file.clone(),
        line: 0,
        column: None,
        message: format!("cannot read: {e}"),
    };
    let f = std::fs::File::open(path).map_err(|e| io(&e))?;
    if let (Some(pb), Ok(m)) = (progress, f.metadata()) {
        pb.set_length(m.len());
    }
    let mut rdr = csv::ReaderBuilder::new()
        .has_headers(false)
        .flexible(true)
        .trim(csv::Trim::All)
        .comment(Some(b'#'))
        .from_reader(std::io::BufReader::new(f));
    let mut rec = csv::ByteRecord::new();
    let mut r = Reader { file: &file, names: Vec::new() };
    // Header: the first record that is not a comment.
    let has_header = rdr.read_byte_record(&mut rec).map_err(|e| io(&e))?;
    if !has_header || rec.iter().all(|f| f.is_empty()) {
        return Err(r.err(
            SessionErrorKind::Empty,
            1,
            None,
            "the file is empty: expected a header line naming the columns",
        ));
    }
    let header_line = rec.position().map_or(1, |p| p.line());
    for (k, f) in rec.iter().enumerate() {
        let name = String::from_utf8_lossy(f).to_string();
        if r.names.contains(&name) {
            r.names.push(name);
            return Err(r.err(SessionErrorKind::BadHeader, header_line, Some(k), "this column name is given twice"));
        }
        r.names.push(name);
    }
    let mut roles = Vec::with_capacity(r.names.len());
    for (k, name) in r.names.iter().enumerate() {
        match classify(name) {
            Ok(role) => roles.push(role),
            Err((kind, why)) => return Err(r.err(kind, header_line, Some(k), why)),
        }
    }
    let missing = |what: &str| r.err(SessionErrorKind::MissingColumn, header_line, None, what.to_string());
    if !roles.contains(&Role::Time) {
        return Err(missing("missing column `t_s` (sample time, s)"));
    }
    let n_fog = roles
        .iter()
        .filter_map(|r| match r {
            Role::FogRate(i) | Role::FogIncrement(i) => Some(i + 1),
            _ => None,
        })
        .max()
        .unwrap_or(0);
    if n_fog == 0 {
        return Err(missing("missing column `fog0_rad_s` (or `fog0_rad`): the session has no FOG output"));
    }
    for i in 0..n_fog {
        if !roles.iter().any(|r| matches!(r, Role::FogRate(j) | Role::FogIncrement(j) if *j == i)) {
            return Err(missing(&format!("missing column `fog{i}_rad_s` (FOGs are numbered from 0 without gaps)")));
        }
        if roles.contains(&Role::FogRate(i)) && roles.contains(&Role::FogIncrement(i)) {
            let k = roles.iter().position(|r| *r == Role::FogIncrement(i)).unwrap_or(0);
            return Err(r.err(
                SessionErrorKind::BadHeader,
                header_line,
                Some(k),
                "FOG given both as rate and increment",
            ));
        }
    }
    for (k, role) in roles.iter().enumerate() {
        if let Role::FogTemp(i) = role {
            if *i >= n_fog {
                return Err(r.err(
                    SessionErrorKind::BadHeader,
                    header_line,
                    Some(k),
                    "temperature of a FOG with no output",
                ));
            }
        }
    }
    let has_ref: Vec<bool> = (0..3).map(|a| roles.contains(&Role::Reference(a))).collect();
    let has_field: Vec<bool> = (0..3).map(|a| roles.contains(&Role::Field(a))).collect();
    if has_ref.iter().any(|&b| b) && !has_ref.iter().all(|&b| b) {
        return Err(missing("the reference rate needs all three of `ref_x_rad_s`, `ref_y_rad_s`, `ref_z_rad_s`"));
    }
    if has_field.iter().any(|&b| b) && !has_field.iter().all(|&b| b) {
        return Err(missing("the magnetic field needs all three of `b_x_nt`, `b_y_nt`, `b_z_nt`"));
    }
    let earth_ref = roles.contains(&Role::Psi) && roles.contains(&Role::Lat);
    if !has_ref[0] && !earth_ref {
        return Err(missing(
            "missing reference: give `ref_x_rad_s`, `ref_y_rad_s`, `ref_z_rad_s`, or `psi_rad` and `lat_rad` \
             (Earth rate on a turntable, plus `table_rate_rad_s` if it turns)",
        ));
    }

    // Rows.
    let ncol = r.names.len();
    let t_col = roles.iter().position(|r| *r == Role::Time).unwrap_or(0);
    let mut cols: Vec<Vec<f64>> = vec![Vec::new(); ncol];
    let mut last_t = f64::NEG_INFINITY;
    let mut rows = 0u64;
    loop {
        match rdr.read_byte_record(&mut rec) {
            Ok(true) => {}
            Ok(false) => break,
            Err(e) => {
                let line = e.position().map_or(0, |p| p.line());
                return Err(r.err(SessionErrorKind::BadNumber, line, None, format!("unreadable line: {e}")));
            }
        }
        let line = rec.position().map_or(0, |p| p.line());
        if rec.len() == 1 && rec.get(0).is_some_and(|f| f.is_empty()) {
            continue; // blank line
        }
        if rec.len() != ncol {
            let (col, what) = if rec.len() < ncol { (rec.len(), "missing") } else { (ncol.saturating_sub(1), "extra") };
            let msg = if rec.len() < ncol {
                format!("value {what}: the line has {} fields, the header {ncol} (truncated line?)", rec.len())
            } else {
                format!("the line has {} fields, the header only {ncol}", rec.len())
            };
            return Err(r.err(SessionErrorKind::FieldCount, line, Some(col), msg));
        }
        for (k, f) in rec.iter().enumerate() {
            let text = std::str::from_utf8(f).unwrap_or("");
            let v: f64 = match text.parse() {
                Ok(v) => v,
                Err(_) => {
                    let shown = String::from_utf8_lossy(f);
                    let msg = if shown.is_empty() {
                        "empty value, expected a number".to_string()
                    } else {
                        format!("`{shown}` is not a number")
                    };
                    return Err(r.err(SessionErrorKind::BadNumber, line, Some(k), msg));
                }
            };
            if !v.is_finite() {
                return Err(r.err(
                    SessionErrorKind::BadNumber,
                    line,
                    Some(k),
                    format!("`{text}` is not a finite number"),
                ));
            }
            cols[k].push(v);
        }
        let t = cols[t_col][cols[t_col].len() - 1];
        if t <= last_t {
            return Err(r.err(SessionErrorKind::BadValue, line, Some(t_col), "time does not increase"));
        }
        last_t = t;
        rows += 1;
        if let Some(pb) = progress {
            if rows.is_multiple_of(8192) {
                pb.set_position(rec.position().map_or(0, |p| p.byte()));
            }
        }
    }
    let increments = roles.iter().any(|r| matches!(r, Role::FogIncrement(_)));
    let min_rows = if increments { 3 } else { 2 };
    if (rows as usize) < min_rows {
        return Err(r.err(SessionErrorKind::NoRows, header_line, None, format!("fewer than {min_rows} data rows")));
    }
    if let Some(pb) = progress {
        pb.set_position(pb.length().unwrap_or(0));
    }

    // FOG rates: an increment covers (t_{k-1}, t_k]; the first row has no interval and is dropped.
    let t_all = cols[t_col].clone();
    let mut fog_rate: Vec<Vec<f64>> = vec![Vec::new(); n_fog];
    for (k, role) in roles.iter().enumerate() {
        match role {
            Role::FogRate(i) => fog_rate[*i] = cols[k].clone(),
            Role::FogIncrement(i) => {
                fog_rate[*i] = std::iter::once(f64::NAN)
                    .chain((1..t_all.len()).map(|j| cols[k][j] / (t_all[j] - t_all[j - 1])))
                    .collect()
            }
            _ => {}
        }
    }
    if increments {
        for c in cols.iter_mut().chain(fog_rate.iter_mut()) {
            c.remove(0);
        }
    }
    let n = cols[t_col].len();
    let col_of = |role: Role| roles.iter().position(|r| *r == role).map(|k| &cols[k]);
    let fogs = fog_rate
        .into_iter()
        .enumerate()
        .map(|(i, rate_rad_s)| FogData { rate_rad_s, t_degc: col_of(Role::FogTemp(i)).cloned() })
        .collect();
    let ref_rad_s: Vec<[f64; 3]> = if has_ref[0] {
        let (x, y, z) = (col_of(Role::Reference(0)), col_of(Role::Reference(1)), col_of(Role::Reference(2)));
        let (x, y, z) = (x.unwrap(), y.unwrap(), z.unwrap());
        (0..n).map(|j| [x[j], y[j], z[j]]).collect()
    } else {
        let psi = col_of(Role::Psi).unwrap();
        let lat = col_of(Role::Lat).unwrap();
        let table = col_of(Role::TableRate);
        (0..n)
            .map(|j| {
                let mut w = earth_rate_ics(psi[j], lat[j]);
                w[2] += table.map_or(0.0, |c| c[j]);
                w
            })
            .collect()
    };
    let field_nt = if has_field[0] {
        let (x, y, z) =
            (col_of(Role::Field(0)).unwrap(), col_of(Role::Field(1)).unwrap(), col_of(Role::Field(2)).unwrap());
        Some((0..n).map(|j| [x[j], y[j], z[j]]).collect())
    } else {
        None
    };
    let names = r.names;
    Ok(Session { file, names, cols, roles, fogs, ref_rad_s, field_nt })
}
