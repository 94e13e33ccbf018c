//! `ssis-faults`: the fault-injection campaign on the in-process flight core.
//!
//! Every fault of `docs/FAULT-CAMPAIGN.md` on the paper's sensors (Earth pointing with a
//! slew, star tracker 20″ 3σ at 4 Hz): per FOG and seed, detected or not, latency,
//! isolation, attitude error before, during and after, false alarms; and a long nominal
//! flight for false alarms. Writes the table as Markdown.
//!
//! ```text
//! cargo run --release --bin ssis-faults -- --seeds 25 --nominal-hours 24 --out ../docs/FAULT-CAMPAIGN.md --force
//! ```

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::Result;
use clap::Parser;
use indicatif::{ProgressBar, ProgressStyle};
use ssis_common::{cli, output};
use ssis_faults::{self as faults, utc_date, CampaignRow, Fault, FaultKind};

/// Fault-injection campaign.
#[derive(Parser, Debug)]
#[command(version, about)]
struct Args {
    /// Monte Carlo seeds per fault and FOG.
    #[arg(long, default_value_t = 10)]
    seeds: u64,
    /// Hours of nominal flight for the false-alarm count (0: skip).
    #[arg(long, default_value_t = 1.0)]
    nominal_hours: f64,
    /// Markdown table to write (stdout always gets it); an existing file is replaced only
    /// with --force.
    #[arg(long)]
    out: Option<PathBuf>,
    /// Replace an existing --out file.
    #[arg(long)]
    force: bool,
    /// Start of the star-tracker outage, s: after the observer's drift estimate has
    /// settled (the 15″ goal is for a unit in steady state).
    #[arg(long, default_value_t = 1800.0)]
    outage_start_s: f64,
    /// Only these rows (names as in the table's first column, substring match).
    #[arg(long)]
    only: Option<String>,
}

/// A fault family to run: its name, the FOGs it is put on, how long it acts, the fault
/// on a given FOG.
struct Plan {
    name: String,
    fogs: Vec<usize>,
    fault_s: f64,
    kind: Box<dyn Fn(usize) -> FaultKind>,
}

impl Plan {
    fn new(name: &str, fogs: &[usize], fault_s: f64, kind: impl Fn(usize) -> FaultKind + 'static) -> Self {
        Plan { name: name.into(), fogs: fogs.to_vec(), fault_s, kind: Box::new(kind) }
    }
}

/// What the campaign runs and what its columns mean (the top of the document), with
/// the outage starting at `outage_start_s`.
fn legend(outage_start_s: f64) -> String {
    format!(
        "\
The in-process flight core (the same `FlightCore::step` as the firmware) on the main job's scenario \
(`scenarios/qemu-flight.toml`: Earth pointing with a 10° roll slew at 50–80 s, the paper's FOGs, star tracker \
20″ 3σ at 4 Hz with 50 ms latency), ideal links. FOG faults start at 60 s (inside the slew) on each FOG in turn \
and last 30 s (dropout 10 s); star-tracker faults and bit errors start at 60 s, the 10-min outage at {outage_start_s} s (the \
observer's drift estimate in steady state); every run goes on 30 s after the fault. Runs: seeds × FOGs.

- **detected**: runs whose output showed the fault (the FOG's health bits, the parity alarm, the isolation bits, \
the held-temperature bit; for the star tracker the outage bit or the gated and frozen counters; for bit errors a \
rejected frame); **latency** from the fault's start to that output, in 5 ms steps.
- **right FOG isolated**: the fault logic excluded the faulty FOG for good (in how many runs; within 10 s). \
Stuck, NaN, dropout and temperature faults need no isolation (the channel checks refuse the samples or hold the \
temperature); an isolation there means a parity alarm stood when the channel check fired. **wrong FOG isolated**: \
a healthy FOG excluded for good.
- **attitude error**: largest axis of the error against truth, arcsec, the largest over the runs: before the fault \
(after 40 s of settling), during it, after it. **after isolation**: the largest error from the isolation to the \
end of the run (median and largest over the runs with an isolation). **jump after**: the largest step-to-step \
change of the error after the fault's end.
- **false alarms**: samples of a healthy FOG dropped as spikes, and, for faults that are not a FOG's, any parity \
alarm. The last column counts over all the row's runs.
"
    )
}

fn main() -> ExitCode {
    let args = Args::parse();
    cli::finish_unit(cli::start("ssis-faults", args.force, false).and_then(|()| campaign(&args)))
}

/// The campaign: every plan, the nominal flight, the document.
fn campaign(args: &Args) -> Result<()> {
    if let Some(p) = &args.out {
        output::claim(p, output::Origin::Named)?;
    }
    let started = std::time::Instant::now();
    let probe = faults::scenario(1, 1.0)?;
    let k = faults::FaultScale::of(&probe)?;
    let start_s = faults::FAULT_START_S;
    let after_s = 30.0;
    let fogs = [0usize, 1, 2, 3];
    let one = [0usize];
    let mut plans = vec![
        Plan::new("FOG stuck", &fogs, 30.0, FaultKind::FogStuck),
        Plan::new("FOG bias step 5σ of the parity residual", &fogs, 30.0, move |i| {
            FaultKind::FogBiasStep(i, k.bias_for_sigma_rad_s(i, 5.0))
        }),
        Plan::new("FOG bias step 20σ of the parity residual", &fogs, 30.0, move |i| {
            FaultKind::FogBiasStep(i, k.bias_for_sigma_rad_s(i, 20.0))
        }),
        Plan::new("FOG drift ramp to 5σ in 10 s", &fogs, 30.0, move |i| {
            FaultKind::FogDriftRamp(i, k.bias_for_sigma_rad_s(i, 5.0) / 10.0)
        }),
        Plan::new("FOG spikes 20σ₁ once a second", &fogs, 30.0, move |i| {
            FaultKind::FogSpikes(i, 20.0 * k.sigma1_rad, 200)
        }),
        Plan::new("FOG NaN (saturated output)", &fogs, 30.0, FaultKind::FogNan),
        Plan::new("FOG NaN sent as 0 (as the ICD encodes it)", &fogs, 30.0, FaultKind::FogNanAsZero),
        Plan::new("FOG dropout 10 s", &fogs, 10.0, FaultKind::FogDropout),
        Plan::new("FOG temperature sensor open", &fogs, 30.0, FaultKind::FogTempSensor),
        Plan::new("star tracker outage 10 min", &one, 600.0, |_| FaultKind::StOutage),
        Plan::new("star tracker outliers 6σ (every 4th frame)", &one, 300.0, |_| FaultKind::StOutliers(6.0, 4)),
        Plan::new("star tracker outliers 10σ (every 4th frame)", &one, 1200.0, |_| FaultKind::StOutliers(10.0, 4)),
        Plan::new("star tracker frozen 60 s", &one, 60.0, |_| FaultKind::StFrozen),
        Plan::new("bit errors 1e-4 on every link, 60 s", &one, 60.0, |_| FaultKind::BitErrors(1e-4)),
        Plan::new("none (nominal, same runs)", &one, 30.0, |_| FaultKind::None),
    ];
    if let Some(o) = &args.only {
        plans.retain(|p| p.name.contains(o.as_str()));
    }
    let total: u64 = plans.iter().map(|p| p.fogs.len() as u64 * args.seeds).sum();
    let bar = ProgressBar::new(total).with_style(ProgressStyle::with_template("{bar:40} {pos}/{len} {msg} {eta}")?);
    let mut rows = Vec::new();
    for Plan { name, fogs, fault_s, kind } in &plans {
        bar.set_message(name.clone());
        let mut runs = Vec::new();
        for &i in fogs {
            for seed in 1..=args.seeds {
                let t0 = if name.starts_with("star tracker outage") { args.outage_start_s } else { start_s };
                let sc = faults::scenario(seed * 7919 + i as u64, t0 + fault_s + after_s)?;
                let fault = Fault { kind: kind(i), start_s: t0, duration_s: *fault_s };
                runs.push((i, faults::run(&sc, &fault)?));
                bar.inc(1);
            }
        }
        rows.push(CampaignRow { name: name.clone(), runs, fault_s: *fault_s });
    }
    bar.finish_and_clear();
    let nominal = if args.nominal_hours > 0.0 {
        let sc = faults::scenario(424242, args.nominal_hours * 3600.0)?;
        let pb = ProgressBar::new_spinner().with_message(format!("nominal flight, {} h", args.nominal_hours));
        pb.enable_steady_tick(std::time::Duration::from_millis(200));
        let r = faults::run(&sc, &Fault { kind: FaultKind::None, start_s: f64::INFINITY, duration_s: 0.0 })?;
        pb.finish_and_clear();
        Some(r)
    } else {
        None
    };
    let command: Vec<String> = std::env::args().skip(1).collect();
    let md = format!(
        "# Fault-injection campaign\n\n\
         Produced by `cd host-tests && cargo run --release --bin ssis-faults -- {}` on {} ({:.0} s on the machine \
         that ran it).\n\n{}\n{}",
        command.join(" "),
        utc_date(),
        started.elapsed().as_secs_f64(),
        legend(args.outage_start_s),
        faults::report(&k, &rows, nominal.as_ref(), args.nominal_hours, args.seeds)
    );
    println!("{md}");
    if let Some(p) = &args.out {
        output::write(p, md.as_bytes())?;
        eprintln!("wrote {}", p.display());
    }
    Ok(())
}
