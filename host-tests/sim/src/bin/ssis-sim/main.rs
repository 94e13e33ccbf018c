//! `ssis-sim`: run scenarios through the flight core on the host, handle calibration
//! tables, compute observer gains, measure replay speed. `ssis-sim --help` for all.

use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

use anyhow::Result;
use clap::{Parser, Subcommand};
use indicatif::{ProgressBar, ProgressStyle};
use ssis::calib::{store, CalibrationTable, Estimator, ObserverConfig};
use ssis::observer::steady_state_gains;
use ssis_common::cli::{self, json};
use ssis_common::output::{self, Origin};
use ssis_common::table;
use ssis_sim::accuracy::CSV_HEADER;
use ssis_sim::harness::run_until;
use ssis_sim::scenario::Scenario;

mod replay;

#[derive(Parser)]
#[command(name = "ssis-sim", version, about = "Host simulator and tools for the ssis flight core")]
struct Cli {
    #[command(subcommand)]
    cmd: Cmd,
    #[command(flatten)]
    flags: cli::Flags,
}

#[derive(Subcommand)]
enum Cmd {
    /// Run a scenario through the flight core (frames byte by byte through mock links)
    /// and print a summary of its errors against truth.
    Run {
        /// Scenario file (TOML), e.g. scenarios/earth-pointing-2h.toml
        scenario: PathBuf,
        /// Write one CSV row per N steps to this file.
        #[arg(long)]
        csv: Option<PathBuf>,
        /// Steps per CSV row.
        #[arg(long, default_value_t = 20)]
        every: u64,
        /// Run a scenario longer than 30 days of simulated time.
        #[arg(long)]
        allow_long: bool,
        /// The estimator that flies, replacing the scenario's: `luenberger` (the paper's
        /// eq. 6 observer) or `mekf`.
        #[arg(long, value_parser = ssis_sim::scenario::parse_estimator)]
        estimator: Option<Estimator>,
    },
    /// Replay a recorded log (docs/RECORDED-LOG.md: a CSV, or raw captures of the links)
    /// through the flight core: the summary against truth where the log has it, and the
    /// unit's own evidence; damage in the log is counted and reported, never fatal unless
    /// nothing usable remains. Exit status 1 when `--check` finds something.
    Replay {
        /// The log: one CSV file, or one or more raw captures (FOG bus, star tracker).
        #[arg(required = true)]
        log: Vec<PathBuf>,
        /// The unit's calibration table (.toml, .bin or .img; default: the nominal table).
        #[arg(long)]
        table: Option<PathBuf>,
        /// Statistics start this long after the log's first sample, s.
        #[arg(long, default_value_t = 60.0)]
        settle: f64,
        /// Write one CSV row per N output frames with truth (as `run --csv`).
        #[arg(long)]
        csv: Option<PathBuf>,
        /// Output frames per CSV row.
        #[arg(long, default_value_t = 20)]
        every: u64,
        /// Write a plot of the attitude error (needs truth in the log).
        #[arg(long)]
        plot: Option<PathBuf>,
        /// The consistency check instead of the replay: each FOG's apparent polarity,
        /// channel and scale relative to the table, from the star tracker and the parity
        /// residual (spacecraft logs).
        #[arg(long)]
        check: bool,
        /// Launch-vehicle log: the pad initialisation block (`SSPI`, docs/LAUNCH-VEHICLE.md)
        /// to start from, in place of the log's `init_*` columns (a capture has none).
        #[arg(long)]
        pad: Option<PathBuf>,
    },
    /// Write a recorded log (docs/RECORDED-LOG.md) of a launch-vehicle ascent scenario
    /// (`kind = "lv-ascent"`): the frames its sensors send, as numbers that give the same
    /// frames back, the GNSS fixes, truth and the initial state.
    Record {
        /// Scenario file (TOML), e.g. scenarios/lv-ascent.toml
        scenario: PathBuf,
        /// Output CSV; refused if it exists (unless --force).
        out: PathBuf,
        /// Seconds from lift-off (default: the scenario's duration).
        #[arg(long)]
        duration: Option<f64>,
        /// Truth on every N-th row (the last row always has it).
        #[arg(long, default_value_t = 1)]
        truth_every: u64,
        /// Only the time and the increments per sensor (no counters, temperatures or
        /// status: a smaller file).
        #[arg(long)]
        compact: bool,
    },
    /// Calibration-table tools.
    Table {
        #[command(subcommand)]
        cmd: TableCmd,
    },
    /// Command-key tools (the key of the unit's command link, docs/ICD.md Telecommand).
    Key {
        #[command(subcommand)]
        cmd: KeyCmd,
    },
    /// Steady-state observer gains for noise figures (defaults: the paper's sensors).
    Gains {
        /// Angle random walk, °/√h.
        #[arg(long, default_value_t = 0.005)]
        arw: f64,
        /// Rate random walk, °/h/√h.
        #[arg(long, default_value_t = 0.01)]
        rrw: f64,
        /// Star-tracker noise 1σ, arcsec.
        #[arg(long, default_value_t = 20.0 / 3.0)]
        st_sigma: f64,
        /// Star-tracker period, s.
        #[arg(long, default_value_t = 0.25)]
        st_period: f64,
    },
}

#[derive(Subcommand)]
enum TableCmd {
    /// Write the default table (nominal geometry, the paper's observer figures) as TOML.
    New {
        /// Output file (.toml); refused if it exists (unless --force).
        out: PathBuf,
    },
    /// Convert a TOML table to the binary form the firmware loads.
    ToBin {
        /// Input TOML.
        input: PathBuf,
        /// Output binary.
        out: PathBuf,
    },
    /// Convert a TOML table to the flash image of the table region (two copies), what the
    /// QEMU board loads at its CALIB region (the ELF's `_calib_start`).
    ToImage {
        /// Input TOML.
        input: PathBuf,
        /// Output image.
        out: PathBuf,
    },
    /// Print a table (TOML, binary or image) as TOML after checking it.
    Show {
        /// Table file (.toml, .bin or .img).
        input: PathBuf,
    },
    /// Compare two tables (any form) field by field in engineering units. Exit status as
    /// diff(1): 0 identical, 1 different, 2 trouble (a table unreadable or refused).
    Diff {
        /// Table A (.toml, .bin or .img).
        a: PathBuf,
        /// Table B.
        b: PathBuf,
    },
    /// Turn a table into the telecommands that upload and activate it in flight: 8
    /// TABLE_CHUNK, TABLE_ARM, TABLE_FIRE (98-byte frames, sealed under the key, sequence
    /// numbers from --seq), written one after the other to --out.
    UploadCmds {
        /// Table file (.toml, .bin or .img); checked as the unit checks it.
        input: PathBuf,
        /// Key file (`ssis-sim key new`).
        #[arg(long)]
        key: PathBuf,
        /// Sequence number of the first telecommand: above the last one the unit
        /// accepted (its command report's `last_seq`).
        #[arg(long)]
        seq: u32,
        /// Output file of the telecommand frames.
        #[arg(long)]
        out: PathBuf,
    },
}

#[derive(Subcommand)]
enum KeyCmd {
    /// Make a new random key (from the operating system) and write it as a key file.
    New {
        /// Key file to write (refused if it exists; readable by its owner only).
        out: PathBuf,
        /// Key id (≥ 1), reported in the unit's command report.
        #[arg(long, default_value_t = 1)]
        id: u16,
    },
    /// Write a key's record for the unit's protected KEY region (44 bytes; the QEMU
    /// runner loads it at the ELF's `_key_start`).
    ToImage {
        /// Key file.
        key: PathBuf,
        /// Output image.
        out: PathBuf,
    },
}

/// Set by the SIGINT handler: end the run after this step.
static INTERRUPTED: AtomicBool = AtomicBool::new(false);

/// Ctrl-C: ask the run to stop (async-signal-safe: one atomic store).
extern "C" fn on_sigint(_: libc::c_int) {
    INTERRUPTED.store(true, Ordering::Relaxed);
}

/// Installs [`on_sigint`] for SIGINT (Ctrl-C) for the rest of the process.
fn stop_on_ctrl_c() {
    // SAFETY: a handler that only stores to an atomic, installed with an emptied mask.
    unsafe {
        let mut sa: libc::sigaction = std::mem::zeroed();
        sa.sa_sigaction = on_sigint as extern "C" fn(libc::c_int) as usize;
        libc::sigemptyset(&mut sa.sa_mask);
        libc::sigaction(libc::SIGINT, &sa, std::ptr::null_mut());
    }
}

/// Exit status of a run a source delivered nothing to (its summary has no figure).
const EXIT_SILENT_SOURCE: u8 = 3;
/// Exit status of a run ended by Ctrl-C (128 + SIGINT, as a shell reports it).
const EXIT_INTERRUPTED: u8 = 130;

/// How a run ended, when it ran to its end without an error.
enum RunEnd {
    Complete,
    SilentSource,
    Interrupted,
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    if let Err(e) = cli.flags.start("ssis-sim").and_then(|()| files(&cli.cmd)) {
        return cli::finish_unit(Err(e));
    }
    match cli.cmd {
        Cmd::Table { cmd: TableCmd::Diff { a, b } } => {
            // Exit status as diff(1): 0 identical, 1 different, 2 trouble.
            let r = table_diff(&a, &b);
            let code = match &r {
                Ok(true) => 0,
                Ok(false) => 1,
                Err(_) => 2,
            };
            let _ = cli::finish(r.map(|_| true));
            ExitCode::from(code)
        }
        Cmd::Run { scenario, csv, every, allow_long, estimator } => {
            stop_on_ctrl_c();
            let r = run_scenario(&scenario, csv, every.max(1), allow_long, estimator);
            let code = match &r {
                Ok(RunEnd::SilentSource) => Some(EXIT_SILENT_SOURCE),
                Ok(RunEnd::Interrupted) => Some(EXIT_INTERRUPTED),
                _ => None,
            };
            let exit = cli::finish(r.map(|e| matches!(e, RunEnd::Complete)));
            code.map_or(exit, ExitCode::from)
        }
        Cmd::Replay { log, table, settle, csv, every, plot, check, pad } => {
            let r = replay::run(&replay::Args { log, table, settle, csv, every: every.max(1), plot, check, pad });
            cli::finish(r)
        }
        cmd => cli::finish_unit(real_main(cmd)),
    }
}

/// Registers the command's inputs and claims its outputs (`ssis_common::output`): a
/// refusal comes before any work.
fn files(cmd: &Cmd) -> Result<()> {
    let (name, inputs, out): (&str, [Option<&Path>; 2], Option<&Path>) = match cmd {
        Cmd::Run { scenario, csv, .. } => ("run", [Some(scenario), None], csv.as_deref()),
        Cmd::Table { cmd: TableCmd::New { out } } => ("table new", [None, None], Some(out)),
        Cmd::Table { cmd: TableCmd::ToBin { input, out } } => ("table to-bin", [Some(input), None], Some(out)),
        Cmd::Table { cmd: TableCmd::ToImage { input, out } } => ("table to-image", [Some(input), None], Some(out)),
        Cmd::Table { cmd: TableCmd::Show { input } } => ("table show", [Some(input), None], None),
        Cmd::Table { cmd: TableCmd::Diff { a, b } } => ("table diff", [Some(a), Some(b)], None),
        Cmd::Table { cmd: TableCmd::UploadCmds { input, key, out, .. } } => {
            ("table upload-cmds", [Some(input), Some(key)], Some(out))
        }
        Cmd::Key { cmd: KeyCmd::New { out, .. } } => {
            cli::report("command", || json!("key new"));
            return output::claim(out, Origin::New);
        }
        Cmd::Key { cmd: KeyCmd::ToImage { key, out } } => ("key to-image", [Some(key), None], Some(out)),
        Cmd::Gains { .. } => ("gains", [None, None], None),
        Cmd::Record { scenario, out, .. } => ("record", [Some(scenario), None], Some(out)),
        Cmd::Replay { log, table, csv, plot, pad, .. } => {
            cli::report("command", || json!("replay"));
            for p in log.iter().chain(table).chain(pad) {
                output::input(p);
            }
            for p in [csv, plot].into_iter().flatten() {
                output::claim(p, Origin::Named)?;
            }
            return Ok(());
        }
    };
    cli::report("command", || json!(name));
    for p in inputs.into_iter().flatten() {
        output::input(p);
    }
    match out {
        Some(p) => output::claim(p, Origin::Named),
        None => Ok(()),
    }
}

fn real_main(cmd: Cmd) -> Result<()> {
    match cmd {
        Cmd::Run { scenario, csv, every, allow_long, estimator } => {
            run_scenario(&scenario, csv, every.max(1), allow_long, estimator).map(|_| ())
        }
        Cmd::Replay { .. } => Ok(()),
        Cmd::Record { scenario, out, duration, truth_every, compact } => {
            replay::record(&scenario, &out, duration, truth_every, compact)
        }
        Cmd::Table { cmd } => table_cmd(cmd),
        Cmd::Key { cmd } => key_cmd(cmd),
        Cmd::Gains { arw, rrw, st_sigma, st_period } => {
            let cfg = ObserverConfig {
                arw_deg_sqrt_h: arw,
                rrw_deg_h_sqrt_h: rrw,
                st_sigma_arcsec: st_sigma,
                st_period_s: st_period,
                ..ObserverConfig::PAPER
            };
            let g = steady_state_gains(&cfg).map_err(|e| anyhow::anyhow!("no gains: {e:?}"))?;
            cli::report("gains", || json!({"k_b": g.k_b[0], "k_u_per_s": g.k_u_per_s[0], "st_period_s": st_period}));
            println!("K_B = {:.6}  K_U = {:.6e} /s  (per update, every {st_period} s)", g.k_b[0], g.k_u_per_s[0]);
            Ok(())
        }
    }
}

/// Runs a scenario: the summary, a CSV with `--csv`; how it ended (a source that
/// delivered nothing, Ctrl-C: the partial summary, no CSV and no `.partial` file left).
fn run_scenario(
    path: &Path,
    csv: Option<PathBuf>,
    every: u64,
    allow_long: bool,
    estimator: Option<Estimator>,
) -> Result<RunEnd> {
    let mut sc = Scenario::from_file_with(path, allow_long)?;
    if estimator.is_some() {
        sc.table.estimator = estimator;
    }
    let dt = sc.profile.profile().dt_s();
    let steps = (sc.duration_s / dt).round() as u64;
    let bar = ProgressBar::new(steps);
    bar.set_style(
        ProgressStyle::with_template("{msg} [{bar:40}] {percent}% {eta} left")
            .unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    bar.set_message(sc.name.clone());
    let mut writer = match &csv {
        Some(p) => Some(csv::Writer::from_writer(output::create(p)?)),
        None => None,
    };
    if let Some(w) = writer.as_mut() {
        w.write_record(CSV_HEADER)?;
    }
    let started = Instant::now();
    let mut n = 0u64;
    let mut csv_err = None;
    let summary = run_until(
        &sc,
        || INTERRUPTED.load(Ordering::Relaxed),
        |r| {
            n += 1;
            if n.is_multiple_of(2000) {
                bar.set_position(n);
            }
            if let Some(w) = writer.as_mut() {
                if n.is_multiple_of(every) && csv_err.is_none() {
                    if let Err(e) = w.write_record(r.csv_row()) {
                        csv_err = Some(e);
                    }
                }
            }
        },
    );
    bar.finish_and_clear();
    let interrupted = summary.as_ref().is_ok_and(|s| s.stopped_at_step.is_some());
    // A CSV is kept only from a run that ended well; otherwise its temporary file goes
    // with the writer.
    if let (Some(w), Some(p)) = (writer, &csv) {
        if summary.is_ok() && csv_err.is_none() && !interrupted {
            w.into_inner().map_err(|e| anyhow::anyhow!("{}: cannot write: {}", p.display(), e.error()))?.commit()?;
            println!("wrote {}", p.display());
        }
    }
    let summary = summary?;
    if let Some(e) = csv_err {
        return Err(e.into());
    }
    print!("{}", summary.report());
    if let Some(l) = sc.lfe_limit().and_then(|l| l.lfe.map(|x| (l, x))) {
        let (l, (_, lfe)) = l;
        let row = |v: [f64; 3]| format!("{:>9.2} {:>9.2} {:>9.2}", 3.0 * v[0], 3.0 * v[1], 3.0 * v[2]);
        println!("  limit 3σ, white tracker (period mean, latency), ″  {}", row(l.latency_mean_arcsec));
        println!("  limit 3σ, the tracker's LFE estimated, ″            {}", row(lfe));
    }
    print!("{}", ssis_common::downlink::timeline(&summary.events.0, summary.events.1));
    let wall = started.elapsed().as_secs_f64();
    cli::report("run", || ssis_sim::json::run_summary(&summary, wall));
    let ran = summary.stopped_at_step.unwrap_or(summary.steps) as f64 / summary.steps.max(1) as f64;
    println!("wall time {wall:.1} s ({:.0}x real time)", sc.duration_s * ran / wall);
    if interrupted {
        eprintln!(
            "interrupted (Ctrl-C): the summary above is partial{}",
            if csv.is_some() { "; no CSV written" } else { "" }
        );
        return Ok(RunEnd::Interrupted);
    }
    let silent = summary.silent_sources();
    if !silent.is_empty() {
        for s in &silent {
            eprintln!("error: {}: {s}", path.display());
        }
        eprintln!(
            "error: {}: no accuracy figure: a source delivered nothing (the 3σ above is not a result)",
            path.display()
        );
        return Ok(RunEnd::SilentSource);
    }
    Ok(RunEnd::Complete)
}

fn key_cmd(cmd: KeyCmd) -> Result<()> {
    match cmd {
        KeyCmd::New { out, id } => {
            let k = ssis_common::keyfile::new_key(id)?;
            ssis_common::keyfile::write_key(&out, &k)?;
            println!("wrote {} (key id {id}; a secret: keep it with the ground's keys)", out.display());
        }
        KeyCmd::ToImage { key, out } => {
            let k = ssis_common::keyfile::read_key(&key)?;
            table::write_atomic(&out, &k.to_record())?;
            println!(
                "wrote {} (key record, {} bytes, key id {})",
                out.display(),
                ssis::telecommand::auth::KEY_RECORD_LEN,
                k.id
            );
        }
    }
    Ok(())
}

fn table_cmd(cmd: TableCmd) -> Result<()> {
    match cmd {
        TableCmd::New { out } => {
            table::write_toml(&out, &CalibrationTable::DEFAULT)?;
            println!("wrote {}", out.display());
        }
        TableCmd::ToBin { input, out } => {
            let t = table::read_toml(&input)?;
            table::write_binary(&out, &t)?;
            println!("wrote {} ({} bytes, revision {})", out.display(), ssis::calib::binary::TABLE_LEN, t.revision);
        }
        TableCmd::ToImage { input, out } => {
            let t = table::read_toml(&input)?;
            table::write_image(&out, &t)?;
            println!("wrote {} ({} bytes, two copies, revision {})", out.display(), store::REGION_LEN, t.revision);
        }
        TableCmd::UploadCmds { input, key, seq, out } => {
            let t = table::read_any(&input)?.0;
            let k = ssis_common::keyfile::read_key(&key)?;
            anyhow::ensure!(seq >= 1, "sequence numbers start at 1");
            let cmds = ssis::telecommand::upload::upload_sequence(&k, &t, seq);
            let bytes: Vec<u8> = cmds.iter().flat_map(|c| c.to_bytes()).collect();
            table::write_atomic(&out, &bytes)?;
            println!(
                "wrote {} ({} telecommands, {} bytes): table revision {}, CRC-32 {:08x}, key id {}, sequence {}..={}",
                out.display(),
                cmds.len(),
                bytes.len(),
                t.revision,
                ssis::flight::table_crc(&t),
                k.id,
                seq,
                seq.saturating_add(cmds.len() as u32 - 1)
            );
        }
        TableCmd::Show { input } => {
            let (t, loaded) = table::read_any(&input)?;
            if let Some(loaded) = loaded {
                for (slot, e) in ["A", "B"].iter().zip(loaded.slot_errors) {
                    if let Some(e) = e {
                        eprintln!("{}: copy {slot} refused: {e}", input.display());
                    }
                }
                eprintln!("{}: using {:?}, generation {}", input.display(), loaded.source, loaded.generation);
            }
            print!("{}", table::to_toml(&t)?);
        }
        TableCmd::Diff { a, b } => {
            table_diff(&a, &b)?;
        }
    }
    Ok(())
}

/// `table diff`: every field that differs, A → B in engineering units; `true` when the
/// tables are identical (every field bit for bit, and the revision). Provenance is not
/// compared.
fn table_diff(a: &Path, b: &Path) -> Result<bool> {
    let (ta, _) = table::read_any(a)?;
    let (tb, _) = table::read_any(b)?;
    let changes = ssis_common::update::diff(&ta, &tb);
    if ta.revision != tb.revision {
        println!("  revision  {} → {}", ta.revision, tb.revision);
    }
    print!("{}", ssis_common::update::render(&changes));
    let same = changes.is_empty() && ta.revision == tb.revision;
    if same {
        println!("{} and {} are identical (every field bit for bit, and the revision)", a.display(), b.display());
    } else {
        println!("{} field(s) differ between {} and {}", changes.len(), a.display(), b.display());
    }
    Ok(same)
}
