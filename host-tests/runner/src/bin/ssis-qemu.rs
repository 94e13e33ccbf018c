//! `ssis-qemu`: run a scenario on the firmware in QEMU (mps2-an500), fed by the
//! simulator over the emulated UARTs, and report against truth. `--help` for options.
//! A launch-vehicle ascent scenario (`kind = "lv-ascent"`, e.g. `scenarios/lv-ascent.toml`)
//! runs on `ssis-fw-lv` at 1.25 ms in lockstep (`ssis_runner::qemu_lv`).

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::{Context, Result};
use clap::Parser;
use ssis_common::plot::{write_svg, PlotPoint};
use ssis_runner::qemu::{build_firmware, default_elf, elf_sizes, run_qemu, QemuOptions};
use ssis_runner::qemu_lv::{run_qemu_lv, LvOptions, LvScenario};
use ssis_sim::harness::CSV_HEADER;
use ssis_sim::scenario::Scenario;

#[derive(Parser)]
#[command(name = "ssis-qemu", version, about = "Run a simulated flight on the firmware in QEMU")]
struct Args {
    /// Scenario file (TOML).
    scenario: PathBuf,
    /// Firmware ELF (default: build the test build and use
    /// target/test-hooks/thumbv7em-none-eabihf/release/ssis-fw-test, or ssis-fw-lv-test for
    /// a launch-vehicle ascent). A flight build (ssis-fw) ignores control frames: it runs
    /// in real time only, and the runner stops it at the end.
    #[arg(long)]
    elf: Option<PathBuf>,
    /// Lockstep: step on control frames and compare every output frame with the
    /// in-process flight core (deterministic; not real time). A launch-vehicle ascent
    /// always runs in lockstep.
    #[arg(long)]
    lockstep: bool,
    /// Count instructions (-icount shift=0): step times are then instructions.
    #[arg(long)]
    icount: bool,
    /// Damage every N-th byte sent on every link (alternately a bit flip and a drop).
    #[arg(long, default_value_t = 0)]
    corrupt_every: u64,
    /// Output directory for the CSV log and the SVG plot.
    #[arg(long, default_value = "out")]
    out: PathBuf,
    /// Shorten the scenario to this many seconds.
    #[arg(long)]
    duration: Option<f64>,
}

fn main() -> ExitCode {
    match real_main() {
        Ok(true) => ExitCode::SUCCESS,
        Ok(false) => ExitCode::FAILURE,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::FAILURE
        }
    }
}

fn real_main() -> Result<bool> {
    let a = Args::parse();
    if LvScenario::is_lv_file(&a.scenario) {
        return run_lv(&a);
    }
    let mut sc = Scenario::from_file(&a.scenario)?;
    if let Some(d) = a.duration {
        sc.duration_s = d;
        sc.settle_s = sc.settle_s.min(d / 2.0);
    }
    let elf = match a.elf {
        Some(e) => e,
        None => {
            build_firmware()?;
            default_elf()
        }
    };
    std::fs::create_dir_all(&a.out).with_context(|| format!("cannot create {}", a.out.display()))?;
    let csv_path = a.out.join(format!("{}-qemu.csv", sc.name));
    let tmp = csv_path.with_extension("partial");
    let mut w = csv::Writer::from_path(&tmp)?;
    w.write_record(CSV_HEADER)?;
    let mut points = Vec::new();
    let mut n = 0u64;
    let opts = QemuOptions {
        elf: elf.clone(),
        lockstep: a.lockstep,
        icount: a.icount,
        corrupt_every: a.corrupt_every,
        progress: true,
        stall_at_step: None,
        table_image: None,
        fault: None,
        key_record: None,
        commands: Vec::new(),
    };
    let s = run_qemu(&sc, &opts, |r| {
        n += 1;
        if n.is_multiple_of(20) {
            let _ = w.write_record(r.csv_row());
            points.push(PlotPoint { t_s: r.t_s, att_arcsec: r.att_err_arcsec, rate_deg_h: r.rate_err_deg_h });
        }
    })?;
    w.flush()?;
    drop(w);
    std::fs::rename(&tmp, &csv_path)?;
    let svg = a.out.join(format!("{}-qemu.svg", sc.name));
    write_svg(&svg, &format!("{} on ssis-fw in QEMU", sc.name), &points)?;
    print!("{}", s.report());
    if let Ok((flash, ram)) = elf_sizes(&elf) {
        println!("ELF: flash {flash} bytes, static RAM {ram} bytes");
    }
    println!("wrote {} and {}", csv_path.display(), svg.display());
    Ok(s.clean())
}

/// A launch-vehicle ascent on `ssis-fw-lv` (lockstep at 1.25 ms).
fn run_lv(a: &Args) -> Result<bool> {
    let mut sc = LvScenario::from_file(&a.scenario)?;
    if let Some(d) = a.duration {
        sc.duration_s = d;
    }
    anyhow::ensure!(a.corrupt_every == 0, "--corrupt-every is not supported for a launch-vehicle ascent");
    let elf = match &a.elf {
        Some(e) => e.clone(),
        None => ssis_runner::qemu_lv::build_firmware()?,
    };
    let s = run_qemu_lv(&sc, &LvOptions { elf: elf.clone(), icount: a.icount, progress: true })?;
    print!("{}", s.report());
    if let Ok((flash, ram)) = elf_sizes(&elf) {
        println!("ELF: flash {flash} bytes, static RAM {ram} bytes");
    }
    Ok(s.clean())
}
