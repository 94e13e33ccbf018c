//! Outputs never destroy inputs: every file a host tool writes goes through here.
//!
//! A command names its inputs ([`input`]) and claims its outputs ([`claim`]) before it
//! starts, so a refusal comes before any work; every write ([`write`], [`create`]) goes
//! to a temporary file in the output's directory that is renamed into place only when it
//! is complete, and is removed on an error, on Ctrl-C (SIGINT, SIGTERM, SIGHUP) and on a
//! closed pipe (`crate::cli` installs the handlers). The rules, in the order checked:
//!
//! 1. An output that is the same file as an input is refused, whatever its spelling
//!    (`./x/../x`, a symbolic or hard link): paths are compared canonicalised and by
//!    device and inode. A file both read and written on purpose (the calibration table a
//!    `ssis-cal` method updates) is registered with [`update`] and may be replaced.
//! 2. Two outputs of one command that are the same file are refused.
//! 3. An output where a file already exists that this run did not write is refused
//!    unless `--force`, with two refinements by [`Origin`]: a file the command must
//!    create new (a model version) is never replaced, not even with `--force`; a file at
//!    a name the user did not give (a plot at its default name, the files an output
//!    directory receives) is replaced when it is recognisably this tools' output of the
//!    same kind ([`Own`]), and otherwise needs `--force` too.
//!
//! The rules are on once a binary calls [`guard`] (through `crate::cli::start`); without
//! it (library users, tests) [`write`] and [`create`] only make the write atomic.

use std::ffi::CString;
use std::fs::{self, File};
use std::io::{self, BufWriter, Write};
use std::os::unix::ffi::OsStrExt;
use std::os::unix::fs::MetadataExt;
use std::path::{Component, Path, PathBuf};
use std::sync::atomic::{AtomicPtr, AtomicU64, Ordering};
use std::sync::{Mutex, MutexGuard};

use anyhow::{bail, Context, Result};

/// Where an output's name comes from, which decides what happens to a file already there.
#[derive(Clone, Debug, PartialEq)]
pub enum Origin {
    /// The user named it: an existing file is replaced only with `--force`.
    Named,
    /// The command chose it (a default name, or a name derived from another path): an
    /// existing file is replaced when it is recognisably our output of that kind,
    /// otherwise only with `--force`.
    Default(Own),
    /// It must be a new file (a model version): an existing file is never replaced.
    New,
}

/// How an existing file is recognised as this tools' own output of a kind.
#[derive(Clone, Debug, PartialEq)]
pub enum Own {
    /// An SVG plot of ours: the file starts with `<svg` and contains this text (a fixed
    /// part of the plot's title).
    Svg(String),
    /// A CSV log of ours: its first line is exactly this header.
    CsvHeader(String),
    /// Never recognised (raw captures): an existing file needs `--force`.
    Nothing,
}

impl Own {
    /// Whether `bytes` (the start of an existing file) are our output of this kind.
    pub fn recognises(&self, bytes: &[u8]) -> bool {
        match self {
            Own::Svg(text) => {
                let escaped = text.replace('&', "&amp;").replace('<', "&lt;").replace('>', "&gt;");
                let body = String::from_utf8_lossy(bytes);
                body.trim_start().starts_with("<svg") && (body.contains(text.as_str()) || body.contains(&escaped))
            }
            Own::CsvHeader(h) => bytes.split(|b| *b == b'\n').next().is_some_and(|l| l == h.as_bytes()),
            Own::Nothing => false,
        }
    }
}

/// A file's identity: its canonical path (or the best absolute form of it) and, when it
/// exists, its device and inode.
#[derive(Clone, Debug)]
struct Id {
    canon: PathBuf,
    inode: Option<(u64, u64)>,
}

impl Id {
    fn of(path: &Path) -> Id {
        let inode = fs::metadata(path).ok().map(|m| (m.dev(), m.ino()));
        let canon = fs::canonicalize(path).ok().or_else(|| {
            let name = path.file_name()?;
            let parent = path.parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or(Path::new("."));
            Some(fs::canonicalize(parent).ok()?.join(name))
        });
        Id { canon: canon.unwrap_or_else(|| lexical(path)), inode }
    }

    fn same(&self, other: &Id) -> bool {
        self.canon == other.canon || (self.inode.is_some() && self.inode == other.inode)
    }
}

/// `path` made absolute with `.` and `..` resolved as text (for paths whose directory
/// does not exist either).
fn lexical(path: &Path) -> PathBuf {
    let abs = std::path::absolute(path).unwrap_or_else(|_| path.to_path_buf());
    let mut out = PathBuf::new();
    for c in abs.components() {
        match c {
            Component::ParentDir => {
                out.pop();
            }
            Component::CurDir => {}
            other => out.push(other),
        }
    }
    out
}

struct Input {
    given: PathBuf,
    id: Id,
    update: bool,
}

struct Claim {
    given: PathBuf,
    id: Id,
    origin: Origin,
}

/// The rules of one run: its inputs, the outputs it claimed and the files it wrote.
struct Guard {
    force: bool,
    inputs: Vec<Input>,
    claims: Vec<Claim>,
    written: Vec<(PathBuf, Id)>,
}

static GUARD: Mutex<Option<Guard>> = Mutex::new(None);

fn lock() -> MutexGuard<'static, Option<Guard>> {
    GUARD.lock().unwrap_or_else(|e| e.into_inner())
}

/// Turns the rules on for this process (a binary's `main`, through `crate::cli::start`);
/// `force` lets outputs replace existing files that are not inputs.
pub fn guard(force: bool) {
    *lock() = Some(Guard { force, inputs: Vec::new(), claims: Vec::new(), written: Vec::new() });
}

/// Registers a file the command reads: no output may be written onto it.
pub fn input(path: &Path) {
    if let Some(g) = lock().as_mut() {
        g.inputs.push(Input { given: path.to_path_buf(), id: Id::of(path), update: false });
    }
}

/// Registers and claims a file the command reads and then replaces on success (a table
/// updated in place): written atomically, never left half-written or replaced by a failed
/// command; refused if it is another input or output of the command.
pub fn update(path: &Path) -> Result<()> {
    if let Some(g) = lock().as_mut() {
        g.inputs.push(Input { given: path.to_path_buf(), id: Id::of(path), update: true });
    }
    claim(path, Origin::Named)
}

/// Claims an output before the command starts: refused (an error naming the path and
/// why) if a write there would break a rule.
pub fn claim(path: &Path, origin: Origin) -> Result<()> {
    let mut g = lock();
    let Some(g) = g.as_mut() else { return Ok(()) };
    g.check(path, &origin, true)?;
    g.claims.push(Claim { given: path.to_path_buf(), id: Id::of(path), origin });
    Ok(())
}

/// The paths written so far in this run, in order.
pub fn written() -> Vec<PathBuf> {
    lock().as_ref().map(|g| g.written.iter().map(|w| w.0.clone()).collect()).unwrap_or_default()
}

impl Guard {
    /// Whether a write at `path` keeps every rule; `Ok(true)` if a file is there that may
    /// be replaced, `Ok(false)` if none is. `claiming`: a new claim, which may not be the
    /// same file as any claim before it (at write time the path's own claim is skipped).
    fn check(&self, path: &Path, origin: &Origin, claiming: bool) -> Result<bool> {
        let shown = path.display();
        let id = Id::of(path);
        let meta = fs::symlink_metadata(path).ok();
        if fs::metadata(path).is_ok_and(|m| m.is_dir()) {
            bail!("{shown}: is a directory, not a file to write");
        }
        if let Some(i) = self.inputs.iter().find(|i| !i.update && id.same(&i.id)) {
            bail!(
                "{shown}: refused: it is the input {} (an output never replaces an input; name another file)",
                i.given.display()
            );
        }
        if let Some(c) = self.claims.iter().find(|c| (claiming || c.given != path) && id.same(&c.id)) {
            bail!("{shown}: refused: the same file as the output {} of this command", c.given.display());
        }
        let updated = self.inputs.iter().any(|i| i.update && id.same(&i.id));
        if meta.is_none() || updated || self.written.iter().any(|w| w.1.same(&id)) {
            return Ok(meta.is_some());
        }
        match origin {
            Origin::New => bail!("{shown}: exists: refused (this file is only ever written new)"),
            Origin::Named if !self.force => bail!("{shown}: exists: refused (--force replaces it)"),
            Origin::Default(own) if !self.force && !own.recognises(&head(path)) => {
                bail!("{shown}: exists and is not recognisably output of this tool: refused (--force replaces it)")
            }
            _ => Ok(true),
        }
    }

    fn origin_of(&self, path: &Path) -> Origin {
        self.claims.iter().find(|c| c.given == path).map_or(Origin::Named, |c| c.origin.clone())
    }
}

/// The first 64 KiB of a file (empty if it cannot be read).
fn head(path: &Path) -> Vec<u8> {
    use std::io::Read;
    let mut buf = Vec::new();
    if let Ok(f) = File::open(path) {
        let _ = f.take(64 * 1024).read_to_end(&mut buf);
    }
    buf
}

/// Checks a write at `path` under the rules (claiming it as [`Origin::Named`] if it was not
/// claimed); `Ok(true)` if an existing file there may be replaced.
fn admit(path: &Path) -> Result<bool> {
    let g = lock();
    match g.as_ref() {
        Some(g) => g.check(path, &g.origin_of(path), !g.claims.iter().any(|c| c.given == path)),
        None => Ok(true),
    }
}

fn wrote(path: &Path) {
    if let Some(g) = lock().as_mut() {
        g.written.push((path.to_path_buf(), Id::of(path)));
    }
}

/// Writes `bytes` to `path` under the rules: a temporary file in the same directory,
/// synced, then renamed into place (or linked, where no file may be replaced).
pub fn write(path: &Path, bytes: &[u8]) -> Result<()> {
    let mut f = create(path)?;
    f.write_all(bytes).with_context(|| format!("{}: cannot write", path.display()))?;
    f.commit()
}

/// Opens `path` for writing under the rules: a temporary file that
/// [`AtomicFile::commit`] puts in place; dropped without it, nothing is left.
pub fn create(path: &Path) -> Result<AtomicFile> {
    let replace = admit(path)?;
    let tmp = Temp::new(path)?;
    let file = File::options()
        .write(true)
        .create_new(true)
        .open(&tmp.path)
        .with_context(|| format!("{}: cannot write (temporary file {})", path.display(), tmp.path.display()))?;
    Ok(AtomicFile { out: BufWriter::new(file), tmp, dest: path.to_path_buf(), replace })
}

/// A file being written: a temporary file until [`AtomicFile::commit`].
pub struct AtomicFile {
    out: BufWriter<File>,
    tmp: Temp,
    dest: PathBuf,
    replace: bool,
}

impl Write for AtomicFile {
    fn write(&mut self, buf: &[u8]) -> io::Result<usize> {
        self.out.write(buf)
    }
    fn flush(&mut self) -> io::Result<()> {
        self.out.flush()
    }
}

impl AtomicFile {
    /// Puts the file in place: flushed, synced, renamed over an existing file that may be
    /// replaced, or linked where none may be (so a file that appeared meanwhile stays).
    pub fn commit(self) -> Result<()> {
        let AtomicFile { out, tmp, dest, replace } = self;
        let shown = dest.display();
        let file = out.into_inner().map_err(|e| anyhow::anyhow!("{shown}: cannot write: {}", e.error()))?;
        file.sync_all().with_context(|| format!("{shown}: cannot write"))?;
        drop(file);
        if replace {
            fs::rename(&tmp.path, &dest).with_context(|| format!("{shown}: cannot replace"))?;
        } else {
            match fs::hard_link(&tmp.path, &dest) {
                Ok(()) => {}
                Err(e) if e.kind() == io::ErrorKind::AlreadyExists => {
                    bail!("{shown}: appeared while this command ran: refused (--force replaces it)")
                }
                // A file system without hard links: the rename is the best left.
                Err(_) => fs::rename(&tmp.path, &dest).with_context(|| format!("{shown}: cannot write"))?,
            }
        }
        drop(tmp);
        wrote(&dest);
        Ok(())
    }
}

/// A temporary file's path, registered for removal on a signal and removed on drop.
struct Temp {
    path: PathBuf,
    slot: Option<usize>,
}

static TEMP_COUNTER: AtomicU64 = AtomicU64::new(0);

impl Temp {
    fn new(dest: &Path) -> Result<Temp> {
        let name = dest.file_name().with_context(|| format!("{}: not a file name", dest.display()))?;
        let n = TEMP_COUNTER.fetch_add(1, Ordering::Relaxed);
        let mut tmp_name = std::ffi::OsString::from(".");
        tmp_name.push(name);
        tmp_name.push(format!(".{}-{n}.partial", std::process::id()));
        let path = dest.with_file_name(tmp_name);
        let slot = register_temp(&path);
        Ok(Temp { path, slot })
    }
}

impl Drop for Temp {
    fn drop(&mut self) {
        let _ = fs::remove_file(&self.path);
        if let Some(k) = self.slot {
            TEMPS[k].store(std::ptr::null_mut(), Ordering::SeqCst);
        }
    }
}

/// Temporary files in flight, as C strings for the signal handler (never freed: a handler
/// on another thread may still read one; a run makes a handful).
static TEMPS: [AtomicPtr<libc::c_char>; 32] = [const { AtomicPtr::new(std::ptr::null_mut()) }; 32];

fn register_temp(path: &Path) -> Option<usize> {
    let c = CString::new(path.as_os_str().as_bytes()).ok()?;
    let p = c.into_raw();
    for (k, slot) in TEMPS.iter().enumerate() {
        if slot.compare_exchange(std::ptr::null_mut(), p, Ordering::SeqCst, Ordering::SeqCst).is_ok() {
            return Some(k);
        }
    }
    None
}

/// Removes every temporary file in flight. Async-signal-safe (only `unlink`): for signal
/// handlers, which then end the process.
pub fn remove_temporaries() {
    for slot in &TEMPS {
        let p = slot.load(Ordering::SeqCst);
        if !p.is_null() {
            // SAFETY: `p` came from `CString::into_raw` and is never freed.
            unsafe { libc::unlink(p) };
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scratch(name: &str) -> PathBuf {
        let d = std::env::temp_dir().join(format!("ssis-output-{name}-{}", std::process::id()));
        let _ = fs::remove_dir_all(&d);
        fs::create_dir_all(&d).unwrap();
        d
    }

    #[test]
    fn identities_see_through_spellings_and_links() {
        let d = scratch("ids");
        let a = d.join("a.csv");
        fs::write(&a, "x").unwrap();
        fs::create_dir_all(d.join("sub")).unwrap();
        std::os::unix::fs::symlink(&a, d.join("link.csv")).unwrap();
        fs::hard_link(&a, d.join("hard.csv")).unwrap();
        let id = Id::of(&a);
        for p in [d.join("sub/../a.csv"), d.join("./a.csv"), d.join("link.csv"), d.join("hard.csv")] {
            assert!(Id::of(&p).same(&id), "{} not seen as {}", p.display(), a.display());
        }
        assert!(!Id::of(&d.join("b.csv")).same(&id));
        assert!(Id::of(&d.join("nowhere/../b.csv")).same(&Id::of(&d.join("b.csv"))));
    }

    #[test]
    fn recognises_own_output() {
        assert!(Own::Svg("Allan deviation".into()).recognises(b"<svg width=\"9\"><text>Allan deviation</text>"));
        assert!(!Own::Svg("Allan deviation".into()).recognises(b"<svg><text>a drawing</text>"));
        assert!(!Own::Svg("Allan deviation".into()).recognises(b"Allan deviation notes"));
        assert!(Own::CsvHeader("t_s,q0".into()).recognises(b"t_s,q0\n1,2\n"));
        assert!(!Own::CsvHeader("t_s,q0".into()).recognises(b"t_s,q0,x\n"));
        assert!(!Own::Nothing.recognises(b""));
    }

    #[test]
    fn atomic_write_leaves_no_temporary() {
        let d = scratch("atomic");
        let p = d.join("out.txt");
        write(&p, b"one").unwrap();
        write(&p, b"two").unwrap();
        assert_eq!(fs::read(&p).unwrap(), b"two");
        let f = create(&d.join("dropped.txt")).unwrap();
        drop(f);
        let names: Vec<_> = fs::read_dir(&d).unwrap().flatten().map(|e| e.file_name()).collect();
        assert_eq!(names, vec![std::ffi::OsString::from("out.txt")]);
    }
}
