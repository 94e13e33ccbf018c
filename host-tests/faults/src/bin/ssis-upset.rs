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
//!
//! `--in-step` flips inside the step instead (at a drawn point between the state guard's
//! check and its seal, into the attitude and the estimator's state) and writes its own
//! section of the same document, between two markers, leaving the rest as it is.

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::{Context, Result};
use clap::Parser;
use indicatif::{ProgressBar, ProgressStyle};
use ssis_common::{cli, output};
use ssis_faults::upset::{self, Outcome, Settings};
use ssis_faults::utc_date;
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
    /// Flip inside the step, into the attitude and the estimator's state, instead of
    /// between two steps into any byte of the core.
    #[arg(long)]
    in_step: bool,
    /// Between two steps: this share of the flips are double-bit patterns of a
    /// multi-cell upset (two adjacent bits, the same bit of the adjacent 32-bit or 64-bit
    /// word; drawn uniformly), 0 to 1.
    #[arg(long, default_value_t = 0.0, value_parser = share)]
    double_share: f64,
    /// Markdown to write (stdout always gets it); an existing file is replaced only with
    /// --force (with --in-step: only its in-step section, between its markers).
    #[arg(long)]
    out: Option<PathBuf>,
    #[command(flatten)]
    flags: cli::Flags,
}

/// The line that ends what the tool writes; the hand-written part after it is kept when
/// `--out` is rewritten.
const HAND_WRITTEN: &str = "---\n\n*Everything above this line is written by `ssis-upset`";

/// What the campaign flies and what its outcomes mean (the top of the document).
const LEGEND: &str = "\
The in-process flight core (the same `FlightCore::step` as the firmware) on the main job's scenario \
(`scenarios/qemu-flight.toml`: two minutes of Earth pointing with a 10° roll slew at 50–80 s, the paper's FOGs, \
star tracker 20″ 3σ at 4 Hz with 50 ms latency, the scenario's own links and seed). Each flip: one bit of the \
`FlightCore` value (uniform over its bytes and bits, padding included), between two steps, at a step drawn \
uniformly from the first after convergence to the last. The flight is flown once undisturbed, then again, \
forking at each flip's step: the child flips its bit and flies to the end, in a process of its own, so a fault is \
an outcome. Every step after the flip is compared with the undisturbed flight (the step's output, every byte of \
the output link: output frame with its counter page, event frames) and with truth (the attitude error, largest \
axis). A frame **claims a good attitude** when its flags say converged (bit 2) and neither degraded (bit 1) nor \
parity alarm (bit 6) (docs/ICD.md, output flags). The **bound** at a step is max(20″, the unit's own 3σ: three \
times the largest axis of the attitude 1σ the undisturbed flight reported at that step).

- **masked**: every output identical to the undisturbed flight's, to the bit.
- **tolerated**: outputs changed; the attitude error stayed within the bound.
- **detected, recovered**: the error went beyond the bound only in frames that did not claim a good attitude, and \
came back within 2× the nominal 3σ (the undisturbed flight's |mean| + 3 std after settling, largest axis) to stay; \
**recovery**: from the flip to the first frame of that stay. **detected, not recovered**: not back by the end of \
the flight.
- **silent**: a frame claiming a good attitude with the error beyond the bound.
- **crash**: the child died: a signal (SIGSEGV: a corrupted index or discriminant read as valid), a panic, or no \
verdict within the timeout (a hang).
- **reset and recovered** does not occur on the host (the core has no reset path; the firmware campaign in QEMU \
has one).

Shares with their exact (Clopper–Pearson) 95 % intervals. The field a flip hit is named by \
`FlightCore::state_map()` (`src/state_map.rs`: offsets from `offset_of!`, down to the stages and one or two levels \
inside some); `(padding)` is a byte no field holds. Events: those the unit logged after the flip that the \
undisturbed flight did not log at the same time.
";

/// What the in-step campaign flies (its section's legend; the outcomes are the
/// between-step campaign's).
const LEGEND_IN_STEP: &str = "\
The same flight and the same outcomes as above, but each bit is flipped *inside* the flip's step, after the state \
guard's check and before its seal: at one of the step's numbered points (`ssis::flight::probe`, drawn uniformly: \
0 after the guard's check, 1 after the FOG links are read, 2–4 per sample: due, checked, integrated, 5 after the \
samples, 6 after the star-tracker frames are applied, 7 after the output frame is assembled, 8 after it is sent; \
a per-sample point in a step without a sample falls to the next), through the test-only \
`FlightCore::step_probed` (feature `step-probe`, which no firmware enables). The field is drawn uniformly from \
the attitude and the estimator's state, then a byte of it and a bit: `attitude.q` (Λ), `twin` (Λ's and Δω's \
second copies and checksums), and in `observer` the drift estimate Δω, the last update's time tag and Λ, the \
convergence state, the re-acquisition streak and the estimator (gains, covariance).
";

/// The markers of the in-step campaign's section in the document.
const IN_STEP_BEGIN: &str = "<!-- ssis-upset --in-step: begin -->";
const IN_STEP_END: &str = "<!-- ssis-upset --in-step: end -->";

/// CPU time of this process and its waited-for children, s.
fn cpu_s() -> f64 {
    let t = |who| {
        // SAFETY: getrusage(2) into a zeroed struct.
        let mut u: libc::rusage = unsafe { std::mem::zeroed() };
        if unsafe { libc::getrusage(who, &mut u) } != 0 {
            return 0.0;
        }
        let tv = |v: libc::timeval| v.tv_sec as f64 + v.tv_usec as f64 * 1e-6;
        tv(u.ru_utime) + tv(u.ru_stime)
    };
    t(libc::RUSAGE_SELF) + t(libc::RUSAGE_CHILDREN)
}

/// A share, 0 to 1.
fn share(s: &str) -> Result<f64, String> {
    match s.parse::<f64>() {
        Ok(x) if (0.0..=1.0).contains(&x) => Ok(x),
        Ok(x) => Err(format!("{x} is not a share between 0 and 1")),
        Err(e) => Err(format!("not a number: {e}")),
    }
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
    anyhow::ensure!(
        !(args.in_step && args.double_share > 0.0),
        "--double-share: the in-step campaign flips single bits only (give one of the two)"
    );
    let set = Settings {
        flips: args.flips,
        seed: args.seed,
        jobs,
        timeout_s: args.timeout_s,
        in_step: args.in_step,
        double_share: args.double_share,
    };
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
    let cpu_s = cpu_s();
    let command: Vec<String> = std::env::args().skip(1).collect();
    let (title, legend) =
        if args.in_step { ("## In-step campaign", LEGEND_IN_STEP) } else { ("# Upset campaign", LEGEND) };
    let mut md = format!(
        "{title}\n\n\
         Produced by `cd host-tests && cargo run --release --bin ssis-upset -- {}` on {} ({:.0} s on the machine that \
         ran it with {} jobs: {:.1} flips/s; CPU time {:.0} s, {:.1} ms a flip).\n\n{legend}\n{}",
        command.join(" "),
        utc_date(),
        wall_s,
        jobs,
        args.flips as f64 / wall_s,
        cpu_s,
        1e3 * cpu_s / args.flips.max(1) as f64,
        upset::report(&reference, &verdicts)
    );
    println!("{md}");
    let counts = upset::counts(&verdicts);
    cli::report("flips", || serde_json::json!(args.flips));
    cli::report("seed", || serde_json::json!(args.seed));
    cli::report("wall_s", || serde_json::json!(wall_s));
    cli::report("cpu_s", || serde_json::json!(cpu_s));
    cli::report("counts", || {
        serde_json::Value::Object(counts.iter().map(|(o, k)| (o.key().to_string(), serde_json::json!(k))).collect())
    });
    cli::report("verdicts", || {
        serde_json::Value::Array(
            verdicts
                .iter()
                .map(|v| {
                    let mut j = serde_json::json!(v);
                    let (field, byte) = v.flip.field();
                    j["field"] = serde_json::json!(field);
                    j["field_byte"] = serde_json::json!(byte);
                    j["flip_t_s"] = serde_json::json!(reference.steps.get(v.flip.step).map(|s| s.t_s));
                    j
                })
                .collect(),
        )
    });
    if let (Some(p), true) = (&args.out, args.in_step) {
        // Only the section between the markers (appended if none yet).
        let old = std::fs::read_to_string(p).unwrap_or_default();
        let section = format!("{IN_STEP_BEGIN}\n{md}{IN_STEP_END}");
        let new = match (old.find(IN_STEP_BEGIN), old.find(IN_STEP_END)) {
            (Some(b), Some(e)) if b < e => format!("{}{section}{}", &old[..b], &old[e + IN_STEP_END.len()..]),
            _ => format!("{}\n\n{section}\n", old.trim_end()),
        };
        output::write(p, new.as_bytes())?;
        eprintln!("wrote the in-step section of {}", p.display());
    } else if let Some(p) = &args.out {
        // The hand-written part of the document stays.
        let old = std::fs::read_to_string(p).unwrap_or_default();
        if let Some(i) = old.find(HAND_WRITTEN) {
            md.push('\n');
            md.push_str(&old[i..]);
        }
        output::write(p, md.as_bytes())?;
        eprintln!("wrote {}", p.display());
    }
    Ok(())
}
