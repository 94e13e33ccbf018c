//! The QEMU runner for the launch-vehicle firmware (`ssis-fw-lv`, its test build `ssis-fw-lv-test`): the ascent
//! simulator ([`ssis_sim::launch`], FOG, accelerometer and GNSS models) or a recorded
//! log ([`ssis_sim::lv_replay::LvFeed`]) feeds the firmware over five emulated UARTs at
//! its 1.25 ms step, in lockstep, and the runner replays the same bytes through the same
//! `FlightCore` + `NavUnit` in-process ([`LvCore`]): every flight output frame and every
//! navigation output frame must be bit-identical.
//!
//! UARTs (the UART map in `firmware/src/bin/ssis-fw-lv/firmware.rs`): 0 control in /
//! flight output out, 1 FOG bus, 2 navigation output out, 3 accelerometer bus, 4 GNSS
//! receiver. The FOG table (two copies), the accelerometer section and the pad
//! initialisation block are loaded into their flash regions with `-device loader` at the
//! addresses the ELF's symbols `_calib_start` and `_lvdata_start` name
//! (`firmware/link/memory-lv.x`).
//!
//! Step times: with `-icount shift=0` a SysTick tick is 40 instructions. The firmware puts
//! each period's step + filter work (ticks) into the next flight output frame; the runner
//! classes it by the filter work the in-process replay did in that period (none,
//! covariance propagation, GNSS update). The firmware's own END report adds the step
//! alone, without the filter work.
//!
//! Scenario files (`scenarios/lv-ascent.toml`):
//!
//! ```toml
//! kind = "lv-ascent"
//! name = "lv-ascent"
//! duration_s = 600
//! seed = 7
//! [launch]      # sim::launch::LaunchProfile (optional: the default ascent)
//! [fog]         # sim::fog::FogSpec
//! [accel]       # sim::accel::AccelSpec
//! [gnss]        # sim::gnss::GnssSpec (optional: no receiver)
//! ```

use std::collections::VecDeque;
use std::io::Write;
use std::path::PathBuf;
use std::time::Instant;

use anyhow::{Context, Result};
use ssis::calib::accel::AccelTable;
use ssis::calib::{store, CalibrationTable};
use ssis::flight::Profile;
use ssis::frames::accel::AccelFrame;
use ssis::frames::control::{command, ControlFrame};
use ssis::frames::decoder::StreamDecoder;
use ssis::frames::fog::FogFrame;
use ssis::frames::gnss::GnssFrame;
use ssis::frames::navout::NavOutputFrame;
use ssis::frames::output::OutputFrame;
use ssis::frames::Frame;
use ssis::nav::init::PadInit;
use ssis::nav::snapshot::NavSnapshot;
use ssis::nav::unit::FilterWork;
use ssis::nav::NavState;

use crate::qemu::{check_qemu_and_elf, masked, progress_bar, symbol, Unit, INSTR_PER_TICK};
use ssis_common::downlink::{Down, Downlink};
use ssis_sim::lv::angle_between;
use ssis_sim::lv_replay::{pad_init, AscentSensors, LvCore, LvStepBytes};

pub use ssis_sim::lv_replay::{LvScenario, KIND};

/// Offset of the pad initialisation block in the LVDATA region (`board::INIT_OFFSET`).
pub const INIT_OFFSET: usize = 0x100;

/// How to run.
#[derive(Debug, Clone)]
pub struct LvOptions {
    /// Firmware ELF (`ssis-fw-lv`).
    pub elf: PathBuf,
    /// Show a progress bar.
    pub progress: bool,
}

/// Count, mean and worst of a step time, ticks.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct TickStats {
    /// Periods.
    pub n: u64,
    /// Sum of ticks.
    pub sum: u64,
    /// Worst, ticks.
    pub max: u32,
}

impl TickStats {
    fn push(&mut self, t: u32) {
        self.n += 1;
        self.sum += u64::from(t);
        self.max = self.max.max(t);
    }

    /// Mean, ticks.
    pub fn mean(&self) -> f64 {
        if self.n == 0 {
            0.0
        } else {
            self.sum as f64 / self.n as f64
        }
    }
}

/// Names of the kinds of filter work, in the order of the per-kind arrays.
pub const WORK_KINDS: [&str; 3] = ["none", "propagation", "gnss_update"];

fn work_kind(w: FilterWork) -> usize {
    match w {
        FilterWork::None => 0,
        FilterWork::Propagated => 1,
        FilterWork::Updated | FilterWork::Refused(_) => 2,
    }
}

/// The firmware's END report of one kind of period (ticks; means × 100).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct FirmwareTimes {
    /// Periods.
    pub periods: u64,
    /// Mean of the step alone (flight step + navigation step, no filter work), ticks × 100.
    pub step_mean_x100: u64,
    /// Worst step alone, ticks.
    pub step_max: u64,
    /// Mean of step + filter work, ticks × 100.
    pub period_mean_x100: u64,
    /// Worst step + filter work, ticks.
    pub period_max: u64,
}

/// What a launch-vehicle QEMU run measured.
#[derive(Debug, Clone, Default)]
pub struct LvSummary {
    /// Scenario name.
    pub name: String,
    /// Steps sent.
    pub steps: u64,
    /// Simulated time, s.
    pub duration_s: f64,
    /// FOG, accelerometer and GNSS frames sent.
    pub frames_in: [u64; 3],
    /// Flight output frames decoded (lockstep steps only).
    pub flight_frames: u64,
    /// Navigation output frames decoded.
    pub nav_frames: u64,
    /// Output bytes that did not decode (both links).
    pub bad_bytes: u64,
    /// Flight frames sent on the firmware's own tick before lockstep (no sample).
    pub frames_before_data: u64,
    /// Flight output frames equal to the in-process replay's / different.
    pub flight_equal: u64,
    /// Flight output frames different from the replay's.
    pub flight_differing: u64,
    /// Navigation output frames equal to the replay's.
    pub nav_equal: u64,
    /// Navigation output frames different from the replay's.
    pub nav_differing: u64,
    /// Step + filter work per period, ticks, by the replay's filter work ([`WORK_KINDS`]),
    /// from the flight output frames.
    pub period_ticks: [TickStats; 3],
    /// The firmware's END report per kind, if it came.
    pub firmware_times: [Option<FirmwareTimes>; 3],
    /// Overruns in the last flight output frame.
    pub overruns: u16,
    /// Largest |r − r_true| and |v − v_true| of the navigation output frames, m and m/s,
    /// and at the end; largest attitude error, rad.
    pub max_err: (f64, f64, f64),
    /// Error at the end (m, m/s, rad).
    pub final_err: (f64, f64, f64),
    /// GNSS fixes used and refused (last navigation frame).
    pub fixes: (u16, u16),
    /// Firmware log.
    pub log: Vec<String>,
    /// QEMU's exit status.
    pub exit_code: Option<i32>,
    /// Wall time, s.
    pub wall_s: f64,
    /// Instruction counting on.
    pub icount: bool,
    /// Step period, SysTick ticks (1.25 ms at 25 MHz).
    pub period_ticks_budget: u32,
}

impl LvSummary {
    /// Whether the run is clean: QEMU ended by the firmware, every frame decoded and equal
    /// to the replay's, one flight and one navigation frame per step, no overrun.
    pub fn clean(&self) -> bool {
        self.exit_code == Some(0)
            && self.bad_bytes == 0
            && self.flight_differing == 0
            && self.nav_differing == 0
            && self.flight_frames == self.steps
            && self.nav_frames == self.steps
            && self.overruns == 0
    }

    /// A report a person can read.
    pub fn report(&self) -> String {
        use std::fmt::Write;
        let mut s = String::new();
        let _ = writeln!(
            s,
            "scenario  {}  on ssis-fw-lv in QEMU mps2-an500, lockstep at 1.25 ms ({:.0} s simulated, {} steps, wall {:.1} s)",
            self.name, self.duration_s, self.steps, self.wall_s
        );
        let _ = writeln!(
            s,
            "frames in: FOG {} accel {} GNSS {}; out: flight {} nav {}, {} bad bytes",
            self.frames_in[0],
            self.frames_in[1],
            self.frames_in[2],
            self.flight_frames,
            self.nav_frames,
            self.bad_bytes
        );
        let _ = writeln!(
            s,
            "host/QEMU equivalence: flight frames {} identical, {} different; navigation frames {} identical, {} different",
            self.flight_equal, self.flight_differing, self.nav_equal, self.nav_differing
        );
        let _ = writeln!(
            s,
            "navigation error: max {:.3} m, {:.4} m/s, {:.1} arcsec; at the end {:.3} m, {:.4} m/s, {:.1} arcsec; fixes used {}, refused {}",
            self.max_err.0,
            self.max_err.1,
            self.max_err.2 * ssis_common::ARCSEC_PER_RAD,
            self.final_err.0,
            self.final_err.1,
            self.final_err.2 * ssis_common::ARCSEC_PER_RAD,
            self.fixes.0,
            self.fixes.1
        );
        let _ = writeln!(s, "overruns (unit's counter): {}", self.overruns);
        let (unit, k) = if self.icount { ("instructions", INSTR_PER_TICK) } else { ("SysTick ticks (40 ns)", 1.0) };
        let _ = writeln!(
            s,
            "step + filter work per 1.25 ms period, {unit} (budget {:.0}), from the output frames:",
            f64::from(self.period_ticks_budget) * k
        );
        for (name, t) in WORK_KINDS.iter().zip(&self.period_ticks) {
            let _ = writeln!(
                s,
                "  {name:<12} {:>7} periods  mean {:>9.0}  worst {:>9.0}",
                t.n,
                t.mean() * k,
                f64::from(t.max) * k
            );
        }
        if self.firmware_times.iter().any(Option::is_some) {
            let _ = writeln!(s, "firmware's own figures (step alone | step + filter work), {unit}:");
            for (name, t) in WORK_KINDS.iter().zip(&self.firmware_times) {
                if let Some(t) = t {
                    let _ = writeln!(
                        s,
                        "  {name:<12} {:>7} periods  step mean {:>8.0} worst {:>8.0} | period mean {:>9.0} worst {:>9.0}",
                        t.periods,
                        t.step_mean_x100 as f64 / 100.0 * k,
                        t.step_max as f64 * k,
                        t.period_mean_x100 as f64 / 100.0 * k,
                        t.period_max as f64 * k
                    );
                }
            }
        }
        for l in &self.log {
            let _ = writeln!(s, "firmware: {l}");
        }
        let _ = writeln!(s, "QEMU exit: {:?}", self.exit_code);
        s
    }
}

/// The launch-vehicle firmware's test build (`ssis-fw-lv-test`: `ssis-fw-lv` with its
/// test hooks, as [`build_firmware`] builds it); the lockstep runner needs its hooks.
pub fn default_elf() -> PathBuf {
    crate::qemu::repo_root().join("target/test-hooks/thumbv7em-none-eabihf/release/ssis-fw-lv-test")
}

/// Builds `ssis-fw-lv-test` (release, thumb target, test hooks) if it is out of date.
pub fn build_firmware() -> Result<PathBuf> {
    crate::qemu::build_test_hooks_bin("ssis-fw-lv-test")
}

/// What the runner streams to `ssis-fw-lv`: its FOG table and pad block, and its steps'
/// bytes one after the other (the ascent simulator, or a recorded log:
/// `ssis_sim::lv_replay::LvFeed`).
pub struct LvRun<'a> {
    /// Name in the report.
    pub name: String,
    /// Steps to be sent.
    pub steps: u64,
    /// The FOG table (loaded into the firmware's flash; the in-process core's too).
    pub table: CalibrationTable,
    /// The pad initialisation block (likewise).
    pub init: PadInit,
    /// Step `n`'s bytes (1-based), or `None` at the end.
    pub next: Box<dyn FnMut(u64) -> Option<LvStepBytes> + 'a>,
}

/// Runs `sc` on the launch-vehicle firmware in QEMU, in lockstep.
pub fn run_qemu_lv(sc: &LvScenario, opts: &LvOptions) -> Result<LvSummary> {
    let mut sensors = AscentSensors::new(sc);
    let init = pad_init(sensors.initial());
    let steps = (sc.duration_s / Profile::LAUNCH_VEHICLE.dt_s()).round() as u64;
    let run = LvRun {
        name: sc.name.clone(),
        steps,
        table: CalibrationTable::DEFAULT,
        init,
        next: Box::new(move |n| Some(sensors.step(n))),
    };
    run_lv(run, opts, |_| {})
}

/// Runs `run` on the launch-vehicle firmware in QEMU, in lockstep, every output frame
/// compared with the in-process [`LvCore`]'s; `on_nav` sees every navigation output frame
/// of the firmware.
pub fn run_lv(run: LvRun<'_>, opts: &LvOptions, on_nav: impl FnMut(&NavOutputFrame)) -> Result<LvSummary> {
    fly(run, opts, None, on_nav).map(|(s, _)| s)
}

/// A forced reset in a run ([`run_lv_reset`]).
#[derive(Debug, Clone, Copy)]
pub struct LvReset {
    /// The unit is reset (QEMU's `system_reset`, what its SYSRESETREQ does) after this
    /// step's output.
    pub after_step: u64,
    /// Steps whose bytes are lost while it is down (generated, not sent).
    pub down_steps: u64,
    /// Steps recorded after it is back ([`LvResetSeen::after`]).
    pub record_steps: u64,
}

/// One step after a forced reset: the firmware's navigation state and the uninterrupted
/// in-process unit's (each its last navigation frame of the step), and truth.
#[derive(Debug, Clone, Copy)]
pub struct LvStepAfter {
    /// Step.
    pub n: u64,
    /// The firmware's state.
    pub firmware: NavState,
    /// The uninterrupted unit's state ([`LvCore`] fed every step).
    pub uninterrupted: NavState,
    /// Truth, if the feed has it.
    pub truth: Option<NavState>,
}

/// What a run with a forced reset saw.
#[derive(Debug, Clone)]
pub struct LvResetSeen {
    /// The navigation snapshot in the SNAP region (after the core's) when the unit was
    /// reset, read through the gdbstub.
    pub snapshot: Option<NavSnapshot>,
    /// The steps after the unit came back, from the first sent.
    pub after: Vec<LvStepAfter>,
}

/// Runs `run` as [`run_lv`] with the unit reset as `reset` says, through QEMU's gdbstub;
/// after the reset the runner follows the unit back into lockstep (its byte counts
/// start afresh) and goes on with the step after the lost ones. The in-process unit is
/// not reset: frames after the reset are compared with the uninterrupted flight's (they
/// differ by the resume), and the navigation states are recorded against it.
pub fn run_lv_reset(run: LvRun<'_>, opts: &LvOptions, reset: LvReset) -> Result<(LvSummary, LvResetSeen)> {
    let (s, seen) = fly(run, opts, Some(reset), |_| {})?;
    Ok((s, seen.unwrap_or(LvResetSeen { snapshot: None, after: Vec::new() })))
}

/// Where the navigation's snapshot lies: after the core's in the SNAP region
/// (`resilience::snapshot_extra`).
fn nav_snapshot_addr(elf: &std::path::Path) -> Result<u32> {
    let core_words = std::mem::size_of::<ssis::flight::snapshot::Snapshots>().div_ceil(4);
    Ok(symbol(elf, "_snapshot_start")? as u32 + 4 * core_words as u32)
}

fn fly(
    mut run: LvRun<'_>,
    opts: &LvOptions,
    reset: Option<LvReset>,
    mut on_nav: impl FnMut(&NavOutputFrame),
) -> Result<(LvSummary, Option<LvResetSeen>)> {
    check_qemu_and_elf(&opts.elf)?;
    let profile = Profile::LAUNCH_VEHICLE;
    let table = run.table;
    let init = run.init;
    init.validate().map_err(|e| anyhow::anyhow!("pad block: {e:?}"))?;
    let mut replay = LvCore::new(&table, &init)?;
    // A forced reset goes through the gdbstub; a watchdog timeout then resets too (the
    // machine's watchdog is not reset with it and may time out once while the unit boots).
    let port = match reset {
        Some(_) => Some(std::net::TcpListener::bind("127.0.0.1:0")?.local_addr()?.port()),
        None => None,
    };
    let extra: Vec<String> = match port {
        Some(p) => vec!["-gdb".into(), format!("tcp:127.0.0.1:{p}"), "-action".into(), "watchdog=reset".into()],
        None => Vec::new(),
    };
    let mut unit = boot(opts, &table, &init, &extra)?;
    let mut gdb = match port {
        Some(p) => {
            // QEMU halts the guest when the client connects.
            let mut g = crate::gdb::Gdb::connect(p, std::time::Duration::from_secs(10))?;
            g.resume()?;
            Some(g)
        }
        None => None,
    };
    let mut seen = reset.map(|_| LvResetSeen { snapshot: None, after: Vec::new() });

    let started = Instant::now();
    let steps = run.steps;
    let mut s = LvSummary {
        name: run.name.clone(),
        steps,
        duration_s: steps as f64 * profile.dt_s(),
        icount: true,
        period_ticks_budget: 25 * profile.dt_us,
        ..Default::default()
    };
    let mut out = LvOutputs::default();
    // Frames of the firmware's own tick before lockstep carry no sample.
    unit.enter_lockstep(|i, b| out.take(i, b))?;
    s.frames_before_data = out.flight.len() as u64;
    anyhow::ensure!(out.nav.is_empty(), "navigation frames before the first sample");
    out.flight.clear();

    let bar = progress_bar(opts.progress, steps, &run.name);
    let mut sender = LvSender::default();
    let mut prev_work: Option<usize> = None;
    for n in 1..=steps {
        let Some(b) = (run.next)(n) else {
            s.steps = n - 1;
            break;
        };
        if let Some(r) = reset.filter(|r| n > r.after_step && n <= r.after_step + r.down_steps) {
            // The unit is down: the step's bytes are lost; the uninterrupted unit goes on.
            replay.period(&b);
            if n == r.after_step + r.down_steps {
                unit.enter_lockstep(|_, _| {})?;
                out = LvOutputs::default();
                sender = LvSender::default();
            }
            continue;
        }
        let step = sender.send(&mut unit, &b, &mut s)?;
        let period = replay.period(&b);
        unit.control(&step)?;
        let want_nav = period.nav.len() / NavOutputFrame::LEN;
        let done = |o: &LvOutputs| !o.flight.is_empty() && o.nav.len() >= want_nav;
        unit.await_output(n, &opts.elf, &mut out, |o, i, b| o.take(i, b), done)?;
        let mut last_nav = None;
        out.check(&mut s, &period.flight, &period.nav, b.truth.as_ref(), prev_work, &mut |f: &NavOutputFrame| {
            last_nav = Some(f.state());
            on_nav(f);
        });
        prev_work = Some(work_kind(period.work));
        if let (Some(r), Some(seen)) = (reset, seen.as_mut()) {
            if n > r.after_step + r.down_steps && n <= r.after_step + r.down_steps + r.record_steps {
                // Both as their last navigation frame of the step (sent before the
                // filter work that follows the outputs).
                let uninterrupted = period.nav.chunks_exact(NavOutputFrame::LEN).last();
                let uninterrupted = uninterrupted.and_then(|f| NavOutputFrame::decode(f).ok()).map(|f| f.state());
                if let (Some(firmware), Some(uninterrupted)) = (last_nav, uninterrupted) {
                    seen.after.push(LvStepAfter { n, firmware, uninterrupted, truth: b.truth });
                }
            }
            if n == r.after_step {
                let g = gdb.as_mut().context("no gdbstub")?;
                g.halt()?;
                let addr = nav_snapshot_addr(&opts.elf)?;
                let bytes = g.read_memory(addr, std::mem::size_of::<NavSnapshot>())?;
                seen.snapshot = NavSnapshot::from_bytes(&bytes);
                g.monitor("system_reset")?;
                g.resume()?;
            }
        }
        if let Some(bar) = &bar {
            if n.is_multiple_of(800) {
                bar.set_position(n);
            }
        }
    }
    s.duration_s = s.steps as f64 * profile.dt_s();
    s.bad_bytes = out.bad + out.flight_link.bad_bytes();
    let status = unit.end()?;
    (s.exit_code, s.log) = unit.finish(status, bar, &opts.elf);
    s.firmware_times = firmware_times(&s.log);
    s.wall_s = started.elapsed().as_secs_f64();
    Ok((s, seen))
}

/// Starts QEMU on the launch-vehicle firmware with the FOG table (two copies) and the
/// LVDATA region (accelerometer table, pad initialisation block) at the addresses the
/// ELF names; reads the flight (UART0) and navigation (UART2) outputs.
pub(crate) fn boot(opts: &LvOptions, table: &CalibrationTable, init: &PadInit, extra: &[String]) -> Result<Unit> {
    let mut lvdata = vec![0xFFu8; INIT_OFFSET + ssis::nav::init::BLOCK_LEN];
    lvdata[..ssis::calib::accel::TABLE_LEN].copy_from_slice(&AccelTable::IDEAL.to_bytes());
    lvdata[INIT_OFFSET..].copy_from_slice(&init.to_bytes());
    let calib_addr = symbol(&opts.elf, "_calib_start")?;
    let lvdata_addr = symbol(&opts.elf, "_lvdata_start")?;
    // Lockstep with virtual time bound to the instructions executed (`sleep=off`): a
    // stall of the QEMU process on a loaded host cannot add tens of milliseconds to
    // virtual time in one jump (which tripped the watchdog between two steps).
    let icount = Some(crate::progress::ICOUNT_LOCKSTEP);
    let images: [(&str, &[u8], u64); 2] =
        [("table.img", &store::image(table), calib_addr), ("lvdata.img", &lvdata, lvdata_addr)];
    Unit::start(&opts.elf, 5, icount, &images, &[0, 2], crate::transport::Transport::Sockets, extra)
}

/// The sensor links as the runner writes them (UART1 FOG bus, UART3 accelerometer bus,
/// UART4 GNSS receiver) and the byte totals a STEP names.
#[derive(Default)]
struct LvSender {
    fog_total: u32,
    accel_total: u32,
    gnss_total: u32,
}

impl LvSender {
    /// Sends one step's bytes, counting its frames into `s`; the STEP that names them.
    fn send(&mut self, unit: &mut Unit, b: &LvStepBytes, s: &mut LvSummary) -> Result<ControlFrame> {
        s.frames_in[0] += (b.fog.len() / FogFrame::LEN) as u64;
        s.frames_in[1] += (b.accel.len() / AccelFrame::LEN) as u64;
        s.frames_in[2] += (b.gnss.len() / GnssFrame::LEN) as u64;
        unit.uarts[1].write_all(&b.fog)?;
        unit.uarts[3].write_all(&b.accel)?;
        unit.uarts[4].write_all(&b.gnss)?;
        self.fog_total = self.fog_total.wrapping_add(b.fog.len() as u32);
        self.accel_total = self.accel_total.wrapping_add(b.accel.len() as u32);
        self.gnss_total = self.gnss_total.wrapping_add(b.gnss.len() as u32);
        Ok(ControlFrame {
            command: command::STEP,
            fog_bytes: self.fog_total,
            st_bytes: self.accel_total,
            arg: (self.gnss_total & 0xFFFF) as u16,
        })
    }
}

/// The two output links as the runner reads them: frames decoded and queued until checked
/// against the replay's, undecodable bytes counted.
#[derive(Default)]
struct LvOutputs {
    /// The flight output link: output frames, and event frames beside them.
    flight_link: Downlink,
    nav_dec: StreamDecoder<NavOutputFrame, 256>,
    flight: VecDeque<OutputFrame>,
    nav: VecDeque<NavOutputFrame>,
    bad: u64,
}

impl LvOutputs {
    /// Decodes a chunk of UART `i` (0 flight, 2 navigation).
    fn take(&mut self, i: usize, b: &[u8]) {
        let bad = &mut self.bad;
        if i == 0 {
            let got = &mut self.flight;
            self.flight_link.push(b, |d| {
                if let Down::Output(f) = d {
                    got.push_back(f);
                }
            });
        } else {
            let got = &mut self.nav;
            self.nav_dec.push_slice(b, |r| match r {
                Ok(f) => got.push_back(f),
                Err(_) => *bad += 1,
            });
        }
    }

    /// Checks one step's frames against the replay's (`ref_flight`, `ref_nav`) and the
    /// navigation frames against `truth`; the flight frame's step time is classed by the
    /// previous period's filter work (`prev_work`), which it carries.
    fn check(
        &mut self,
        s: &mut LvSummary,
        ref_flight: &[u8],
        ref_nav: &[u8],
        truth: Option<&ssis::nav::NavState>,
        prev_work: Option<usize>,
        on_nav: &mut impl FnMut(&NavOutputFrame),
    ) {
        if let Some(f) = self.flight.pop_front() {
            s.flight_frames += 1;
            match OutputFrame::decode(ref_flight) {
                Ok(r) if masked(r) == masked(f) => s.flight_equal += 1,
                _ => s.flight_differing += 1,
            }
            if let Some(k) = prev_work {
                if let Some(t) = s.period_ticks.get_mut(k) {
                    t.push(u32::from(f.counters.step_ticks));
                }
            }
            s.overruns = f.counters.overruns;
        }
        for r in ref_nav.chunks_exact(NavOutputFrame::LEN) {
            let Some(f) = self.nav.pop_front() else { break };
            s.nav_frames += 1;
            if f.to_bytes()[..] == r[..] {
                s.nav_equal += 1;
            } else {
                s.nav_differing += 1;
            }
            on_nav(&f);
            let Some(truth) = truth else { continue };
            let st = f.state();
            let err = (
                (st.r_e_m - truth.r_e_m).norm(),
                (st.v_e_m_s - truth.v_e_m_s).norm(),
                angle_between(&st.q_eb, &truth.q_eb),
            );
            s.max_err = (s.max_err.0.max(err.0), s.max_err.1.max(err.1), s.max_err.2.max(err.2));
            s.final_err = err;
            s.fixes = (f.fixes_used, f.fixes_refused);
        }
    }
}

/// The firmware's END report per kind of period, from its `lv_times` log lines.
fn firmware_times(log: &[String]) -> [Option<FirmwareTimes>; 3] {
    let mut times = [None; 3];
    for l in log {
        let w: Vec<&str> = l.split_whitespace().collect();
        if w.first() == Some(&"lv_times") {
            let num = |i: usize| w.get(i).and_then(|v| v.parse::<u64>().ok()).unwrap_or(0);
            if let Some(k) = WORK_KINDS.iter().position(|n| w.get(1) == Some(n)) {
                times[k] = Some(FirmwareTimes {
                    periods: num(3),
                    step_mean_x100: num(5),
                    step_max: num(7),
                    period_mean_x100: num(9),
                    period_max: num(11),
                });
            }
        }
    }
    times
}
