//! `ssis-sim replay`: a recorded log through the flight core, or its consistency check.

use std::path::PathBuf;

use anyhow::Result;
use ssis::calib::CalibrationTable;
use ssis::flight::Profile;
use ssis_common::cli;
use ssis_common::output;
use ssis_common::plot::{write_svg, PlotPoint};
use ssis_sim::harness::CSV_HEADER;
use ssis_sim::replay::{farrenkopf_1sigma_arcsec, replay};
use ssis_sim::{check, conventions, recorded};

/// The command's arguments.
pub struct Args {
    pub log: Vec<PathBuf>,
    pub table: Option<PathBuf>,
    pub settle: f64,
    pub csv: Option<PathBuf>,
    pub every: u64,
    pub plot: Option<PathBuf>,
    pub check: bool,
}

/// Runs it; `Ok(false)` when the conventions check or `--check` finds something.
pub fn run(a: &Args) -> Result<bool> {
    let table = match &a.table {
        Some(p) => ssis_common::table::read_any(p)?.0,
        None => CalibrationTable::DEFAULT,
    };
    let dt_us = Profile::SPACECRAFT.dt_us;
    let rec = recorded::read(&a.log, dt_us)?;
    let conv = conventions::check_conventions(&rec, &table, dt_us)?;
    cli::report("conventions", || ssis_sim::json::conventions(&conv));
    if a.check {
        print!("log: {}\ndamage in the log (counted, skipped):\n{}", rec.origin, rec.problems.report());
        print!("{}", conv.report());
        if !conv.tracker_ok {
            println!(
                "FOG check not run: it reads the FOGs against the star tracker, whose log breaks a convention (above)"
            );
            cli::report("damage", || ssis_sim::json::damage(&rec.problems));
            return Ok(false);
        }
        let r = check::check(&rec, &table, dt_us)?;
        print!("{}", r.report());
        cli::report("check", || ssis_sim::json::check_report(&r));
        cli::report("damage", || ssis_sim::json::damage(&rec.problems));
        return Ok(r.findings.is_empty() && conv.findings.is_empty());
    }
    let mut writer = match &a.csv {
        Some(p) => {
            let mut w = csv::Writer::from_writer(output::create(p)?);
            w.write_record(CSV_HEADER)?;
            Some(w)
        }
        None => None,
    };
    let mut points = Vec::new();
    let mut n = 0u64;
    let mut csv_err = None;
    let s = replay(&rec, &table, a.settle, |_, r| {
        let Some(r) = r else { return };
        n += 1;
        if n.is_multiple_of(a.every) {
            if let Some(w) = writer.as_mut() {
                if let Err(e) = w.write_record(r.csv_row()) {
                    csv_err.get_or_insert(e);
                }
            }
            points.push(PlotPoint { t_s: r.t_s, att_arcsec: r.att_err_arcsec, rate_deg_h: r.rate_err_deg_h });
        }
    })?;
    if let Some(e) = csv_err {
        return Err(e.into());
    }
    let dt = Profile::SPACECRAFT;
    let limit = farrenkopf_1sigma_arcsec(&table.observer, &table.axes(), dt.dt_s(), rec.st_latency_s(dt.dt_us));
    print!("{}", s.report(&rec, Some(limit)));
    print!("{}", conv.report());
    if let (Some(w), Some(p)) = (writer, &a.csv) {
        w.into_inner().map_err(|e| anyhow::anyhow!("{}: cannot write: {}", p.display(), e.error()))?.commit()?;
        println!("wrote {}", p.display());
    }
    if let Some(p) = &a.plot {
        anyhow::ensure!(!points.is_empty(), "{}: no truth in the log: nothing to plot", p.display());
        write_svg(p, &format!("replay of {}", rec.origin), &points)?;
        println!("wrote {}", p.display());
    }
    cli::report("replay", || {
        let mut v = ssis_sim::json::replay_summary(&s);
        ssis_sim::json::add_limit_and_damage(&mut v, &limit, &rec.problems);
        v
    });
    if let Some(w) = conv.warning() {
        println!("{w}");
    }
    Ok(conv.findings.is_empty())
}
