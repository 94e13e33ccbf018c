//! `ssis-lv`: launch-vehicle navigation studies. `ssis-lv growth` prints the
//! free-inertial error growth over the default 600 s ascent as Markdown tables: the
//! FOGs with the paper's post-calibration figures alone, the accelerometers with the
//! assumed pendulous figures alone, and both, RMS over `--seeds` runs.

use std::time::Instant;

use anyhow::Result;
use clap::{Parser, Subcommand};
use ssis_common::ARCSEC_PER_RAD;
use ssis_sim::accel::AccelSpec;
use ssis_sim::fog::FogSpec;
use ssis_sim::gnss::GnssSpec;
use ssis_sim::launch::LaunchProfile;
use ssis_sim::lv::{filter_config, free_inertial, rms_over_runs, run, AscentRecord, NavError};

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
        /// GNSS outage for the aided case: start and end, s.
        #[arg(long, num_args = 2, default_values_t = [300.0, 330.0])]
        outage: Vec<f64>,
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
        Cmd::Growth { seeds, duration, every, outage } => {
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
            // GNSS-aided with an outage: 1 s resolution, rows every `every` plus the outage.
            let spec = GnssSpec { outages_s: vec![[outage[0], outage[1]]], ..GnssSpec::default() };
            let cfg = filter_config(&fog, &acc);
            let runs: Vec<_> =
                (1..=seeds).map(|s| run(&rec, Some(&fog), Some(&acc), Some((&spec, &cfg)), s, 1.0).errors).collect();
            let rms = rms_over_runs(&runs);
            let keep = |t: f64| {
                let on_grid = (t / every - (t / every).round()).abs() < 1e-9;
                let near_outage = t >= outage[0] - 1.0 && t <= outage[1] + 10.0 && (t - outage[0] + 1.0) % 5.0 < 1e-9;
                on_grid || near_outage
            };
            let rows: Vec<_> = rms.into_iter().filter(|e| keep(e.t_s)).collect();
            table(
                &format!(
                    "FOGs and accelerometers, GNSS-aided ({} Hz, {} m / {} m/s per axis), outage {}-{} s: RMS over {seeds} runs",
                    spec.rate_hz, spec.sigma_pos_m, spec.sigma_vel_m_s, outage[0], outage[1]
                ),
                &rows,
            );
            eprintln!("done in {:.1} s", t0.elapsed().as_secs_f64());
        }
    }
    Ok(())
}
