//! What the hostile-file tests of every tool share (`*/tests/hostile_files.rs`, one per
//! crate with a binary): a scratch directory whose files are compared byte for byte before
//! and after a command, running a tool, and a reader that closes the tool's standard output.
#![allow(dead_code)]

use std::collections::BTreeMap;
use std::io::{BufRead, BufReader, Read};
use std::os::unix::process::ExitStatusExt;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};

pub use ssis_common::cli::serde_json::{self, Value};

/// A fresh scratch directory for one test.
pub struct Scratch {
    pub dir: PathBuf,
}

impl Scratch {
    pub fn new(name: &str) -> Scratch {
        let dir = std::env::temp_dir().join(format!("ssis-hostile-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        Scratch { dir }
    }

    /// Writes a file (relative name) and returns its path.
    pub fn file(&self, name: &str, bytes: impl AsRef<[u8]>) -> PathBuf {
        let p = self.dir.join(name);
        std::fs::write(&p, bytes).unwrap();
        p
    }

    pub fn path(&self, name: &str) -> PathBuf {
        self.dir.join(name)
    }

    /// Every file below the directory: its bytes, or for a symbolic link its target.
    pub fn snapshot(&self) -> BTreeMap<PathBuf, Vec<u8>> {
        let mut out = BTreeMap::new();
        let mut stack = vec![self.dir.clone()];
        while let Some(d) = stack.pop() {
            for e in std::fs::read_dir(&d).unwrap().flatten() {
                let p = e.path();
                let m = std::fs::symlink_metadata(&p).unwrap();
                let rel = p.strip_prefix(&self.dir).unwrap().to_path_buf();
                if m.file_type().is_symlink() {
                    let t = std::fs::read_link(&p).unwrap();
                    out.insert(rel, format!("-> {}", t.display()).into_bytes());
                } else if m.is_dir() {
                    stack.push(p);
                } else {
                    out.insert(rel, std::fs::read(&p).unwrap());
                }
            }
        }
        out
    }
}

/// What a tool did: exit code or signal, and what it printed.
#[derive(Debug)]
pub struct Ran {
    pub code: Option<i32>,
    pub signal: Option<i32>,
    pub stdout: String,
    pub stderr: String,
}

/// Runs `exe` in `dir` with `args`.
pub fn run(exe: &str, dir: &Path, args: &[&str]) -> Ran {
    let out = Command::new(exe)
        .current_dir(dir)
        .args(args)
        .env_remove("RUST_BACKTRACE")
        .stdin(Stdio::null())
        .output()
        .unwrap();
    Ran {
        code: out.status.code(),
        signal: out.status.signal(),
        stdout: String::from_utf8_lossy(&out.stdout).into(),
        stderr: String::from_utf8_lossy(&out.stderr).into(),
    }
}

/// Runs a command that must be refused: exit status 1, every text of `must` in its
/// message, and every file of the directory (and no other) byte-identical afterwards.
pub fn refused(exe: &str, s: &Scratch, args: &[&str], must: &[&str]) -> Ran {
    let before = s.snapshot();
    let r = run(exe, &s.dir, args);
    println!("{} {}: {:?} {}", exe.rsplit('/').next().unwrap_or(exe), args.join(" "), r.code, r.stderr.trim());
    assert_eq!(r.code, Some(1), "{args:?}: not refused: {r:?}");
    for m in must {
        assert!(r.stderr.contains(m), "{args:?}: the message does not name `{m}`: {}", r.stderr);
    }
    assert!(!r.stderr.contains("panicked"), "{args:?}: panicked: {}", r.stderr);
    assert_eq!(s.snapshot(), before, "{args:?}: the directory changed");
    r
}

/// Runs a command that must succeed; every file that existed before and is not in
/// `changes` is byte-identical afterwards, and no temporary file is left.
pub fn succeeds(exe: &str, s: &Scratch, args: &[&str], changes: &[&str]) -> Ran {
    let before = s.snapshot();
    let r = run(exe, &s.dir, args);
    assert_eq!(r.code, Some(0), "{args:?}: failed: {r:?}");
    let after = s.snapshot();
    for (p, bytes) in &before {
        if !changes.iter().any(|c| Path::new(c) == p) {
            assert_eq!(after.get(p), Some(bytes), "{args:?}: {} changed", p.display());
        }
    }
    no_temporaries(s);
    r
}

/// No temporary (`.partial`) file anywhere in the directory.
pub fn no_temporaries(s: &Scratch) {
    let stray: Vec<_> = s.snapshot().into_keys().filter(|p| p.to_string_lossy().contains(".partial")).collect();
    assert!(stray.is_empty(), "temporary files left: {stray:?}");
}

/// A closed pipe: runs `exe`, reads `lines` lines of its standard output (0: none) and
/// closes it. The tool must end quietly: no panic, exit status 0 or SIGPIPE (141 in a
/// shell), no temporary file left. Returns what it wrote to standard error.
pub fn closed_pipe(exe: &str, s: &Scratch, args: &[&str], lines: usize) -> String {
    let mut child = Command::new(exe)
        .current_dir(&s.dir)
        .args(args)
        .env_remove("RUST_BACKTRACE")
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let mut err = child.stderr.take().unwrap();
    let errs = std::thread::spawn(move || {
        let mut s = String::new();
        let _ = err.read_to_string(&mut s);
        s
    });
    let mut out = BufReader::new(child.stdout.take().unwrap());
    for _ in 0..lines {
        let mut line = String::new();
        let _ = out.read_line(&mut line);
    }
    drop(out);
    let status = child.wait().unwrap();
    let stderr = errs.join().unwrap();
    println!("{} {} | head -{lines}: {status:?}", exe.rsplit('/').next().unwrap_or(exe), args.join(" "));
    assert!(!stderr.contains("panicked"), "{args:?}: panicked on a closed pipe: {stderr}");
    assert!(
        status.code() == Some(0) || status.signal() == Some(SIGPIPE),
        "{args:?}: exit {status:?} on a closed pipe (0 or SIGPIPE expected): {stderr}"
    );
    no_temporaries(s);
    stderr
}

/// SIGPIPE's number on Linux.
const SIGPIPE: i32 = 13;

/// Runs a `--json` command: standard output must be one JSON object with `ok` as
/// expected; returns it.
pub fn json_of(exe: &str, s: &Scratch, args: &[&str], ok: bool) -> Value {
    let r = run(exe, &s.dir, args);
    let v: Value = serde_json::from_str(&r.stdout)
        .unwrap_or_else(|e| panic!("{args:?}: standard output is not JSON ({e}): {}\n{}", r.stdout, r.stderr));
    assert_eq!(v["ok"], Value::Bool(ok), "{args:?}: {v}");
    assert_eq!(r.code, Some(if ok { 0 } else { 1 }), "{args:?}: {}", r.stderr);
    v
}

/// The value at a JSON pointer (`/run/steps`), which must exist.
pub fn at<'a>(v: &'a Value, pointer: &str) -> &'a Value {
    v.pointer(pointer).unwrap_or_else(|| panic!("no `{pointer}` in {v}"))
}

/// The keys docs/JSON.md lists for a command (the section headed `### `NAME``, or
/// `## Every command` for "every command"): the JSON pointers in its table's first column.
pub fn documented(name: &str) -> Vec<String> {
    let doc = std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/../../docs/JSON.md")).unwrap();
    let heading = if name == "every command" { "## Every command".to_string() } else { format!("### `{name}`") };
    let mut lines = doc.lines().skip_while(|l| l.trim() != heading).skip(1);
    let mut keys = Vec::new();
    for l in lines.by_ref().take_while(|l| !l.starts_with("## ") && !l.starts_with("### ")) {
        if let Some(rest) = l.strip_prefix("| `/") {
            keys.push(format!("/{}", rest.split('`').next().unwrap()));
        }
    }
    assert!(!keys.is_empty(), "docs/JSON.md lists no key for `{name}`");
    keys
}

/// Every key docs/JSON.md lists for `name` (and for every command) is in `v`.
pub fn has_documented_keys(v: &Value, name: &str) {
    for key in documented("every command").into_iter().chain(documented(name)) {
        assert!(v.pointer(&key).is_some(), "`{name}`: documented key {key} missing from {v}");
    }
}

/// Time damage in a CSV log's `lines` (data from index `first`): row 50 repeated, rows 300
/// and 301 swapped (one sample goes backward), rows 700..710 cut out; a replay counts 1
/// repeated, 1 backward and 11 missing samples.
pub fn damage_time(lines: &mut Vec<String>, first: usize) {
    lines.insert(first + 50, lines[first + 50].clone());
    lines.swap(first + 300, first + 301);
    lines.drain(first + 700..first + 710);
}
