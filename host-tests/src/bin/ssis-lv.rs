//! `ssis-lv`: launch-vehicle navigation studies (issue 7). `ssis-lv growth` prints the
//! free-inertial error growth over the default 600 s ascent as Markdown tables: the
//! FOGs with the paper's post-calibration figures alone, the accelerometers with the
//! assumed pendulous figures alone, and both, RMS over `--seeds` runs.

use std::time::Instant;

use anyhow::Result;
use clap::{Parser, Subcommand};
use ssis_host::lv::{free_inertial, rms_over_runs, AscentRecord, NavError};
use ssis_host::sim::accel::AccelSpec;
use ssis_host::sim::fog::FogSpec;
use ssis_host::sim::launch::LaunchProfile;
use ssis_host::ARCSEC_PER_RAD;

#[derive(Parser)]
#[command(name = "ssis-lv", version, about = "Launch-vehicle navigation studies")]
struct Cli {
    #[command(subcommand)]
    cmd: Cmd,
}

#[derive(Subcommand)]
enum Cmd {
    /// Free-inertial error growth over the ascent (Markdown tables on stdout).
    Growth {
        /// Runs per case (different draws of the sensor errors).
        #[arg(long, default_value_t = 10)]
        seeds: u64,
        /// Ascent duration, s.
        #[arg(long, default_value_t = 600.0)]
        duration: f64,
        /// Table row interval, s.
        #[arg(long, default_value_t = 60.0)]
        every: f64,
    },
}

fn table(title: &str, rows: &[NavError]) {
    println!("\n{title}\n");
    println!("| t, s | position, m | velocity, m/s | attitude, arcsec |");
    println!("|---|---|---|---|");
    for e in rows {
        println!("| {:.0} | {:.2} | {:.4} | {:.1} |", e.t_s, e.pos_m, e.vel_m_s, e.att_rad * ARCSEC_PER_RAD);
    }
}

fn main() -> Result<()> {
    let cli = Cli::parse();
    match cli.cmd {
        Cmd::Growth { seeds, duration, every } => {
            let t0 = Instant::now();
            let rec = AscentRecord::record(LaunchProfile::default(), 1.25e-3, duration);
            eprintln!("truth recorded in {:.1} s", t0.elapsed().as_secs_f64());
            let fog = FogSpec::paper_post_calibration();
            let acc = AccelSpec::typical_pendulous();
            let ideal = free_inertial(&rec, None, None, 0, every);
            table("Ideal sensors (the algorithm's own error)", &ideal);
            let cases: [(&str, Option<&FogSpec>, Option<&AccelSpec>); 3] = [
                ("FOGs only (paper, after calibration)", Some(&fog), None),
                ("Accelerometers only (assumed pendulous figures)", None, Some(&acc)),
                ("FOGs and accelerometers", Some(&fog), Some(&acc)),
            ];
            for (name, f, a) in cases {
                let runs: Vec<_> = (1..=seeds).map(|s| free_inertial(&rec, f, a, s, every)).collect();
                table(&format!("{name}: RMS over {seeds} runs"), &rms_over_runs(&runs));
            }
            eprintln!("done in {:.1} s", t0.elapsed().as_secs_f64());
        }
    }
    Ok(())
}
