//! `ssis-sim`: run scenarios through the flight core on the host, handle calibration
//! tables, compute observer gains, measure replay speed. `ssis-sim --help` for all.

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Instant;

use anyhow::{Context, Result};
use clap::{Parser, Subcommand};
use indicatif::{ProgressBar, ProgressStyle};
use ssis::calib::{store, CalibrationTable, ObserverConfig};
use ssis::observer::steady_state_gains;
use ssis_common::table;
use ssis_sim::harness::{run, CSV_HEADER};
use ssis_sim::scenario::Scenario;

#[derive(Parser)]
#[command(name = "ssis-sim", version, about = "Host simulator and tools for the ssis flight core")]
struct Cli {
    #[command(subcommand)]
    cmd: Cmd,
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
        /// Output file (.toml); refused if it exists.
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
    /// QEMU board loads at its CALIB region (0x0002_0000).
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
    /// runner loads it at the ELF's `_key_start`, 0x0002_1000).
    ToImage {
        /// Key file.
        key: PathBuf,
        /// Output image.
        out: PathBuf,
    },
}

fn main() -> ExitCode {
    match real_main() {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::FAILURE
        }
    }
}

fn real_main() -> Result<()> {
    match Cli::parse().cmd {
        Cmd::Run { scenario, csv, every } => run_scenario(&scenario, csv, every.max(1)),
        Cmd::Table { cmd } => table_cmd(cmd),
        Cmd::Key { cmd } => key_cmd(cmd),
        Cmd::Gains { arw, rrw, st_sigma, st_period } => {
            let cfg = ObserverConfig {
                arw_deg_sqrt_h: arw,
                rrw_deg_h_sqrt_h: rrw,
                st_sigma_arcsec: st_sigma,
                st_period_s: st_period,
                gains_override: None,
            };
            let g = steady_state_gains(&cfg).map_err(|e| anyhow::anyhow!("no gains: {e:?}"))?;
            println!("K_B = {:.6}  K_U = {:.6e} /s  (per update, every {st_period} s)", g.k_b[0], g.k_u_per_s[0]);
            Ok(())
        }
    }
}

fn run_scenario(path: &std::path::Path, csv: Option<PathBuf>, every: u64) -> Result<()> {
    let sc = Scenario::from_file(path)?;
    let dt = sc.profile.profile().dt_s();
    let steps = (sc.duration_s / dt).round() as u64;
    let bar = ProgressBar::new(steps);
    bar.set_style(
        ProgressStyle::with_template("{msg} [{bar:40}] {percent}% {eta} left")
            .unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    bar.set_message(sc.name.clone());
    let mut writer = match &csv {
        Some(p) => {
            let tmp = p.with_extension("partial");
            Some((csv::Writer::from_path(&tmp).with_context(|| format!("cannot write {}", tmp.display()))?, tmp))
        }
        None => None,
    };
    if let Some((w, _)) = writer.as_mut() {
        w.write_record(CSV_HEADER)?;
    }
    let started = Instant::now();
    let mut n = 0u64;
    let mut csv_err = None;
    let summary = run(&sc, |r| {
        n += 1;
        if n.is_multiple_of(2000) {
            bar.set_position(n);
        }
        if let Some((w, _)) = writer.as_mut() {
            if n.is_multiple_of(every) && csv_err.is_none() {
                if let Err(e) = w.write_record(r.csv_row()) {
                    csv_err = Some(e);
                }
            }
        }
    })?;
    bar.finish_and_clear();
    if let Some(e) = csv_err {
        return Err(e.into());
    }
    if let (Some((mut w, tmp)), Some(p)) = (writer, csv) {
        w.flush()?;
        std::fs::rename(&tmp, &p)?;
        println!("wrote {}", p.display());
    }
    print!("{}", summary.report());
    let wall = started.elapsed().as_secs_f64();
    println!("wall time {wall:.1} s ({:.0}x real time)", sc.duration_s / wall);
    Ok(())
}

/// A table from a TOML, binary (.bin) or image (.img) file, checked.
fn read_any(input: &std::path::Path) -> Result<CalibrationTable> {
    if input.extension().is_some_and(|e| e == "img") {
        Ok(table::read_image(input)?.0)
    } else if input.extension().is_some_and(|e| e == "bin") {
        table::read_binary(input)
    } else {
        table::read_toml(input)
    }
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
            anyhow::ensure!(!out.exists(), "{} exists; not overwritten", out.display());
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
            let t = read_any(&input)?;
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
            let t = if input.extension().is_some_and(|e| e == "img") {
                let (t, loaded) = table::read_image(&input)?;
                for (slot, e) in ["A", "B"].iter().zip(loaded.slot_errors) {
                    if let Some(e) = e {
                        eprintln!("{}: copy {slot} refused: {e:?}", input.display());
                    }
                }
                eprintln!("{}: using {:?}, generation {}", input.display(), loaded.source, loaded.generation);
                t
            } else if input.extension().is_some_and(|e| e == "bin") {
                table::read_binary(&input)?
            } else {
                table::read_toml(&input)?
            };
            print!("{}", table::to_toml(&t)?);
        }
    }
    Ok(())
}
