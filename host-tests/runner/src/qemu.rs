//! The QEMU runner: the firmware ELF on `qemu-system-arm -machine mps2-an500`, fed by
//! the simulator over the emulated UARTs, its output frames decoded and compared with
//! truth.
//!
//! UART mapping (`docs/ICD.md`): UART0 = output frames out / control frames in,
//! UART1 = FOG bus, UART2 = star tracker. Each is a Unix socket the runner listens on
//! and QEMU connects to. The firmware's defmt log comes over semihosting on QEMU's
//! stdout and is decoded with the ELF's defmt table.
//!
//! Two pacings:
//! - real time: the firmware steps on its own 5 ms SysTick; the runner sends each step's
//!   frames at the real rate, a few steps ahead (the unit's time is its FOG sample
//!   clock, so the lead costs nothing), and never more than [`MAX_LEAD`] steps ahead of
//!   the outputs it has received;
//! - lockstep: the runner sends a step's bytes and a STEP control frame naming the byte
//!   totals, and waits for that step's output. Deterministic: the runner also runs the
//!   same `FlightCore` in-process on the same bytes and compares every output frame.

use std::io::{Read, Write};
use std::os::unix::net::{UnixListener, UnixStream};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::mpsc;
use std::time::{Duration, Instant};

use anyhow::{bail, Context, Result};
use ssis::calib::store;
use ssis::flight::{st_status, FlightCore, FogLinks, Links, Profile};
use ssis::frames::control::{command, ControlFrame};
use ssis::frames::event::EventFrame;
use ssis::frames::output::OutputFrame;
use ssis::telemetry::events::EventRecord;
use ssis::telemetry::{page, Counter};

use crate::progress::{Patience, ICOUNT_LOCKSTEP, QEMU_CPU_PATIENCE_S};
use crate::transport::{open_serial, read_pty_names, BoardPorts, Port, Transport, BAUD};
use ssis_common::downlink::{records, timeline, Down, Downlink};
use ssis_common::mock::{MockLink, MockSink};
use ssis_common::stats::AxisStats;
use ssis_sim::harness::{Accuracy, Evaluator, Observed, Record, Simulation, StepInput};
use ssis_sim::scenario::Scenario;

/// QEMU processor time without an output byte that shows the firmware has switched to
/// lockstep, s.
const SILENCE_CPU_S: f64 = 0.05;
/// Steps the runner may be ahead of the outputs it has received (real time).
pub const MAX_LEAD: u64 = 6;
/// Steps of frames sent before the first output is awaited (real time).
pub const LEAD: u64 = 4;
/// Instructions per SysTick tick under `-icount shift=0` (25 MHz SysTick, 1 GHz virtual).
pub const INSTR_PER_TICK: f64 = 40.0;

/// How to run.
#[derive(Debug, Clone)]
pub struct QemuOptions {
    /// Firmware ELF.
    pub elf: PathBuf,
    /// Lockstep (deterministic, with the in-process comparison) instead of real time.
    pub lockstep: bool,
    /// Lockstep paced at the real rate: no step is sent before its time, and a step the
    /// host could not send in time waits (the unit is held, nothing is lost); how far the
    /// run fell behind is reported ([`QemuSummary::host`]).
    pub paced: bool,
    /// `-icount shift=0`: one instruction per ns of virtual time, for instruction counts.
    pub icount: bool,
    /// Damage every N-th byte sent on every link, alternately a bit flip and a drop
    /// (0 = none).
    pub corrupt_every: u64,
    /// Show a progress bar.
    pub progress: bool,
    /// Fault injection (lockstep, firmware built with `test-hooks`): at this step send
    /// `STALL` instead of `STEP`, then wait for the watchdog to end the run.
    pub stall_at_step: Option<u64>,
    /// Flash image of the calibration table region to load instead of the scenario
    /// table's two-copy image (`ssis::calib::store`), e.g. with one copy damaged. The
    /// in-process comparison still uses the scenario's table.
    pub table_image: Option<Vec<u8>>,
    /// A sensor fault injected into the simulator's frames before they are sent
    /// (`ssis_faults`); the in-process comparison gets the same bytes.
    pub fault: Option<ssis_faults::Fault>,
    /// The runner itself stops for this long before sending this step (a host that falls
    /// behind, made repeatable for tests of the lateness report).
    pub host_stall: Option<(u64, Duration)>,
    /// The command key's record to load into the KEY region (`ssis::telecommand::auth`;
    /// none: the unit has no key and refuses every telecommand).
    pub key_record: Option<Vec<u8>>,
    /// Telecommand bytes sent on UART0 before a step's STEP frame, by step (lockstep);
    /// the in-process core's command link gets the same bytes before the same step.
    pub commands: Vec<(u64, Vec<u8>)>,
    /// How the UARTs are reached: Unix sockets, or pseudo-terminals through the serial-port
    /// path (the hardware-in-the-loop path).
    pub transport: Transport,
    /// A unit already running, on serial ports the user names (a board through
    /// USB–RS-422 adapters, or QEMU started by hand with `-serial pty`): no QEMU is
    /// started, `transport`, `table_image` and `key_record` are not used (the board's
    /// flash holds its table: the same as the feed's, or the frames differ), the waits
    /// are in wall time, and the run ends with END without waiting for an exit.
    pub board: Option<BoardPorts>,
}

impl QemuOptions {
    /// A lockstep run of `elf` with nothing else: no instruction counting, no damage, no
    /// progress bar, no stall, the scenario's table, no fault (set what a run needs with
    /// `..QemuOptions::lockstep(elf)`).
    pub fn lockstep(elf: PathBuf) -> QemuOptions {
        QemuOptions {
            elf,
            lockstep: true,
            paced: false,
            icount: false,
            corrupt_every: 0,
            progress: false,
            stall_at_step: None,
            table_image: None,
            fault: None,
            host_stall: None,
            key_record: None,
            commands: Vec::new(),
            transport: Transport::Sockets,
            board: None,
        }
    }
}

/// What a QEMU run measured.
#[derive(Debug, Clone, Default)]
pub struct QemuSummary {
    /// Scenario name.
    pub name: String,
    /// Steps sent.
    pub steps: u64,
    /// Simulated time, s.
    pub duration_s: f64,
    /// How well the run followed the truth.
    pub accuracy: Accuracy,
    /// FOG frames sent.
    pub fog_frames_in: u64,
    /// Star-tracker frames sent.
    pub st_frames_in: u64,
    /// Output frames decoded.
    pub frames_out: u64,
    /// Output bytes that did not decode.
    pub frames_out_bad: u64,
    /// Lockstep: frames the firmware sent on its own tick before the first sample.
    pub frames_before_data: u64,
    /// The unit's counters from its last output frame.
    pub last_frame: OutputFrame,
    /// The counter page as last seen, by page id (`ssis::telemetry::page`).
    pub paged: Vec<u16>,
    /// Lockstep: output frames identical to the in-process core's.
    pub equal_frames: u64,
    /// Lockstep: output frames that differ from the in-process core's.
    pub differing_frames: u64,
    /// Step time (ticks) of steps without / with a star-tracker update.
    pub step_ticks: AxisStats,
    /// Largest step time, ticks, without / with a star-tracker update.
    pub step_ticks_max: [u32; 2],
    /// Mean step time, ticks, without / with a star-tracker update, and counts.
    pub step_ticks_mean: [f64; 2],
    /// Steps counted in the means.
    pub step_counts: [u64; 2],
    /// Decoded defmt log lines.
    pub log: Vec<String>,
    /// QEMU's exit status (0 = the firmware ended the run cleanly).
    pub exit_code: Option<i32>,
    /// With an injected stall (see [`QemuOptions::stall_at_step`]): the time from the
    /// STALL command to QEMU's exit, s (`None`: still running after 20 s, stopped).
    pub stalled_exit_s: Option<f64>,
    /// Wall time, s.
    pub wall_s: f64,
    /// Whether instruction counting was on.
    pub icount: bool,
    /// How well the host kept the run's pace.
    pub host: HostPace,
    /// The firmware was a flight build (no test hooks): run in real time and stopped by
    /// the runner at the end, since it ignores END (no end-of-run report).
    pub flight_build: bool,
    /// Command reports the firmware sent (after the output frame of a step in which a
    /// STATUS telecommand was accepted).
    pub command_reports: Vec<ssis::frames::telecommand::CommandReport>,
    /// Lockstep: the command reports of the in-process core's command link.
    pub reference_reports: Vec<ssis::frames::telecommand::CommandReport>,
    /// The event frames the firmware sent.
    pub event_frames: Vec<EventFrame>,
    /// Lockstep: the in-process core's events.
    pub reference_events: Vec<EventRecord>,
    /// (time tag µs, page id, value) of every output frame whose counter page is a unit
    /// counter (`ssis::telemetry::PAGED`: the command link's counters, the active table).
    pub unit_pages: Vec<(u64, u8, u16)>,
    /// The unit was a running board on serial ports ([`QemuOptions::board`]): no exit
    /// status, no log.
    pub board: bool,
}

impl QemuSummary {
    /// A report a person can read.
    pub fn report(&self) -> String {
        use std::fmt::Write;
        let mut s = String::new();
        let _ = writeln!(
            s,
            "scenario  {}  in QEMU mps2-an500 ({:.0} s simulated, {} steps, wall {:.1} s)",
            self.name, self.duration_s, self.steps, self.wall_s
        );
        s.push_str(&self.accuracy.table());
        let c = &self.last_frame.counters;
        let _ = writeln!(
            s,
            "frames in: FOG {} star {}; out: {} decoded, {} bad bytes",
            self.fog_frames_in, self.st_frames_in, self.frames_out, self.frames_out_bad
        );
        let _ = writeln!(
            s,
            "unit counters: FOG rejected {}, missing {}; star accepted {}, rejected {}, gated {}; overruns {}",
            c.fog_frames_rejected,
            c.fog_samples_missing,
            c.st_frames_accepted,
            c.st_frames_rejected,
            c.st_updates_gated,
            c.overruns
        );
        let _ = writeln!(
            s,
            "star-tracker timing: late (older than the attitude history) {}, early (ahead of the unit's clock) {}",
            self.paged_counter(Counter::StFramesLate),
            self.paged_counter(Counter::StFramesEarly)
        );
        let unit = if self.icount { "instructions" } else { "SysTick ticks (40 ns)" };
        let k = if self.icount { INSTR_PER_TICK } else { 1.0 };
        let _ = writeln!(
            s,
            "step time, {unit}: mean {:.0} / worst {:.0} (no star update, {} steps); mean {:.0} / worst {:.0} (star update, {} steps)",
            self.step_ticks_mean[0] * k,
            f64::from(self.step_ticks_max[0]) * k,
            self.step_counts[0],
            self.step_ticks_mean[1] * k,
            f64::from(self.step_ticks_max[1]) * k,
            self.step_counts[1]
        );
        if let Some(l) = self.host.line(self.steps, u64::from(c.overruns)) {
            let _ = writeln!(s, "{l}");
        }
        if self.equal_frames + self.differing_frames > 0 {
            let _ = writeln!(
                s,
                "host/QEMU equivalence: {} output frames identical, {} different",
                self.equal_frames, self.differing_frames
            );
        }
        let (events, lost) = records(&self.event_frames);
        s.push_str(&timeline(&events, lost));
        if let Some(same) = self.events_match() {
            let _ = writeln!(
                s,
                "host/QEMU events: {}",
                if same { "identical" } else { "DIFFERENT from the in-process core's" }
            );
        }
        for l in &self.log {
            let _ = writeln!(s, "firmware: {l}");
        }
        if self.board {
            let _ = writeln!(s, "board on serial ports: END sent, left running (no exit status, no log)");
        } else if self.flight_build {
            let _ = writeln!(s, "QEMU stopped by the runner (a flight build ignores END: no end-of-run report)");
        } else {
            let _ = writeln!(s, "QEMU exit: {:?}", self.exit_code);
        }
        s
    }

    /// Whether the run ended as it should: every output decoded, none different from
    /// the in-process core's (lockstep), and a clean exit (a flight build is stopped by
    /// the runner instead).
    pub fn clean(&self) -> bool {
        let ended = self.exit_code == Some(0) || (self.flight_build || self.board) && self.exit_code.is_none();
        ended
            && self.frames_out_bad == 0
            && self.differing_frames == 0
            && self.frames_out > 0
            && self.events_match() != Some(false)
    }

    /// Lockstep: whether the firmware's events are the in-process core's (`None`: not
    /// compared).
    pub fn events_match(&self) -> Option<bool> {
        (self.equal_frames + self.differing_frames > 0).then(|| records(&self.event_frames).0 == self.reference_events)
    }
}

impl QemuSummary {
    /// Unit counter `c` from the counter page as last seen (0 if never paged).
    pub fn paged_counter(&self, c: Counter) -> u16 {
        (0..page::COUNT)
            .find(|&id| page::entry(id) == Some(page::Entry::Unit(c)))
            .and_then(|id| self.paged.get(usize::from(id)).copied())
            .unwrap_or(0)
    }
}

/// How the run was paced, and how well this host kept up (the unit is not judged here).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct HostPace {
    /// The pacing: lockstep as fast as possible, lockstep at the real rate, or real time.
    pub mode: Pacing,
    /// Steps whose bytes the runner sent after the step's own tick (real time: the unit
    /// met the sample late or not at all; paced: the unit was held for it).
    pub late_steps: u64,
    /// The largest of those delays, s.
    pub late_max_s: f64,
    /// Real time: the largest lag of the output frames behind real time, s.
    pub out_lag_max_s: f64,
}

/// How a run is paced.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub enum Pacing {
    /// Lockstep as fast as the host goes (deterministic).
    #[default]
    Lockstep,
    /// Lockstep at the real rate (deterministic; a slow host delays, never drops).
    Paced,
    /// The firmware's own tick; QEMU's clock follows the host's.
    RealTime,
}

impl HostPace {
    /// Real time: the share of steps the host delayed (late sends plus the unit's
    /// overruns, which in real time under QEMU are the host's: the firmware's step needs
    /// a few per cent of its budget in counted instructions), %.
    pub fn late_pct(&self, steps: u64, overruns: u64) -> f64 {
        100.0 * (self.late_steps + overruns) as f64 / steps.max(1) as f64
    }

    /// The summary line on the host's pace (none for plain lockstep).
    fn line(&self, steps: u64, overruns: u64) -> Option<String> {
        let ms = |s: f64| s * 1e3;
        match self.mode {
            Pacing::Lockstep => None,
            Pacing::Paced if self.late_steps == 0 => {
                Some("pace: lockstep at the real rate, the host kept up (no step late)".into())
            }
            Pacing::Paced => Some(format!(
                "pace: lockstep at the real rate; the host fell behind on {} of {steps} steps, at most {:.2} s; \
                 the unit was held meanwhile, no sample lost",
                self.late_steps, self.late_max_s
            )),
            Pacing::RealTime if self.late_steps + overruns == 0 => Some(format!(
                "host kept up: every sample sent before its tick, outputs at most {:.0} ms behind real time",
                ms(self.out_lag_max_s)
            )),
            Pacing::RealTime => Some(format!(
                "host late: {} of {steps} samples sent after their tick (worst {:.0} ms), outputs up to {:.0} ms \
                 behind real time, {overruns} overruns caused by the host ({:.2} % of steps); QEMU's clock follows \
                 this host's, so the accuracy figures reflect the host, not the unit; rerun without --real-time",
                self.late_steps,
                ms(self.late_max_s),
                ms(self.out_lag_max_s),
                self.late_pct(steps, overruns)
            )),
        }
    }
}

/// The test build of the spacecraft firmware (`ssis-fw-test`, the runner's default):
/// `ssis-fw` with its test hooks, built by [`build_firmware`] into `target/test-hooks`.
pub fn default_elf() -> PathBuf {
    repo_root().join("target/test-hooks/thumbv7em-none-eabihf/release/ssis-fw-test")
}

/// The flight build of the spacecraft firmware (`cargo build --release` in `firmware/`):
/// it ignores control frames, so it runs only in real time.
pub fn flight_elf() -> PathBuf {
    repo_root().join("target/thumbv7em-none-eabihf/release/ssis-fw")
}

/// Whether `elf` is a test build (it defines the symbol of `ssis_firmware::mps2_test_hooks!`, so
/// it honours LOCKSTEP, STEP, END and STALL); a flight build ignores them.
pub fn is_test_build(elf: &Path) -> Result<bool> {
    use object::{Object, ObjectSymbol};
    let data = std::fs::read(elf).with_context(|| format!("cannot read {}", elf.display()))?;
    let file = object::File::parse(&*data)?;
    Ok(file.symbols().any(|s| s.name().is_ok_and(|n| n.starts_with("ERROR(ssis): test hooks"))))
}

/// Address of a symbol in an ELF.
pub fn symbol(elf: &Path, name: &str) -> Result<u64> {
    use object::{Object, ObjectSymbol};
    let data = std::fs::read(elf)?;
    let file = object::File::parse(&*data)?;
    file.symbols()
        .find(|s| s.name() == Ok(name))
        .map(|s| s.address())
        .with_context(|| format!("{} has no symbol {name}", elf.display()))
}

/// The repository root (`host-tests/runner/../..`).
pub fn repo_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).ancestors().nth(2).map(Path::to_path_buf).unwrap_or_default()
}

/// The firmware crate (`firmware/`: board support and firmware binaries), where the
/// firmware is built from.
pub fn firmware_dir() -> PathBuf {
    repo_root().join("firmware")
}

/// Builds the test build of the firmware (`ssis-fw-test`: release, thumb target, test
/// hooks) if it is out of date; what the runner and the QEMU tests run.
pub fn build_firmware() -> Result<PathBuf> {
    build_test_hooks_bin("ssis-fw-test")
}

/// Builds the flight firmware (`ssis-fw`, `cargo build --release` in `firmware/`) if it
/// is out of date.
pub fn build_flight_firmware() -> Result<PathBuf> {
    build_target_bin("ssis-fw")
}

/// Builds a target binary of the firmware crate (release) and returns its ELF path.
pub fn build_target_bin(name: &str) -> Result<PathBuf> {
    let status = cargo_build(&["--bin".as_ref(), name.as_ref()])?;
    if !status.success() {
        bail!("building {name} failed ({status})");
    }
    Ok(repo_root().join("target/thumbv7em-none-eabihf/release").join(name))
}

/// `cargo build --release --quiet` with `args` in `firmware/`, with the environment's
/// target directory and target unset (the `.cargo` configs there decide: the thumb
/// target, the root's `target/`).
fn cargo_build(args: &[&std::ffi::OsStr]) -> Result<std::process::ExitStatus> {
    Command::new("cargo")
        .args(["build", "--release", "--quiet"])
        .args(args)
        .current_dir(firmware_dir())
        .env_remove("CARGO_TARGET_DIR")
        .env_remove("CARGO_BUILD_TARGET")
        .status()
        .context("cannot run cargo to build the firmware")
}

/// Runs a target binary that needs no link (an on-target test) in QEMU until it exits
/// through semihosting or QEMU has used `patience` of processor time (a busy host does
/// not count against it, [`crate::progress`]); returns its exit code (`None`: stopped)
/// and its decoded defmt log.
pub fn run_bare(elf: &Path, patience: Duration) -> Result<(Option<i32>, Vec<String>)> {
    run_bare_with(elf, patience, false)
}

/// [`run_bare`], with `-icount shift=0` when `icount` (one instruction per ns of virtual
/// time: SysTick differences become instruction counts, [`INSTR_PER_TICK`] a tick).
pub fn run_bare_with(elf: &Path, patience: Duration, icount: bool) -> Result<(Option<i32>, Vec<String>)> {
    let mut cmd = Command::new("qemu-system-arm");
    cmd.args(["-machine", "mps2-an500", "-cpu", "cortex-m7", "-display", "none", "-monitor", "none"]).args([
        "-serial",
        "null",
        "-semihosting-config",
        "enable=on,target=native",
    ]);
    if icount {
        cmd.args(["-icount", ICOUNT_LOCKSTEP]);
    }
    let mut child = cmd
        .arg("-kernel")
        .arg(elf)
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .context("cannot start qemu-system-arm")?;
    let mut stdout = child.stdout.take().context("no stdout")?;
    let reader = std::thread::spawn(move || {
        let mut buf = Vec::new();
        let _ = stdout.read_to_end(&mut buf);
        buf
    });
    let status = wait_exit(&mut child, patience.as_secs_f64())?;
    if status.is_none() {
        let _ = child.kill();
        let _ = child.wait();
    }
    let log = reader.join().unwrap_or_default();
    Ok((status.and_then(|s| s.code()), decode_defmt(elf, &log)?))
}

/// Builds the firmware with the `test-hooks` feature (fault injection) into its own
/// target directory, so the flight build is left alone; returns the ELF path (the same
/// as [`build_firmware`]).
pub fn build_firmware_with_test_hooks() -> Result<PathBuf> {
    build_firmware()
}

/// Builds a target binary of the firmware crate with the `test-hooks` feature (release) into
/// `target/test-hooks`, so the flight build is left alone; returns its ELF path.
pub fn build_test_hooks_bin(name: &str) -> Result<PathBuf> {
    let dir = repo_root().join("target/test-hooks");
    let status = cargo_build(&[
        "--bin".as_ref(),
        name.as_ref(),
        "--features".as_ref(),
        "test-hooks".as_ref(),
        "--target-dir".as_ref(),
        dir.as_os_str(),
    ])?;
    if !status.success() {
        bail!("building {name} with test hooks failed ({status})");
    }
    Ok(dir.join("thumbv7em-none-eabihf/release").join(name))
}

/// A running QEMU; killed (and its socket directory removed) when dropped.
pub(crate) struct Qemu {
    pub(crate) child: Child,
    pub(crate) dir: PathBuf,
}

impl Drop for Qemu {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
        let _ = std::fs::remove_dir_all(&self.dir);
    }
}

pub(crate) fn accept(listener: &UnixListener, child: &mut Child, what: &str) -> Result<UnixStream> {
    listener.set_nonblocking(true)?;
    let patience = Patience::new(child, QEMU_CPU_PATIENCE_S);
    loop {
        match listener.accept() {
            Ok((s, _)) => {
                s.set_nonblocking(false)?;
                return Ok(s);
            }
            Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => {
                if let Some(st) = child.try_wait()? {
                    bail!("qemu-system-arm exited ({st}) before connecting {what}");
                }
                if let Some(why) = patience.exhausted() {
                    bail!("qemu-system-arm did not connect {what}: {why}");
                }
                std::thread::sleep(Duration::from_millis(5));
            }
            Err(e) => return Err(e.into()),
        }
    }
}

/// A QEMU started by [`start_qemu`]: the process, its UARTs (connected, in order) and the
/// thread collecting its stdout (the defmt log over semihosting).
pub(crate) struct Started {
    pub(crate) q: Qemu,
    pub(crate) uarts: Vec<Box<dyn Port>>,
    pub(crate) log_thread: std::thread::JoinHandle<Vec<u8>>,
}

/// Starts `qemu-system-arm -machine mps2-an500 -cpu cortex-m7` on `elf` with `n_uarts`
/// serial ports, each a Unix socket in `dir` (removed with the returned [`Qemu`]) or, with
/// [`Transport::Pty`], a pseudo-terminal opened as a serial port,
/// `-icount` with `icount` if given, semihosting, `-action watchdog=poweroff` (with
/// `-icount`; otherwise `none`), the arguments `extra` (the upset campaign's `-gdb`), and
/// each (file, address) of `loaders` loaded with `-device loader`; waits for every UART to
/// connect.
pub(crate) fn start_qemu(
    elf: &Path,
    dir: PathBuf,
    n_uarts: usize,
    icount: Option<&str>,
    loaders: &[(PathBuf, u64)],
    transport: Transport,
    extra: &[String],
) -> Result<Started> {
    let pty = transport == Transport::Pty;
    let socks: Vec<PathBuf> =
        if pty { Vec::new() } else { (0..n_uarts).map(|i| dir.join(format!("uart{i}.sock"))).collect() };
    let listeners = socks.iter().map(UnixListener::bind).collect::<std::io::Result<Vec<_>>>()?;
    let mut cmd = Command::new("qemu-system-arm");
    cmd.args(["-machine", "mps2-an500", "-cpu", "cortex-m7", "-display", "none", "-monitor", "none"]);
    cmd.args(["-semihosting-config", "enable=on,target=native"]);
    if let Some(ic) = icount {
        cmd.args(["-icount", ic]);
    }
    // A watchdog reset ends the run (a flight unit would reboot; here that would hide it)
    // when virtual time is the guest's instruction count. Free-running on the host's clock,
    // an emulator the host does not schedule for two watchdog periods is reset for the
    // host's doing, not the unit's: the reset is then left to the log (`watchdog_warnings`)
    // and the runner's own bounded waits.
    // Unless the caller chooses (the upset campaign follows a watchdog reset: `extra`).
    if !extra.iter().any(|a| a == "-action") {
        let on_watchdog = if icount.is_some() { "watchdog=poweroff" } else { "watchdog=none" };
        cmd.args(["-action", on_watchdog]);
    }
    for (i, p) in socks.iter().enumerate() {
        cmd.args(["-chardev", &format!("socket,id=u{i},path={}", p.display())]);
        cmd.args(["-serial", &format!("chardev:u{i}")]);
    }
    if pty {
        for _ in 0..n_uarts {
            cmd.args(["-serial", "pty"]);
        }
    }
    // Extra QEMU arguments for profiling (for example `-d in_asm,exec,nochain -D trace.log`,
    // read by `scripts/qemu-profile`); whitespace-separated.
    if let Ok(extra) = std::env::var("SSIS_QEMU_EXTRA_ARGS") {
        cmd.args(extra.split_whitespace());
    }
    cmd.args(extra);
    for (file, addr) in loaders {
        cmd.args(["-device", &format!("loader,file={},addr={addr:#x}", file.display())]);
    }
    cmd.arg("-kernel").arg(elf);
    cmd.stdin(Stdio::null()).stdout(Stdio::piped()).stderr(Stdio::piped());
    let child = cmd.spawn().context("cannot start qemu-system-arm")?;
    let mut q = Qemu { child, dir };
    // QEMU names its pseudo-terminals on its standard output, before the firmware's log.
    let mut stdout = std::io::BufReader::new(q.child.stdout.take().context("no stdout")?);
    let ptys = if pty { read_pty_names(&mut stdout, n_uarts)? } else { Vec::new() };
    let log_thread = std::thread::spawn(move || {
        let mut buf = Vec::new();
        let _ = stdout.read_to_end(&mut buf);
        buf
    });
    let mut uarts: Vec<Box<dyn Port>> = Vec::with_capacity(n_uarts);
    for (i, l) in listeners.iter().enumerate() {
        uarts.push(Box::new(accept(l, &mut q.child, &format!("UART{i}"))?));
    }
    for p in &ptys {
        uarts.push(Box::new(open_serial(p, BAUD)?));
    }
    Ok(Started { q, uarts, log_thread })
}

/// Reads `stream` on a thread until it closes, sending each chunk through `wrap` to `tx`.
pub(crate) fn spawn_reader<T: Send + 'static>(
    stream: &dyn Port,
    tx: mpsc::Sender<T>,
    wrap: impl Fn(Vec<u8>) -> T + Send + 'static,
) -> Result<()> {
    let mut reader = stream.try_clone_port()?;
    std::thread::spawn(move || {
        let mut buf = [0u8; 4096];
        while let Ok(n) = reader.read(&mut buf) {
            if n == 0 || tx.send(wrap(buf[..n].to_vec())).is_err() {
                break;
            }
        }
    });
    Ok(())
}

/// Damages every `every`-th byte (counted over the link's life): alternately flips one
/// of its bits and drops it.
struct Corrupter {
    every: u64,
    count: u64,
}

impl Corrupter {
    fn apply(&mut self, bytes: &[u8]) -> Vec<u8> {
        let mut v = Vec::with_capacity(bytes.len());
        for &b in bytes {
            self.count += 1;
            if self.every > 0 && self.count.is_multiple_of(self.every) {
                if (self.count / self.every).is_multiple_of(2) {
                    continue; // dropped
                }
                v.push(b ^ (1 << (self.count % 8)));
            } else {
                v.push(b);
            }
        }
        v
    }
}

/// Fails with a helpful message when `qemu-system-arm` or the firmware `elf` is missing.
pub(crate) fn check_qemu_and_elf(elf: &Path) -> Result<()> {
    if Command::new("qemu-system-arm").arg("--version").stdout(Stdio::null()).status().is_err() {
        bail!("qemu-system-arm not found: install it (Debian: apt-get install qemu-system-arm), or run `bash .ci/run` once");
    }
    anyhow::ensure!(elf.exists(), "firmware ELF {} missing: run `cargo build --release` in firmware/", elf.display());
    Ok(())
}

/// Called with a lockstep step's output frame and the event frames sent after it.
pub type OnStep<'a> = Box<dyn FnMut(&OutputFrame, &[EventFrame]) + 'a>;

/// What the runner streams to the unit: its table and profile, and its steps' bytes one
/// after the other (a simulated scenario, or a recorded log: `ssis_sim::replay::Feed`).
pub struct Feed<'a> {
    /// Name in the report.
    pub name: String,
    /// The unit's profile (the spacecraft unit's 5 ms).
    pub profile: Profile,
    /// The table the unit flies (loaded into its flash; the in-process core's too).
    pub table: ssis::calib::CalibrationTable,
    /// Steps to be sent.
    pub steps: u64,
    /// Statistics against truth from here, s.
    pub settle_s: f64,
    /// The next step's bytes, or `None` at the end.
    pub next: Box<dyn FnMut() -> Option<StepInput> + 'a>,
    /// Lockstep: called once a step's output is all in, with its output frame and the
    /// event frames the firmware sent after it (as many as the in-process core sent).
    pub on_step: Option<OnStep<'a>>,
}

/// Runs `sc` on the firmware in QEMU; `on_step` sees every evaluated output.
pub fn run_qemu(sc: &Scenario, opts: &QemuOptions, mut on_step: impl FnMut(&Record)) -> Result<QemuSummary> {
    let mut sim = Simulation::new(sc)?;
    if let Some(f) = &opts.fault {
        ssis_faults::mount_for(&mut sim, f);
    }
    let dt_s = sim.profile.dt_s();
    let sigma_st_rad = sc.star_tracker.sigma_3sigma_arcsec / 3.0 / ssis_common::ARCSEC_PER_RAD;
    let mut injector = opts.fault.map(|f| (f, ssis_faults::Injector::new(f, sigma_st_rad, sc.seed)));
    let mut injected = ssis_faults::FaultRun::default();
    let feed = Feed {
        name: sc.name.clone(),
        profile: sim.profile,
        table: sim.table,
        steps: sim.steps,
        settle_s: sc.settle_s,
        next: Box::new(move || {
            let mut input = sim.next_step()?;
            if let Some((f, inj)) = injector.as_mut() {
                let t_s = input.n as f64 * dt_s;
                let active = t_s > f.start_s && t_s <= f.start_s + f.duration_s;
                inj.apply(&mut input, active, t_s - f.start_s, &mut injected);
            }
            Some(input)
        }),
        on_step: None,
    };
    run_feed(feed, opts, |_, r| {
        if let Some(r) = r {
            on_step(r);
        }
    })
}

/// The summary of a run of `feed` before its first step.
fn new_summary(feed: &Feed<'_>, opts: &QemuOptions, flight_build: bool) -> QemuSummary {
    QemuSummary {
        name: feed.name.clone(),
        steps: feed.steps,
        duration_s: feed.steps as f64 * feed.profile.dt_s(),
        accuracy: Accuracy { settle_s: feed.settle_s, ..Default::default() },
        icount: opts.icount || opts.lockstep,
        paged: vec![0; usize::from(page::COUNT)],
        host: HostPace {
            mode: match (opts.lockstep, opts.paced) {
                (true, false) => Pacing::Lockstep,
                (true, true) => Pacing::Paced,
                (false, _) => Pacing::RealTime,
            },
            ..Default::default()
        },
        flight_build,
        board: opts.board.is_some(),
        ..Default::default()
    }
}

/// Holds step `n` as the run's pacing asks (a host stall injected at it; a paced run not
/// before its `tick`) and counts it late: in real time any send after the tick, paced only
/// a delay beyond a step (`dt_s`); plain lockstep keeps no pace.
fn pace_step(opts: &QemuOptions, n: u64, tick: Instant, dt_s: f64, host: &mut HostPace) {
    if let Some((_, d)) = opts.host_stall.filter(|(at, _)| *at == n) {
        std::thread::sleep(d);
    }
    if opts.lockstep && opts.paced {
        // Paced: not before its time; a late step is held, not dropped.
        let now = Instant::now();
        if now < tick {
            std::thread::sleep(tick - now);
        }
    }
    let late_s = Instant::now().saturating_duration_since(tick).as_secs_f64();
    let late = if opts.lockstep { opts.paced && late_s > dt_s } else { late_s > 0.0 };
    if late {
        host.late_steps += 1;
        host.late_max_s = host.late_max_s.max(late_s);
    }
}

/// How long a lockstep step waits, after its output frame, for the event frame the
/// in-process core sent in the same step.
const EVENT_FRAME_WAIT: Duration = Duration::from_secs(2);

/// Runs `feed` on the firmware in QEMU; `on_frame` sees every output frame with its record
/// against truth (when the feed has truth for it).
pub fn run_feed(
    mut feed: Feed<'_>,
    opts: &QemuOptions,
    mut on_frame: impl FnMut(&OutputFrame, Option<&Record>),
) -> Result<QemuSummary> {
    if opts.board.is_none() {
        check_qemu_and_elf(&opts.elf)?;
    }
    let flight_build = !is_test_build(&opts.elf)?;
    if flight_build && opts.lockstep {
        bail!(
            "{} is a flight build: it ignores LOCKSTEP, STEP and END. Lockstep needs the test build \
             (ssis-fw-test, in firmware/: `cargo build --release --bin ssis-fw-test --features test-hooks --target-dir ../target/test-hooks`)",
            opts.elf.display()
        );
    }
    anyhow::ensure!(feed.profile.dt_us == 5_000, "the QEMU firmware runs the spacecraft profile (5 ms)");
    let mut eval = Evaluator::for_unit(&feed.table, &feed.profile, feed.settle_s);
    let mut unit = Unit::boot(&feed.table, opts)?;
    let started = Instant::now();
    let bar = progress_bar(opts.progress, feed.steps, &feed.name);
    let mut s = new_summary(&feed, opts, flight_build);
    let mut outputs = Outputs::new(opts.lockstep);
    let mut reference = if opts.lockstep {
        unit.enter_lockstep(|_, b| s.frames_before_data += (b.len() / OutputFrame::LEN) as u64)?;
        Some(Reference::new(&feed.table, feed.profile, opts)?)
    } else {
        None
    };
    let mut sender = Sender::new(opts.corrupt_every);
    // Lockstep: event frames the in-process core sent so far.
    let mut expected_events = 0;
    let dt = Duration::from_micros(u64::from(feed.profile.dt_us));
    let dt_s = feed.profile.dt_s();
    // Real time from here: step n's tick is at t0 + n·Δt.
    let t0 = Instant::now();
    let tick = |n: u64| t0 + dt * (n as u32);
    let mut sent = 0;
    while let Some(input) = (feed.next)() {
        let n = input.n;
        sent += 1;
        if !opts.lockstep {
            // Real time: the frames of step n go out LEAD steps before its tick, and never
            // more than MAX_LEAD steps ahead of the outputs received.
            let due = t0 + dt * (n.saturating_sub(LEAD) as u32);
            loop {
                while let Ok((_, b)) = unit.rx.try_recv() {
                    outputs.take(&b, &mut s, &mut eval, &mut on_frame);
                    let lag = Instant::now().saturating_duration_since(tick(s.frames_out)).as_secs_f64();
                    s.host.out_lag_max_s = s.host.out_lag_max_s.max(lag);
                }
                if Instant::now() >= due && s.frames_out + MAX_LEAD >= n {
                    break;
                }
                if let Some(st) = unit.exited()? {
                    bail!("QEMU exited early ({st})");
                }
                std::thread::sleep(Duration::from_micros(200));
            }
        }
        pace_step(opts, n, tick(n), dt_s, &mut s.host);
        let (fog_sent, st_sent) = sender.send(&mut unit, &input, &feed.profile, &mut s)?;
        if let Some(t) = input.truth {
            eval.push_truth(t);
        }
        if let Some(r) = reference.as_mut() {
            let commands = crate::telecommands::due(&opts.commands, n);
            unit.uarts[0].write_all(&commands)?;
            let (frame, events) = r.step(&fog_sent, &st_sent, &commands, &mut s);
            outputs.check.reference.push_back(frame);
            expected_events += events;
            if opts.stall_at_step == Some(n) {
                return unit.stall(s, &opts.elf);
            }
            let step =
                ControlFrame { command: command::STEP, fog_bytes: sender.fog_total, st_bytes: sender.st_total, arg: 0 };
            unit.control(&step)?;
            let before = (s.frames_out, s.event_frames.len());
            let take = |s: &mut QemuSummary, _, b: &[u8]| outputs.take(b, s, &mut eval, &mut on_frame);
            unit.await_output(n, &opts.elf, &mut s, take, |s| s.frames_out != before.0)?;
            // The step's event frame follows its output frame: a moment for it to arrive (a
            // firmware that does not send it is told by `events_match`, not stopped here).
            let t = Instant::now();
            while s.event_frames.len() < expected_events && t.elapsed() < EVENT_FRAME_WAIT {
                if let Ok((_, b)) = unit.rx.recv_timeout(Duration::from_millis(20)) {
                    outputs.take(&b, &mut s, &mut eval, &mut on_frame);
                }
            }
            if let Some(f) = feed.on_step.as_mut() {
                f(&s.last_frame, s.event_frames.get(before.1..).unwrap_or_default());
            }
        }
        if let Some(b) = &bar {
            if n.is_multiple_of(200) {
                b.set_position(n);
            }
        }
    }
    // The run's length is what was sent (a streamed log's is known only at its end).
    s.steps = sent;
    s.duration_s = sent as f64 * dt_s;
    // Collect what is still coming, then end the run.
    let t_end = Instant::now();
    while s.frames_out < s.steps && t_end.elapsed() < Duration::from_secs(2) {
        if let Ok((_, b)) = unit.rx.recv_timeout(Duration::from_millis(50)) {
            outputs.take(&b, &mut s, &mut eval, &mut on_frame);
        }
    }
    // A flight build ignores END: it is stopped by `finish` below.
    let status = if flight_build { None } else { unit.end()? };
    while let Ok((_, b)) = unit.rx.try_recv() {
        outputs.take(&b, &mut s, &mut eval, &mut on_frame);
    }
    (s.exit_code, s.log) = unit.finish(status, bar, &opts.elf);
    for (k, t) in outputs.check.ticks.iter().enumerate() {
        s.step_ticks_mean[k] = t.mean()[0];
        s.step_counts[k] = t.count();
    }
    s.step_ticks = outputs.check.ticks[0];
    s.accuracy = eval.accuracy(outputs.check.last_drift);
    s.wall_s = started.elapsed().as_secs_f64();
    Ok(s)
}

/// A firmware running in QEMU: the process, its UARTs in order (UART0 takes the control
/// frames), the chunks its output UARTs send as they arrive (UART, bytes), and the thread
/// collecting the defmt log. The spacecraft runner and the launch-vehicle runner
/// (`crate::qemu_lv`) drive it alike.
pub(crate) struct Unit {
    /// The QEMU the runner started (`None`: a board already running, on serial ports).
    pub(crate) q: Option<Qemu>,
    pub(crate) uarts: Vec<Box<dyn Port>>,
    pub(crate) rx: mpsc::Receiver<(usize, Vec<u8>)>,
    /// Until the log is read ([`Unit::log`]).
    log_thread: Option<std::thread::JoinHandle<Vec<u8>>>,
}

impl Unit {
    /// Starts QEMU on `elf` with `n_uarts` UARTs, `-icount` with `icount` if given and the
    /// arguments `extra`; each
    /// (file name, bytes, address) of `images` is written to the run's directory and loaded
    /// into flash; a thread reads each UART of `outputs`.
    pub(crate) fn start(
        elf: &Path,
        n_uarts: usize,
        icount: Option<&str>,
        images: &[(&str, &[u8], u64)],
        outputs: &[usize],
        transport: Transport,
        extra: &[String],
    ) -> Result<Unit> {
        static RUN: std::sync::atomic::AtomicU32 = std::sync::atomic::AtomicU32::new(0);
        let k = RUN.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        let dir = std::env::temp_dir().join(format!("ssis-qemu-{}-{k}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir)?;
        let mut loaders = Vec::with_capacity(images.len());
        for (name, bytes, addr) in images {
            let path = dir.join(name);
            std::fs::write(&path, bytes)?;
            loaders.push((path, *addr));
        }
        let Started { q, uarts, log_thread } = start_qemu(elf, dir, n_uarts, icount, &loaders, transport, extra)?;
        Unit::with_uarts(Some(q), uarts, outputs, Some(log_thread))
    }

    /// A unit already running, on the serial ports `board` names (UART0, UART1, UART2 in
    /// order); a thread reads each UART of `outputs`.
    pub(crate) fn attach(board: &BoardPorts, outputs: &[usize]) -> Result<Unit> {
        let mut uarts: Vec<Box<dyn Port>> = Vec::with_capacity(board.links.len());
        for (path, baud) in &board.links {
            uarts.push(Box::new(open_serial(path, *baud)?));
        }
        Unit::with_uarts(None, uarts, outputs, None)
    }

    fn with_uarts(
        q: Option<Qemu>,
        uarts: Vec<Box<dyn Port>>,
        outputs: &[usize],
        log_thread: Option<std::thread::JoinHandle<Vec<u8>>>,
    ) -> Result<Unit> {
        let (tx, rx) = mpsc::channel();
        for &i in outputs {
            let uart = uarts.get(i).with_context(|| format!("no UART{i}"))?;
            spawn_reader(uart.as_ref(), tx.clone(), move |b| (i, b))?;
        }
        Ok(Unit { q, uarts, rx, log_thread })
    }

    /// QEMU's exit status if it has exited (a board never has one).
    pub(crate) fn exited(&mut self) -> Result<Option<std::process::ExitStatus>> {
        match self.q.as_mut() {
            Some(q) => Ok(q.child.try_wait()?),
            None => Ok(None),
        }
    }

    /// A wait allowing `cpu_s` of QEMU's processor time, or of wall time on a board.
    fn patience(&self, cpu_s: f64) -> Patience {
        match &self.q {
            Some(q) => Patience::new(&q.child, cpu_s),
            None => Patience::wall_clock(cpu_s),
        }
    }

    /// Waits for QEMU to exit ([`wait_exit`]); a board: `None` at once.
    fn wait_exit(&mut self, cpu_s: f64) -> Result<Option<std::process::ExitStatus>> {
        match self.q.as_mut() {
            Some(q) => wait_exit(&mut q.child, cpu_s),
            None => Ok(None),
        }
    }

    /// Stops QEMU (a board is left running).
    pub(crate) fn kill(&mut self) {
        if let Some(q) = self.q.as_mut() {
            let _ = q.child.kill();
            let _ = q.child.wait();
        }
    }

    /// Starts QEMU on the spacecraft firmware with the table's flash region (two copies,
    /// `ssis::calib::store`, as a flight image, or the options' image): UART0 control and
    /// output, UART1 FOG bus, UART2 star tracker.
    fn boot(table: &ssis::calib::CalibrationTable, opts: &QemuOptions) -> Result<Unit> {
        Unit::boot_with(table, opts, &[])
    }

    /// [`Unit::boot`] with more QEMU arguments (`-gdb tcp::PORT`).
    pub(crate) fn boot_with(
        table: &ssis::calib::CalibrationTable,
        opts: &QemuOptions,
        extra: &[String],
    ) -> Result<Unit> {
        let image = match &opts.table_image {
            Some(img) => img.clone(),
            None => store::image(table).to_vec(),
        };
        let mut images = vec![("table.img", &image[..], symbol(&opts.elf, "_calib_start")?)];
        if let Some(key) = &opts.key_record {
            images.push(("key.img", &key[..], symbol(&opts.elf, "_key_start")?));
        }
        // Lockstep always counts instructions with virtual time bound to them
        // ([`ICOUNT_LOCKSTEP`]); real time follows the host's clock, or with --icount
        // runs one instruction per ns while busy.
        let icount = if opts.lockstep { Some(ICOUNT_LOCKSTEP) } else { opts.icount.then_some("shift=0") };
        if let Some(board) = &opts.board {
            return Unit::attach(board, &[0]);
        }
        Unit::start(&opts.elf, 3, icount, &images, &[0], opts.transport, extra)
    }

    /// Sends a control frame with `command` alone.
    pub(crate) fn command(&mut self, command: u8) -> Result<()> {
        self.control(&ControlFrame { command, ..Default::default() })
    }

    /// Sends a control frame on UART0.
    pub(crate) fn control(&mut self, c: &ControlFrame) -> Result<()> {
        self.uarts[0].write_all(&c.to_bytes())?;
        Ok(())
    }

    /// Switches the booted firmware to lockstep, handing `take` what it sends on its own
    /// tick meanwhile (frames that carry no sample).
    pub(crate) fn enter_lockstep(&mut self, mut take: impl FnMut(usize, &[u8])) -> Result<()> {
        // First a frame from the firmware's own tick: it has booted and is in its loop.
        let boot = self.patience(QEMU_CPU_PATIENCE_S);
        loop {
            match self.rx.recv_timeout(Duration::from_millis(100)) {
                Ok((i, b)) => {
                    take(i, &b);
                    break;
                }
                Err(mpsc::RecvTimeoutError::Disconnected) => bail!("QEMU closed its output UARTs"),
                Err(mpsc::RecvTimeoutError::Timeout) => {
                    if let Some(st) = self.exited()? {
                        bail!("QEMU exited ({st}) before the firmware's first output");
                    }
                    if let Some(why) = boot.exhausted() {
                        bail!("no output from the firmware after boot: {why}");
                    }
                }
            }
        }
        self.command(command::LOCKSTEP)?;
        self.await_silence(take, || Ok(()))
    }

    /// After LOCKSTEP was sent: waits until the firmware has fallen silent, handing
    /// `take` what it sends meanwhile and calling `idle` whenever nothing came for 20 ms
    /// (the upset campaign lets the guest past its breakpoints there).
    pub(crate) fn await_silence(
        &mut self,
        mut take: impl FnMut(usize, &[u8]),
        mut idle: impl FnMut() -> Result<()>,
    ) -> Result<()> {
        // Until the LOCKSTEP frame has arrived the firmware steps on its own tick; no
        // sensor byte may go out before that, or it would integrate a sample on a tick.
        // In lockstep it is silent between STEPs. Silence is counted in QEMU's processor
        // time, not the wall clock's: on its own tick (virtual time jumping from tick to
        // tick, `sleep=off`) the firmware sends a frame every few microseconds of it, so
        // [`SILENCE_CPU_S`] of it without a byte proves the switch, however slowly the
        // host runs QEMU. Frames of that time carry no sample (time tag 0), set aside.
        let mut quiet = self.patience(SILENCE_CPU_S);
        let cap = self.patience(QEMU_CPU_PATIENCE_S);
        loop {
            match self.rx.recv_timeout(Duration::from_millis(20)) {
                Ok((i, b)) => {
                    take(i, &b);
                    quiet = self.patience(SILENCE_CPU_S);
                }
                Err(mpsc::RecvTimeoutError::Timeout) => {
                    idle()?;
                    if quiet.exhausted().is_some() && quiet.wall() >= Duration::from_millis(100) {
                        return Ok(());
                    }
                    if let Some(why) = cap.exhausted() {
                        bail!("the firmware did not fall silent after LOCKSTEP: {why}");
                    }
                }
                Err(mpsc::RecvTimeoutError::Disconnected) => bail!("QEMU closed its output UARTs"),
            }
        }
    }

    /// Lockstep: waits until `done` holds for the output of step `n`, handing every chunk
    /// to `take` with `state`; when QEMU exits, or uses [`QEMU_CPU_PATIENCE_S`] of
    /// processor time without it (a busy host does not count), fails with QEMU's exit
    /// status and the firmware's last words.
    pub(crate) fn await_output<S>(
        &mut self,
        n: u64,
        elf: &Path,
        state: &mut S,
        mut take: impl FnMut(&mut S, usize, &[u8]),
        done: impl Fn(&S) -> bool,
    ) -> Result<()> {
        // Started at the first pause only: most steps' output is already on its way.
        let mut patience: Option<Patience> = None;
        while !done(state) {
            let why = match self.rx.recv_timeout(Duration::from_millis(200)) {
                Ok((i, b)) => {
                    take(state, i, &b);
                    continue;
                }
                Err(mpsc::RecvTimeoutError::Disconnected) => "QEMU closed its output UARTs".to_string(),
                Err(mpsc::RecvTimeoutError::Timeout) => match (
                    self.exited()?,
                    patience.get_or_insert_with(|| self.patience(QEMU_CPU_PATIENCE_S)).exhausted(),
                ) {
                    (Some(st), _) => format!("QEMU exited ({st})"),
                    (None, Some(why)) => why,
                    (None, None) => continue,
                },
            };
            let status = self.wait_exit(2.0)?;
            if status.is_none() {
                self.kill();
            }
            let log = self.log(elf);
            bail!(
                "no output frame for step {n}: {why}; QEMU exit {:?}; firmware log: {}",
                status.and_then(|st| st.code()),
                log.join(" | ")
            )
        }
        Ok(())
    }

    /// Fault injection: sends `STALL` instead of `STEP` and ends the run at the watchdog
    /// reset (or stops QEMU after 20 s); the summary so far with the time to the exit.
    fn stall(mut self, mut s: QemuSummary, elf: &Path) -> Result<QemuSummary> {
        self.command(command::STALL)?;
        let t_stall = Instant::now();
        let status = self.wait_exit(QEMU_CPU_PATIENCE_S)?;
        if status.is_none() {
            self.kill();
        }
        s.stalled_exit_s = status.map(|_| t_stall.elapsed().as_secs_f64());
        s.exit_code = status.and_then(|st| st.code());
        s.log = self.log(elf);
        Ok(s)
    }

    /// Sends `END` and waits for QEMU to exit (up to 10 s of its processor time); its
    /// status if it did.
    pub(crate) fn end(&mut self) -> Result<Option<std::process::ExitStatus>> {
        self.command(command::END)?;
        self.wait_exit(10.0)
    }

    /// The end of a run: the progress bar closed, QEMU stopped, its exit code and log.
    pub(crate) fn finish(
        &mut self,
        status: Option<std::process::ExitStatus>,
        bar: Option<indicatif::ProgressBar>,
        elf: &Path,
    ) -> (Option<i32>, Vec<String>) {
        if let Some(b) = bar {
            b.finish_and_clear();
        }
        self.kill();
        (status.and_then(|st| st.code()), self.log(elf))
    }

    /// The firmware's defmt log, decoded (once QEMU has ended: the log closes with it).
    pub(crate) fn log(&mut self, elf: &Path) -> Vec<String> {
        let bytes = self.log_thread.take().and_then(|t| t.join().ok()).unwrap_or_default();
        decode_defmt(elf, &bytes).unwrap_or_else(|e| vec![format!("(defmt log not decoded: {e})")])
    }
}

/// The sensor links as the runner writes them: each step's FOG frames (of the profile's
/// FOGs) and star-tracker bytes, damaged as the options say, and the byte totals a STEP
/// names.
struct Sender {
    fog_corrupt: Corrupter,
    st_corrupt: Corrupter,
    fog_total: u32,
    st_total: u32,
}

impl Sender {
    fn new(corrupt_every: u64) -> Sender {
        Sender {
            fog_corrupt: Corrupter { every: corrupt_every, count: 0 },
            st_corrupt: Corrupter { every: corrupt_every, count: 0 },
            fog_total: 0,
            st_total: 0,
        }
    }

    /// Sends one step's bytes; returns them as sent (FOG bus, star tracker).
    fn send(
        &mut self,
        unit: &mut Unit,
        input: &StepInput,
        profile: &Profile,
        s: &mut QemuSummary,
    ) -> Result<(Vec<u8>, Vec<u8>)> {
        let mut fog_bytes = Vec::with_capacity(64);
        for (i, f) in input.fog_frames.iter().enumerate() {
            if profile.fogs.contains(i) && input.present.contains(i) {
                fog_bytes.extend_from_slice(f);
                s.fog_frames_in += 1;
            }
        }
        s.st_frames_in += (input.st_bytes.len() / ssis::frames::star::StarFrame::LEN) as u64;
        let fog_sent = self.fog_corrupt.apply(&fog_bytes);
        let st_sent = self.st_corrupt.apply(&input.st_bytes);
        unit.uarts[1].write_all(&fog_sent)?;
        unit.uarts[2].write_all(&st_sent)?;
        self.fog_total = self.fog_total.wrapping_add(fog_sent.len() as u32);
        self.st_total = self.st_total.wrapping_add(st_sent.len() as u32);
        Ok((fog_sent, st_sent))
    }
}

/// Lockstep reference: the same core in-process on the same bytes, with the same
/// command link on a copy of the table's flash region.
struct Reference {
    core: FlightCore,
    fog: MockLink,
    star: MockLink,
    out: MockSink,
    /// The event frames the core sends after its step, as the board does.
    events: MockSink,
    down: Downlink,
    commands: crate::telecommands::ReferenceLink,
}

impl Reference {
    fn new(table: &ssis::calib::CalibrationTable, profile: Profile, opts: &QemuOptions) -> Result<Reference> {
        let core = FlightCore::new(profile, table, false).map_err(|e| anyhow::anyhow!("{e:?}"))?;
        let image = opts.table_image.clone().unwrap_or_else(|| store::image(table).to_vec());
        let commands = crate::telecommands::ReferenceLink::new(opts.key_record.as_deref(), &image);
        Ok(Reference {
            core,
            fog: MockLink::ideal(),
            star: MockLink::ideal(),
            out: MockSink::default(),
            events: MockSink::default(),
            down: Downlink::new(),
            commands,
        })
    }

    /// One step on the bytes the firmware was sent (telecommands before the step): the
    /// output frame's bytes and the number of event frames sent after it (0 or 1, as the
    /// board's `send_events`). A command report and the events go to `s`.
    fn step(&mut self, fog_sent: &[u8], st_sent: &[u8], commands: &[u8], s: &mut QemuSummary) -> (Vec<u8>, usize) {
        self.commands.receive(commands, &mut self.core);
        self.fog.send(fog_sent);
        self.star.send(st_sent);
        let mut links = Links { fog: FogLinks::Bus(&mut self.fog), star: &mut self.star, out: &mut self.out };
        self.core.step(&mut links);
        s.reference_reports.extend(self.commands.take_report());
        self.core.send_events(&mut self.events);
        let mut sent = 0;
        self.down.push(&self.events.bytes, |d| {
            if let Down::Events(f) = d {
                s.reference_events.extend(f.iter().copied());
                sent += 1;
            }
        });
        self.events.bytes.clear();
        (std::mem::take(&mut self.out.bytes), sent)
    }
}

/// The output link as the runner reads it: output frames decoded, then checked
/// ([`FrameCheck`]); event frames and command reports decoded beside them.
struct Outputs {
    link: Downlink,
    check: FrameCheck,
}

impl Outputs {
    fn new(lockstep: bool) -> Outputs {
        Outputs {
            link: Downlink::new(),
            check: FrameCheck {
                lockstep,
                reference: Default::default(),
                ticks: [AxisStats::default(), AxisStats::default()],
                prev_st_updated: false,
                last_drift: [0.0; 3],
            },
        }
    }

    /// Decodes a chunk of the output link and checks every frame in it.
    fn take(
        &mut self,
        bytes: &[u8],
        s: &mut QemuSummary,
        eval: &mut Evaluator,
        on_frame: &mut impl FnMut(&OutputFrame, Option<&Record>),
    ) {
        let check = &mut self.check;
        self.link.push(bytes, |d| match d {
            Down::Output(f) => check.frame(f, s, eval, on_frame),
            Down::Events(e) => s.event_frames.push(e),
            Down::Report(r) => s.command_reports.push(r),
        });
        s.frames_out_bad = self.link.bad_bytes();
    }
}

/// Each decoded output frame compared with the in-process core's (lockstep), its step time
/// classed by the star-tracker status of the step it times, and evaluated against truth.
struct FrameCheck {
    lockstep: bool,
    /// Lockstep: the in-process core's frames not yet compared.
    reference: std::collections::VecDeque<Vec<u8>>,
    /// Step time, ticks, of steps without / with a star-tracker update.
    ticks: [AxisStats; 2],
    prev_st_updated: bool,
    last_drift: [f64; 3],
}

impl FrameCheck {
    fn frame(
        &mut self,
        f: OutputFrame,
        s: &mut QemuSummary,
        eval: &mut Evaluator,
        on_frame: &mut impl FnMut(&OutputFrame, Option<&Record>),
    ) {
        if self.lockstep && f.time_us == 0 {
            // Sent on the firmware's own tick before lockstep began: no sample yet.
            s.frames_before_data += 1;
            return;
        }
        s.frames_out += 1;
        if let Some(r) = self.reference.pop_front() {
            use ssis::frames::Frame;
            match OutputFrame::decode(&r) {
                Ok(rf) if masked(rf) == masked(f) => s.equal_frames += 1,
                _ => s.differing_frames += 1,
            }
        }
        let o = Observed::from(&f);
        if s.frames_out > 1 {
            // A frame carries the time of the step before it: class by that step's status.
            let k = usize::from(self.prev_st_updated);
            self.ticks[k].push([f64::from(o.step_ticks); 3]);
            s.step_ticks_max[k] = s.step_ticks_max[k].max(u32::from(o.step_ticks));
        }
        self.prev_st_updated = o.st_status & st_status::UPDATED != 0;
        self.last_drift = f.drift_rad_s();
        if f.page_id >= ssis::telemetry::page::FOG_PAGES {
            s.unit_pages.push((f.time_us, f.page_id, f.page_value));
        }
        s.last_frame = f;
        if let Some(v) = s.paged.get_mut(usize::from(f.page_id)) {
            *v = f.page_value;
        }
        let rec = eval.evaluate(&o);
        on_frame(&f, rec.as_ref());
    }
}

/// Waits for QEMU to exit while it uses up to `cpu_s` of processor time
/// ([`Patience`]); `None` if it is still running.
pub(crate) fn wait_exit(child: &mut Child, cpu_s: f64) -> Result<Option<std::process::ExitStatus>> {
    let patience = Patience::new(child, cpu_s);
    loop {
        if let Some(st) = child.try_wait()? {
            return Ok(Some(st));
        }
        if patience.exhausted().is_some() {
            return Ok(None);
        }
        std::thread::sleep(Duration::from_millis(5));
    }
}

/// An output frame without what the board fills in itself (its step time, overruns and
/// dropped outputs) and its frame counter (which also counts the frames sent on its own tick before
/// lockstep): everything left must be bit-identical to the in-process core's frame.
pub fn masked(mut f: OutputFrame) -> OutputFrame {
    f.counter = 0;
    f.counters.step_ticks = 0;
    f.counters.overruns = 0;
    // Output frames the board's TX ring dropped (before lockstep, on its own tick, while
    // the runner was busy): the board's count, as overruns are. A frame dropped in
    // lockstep shows as a missing output instead ([`QemuSummary::frames_out`]).
    if page::entry(f.page_id) == Some(page::Entry::Unit(Counter::OutputDropped)) {
        f.page_value = 0;
    }
    f.flags &= !ssis::frames::output::flags::OUTPUT_DROPPED;
    f
}

pub(crate) fn progress_bar(show: bool, steps: u64, name: &str) -> Option<indicatif::ProgressBar> {
    if !show {
        return None;
    }
    let b = indicatif::ProgressBar::new(steps);
    if let Ok(st) = indicatif::ProgressStyle::with_template("{msg} [{bar:40}] {percent}% {elapsed} / {duration}") {
        b.set_style(st);
    }
    b.set_message(format!("{name} in QEMU"));
    Some(b)
}

/// Decodes the firmware's defmt stream with the ELF's table.
pub fn decode_defmt(elf: &Path, bytes: &[u8]) -> Result<Vec<String>> {
    let elf_bytes = std::fs::read(elf)?;
    let table = defmt_decoder::Table::parse(&elf_bytes)?.context("no defmt table in the ELF")?;
    let mut dec = table.new_stream_decoder();
    dec.received(bytes);
    let mut out = Vec::new();
    loop {
        match dec.decode() {
            Ok(f) => out.push(f.display_message().to_string()),
            Err(defmt_decoder::DecodeError::UnexpectedEof) => break,
            Err(defmt_decoder::DecodeError::Malformed) => {
                out.push("(malformed defmt frame)".into());
                break;
            }
        }
    }
    Ok(out)
}

/// Flash and static RAM of the ELF: (flash bytes, RAM bytes of .data + .bss + .uninit).
pub fn elf_sizes(elf: &Path) -> Result<(u64, u64)> {
    use object::{Object, ObjectSection};
    let data = std::fs::read(elf)?;
    let file = object::File::parse(&*data)?;
    let (mut flash, mut ram) = (0u64, 0u64);
    for sec in file.sections() {
        let name = sec.name().unwrap_or("");
        match name {
            ".vector_table" | ".text" | ".rodata" => flash += sec.size(),
            ".data" => {
                flash += sec.size();
                ram += sec.size();
            }
            ".bss" | ".uninit" => ram += sec.size(),
            _ => {}
        }
    }
    Ok((flash, ram))
}

#[cfg(test)]
mod tests {
    #[test]
    fn decode_log_file() {
        if let Ok(p) = std::env::var("SSIS_DEFMT_LOG") {
            let bytes = std::fs::read(&p).expect("log");
            for l in super::decode_defmt(&super::default_elf(), &bytes).expect("decode") {
                println!("{l}");
            }
        }
    }
}
