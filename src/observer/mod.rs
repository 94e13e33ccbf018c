//! Observer: the paper's Luenberger observer with extended state, eq. (6),
//!
//! ```text
//! Λ̇  = ½ Λ ∘ (ω* + K_B · vect(ΔΛ) − Δω)
//! Δω̇ = −K_U · vect(ΔΛ),            ΔΛ = Λ⁻¹ ∘ Λ*
//! ```
//!
//! discretised for star-tracker frames that arrive at their own rate (1–10 Hz) and late.
//! Between frames Λ is propagated on the gyros with ω* − Δω ([`crate::attitude`]). At a
//! frame with time tag t_s the observer
//!
//! 1. takes Λ(t_s) from its history of propagated attitudes (interpolated between the two
//!    steps around t_s), so latency does not enter the mismatch;
//! 2. forms the mismatch rotation vector e = 2 vect(ΔΛ) (exact: [`math::rotvec_from_quat`])
//!    with Λ* taken back from the star-tracker frame to the ICS through the mount, eq. (5);
//! 3. corrects Λ(t_s) by the body rotation K_B ⊙ e and the drift by Δω ← Δω − K_U ⊙ e,
//!    and carries both corrections forward to the present step at once, and to the
//!    history entries after t_s lazily: the correction is kept as a pending fix and
//!    applied to the (at most two) entries a later update reads, with the same arithmetic
//!    in the same order as applying it to every entry, so the result is bit-identical.
//!    A later frame's time tag usually lies after the present step of the previous
//!    update (4 Hz, 50 ms latency), and then no fix is applied at all.
//!
//! The gains are per update: K_B dimensionless, K_U in 1/s. [`steady_state_gains`] gives
//! the steady-state Kalman gains of the per-axis model (attitude error, drift) for stated
//! noise figures (Farrenkopf 1978); a fixed-gain observer with these gains matches the
//! Kalman filter in steady state (4 Hz → K = [0.0224, 1.24e-5 /s]).
//!
//! A table may override them, and may make the override a first stage only
//! ([`ObserverConfig::acquisition_s`], "gear shift"): the paper's gains "selected from a
//! given performance" (critically damped, τ = 60 s: K_B = 2T/τ, K_U = T/τ²) find an
//! uncalibrated bias of tens of °/h in minutes, where the steady-state gains' slow pole
//! (K_U/K_B ≈ 1/(30 min)) takes hours; but in steady state they hold the attitude error
//! 21 % above the Kalman limit (per-axis fixed-gain covariance, 4 Hz, the paper's
//! sensors), so after t_acq the steady-state gains take over. Both stages are eq. (6)
//! with fixed gains; the switch changes gains only, not the state.
//!
//! The table may select instead a multiplicative extended Kalman filter
//! ([`Estimator::Mekf`], [`mekf`]): the same history, alignment of the time tag, lazy fix
//! and re-acquisition, with the gains, the gate and the 1σ from its own 6-state covariance.

pub mod mekf;

use heapless::Deque;
use nalgebra::{Matrix3, Quaternion, Vector3};

use crate::attitude::Attitude;
use crate::calib::{Estimator, ObserverConfig, ObserverGains};
use crate::math;
use mekf::MekfCov;

const ARCSEC_RAD: f64 = core::f64::consts::PI / 180.0 / 3600.0;
const DEG_RAD: f64 = core::f64::consts::PI / 180.0;

/// A star-tracker frame's mismatch, heard but not used ([`Observer::listen`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Mismatch {
    /// Mismatch e, rad (ICS at the frame's time tag).
    pub e_rad: Vector3<f64>,
    /// Its expected variance per axis, rad².
    pub var_rad2: f64,
}

/// Why gains could not be computed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub enum GainError {
    /// A noise figure is zero, negative or not finite.
    BadFigures,
    /// The Riccati iteration did not settle within its bound.
    NotConverged,
}

/// Steady-state Kalman gains of the per-axis model x = (attitude error, drift error):
/// F = [[1, −T], [0, 1]], Q from ARW σ_v and rate random walk σ_u, R = σ_st².
/// Bounded iteration of the discrete Riccati equation.
pub fn steady_state_gains(cfg: &ObserverConfig) -> Result<ObserverGains, GainError> {
    steady_state(cfg).map(|s| s.gains)
}

/// The steady state of the per-axis Kalman filter: gains and the variances the gate needs.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SteadyState {
    /// Gains K_B, K_U.
    pub gains: ObserverGains,
    /// Prior attitude-error variance at an update, rad² per axis.
    pub prior_var_rad2: f64,
    /// Posterior drift-error variance, (rad/s)² per axis.
    pub drift_var_rad2_s2: f64,
    /// Star-tracker noise variance R, rad² per axis.
    pub r_rad2: f64,
    /// ARW variance rate σ_v², rad²/s.
    pub arw_var_rad2_s: f64,
    /// Rate random walk variance rate σ_u², rad²/s³.
    pub rrw_var_rad2_s3: f64,
}

/// [`steady_state_gains`] with the variances at steady state.
pub fn steady_state(cfg: &ObserverConfig) -> Result<SteadyState, GainError> {
    let t = cfg.st_period_s;
    let sv = cfg.arw_deg_sqrt_h * DEG_RAD / 60.0; // rad/√s
    let su = cfg.rrw_deg_h_sqrt_h * DEG_RAD / 3600.0 / 60.0; // rad/s/√s
    let r = (cfg.st_sigma_arcsec * ARCSEC_RAD) * (cfg.st_sigma_arcsec * ARCSEC_RAD);
    let ok = |x: f64| x.is_finite() && x > 0.0;
    if !(ok(t) && ok(sv) && ok(su) && ok(r)) {
        return Err(GainError::BadFigures);
    }
    let q11 = sv * sv * t + su * su * t * t * t / 3.0;
    let q12 = -su * su * t * t / 2.0;
    let q22 = su * su * t;
    // Start from a posterior that is surely larger than the steady state.
    let (mut p11, mut p12, mut p22) = (r, 0.0, 1e-8);
    let (mut k1, mut k2) = (0.0f64, 0.0f64);
    for _ in 0..2_000_000u32 {
        let m11 = p11 - 2.0 * t * p12 + t * t * p22 + q11;
        let m12 = p12 - t * p22 + q12;
        let m22 = p22 + q22;
        let s = m11 + r;
        let (n1, n2) = (m11 / s, m12 / s);
        p11 = (1.0 - n1) * m11;
        p12 = (1.0 - n1) * m12;
        p22 = m22 - n2 * m12;
        let settled = (n1 - k1).abs() <= 1e-13 * n1.abs() && (n2 - k2).abs() <= 1e-13 * n2.abs();
        k1 = n1;
        k2 = n2;
        if settled {
            return Ok(SteadyState {
                gains: ObserverGains { k_b: [k1; 3], k_u_per_s: [-k2; 3] },
                prior_var_rad2: m11,
                drift_var_rad2_s2: p22,
                r_rad2: r,
                arw_var_rad2_s: sv * sv,
                rrw_var_rad2_s3: su * su,
            });
        }
    }
    Err(GainError::NotConverged)
}

/// χ²₃ gate on the normalised mismatch: 16.27 refuses 0.1 % of nominal frames.
pub const CHI2_GATE: f64 = 16.266;
/// Consecutive gated frames that agree with each other and re-acquire (8 at 4 Hz: 2 s):
/// the attitude, not the star tracker, is off (after a long outage or a fault).
pub const REACQUIRE_FRAMES: u32 = 8;

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

/// Counters of the observer's star-tracker updates.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct ObserverStats {
    /// Updates applied (including the initial alignment).
    pub updates: u32,
    /// Frames refused as older than the history.
    pub stale: u32,
    /// Frames refused as newer than the present step.
    pub future: u32,
    /// Frames refused by the gate.
    pub gated: u32,
    /// Re-acquisitions (a streak of gated frames that agreed with each other).
    pub reacquired: u32,
}

#[derive(Debug, Clone, Copy, PartialEq)]
struct Sample {
    time_us: u64,
    q: Quaternion<f64>,
}

/// Pending fixes kept at once: a frame per update, the history spans H steps; more
/// star-tracker updates than this within the history (an 8 Hz tracker with 0.5 s
/// latency) apply the oldest fix to the stored entries, as an eager update would.
const PENDING_FIXES: usize = 4;

/// A correction of eq. (6) not yet applied to the history: entries with `from_us` ≤
/// t ≤ `to_us` (recorded before the update) become c ∘ Λ(t) ∘ q(−δΔω · (t − from_us)).
#[derive(Debug, Clone, Copy, PartialEq)]
struct Fix {
    from_us: u64,
    to_us: u64,
    c: Quaternion<f64>,
    d_drift: Vector3<f64>,
}

impl Fix {
    fn covers(&self, t_us: u64) -> bool {
        self.from_us <= t_us && t_us <= self.to_us
    }

    fn apply(&self, q: &Quaternion<f64>, t_us: u64) -> Quaternion<f64> {
        let dt_s = f64::from(u32::try_from(t_us.saturating_sub(self.from_us)).unwrap_or(u32::MAX)) * 1e-6;
        self.c * q * math::quat_from_rotvec(&(-self.d_drift * dt_s))
    }
}

/// The observer of eq. (6). `H` attitudes of history bound the star-tracker latency it
/// can absorb (H × step: 64 × 5 ms = 320 ms).
#[derive(Debug, Clone)]
pub struct Observer<const H: usize> {
    gains: ObserverGains,
    drift_rad_s: Vector3<f64>,
    /// Ring of the last H propagated attitudes: `head` is the next slot written,
    /// `len` how many are held (a plain array: one store a step, no deque bookkeeping).
    history: [Sample; H],
    head: usize,
    len: usize,
    fixes: Deque<Fix, PENDING_FIXES>,
    aligned: bool,
    stats: ObserverStats,
    innov_ms_rad2: f64,
    sigma_st_rad: f64,
    steady: SteadyState,
    /// Time tag of the last frame that updated the observer, µs.
    last_update_tag_us: Option<u64>,
    /// Covariance of (attitude error, drift error) of each axis after the last update:
    /// P11 rad², P12 rad²/s, P22 rad²/s² (the gate's expected mismatch variance).
    cov: [[f64; 3]; 3],
    /// Whether the three axes' covariances and noise figures are equal (then one axis is
    /// propagated for all: the nominal four FOGs, and the orthogonal triad).
    isotropic: bool,
    /// The last 1σ of the attitude error (rad, x y z) and of the drift error (rad/s, x y
    /// z) reported ([`Observer::sigmas`]): the start of the next step's Newton step; 0
    /// none yet.
    sigma_roots: [f64; 6],
    /// N = (SᵀS)⁻¹ of the FOG combination flying ([`mekf::noise_of`]): one FOG's noise
    /// variance becomes σ² N on the body axes.
    noise: Matrix3<f64>,
    /// N_kk per axis (equal on every axis when they differ only by rounding).
    noise_axis: [f64; 3],
    /// ARW variance rate per axis, σ_v² N_kk, rad²/s.
    arw_axis_rad2_s: [f64; 3],
    /// Rate random walk variance rate per axis, σ_u² N_kk, rad²/s³.
    rrw_axis_rad2_s3: [f64; 3],
    /// The MEKF's P_bb at alignment, (rad/s)² ([`MekfCov::remove_share`]).
    mekf_pbb0: Matrix3<f64>,
    streak: Streak,
    /// The estimator that flies.
    estimator: Estimator,
    /// The MEKF's covariance after its last update (used only with [`Estimator::Mekf`]).
    mekf: MekfCov,
    /// The MEKF's last 1σ roots (attitude x y z, drift x y z), as `sigma_roots`.
    mekf_roots: [f64; 6],
    /// Each FOG's drift variance at alignment, (rad/s)² (the table's initial drift 1σ
    /// squared; σ_b² N on the body axes).
    initial_drift_var_rad2_s2: f64,
    /// Λ(t_s) after the last update (the MEKF's start of the body's turn to the next).
    last_q: Quaternion<f64>,
    /// Unit time of the alignment, µs.
    aligned_us: Option<u64>,
    /// The first stage of a two-stage observer ([`ObserverConfig::acquisition_s`]);
    /// `None`: one stage, `gains` throughout.
    acquisition: Option<Acquisition>,
}

/// The acquisition stage of a two-stage observer ("gear shift"): eq. (6) with the table's
/// override gains for `for_us` after alignment, then with the steady-state Kalman gains.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Acquisition {
    /// K_B, K_U of the acquisition (the table's `gains_override`).
    gains: ObserverGains,
    /// Its length t_acq after alignment, ms (u32: one conversion instruction from f64 on
    /// the M7, where u64 is a library call; 7200 s fit 600 times over).
    for_ms: u32,
}

impl Acquisition {
    /// The stage a table asks for: an override and t_acq > 0.
    #[inline(never)]
    fn of(cfg: &ObserverConfig) -> Option<Self> {
        let gains = cfg.gains_override?;
        // `validate` bounds t_acq to 0…7200 s; `as` saturates whatever else comes.
        let for_ms = (cfg.acquisition_s * 1e3) as u32;
        (for_ms > 0).then_some(Acquisition { gains, for_ms })
    }
}

/// Consecutive gated frames and their running sums (re-acquisition).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
struct Streak {
    n: u32,
    e: Vector3<f64>,
    ee: f64,
}

impl<const H: usize> Observer<H> {
    /// A new observer with `gains`, expecting star-tracker noise `sigma_st_rad` (1σ),
    /// gating with the noise figures of `steady`.
    pub fn new(gains: ObserverGains, sigma_st_rad: f64, steady: SteadyState) -> Self {
        Observer {
            gains,
            drift_rad_s: Vector3::zeros(),
            history: [Sample { time_us: 0, q: Quaternion::identity() }; H],
            head: 0,
            len: 0,
            fixes: Deque::new(),
            aligned: false,
            stats: ObserverStats::default(),
            innov_ms_rad2: 0.0,
            sigma_st_rad,
            steady,
            last_update_tag_us: None,
            cov: [[0.0; 3]; 3],
            isotropic: true,
            sigma_roots: [0.0; 6],
            noise: Matrix3::identity(),
            noise_axis: [1.0; 3],
            arw_axis_rad2_s: [steady.arw_var_rad2_s; 3],
            rrw_axis_rad2_s3: [steady.rrw_var_rad2_s3; 3],
            mekf_pbb0: Matrix3::zeros(),
            streak: Streak::default(),
            estimator: Estimator::Luenberger,
            mekf: MekfCov::aligned(0.0, 0.0, &Matrix3::zeros()),
            mekf_roots: [0.0; 6],
            initial_drift_var_rad2_s2: 0.0,
            last_q: Quaternion::identity(),
            aligned_us: None,
            acquisition: None,
        }
    }

    /// From the table: its override gains if present, else the steady-state gains.
    pub fn from_config(cfg: &ObserverConfig) -> Result<Self, GainError> {
        let steady = steady_state(cfg)?;
        let gains = cfg.gains_override.unwrap_or(steady.gains);
        let mut o = Self::new(gains, cfg.st_sigma_arcsec * ARCSEC_RAD, steady);
        o.estimator = cfg.estimator;
        o.initial_drift_var_rad2_s2 = initial_drift_var_rad2_s2(cfg);
        o.acquisition = Acquisition::of(cfg);
        Ok(o)
    }

    /// A new table's figures (a table switch): its gains, star-tracker noise and gate
    /// figures from the next update on; the drift estimate, the history, the alignment
    /// and the statistics stay. Nothing changes if the gains cannot be computed.
    pub fn retune(&mut self, cfg: &ObserverConfig) -> Result<(), GainError> {
        let steady = steady_state(cfg)?;
        self.gains = cfg.gains_override.unwrap_or(steady.gains);
        self.acquisition = Acquisition::of(cfg);
        self.sigma_st_rad = cfg.st_sigma_arcsec * ARCSEC_RAD;
        self.steady = steady;
        self.initial_drift_var_rad2_s2 = initial_drift_var_rad2_s2(cfg);
        if cfg.estimator != self.estimator {
            // The covariance carries over: per axis into the diagonals of the MEKF's
            // blocks, or the diagonals of the MEKF's into the observer's running one (both
            // as of the last update).
            match cfg.estimator {
                Estimator::Mekf => {
                    let [[a0, b0, c0], [a1, b1, c1], [a2, b2, c2]] = self.cov;
                    let d = |x: f64, y: f64, z: f64| Matrix3::from_diagonal(&Vector3::new(x, y, z));
                    self.mekf = MekfCov { paa: d(a0, a1, a2), pab: d(b0, b1, b2), pbb: d(c0, c1, c2) };
                }
                Estimator::Luenberger => {
                    let m = &self.mekf;
                    for (k, c) in self.cov.iter_mut().enumerate() {
                        let at = |x: &Matrix3<f64>| x.get((k, k)).copied().unwrap_or(0.0);
                        *c = [at(&m.paa), at(&m.pab), at(&m.pbb)];
                    }
                }
            }
            self.estimator = cfg.estimator;
        }
        self.set_noise(&self.noise.clone_owned());
        Ok(())
    }

    /// Flies on a FOG combination whose N = (SᵀS)⁻¹ is `noise` ([`mekf::noise_of`]) from
    /// now on: the gyros' noise figures per body axis, σ² N_kk for the observer's running
    /// covariance and σ² N for the MEKF's (the four nominal FOGs: 5/6 on each axis; after
    /// an isolation the triad's). What was propagated until now stays.
    pub fn set_noise(&mut self, noise: &Matrix3<f64>) {
        self.noise = *noise;
        let st = &self.steady;
        // Diagonals equal but for rounding (the nominal four FOGs: 5/6 each) are made
        // equal, so one axis stands for all ([`Observer::refresh_isotropic`]).
        let d = [noise.m11, noise.m22, noise.m33];
        let mean = (d[0] + d[1] + d[2]) / 3.0;
        let equal = d.iter().all(|x| (x - mean).abs() <= 1e-9 * mean.abs());
        for ((n, na), (v, u)) in d
            .iter()
            .zip(self.noise_axis.iter_mut())
            .zip(self.arw_axis_rad2_s.iter_mut().zip(self.rrw_axis_rad2_s3.iter_mut()))
        {
            let n = if equal { mean } else { *n };
            *na = n;
            *v = st.arw_var_rad2_s * n;
            *u = st.rrw_var_rad2_s3 * n;
        }
        self.refresh_isotropic();
    }

    /// Whether one axis stands for all three ([`Observer::sigmas`]): the same covariance
    /// and noise figures, bit for bit, on every axis.
    fn refresh_isotropic(&mut self) {
        let same = |[a, b, c]: &[f64; 3]| a.to_bits() == b.to_bits() && b.to_bits() == c.to_bits();
        let [c0, c1, c2] = &self.cov;
        let cov_same =
            c0.iter().zip(c1).zip(c2).all(|((a, b), c)| a.to_bits() == b.to_bits() && b.to_bits() == c.to_bits());
        self.isotropic = cov_same && same(&self.arw_axis_rad2_s) && same(&self.rrw_axis_rad2_s3);
    }

    /// The estimator that flies.
    pub fn estimator(&self) -> Estimator {
        self.estimator
    }

    /// Gains in use (of the stage the last update flew, with two stages).
    pub fn gains(&self) -> &ObserverGains {
        &self.gains
    }

    /// The gains of eq. (6) for an update with time tag `time_us`: with two stages the
    /// acquisition's until t_acq after alignment, the steady-state Kalman gains from then
    /// on (a restart aligns again, and acquires again).
    #[inline(never)]
    fn shift_gears(&mut self, time_us: u64) {
        if let (Some(acq), Some(t0)) = (self.acquisition, self.aligned_us) {
            let acquiring = time_us.saturating_sub(t0) < u64::from(acq.for_ms) * 1000;
            self.gains = if acquiring { acq.gains } else { self.steady.gains };
        }
    }

    /// Drift estimate Δω (ICS), rad/s.
    pub fn drift_rad_s(&self) -> Vector3<f64> {
        self.drift_rad_s
    }

    /// Whether the first star-tracker frame has aligned the attitude.
    pub fn aligned(&self) -> bool {
        self.aligned
    }

    /// Marks the attitude as aligned by other means (launch-vehicle pad alignment).
    pub fn set_aligned(&mut self) {
        self.aligned = true;
    }

    /// Converged: aligned, at least 40 updates, and the mean-square mismatch (per axis)
    /// within 3σ of the star tracker's.
    pub fn converged(&self) -> bool {
        self.aligned && self.stats.updates >= 40 && self.innov_ms_rad2 < 9.0 * self.sigma_st_rad * self.sigma_st_rad
    }

    /// Counters.
    pub fn stats(&self) -> ObserverStats {
        self.stats
    }

    /// Records the propagated attitude at the end of a step.
    pub fn record(&mut self, time_us: u64, q: Quaternion<f64>) {
        if let Some(slot) = self.history.get_mut(self.head) {
            *slot = Sample { time_us, q };
        }
        self.head = (self.head + 1) % H;
        self.len = (self.len + 1).min(H);
    }

    /// History entries from the newest back to the oldest: slots below `head` hold the
    /// newest (the last written at `head − 1`), those from `head` on the previous lap,
    /// valid only once the ring has filled (then `len` = H).
    fn newest_first(&self) -> impl Iterator<Item = &Sample> {
        let (recent, lap) = self.history.split_at_checked(self.head).unwrap_or((&[], &[]));
        recent.iter().rev().chain(lap.iter().rev()).take(self.len)
    }

    /// The oldest entry held.
    fn oldest(&self) -> Option<&Sample> {
        if self.len < H {
            if self.len == 0 {
                None
            } else {
                self.history.first()
            }
        } else {
            self.history.get(self.head)
        }
    }

    /// A history entry as corrected by every update so far (pending fixes in order).
    fn corrected(&self, s: &Sample) -> Quaternion<f64> {
        let mut q = s.q;
        for f in self.fixes.iter() {
            if f.covers(s.time_us) {
                q = f.apply(&q, s.time_us);
            }
        }
        q
    }

    /// Propagated attitude at `time_us`, interpolated between recorded steps.
    pub fn attitude_at(&self, time_us: u64) -> Result<Quaternion<f64>, UpdateError> {
        let (first, last) = match (self.oldest(), self.newest_first().next()) {
            (Some(f), Some(l)) => (f, l),
            _ => return Err(UpdateError::Stale),
        };
        if time_us < first.time_us {
            return Err(UpdateError::Stale);
        }
        if time_us > last.time_us {
            return Err(UpdateError::Future);
        }
        // From the newest entry back: a time tag lags the present by the star tracker's
        // latency, a few entries, so this is shorter than a scan from the oldest.
        let mut next = last;
        for s in self.newest_first() {
            if s.time_us <= time_us {
                let span = next.time_us.saturating_sub(s.time_us);
                if span == 0 {
                    return Ok(self.corrected(s));
                }
                // u32 µs (71 min) covers any span here; u32 → f64 is one instruction on
                // the M7, u64 → f64 a library call.
                let us = |d: u64| f64::from(u32::try_from(d).unwrap_or(u32::MAX));
                let frac = us(time_us - s.time_us) / us(span);
                return Ok(math::nlerp(&self.corrected(s), &self.corrected(next), frac));
            }
            next = s;
        }
        Err(UpdateError::Stale)
    }

    /// Each axis's covariance propagated from the last update to `time_us` ([`propagate`]).
    fn propagated(&self, time_us: u64) -> [[f64; 3]; 3] {
        let tau = self.since_update_s(time_us);
        let mut out = self.cov;
        if self.isotropic {
            let ([c0, ..], [sv2, ..], [su2, ..]) = (self.cov, self.arw_axis_rad2_s, self.rrw_axis_rad2_s3);
            return [propagate(&c0, tau, sv2, su2); 3];
        }
        for ((c, sv2), su2) in out.iter_mut().zip(self.arw_axis_rad2_s).zip(self.rrw_axis_rad2_s3) {
            *c = propagate(c, tau, sv2, su2);
        }
        out
    }

    /// Seconds from the last update's time tag to `time_us` (0 before any).
    #[inline(always)]
    fn since_update_s(&self, time_us: u64) -> f64 {
        let gap_us = self.last_update_tag_us.map_or(0, |t| time_us.saturating_sub(t));
        f64::from(u32::try_from(gap_us).unwrap_or(u32::MAX)) * 1e-6
    }

    /// The 1σ of the attitude error (rad) and of the drift error (rad/s) per axis at
    /// `time_us`: the square roots of P11 and P22 of the running covariance propagated to
    /// that time (the fixed gains in the Joseph form at each update, the gyros' random
    /// walks through the combination flying between: [`Observer::set_noise`]). One axis
    /// for all while they are equal ([`Observer::refresh_isotropic`]). Infinite before
    /// alignment: unknown.
    ///
    /// Each root is one Newton step x ← (x + P/x)/2 from the last step's (relative error
    /// ε²/2 for a start off by ε: below 2e-3 whenever P moved by less than 12.5 %, as it
    /// does from step to step and at an update), and a full square root otherwise.
    ///
    /// With the MEKF: the diagonals of its P_aa and P_bb, per axis ([`MekfCov::diagonals`]).
    pub fn sigmas(&mut self, time_us: u64) -> ([f64; 3], [f64; 3]) {
        if !self.aligned {
            self.sigma_roots = [0.0; 6];
            self.mekf_roots = [0.0; 6];
            return ([f64::INFINITY; 3], [f64::INFINITY; 3]);
        }
        if self.estimator == Estimator::Mekf {
            return self.mekf_sigmas(time_us);
        }
        if !self.isotropic {
            return self.axis_sigmas(time_us);
        }
        let tau = self.since_update_s(time_us);
        let [c, ..] = &self.cov;
        let ([sv2, ..], [su2, ..]) = (self.arw_axis_rad2_s, self.rrw_axis_rad2_s3);
        let [p11, _, p22] = propagate(c, tau, sv2, su2);
        let [a, _, _, d, _, _] = &mut self.sigma_roots;
        for (x, p) in [(a, p11), (d, p22)] {
            mekf::root(x, p);
        }
        let [a, _, _, d, _, _] = self.sigma_roots;
        ([a; 3], [d; 3])
    }

    /// [`Observer::sigmas`] of the observer axis by axis (out of line: after an isolation
    /// the combination's noise differs between axes).
    #[inline(never)]
    fn axis_sigmas(&mut self, time_us: u64) -> ([f64; 3], [f64; 3]) {
        let [c0, c1, c2] = self.propagated(time_us);
        let p = [c0[0], c1[0], c2[0], c0[2], c1[2], c2[2]];
        let mut out = [0.0; 6];
        for ((o, x), p) in out.iter_mut().zip(self.sigma_roots.iter_mut()).zip(p) {
            *o = mekf::root(x, p);
        }
        let [a0, a1, a2, d0, d1, d2] = out;
        ([a0, a1, a2], [d0, d1, d2])
    }

    /// [`Observer::sigmas`] of the MEKF (out of line: the observer's step stays as short
    /// as it was).
    #[inline(never)]
    fn mekf_sigmas(&mut self, time_us: u64) -> ([f64; 3], [f64; 3]) {
        let tau = self.since_update_s(time_us);
        let (pa, pb) = self.mekf.diagonals(tau, &self.arw_axis_rad2_s, &self.rrw_axis_rad2_s3);
        let mut out = [0.0; 6];
        for ((o, x), p) in out.iter_mut().zip(self.mekf_roots.iter_mut()).zip(pa.into_iter().chain(pb)) {
            *o = mekf::root(x, p);
        }
        let [a0, a1, a2, d0, d1, d2] = out;
        ([a0, a1, a2], [d0, d1, d2])
    }

    /// Expected variance of a mismatch per axis, rad², for a frame with time tag
    /// `time_us`: R + the attitude-error variance of the observer as it runs (its
    /// fixed gains in the Joseph form at each update, the gyros' random walks between),
    /// so an outage widens the gate as the attitude uncertainty grows and the return
    /// narrows it again only as fast as the observer really converges.
    ///
    /// With the MEKF: the mean per axis of its P_aa propagated to `time_us`, plus R; with
    /// the observer the mean of its axes' P11 when they differ.
    pub fn mismatch_var_rad2(&self, time_us: u64) -> f64 {
        if self.estimator == Estimator::Mekf {
            let tau = self.since_update_s(time_us);
            let (pa, _) = self.mekf.diagonals(tau, &self.arw_axis_rad2_s, &self.rrw_axis_rad2_s3);
            return pa.iter().sum::<f64>() / 3.0 + self.steady.r_rad2;
        }
        let [c0, c1, c2] = self.propagated(time_us);
        let p11 = if self.isotropic { c0[0] } else { (c0[0] + c1[0] + c2[0]) / 3.0 };
        p11 + self.steady.r_rad2
    }

    /// The covariance after an update at `time_us` with the gains in use, axis by axis
    /// (Joseph form of x⁺ = (I − K H) x⁻ + K v with K = (K_B, −K_U) and H = (1, 0): exact
    /// for the fixed-gain loop, whatever the gains).
    fn update_cov(&mut self, time_us: u64) {
        let r = self.steady.r_rad2;
        let prior = self.propagated(time_us);
        let gains_equal = |[a, b, c]: [f64; 3]| a.to_bits() == b.to_bits() && b.to_bits() == c.to_bits();
        let axes =
            if self.isotropic && gains_equal(self.gains.k_b) && gains_equal(self.gains.k_u_per_s) { 1 } else { 3 };
        for (((c, [p11, p12, p22]), k1), k_u) in
            self.cov.iter_mut().zip(prior).zip(self.gains.k_b).zip(self.gains.k_u_per_s).take(axes)
        {
            let k2 = -k_u;
            *c = [
                (1.0 - k1) * (1.0 - k1) * p11 + k1 * k1 * r,
                (1.0 - k1) * (p12 - k2 * p11) + k1 * k2 * r,
                p22 - 2.0 * k2 * p12 + k2 * k2 * (p11 + r),
            ];
        }
        if axes == 1 {
            let [c0, ..] = self.cov;
            self.cov = [c0; 3];
        } else {
            self.refresh_isotropic();
        }
    }

    /// Eq. (5) and the mismatch e = 2 vect(Λ(t_s)⁻¹ ∘ Λ*) for a frame, without using it.
    fn mismatch(
        &mut self,
        time_us: u64,
        q_st: &Quaternion<f64>,
        mount: &Quaternion<f64>,
    ) -> Result<(Quaternion<f64>, Quaternion<f64>), UpdateError> {
        let n2 = q_st.norm_squared();
        if !n2.is_finite() || (n2 - 1.0).abs() > 1e-5 {
            return Err(UpdateError::BadQuaternion);
        }
        let q_at = match self.attitude_at(time_us) {
            Ok(q) => q,
            Err(e) => {
                match e {
                    UpdateError::Stale => self.stats.stale = self.stats.stale.saturating_add(1),
                    UpdateError::Future => self.stats.future = self.stats.future.saturating_add(1),
                    _ => {}
                }
                return Err(e);
            }
        };
        // Eq. (5): Λ* = Λ ∘ δΨ_Λ  →  Λ_ICS = Λ* ∘ q_bs⁻¹.
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
        let (q_at, q_meas) = self.mismatch(time_us, q_st, mount)?;
        Ok(Mismatch {
            e_rad: math::rotvec_from_quat(&(q_at.conjugate() * q_meas)),
            var_rad2: self.mismatch_var_rad2(time_us),
        })
    }

    /// One star-tracker update: `q_st` is Λ* of the star-tracker frame, `mount` q_bs.
    /// Corrects `att` (whose present time is `now_us`) and the drift estimate.
    /// Returns the mismatch e (rad, ICS at t_s) that was used.
    ///
    /// Once converged, a frame whose normalised mismatch |e|²/σ² exceeds [`CHI2_GATE`]
    /// is refused (σ² from [`Observer::mismatch_var_rad2`]: 0.1 % of nominal frames);
    /// [`REACQUIRE_FRAMES`] refused in a row that agree with each other re-acquire:
    /// the frame is used and the gate stays open until the observer converges again.
    pub fn update(
        &mut self,
        att: &mut Attitude,
        now_us: u64,
        time_us: u64,
        q_st: &Quaternion<f64>,
        mount: &Quaternion<f64>,
    ) -> Result<Vector3<f64>, UpdateError> {
        let (q_at, q_meas) = self.mismatch(time_us, q_st, mount)?;
        if !self.aligned {
            // First frame: align. C ∘ Λ(t_s) = Λ*, applied to the present and the history.
            let c = q_meas * q_at.conjugate();
            self.apply(att, now_us, time_us, &c, &Vector3::zeros());
            self.aligned = true;
            self.aligned_us = Some(time_us);
            self.last_update_tag_us = Some(time_us);
            // Aligned to one frame; the drift is what is left of each FOG's turn-on bias
            // (the table's initial drift 1σ, σ_b), on the body axes σ_b² N: what the
            // error of either estimator really is at alignment, the drift estimate being 0.
            let (r, sb2) = (self.steady.r_rad2, self.initial_drift_var_rad2_s2);
            for (c, n) in self.cov.iter_mut().zip(self.noise_axis) {
                *c = [r, 0.0, sb2 * n];
            }
            self.refresh_isotropic();
            self.mekf = MekfCov::aligned(r, sb2, &self.noise);
            self.mekf_pbb0 = self.mekf.pbb;
            self.last_q = c * q_at;
            self.stats.updates = self.stats.updates.saturating_add(1);
            return Ok(Vector3::zeros());
        }
        let e = math::rotvec_from_quat(&(q_at.conjugate() * q_meas));
        if self.estimator == Estimator::Mekf {
            return self.update_mekf(att, now_us, time_us, &q_at, &e);
        }
        let e2 = e.norm_squared();
        if self.converged() {
            let var = self.mismatch_var_rad2(time_us);
            if e2 > CHI2_GATE * var {
                let Some(mean2) = self.streak_reacquires(&e, var) else { return Err(UpdateError::Gated) };
                // Re-acquire: the frames agree with each other, the attitude is off by
                // about their mean. The covariance is reset to that (per axis, twice the
                // mean square), so the gate stays open while the observer closes the gap.
                let prior = self.propagated(time_us);
                for (c, [_, _, p22]) in self.cov.iter_mut().zip(prior) {
                    *c = [2.0 * mean2 / 3.0, 0.0, p22];
                }
                self.last_update_tag_us = Some(time_us);
            }
        }
        self.streak = Streak::default();
        self.shift_gears(time_us);
        let k_b = Vector3::from(self.gains.k_b);
        let k_u = Vector3::from(self.gains.k_u_per_s);
        let corr = math::mul_elem(&k_b, &e);
        let d_drift = -math::mul_elem(&k_u, &e);
        // Body correction at t_s as an inertial left factor: Λ(t_s) ∘ q(corr) ∘ Λ(t_s)⁻¹.
        let c = q_at * math::quat_from_rotvec(&corr) * q_at.conjugate();
        self.apply(att, now_us, time_us, &c, &d_drift);
        self.drift_rad_s += d_drift;
        self.last_q = c * q_at;
        self.note_innovation(e2);
        self.update_cov(time_us);
        self.last_update_tag_us = Some(time_us);
        Ok(e)
    }

    /// The running mean square mismatch per axis (of |e|² = `e2`) and the update count.
    fn note_innovation(&mut self, e2: f64) {
        let e2 = e2 / 3.0;
        self.innov_ms_rad2 =
            if self.stats.updates <= 1 { e2 } else { self.innov_ms_rad2 + 0.05 * (e2 - self.innov_ms_rad2) };
        self.stats.updates = self.stats.updates.saturating_add(1);
    }

    /// A gated frame into the re-acquisition streak: `Some(mean²)` of the streak's
    /// mismatch when [`REACQUIRE_FRAMES`] in a row agree with each other within the gate
    /// (per-axis variance `var`), else `None` (the frame stays refused and is counted).
    fn streak_reacquires(&mut self, e: &Vector3<f64>, var: f64) -> Option<f64> {
        let s = &mut self.streak;
        s.n = s.n.saturating_add(1);
        s.e += e;
        s.ee += e.norm_squared();
        // Spread of the streak's mismatches about their mean, per frame.
        let n = f64::from(s.n);
        let spread = (s.ee - s.e.norm_squared() / n) / n;
        if s.n < REACQUIRE_FRAMES || spread > CHI2_GATE * var {
            self.stats.gated = self.stats.gated.saturating_add(1);
            return None;
        }
        self.stats.reacquired = self.stats.reacquired.saturating_add(1);
        Some(s.e.norm_squared() / (n * n))
    }

    /// The MEKF's update with mismatch `e` at Λ(t_s) = `q_at` ([`mekf`]): the covariance
    /// propagated over the body's turn since the last update, the χ²₃ gate eᵀ S⁻¹ e from
    /// it (always once aligned: the covariance, not a convergence test, says how large a
    /// mismatch may be), the Joseph update, and the corrections K_a e (attitude, body at
    /// t_s) and K_b e (drift), carried to the present and the history as the observer's.
    fn update_mekf(
        &mut self,
        att: &mut Attitude,
        now_us: u64,
        time_us: u64,
        q_at: &Quaternion<f64>,
        e: &Vector3<f64>,
    ) -> Result<Vector3<f64>, UpdateError> {
        let st = self.steady;
        let tau = self.since_update_s(time_us);
        let q_rel = self.last_q.conjugate() * q_at;
        let mut prior = self.mekf.propagated(&q_rel, tau, st.arw_var_rad2_s, st.rrw_var_rad2_s3, &self.noise);
        let mut s_inv = prior.innovation_inverse(st.r_rad2);
        let d2 = s_inv.map_or(f64::INFINITY, |s| mekf::normalised(e, &s));
        if d2 > CHI2_GATE {
            let var = prior.mean_attitude_var_rad2() + st.r_rad2;
            let Some(mean2) = self.streak_reacquires(e, var) else { return Err(UpdateError::Gated) };
            // Re-acquire: the attitude is off by about the streak's mean (per axis, twice
            // its mean square), uncorrelated with the drift.
            prior.paa = nalgebra::Matrix3::identity() * (2.0 * mean2 / 3.0);
            prior.pab = nalgebra::Matrix3::zeros();
            s_inv = prior.innovation_inverse(st.r_rad2);
        }
        let Some(s_inv) = s_inv else {
            self.stats.gated = self.stats.gated.saturating_add(1);
            return Err(UpdateError::Gated);
        };
        self.streak = Streak::default();
        let gain = prior.update(&s_inv, st.r_rad2);
        let corr = gain.ka * e;
        let d_drift = gain.kb * e;
        let c = q_at * math::quat_from_rotvec(&corr) * q_at.conjugate();
        self.apply(att, now_us, time_us, &c, &d_drift);
        self.drift_rad_s += d_drift;
        self.note_innovation(e.norm_squared());
        self.mekf = prior;
        self.last_q = c * q_at;
        self.last_update_tag_us = Some(time_us);
        Ok(*e)
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
        self.stats = ObserverStats::default();
        self.innov_ms_rad2 = 0.0;
        self.last_update_tag_us = None;
        self.cov = [[0.0; 3]; 3];
        self.refresh_isotropic();
        self.sigma_roots = [0.0; 6];
        self.mekf_roots = [0.0; 6];
        self.streak = Streak::default();
    }

    /// Takes out of the drift estimate what it has learned of a constant drift
    /// `share_rad_s` (ICS) present since alignment (an isolated gyro's share, as the
    /// parity baseline estimates it, with covariance `share_cov_rad2_s2`), at unit time
    /// `now_us`; each estimator by what its own gains have learned of it.
    ///
    /// - The fixed-gain loop learns a constant drift with its slow pole, K_U / K_B per
    ///   second (about 30 min at 4 Hz): 1 − exp(−t K_U / K_B) of it after t. Its running
    ///   covariance takes the share's uncertainty: P22_k ← P22_k + (Σ_s)_kk.
    /// - The MEKF: b̂ ← b̂ − (I − F) ŝ with F = P_bb P_bb(0)⁻¹ the fraction its own gains
    ///   have not learned, and P_bb widened by what is no longer known
    ///   ([`MekfCov::remove_share`], the derivation), so it relearns at its own rate.
    pub fn remove_drift_share(&mut self, now_us: u64, share_rad_s: &Vector3<f64>, share_cov_rad2_s2: &Matrix3<f64>) {
        let Some(t0) = self.aligned_us else { return };
        if self.estimator == Estimator::Mekf {
            self.drift_rad_s -= self.mekf.remove_share(share_rad_s, share_cov_rad2_s2, &self.mekf_pbb0);
            return;
        }
        let t_s = f64::from(u32::try_from(now_us.saturating_sub(t0) / 1000).unwrap_or(u32::MAX)) * 1e-3;
        for ((d, s), (k_u, k_b)) in self
            .drift_rad_s
            .iter_mut()
            .zip(share_rad_s.iter())
            .zip(self.gains.k_u_per_s.iter().zip(self.gains.k_b.iter()))
        {
            if *k_b > 0.0 {
                *d -= s * (1.0 - libm::exp(-t_s * k_u / k_b));
            }
        }
        for (k, c) in self.cov.iter_mut().enumerate() {
            if let Some(p22) = c.get_mut(2) {
                *p22 += share_cov_rad2_s2.get((k, k)).copied().unwrap_or(0.0);
            }
        }
        self.refresh_isotropic();
    }

    /// Removes a drift `drift_rad_s` (ICS) that entered the attitude from `since_us` on
    /// (an isolated gyro's fault): Λ(t) ← Λ(t) ∘ q(−drift · (t − since)) for the present
    /// attitude and, lazily, the history.
    pub fn remove_drift(&mut self, att: &mut Attitude, now_us: u64, since_us: u64, drift_rad_s: &Vector3<f64>) {
        self.apply(att, now_us, since_us, &Quaternion::identity(), drift_rad_s);
    }

    /// Left-multiplies by `c` every attitude at or after `t_s` (and the present one), and
    /// removes the drift change `d_drift` integrated from t_s to each of them: the present
    /// attitude now, the history through a pending [`Fix`].
    fn apply(&mut self, att: &mut Attitude, now_us: u64, t_s: u64, c: &Quaternion<f64>, d_drift: &Vector3<f64>) {
        let fix = Fix { from_us: t_s, to_us: now_us, c: *c, d_drift: *d_drift };
        // Fixes whose span has left the history cover nothing any more.
        let oldest = self.oldest().map_or(u64::MAX, |s| s.time_us);
        while self.fixes.front().is_some_and(|f| f.to_us < oldest) {
            let _ = self.fixes.pop_front();
        }
        if self.fixes.is_full() {
            if let Some(old) = self.fixes.pop_front() {
                // Each entry on its own, so slot order does not matter (rare: more
                // updates within the history than pending fixes).
                for s in self.history.iter_mut() {
                    if old.covers(s.time_us) {
                        s.q = old.apply(&s.q, s.time_us);
                    }
                }
            }
        }
        let _ = self.fixes.push_back(fix);
        att.set_quaternion(fix.apply(&att.quaternion(), now_us));
    }
}

/// One axis's covariance (P11, P12, P22) propagated over `tau_s` without an update:
/// F = [[1, −τ], [0, 1]], the gyros' random walks (`sv2`, `su2`: this axis's σ_v² N_kk and
/// σ_u² N_kk) as process noise.
#[inline(always)]
fn propagate(c: &[f64; 3], tau_s: f64, sv2: f64, su2: f64) -> [f64; 3] {
    let [p11, p12, p22] = *c;
    let tau = tau_s;
    [
        p11 - 2.0 * tau * p12 + tau * tau * p22 + sv2 * tau + su2 * tau * tau * tau / 3.0,
        p12 - tau * p22 - su2 * tau * tau / 2.0,
        p22 + su2 * tau,
    ]
}

/// Each FOG's drift variance at alignment of the table's initial drift 1σ, (rad/s)².
fn initial_drift_var_rad2_s2(cfg: &ObserverConfig) -> f64 {
    let s = cfg.initial_drift_sigma_deg_h * DEG_RAD / 3600.0;
    s * s
}
