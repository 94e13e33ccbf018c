//! `ssis-sim replay`: a recorded log through the flight core (the spacecraft unit's, or
//! the launch vehicle's flight core and navigation), or its consistency check; `ssis-sim
//! record`: a launch-vehicle log written from an ascent scenario.

use std::path::{Path, PathBuf};

use anyhow::Result;
use ssis::calib::CalibrationTable;
use ssis::flight::Profile;
use ssis::frames::output::OutputFrame;
use ssis_common::cli;
use ssis_common::output;
use ssis_common::plot::{write_svg, write_svg_panels, PlotPoint};
use ssis_sim::accuracy::farrenkopf_1sigma_arcsec;
use ssis_sim::accuracy::Record;
use ssis_sim::accuracy::CSV_HEADER;
use ssis_sim::lv_replay::{replay_lv, LogOptions, LvScenario, LV_CSV_HEADER};
use ssis_sim::recorded::{LogStream, LogUnit, Recorded};
use ssis_sim::replay::{replay, LogInfo, Rows};
use ssis_sim::streamed::{self, Streamed};
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
    pub pad: Option<PathBuf>,
}

/// Runs it; `Ok(false)` when the conventions check or `--check` finds something.
pub fn run(a: &Args) -> Result<bool> {
    let table = match &a.table {
        Some(p) => ssis_common::table::read_any(p)?.0,
        None => CalibrationTable::DEFAULT,
    };
    let dt_us = Profile::SPACECRAFT.dt_us;
    if let [p] = a.log.as_slice() {
        if recorded::is_csv(p) && !a.check {
            let stream = LogStream::open(p)?;
            if stream.unit == LogUnit::Spacecraft {
                anyhow::ensure!(a.pad.is_none(), "--pad: {} is a spacecraft log (no navigation to start)", p.display());
                return run_spacecraft(a, &table, |table, on_frame| {
                    streamed::replay_stream(
                        stream,
                        table,
                        a.settle,
                        |c| cli::report("conventions", || ssis_sim::json::conventions(c)),
                        on_frame,
                    )
                });
            }
        }
    }
    let rec = recorded::read_log(&a.log)?;
    if rec.unit == LogUnit::LaunchVehicle {
        anyhow::ensure!(
            !a.check,
            "{}: --check needs the spacecraft unit's four FOGs and star tracker; this is a launch-vehicle log",
            rec.origin
        );
        return run_lv(a, &rec, &table);
    }
    anyhow::ensure!(a.pad.is_none(), "--pad: {} is a spacecraft log (no navigation to start)", rec.origin);
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
    run_spacecraft(a, &table, |table, on_frame| {
        let summary = replay(&rec, table, a.settle, on_frame)?;
        Ok(Streamed { summary, conventions: conv, info: LogInfo::of(&rec), st_latency_s: rec.st_latency_s(dt_us) })
    })
}

/// The replay of a spacecraft log that `replay_log` runs (with the conventions check;
/// every output frame to its `on_frame`), and its report, CSV, plot and JSON.
fn run_spacecraft<F>(a: &Args, table: &CalibrationTable, replay_log: F) -> Result<bool>
where
    F: FnOnce(&CalibrationTable, &mut dyn FnMut(&OutputFrame, Option<&Record>)) -> Result<Streamed>,
{
    let mut rows = Rows::new(a.csv.as_deref(), &CSV_HEADER, a.every)?;
    let Streamed { summary: s, conventions: conv, info, st_latency_s } = replay_log(table, &mut |_, r| {
        if let Some(r) = r {
            rows.take(
                || r.csv_row(),
                PlotPoint { t_s: r.t_s, att_arcsec: r.att_err_arcsec, rate_deg_h: r.rate_err_deg_h },
            );
        }
    })?;
    let dt = Profile::SPACECRAFT;
    let limit = farrenkopf_1sigma_arcsec(&table.observer, &table.axes(), dt.dt_s(), st_latency_s);
    print!("{}", s.report_on(&info, Some(limit)));
    print!("{}", ssis_common::downlink::timeline(&s.events.0, s.events.1));
    print!("{}", conv.report());
    let points = rows.finish()?;
    if let Some(p) = &a.plot {
        anyhow::ensure!(!points.is_empty(), "{}: no truth in the log: nothing to plot", p.display());
        write_svg(p, &format!("replay of {}", s.origin), &points)?;
        println!("wrote {}", p.display());
    }
    cli::report("replay", || {
        let mut v = ssis_sim::json::replay_summary(&s);
        ssis_sim::json::add_limit_and_damage(&mut v, &limit, &info.problems);
        v
    });
    if let Some(w) = conv.warning() {
        println!("{w}");
    }
    Ok(conv.findings.is_empty())
}

/// A launch-vehicle log through `FlightCore::step_with()` + `NavUnit`.
fn run_lv(a: &Args, rec: &Recorded, table: &CalibrationTable) -> Result<bool> {
    let init = ssis_sim::lv_replay::pad_for(rec, a.pad.as_deref())?;
    let conv = conventions::check_lv(rec, table, &init.state);
    cli::report("conventions", || ssis_sim::json::lv_conventions(&conv));
    let mut rows = Rows::new(a.csv.as_deref(), &LV_CSV_HEADER, a.every)?;
    let s = replay_lv(rec, table, &init, |_, r| {
        if let Some(r) = r {
            rows.take(|| r.csv_row(), (r.t_s, r.att_err_arcsec.into(), r.pos_err_m.into()));
        }
    })?;
    print!("{}", s.report(rec));
    print!("{}", conv.report());
    let points = rows.finish()?;
    if let Some(p) = &a.plot {
        anyhow::ensure!(!points.is_empty(), "{}: no truth in the log: nothing to plot", p.display());
        let captions = ["attitude error, arcsec, body axes (x red, y green, z blue)", "position error, m, ECEF"];
        write_svg_panels(p, &format!("replay of {}", rec.origin), captions, &points)?;
        println!("wrote {}", p.display());
    }
    cli::report("replay", || ssis_sim::json::lv_replay_summary(&s, rec));
    if let Some(w) = conv.warning() {
        println!("{w}");
    }
    Ok(conv.findings.is_empty())
}

/// `ssis-sim record`: a launch-vehicle log of an ascent scenario.
pub fn record(scenario: &Path, out: &Path, duration: Option<f64>, truth_every: u64, compact: bool) -> Result<()> {
    anyhow::ensure!(
        LvScenario::is_lv_file(scenario),
        "{}: `record` writes launch-vehicle logs: the scenario must be `kind = \"{}\"` (spacecraft logs come from \
         a peer simulator, examples/basilisk/)",
        scenario.display(),
        ssis_sim::lv_replay::KIND
    );
    let sc = LvScenario::from_file(scenario)?;
    let duration_s = duration.unwrap_or(sc.duration_s);
    anyhow::ensure!(duration_s > 0.0 && duration_s.is_finite(), "--duration must be > 0");
    let steps = (duration_s / Profile::LAUNCH_VEHICLE.dt_s()).round() as u64;
    let mut f = std::io::BufWriter::new(output::create(out)?);
    ssis_sim::lv_replay::write_log(&sc, LogOptions { steps, truth_every: truth_every.max(1), full: !compact }, &mut f)?;
    f.into_inner().map_err(|e| anyhow::anyhow!("{}: cannot write: {}", out.display(), e.error()))?.commit()?;
    cli::report("record", || cli::json!({"scenario": sc.name, "steps": steps, "out": out.display().to_string()}));
    println!("wrote {} ({steps} steps of 1.25 ms)", out.display());
    Ok(())
}
