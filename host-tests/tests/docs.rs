//! Executable documentation: every command block a user is meant to run in README.md,
//! docs/TOOLS.md, docs/TUTORIAL-CALIBRATION.md, docs/LAB.md and docs/RECORDED-LOG.md is run, in order,
//! in a scratch directory per document, and the output the text shows is checked against
//! what the run prints.
//!
//! The markdown conventions (the syntax of `trycmd`'s `.md` files, plus a tolerance for
//! figures; `trycmd` itself has no numeric tolerance and runs each command in a fresh
//! shell, where the tutorials need one shell per document: `cd`, shell functions):
//!
//! - A ```` ```console ```` block is run. `$ CMD` is a command (a line ending in `\` goes
//!   on); the lines after it up to the next `$ ` are its expected output.
//! - Expected output: a line `...` matches any number of lines; `…` or `[..]` inside a line
//!   matches any text on that line. Every other line must match an output line, in order,
//!   with no other line between (so elisions are written). The exit status must be 0,
//!   unless the expected output has a line starting with `error:` (then non-zero).
//! - Figures: numbers are compared as numbers, exactly as printed unless the block is
//!   marked `<!-- doc-run: tol 2% -->` (relative) on the line before its fence.
//! - A block whose first command starts with `cd ` runs from the repository root (the
//!   text's `cd host-tests` means from there); other blocks go on where the last one left.
//! - `<!-- doc-run: skip: REASON -->` before a block: not run (QEMU, hour-long runs); the
//!   reason is required and printed.
//! - `<!-- doc-run: file NAME -->` before a block: its text is written to NAME in the
//!   current directory of the document's shell (a tutorial creates every file it uses).
//! - A fenced block with no info string whose first line is a command (`cargo `, `cd `,
//!   `bash `, `ssis-`) is refused: commands go in ```` ```console ```` blocks.
//!
//! - `<!-- doc-run: figures: 0.088 -15.26 4.3=(49.33)-(45.00) -->` after a paragraph:
//!   the figures its prose quotes, checked against what the run printed (the shown output's
//!   elisions do not hide them), by default in the output of the last console block before
//!   it, or with `figures of `TEXT`: …` in the block of the last command before it whose
//!   text contains TEXT (the first after it if none before). A figure matches a printed number that rounds
//!   to it at the figure's last digit (`0.067` matches 0.06681), or within the block's `tol`.
//!   `X=(A)-(B)` is a figure the prose derives (an error against the truth): A and B must be
//!   printed, and A − B must round to X. Each figure X must be quoted in the prose between
//!   the last block and the marker (so the marker cannot drift from its text). Figures that no run of the document prints (the
//!   paper's, a test's, a skipped block's) are not marked.
//!
//! `cargo run --release -q --bin NAME -- ARGS` is served by a shim that calls the
//! binary built once, in release, by this test (`cargo build --release`), and the
//! binaries' directory is on `PATH` (`ssis-sim table diff …`). The repository root of the
//! scratch directory has a `host-tests/` with the real `scenarios/` linked in, and the
//! real `examples/`.
//!
//! `DOC_RUN_ONLY=LAB` runs one document (a substring of its path); `DOC_RUN_KEEP=1` keeps
//! the scratch directories; `DOC_RUN_BLESS=1` writes what the run printed into the document
//! in place of each drifted output (then put back the elisions and check the diff).

use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::process::Command;

/// The documents, each run in its own scratch directory.
const DOCS: [&str; 5] =
    ["README.md", "docs/TOOLS.md", "docs/TUTORIAL-CALIBRATION.md", "docs/LAB.md", "docs/RECORDED-LOG.md"];

/// One command of a console block and the output the text shows for it.
#[derive(Debug)]
struct Step {
    /// Line of the `$` in the markdown (1-based).
    line: usize,
    cmd: String,
    expected: Vec<String>,
    /// Relative tolerance on figures (0: as printed).
    tol: f64,
    /// The first command of a block that starts with `cd `: run from the repository root.
    from_root: bool,
    /// Line of the block's fence: the steps of one block share it.
    block: usize,
}

/// What a document asks the shell to do, in order.
#[derive(Debug)]
enum Action {
    Run(Step),
    File {
        line: usize,
        name: String,
        text: String,
    },
    /// Figures the prose quotes, checked against a command's output (`doc-run: figures`).
    Figures {
        line: usize,
        of: Option<String>,
        figures: Vec<String>,
    },
}

/// The numbers of a stretch of prose, thousands separators (`294,880,000`, `15 200`) joined.
fn prose_numbers(prose: &str) -> Vec<f64> {
    let chars: Vec<char> = prose.chars().collect();
    let joined: String = chars
        .iter()
        .enumerate()
        .filter(|&(i, &c)| {
            let group = i > 0
                && chars[i - 1].is_ascii_digit()
                && chars.len() > i + 3
                && chars[i + 1..=i + 3].iter().all(char::is_ascii_digit)
                && !chars.get(i + 4).is_some_and(|d| d.is_ascii_digit() || *d == '.');
            !(matches!(c, ',' | ' ' | '\u{202f}') && group)
        })
        .map(|(_, &c)| c)
        .collect();
    joined
        .lines()
        .flat_map(|l| pieces(l, false))
        .filter_map(|p| match p {
            Piece::Num(v, _) => Some(v),
            _ => None,
        })
        .collect()
}

/// A `doc-run: figures` marker's command text (if it names one) and figures.
type FiguresMarker = (Option<String>, Vec<String>);

/// A `doc-run: figures` marker: the command text it names (if any) and its figures.
fn figures_marker(line: &str) -> Option<Result<FiguresMarker, String>> {
    let m = line.trim().strip_prefix("<!-- doc-run:")?.strip_suffix("-->")?.trim();
    let rest = m.strip_prefix("figures")?;
    let (of, list) = match rest.trim_start().strip_prefix("of `") {
        Some(r) => match r.split_once('`') {
            Some((of, l)) => (Some(of.to_string()), l),
            None => return Some(Err("`figures of` needs its command text in backticks".into())),
        },
        None => (None, rest),
    };
    let Some(list) = list.trim_start().strip_prefix(':') else {
        return Some(Err("`doc-run: figures` needs `:` before its figures".into()));
    };
    let figures: Vec<String> = list.split_whitespace().map(str::to_string).collect();
    if figures.is_empty() {
        return Some(Err("`doc-run: figures` lists no figure".into()));
    }
    Some(Ok((of, figures)))
}

/// Parses the document's blocks; skipped blocks are listed in `skipped`.
fn parse(doc: &str, text: &str, skipped: &mut Vec<String>) -> Result<Vec<Action>, String> {
    let lines: Vec<&str> = text.lines().collect();
    let mut actions = Vec::new();
    let mut i = 0;
    // Where the prose before a `figures` marker starts: after the last block.
    let mut prose_from = 0;
    while i < lines.len() {
        if let Some(m) = figures_marker(lines[i]) {
            let (of, figures) = m.map_err(|e| format!("{doc}:{}: {e}", i + 1))?;
            // The marker's figures are the prose's: each is quoted in the text before it.
            let prose: Vec<&str> =
                lines[prose_from..i].iter().copied().filter(|l| !l.trim().starts_with("<!--")).collect();
            let quoted_in_prose = prose_numbers(&prose.join("\n"));
            for f in &figures {
                let x = f.split_once('=').map_or(f.as_str(), |(x, _)| x);
                let v = quoted(x).ok_or(format!("{doc}:{}: `{f}` is not a figure", i + 1))?.0;
                if !quoted_in_prose.contains(&v) {
                    return Err(format!(
                        "{doc}:{}: `doc-run: figures` lists {x}, which the prose before it (from line {}) does not quote",
                        i + 1,
                        prose_from + 1
                    ));
                }
            }
            actions.push(Action::Figures { line: i + 1, of, figures });
            i += 1;
            continue;
        }
        let Some(info) = lines[i].trim_start().strip_prefix("```") else {
            i += 1;
            continue;
        };
        let fence_line = i + 1;
        let marker = (0..i)
            .rev()
            .map(|k| lines[k].trim())
            .find(|l| !l.is_empty() && figures_marker(l).is_none())
            .and_then(|l| l.strip_prefix("<!-- doc-run:"))
            .and_then(|l| l.strip_suffix("-->"))
            .map(|l| l.trim().to_string());
        let end = (i + 1..lines.len())
            .find(|&k| lines[k].trim_start().starts_with("```"))
            .ok_or(format!("{doc}:{fence_line}: a block without its closing fence"))?;
        let body = &lines[i + 1..end];
        i = end + 1;
        prose_from = i;
        match marker.as_deref() {
            Some(m) if m.starts_with("skip") => {
                let reason = m.trim_start_matches("skip").trim_start_matches(':').trim();
                if reason.is_empty() {
                    return Err(format!("{doc}:{fence_line}: `doc-run: skip` needs its reason"));
                }
                skipped.push(format!("{doc}:{fence_line}: {reason}"));
                continue;
            }
            Some(m) if m.starts_with("file ") => {
                let name = m["file ".len()..].trim().to_string();
                actions.push(Action::File { line: fence_line, name, text: body.join("\n") + "\n" });
                continue;
            }
            _ => {}
        }
        let tol = match marker.as_deref() {
            Some(m) if m.starts_with("tol ") => {
                let pct = m["tol ".len()..].trim().trim_end_matches('%');
                pct.parse::<f64>().map_err(|_| format!("{doc}:{fence_line}: `doc-run: tol` needs a percentage"))?
                    / 100.0
            }
            Some(m) => return Err(format!("{doc}:{fence_line}: unknown `doc-run: {m}`")),
            None => 0.0,
        };
        let info = info.trim();
        if info.is_empty() {
            let first = body.iter().map(|l| l.trim()).find(|l| !l.is_empty()).unwrap_or("");
            if ["cargo ", "cd ", "bash ", "ssis-", "$ "].iter().any(|p| first.starts_with(p)) {
                return Err(format!(
                    "{doc}:{fence_line}: a block of commands without `console`: mark it ```console with `$ ` \
                     prompts, or `<!-- doc-run: skip: REASON -->`"
                ));
            }
            continue;
        }
        if info != "console" {
            continue;
        }
        let mut k = 0;
        while k < body.len() {
            let Some(first) = body[k].strip_prefix("$ ") else {
                return Err(format!("{doc}:{}: output before any `$ ` command", i_of(fence_line, k)));
            };
            let line = i_of(fence_line, k);
            let first_of_block = k == 0;
            let mut cmd = first.to_string();
            while cmd.ends_with('\\') && k + 1 < body.len() {
                k += 1;
                cmd.push('\n');
                cmd.push_str(body[k]);
            }
            k += 1;
            let mut expected = Vec::new();
            while k < body.len() && !body[k].starts_with("$ ") {
                expected.push(body[k].to_string());
                k += 1;
            }
            let from_root = first_of_block && cmd.starts_with("cd ");
            actions.push(Action::Run(Step { line, cmd, expected, tol, from_root, block: fence_line }));
        }
    }
    Ok(actions)
}

fn i_of(fence_line: usize, k: usize) -> usize {
    fence_line + 1 + k
}

/// A piece of an expected line: text, a number, or "any text".
#[derive(Debug, PartialEq)]
enum Piece {
    Text(String),
    Num(f64, String),
    Any,
}

/// Splits a line into text, numbers and wildcards. A number is an optional sign
/// (`-`, `+` or `−`) before digits with an optional fraction and exponent; a sign counts
/// only where a word does not go on before it.
fn pieces(line: &str, wildcards: bool) -> Vec<Piece> {
    let chars: Vec<char> = line.chars().collect();
    let mut out = Vec::new();
    let mut text = String::new();
    let mut i = 0;
    let flush = |text: &mut String, out: &mut Vec<Piece>| {
        if !text.is_empty() {
            out.push(Piece::Text(std::mem::take(text)));
        }
    };
    while i < chars.len() {
        if wildcards && chars[i] == '…' {
            flush(&mut text, &mut out);
            out.push(Piece::Any);
            i += 1;
            continue;
        }
        if wildcards && chars[i..].starts_with(&['[', '.', '.', ']']) {
            flush(&mut text, &mut out);
            out.push(Piece::Any);
            i += 4;
            continue;
        }
        let prev_word = i > 0 && (chars[i - 1].is_alphanumeric() || chars[i - 1] == '_' || chars[i - 1] == '.');
        let signed =
            matches!(chars[i], '-' | '+' | '−') && !prev_word && chars.get(i + 1).is_some_and(|c| c.is_ascii_digit());
        if (chars[i].is_ascii_digit() && !prev_word) || signed {
            let start = i;
            i += 1;
            while i < chars.len() && chars[i].is_ascii_digit() {
                i += 1;
            }
            if i + 1 < chars.len() && chars[i] == '.' && chars[i + 1].is_ascii_digit() {
                i += 1;
                while i < chars.len() && chars[i].is_ascii_digit() {
                    i += 1;
                }
            }
            if i + 1 < chars.len() && (chars[i] == 'e' || chars[i] == 'E') {
                let mut j = i + 1;
                if j < chars.len() && (chars[j] == '-' || chars[j] == '+') {
                    j += 1;
                }
                if j < chars.len() && chars[j].is_ascii_digit() {
                    i = j;
                    while i < chars.len() && chars[i].is_ascii_digit() {
                        i += 1;
                    }
                }
            }
            // A number glued to letters (`v2`, `fog0`, `3σ`) stays text.
            if i < chars.len() && (chars[i].is_alphabetic() && chars[i] != 'e' || chars[i] == '_') {
                text.extend(&chars[start..i]);
                continue;
            }
            let s: String = chars[start..i].iter().collect();
            match s.replace('−', "-").parse::<f64>() {
                Ok(v) => {
                    flush(&mut text, &mut out);
                    out.push(Piece::Num(v, s));
                }
                Err(_) => text.push_str(&s),
            }
            continue;
        }
        text.push(chars[i]);
        i += 1;
    }
    flush(&mut text, &mut out);
    out
}

/// Whether the output line matches the expected line (wildcards, figures within `tol`).
fn line_matches(expected: &str, actual: &str, tol: f64) -> bool {
    let exp = pieces(expected.trim_end(), true);
    let act = pieces(actual.trim_end(), false);
    // Flatten the actual line to a sequence of tokens the expected pieces consume.
    match_from(&exp, &act, 0, tol)
}

fn match_from(exp: &[Piece], act: &[Piece], text_off: usize, tol: f64) -> bool {
    let Some((first, rest)) = exp.split_first() else {
        return act.is_empty() || (act.len() == 1 && matches!(&act[0], Piece::Text(t) if t.len() == text_off));
    };
    // The current actual piece, with `text_off` bytes of its text consumed.
    let cur = act.first();
    match first {
        Piece::Text(t) => match cur {
            Some(Piece::Text(a)) => {
                let avail = &a[text_off..];
                if avail.starts_with(t.as_str()) {
                    let off = text_off + t.len();
                    if off == a.len() {
                        match_from(rest, &act[1..], 0, tol)
                    } else {
                        match_from(rest, act, off, tol)
                    }
                } else {
                    false
                }
            }
            _ => false,
        },
        Piece::Num(v, s) => match cur {
            Some(Piece::Num(w, ws)) if text_off == 0 => {
                let same = if tol == 0.0 {
                    ws.replace('−', "-") == s.replace('−', "-")
                } else {
                    (v - w).abs() <= tol * v.abs().max(w.abs()) || v == w
                };
                same && match_from(rest, &act[1..], 0, tol)
            }
            _ => false,
        },
        Piece::Any => {
            // Any suffix of the actual line, from the current position on.
            if match_from(rest, act, text_off, tol) {
                return true;
            }
            let Some(c) = cur else { return false };
            match c {
                Piece::Text(a) => {
                    let mut off = text_off;
                    while off < a.len() {
                        off += a[off..].chars().next().map_or(1, char::len_utf8);
                        let ok = if off == a.len() {
                            match_from(exp, &act[1..], 0, tol)
                        } else {
                            match_from(exp, act, off, tol)
                        };
                        if ok {
                            return true;
                        }
                    }
                    false
                }
                Piece::Num(..) => match_from(exp, &act[1..], 0, tol),
                Piece::Any => false,
            }
        }
    }
}

/// Whether the output matches the expected lines (`...` lines match any lines).
fn output_matches(expected: &[String], actual: &[&str], tol: f64) -> bool {
    let Some((first, rest)) = expected.split_first() else {
        return actual.is_empty();
    };
    if first.trim() == "..." || first.trim() == "…" {
        return (0..=actual.len()).any(|k| output_matches(rest, &actual[k..], tol));
    }
    match actual.split_first() {
        Some((a, more)) => line_matches(first, a, tol) && output_matches(rest, more, tol),
        None => false,
    }
}

/// The binaries' directory: `cargo build --release` of the host workspace's binaries, once.
fn bin_dir() -> PathBuf {
    let manifest = Path::new(env!("CARGO_MANIFEST_DIR"));
    let status = Command::new(env!("CARGO"))
        .current_dir(manifest)
        .args(["build", "--release", "--quiet", "--bins"])
        .status()
        .expect("cargo runs");
    assert!(status.success(), "building the binaries failed");
    // target/<triple>/<profile>/deps/docs-HASH -> target/<triple>/release
    let exe = std::env::current_exe().expect("the test binary");
    let triple_dir = exe.ancestors().nth(3).expect("target/<triple>/<profile>/deps");
    let dir = triple_dir.join("release");
    assert!(dir.join("ssis-cal").exists(), "no ssis-cal in {}", dir.display());
    dir
}

/// The `cargo` a document's shell sees: `cargo run [--release] [-q] --bin NAME -- ARGS`
/// runs the built binary; anything else is refused (the test does not build).
const CARGO_SHIM: &str = r#"#!/usr/bin/env bash
if [ "$1" != run ]; then echo "doc-run shim: only \`cargo run … --bin NAME -- ARGS\` is served" >&2; exit 97; fi
shift
name=""
while [ $# -gt 0 ]; do
  case "$1" in
    --bin) name="$2"; shift 2 ;;
    --) shift; break ;;
    *) shift ;;
  esac
done
[ -n "$name" ] || { echo "doc-run shim: no --bin" >&2; exit 97; }
exec "$DOC_RUN_BIN/$name" "$@"
"#;

/// Runs one document; returns its failures.
fn run_doc(root: &Path, bins: &Path, doc: &str, scratch: &Path) -> Vec<String> {
    let text = std::fs::read_to_string(root.join(doc)).expect("the document reads");
    let mut skipped = Vec::new();
    let actions = match parse(doc, &text, &mut skipped) {
        Ok(a) => a,
        Err(e) => return vec![e],
    };
    for s in &skipped {
        println!("skipped {s}");
    }
    let _ = std::fs::remove_dir_all(scratch);
    let shim = scratch.join(".doc-run");
    let outs = shim.join("out");
    std::fs::create_dir_all(&outs).expect("scratch");
    std::fs::create_dir_all(scratch.join("host-tests")).expect("scratch");
    std::os::unix::fs::symlink(root.join("host-tests/scenarios"), scratch.join("host-tests/scenarios"))
        .expect("scenarios linked");
    std::os::unix::fs::symlink(root.join("examples"), scratch.join("examples")).expect("examples linked");
    let cargo = shim.join("cargo");
    std::fs::write(&cargo, CARGO_SHIM).expect("shim");
    std::fs::set_permissions(&cargo, std::os::unix::fs::PermissionsExt::from_mode(0o755)).expect("shim mode");

    // One shell for the document: `cd` and functions carry over from command to command.
    let mut script = String::from("set +e\n");
    for (n, a) in actions.iter().enumerate() {
        match a {
            Action::Run(s) => {
                if s.from_root {
                    let _ = writeln!(script, "cd '{}'", scratch.display());
                }
                let _ = writeln!(script, "{{\n{}\n}} > '{}/{n}.out' 2>&1 < /dev/null", s.cmd, outs.display());
                let _ = writeln!(script, "echo $? > '{}/{n}.rc'", outs.display());
            }
            Action::File { name, line, .. } => {
                println!("{doc}:{line}: writes {name}");
                let _ = writeln!(script, "cp '{}/{n}.file' '{name}'", outs.display());
            }
            Action::Figures { .. } => {}
        }
    }
    for (n, a) in actions.iter().enumerate() {
        if let Action::File { text, .. } = a {
            std::fs::write(outs.join(format!("{n}.file")), text).expect("file");
        }
    }
    let path = format!("{}:{}:{}", shim.display(), bins.display(), std::env::var("PATH").unwrap_or_default());
    let status = Command::new("bash")
        .arg("-c")
        .arg(&script)
        .current_dir(scratch)
        .env("PATH", path)
        .env("DOC_RUN_BIN", bins)
        .env_remove("RUST_BACKTRACE")
        .env("NO_COLOR", "1")
        .status()
        .expect("bash runs");
    assert!(status.success() || status.code().is_some(), "the document's shell died");

    let mut failures = Vec::new();
    let mut bless: Vec<(usize, usize, String)> = Vec::new();
    for (n, a) in actions.iter().enumerate() {
        let Action::Run(s) = a else { continue };
        let out = std::fs::read_to_string(outs.join(format!("{n}.out"))).unwrap_or_default();
        let rc: i32 = std::fs::read_to_string(outs.join(format!("{n}.rc")))
            .ok()
            .and_then(|r| r.trim().parse().ok())
            .unwrap_or(-1);
        let actual: Vec<&str> = out.lines().collect();
        let wants_error = s.expected.iter().any(|l| l.starts_with("error:"));
        let status_ok = if wants_error { rc != 0 } else { rc == 0 };
        let ok = status_ok && output_matches(&s.expected, &actual, s.tol) && !out.contains("panicked");
        println!("{doc}:{} $ {}  (exit {rc}){}", s.line, s.cmd, if ok { "" } else { "  DRIFTED" });
        if !ok {
            let from = s.line + s.cmd.lines().count() - 1;
            bless.push((from, s.expected.len(), out.trim_end().to_string()));
            failures.push(format!(
                "{doc}:{}: `{}` (exit {rc}, {})\n--- the text shows:\n{}\n--- the run printed:\n{}",
                s.line,
                s.cmd,
                if status_ok { "status as expected" } else { "unexpected exit status" },
                s.expected.join("\n"),
                out.trim_end()
            ));
        }
    }
    for (n, a) in actions.iter().enumerate() {
        let Action::Figures { line, of, figures } = a else { continue };
        let Some(steps) = figure_source(&actions, n, of.as_deref()) else {
            failures.push(format!(
                "{doc}:{line}: `doc-run: figures` has no command to check against{}",
                of.as_ref().map_or(String::new(), |o| format!(" (none contains `{o}`)"))
            ));
            continue;
        };
        let mut printed = Vec::new();
        let mut out_text = String::new();
        let mut tol = 0.0;
        for &k in &steps {
            let Action::Run(s) = &actions[k] else { continue };
            tol = s.tol;
            let out = std::fs::read_to_string(outs.join(format!("{k}.out"))).unwrap_or_default();
            let _ = writeln!(out_text, "$ {}\n{}", s.cmd, out.trim_end());
            printed.extend(out.lines().flat_map(|l| pieces(l, false)).filter_map(|p| match p {
                Piece::Num(v, s) => Some((v, s)),
                _ => None,
            }));
        }
        let missing: Vec<String> = figures.iter().filter_map(|f| figure_check(f, &printed, tol).err()).collect();
        println!("{doc}:{line}: figures {}{}", figures.join(" "), if missing.is_empty() { "" } else { "  DRIFTED" });
        if !missing.is_empty() {
            failures.push(format!(
                "{doc}:{line}: the prose quotes figures the run did not print:\n  {}\n--- the run printed:\n{}",
                missing.join("\n  "),
                out_text.trim_end()
            ));
        }
    }
    if std::env::var_os("DOC_RUN_BLESS").is_some() && !bless.is_empty() {
        // Replace the drifted outputs with the run's (elisions and tolerances are the
        // writer's to put back).
        let mut lines: Vec<String> = text.lines().map(str::to_string).collect();
        for (from, len, out) in bless.into_iter().rev() {
            let new: Vec<String> = out.lines().map(str::to_string).collect();
            lines.splice(from..from + len, new);
        }
        std::fs::write(root.join(doc), lines.join("\n") + "\n").expect("the document is written");
    }
    failures
}

/// The actions whose output a `figures` marker at `n` is checked against: the steps of the
/// last block before it, or of the block of the last step before it (else the first after)
/// whose command contains `of`.
fn figure_source(actions: &[Action], n: usize, of: Option<&str>) -> Option<Vec<usize>> {
    let run = |k: usize| match &actions[k] {
        Action::Run(s) => Some(s),
        _ => None,
    };
    let k = match of {
        Some(text) => {
            let hit = |k: &usize| run(*k).is_some_and(|s| s.cmd.contains(text));
            (0..n).rev().find(hit).or_else(|| (n + 1..actions.len()).find(hit))?
        }
        None => (0..n).rev().find(|&k| run(k).is_some())?,
    };
    let block = run(k)?.block;
    Some((0..actions.len()).filter(|&j| run(j).is_some_and(|s| s.block == block)).collect())
}

/// A quoted figure's value and half a unit of its last digit (`0.067`: 0.0005).
fn quoted(fig: &str) -> Option<(f64, f64)> {
    let f = fig.replace('−', "-");
    let v: f64 = f.parse().ok()?;
    let (mantissa, exp) = match f.split_once(['e', 'E']) {
        Some((m, e)) => (m.to_string(), e.parse::<i32>().ok()?),
        None => (f.clone(), 0),
    };
    let decimals = mantissa.split_once('.').map_or(0, |(_, d)| d.len() as i32);
    Some((v, 0.5 * 10f64.powi(exp - decimals)))
}

/// Whether a printed number rounds to the quoted figure (or lies within `tol` of it).
fn rounds_to(fig: &str, printed: &[(f64, String)], tol: f64) -> Result<f64, String> {
    let (v, half) = quoted(fig).ok_or(format!("`{fig}` is not a number"))?;
    printed
        .iter()
        .map(|(w, _)| *w)
        .find(|w| (w - v).abs() <= half * (1.0 + 1e-9) || (tol > 0.0 && (w - v).abs() <= tol * v.abs().max(w.abs())))
        .map(|_| v)
        .ok_or(format!("{fig}: no printed number rounds to it"))
}

/// Checks one figure of a `figures` marker: `X` printed, or `X=(A)-(B)` with A and B
/// printed and A − B rounding to X.
fn figure_check(fig: &str, printed: &[(f64, String)], tol: f64) -> Result<(), String> {
    let Some((x, expr)) = fig.split_once('=') else {
        return rounds_to(fig, printed, tol).map(|_| ());
    };
    let terms = expr
        .strip_prefix('(')
        .and_then(|e| e.strip_suffix(')'))
        .and_then(|e| e.split_once(")-("))
        .ok_or(format!("{fig}: a derived figure is written `X=(A)-(B)`"))?;
    let a = rounds_to(terms.0, printed, tol).map_err(|e| format!("{fig}: {e}"))?;
    let b = rounds_to(terms.1, printed, tol).map_err(|e| format!("{fig}: {e}"))?;
    let (v, half) = quoted(x).ok_or(format!("{fig}: `{x}` is not a number"))?;
    if (a - b - v).abs() <= half * (1.0 + 1e-9) {
        Ok(())
    } else {
        Err(format!("{fig}: {a} - {b} = {} does not round to {x}", a - b))
    }
}

#[test]
fn figures_round_to_the_printed_numbers() {
    let printed: Vec<(f64, String)> = ["0.06681", "-15.26", "49.33", "45.00", "3.57e-5", "294880000"]
        .iter()
        .map(|s| (s.parse().unwrap(), s.to_string()))
        .collect();
    assert!(figure_check("0.067", &printed, 0.0).is_ok());
    assert!(figure_check("0.0668", &printed, 0.0).is_ok());
    assert!(figure_check("0.066", &printed, 0.0).is_err());
    assert!(figure_check("−15.3", &printed, 0.0).is_ok());
    assert!(figure_check("-15.1", &printed, 0.0).is_err());
    assert!(figure_check("3.6e-5", &printed, 0.0).is_ok());
    assert!(figure_check("294880000", &printed, 0.0).is_ok());
    assert!(figure_check("4.3=(49.33)-(45.00)", &printed, 0.0).is_ok());
    assert!(figure_check("4.4=(49.33)-(45.00)", &printed, 0.0).is_err());
    assert!(figure_check("4.3=(49.33)-(45.01)", &printed, 0.0).is_err());
    assert!(figure_check("0.069", &printed, 0.05).is_ok());
    assert!(figures_marker("<!-- doc-run: figures: 1 2 -->").is_some_and(|m| m.is_ok()));
    assert!(figures_marker("<!-- doc-run: figures of `add x`: 1 -->")
        .is_some_and(|m| m.is_ok_and(|(of, f)| of.as_deref() == Some("add x") && f.len() == 1)));
    assert!(figures_marker("<!-- doc-run: figures 1 2 -->").is_some_and(|m| m.is_err()));
    assert!(figures_marker("<!-- doc-run: tol 2% -->").is_none());
    let prose = prose_numbers("is 294,880,000 bytes, the 15 200-s flight; (6.59, 16.69) −0.470, +0.38″");
    assert_eq!(prose, [294880000.0, 15200.0, 6.59, 16.69, -0.47, 0.38]);
}

#[test]
fn matcher_compares_figures_and_wildcards() {
    assert!(line_matches("ARW 0.00500 [0.00499, 0.00501] °/√h", "ARW 0.00500 [0.00499, 0.00501] °/√h", 0.0));
    assert!(!line_matches("ARW 0.00500 °/√h", "ARW 0.00501 °/√h", 0.0));
    assert!(line_matches("ARW 0.00500 °/√h", "ARW 0.00501 °/√h", 0.01));
    assert!(!line_matches("ARW 0.00500 °/√h", "ARW 0.00600 °/√h", 0.01));
    assert!(line_matches("flew 15200 s in … s; wrote x", "flew 15200 s in 20.1 s; wrote x", 0.0));
    assert!(line_matches("error: x (…)", "error: x (a long reason)", 0.0));
    assert!(line_matches("d = −15.1°", "d = -15.1°", 0.0));
    assert!(!line_matches("revision 4", "revision 5", 0.0));
    assert!(line_matches("wrote model.v2.toml (version 2)", "wrote model.v2.toml (version 2)", 0.0));
    assert!(!line_matches("short", "short and more", 0.0));
    let out = ["a", "b 1", "c", "d"];
    let exp = |v: &[&str]| v.iter().map(|s| s.to_string()).collect::<Vec<_>>();
    assert!(output_matches(&exp(&["a", "...", "d"]), &out, 0.0));
    assert!(!output_matches(&exp(&["a", "d"]), &out, 0.0));
    assert!(output_matches(&exp(&["...", "b 1", "..."]), &out, 0.0));
    assert!(!output_matches(&exp(&["...", "b 2", "..."]), &out, 0.0));
}

#[test]
fn documented_commands_run_as_written() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).parent().expect("the repository root").to_path_buf();
    let only = std::env::var("DOC_RUN_ONLY").ok();
    let bins = bin_dir();
    let base = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join("doc-run");
    let mut failures = Vec::new();
    for doc in DOCS {
        if only.as_deref().is_some_and(|o| !doc.contains(o)) {
            continue;
        }
        let scratch = base.join(doc.replace('/', "-"));
        let f = run_doc(&root, &bins, doc, &scratch);
        if f.is_empty() && std::env::var_os("DOC_RUN_KEEP").is_none() {
            let _ = std::fs::remove_dir_all(&scratch);
        }
        failures.extend(f);
    }
    assert!(failures.is_empty(), "{} block(s) drifted:\n\n{}", failures.len(), failures.join("\n\n"));
}
