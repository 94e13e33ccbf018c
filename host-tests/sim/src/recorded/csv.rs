//! The CSV form of a recorded log read row by row ([`LogStream`]): the steps come out in
//! order while the file is read, in memory bounded by the look-ahead the interval check
//! needs (the first [`INTERVAL_ROWS`] rows with a time), whatever the log's length.
//! [`read_csv`] collects the same steps into a [`Recorded`].

use std::collections::{BTreeMap, VecDeque};
use std::fs::File;
use std::io::{BufRead, BufReader};
use std::path::Path;

use anyhow::{bail, Context, Result};
use ssis::calib::accel::N_ACCEL;
use ssis::calib::N_FOG;
use ssis::combination::FogSet;
use ssis::flight::Profile;
use ssis::nav::NavState;

use super::{check_counters, parse_row, Columns, LogStep, LogUnit, Problems, RawRow, Recorded, StarSample, Unwrap};

/// Rows with a time read ahead before the first step comes out: the sample interval is
/// checked on the median of their intervals.
pub const INTERVAL_ROWS: usize = 1001;

/// A CSV log (`docs/RECORDED-LOG.md`) read row by row into the unit's steps: sample k of
/// the log is step k + 1 after re-basing; repeated and backward samples dropped, gaps
/// given as empty steps, each counted in [`LogStream::problems`].
pub struct LogStream {
    origin: String,
    reader: Box<dyn BufRead + Send>,
    rows: RowReader,
    line: usize,
    buf: Vec<u8>,
    /// Rows with a time not yet placed (the interval check's look-ahead).
    ahead: VecDeque<(f64, RawRow)>,
    interval_checked: bool,
    unwrap: Unwrap,
    place: Placer,
    /// Empty steps still to give before `ready` (a gap).
    gap: u64,
    ready: Option<LogStep>,
    done: bool,
    /// What was wrong with the log so far.
    pub problems: Problems,
    /// Whether the log carries truth.
    pub has_truth: bool,
    /// The unit it is for.
    pub unit: LogUnit,
    /// Steps given so far.
    pub steps: u64,
    /// FOG samples given so far.
    pub fog_samples: u64,
    /// Star-tracker solutions given so far.
    pub st_count: u64,
    /// Star-tracker solutions by latency (end of the step it arrives in less its tag), µs.
    st_late_us: BTreeMap<u64, u64>,
}

/// Where the rows so far put the unit's clock.
#[derive(Default)]
struct Placer {
    t0_s: Option<f64>,
    init: Option<NavState>,
    fogs: u8,
    accels: u8,
    last_n: u64,
    last_counter: [Option<(u64, u16)>; N_FOG],
    last_acc_counter: [Option<(u64, u16)>; N_ACCEL],
    last_st_us: Option<u64>,
    last_gnss_us: Option<u64>,
}

/// Whether a line holds nothing but white space (Unicode's, as `str::trim` has it).
fn blank(l: &[u8]) -> bool {
    // A line opening with a visible ASCII character (every data row) is not blank.
    if l.first().is_some_and(u8::is_ascii_graphic) {
        return false;
    }
    if l.is_ascii() && !l.contains(&0x0b) {
        l.trim_ascii().is_empty()
    } else {
        String::from_utf8_lossy(l).trim().is_empty()
    }
}

impl LogStream {
    /// Opens the CSV log at `path` and reads its header (refused as `read_csv` refuses it).
    pub fn open(path: &Path) -> Result<LogStream> {
        let file = File::open(path).with_context(|| format!("cannot read {}", path.display()))?;
        Self::from_reader(Box::new(BufReader::with_capacity(1 << 16, file)), path.display().to_string())
    }

    /// Reads a log from `reader`, named `origin` in messages.
    pub fn from_reader(reader: Box<dyn BufRead + Send>, origin: String) -> Result<LogStream> {
        let mut s = LogStream {
            origin,
            reader,
            rows: RowReader { cols: Columns::default(), n_fields: 0, fields: Vec::with_capacity(64) },
            line: 0,
            buf: Vec::with_capacity(256),
            ahead: VecDeque::new(),
            interval_checked: false,
            unwrap: Unwrap::default(),
            place: Placer::default(),
            gap: 0,
            ready: None,
            done: false,
            problems: Problems::default(),
            has_truth: false,
            unit: LogUnit::Spacecraft,
            steps: 0,
            fog_samples: 0,
            st_count: 0,
            st_late_us: BTreeMap::new(),
        };
        loop {
            if s.read_line()?.is_none() {
                bail!("{}: empty log: no header line", s.origin);
            }
            let text = String::from_utf8_lossy(&s.buf);
            let l = text.trim_end_matches(['\n', '\r']);
            if l.trim().is_empty() || l.starts_with('#') {
                continue;
            }
            let cols = Columns::parse(l, &s.origin, s.line)?;
            s.rows.n_fields = l.split(',').count();
            s.has_truth = cols.true_q[0].is_some();
            s.unit = cols.unit.unwrap_or(LogUnit::Spacecraft);
            s.rows.cols = cols;
            return Ok(s);
        }
    }

    /// What was read (for messages).
    pub fn origin(&self) -> &str {
        &self.origin
    }

    /// The log's time of unit time 0 (one interval before the first sample), s, once the
    /// first step is out.
    pub fn t0_s(&self) -> Option<f64> {
        self.place.t0_s
    }

    /// The FOG slots the log has had so far.
    pub fn fogs(&self) -> FogSet {
        FogSet(self.place.fogs)
    }

    /// Launch vehicle: the initial state, from the first row that has it.
    pub fn init(&self) -> Option<NavState> {
        self.place.init
    }

    /// The star tracker's latency as logged so far, s ([`Recorded::st_latency_s`]).
    pub fn st_latency_s(&self) -> f64 {
        let mut k = self.st_count / 2;
        for (&us, &n) in &self.st_late_us {
            if k < n {
                return us as f64 * 1e-6;
            }
            k -= n;
        }
        0.0
    }

    /// The next line into `buf`; `None` at the end, else whether it had its line end.
    fn read_line(&mut self) -> Result<Option<bool>> {
        self.buf.clear();
        let n = self.reader.read_until(b'\n', &mut self.buf).with_context(|| format!("cannot read {}", self.origin))?;
        if n == 0 {
            return Ok(None);
        }
        if self.line == 0 && self.buf.starts_with(b"\xEF\xBB\xBF") {
            self.buf.drain(..3);
        }
        self.line += 1;
        Ok(Some(self.buf.ends_with(b"\n")))
    }

    /// The next data row, parsed (a line with the wrong number of fields is counted and
    /// skipped); `None` at the end of the file. A line that lies whole in the reader's
    /// buffer is parsed there, without a copy; one that crosses the buffer's end (and the
    /// first, which may open with a byte-order mark) is read into `buf` first.
    fn next_row(&mut self) -> Result<Option<RawRow>> {
        loop {
            if self.line > 0 {
                let avail = self.reader.fill_buf().with_context(|| format!("cannot read {}", self.origin))?;
                if let Some(nl) = memchr::memchr(b'\n', avail) {
                    self.line += 1;
                    let line = avail.get(..=nl).unwrap_or_default();
                    let row = self.rows.row(line, true, self.line, &self.origin, &mut self.problems);
                    self.reader.consume(nl + 1);
                    match row {
                        Some(r) => return Ok(Some(r)),
                        None => continue,
                    }
                }
            }
            let Some(ended) = self.read_line()? else { return Ok(None) };
            let row = self.rows.row(&self.buf, ended, self.line, &self.origin, &mut self.problems);
            if let Some(r) = row {
                return Ok(Some(r));
            }
        }
    }

    /// The next row with a time (`t_s`, or the first FOG counter unwrapped); rows without
    /// one are skipped.
    fn read_timed(&mut self) -> Result<Option<(f64, RawRow)>> {
        let dt_s = self.unit.profile().dt_s();
        while let Some(r) = self.next_row()? {
            let t = match r.t_s {
                Some(t) => Some(t),
                None => r.counter.iter().flatten().next().map(|&c| self.unwrap.next(c) as f64 * dt_s),
            };
            if let Some(t) = t {
                return Ok(Some((t, r)));
            }
        }
        Ok(None)
    }

    /// The next row with a time, the first [`INTERVAL_ROWS`] read ahead to check the
    /// sample interval before any is placed.
    fn next_timed(&mut self) -> Result<Option<(f64, RawRow)>> {
        if !self.interval_checked {
            while self.ahead.len() < INTERVAL_ROWS {
                match self.read_timed()? {
                    Some(r) => self.ahead.push_back(r),
                    None => break,
                }
            }
            self.interval_checked = true;
            if self.ahead.is_empty() {
                bail!(
                    "{}: nothing usable: no row with a time and a FOG sample\n{}",
                    self.origin,
                    self.problems.report()
                );
            }
            check_interval(self.ahead.make_contiguous(), self.unit, &self.origin)?;
        }
        match self.ahead.pop_front() {
            Some(r) => Ok(Some(r)),
            None => self.read_timed(),
        }
    }

    /// The next step of the unit (steps inside a gap are empty), or `None` after the
    /// last; an error when nothing usable remained.
    pub fn next_step(&mut self) -> Result<Option<LogStep>> {
        loop {
            if self.gap > 0 {
                self.gap -= 1;
                return Ok(Some(self.give(LogStep::default())));
            }
            if let Some(s) = self.ready.take() {
                return Ok(Some(self.give(s)));
            }
            if self.done {
                return Ok(None);
            }
            match self.next_timed()? {
                Some((t, r)) => {
                    let dt_s = self.unit.profile().dt_s();
                    let t0_s = *self.place.t0_s.get_or_insert(t - dt_s);
                    if self.place.init.is_none() {
                        self.place.init = r.init.as_deref().copied();
                    }
                    if let Some((gap, step)) = self.place.place(t, t0_s, dt_s, r, &self.origin, &mut self.problems) {
                        self.gap = gap;
                        self.ready = Some(step);
                    }
                }
                None => {
                    self.done = true;
                    if self.place.fogs == 0 {
                        bail!("{}: nothing usable: no FOG sample\n{}", self.origin, self.problems.report());
                    }
                    if self.unit == LogUnit::LaunchVehicle && self.place.accels == 0 {
                        bail!("{}: nothing usable: no accelerometer sample\n{}", self.origin, self.problems.report());
                    }
                }
            }
        }
    }

    /// Counts step `s` as given.
    fn give(&mut self, s: LogStep) -> LogStep {
        self.steps += 1;
        self.fog_samples += s.fog.iter().flatten().count() as u64;
        let end_us = self.steps * u64::from(self.unit.profile().dt_us);
        for st in &s.st {
            self.st_count += 1;
            *self.st_late_us.entry(end_us.saturating_sub(st.time_us)).or_default() += 1;
        }
        s
    }

    /// Reads the rest of the log into a [`Recorded`].
    pub fn collect(mut self) -> Result<Recorded> {
        let mut steps = Vec::new();
        while let Some(s) = self.next_step()? {
            steps.push(s);
        }
        Ok(Recorded {
            origin: self.origin,
            steps,
            fogs: FogSet(self.place.fogs),
            t0_s: self.place.t0_s.unwrap_or(0.0),
            problems: self.problems,
            has_truth: self.has_truth,
            unit: self.unit,
            init: self.place.init,
        })
    }
}

/// A data row's reading: the header's columns and field count, and the fields' places
/// in the current line (reused: no allocation a row).
struct RowReader {
    cols: Columns,
    n_fields: usize,
    fields: Vec<std::ops::Range<usize>>,
}

impl RowReader {
    /// Line `ln` of `origin` (`line`, with its line end when `ended`) parsed as a data row;
    /// `None` for a comment, a blank line, or a line with the wrong number of fields or cut
    /// short (counted in `problems`).
    fn row(&mut self, line: &[u8], ended: bool, ln: usize, origin: &str, problems: &mut Problems) -> Option<RawRow> {
        let (fields, n_fields) = (&mut self.fields, self.n_fields);
        let mut l = line;
        while let [rest @ .., b'\n' | b'\r'] = l {
            l = rest;
        }
        if l.starts_with(b"#") || blank(l) {
            return None;
        }
        fields.clear();
        let mut start = 0;
        for_each_comma(l, |k| {
            fields.push(start..k);
            start = k + 1;
        });
        fields.push(start..l.len());
        if fields.len() != n_fields || !ended {
            let why = if ended {
                format!("{} fields, the header has {}", fields.len(), n_fields)
            } else {
                "last line without its line end (cut while written?)".to_string()
            };
            problems.truncated_lines.add(1, || format!("{origin}:{ln}: {why}"));
            return None;
        }
        Some(parse_row(l, fields, &self.cols, ln, origin, problems))
    }
}

/// Calls `f` with the place of every comma of `line`, in order: eight bytes a pass, the
/// commas of a word found at once (a field is a few bytes: a search per comma costs more).
fn for_each_comma(line: &[u8], mut f: impl FnMut(usize)) {
    const LOW7: u64 = 0x7f7f_7f7f_7f7f_7f7f;
    let (words, rest) = line.as_chunks::<8>();
    for (w, word) in words.iter().enumerate() {
        // Exact per byte (no carry between bytes): the high bit set where x's byte is 0.
        let x = u64::from_le_bytes(*word) ^ u64::from_le_bytes([b','; 8]);
        let mut zeros = !(((x & LOW7) + LOW7) | x | LOW7);
        while zeros != 0 {
            f(w * 8 + zeros.trailing_zeros() as usize / 8);
            zeros &= zeros - 1;
        }
    }
    let base = words.len() * 8;
    for (k, &b) in rest.iter().enumerate() {
        if b == b',' {
            f(base + k);
        }
    }
}

impl Placer {
    /// Places row `r` at log time `t`: `None` when it is dropped (repeated or backward),
    /// else the empty steps of a gap before it and its step.
    fn place(
        &mut self,
        t: f64,
        t0_s: f64,
        dt_s: f64,
        r: RawRow,
        origin: &str,
        p: &mut Problems,
    ) -> Option<(u64, LogStep)> {
        let n = ((t - t0_s) / dt_s).round();
        let at = || format!("{origin}:{}", r.line);
        let last_n = self.last_n;
        if n <= last_n as f64 {
            let d = if n == last_n as f64 { &mut p.repeated_samples } else { &mut p.backward_samples };
            d.add(1, || format!("{}: t = {t} s, the sample before is at {} s", at(), t0_s + last_n as f64 * dt_s));
            return None;
        }
        let n = n as u64;
        let mut gap = 0;
        if n > last_n + 1 {
            let lost = n - last_n - 1;
            gap = lost;
            p.gaps.add(lost, || format!("{}: {lost} samples missing before t = {t} s", at()));
        }
        check_counters(&r.counter, &mut self.last_counter, n, "fog", &mut p.counter_jumps, &at);
        check_counters(&r.acc_counter, &mut self.last_acc_counter, n, "acc", &mut p.counter_jumps, &at);
        let mut step = LogStep { fog: r.fog, accel: r.accel, truth: r.truth, ..LogStep::default() };
        for (i, f) in r.fog.iter().enumerate() {
            if f.is_some() {
                self.fogs |= 1 << i;
            }
        }
        for (i, a) in r.accel.iter().enumerate() {
            if a.is_some() {
                self.accels |= 1 << i;
            }
        }
        if let Some((t_st, valid, q)) = r.st {
            let norm = q.iter().map(|v| v * v).sum::<f64>().sqrt();
            let us = ((t_st - t0_s) * 1e6).round();
            if (norm - 1.0).abs() > 1e-3 {
                p.st_not_unit.add(1, || format!("{}: |st_q| = {norm}", at()));
            } else if us < 0.0 || self.last_st_us.is_some_and(|l| us as u64 <= l) {
                p.st_time_backward.add(1, || format!("{}: st_t_s = {t_st} s not after the previous tag", at()));
            } else {
                self.last_st_us = Some(us as u64);
                step.st.push(StarSample { time_us: us as u64, valid, q: q.map(|v| v / norm) });
            }
        }
        if let Some(&(t_g, mut g)) = r.gnss.as_deref() {
            let us = ((t_g - t0_s) * 1e6).round();
            if us < 0.0 || self.last_gnss_us.is_some_and(|l| us as u64 <= l) {
                p.gnss_time_backward
                    .add(1, || format!("{}: gnss_t_s = {t_g} s not after the previous fix's tag", at()));
            } else {
                self.last_gnss_us = Some(us as u64);
                g.time_us = us as u64;
                step.gnss.push(g);
            }
        }
        self.last_n = n;
        Some((gap, step))
    }
}

/// Reads a CSV log (`docs/RECORDED-LOG.md`) whole.
pub fn read_csv(path: &Path) -> Result<Recorded> {
    LogStream::open(path)?.collect()
}

/// The log's sample interval must be its unit's: the median of the first intervals
/// within 1 %.
fn check_interval(timed: &[(f64, RawRow)], unit: LogUnit, origin: &str) -> Result<()> {
    let mut d: Vec<f64> = timed.windows(2).take(1000).map(|w| w[1].0 - w[0].0).filter(|d| *d > 0.0).collect();
    if d.is_empty() {
        return Ok(());
    }
    d.sort_by(f64::total_cmp);
    let med = d[d.len() / 2];
    let dt_s = unit.profile().dt_s();
    let near = |dt: f64| (med - dt).abs() <= 0.01 * dt;
    if near(dt_s) {
        return Ok(());
    }
    let why = match unit {
        LogUnit::Spacecraft if near(Profile::LAUNCH_VEHICLE.dt_s()) => {
            "that is the launch-vehicle unit's interval, but the log has no accelerometer columns (`acc0_dv_m_s` … \
             `acc2_dv_m_s`): a launch-vehicle log needs them (docs/RECORDED-LOG.md); a spacecraft log must be \
             resampled to"
        }
        LogUnit::LaunchVehicle if near(Profile::SPACECRAFT.dt_s()) => {
            "that is the spacecraft unit's interval, but the log has accelerometer (launch-vehicle) columns; \
             the launch-vehicle unit integrates one sample of each sensor every"
        }
        _ => "resample the log to the unit's interval,",
    };
    bail!(
        "{origin}: the samples are {:.4} ms apart (median of the first intervals): {why} {:.4} ms ({} unit)",
        med * 1e3,
        dt_s * 1e3,
        unit.name()
    );
}

#[cfg(test)]
mod tests {
    use super::for_each_comma;

    #[test]
    fn commas_found_a_word_at_a_time_are_those_a_byte_at_a_time() {
        // Every length 0..40 (words and a rest), commas at every place, and bytes that
        // differ from a comma by one bit or carry (0x2b, 0x2d, 0xac, 0x00, 0xff).
        let alphabet = [b',', b'1', b'+', b'-', 0xac, 0x00, 0xff, b'.'];
        let mut seed = 0x2545_f491_4f6c_dd1du64;
        for len in 0..40 {
            for _ in 0..200 {
                let line: Vec<u8> = (0..len)
                    .map(|_| {
                        seed ^= seed << 13;
                        seed ^= seed >> 7;
                        seed ^= seed << 17;
                        alphabet[(seed % alphabet.len() as u64) as usize]
                    })
                    .collect();
                let mut found = Vec::new();
                for_each_comma(&line, |k| found.push(k));
                let expected: Vec<usize> = (0..line.len()).filter(|&k| line[k] == b',').collect();
                assert_eq!(found, expected, "{line:?}");
            }
        }
    }
}
