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
//! | [`gate`] | the mismatch, the χ²₃ gate, re-acquisition, convergence |
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
//! 2. A variant of [`crate::calib::Estimator`] for the table, and one of [`Filter`]
//!    holding the new state; each `match` in `impl Filter` gets its arm (the compiler
//!    lists them), and [`Filter::retune`] says what the covariance becomes when a table
//!    switches estimators in flight.
//!
//! There is no dynamic dispatch and no allocation: [`Filter`] is an enum held by value.

pub mod gains;
pub mod gate;
pub mod history;
pub mod luenberger;
pub mod mekf;

use nalgebra::{Matrix3, Quaternion, Vector3};

use crate::attitude::Attitude;
use crate::calib::{Estimator, ObserverConfig, ObserverGains};
use crate::math;
use gains::{initial_drift_var_rad2_s2, Figures, ARCSEC_RAD};
use gate::{Convergence, Streak};
use luenberger::Luenberger;
use mekf::Mekf;

pub use gains::{steady_state, steady_state_gains, GainError, SteadyState};
pub use gate::{CHI2_GATE, REACQUIRE_FRAMES};
pub use history::History;

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

/// The estimator that flies: one variant per estimator, one `match` per method.
// One instance, held by value without allocation: the MEKF's LFE blocks make its variant
// the larger by 264 bytes, which a box (an allocation) would not save.
#[allow(clippy::large_enum_variant)]
#[derive(Debug, Clone, PartialEq)]
pub enum Filter {
    /// The paper's eq. (6) with fixed gains ([`luenberger`]).
    Luenberger(Luenberger),
    /// The MEKF ([`mekf`]).
    Mekf(Mekf),
}

impl Filter {
    /// The estimator `cfg` selects, `steady` its steady-state gains.
    pub fn of(cfg: &ObserverConfig, steady: &ObserverGains) -> Self {
        match cfg.estimator {
            Estimator::Luenberger => Filter::Luenberger(Luenberger::from_config(cfg, steady)),
            Estimator::Mekf => Filter::Mekf(Mekf::new()),
        }
    }

    /// Which estimator this is.
    pub fn estimator(&self) -> Estimator {
        match self {
            Filter::Luenberger(_) => Estimator::Luenberger,
            Filter::Mekf(_) => Estimator::Mekf,
        }
    }

    /// A new table `cfg` (figures already in `fig`). A switch of estimator carries the
    /// covariance over as of the last update: per axis into the diagonals of the MEKF's
    /// blocks, or the diagonals of the MEKF's into the observer's running one.
    pub fn retune(&mut self, cfg: &ObserverConfig, fig: &Figures) {
        let steady = &fig.steady.gains;
        *self = match (&mut *self, cfg.estimator) {
            (Filter::Luenberger(l), Estimator::Luenberger) => {
                l.retune(cfg, steady);
                return;
            }
            (Filter::Mekf(m), Estimator::Mekf) => {
                m.retune(fig);
                return;
            }
            (Filter::Luenberger(l), Estimator::Mekf) => {
                let mut m = Mekf::with_axes(l.cov());
                m.retune(fig);
                Filter::Mekf(m)
            }
            (Filter::Mekf(m), Estimator::Luenberger) => {
                Filter::Luenberger(Luenberger::from_config(cfg, steady).with_cov(m.axes(), fig))
            }
        };
    }

    /// At alignment on one frame (`sb2`: each FOG's turn-on bias variance).
    pub fn align(&mut self, fig: &Figures, sb2: f64) {
        match self {
            Filter::Luenberger(l) => l.align(fig, sb2),
            Filter::Mekf(m) => m.align(fig, sb2),
        }
    }

    /// Starts again from nothing (a new alignment follows).
    pub fn restart(&mut self, fig: &Figures) {
        match self {
            Filter::Luenberger(l) => l.restart(fig),
            Filter::Mekf(m) => m.forget_roots(),
        }
    }

    /// The noise figures per axis changed (`fig`).
    pub fn set_noise(&mut self, fig: &Figures) {
        match self {
            Filter::Luenberger(l) => l.refresh_isotropic(fig),
            Filter::Mekf(_) => {}
        }
    }

    /// The gate and the correction for a frame `at`.
    #[inline]
    pub fn update(&mut self, fig: &Figures, at: &UpdateAt, streak: &mut Streak) -> Result<Correction, UpdateError> {
        match self {
            Filter::Luenberger(l) => l.update(fig, at, streak),
            Filter::Mekf(m) => m.update(fig, at, streak),
        }
    }

    /// Expected variance of a mismatch per axis `tau_s` after the last update, rad².
    pub fn mismatch_var_rad2(&self, fig: &Figures, tau_s: f64) -> f64 {
        match self {
            Filter::Luenberger(l) => l.mismatch_var_rad2(fig, tau_s),
            Filter::Mekf(m) => m.mismatch_var_rad2(fig, tau_s),
        }
    }

    /// 1σ of the attitude error (rad) and of the drift error (rad/s) per axis.
    #[inline]
    pub fn sigmas(&mut self, fig: &Figures, tau_s: f64) -> ([f64; 3], [f64; 3]) {
        match self {
            Filter::Luenberger(l) => l.sigmas(fig, tau_s),
            Filter::Mekf(m) => m.sigmas(fig, tau_s),
        }
    }

    /// Forgets the last 1σ roots (unaligned).
    #[inline]
    pub fn forget_roots(&mut self) {
        match self {
            Filter::Luenberger(l) => l.forget_roots(),
            Filter::Mekf(m) => m.forget_roots(),
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
        match self {
            Filter::Luenberger(l) => l.remove_share(fig, times_us, drift_rad_s, share),
            Filter::Mekf(m) => m.remove_share(drift_rad_s, share, pbb0),
        }
    }
}

/// The estimate from star-tracker frames: the attitude history, alignment, the drift
/// estimate, and the estimator that flies ([`Filter`]). `H` attitudes of history bound
/// the star-tracker latency it can absorb (H × step: 64 × 5 ms = 320 ms).
#[derive(Debug, Clone)]
pub struct Observer<const H: usize> {
    history: History<H>,
    drift_rad_s: Vector3<f64>,
    aligned: bool,
    /// Unit time of the alignment, µs.
    aligned_us: Option<u64>,
    /// Time tag of the last frame that updated the observer, µs.
    last_update_tag_us: Option<u64>,
    /// Λ(t_s) after the last update (the MEKF's start of the body's turn to the next).
    last_q: Quaternion<f64>,
    conv: Convergence,
    streak: Streak,
    fig: Figures,
    /// Each FOG's drift variance at alignment, (rad/s)² (the table's initial drift 1σ
    /// squared).
    initial_drift_var_rad2_s2: f64,
    /// The body drift's covariance at alignment, σ_b² N, (rad/s)² ([`mekf::MekfCov::remove_share`]).
    drift_cov0: Matrix3<f64>,
    filter: Filter,
}

impl<const H: usize> Observer<H> {
    /// A new observer of eq. (6) with `gains`, expecting star-tracker noise `sigma_st_rad`
    /// (1σ), gating with the noise figures of `steady`.
    pub fn new(gains: ObserverGains, sigma_st_rad: f64, steady: SteadyState) -> Self {
        Observer {
            history: History::default(),
            drift_rad_s: Vector3::zeros(),
            aligned: false,
            aligned_us: None,
            last_update_tag_us: None,
            last_q: Quaternion::identity(),
            conv: Convergence::new(sigma_st_rad),
            streak: Streak::default(),
            fig: Figures::new(steady),
            initial_drift_var_rad2_s2: 0.0,
            drift_cov0: Matrix3::zeros(),
            filter: Filter::Luenberger(Luenberger::new(gains)),
        }
    }

    /// From the table: the estimator it selects; for eq. (6) its override gains if
    /// present, else the steady-state gains.
    pub fn from_config(cfg: &ObserverConfig) -> Result<Self, GainError> {
        let steady = steady_state(cfg)?;
        let mut o = Self::new(steady.gains, cfg.st_sigma_arcsec * ARCSEC_RAD, steady);
        o.filter = Filter::of(cfg, &steady.gains);
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
        match &self.filter {
            Filter::Luenberger(l) => Some(l.gains()),
            Filter::Mekf(_) => None,
        }
    }

    /// Drift estimate Δω (ICS), rad/s.
    #[inline]
    pub fn drift_rad_s(&self) -> Vector3<f64> {
        self.drift_rad_s
    }

    /// Whether the first star-tracker frame has aligned the attitude.
    #[inline]
    pub fn aligned(&self) -> bool {
        self.aligned
    }

    /// Marks the attitude as aligned by other means (launch-vehicle pad alignment).
    pub fn set_aligned(&mut self) {
        self.aligned = true;
    }

    /// Converged: aligned, at least 40 updates, and the mean-square mismatch (per axis)
    /// within 3σ of the star tracker's ([`Convergence`]).
    #[inline]
    pub fn converged(&self) -> bool {
        self.aligned && self.conv.converged()
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
        let gap_us = self.last_update_tag_us.map_or(0, |t| time_us.saturating_sub(t));
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
        if !self.aligned {
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
        if !self.aligned {
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
        if !self.aligned {
            self.align(att, now_us, time_us, &q_at, &q_meas);
            return Ok(Updated { e_rad: Vector3::zeros(), reacquired: false });
        }
        let e = gate::mismatch_rad(&q_at, &q_meas);
        let at = UpdateAt {
            e_rad: &e,
            converged: self.conv.converged(),
            time_us,
            tau_s: self.since_update_s(time_us),
            aligned_us: self.aligned_us,
            q_at: &q_at,
            last_q: &self.last_q,
        };
        let corr = self.filter.update(&self.fig, &at, &mut self.streak)?;
        // Body correction at t_s as an inertial left factor: Λ(t_s) ∘ q(corr) ∘ Λ(t_s)⁻¹.
        let c = q_at * math::quat_from_rotvec(&corr.body_rad) * q_at.conjugate();
        self.history.fix(att, now_us, time_us, &c, &corr.d_drift_rad_s);
        self.drift_rad_s += corr.d_drift_rad_s;
        self.last_q = c * q_at;
        self.conv.note(e.norm_squared());
        self.last_update_tag_us = Some(time_us);
        Ok(Updated { e_rad: e, reacquired: corr.reacquired })
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
        let c = q_meas * q_at.conjugate();
        self.history.fix(att, now_us, time_us, &c, &Vector3::zeros());
        self.aligned = true;
        self.aligned_us = Some(time_us);
        self.last_update_tag_us = Some(time_us);
        let sb2 = self.initial_drift_var_rad2_s2;
        self.filter.align(&self.fig, sb2);
        self.drift_cov0 = self.fig.noise * sb2;
        self.last_q = c * q_at;
        self.conv.aligned();
    }

    /// Starts again from an unaligned state (a FOG found mounted wrong before the unit
    /// reported aligned): the next frame aligns, the drift estimate and the covariance
    /// start from zero. The attitude history and its pending fixes stay, so that frame
    /// reads the attitude as it was propagated.
    /// Everything else (gains, figures, the estimator's choice) stays.
    pub fn restart(&mut self) {
        self.aligned = false;
        self.aligned_us = None;
        self.drift_rad_s = Vector3::zeros();
        self.conv.reset();
        self.last_update_tag_us = None;
        self.filter.restart(&self.fig);
        self.streak.end();
    }

    /// Takes out of the drift estimate what it has learned of a constant drift
    /// `share_rad_s` (ICS) present since alignment (an isolated gyro's share, as the
    /// parity baseline estimates it, with covariance `share_cov_rad2_s2`), at unit time
    /// `now_us`; each estimator by what its own gains have learned of it
    /// ([`Luenberger::remove_share`], [`mekf::MekfCov::remove_share`]).
    pub fn remove_drift_share(&mut self, now_us: u64, share_rad_s: &Vector3<f64>, share_cov_rad2_s2: &Matrix3<f64>) {
        let Some(t0) = self.aligned_us else { return };
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
