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
use ssis::telemetry::{page, Counter, PAGED};
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

/// A loop fault of the flight build flown on its scenario, fed on time
/// ([`loop_fault_in_flight`]).
#[derive(Debug, Clone, Default)]
pub struct FlightFaultCheck {
    /// The undisturbed flight's attitude error 3σ per axis (|mean| + 3 std after
    /// settling, the in-process core on the same scenario), ″.
    pub nominal_3sigma_arcsec: [f64; 3],
    /// The fault, s of the unit's virtual time since its first tick.
    pub fault_s: f64,
    /// Output frames before the fault.
    pub frames_before: u64,
    /// Of those, frames equal to the in-process core's on the same bytes in the same steps
    /// (masked as [`masked`]): the feed was on time.
    pub equal_before: u64,
    /// From the fault to the watchdog's action, s of virtual time (`None`: no reset).
    pub reset_after_s: Option<f64>,
    /// No reset: from the fault to the first tick after it, s of virtual time (the tick
    /// restored by the firmware), if the tick came back.
    pub tick_back_after_s: Option<f64>,
    /// At the watchdog's action: the firmware's count of watchdog warnings.
    pub warnings: u32,
    /// At the watchdog's action: its raw interrupt status (a timeout not fed since).
    pub watchdog_pending: bool,
    /// Output frames between the fault and the reset (or the end, without one).
    pub frames_faulted: u64,
    /// From the fault to the first output frame after the reset, s of virtual time.
    pub output_back_after_s: Option<f64>,
    /// From the fault to the frame from which every frame to the end is judged against
    /// truth and within twice the nominal 3σ on each axis, s of virtual time.
    pub back_after_s: Option<f64>,
    /// Frames after settling that claim a good attitude (converged, not degraded, no
    /// parity alarm) with an error beyond twice the nominal 3σ on an axis.
    pub claimed_beyond: u64,
    /// Frames after settling that claim a good attitude.
    pub claimed: u64,
    /// The largest error of a frame that claims a good attitude, after settling, as a
    /// share of twice the nominal 3σ of its axis (1: on the bound).
    pub worst_claimed_share: f64,
    /// Output frames after the fault (or the reset).
    pub frames_after: u64,
    /// Virtual time flown, s.
    pub flown_s: f64,
    /// The firmware's defmt log.
    pub log: Vec<String>,
}

/// QEMU's `-icount` for the fed flight: virtual time the instruction count while busy,
/// the host's time while idle (`sleep=on`), stopped while the runner holds the guest.
const FED_ICOUNT: &str = "shift=0,sleep=off";

/// The CMSDK timer the runner keeps as its clock of the guest's virtual time (mps2 TIMER0,
/// unused by the firmware): CTRL, VALUE, RELOAD; it counts down at the 25 MHz system clock.
const CLOCK_TIMER: u32 = 0x4000_0000;
/// The system clock, Hz.
const SYSCLK_HZ: f64 = 25e6;
/// The CMSDK watchdog's raw interrupt status (WDOGRIS).
const WDOG_RIS: u32 = 0x4000_8010;

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
        use gimli::{AttributeValue, EndianSlice, RunTimeEndian};
        use object::{Object, ObjectSection};
        let data = std::fs::read(elf).with_context(|| format!("cannot read {}", elf.display()))?;
        let file = object::File::parse(&*data)?;
        let load = |id: gimli::SectionId| -> Result<std::borrow::Cow<'_, [u8]>, gimli::Error> {
            Ok(file.section_by_name(id.name()).and_then(|s| s.uncompressed_data().ok()).unwrap_or_default())
        };
        let sections = gimli::DwarfSections::load(load)?;
        let dwarf = sections.borrow(|s| EndianSlice::new(s, RunTimeEndian::Little));
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
                let size = match unit.entry(ty)?.attr_value(gimli::DW_AT_byte_size)? {
                    Some(v) => v.udata_value().context("ring size")? as usize,
                    None => bail_size(name)?,
                };
                let mut fields = Vec::new();
                members(&dwarf, &unit, ty, 0, 0, &mut fields)?;
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
            let i = (head + len) % self.capacity;
            *m.get_mut(self.buf + i).context("ring slot")? = b;
            len += 1;
        }
        for (o, v) in [(self.len, len as u32), (self.received, received), (self.overflows, overflows)] {
            m.get_mut(o..o + 4).context("ring field")?.copy_from_slice(&v.to_le_bytes());
        }
        g.write_memory(self.addr, &m)
    }
}

/// The address of the main loop's `wfi` (where it sleeps until its next tick): the one
/// `wfi` in `ssis_fw::firmware::fly` of `elf`.
fn loop_wfi(elf: &Path) -> Result<u32> {
    use object::{Object, ObjectSection, ObjectSymbol};
    let data = std::fs::read(elf).with_context(|| format!("cannot read {}", elf.display()))?;
    let file = object::File::parse(&*data)?;
    let sym = file
        .symbols()
        .find(|s| s.name().is_ok_and(|n| n.contains("7ssis_fw8firmware3fly17h")))
        .context("no ssis_fw::firmware::fly")?;
    let start = sym.address() & !1;
    let text = file.section_by_name(".text").context("no .text")?;
    let code = text.data_range(start, sym.size())?.context("fly outside .text")?;
    let at: Vec<u64> = code
        .chunks_exact(2)
        .enumerate()
        .filter(|(_, h)| h == &[0x30, 0xbf])
        .map(|(i, _)| start + 2 * i as u64)
        .collect();
    match at.as_slice() {
        [a] => Ok(*a as u32),
        _ => anyhow::bail!("{} wfi in ssis_fw::firmware::fly, not one", at.len()),
    }
}

fn bail_size(name: &str) -> Result<usize> {
    anyhow::bail!("{name}: its type has no size")
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

/// Flies the flight build `elf` (its own SysTick, no lockstep) on scenario `sc` with its
/// sensor bytes on time in the unit's virtual time, injects `fault` at `fault_s` (after
/// convergence), and follows the unit for `watch_s` after it.
///
/// QEMU runs with `-icount shift=0,sleep=off` (virtual time the instruction count, idle
/// time skipped), started halted (`-S`), its gdbstub driven by the runner, and
/// `-action watchdog=pause`. A breakpoint on the SysTick handler stops the guest at every
/// tick, before the step that tick starts: the runner reads its clock of virtual time (a
/// CMSDK timer it keeps, [`GuestClock`]) and puts the bytes of every scenario step due by
/// then into the firmware's FOG and star-tracker receive rings ([`RxRingAt::push`]),
/// as the UART interrupts would have by then, and resumes. The step of tick n so takes
/// the scenario's step n, as in lockstep, with no host in the timing: the frames before
/// the fault must equal the in-process core's on the same bytes.
///
/// At the first tick at or after `fault_s` the runner injects the fault. The watchdog's
/// action pauses the guest: that instant is the reset's time; the runner then resets the
/// machine (`system_reset`, what `-action watchdog=reset` does) and starts its clock again
/// at the reset vector. Sensor bytes due while the unit was down are lost; the first tick
/// after the reset takes the step then due. Every output frame is judged against truth by
/// its time tag ([`Evaluator`]).
pub fn loop_fault_in_flight(
    elf: &Path,
    sc: &Scenario,
    fault: LoopFault,
    fault_s: f64,
    watch_s: f64,
) -> Result<FlightFaultCheck> {
    use crate::gdb::{Gdb, PC};
    crate::qemu::check_qemu_and_elf(elf)?;
    let mut sim = Simulation::new(sc)?;
    let (table, profile) = (sim.table, sim.profile);
    let dt_s = profile.dt_s();
    let inputs: Vec<StepInput> = std::iter::from_fn(|| sim.next_step()).collect();
    let nominal = ssis_sim::harness::run(sc, |_| {})?.accuracy.att.three_sigma();
    let bound = nominal.map(|s| 2.0 * s);
    let calib = crate::qemu::symbol(elf, "_calib_start")?;
    let reset_at = (crate::qemu::symbol(elf, "Reset")? & !1) as u32;
    let wfi = loop_wfi(elf)?;
    let warnings_at = crate::upset::data_symbol(elf, "ssis_firmware::mps2::WATCHDOG_WARNINGS")?;
    let (fog_ring, st_ring) = (RxRingAt::find(elf, "FOG_RX")?, RxRingAt::find(elf, "ST_RX")?);
    let image = store::image(&table);
    let port = std::net::TcpListener::bind("127.0.0.1:0")?.local_addr()?.port();
    let extra = ["-S", "-gdb", &format!("tcp:127.0.0.1:{port}"), "-action", "watchdog=pause"].map(String::from);
    let mut unit = Unit::start(
        elf,
        3,
        Some(FED_ICOUNT),
        &[("table.img", &image, calib)],
        &[0],
        crate::transport::Transport::Sockets,
        &extra,
    )?;
    let mut g = Gdb::connect(port, Duration::from_secs(10))?;
    g.set_breakpoint(wfi)?;
    g.resume()?;
    let mut c = FlightFaultCheck { nominal_3sigma_arcsec: nominal, fault_s, ..Default::default() };
    let mut eval = Evaluator::for_unit(&table, &profile, sc.settle_s);
    let mut reference = FlightCore::new(profile, &table, false).map_err(|e| anyhow::anyhow!("{e:?}"))?;
    let (mut ref_fog, mut ref_star, mut ref_out) = (MockLink::ideal(), MockLink::ideal(), MockSink::default());
    let mut ref_frames = std::collections::VecDeque::new();
    let mut dec: StreamDecoder<OutputFrame, 256> = StreamDecoder::new();
    let mut clock: Option<GuestClock> = None;
    // Virtual time of the first tick (the scenario's step 1), s.
    let mut t0_s: Option<f64> = None;
    let mut next = 0usize;
    let mut faulted_at: Option<f64> = None;
    let mut reset_s: Option<f64> = None;
    // After a reset, until its first feed: the steps due meanwhile are lost.
    let mut lost = false;
    // The loop's breakpoint is set.
    let mut at_wfi = true;
    // The first frame after the fault from which every frame has been within the bound.
    let mut back_from: Option<f64> = None;
    let patience = crate::progress::Patience::new(&unit.q.as_ref().context("no QEMU")?.child, 120.0);
    let mut now_s;
    loop {
        let stop = loop {
            if let Some(s) = g.wait_stop(Duration::from_millis(50))? {
                break s;
            }
            anyhow::ensure!(unit.exited()?.is_none(), "QEMU exited");
            if let Some(why) = patience.exhausted() {
                anyhow::bail!("the flight build stopped coming back to the runner: {why}");
            }
        };
        let watchdog = stop.starts_with("T0e");
        let pc = g.register_u32(PC)?;
        if pc == reset_at && !watchdog {
            g.clear_breakpoint(reset_at)?;
            clock = Some(GuestClock::start(&mut g, reset_s.context("a reset without the watchdog")?)?);
            lost = true;
            if !at_wfi {
                g.set_breakpoint(wfi)?;
                at_wfi = true;
            }
            g.resume()?;
            continue;
        }
        anyhow::ensure!(watchdog || pc == wfi, "the guest stopped at {pc:#x}: {stop}");
        if clock.is_none() {
            clock = Some(GuestClock::start(&mut g, 0.0)?);
        }
        now_s = clock.as_ref().context("no clock")?.now_s(&mut g)?;
        let t0 = *t0_s.get_or_insert(now_s);
        if watchdog || faulted_at.is_none() && now_s - t0 >= fault_s {
            // Before the fault and at the reset: every frame the guest sent is in (it is
            // halted; the socket's bytes arrive within this wait).
            std::thread::sleep(Duration::from_millis(50));
        }
        // Output frames so far: sent by now_s at the latest.
        let mut frames = Vec::new();
        while let Ok((_, b)) = unit.rx.try_recv() {
            dec.push_slice(&b, |r| frames.extend(r.ok()));
        }
        for f in frames {
            match (faulted_at, reset_s) {
                (None, _) => {
                    c.frames_before += 1;
                    c.equal_before += u64::from(ref_frames.pop_front().is_some_and(|r| masked(r) == masked(f)));
                }
                (Some(_), None) => c.frames_faulted += 1,
                (Some(t_f), Some(_)) => {
                    c.frames_after += 1;
                    c.output_back_after_s.get_or_insert(now_s - t_f);
                }
            }
            let rec = eval.evaluate(&Observed::from(&f));
            if let Some(r) = rec.filter(|r| r.t_s >= sc.settle_s && claims_good(&f)) {
                c.claimed += 1;
                let share = r.att_err_arcsec.iter().zip(&bound).fold(0.0f64, |a, (e, b)| a.max(e.abs() / b));
                let share = if share.is_nan() { f64::INFINITY } else { share };
                c.worst_claimed_share = c.worst_claimed_share.max(share);
                c.claimed_beyond += u64::from(share > 1.0);
            }
            if faulted_at.is_some() {
                let within = rec.is_some_and(|r| r.att_err_arcsec.iter().zip(&bound).all(|(e, b)| e.abs() <= *b));
                if !within {
                    back_from = None;
                } else if back_from.is_none() {
                    back_from = Some(now_s);
                }
            }
        }
        if watchdog {
            // The watchdog's action: the reset's instant, then the reset itself.
            reset_s = Some(now_s);
            c.reset_after_s = faulted_at.map(|f| now_s - f);
            if let Some(a) = warnings_at {
                c.warnings = u32::from_le_bytes(g.read_memory(a, 4)?.as_slice().try_into()?);
            }
            c.watchdog_pending = g.read_memory(WDOG_RIS, 4)?.first().is_some_and(|b| b & 1 != 0);
            g.monitor("system_reset")?;
            g.set_breakpoint(reset_at)?;
            g.resume()?;
            continue;
        }
        // The loop is about to sleep until its next tick: the scenario's steps due by then
        // (step n at (n − 1)·Δt after the first) go into the rings now.
        let csr = u32::from_le_bytes(g.read_memory(crate::upset::SYST_CSR, 4)?.as_slice().try_into()?);
        let cvr = u32::from_le_bytes(g.read_memory(crate::upset::SYST_CSR + 8, 4)?.as_slice().try_into()?);
        if csr & 1 != 0 {
            if faulted_at.is_some() && reset_s.is_none() && c.tick_back_after_s.is_none() {
                c.tick_back_after_s = faulted_at.map(|f| now_s - f);
            }
            let tick_s = now_s + f64::from(cvr) / SYSCLK_HZ - t0;
            let due = ((tick_s / dt_s).round().max(0.0) as usize + 1).min(inputs.len());
            if std::mem::take(&mut lost) {
                next = next.max(due.saturating_sub(1));
            }
            let (mut fog, mut st) = (Vec::new(), Vec::new());
            for input in inputs.get(next..due).unwrap_or_default() {
                let bus = bus_bytes(input, &profile);
                if let Some(t) = input.truth {
                    eval.push_truth(t);
                }
                if faulted_at.is_none() {
                    ref_fog.send(&bus);
                    ref_star.send(&input.st_bytes);
                    let mut links = Links { fog: FogLinks::Bus(&mut ref_fog), star: &mut ref_star, out: &mut ref_out };
                    reference.step(&mut links);
                    ref_frames.extend(OutputFrame::decode(&std::mem::take(&mut ref_out.bytes)).ok());
                }
                fog.extend(bus);
                st.extend_from_slice(&input.st_bytes);
            }
            next = next.max(due);
            fog_ring.push(&mut g, &fog)?;
            st_ring.push(&mut g, &st)?;
        }
        if faulted_at.is_none() && now_s - t0 >= fault_s {
            faulted_at = Some(now_s);
            match fault {
                LoopFault::TickStopped => g.write_device_u32(crate::upset::SYST_CSR, csr & !1)?,
                LoopFault::Stall => g.write_memory(wfi, &[0xfe, 0xe7])?,
                LoopFault::InterruptsMasked => g.mask_interrupts()?,
            }
            if fault != LoopFault::TickStopped {
                // The loop no longer sleeps there: no more stops until the reset.
                g.clear_breakpoint(wfi)?;
                at_wfi = false;
            }
        }
        if now_s - t0 >= fault_s + watch_s || next >= inputs.len() {
            break;
        }
        // Past the `wfi` (a single step: the guest sleeps to its next timer deadline, as
        // it would have), then on.
        if at_wfi {
            g.resume_past(wfi)?;
        } else {
            g.resume()?;
        }
    }
    c.back_after_s = back_from.zip(faulted_at).map(|(b, f)| b - f);
    c.flown_s = now_s;
    unit.kill();
    c.log = unit.log(elf);
    Ok(c)
}
