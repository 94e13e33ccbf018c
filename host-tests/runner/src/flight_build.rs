//! A flight build of the spacecraft firmware (`ssis-fw`) under every control frame the
//! runner uses: it must ignore them (counting each) and keep stepping on its own timer
//! with the output it would have had without them.
//!
//! The firmware runs in real time with the calibration table loaded and no sensor input;
//! the runner listens to its output for a while, sends LOCKSTEP, STEP, END and STALL
//! (as it would to a test build), and listens on. Every output frame is compared with
//! the same flight core stepped in-process on the same (empty) links, one step per
//! frame: with no input a step's output does not depend on when it runs, so the two
//! must agree field for field, apart from what only the board fills in (step time,
//! overruns, the frame counter) and the counter page of ignored control frames. Then FOG
//! samples make the counter page come round, to read the count of ignored frames.

use std::io::Write;
use std::path::Path;
use std::time::{Duration, Instant};

use anyhow::{Context, Result};
use ssis::calib::{store, CalibrationTable};
use ssis::flight::{FlightCore, FogLinks, Links, Profile};
use ssis::frames::control::{command, ControlFrame};
use ssis::frames::decoder::StreamDecoder;
use ssis::frames::fog::FogFrame;
use ssis::frames::output::{flags, OutputFrame};
use ssis::frames::Frame;
use ssis::telemetry::{page, Counter, FogCounter, PAGED};
use ssis_common::mock::{MockLink, MockSink};
use ssis_sim::harness::{Evaluator, Observed, Simulation, StepInput};
use ssis_sim::scenario::Scenario;

use crate::qemu::{masked, Unit};

/// What a flight build did with the control frames.
#[derive(Debug, Clone, Default)]
pub struct ControlCheck {
    /// Control frames sent.
    pub sent: u32,
    /// Output frames before the first control frame was sent.
    pub frames_before: u64,
    /// Output frames after.
    pub frames_after: u64,
    /// Frames equal to the in-process core's (masked as [`masked`], the ignored-control
    /// page left out).
    pub equal: u64,
    /// Frames that differ.
    pub differing: u64,
    /// Frame counters that did not follow the previous frame's by one.
    pub counter_gaps: u64,
    /// The largest value the page of ignored control frames carried (once FOG samples
    /// made the page come round).
    pub ignored_shown: u16,
    /// The firmware still ran when the runner stopped it (it did not end on END, nor stall
    /// into a watchdog reset).
    pub still_running: bool,
    /// The firmware's defmt log.
    pub log: Vec<String>,
}

/// The page id of the ignored-control-frame counter.
pub fn ignored_page_id() -> u8 {
    let k = PAGED.iter().position(|c| *c == Counter::ControlIgnored).unwrap_or(PAGED.len());
    page::FOG_PAGES + k as u8
}

/// Runs the flight build `elf` with `table` loaded: `before` of output, then every control
/// frame the runner uses (LOCKSTEP, three STEPs, END, STALL), then `after` of output.
pub fn control_frames_on_flight_build(
    elf: &Path,
    table: &CalibrationTable,
    before: Duration,
    after: Duration,
) -> Result<ControlCheck> {
    crate::qemu::check_qemu_and_elf(elf)?;
    let calib = crate::qemu::symbol(elf, "_calib_start")?;
    let image = store::image(table);
    let mut unit =
        Unit::start(elf, 3, None, &[("table.img", &image, calib)], &[0], crate::transport::Transport::Sockets, &[])?;
    let mut bytes = Vec::new();
    let listen = |unit: &mut Unit, bytes: &mut Vec<u8>, d: Duration| {
        let t0 = Instant::now();
        while t0.elapsed() < d {
            if let Ok((_, b)) = unit.rx.recv_timeout(Duration::from_millis(20)) {
                bytes.extend_from_slice(&b);
            }
        }
    };
    listen(&mut unit, &mut bytes, before);
    let split = bytes.len();
    let frames = [
        ControlFrame { command: command::LOCKSTEP, ..Default::default() },
        ControlFrame { command: command::STEP, ..Default::default() },
        ControlFrame { command: command::STEP, fog_bytes: 64, ..Default::default() },
        ControlFrame { command: command::STEP, fog_bytes: 128, st_bytes: 32, ..Default::default() },
        ControlFrame { command: command::END, ..Default::default() },
        ControlFrame { command: command::STALL, ..Default::default() },
    ];
    for f in &frames {
        unit.control(f)?;
    }
    listen(&mut unit, &mut bytes, after);
    let compared = bytes.len();
    // The counter page follows the FOG sample clock, which stands still without samples:
    // stream FOG samples at the real rate for a while so that every page comes round.
    // (What the unit does with them depends on when they arrive, so these frames are not
    // compared; they only show the count.)
    for k in 0..PAGING_SAMPLES {
        let mut buf = Vec::with_capacity(64);
        for fog_id in 0..4u8 {
            let f = FogFrame {
                fog_id,
                counter: k as u16,
                status: 0,
                dtheta_counts: 1000 + k % 7,
                temperature_counts: 6400,
            };
            buf.extend_from_slice(&f.to_bytes());
        }
        unit.uarts[1].write_all(&buf)?;
        listen(&mut unit, &mut bytes, Duration::from_millis(5));
    }
    listen(&mut unit, &mut bytes, Duration::from_millis(100));
    let still_running = unit.exited()?.is_none();
    let (_, log) = unit.finish(None, None, elf);
    let (head, tail) = bytes.split_at(compared);
    let mut check = compare(head, split, table)?;
    check.ignored_shown = ignored_shown(tail);
    check.sent = frames.len() as u32;
    check.still_running = still_running;
    check.log = log;
    Ok(check)
}

/// FOG samples streamed after the comparison (0.5 s), so the counter page comes round.
const PAGING_SAMPLES: i32 = 100;

/// The largest value the ignored-control page shows in the output `bytes`.
fn ignored_shown(bytes: &[u8]) -> u16 {
    let mut dec: StreamDecoder<OutputFrame, 256> = StreamDecoder::new();
    let mut shown = 0;
    dec.push_slice(bytes, |r| {
        if let Ok(f) = r {
            if f.page_id == ignored_page_id() {
                shown = shown.max(f.page_value);
            }
        }
    });
    shown
}

/// Decodes the output bytes (the first `split` of them came before the control frames)
/// and compares every frame with the in-process core's.
fn compare(bytes: &[u8], split: usize, table: &CalibrationTable) -> Result<ControlCheck> {
    let mut reference = FlightCore::new(Profile::SPACECRAFT, table, false).map_err(|e| anyhow::anyhow!("{e:?}"))?;
    let (mut fog, mut star, mut out) = (MockLink::ideal(), MockLink::ideal(), MockSink::default());
    let mut dec: StreamDecoder<OutputFrame, 256> = StreamDecoder::new();
    let mut c = ControlCheck::default();
    let mut last_counter: Option<u16> = None;
    let ignored = ignored_page_id();
    for (i, &b) in bytes.iter().enumerate() {
        let Some(Ok(f)) = dec.push(b) else { continue };
        if i < split {
            c.frames_before += 1;
        } else {
            c.frames_after += 1;
        }
        if last_counter.is_some_and(|n| n.wrapping_add(1) != f.counter) {
            c.counter_gaps += 1;
        }
        last_counter = Some(f.counter);
        let mut links = Links { fog: FogLinks::Bus(&mut fog), star: &mut star, out: &mut out };
        reference.step(&mut links);
        let r = OutputFrame::decode(&std::mem::take(&mut out.bytes))
            .map_err(|e| anyhow::anyhow!("the reference core's frame: {e:?}"))?;
        let (mut a, mut b) = (masked(f), masked(r));
        if f.page_id == ignored {
            (a.page_value, b.page_value) = (0, 0);
        }
        if a == b {
            c.equal += 1;
        } else {
            c.differing += 1;
        }
    }
    Ok(c)
}

/// A fault of the flight build's loop ([`loop_fault_on_flight_build`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LoopFault {
    /// The SysTick's enable bit cleared (the guest's own `str`, [`crate::gdb::Gdb::write_device_u32`]).
    TickStopped,
    /// The instruction at the halted PC replaced by a branch to itself (`b .`).
    Stall,
    /// PRIMASK set (the guest's own `cpsid i`): the tick's interrupt is never taken.
    InterruptsMasked,
}

/// What the flight build did after a loop fault.
#[derive(Debug, Clone, Default)]
pub struct LoopFaultCheck {
    /// Output frames before the fault.
    pub frames_before: u64,
    /// Output frames between the fault and the reset.
    pub frames_faulted: u64,
    /// The unit reset (stopped at `Reset`).
    pub reset: bool,
    /// No reset, but [`RESTORED_FRAMES`] frames after the fault and the SysTick enabled
    /// again (restored by the firmware).
    pub tick_restored: bool,
    /// At the reset: the firmware's count of watchdog warnings.
    pub warnings: u32,
    /// At the reset: the watchdog's raw interrupt status (a timeout not fed since).
    pub watchdog_pending: bool,
    /// Output frames after the reset, within the wait.
    pub frames_after: u64,
    /// The firmware's defmt log.
    pub log: Vec<String>,
}

/// Output frames after a fault without a reset that end the wait for one.
pub const RESTORED_FRAMES: u64 = 20;

/// Output frames in `bytes`.
fn count_frames(bytes: &[u8]) -> u64 {
    let mut dec: StreamDecoder<OutputFrame, 256> = StreamDecoder::new();
    let mut n = 0;
    dec.push_slice(bytes, |r| n += u64::from(r.is_ok()));
    n
}

/// Runs the flight build `elf` (its own timer, no lockstep, no sensor input) with `table`
/// loaded under `-icount` (virtual time the instruction count; an idle guest's jumps to
/// its next timer deadline) and QEMU's gdbstub, `-action watchdog=reset`: after `before`
/// output frames it halts the guest, injects `fault`, and waits for the reset (a
/// breakpoint on `Reset`, bounded by QEMU's processor time), then for `after` frames.
pub fn loop_fault_on_flight_build(
    elf: &Path,
    table: &CalibrationTable,
    fault: LoopFault,
    before: u64,
    after: u64,
) -> Result<LoopFaultCheck> {
    use crate::gdb::{Gdb, PC};
    crate::qemu::check_qemu_and_elf(elf)?;
    let calib = crate::qemu::symbol(elf, "_calib_start")?;
    let reset_at = (crate::qemu::symbol(elf, "Reset")? & !1) as u32;
    let image = store::image(table);
    let port = std::net::TcpListener::bind("127.0.0.1:0")?.local_addr()?.port();
    let extra =
        ["-gdb".to_string(), format!("tcp:127.0.0.1:{port}"), "-action".to_string(), "watchdog=reset".to_string()];
    let mut unit = Unit::start(
        elf,
        3,
        Some(crate::progress::ICOUNT_LOCKSTEP),
        &[("table.img", &image, calib)],
        &[0],
        crate::transport::Transport::Sockets,
        &extra,
    )?;
    let mut g = Gdb::connect(port, Duration::from_secs(10))?;
    g.set_breakpoint(reset_at)?;
    g.resume()?;
    let mut c = LoopFaultCheck::default();
    let mut bytes = Vec::new();
    let patience = crate::progress::Patience::new(&unit.q.as_ref().context("no QEMU")?.child, 20.0);
    while count_frames(&bytes) < before {
        if let Ok((_, b)) = unit.rx.recv_timeout(Duration::from_millis(20)) {
            bytes.extend_from_slice(&b);
        }
        anyhow::ensure!(patience.exhausted().is_none(), "the flight build sent no {before} frames");
    }
    g.halt()?;
    while let Ok((_, b)) = unit.rx.try_recv() {
        bytes.extend_from_slice(&b);
    }
    c.frames_before = count_frames(&bytes);
    let pc = g.register_u32(PC)?;
    inject(&mut g, fault, pc)?;
    g.resume()?;
    let mut faulted = Vec::new();
    let patience = crate::progress::Patience::new(&unit.q.as_ref().context("no QEMU")?.child, 20.0);
    loop {
        if let Ok((_, b)) = unit.rx.recv_timeout(Duration::from_millis(20)) {
            faulted.extend_from_slice(&b);
        }
        if g.wait_stop(Duration::ZERO)?.is_some() {
            c.reset = g.register_u32(PC)? == reset_at;
            break;
        }
        // Stepping again without a reset: the tick restored (a register check) or the
        // fault without effect; SYST_CSR says which.
        if count_frames(&faulted) >= RESTORED_FRAMES {
            g.halt()?;
            c.tick_restored = g.read_device_u32(crate::upset::SYST_CSR)? & 1 != 0;
            break;
        }
        if patience.exhausted().is_some() || unit.exited()?.is_some() {
            break;
        }
    }
    c.frames_faulted = count_frames(&faulted);
    if c.reset {
        g.clear_breakpoint(reset_at)?;
        let warnings = crate::upset::data_symbol(elf, "ssis_firmware::mps2::WATCHDOG_WARNINGS")?;
        (c.warnings, c.watchdog_pending) = crate::upset::watchdog_at_reset(&mut g, warnings)?;
        g.resume()?;
        let mut back = Vec::new();
        let patience = crate::progress::Patience::new(&unit.q.as_ref().context("no QEMU")?.child, 20.0);
        while count_frames(&back) < after && patience.exhausted().is_none() {
            if let Ok((_, b)) = unit.rx.recv_timeout(Duration::from_millis(20)) {
                back.extend_from_slice(&b);
            }
        }
        c.frames_after = count_frames(&back);
    }
    unit.kill();
    c.log = unit.log(elf);
    Ok(c)
}

/// A loop fault of a spacecraft build flown on its scenario, fed on time
/// ([`loop_fault_in_flight`]).
#[derive(Debug, Clone, Default)]
pub struct FlightFaultCheck {
    /// The unit flew in lockstep (the test build) rather than on its own tick.
    pub lockstep: bool,
    /// The undisturbed flight's attitude error 3σ per axis (|mean| + 3 std after
    /// settling, the in-process core on the same scenario), ″.
    pub nominal_3sigma_arcsec: [f64; 3],
    /// The fault: the time tag of the last frame before it, s of the scenario.
    pub fault_s: f64,
    /// Output frames before the fault.
    pub frames_before: u64,
    /// Of those (from the first sample on), frames whose step took exactly the sample
    /// after the previous frame's: the feed was on time for that step.
    pub on_time_before: u64,
    /// Frames before the fault whose step took no sample or more than one (its bytes
    /// arrived after its tick): missed samples, caught up later.
    pub missed_before: u64,
    /// The flight build: ticks before the fault at which the runner put more than one
    /// step's bytes into the rings because virtual time had passed more than one period
    /// since the last tick. Asleep, the guest's virtual time follows the host's (`-icount
    /// sleep=on`) and lands late on its deadline when the host is loaded; SysTick periods
    /// that pass meanwhile become one tick, and the unit's step takes both samples (a
    /// missed frame before the fault that the feed did not cause).
    pub ticks_coalesced_before: u64,
    /// Samples the unit counted missing before the fault (each FOG's `missing` counter, as
    /// its frames' counter page last showed it): a sample the feed did not deliver in time.
    pub samples_missing_before: u32,
    /// Frames before the fault equal to the in-process core's frame of the same time tag
    /// (the core stepped once per scenario step on its bytes; masked as [`masked`]).
    pub equal_before: u64,
    /// From the fault to the watchdog's action, s of the unit's virtual time (`None`: no
    /// reset).
    pub reset_after_s: Option<f64>,
    /// No reset: from the fault to the first output frame after it, s of virtual time
    /// (the tick restored by the firmware).
    pub tick_back_after_s: Option<f64>,
    /// At the watchdog's action: the firmware's count of watchdog warnings.
    pub warnings: u32,
    /// At the watchdog's action: its raw interrupt status (a timeout not fed since).
    pub watchdog_pending: bool,
    /// Output frames between the fault and the reset (or the end, without one).
    pub frames_faulted: u64,
    /// From the fault to the first output frame after the reset, s of virtual time.
    pub output_back_after_s: Option<f64>,
    /// The firmware logged that it resumed from its snapshot after the reset.
    pub resumed: bool,
    /// From the fault to the frame from which every frame to the end is judged against
    /// truth and within twice the nominal 3σ on each axis, s of the scenario (time tags).
    pub back_after_s: Option<f64>,
    /// Frames after settling that claim a good attitude (converged, not degraded, no
    /// parity alarm) with an error beyond twice the nominal 3σ on an axis.
    pub claimed_beyond: u64,
    /// Frames after settling that claim a good attitude.
    pub claimed: u64,
    /// The largest error of a frame that claims a good attitude, after settling, as a
    /// share of twice the nominal 3σ of its axis (1: on the bound).
    pub worst_claimed_share: f64,
    /// Output frames after the reset (or after the fault, without one).
    pub frames_after: u64,
    /// In lockstep: sensor and control bytes sent before the reset that the unit had not
    /// taken when it reset, dropped as a UART held in reset drops them (QEMU would
    /// otherwise hand them to the booted unit).
    pub dropped_at_reset: u64,
    /// Time followed from the fault, s: of virtual time on the flight build; in lockstep
    /// of the unit's time (its frames' time tags), or of virtual time without a frame.
    pub watched_s: f64,
    /// Wall time of the run, s.
    pub wall_s: f64,
    /// The firmware's defmt log.
    pub log: Vec<String>,
}

/// The CMSDK timer the runner keeps as its clock of the guest's virtual time (mps2 TIMER0,
/// unused by the firmware): CTRL, VALUE, RELOAD; it counts down at the 25 MHz system clock.
const CLOCK_TIMER: u32 = 0x4000_0000;
/// The system clock, Hz.
const SYSCLK_HZ: f64 = 25e6;
/// The CMSDK watchdog's raw interrupt status (WDOGRIS).
const WDOG_RIS: u32 = 0x4000_8010;
/// The CMSDK UARTs the firmware receives on (mps2-an500 UART0–2: control, FOG bus, star
/// tracker); their DATA, STATE and CTRL registers are at these offsets.
const UART_BASE: [u32; 3] = [0x4000_4000, 0x4000_5000, 0x4000_6000];
const UART_STATE: u32 = 0x04;
const UART_CTRL: u32 = 0x08;
/// STATE: a byte waits in the receive buffer; CTRL: receive enabled.
const UART_RX_FULL: u32 = 1 << 1;
const UART_RX_EN: u32 = 1 << 1;
/// Host time without a byte after which a UART held in reset counts as drained.
const DRAIN_QUIET: Duration = Duration::from_millis(50);

/// Drops the bytes on the way to the unit's UARTs (the guest halted at `Reset`, the UARTs
/// in their reset state): a real UART receives nothing while its unit is in reset, but
/// QEMU's leaves what it has not taken in the host's socket and hands it to the booted
/// firmware. Each UART's receiver is enabled for the drain (no interrupt), its data
/// register read until no byte has come for [`DRAIN_QUIET`], and its control word put
/// back to its reset value. Returns the bytes dropped.
fn drain_uarts(g: &mut crate::gdb::Gdb) -> Result<u64> {
    let word = |g: &mut crate::gdb::Gdb, a: u32| -> Result<u32> {
        Ok(u32::from_le_bytes(g.read_memory(a, 4)?.as_slice().try_into()?))
    };
    let mut dropped = 0;
    for base in UART_BASE {
        let ctrl = g.read_device_u32(base + UART_CTRL)?;
        g.write_device_u32(base + UART_CTRL, UART_RX_EN)?;
        let mut quiet_since = Instant::now();
        while quiet_since.elapsed() < DRAIN_QUIET {
            // The gdbstub reads a device as the CPU would: reading DATA takes the byte.
            if word(g, base + UART_STATE)? & UART_RX_FULL != 0 {
                word(g, base)?;
                dropped += 1;
                quiet_since = Instant::now();
            }
        }
        g.write_device_u32(base + UART_CTRL, ctrl)?;
    }
    Ok(dropped)
}

/// The runner's clock of the unit's virtual time: a CMSDK timer it starts itself
/// (restarted after a reset, which stops it), plus the time before that restart.
struct GuestClock {
    /// Virtual time at the last (re)start, s.
    base_s: f64,
}

impl GuestClock {
    /// Starts the timer from its top (the guest halted at an instruction).
    fn start(g: &mut crate::gdb::Gdb, base_s: f64) -> Result<GuestClock> {
        g.write_device_u32(CLOCK_TIMER + 8, u32::MAX)?;
        g.write_device_u32(CLOCK_TIMER + 4, u32::MAX)?;
        g.write_device_u32(CLOCK_TIMER, 1)?;
        Ok(GuestClock { base_s })
    }

    /// Virtual time now, s (the gdbstub's read of the counter: one packet).
    fn now_s(&self, g: &mut crate::gdb::Gdb) -> Result<f64> {
        let b = g.read_memory(CLOCK_TIMER + 4, 4)?;
        let v = u32::from_le_bytes(b.as_slice().try_into()?);
        Ok(self.base_s + f64::from(u32::MAX - v) / SYSCLK_HZ)
    }
}

/// The unit's virtual time as the runner tracks it between two halts: exact at a halt
/// (the [`GuestClock`]), and while the guest runs the host's time since it was resumed
/// (QEMU without `-icount`, or idle under `sleep=on`: virtual time follows the host's).
struct VirtualTime {
    at_halt_s: f64,
    running_since: Option<Instant>,
}

impl VirtualTime {
    fn now_s(&self) -> f64 {
        self.at_halt_s + self.running_since.map_or(0.0, |t| t.elapsed().as_secs_f64())
    }

    /// The guest halted: its clock read.
    fn halted(&mut self, clock: &GuestClock, g: &mut crate::gdb::Gdb) -> Result<f64> {
        self.at_halt_s = clock.now_s(g)?;
        self.running_since = None;
        Ok(self.at_halt_s)
    }

    /// The guest resumed.
    fn resume(&mut self, g: &mut crate::gdb::Gdb) -> Result<()> {
        g.resume()?;
        self.running_since = Some(Instant::now());
        Ok(())
    }
}

/// The addresses of the main loop's `wfi` (where it sleeps until its next tick, or in
/// lockstep its next STEP): every `wfi` in `firmware::fly` of `elf` (the flight build
/// `ssis-fw` has one; its test build `ssis-fw-test` a second, its STALL's).
fn loop_wfi(elf: &Path) -> Result<Vec<u32>> {
    use object::{Object, ObjectSection, ObjectSymbol};
    let data = std::fs::read(elf).with_context(|| format!("cannot read {}", elf.display()))?;
    let file = object::File::parse(&*data)?;
    let sym = file
        .symbols()
        .find(|s| {
            s.kind() == object::SymbolKind::Text
                && s.name().is_ok_and(|n| {
                    n.contains("8firmware3fly17h") && (n.contains("7ssis_fw8") || n.contains("12ssis_fw_test8"))
                })
        })
        .context("no firmware::fly")?;
    let start = sym.address() & !1;
    let text = file.section_by_name(".text").context("no .text")?;
    let code = text.data_range(start, sym.size())?.context("fly outside .text")?;
    let at: Vec<u64> = code
        .chunks_exact(2)
        .enumerate()
        .filter(|(_, h)| h == &[0x30, 0xbf])
        .map(|(i, _)| start + 2 * i as u64)
        .collect();
    anyhow::ensure!(!at.is_empty(), "no wfi in firmware::fly");
    Ok(at.into_iter().map(|a| a as u32).collect())
}

/// The FOG bus bytes of one step (the profile's FOGs that sent a frame).
fn bus_bytes(input: &StepInput, profile: &Profile) -> Vec<u8> {
    let fitted =
        input.fog_frames.iter().enumerate().filter(|(i, _)| profile.fogs.contains(*i) && input.present.contains(*i));
    fitted.flat_map(|(_, f)| f.iter().copied()).collect()
}

/// Whether a frame claims a good attitude: converged, not degraded, no parity alarm.
fn claims_good(f: &OutputFrame) -> bool {
    f.flags & flags::CONVERGED != 0 && f.flags & (flags::DEGRADED | flags::FDI_ALARM) == 0
}

/// Where the fed flight is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Phase {
    /// Undisturbed.
    Before,
    /// The fault injected; no reset yet.
    Faulted,
    /// The watchdog acted: the machine resetting, the guest held at `Reset`.
    Resetting,
    /// After the reset.
    After,
}

/// Every output frame of the fed flight, judged.
struct Judge {
    eval: Evaluator,
    bound: [f64; 3],
    settle_s: f64,
    dt_us: u64,
    reference: std::collections::HashMap<u64, OutputFrame>,
    /// The sample of the last frame (its time tag over Δt), once one came.
    last_sample: Option<u64>,
    /// The first frame after the fault from which every frame has been within the bound
    /// (its time tag, s).
    back_from: Option<f64>,
    last_t_s: f64,
    /// Each FOG's `missing` counter as the counter page last showed it.
    missing: [u16; ssis::calib::N_FOG],
}

impl Judge {
    fn frame(&mut self, f: &OutputFrame, phase: Phase, now_s: f64, fault_v: Option<f64>, c: &mut FlightFaultCheck) {
        let sample = f.time_us / self.dt_us;
        match phase {
            Phase::Before => {
                c.frames_before += 1;
                if f.time_us > 0 {
                    match self.last_sample {
                        Some(s) if sample == s + 1 => c.on_time_before += 1,
                        Some(_) => c.missed_before += 1,
                        None => {}
                    }
                }
                if let Some(page::Entry::Fog(i, FogCounter::Missing)) = page::entry(f.page_id) {
                    if let Some(m) = self.missing.get_mut(i) {
                        *m = f.page_value;
                    }
                    c.samples_missing_before = self.missing.iter().map(|&m| u32::from(m)).sum();
                }
                let r = self.reference.remove(&f.time_us);
                c.equal_before += u64::from(r.is_some_and(|r| masked(r) == masked(*f)));
            }
            Phase::Faulted => {
                c.frames_faulted += 1;
                // The flight build: not the step of the wake the fault came in at (its
                // tick was counted already).
                let late = c.lockstep || f.time_us > (c.fault_s * 1e6) as u64 + self.dt_us * 3 / 2;
                if let Some(t_f) = fault_v.filter(|_| late) {
                    c.tick_back_after_s.get_or_insert(now_s - t_f);
                }
            }
            Phase::Resetting | Phase::After => {
                c.frames_after += 1;
                if let Some(t_f) = fault_v {
                    c.output_back_after_s.get_or_insert(now_s - t_f);
                }
            }
        }
        if f.time_us > 0 {
            self.last_sample = Some(sample);
        }
        let rec = self.eval.evaluate(&Observed::from(f));
        if let Some(r) = rec.as_ref() {
            self.last_t_s = r.t_s;
        }
        if let Some(r) = rec.as_ref().filter(|r| r.t_s >= self.settle_s && claims_good(f)) {
            c.claimed += 1;
            let share = r.att_err_arcsec.iter().zip(&self.bound).fold(0.0f64, |a, (e, b)| a.max(e.abs() / b));
            let share = if share.is_nan() { f64::INFINITY } else { share };
            c.worst_claimed_share = c.worst_claimed_share.max(share);
            c.claimed_beyond += u64::from(share > 1.0);
        }
        if phase != Phase::Before {
            match rec.filter(|r| r.att_err_arcsec.iter().zip(&self.bound).all(|(e, b)| e.abs() <= *b)) {
                None => self.back_from = None,
                Some(r) => {
                    self.back_from.get_or_insert(r.t_s);
                }
            }
        }
    }
}

/// Steps of FOG bytes the flight build's receive ring holds (512 B, 64 B a step).
const RING_STEPS: usize = 8;

/// The sensor links as the fed flight writes them, and the byte totals a STEP names.
struct Links3 {
    fog_total: u32,
    st_total: u32,
}

/// Injects `fault` through the gdbstub into the guest halted at `pc`: the SysTick's
/// enable bit cleared (the guest's own accesses), a branch to itself written at `pc`, or
/// PRIMASK set.
fn inject(g: &mut crate::gdb::Gdb, fault: LoopFault, pc: u32) -> Result<()> {
    match fault {
        LoopFault::TickStopped => {
            let csr = g.read_device_u32(crate::upset::SYST_CSR)?;
            g.write_device_u32(crate::upset::SYST_CSR, csr & !1)
        }
        LoopFault::Stall => g.write_memory(pc & !1, &[0xfe, 0xe7]),
        LoopFault::InterruptsMasked => g.mask_interrupts(),
    }
}

/// `-icount` of the flight build's fed flight: virtual time the instruction count while
/// the guest runs; asleep, it waits the host's time to its next timer deadline and lands
/// on it (`sleep=on`), and a stop at a breakpoint costs it only the host's time to the
/// halt, not a jump to that deadline (`sleep=off` would make every stop a tick late).
pub const FED_ICOUNT: &str = "shift=0,sleep=on";

/// Where a receive ring (`ssis::link::RxRing`) of the firmware lies, and its fields, from
/// the ELF's debug information: the runner puts a step's bytes into it as the UART
/// interrupt would ([`RxRingAt::push`]).
#[derive(Debug, Clone, Copy)]
struct RxRingAt {
    addr: u32,
    size: usize,
    /// The `RefCell`'s borrow flag.
    borrow: usize,
    buf: usize,
    capacity: usize,
    head: usize,
    len: usize,
    overflows: usize,
    received: usize,
}

impl RxRingAt {
    /// The ring the static `name` of `elf` is (its DWARF variable's name).
    fn find(elf: &Path, name: &str) -> Result<RxRingAt> {
        crate::upset::with_dwarf(elf, |_, dwarf| Self::find_in(elf, name, dwarf))
    }

    fn find_in(elf: &Path, name: &str, dwarf: &crate::upset::Dwarf<'_>) -> Result<RxRingAt> {
        use gimli::AttributeValue;
        let mut units = dwarf.units();
        while let Some(header) = units.next()? {
            let unit = dwarf.unit(header)?;
            let mut entries = unit.entries();
            while let Some((_, e)) = entries.next_dfs()? {
                if e.tag() != gimli::DW_TAG_variable {
                    continue;
                }
                let Some(n) = e.attr_value(gimli::DW_AT_name)? else { continue };
                if dwarf.attr_string(&unit, n)?.to_string_lossy() != name {
                    continue;
                }
                let Some(AttributeValue::Exprloc(loc)) = e.attr_value(gimli::DW_AT_location)? else { continue };
                let mut ops = loc.operations(unit.encoding());
                let Some(gimli::Operation::Address { address }) = ops.next()? else { continue };
                let Some(AttributeValue::UnitRef(ty)) = e.attr_value(gimli::DW_AT_type)? else { continue };
                let size = unit
                    .entry(ty)?
                    .attr_value(gimli::DW_AT_byte_size)?
                    .and_then(|v| v.udata_value())
                    .with_context(|| format!("{name}: its type has no size"))? as usize;
                let mut fields = Vec::new();
                members(dwarf, &unit, ty, 0, 0, &mut fields)?;
                let at = |f: &str| -> Result<&(String, usize, usize)> {
                    let mut it = fields.iter().filter(|(n, _, _)| n == f);
                    let first = it.next().with_context(|| format!("{name}: no field {f} in its type"))?;
                    anyhow::ensure!(it.next().is_none(), "{name}: two fields named {f}");
                    Ok(first)
                };
                let buf = at("buf")?;
                return Ok(RxRingAt {
                    addr: address as u32,
                    size,
                    borrow: at("borrow")?.1,
                    buf: buf.1,
                    capacity: buf.2,
                    head: at("head")?.1,
                    len: at("len")?.1,
                    overflows: at("overflows")?.1,
                    received: at("received")?.1,
                });
            }
        }
        anyhow::bail!("{}: no static {name} in its debug information", elf.display())
    }

    /// Pushes `bytes` into the ring as `RxRing::push` does byte by byte (counted as
    /// received; a full ring drops and counts an overflow). The guest must be halted
    /// outside the ring's critical section (on entry to an interrupt handler it is: the
    /// section masks interrupts).
    fn push(&self, g: &mut crate::gdb::Gdb, bytes: &[u8]) -> Result<()> {
        if bytes.is_empty() {
            return Ok(());
        }
        let mut m = g.read_memory(self.addr, self.size)?;
        let word = |m: &[u8], o: usize| -> Result<u32> {
            Ok(u32::from_le_bytes(m.get(o..o + 4).context("ring field")?.try_into()?))
        };
        anyhow::ensure!(word(&m, self.borrow)? == 0, "the ring at {:#x} is borrowed", self.addr);
        let (head, mut len) = (word(&m, self.head)? as usize, word(&m, self.len)? as usize);
        let (mut received, mut overflows) = (word(&m, self.received)?, word(&m, self.overflows)?);
        for &b in bytes {
            received = received.wrapping_add(1);
            if len >= self.capacity {
                overflows = overflows.saturating_add(1);
                continue;
            }
            *m.get_mut(self.buf + (head + len) % self.capacity).context("ring slot")? = b;
            len += 1;
        }
        for (o, v) in [(self.len, len as u32), (self.received, received), (self.overflows, overflows)] {
            m.get_mut(o..o + 4).context("ring field")?.copy_from_slice(&v.to_le_bytes());
        }
        g.write_memory(self.addr, &m)
    }
}

/// Every member reachable from the structure type at `ty` (offset `base`): (name, byte
/// offset, element count of an array member, else 0).
fn members<R: gimli::Reader<Offset = usize>>(
    dwarf: &gimli::Dwarf<R>,
    unit: &gimli::Unit<R>,
    ty: gimli::UnitOffset,
    base: usize,
    depth: u32,
    out: &mut Vec<(String, usize, usize)>,
) -> Result<()> {
    use gimli::AttributeValue;
    anyhow::ensure!(depth < 16, "the ring's type nests too deep");
    let mut tree = unit.entries_tree(Some(ty))?;
    let root = tree.root()?;
    let mut children = root.children();
    while let Some(child) = children.next()? {
        let e = child.entry();
        if e.tag() != gimli::DW_TAG_member {
            continue;
        }
        let Some(n) = e.attr_value(gimli::DW_AT_name)? else { continue };
        let name = dwarf.attr_string(unit, n)?.to_string_lossy()?.into_owned();
        let off =
            base + e.attr_value(gimli::DW_AT_data_member_location)?.and_then(|v| v.udata_value()).unwrap_or(0) as usize;
        let Some(AttributeValue::UnitRef(t)) = e.attr_value(gimli::DW_AT_type)? else { continue };
        let te = unit.entry(t)?;
        let mut count = 0;
        if te.tag() == gimli::DW_TAG_array_type {
            let mut at = unit.entries_tree(Some(t))?;
            let r = at.root()?;
            let mut sub = r.children();
            while let Some(s) = sub.next()? {
                if let Some(c) = s.entry().attr_value(gimli::DW_AT_count)?.and_then(|v| v.udata_value()) {
                    count = c as usize;
                }
            }
        }
        out.push((name, off, count));
        if te.tag() == gimli::DW_TAG_structure_type {
            members(dwarf, unit, t, off, depth + 1, out)?;
        }
    }
    Ok(())
}

/// What both feeds of a fed flight share: the scenario's steps, the QEMU unit and its
/// gdbstub, the judge, and the in-process core that gives the frames to compare with.
struct FedFlight {
    inputs: Vec<StepInput>,
    profile: Profile,
    reset_at: u32,
    wfi: Vec<u32>,
    warnings_at: Option<u32>,
    unit: Unit,
    g: crate::gdb::Gdb,
    judge: Judge,
    core: FlightCore,
    ref_links: (MockLink, MockLink, MockSink),
    dec: StreamDecoder<OutputFrame, 256>,
    c: FlightFaultCheck,
    started: Instant,
    wall_cap: Duration,
}

impl FedFlight {
    /// QEMU started halted (`-S`) on `elf` with the table loaded, its gdbstub connected,
    /// `-action watchdog=pause`; `lockstep`: `elf` is a test build.
    fn start(elf: &Path, sc: &Scenario, watch_s: f64, icount: Option<&str>, lockstep: bool) -> Result<FedFlight> {
        crate::qemu::check_qemu_and_elf(elf)?;
        let started = Instant::now();
        let mut sim = Simulation::new(sc)?;
        let (table, profile) = (sim.table, sim.profile);
        let inputs: Vec<StepInput> = std::iter::from_fn(|| sim.next_step()).collect();
        let nominal = ssis_sim::harness::run(sc, |_| {})?.accuracy.att.three_sigma();
        let calib = crate::qemu::symbol(elf, "_calib_start")?;
        let image = store::image(&table);
        let port = std::net::TcpListener::bind("127.0.0.1:0")?.local_addr()?.port();
        let extra = ["-S", "-gdb", &format!("tcp:127.0.0.1:{port}"), "-action", "watchdog=pause"].map(String::from);
        let unit = Unit::start(
            elf,
            3,
            icount,
            &[("table.img", &image, calib)],
            &[0],
            crate::transport::Transport::Sockets,
            &extra,
        )?;
        let g = crate::gdb::Gdb::connect(port, Duration::from_secs(10))?;
        Ok(FedFlight {
            profile,
            reset_at: (crate::qemu::symbol(elf, "Reset")? & !1) as u32,
            wfi: loop_wfi(elf)?,
            warnings_at: crate::upset::data_symbol(elf, "ssis_firmware::mps2::WATCHDOG_WARNINGS")?,
            unit,
            g,
            judge: Judge {
                eval: Evaluator::for_unit(&table, &profile, sc.settle_s),
                bound: nominal.map(|s| 2.0 * s),
                settle_s: sc.settle_s,
                dt_us: u64::from(profile.dt_us),
                reference: std::collections::HashMap::new(),
                last_sample: None,
                back_from: None,
                last_t_s: 0.0,
                missing: [0; ssis::calib::N_FOG],
            },
            core: FlightCore::new(profile, &table, false).map_err(|e| anyhow::anyhow!("{e:?}"))?,
            ref_links: (MockLink::ideal(), MockLink::ideal(), MockSink::default()),
            dec: StreamDecoder::new(),
            c: FlightFaultCheck { lockstep, nominal_3sigma_arcsec: nominal, ..Default::default() },
            wall_cap: Duration::from_secs_f64(3.0 * (sc.duration_s + watch_s) + 120.0),
            started,
            inputs,
        })
    }

    /// Step `k`'s truth to the judge; before the fault, the in-process core steps on its
    /// bytes and its frame is kept to compare with the unit's.
    fn reference(&mut self, k: usize, phase: Phase) -> Option<(Vec<u8>, &[u8])> {
        let input = self.inputs.get(k)?;
        let bus = bus_bytes(input, &self.profile);
        if let Some(t) = input.truth {
            self.judge.eval.push_truth(t);
        }
        if phase == Phase::Before {
            let (fog, star, out) = &mut self.ref_links;
            fog.send(&bus);
            star.send(&input.st_bytes);
            self.core.step(&mut Links { fog: FogLinks::Bus(fog), star, out: &mut *out });
            if let Ok(f) = OutputFrame::decode(&std::mem::take(&mut out.bytes)) {
                self.judge.reference.insert(f.time_us, f);
            }
        }
        Some((bus, &input.st_bytes))
    }

    /// The output bytes received so far, decoded and judged at virtual time `now_s`;
    /// whether any frame came.
    fn judge_output(&mut self, phase: Phase, now_s: f64, fault_v: Option<f64>) -> bool {
        let mut frames = Vec::new();
        while let Ok((_, b)) = self.unit.rx.try_recv() {
            self.dec.push_slice(&b, |r| frames.extend(r.ok()));
        }
        for f in &frames {
            self.judge.frame(f, phase, now_s, fault_v, &mut self.c);
        }
        !frames.is_empty()
    }

    /// Switches the test build to lockstep with none of the runner's time in the unit's:
    /// a breakpoint after each `wfi` of its loop, and at the first wake (booted, in its
    /// loop, halted: virtual time stands still) the LOCKSTEP frame is put into its
    /// control ring as the UART's interrupt would ([`RxRingAt::push`]). The loop's next
    /// wait drains the ring before it looks at the tick, so no step runs on the timer
    /// after that wake and the feed may go at once. (Sent over the UART instead, the
    /// frame's arrival could be proven only by a silence of the unit's own tick, some
    /// hundreds of ms of virtual time on a loaded host.) The wake's virtual time is read
    /// on `clock` into `vt`. Resumes the guest (halted or at `Reset`) and leaves it
    /// running; returns the output sent before the wake.
    fn enter_lockstep(&mut self, ctl: &RxRingAt, vt: &mut VirtualTime, clock: &GuestClock) -> Result<Vec<u8>> {
        let woke: Vec<u32> = self.wfi.iter().map(|a| a + 2).collect();
        for &a in &woke {
            self.g.set_breakpoint(a)?;
        }
        vt.resume(&mut self.g)?;
        let mut out = Vec::new();
        let stop = loop {
            while let Ok((_, b)) = self.unit.rx.try_recv() {
                out.extend_from_slice(&b);
            }
            if let Some(s) = self.g.wait_stop(Duration::from_millis(20))? {
                break s;
            }
            self.check_running()?;
        };
        vt.halted(clock, &mut self.g)?;
        let pc = self.g.register_u32(crate::gdb::PC)?;
        anyhow::ensure!(woke.contains(&pc), "entering lockstep, the guest stopped at {pc:#x}: {stop}");
        while let Ok((_, b)) = self.unit.rx.try_recv() {
            out.extend_from_slice(&b);
        }
        ctl.push(&mut self.g, &ControlFrame { command: command::LOCKSTEP, ..Default::default() }.to_bytes())?;
        for &a in &woke {
            self.g.clear_breakpoint(a)?;
        }
        vt.resume(&mut self.g)?;
        Ok(out)
    }

    /// The watchdog acted (the guest paused at `now_s`): its counts read, the machine
    /// reset (what `-action watchdog=reset` does) and held at `Reset`.
    fn watchdog_acted(&mut self, now_s: f64, fault_v: Option<f64>) -> Result<()> {
        self.c.reset_after_s = fault_v.map(|f| now_s - f);
        if let Some(a) = self.warnings_at {
            self.c.warnings = u32::from_le_bytes(self.g.read_memory(a, 4)?.as_slice().try_into()?);
        }
        self.c.watchdog_pending = self.g.read_memory(WDOG_RIS, 4)?.first().is_some_and(|b| b & 1 != 0);
        self.g.monitor("system_reset")?;
        self.g.set_breakpoint(self.reset_at)
    }

    fn check_running(&mut self) -> Result<()> {
        anyhow::ensure!(self.unit.exited()?.is_none(), "QEMU exited");
        anyhow::ensure!(
            self.started.elapsed() < self.wall_cap,
            "the fed flight took over {:?} of wall time",
            self.wall_cap
        );
        Ok(())
    }

    fn finish(mut self, elf: &Path) -> FlightFaultCheck {
        // A resumed unit's first frames carry its snapshot's (earlier) time tags.
        self.c.back_after_s = self.judge.back_from.map(|b| (b - self.c.fault_s).max(0.0));
        self.c.wall_s = self.started.elapsed().as_secs_f64();
        self.unit.kill();
        self.c.log = self.unit.log(elf);
        self.c.resumed = self.c.log.iter().any(|l| l.contains("resumed from the snapshot"));
        self.c
    }
}

/// Flies the spacecraft firmware `elf` on scenario `sc` with its sensor bytes on time,
/// injects `fault` at the first output frame whose time tag reaches `fault_s` (after
/// convergence), and follows the unit for `watch_s` of virtual time after it. The
/// watchdog's action (`-action watchdog=pause`) gives the reset's instant; the runner then
/// resets the machine (`system_reset`, what `-action watchdog=reset` does); the steps due
/// while the unit was down are lost, as a real unit's sensors' would be.
///
/// The flight build (`ssis-fw`, its own SysTick) runs under `-icount` [`FED_ICOUNT`] with
/// a breakpoint on its SysTick handler: at each tick, before the step it starts, the runner
/// reads its clock of virtual time (a CMSDK timer it keeps, [`GuestClock`]) and puts the
/// bytes of every scenario step due by then into the firmware's FOG and star-tracker
/// receive rings ([`RxRingAt::push`]), as the UART interrupts would have by then. No host
/// is in the timing: the feed is on time however loaded the host. The fault goes in at
/// the loop's `wfi` after the step whose frame reaches `fault_s`.
///
/// A test build (`ssis-fw-test`) flies in lockstep, paced at the real rate at most
/// (`icount`: QEMU's `-icount`, or none): LOCKSTEP into its control ring at the first
/// wake of its loop after boot and again after the reset (`FedFlight::enter_lockstep`:
/// the feed goes on at once, no virtual time spent on the switch), then step n's bytes
/// over the UARTs and its STEP frame once step n − 1's output is in and not before step
/// n's time. On a loaded host a step's round trip outlasts its period and the feed runs
/// behind the real rate, so the unit is followed for `watch_s` of its own time (its
/// frames' time tags). At the reset the bytes the unit had not taken are dropped
/// ([`drain_uarts`]: a UART in reset receives nothing), the steps whose time came while
/// it was down (from the fault to its first wake, virtual time) are lost, and the
/// scenario goes on from there at the real rate.
///
/// Every output frame is judged against truth by its time tag ([`Evaluator`]); before the
/// fault each is also compared with the in-process core's frame of the same time tag.
pub fn loop_fault_in_flight(
    elf: &Path,
    sc: &Scenario,
    fault: LoopFault,
    fault_s: f64,
    watch_s: f64,
    icount: Option<&str>,
) -> Result<FlightFaultCheck> {
    if crate::qemu::is_test_build(elf)? {
        in_lockstep(FedFlight::start(elf, sc, watch_s, icount, true)?, elf, fault, fault_s, watch_s)
            .map(|f| f.finish(elf))
    } else {
        at_ticks(FedFlight::start(elf, sc, watch_s, Some(FED_ICOUNT), false)?, elf, fault, fault_s, watch_s)
            .map(|f| f.finish(elf))
    }
}

/// The flight build fed at its ticks ([`loop_fault_in_flight`]).
fn at_ticks(mut f: FedFlight, elf: &Path, fault: LoopFault, fault_s: f64, watch_s: f64) -> Result<FedFlight> {
    // Where the loop wakes from its `wfi`: the pass after it steps if a tick came.
    let [wfi] = f.wfi.as_slice() else { anyhow::bail!("{} wfi in the flight build's loop, not one", f.wfi.len()) };
    let woke = wfi + 2;
    let (fog_ring, st_ring) = (RxRingAt::find(elf, "FOG_RX")?, RxRingAt::find(elf, "ST_RX")?);
    let dt_s = f.profile.dt_s();
    let mut clock = GuestClock::start(&mut f.g, 0.0)?;
    f.g.set_breakpoint(woke)?;
    f.g.resume()?;
    let mut phase = Phase::Before;
    // Virtual time of the first wake (the scenario's step 1), s.
    let mut t0_s: Option<f64> = None;
    let mut next = 0usize;
    let mut fault_v: Option<f64> = None;
    // After a reset, until its first wake: the steps due meanwhile are lost.
    let mut lost = false;
    // Virtual time at the last stop, s.
    let mut now_s = 0.0;
    // The ticks its SysTick handler had counted at the last wake.
    let ticks_at = crate::upset::data_symbol(elf, "ssis_firmware::mps2::TICKS")?.context("no TICKS")?;
    let mut ticks_seen = 0u32;
    loop {
        let stop = loop {
            if let Some(s) = f.g.wait_stop(Duration::from_millis(20))? {
                break s;
            }
            f.check_running()?;
        };
        if phase == Phase::Resetting {
            // The timer was reset too: the reset's instant stands.
            anyhow::ensure!(f.g.register_u32(crate::gdb::PC)? == f.reset_at, "the reset stopped elsewhere: {stop}");
            f.g.clear_breakpoint(f.reset_at)?;
            f.g.set_breakpoint(woke)?;
            clock = GuestClock::start(&mut f.g, now_s)?;
            phase = Phase::After;
            lost = true;
            ticks_seen = 0;
            f.g.resume()?;
            continue;
        }
        now_s = clock.now_s(&mut f.g)?;
        // Frames sent before this stop (the guest is halted; its last bytes are in the socket).
        f.judge_output(phase, now_s, fault_v);
        // The watchdog's pause can meet a breakpoint's stop, which then reports it.
        if stop.starts_with("T0e") || f.g.monitor("info status")?.contains("watchdog") {
            f.watchdog_acted(now_s, fault_v)?;
            phase = Phase::Resetting;
            f.g.resume()?;
            continue;
        }
        let pc = f.g.register_u32(crate::gdb::PC)?;
        anyhow::ensure!(pc == woke, "the guest stopped at {pc:#x}: {stop}");
        // Woken (by its tick): the next step's bytes go into the rings, as the FOGs sample
        // on the unit's sync pulse; steps overdue by more than a period by virtual time
        // (step n at (n − 1)·Δt after the first: the tick stopped, the unit down) go in
        // with them, as the sensors would have sent them. Virtual time alone would not
        // do: asleep, or stopped here until QEMU halts, the guest's time follows the
        // host's, and a loaded host lands it late on its deadline.
        let t0 = *t0_s.get_or_insert(now_s);
        let overdue = ((now_s - t0) / dt_s - 1.0).max(0.0) as usize + 1;
        if std::mem::take(&mut lost) {
            next = next.max(overdue.saturating_sub(1));
        }
        // One step a tick its handler counted since the last wake (none when a pending
        // interrupt it cannot take ends the `wfi`: interrupts masked).
        let counted = u32::from_le_bytes(f.g.read_memory(ticks_at, 4)?.as_slice().try_into()?);
        let ticks = counted.wrapping_sub(std::mem::replace(&mut ticks_seen, counted)) as usize;
        let due = (next + ticks.min(RING_STEPS)).max(overdue).min(f.inputs.len());
        if phase == Phase::Before && due > next + 1 && next > 0 {
            f.c.ticks_coalesced_before += 1;
        }
        let (mut fog, mut st) = (Vec::new(), Vec::new());
        for k in next..due {
            if let Some((bus, st_bytes)) = f.reference(k, phase) {
                fog.extend(bus);
                st.extend_from_slice(st_bytes);
            }
        }
        next = due;
        fog_ring.push(&mut f.g, &fog)?;
        st_ring.push(&mut f.g, &st)?;
        if phase == Phase::Before && f.judge.last_t_s >= fault_s {
            // The fault, before the step of this wake.
            inject(&mut f.g, fault, pc)?;
            fault_v = Some(now_s);
            f.c.fault_s = f.judge.last_t_s;
            phase = Phase::Faulted;
            if fault != LoopFault::TickStopped {
                // The loop spins here, or on a pending interrupt it cannot take, until the
                // reset (a stop here could also take the place of the watchdog's pause).
                f.g.clear_breakpoint(woke)?;
                f.g.resume()?;
                continue;
            }
        }
        if fault_v.is_some_and(|t_f| now_s - t_f >= watch_s) {
            f.c.watched_s = fault_v.map_or(0.0, |t_f| now_s - t_f);
            return Ok(f);
        }
        anyhow::ensure!(next < f.inputs.len(), "the scenario ended before the watch did");
        f.g.resume_past(woke)?;
    }
}

/// The test build fed in lockstep ([`loop_fault_in_flight`]).
fn in_lockstep(mut f: FedFlight, elf: &Path, fault: LoopFault, fault_s: f64, watch_s: f64) -> Result<FedFlight> {
    let dt_s = f.profile.dt_s();
    let mut clock = GuestClock::start(&mut f.g, 0.0)?;
    let mut vt = VirtualTime { at_halt_s: 0.0, running_since: None };
    // The step due when the fault went in (its bytes and the later ones until the unit is
    // back are the steps a unit that is down loses).
    let mut fault_next = 0usize;
    // Virtual time of the last output frame, s.
    let mut last_frame_s = 0.0;
    let mut links = Links3 { fog_total: 0, st_total: 0 };
    let mut phase = Phase::Before;
    // The next step to send (index into `inputs`).
    let mut next = 0usize;
    let mut fault_v: Option<f64> = None;
    let mut fault_armed = false;
    // A STEP sent whose output is not yet in.
    let mut awaiting = false;
    let mut last_poll = Instant::now();
    let ctl = RxRingAt::find(elf, "CTL_RX")?;
    let boot = f.enter_lockstep(&ctl, &mut vt, &clock)?;
    f.dec.push_slice(&boot, |r| {
        if let Ok(fr) = r {
            f.c.frames_before += u64::from(fr.time_us == 0);
        }
    });
    // Virtual time of step 1's tick, s (moved after a reset: the scenario goes on at the
    // real rate from the re-entry).
    let mut t0_s = vt.now_s() + dt_s;
    loop {
        f.check_running()?;
        // Output frames.
        let mut frames = Vec::new();
        if let Ok((_, b)) = f.unit.rx.recv_timeout(Duration::from_millis(1)) {
            f.dec.push_slice(&b, |r| frames.extend(r.ok()));
            while let Ok((_, b)) = f.unit.rx.try_recv() {
                f.dec.push_slice(&b, |r| frames.extend(r.ok()));
            }
        }
        let now_s = vt.now_s();
        if !frames.is_empty() {
            last_frame_s = now_s;
        }
        for fr in &frames {
            f.judge.frame(fr, phase, now_s, fault_v, &mut f.c);
            if phase == Phase::Before && !fault_armed && fr.time_us as f64 * 1e-6 >= fault_s {
                // The fault at the loop's `wfi`, where the guest goes next (the gdbstub
                // takes a packet only from a halted guest; virtual time stands still).
                f.g.halt()?;
                vt.halted(&clock, &mut f.g)?;
                for &a in &f.wfi {
                    f.g.set_breakpoint(a)?;
                }
                vt.resume(&mut f.g)?;
                fault_armed = true;
            }
        }
        // The feed.
        awaiting &= frames.is_empty();
        let due = now_s >= t0_s + next as f64 * dt_s;
        if !awaiting && due && phase != Phase::Resetting && !fault_armed {
            if let Some((bus, st)) = f.reference(next, phase) {
                let st = st.to_vec();
                f.unit.uarts[1].write_all(&bus)?;
                f.unit.uarts[2].write_all(&st)?;
                links.fog_total = links.fog_total.wrapping_add(bus.len() as u32);
                links.st_total = links.st_total.wrapping_add(st.len() as u32);
                f.unit.control(&ControlFrame {
                    command: command::STEP,
                    fog_bytes: links.fog_total,
                    st_bytes: links.st_total,
                    arg: 0,
                })?;
            }
            next += 1;
            awaiting = true;
        }
        // The gdbstub: a stop at the fault's breakpoint, the watchdog's action, the reset.
        let watching = fault_armed || phase != Phase::Before;
        if watching || last_poll.elapsed() > Duration::from_millis(20) {
            last_poll = Instant::now();
            if let Some(stop) = f.g.wait_stop(Duration::ZERO)? {
                // Resetting, the timer was reset too: the reset's instant stands.
                let now_s = if phase == Phase::Resetting {
                    vt.running_since = None;
                    vt.at_halt_s
                } else {
                    vt.halted(&clock, &mut f.g)?
                };
                if stop.starts_with("T0e") {
                    f.watchdog_acted(now_s, fault_v)?;
                    phase = Phase::Resetting;
                    vt.resume(&mut f.g)?;
                    continue;
                }
                let pc = f.g.register_u32(crate::gdb::PC)?;
                if pc == f.reset_at && phase == Phase::Resetting {
                    f.g.clear_breakpoint(f.reset_at)?;
                    f.c.dropped_at_reset += drain_uarts(&mut f.g)?;
                    clock = GuestClock::start(&mut f.g, now_s)?;
                    phase = Phase::After;
                    // Back into lockstep at the first wake; the byte counts start again.
                    links = Links3 { fog_total: 0, st_total: 0 };
                    let boot = f.enter_lockstep(&ctl, &mut vt, &clock)?;
                    let now_s = vt.now_s();
                    let mut booted = Vec::new();
                    f.dec.push_slice(&boot, |r| booted.extend(r.ok()));
                    for fr in &booted {
                        f.judge.frame(fr, phase, now_s, fault_v, &mut f.c);
                    }
                    // The steps whose tick came while the unit was down (from the fault to
                    // this wake, virtual time) are lost, and the scenario goes on from here
                    // at the real rate. Not the runner's schedule from step 1: the lockstep
                    // feed runs behind the real rate on a loaded host (a step's round
                    // trip is longer than its period), and that backlog is not time the
                    // unit was down.
                    let down_s = fault_v.map_or(0.0, |t_f| (now_s - t_f).max(0.0));
                    next = next.max(fault_next + (down_s / dt_s).ceil() as usize);
                    t0_s = now_s - next as f64 * dt_s;
                    awaiting = false;
                    continue;
                }
                anyhow::ensure!(fault_armed && f.wfi.contains(&pc), "the guest stopped at {pc:#x}: {stop}");
                fault_armed = false;
                fault_v = Some(now_s);
                fault_next = next;
                f.c.fault_s = f.judge.last_t_s;
                for &a in &f.wfi {
                    f.g.clear_breakpoint(a)?;
                }
                match fault {
                    // The test build clears it itself at its next pass (a guest access
                    // here can fault with an interrupt pending at the stop).
                    LoopFault::TickStopped => f.unit.command(command::TICK_STOP)?,
                    _ => inject(&mut f.g, fault, pc)?,
                }
                phase = Phase::Faulted;
                vt.resume(&mut f.g)?;
                continue;
            }
        }
        // Followed for `watch_s` of the unit's time (its frames' tags: in lockstep the
        // feed sets its pace, not virtual time), or of virtual time without a frame (the
        // unit did not come back).
        if let Some(t_f) = fault_v {
            let now_s = vt.now_s();
            f.c.watched_s = f.judge.last_t_s - f.c.fault_s;
            if f.c.watched_s >= watch_s || now_s - last_frame_s.max(t_f) >= watch_s {
                f.c.watched_s = f.c.watched_s.max(0.0);
                return Ok(f);
            }
        }
        anyhow::ensure!(
            next < f.inputs.len() || awaiting,
            "the scenario ended {} s after the fault ({} steps sent, the last frame's time tag {} s, fault {})",
            f.c.watched_s,
            next,
            f.judge.last_t_s,
            if fault_v.is_some() {
                "in"
            } else if fault_armed {
                "armed"
            } else {
                "not armed"
            }
        );
    }
}
