//! Where a flip lands: the traced paths (one per [`PathKind`], traced once by
//! single-stepping and kept on disk for the same ELF) and the way to the k-th instruction
//! of one with few stops for the debugger.
//!
//! A breakpoint the guest is halted at is hit again at once on `c` (QEMU checks
//! breakpoints before it executes an instruction; a debugger steps past it: lift,
//! single-step, set again), and a stop at a breakpoint can move QEMU's virtual clock
//! ([`MAX_HITS`]). A flip at the k-th instruction of a path therefore goes through an
//! anchor j ≤ k: a breakpoint at the address of instruction j, taken the first time that
//! address is reached, then k − j single steps ([`Traced::plan`]). The cost is the single
//! steps: a few in straight-line code, up to some thousands inside the pass's loops
//! (about 0.1 ms each on an idle host).

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use anyhow::{Context, Result};
use rand::Rng;
use rand_chacha::ChaCha8Rng;
use ssis::frames::control::{command, ControlFrame};

use super::{flip, pick_device, pick_double, pick_state, Ctx, PathKind, Population, Target};
use crate::gdb::{self, Gdb};
use crate::qemu::Unit;

/// A traced path: the address of every instruction executed, in order, and how often
/// each address has occurred up to there.
#[derive(Debug, Clone, Default)]
pub(super) struct Traced {
    /// The addresses.
    pub(super) pcs: Vec<u32>,
    /// `occ[i]`: the occurrences of `pcs[i]` in `pcs[..=i]`.
    occ: Vec<u32>,
}

/// Round trips of a breakpoint hit past the first (lift, step, set, continue, the stop,
/// the PC) and of one single step (the step and its stop).
const HIT_COST: usize = 5;
const STEP_COST: usize = 1;

/// Most hits of an anchor: one. A stop at a breakpoint can let QEMU warp its virtual
/// clock (`-icount …,sleep=off`) to the next timer deadline while the machine is not yet
/// stopped with the CPU: some ten hits of a breakpoint in the wait loop at the end of a
/// pass (0x6d08–0x6d2a on this build) reset the unit by its watchdog, sixteen elsewhere
/// raised a watchdog warning. Single steps run with QEMU's timers held
/// (`SSTEP_NOTIMER`): a whole pass traced by single steps changes nothing. So the anchor
/// is an address's first occurrence, and the rest is single-stepped (some 1,000 steps
/// on average into a pass, 0.1–0.3 s).
const MAX_HITS: u32 = 1;

impl Traced {
    pub(super) fn new(pcs: Vec<u32>) -> Traced {
        let mut seen: HashMap<u32, u32> = HashMap::new();
        let occ = pcs
            .iter()
            .map(|a| {
                let c = seen.entry(*a).or_default();
                *c += 1;
                *c
            })
            .collect();
        Traced { pcs, occ }
    }

    /// Instructions in the path.
    pub(super) fn len(&self) -> usize {
        self.pcs.len()
    }

    /// The way to instruction `k`: the anchor j ≤ k and the hit m at which its address
    /// is instruction j, the cheapest in round trips (m − 1 hits stepped past, k − j
    /// single steps) of at most [`MAX_HITS`] hits (the entry, j = 0, is one).
    pub(super) fn plan(&self, k: usize) -> (usize, u32) {
        let k = k.min(self.len().saturating_sub(1));
        (0..=k)
            .rev()
            .map(|j| (j, self.occ.get(j).copied().unwrap_or(1)))
            .filter(|&(_, m)| m <= MAX_HITS)
            .min_by_key(|&(j, m)| (m as usize - 1) * HIT_COST + (k - j) * STEP_COST)
            .unwrap_or((0, 1))
    }

    /// The file that keeps the path of `kind` for the ELF whose contents hash to `elf`.
    fn file(elf: u64, kind: PathKind) -> PathBuf {
        let tag = match kind {
            PathKind::Pass(true) => "pass-star",
            PathKind::Pass(false) => "pass",
            PathKind::Handler => "handler",
            PathKind::SnapshotWrite => "snapshot-write",
        };
        std::env::temp_dir().join(format!("ssis-upset-path-{elf:016x}-{tag}.bin"))
    }

    /// The kept path of `kind` for this ELF, if one was traced before.
    pub(super) fn load(elf: u64, kind: PathKind) -> Option<Traced> {
        let b = std::fs::read(Traced::file(elf, kind)).ok()?;
        let pcs: Vec<u32> = b.chunks_exact(4).filter_map(|c| c.try_into().ok()).map(u32::from_le_bytes).collect();
        (!pcs.is_empty()).then(|| Traced::new(pcs))
    }

    /// Keeps the path for later campaigns on the same ELF (written whole, then renamed:
    /// jobs side by side may write it at once).
    fn store(&self, elf: u64, kind: PathKind) {
        let path = Traced::file(elf, kind);
        let tmp = path.with_extension(format!("{}.tmp", std::process::id()));
        let bytes: Vec<u8> = self.pcs.iter().flat_map(|a| a.to_le_bytes()).collect();
        if std::fs::write(&tmp, bytes).is_ok() {
            let _ = std::fs::rename(&tmp, &path);
        }
    }
}

/// A 64-bit FNV-1a hash of the ELF's bytes: the kept paths' key.
pub(super) fn elf_hash(elf: &Path) -> Result<u64> {
    let data = std::fs::read(elf).with_context(|| format!("cannot read {}", elf.display()))?;
    Ok(data.iter().fold(0xcbf2_9ce4_8422_2325u64, |h, b| (h ^ u64::from(*b)).wrapping_mul(0x0100_0000_01b3)))
}

/// The path from here: the address of every instruction executed, in order, up to the
/// first for which `end` holds (single-stepping): for a pass the loop's next `wfi`, for
/// the interrupt its return address, for the snapshot write its caller.
fn trace(g: &mut Gdb, mut end: impl FnMut(&mut Gdb, u32) -> Result<bool>) -> Result<Vec<u32>> {
    let mut pcs = Vec::with_capacity(8192);
    loop {
        let pc = g.register_u32(gdb::PC)?;
        pcs.push(pc);
        if end(g, pc)? {
            return Ok(pcs);
        }
        if pcs.len() >= TRACE_MAX {
            eprintln!("a traced path reached {TRACE_MAX} instructions without its end: cut there");
            return Ok(pcs);
        }
        g.step()?;
    }
}

/// Most instructions of a traced path (a pass with a star update is some 15,000).
const TRACE_MAX: usize = 40_000;

/// Thumb `wfi`.
const WFI: [u8; 2] = [0x30, 0xbf];

/// Where the path of `kind` entered here ends, the guest halted at its entry: a pass at
/// the loop's next `wfi` (`None`: found while tracing), the interrupt at its return
/// address (from the exception frame), the snapshot write at its caller (LR).
fn path_end(g: &mut Gdb, kind: PathKind) -> Result<Option<u32>> {
    Ok(match kind {
        PathKind::Pass(_) => None,
        PathKind::Handler => {
            let sp = g.register_u32(gdb::SP)?;
            let ret = g.read_memory(sp.wrapping_add(24), 4)?;
            let ret = u32::from_le_bytes(ret.get(..4).and_then(|b| b.try_into().ok()).context("no exception frame")?);
            Some(ret & !1)
        }
        PathKind::SnapshotWrite => Some(g.register_u32(14)? & !1),
    })
}

/// The path's entry for `kind`.
fn entry(ctx: &Ctx<'_>, kind: PathKind) -> u32 {
    match kind {
        PathKind::Handler => ctx.handler,
        PathKind::SnapshotWrite => ctx.snapshot_into.unwrap_or(ctx.code.entry),
        PathKind::Pass(_) => ctx.code.entry,
    }
}

/// What placing a flip in a step came to.
pub(super) enum Placed {
    /// The flip: the instruction's index in the path, the target, the PC, the population
    /// (a snapshot write's flip whose write did not come in the step is a state flip).
    Flip { instr: u32, target: Target, pc: u32, population: Population },
    /// No flip: the step traced the path of its kind (the flip goes into a later step).
    Traced,
    /// No flip: the unit stopped at its `Reset` or `HardFault` before the flip's
    /// instruction (an earlier flip's latent effect), halted there.
    Stopped(String),
}

/// Halts the guest, breaks at `at`, sends `step` and waits up to `timeout` for the stop
/// there. `Ok(Some(pc))`: stopped at `pc` (`at`, or a trap), the breakpoint lifted;
/// `Ok(None)`: not reached, the guest halted wherever it was.
fn stop_at(unit: &mut Unit, g: &mut Gdb, step: &ControlFrame, at: u32, timeout: Duration) -> Result<Option<u32>> {
    g.halt()?;
    g.set_breakpoint(at)?;
    g.resume()?;
    unit.control(step)?;
    let stop = g.wait_stop(timeout)?;
    if stop.is_none() {
        g.halt()?;
    }
    g.clear_breakpoint(at)?;
    match stop {
        Some(_) => Ok(Some(g.register_u32(gdb::PC)?)),
        None => Ok(None),
    }
}

/// The name of a stop at one of the traps, `None` at another address.
fn trap(ctx: &Ctx<'_>, pc: u32) -> Option<String> {
    if pc == ctx.traps.reset {
        Some("the unit reset before the flip".to_string())
    } else if pc == ctx.traps.hard_fault {
        Some("a HardFault before the flip".to_string())
    } else {
        None
    }
}

/// Runs the guest, halted at its path's entry, to instruction `k` of `path` ([`Traced::plan`]:
/// a breakpoint at the anchor's address taken at its m-th hit, then single steps), or to
/// `end` (a breakpoint there as well, where a run that leaves the traced path stops
/// first). `Ok(Some(why))`: stopped at a trap instead, halted there.
fn run_to(ctx: &Ctx<'_>, g: &mut Gdb, path: &Traced, k: usize, end: Option<u32>) -> Result<Option<String>> {
    let (j, m) = path.plan(k);
    let a = path.pcs.get(j).copied().context("empty path")?;
    let mut at = g.register_u32(gdb::PC)?;
    let mut hits = u32::from(at == a);
    if hits < m {
        let mut bps = vec![a];
        if let Some(e) = end.filter(|&e| e != a) {
            bps.push(e);
        }
        for &b in &bps {
            g.set_breakpoint(b)?;
        }
        let traps = [ctx.traps.reset, ctx.traps.hard_fault];
        let result = loop {
            if bps.contains(&at) || traps.contains(&at) {
                // Halted at a breakpoint: step past it, or `c` stops there again.
                g.clear_breakpoint(at)?;
                g.step()?;
                g.set_breakpoint(at)?;
                let now = g.register_u32(gdb::PC)?;
                if (ctx.traps.reset..ctx.traps.reset + 64).contains(&now) {
                    for &b in &bps {
                        g.clear_breakpoint(b)?;
                    }
                    return Ok(Some("the unit reset before the flip (seen stepping past a breakpoint)".into()));
                }
            }
            g.resume()?;
            g.wait_stop(Duration::from_secs(60))?
                .with_context(|| format!("{a:#x} (instruction {j}) was not reached"))?;
            at = g.register_u32(gdb::PC)?;
            if at == a {
                hits += 1;
                if hits >= m {
                    break None;
                }
            } else if Some(at) == end {
                break None;
            } else if let Some(why) = trap(ctx, at) {
                break Some(why);
            } else {
                anyhow::bail!("the guest stopped for the debugger at {} on the way to a flip", ctx.syms.name(at));
            }
        };
        for &b in &bps {
            g.clear_breakpoint(b)?;
        }
        if result.is_some() {
            return Ok(result);
        }
    }
    if hits >= m {
        for _ in j..k {
            g.step()?;
        }
    }
    Ok(None)
}

/// The traced path of `kind`, if traced (or kept from an earlier campaign on this ELF).
pub(super) fn path_of<'c>(ctx: &'c Ctx<'_>, kind: PathKind) -> Option<std::cell::Ref<'c, Traced>> {
    std::cell::Ref::filter_map(ctx.paths.borrow(), |p| p.get(&kind)).ok()
}

/// Places a flip of population `pop` in the step `step` (one with a star update when
/// `star`): halts the guest, breaks at the entry of the flip's path, sends `step`, runs
/// to an instruction drawn uniformly over the traced path ([`run_to`]), flips the
/// target's bit and lets the guest run on. A path not traced yet is traced in this step
/// instead, with no flip ([`Placed::Traced`]).
#[allow(clippy::too_many_arguments)]
pub(super) fn place_flip(
    ctx: &Ctx<'_>,
    unit: &mut Unit,
    g: &mut Gdb,
    rng: &mut ChaCha8Rng,
    step: &ControlFrame,
    pop: Population,
    star: bool,
) -> Result<Placed> {
    let t0 = Instant::now();
    let kind = match pop {
        Population::Handler => PathKind::Handler,
        Population::SnapshotWrite => PathKind::SnapshotWrite,
        _ => PathKind::Pass(star),
    };
    let at = entry(ctx, kind);
    let wait = Duration::from_secs(if kind == PathKind::SnapshotWrite { 5 } else { 20 });
    let stop = stop_at(unit, g, step, at, wait)?;
    let mut pop = pop;
    match stop {
        None => {
            // The snapshot write did not come in this step (its phase moved): a state
            // flip wherever the guest is.
            anyhow::ensure!(kind == PathKind::SnapshotWrite, "the breakpoint at {at:#x} was not reached");
            pop = Population::State;
        }
        Some(pc) if pc != at => {
            if std::env::var_os("SSIS_UPSET_TIMES").is_some() {
                eprintln!("step {}: stopped at {pc:#x} on the way to {kind:?}'s entry", ctx.awaiting.get());
            }
            return Ok(Placed::Stopped(trap(ctx, pc).unwrap_or_else(|| format!("stopped at {pc:#x}"))));
        }
        Some(_) => {}
    }
    let end = if stop.is_some() { path_end(g, kind)? } else { None };
    let mut k = 0usize;
    let mut path_len = 0;
    if stop.is_some() {
        let traced = path_of(ctx, kind).map(|p| p.clone());
        let Some(path) = traced else {
            let pcs = match end {
                Some(e) => trace(g, |_, pc| Ok(pc == e))?,
                None => trace(g, |g, pc| Ok(g.read_memory(pc, 2)? == WFI))?,
            };
            let path = Traced::new(pcs);
            path.store(ctx.elf_hash, kind);
            if std::env::var_os("SSIS_UPSET_TIMES").is_some() {
                eprintln!("traced {kind:?}: {} instructions in {:.3} s", path.len(), t0.elapsed().as_secs_f64());
            }
            ctx.paths.borrow_mut().insert(kind, path);
            g.resume()?;
            return Ok(Placed::Traced);
        };
        path_len = path.len();
        k = rng.random_range(0..path.len());
        let end = end.or(path.pcs.last().copied());
        if let Some(why) = run_to(ctx, g, &path, k, end)? {
            return Ok(Placed::Stopped(why));
        }
    }
    let pc = g.register_u32(gdb::PC)?;
    let sp = g.register_u32(gdb::SP)?;
    // A negative share: in proportion to the bits.
    let reg_share = (ctx.o.register_share >= 0.0).then_some(ctx.o.register_share);
    let target = match ctx.inject {
        Some(t) => t,
        None if ctx.o.forced_reset => Target::Reset,
        None => match pop {
            Population::State | Population::Handler => pick_state(rng, ctx.ram, sp, reg_share),
            Population::Double => pick_double(rng, ctx.ram, sp),
            Population::Device => pick_device(rng),
            Population::SnapshotReset => Target::SnapshotReset {
                addr: ctx.snap_region.0 + rng.random_range(0..ctx.snap_region.1),
                bit: rng.random_range(0..8),
            },
            Population::SnapshotWrite if rng.random_bool(0.5) => Target::Reset,
            Population::SnapshotWrite => pick_state(rng, ctx.ram, sp, reg_share),
        },
    };
    flip(g, target)?;
    if target.resets() {
        // The machine resets from the main loop: halted at `Reset`, the runner follows
        // it back into lockstep ([`super::relock`]).
        let t = Instant::now();
        while g.register_u32(gdb::PC)? != ctx.traps.reset {
            anyhow::ensure!(t.elapsed() < Duration::from_secs(10), "the unit did not reset on system_reset");
            std::thread::sleep(Duration::from_millis(1));
        }
    } else {
        g.resume()?;
    }
    match target {
        Target::Stall => unit.command(command::STALL)?,
        Target::TickStopped => unit.command(command::TICK_STOP)?,
        _ => {}
    }
    if std::env::var_os("SSIS_UPSET_TIMES").is_some() {
        let plan = path_of(ctx, kind).map(|p| p.plan(k));
        eprintln!(
            "flip placed in {:.3} s (step {}: {} instruction {k} of {path_len} by {plan:?}, pc {pc:#x}, sp {sp:#x}, {})",
            t0.elapsed().as_secs_f64(),
            ctx.awaiting.get(),
            pop.name(),
            target.describe()
        );
    }
    Ok(Placed::Flip { instr: k as u32, target, pc, population: pop })
}
