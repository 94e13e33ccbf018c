//! The paper's Luenberger observer with extended state, eq. (6), with fixed gains:
//!
//! ```text
//! Λ̇  = ½ Λ ∘ (ω* + K_B · vect(ΔΛ) − Δω)
//! Δω̇ = −K_U · vect(ΔΛ),            ΔΛ = Λ⁻¹ ∘ Λ*
//! ```
//!
//! discretised per star-tracker frame: with the mismatch e = 2 vect(ΔΛ) at the frame's
//! time tag t_s, Λ(t_s) is corrected by the body rotation K_B ⊙ e and the drift by
//! Δω ← Δω − K_U ⊙ e (K_B dimensionless, K_U in 1/s, per update).
//!
//! Two stages ("gear shift", [`crate::calib::ObserverConfig::acquisition_s`]): a table may
//! fly its override gains for t_acq after alignment and the steady-state Kalman gains
//! ([`super::gains`]) from then on. The paper's gains "selected from a given performance"
//! (critically damped, τ = 60 s: K_B = 2T/τ, K_U = T/τ²) find an uncalibrated bias of tens
//! of °/h in minutes, where the steady-state gains' slow pole (K_U/K_B ≈ 1/(30 min)) takes
//! hours; but in steady state they hold the attitude error 21 % above the Kalman limit, so
//! after t_acq the steady-state gains take over. The switch changes gains only.
//!
//! The gate needs the variance of the mismatch: the observer keeps the covariance of
//! (attitude error, drift error) of each axis as it really runs (its fixed gains in the
//! Joseph form at each update, the gyros' random walks between), so an outage widens the
//! gate and the return narrows it only as fast as the observer converges. Its gate opens
//! only once [`super::gate::Convergence`] says the observer converged.

use crate::state::{Flag, Maybe};
use nalgebra::{Matrix3, Vector3};

use super::gains::Figures;
use super::gate::{self, Streak};
use super::{mekf, Correction, UpdateAt, UpdateError};
use crate::calib::{ObserverConfig, ObserverGains};

/// The acquisition stage of a two-stage observer: eq. (6) with the table's override gains
/// for `for_ms` after alignment, then with the steady-state Kalman gains.
#[derive(Debug, Clone, Copy, PartialEq, bytemuck::AnyBitPattern)]
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

/// The fixed-gain observer of eq. (6): its gains and its running covariance.
#[derive(Debug, Clone, Copy, PartialEq, bytemuck::AnyBitPattern)]
pub struct Luenberger {
    gains: ObserverGains,
    /// The first stage of a two-stage observer; `None`: one stage, `gains` throughout.
    acquisition: Maybe<Acquisition>,
    /// Covariance of (attitude error, drift error) of each axis after the last update:
    /// P11 rad², P12 rad²/s, P22 rad²/s² (the gate's expected mismatch variance).
    cov: [[f64; 3]; 3],
    /// Whether the three axes' covariances and noise figures are equal (then one axis is
    /// propagated for all: the nominal four FOGs, and the orthogonal triad).
    isotropic: Flag,
    /// The last 1σ of the attitude error (rad, x y z) and of the drift error (rad/s, x y
    /// z) reported ([`Luenberger::sigmas`]): the start of the next Newton step; 0 none.
    roots: [f64; 6],
}

impl Luenberger {
    /// An observer with `gains` throughout.
    pub fn new(gains: ObserverGains) -> Self {
        Luenberger { gains, acquisition: Maybe::none(), cov: [[0.0; 3]; 3], isotropic: Flag::SET, roots: [0.0; 6] }
    }

    /// From the table: its override gains if present, else the steady-state `steady`
    /// gains; two stages if it asks for them.
    pub fn from_config(cfg: &ObserverConfig, steady: &ObserverGains) -> Self {
        let mut o = Self::new(cfg.gains_override.unwrap_or(*steady));
        o.acquisition = Acquisition::of(cfg).into();
        o
    }

    /// A new table's gains; the covariance stays.
    pub fn retune(&mut self, cfg: &ObserverConfig, steady: &ObserverGains) {
        self.gains = cfg.gains_override.unwrap_or(*steady);
        self.acquisition = Acquisition::of(cfg).into();
    }

    /// Taking over from another estimator: its per-axis (P11, P12, P22) as of its last
    /// update.
    pub fn with_cov(mut self, cov: [[f64; 3]; 3], fig: &Figures) -> Self {
        self.cov = cov;
        self.refresh_isotropic(fig);
        self
    }

    /// Per-axis (P11, P12, P22) as of the last update.
    pub fn cov(&self) -> [[f64; 3]; 3] {
        self.cov
    }

    /// Gains in use (of the stage the last update flew, with two stages).
    pub fn gains(&self) -> &ObserverGains {
        &self.gains
    }

    /// At alignment on one frame: the attitude known to R, each axis's drift to its
    /// share σ_b² N_kk of the FOGs' turn-on bias (`sb2`), uncorrelated.
    pub fn align(&mut self, fig: &Figures, sb2: f64) {
        let r = fig.steady.r_rad2;
        for (c, n) in self.cov.iter_mut().zip(fig.noise_axis) {
            *c = [r, 0.0, sb2 * n];
        }
        self.refresh_isotropic(fig);
    }

    /// A re-alignment, the drift estimate kept: each axis's attitude known to
    /// `att_var_rad2`, uncorrelated with its drift, whose variance stays.
    pub fn realign(&mut self, fig: &Figures, att_var_rad2: f64) {
        for c in self.cov.iter_mut() {
            *c = [att_var_rad2, 0.0, c[2]];
        }
        self.refresh_isotropic(fig);
    }

    /// Starts again from nothing (a new alignment follows).
    pub fn restart(&mut self, fig: &Figures) {
        self.cov = [[0.0; 3]; 3];
        self.refresh_isotropic(fig);
        self.roots = [0.0; 6];
    }

    /// Its covariance and the gains in use, for the state guard ([`crate::shadow`]); the
    /// 1σ roots are only a Newton step's start.
    pub fn visit<V: crate::shadow::Visit>(&mut self, v: &mut V) {
        for c in self.cov.iter_mut() {
            v.f64s(c);
        }
        v.f64s(&mut self.gains.k_b);
        v.f64s(&mut self.gains.k_u_per_s);
    }

    /// The acquisition stage's gains and length (only a new table changes them), for the
    /// state guard ([`crate::shadow`]).
    pub fn visit_tuning<V: crate::shadow::Visit>(&mut self, v: &mut V) {
        if let Some(a) = self.acquisition.as_mut() {
            v.f64s(&mut a.gains.k_b);
            v.f64s(&mut a.gains.k_u_per_s);
            v.u32(&mut a.for_ms);
        }
    }

    /// Forgets the last 1σ roots (unaligned).
    #[inline]
    pub fn forget_roots(&mut self) {
        self.roots = [0.0; 6];
    }

    /// Whether one axis stands for all three: the same covariance and noise figures, bit
    /// for bit, on every axis.
    pub fn refresh_isotropic(&mut self, fig: &Figures) {
        let same = |[a, b, c]: &[f64; 3]| a.to_bits() == b.to_bits() && b.to_bits() == c.to_bits();
        let [c0, c1, c2] = &self.cov;
        let cov_same =
            c0.iter().zip(c1).zip(c2).all(|((a, b), c)| a.to_bits() == b.to_bits() && b.to_bits() == c.to_bits());
        self.isotropic = Flag::new(cov_same && same(&fig.arw_axis_rad2_s) && same(&fig.rrw_axis_rad2_s3));
    }

    /// The gains of eq. (6) for an update at `time_us`: with two stages the acquisition's
    /// until t_acq after alignment (`aligned_us`), the steady-state gains from then on.
    #[inline(never)]
    fn shift_gears(&mut self, time_us: u64, aligned_us: Option<u64>, steady: &ObserverGains) {
        if let (Some(acq), Some(t0)) = (self.acquisition.get(), aligned_us) {
            let acquiring = time_us.saturating_sub(t0) < u64::from(acq.for_ms) * 1000;
            self.gains = if acquiring { acq.gains } else { *steady };
        }
    }

    /// Each axis's covariance propagated over `tau_s` since the last update.
    fn propagated(&self, fig: &Figures, tau_s: f64) -> [[f64; 3]; 3] {
        let mut out = self.cov;
        if self.isotropic.get() {
            let ([c0, ..], [sv2, ..], [su2, ..]) = (self.cov, fig.arw_axis_rad2_s, fig.rrw_axis_rad2_s3);
            return [propagate(&c0, tau_s, sv2, su2); 3];
        }
        for ((c, sv2), su2) in out.iter_mut().zip(fig.arw_axis_rad2_s).zip(fig.rrw_axis_rad2_s3) {
            *c = propagate(c, tau_s, sv2, su2);
        }
        out
    }

    /// The update for a frame `at` with mismatch e: the gate once the observer converged
    /// (re-acquisition through `streak`), the gains of the stage, the correction
    /// K_B ⊙ e, −K_U ⊙ e, and the covariance after it.
    pub fn update(&mut self, fig: &Figures, at: &UpdateAt, streak: &mut Streak) -> Result<Correction, UpdateError> {
        let (e, time_us, aligned_us, mut tau_s) = (at.e_rad, at.time_us, at.aligned_us, at.tau_s);
        let mut reacquired = false;
        if at.converged {
            let var = self.mismatch_var_rad2(fig, tau_s);
            if gate::outside(e.norm_squared(), var) {
                let Some(mean2) = streak.reacquires(e, var) else { return Err(UpdateError::Gated) };
                // Re-acquire: the frames agree with each other, the attitude is off by
                // about their mean. The covariance is reset to that (per axis, twice the
                // mean square), so the gate stays open while the observer closes the gap.
                let prior = self.propagated(fig, tau_s);
                for (c, [_, _, p22]) in self.cov.iter_mut().zip(prior) {
                    *c = [2.0 * mean2 / 3.0, 0.0, p22];
                }
                // The covariance now holds at t_s.
                tau_s = 0.0;
                reacquired = true;
            }
        }
        streak.end();
        self.shift_gears(time_us, aligned_us, &fig.steady.gains);
        self.update_cov(fig, tau_s);
        let k_b = Vector3::from(self.gains.k_b);
        let k_u = Vector3::from(self.gains.k_u_per_s);
        Ok(Correction {
            body_rad: crate::math::mul_elem(&k_b, e),
            d_drift_rad_s: -crate::math::mul_elem(&k_u, e),
            reacquired,
        })
    }

    /// The covariance after an update `tau_s` after the last with the gains in use, axis
    /// by axis (Joseph form of x⁺ = (I − K H) x⁻ + K v with K = (K_B, −K_U) and
    /// H = (1, 0): exact for the fixed-gain loop, whatever the gains).
    fn update_cov(&mut self, fig: &Figures, tau_s: f64) {
        let r = fig.steady.r_rad2;
        let prior = self.propagated(fig, tau_s);
        let gains_equal = |[a, b, c]: [f64; 3]| a.to_bits() == b.to_bits() && b.to_bits() == c.to_bits();
        let axes = if self.isotropic.get() && gains_equal(self.gains.k_b) && gains_equal(self.gains.k_u_per_s) {
            1
        } else {
            3
        };
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
            self.refresh_isotropic(fig);
        }
    }

    /// Expected variance of a mismatch per axis `tau_s` after the last update, rad²: R +
    /// the attitude-error variance (the mean of the axes' P11 when they differ).
    pub fn mismatch_var_rad2(&self, fig: &Figures, tau_s: f64) -> f64 {
        let [c0, c1, c2] = self.propagated(fig, tau_s);
        let p11 = if self.isotropic.get() { c0[0] } else { (c0[0] + c1[0] + c2[0]) / 3.0 };
        p11 + fig.steady.r_rad2
    }

    /// The 1σ of the attitude error (rad) and of the drift error (rad/s) per axis
    /// `tau_s` after the last update: the roots of P11 and P22 propagated there, one axis
    /// for all while they are equal; each root one Newton step from the last
    /// ([`mekf::root`]).
    pub fn sigmas(&mut self, fig: &Figures, tau_s: f64) -> ([f64; 3], [f64; 3]) {
        if !self.isotropic.get() {
            return self.axis_sigmas(fig, tau_s);
        }
        let [c, ..] = &self.cov;
        let ([sv2, ..], [su2, ..]) = (fig.arw_axis_rad2_s, fig.rrw_axis_rad2_s3);
        let [p11, _, p22] = propagate(c, tau_s, sv2, su2);
        let [a, _, _, d, _, _] = &mut self.roots;
        for (x, p) in [(a, p11), (d, p22)] {
            mekf::root(x, p);
        }
        let [a, _, _, d, _, _] = self.roots;
        ([a; 3], [d; 3])
    }

    /// [`Luenberger::sigmas`] axis by axis (out of line: after an isolation the
    /// combination's noise differs between axes).
    #[inline(never)]
    fn axis_sigmas(&mut self, fig: &Figures, tau_s: f64) -> ([f64; 3], [f64; 3]) {
        let [c0, c1, c2] = self.propagated(fig, tau_s);
        let p = [c0[0], c1[0], c2[0], c0[2], c1[2], c2[2]];
        let mut out = [0.0; 6];
        for ((o, x), p) in out.iter_mut().zip(self.roots.iter_mut()).zip(p) {
            *o = mekf::root(x, p);
        }
        let [a0, a1, a2, d0, d1, d2] = out;
        ([a0, a1, a2], [d0, d1, d2])
    }

    /// Takes out of `drift_rad_s` what the loop has learned of a constant drift
    /// `share_rad_s` present since alignment (`aligned_us`; now `now_us`): its slow pole
    /// K_U / K_B per second learns 1 − exp(−t K_U / K_B) of it after t. The running
    /// covariance takes the share's uncertainty: P22_k ← P22_k + (Σ_s)_kk.
    pub fn remove_share(
        &mut self,
        fig: &Figures,
        (now_us, aligned_us): (u64, u64),
        drift_rad_s: &mut Vector3<f64>,
        (share_rad_s, share_cov_rad2_s2): (&Vector3<f64>, &Matrix3<f64>),
    ) {
        let since_s = f64::from(u32::try_from(now_us.saturating_sub(aligned_us) / 1000).unwrap_or(u32::MAX)) * 1e-3;
        for ((d, s), (k_u, k_b)) in
            drift_rad_s.iter_mut().zip(share_rad_s.iter()).zip(self.gains.k_u_per_s.iter().zip(self.gains.k_b.iter()))
        {
            if *k_b > 0.0 {
                *d -= s * (1.0 - libm::exp(-since_s * k_u / k_b));
            }
        }
        for (k, c) in self.cov.iter_mut().enumerate() {
            if let Some(p22) = c.get_mut(2) {
                *p22 += share_cov_rad2_s2.get((k, k)).copied().unwrap_or(0.0);
            }
        }
        self.refresh_isotropic(fig);
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
