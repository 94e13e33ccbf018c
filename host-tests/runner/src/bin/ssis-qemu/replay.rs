//! `ssis-qemu --replay LOG`: a recorded log streamed to the firmware in QEMU.

use anyhow::{Context, Result};
use ssis::calib::CalibrationTable;
use ssis::flight::Profile;
use ssis_common::cli;
use ssis_common::output::{self, Origin, Own};
use ssis_runner::qemu::{run_feed, Feed};
use ssis_sim::harness::CSV_HEADER;
use ssis_sim::replay::{farrenkopf_1sigma_arcsec, Evidence, Feed as LogFeed, ReplaySummary};
use ssis_sim::{conventions, recorded};

use super::Args;

/// Runs the replay; `Ok(false)` when the run was not clean.
pub fn run(a: &Args) -> Result<bool> {
    let table = match &a.table {
        Some(p) => ssis_common::table::read_any(p)?.0,
        None => CalibrationTable::DEFAULT,
    };
    let profile = Profile::SPACECRAFT;
    let rec = recorded::read(&a.replay, profile.dt_us)?;
    let conv = conventions::check_conventions(&rec, &table, profile.dt_us)?;
    cli::report("conventions", || ssis_sim::json::conventions(&conv));
    let stem = a.replay[0].file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_else(|| "log".into());
    let csv_path = a.out.join(format!("{stem}-replay-qemu.csv"));
    let svg = a.out.join(format!("{stem}-replay-qemu.svg"));
    let title = format!("replay of {} on ssis-fw in QEMU", rec.origin);
    output::claim(&csv_path, Origin::Default(Own::CsvHeader(CSV_HEADER.join(","))))?;
    output::claim(&svg, Origin::Default(Own::Svg(title.clone())))?;
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
