//! What every host tool's `main` sets up, and how it ends: the output rules
//! ([`crate::output`]), signals, `--json`, the exit status.
//!
//! For binaries only: [`start`] installs process-wide signal handlers and, with `--json`,
//! moves the process's standard output (like `ssis_session::exit_plainly_on_truncated_map`,
//! a library function that only a `main` calls).
//!
//! - **A closed pipe ends a command quietly.** `ssis-lab diagnose … | head -1`: the write
//!   that finds standard output (or the JSON output, or standard error) closed ends the
//!   process by SIGPIPE (status 141 in a shell), as `cat` or `grep` would, after removing
//!   any temporary file in flight; it never panics. A SIGPIPE from another pipe or socket
//!   (a QEMU UART) stays an ordinary error of that write.
//! - **Ctrl-C** (SIGINT, and SIGTERM, SIGHUP) removes any temporary file in flight, then
//!   ends the process by that signal: no output is left half-written.
//! - **`--json`**: standard output then carries one JSON object (docs/JSON.md) written when
//!   the command ends, success or failure; the human text goes to standard error.

use std::io::Write;
use std::os::fd::{FromRawFd, RawFd};
use std::process::ExitCode;
use std::sync::atomic::{AtomicI32, Ordering};
use std::sync::Mutex;

use anyhow::Result;
pub use serde_json::{self, json, Value};

use crate::output;

/// The JSON output's file descriptor (-1: not in JSON mode).
static JSON_FD: AtomicI32 = AtomicI32::new(-1);
/// The JSON object being assembled: tool, command, the command's fields.
static JSON: Mutex<Option<serde_json::Map<String, Value>>> = Mutex::new(None);

/// The options every tool's command line shares (flattened into its `Cli`):
/// `--force` and `--json`.
#[derive(clap::Args, Debug, Clone, Copy)]
pub struct Flags {
    /// Replace existing files at output paths (never an input; model versions are never
    /// replaced).
    #[arg(long, global = true)]
    pub force: bool,
    /// Print one JSON object on standard output (docs/JSON.md); the text goes to standard error.
    #[arg(long, global = true)]
    pub json: bool,
}

impl Flags {
    /// [`start`] with these options.
    pub fn start(&self, tool: &str) -> Result<()> {
        start(tool, self.force, self.json)
    }
}

/// Sets up a tool's process: the output rules (`force`: `--force`), the signal handlers,
/// and with `json` (`--json`) the JSON object on standard output. `tool` names the run in
/// the JSON object; the command sets `command` with [`report`].
pub fn start(tool: &str, force: bool, json: bool) -> Result<()> {
    output::guard(force);
    install_handlers();
    if json {
        // SAFETY: plain descriptor calls at the start of `main`, before anything is printed.
        let fd = unsafe { libc::dup(1) };
        if fd < 0 || unsafe { libc::dup2(2, 1) } < 0 {
            anyhow::bail!("--json: cannot set up standard output: {}", std::io::Error::last_os_error());
        }
        JSON_FD.store(fd, Ordering::SeqCst);
        let mut m = serde_json::Map::new();
        m.insert("tool".into(), json!(tool));
        *JSON.lock().unwrap_or_else(|e| e.into_inner()) = Some(m);
    }
    Ok(())
}

/// Whether the run writes a JSON object (`--json`).
pub fn json_mode() -> bool {
    JSON_FD.load(Ordering::SeqCst) >= 0
}

/// Sets `key` of the JSON object to `value` (nothing without `--json`). `value` is built
/// only in JSON mode.
pub fn report(key: &str, value: impl FnOnce() -> Value) {
    if let Some(m) = JSON.lock().unwrap_or_else(|e| e.into_inner()).as_mut() {
        m.insert(key.to_string(), value());
    }
}

/// Ends the run: with `--json`, the object (with `ok`, `files_written` and, on failure,
/// `error`) on standard output; an error also on standard error. `Ok(false)` is a run
/// that completed but failed its own check (exit status 1, like an error).
pub fn finish(result: Result<bool>) -> ExitCode {
    let ok = matches!(result, Ok(true));
    if let Err(e) = &result {
        eprintln!("error: {e:#}");
    }
    let fd = JSON_FD.load(Ordering::SeqCst);
    if fd >= 0 {
        let mut m = JSON.lock().unwrap_or_else(|e| e.into_inner()).take().unwrap_or_default();
        m.insert("ok".into(), json!(ok));
        if let Err(e) = &result {
            m.insert("error".into(), json!(format!("{e:#}")));
        }
        let files: Vec<String> = output::written().iter().map(|p| p.display().to_string()).collect();
        m.insert("files_written".into(), json!(files));
        let _ = std::io::stdout().flush();
        // SAFETY: `fd` is the descriptor `start` duplicated; ManuallyDrop keeps it open.
        let mut f = std::mem::ManuallyDrop::new(unsafe { std::fs::File::from_raw_fd(fd) });
        let text = serde_json::to_string_pretty(&Value::Object(m)).unwrap_or_default();
        if writeln!(f, "{text}").and_then(|()| f.flush()).is_err() {
            return ExitCode::FAILURE;
        }
    }
    if ok {
        ExitCode::SUCCESS
    } else {
        ExitCode::FAILURE
    }
}

/// [`finish`] for a command that has no check of its own.
pub fn finish_unit(result: Result<()>) -> ExitCode {
    finish(result.map(|()| true))
}

fn install_handlers() {
    // SAFETY: sigaction with a handler that only calls async-signal-safe functions.
    unsafe {
        for sig in [libc::SIGPIPE, libc::SIGINT, libc::SIGTERM, libc::SIGHUP] {
            let mut sa: libc::sigaction = std::mem::zeroed();
            sa.sa_sigaction = on_signal as extern "C" fn(libc::c_int) as libc::sighandler_t;
            sa.sa_flags = libc::SA_RESTART;
            libc::sigemptyset(&mut sa.sa_mask);
            libc::sigaction(sig, &sa, std::ptr::null_mut());
        }
    }
}

/// Whether the pipe or socket on `fd` has lost its reader.
fn reader_gone(fd: RawFd) -> bool {
    if fd < 0 {
        return false;
    }
    let mut p = libc::pollfd { fd, events: libc::POLLOUT, revents: 0 };
    // SAFETY: one pollfd, no wait.
    let n = unsafe { libc::poll(&mut p, 1, 0) };
    n > 0 && p.revents & (libc::POLLERR | libc::POLLHUP) != 0
}

extern "C" fn on_signal(sig: libc::c_int) {
    if sig == libc::SIGPIPE && ![1, 2, JSON_FD.load(Ordering::SeqCst)].into_iter().any(reader_gone) {
        // Another pipe (a QEMU UART): the write fails with EPIPE and is reported.
        return;
    }
    output::remove_temporaries();
    // SAFETY: async-signal-safe; the signal is blocked until the handler returns, then
    // ends the process with its default action.
    unsafe {
        libc::signal(sig, libc::SIG_DFL);
        libc::raise(sig);
    }
}
