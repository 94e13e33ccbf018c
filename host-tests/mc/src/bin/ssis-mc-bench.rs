//! `ssis-mc-bench CAMPAIGN [--runs N] [--first I] [--reverse] [--series-every K]`: flies
//! runs of a campaign in one process, one line per run (its digest, parameters and
//! indices), and the speed: unit steps per CPU second, end to end (draw, simulation,
//! core, indices). Two invocations over the same runs in different orders print the same
//! digests: the bit-identity check of "run i is a pure function of (campaign, i)".

use std::path::PathBuf;

use anyhow::Result;
use clap::Parser;
use ssis_mc::{run, Campaign};

#[derive(Parser)]
#[command(about = "Fly runs of a Monte Carlo campaign in one process: digests, indices, steps per CPU second")]
struct Args {
    /// The campaign file.
    campaign: PathBuf,
    /// How many runs (default: the campaign's).
    #[arg(long)]
    runs: Option<u64>,
    /// The first run.
    #[arg(long, default_value_t = 0)]
    first: u64,
    /// Fly them last to first.
    #[arg(long)]
    reverse: bool,
    /// Keep every K-th output's error in the digest (0: none).
    #[arg(long, default_value_t = 0)]
    series_every: u64,
    /// Print the digests only (no parameters and indices).
    #[arg(long)]
    quiet: bool,
}

/// CPU time of this process (user + system), s.
fn cpu_s() -> f64 {
    // SAFETY: getrusage writes the struct it is given and nothing else.
    let mut u: libc::rusage = unsafe { std::mem::zeroed() };
    // SAFETY: as above; RUSAGE_SELF is always valid.
    unsafe { libc::getrusage(libc::RUSAGE_SELF, &mut u) };
    let tv = |t: libc::timeval| t.tv_sec as f64 + t.tv_usec as f64 * 1e-6;
    tv(u.ru_utime) + tv(u.ru_stime)
}

fn main() -> Result<()> {
    let a = Args::parse();
    let c = Campaign::from_file(&a.campaign)?;
    let n = a.runs.unwrap_or(c.runs).min(c.runs.saturating_sub(a.first));
    let mut order: Vec<u64> = (a.first..a.first + n).collect();
    if a.reverse {
        order.reverse();
    }
    let (cpu0, wall0) = (cpu_s(), std::time::Instant::now());
    let mut steps = 0u64;
    for i in order {
        let r = run::run(&c, i, a.series_every)?;
        steps += r.steps;
        if a.quiet {
            println!("run {i:>6} digest {:016x}", r.digest());
        } else {
            let f = |v: &[(String, f64)]| v.iter().map(|(k, x)| format!("{k}={x:.4}")).collect::<Vec<_>>().join(" ");
            let p = r.params.iter().map(|(k, x)| format!("{k}={x:.4e}")).collect::<Vec<_>>().join(" ");
            println!("run {i:>6} digest {:016x} | {} | {p}", r.digest(), f(&r.indices));
        }
    }
    let (cpu, wall) = (cpu_s() - cpu0, wall0.elapsed().as_secs_f64());
    eprintln!(
        "{n} runs, {steps} unit steps: CPU {cpu:.2} s ({:.3} M steps per CPU second), wall {wall:.2} s",
        steps as f64 / cpu.max(1e-9) / 1e6
    );
    Ok(())
}
