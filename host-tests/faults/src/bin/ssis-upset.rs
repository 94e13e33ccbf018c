//! `ssis-upset`: the upset campaign on the in-process flight core.
//!
//! One random bit of the `FlightCore` value flipped at a random step after convergence
//! of the main job's two-minute scenario (`scenarios/qemu-flight.toml`), each flip flown
//! to the end in a child process of its own, classed against truth and the undisturbed
//! flight (`ssis_faults::upset`). Writes the tables as Markdown.
//!
//! ```text
//! cargo run --release --bin ssis-upset -- --flips 2000 --out ../docs/UPSET-CAMPAIGN.md --force
//! ```

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::{Context, Result};
use clap::Parser;
use indicatif::{ProgressBar, ProgressStyle};
use ssis_common::{cli, output};
use ssis_faults::upset::{self, Outcome, Settings};
use ssis_sim::scenario::Scenario;

/// Upset campaign: single bit flips in the flight core's state.
#[derive(Parser, Debug)]
#[command(version, about)]
struct Args {
    /// Flips (each flies the rest of the flight in its own process).
    #[arg(long, default_value_t = 1000)]
    flips: usize,
    /// Seed of the flips (step, byte, bit): the same seed gives the same flips.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Child processes at once (default: the CPUs available).
    #[arg(long)]
    jobs: Option<usize>,
    /// A child with no verdict after this long is a hang, s.
    #[arg(long, default_value_t = 120)]
    timeout_s: u32,
    /// The scenario.
    #[arg(long, default_value = concat!(env!("CARGO_MANIFEST_DIR"), "/../scenarios/qemu-flight.toml"))]
    scenario: PathBuf,
    /// Markdown to write (stdout always gets it); an existing file is replaced only with
    /// --force.
    #[arg(long)]
    out: Option<PathBuf>,
    #[command(flatten)]
    flags: cli::Flags,
}

fn main() -> ExitCode {
    let args = Args::parse();
    cli::finish_unit(args.flags.start("ssis-upset").and_then(|()| run(&args)))
}

fn run(args: &Args) -> Result<()> {
    if let Some(p) = &args.out {
        output::claim(p, output::Origin::Named)?;
    }
    output::input(&args.scenario);
    let sc = Scenario::from_file(&args.scenario).with_context(|| format!("reading {}", args.scenario.display()))?;
    let jobs = args.jobs.unwrap_or_else(|| std::thread::available_parallelism().map_or(1, |n| n.get()));
    let set = Settings { flips: args.flips, seed: args.seed, jobs, timeout_s: args.timeout_s };
    let started = std::time::Instant::now();
    let bar = ProgressBar::new(args.flips as u64)
        .with_style(ProgressStyle::with_template("{bar:40} {pos}/{len} {msg} {eta}")?);
    bar.set_message("undisturbed flight");
    let mut bad = 0u64;
    let (reference, verdicts) = upset::campaign(&sc, &set, |v| {
        if matches!(v.outcome, Outcome::Silent | Outcome::Crash) {
            bad += 1;
        }
        bar.set_message(format!("silent or crash: {bad}"));
        bar.inc(1);
    })?;
    bar.finish_and_clear();
    let wall_s = started.elapsed().as_secs_f64();
    let command: Vec<String> = std::env::args().skip(1).collect();
    let md = format!(
        "# Upset campaign\n\n\
         Produced by `cd host-tests && cargo run --release --bin ssis-upset -- {}` ({:.0} s on the machine that ran it, \
         {} jobs: {:.1} flips/s).\n\n{}",
        command.join(" "),
        wall_s,
        jobs,
        args.flips as f64 / wall_s,
        upset::report(&reference, &verdicts)
    );
    println!("{md}");
    let counts = upset::counts(&verdicts);
    cli::report("flips", || serde_json::json!(args.flips));
    cli::report("seed", || serde_json::json!(args.seed));
    cli::report("wall_s", || serde_json::json!(wall_s));
    cli::report("counts", || {
        serde_json::json!(counts
            .iter()
            .map(|(o, k)| (o.name().to_string(), serde_json::json!(*k)))
            .collect::<serde_json::Map<_, _>>())
    });
    cli::report("verdicts", || serde_json::json!(verdicts));
    if let Some(p) = &args.out {
        output::write(p, md.as_bytes())?;
        eprintln!("wrote {}", p.display());
    }
    Ok(())
}
