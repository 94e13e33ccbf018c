//! A session's header: its names, the role of each column and the column layout.

use crate::*;

/// The columns of a session by role, from its header.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Layout {
    /// Number of FOGs.
    pub n_fog: usize,
    /// Column of `t_s`.
    pub t: usize,
    /// Column of each FOG's output and whether it is an increment (`fogN_rad`).
    pub fog: Vec<(usize, bool)>,
    /// Column of each FOG's temperature.
    pub fog_temp: Vec<Option<usize>>,
    /// Columns of `ref_x_rad_s`, `ref_y_rad_s`, `ref_z_rad_s` (form 1).
    pub reference: Option<[usize; 3]>,
    /// Columns of `psi_rad`, `lat_rad` (form 2).
    pub turntable: Option<[usize; 2]>,
    /// Column of `table_rate_rad_s`.
    pub table_rate: Option<usize>,
    /// Columns of `b_x_nt`, `b_y_nt`, `b_z_nt`.
    pub field: Option<[usize; 3]>,
}

impl Layout {
    /// Whether the FOG outputs are increments (the first row is then dropped).
    pub fn increments(&self) -> bool {
        self.fog.iter().any(|f| f.1)
    }
}

/// A session's header: names, roles and the column layout.
#[derive(Debug, Clone)]
pub struct Header {
    /// The file name as given.
    pub file: String,
    /// Column names in file order.
    pub names: Vec<String>,
    /// Role of each column.
    pub roles: Vec<Role>,
    /// Columns by role.
    pub layout: Layout,
    /// Line of the header (after comments), 1-based.
    pub line: u64,
}

impl Header {
    pub(crate) fn empty(file: &str) -> Header {
        Header { file: file.to_string(), names: Vec::new(), roles: Vec::new(), layout: Layout::default(), line: 0 }
    }

    pub(crate) fn err(
        &self,
        kind: SessionErrorKind,
        line: u64,
        column: Option<usize>,
        message: impl Into<String>,
    ) -> SessionError {
        SessionError {
            kind,
            file: self.file.clone(),
            line,
            column: column.map(|k| (k + 1, self.names.get(k).cloned().unwrap_or_default())),
            message: message.into(),
        }
    }

    /// Checks one row's values against their columns' physical ranges ([`physical_range`];
    /// a FOG increment as the rate over its interval since `prev_t`, if there is one): the
    /// first value outside, as kind, 0-based column and message.
    pub fn check_values(&self, row: &[f64], prev_t: Option<f64>) -> Option<(SessionErrorKind, usize, String)> {
        for (k, (&v, &role)) in row.iter().zip(&self.roles).enumerate() {
            let (v, role, per) = match (role, prev_t) {
                (Role::FogIncrement(i), Some(p)) => {
                    (v / (row[self.layout.t] - p), Role::FogRate(i), " over its interval")
                }
                (Role::FogIncrement(_), None) => (v, Role::Extra, ""),
                _ => (v, role, ""),
            };
            let ((lo, hi), why) = physical_range(role);
            if !(lo..=hi).contains(&v) {
                let deg = if matches!(role, Role::FogRate(_) | Role::TableRate | Role::Reference(_)) {
                    format!(" ({} °/s)", readable(v.to_degrees()))
                } else {
                    String::new()
                };
                return Some((
                    SessionErrorKind::OutOfRange,
                    k,
                    format!("`{}`{per}{deg} is outside {why}", readable(row[k])),
                ));
            }
        }
        None
    }

    /// A header of any numeric CSV with a `t_s` column and the `required` ones (every column
    /// a user column; for logs that are not sessions, `ssis_lab::framelog`).
    pub fn plain(file: &str, names: Vec<String>, line: u64, required: &[&str]) -> Result<Header, SessionError> {
        let mut h = Header::empty(file);
        h.line = line;
        h.roles = names.iter().map(|n| if n == "t_s" { Role::Time } else { Role::Extra }).collect();
        h.names = names;
        for r in std::iter::once(&"t_s").chain(required) {
            if !h.names.iter().any(|n| n == r) {
                return Err(h.err(SessionErrorKind::MissingColumn, line, None, format!("missing column `{r}`")));
            }
        }
        h.layout.t = h.names.iter().position(|n| n == "t_s").unwrap_or(0);
        Ok(h)
    }

    /// Classifies and checks the header names (`line` is the header's line number).
    pub fn parse(file: &str, names: Vec<String>, line: u64) -> Result<Header, SessionError> {
        let mut h = Header::empty(file);
        h.line = line;
        for (k, name) in names.into_iter().enumerate() {
            let twice = h.names.contains(&name);
            h.names.push(name);
            if twice {
                return Err(h.err(SessionErrorKind::BadHeader, line, Some(k), "this column name is given twice"));
            }
        }
        for (k, name) in h.names.iter().enumerate() {
            match classify(name) {
                Ok(role) => h.roles.push(role),
                Err((kind, why)) => return Err(h.err(kind, line, Some(k), why)),
            }
        }
        let roles = &h.roles;
        let pos = |role: Role| roles.iter().position(|r| *r == role);
        let missing = |what: &str| h.err(SessionErrorKind::MissingColumn, line, None, what.to_string());
        let Some(t) = pos(Role::Time) else { return Err(missing("missing column `t_s` (sample time, s)")) };
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
        let mut fog = Vec::new();
        for i in 0..n_fog {
            match (pos(Role::FogRate(i)), pos(Role::FogIncrement(i))) {
                (Some(_), Some(k)) => {
                    return Err(h.err(
                        SessionErrorKind::BadHeader,
                        line,
                        Some(k),
                        "FOG given both as rate and increment",
                    ))
                }
                (Some(k), None) => fog.push((k, false)),
                (None, Some(k)) => fog.push((k, true)),
                (None, None) => {
                    return Err(missing(&format!(
                        "missing column `fog{i}_rad_s` (FOGs are numbered from 0 without gaps)"
                    )))
                }
            }
        }
        for (k, role) in roles.iter().enumerate() {
            if let Role::FogTemp(i) = role {
                if *i >= n_fog {
                    return Err(h.err(
                        SessionErrorKind::BadHeader,
                        line,
                        Some(k),
                        "temperature of a FOG with no output",
                    ));
                }
            }
        }
        let three = |f: fn(usize) -> Role| -> Option<Vec<usize>> { (0..3).map(|a| pos(f(a))).collect() };
        let any3 = |f: fn(usize) -> Role| (0..3).any(|a| pos(f(a)).is_some());
        let reference = three(Role::Reference);
        if any3(Role::Reference) && reference.is_none() {
            return Err(missing("the reference rate needs all three of `ref_x_rad_s`, `ref_y_rad_s`, `ref_z_rad_s`"));
        }
        let field = three(Role::Field);
        if any3(Role::Field) && field.is_none() {
            return Err(missing("the magnetic field needs all three of `b_x_nt`, `b_y_nt`, `b_z_nt`"));
        }
        let turntable = pos(Role::Psi).zip(pos(Role::Lat)).map(|(a, b)| [a, b]);
        if reference.is_none() && turntable.is_none() {
            return Err(missing(
                "missing reference: give `ref_x_rad_s`, `ref_y_rad_s`, `ref_z_rad_s`, or `psi_rad` and `lat_rad` \
                 (Earth rate on a turntable, plus `table_rate_rad_s` if it turns)",
            ));
        }
        let arr3 = |v: Vec<usize>| [v[0], v[1], v[2]];
        h.layout = Layout {
            n_fog,
            t,
            fog,
            fog_temp: (0..n_fog).map(|i| pos(Role::FogTemp(i))).collect(),
            reference: reference.map(arr3),
            turntable,
            table_rate: pos(Role::TableRate),
            field: field.map(arr3),
        };
        Ok(h)
    }
}
