//! The flight executive: the one fixed-rate loop of every board and mission, written
//! once ([`run`]). A board supplies what differs through [`StepBoard`] (its tick and
//! its pacing, its links' transmit side, its watchdog, its memory areas, its clock,
//! its memory-error source, its code image, its reset); a mission (the spacecraft unit,
//! the launch vehicle with its navigation) supplies the step and what rides on it
//! through [`Mission`]. Host-tested with a simulated board (`host-tests/tests/exec.rs`
//! and the unit tests below).
//!
//! Each pass of the loop:
//!
//! 0. **The pass's registers** ([`StepBoard::check_pass`]: the SysTick's control word and
//!    reload, the links' control words) checked and restored, so a tick an upset stopped
//!    runs again at the next wake, and a link whose receiver or its interrupt an upset
//!    turned off receives again; a restore logged (`register_restored`), one that does
//!    not hold resets.
//! 1. **Wait** ([`StepBoard::wait`]): a step due on the timer (with the ticks it
//!    missed: each an overrun), a step due in lockstep (test equipment), an idle wake,
//!    or the end of a test run.
//! 2. **Step** ([`Mission::step`]), then **the after-step work on one schedule**: a slice
//!    of the table scrub ([`FlightCore::background`]) every step, a slice of the code
//!    check ([`CodeCheck`]) every [`CODE_STEPS`](super::code::CODE_STEPS), the memory-error
//!    poll every step, the snapshot every [`SNAPSHOT_STEPS`] (with the mission's extra
//!    state, [`Mission::save`]), the command key every [`KEY_CHECK_STEPS`], the board's
//!    configuration registers every [`REGISTER_STEPS`] ([`StepBoard::check_registers`]:
//!    restored and logged, `register_restored`; a restore that does not hold resets).
//!    A code check that finds the image changed resets the unit (module doc of
//!    [`super::code`]).
//! 3. **Outputs**: handed to the links ([`StepBoard::send`]; on the timer at once, in
//!    lockstep at the end of the pass), then the mission's work after the outputs
//!    ([`Mission::after_outputs`]: the launch vehicle's navigation filter) and the event
//!    frames ([`Mission::send_events`]).
//! 4. **Deadline and watchdog**: the pass's time on the board's clock goes into the next
//!    output frame; a step in lockstep that took longer than the period is an overrun.
//!    The watchdog is fed **only when a step completed within its deadline**: its time
//!    on the clock more than zero (a clock that stood still is a stopped tick: an
//!    upset of the SysTick control word) and at most one period. On the timer nothing
//!    else feeds it, so a loop that wakes but never steps (the tick stopped, interrupts
//!    masked) or a step that never ends is reset by the watchdog. In lockstep the step
//!    waits for the runner, which costs virtual time: an idle pass on which the board's
//!    tick has moved on also feeds it (the tick proves the clock runs), and those passes
//!    are counted ([`LoopStats::awaited_ticks_max`]); an idle pass without a new tick
//!    feeds nothing.
//! 5. **Ring faults**: a link ring whose borrow flag or indices are corrupted takes no
//!    byte again, or drops them for seconds ([`crate::link::ring_faults`]): snapshot and reset ([`StepBoard::reset`]), as for
//!    a register whose restore does not hold and a code image found changed.
//!
//! At boot [`run`] resumes the core from the newer of the board's two snapshot copies
//! that passes ([`FlightCore::resume_from`]; the snapshot is written into them in turn,
//! so a reset that tears one write leaves the other) and spoils both, so one snapshot
//! is resumed at most once, then
//! lets the mission resume its own ([`Mission::resume`]).

use super::code::CodeCheck;
use super::Board;
use crate::flight::snapshot::Snapshots;
use crate::flight::{st_status, FlightCore, StepOutput};
use crate::telemetry::events::Event;

/// Steps between two snapshots (400 ms at 5 ms): a snapshot costs about 1,200
/// instructions, some 15 a step spread this thin. The resume bridges the snapshot's
/// age (up to this period and the time the unit was down).
pub const SNAPSHOT_STEPS: u32 = 80;

/// Steps between two checks of the command key against its record (10 s at 5 ms).
pub const KEY_CHECK_STEPS: u32 = 2_000;

/// Steps between two checks of the board's configuration registers
/// ([`StepBoard::check_registers`]: 320 ms at 5 ms, 80 ms at 1.25 ms). A check reads
/// some 25 registers (about 250 instructions), some 4 a step spread this thin.
pub const REGISTER_STEPS: u32 = 64;

/// What a check of the board's configuration registers found
/// ([`StepBoard::check_registers`]).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct RegisterCheck {
    /// Registers found changed and restored (the restore read back as expected).
    pub restored: u32,
    /// Registers found changed whose restore did not hold, or a table of expected
    /// values that fails its own check: the executive resets the unit.
    pub failed: u32,
}

/// What the board's wait found ([`StepBoard::wait`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Wait {
    /// A step is due on the board's timer; `missed` ticks came and went since the last
    /// step without one (each an overrun).
    Tick {
        /// Ticks missed.
        missed: u32,
    },
    /// A step is due in lockstep (test equipment: a STEP frame whose bytes have arrived).
    Lockstep,
    /// No step is due: the loop woke for something else.
    Idle {
        /// In lockstep, awaiting a STEP frame.
        lockstep: bool,
        /// The board's tick moved on since the last pass.
        tick: bool,
    },
    /// The end of a test run (an END control frame, the output sent): report and stop.
    End,
}

/// Memory errors found by the board's poll ([`StepBoard::memory_errors`]).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct MemoryErrors {
    /// Single-bit errors corrected in hardware.
    pub corrected: u32,
    /// Errors detected and not corrected.
    pub uncorrected: u32,
}

/// What the executive needs of a board besides the boot's [`Board`]: only what differs
/// from board to board.
pub trait StepBoard: Board {
    /// Waits for the next thing to do (sleeping until an interrupt when there is none).
    /// Bytes of the control line (telecommands) are the board's to hand on; the core is
    /// lent for that and for the counters of ignored control frames.
    fn wait(&mut self, core: &mut FlightCore) -> Wait;

    /// A free-running clock, wrapping (the SysTick's count on the QEMU board, which
    /// stands still when the step tick is stopped; the cycle counter on the STM32H7).
    fn clock(&self) -> u32;

    /// Clock counts in one step period (the deadline of a step).
    fn period(&self) -> u32;

    /// A time on the clock in units of the output frame's step time (the 25 MHz tick,
    /// 40 ns; the QEMU board's clock already counts those).
    fn to_ticks(&self, clock: u32) -> u32 {
        clock
    }

    /// Hands what the output rings hold to the transmitters (never waits).
    fn send(&mut self);

    /// The board's own work after a step, with the core (the command link's report; a
    /// status log), and the pass's time on the clock.
    fn after_step(&mut self, _core: &mut FlightCore, _busy: u32) {}

    /// The snapshot's two copies in RAM the reset does not clear, if the layout has them.
    fn snapshots(&mut self) -> Option<&mut Snapshots>;

    /// The code image in flash the code check covers.
    fn code_image(&self) -> &'static [u8];

    /// Checks the command key against its record and restores it if it differs
    /// (returns true then); a board without a command link has no key.
    fn check_key(&mut self) -> bool {
        false
    }

    /// Checks the registers every pass depends on (the SysTick's control word and
    /// reload, the links' control words: the first entries of a Cortex-M7 board's list)
    /// against their start-up values, restoring them; run at the start of every pass,
    /// before the wait, so that a tick an upset stopped or changed (its enable, its
    /// interrupt, its clock source, its period) runs again at the loop's next wake (a
    /// received byte, the next tick), and a link whose receiver, transmitter or their
    /// interrupts an upset turned off works again from then (in lockstep no step comes
    /// without it: the steps' checks would never run), not a watchdog period or
    /// [`REGISTER_STEPS`] later. Nothing by default.
    fn check_pass(&mut self) -> RegisterCheck {
        RegisterCheck::default()
    }

    /// Checks the configuration registers the unit depends on (the step tick, the
    /// interrupt enables and priorities, the links' control registers, the MPU, the
    /// watchdog, the interrupt masks) against the values the board set at start-up,
    /// restoring any that changed; run every [`REGISTER_STEPS`]. Nothing by default.
    fn check_registers(&mut self) -> RegisterCheck {
        RegisterCheck::default()
    }

    /// Memory errors since the last poll (a board with ECC RAM); none by default.
    fn memory_errors(&mut self) -> MemoryErrors {
        MemoryErrors::default()
    }

    /// Watchdog warnings (first timeouts) so far; none on a board whose watchdog has no
    /// early warning.
    fn watchdog_warnings(&self) -> u32 {
        0
    }

    /// The board's end-of-run figures (test builds, at END), after the mission's.
    fn report(&mut self, _core: &FlightCore) {}

    /// Resets the unit (it resumes from the snapshot).
    fn reset(&mut self) -> !;
}

/// What a mission runs in the executive's loop: the step and what rides on it.
pub trait Mission {
    /// One step of the flight core on the mission's links (the launch vehicle's
    /// navigation runs from its hook, once per increment).
    fn step(&mut self, core: &mut FlightCore) -> StepOutput;

    /// Work after the outputs have been handed to the links, in the same period (the
    /// launch vehicle's filter work).
    fn after_outputs(&mut self, _core: &mut FlightCore) {}

    /// Sends the core's pending event frames on the mission's output link.
    fn send_events(&mut self, core: &mut FlightCore);

    /// Takes the period's times (25 MHz ticks): the step alone and the whole pass.
    fn record(&mut self, _step: u32, _busy: u32, _out: &StepOutput) {}

    /// Lockstep began: statistics restart.
    fn lockstep_began(&mut self) {}

    /// Extra state that survives a reset, written with the core's snapshot (none by
    /// default).
    fn save(&mut self) {}

    /// At boot, after the core's resume: resumes the extra state (none by default).
    fn resume(&mut self, _core: &mut FlightCore) {}

    /// The end-of-run figures (test builds, at END).
    fn report(&self, _core: &FlightCore, _stats: &LoopStats) {}
}

/// Count, sum and worst of a time on the board's clock.
#[derive(Default, Clone, Copy, Debug, PartialEq, Eq)]
pub struct Times {
    /// How many.
    pub n: u32,
    /// Their sum.
    pub sum: u64,
    /// The largest.
    pub max: u32,
}

impl Times {
    /// Adds one time.
    pub fn push(&mut self, ticks: u32) {
        self.n = self.n.saturating_add(1);
        self.sum = self.sum.saturating_add(u64::from(ticks));
        self.max = self.max.max(ticks);
    }

    /// Mean × 100 (0 when empty).
    pub fn mean_x100(&self) -> u64 {
        (self.sum.saturating_mul(100)).checked_div(u64::from(self.n)).unwrap_or(0)
    }
}

/// What the loop counts about itself.
#[derive(Default, Clone, Copy, Debug, PartialEq, Eq)]
pub struct LoopStats {
    /// Steps taken.
    pub steps: u32,
    /// Steps that fed the watchdog (completed within their deadline).
    pub fed_steps: u32,
    /// Steps that did not: their time on the clock zero (the clock stood still) or over
    /// the period.
    pub late_steps: u32,
    /// Idle passes in lockstep that fed the watchdog (a new tick while a STEP was awaited).
    pub awaited_ticks: u32,
    /// The longest run of such passes between two steps.
    pub awaited_ticks_max: u32,
    /// Passes through the loop.
    pub passes: u32,
}

/// The watchdog rule (module doc, step 4): whether a step whose pass took `busy` clock
/// counts met its deadline of `period`.
pub fn within_deadline(busy: u32, period: u32) -> bool {
    busy > 0 && busy <= period
}

/// The executive's state: what persists from pass to pass.
pub struct Executive {
    code: CodeCheck,
    stats: LoopStats,
    awaited_run: u32,
    warnings: u32,
    /// A step has been taken in lockstep.
    lockstep: bool,
    /// The snapshot copy the next write goes to (its low bit).
    snap_slot: u32,
}

impl Executive {
    /// At boot, on the booted core: resumes the core from `board`'s snapshot if it
    /// passes (and spoils it), then the mission's extra state; takes the code's
    /// reference CRC.
    pub fn start<B: StepBoard + ?Sized, M: Mission + ?Sized>(
        board: &mut B,
        mission: &mut M,
        core: &mut FlightCore,
    ) -> Executive {
        if let Some(snaps) = board.snapshots() {
            match core.resume_from(snaps) {
                Ok(()) => {
                    #[cfg(target_os = "none")]
                    defmt::warn!("reset: resumed from the snapshot");
                }
                Err(_e) => {
                    #[cfg(target_os = "none")]
                    defmt::info!("no snapshot resumed ({}): aligning on the star tracker", _e);
                }
            }
            snaps.invalidate();
        }
        mission.resume(core);
        let code = CodeCheck::new(board.code_image());
        #[cfg(target_os = "none")]
        {
            let (len, crc) = code.image();
            defmt::info!("code check: {} bytes of flash, CRC {=u32:#010x}", len, crc);
        }
        board.feed_watchdog();
        Executive {
            code,
            stats: LoopStats::default(),
            awaited_run: 0,
            warnings: board.watchdog_warnings(),
            lockstep: false,
            snap_slot: 0,
        }
    }

    /// The loop's own figures.
    pub fn stats(&self) -> &LoopStats {
        &self.stats
    }

    /// The code check.
    pub fn code(&self) -> &CodeCheck {
        &self.code
    }

    /// One pass of the loop (module doc); `Some(ok)` once the run is over (END). Inline
    /// (as [`run`]): inlined into the firmware's function that built the board and the
    /// mission, the links' static rings are constants there, not loads through them.
    #[inline(always)]
    pub fn pass<B: StepBoard + ?Sized, M: Mission + ?Sized>(
        &mut self,
        board: &mut B,
        mission: &mut M,
        core: &mut FlightCore,
    ) -> Option<bool> {
        self.stats.passes = self.stats.passes.wrapping_add(1);
        if crate::link::ring_faults() != 0 {
            self.fault_reset(board, mission, core, Fault::Ring);
        }
        let tick = board.check_pass();
        if tick != RegisterCheck::default() {
            self.restored(board, mission, core, tick);
        }
        let lockstep = match board.wait(core) {
            Wait::End => {
                board.send();
                mission.report(core, &self.stats);
                board.report(core);
                return Some(true);
            }
            Wait::Idle { lockstep, tick } => {
                if lockstep && tick {
                    board.feed_watchdog();
                    self.stats.awaited_ticks = self.stats.awaited_ticks.saturating_add(1);
                    self.awaited_run = self.awaited_run.saturating_add(1);
                    self.stats.awaited_ticks_max = self.stats.awaited_ticks_max.max(self.awaited_run);
                }
                board.send();
                return None;
            }
            Wait::Tick { missed } => {
                // Bounded: a stall of more than 1,000 ticks counts as 1,000.
                for _ in 0..missed.min(1_000) {
                    core.note_overrun();
                }
                false
            }
            Wait::Lockstep => {
                if !self.lockstep {
                    self.lockstep = true;
                    mission.lockstep_began();
                }
                true
            }
        };
        self.awaited_run = 0;
        self.step(board, mission, core, lockstep);
        None
    }

    /// The step and the after-step work (module doc, steps 2–4).
    #[inline(always)]
    fn step<B: StepBoard + ?Sized, M: Mission + ?Sized>(
        &mut self,
        board: &mut B,
        mission: &mut M,
        core: &mut FlightCore,
        lockstep: bool,
    ) {
        let t0 = board.clock();
        let out = mission.step(core);
        // The after-step work, timed with the step: the table's slice first (the upset
        // campaign ends a step's traced path at it).
        core.background(board.calib_area());
        if self.code.step(core) == Some(false) {
            self.fault_reset(board, mission, core, Fault::Code);
        }
        let e = board.memory_errors();
        if e.corrected != 0 || e.uncorrected != 0 {
            core.note_sram_ecc(e.corrected, e.uncorrected);
        }
        let steps = self.stats.steps.wrapping_add(1);
        self.stats.steps = steps;
        if steps.is_multiple_of(SNAPSHOT_STEPS) {
            self.write_snapshot(board, core);
            mission.save();
        }
        if steps.is_multiple_of(KEY_CHECK_STEPS) && board.check_key() {
            core.note_key_restored();
        }
        if steps.is_multiple_of(REGISTER_STEPS) {
            self.registers(board, mission, core);
        }
        let step = board.clock().wrapping_sub(t0);
        if !lockstep {
            // On the timer the outputs go at once; in lockstep at the end of the pass,
            // so the runner's next bytes cannot interrupt the measured work.
            board.send();
        }
        mission.after_outputs(core);
        let busy = board.clock().wrapping_sub(t0);
        let period = board.period();
        if lockstep && busy > period {
            core.note_overrun();
        }
        let (step_ticks, busy_ticks) = (board.to_ticks(step), board.to_ticks(busy));
        core.set_step_ticks(u16::try_from(busy_ticks).unwrap_or(u16::MAX));
        mission.record(step_ticks, busy_ticks, &out);
        board.after_step(core, busy);
        let warnings = board.watchdog_warnings();
        if warnings != self.warnings {
            self.warnings = warnings;
            core.note_watchdog_warning();
        }
        mission.send_events(core);
        board.send();
        if within_deadline(busy, period) {
            board.feed_watchdog();
            self.stats.fed_steps = self.stats.fed_steps.saturating_add(1);
        } else {
            self.stats.late_steps = self.stats.late_steps.saturating_add(1);
        }
    }

    /// The board's configuration registers (module doc, step 2): restored ones logged;
    /// a restore that did not hold resets the unit.
    #[inline(never)]
    fn registers<B: StepBoard + ?Sized, M: Mission + ?Sized>(
        &mut self,
        board: &mut B,
        mission: &mut M,
        core: &mut FlightCore,
    ) {
        let r = board.check_registers();
        self.restored(board, mission, core, r);
    }

    /// What a register check found: restores logged (`register_restored`); a restore
    /// that did not hold resets the unit.
    #[inline(never)]
    fn restored<B: StepBoard + ?Sized, M: Mission + ?Sized>(
        &mut self,
        board: &mut B,
        mission: &mut M,
        core: &mut FlightCore,
        r: RegisterCheck,
    ) {
        if r.restored != 0 {
            core.log_event(Event::RegisterRestored, u8::try_from(r.restored).unwrap_or(u8::MAX), 0);
        }
        if r.failed != 0 {
            self.fault_reset(board, mission, core, Fault::Register);
        }
    }

    /// A fault the unit recovers from by a reset (`why` logged): snapshot, reset.
    #[inline(never)]
    #[cold]
    fn fault_reset<B: StepBoard + ?Sized, M: Mission + ?Sized>(
        &mut self,
        board: &mut B,
        mission: &mut M,
        core: &mut FlightCore,
        why: Fault,
    ) -> ! {
        #[cfg(target_os = "none")]
        defmt::error!("{}: snapshot and reset", why);
        #[cfg(not(target_os = "none"))]
        let _ = why;
        self.write_snapshot(board, core);
        mission.save();
        board.reset()
    }

    /// The core's snapshot into the copy whose turn it is (the other, one snapshot
    /// period older, stays whole should a reset tear this write).
    fn write_snapshot<B: StepBoard + ?Sized>(&mut self, board: &mut B, core: &FlightCore) {
        if let Some(snaps) = board.snapshots() {
            snaps.write(core, self.snap_slot);
            self.snap_slot = (self.snap_slot & 1) ^ 1;
        }
    }
}

/// Why the executive resets the unit ([`Executive`]'s fault path; logged).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
enum Fault {
    /// A link ring's borrow flag or indices are corrupted ([`crate::link::ring_faults`]).
    Ring,
    /// A configuration register whose restore did not hold.
    Register,
    /// The code check found the image in flash changed.
    Code,
}

/// Runs the flight on the booted `core`: [`Executive::start`], then its passes until
/// the end of a test run, where the board stops with success. Never returns.
#[inline(always)]
pub fn run<B: StepBoard + ?Sized, M: Mission + ?Sized>(board: &mut B, mission: &mut M, core: &mut FlightCore) -> ! {
    let mut exec = Executive::start(board, mission, core);
    loop {
        if let Some(ok) = exec.pass(board, mission, core) {
            board.stop(ok)
        }
    }
}

/// The spacecraft mission: the core's step on its links, its event frames on the output
/// link, and the step times (all steps, and those with a star-tracker update).
pub struct Spacecraft<F, S, O> {
    /// The unit's links.
    pub links: crate::flight::Links<F, S, O>,
    /// Times of every pass with a step.
    pub all: Times,
    /// Times of the passes whose step took a star-tracker update.
    pub star: Times,
}

impl<F, S, O> Spacecraft<F, S, O> {
    /// The mission on `links`.
    pub fn new(links: crate::flight::Links<F, S, O>) -> Self {
        Spacecraft { links, all: Times::default(), star: Times::default() }
    }
}

impl<F: crate::link::RxPort, S: crate::link::StarPort, O: crate::link::OutPort> Mission for Spacecraft<F, S, O> {
    #[inline(always)]
    fn step(&mut self, core: &mut FlightCore) -> StepOutput {
        core.step(&mut self.links)
    }

    fn send_events(&mut self, core: &mut FlightCore) {
        core.send_events(&mut self.links.out);
    }

    fn record(&mut self, _step: u32, busy: u32, out: &StepOutput) {
        self.all.push(busy);
        if out.st_status & st_status::UPDATED != 0 {
            self.star.push(busy);
        }
    }

    fn report(&self, _core: &FlightCore, _stats: &LoopStats) {
        #[cfg(target_os = "none")]
        defmt::info!(
            "steps {} mean_ticks_x100 {} max_ticks {} st_steps {} st_mean_ticks_x100 {} st_max_ticks {}",
            self.all.n,
            self.all.mean_x100(),
            self.all.max,
            self.star.n,
            self.star.mean_x100(),
            self.star.max
        );
        #[cfg(target_os = "none")]
        defmt::info!(
            "loop fed_steps {} late_steps {} awaited_ticks {} awaited_ticks_max {}",
            _stats.fed_steps,
            _stats.late_steps,
            _stats.awaited_ticks,
            _stats.awaited_ticks_max
        );
    }
}

#[cfg(test)]
mod tests {
    use std::cell::Cell;
    use std::rc::Rc;

    use super::*;
    use crate::calib::store;
    use crate::calib::CalibrationTable;
    use crate::flight::{Counter, Profile};

    /// A simulated board: a script of waits, a clock shared with the mission (which
    /// moves it by the cost of a step), the watchdog's feeds counted.
    struct Sim {
        waits: std::vec::Vec<Wait>,
        clock: Rc<Cell<u32>>,
        feeds: u32,
        snap: Snapshots,
        calib: std::vec::Vec<u8>,
        ecc: MemoryErrors,
        key_checks: u32,
        regs: RegisterCheck,
        reg_checks: u32,
        tick: RegisterCheck,
        tick_checks: u32,
    }

    static IMAGE: [u8; 300] = [0x5A; 300];

    impl Board for Sim {
        fn calib_area(&self) -> &[u8] {
            &self.calib
        }
        fn feed_watchdog(&mut self) {
            self.feeds += 1;
        }
        fn ticks(&self) -> u32 {
            self.clock.get() / PERIOD
        }
        fn stop(&mut self, _ok: bool) -> ! {
            unreachable!("the tests run passes, not run()")
        }
    }

    const PERIOD: u32 = 100;

    impl StepBoard for Sim {
        fn wait(&mut self, _core: &mut FlightCore) -> Wait {
            self.waits.pop().unwrap_or(Wait::End)
        }
        fn clock(&self) -> u32 {
            self.clock.get()
        }
        fn period(&self) -> u32 {
            PERIOD
        }
        fn send(&mut self) {}
        fn snapshots(&mut self) -> Option<&mut Snapshots> {
            Some(&mut self.snap)
        }
        fn code_image(&self) -> &'static [u8] {
            &IMAGE
        }
        fn check_key(&mut self) -> bool {
            self.key_checks += 1;
            false
        }
        fn memory_errors(&mut self) -> MemoryErrors {
            core::mem::take(&mut self.ecc)
        }
        fn check_registers(&mut self) -> RegisterCheck {
            self.reg_checks += 1;
            core::mem::take(&mut self.regs)
        }
        fn check_pass(&mut self) -> RegisterCheck {
            self.tick_checks += 1;
            core::mem::take(&mut self.tick)
        }
        fn reset(&mut self) -> ! {
            panic!("the unit resets")
        }
    }

    /// A mission whose step only costs time on the clock (the core's step is tested
    /// elsewhere).
    struct Cost {
        clock: Rc<Cell<u32>>,
        cost: u32,
        steps: u32,
        began: u32,
        saves: u32,
    }

    impl Mission for Cost {
        fn step(&mut self, core: &mut FlightCore) -> StepOutput {
            self.steps += 1;
            self.clock.set(self.clock.get().wrapping_add(self.cost));
            *core.last_output()
        }
        fn send_events(&mut self, _core: &mut FlightCore) {}
        fn lockstep_began(&mut self) {
            self.began += 1;
        }
        fn save(&mut self) {
            self.saves += 1;
        }
    }

    /// Flies the script `waits` (then END) with steps of `cost` clock counts; the board,
    /// the mission and the loop's figures after.
    fn fly(waits: &[Wait], cost: u32, ecc: MemoryErrors) -> (Sim, Cost, LoopStats, FlightCore) {
        fly_with(waits, cost, ecc, RegisterCheck::default(), RegisterCheck::default())
    }

    /// As [`fly`], the first register check finding `regs` and the first check of the
    /// tick's registers `tick`.
    fn fly_with(
        waits: &[Wait],
        cost: u32,
        ecc: MemoryErrors,
        regs: RegisterCheck,
        tick: RegisterCheck,
    ) -> (Sim, Cost, LoopStats, FlightCore) {
        let mut core = FlightCore::new(Profile::SPACECRAFT, &CalibrationTable::DEFAULT, false).expect("core");
        let clock = Rc::new(Cell::new(0));
        let mut sim = Sim {
            waits: waits.iter().rev().copied().collect(),
            clock: clock.clone(),
            feeds: 0,
            snap: Snapshots::default(),
            calib: std::vec![0xFF; store::REGION_LEN],
            ecc,
            key_checks: 0,
            regs,
            reg_checks: 0,
            tick,
            tick_checks: 0,
        };
        let mut m = Cost { clock, cost, steps: 0, began: 0, saves: 0 };
        let mut exec = Executive::start(&mut sim, &mut m, &mut core);
        assert_eq!(sim.feeds, 1, "fed once at the start");
        for _ in 0..=waits.len() {
            if exec.pass(&mut sim, &mut m, &mut core).is_some() {
                break;
            }
        }
        let stats = *exec.stats();
        (sim, m, stats, core)
    }

    #[test]
    fn the_watchdog_rule() {
        assert!(within_deadline(1, 125_000));
        assert!(within_deadline(125_000, 125_000));
        assert!(!within_deadline(0, 125_000), "a clock that stood still: the tick stopped");
        assert!(!within_deadline(125_001, 125_000), "over the period");
    }

    #[test]
    fn times_mean_and_worst() {
        let mut t = Times::default();
        assert_eq!(t.mean_x100(), 0);
        t.push(10);
        t.push(21);
        assert_eq!((t.n, t.max, t.mean_x100()), (2, 21, 1550));
    }

    #[test]
    fn steps_within_the_deadline_feed_the_watchdog_and_idle_passes_on_the_timer_do_not() {
        let waits = [
            Wait::Tick { missed: 0 },
            Wait::Idle { lockstep: false, tick: true },
            Wait::Idle { lockstep: false, tick: false },
            Wait::Tick { missed: 2 },
        ];
        let (sim, m, stats, core) = fly(&waits, 40, MemoryErrors::default());
        assert_eq!(m.steps, 2);
        assert_eq!(sim.feeds, 1 + 2, "{stats:?}");
        assert_eq!((stats.fed_steps, stats.late_steps), (2, 0));
        assert_eq!(core.counter(Counter::Overruns), 2, "the two missed ticks");
    }

    #[test]
    fn a_stopped_clock_or_an_overlong_step_feeds_nothing() {
        let waits = [Wait::Tick { missed: 0 }, Wait::Tick { missed: 0 }];
        let (sim, _, stats, _) = fly(&waits, 0, MemoryErrors::default());
        assert_eq!((sim.feeds, stats.late_steps), (1, 2), "the clock stood still: the tick stopped");
        let (sim, _, stats, core) = fly(&[Wait::Lockstep, Wait::Lockstep], PERIOD + 1, MemoryErrors::default());
        assert_eq!((sim.feeds, stats.late_steps), (1, 2), "over the period");
        assert_eq!(core.counter(Counter::Overruns), 2, "in lockstep a step over the period is an overrun");
    }

    #[test]
    fn in_lockstep_an_awaited_step_feeds_only_on_a_new_tick_and_is_counted() {
        let waits = [
            Wait::Lockstep,
            Wait::Idle { lockstep: true, tick: true },
            Wait::Idle { lockstep: true, tick: false },
            Wait::Idle { lockstep: true, tick: true },
            Wait::Lockstep,
            Wait::Idle { lockstep: true, tick: true },
            Wait::Lockstep,
        ];
        let (sim, m, stats, _) = fly(&waits, 10, MemoryErrors::default());
        assert_eq!(m.began, 1, "statistics restart once");
        assert_eq!(sim.feeds, 1 + 3 + 3, "{stats:?}");
        assert_eq!((stats.awaited_ticks, stats.awaited_ticks_max), (3, 2));
    }

    #[test]
    fn the_after_step_work_runs_on_its_schedule() {
        let n = KEY_CHECK_STEPS as usize;
        let waits = std::vec![Wait::Tick { missed: 0 }; n];
        let ecc = MemoryErrors { corrected: 2, uncorrected: 1 };
        let (sim, m, stats, core) = fly(&waits, 10, ecc);
        assert_eq!(stats.steps, KEY_CHECK_STEPS);
        assert_eq!(m.saves, KEY_CHECK_STEPS / SNAPSHOT_STEPS, "the mission's state with every snapshot");
        assert_eq!(sim.key_checks, 1);
        assert_eq!(sim.reg_checks, KEY_CHECK_STEPS / REGISTER_STEPS);
        assert_eq!((core.counter(Counter::SramEccCorrected), core.counter(Counter::SramEccUncorrected)), (2, 1));
        // Spoiled at the start (resumed at most once); the core is not aligned (no FOG
        // samples), so nothing was written after.
        let mut spoiled = Snapshots::default();
        spoiled.invalidate();
        assert_eq!(bytemuck::bytes_of(&sim.snap), bytemuck::bytes_of(&spoiled));
    }

    #[test]
    fn a_restored_register_is_logged_and_the_unit_flies_on() {
        let waits = std::vec![Wait::Tick { missed: 0 }; REGISTER_STEPS as usize + 1];
        let regs = RegisterCheck { restored: 2, failed: 0 };
        let (sim, m, _, core) = fly_with(&waits, 10, MemoryErrors::default(), regs, RegisterCheck::default());
        assert_eq!((sim.reg_checks, m.steps), (1, REGISTER_STEPS + 1));
        let logged: std::vec::Vec<_> = core.events().pending().collect();
        assert!(logged.iter().any(|r| r.event == Event::RegisterRestored && r.a == 2), "{logged:?}");
    }

    #[test]
    #[should_panic(expected = "the unit resets")]
    fn a_register_whose_restore_does_not_hold_resets_the_unit() {
        let waits = std::vec![Wait::Tick { missed: 0 }; REGISTER_STEPS as usize];
        let regs = RegisterCheck { restored: 0, failed: 1 };
        let _ = fly_with(&waits, 10, MemoryErrors::default(), regs, RegisterCheck::default());
    }

    #[test]
    fn the_tick_is_checked_at_every_pass_and_a_restore_logged() {
        let waits = [Wait::Idle { lockstep: false, tick: false }, Wait::Tick { missed: 0 }, Wait::Tick { missed: 0 }];
        let tick = RegisterCheck { restored: 1, failed: 0 };
        let (sim, m, stats, core) = fly_with(&waits, 10, MemoryErrors::default(), RegisterCheck::default(), tick);
        assert_eq!(sim.tick_checks, stats.passes, "every pass, the idle one too");
        assert_eq!(m.steps, 2);
        let logged: std::vec::Vec<_> = core.events().pending().collect();
        assert!(logged.iter().any(|r| r.event == Event::RegisterRestored && r.a == 1), "{logged:?}");
    }

    #[test]
    #[should_panic(expected = "the unit resets")]
    fn a_tick_whose_restore_does_not_hold_resets_the_unit() {
        let waits = [Wait::Tick { missed: 0 }];
        let tick = RegisterCheck { restored: 0, failed: 1 };
        let _ = fly_with(&waits, 10, MemoryErrors::default(), RegisterCheck::default(), tick);
    }
}
