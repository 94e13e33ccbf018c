//! `ssis-qemu-upset`: the upset campaign on the firmware in QEMU: single bit
//! flips into the RAM in use and the registers through QEMU's gdbstub, at random
//! instructions inside random steps after convergence, classed against truth and the
//! undisturbed run (`ssis_runner::upset`). A spacecraft scenario flies on `ssis-fw-test`,
//! a launch-vehicle ascent (`kind = "lv-ascent"`) on `ssis-fw-lv-test`. `--help` for
//! options.

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::{Context, Result};
use clap::Parser;
use ssis_common::cli;
use ssis_common::output::{self, Origin};
use ssis_runner::qemu::{build_firmware, default_elf};
use ssis_runner::upset::{run_flown_jobs, Campaign, Flown, UpsetOptions};
use ssis_sim::lv_replay::LvScenario;
use ssis_sim::scenario::Scenario;

#[derive(Parser)]
#[command(
    name = "ssis-qemu-upset",
    version,
    about = "Upset campaign on the firmware in QEMU (bit flips through the gdbstub)"
)]
struct Args {
    /// Scenario file (TOML): a spacecraft scenario, or a launch-vehicle ascent.
    #[arg(default_value = "scenarios/qemu-flight.toml")]
    scenario: PathBuf,
    /// Flips to make.
    #[arg(long, default_value_t = 20)]
    flips: usize,
    /// Seed of the flips.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Shorten the scenario to this many seconds.
    #[arg(long)]
    duration: Option<f64>,
    /// First flip at this time, s (after the observer's convergence).
    #[arg(long, default_value_t = 12.0)]
    first: f64,
    /// Outputs identical for this long after a flip: masked, s.
    #[arg(long, default_value_t = 0.5)]
    quiet: f64,
    /// A flip that changed an output is followed this long, s.
    #[arg(long, default_value_t = 10.0)]
    window: f64,
    /// Largest gap between one masked flip's quiet time and the next flip, s.
    #[arg(long, default_value_t = 0.5)]
    gap: f64,
    /// Share of the state's flips into registers (core and FPU), the rest into the RAM in
    /// use; negative (the default): in proportion to their bits.
    #[arg(long, default_value_t = -1.0, allow_hyphen_values = true)]
    register_share: f64,
    /// The populations and their shares: `all` (state 40 %, double 15 %, device 15 %,
    /// snapshot-reset 10 %, handler 10 %, snapshot-write 10 %), `state`, or
    /// `name=share,…` of state, double, device, snapshot-reset, handler, snapshot-write.
    #[arg(long, default_value = "all", value_parser = ssis_runner::upset::Mix::parse)]
    mix: ssis_runner::upset::Mix,
    /// The estimator that flies, replacing the scenario's: `luenberger` or `mekf`.
    #[arg(long, value_parser = ssis_sim::scenario::parse_estimator)]
    estimator: Option<ssis::calib::Estimator>,
    /// Campaigns side by side, each in its own QEMU (job j with seed + j).
    #[arg(long, default_value_t = 1)]
    jobs: usize,
    /// Reset the unit at each drawn instruction instead of flipping a bit (the resume
    /// measured in QEMU).
    #[arg(long)]
    forced_reset: bool,
    /// Make no new flip after this many minutes of wall time.
    #[arg(long)]
    max_minutes: Option<f64>,
    /// Firmware ELF (default: build and use the test build ssis-fw-test).
    #[arg(long)]
    elf: Option<PathBuf>,
    /// Write the campaign document here (docs/UPSET-CAMPAIGN-QEMU.md).
    #[arg(long)]
    out: Option<PathBuf>,
    /// Also write the whole campaign, every flip, here (JSON), for a later `--merge`.
    #[arg(long)]
    save: Option<PathBuf>,
    /// Run nothing: merge campaigns saved with `--save` by runs of the same firmware,
    /// scenario, populations and schedule with seeds that do not overlap (run with
    /// `--seed` at least the other runs' seed + jobs), and report them as one.
    #[arg(long, num_args = 1.., conflicts_with_all = ["save", "elf", "flips", "seed", "jobs", "max_minutes"])]
    merge: Vec<PathBuf>,
    /// One line per flip on standard error.
    #[arg(long)]
    verbose: bool,
    #[command(flatten)]
    flags: cli::Flags,
}

fn main() -> ExitCode {
    let args = Args::parse();
    cli::finish(args.flags.start("ssis-qemu-upset").and_then(|()| campaign(&args)))
}

/// Runs the campaign (or merges saved ones); `Ok(false)` when a flip was silent.
fn campaign(args: &Args) -> Result<bool> {
    for p in [&args.out, &args.save].into_iter().flatten() {
        output::claim(p, Origin::Named)?;
    }
    if !args.merge.is_empty() {
        let parts = args
            .merge
            .iter()
            .map(|p| {
                output::input(p);
                let text = std::fs::read_to_string(p).with_context(|| format!("{}: cannot read", p.display()))?;
                serde_json::from_str::<Campaign>(&text)
                    .with_context(|| format!("{}: not a campaign saved by ssis-qemu-upset --save", p.display()))
            })
            .collect::<Result<Vec<_>>>()?;
        let c = Campaign::merge(parts).context("--merge")?;
        return finish(args, &c);
    }
    output::input(&args.scenario);
    let lv = LvScenario::is_lv_file(&args.scenario);
    let (mut sc, mut lv_sc) = (None, None);
    if lv {
        anyhow::ensure!(args.estimator.is_none(), "--estimator: the launch vehicle's scenario has no estimator choice");
        let mut s = LvScenario::from_file(&args.scenario)?;
        if let Some(d) = args.duration {
            s.duration_s = d;
        }
        lv_sc = Some(s);
    } else {
        let mut s = Scenario::from_file(&args.scenario)?;
        if let Some(d) = args.duration {
            s.duration_s = d;
        }
        if args.estimator.is_some() {
            s.table.estimator = args.estimator;
        }
        sc = Some(s);
    }
    let flown = match (&sc, &lv_sc) {
        (Some(sc), _) => Flown::Spacecraft(sc),
        (None, Some(sc)) => Flown::LaunchVehicle(sc),
        (None, None) => anyhow::bail!("no scenario"),
    };
    let elf = match &args.elf {
        Some(e) => e.clone(),
        None if lv => ssis_runner::qemu_lv::build_firmware()?,
        None => {
            build_firmware()?;
            default_elf()
        }
    };
    let o = UpsetOptions {
        elf,
        flips: args.flips,
        seed: args.seed,
        first_s: args.first,
        quiet_s: args.quiet,
        window_s: args.window,
        gap_s: args.gap,
        register_share: args.register_share,
        max_wall_s: args.max_minutes.map(|m| m * 60.0),
        forced_reset: args.forced_reset,
    };
    let mut k = 0;
    let c = run_flown_jobs(flown, &o, &args.mix, args.jobs, |f: &ssis_runner::upset::Flip| {
        k += 1;
        if args.verbose || f.outcome.name() != "masked" {
            eprintln!(
                "flip {k}/{}: {} step {}{} (+{} instr) {} -> {} (worst {}{})",
                o.flips,
                f.population.name(),
                f.step,
                match (f.star, lv) {
                    (false, _) => "",
                    (true, false) => " (star update)",
                    (true, true) => " (filter work)",
                },
                f.instr,
                f.target.describe(),
                f.outcome.name(),
                match f.nav_worst {
                    Some(([p, v, a], r)) => format!("{p:.2} m, {v:.3} m/s, {a:.1}″, {r:.2} of the bound"),
                    None => format!("{:.1}″", f.worst_arcsec),
                },
                match (&f.outcome, &f.reset_cause) {
                    (ssis_runner::upset::Outcome::Crash(w), _) => format!("; {w}"),
                    (_, Some(c)) => format!(
                        "; reset: {c}, aligned after {:.2} s, within 2× the nominal 3σ after {:.2} s",
                        f.reset_aligned_s.unwrap_or(f64::NAN),
                        f.reset_nominal_s.unwrap_or(f64::NAN)
                    ),
                    _ => String::new(),
                }
            );
        } else if k % 50 == 0 {
            eprintln!("flip {k}/{}", o.flips);
        }
    })?;
    if let Some(p) = &args.save {
        output::write(p, serde_json::to_string(&c)?.as_bytes())?;
        println!("saved {}", p.display());
    }
    finish(args, &c)
}

/// Prints the report and writes the document; `Ok(false)` when a flip was silent.
fn finish(args: &Args, c: &Campaign) -> Result<bool> {
    print!("{}", c.report());
    cli::report("campaign", || c.json());
    if let Some(p) = &args.out {
        let command = std::iter::once("ssis-qemu-upset".to_string())
            .chain(std::env::args().skip(1))
            .collect::<Vec<_>>()
            .join(" ");
        output::write(p, c.document(&command).as_bytes())?;
        println!("wrote {}", p.display());
    }
    Ok(c.silent() == 0)
}
