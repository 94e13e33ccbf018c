//! The estimator: star-tracker frames correct the attitude Λ and the gyro drift estimate
//! Δω, by the paper's Luenberger observer with extended state, eq. (6),
//!
//! ```text
//! Λ̇  = ½ Λ ∘ (ω* + K_B · vect(ΔΛ) − Δω)
//! Δω̇ = −K_U · vect(ΔΛ),            ΔΛ = Λ⁻¹ ∘ Λ*
//! ```
//!
//! or by a multiplicative extended Kalman filter, as the table selects
//! ([`crate::calib::Estimator`]). Frames arrive at their own rate (1–10 Hz) and late.
//! Between frames Λ is propagated on the gyros with ω* − Δω ([`crate::attitude`]). At a
//! frame with time tag t_s the [`Observer`]
//!
//! 1. takes Λ(t_s) from its attitude history, interpolated between the two steps around
//!    t_s, so latency does not enter the mismatch ([`history`]);
//! 2. forms the mismatch e = 2 vect(ΔΛ) with Λ* taken back from the star-tracker frame to
//!    the ICS through the mount, eq. (5) ([`gate`]);
//! 3. asks the estimator that flies ([`Filter`]) whether the frame passes its gate and for
//!    the correction: a body rotation at t_s and a drift change;
//! 4. carries both to the present step at once and to the history lazily ([`history`]).
//!
//! | file | what |
//! |---|---|
//! | `mod.rs` | [`Observer`]: alignment, the frame's path above, [`Filter`] |
//! | [`luenberger`] | eq. (6) with fixed gains, two stages (acquisition, steady state) |
//! | [`mekf`] | the MEKF: 6-state covariance (9 with the star tracker's low-frequency error), its gain and gate |
//! | [`history`] | the attitude history, [`History::attitude_at`], the lazy fix |
//! | [`gate`] | the mismatch, the χ²₃ gate, re-acquisition, convergence, the consistency monitor |
//! | [`gains`] | the steady-state Kalman gains (Farrenkopf 1978), the noise figures |
//!
//! # Adding an estimator
//!
//! 1. A new file `src/observer/NAME.rs` with the estimator's state and the methods
//!    [`Filter`] calls: `align`, `update` (gate and correction: a [`Correction`]),
//!    `mismatch_var_rad2`, `sigmas`, `forget_roots`, `remove_share`, and what a restart
//!    and a change of the FOGs flying do to it ([`Filter::restart`],
//!    [`Filter::set_noise`]). It reads the shared pieces: [`gains::Figures`] for the
//!    noise, [`UpdateAt`] for the frame (its mismatch, the time since the last update,
//!    whether the estimate converged), [`gate::Streak`] for re-acquisition.
//! 2. A variant of [`crate::calib::Estimator`] for the table, and a field of [`Filter`]
//!    holding the new state; each `match` in `impl Filter` gets its arm (the compiler
//!    lists them), and [`Filter::retune`] says what the covariance becomes when a table
//!    switches estimators in flight.
//!
//! There is no dynamic dispatch and no allocation: [`Filter`] holds each estimator's state
//! by value and a byte naming the one that flies.

pub mod gains;
pub mod gate;
pub mod history;
pub mod luenberger;
pub mod mekf;

use nalgebra::{Matrix3, Quaternion, Vector3};

use crate::attitude::Attitude;
use crate::calib::{Estimator, ObserverConfig, ObserverGains};
use crate::math;
use crate::state::{Flag, Maybe};
use crate::state_map::state_struct;
use gains::{initial_drift_var_rad2_s2, Figures, ARCSEC_RAD};
use gate::{Convergence, Monitor, Streak};
use luenberger::Luenberger;
use mekf::Mekf;

pub use gains::{steady_state, steady_state_gains, GainError, SteadyState};
pub use gate::{CHI2_GATE, REACQUIRE_FRAMES, REALIGN_FRAMES, SUSPECT_FRAMES};
pub use history::History;

/// A drift estimate the re-alignment keeps whatever the table's initial drift 1σ, (rad/s)²:
/// |Δω| up to 10 °/h, ten times the largest bias residue calibration can leave
/// ([`crate::integrity::mounting::BIAS_MAX_RAD_S`]; an estimate learning an uncalibrated
/// offset of a few °/h is kept, a corrupted one of orders of magnitude more is not).
const DRIFT_PLAUSIBLE_RAD_S2: f64 =
    100.0 * crate::integrity::mounting::BIAS_MAX_RAD_S * crate::integrity::mounting::BIAS_MAX_RAD_S;

/// A star-tracker frame's mismatch, heard but not used ([`Observer::listen`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Mismatch {
    /// Mismatch e, rad (ICS at the frame's time tag).
    pub e_rad: Vector3<f64>,
    /// Its expected variance per axis, rad².
    pub var_rad2: f64,
}

/// A star-tracker frame that updated the estimate ([`Observer::update`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Updated {
    /// The mismatch e that was used, rad (ICS at t_s; zero for the alignment).
    pub e_rad: Vector3<f64>,
    /// The frame ended a streak of gated frames that agreed with each other: the
    /// estimator re-acquired.
    pub reacquired: bool,
    /// The consistency monitor re-aligned the attitude on the frame ([`gate::Monitor`]);
    /// `e_rad` is the disagreement.
    pub realigned: bool,
}

/// Why a star-tracker frame did not update the observer.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub enum UpdateError {
    /// Time tag older than the attitude history.
    Stale,
    /// Time tag later than the newest propagated attitude.
    Future,
    /// Mismatch larger than the gate once converged.
    Gated,
    /// Quaternion not finite or not unit.
    BadQuaternion,
}

/// What an estimator's update gives ([`Filter::update`]): the body rotation at t_s and the
/// drift change, carried to the present and the history by the [`Observer`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Correction {
    /// Body rotation at t_s, rad (eq. 6: K_B ⊙ e).
    pub body_rad: Vector3<f64>,
    /// Change of the drift estimate Δω, rad/s (eq. 6: −K_U ⊙ e).
    pub d_drift_rad_s: Vector3<f64>,
    /// The frame re-acquired ([`gate::Streak`]).
    pub reacquired: bool,
}

/// A frame as an estimator's update sees it.
#[derive(Debug)]
pub struct UpdateAt<'a> {
    /// Its mismatch e, rad (ICS at t_s).
    pub e_rad: &'a Vector3<f64>,
    /// Whether the estimate had converged before it ([`Convergence`]).
    pub converged: bool,
    /// Its time tag t_s, µs.
    pub time_us: u64,
    /// Seconds since the last update's time tag.
    pub tau_s: f64,
    /// Unit time of the alignment, µs.
    pub aligned_us: Option<u64>,
    /// Λ(t_s).
    pub q_at: &'a Quaternion<f64>,
    /// Λ at the last update's time tag, as corrected by it.
    pub last_q: &'a Quaternion<f64>,
}

/// The estimator that flies: the state of each estimator, and which one flies as a
/// byte every value of which decodes ([`Filter::estimator`]); one `match` per method.
/// Both states are held (no enum: a corrupted discriminant would be a wild jump); the
/// one that does not fly is not touched.
#[derive(Debug, Clone, Copy, PartialEq, bytemuck::AnyBitPattern)]
pub struct Filter {
    /// [`Filter::LUENBERGER`] or [`Filter::MEKF`].
    kind: u8,
    luenberger: Luenberger,
    mekf: Mekf,
}

/// Whether byte b is nearer [`Filter::MEKF`] than [`Filter::LUENBERGER`] (more than four
/// bits set): one load, where a bit count is a dozen instructions on the M7.
// Evaluated at compile time: an index out of range fails the build.
#[allow(clippy::indexing_slicing)]
const NEARER_MEKF: [bool; 256] = {
    let mut t = [false; 256];
    let mut b = 0;
    while b < 256 {
        t[b] = (b as u8).count_ones() > 4;
        b += 1;
    }
    t
};

impl Filter {
    /// The code of the paper's eq. (6).
    const LUENBERGER: u8 = 0x00;
    /// The code of the MEKF: eight bits from the other's, so a byte decodes to the
    /// nearer one and any single flipped bit is corrected.
    const MEKF: u8 = 0xFF;

    /// The estimator `cfg` selects, `steady` its steady-state gains.
    pub fn of(cfg: &ObserverConfig, steady: &ObserverGains) -> Self {
        let kind = match cfg.estimator {
            Estimator::Luenberger => Self::LUENBERGER,
            Estimator::Mekf => Self::MEKF,
        };
        Filter { kind, luenberger: Luenberger::from_config(cfg, steady), mekf: Mekf::new() }
    }

    /// Eq. (6) with `l`.
    fn luenberger(l: Luenberger) -> Self {
        Filter { kind: Self::LUENBERGER, luenberger: l, mekf: Mekf::new() }
    }

    /// Which estimator this is: the code nearer in bits (more than four set: the MEKF).
    #[inline(always)]
    pub fn estimator(&self) -> Estimator {
        if NEARER_MEKF.get(usize::from(self.kind)).copied().unwrap_or(false) {
            Estimator::Mekf
        } else {
            Estimator::Luenberger
        }
    }

    /// The state of eq. (6), when it flies.
    pub fn as_luenberger(&self) -> Option<&Luenberger> {
        (self.estimator() == Estimator::Luenberger).then_some(&self.luenberger)
    }

    /// The MEKF's state, when it flies.
    pub fn as_mekf(&self) -> Option<&Mekf> {
        (self.estimator() == Estimator::Mekf).then_some(&self.mekf)
    }

    /// A new table `cfg` (figures already in `fig`). A switch of estimator carries the
    /// covariance over as of the last update: per axis into the diagonals of the MEKF's
    /// blocks, or the diagonals of the MEKF's into the observer's running one.
    pub fn retune(&mut self, cfg: &ObserverConfig, fig: &Figures) {
        let steady = &fig.steady.gains;
        match (self.estimator(), cfg.estimator) {
            (Estimator::Luenberger, Estimator::Luenberger) => self.luenberger.retune(cfg, steady),
            (Estimator::Mekf, Estimator::Mekf) => self.mekf.retune(fig),
            (Estimator::Luenberger, Estimator::Mekf) => {
                let mut m = Mekf::with_axes(self.luenberger.cov());
                m.retune(fig);
                self.mekf = m;
                self.kind = Self::MEKF;
            }
            (Estimator::Mekf, Estimator::Luenberger) => {
                self.luenberger = Luenberger::from_config(cfg, steady).with_cov(self.mekf.axes(), fig);
                self.kind = Self::LUENBERGER;
            }
        }
    }

    /// At alignment on one frame (`sb2`: each FOG's turn-on bias variance).
    pub fn align(&mut self, fig: &Figures, sb2: f64) {
        match self.estimator() {
            Estimator::Luenberger => self.luenberger.align(fig, sb2),
            Estimator::Mekf => self.mekf.align(fig, sb2),
        }
    }

    /// Starts again from nothing (a new alignment follows).
    pub fn restart(&mut self, fig: &Figures) {
        match self.estimator() {
            Estimator::Luenberger => self.luenberger.restart(fig),
            Estimator::Mekf => self.mekf.forget_roots(),
        }
    }

    /// A re-alignment ([`Observer::realign`]), the drift estimate kept: the attitude
    /// known to `att_var_rad2` per axis, uncorrelated with the drift, whose covariance
    /// stays.
    pub fn realign(&mut self, fig: &Figures, att_var_rad2: f64) {
        match self.estimator() {
            Estimator::Luenberger => self.luenberger.realign(fig, att_var_rad2),
            Estimator::Mekf => self.mekf.realign(att_var_rad2),
        }
    }

    /// The noise figures per axis changed (`fig`).
    pub fn set_noise(&mut self, fig: &Figures) {
        match self.estimator() {
            Estimator::Luenberger => self.luenberger.refresh_isotropic(fig),
            Estimator::Mekf => {}
        }
    }

    /// The gate and the correction for a frame `at`.
    #[inline]
    pub fn update(&mut self, fig: &Figures, at: &UpdateAt, streak: &mut Streak) -> Result<Correction, UpdateError> {
        match self.estimator() {
            Estimator::Luenberger => self.luenberger.update(fig, at, streak),
            Estimator::Mekf => self.mekf.update(fig, at, streak),
        }
    }

    /// Expected variance of a mismatch per axis `tau_s` after the last update, rad².
    pub fn mismatch_var_rad2(&self, fig: &Figures, tau_s: f64) -> f64 {
        match self.estimator() {
            Estimator::Luenberger => self.luenberger.mismatch_var_rad2(fig, tau_s),
            Estimator::Mekf => self.mekf.mismatch_var_rad2(fig, tau_s),
        }
    }

    /// 1σ of the attitude error (rad) and of the drift error (rad/s) per axis.
    #[inline]
    pub fn sigmas(&mut self, fig: &Figures, tau_s: f64) -> ([f64; 3], [f64; 3]) {
        match self.estimator() {
            Estimator::Luenberger => self.luenberger.sigmas(fig, tau_s),
            Estimator::Mekf => self.mekf.sigmas(fig, tau_s),
        }
    }

    /// Its gains and covariance, for the state guard ([`crate::shadow`]).
    pub fn visit<V: crate::shadow::Visit>(&mut self, v: &mut V) {
        match self.estimator() {
            Estimator::Luenberger => self.luenberger.visit(v),
            Estimator::Mekf => self.mekf.visit(v),
        }
    }

    /// What only a new table changes (the acquisition stage's gains), for the state guard
    /// ([`crate::shadow`]).
    pub fn visit_tuning<V: crate::shadow::Visit>(&mut self, v: &mut V) {
        if let Estimator::Luenberger = self.estimator() {
            self.luenberger.visit_tuning(v);
        }
    }

    /// Whether the covariance is plausible: every variance finite, at least 0, and at
    /// most `max_att_rad2` (attitude) or `max_drift_rad2_s2` (drift).
    pub fn cov_plausible(&self, max_att_rad2: f64, max_drift_rad2_s2: f64) -> bool {
        let ok = |p: f64, max: f64| (0.0..=max).contains(&p);
        match self.estimator() {
            Estimator::Luenberger => {
                self.luenberger.cov().iter().all(|[a, _, d]| ok(*a, max_att_rad2) && ok(*d, max_drift_rad2_s2))
            }
            Estimator::Mekf => {
                let c = self.mekf.cov();
                c.paa.diagonal().iter().all(|a| ok(*a, max_att_rad2))
                    && c.pbb.diagonal().iter().all(|d| ok(*d, max_drift_rad2_s2))
            }
        }
    }

    /// Forgets the last 1σ roots (unaligned).
    #[inline]
    pub fn forget_roots(&mut self) {
        match self.estimator() {
            Estimator::Luenberger => self.luenberger.forget_roots(),
            Estimator::Mekf => self.mekf.forget_roots(),
        }
    }

    /// The covariance as plain numbers (a reset's snapshot): the MEKF's blocks P_aa,
    /// P_ab, P_bb column by column, or the observer's per-axis (P11, P12, P22) in the
    /// first nine.
    pub fn cov_words(&self) -> [f64; 27] {
        let mut out = [0.0; 27];
        match self.estimator() {
            Estimator::Luenberger => {
                for (o, v) in out.iter_mut().zip(self.luenberger.cov().iter().flatten()) {
                    *o = *v;
                }
            }
            Estimator::Mekf => {
                let c = self.mekf.cov();
                for (o, v) in out.iter_mut().zip(c.paa.iter().chain(c.pab.iter()).chain(c.pbb.iter())) {
                    *o = *v;
                }
            }
        }
        out
    }

    /// The inverse of [`Filter::cov_words`] (a reset resumed); the 1σ roots start over,
    /// and the MEKF's LFE states, which a snapshot does not carry, start unknown at
    /// their stationary covariance σ_c² I ([`mekf::Mekf::retune`]).
    pub fn set_cov_words(&mut self, w: &[f64; 27], fig: &Figures) {
        match self.estimator() {
            Estimator::Luenberger => {
                let mut cov = [[0.0; 3]; 3];
                for (c, v) in cov.iter_mut().flatten().zip(w) {
                    *c = *v;
                }
                self.luenberger = self.luenberger.with_cov(cov, fig);
                self.luenberger.forget_roots();
            }
            Estimator::Mekf => {
                let block = |k: usize| Matrix3::from_iterator(w.iter().skip(9 * k).take(9).copied());
                // The LFE states are not in the snapshot: they restart at their prior
                // (stationary) covariance, ĉ = 0, uncorrelated with the rest.
                let mut m = mekf::Mekf::with_cov(mekf::MekfCov { paa: block(0), pab: block(1), pbb: block(2) });
                m.retune(fig);
                self.mekf = m;
            }
        }
    }

    /// Takes an isolated gyro's share out of `drift_rad_s` ([`Observer::remove_drift_share`]).
    pub fn remove_share(
        &mut self,
        fig: &Figures,
        times_us: (u64, u64),
        drift_rad_s: &mut Vector3<f64>,
        share: (&Vector3<f64>, &Matrix3<f64>),
        pbb0: &Matrix3<f64>,
    ) {
        match self.estimator() {
            Estimator::Luenberger => self.luenberger.remove_share(fig, times_us, drift_rad_s, share),
            Estimator::Mekf => self.mekf.remove_share(drift_rad_s, share, pbb0),
        }
    }
}

/// What a reset resumes of the estimate ([`Observer::resume_state`]): plain numbers, so
/// any bit pattern of a snapshot reads back as a value (checked by its CRC and
/// plausibility, `crate::flight::snapshot`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ResumeState {
    /// Drift estimate Δω (ICS), rad/s.
    pub drift_rad_s: [f64; 3],
    /// Unit time of the alignment, µs.
    pub aligned_us: u64,
    /// Time tag of the last frame that updated the estimate, µs.
    pub last_update_tag_us: u64,
    /// Λ(t_s) after the last update (w x y z).
    pub last_q: [f64; 4],
    /// Updates since alignment ([`gate::Convergence`]).
    pub updates: u32,
    /// Running mean-square mismatch per axis, rad².
    pub innov_ms_rad2: f64,
    /// The estimator's covariance ([`Filter::cov_words`]).
    pub cov: [f64; 27],
}

state_struct! {
    /// The estimate from star-tracker frames: the attitude history, alignment, the drift
    /// estimate, and the estimator that flies ([`Filter`]). `H` attitudes of history bound
    /// the star-tracker latency it can absorb (H × step: 64 × 5 ms = 320 ms).
    #[derive(Debug, Clone, Copy, bytemuck::AnyBitPattern)]
    pub struct Observer<const H: usize> {
        history: History<H> = History::default(), map(History::<H>::STATE_MAP);
        drift_rad_s: Vector3<f64> = Vector3::zeros();
        aligned: Flag = Flag::CLEAR;
        /// Unit time of the alignment, µs.
        aligned_us: Maybe<u64> = Maybe::none();
        /// Time tag of the last frame that updated the observer, µs.
        last_update_tag_us: Maybe<u64> = Maybe::none();
        /// Λ(t_s) after the last update (the MEKF's start of the body's turn to the next).
        last_q: Quaternion<f64> = Quaternion::identity();
        conv: Convergence = Convergence::new(sigma_st_rad);
        streak: Streak = Streak::default();
        /// The consistency monitor between the tracker and the propagated attitude.
        monitor: Monitor = Monitor::default();
        fig: Figures = Figures::new(steady);
        /// Each FOG's drift variance at alignment, (rad/s)² (the table's initial drift 1σ
        /// squared).
        initial_drift_var_rad2_s2: f64 = 0.0;
        /// The body drift's covariance at alignment, σ_b² N, (rad/s)² ([`mekf::MekfCov::remove_share`]).
        drift_cov0: Matrix3<f64> = Matrix3::zeros();
        filter: Filter = filter;
    }
    constructor
    /// An observer flying `filter`.
    fn with_filter(filter: Filter, sigma_st_rad: f64, steady: SteadyState) -> Self => core::convert::identity {}
}

impl<const H: usize> Observer<H> {
    /// A new observer of eq. (6) with `gains`, expecting star-tracker noise `sigma_st_rad`
    /// (1σ), gating with the noise figures of `steady`.
    pub fn new(gains: ObserverGains, sigma_st_rad: f64, steady: SteadyState) -> Self {
        Self::with_filter(Filter::luenberger(Luenberger::new(gains)), sigma_st_rad, steady)
    }

    /// From the table: the estimator it selects; for eq. (6) its override gains if
    /// present, else the steady-state gains.
    pub fn from_config(cfg: &ObserverConfig) -> Result<Self, GainError> {
        let steady = steady_state(cfg)?;
        let mut o = Self::with_filter(Filter::of(cfg, &steady.gains), cfg.st_sigma_arcsec * ARCSEC_RAD, steady);
        o.initial_drift_var_rad2_s2 = initial_drift_var_rad2_s2(cfg);
        Ok(o)
    }

    /// A new table's figures (a table switch): its estimator, gains, star-tracker noise
    /// and gate figures from the next update on; the drift estimate, the history, the
    /// alignment and the covariance stay. Nothing changes if the gains cannot be computed.
    pub fn retune(&mut self, cfg: &ObserverConfig) -> Result<(), GainError> {
        let steady = steady_state(cfg)?;
        self.conv.set_sigma_st_rad(cfg.st_sigma_arcsec * ARCSEC_RAD);
        self.fig.steady = steady;
        self.initial_drift_var_rad2_s2 = initial_drift_var_rad2_s2(cfg);
        self.filter.retune(cfg, &self.fig);
        self.set_noise(&self.fig.noise.clone_owned());
        Ok(())
    }

    /// Flies on a FOG combination whose N = (SᵀS)⁻¹ is `noise` ([`mekf::noise_of`]) from
    /// now on: the gyros' noise figures per body axis (the four nominal FOGs: 5/6 on each
    /// axis; after an isolation the triad's). What was propagated until now stays.
    pub fn set_noise(&mut self, noise: &Matrix3<f64>) {
        self.fig.set_noise(noise);
        self.filter.set_noise(&self.fig);
    }

    /// The estimator that flies.
    pub fn estimator(&self) -> Estimator {
        self.filter.estimator()
    }

    /// The estimator's state.
    pub fn filter(&self) -> &Filter {
        &self.filter
    }

    /// Gains of eq. (6) in use (of the stage the last update flew, with two stages);
    /// `None` when the MEKF flies.
    pub fn gains(&self) -> Option<&ObserverGains> {
        self.filter.as_luenberger().map(Luenberger::gains)
    }

    /// Drift estimate Δω (ICS), rad/s.
    #[inline]
    pub fn drift_rad_s(&self) -> Vector3<f64> {
        self.drift_rad_s
    }

    /// The drift estimate's storage (x, y, z), rad/s, written back bit for bit by the
    /// in-step twin's repair (`flight::twin`).
    pub fn drift_words_mut(&mut self) -> &mut [f64] {
        self.drift_rad_s.as_mut_slice()
    }

    /// Flips bit `bit` of Δω's component `axis` (tests: an upset).
    #[cfg(test)]
    pub fn flip_drift(&mut self, axis: usize, bit: u32) {
        let c = &mut self.drift_rad_s[axis];
        *c = f64::from_bits(c.to_bits() ^ 1 << bit);
    }

    /// Whether the first star-tracker frame has aligned the attitude.
    #[inline]
    pub fn aligned(&self) -> bool {
        self.aligned.get()
    }

    /// Marks the attitude as aligned by other means (launch-vehicle pad alignment).
    pub fn set_aligned(&mut self) {
        self.aligned = Flag::SET;
    }

    /// Converged: aligned, at least 40 updates, and the mean-square mismatch (per axis)
    /// within 3σ of the star tracker's ([`Convergence`]), and the consistency monitor
    /// not suspecting the attitude ([`gate::Monitor::suspect`]: the last frames gated in
    /// a row, or a re-alignment asked for).
    #[inline]
    pub fn converged(&self) -> bool {
        self.aligned.get() && self.conv.converged() && !self.monitor.suspect()
    }

    /// What every step reads: the drift estimate Δω, the last update's time and the
    /// convergence state, for the
    /// state guard ([`crate::shadow`]).
    #[inline(always)]
    pub fn visit_steady<V: crate::shadow::Visit>(&mut self, v: &mut V) {
        v.f64s(self.drift_rad_s.as_mut_slice());
        v.opt_u64(&mut self.last_update_tag_us);
        self.conv.visit(v);
    }

    /// What a star-tracker frame reads and changes: the last update's Λ, the alignment
    /// time, the re-acquisition streak, the drift covariance at alignment, the estimator's
    /// gains and covariance, for the state guard ([`crate::shadow`]).
    pub fn visit_frame<V: crate::shadow::Visit>(&mut self, v: &mut V) {
        v.f64s(self.last_q.coords.as_mut_slice());
        v.opt_u64(&mut self.aligned_us);
        self.streak.visit(v);
        v.f64s(self.drift_cov0.as_mut_slice());
        self.filter.visit(v);
    }

    /// What a star-tracker frame reads and only a new table, an isolation or a mounting
    /// verdict changes: the noise figures, the initial drift variance, the acquisition
    /// stage's gains, for the state guard ([`crate::shadow`]).
    pub fn visit_tuning<V: crate::shadow::Visit>(&mut self, v: &mut V) {
        self.fig.visit(v);
        v.f64(&mut self.initial_drift_var_rad2_s2);
        self.filter.visit_tuning(v);
    }

    /// Re-aligns the attitude on the next star-tracker frame whatever its mismatch (the
    /// estimator's state was found corrupted), as the consistency monitor does on a
    /// persistent disagreement ([`Observer::realign`]); not converged until then.
    pub fn realign_on_next_frame(&mut self) {
        self.monitor.force();
    }

    /// Records the propagated attitude at the end of a step.
    #[inline]
    pub fn record(&mut self, time_us: u64, q: Quaternion<f64>) {
        self.history.record(time_us, q);
    }

    /// Propagated attitude at `time_us`, interpolated between recorded steps.
    pub fn attitude_at(&self, time_us: u64) -> Result<Quaternion<f64>, UpdateError> {
        self.history.attitude_at(time_us)
    }

    /// Seconds from the last update's time tag to `time_us` (0 before any).
    #[inline(always)]
    fn since_update_s(&self, time_us: u64) -> f64 {
        let gap_us = self.last_update_tag_us.get().map_or(0, |t| time_us.saturating_sub(t));
        f64::from(u32::try_from(gap_us).unwrap_or(u32::MAX)) * 1e-6
    }

    /// The 1σ of the attitude error (rad) and of the drift error (rad/s) per axis at
    /// `time_us`, the estimator's covariance propagated to that time; infinite before
    /// alignment: unknown.
    ///
    /// Each root is one Newton step x ← (x + P/x)/2 from the last step's (relative error
    /// ε²/2 for a start off by ε: below 2e-3 whenever P moved by less than 12.5 %, as it
    /// does from step to step and at an update), and a full square root otherwise.
    #[inline]
    pub fn sigmas(&mut self, time_us: u64) -> ([f64; 3], [f64; 3]) {
        if !self.aligned.get() {
            self.filter.forget_roots();
            return ([f64::INFINITY; 3], [f64::INFINITY; 3]);
        }
        let tau_s = self.since_update_s(time_us);
        self.filter.sigmas(&self.fig, tau_s)
    }

    /// Expected variance of a mismatch per axis, rad², for a frame with time tag
    /// `time_us`: R + the estimator's attitude-error variance propagated to it, so an
    /// outage widens the gate as the attitude uncertainty grows.
    pub fn mismatch_var_rad2(&self, time_us: u64) -> f64 {
        self.filter.mismatch_var_rad2(&self.fig, self.since_update_s(time_us))
    }

    /// Λ(t_s) and Λ* taken to the ICS (eq. 5: Λ* = Λ ∘ δΨ_Λ → Λ_ICS = Λ* ∘ q_bs⁻¹) for a
    /// frame, without using it.
    #[inline(always)]
    fn at_frame(
        &self,
        time_us: u64,
        q_st: &Quaternion<f64>,
        mount: &Quaternion<f64>,
    ) -> Result<(Quaternion<f64>, Quaternion<f64>), UpdateError> {
        if !gate::quaternion_ok(q_st) {
            return Err(UpdateError::BadQuaternion);
        }
        let q_at = self.history.attitude_at(time_us)?;
        Ok((q_at, q_st * mount.conjugate()))
    }

    /// The mismatch e (rad, ICS at t_s) of a frame and its expected variance per axis,
    /// without correcting anything (the fault logic listens while it isolates a gyro).
    pub fn listen(
        &mut self,
        time_us: u64,
        q_st: &Quaternion<f64>,
        mount: &Quaternion<f64>,
    ) -> Result<Mismatch, UpdateError> {
        if !self.aligned.get() {
            return Err(UpdateError::Future);
        }
        let (q_at, q_meas) = self.at_frame(time_us, q_st, mount)?;
        Ok(Mismatch { e_rad: gate::mismatch_rad(&q_at, &q_meas), var_rad2: self.mismatch_var_rad2(time_us) })
    }

    /// One star-tracker frame: `q_st` is Λ* of the frame with time tag `time_us`,
    /// `mount` q_bs. The first aligns; later ones go through the estimator's gate
    /// ([`gate`]) and correct `att` (whose present time is `now_us`), the history and the
    /// drift estimate.
    #[inline(never)]
    pub fn update(
        &mut self,
        att: &mut Attitude,
        now_us: u64,
        time_us: u64,
        q_st: &Quaternion<f64>,
        mount: &Quaternion<f64>,
    ) -> Result<Updated, UpdateError> {
        let (q_at, q_meas) = self.at_frame(time_us, q_st, mount)?;
        if !self.aligned.get() {
            self.align(att, now_us, time_us, &q_at, &q_meas);
            return Ok(Updated { e_rad: Vector3::zeros(), reacquired: false, realigned: false });
        }
        let e = gate::mismatch_rad(&q_at, &q_meas);
        if self.monitor.forced() {
            let c = q_meas * q_at.conjugate();
            let r = self.fig.steady.r_rad2;
            self.realign(att, (now_us, time_us), &q_at, &c, r);
            return Ok(Updated { e_rad: e, reacquired: false, realigned: true });
        }
        let at = UpdateAt {
            e_rad: &e,
            converged: self.conv.converged(),
            time_us,
            tau_s: self.since_update_s(time_us),
            aligned_us: self.aligned_us.get(),
            q_at: &q_at,
            last_q: &self.last_q,
        };
        let corr = match self.filter.update(&self.fig, &at, &mut self.streak) {
            Ok(corr) => corr,
            Err(UpdateError::Gated) => return self.on_gated(att, (now_us, time_us), (&q_at, &q_meas)),
            Err(err) => return Err(err),
        };
        self.monitor.end();
        // Body correction at t_s as an inertial left factor: Λ(t_s) ∘ q(corr) ∘ Λ(t_s)⁻¹.
        let c = q_at * math::quat_from_rotvec(&corr.body_rad) * q_at.conjugate();
        self.history.fix(att, now_us, time_us, &c, &corr.d_drift_rad_s);
        self.drift_rad_s += corr.d_drift_rad_s;
        self.last_q = c * q_at;
        self.conv.note(e.norm_squared());
        self.last_update_tag_us = Maybe::some(time_us);
        Ok(Updated { e_rad: e, reacquired: corr.reacquired, realigned: false })
    }

    /// A gated frame (Λ(t_s) and Λ* in `q`, at `times_us` = (now, t_s)) into the
    /// consistency monitor: refused, unless it is the [`gate::REALIGN_FRAMES`]-th gated in
    /// a row and their inertial corrections agree, when the attitude re-aligns by their
    /// mean ([`Observer::realign`]), known to R / n; the disagreement reported is that
    /// mean.
    #[inline(never)]
    fn on_gated(
        &mut self,
        att: &mut Attitude,
        times_us: (u64, u64),
        (q_at, q_meas): (&Quaternion<f64>, &Quaternion<f64>),
    ) -> Result<Updated, UpdateError> {
        let d = math::rotvec_from_quat(&(q_meas * q_at.conjugate()));
        let var = self.mismatch_var_rad2(times_us.1);
        let Some((mean, n)) = self.monitor.realigns(&d, var) else { return Err(UpdateError::Gated) };
        let c = math::quat_from_rotvec(&mean);
        let r = self.fig.steady.r_rad2 / n;
        self.realign(att, times_us, q_at, &c, r);
        Ok(Updated { e_rad: mean, reacquired: false, realigned: true })
    }

    /// Re-aligns by an inertial correction `c` (C ∘ Λ(t_s), for the present and the
    /// history; [`Observer::settle_on`]), the attitude then known to `att_var_rad2` per
    /// axis, the estimate already aligned: the drift estimate stays if it is plausible
    /// (|Δω|² within 25 σ_b² tr N, 5σ of what the FOGs' turn-on biases leave, or within
    /// [`DRIFT_PLAUSIBLE_RAD_S2`]; its covariance kept), else it starts again from zero as
    /// at alignment (the acquisition stage too). Not converged until [`Convergence`] says so again (40 updates).
    fn realign(
        &mut self,
        att: &mut Attitude,
        times_us: (u64, u64),
        q_at: &Quaternion<f64>,
        c: &Quaternion<f64>,
        att_var_rad2: f64,
    ) {
        let bound2 = (25.0 * self.initial_drift_var_rad2_s2 * self.fig.noise.trace()).max(DRIFT_PLAUSIBLE_RAD_S2);
        let plausible = self.drift_rad_s.norm_squared() <= bound2;
        self.settle_on(att, times_us, (q_at, c), plausible.then_some(att_var_rad2));
    }

    /// The first frame: C ∘ Λ(t_s) = Λ*, applied to the present and the history. The
    /// drift is what is left of each FOG's turn-on bias (the table's initial drift 1σ,
    /// σ_b), on the body axes σ_b² N: what the error of either estimator really is at
    /// alignment, the drift estimate being 0.
    fn align(
        &mut self,
        att: &mut Attitude,
        now_us: u64,
        time_us: u64,
        q_at: &Quaternion<f64>,
        q_meas: &Quaternion<f64>,
    ) {
        self.aligned = Flag::SET;
        self.settle_on(att, (now_us, time_us), (q_at, &(q_meas * q_at.conjugate())), None);
    }

    /// Sets the attitude by the inertial correction `c` at a frame (Λ(t_s) and C in `q`,
    /// at `times_us` = (now, t_s)): C ∘ Λ(t_s) for the present and the history; the drift
    /// estimate and its covariance kept (`kept_att_var_rad2`: `Some` of the attitude's
    /// variance per axis) or started again from zero as at alignment, the history
    /// re-propagated without the old drift. The convergence count starts again.
    fn settle_on(
        &mut self,
        att: &mut Attitude,
        (now_us, time_us): (u64, u64),
        (q_at, c): (&Quaternion<f64>, &Quaternion<f64>),
        kept_att_var_rad2: Option<f64>,
    ) {
        let keep_drift = kept_att_var_rad2.is_some();
        let drift = self.drift_rad_s;
        let d_drift = if keep_drift || drift == Vector3::zeros() || !drift.iter().all(|v| v.is_finite()) {
            Vector3::zeros()
        } else {
            -drift
        };
        self.history.fix(att, now_us, time_us, c, &d_drift);
        if let Some(var) = kept_att_var_rad2 {
            self.filter.realign(&self.fig, var);
        } else {
            let sb2 = self.initial_drift_var_rad2_s2;
            self.drift_rad_s = Vector3::zeros();
            self.aligned_us = Maybe::some(time_us);
            self.filter.align(&self.fig, sb2);
            self.drift_cov0 = self.fig.noise * sb2;
        }
        self.last_update_tag_us = Maybe::some(time_us);
        self.last_q = c * q_at;
        self.conv.reset();
        self.conv.aligned();
        self.streak.end();
        self.monitor.end();
    }

    /// The estimate a reset resumes from (`None` before alignment).
    pub fn resume_state(&self) -> Option<ResumeState> {
        let aligned_us = self.aligned_us.get().filter(|_| self.aligned.get())?;
        let (updates, innov_ms_rad2) = self.conv.state();
        let q = &self.last_q;
        Some(ResumeState {
            drift_rad_s: self.drift_rad_s.into(),
            aligned_us,
            last_update_tag_us: self.last_update_tag_us.get().unwrap_or(aligned_us),
            last_q: [q.w, q.i, q.j, q.k],
            updates,
            innov_ms_rad2,
            cov: self.filter.cov_words(),
        })
    }

    /// Resumes the estimate `s` after a reset: aligned at `s.aligned_us`, its drift
    /// estimate, convergence and covariance; the attitude history starts empty (frames
    /// tagged before the resume are refused as late).
    pub fn resume(&mut self, s: &ResumeState) {
        let [w, i, j, k] = s.last_q;
        self.aligned = Flag::SET;
        self.aligned_us = Maybe::some(s.aligned_us);
        self.last_update_tag_us = Maybe::some(s.last_update_tag_us);
        self.last_q = Quaternion::new(w, i, j, k);
        self.drift_rad_s = Vector3::from(s.drift_rad_s);
        self.conv.restore(s.updates, s.innov_ms_rad2);
        self.drift_cov0 = self.fig.noise * self.initial_drift_var_rad2_s2;
        self.filter.set_cov_words(&s.cov, &self.fig);
        self.streak.end();
    }

    /// Starts again from an unaligned state (a FOG found mounted wrong before the unit
    /// reported aligned): the next frame aligns, the drift estimate and the covariance
    /// start from zero. The attitude history and its pending fixes stay, so that frame
    /// reads the attitude as it was propagated.
    /// Everything else (gains, figures, the estimator's choice) stays.
    pub fn restart(&mut self) {
        self.aligned = Flag::CLEAR;
        self.aligned_us = Maybe::none();
        self.drift_rad_s = Vector3::zeros();
        self.conv.reset();
        self.last_update_tag_us = Maybe::none();
        self.filter.restart(&self.fig);
        self.streak.end();
        self.monitor.end();
    }

    /// Takes out of the drift estimate what it has learned of a constant drift
    /// `share_rad_s` (ICS) present since alignment (an isolated gyro's share, as the
    /// parity baseline estimates it, with covariance `share_cov_rad2_s2`), at unit time
    /// `now_us`; each estimator by what its own gains have learned of it
    /// ([`Luenberger::remove_share`], [`mekf::MekfCov::remove_share`]).
    pub fn remove_drift_share(&mut self, now_us: u64, share_rad_s: &Vector3<f64>, share_cov_rad2_s2: &Matrix3<f64>) {
        let Some(t0) = self.aligned_us.get() else { return };
        self.filter.remove_share(
            &self.fig,
            (now_us, t0),
            &mut self.drift_rad_s,
            (share_rad_s, share_cov_rad2_s2),
            &self.drift_cov0,
        );
    }

    /// Removes a drift `drift_rad_s` (ICS) that entered the attitude from `since_us` on
    /// (an isolated gyro's fault): Λ(t) ← Λ(t) ∘ q(−drift · (t − since)) for the present
    /// attitude and, lazily, the history.
    pub fn remove_drift(&mut self, att: &mut Attitude, now_us: u64, since_us: u64, drift_rad_s: &Vector3<f64>) {
        self.history.fix(att, now_us, since_us, &Quaternion::identity(), drift_rad_s);
    }
}
