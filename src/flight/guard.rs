//! The state guard: the flight core's critical state checked every step against a shadow
//! copy and its checksum ([`crate::shadow`]), restored bit for bit on a mismatch, and its
//! plausibility checked; so a bit flipped in RAM (a single-event upset) between two
//! steps never flies.
//!
//! Blocks, by when their words change and when they are read ([`Block`]; what is guarded
//! is each field's `guard` in the core's one declaration, [`FlightCore`], in declaration
//! order; each stage's words are its [`Guarded`] impl below):
//!
//! | block | words | saved | checked |
//! |---|---|---|---|
//! | `Step` | Λ, the coning terms' two previous increments, the sample clock's index (unit time) and the counter of the next sample | end of every step | start of every step |
//! | `Steady` | the drift estimate Δω, the last update's time, the convergence state | end of a step that changed them | start of every step, and again before the first change of a step |
//! | `Geometry` | the four-FOG combiner and parity vector, the profile (period, FOGs fitted, range) | end of a step that changed the combiner (a table, an isolation) | start of every step, and again before the combiner changes |
//! | `Frame` | what a star-tracker frame reads and changes: the last update's Λ, the alignment time, the re-acquisition streak, the drift covariance at alignment, the estimator's gains and covariance | as `Steady` | before the first change of a step (a frame due, an isolation, a table switch) |
//! | `Tuning` | what a star-tracker frame reads and does not change: the noise figures, the initial drift variance, the acquisition stage's gains, the tracker mount | end of a step that changed them (a table, an isolation, a mounting verdict) | as `Frame` |
//! | `Without(i)` | the combiner without FOG i (flown after an isolation) | end of a step that changed the combiner | one a touch, in turn (at 4 Hz, each within four tracker periods) |
//!
//! The covariance and the noise figures (`Frame`, `Tuning`) also give the reported 1σ every step: a flip in
//! them between two frames shows in the 1σ until the next frame's check restores them
//! (at most one tracker period), never in the attitude or the drift estimate.
//!
//! A changed block is marked ([`FlightCore::guard_touch`], which first checks the `Steady`
//! and `Frame` blocks, so what a step changes and saves was good before: a flip since the
//! step's first check is restored, not saved) and saved at the end of the step. A
//! step that changes a word of a block other than `Step` without marking it would see
//! the change "restored" at the next check and logged as an upset: a debug build asserts
//! at the end of every step that such blocks still match their checksums
//! ([`FlightCore::guard_seal`]; compiled out of the flight build).
//!
//! On a mismatch the good copy is written back and the step proceeds exactly as without
//! the flip: `state_restored` is logged (a: the block, b: 0 restored, 1 the shadow or
//! checksum took the flip, 2 lost) and counted. A block that neither copy can restore
//! is derived again from the table (combiner, mount, gains) and the estimator starts
//! again from the next star-tracker frame (the alignment path).
//!
//! Inside the step, between the check and the seal, Λ and Δω are carried twice
//! ([`super::twin`]): compared with their twins before each change and before the output
//! frame, so a flip there is written back before it is integrated, sent or sealed.
//!
//! Plausibility every step, for what the checksums cannot see (a flip during the step
//! the twins do not hold, or a bug; an implausible Λ or Δω is first compared with its
//! twin, which restores a flip the last step's seal took): |Λ| within 1e-9 of 1, each drift component within ±1000 °/h, and at a
//! frame each variance of the estimator's covariance finite, ≥ 0 and bounded. On a
//! failure the unit does not claim its attitude: the estimator starts again from the
//! next star-tracker frame (not aligned, not converged until it converges again), and
//! `state_implausible` is logged (a: [`Implausible`]) and counted.

use super::{FlightCore, Guarded as Parts, ProfileState, GUARD_WORDS, HISTORY};
use crate::attitude::Attitude;
use crate::calib::N_FOG;
use crate::combination::Combiner;
use crate::intake::FogIntake;
use crate::observer::Observer;
use crate::shadow::{Blocks, Check, Guarded, Pass, Shadow, Sum, Visit, MAX_KINDS};
use crate::telemetry::events::Event;
use crate::telemetry::Counter;

use super::geometry::{checked_combiner, sample_noise_rad};

/// Words of the `Step` block (from the core's declaration).
const STEP_WORDS: usize = GUARD_WORDS[0];
/// Words of the `Steady` block at most.
const STEADY_WORDS: usize = GUARD_WORDS[1];
/// Words of the `Frame` block at most.
const FRAME_WORDS: usize = GUARD_WORDS[2];
/// Words of a `Without` block at most.
const WITHOUT_WORDS: usize = GUARD_WORDS[3];
/// Words of the `Geometry` block.
const GEOMETRY_WORDS: usize = GUARD_WORDS[4];
/// Words of the `Tuning` block at most.
const TUNING_WORDS: usize = GUARD_WORDS[5];

/// |Λ|² − 1 beyond this is implausible: Λ is normalised every step (to ~1e-16).
const Q_NORM2_TOL: f64 = 1e-9;
/// A drift estimate component beyond this is implausible, rad/s (1000 °/h: the FOGs'
/// uncalibrated biases are tens of °/h).
const MAX_DRIFT_RAD_S: f64 = 1000.0 * core::f64::consts::PI / 180.0 / 3600.0;
/// An attitude-error variance beyond this is implausible, rad² (1 rad²).
const MAX_ATT_VAR_RAD2: f64 = 1.0;
/// A drift-error variance beyond this is implausible, (rad/s)² ((1 rad/s)²).
const MAX_DRIFT_VAR_RAD2_S2: f64 = 1.0;

/// A guarded block of the core's state.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Block {
    /// Λ and the increments: changed every step.
    Step,
    /// The drift estimate and the convergence state: read every step, changed by a
    /// star-tracker frame.
    Steady,
    /// What a star-tracker frame reads.
    Frame,
    /// The combiner without FOG i.
    Without(usize),
    /// The nominal combiner and the profile: read every step, changed only with the
    /// combiner (a table, an isolation), so a star-tracker frame's step neither checks
    /// them again nor saves them.
    Geometry,
    /// What a star-tracker frame reads and does not change (the noise figures, the
    /// tracker mount): checked with `Frame`, saved only under its own mark, so a
    /// star-tracker frame's step does not save them.
    Tuning,
}

impl Block {
    /// Its number in the `state_restored` event (1 `Step`, 2 `Steady`, 3 `Frame`, 4 + i
    /// `Without(i)`, 9 `Geometry`, 10 `Tuning`; 8 is Λ or Δω restored from its twin,
    /// [`super::twin::TWIN_ID`]).
    pub fn id(self) -> u8 {
        match self {
            Block::Step => 1,
            Block::Steady => 2,
            Block::Frame => 3,
            Block::Without(i) => 4 + (i as u8 & 3),
            Block::Geometry => 9,
            Block::Tuning => 10,
        }
    }

    /// Every block.
    pub const ALL: [Block; 5 + N_FOG] = [
        Block::Step,
        Block::Steady,
        Block::Frame,
        Block::Without(0),
        Block::Without(1),
        Block::Without(2),
        Block::Without(3),
        Block::Geometry,
        Block::Tuning,
    ];
}

impl Blocks for Block {
    const KINDS: &'static [Block] =
        &[Block::Step, Block::Steady, Block::Frame, Block::Without(0), Block::Geometry, Block::Tuning];
}

/// Words of a stage in the blocks of kind `Step`, `Steady`, `Frame`, `Without`, `Geometry`,
/// `Tuning`.
const fn words(
    step: usize,
    steady: usize,
    frame: usize,
    without: usize,
    geometry: usize,
    tuning: usize,
) -> [usize; MAX_KINDS] {
    [step, steady, frame, without, geometry, tuning]
}

impl Guarded<Block> for Attitude {
    /// Λ (4) and the coning terms' two previous increments (6).
    const WORDS: [usize; MAX_KINDS] = words(10, 0, 0, 0, 0, 0);
    #[inline(always)]
    fn visit_block<V: Visit>(&mut self, block: Block, v: &mut V) {
        if let Block::Step = block {
            self.visit_q(v);
            self.visit_increments(v);
        }
    }
}

impl Guarded<Block> for FogIntake {
    /// The sample clock's index and the counter of the next sample.
    const WORDS: [usize; MAX_KINDS] = words(2, 0, 0, 0, 0, 0);
    #[inline(always)]
    fn visit_block<V: Visit>(&mut self, block: Block, v: &mut V) {
        if let Block::Step = block {
            self.visit_clock(v);
        }
    }
}

impl Guarded<Block> for ProfileState {
    /// The period, the FOGs fitted, the measuring range.
    const WORDS: [usize; MAX_KINDS] = words(0, 0, 0, 0, 3, 0);
    #[inline(always)]
    fn visit_block<V: Visit>(&mut self, block: Block, v: &mut V) {
        if let Block::Geometry = block {
            self.visit(v);
        }
    }
}

impl Guarded<Block> for Combiner {
    /// The four-FOG solution (12), the FOGs it solves (1) and the parity vector (4); a
    /// solution without one FOG (12).
    const WORDS: [usize; MAX_KINDS] = words(0, 0, 0, 12, 17, 0);
    #[inline(always)]
    fn visit_block<V: Visit>(&mut self, block: Block, v: &mut V) {
        match block {
            Block::Geometry => self.visit_nominal(v),
            Block::Without(i) => self.visit_without(i, v),
            _ => {}
        }
    }
}

impl Guarded<Block> for Observer<HISTORY> {
    /// Δω (3), the last update's time (1) and the convergence state (3); what a frame
    /// reads and changes: 76 with the MEKF, fewer with the Luenberger observer; what it
    /// reads only: 37 with the Luenberger observer in two stages, 30 otherwise.
    const WORDS: [usize; MAX_KINDS] = words(0, 7, 76, 0, 0, 37);
    #[inline(always)]
    fn visit_block<V: Visit>(&mut self, block: Block, v: &mut V) {
        match block {
            Block::Steady => self.visit_steady(v),
            Block::Frame => self.visit_frame(v),
            Block::Tuning => self.visit_tuning(v),
            _ => {}
        }
    }
}

/// Which plausibility check failed (the `state_implausible` event's a).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u8)]
pub enum Implausible {
    /// |Λ| not 1.
    QuaternionNorm = 1,
    /// The drift estimate beyond the FOGs' plausible range.
    Drift = 2,
    /// A variance of the estimator's covariance negative, not finite or too large.
    Covariance = 3,
}

/// The shadows of the guarded blocks and what the step changed.
#[derive(Debug, Clone, Copy, Default, bytemuck::AnyBitPattern)]
pub(super) struct Guard {
    step: Shadow<STEP_WORDS>,
    steady: Shadow<STEADY_WORDS>,
    frame: Shadow<FRAME_WORDS>,
    without: crate::state::Quad<Shadow<WITHOUT_WORDS>>,
    geometry: Shadow<GEOMETRY_WORDS>,
    tuning: Shadow<TUNING_WORDS>,
    /// Non-zero: this step changed a block other than `Step` (saved at its end); the
    /// `Frame` block was checked before.
    touched: u32,
    /// The `Without` block the next touch checks.
    next_without: u32,
    /// [`SEALED`] once the shadows hold the state (the core is built without a save, so
    /// that it is built in place: the first check saves instead).
    sealed: u32,
    /// Debug builds: each block's live checksum at the start of the step (or at its last
    /// seal), which a step that marked nothing must leave as it found
    /// ([`FlightCore::guard_seal`]).
    #[cfg(debug_assertions)]
    entry: [crate::shadow::CheckWord; 5 + N_FOG],
}

/// [`Guard::sealed`]'s value once the shadows hold the state (a flipped bit reads as not
/// sealed: the state is saved again unchecked, at worst one check missed).
const SEALED: u32 = 0x5EA1_ED5A;

/// [`Guard::touched`]: the combiner changed too.
const COMBINER_TOUCHED: u32 = 2;
/// [`Guard::touched`]: the `Tuning` block changed too.
const TUNING_TOUCHED: u32 = 4;

/// The guarded fields and the shadows of `core`.
#[inline(always)]
fn split(core: &mut FlightCore) -> (Parts<'_>, &mut Guard) {
    core.guard_split()
}

/// The words of `block`, in the declaration's order.
#[inline(always)]
fn visit<V: Visit>(p: &mut Parts<'_>, block: Block, v: &mut V) {
    p.visit(block, v);
}

/// [`visit`] through a [`Pass`]: one compiled walk for the blocks checked rarely.
#[inline(never)]
fn visit_pass(p: &mut Parts<'_>, block: Block, pass: &mut Pass<'_>) {
    visit(p, block, pass);
}

/// Saves the `Step` block of `core` into its shadow (every step: its own walk).
#[inline(always)]
fn save_step(core: &mut FlightCore) {
    let (mut p, g) = split(core);
    g.step.save(|s| visit(&mut p, Block::Step, s));
}

/// Saves `block` of `core` into its shadow (through the one walk of [`visit_pass`]).
#[inline(never)]
fn save(core: &mut FlightCore, block: Block) {
    let (mut p, g) = split(core);
    match block {
        Block::Step => g.step.save_pass(|s| visit_pass(&mut p, block, s)),
        Block::Steady => g.steady.save_pass(|s| visit_pass(&mut p, block, s)),
        Block::Frame => g.frame.save_pass(|s| visit_pass(&mut p, block, s)),
        Block::Without(i) => {
            if let Some(sh) = g.without.get_mut(i) {
                sh.save_pass(|s| visit_pass(&mut p, block, s));
            }
        }
        Block::Geometry => g.geometry.save_pass(|s| visit_pass(&mut p, block, s)),
        Block::Tuning => g.tuning.save_pass(|s| visit_pass(&mut p, block, s)),
    }
}

/// Checks `block` of `core` against its checksum; restores it from the shadow when the
/// shadow is the good copy.
#[inline(always)]
fn check(core: &mut FlightCore, block: Block) -> Check {
    // The borrow of the fields ends before the cold restore, which borrows them again: the
    // step does not build the fields' references in memory for a call it rarely makes.
    let c = {
        let (mut p, g) = split(core);
        let live = match block {
            Block::Step | Block::Steady | Block::Frame | Block::Geometry | Block::Tuning => {
                let mut live = Sum::default();
                visit(&mut p, block, &mut live);
                live
            }
            Block::Without(_) => {
                let mut pass = Pass::Sum(Sum::default());
                visit_pass(&mut p, block, &mut pass);
                match pass {
                    Pass::Sum(s) => s,
                    _ => Sum::default(),
                }
            }
        };
        match block {
            Block::Step => g.step.check(live.0),
            Block::Steady => g.steady.check(live.0),
            Block::Frame => g.frame.check(live.0),
            Block::Without(i) => g.without.get_mut(i).map_or(Check::Intact, |s| s.check(live.0)),
            Block::Geometry => g.geometry.check(live.0),
            Block::Tuning => g.tuning.check(live.0),
        }
    };
    if c == Check::Restore {
        restore(core, block);
    }
    c
}

#[inline(never)]
#[cold]
fn restore(core: &mut FlightCore, block: Block) {
    let (mut p, g) = split(core);
    match block {
        Block::Step => g.step.restore_pass(|b| visit_pass(&mut p, block, b)),
        Block::Steady => g.steady.restore_pass(|b| visit_pass(&mut p, block, b)),
        Block::Frame => g.frame.restore_pass(|b| visit_pass(&mut p, block, b)),
        Block::Without(i) => {
            if let Some(w) = g.without.get(i) {
                w.restore_pass(|b| visit_pass(&mut p, block, b));
            }
        }
        Block::Geometry => g.geometry.restore_pass(|b| visit_pass(&mut p, block, b)),
        Block::Tuning => g.tuning.restore_pass(|b| visit_pass(&mut p, block, b)),
    }
}

impl FlightCore {
    /// Saves every block (the core built, or changed between steps). The step's mark
    /// stays: what the step changes after this is saved at its end.
    #[inline(never)]
    #[cold]
    pub(super) fn guard_seal_all(&mut self) {
        self.twin_seal();
        for b in Block::ALL {
            save(self, b);
        }
        self.guard.sealed = SEALED;
        #[cfg(debug_assertions)]
        {
            self.guard.entry = self.guard_sums();
        }
    }

    /// Start of a step: the `Step` and `Steady` blocks checked, then the plausibility of
    /// Λ and Δω.
    #[inline(always)]
    pub(super) fn guard_check(&mut self) {
        if self.guard.sealed != SEALED {
            self.guard_seal_all();
        }
        self.guard_check_block(Block::Step);
        self.guard_check_steady();
        self.guard_check_block(Block::Geometry);
        #[cfg(debug_assertions)]
        {
            self.guard.entry = self.guard_sums();
        }
        if !self.quaternion_plausible() {
            self.implausible(Implausible::QuaternionNorm);
        }
        if !self.drift_plausible() {
            self.implausible(Implausible::Drift);
        }
    }

    /// |Λ|² within [`Q_NORM2_TOL`] of 1 (a NaN is not).
    #[inline(always)]
    fn quaternion_plausible(&self) -> bool {
        let n2 = self.attitude.quaternion().norm_squared();
        (n2 - 1.0).abs() <= Q_NORM2_TOL
    }

    /// Each drift component within ±[`MAX_DRIFT_RAD_S`] (a NaN is not).
    #[inline(always)]
    fn drift_plausible(&self) -> bool {
        let d = self.observer.drift_rad_s();
        d.x.abs() <= MAX_DRIFT_RAD_S && d.y.abs() <= MAX_DRIFT_RAD_S && d.z.abs() <= MAX_DRIFT_RAD_S
    }

    /// A block other than `Step` is about to change (a star-tracker frame is due, a FOG is
    /// isolated, a table switched): the first time in a step the `Frame` block and the
    /// covariance's plausibility are checked, and every block is saved at the step's end.
    #[inline(never)]
    pub(super) fn guard_touch(&mut self) {
        if self.guard.touched != 0 {
            return;
        }
        if self.guard.sealed != SEALED {
            self.guard_seal_all();
        }
        self.guard.touched = 1;
        // What the step is about to change and save at its end was good before: a flip
        // since the step's first check is restored, not saved.
        self.guard_check_steady();
        self.guard_check_block(Block::Frame);
        self.guard_check_block(Block::Tuning);
        // One triad solution a touch, in turn (flown only after an isolation).
        let i = self.guard.next_without as usize % N_FOG;
        self.guard.next_without = (i as u32 + 1) % N_FOG as u32;
        self.guard_check_block(Block::Without(i));
        if !self.observer.filter().cov_plausible(MAX_ATT_VAR_RAD2, MAX_DRIFT_VAR_RAD2_S2) {
            self.implausible(Implausible::Covariance);
        }
    }

    /// End of a step: the `Step` block saved, and every other block if the step changed it.
    /// A debug build first asserts that a step that marked nothing changed left every other
    /// block as sealed.
    #[inline(always)]
    pub(super) fn guard_seal(&mut self) {
        #[cfg(debug_assertions)]
        self.guard_assert_unchanged();
        save_step(self);
        if self.guard.touched != 0 {
            self.guard_seal_changed();
        }
    }

    /// Debug builds: the blocks other than `Step` that the step's mark does not cover are
    /// as the step found them (an upset between two steps included: the next check finds
    /// it): every one without a mark ([`FlightCore::guard_touch`]), the combiner's
    /// (`Geometry`, `Without`) without its mark ([`FlightCore::guard_touch_combiner`]). A
    /// change made without the mark would be taken for an upset and undone at the next
    /// check.
    #[cfg(debug_assertions)]
    fn guard_assert_unchanged(&mut self) {
        if self.guard.sealed != SEALED || self.guard.touched & COMBINER_TOUCHED != 0 {
            return;
        }
        let touched = self.guard.touched != 0;
        let now = self.guard_sums();
        for (k, block) in Block::ALL.iter().enumerate().skip(1) {
            if touched && matches!(block, Block::Steady | Block::Frame) {
                continue;
            }
            if self.guard.touched & TUNING_TOUCHED != 0 && *block == Block::Tuning {
                continue;
            }
            debug_assert_eq!(
                now[k], self.guard.entry[k],
                "{block:?} changed in a step without guard_touch: it would be undone as an upset"
            );
        }
    }

    /// Debug builds: the live checksum of every block ([`Block::ALL`]'s order).
    #[cfg(debug_assertions)]
    fn guard_sums(&mut self) -> [crate::shadow::CheckWord; 5 + N_FOG] {
        let (mut p, _) = split(self);
        Block::ALL.map(|block| {
            let mut live = Sum::default();
            visit(&mut p, block, &mut live);
            live.0
        })
    }

    #[inline(never)]
    #[cold]
    fn guard_seal_changed(&mut self) {
        // Each block's own walk (a star-tracker frame's step saves both: 41 words with the
        // observer, 83 with the MEKF), not the shared `Pass` walk the rare saves take.
        {
            let (mut p, g) = split(self);
            g.steady.save(|s| visit(&mut p, Block::Steady, s));
            g.frame.save(|s| visit(&mut p, Block::Frame, s));
        }
        if self.guard.touched & TUNING_TOUCHED != 0 {
            save(self, Block::Tuning);
        }
        if self.guard.touched & COMBINER_TOUCHED != 0 {
            save(self, Block::Geometry);
            for i in 0..N_FOG {
                save(self, Block::Without(i));
            }
        }
        self.guard.touched = 0;
    }

    /// Saves the `Steady` block again (the in-step twin wrote back a Δω that the last
    /// step's seal had saved with a flip in it).
    #[inline(never)]
    #[cold]
    pub(super) fn guard_save_steady(&mut self) {
        save(self, Block::Steady);
        #[cfg(debug_assertions)]
        {
            self.guard.entry = self.guard_sums();
        }
    }

    /// The guarded state changed between steps (a resume): saved again, unchecked, at the
    /// next step's check.
    pub(super) fn guard_unseal(&mut self) {
        self.guard.sealed = 0;
    }

    /// The combiner is about to change ([`FlightCore::guard_touch`], and its `Without`
    /// blocks saved at the step's end).
    pub(super) fn guard_touch_combiner(&mut self) {
        self.guard_touch();
        if self.guard.touched & COMBINER_TOUCHED == 0 {
            // Marked first: a block found lost is derived again, through here.
            self.guard.touched |= COMBINER_TOUCHED;
            // What the step changes and saves at its end was good before (the `Geometry`
            // block is not checked at every touch).
            self.guard_check_block(Block::Geometry);
        }
    }

    /// The noise figures, the tracker mount or the acquisition stage are about to change
    /// ([`FlightCore::guard_touch`], which checked them, and the `Tuning` block saved at
    /// the step's end).
    pub(super) fn guard_touch_tuning(&mut self) {
        self.guard_touch();
        self.guard.touched |= TUNING_TOUCHED;
    }

    /// The `Steady` block checked: out of line, one copy of its walk for the step's first
    /// check and a touch's (flash).
    #[inline(never)]
    fn guard_check_steady(&mut self) {
        self.guard_check_block(Block::Steady);
    }

    /// Checks `block` against its checksum and restores it.
    #[inline(always)]
    fn guard_check_block(&mut self, block: Block) {
        let c = check(self, block);
        if c != Check::Intact {
            self.guard_repaired(block, c);
        }
    }

    /// A mismatch in `block`, restored from the shadow (or the shadow saved again, or the
    /// block derived again): logged and counted.
    #[inline(never)]
    #[cold]
    fn guard_repaired(&mut self, block: Block, c: Check) {
        let how = match c {
            Check::Intact => return,
            Check::Restore => 0,
            Check::ShadowRepaired => {
                save(self, block);
                1
            }
            Check::Lost => {
                self.guard_rederive();
                2
            }
        };
        self.guard_logged(block.id(), how);
        // The block is as sealed again: what the step changes from here is what the seal's
        // debug assertion judges.
        #[cfg(debug_assertions)]
        {
            self.guard.entry = self.guard_sums();
        }
    }

    /// A repair logged (`state_restored`, a: `id`, b: `how`) and counted.
    #[inline(never)]
    #[cold]
    pub(super) fn guard_logged(&mut self, id: u8, how: u16) {
        self.telemetry.counters.bump(Counter::StateRestored);
        self.events.log(self.last_output.time_us, Event::StateRestored, id, how);
    }

    /// A block neither copy restores: what derives from the table is derived again, and
    /// the estimator starts again from the next star-tracker frame.
    #[inline(never)]
    #[cold]
    pub(super) fn guard_rederive(&mut self) {
        if let Ok(combiner) = checked_combiner(self.profile.get(), &self.table, &self.fog_map) {
            let noise_rad = sample_noise_rad(&self.table, self.profile.dt_s());
            self.install_geometry(combiner, noise_rad);
        }
        self.mount = self.table.st_mount();
        let _ = self.observer.retune(&self.table.observer);
        self.observer.restart();
        self.guard_seal_all();
    }

    /// A plausibility check failed: the estimator starts again from the next star-tracker
    /// frame, and the unit claims no attitude until it has converged again.
    #[inline(never)]
    #[cold]
    fn implausible(&mut self, what: Implausible) {
        // A flip in Λ or Δω after the last step's final compare, saved by the guard: the
        // twin ([`super::twin`]) still holds the good value.
        self.twin_check_rare();
        if what != Implausible::Covariance && self.quaternion_plausible() && self.drift_plausible() {
            return;
        }
        self.telemetry.counters.bump(Counter::StateImplausible);
        self.events.log(self.last_output.time_us, Event::StateImplausible, what as u8, 0);
        self.observer.restart();
        self.guard_seal_all();
    }

    /// Flips bit `bit` of word `word` of `block` (tests: an upset between two steps).
    #[cfg(test)]
    pub(crate) fn flip_guarded(&mut self, block: Block, word: usize, bit: u32) {
        visit(&mut split(self).0, block, &mut crate::shadow::Flip::new(word, bit));
    }

    /// Words in `block` (tests).
    #[cfg(test)]
    pub(crate) fn guarded_words(&mut self, block: Block) -> usize {
        let mut c = crate::shadow::Count::default();
        visit(&mut split(self).0, block, &mut c);
        c.0
    }
}

#[cfg(test)]
mod tests {
    use std::convert::Infallible;

    use nalgebra::{UnitQuaternion, Vector3};

    use super::*;
    use crate::calib::CalibrationTable;
    use crate::flight::{flags, FogLinks, Links, Profile, StepOutput};
    use crate::frames::fog::FogFrame;
    use crate::frames::star::{flags as st_flags, StarFrame};
    use crate::shadow::Visit;

    /// A receive link holding one step's bytes.
    #[derive(Default)]
    struct BytesIn(Vec<u8>, usize);

    impl embedded_io::ErrorType for BytesIn {
        type Error = Infallible;
    }
    impl embedded_io::ReadReady for BytesIn {
        fn read_ready(&mut self) -> Result<bool, Infallible> {
            Ok(self.1 < self.0.len())
        }
    }
    impl embedded_io::Read for BytesIn {
        fn read(&mut self, out: &mut [u8]) -> Result<usize, Infallible> {
            let n = (self.0.len() - self.1).min(out.len());
            out[..n].copy_from_slice(&self.0[self.1..self.1 + n]);
            self.1 += n;
            Ok(n)
        }
    }

    /// A transmit link that drops what it is given.
    struct Sink;

    impl embedded_io::ErrorType for Sink {
        type Error = Infallible;
    }
    impl embedded_io::WriteReady for Sink {
        fn write_ready(&mut self) -> Result<bool, Infallible> {
            Ok(true)
        }
    }
    impl embedded_io::Write for Sink {
        fn write(&mut self, buf: &[u8]) -> Result<usize, Infallible> {
            Ok(buf.len())
        }
        fn flush(&mut self) -> Result<(), Infallible> {
            Ok(())
        }
    }

    /// Body rate of the test flight, rad/s.
    const RATE_RAD_S: [f64; 3] = [2.0e-3, -1.0e-3, 1.5e-3];

    /// Step `n` of a slow tumble with a star tracker at 4 Hz (50 ms latency): four FOG
    /// frames, and a star-tracker frame every 50th step.
    fn fly(core: &mut FlightCore, n: u32) -> StepOutput {
        fly_probed(core, n, |_, _| {})
    }

    /// [`fly`], `probe` called at the step's numbered points ([`crate::flight::probe`]).
    fn fly_probed(core: &mut FlightCore, n: u32, probe: impl FnMut(&mut FlightCore, u8)) -> StepOutput {
        let table = CalibrationTable::DEFAULT;
        let dt_s = Profile::SPACECRAFT.dt_s();
        let w = Vector3::from(RATE_RAD_S);
        let mut bus = BytesIn::default();
        for (i, axis) in table.axes().iter().enumerate() {
            let f = FogFrame::from_physical(i as u8, n as u16, 0, axis.dot(&w) * dt_s, 20.0);
            bus.0.extend_from_slice(&f.to_bytes());
        }
        let mut star = BytesIn::default();
        if n.is_multiple_of(50) && n >= 20 {
            let tag_us = u64::from(n - 10) * 5_000;
            let truth = UnitQuaternion::from_scaled_axis(w * (tag_us as f64 * 1e-6)).into_inner() * table.st_mount();
            let f = StarFrame::from_physical(st_flags::VALID, n as u16, tag_us, [truth.w, truth.i, truth.j, truth.k]);
            star.0.extend_from_slice(&f.to_bytes());
        }
        let mut out = Sink;
        core.step_probed_with(
            &mut Links { fog: FogLinks::Bus(&mut bus), star: &mut star, out: &mut out },
            |_, _| {},
            probe,
        )
    }

    /// A core flown `steps` steps.
    fn flown(estimator: crate::calib::Estimator, steps: u32) -> FlightCore {
        let mut table = CalibrationTable::DEFAULT;
        table.observer.estimator = estimator;
        let mut core = FlightCore::new(Profile::SPACECRAFT, &table, false).unwrap();
        for n in 1..=steps {
            fly(&mut core, n);
        }
        core
    }

    /// The words of `block`.
    struct Collect(Vec<u64>);
    impl Visit for Collect {
        const WRITES: bool = false;
        fn word(&mut self, w: &mut u64) {
            self.0.push(*w);
        }
    }

    fn words(core: &mut FlightCore, block: Block) -> Vec<u64> {
        let mut c = Collect(Vec::new());
        visit(&mut split(core).0, block, &mut c);
        c.0
    }

    fn restored(core: &FlightCore) -> u32 {
        core.telemetry.counters.get(Counter::StateRestored)
    }

    /// Every bit of every word of every block, flipped between two steps, is found by
    /// the checks the next step makes and restored bit for bit, once, and logged.
    #[test]
    fn every_flip_of_every_block_is_restored() {
        for est in [crate::calib::Estimator::Luenberger, crate::calib::Estimator::Mekf] {
            let mut core = flown(est, 2400);
            assert!(core.last_output().flags & flags::CONVERGED != 0, "{est:?}: the test flight converges");
            for block in Block::ALL {
                let n = core.guarded_words(block);
                assert!(n > 0, "{block:?} holds words");
                let capacity = match block {
                    Block::Step => STEP_WORDS,
                    Block::Steady => STEADY_WORDS,
                    Block::Frame => FRAME_WORDS,
                    Block::Without(_) => WITHOUT_WORDS,
                    Block::Geometry => GEOMETRY_WORDS,
                    Block::Tuning => TUNING_WORDS,
                };
                assert!(n <= capacity, "{block:?}: {n} words, shadow {capacity}");
                let good = words(&mut core, block);
                for word in 0..n {
                    for bit in 0..64 {
                        let mut c = core.clone();
                        c.flip_guarded(block, word, bit);
                        assert_ne!(words(&mut c, block), good);
                        // The checks of four steps that touch the state (every
                        // `Without` block once in four).
                        for _ in 0..N_FOG {
                            c.guard_check();
                            c.guard_touch();
                            c.guard.touched = 0;
                        }
                        assert_eq!(words(&mut c, block), good, "{est:?} {block:?} word {word} bit {bit}");
                        assert_eq!(restored(&c), 1, "{est:?} {block:?} word {word} bit {bit}");
                        assert_eq!(c.telemetry.counters.get(Counter::StateImplausible), 0);
                        let ev = c.events.pending().find(|e| e.event == Event::StateRestored).unwrap();
                        assert_eq!((ev.event, ev.a, ev.b), (Event::StateRestored, block.id(), 0));
                    }
                }
            }
        }
    }

    /// Each shadow holds exactly its block's words (for the estimator that has the most;
    /// another may hold fewer), so the stages' word counts ([`Guarded::WORDS`]) are
    /// neither short (words left unsaved) nor long (RAM spent).
    #[test]
    fn every_shadow_fits_its_block_exactly() {
        let mut most = [0; 5 + N_FOG];
        let mut two_stage = CalibrationTable::DEFAULT.observer;
        two_stage.gains_override = Some(crate::observer::steady_state_gains(&two_stage).unwrap());
        two_stage.acquisition_s = 600.0;
        for (est, stages) in [
            (crate::calib::Estimator::Luenberger, None),
            (crate::calib::Estimator::Luenberger, Some(two_stage)),
            (crate::calib::Estimator::Mekf, None),
        ] {
            let mut table = CalibrationTable::DEFAULT;
            if let Some(o) = stages {
                table.observer = o;
            }
            table.observer.estimator = est;
            let mut core = FlightCore::new(Profile::SPACECRAFT, &table, false).unwrap();
            // Every state of the flight: before alignment, in acquisition, converged.
            for n in 1..=2400 {
                fly(&mut core, n);
                for (k, block) in Block::ALL.into_iter().enumerate() {
                    most[k] = most[k].max(core.guarded_words(block));
                }
            }
        }
        assert_eq!(
            most,
            [
                STEP_WORDS,
                STEADY_WORDS,
                FRAME_WORDS,
                WITHOUT_WORDS,
                WITHOUT_WORDS,
                WITHOUT_WORDS,
                WITHOUT_WORDS,
                GEOMETRY_WORDS,
                TUNING_WORDS
            ]
        );
    }

    /// Each block's number in `state_restored` is its own, and not the twin's.
    #[test]
    fn the_blocks_numbers_are_distinct() {
        let mut ids: Vec<u8> = Block::ALL.iter().map(|b| b.id()).collect();
        ids.push(super::super::twin::TWIN_ID);
        let n = ids.len();
        ids.sort_unstable();
        ids.dedup();
        assert_eq!(ids.len(), n, "{ids:?}");
    }

    /// What the guard covers, as the module's table says: a field dropped from a block in
    /// the core's declaration, or moved to another, shows here.
    #[test]
    fn the_guarded_fields_are_the_tables() {
        let blocks = |name: &str| {
            let (_, kinds) = FlightCore::GUARD_BLOCKS.iter().find(|(n, _)| *n == name).unwrap();
            ["Step", "Steady", "Frame", "Without", "Geometry", "Tuning"]
                .iter()
                .zip(kinds)
                .filter(|(_, k)| **k)
                .map(|(b, _)| *b)
                .collect::<Vec<_>>()
        };
        assert_eq!(blocks("attitude"), ["Step"]);
        assert_eq!(blocks("fog_intake"), ["Step"]);
        assert_eq!(blocks("profile"), ["Geometry"]);
        assert_eq!(blocks("combiner"), ["Without", "Geometry"]);
        assert_eq!(blocks("observer"), ["Steady", "Frame", "Tuning"]);
        assert_eq!(blocks("mount"), ["Tuning"]);
    }

    /// A step that changes a guarded word outside the guard's path (no
    /// [`FlightCore::guard_touch`]) fails the debug build's assertion at the step's end,
    /// instead of being undone at the next step and logged as an upset.
    #[test]
    #[cfg(debug_assertions)]
    #[should_panic(expected = "changed in a step without guard_touch")]
    fn a_change_without_the_guard_fails_the_debug_build() {
        let mut core = flown(crate::calib::Estimator::Luenberger, 200);
        core.guard_check();
        core.mount.i += 1e-9;
        core.guard_seal();
    }

    /// The same change through the guard's path is sealed and stays.
    #[test]
    fn a_change_through_the_guard_is_sealed() {
        let mut core = flown(crate::calib::Estimator::Luenberger, 200);
        core.guard_check();
        core.guard_touch_tuning();
        core.mount.i += 1e-9;
        let changed = core.mount;
        core.guard_seal();
        core.guard_check();
        core.guard_touch();
        assert_eq!(core.mount, changed);
        assert_eq!(restored(&core), 0);
    }

    /// After a flip the flight goes on exactly as without it: every output of the next
    /// steps identical, bit for bit.
    #[test]
    fn a_restored_flight_is_the_undisturbed_flight() {
        for est in [crate::calib::Estimator::Luenberger, crate::calib::Estimator::Mekf] {
            let core = flown(est, 2400);
            for block in Block::ALL {
                let n = core.clone().guarded_words(block);
                for word in 0..n {
                    for bit in [0, 31, 51, 62, 63] {
                        let (mut a, mut b) = (core.clone(), core.clone());
                        b.flip_guarded(block, word, bit);
                        for s in 2401..2621 {
                            let (mut oa, mut ob) = (fly(&mut a, s), fly(&mut b, s));
                            if matches!(block, Block::Frame | Block::Tuning) {
                                // Its covariance and noise figures give the 1σ of the
                                // steps before the next frame's check.
                                (oa.att_sigma_rad, oa.drift_sigma_rad_s) = ([0.0; 3], [0.0; 3]);
                                (ob.att_sigma_rad, ob.drift_sigma_rad_s) = ([0.0; 3], [0.0; 3]);
                            }
                            assert_eq!(format!("{oa:?}"), format!("{ob:?}"), "{est:?} {block:?} {word} {bit} step {s}");
                        }
                        assert_eq!(restored(&b), 1);
                    }
                }
            }
        }
    }

    /// A change the checksums cannot see (made and sealed, as a bug or a flip inside the
    /// step would): Λ off unit norm, or a drift estimate beyond the FOGs' range. The unit
    /// stops claiming its attitude, re-aligns on the next star-tracker frame and logs it.
    #[test]
    fn implausible_state_re_aligns() {
        // Λ's w and the drift estimate's x, wherever the declaration puts them in their block.
        let at = |block: Block, x: f64| {
            let mut core = flown(crate::calib::Estimator::Luenberger, 2400);
            words(&mut core, block).iter().position(|w| *w == x.to_bits()).unwrap()
        };
        let core = flown(crate::calib::Estimator::Luenberger, 2400);
        let (q_w, drift_x) = (core.attitude.quaternion().w, core.observer.drift_rad_s().x);
        for (block, word, bit, what) in [
            (Block::Step, at(Block::Step, q_w), 61, Implausible::QuaternionNorm),
            (Block::Steady, at(Block::Steady, drift_x), 62, Implausible::Drift),
        ] {
            let mut core = core.clone();
            core.flip_guarded(block, word, bit);
            core.guard_seal_all();
            let o = fly(&mut core, 2401);
            assert_eq!(core.telemetry.counters.get(Counter::StateImplausible), 1);
            assert_eq!(restored(&core), 0);
            assert_eq!(o.flags & flags::CONVERGED, 0, "{what:?}: not converged");
            let ev = core.events.pending().find(|e| e.event == Event::StateImplausible).unwrap();
            assert_eq!((ev.event, ev.a), (Event::StateImplausible, what as u8));
            // The next star-tracker frame aligns again.
            let mut aligned_at = None;
            for s in 2402..2502 {
                fly(&mut core, s);
                if core.observer().aligned() && aligned_at.is_none() {
                    aligned_at = Some(s);
                }
            }
            assert_eq!(aligned_at, Some(2450), "{what:?}");
            let q = core.last_output().q;
            assert!((q.norm() - 1.0).abs() < 1e-12);
        }
    }

    /// A block neither copy can restore (the live words and the shadow both changed) is
    /// derived again from the table and the estimator re-aligns.
    #[test]
    fn a_lost_block_is_derived_again() {
        let mut core = flown(crate::calib::Estimator::Luenberger, 2400);
        let nominal = core.combiner;
        // The combiner's words follow the profile's three in the `Geometry` block.
        core.guard.geometry.flip_word(4, 12);
        core.flip_guarded(Block::Geometry, 5, 40);
        fly(&mut core, 2401);
        assert_eq!(core.combiner, nominal);
        assert!(!core.observer().converged());
        let ev = core.events.pending().find(|e| e.event == Event::StateRestored).unwrap();
        assert_eq!((ev.event, ev.a, ev.b), (Event::StateRestored, Block::Geometry.id(), 2));
    }

    /// A bit of Λ, of Δω or of their twins flipped inside a step, at each numbered point
    /// between the guard's check and its seal (a star-tracker frame's step and a plain
    /// one): the twin's compare finds it before the next use or the output frame, the good
    /// copy is written back bit for bit, and every output frame is the undisturbed
    /// flight's; `state_restored` logged once (a twin flipped before the next seal rewrites
    /// it: at most once).
    #[test]
    fn a_flip_inside_the_step_never_flies() {
        use crate::flight::probe;
        for est in [crate::calib::Estimator::Luenberger, crate::calib::Estimator::Mekf] {
            let core = flown(est, 2398);
            let mut undisturbed = core.clone();
            let reference: Vec<String> = (2399..2460).map(|s| format!("{:?}", fly(&mut undisturbed, s))).collect();
            // Λ (i, j, k, w), Δω (x, y, z), and the twins' words and checksums.
            type Target = fn(&mut FlightCore, u32);
            let targets: [(&str, Target); 6] = [
                ("q.i", |c, b| c.attitude.flip_q(0, b)),
                ("q.w", |c, b| c.attitude.flip_q(3, b)),
                ("drift.y", |c, b| c.observer.flip_drift(1, b)),
                ("twin.q.k", |c, b| c.twin.flip_q(2, b)),
                ("twin.q_sum", |c, b| c.twin.flip_q(4, b)),
                ("twin.drift.z", |c, b| c.twin.flip_drift(2, b)),
            ];
            // Step 2400 takes a star-tracker frame, 2399 does not.
            for step in [2399, 2400] {
                for point in 0..probe::COUNT {
                    for (name, flip) in targets {
                        for bit in [0, 30, 51, 52, 61, 62, 63] {
                            let mut c = core.clone();
                            let mut done = false;
                            let mut outs = Vec::new();
                            for s in 2399..2460 {
                                let o = fly_probed(&mut c, s, |c, p| {
                                    if s == step && p >= point && !done {
                                        flip(c, bit);
                                        done = true;
                                        // An upset, not a change the step made: the debug
                                        // build's end-of-step assertion starts from it.
                                        #[cfg(debug_assertions)]
                                        {
                                            c.guard.entry = c.guard_sums();
                                        }
                                    }
                                });
                                outs.push(format!("{o:?}"));
                            }
                            let what = format!("{est:?} step {step} point {point} {name} bit {bit}");
                            assert!(done, "{what}: flipped");
                            let first = outs.iter().zip(&reference).position(|(a, b)| a != b);
                            assert_eq!(first.map(|k| (&outs[k], &reference[k])), None, "{what}");
                            // A flip of a twin's word or checksum that the next seal
                            // rewrites harms nothing and may go unseen.
                            let seen = if name.starts_with("twin") { 0..=1 } else { 1..=1 };
                            assert!(seen.contains(&restored(&c)), "{what}: restored {}", restored(&c));
                            assert_eq!(c.telemetry.counters.get(Counter::StateImplausible), 0, "{what}");
                        }
                    }
                }
            }
        }
    }
}
