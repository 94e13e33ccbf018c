//! `ssis-lab`: the model lab for calibration engineers (`docs/LAB.md`).
//!
//! Compare the FOG error model with a ground-test session, see where it fails, learn which
//! effect is missing, add it, watch the held-out error fall, export the flight table.

use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::Duration;

use anyhow::{bail, Context, Result};
use clap::{Parser, Subcommand};
use indicatif::{ProgressBar, ProgressStyle};
use ssis_common::cli::{self, json};
use ssis_common::output::{self, Origin, Own};
use ssis_common::update;
use ssis_common::DEG_H_PER_RAD_S;
use ssis_lab::diagnose::{
    anova_beside_main, candidate_terms, diagnose_digest, diagnose_with_progress, f_critical, Diagnosis, Options,
};
use ssis_lab::export::to_table;
use ssis_lab::fit::{
    add_term, compare, complete, fit_digest, held_out_many, history_files, pooled, spec_for, version_path,
};
use ssis_lab::model::{did_you_mean, Kind, Model, FOG_VARIABLES};
use ssis_lab::plot::{history_svg, residual_svg, write_svg};
use ssis_lab::replay::replay;
use ssis_lab::session::{read_session, Session};
use ssis_lab::stream::{digest, Source};
use ssis_lab::{report, simulate};

#[derive(Parser)]
#[command(
    name = "ssis-lab",
    version,
    about = "Model lab: fit, diagnose and extend the FOG error model on ground-test sessions"
)]
struct Cli {
    #[command(subcommand)]
    cmd: Cmd,
    #[command(flatten)]
    flags: cli::Flags,
}

#[derive(Subcommand)]
enum Cmd {
    /// Write a new model (version 1) with the given catalog terms and no coefficients.
    Init {
        /// Model file to create (refused if it exists), e.g. model.v1.toml.
        model: PathBuf,
        /// Comma-separated terms (catalog names, `sinusoid:F_HZ`, or expressions).
        #[arg(long, default_value = "bias,scale_factor,misalignment")]
        terms: String,
        /// Reference temperature of the thermal terms, °C.
        #[arg(long, default_value_t = 25.0)]
        t_ref_degc: f64,
        /// Window of the temperature-rate estimate G, s (0: 2 × sample interval, at least 60 s).
        #[arg(long, default_value_t = 0.0)]
        g_window_s: f64,
    },
    /// Fit (or evaluate) the model on a session: residual RMS, max, explained fraction, plots.
    Compare {
        /// Model file.
        #[arg(long)]
        model: PathBuf,
        /// Session CSV (docs/SESSION-FORMAT.md).
        #[arg(long)]
        session: PathBuf,
        /// Use the model's coefficients as they are instead of fitting them.
        #[arg(long)]
        evaluate: bool,
        /// Directory for the residual plots (one SVG per FOG).
        #[arg(long)]
        plots: Option<PathBuf>,
        /// Number of time blocks for the held-out figures.
        #[arg(long, default_value_t = ssis_lab::fit::DEFAULT_BLOCKS)]
        blocks: usize,
    },
    /// Rank the effects the model lacks by held-out F-tests (Benjamini–Hochberg FDR).
    Diagnose {
        /// Model file.
        #[arg(long)]
        model: PathBuf,
        /// Session CSV.
        #[arg(long)]
        session: PathBuf,
        /// False-discovery-rate level.
        #[arg(long, default_value_t = 0.01)]
        level: f64,
        /// Number of time blocks (even ones train, odd ones test).
        #[arg(long, default_value_t = ssis_lab::fit::DEFAULT_BLOCKS)]
        blocks: usize,
    },
    /// Add a term, refit, write the next model version (never overwrites) and show the history.
    Add {
        /// Catalog name, `sinusoid:F_HZ`, or an expression over session columns.
        term: String,
        /// Model file (any version; the next version is written beside it as STEM.vN.toml).
        #[arg(long)]
        model: PathBuf,
        /// Session CSV.
        #[arg(long)]
        session: PathBuf,
        /// Number of time blocks.
        #[arg(long, default_value_t = ssis_lab::fit::DEFAULT_BLOCKS)]
        blocks: usize,
    },
    /// Write the calibration table the firmware loads (TOML and/or binary) from a fitted model.
    Export {
        /// Fitted model file.
        #[arg(long)]
        model: PathBuf,
        /// Table whose other fields (geometry, star tracker, observer) are kept; default: the nominal table.
        #[arg(long)]
        base: Option<PathBuf>,
        /// TOML table to write.
        #[arg(long)]
        toml: Option<PathBuf>,
        /// Binary table to write.
        #[arg(long)]
        bin: Option<PathBuf>,
    },
    /// One self-contained HTML page: fit, diagnosis, history and residual plots.
    Report {
        /// Model file.
        #[arg(long)]
        model: PathBuf,
        /// Session CSV.
        #[arg(long)]
        session: PathBuf,
        /// HTML file to write.
        #[arg(long)]
        out: PathBuf,
    },
    /// Replay a session through the flight core (FlightCore::step) with a calibration table:
    /// the core's body-rate error against the session's reference.
    Replay {
        /// Session CSV with equally spaced rows (one core step per row).
        #[arg(long)]
        session: PathBuf,
        /// Calibration table, binary (.bin) or TOML; default: the nominal table (no error terms).
        #[arg(long)]
        table: Option<PathBuf>,
    },
    /// Turn a log into a session file: a raw capture of the output link (its output frames;
    /// the body rate is the measurement, bad frames are counted), the per-step CSV of
    /// ssis-qemu / ssis-sim (the attitude is the measurement, the truth the reference), or a
    /// logger's own CSV mapped column by column (--map).
    Import {
        /// What the log is.
        kind: LogKind,
        /// The log file.
        log: PathBuf,
        /// Session CSV to write.
        #[arg(long)]
        out: PathBuf,
        /// csv only: a session column from a logger's column, TARGET=SOURCE:UNIT
        /// (fog0_rad_s=gyro_x:deg/s; counts as SCALE*UNIT: fog1_rad_s=gy:0.00875*deg/s);
        /// repeat per column (docs/SESSION-FORMAT.md).
        #[arg(long = "map")]
        map: Vec<String>,
        /// Capture, csv: azimuth of X_P from north (clockwise) of the turntable, rad.
        #[arg(long, allow_negative_numbers = true)]
        psi_rad: Option<f64>,
        /// Capture, csv: latitude, rad.
        #[arg(long, allow_negative_numbers = true)]
        lat_rad: Option<f64>,
        /// Capture, csv: table rate about Z_P (up), rad/s.
        #[arg(long, default_value_t = 0.0, allow_negative_numbers = true)]
        table_rate_rad_s: f64,
    },
    /// Write a simulated session with a known hidden effect (for trying the lab).
    Simulate {
        /// magnetic, thermal, asymmetry, sin2psi, flight or replay.
        preset: String,
        /// CSV file to write.
        out: PathBuf,
        /// Random seed.
        #[arg(long, default_value_t = 1)]
        seed: u64,
        /// Leave the hidden effect out.
        #[arg(long)]
        no_hidden: bool,
        /// The Earth field at the site (Kharkov): `wmm` (WMM2025 on 2025-001, the real field)
        /// or `paper` (the paper's dipole tilt, to reproduce its example).
        #[arg(long, default_value = "wmm", value_parser = ["wmm", "paper"])]
        field: String,
    },
}

/// Kinds of firmware log `import` reads.
#[derive(Clone, Copy, clap::ValueEnum)]
enum LogKind {
    /// Raw bytes of the output link.
    Capture,
    /// The per-step CSV of ssis-qemu / ssis-sim run --csv.
    QemuCsv,
    /// A logger's CSV with its own column names and units, mapped by --map.
    Csv,
}

fn dh(v: f64) -> f64 {
    v * DEG_H_PER_RAD_S
}

fn load_session(path: &Path) -> Result<Session> {
    let pb = bytes_bar(path, "reading");
    let s = read_session(path, Some(&pb));
    pb.finish_and_clear();
    s.context("session refused")
}

/// A progress bar over the bytes of a session file.
fn bytes_bar(path: &Path, what: &str) -> ProgressBar {
    let pb = ProgressBar::new(0).with_style(
        ProgressStyle::with_template("{prefix} {msg} {bar:30} {bytes}/{total_bytes} {bytes_per_sec}")
            .expect("template"),
    );
    pb.set_prefix(what.to_string());
    pb.set_message(path.display().to_string());
    pb
}

/// Runs `f` with a progress bar over the file's bytes; the error says the session was refused.
fn pass<T>(path: &Path, what: &str, f: impl FnOnce(&ProgressBar) -> ssis_lab::LabResult<T>) -> Result<T> {
    let pb = bytes_bar(path, what);
    let out = f(&pb);
    pb.finish_and_clear();
    out.with_context(|| format!("{what} {}", path.display()))
}

/// Prints what the figures do not say about the session (to stderr: the figures stay on
/// stdout).
fn notes(notes: &[String]) {
    for n in notes {
        eprintln!("note: {n}");
    }
}

fn load_model(path: &Path) -> Result<Model> {
    Model::read(path).context("model refused")
}

fn spinner(msg: &str) -> ProgressBar {
    let pb = ProgressBar::new_spinner();
    pb.set_message(msg.to_string());
    pb.enable_steady_tick(Duration::from_millis(120));
    pb
}

fn print_diagnosis(d: &Diagnosis) {
    println!(
        "held-out blocks: {} training samples, {} test samples; Benjamini-Hochberg at {} %",
        d.n_train,
        d.n_test,
        100.0 * d.fdr_level
    );
    println!(
        "{:>4}  {:<34} {:>10}  {:>12} {:>12} {:>7}  {:>27}  origin",
        "rank", "candidate", "p", "before °/h", "after °/h", "drop", "removed °/h (1σ)"
    );
    for (r, c) in d.candidates.iter().enumerate() {
        let (rm, lo, hi) = c.removed_rad_s();
        println!(
            "{:>4}  {:<34} {:>10.2e}  {:>12.5} {:>12.5} {:>6.1}%  {:>9.5} [{:.5}, {:.5}]  {}{}",
            r + 1,
            c.kind.label(),
            c.p_value,
            dh(c.before_rad_s),
            dh(c.after_rad_s),
            100.0 * (1.0 - c.after_rad_s / c.before_rad_s),
            dh(rm),
            dh(lo),
            dh(hi),
            c.origin,
            if c.significant { "  ** significant" } else { "" }
        );
    }
    println!(
        "p: the larger of the GLS F-test's and the held-out direction test's under each FOG's noise model \
         (white + Gauss-Markov, fitted on the cross-fitted residual of every block); removed: √(before² − after²)"
    );
    for (k, why) in &d.skipped {
        println!("      {k:<34} not tested: {why}");
    }
    for c in &d.candidates {
        for (fog, why) in &c.untested {
            println!("      {:<34} FOG{fog}: {why}", c.kind.label());
        }
    }
    match d.significant().next() {
        None => println!("no significant missing effect (level {} %)", 100.0 * d.fdr_level),
        Some(c) => {
            println!("most significant missing effect: {}  (ssis-lab add '{}' ...)", c.kind.label(), arg_of(&c.kind))
        }
    }
    for a in &d.anova {
        println!(
            "FOG{} two-factor ANOVA, T × G (paper Tables 1-2), {} cells, T levels cut at {:.1}/{:.1} °C, G at {:.4}/{:.4} °C/min:",
            a.fog,
            a.cells,
            a.t_edges_degc[0],
            a.t_edges_degc[1],
            a.g_edges_degc_s[0] * 60.0,
            a.g_edges_degc_s[1] * 60.0
        );
        for (name, f) in [("F_T ", a.f_t), ("F_G ", a.f_g), ("F_TG", a.f_tg)] {
            println!(
                "    {name} = {:>9.2}  (ν {}, {})  p {:.2e}  critical 5 % {:.2}, 1 % {:.2}",
                f.0,
                f.1,
                f.2,
                f.3,
                f_critical(0.05, f.1, f.2),
                f_critical(0.01, f.1, f.2)
            );
        }
    }
    for line in anova_beside_main(d) {
        println!("{line}");
    }
    for line in d.detectable.lines() {
        println!("{line}");
    }
}

fn arg_of(k: &Kind) -> String {
    match k {
        Kind::Catalog(c) => c.name().to_string(),
        Kind::Sinusoid(f) => format!("sinusoid:{f:e}"),
        Kind::Expr(e) => e.clone(),
    }
}

/// One model version on a session: version, pooled held-out RMS °/h, per FOG °/h, terms.
type HistoryRow = (u32, f64, Vec<f64>, String);

/// Every version of the model on the session (one pass for all of them).
fn history(model_path: &Path, session: &Path, blocks: usize) -> Result<Vec<HistoryRow>> {
    let files = history_files(model_path);
    let models = files.iter().map(|(_, p)| load_model(p)).collect::<Result<Vec<_>>>()?;
    let rms = pass(session, "history on", |pb| held_out_many(&models, Source::File(session), blocks, Some(pb)))?;
    Ok(files
        .iter()
        .zip(&models)
        .zip(rms)
        .map(|(((v, _), m), r)| {
            let terms = m.kinds().iter().map(|k| k.label()).collect::<Vec<_>>().join(", ");
            (*v, dh(pooled(&r)), r.iter().map(|x| dh(*x)).collect(), terms)
        })
        .collect())
}

fn main() -> ExitCode {
    ssis_lab::session::exit_plainly_on_truncated_map();
    let cli = Cli::parse();
    let started = cli.flags.start("ssis-lab").and_then(|()| files(&cli.cmd));
    let force = cli.flags.force;
    cli::finish_unit(started.and_then(|()| run(cli.cmd, force)))
}

/// Registers the command's inputs and claims its outputs (`ssis_common::output`): a
/// refusal comes before any work. Plots at derived names are replaced when they are ours.
fn files(cmd: &Cmd) -> Result<()> {
    let svg = |p: &Path, title: &str| output::claim(p, Origin::Default(Own::Svg(title.into())));
    let named = |p: &Path| output::claim(p, Origin::Named);
    let inputs = |paths: &[&Path]| paths.iter().for_each(|p| output::input(p));
    // Every version of the model is read (the history).
    let versions = |model: &Path| history_files(model).iter().for_each(|(_, p)| output::input(p));
    let name = match cmd {
        Cmd::Init { model, .. } => output::claim(model, Origin::New).map(|()| "init")?,
        Cmd::Compare { model, session, plots, .. } => {
            inputs(&[model, session]);
            for (i, d) in (0..4).flat_map(|i| plots.iter().map(move |d| (i, d))) {
                svg(&d.join(format!("residual-fog{i}.svg")), &format!(": FOG{i} residual, °/h"))?;
            }
            "compare"
        }
        Cmd::Diagnose { model, session, .. } => {
            inputs(&[model, session]);
            "diagnose"
        }
        Cmd::Add { model, session, .. } => {
            inputs(&[model, session]);
            versions(model);
            let stem = ssis_lab::fit::model_stem(model);
            svg(&model.with_file_name(format!("{stem}.history-fogs.svg")), "held-out RMS per FOG on ")?;
            let h = model.with_file_name(format!("{stem}.history.svg"));
            svg(&h, "held-out RMS on ").map(|()| "add")?
        }
        Cmd::Export { model, base, toml, bin } => {
            inputs(&[model]);
            // `--toml` onto `--base` updates that table in place, as `ssis-cal --table` does.
            let in_place = toml.as_deref().filter(|t| base.as_deref().is_some_and(|b| same_file(b, t)));
            match in_place {
                Some(t) => output::update(t)?,
                None => base.iter().for_each(|b| output::input(b)),
            }
            toml.iter().filter(|_| in_place.is_none()).chain(bin).try_for_each(|p| named(p)).map(|()| "export")?
        }
        Cmd::Report { model, session, out } => {
            inputs(&[model, session]);
            versions(model);
            named(out).map(|()| "report")?
        }
        Cmd::Replay { session, table } => {
            inputs(&[session]);
            table.iter().for_each(|t| output::input(t));
            "replay"
        }
        Cmd::Import { log, out, .. } => {
            inputs(&[log]);
            named(out).map(|()| "import")?
        }
        Cmd::Simulate { out, .. } => named(out).map(|()| "simulate")?,
    };
    cli::report("command", || json!(name));
    Ok(())
}

/// Whether two paths name one existing file (however spelt).
fn same_file(a: &Path, b: &Path) -> bool {
    matches!((a.canonicalize(), b.canonicalize()), (Ok(x), Ok(y)) if x == y)
}

/// One subcommand, one function (`force`: `--force`).
fn run(cmd: Cmd, force: bool) -> Result<()> {
    match cmd {
        Cmd::Init { model, terms, t_ref_degc, g_window_s } => init(model, terms, t_ref_degc, g_window_s),
        Cmd::Compare { model, session, evaluate, plots, blocks } => {
            compare_cmd(model, session, evaluate, plots, blocks)
        }
        Cmd::Diagnose { model, session, level, blocks } => diagnose_cmd(model, session, level, blocks),
        Cmd::Add { term, model, session, blocks } => add_cmd(term, model, session, blocks, force),
        Cmd::Export { model, base, toml, bin } => export_cmd(model, base, toml, bin),
        Cmd::Report { model, session, out } => report_cmd(model, session, out),
        Cmd::Replay { session, table } => replay_cmd(session, table),
        Cmd::Import { kind, log, out, map, psi_rad, lat_rad, table_rate_rad_s } => {
            let table = psi_rad.zip(lat_rad).map(|(psi_rad, lat_rad)| ssis_lab::framelog::Turntable {
                psi_rad,
                lat_rad,
                table_rate_rad_s,
            });
            import_cmd(kind, log, out, &map, table)
        }
        Cmd::Simulate { preset, out, seed, no_hidden, field } => simulate_cmd(preset, out, seed, no_hidden, &field),
    }
}

/// The column names of a CSV session (its first line that is not a `#` comment); none for
/// another format (a capture).
fn session_columns(path: &Path) -> Vec<String> {
    use std::io::BufRead;
    let Ok(f) = std::fs::File::open(path) else { return Vec::new() };
    let header = std::io::BufReader::new(f).lines().map_while(|l| l.ok()).find(|l| !l.starts_with('#'));
    match header {
        Some(h) if h.is_ascii() && h.contains(',') => {
            h.trim_start_matches('\u{feff}').split(',').map(|c| c.trim().to_string()).collect()
        }
        _ => Vec::new(),
    }
}

/// A command-line term, checked before any work: a name close to a catalog term is a typo
/// (refused with the catalog and the nearest name, not taken as an expression), and with a
/// CSV `session` every variable of an expression must be one of its columns or a per-FOG
/// variable.
fn checked_term(arg: &str, session: Option<&Path>) -> Result<Kind> {
    use exmex::Express;
    let kind = Kind::parse_arg(arg)?;
    let Kind::Expr(e) = &kind else { return Ok(kind) };
    let catalog = ssis_lab::model::catalog_names();
    let bare = !arg.is_empty() && arg.chars().all(|c| c.is_ascii_alphanumeric() || c == '_');
    let columns = session.map(session_columns).unwrap_or_default();
    let known = |v: &str| FOG_VARIABLES.contains(&v) || columns.iter().any(|c| c == v);
    if bare && !known(arg) {
        let hint = did_you_mean(arg, catalog.split(", "));
        if !hint.is_empty() || !columns.is_empty() {
            bail!(
                "`{arg}` is not a term of the catalog ({catalog}, sinusoid:F_HZ){hint} \
                 (an expression over session columns is a term too)"
            );
        }
    }
    if columns.is_empty() {
        return Ok(kind);
    }
    let parsed = exmex::parse::<f64>(e).map_err(|err| anyhow::anyhow!("`{e}`: {err}"))?;
    if let Some(v) = parsed.var_names().iter().find(|v| !known(v)) {
        let names = columns.iter().map(String::as_str).chain(FOG_VARIABLES).chain(catalog.split(", "));
        bail!(
            "{}: `{v}` in the term `{e}` is not a column of the session ({}) nor a per-FOG variable ({}){}",
            session.map_or(String::new(), |p| p.display().to_string()),
            columns.join(", "),
            FOG_VARIABLES.join(", "),
            did_you_mean(v, names)
        );
    }
    Ok(kind)
}

/// `init`: writes version 1 of a new model (never over an existing file).
fn init(model: PathBuf, terms: String, t_ref_degc: f64, g_window_s: f64) -> Result<()> {
    if model.exists() {
        bail!("{} exists: the lab never overwrites a model", model.display());
    }
    let kinds = terms.split(',').map(|t| checked_term(t.trim(), None)).collect::<Result<Vec<_>>>()?;
    let mut m = Model::new(&kinds);
    m.t_ref_degc = t_ref_degc;
    m.g_window_s = g_window_s;
    m.note = "v1: starting model".into();
    ssis_lab::write_atomic(&model, m.to_toml().as_bytes())?;
    println!("wrote {} (version 1: {terms})", model.display());
    Ok(())
}

/// `compare`: the model fitted (or evaluated) on a session, per FOG and term, with residual plots.
fn compare_cmd(model: PathBuf, session: PathBuf, evaluate: bool, plots: Option<PathBuf>, blocks: usize) -> Result<()> {
    let m = load_model(&model)?;
    let c = pass(&session, "comparing on", |pb| compare(&m, Source::File(&session), evaluate, blocks, Some(pb)))?;
    cli::report("fit", || {
        ssis_lab::json::comparison(&c, &model.display().to_string(), &session.display().to_string(), evaluate)
    });
    let (f, ho) = (&c.fitted, &c.held_out_rad_s);
    notes(&f.notes);
    println!(
        "{} on {} ({} samples, {}): {}",
        model.display(),
        session.display(),
        f.sample.of_rows,
        if evaluate { "evaluated with its coefficients" } else { "fitted on all samples" },
        m.kinds().iter().map(|k| k.label()).collect::<Vec<_>>().join(", ")
    );
    println!(
        "{:>4} {:>14} {:>14} {:>14} {:>10} {:>16}",
        "FOG", "error °/h", "residual °/h", "max °/h", "explained", "held-out °/h"
    );
    for (i, x) in f.summary.iter().enumerate() {
        println!(
            "{i:>4} {:>14.5} {:>14.5} {:>14.5} {:>9.1}% {:>16.5}",
            dh(x.rms_error_rad_s),
            dh(x.rms_residual_rad_s),
            dh(x.max_abs_residual_rad_s),
            100.0 * x.explained,
            dh(ho[i])
        );
    }
    if !f.not_identified.is_empty() {
        println!("not identifiable in this session (left at zero): {}", f.not_identified.join(", "));
    }
    for (t, k) in f.model.kinds().iter().enumerate() {
        for (fog, c) in f.model.terms[t].coef.iter().enumerate() {
            // Engineering units, as `add` prints them (SI stays in the model file and --json).
            let labels = k.regressor_labels(fog);
            let units = k.eng_units(fog);
            let text: Vec<String> = c
                .iter()
                .zip(&labels)
                .zip(&units)
                .map(|((v, (n, _)), (u, f))| format!("{n} = {:.5} {u}", v * f))
                .collect();
            println!("  {:<24} FOG{fog}: {}", k.label(), text.join(", "));
        }
    }
    if let Some(dir) = plots {
        std::fs::create_dir_all(&dir).with_context(|| format!("cannot create {}", dir.display()))?;
        if f.sample.of_rows > f.sample.residual[0].len() {
            println!("plots: {} of the {} samples", f.sample.residual[0].len(), f.sample.of_rows);
        }
        for fog in 0..f.summary.len() {
            let p = dir.join(format!("residual-fog{fog}.svg"));
            write_svg(&p, &residual_svg(&session.display().to_string(), f, fog)?)?;
            println!("wrote {}", p.display());
        }
    }
    Ok(())
}

/// `diagnose`: the candidate missing effects ranked by their held-out F-test.
fn diagnose_cmd(model: PathBuf, session: PathBuf, level: f64, blocks: usize) -> Result<()> {
    let m = load_model(&model)?;
    let opt = Options { n_blocks: blocks, fdr_level: level, ..Options::default() };
    let d = pass(&session, "diagnosing on", |pb| diagnose_with_progress(&m, Source::File(&session), &opt, Some(pb)))?;
    cli::report("diagnosis", || ssis_lab::json::diagnosis(&d));
    notes(&d.notes);
    print_diagnosis(&d);
    Ok(())
}

/// What `add` removed, per FOG: the systematic part √(before² − after²) of the held-out RMS,
/// and the residual (every kept row, the models fitted on all rows) as RMS of 1-s, 100-s and
/// 1000-s means before and after, beside the white-noise floor at that averaging time.
fn print_error_fall(out: &ssis_lab::fit::AddOutcome) {
    use ssis_lab::noise::{allan_deviation, tau_mean_rms};
    let dt = out.kept_dt_s;
    println!("systematic part removed, √(before² − after²) of the held-out RMS, °/h:");
    for (fog, (b, a)) in out.before_rad_s.iter().zip(&out.after_rad_s).enumerate() {
        println!("  FOG{fog} {:.5}", dh((b * b - a * a).max(0.0).sqrt()));
    }
    println!("residual RMS of tau-means, °/h (before -> after; white floor from the Allan deviation at one sample):");
    for (fog, (rb, ra)) in out.residual_before_rad_s.iter().zip(&out.residual_after_rad_s).enumerate() {
        let sigma1 = allan_deviation(ra, dt).first().map_or(f64::NAN, |p| p.1);
        let cells: Vec<String> = [1.0, 100.0, 1000.0]
            .iter()
            .map(|&tau| match (tau_mean_rms(rb, dt, tau), tau_mean_rms(ra, dt, tau)) {
                (Some((t, b)), Some((_, a))) => {
                    format!("{t:>5} s {:.5} -> {:.5} (floor {:.5})", dh(b), dh(a), dh(sigma1 * (dt / t).sqrt()))
                }
                _ => format!("{tau:>5} s -"),
            })
            .collect();
        println!("  FOG{fog} {}", cells.join(" | "));
    }
}

/// `add`: the next model version with one more term, its held-out gain and the history of versions.
fn add_cmd(term: String, model: PathBuf, session: PathBuf, blocks: usize, force: bool) -> Result<()> {
    let m = load_model(&model)?;
    let kind = checked_term(&term, Some(&session))?;
    let mut out = pass(&session, "refitting on", |_| add_term(&m, &kind, Source::File(&session), blocks))?;
    notes(&out.notes);
    let (b, a) = (pooled(&out.before_rad_s), pooled(&out.after_rad_s));
    if a > b && !force {
        bail!(
            "{}: adding {} makes the held-out RMS worse ({:.5} -> {:.5} °/h over {} blocks); no version written \
             (--force writes it anyway)",
            session.display(),
            kind.label(),
            dh(b),
            dh(a),
            blocks
        );
    }
    let newest = history_files(&model).last().map_or(0, |v| v.0).max(m.version);
    if newest > m.version {
        println!("note: {} is version {}, newer versions exist up to {newest}", model.display(), m.version);
    }
    out.model.version = newest + 1;
    out.model.note = format!("v{}: v{} + {}", out.model.version, m.version, kind.label());
    let path = version_path(&model, out.model.version);
    if path.exists() {
        bail!("{} exists: the lab never overwrites a model", path.display());
    }
    // A version that only repeats one that exists (the same terms and coefficients from
    // the same session) is not written.
    let same = |a: &Model, b: &Model| {
        Model { version: 0, note: String::new(), ..a.clone() } == Model { version: 0, note: String::new(), ..b.clone() }
    };
    for (v, p) in history_files(&model) {
        if load_model(&p).is_ok_and(|old| same(&old, &out.model)) {
            bail!(
                "{}: adding {} to {} gives version {v} again ({}): not written",
                session.display(),
                kind.label(),
                model.display(),
                p.display()
            );
        }
    }
    // Written whole (or not at all) before anything is printed: a closed pipe cannot cut it.
    output::claim(&path, Origin::New)?;
    ssis_lab::write_atomic(&path, out.model.to_toml().as_bytes())?;
    cli::report("added", || ssis_lab::json::added(&out, &kind, &path.display().to_string()));
    println!("held-out residual RMS, °/h ({} blocks):", blocks);
    println!("{:>4} {:>12} {:>12} {:>8}", "FOG", "before", "after", "drop");
    for (i, (b, a)) in out.before_rad_s.iter().zip(&out.after_rad_s).enumerate() {
        println!("{i:>4} {:>12.5} {:>12.5} {:>7.1}%", dh(*b), dh(*a), 100.0 * (1.0 - a / b));
    }
    let (b, a) = (pooled(&out.before_rad_s), pooled(&out.after_rad_s));
    println!(" all {:>12.5} {:>12.5} {:>7.1}%", dh(b), dh(a), 100.0 * (1.0 - a / b));
    let t = out.model.terms.len() - 1;
    let first: usize = out.model.terms[..t].iter().map(|x| x.coef.first().map_or(0, Vec::len)).sum();
    for (fog, c) in out.model.terms[t].coef.iter().enumerate() {
        let labels = kind.regressor_labels(fog);
        let units = kind.eng_units(fog);
        let text: Vec<String> = c
            .iter()
            .zip(&labels)
            .zip(&units)
            .enumerate()
            .map(|(m, ((v, (n, _)), (u, f)))| {
                let sd = out.sigma.get(fog).and_then(|s| s.get(first + m)).copied().unwrap_or(f64::NAN);
                format!("{n} = {:.5} ± {:.5} {u} (1σ)", v * f, sd * f)
            })
            .collect();
        println!("  {} FOG{fog}: {}", kind.label(), text.join(", "));
    }
    if !out.not_identified.is_empty() {
        println!("not identifiable in this session (left at zero): {}", out.not_identified.join(", "));
    }
    for w in ssis_lab::export::implausible(&out.model) {
        println!("WARNING: {w}");
    }
    print_error_fall(&out);
    println!("wrote {} (version {})", path.display(), out.model.version);
    let h = history(&path, &session, blocks)?;
    cli::report("history", || {
        json!(h.iter().map(|(v, r, per, terms)| ssis_lab::json::history_row(*v, *r, per, terms)).collect::<Vec<_>>())
    });
    println!("history on {} (held-out RMS, °/h):", session.display());
    for (v, r, per, terms) in &h {
        let per: Vec<String> = per.iter().map(|x| format!("{x:.5}")).collect();
        println!("  v{v:<3} {r:>10.5}  [{}]  {terms}", per.join(" "));
    }
    let curves: Vec<_> = out
        .residual_before_rad_s
        .iter()
        .zip(&out.residual_after_rad_s)
        .map(|(b, a)| {
            (ssis_lab::noise::allan_deviation(b, out.kept_dt_s), ssis_lab::noise::allan_deviation(a, out.kept_dt_s))
        })
        .collect();
    let floor: Vec<f64> = curves.iter().map(|c| c.1.first().map_or(0.0, |p| p.1)).collect();
    let allan_path =
        path.with_file_name(format!("{}.v{}.allan.svg", ssis_lab::fit::model_stem(&path), out.model.version));
    let title = format!("residual before/after {} (dashed/solid), white floor (grey)", kind.label());
    if let Ok(svg) = ssis_lab::plot::allan_svg(&title, &curves, &floor, out.kept_dt_s) {
        match write_svg(&allan_path, &svg) {
            Ok(()) => println!("wrote {}", allan_path.display()),
            Err(e) => println!("not written: {e:#}"),
        }
    }
    let svg_path = path.with_file_name(format!("{}.history.svg", ssis_lab::fit::model_stem(&path)));
    let pts: Vec<(u32, f64)> = h.iter().map(|x| (x.0, x.1)).collect();
    write_svg(&svg_path, &history_svg(&format!("held-out RMS on {}", session.display()), &pts)?)?;
    println!("wrote {}", svg_path.display());
    // Per FOG, with the term each version added and the white floor (pooled σ₁ of the residual).
    let mut rows: Vec<(u32, Vec<f64>, String)> = Vec::new();
    let mut prev: Vec<&str> = Vec::new();
    for (v, _, per, terms) in &h {
        let now: Vec<&str> = terms.split(", ").collect();
        let added: Vec<&str> = now.iter().filter(|t| !prev.contains(t)).copied().collect();
        let label = if prev.is_empty() { "start".to_string() } else { format!("+{}", added.join(" +")) };
        rows.push((*v, per.clone(), label));
        prev = now;
    }
    let floor_deg_h = dh(pooled(&floor));
    let fogs_path = path.with_file_name(format!("{}.history-fogs.svg", ssis_lab::fit::model_stem(&path)));
    let title = format!("held-out RMS per FOG on {}", session.display());
    match ssis_lab::plot::history_fogs_svg(&title, &rows, floor_deg_h).and_then(|svg| write_svg(&fogs_path, &svg)) {
        Ok(()) => println!("wrote {}", fogs_path.display()),
        Err(e) => println!("not written: {e:#}"),
    }
    Ok(())
}

/// `export`: the calibration table the firmware loads, from the model's onboard terms.
fn export_cmd(model: PathBuf, base: Option<PathBuf>, toml: Option<PathBuf>, bin: Option<PathBuf>) -> Result<()> {
    let m = load_model(&model)?;
    if m.fit.is_none() && m.terms.iter().all(|t| t.coef.is_empty()) {
        bail!("{}: the model has no coefficients: fit it first (ssis-lab add or compare)", model.display());
    }
    let base_doc = match &base {
        Some(p) => ssis_common::table::read_doc(p)?,
        None => ssis_common::table::TableDoc::new(ssis::calib::CalibrationTable::DEFAULT),
    };
    let e = to_table(&m, &base_doc.table).with_context(|| format!("{}: nothing written", model.display()))?;
    if toml.is_none() && bin.is_none() {
        bail!("nothing to write: give --toml and/or --bin");
    }
    let origin = update::Origin {
        command: "ssis-lab export".into(),
        session: m.fit.as_ref().map_or_else(|| "(coefficients as written in the model)".into(), |f| f.session.clone()),
        model: Some((model.display().to_string(), m.version)),
    };
    let (doc, changes) = ssis_common::update::apply(&base_doc, &e.table, &e.set, &origin)
        .with_context(|| format!("{}: nothing written", model.display()))?;
    print!("{}", ssis_common::update::report(&base_doc, &doc, &changes, &origin));
    if let Some(p) = &toml {
        ssis_common::table::write_doc(p, &doc)?;
        if base.as_deref().is_some_and(|b| same_file(b, p)) {
            println!("updated {} (revision {})", p.display(), doc.table.revision);
        } else {
            println!("wrote {}", p.display());
        }
    }
    if let Some(p) = &bin {
        ssis_common::table::write_binary(p, &doc.table)?;
        println!("wrote {}", p.display());
    }
    println!("applied onboard: {}", e.applied.join(", "));
    cli::report("export", || {
        let not_applied: Vec<_> = e.not_applied.iter().map(|(k, why)| json!({"term": k, "why": why})).collect();
        let not_identified = m.fit.as_ref().map(|f| f.not_identified.clone()).unwrap_or_default();
        json!({"applied_onboard": e.applied, "not_applied": not_applied, "not_identified": not_identified})
    });
    if let Some(f) = m.fit.as_ref().filter(|f| !f.not_identified.is_empty()) {
        println!(
            "{} could not identify {}: those fields keep the base's values (their constant part is in the bias)",
            f.session,
            f.not_identified.join(", ")
        );
    }
    if e.not_applied.is_empty() {
        println!("every term of the model is applied onboard");
    }
    for (k, why) in &e.not_applied {
        println!("NOT applied onboard: {k}: {why}");
    }
    Ok(())
}

/// `report`: one HTML page of the fit, the diagnosis and the history.
fn report_cmd(model: PathBuf, session: PathBuf, out: PathBuf) -> Result<()> {
    let m = load_model(&model)?;
    let opt = Options::default();
    let versions =
        history_files(&model).iter().map(|(v, p)| load_model(p).map(|m| (*v, m))).collect::<Result<Vec<_>>>()?;
    let (f, d, steps, kept) = pass(&session, "fitting and diagnosing on", |pb| {
        let mut terms = candidate_terms(&Source::File(&session).header()?);
        terms.extend(versions.iter().flat_map(|(_, v)| v.kinds()));
        let dg = digest(Source::File(&session), &spec_for(&m, &terms, opt.n_blocks), Some(pb))?;
        let kept = ssis_lab::fit::KeptTimes { t_s: dg.kept.t_s.clone(), dt_s: dg.dt_s * dg.kept.stride.max(1) as f64 };
        let steps = ssis_lab::fit::add_steps(&versions, &dg)?;
        Ok((complete(fit_digest(&m, &dg)?, Source::File(&session), &dg)?, diagnose_digest(&m, &dg, &opt)?, steps, kept))
    })?;
    let h: Vec<(u32, f64)> =
        history(&model, &session, ssis_lab::fit::DEFAULT_BLOCKS)?.iter().map(|x| (x.0, x.1)).collect();
    let page = report::render(&session.display().to_string(), &f, &d, &h, &steps, &kept)?;
    ssis_lab::write_atomic(&out, page.as_bytes())?;
    println!("wrote {}", out.display());
    Ok(())
}

/// `replay`: the session through the flight core with a table, and the body-rate error.
fn replay_cmd(session: PathBuf, table: Option<PathBuf>) -> Result<()> {
    let s = load_session(&session)?;
    let t = match &table {
        Some(p) if p.extension().is_some_and(|e| e == "bin") => ssis_common::table::read_binary(p)?,
        Some(p) => ssis_common::table::read_toml(p)?,
        None => ssis::calib::CalibrationTable::DEFAULT,
    };
    let pb = spinner("replaying through the flight core");
    let r = replay(&s, &t);
    pb.finish_and_clear();
    let r = r.with_context(|| format!("cannot replay {}", session.display()))?;
    let n = r.error_rad_s.len() as f64;
    let axis = |a: usize| dh((r.error_rad_s.iter().map(|e| e[a] * e[a]).sum::<f64>() / n).sqrt());
    cli::report("replay", || {
        json!({
            "steps": r.error_rad_s.len(),
            "step_s": f64::from(r.dt_us) * 1e-6,
            "body_rate_error_rms_deg_h": [axis(0), axis(1), axis(2)],
            "body_rate_error_rms_norm_deg_h": dh(r.rms_error_rad_s(None)),
            "steps_degraded": r.steps_degraded,
            "frames_out": r.frames_out,
            "frames_out_bad": r.frames_out_bad,
        })
    });
    println!(
        "{} through FlightCore::step() with {} ({} steps of {} s, {} FOGs)",
        s.file,
        table.as_ref().map_or("the nominal table".to_string(), |p| p.display().to_string()),
        r.error_rad_s.len(),
        f64::from(r.dt_us) * 1e-6,
        r.profile.fogs.count()
    );
    println!(
        "body rate error RMS, °/h: x {:.5}  y {:.5}  z {:.5}  |e| {:.5}",
        axis(0),
        axis(1),
        axis(2),
        dh(r.rms_error_rad_s(None))
    );
    println!(
        "steps with a FOG not used: {}; output frames {} ({} bad)",
        r.steps_degraded, r.frames_out, r.frames_out_bad
    );
    Ok(())
}

/// `import`: a firmware log or a logger's CSV written as a session.
fn import_cmd(
    kind: LogKind,
    log: PathBuf,
    out: PathBuf,
    map: &[String],
    table: Option<ssis_lab::framelog::Turntable>,
) -> Result<()> {
    let (s, axes) = match kind {
        LogKind::Capture => {
            let Some(t) = table else {
                bail!("a capture of the output link has no reference: give --psi-rad and --lat-rad (and --table-rate-rad-s if the table turns)");
            };
            let (s, rep) = ssis_lab::framelog::read_output_capture(&log, &t).context("log refused")?;
            println!("{rep}");
            (s, ", body axes as fog0..fog2")
        }
        LogKind::QemuCsv => {
            let (s, rep) = ssis_lab::framelog::read_qemu_csv(&log).context("log refused")?;
            println!("{rep}");
            (s, ", body axes as fog0..fog2")
        }
        LogKind::Csv => {
            let maps = map.iter().map(|m| ssis_lab::import::Mapping::parse(m)).collect::<Result<Vec<_>, _>>()?;
            let (s, rep) = ssis_lab::import::read_logger_csv(&log, &maps, table.as_ref()).context("log refused")?;
            println!("{rep}");
            (s, "")
        }
    };
    ssis_lab::write_atomic(&out, ssis_lab::session::session_csv(&s).as_bytes())?;
    println!("wrote {} ({} samples{axes})", out.display(), s.len());
    Ok(())
}

/// `simulate`: a session of a preset with known effects.
fn simulate_cmd(preset: String, out: PathBuf, seed: u64, no_hidden: bool, field: &str) -> Result<()> {
    let Some(mut spec) = simulate::preset(&preset, seed, !no_hidden) else {
        bail!("unknown preset `{preset}`: magnetic, thermal, asymmetry, sin2psi, flight, replay");
    };
    spec.field = if field == "paper" {
        ssis_lab::session::FieldModel::PaperDipole
    } else {
        ssis_lab::session::FieldModel::Wmm2025
    };
    let sim = simulate::generate(&spec);
    sim.write_csv(&out)?;
    println!(
        "wrote {} ({} rows, {} s samples, white-noise floor {:.4} °/h, hidden effect {:?}{})",
        out.display(),
        sim.rows.len(),
        spec.dt_s,
        dh(sim.truth.noise_rad_s),
        spec.hidden,
        if spec.field_columns {
            let b = simulate::b0_nwu_nt(spec.field);
            format!(", {} field ({:.0}, {:.0}, {:.0}) nT north, west, up", spec.field.name(), b[0], b[1], b[2])
        } else {
            String::new()
        }
    );
    Ok(())
}
