//! [`RowReader`]: a session file streamed line by line through a memory map or a fixed
//! buffer, each line parsed in place and checked.

use crate::*;

/// Parses the data line `data[a..b]` into `values` (one per column) the fast way: each field
/// a number [`parse_number`] takes whole and finite, fields separated by `,` with optional
/// spaces. Numbers are read from `data[p..]` (what follows the line lets the digit scan take
/// eight bytes at a time; the line's end stops it). `false` on anything else (then
/// [`check_line`] decides).
fn parse_line(data: &[u8], a: usize, b: usize, values: &mut [f64]) -> bool {
    let ncol = values.len();
    let mut p = a;
    for (k, v) in values.iter_mut().enumerate() {
        while p < b && (data[p] == b' ' || data[p] == b'\t') {
            p += 1;
        }
        let Some((x, used)) = parse_number(&data[p..]) else { return false };
        if used == 0 || !x.is_finite() || p + used > b {
            return false;
        }
        *v = x;
        p += used;
        while p < b && (data[p] == b' ' || data[p] == b'\t' || data[p] == b'\r') {
            p += 1;
        }
        if k + 1 < ncol {
            if p >= b || data[p] != b',' {
                return false;
            }
            p += 1;
        }
    }
    p == b
}

/// [`parse_line`] on the line starting at `data[a]`, found as it is read: the same fields,
/// separators and spaces, and then the line's `\n`. The bytes it took (the `\n` included);
/// `None` when the line is anything else (a comment, a blank line, a line [`parse_line`]
/// refuses) or has no `\n` in `data` (then the careful path finds the line first). A line
/// it takes is one [`parse_line`] takes, with the same values: no number or space runs
/// over a `\n`.
///
/// A field whose bytes repeat the column's [`Repeat`] takes its value from there; with
/// `retry`, a field read in full is stored there.
#[inline]
fn parse_next_line(data: &[u8], a: usize, values: &mut [f64], repeats: &mut [Repeat], retry: bool) -> Option<usize> {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("ssse3") {
        // SAFETY: the CPU has SSSE3 (checked above).
        return unsafe { parse_next_line_ssse3(data, a, values, repeats, retry) };
    }
    next_line_with(data, a, values, repeats, retry, parse_number_general)
}

/// [`parse_next_line`] where the CPU has SSSE3.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "ssse3")]
fn parse_next_line_ssse3(
    data: &[u8],
    a: usize,
    values: &mut [f64],
    repeats: &mut [Repeat],
    retry: bool,
) -> Option<usize> {
    next_line_with(data, a, values, repeats, retry, |b| parse_number_ssse3(b))
}

/// [`parse_next_line`] with `parse` for [`parse_number`].
#[inline(always)]
fn next_line_with(
    data: &[u8],
    a: usize,
    values: &mut [f64],
    repeats: &mut [Repeat],
    retry: bool,
    parse: impl Fn(&[u8]) -> Option<(f64, usize)>,
) -> Option<usize> {
    let ncol = values.len();
    let mut p = a;
    // A comment or a line that starts blank goes the careful way.
    if matches!(data.get(p), None | Some(b'#' | b' ' | b'\t' | b'\r' | b'\n')) {
        return None;
    }
    for (k, (v, rep)) in values.iter_mut().zip(repeats.iter_mut()).enumerate() {
        while let Some(b' ' | b'\t') = data.get(p) {
            p += 1;
        }
        let rest = data.get(p..)?;
        let window: Option<&[u8; REPEAT_WINDOW]> = rest.get(..REPEAT_WINDOW).and_then(|w| w.try_into().ok());
        let (x, used) = match window {
            Some(w) if rep.armed && *w == rep.bytes => (rep.value, rep.used),
            _ => {
                rep.armed = false;
                let (x, used) = parse(rest)?;
                if used == 0 || !x.is_finite() {
                    return None;
                }
                if let (true, Some(w)) = (retry, window) {
                    if used < REPEAT_WINDOW && matches!(w[used], b',' | b'\n' | b'\r' | b' ' | b'\t') {
                        *rep = Repeat { bytes: *w, used, value: x, armed: true };
                    }
                }
                (x, used)
            }
        };
        *v = x;
        p += used;
        while let Some(b' ' | b'\t' | b'\r') = data.get(p) {
            p += 1;
        }
        if k + 1 < ncol {
            if data.get(p) != Some(&b',') {
                return None;
            }
            p += 1;
        }
    }
    (data.get(p) == Some(&b'\n')).then_some(p + 1 - a)
}

/// Bytes of a field a [`Repeat`] compares.
const REPEAT_WINDOW: usize = 16;

/// Rows between two tries of the columns whose value changed ([`Repeat`]).
const REPEAT_RETRY: u64 = 64;

/// Per column, the bytes of a value read in full and that value, to take a field that
/// repeats them without parsing it again (a constant column: the reference rate on a dwell,
/// a turntable's azimuth and latitude). A field is taken from it only when its first
/// [`REPEAT_WINDOW`] bytes equal the stored ones, and these held the whole number and the
/// byte after it, a separator (`,` `\n` `\r` space tab: none can be inside a number): the
/// number is then the same bytes, so it has the same value and length. Compared while the
/// column repeats; after a change, stored again every [`REPEAT_RETRY`] rows.
#[derive(Debug, Clone, Default)]
struct Repeat {
    bytes: [u8; REPEAT_WINDOW],
    used: usize,
    value: f64,
    armed: bool,
}

/// The careful reading of a data line: fields split at `,` and trimmed, the field count
/// checked first, then each value. Fills `values` and returns `None` when the line is good,
/// else what is wrong: kind, 0-based column, message.
fn check_line(line: &[u8], values: &mut [f64]) -> Option<(SessionErrorKind, usize, String)> {
    let ncol = values.len();
    let mut k = 0;
    let mut bad: Option<(usize, String)> = None;
    for field in line.split(|&c| c == b',') {
        if k < ncol && bad.is_none() {
            let f = trim(field);
            match parse_number(f) {
                Some((v, used)) if used == f.len() && v.is_finite() => values[k] = v,
                Some((_, used)) if used == f.len() => {
                    bad = Some((k, format!("`{}` is not a finite number", String::from_utf8_lossy(f))))
                }
                _ if f.is_empty() => bad = Some((k, "empty value, expected a number".into())),
                _ => bad = Some((k, format!("`{}` is not a number", String::from_utf8_lossy(f)))),
            }
        }
        k += 1;
    }
    if k != ncol {
        return Some(if k < ncol {
            (
                SessionErrorKind::FieldCount,
                k,
                format!("value missing: the line has {k} fields, the header {ncol} (truncated line?)"),
            )
        } else {
            (SessionErrorKind::FieldCount, ncol - 1, format!("the line has {k} fields, the header only {ncol}"))
        });
    }
    bad.map(|(col, msg)| (SessionErrorKind::BadNumber, col, msg))
}

/// Bytes read from the file at a time.
const READ_CHUNK: usize = 1 << 20;

/// Streams the data rows of a session file: each row's values in file column order, checked
/// (field count, numbers, finite, time increasing). At the end of the file it refuses a
/// session with too few rows.
pub struct RowReader {
    header: Header,
    file: std::fs::File,
    buf: Buf,
    start: usize,
    end: usize,
    eof: bool,
    line: u64,
    values: Vec<f64>,
    repeats: Vec<Repeat>,
    last_t: f64,
    rows: u64,
    bytes: u64,
    /// The last line [`RowReader::next_line`] returned ended the file without a `\n`.
    unterminated: bool,
}

/// The bytes a [`RowReader`] reads from: the whole file mapped ([`map_file`]), or read
/// into a buffer a chunk at a time (what cannot be mapped: a pipe, an empty file).
enum Buf {
    Read(Vec<u8>),
    Mapped(memmap2::Mmap),
}

impl std::ops::Deref for Buf {
    type Target = [u8];
    fn deref(&self) -> &[u8] {
        match self {
            Buf::Read(v) => v,
            Buf::Mapped(m) => m,
        }
    }
}

/// A regular, non-empty file mapped into memory, read ahead as the pages are reached (no
/// copy out of the page cache); `None` when it cannot be (then it is read). A file that
/// another program truncates while it is mapped ends the process on a `SIGBUS` at the first
/// page past its new end: a program that reads sessions calls
/// [`exit_plainly_on_truncated_map`] at its start, so that this ends in a plain message and
/// status 74. A file appended to while it is read is safe (the map ends at the length it
/// had; the pass's count of rows then differs and says so).
fn map_file(file: &std::fs::File) -> Option<memmap2::Mmap> {
    let meta = file.metadata().ok()?;
    if !meta.is_file() || meta.len() == 0 {
        return None;
    }
    // SAFETY: the map is only read; a file truncated under it raises SIGBUS (see above).
    let m = unsafe { memmap2::MmapOptions::new().map(file) }.ok()?;
    let _ = m.advise(memmap2::Advice::Sequential);
    Some(m)
}

/// Installs the process's `SIGBUS` handler for session files mapped by [`RowReader`]: a
/// file truncated by another program while it is read then stops the process with a plain
/// message on stderr and status 74 instead of a crash. For a program's `main` (a signal
/// handler is the whole process's): the lab's outputs are all written to a temporary file
/// and renamed, so none is left half written. Calling it again does nothing.
pub fn exit_plainly_on_truncated_map() {
    static SIGBUS: std::sync::Once = std::sync::Once::new();
    SIGBUS.call_once(|| {
        // SAFETY: a handler that calls only async-signal-safe functions (write, _exit),
        // installed once with a zeroed, then emptied, signal mask.
        unsafe {
            let mut sa: libc::sigaction = std::mem::zeroed();
            sa.sa_sigaction = on_sigbus as extern "C" fn(libc::c_int) as usize;
            libc::sigemptyset(&mut sa.sa_mask);
            libc::sigaction(libc::SIGBUS, &sa, std::ptr::null_mut());
        }
    });
}

/// `SIGBUS` while a mapped session file is read: it was truncated by another program.
extern "C" fn on_sigbus(_: libc::c_int) {
    const MSG: &[u8] = b"error: a session file was truncated by another program while it was being read \
(SIGBUS on its memory map); no output was written in part. Read it again once it is complete.\n";
    // SAFETY: write(2) and _exit(2) are async-signal-safe.
    unsafe {
        libc::write(2, MSG.as_ptr().cast(), MSG.len());
        libc::_exit(74);
    }
}

/// A line of a file: whether it is blank or a comment (skipped everywhere).
fn skipped_line(line: &[u8]) -> bool {
    line.first() == Some(&b'#') || line.iter().all(|c| c.is_ascii_whitespace())
}

pub(crate) fn trim(mut b: &[u8]) -> &[u8] {
    while let [first, rest @ ..] = b {
        if *first == b' ' || *first == b'\t' {
            b = rest;
        } else {
            break;
        }
    }
    while let [rest @ .., last] = b {
        if *last == b' ' || *last == b'\t' || *last == b'\r' {
            b = rest;
        } else {
            break;
        }
    }
    b
}

impl RowReader {
    /// Opens a session file and reads its header (comment lines before it are skipped).
    pub fn open(path: &Path) -> Result<RowReader, SessionError> {
        Self::open_with(path, Header::parse)
    }

    /// Opens any numeric CSV whose header `make` accepts (file, names, line).
    pub fn open_with(
        path: &Path,
        make: impl FnOnce(&str, Vec<String>, u64) -> Result<Header, SessionError>,
    ) -> Result<RowReader, SessionError> {
        let file_name = path.display().to_string();
        let io = |e: &dyn std::fmt::Display| SessionError {
            kind: SessionErrorKind::Io,
            file: file_name.clone(),
            line: 0,
            column: None,
            message: format!("cannot read: {e}"),
        };
        let file = std::fs::File::open(path).map_err(|e| io(&e))?;
        let mapped = map_file(&file);
        let (buf, end, eof) = match mapped {
            Some(m) => {
                let n = m.len();
                (Buf::Mapped(m), n, true)
            }
            None => (Buf::Read(vec![0; READ_CHUNK]), 0, false),
        };
        let mut r = RowReader {
            header: Header::empty(&file_name),
            file,
            buf,
            start: 0,
            end,
            eof,
            line: 0,
            values: Vec::new(),
            repeats: Vec::new(),
            last_t: f64::NEG_INFINITY,
            rows: 0,
            bytes: 0,
            unterminated: false,
        };
        let names = loop {
            let Some((a, b)) = r.next_line().map_err(|e| io(&e))? else {
                return Err(SessionError {
                    kind: SessionErrorKind::Empty,
                    file: file_name,
                    line: 1,
                    column: None,
                    message: "the file is empty: expected a header line naming the columns".into(),
                });
            };
            let mut line = &r.buf[a..b];
            if r.line == 1 {
                if line.starts_with(&[0xFF, 0xFE]) || line.starts_with(&[0xFE, 0xFF]) {
                    return Err(SessionError {
                        kind: SessionErrorKind::Encoding,
                        file: file_name,
                        line: 1,
                        column: None,
                        message: "the file is UTF-16 text (byte-order mark FF FE or FE FF): save it as UTF-8".into(),
                    });
                }
                // A UTF-8 byte-order mark (spreadsheets write one) is not part of the first name.
                line = line.strip_prefix(&[0xEF, 0xBB, 0xBF]).unwrap_or(line);
            }
            if !skipped_line(line) {
                break line.split(|&c| c == b',').map(|f| String::from_utf8_lossy(trim(f)).to_string()).collect();
            }
        };
        r.header = make(&file_name, names, r.line)?;
        r.values = vec![0.0; r.header.names.len()];
        r.repeats = vec![Repeat::default(); r.header.names.len()];
        Ok(r)
    }

    /// The header.
    pub fn header(&self) -> &Header {
        &self.header
    }

    /// Line number of the last line returned, 1-based.
    pub fn line(&self) -> u64 {
        self.line
    }

    /// Bytes of the file consumed so far.
    pub fn bytes(&self) -> u64 {
        self.bytes
    }

    /// The next line without its `\n`, as a range of the buffer (which grows for a line
    /// longer than it).
    fn next_line(&mut self) -> std::io::Result<Option<(usize, usize)>> {
        loop {
            if let Some(k) = memchr::memchr(b'\n', &self.buf[self.start..self.end]) {
                let (a, b) = (self.start, self.start + k);
                self.start = b + 1;
                self.line += 1;
                self.bytes += (k + 1) as u64;
                return Ok(Some((a, b)));
            }
            if self.eof {
                if self.start < self.end {
                    self.unterminated = true;
                    let (a, b) = (self.start, self.end);
                    self.start = self.end;
                    self.line += 1;
                    self.bytes += (b - a) as u64;
                    return Ok(Some((a, b)));
                }
                return Ok(None);
            }
            self.refill()?;
        }
    }

    /// Moves the unread bytes to the front of the buffer (growing it when they fill it) and
    /// reads more behind them; at the end of the file sets `eof`.
    fn refill(&mut self) -> std::io::Result<()> {
        let Buf::Read(buf) = &mut self.buf else {
            self.eof = true;
            return Ok(());
        };
        buf.copy_within(self.start..self.end, 0);
        self.end -= self.start;
        self.start = 0;
        if self.end == buf.len() {
            buf.resize(buf.len() * 2, 0);
        }
        let k = self.file.read(&mut buf[self.end..])?;
        if k == 0 {
            self.eof = true;
        }
        self.end += k;
        Ok(())
    }

    /// Counts the data lines left (not read as rows: unchecked) and returns the last of them.
    pub(crate) fn count_rest(&mut self) -> std::io::Result<(usize, Vec<u8>)> {
        let (mut count, mut last) = (0usize, Vec::new());
        loop {
            let data = &self.buf[self.start..self.end];
            // Whole lines only (all of what is left at the end of the file).
            let upto = match memchr::memrchr(b'\n', data) {
                Some(k) => k + 1,
                None if self.eof => data.len(),
                None => 0,
            };
            let region = &data[..upto];
            if !region.is_empty() {
                let mut line_start = 0;
                let mut last_data: Option<(usize, usize)> = None;
                let mut take = |a: usize, b: usize| {
                    let line = &region[a..b];
                    // A line is skipped only if it starts with '#' or white space (checked whole).
                    let first = line.first().copied().unwrap_or(b'\n');
                    if !(first == b'#' || first.is_ascii_whitespace()) || !skipped_line(line) {
                        count += 1;
                        last_data = Some((a, b));
                    }
                };
                let mut lines = 0u64;
                for p in memchr::memchr_iter(b'\n', region) {
                    take(line_start, p);
                    line_start = p + 1;
                    lines += 1;
                }
                if line_start < region.len() {
                    take(line_start, region.len());
                }
                if let Some((a, b)) = last_data {
                    last.clear();
                    last.extend_from_slice(&region[a..b]);
                }
                self.line += lines;
                self.bytes += region.len() as u64;
                self.start += upto;
            }
            if self.eof && self.start >= self.end {
                return Ok((count, last));
            }
            self.refill()?;
        }
    }

    /// The next data row (values in file column order), or `None` after the last.
    pub fn next_row(&mut self) -> Result<Option<&[f64]>, SessionError> {
        let t_col = self.header.layout.t;
        loop {
            // The common line first: read in one go up to its `\n`, with no search for the
            // line's end before.
            if let Some(len) = parse_next_line(
                &self.buf[..self.end],
                self.start,
                &mut self.values,
                &mut self.repeats,
                self.rows.is_multiple_of(REPEAT_RETRY),
            ) {
                self.start += len;
                self.line += 1;
                self.bytes += len as u64;
            } else {
                let (a, b) = match self.next_line() {
                    Ok(Some(l)) => l,
                    Ok(None) => break,
                    Err(e) => {
                        return Err(self.header.err(SessionErrorKind::Io, self.line, None, format!("cannot read: {e}")))
                    }
                };
                let line = &self.buf[a..b];
                if skipped_line(line) {
                    continue;
                }
                if !parse_line(&self.buf[..self.end], a, b, &mut self.values) {
                    // Something unusual: the careful path, which also words the refusal.
                    let line_no = self.line;
                    if let Some((kind, col, msg)) = check_line(&self.buf[a..b], &mut self.values) {
                        return Err(self.header.err(kind, line_no, Some(col), msg));
                    }
                }
                if self.unterminated {
                    let last = line.rsplit(|&c| c == b',').next().map(trim).unwrap_or(&[]);
                    let (line_no, col) = (self.line, self.values.len().saturating_sub(1));
                    return Err(self.header.err(
                        SessionErrorKind::Truncated,
                        line_no,
                        Some(col),
                        format!(
                            "the file ends inside this line, after `{}` with no line end: it may be truncated (cut \
                             while being written?), a number cut short reads as another; every line of a session \
                             ends with a newline",
                            String::from_utf8_lossy(last)
                        ),
                    ));
                }
            }
            let t = self.values[t_col];
            if t <= self.last_t {
                let line_no = self.line;
                return Err(self.header.err(
                    SessionErrorKind::BadValue,
                    line_no,
                    Some(t_col),
                    "time does not increase",
                ));
            }
            let prev = (self.rows > 0).then_some(self.last_t);
            if let Some((kind, col, msg)) = self.header.check_values(&self.values, prev) {
                let line_no = self.line;
                return Err(self.header.err(kind, line_no, Some(col), msg));
            }
            self.last_t = t;
            self.rows += 1;
            return Ok(Some(&self.values));
        }
        let min_rows = if self.header.layout.increments() { 3 } else { 2 };
        if self.rows < min_rows {
            return Err(self.header.err(
                SessionErrorKind::NoRows,
                self.header.line,
                None,
                format!("fewer than {min_rows} data rows"),
            ));
        }
        Ok(None)
    }
}

#[cfg(all(test, unix))]
mod read_paths {
    use super::RowReader;

    /// Every row, as the reader gives it.
    fn rows(path: &std::path::Path) -> Vec<Vec<u64>> {
        let mut rr = RowReader::open(path).expect("the session reads");
        let mut out = Vec::new();
        while let Some(r) = rr.next_row().expect("a good row") {
            out.push(r.iter().map(|v| v.to_bits()).collect());
        }
        out
    }

    /// A regular file is mapped, a pipe is read a chunk at a time: the same rows, bit for
    /// bit, through comments, blank lines, spaces, CRLF ends, a line longer than a read
    /// chunk (a comment); and both refuse a last line without `\n` as possibly truncated.
    #[test]
    fn mapped_and_read_give_the_same_rows() {
        let mut text = String::from("# a session\nt_s, fog0_rad_s ,fog0_t_degc,ref_x_rad_s,ref_y_rad_s,ref_z_rad_s\n");
        for k in 1..5000 {
            let t = k as f64 * 0.01;
            if k == 1234 {
                text.push_str(&format!("# {}\n\n", "x".repeat(3 * super::READ_CHUNK)));
            }
            let end = if k % 7 == 0 { "\r\n" } else { "\n" };
            text.push_str(&format!(
                "{t}, {:e},{:.4} ,1.75e-2,0,0{end}",
                1e-5 * (k as f64).sin(),
                25.0 + 1e-3 * k as f64
            ));
        }
        text.push_str("50.0,1e-5,25.1,1.75e-2,0,-5.72e-5\n");
        let dir = std::env::temp_dir().join(format!("ssis-read-paths-{}", std::process::id()));
        std::fs::create_dir_all(&dir).expect("a temporary directory");
        let file = dir.join("s.csv");
        std::fs::write(&file, &text).expect("written");
        assert!(super::map_file(&std::fs::File::open(&file).expect("opens")).is_some(), "a regular file is mapped");
        let mapped = rows(&file);
        assert_eq!(mapped.len(), 5000);

        let fifo = dir.join("s.fifo");
        let c = std::ffi::CString::new(fifo.to_str().expect("utf-8")).expect("no NUL");
        // SAFETY: a valid C string path.
        assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o600) }, 0, "mkfifo");
        // Opened for reading and writing, a FIFO does not wait for a writer (Linux).
        let rw = std::fs::OpenOptions::new().read(true).write(true).open(&fifo).expect("opens");
        assert!(super::map_file(&rw).is_none(), "a pipe is read");
        drop(rw);
        let whole = text.clone();
        let writer = std::thread::spawn(move || std::fs::write(&fifo, whole).expect("written to the pipe"));
        let read = rows(&dir.join("s.fifo"));
        writer.join().expect("the writer ends");
        assert_eq!(read, mapped);
        // The same file cut inside its last number (`-5.72e-5` → `-5.72`): refused, mapped or read.
        let cut = &text[..text.len() - 4];
        std::fs::write(&file, cut).expect("written");
        let refusal = |path: &std::path::Path| {
            let mut rr = RowReader::open(path).expect("opens");
            loop {
                match rr.next_row() {
                    Ok(Some(_)) => {}
                    Ok(None) => panic!("a cut last line was read as a row"),
                    Err(e) => return e,
                }
            }
        };
        let e = refusal(&file);
        assert_eq!((e.kind, e.line), (super::SessionErrorKind::Truncated, 5004), "{e}");
        let (fifo, cut) = (dir.join("s.fifo"), cut.to_string());
        let writer = std::thread::spawn(move || std::fs::write(&fifo, cut).expect("written to the pipe"));
        let e2 = refusal(&dir.join("s.fifo"));
        writer.join().expect("the writer ends");
        assert_eq!(e2.to_string(), e.to_string().replace("s.csv", "s.fifo"));
        let _ = std::fs::remove_dir_all(&dir);
    }

    /// A session truncated by another program under the map: the reader's next page past
    /// the new end raises SIGBUS, and the process stops with the plain message and status
    /// 74 ([`super::on_sigbus`], installed as a program does with
    /// [`super::exit_plainly_on_truncated_map`]). Run in a child process (this test binary again, with
    /// `SSIS_SIGBUS_CHILD`), which opens a three-page session, truncates it to one page and
    /// reads on: deterministic, the second page is gone before the reader reaches it.
    #[test]
    fn a_session_truncated_under_the_map_stops_with_a_plain_message() {
        const NAME: &str = "reader::read_paths::a_session_truncated_under_the_map_stops_with_a_plain_message";
        if let Some(path) = std::env::var_os("SSIS_SIGBUS_CHILD") {
            let path = std::path::PathBuf::from(path);
            let mut text = String::from("t_s,fog0_rad_s,fog0_t_degc,ref_x_rad_s,ref_y_rad_s,ref_z_rad_s\n");
            let mut k = 1;
            while text.len() < 3 * 4096 {
                text.push_str(&format!("{}.0,1e-5,25.0,1.75e-2,0,0\n", k));
                k += 1;
            }
            std::fs::write(&path, &text).expect("written");
            super::exit_plainly_on_truncated_map();
            let mut rr = RowReader::open(&path).expect("opens");
            std::fs::OpenOptions::new().write(true).open(&path).expect("opens").set_len(4096).expect("truncated");
            let mut rows = 0;
            while let Ok(Some(_)) = rr.next_row() {
                rows += 1;
            }
            // Not reached: the reader touches the second page first.
            panic!("read {rows} rows past a truncation without SIGBUS");
        }
        let dir = std::env::temp_dir().join(format!("ssis-sigbus-{}", std::process::id()));
        std::fs::create_dir_all(&dir).expect("a temporary directory");
        let out = std::process::Command::new(std::env::current_exe().expect("the test binary"))
            .args(["--exact", NAME, "--nocapture", "--test-threads=1"])
            .env("SSIS_SIGBUS_CHILD", dir.join("s.csv"))
            .output()
            .expect("the child runs");
        let _ = std::fs::remove_dir_all(&dir);
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(74), "status {:?}, stderr: {stderr}", out.status);
        assert!(stderr.contains("truncated by another program while it was being read"), "stderr: {stderr}");
    }
}
