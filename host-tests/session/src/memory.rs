//! A session in memory ([`Session`]: `f64` columns), read whole ([`read_session`]) or built
//! from columns ([`session_from_columns`]), written back ([`session_csv`]), and the quick look
//! at a file before a pass ([`shape`]).

use crate::*;

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
    /// The file line of each sample (header = 1; comment lines and a dropped first row of
    /// an increment session counted), for messages about a sample.
    pub lines: Vec<u64>,
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

    /// The session's sample interval, s ([`median_interval_s`]).
    pub fn median_dt_s(&self) -> f64 {
        median_interval_s(self.t_s())
    }
}

/// Intervals [`median_interval_s`] looks at.
pub const INTERVALS_FOR_MEDIAN: usize = 1000;

/// The sample interval of a session: the median of its first [`INTERVALS_FOR_MEDIAN`] sample
/// intervals, s (1 s with fewer than two samples). Known after the first rows, so a pass over
/// a file can use it before it ends.
pub fn median_interval_s(t_s: &[f64]) -> f64 {
    let n = t_s.len().min(INTERVALS_FOR_MEDIAN + 1);
    let mut d: Vec<f64> = t_s[..n].windows(2).map(|w| w[1] - w[0]).collect();
    if d.is_empty() {
        return 1.0;
    }
    d.sort_by(f64::total_cmp);
    d[d.len() / 2]
}

/// Collects samples into a [`Session`].
struct Builder {
    cols: Vec<Vec<f64>>,
    rates: Vec<Vec<f64>>,
    reference: Vec<[f64; 3]>,
    field: Vec<[f64; 3]>,
    lines: Vec<u64>,
}

impl Builder {
    fn new(h: &Header) -> Builder {
        Builder {
            cols: vec![Vec::new(); h.names.len()],
            rates: vec![Vec::new(); h.layout.n_fog],
            reference: Vec::new(),
            field: Vec::new(),
            lines: Vec::new(),
        }
    }

    fn push(&mut self, s: &SampleRef, line: u64) {
        self.lines.push(line);
        for (c, v) in self.cols.iter_mut().zip(s.values) {
            c.push(*v);
        }
        for (r, v) in self.rates.iter_mut().zip(s.rate_rad_s) {
            r.push(*v);
        }
        self.reference.push(s.ref_rad_s);
        self.field.push(s.field_nt);
    }

    fn finish(self, h: &Header) -> Session {
        let l = &h.layout;
        let cols = self.cols;
        let fogs = self
            .rates
            .into_iter()
            .enumerate()
            .map(|(i, rate_rad_s)| FogData { rate_rad_s, t_degc: l.fog_temp[i].map(|c| cols[c].clone()) })
            .collect();
        Session {
            file: h.file.clone(),
            names: h.names.clone(),
            cols,
            roles: h.roles.clone(),
            fogs,
            ref_rad_s: self.reference,
            field_nt: l.field.map(|_| self.field),
            lines: self.lines,
        }
    }
}

/// Reads and checks a whole session file into memory. `progress`, when given, advances with
/// the bytes read.
pub fn read_session(path: &Path, progress: Option<&ProgressBar>) -> Result<Session, SessionError> {
    let mut rr = RowReader::open(path)?;
    if let (Some(pb), Ok(m)) = (progress, std::fs::metadata(path)) {
        pb.set_length(m.len());
    }
    let h = rr.header().clone();
    let mut conv = Converter::new(&h.layout);
    let mut rec = Vec::new();
    let mut b = Builder::new(&h);
    let mut rows = 0u64;
    while let Some(row) = rr.next_row()? {
        if conv.convert(row, &mut rec) {
            b.push(&SampleRef::of_record(&rec, h.layout.n_fog), rr.line());
        }
        rows += 1;
        if let Some(pb) = progress.filter(|_| rows.is_multiple_of(8192)) {
            pb.set_position(rr.bytes());
        }
    }
    if let Some(pb) = progress {
        pb.set_position(pb.length().unwrap_or(0));
    }
    Ok(b.finish(&h))
}

/// A session from columns in memory (`names` as in a session file's header, `cols[k]` the
/// values of column k), checked as a file would be: `file` names it in messages, and a
/// refusal's line is the row's (header = 1).
pub fn session_from_columns(file: &str, names: Vec<String>, cols: &[Vec<f64>]) -> Result<Session, SessionError> {
    let h = Header::parse(file, names, 1)?;
    let n = cols.first().map_or(0, Vec::len);
    let min_rows = if h.layout.increments() { 3 } else { 2 };
    if n < min_rows {
        return Err(h.err(SessionErrorKind::NoRows, 1, None, format!("fewer than {min_rows} data rows")));
    }
    let mut conv = Converter::new(&h.layout);
    let mut rec = Vec::new();
    let mut b = Builder::new(&h);
    let mut row = vec![0.0; h.names.len()];
    let mut last_t = f64::NEG_INFINITY;
    for j in 0..n {
        for (v, c) in row.iter_mut().zip(cols) {
            *v = c[j];
        }
        let line = j as u64 + 2;
        if let Some(k) = row.iter().position(|v| !v.is_finite()) {
            return Err(h.err(
                SessionErrorKind::BadNumber,
                line,
                Some(k),
                format!("`{}` is not a finite number", row[k]),
            ));
        }
        if row[h.layout.t] <= last_t {
            return Err(h.err(SessionErrorKind::BadValue, line, Some(h.layout.t), "time does not increase"));
        }
        if let Some((kind, col, msg)) = h.check_values(&row, (j > 0).then_some(last_t)) {
            return Err(h.err(kind, line, Some(col), msg));
        }
        last_t = row[h.layout.t];
        if conv.convert(&row, &mut rec) {
            b.push(&SampleRef::of_record(&rec, h.layout.n_fog), line);
        }
    }
    Ok(b.finish(&h))
}

/// A session in memory as the text of a session file: its columns in file order, each
/// value in Rust's shortest form that reads back to the same `f64`.
pub fn session_csv(session: &Session) -> String {
    use std::fmt::Write;
    let mut out = String::new();
    let _ = writeln!(out, "{}", session.names.join(","));
    for j in 0..session.cols.first().map_or(0, Vec::len) {
        for (k, c) in session.cols.iter().enumerate() {
            let _ = write!(out, "{}{}", if k > 0 { "," } else { "" }, c[j]);
        }
        out.push('\n');
    }
    out
}

/// Writes a session in memory as a session file ([`session_csv`]; temporary file and
/// rename).
pub fn write_session_csv(session: &Session, path: &Path) -> std::io::Result<()> {
    let tmp = path.with_extension("partial");
    let named = |e: std::io::Error| std::io::Error::new(e.kind(), format!("{}: cannot write: {e}", path.display()));
    std::fs::write(&tmp, session_csv(session).as_bytes()).map_err(named)?;
    std::fs::rename(&tmp, path).map_err(named)
}

/// What a quick look at a session file tells before a pass: its header, how many samples
/// it has, their time span and the sample interval.
#[derive(Debug, Clone)]
pub struct Shape {
    /// The header.
    pub header: Header,
    /// Samples (rows, less the first of an increment session).
    pub samples: usize,
    /// Time of the first and the last sample, s.
    pub t_span_s: [f64; 2],
    /// The sample interval ([`median_interval_s`]), s.
    pub dt_s: f64,
    /// File size, bytes.
    pub bytes: u64,
}

/// Reads the header and the first rows of a session file (checked) and counts the rest of
/// its lines (not checked: the pass that follows checks them). The last sample's time is
/// read from the last data line.
pub fn shape(path: &Path) -> Result<Shape, SessionError> {
    let mut rr = RowReader::open(path)?;
    let header = rr.header().clone();
    let mut conv = Converter::new(&header.layout);
    let mut rec = Vec::new();
    let mut t = Vec::new();
    while t.len() <= INTERVALS_FOR_MEDIAN {
        match rr.next_row()? {
            Some(row) => {
                if conv.convert(row, &mut rec) {
                    t.push(rec[0]);
                }
            }
            None => break,
        }
    }
    let mut samples = t.len();
    let mut last_line: Vec<u8> = Vec::new();
    if samples > INTERVALS_FOR_MEDIAN {
        let io = |e: std::io::Error| header.err(SessionErrorKind::Io, 0, None, format!("cannot read: {e}"));
        let (n, last) = rr.count_rest().map_err(io)?;
        samples += n;
        last_line = last;
    }
    let t_last = if last_line.is_empty() {
        t[t.len() - 1]
    } else {
        let f = last_line.split(|&c| c == b',').nth(header.layout.t).map(trim).unwrap_or(&[]);
        parse_number(f).map_or(f64::NAN, |v| v.0)
    };
    Ok(Shape {
        samples,
        t_span_s: [t[0], t_last],
        dt_s: median_interval_s(&t),
        bytes: std::fs::metadata(path).map_or(0, |m| m.len()),
        header,
    })
}
