//! `ssis-faults`: the fault-injection campaign of issue 6 on the in-process flight core.
//!
//! Every fault of `docs/FAULT-CAMPAIGN.md` on the paper's sensors (Earth pointing with a
//! slew, star tracker 20″ 3σ at 4 Hz): per FOG and seed, detected or not, latency,
//! isolation, attitude error before, during and after, false alarms; and a long nominal
//! flight for false alarms. Writes the table as Markdown.
//!
//! ```text
//! cargo run --release --bin ssis-faults -- --seeds 25 --nominal-hours 24 --out ../docs/FAULT-CAMPAIGN.md
//! ```

use std::path::PathBuf;

use anyhow::{Context, Result};
use clap::Parser;
use indicatif::{ProgressBar, ProgressStyle};
use ssis_host::faults::{self, CampaignRow, Fault, FaultKind};

/// Fault-injection campaign (issue 6).
#[derive(Parser, Debug)]
#[command(version, about)]
struct Args {
    /// Monte Carlo seeds per fault and FOG.
    #[arg(long, default_value_t = 10)]
    seeds: u64,
    /// Hours of nominal flight for the false-alarm count (0: skip).
    #[arg(long, default_value_t = 1.0)]
    nominal_hours: f64,
    /// Markdown table to write (stdout always gets it).
    #[arg(long)]
    out: Option<PathBuf>,
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

fn main() -> Result<()> {
    let args = Args::parse();
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
    let md = faults::report(&k, &rows, nominal.as_ref(), args.nominal_hours, args.seeds);
    println!("{md}");
    if let Some(p) = &args.out {
        std::fs::write(p, &md).with_context(|| format!("writing {}", p.display()))?;
        eprintln!("wrote {}", p.display());
    }
    Ok(())
}
