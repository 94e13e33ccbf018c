//! `ssis-qemu --replay LOG`: a recorded log streamed to the firmware in QEMU (`ssis-fw`
//! for a spacecraft log, `ssis-fw-lv` for a launch-vehicle log).

use anyhow::{Context, Result};
use ssis::calib::CalibrationTable;
use ssis::flight::Profile;
use ssis_common::cli;
use ssis_common::output::{self, Origin, Own};
use ssis_runner::qemu::{run_feed, Feed};
use ssis_runner::qemu_lv::{run_lv, LvOptions, LvRun};
use ssis_sim::conventions;
use ssis_sim::harness::CSV_HEADER;
use ssis_sim::lv_replay::{pad_for, LvFeed, LvReplaySummary, NavEvidence, LV_CSV_HEADER};
use ssis_sim::recorded::{self, LogUnit, Recorded};
use ssis_sim::replay::{farrenkopf_1sigma_arcsec, Evidence, Feed as LogFeed, ReplaySummary, Rows};

use super::Args;

/// Runs the replay; `Ok(false)` when the run was not clean.
pub fn run(a: &Args) -> Result<bool> {
    let table = match &a.table {
        Some(p) => ssis_common::table::read_any(p)?.0,
        None => CalibrationTable::DEFAULT,
    };
    let profile = Profile::SPACECRAFT;
    let rec = recorded::read_log(&a.replay)?;
    if rec.unit == LogUnit::LaunchVehicle {
        return run_lv_replay(a, &rec, &table);
    }
    anyhow::ensure!(a.pad.is_none(), "--pad: {} is a spacecraft log (no navigation to start)", rec.origin);
    let conv = conventions::check_conventions(&rec, &table, profile.dt_us)?;
    cli::report("conventions", || ssis_sim::json::conventions(&conv));
    let Outputs { stem, csv_path, svg, title } = outputs(a, &rec, "ssis-fw", &CSV_HEADER)?;
    let elf = super::firmware(a)?;
    std::fs::create_dir_all(&a.out).with_context(|| format!("cannot create {}", a.out.display()))?;
    let mut rows = super::Rows::new(&csv_path)?;
    let mut log_feed = LogFeed::new(&rec, &table, profile.dt_us);
    let mut steps = log_feed.steps();
    if let Some(d) = a.duration {
        steps = steps.min((d / profile.dt_s()).round() as u64);
    }
    let feed = Feed {
        name: stem,
        profile,
        table,
        steps,
        settle_s: a.settle,
        next: Box::new(move || log_feed.next_step().filter(|i| i.n <= steps)),
        on_step: None,
    };
    let opts = super::options(a, &elf)?;
    let mut evidence = Evidence::new(&rec, &table, a.settle);
    let s = run_feed(feed, &opts, |f, r| {
        evidence.frame(f);
        if let Some(r) = r {
            rows.take(r);
        }
    })?;
    let plotted = rows.finish(&csv_path, &svg, &title)?;
    let limit =
        farrenkopf_1sigma_arcsec(&table.observer, &table.axes(), profile.dt_s(), rec.st_latency_s(profile.dt_us));
    let host_like = ReplaySummary {
        origin: rec.origin.clone(),
        steps: s.steps,
        duration_s: s.duration_s,
        accuracy: s.accuracy.clone(),
        evidence: evidence.clone(),
        frames_out: s.frames_out,
        hash: 0,
        events: ssis_common::downlink::records(&s.event_frames),
    };
    cli::report("run", || ssis_runner::json::qemu_summary(&s));
    cli::report("replay", || {
        let mut v = ssis_sim::json::replay_summary(&host_like);
        ssis_sim::json::add_limit_and_damage(&mut v, &limit, &rec.problems);
        v
    });
    print!("{}", s.report());
    print!("{}", host_like.report(&rec, Some(limit)));
    print!("{}", conv.report());
    println!("wrote {}{}", csv_path.display(), if plotted { format!(" and {}", svg.display()) } else { String::new() });
    if let Some(w) = conv.warning() {
        println!("{w}");
    }
    Ok(s.clean() && conv.findings.is_empty())
}

/// A launch-vehicle log on `ssis-fw-lv` in QEMU (lockstep at 1.25 ms), every output frame
/// compared with the host's `LvCore`; the report of `ssis-sim replay` on the firmware's
/// navigation frames.
fn run_lv_replay(a: &Args, rec: &Recorded, table: &ssis::calib::CalibrationTable) -> Result<bool> {
    anyhow::ensure!(a.board.is_none() && !a.pty, "--board, --pty: a launch-vehicle log replays on QEMU's sockets only");
    anyhow::ensure!(!a.real_time, "a launch-vehicle log replays in lockstep only (no --real-time)");
    anyhow::ensure!(a.corrupt_every == 0, "--corrupt-every is not supported for a launch-vehicle log");
    let init = pad_for(rec, a.pad.as_deref())?;
    let conv = conventions::check_lv(rec, table, &init.state);
    cli::report("conventions", || ssis_sim::json::lv_conventions(&conv));
    let Outputs { stem, csv_path, svg, title } = outputs(a, rec, "ssis-fw-lv", &LV_CSV_HEADER)?;
    let elf = match &a.elf {
        Some(e) => e.clone(),
        None => ssis_runner::qemu_lv::build_firmware()?,
    };
    std::fs::create_dir_all(&a.out).with_context(|| format!("cannot create {}", a.out.display()))?;
    let mut feed = LvFeed::new(rec);
    let mut steps = feed.steps();
    if let Some(d) = a.duration {
        steps = steps.min((d / Profile::LAUNCH_VEHICLE.dt_s()).round() as u64);
    }
    let run = LvRun {
        name: stem,
        steps,
        table: *table,
        init,
        next: Box::new(move |n| feed.next_step().filter(|_| n <= steps)),
    };
    let mut evidence = NavEvidence::new(rec);
    let mut rows = Rows::new(Some(&csv_path), &LV_CSV_HEADER, 20)?;
    let s = run_lv(run, &LvOptions { elf, progress: true }, |f| {
        if let Some(r) = evidence.frame(f) {
            rows.take(|| r.csv_row(), (r.t_s, r.att_err_arcsec.into(), r.pos_err_m.into()));
        }
    })?;
    let points = rows.finish()?;
    if !points.is_empty() {
        let captions = ["attitude error, arcsec, body axes (x red, y green, z blue)", "position error, m, ECEF"];
        ssis_common::plot::write_svg_panels(&svg, &title, captions, &points)?;
        println!("wrote {}", svg.display());
    }
    let host_like =
        LvReplaySummary { steps: s.steps, duration_s: s.duration_s, flight_frames: s.flight_frames, evidence, hash: 0 };
    cli::report("run", || ssis_runner::json::lv_summary(&s));
    cli::report("replay", || ssis_sim::json::lv_replay_summary(&host_like, rec));
    print!("{}", s.report());
    print!("{}", host_like.report(rec));
    print!("{}", conv.report());
    if let Some(w) = conv.warning() {
        println!("{w}");
    }
    Ok(s.clean() && conv.findings.is_empty())
}

/// A replay's CSV and plot, claimed before anything runs (`ssis_common::output`).
struct Outputs {
    stem: String,
    csv_path: std::path::PathBuf,
    svg: std::path::PathBuf,
    title: String,
}

/// Names and claims the outputs of a replay of `rec` on `firmware`, whose CSV has `header`.
fn outputs(a: &Args, rec: &Recorded, firmware: &str, header: &[&str]) -> Result<Outputs> {
    let stem = a.replay[0].file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_else(|| "log".into());
    let csv_path = a.out.join(format!("{stem}-replay-qemu.csv"));
    let svg = a.out.join(format!("{stem}-replay-qemu.svg"));
    let title = format!("replay of {} on {firmware} in QEMU", rec.origin);
    output::claim(&csv_path, Origin::Default(Own::CsvHeader(header.join(","))))?;
    output::claim(&svg, Origin::Default(Own::Svg(title.clone())))?;
    Ok(Outputs { stem, csv_path, svg, title })
}
