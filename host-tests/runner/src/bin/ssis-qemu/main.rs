//! `ssis-qemu`: run a scenario on the firmware in QEMU (mps2-an500), fed by the
//! simulator over the emulated UARTs, and report against truth. `--help` for options.
//!
//! Pacing: by default lockstep at the real rate (the unit is held when the host falls
//! behind, so the result does not depend on the host's load; the lateness is reported);
//! `--lockstep` as fast as the host goes; `--real-time` the firmware's own tick, which
//! measures the host as much as the unit and fails the run when the host delayed more
//! than `--max-host-late-pct` of the steps.
//! A launch-vehicle ascent scenario (`kind = "lv-ascent"`, e.g. `scenarios/lv-ascent.toml`)
//! runs on `ssis-fw-lv` at 1.25 ms in lockstep (`ssis_runner::qemu_lv`).

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::{Context, Result};
use clap::Parser;
use ssis_common::cli;
use ssis_common::output::{self, Origin, Own};
use ssis_common::plot::{write_svg, PlotPoint};
use ssis_runner::qemu::{build_firmware, default_elf, elf_sizes, is_test_build, run_qemu, QemuOptions};
use ssis_runner::qemu_lv::{run_qemu_lv, LvOptions, LvScenario};
use ssis_sim::harness::CSV_HEADER;
use ssis_sim::scenario::Scenario;

mod replay;

#[derive(Parser)]
#[command(name = "ssis-qemu", version, about = "Run a simulated flight on the firmware in QEMU")]
struct Args {
    /// Scenario file (TOML).
    #[arg(required_unless_present = "replay")]
    scenario: Option<PathBuf>,
    /// Replay a recorded log instead (docs/RECORDED-LOG.md: a CSV, or raw captures of the
    /// links): the same bytes `ssis-sim replay` steps the core on, streamed to the
    /// firmware; the summary against truth where the log has it, and the unit's own
    /// evidence.
    #[arg(long, num_args = 1.., conflicts_with = "scenario")]
    replay: Vec<PathBuf>,
    /// --replay: the unit's calibration table (.toml, .bin or .img; default nominal).
    #[arg(long, requires = "replay")]
    table: Option<PathBuf>,
    /// --replay of a launch-vehicle log: the pad initialisation block (`SSPI`) to start
    /// from, in place of the log's `init_*` columns (a capture has none).
    #[arg(long, requires = "replay")]
    pad: Option<PathBuf>,
    /// --replay: statistics start this long after the log's first sample, s.
    #[arg(long, default_value_t = 60.0)]
    settle: f64,
    /// The UARTs as pseudo-terminals (`-serial pty`) driven through the real serial-port
    /// path (`serialport`, the ICD's framing), instead of Unix sockets: the
    /// hardware-in-the-loop path, tested on QEMU.
    #[arg(long, conflicts_with = "board")]
    pty: bool,
    /// Hardware in the loop without QEMU: a unit already running (the STM32H7 board
    /// through USB–RS-422 adapters, boards/stm32h7/README.md, or QEMU started by hand with
    /// `-serial pty`) on three serial ports, OUT,FOG,STAR: UART0 (output frames out,
    /// control frames in), UART1 (FOG bus), UART2 (star tracker); each PATH or PATH@BAUD
    /// (default 921600), 8N1 without flow control as docs/ICD.md says. Its flash must hold
    /// the run's table (--table for a replay). --elf names the firmware it runs (a test
    /// build: lockstep; a flight build: real time).
    #[arg(long, value_name = "OUT,FOG,STAR")]
    board: Option<String>,
    /// Firmware ELF (default: build the test build and use
    /// target/test-hooks/thumbv7em-none-eabihf/release/ssis-fw-test, or ssis-fw-lv-test for
    /// a launch-vehicle ascent). A flight build (ssis-fw) ignores control frames: it runs
    /// in real time only, and the runner stops it at the end.
    #[arg(long)]
    elf: Option<PathBuf>,
    /// Lockstep as fast as the host goes, not paced at the real rate (the output is the
    /// same). A launch-vehicle ascent always runs in lockstep.
    #[arg(long, conflicts_with = "real_time")]
    lockstep: bool,
    /// Free-running real time on the firmware's own tick, QEMU's clock following the
    /// host's: a study of the deadline on this host. Exits non-zero when the host
    /// delayed more than --max-host-late-pct of the steps.
    #[arg(long)]
    real_time: bool,
    /// --real-time: the share of steps (samples sent after their tick plus overruns)
    /// the host may delay before the run fails, %.
    #[arg(long, default_value_t = 0.5)]
    max_host_late_pct: f64,
    /// Step times in instructions (-icount shift=0). Lockstep runs always count them;
    /// with --real-time, virtual time then runs at one instruction per ns while busy.
    #[arg(long)]
    icount: bool,
    /// Damage every N-th byte sent on every link (alternately a bit flip and a drop).
    #[arg(long, default_value_t = 0)]
    corrupt_every: u64,
    /// Output directory for the CSV log and the SVG plot (SCENARIO-qemu.csv and .svg: a
    /// file there that is not one of ours is replaced only with --force).
    #[arg(long, default_value = "out")]
    out: PathBuf,
    /// Fail the run when the attitude error 3σ after settling exceeds this on any axis,
    /// arcsec (an acceptance bound for scripted runs).
    #[arg(long)]
    max_att_3sigma_arcsec: Option<f64>,
    /// Shorten the scenario to this many seconds.
    #[arg(long)]
    duration: Option<f64>,
    /// The estimator that flies, replacing the scenario's: `luenberger` (the paper's
    /// eq. 6 observer) or `mekf` (spacecraft scenarios).
    #[arg(long, value_parser = ssis_sim::scenario::parse_estimator)]
    estimator: Option<ssis::calib::Estimator>,
    #[command(flatten)]
    flags: cli::Flags,
}

fn main() -> ExitCode {
    let a = Args::parse();
    cli::finish(a.flags.start("ssis-qemu").and_then(|()| real_main(a)))
}

fn real_main(a: Args) -> Result<bool> {
    cli::report("command", || cli::json!(if a.replay.is_empty() { "run" } else { "replay" }));
    for p in a.scenario.iter().chain(&a.replay).chain(&a.table).chain(&a.pad) {
        output::input(p);
    }
    if let Some(e) = &a.elf {
        output::input(e);
    }
    let Some(scenario) = a.scenario.clone() else { return replay::run(&a) };
    if LvScenario::is_lv_file(&scenario) {
        return run_lv(&a, &scenario);
    }
    let mut sc = Scenario::from_file(&scenario)?;
    if let Some(d) = a.duration {
        sc.duration_s = d;
        sc.settle_s = sc.settle_s.min(d / 2.0);
    }
    if a.estimator.is_some() {
        sc.table.estimator = a.estimator;
    }
    let csv_path = a.out.join(format!("{}-qemu.csv", sc.name));
    let svg = a.out.join(format!("{}-qemu.svg", sc.name));
    let svg_title = format!("{} on ssis-fw in QEMU", sc.name);
    output::claim(&csv_path, Origin::Default(Own::CsvHeader(CSV_HEADER.join(","))))?;
    output::claim(&svg, Origin::Default(Own::Svg(svg_title.clone())))?;
    let elf = firmware(&a)?;
    std::fs::create_dir_all(&a.out).with_context(|| format!("cannot create {}", a.out.display()))?;
    let mut rows = Rows::new(&csv_path)?;
    let opts = options(&a, &elf)?;
    let real_time = !opts.lockstep;
    let s = run_qemu(&sc, &opts, |r| rows.take(r))?;
    rows.finish(&csv_path, &svg, &svg_title)?;
    cli::report("run", || ssis_runner::json::qemu_summary(&s));
    print!("{}", s.report());
    if let Ok((flash, ram)) = elf_sizes(&elf) {
        println!("ELF: flash {flash} bytes, static RAM {ram} bytes");
    }
    println!("wrote {} and {}", csv_path.display(), svg.display());
    let clean = s.clean();
    if let Some(max) = a.max_att_3sigma_arcsec {
        let att = s.accuracy.att.three_sigma();
        if !att.iter().all(|e| *e <= max) {
            eprintln!("error: attitude error 3σ {att:.2?}″ exceeds --max-att-3sigma-arcsec {max}");
            return Ok(false);
        }
    }
    let late_pct = s.host.late_pct(s.steps, u64::from(s.last_frame.counters.overruns));
    if real_time && late_pct > a.max_host_late_pct {
        eprintln!(
            "error: the host delayed {late_pct:.2} % of the steps (over --max-host-late-pct {}): this run measured \
             the host, not the unit; rerun without --real-time",
            a.max_host_late_pct
        );
        return Ok(false);
    }
    Ok(clean)
}

/// The per-step CSV (every 20th evaluated output) and the plot's points.
struct Rows {
    w: csv::Writer<output::AtomicFile>,
    points: Vec<PlotPoint>,
    n: u64,
}

impl Rows {
    fn new(csv_path: &std::path::Path) -> Result<Rows> {
        let mut w = csv::Writer::from_writer(output::create(csv_path)?);
        w.write_record(CSV_HEADER)?;
        Ok(Rows { w, points: Vec::new(), n: 0 })
    }

    fn take(&mut self, r: &ssis_sim::harness::Record) {
        self.n += 1;
        if self.n.is_multiple_of(20) {
            let _ = self.w.write_record(r.csv_row());
            self.points.push(PlotPoint { t_s: r.t_s, att_arcsec: r.att_err_arcsec, rate_deg_h: r.rate_err_deg_h });
        }
    }

    /// Commits the CSV and writes the plot (none without points); whether it did.
    fn finish(self, csv_path: &std::path::Path, svg: &std::path::Path, title: &str) -> Result<bool> {
        self.w
            .into_inner()
            .map_err(|e| anyhow::anyhow!("{}: cannot write: {}", csv_path.display(), e.error()))?
            .commit()?;
        if self.points.is_empty() {
            return Ok(false);
        }
        write_svg(svg, title, &self.points)?;
        Ok(true)
    }
}

/// The firmware: `--elf`, or the test build (built if out of date).
fn firmware(a: &Args) -> Result<PathBuf> {
    Ok(match &a.elf {
        Some(e) => e.clone(),
        None => {
            build_firmware()?;
            default_elf()
        }
    })
}

/// How to run `elf`: lockstep (paced unless --lockstep), or real time for --real-time and
/// for a flight build (it ignores control frames); over QEMU's sockets or ptys, or a
/// running board's serial ports.
fn options(a: &Args, elf: &std::path::Path) -> Result<QemuOptions> {
    let real_time = a.real_time || !a.lockstep && !is_test_build(elf)?;
    if real_time && !a.real_time {
        eprintln!(
            "note: {} is a flight build (no test hooks): it runs in real time (--real-time); the test build \
             (the default ELF) runs paced lockstep",
            elf.display()
        );
    }
    let board = a.board.as_deref().map(ssis_runner::transport::BoardPorts::parse).transpose()?;
    Ok(QemuOptions {
        lockstep: !real_time,
        paced: !real_time && !a.lockstep,
        icount: a.icount,
        corrupt_every: a.corrupt_every,
        progress: true,
        transport: transport(a),
        board,
        ..QemuOptions::lockstep(elf.to_path_buf())
    })
}

/// The UARTs' transport the options ask for.
fn transport(a: &Args) -> ssis_runner::transport::Transport {
    if a.pty {
        ssis_runner::transport::Transport::Pty
    } else {
        ssis_runner::transport::Transport::Sockets
    }
}

/// A launch-vehicle ascent on `ssis-fw-lv` (lockstep at 1.25 ms).
fn run_lv(a: &Args, scenario: &std::path::Path) -> Result<bool> {
    let mut sc = LvScenario::from_file(scenario)?;
    if let Some(d) = a.duration {
        sc.duration_s = d;
    }
    anyhow::ensure!(a.corrupt_every == 0, "--corrupt-every is not supported for a launch-vehicle ascent");
    anyhow::ensure!(a.board.is_none(), "--board: a launch-vehicle ascent runs on QEMU only");
    let elf = match &a.elf {
        Some(e) => e.clone(),
        None => ssis_runner::qemu_lv::build_firmware()?,
    };
    anyhow::ensure!(!a.real_time, "a launch-vehicle ascent runs in lockstep only (no --real-time)");
    let s = run_qemu_lv(&sc, &LvOptions { elf: elf.clone(), progress: true })?;
    cli::report("run", || ssis_runner::json::lv_summary(&s));
    print!("{}", s.report());
    if let Ok((flash, ram)) = elf_sizes(&elf) {
        println!("ELF: flash {flash} bytes, static RAM {ram} bytes");
    }
    Ok(s.clean())
}
