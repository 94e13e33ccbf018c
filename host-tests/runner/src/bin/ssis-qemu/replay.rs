//! `ssis-qemu --replay LOG`: a recorded log streamed to the firmware in QEMU (`ssis-fw`
//! for a spacecraft log, `ssis-fw-lv` for a launch-vehicle log). A spacecraft CSV log is
//! read as it is sent (`ssis_sim::streamed`: the conventions check on its first 600 s),
//! in memory bounded whatever its length; captures and a launch-vehicle log are read whole.

use std::cell::RefCell;

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
use ssis_sim::recorded::{self, LogStep, LogStream, LogUnit, Recorded};
use ssis_sim::replay::{farrenkopf_1sigma_arcsec, Encoder, Evidence, LogInfo, ReplaySummary, Rows};
use ssis_sim::streamed;

use super::Args;

/// Runs the replay; `Ok(false)` when the run was not clean.
pub fn run(a: &Args) -> Result<bool> {
    let table = match &a.table {
        Some(p) => ssis_common::table::read_any(p)?.0,
        None => CalibrationTable::DEFAULT,
    };
    if let [p] = a.replay.as_slice() {
        if recorded::is_csv(p) {
            let mut stream = LogStream::open(p)?;
            if stream.unit == LogUnit::Spacecraft {
                anyhow::ensure!(a.pad.is_none(), "--pad: {} is a spacecraft log (no navigation to start)", p.display());
                let head = streamed::read_head(&mut stream, &table)?;
                let rows = if head.next.is_some() { count_lines(p)? } else { head.rec.steps.len() as u64 };
                return run_spacecraft(a, &table, head, Some(stream), rows);
            }
        }
    }
    let rec = recorded::read_log(&a.replay)?;
    if rec.unit == LogUnit::LaunchVehicle {
        return run_lv_replay(a, &rec, &table);
    }
    anyhow::ensure!(a.pad.is_none(), "--pad: {} is a spacecraft log (no navigation to start)", rec.origin);
    let conventions = conventions::check_conventions(&rec, &table, Profile::SPACECRAFT.dt_us)?;
    let steps = rec.steps.len() as u64;
    run_spacecraft(a, &table, streamed::Head { rec, next: None, conventions }, None, steps)
}

/// Lines in the file at `p` (a streamed log's length for the progress bar, read without
/// holding it).
fn count_lines(p: &std::path::Path) -> Result<u64> {
    use std::io::Read;
    let mut f = std::fs::File::open(p).with_context(|| format!("cannot read {}", p.display()))?;
    let mut buf = vec![0u8; 1 << 20];
    let mut n = 0u64;
    loop {
        let k = f.read(&mut buf).with_context(|| format!("cannot read {}", p.display()))?;
        if k == 0 {
            return Ok(n);
        }
        n += buf.get(..k).unwrap_or_default().iter().filter(|&&b| b == b'\n').count() as u64;
    }
}

/// A spacecraft log on `ssis-fw` in QEMU: `head`'s steps (its conventions checked), then
/// the rest of `stream` as it is read (`None`: `head` is the whole log), in memory bounded
/// whatever the log's length; `rows` is the log's length as the progress bar counts it.
fn run_spacecraft(
    a: &Args,
    table: &CalibrationTable,
    head: streamed::Head,
    stream: Option<LogStream>,
    rows: u64,
) -> Result<bool> {
    let profile = Profile::SPACECRAFT;
    let streamed::Head { rec, next, conventions: conv } = head;
    cli::report("conventions", || ssis_sim::json::conventions(&conv));
    let Outputs { stem, csv_path, svg, title } = outputs(a, &rec.origin, "ssis-fw", &CSV_HEADER)?;
    let elf = super::firmware(a)?;
    std::fs::create_dir_all(&a.out).with_context(|| format!("cannot create {}", a.out.display()))?;
    let mut rows_out = super::Rows::new(&csv_path)?;
    let whole = stream.is_none().then(|| (LogInfo::of(&rec), rec.st_latency_s(profile.dt_us)));
    let origin = rec.origin.clone();
    let mut steps = rows;
    let mut last = u64::MAX;
    if let Some(d) = a.duration {
        last = (d / profile.dt_s()).round() as u64;
        steps = steps.min(last);
    }
    // The log's steps in order: the head, then the stream (errors kept for after the run).
    let stream = RefCell::new(stream);
    let failed: RefCell<Option<anyhow::Error>> = RefCell::new(None);
    let evidence = RefCell::new(Evidence::empty(table, a.settle));
    let mut enc = Encoder::new(table, profile.dt_us);
    let mut log = rec.steps.into_iter().chain(next);
    let mut pull = || -> Option<LogStep> {
        if let Some(s) = log.next() {
            return Some(s);
        }
        match stream.borrow_mut().as_mut()?.next_step() {
            Ok(s) => s,
            Err(e) => {
                *failed.borrow_mut() = Some(e);
                None
            }
        }
    };
    let feed = Feed {
        name: stem,
        profile,
        table: *table,
        steps,
        settle_s: a.settle,
        next: Box::new(|| {
            if enc.steps() >= last {
                return None;
            }
            let step = pull()?;
            let mut ev = evidence.borrow_mut();
            for st in &step.st {
                ev.star(st);
            }
            Some(enc.encode(&step))
        }),
        on_step: None,
    };
    let opts = super::options(a, &elf)?;
    let s = run_feed(feed, &opts, |f, r| {
        evidence.borrow_mut().frame(f);
        if let Some(r) = r {
            rows_out.take(r);
        }
    })?;
    if let Some(e) = failed.take() {
        return Err(e);
    }
    let (info, st_latency_s) = match (whole, stream.take()) {
        (Some(w), _) => w,
        (None, Some(st)) => (LogInfo::of_stream(&st), st.st_latency_s()),
        (None, None) => anyhow::bail!("{origin}: the log's stream was lost"),
    };
    let plotted = rows_out.finish(&csv_path, &svg, &title)?;
    let limit = farrenkopf_1sigma_arcsec(&table.observer, &table.axes(), profile.dt_s(), st_latency_s);
    let host_like = ReplaySummary {
        origin,
        steps: s.steps,
        duration_s: s.duration_s,
        accuracy: s.accuracy.clone(),
        evidence: evidence.into_inner(),
        frames_out: s.frames_out,
        hash: 0,
        events: ssis_common::downlink::records(&s.event_frames),
    };
    cli::report("run", || ssis_runner::json::qemu_summary(&s));
    cli::report("replay", || {
        let mut v = ssis_sim::json::replay_summary(&host_like);
        ssis_sim::json::add_limit_and_damage(&mut v, &limit, &info.problems);
        v
    });
    print!("{}", s.report());
    print!("{}", host_like.report_on(&info, Some(limit)));
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
    let Outputs { stem, csv_path, svg, title } = outputs(a, &rec.origin, "ssis-fw-lv", &LV_CSV_HEADER)?;
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

/// Names and claims the outputs of a replay of the log `origin` on `firmware`, whose CSV
/// has `header`.
fn outputs(a: &Args, origin: &str, firmware: &str, header: &[&str]) -> Result<Outputs> {
    let stem = a.replay[0].file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_else(|| "log".into());
    let csv_path = a.out.join(format!("{stem}-replay-qemu.csv"));
    let svg = a.out.join(format!("{stem}-replay-qemu.svg"));
    let title = format!("replay of {origin} on {firmware} in QEMU");
    output::claim(&csv_path, Origin::Default(Own::CsvHeader(header.join(","))))?;
    output::claim(&svg, Origin::Default(Own::Svg(title.clone())))?;
    Ok(Outputs { stem, csv_path, svg, title })
}
