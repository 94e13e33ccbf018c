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
use ssis::frames::output::OutputFrame;
use ssis::frames::Frame;
use ssis::telemetry::{page, Counter, PAGED};
use ssis_common::mock::{MockLink, MockSink};

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
    match fault {
        LoopFault::TickStopped => {
            let csr = g.read_device_u32(crate::upset::SYST_CSR)?;
            g.write_device_u32(crate::upset::SYST_CSR, csr & !1)?;
        }
        LoopFault::Stall => {
            let pc = g.register_u32(PC)?;
            g.write_memory(pc & !1, &[0xfe, 0xe7])?;
        }
        LoopFault::InterruptsMasked => g.mask_interrupts()?,
    }
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
