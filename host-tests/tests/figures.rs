//! The documents' figures against their one source, `docs/figures.toml`.
//!
//! - BENCHMARKS.md's current table and README.md's datasheet budgets are the tables this
//!   test renders from the file (between `<!-- figures: … -->` and `<!-- figures: end -->`);
//!   `FIGURES_BLESS=1` writes them in place.
//! - A figure quoted in prose is followed by `<!-- fig: ID -->`: the number(s) just before
//!   the marker on its line must be the file's value (rounded as quoted), so two documents
//!   cannot state one figure differently.
//! - A figure with a `source` is checked against what declares it: the code, a linker
//!   script, a directory, or the flight ELF when it is built.
//! - The documents stand on their own: no path outside the repository, no development
//!   label ("session 12", "issue 42": history lives in git); README.md stays a front page
//!   (under 300 lines) and BENCHMARKS.md's current table under 100 rows.
//!
//! `cd host-tests && cargo test --release --test figures`.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

/// One figure of docs/figures.toml.
#[derive(Debug)]
struct Figure {
    id: String,
    what: String,
    /// The value, one per axis; `ints` when every one is a TOML integer.
    value: Vec<f64>,
    ints: bool,
    decimals: Option<usize>,
    hex: bool,
    unit: String,
    bound: Option<(bool, f64)>,
    goal: Option<String>,
    command: String,
    measured_at: String,
    source: Option<String>,
    table: bool,
    datasheet: bool,
}

fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).parent().expect("the repository root").to_path_buf()
}

fn read(rel: &str) -> String {
    std::fs::read_to_string(root().join(rel)).unwrap_or_else(|e| panic!("{rel}: {e}"))
}

fn figures() -> Vec<Figure> {
    let doc: toml::Table = read("docs/figures.toml").parse().expect("docs/figures.toml parses");
    let list = doc.get("figure").and_then(|f| f.as_array()).expect("[[figure]] entries");
    let s = |t: &toml::Table, k: &str| t.get(k).and_then(|v| v.as_str()).map(str::to_string);
    let num = |v: &toml::Value| v.as_float().or_else(|| v.as_integer().map(|i| i as f64));
    list.iter()
        .map(|f| {
            let t = f.as_table().expect("a figure is a table");
            let id = s(t, "id").expect("every figure has an id");
            let raw = t.get("value").unwrap_or_else(|| panic!("{id}: no value"));
            let (value, ints): (Vec<f64>, bool) = match raw.as_array() {
                Some(a) => (a.iter().map(|v| num(v).expect("a number")).collect(), a.iter().all(|v| v.is_integer())),
                None => (vec![num(raw).unwrap_or_else(|| panic!("{id}: value is not a number"))], raw.is_integer()),
            };
            let bound = match s(t, "bound").as_deref() {
                Some(b) => {
                    let limit = t.get("limit").and_then(num).unwrap_or_else(|| panic!("{id}: a bound needs a limit"));
                    assert!(b == "max" || b == "min", "{id}: bound is \"max\" or \"min\"");
                    Some((b == "max", limit))
                }
                None => None,
            };
            Figure {
                what: s(t, "what").unwrap_or_else(|| panic!("{id}: no `what`")),
                value,
                ints,
                decimals: t.get("decimals").and_then(|d| d.as_integer()).map(|d| d as usize),
                hex: s(t, "format").as_deref() == Some("hex"),
                unit: s(t, "unit").unwrap_or_default(),
                bound,
                goal: s(t, "goal"),
                command: s(t, "command").unwrap_or_else(|| panic!("{id}: no `command`")),
                measured_at: s(t, "measured_at").unwrap_or_else(|| panic!("{id}: no `measured_at`")),
                source: s(t, "source"),
                table: t.get("table").and_then(|v| v.as_bool()).unwrap_or(false),
                datasheet: t.get("datasheet").and_then(|v| v.as_bool()).unwrap_or(false),
                id,
            }
        })
        .collect()
}

/// `129696` → `129,696`.
fn thousands(n: i64) -> String {
    let digits = n.unsigned_abs().to_string();
    let mut out = String::new();
    for (i, c) in digits.chars().enumerate() {
        if i > 0 && (digits.len() - i).is_multiple_of(3) {
            out.push(',');
        }
        out.push(c);
    }
    if n < 0 {
        format!("-{out}")
    } else {
        out
    }
}

impl Figure {
    fn decimals_of(&self, v: f64) -> usize {
        self.decimals.unwrap_or_else(|| {
            let s = format!("{v}");
            s.split_once('.').map_or(0, |(_, d)| d.len())
        })
    }

    fn fmt_one(&self, v: f64, decimals: usize) -> String {
        if self.hex {
            let h = format!("{:08x}", v as u64);
            format!("0x{}_{}", &h[..4], &h[4..])
        } else if self.ints {
            thousands(v as i64)
        } else {
            format!("{v:.decimals$}")
        }
    }

    /// The value as the documents write it: `3,888`, `3.78 / 3.17 / 1.58`, `0x0002_2000`.
    fn value_text(&self) -> String {
        self.value.iter().map(|&v| self.fmt_one(v, self.decimals_of(v))).collect::<Vec<_>>().join(" / ")
    }

    fn with_unit(&self, text: String) -> String {
        if self.unit.is_empty() {
            text
        } else if self.unit == "″" || self.unit == "σ" {
            format!("{text}{}", self.unit)
        } else {
            format!("{text} {}", self.unit)
        }
    }

    fn limit_text(&self) -> String {
        match self.bound {
            Some((max, limit)) => {
                let d = self.value.iter().map(|&v| self.decimals_of(v)).max().unwrap_or(0);
                let l = self.with_unit(self.fmt_one(limit, d));
                format!("{} {l}", if max { "≤" } else { "≥" })
            }
            None => "—".into(),
        }
    }

    fn goal_text(&self) -> String {
        self.goal.clone().unwrap_or_else(|| self.limit_text())
    }

    /// What is left to the limit on the worst axis, and as a share of the limit.
    fn margin_text(&self) -> String {
        let Some((max, limit)) = self.bound else { return "—".into() };
        let worst = if max {
            self.value.iter().copied().fold(f64::MIN, f64::max)
        } else {
            self.value.iter().copied().fold(f64::MAX, f64::min)
        };
        let m = if max { limit - worst } else { worst - limit };
        let d = self.value.iter().map(|&v| self.decimals_of(v)).max().unwrap_or(0);
        let verdict = if m < 0.0 { "**missed**: " } else { "" };
        if limit == 0.0 {
            return if m < 0.0 { "**missed**".into() } else { "met (none allowed)".into() };
        }
        format!("{verdict}{} ({:.1} %)", self.with_unit(self.fmt_one(m, d)), 100.0 * m / limit.abs())
    }
}

/// A markdown table: the header's cells, then one row per figure.
fn table<'a>(header: &[&str], figs: impl Iterator<Item = &'a Figure>, row: impl Fn(&Figure) -> Vec<String>) -> String {
    let mut t = format!("| {} |\n|{}\n", header.join(" | "), "---|".repeat(header.len()));
    for f in figs {
        let _ = writeln!(t, "| {} |", row(f).join(" | "));
    }
    t
}

/// A command as a table cell: code when it is one, words when it refers to another row.
fn command_cell(f: &Figure) -> String {
    if f.command.contains('`') || f.command.starts_with("the ") {
        f.command.clone()
    } else {
        format!("`{}`", f.command)
    }
}

/// BENCHMARKS.md's current table.
fn current_table(figs: &[Figure]) -> String {
    let header = ["figure", "goal", "current", "margin", "command", "measured at"];
    table(&header, figs.iter().filter(|f| f.table), |f| {
        let value = format!("**{}**", f.with_unit(f.value_text()));
        vec![f.what.clone(), f.goal_text(), value, f.margin_text(), command_cell(f), f.measured_at.clone()]
    })
}

/// README.md's datasheet budgets.
fn datasheet_table(figs: &[Figure]) -> String {
    let header = ["budget", "current", "limit", "margin", "measured by"];
    table(&header, figs.iter().filter(|f| f.datasheet), |f| {
        let value = format!("**{}**", f.with_unit(f.value_text()));
        vec![f.what.clone(), value, f.goal_text(), f.margin_text(), command_cell(f)]
    })
}

/// Checks (or with FIGURES_BLESS writes) a generated table between its markers.
fn generated_block(rel: &str, name: &str, want: &str) -> Result<(), String> {
    let text = read(rel);
    let begin = format!("<!-- figures: {name}, generated from docs/figures.toml by host-tests/tests/figures.rs -->\n");
    let end = "<!-- figures: end -->";
    let start = text.find(&begin).ok_or(format!("{rel}: no marker `{}`", begin.trim()))? + begin.len();
    let len = text[start..].find(end).ok_or(format!("{rel}: no `{end}` after `{name}`"))?;
    if &text[start..start + len] == want {
        return Ok(());
    }
    if std::env::var_os("FIGURES_BLESS").is_some() {
        let new = format!("{}{want}{}", &text[..start], &text[start + len..]);
        std::fs::write(root().join(rel), new).expect("the document is written");
        return Ok(());
    }
    let line0 = text[..start].lines().count();
    let (have, want): (Vec<&str>, Vec<&str>) = (text[start..start + len].lines().collect(), want.lines().collect());
    let mut diff = String::new();
    for k in 0..have.len().max(want.len()) {
        let (h, w) = (have.get(k).copied().unwrap_or(""), want.get(k).copied().unwrap_or(""));
        if h != w {
            let _ = write!(diff, "\n  {rel}:{}:\n    the document has {h}\n    the file gives   {w}", line0 + k + 1);
        }
    }
    Err(format!("{rel}: the {name} differs from docs/figures.toml (FIGURES_BLESS=1 writes it):{diff}"))
}

/// The numbers of a stretch of text, as written (`3,888`, `0x0002_2000`, `−0.47`); a
/// number glued to letters (`3σ`, `v2`, `fog0`) is not one.
fn numbers(text: &str) -> Vec<(f64, String)> {
    let c: Vec<char> = text.chars().collect();
    let mut out = Vec::new();
    let mut i = 0;
    while i < c.len() {
        let prev_word = i > 0 && (c[i - 1].is_alphanumeric() || c[i - 1] == '_' || c[i - 1] == '.');
        if !c[i].is_ascii_digit() || prev_word {
            i += 1;
            continue;
        }
        let start = i;
        let mut s = String::new();
        if c[i] == '0' && c.get(i + 1) == Some(&'x') {
            i += 2;
            while i < c.len() && (c[i].is_ascii_hexdigit() || c[i] == '_') {
                s.push(c[i]);
                i += 1;
            }
            let v = u64::from_str_radix(&s.replace('_', ""), 16).map(|v| v as f64);
            if let Ok(v) = v {
                out.push((v, c[start..i].iter().collect()));
            }
            continue;
        }
        while i < c.len() {
            if c[i].is_ascii_digit() {
                s.push(c[i]);
                i += 1;
            } else if c[i] == ','
                && c.len() > i + 3
                && c[i + 1..=i + 3].iter().all(char::is_ascii_digit)
                && !c.get(i + 4).is_some_and(char::is_ascii_digit)
            {
                i += 1;
            } else {
                break;
            }
        }
        if i + 1 < c.len() && c[i] == '.' && c[i + 1].is_ascii_digit() {
            s.push('.');
            i += 1;
            while i < c.len() && c[i].is_ascii_digit() {
                s.push(c[i]);
                i += 1;
            }
        }
        if i < c.len() && (c[i].is_alphabetic() || c[i] == '_') {
            continue;
        }
        let neg = start > 0 && matches!(c[start - 1], '-' | '−') && !(start > 1 && c[start - 2].is_alphanumeric());
        if let Ok(v) = s.parse::<f64>() {
            out.push((if neg { -v } else { v }, c[start..i].iter().collect()));
        }
    }
    out
}

/// Whether a quoted number is the value rounded at the quote's last digit.
fn quotes(quoted: &(f64, String), value: f64) -> bool {
    if quoted.1.starts_with("0x") {
        return quoted.0 == value;
    }
    let decimals = quoted.1.split_once('.').map_or(0, |(_, d)| d.len() as i32);
    (quoted.0 - value).abs() <= 0.5 * 10f64.powi(-decimals) * (1.0 + 1e-9)
}

/// Every markdown document of the repository (not the build directories).
fn documents(dir: &Path, out: &mut Vec<PathBuf>) {
    let Ok(rd) = std::fs::read_dir(dir) else { return };
    for e in rd.flatten() {
        let p = e.path();
        let name = e.file_name().to_string_lossy().to_string();
        if p.is_dir() {
            if !(name.starts_with('.') || name == "target" || name == "node_modules" || name.contains("venv")) {
                documents(&p, out);
            }
        } else if name.ends_with(".md") {
            out.push(p);
        }
    }
}

/// The `<!-- fig: ID -->` quotes of every document against the file.
fn prose_quotes(figs: &[Figure]) -> (usize, Vec<String>) {
    let root = root();
    let mut docs = Vec::new();
    documents(&root, &mut docs);
    docs.sort();
    let (mut checked, mut failures) = (0, Vec::new());
    for doc in docs {
        let rel = doc.strip_prefix(&root).unwrap_or(&doc).display().to_string();
        let text = std::fs::read_to_string(&doc).unwrap_or_default();
        for (n, line) in text.lines().enumerate() {
            let mut from = 0;
            while let Some(k) = line[from..].find("<!-- fig:") {
                let at = from + k;
                let Some(close) = line[at..].find("-->") else { break };
                let id = line[at + "<!-- fig:".len()..at + close].trim();
                from = at + close + 3;
                if line[..at].ends_with('`') {
                    continue; // the marker's syntax quoted in code, not a quote
                }
                let Some(f) = figs.iter().find(|f| f.id == id) else {
                    failures
                        .push(format!("{rel}:{}: `<!-- fig: {id} -->` names no figure of docs/figures.toml", n + 1));
                    continue;
                };
                // The prose before the marker, other markers taken out.
                let mut before = line[..at].to_string();
                while let (Some(a), Some(b)) = (before.find("<!--"), before.find("-->")) {
                    if b < a {
                        break;
                    }
                    before.replace_range(a..b + 3, " ");
                }
                let nums = numbers(&before);
                let quoted = &nums[nums.len().saturating_sub(f.value.len())..];
                checked += 1;
                let ok = quoted.len() == f.value.len() && quoted.iter().zip(&f.value).all(|(q, &v)| quotes(q, v));
                if !ok {
                    failures.push(format!(
                        "{rel}:{}: `{id}` quoted as {} but docs/figures.toml has {} ({})",
                        n + 1,
                        quoted.iter().map(|q| q.1.as_str()).collect::<Vec<_>>().join(" / "),
                        f.value_text(),
                        f.what
                    ));
                }
            }
        }
    }
    (checked, failures)
}

/// A number in a linker script: `0x20000`, `32K`, `3584`.
fn linker_number(s: &str) -> Option<f64> {
    let s = s.trim().trim_end_matches([',', ';', ')']);
    if let Some(h) = s.strip_prefix("0x") {
        return u64::from_str_radix(&h.replace('_', ""), 16).ok().map(|v| v as f64);
    }
    if let Some(k) = s.strip_suffix('K') {
        return k.parse::<f64>().ok().map(|k| k * 1024.0);
    }
    s.parse().ok()
}

/// A region's ORIGIN or LENGTH in memory.x.
fn memory_x(region: &str, field: &str) -> Option<f64> {
    let text = read("memory.x");
    let line = text.lines().find(|l| l.trim_start().starts_with(region) && l.contains("ORIGIN"))?;
    let rest = &line[line.find(field)? + field.len()..];
    linker_number(rest.trim_start().trim_start_matches('=').split(',').next()?)
}

/// What declares a `source` figure, or `None` when it is not there to read (an ELF not
/// built).
fn declared(source: &str) -> Result<Option<f64>, String> {
    let (kind, what) = source.split_once(':').ok_or(format!("source `{source}` is KIND:WHAT"))?;
    Ok(match (kind, what) {
        ("code", "output_frame_len") => Some(ssis::frames::output::FRAME_LEN as f64),
        ("code", "fog_frame_len") => Some(ssis::frames::fog::FRAME_LEN as f64),
        ("code", "star_frame_len") => Some(ssis::frames::star::FRAME_LEN as f64),
        ("code", "counter_pages") => Some(f64::from(ssis::telemetry::page::COUNT)),
        ("link", "flight-budget") => {
            let text = read("firmware/link/flight-budget.x");
            let assert = text.find("<=").ok_or("flight-budget.x: no `<=` in its ASSERT")?;
            linker_number(text[assert + 2..].split_whitespace().next().unwrap_or(""))
        }
        ("link", "stack") => memory_x("STACK", "LENGTH"),
        ("link", "calib") => memory_x("CALIB", "ORIGIN"),
        ("count", dir) => Some(
            std::fs::read_dir(root().join(dir))
                .map_err(|e| format!("{dir}: {e}"))?
                .flatten()
                .filter(|e| e.file_name().to_string_lossy().ends_with(".toml"))
                .count() as f64,
        ),
        ("elf", bin) => {
            let elf = root().join("target/thumbv7em-none-eabihf/release").join(bin);
            if !elf.exists() {
                println!("{bin}: not built (cd firmware && cargo build --release): its flash not checked");
                return Ok(None);
            }
            let (flash, _) = ssis_runner::qemu::elf_sizes(&elf).map_err(|e| format!("{}: {e}", elf.display()))?;
            Some(flash as f64)
        }
        _ => return Err(format!("source `{source}`: unknown")),
    })
}

#[test]
fn documents_state_each_figure_as_its_source_does() {
    let figs = figures();
    let mut failures = Vec::new();
    let mut ids = std::collections::HashSet::new();
    for f in &figs {
        if !ids.insert(f.id.clone()) {
            failures.push(format!("docs/figures.toml: `{}` twice", f.id));
        }
    }
    for f in figs.iter().filter(|f| f.source.is_some()) {
        let src = f.source.as_deref().unwrap_or("");
        match declared(src) {
            Ok(Some(v)) if f.value.len() == 1 && v == f.value[0] => println!("{}: {} = {src}", f.id, f.value_text()),
            Ok(Some(v)) => failures.push(format!(
                "docs/figures.toml: `{}` is {} but {src} gives {v} ({}): re-measure and change it there",
                f.id,
                f.value_text(),
                f.what
            )),
            Ok(None) => {}
            Err(e) => failures.push(format!("docs/figures.toml: `{}`: {e}", f.id)),
        }
    }
    for (rel, name, want) in [
        ("BENCHMARKS.md", "current table", current_table(&figs)),
        ("README.md", "datasheet budgets", datasheet_table(&figs)),
    ] {
        if let Err(e) = generated_block(rel, name, &want) {
            failures.push(e);
        }
    }
    let (checked, quoted) = prose_quotes(&figs);
    println!("{checked} quoted figures checked");
    failures.extend(quoted);
    assert!(failures.is_empty(), "{} figure(s) disagree:\n{}", failures.len(), failures.join("\n"));
}

/// A development label in a line: `session` or `issue` as a word, then a number
/// (`Session 12`, `issue #42`).
fn development_label(line: &str) -> Option<String> {
    let lower = line.to_lowercase();
    for word in ["session", "issue"] {
        for (at, _) in lower.match_indices(word) {
            let starts_word = !lower[..at].chars().next_back().is_some_and(|c| c.is_alphanumeric() || c == '_');
            let rest = lower[at + word.len()..].trim_start_matches(' ').trim_start_matches('#');
            if starts_word
                && lower[at + word.len()..].starts_with(' ')
                && rest.starts_with(|c: char| c.is_ascii_digit())
            {
                let tail = lower[at + word.len()..].chars().take_while(|c| matches!(c, ' ' | '#' | '0'..='9'));
                return Some(format!("{word}{}", tail.collect::<String>()));
            }
        }
    }
    None
}

#[test]
fn documents_are_self_contained() {
    let root = root();
    let mut docs = Vec::new();
    documents(&root, &mut docs);
    docs.sort();
    let mut failures = Vec::new();
    for doc in &docs {
        let rel = doc.strip_prefix(&root).unwrap_or(doc).display().to_string();
        let text = std::fs::read_to_string(doc).unwrap_or_default();
        for (n, line) in text.lines().enumerate() {
            for outside in ["../shared", "NOTES.md", "/work/"] {
                if line.contains(outside) {
                    failures.push(format!("{rel}:{}: names `{outside}`, outside the repository", n + 1));
                }
            }
            if let Some(label) = development_label(line) {
                failures.push(format!("{rel}:{}: a development label `{label}` (history lives in git)", n + 1));
            }
        }
    }
    let readme = read("README.md").lines().count();
    if readme >= 300 {
        failures.push(format!("README.md: {readme} lines, a front page stays under 300"));
    }
    let bench = read("BENCHMARKS.md");
    let rows = bench
        .split_once("<!-- figures: current table")
        .and_then(|(_, t)| t.split_once("<!-- figures: end -->"))
        .map_or(usize::MAX, |(t, _)| t.lines().filter(|l| l.starts_with("| ")).count());
    if rows >= 100 {
        failures.push(format!("BENCHMARKS.md: the current table has {rows} rows, fewer than 100 are read"));
    }
    println!("{} documents read; README.md {readme} lines, BENCHMARKS.md's table {rows} rows", docs.len());
    assert!(failures.is_empty(), "{} document(s) not self-contained:\n{}", failures.len(), failures.join("\n"));
}

#[test]
fn numbers_are_read_as_written() {
    let n: Vec<f64> = numbers("3,888 instructions, 3.78 / 3.17 / 1.58″ 3σ at 0x0002_2000; v2 fog0 −0.47, 1, 2")
        .into_iter()
        .map(|x| x.0)
        .collect();
    assert_eq!(n, [3888.0, 3.78, 3.17, 1.58, 139264.0, -0.47, 1.0, 2.0]);
    assert!(quotes(&(3.8, "3.8".into()), 3.78));
    assert!(!quotes(&(3900.0, "3,900".into()), 3888.0));
    assert_eq!(thousands(131072), "131,072");
    assert!(development_label("as in Session 12, the").is_some());
    assert_eq!(development_label("see issue #42.").as_deref(), Some("issue #42"));
    assert!(development_label("40 null sessions 1 at 1.0e-2; a session's 3 files; tissue 3").is_none());
}
