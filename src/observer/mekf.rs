//! The multiplicative extended Kalman filter (MEKF), the optional estimator beside the
//! paper's eq. (6) observer ([`crate::calib::Estimator::Mekf`]): the same attitude
//! history, alignment of the time tag, lazy fix and re-acquisition ([`super`]), with the
//! gains, the gate and the 1σ from its own 6-state covariance ([`Mekf`]).
//!
//! States, body frame (ICS) at the time of the last update:
//!
//! ```text
//! x = (δθ, δb),   Λ = Λ̂ ∘ q(δθ),   Δω = Δω̂ + δb
//! δθ̇ = −[ω̂×] δθ − δb − n_v,   δḃ = n_u
//! ```
//!
//! with Λ the attitude of eq. (6), Δω the gyro drift, n_v the angle random walk (σ_v²,
//! rad²/s) and n_u the rate random walk (σ_u², rad²/s³). The measurement is the
//! mismatch of eq. (6), e = 2 vect(Λ̂⁻¹ ∘ Λ*) = δθ + v, v ~ N(0, R I): H = [I 0].
//!
//! The attitude itself is propagated every step on the gyros, as for the observer; the
//! covariance is propagated only to each frame's time tag t_s, over the whole interval
//! τ since the last update at once:
//!
//! ```text
//! Φ = [[A, −B], [0, I]],   A = C(Λ̂(t_l)⁻¹ ∘ Λ̂(t_s))ᵀ,   B = τ (A + I) / 2
//! Q = [[(σ_v² τ + σ_u² τ³/3) N, −σ_u² τ²/2 N], [−σ_u² τ²/2 N, σ_u² τ N]]
//! ```
//!
//! σ_v, σ_u are one FOG's (the table's figures); the body increment is the least-squares
//! combination Δθ = S⁺ m of the FOGs flying ([`crate::combination`]), so independent
//! noise of σ² on each FOG is σ² N on the body axes with N = S⁺ S⁺ᵀ = (SᵀS)⁻¹: 5/6 on
//! each axis (−1/6 between axes) for the four nominal FOGs, I for the orthogonal triad,
//! diag(5, 1, 1) for the triad without FOG1 ([`noise_of`]). Likewise each FOG's turn-on
//! bias: P_bb = σ_b² N at alignment. (Q takes N unrotated over τ: exact for the isotropic
//! part, and the anisotropic part turns by at most ωτ, 0.017 rad in a 4 Hz interval.)
//!
//! (A maps an error in the body at t_l to the body at t_s; B is the trapezoid of
//! ∫A(t) dt, exact for a constant rate to O((ωτ)²), below 1e-5 relative for 1 °/s over
//! 0.25 s). The update is the Joseph form with the full 3 × 3 innovation covariance
//! S = P_aa + R I, and the χ² gate is eᵀ S⁻¹ e. Stored as three 3 × 3 blocks
//! P_aa, P_ab, P_bb (P_ba = P_abᵀ), 216 bytes.
//!
//! # The star tracker's low-frequency error (9 states)
//!
//! When the table gives the tracker a low-frequency error (LFE: `observer.st_lfe_sigma_arcsec`
//! σ_c per tracker axis, correlated over `observer.st_lfe_tau_s` τ_c), the filter carries
//! it as three more states, a first-order Gauss–Markov process per axis:
//!
//! ```text
//! x = (δθ, δb, c),   ċ = −c / τ_c + n_c,   n_c ~ 2 σ_c² / τ_c
//! Λ* = Λ ∘ q_bs ∘ q(c_st + v)   ⇒   e = δθ + c + v,   H = [I 0 I],   c = C(q_bs) c_st
//! ```
//!
//! The LFE is an error of the tracker's solution, in the tracker's frame (c_st); taken
//! back through the mount it is c = C(q_bs) c_st in the body, fixed to it (the tracker is),
//! with the same isotropic statistics σ_c² I, so the filter carries it in the body frame
//! and it does not turn with A. Over τ since the last update, with φ = e^(−τ/τ_c):
//!
//! ```text
//! P_ac ← (A P_ac − B P_bc) φ,   P_bc ← P_bc φ,   P_cc ← φ² P_cc + σ_c² (1 − φ²) I,   ĉ ← φ ĉ
//! ```
//!
//! (the exact discrete form of the process noise 2σ_c²/τ_c). The innovation is
//! ν = e − ĉ with S = P_aa + P_ac + P_ca + P_cc + R I; with U = P Hᵀ by blocks
//! (U_a = P_aa + P_ac, U_b = P_ba + P_bc, U_c = P_ca + P_cc) the gain is K_x = U_x S⁻¹ and
//! the update P_xy ← P_xy − K_x U_yᵀ (diagonal blocks symmetrised); the LFE estimate keeps
//! ĉ ← ĉ + K_c ν while the attitude and drift take K_a ν and K_b ν as before. At
//! alignment on one frame the attitude takes the frame's LFE too: P_aa = (R + σ_c²) I,
//! P_ac = −σ_c² I, P_cc = σ_c² I. The six LFE blocks ([`Lfe`]) are 9 × 3 × 3 + 3 more
//! numbers; without an LFE in the table they stay zero and the update is the 6-state code
//! above, unchanged.

use nalgebra::{Matrix3, Quaternion, Vector3};

use super::gains::{Figures, SteadyState};
use super::gate::{Streak, CHI2_GATE};
use super::{Correction, UpdateAt, UpdateError};
use crate::math;

/// The MEKF: its covariance after the last update and its last 1σ roots.
#[derive(Debug, Clone, Copy, PartialEq, bytemuck::AnyBitPattern)]
pub struct Mekf {
    cov: MekfCov,
    /// The last 1σ roots (attitude x y z, drift x y z): the start of the next Newton
    /// step ([`root`]); 0 none.
    roots: [f64; 6],
    /// The star tracker's LFE states (module doc); zero without an LFE in the table.
    lfe: Lfe,
}

/// The MEKF's LFE states after its last update: the estimate ĉ (body frame) and the
/// blocks of the 9 × 9 covariance that involve it.
#[derive(Debug, Clone, Copy, PartialEq, bytemuck::AnyBitPattern)]
pub struct Lfe {
    /// Attitude error × LFE, rad².
    pub pac: Matrix3<f64>,
    /// Bias error × LFE, rad²/s.
    pub pbc: Matrix3<f64>,
    /// LFE, rad².
    pub pcc: Matrix3<f64>,
    /// The LFE estimate ĉ, body frame, rad.
    pub c_rad: Vector3<f64>,
}

impl Lfe {
    /// No LFE (a white tracker).
    pub const NONE: Lfe = Lfe { pac: ZERO3, pbc: ZERO3, pcc: ZERO3, c_rad: Vector3::new(0.0, 0.0, 0.0) };

    /// Unknown: its stationary covariance σ_c² I, uncorrelated with the rest, ĉ = 0.
    fn unknown(var_rad2: f64) -> Lfe {
        Lfe { pcc: Matrix3::identity() * var_rad2, ..Lfe::NONE }
    }

    /// Propagated over `tau_s` (module doc), `a` and `b` the attitude error's Φ blocks.
    fn propagated(&self, a: &Matrix3<f64>, b: &Matrix3<f64>, tau_s: f64, st: &SteadyState) -> Lfe {
        let phi = libm::exp(-tau_s / st.lfe_tau_s);
        Lfe {
            pac: (mul(a, &self.pac) - mul(b, &self.pbc)) * phi,
            pbc: self.pbc * phi,
            pcc: self.pcc * (phi * phi) + Matrix3::identity() * (st.lfe_var_rad2 * (1.0 - phi * phi)),
            c_rad: self.c_rad * phi,
        }
    }
}

const ZERO3: Matrix3<f64> = Matrix3::new(0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0);

impl Mekf {
    /// Before alignment (the covariance is set by [`Mekf::align`]).
    pub fn new() -> Self {
        Mekf { cov: MekfCov::aligned(0.0, 0.0, &Matrix3::zeros()), roots: [0.0; 6], lfe: Lfe::NONE }
    }

    /// With covariance `cov` (a reset resumed); the 1σ roots start over.
    pub fn with_cov(cov: MekfCov) -> Self {
        Mekf { cov, roots: [0.0; 6], lfe: Lfe::NONE }
    }

    /// Taking over from the fixed-gain observer: its per-axis (P11, P12, P22) as of its
    /// last update into the diagonals of the blocks.
    pub fn with_axes(cov: [[f64; 3]; 3]) -> Self {
        let [[a0, b0, c0], [a1, b1, c1], [a2, b2, c2]] = cov;
        let d = |x: f64, y: f64, z: f64| Matrix3::from_diagonal(&Vector3::new(x, y, z));
        Mekf {
            cov: MekfCov { paa: d(a0, a1, a2), pab: d(b0, b1, b2), pbb: d(c0, c1, c2) },
            roots: [0.0; 6],
            lfe: Lfe::NONE,
        }
    }

    /// The diagonals of the blocks as per-axis (P11, P12, P22), as of the last update.
    pub fn axes(&self) -> [[f64; 3]; 3] {
        let m = &self.cov;
        let at = |x: &Matrix3<f64>, k: usize| x.get((k, k)).copied().unwrap_or(0.0);
        [0, 1, 2].map(|k| [at(&m.paa, k), at(&m.pab, k), at(&m.pbb, k)])
    }

    /// Its covariance, for the state guard ([`crate::shadow`]); the 1σ roots are only a
    /// Newton step's start.
    pub fn visit<V: crate::shadow::Visit>(&mut self, v: &mut V) {
        v.f64s(self.cov.paa.as_mut_slice());
        v.f64s(self.cov.pab.as_mut_slice());
        v.f64s(self.cov.pbb.as_mut_slice());
        v.f64s(self.lfe.pac.as_mut_slice());
        v.f64s(self.lfe.pbc.as_mut_slice());
        v.f64s(self.lfe.pcc.as_mut_slice());
        v.f64s(self.lfe.c_rad.as_mut_slice());
    }

    /// The covariance after the last update.
    pub fn cov(&self) -> &MekfCov {
        &self.cov
    }

    /// The LFE states after the last update (zero without an LFE in the table).
    pub fn lfe(&self) -> &Lfe {
        &self.lfe
    }

    /// At alignment on one frame ([`MekfCov::aligned`]; `sb2` each FOG's turn-on bias
    /// variance); with an LFE, the frame's LFE in the attitude (module doc).
    pub fn align(&mut self, fig: &Figures, sb2: f64) {
        self.cov = MekfCov::aligned(fig.steady.r_rad2, sb2, &fig.noise);
        self.lfe = Lfe::NONE;
        if fig.steady.lfe() {
            let v = fig.steady.lfe_var_rad2;
            self.cov.paa += Matrix3::identity() * v;
            self.lfe = Lfe { pac: Matrix3::identity() * -v, ..Lfe::unknown(v) };
        }
    }

    /// A new table (`fig`): an LFE it adds starts unknown (its stationary covariance), one
    /// it removes is dropped, one it keeps stays.
    pub fn retune(&mut self, fig: &Figures) {
        if !fig.steady.lfe() {
            self.lfe = Lfe::NONE;
        } else if self.lfe == Lfe::NONE {
            self.lfe = Lfe::unknown(fig.steady.lfe_var_rad2);
        }
    }

    /// A re-alignment, the drift estimate kept: the attitude known to `att_var_rad2` per
    /// axis, uncorrelated with the bias, whose covariance stays.
    pub fn realign(&mut self, att_var_rad2: f64) {
        self.cov.paa = Matrix3::identity() * att_var_rad2;
        self.cov.pab = Matrix3::zeros();
    }

    /// Forgets the last 1σ roots (unaligned, or a restart).
    #[inline]
    pub fn forget_roots(&mut self) {
        self.roots = [0.0; 6];
    }

    /// The update for a frame `at` with mismatch e (module doc): the covariance
    /// propagated over the body's turn since the last update, the χ²₃ gate eᵀ S⁻¹ e
    /// (always once aligned: the covariance, not a convergence test, says how large a
    /// mismatch may be; re-acquisition through `streak`), the Joseph update, and the
    /// corrections K_a e (attitude, body at t_s) and K_b e (drift).
    pub fn update(&mut self, fig: &Figures, at: &UpdateAt, streak: &mut Streak) -> Result<Correction, UpdateError> {
        if fig.steady.lfe() {
            return self.update_lfe(fig, at, streak);
        }
        let (st, e) = (&fig.steady, at.e_rad);
        let q_rel = at.last_q.conjugate() * at.q_at;
        let mut prior = self.cov.propagated(&q_rel, at.tau_s, st.arw_var_rad2_s, st.rrw_var_rad2_s3, &fig.noise);
        let mut s_inv = prior.innovation_inverse(st.r_rad2);
        let d2 = s_inv.map_or(f64::INFINITY, |s| normalised(e, &s));
        let mut reacquired = false;
        if d2 > CHI2_GATE {
            let var = prior.mean_attitude_var_rad2() + st.r_rad2;
            let Some(mean2) = streak.reacquires(e, var) else { return Err(UpdateError::Gated) };
            // Re-acquire: the attitude is off by about the streak's mean (per axis, twice
            // its mean square), uncorrelated with the drift.
            prior.paa = Matrix3::identity() * (2.0 * mean2 / 3.0);
            prior.pab = Matrix3::zeros();
            s_inv = prior.innovation_inverse(st.r_rad2);
            reacquired = true;
        }
        let Some(s_inv) = s_inv else { return Err(UpdateError::Gated) };
        streak.end();
        let gain = prior.update(&s_inv, st.r_rad2);
        self.cov = prior;
        Ok(Correction { body_rad: gain.ka * e, d_drift_rad_s: gain.kb * e, reacquired })
    }

    /// [`Mekf::update`] with the LFE states (module doc): the same gate, re-acquisition
    /// and correction on the innovation ν = e − ĉ.
    #[inline(never)]
    fn update_lfe(&mut self, fig: &Figures, at: &UpdateAt, streak: &mut Streak) -> Result<Correction, UpdateError> {
        let st = &fig.steady;
        let q_rel = at.last_q.conjugate() * at.q_at;
        let a = dcm(&q_rel).transpose();
        let b = (a + Matrix3::identity()) * (0.5 * at.tau_s);
        let mut prior = self.cov.propagated(&q_rel, at.tau_s, st.arw_var_rad2_s, st.rrw_var_rad2_s3, &fig.noise);
        let mut lfe = self.lfe.propagated(&a, &b, at.tau_s, st);
        let nu = at.e_rad - lfe.c_rad;
        let s_of = |p: &MekfCov, l: &Lfe| sym(&(p.paa + l.pac + l.pac.transpose() + l.pcc));
        let mut s_inv = inverse_plus_r(&s_of(&prior, &lfe), st.r_rad2);
        let d2 = s_inv.map_or(f64::INFINITY, |s| normalised(&nu, &s));
        let mut reacquired = false;
        if d2 > CHI2_GATE {
            let var = s_of(&prior, &lfe).trace() / 3.0 + st.r_rad2;
            let Some(mean2) = streak.reacquires(&nu, var) else { return Err(UpdateError::Gated) };
            // Re-acquire as the 6-state filter does; the LFE keeps what it knew.
            prior.paa = Matrix3::identity() * (2.0 * mean2 / 3.0);
            prior.pab = Matrix3::zeros();
            lfe.pac = Matrix3::zeros();
            s_inv = inverse_plus_r(&s_of(&prior, &lfe), st.r_rad2);
            reacquired = true;
        }
        let Some(s_inv) = s_inv else { return Err(UpdateError::Gated) };
        streak.end();
        // U = P Hᵀ by blocks, K = U S⁻¹, P ← P − K Uᵀ.
        let ua = prior.paa + lfe.pac;
        let ub = prior.pab.transpose() + lfe.pbc;
        let uc = lfe.pac.transpose() + lfe.pcc;
        let (ka, kb, kc) = (mul(&ua, &s_inv), mul(&ub, &s_inv), mul(&uc, &s_inv));
        self.cov = MekfCov {
            paa: sym(&(prior.paa - mul_t(&ka, &ua))),
            pab: prior.pab - mul_t(&ka, &ub),
            pbb: sym(&(prior.pbb - mul_t(&kb, &ub))),
        };
        self.lfe = Lfe {
            pac: lfe.pac - mul_t(&ka, &uc),
            pbc: lfe.pbc - mul_t(&kb, &uc),
            pcc: sym(&(lfe.pcc - mul_t(&kc, &uc))),
            c_rad: lfe.c_rad + kc * nu,
        };
        Ok(Correction { body_rad: ka * nu, d_drift_rad_s: kb * nu, reacquired })
    }

    /// Expected variance of a mismatch per axis `tau_s` after the last update, rad²: the
    /// mean per axis of P_aa propagated there, plus R, plus the LFE's σ_c² when the table
    /// has one (the mismatch e carries the whole LFE, not only its unestimated part).
    pub fn mismatch_var_rad2(&self, fig: &Figures, tau_s: f64) -> f64 {
        let (pa, _) = self.cov.diagonals(tau_s, &fig.arw_axis_rad2_s, &fig.rrw_axis_rad2_s3);
        pa.iter().sum::<f64>() / 3.0 + fig.steady.r_rad2 + fig.steady.lfe_var_rad2
    }

    /// The 1σ of the attitude error (rad) and of the drift error (rad/s) per axis `tau_s`
    /// after the last update: the roots of the diagonals of P_aa and P_bb
    /// ([`MekfCov::diagonals`]). Out of line: the observer's step stays as short as it was.
    #[inline(never)]
    pub fn sigmas(&mut self, fig: &Figures, tau_s: f64) -> ([f64; 3], [f64; 3]) {
        let ([pa0, pa1, pa2], [pb0, pb1, pb2]) = self.cov.diagonals(tau_s, &fig.arw_axis_rad2_s, &fig.rrw_axis_rad2_s3);
        let [a0, a1, a2, d0, d1, d2] = &mut self.roots;
        ([root(a0, pa0), root(a1, pa1), root(a2, pa2)], [root(d0, pb0), root(d1, pb1), root(d2, pb2)])
    }

    /// Takes an isolated FOG's share out of `drift_rad_s` ([`MekfCov::remove_share`];
    /// `pbb0` the bias covariance at alignment).
    pub fn remove_share(
        &mut self,
        drift_rad_s: &mut Vector3<f64>,
        (share_rad_s, share_cov_rad2_s2): (&Vector3<f64>, &Matrix3<f64>),
        pbb0: &Matrix3<f64>,
    ) {
        *drift_rad_s -= self.cov.remove_share(share_rad_s, share_cov_rad2_s2, pbb0);
    }
}

impl Default for Mekf {
    fn default() -> Self {
        Self::new()
    }
}

/// The MEKF's covariance (blocks of the 6 × 6 P) after its last update.
#[derive(Debug, Clone, Copy, PartialEq, bytemuck::AnyBitPattern)]
pub struct MekfCov {
    /// Attitude error, rad².
    pub paa: Matrix3<f64>,
    /// Attitude error × bias error, rad²/s.
    pub pab: Matrix3<f64>,
    /// Bias error, rad²/s².
    pub pbb: Matrix3<f64>,
}

/// The gain of one update: K = [K_a; K_b] (attitude, rad/rad; bias, 1/s).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MekfGain {
    /// Attitude rows.
    pub ka: Matrix3<f64>,
    /// Bias rows, 1/s.
    pub kb: Matrix3<f64>,
}

/// The rotation matrix C(q) of a unit quaternion: v_ref = C v_body (q ∘ v ∘ q̃).
pub fn dcm(q: &Quaternion<f64>) -> Matrix3<f64> {
    let (w, x, y, z) = (q.w, q.i, q.j, q.k);
    Matrix3::new(
        1.0 - 2.0 * (y * y + z * z),
        2.0 * (x * y - w * z),
        2.0 * (x * z + w * y),
        2.0 * (x * y + w * z),
        1.0 - 2.0 * (x * x + z * z),
        2.0 * (y * z - w * x),
        2.0 * (x * z - w * y),
        2.0 * (y * z + w * x),
        1.0 - 2.0 * (x * x + y * y),
    )
}

/// Symmetric part of `m` (removes the rounding asymmetry of the products).
fn sym(m: &Matrix3<f64>) -> Matrix3<f64> {
    (m + m.transpose()) * 0.5
}

/// a b, out of line: the LFE update's many products share one copy (flash; the 6-state
/// code keeps its products inline).
#[inline(never)]
fn mul(a: &Matrix3<f64>, b: &Matrix3<f64>) -> Matrix3<f64> {
    a * b
}

/// a bᵀ, out of line ([`mul`]).
#[inline(never)]
fn mul_t(a: &Matrix3<f64>, b: &Matrix3<f64>) -> Matrix3<f64> {
    a * b.transpose()
}

/// (M + r I)⁻¹ of a symmetric M ([`inverse_spd`]).
fn inverse_plus_r(m: &Matrix3<f64>, r: f64) -> Option<Matrix3<f64>> {
    inverse_spd(&(m + Matrix3::identity() * r))
}

/// Inverse of a symmetric positive definite 3 × 3 matrix by cofactors; `None` if it is
/// singular or not finite.
fn inverse_spd(s: &Matrix3<f64>) -> Option<Matrix3<f64>> {
    let c11 = s.m22 * s.m33 - s.m23 * s.m32;
    let c12 = s.m23 * s.m31 - s.m21 * s.m33;
    let c13 = s.m21 * s.m32 - s.m22 * s.m31;
    let det = s.m11 * c11 + s.m12 * c12 + s.m13 * c13;
    if !(det.is_finite() && det > 0.0) {
        return None;
    }
    let c22 = s.m11 * s.m33 - s.m13 * s.m31;
    let c23 = s.m12 * s.m31 - s.m11 * s.m32;
    let c33 = s.m11 * s.m22 - s.m12 * s.m21;
    let inv = 1.0 / det;
    Some(Matrix3::new(c11, c12, c13, c12, c22, c23, c13, c23, c33) * inv)
}

impl MekfCov {
    /// At alignment on one frame: the attitude known to the star tracker's noise `r_rad2`,
    /// each FOG's turn-on bias to `drift_var_rad2_s2`, so the body drift to
    /// `drift_var_rad2_s2` N (`noise`: N of the combination flying), uncorrelated.
    pub fn aligned(r_rad2: f64, drift_var_rad2_s2: f64, noise: &Matrix3<f64>) -> Self {
        MekfCov { paa: Matrix3::identity() * r_rad2, pab: Matrix3::zeros(), pbb: noise * drift_var_rad2_s2 }
    }

    /// The covariance at `tau_s` after the last update, the body having turned by
    /// `q_rel` (Λ̂(t_l)⁻¹ ∘ Λ̂(t_s)) meanwhile (module doc: Φ P Φᵀ + Q), one FOG's noise
    /// figures σ_v², σ_u² reaching the body axes as σ² N (`noise`, [`noise_of`]).
    pub fn propagated(
        &self,
        q_rel: &Quaternion<f64>,
        tau_s: f64,
        arw_var_rad2_s: f64,
        rrw_var_rad2_s3: f64,
        noise: &Matrix3<f64>,
    ) -> Self {
        let a = dcm(q_rel).transpose();
        let b = (a + Matrix3::identity()) * (0.5 * tau_s);
        let (sv2, su2, t) = (arw_var_rad2_s, rrw_var_rad2_s3, tau_s);
        let apab = a * self.pab;
        let bpbb = b * self.pbb;
        let cross = apab * b.transpose();
        let paa = a * self.paa * a.transpose() - cross - cross.transpose()
            + bpbb * b.transpose()
            + noise * (sv2 * t + su2 * t * t * t / 3.0);
        MekfCov { paa: sym(&paa), pab: apab - bpbb - noise * (su2 * t * t / 2.0), pbb: self.pbb + noise * (su2 * t) }
    }

    /// The diagonal of P_aa and P_bb at `tau_s` after the last update, the body's turn
    /// meanwhile left out (what the output's 1σ needs every step, at the cost of a few
    /// products per axis; exact for an isotropic P, as the star tracker's equal noise on
    /// every axis makes it in steady state). `arw_var_rad2_s` and `rrw_var_rad2_s3` per
    /// axis: σ_v² N_kk and σ_u² N_kk.
    pub fn diagonals(&self, tau_s: f64, arw_var_rad2_s: &[f64; 3], rrw_var_rad2_s3: &[f64; 3]) -> ([f64; 3], [f64; 3]) {
        let t = tau_s;
        let t3 = t * t * t / 3.0;
        let (a, ab, b) = (&self.paa, &self.pab, &self.pbb);
        let [v0, v1, v2] = *arw_var_rad2_s;
        let [u0, u1, u2] = *rrw_var_rad2_s3;
        let att =
            |paa: f64, pab: f64, pbb: f64, sv2: f64, su2: f64| paa - 2.0 * t * pab + t * t * pbb + sv2 * t + su2 * t3;
        (
            [att(a.m11, ab.m11, b.m11, v0, u0), att(a.m22, ab.m22, b.m22, v1, u1), att(a.m33, ab.m33, b.m33, v2, u2)],
            [b.m11 + u0 * t, b.m22 + u1 * t, b.m33 + u2 * t],
        )
    }

    /// The inverse innovation covariance S⁻¹ = (P_aa + R I)⁻¹ of a frame, `None` if S is
    /// not positive definite (a covariance gone wrong: the frame is not used).
    pub fn innovation_inverse(&self, r_rad2: f64) -> Option<Matrix3<f64>> {
        inverse_spd(&(self.paa + Matrix3::identity() * r_rad2))
    }

    /// The Kalman gain for S⁻¹ = `s_inv`, and the covariance after the update (Joseph
    /// form: (I − KH) P (I − KH)ᵀ + K R Kᵀ, by blocks with M = I − K_a).
    pub fn update(&mut self, s_inv: &Matrix3<f64>, r_rad2: f64) -> MekfGain {
        let pba = self.pab.transpose();
        let ka = self.paa * s_inv;
        let kb = pba * s_inv;
        let m = Matrix3::identity() - ka;
        let kbt = kb.transpose();
        let paa = m * self.paa * m.transpose() + ka * ka.transpose() * r_rad2;
        let pab = m * (self.pab - self.paa * kbt) + ka * kbt * r_rad2;
        let kb_paa_pba = kb * self.paa - pba;
        let pbb = kb_paa_pba * kbt - kb * self.pab + self.pbb + kb * kbt * r_rad2;
        self.paa = sym(&paa);
        self.pab = pab;
        self.pbb = sym(&pbb);
        MekfGain { ka, kb }
    }

    /// Takes an isolated FOG's share out of the bias state: returns what to subtract from
    /// the drift estimate b̂ and widens P_bb by what is no longer known.
    ///
    /// The bias state is the drift of the combination flying. With FOG i isolated the
    /// four-FOG solution S₄⁺ = S₃⁺ + u_i v (v the parity vector, u_i = S₄⁺_{:,i} / v_i) gives
    /// way to the triad's S₃⁺, so the true drift moves by −s = −u_i (v β) (β the FOGs'
    /// biases), estimated as ŝ = `share_rad_s` = u_i p̄ / Δt from the parity baseline p̄
    /// with covariance Σ_s = `share_cov_rad2_s2` = u_i u_iᵀ σ²_p̄ / Δt² (the baseline's noise
    /// is independent of the body noise: S₄⁺ vᵀ = 0).
    ///
    /// The filter had learned only part of s. For a constant drift present since
    /// alignment the mean of the bias error m_b obeys m_b ← (I − K_b H) Φ … as P_bb does
    /// without process noise, so m_b(t) = P_bb(t) P_bb(0)⁻¹ d: the unlearned fraction is
    /// F = P_bb P_bb(0)⁻¹ (exact without the rate random walk; with it F overstates what is
    /// unlearned, by 0.19 against 0.11 of s after 30 min with the paper's post-calibration
    /// bias, and less from a pre-calibration prior). So
    ///
    /// ```text
    /// b̂ ← b̂ − (I − F) ŝ,     P_bb ← P_bb + (F ŝ)(F ŝ)ᵀ + Σ_s,     F = P_bb P_bb(0)⁻¹
    /// ```
    ///
    /// the unlearned part counted as a 1σ error of its own size in its direction: the
    /// filter relearns it with its own gains. P_aa and P_ab stay (Σ_s is independent of
    /// the attitude error; the unlearned part is what the bias error already held).
    /// `pbb0` is P_bb(0), the bias covariance at alignment; a singular one (no prior)
    /// counts everything as unlearned.
    pub fn remove_share(
        &mut self,
        share_rad_s: &Vector3<f64>,
        share_cov_rad2_s2: &Matrix3<f64>,
        pbb0: &Matrix3<f64>,
    ) -> Vector3<f64> {
        let f = inverse_spd(pbb0).map_or_else(Matrix3::identity, |inv| self.pbb * inv);
        let unlearned = f * share_rad_s;
        self.pbb = sym(&(self.pbb + unlearned * unlearned.transpose() + share_cov_rad2_s2));
        share_rad_s - unlearned
    }

    /// The mean variance per axis of P_aa, rad² (a scalar for the fault logic).
    pub fn mean_attitude_var_rad2(&self) -> f64 {
        self.paa.trace() / 3.0
    }
}

/// N = S⁺ S⁺ᵀ for the least-squares solution S⁺ = (SᵀS)⁻¹ Sᵀ (3 × 4, the columns of FOGs
/// not flying zero): what independent noise of unit variance on each FOG becomes on the
/// body axes (S⁺ S = I, so S⁺ S⁺ᵀ = (SᵀS)⁻¹).
pub fn noise_of(solution: &nalgebra::Matrix3x4<f64>) -> Matrix3<f64> {
    sym(&(solution * solution.transpose()))
}

/// eᵀ S⁻¹ e: the normalised mismatch squared (χ²₃ for a consistent filter).
pub fn normalised(e: &Vector3<f64>, s_inv: &Matrix3<f64>) -> f64 {
    e.dot(&(s_inv * e))
}

/// One Newton step x ← (x + p/x)/2 from the last root when p moved by less than 12.5 %
/// (relative error ε²/2), a full square root otherwise; `x` is updated and returned.
#[inline(always)]
pub fn root(x: &mut f64, p: f64) -> f64 {
    let near = *x > 0.0 && (*x * *x - p).abs() <= 0.125 * p;
    *x = if near { 0.5 * (*x + p / *x) } else { math::sqrt(p.max(0.0)) };
    *x
}

#[cfg(test)]
mod tests {
    use nalgebra::Matrix6;

    use super::*;
    use crate::calib::ObserverConfig;
    use crate::observer::gains::steady_state;

    /// The full 6 × 6 P from its blocks.
    fn full(c: &MekfCov) -> Matrix6<f64> {
        let mut p = Matrix6::zeros();
        p.fixed_view_mut::<3, 3>(0, 0).copy_from(&c.paa);
        p.fixed_view_mut::<3, 3>(0, 3).copy_from(&c.pab);
        p.fixed_view_mut::<3, 3>(3, 0).copy_from(&c.pab.transpose());
        p.fixed_view_mut::<3, 3>(3, 3).copy_from(&c.pbb);
        p
    }

    #[test]
    fn the_covariance_stays_symmetric_positive_definite_over_updates() {
        let st = steady_state(&ObserverConfig::PAPER).unwrap();
        // The four nominal FOGs' N: 5/6 on each axis, −1/6 between.
        let noise = Matrix3::from_fn(|i, j| if i == j { 5.0 / 6.0 } else { -1.0 / 6.0 });
        let sb = 0.3 * core::f64::consts::PI / 180.0 / 3600.0;
        let mut cov = MekfCov::aligned(st.r_rad2, sb * sb, &noise);
        let tau = 0.25;
        for k in 0..4000u32 {
            // The body turns at up to 1 °/s about an axis that wanders.
            let a = f64::from(k) * 0.01;
            let w = Vector3::new(libm::sin(a), libm::cos(1.3 * a), 0.5) * (0.0175 * tau);
            let prior = cov.propagated(&math::quat_from_rotvec(&w), tau, st.arw_var_rad2_s, st.rrw_var_rad2_s3, &noise);
            let s_inv = prior.innovation_inverse(st.r_rad2).expect("S positive definite");
            let mut post = prior;
            let _ = post.update(&s_inv, st.r_rad2);
            for (name, c) in [("prior", &prior), ("posterior", &post)] {
                let p = full(c);
                assert_eq!(p, p.transpose(), "{name} {k} not symmetric");
                assert!(p.cholesky().is_some(), "{name} {k} not positive definite: {p}");
            }
            // An update never increases the attitude uncertainty.
            assert!(post.paa.trace() <= prior.paa.trace(), "update {k}");
            cov = post;
        }
        // And it settles near the per-axis steady state (the Farrenkopf posterior
        // (1 − K_B) M11 per axis, within the FOG combination's 5/6 and the turning).
        let per_axis = cov.paa.trace() / 3.0;
        let ss = (1.0 - st.gains.k_b[0]) * st.prior_var_rad2;
        assert!(per_axis > 0.5 * ss && per_axis < 1.5 * ss, "{per_axis:e} against {ss:e}");
    }

    /// The full 9 × 9 P of the filter with the tracker's LFE.
    fn full9(m: &Mekf) -> nalgebra::SMatrix<f64, 9, 9> {
        let (c, l) = (&m.cov, &m.lfe);
        let mut p = nalgebra::SMatrix::<f64, 9, 9>::zeros();
        for (i, j, b) in [(0, 0, c.paa), (0, 3, c.pab), (3, 3, c.pbb), (0, 6, l.pac), (3, 6, l.pbc), (6, 6, l.pcc)] {
            p.fixed_view_mut::<3, 3>(i, j).copy_from(&b);
            p.fixed_view_mut::<3, 3>(j, i).copy_from(&b.transpose());
        }
        p
    }

    #[test]
    fn with_the_tracker_lfe_the_covariance_settles_on_the_per_axis_kalman_filter() {
        // The paper's sensors with a 4″ / 300 s LFE; one FOG per axis (N = I) and no
        // turning, so the 9 states are three independent copies of the per-axis filter
        // x = (attitude, drift, LFE), H = [1 0 1], iterated here on its own.
        let cfg = ObserverConfig { st_lfe_sigma_arcsec: 4.0, st_lfe_tau_s: 300.0, ..ObserverConfig::PAPER };
        let st = steady_state(&cfg).unwrap();
        let fig = Figures::new(st);
        let mut m = Mekf::new();
        m.align(&fig, 1e-12);
        let (tau, phi) = (0.25, libm::exp(-0.25 / 300.0));
        let f = Matrix3::new(1.0, -tau, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, phi);
        let (sv2, su2) = (st.arw_var_rad2_s, st.rrw_var_rad2_s3);
        let q = Matrix3::new(
            sv2 * tau + su2 * tau * tau * tau / 3.0,
            -su2 * tau * tau / 2.0,
            0.0,
            -su2 * tau * tau / 2.0,
            su2 * tau,
            0.0,
            0.0,
            0.0,
            st.lfe_var_rad2 * (1.0 - phi * phi),
        );
        let h = Vector3::new(1.0, 0.0, 1.0);
        let v = st.lfe_var_rad2;
        let mut p = Matrix3::new(st.r_rad2 + v, 0.0, -v, 0.0, 1e-12, 0.0, -v, 0.0, v);
        let mut streak = Streak::default();
        let zero = Vector3::zeros();
        let ident = Quaternion::identity();
        for k in 0..20_000u32 {
            let at = UpdateAt {
                e_rad: &zero,
                converged: true,
                time_us: 0,
                tau_s: tau,
                aligned_us: None,
                q_at: &ident,
                last_q: &ident,
            };
            m.update(&fig, &at, &mut streak).expect("not gated");
            let pm = f * p * f.transpose() + q;
            let u = pm * h;
            p = pm - u * u.transpose() / (h.dot(&u) + st.r_rad2);
            if k % 1000 == 0 {
                let full = full9(&m);
                assert!(full.cholesky().is_some(), "update {k}: not positive definite");
            }
        }
        for (got, want) in
            [(m.cov.paa.m11, p.m11), (m.lfe.pcc.m22, p.m33), (m.lfe.pac.m33, p.m13), (m.cov.pbb.m11, p.m22)]
        {
            assert!((got - want).abs() <= 1e-6 * want.abs(), "{got:e} against {want:e}");
        }
        // Estimating the LFE leaves less of it in the attitude than a white filter's
        // whole σ_c: the attitude 1σ after an update is below √(σ_c²).
        assert!(m.cov.paa.m11 < v, "{:e} against {v:e}", m.cov.paa.m11);
    }

    #[test]
    fn a_resumed_mekf_restarts_its_lfe_at_the_prior_covariance() {
        // A snapshot carries P_aa, P_ab, P_bb only: the LFE states come back unknown
        // (σ_c² I, ĉ = 0, uncorrelated), never at zero covariance.
        let cfg = ObserverConfig {
            st_lfe_sigma_arcsec: 4.0,
            st_lfe_tau_s: 300.0,
            estimator: crate::calib::Estimator::Mekf,
            ..ObserverConfig::PAPER
        };
        let st = steady_state(&cfg).unwrap();
        let fig = Figures::new(st);
        let mut f = crate::observer::Filter::of(&cfg, &st.gains);
        f.align(&fig, 1e-12);
        let words = f.cov_words();
        let mut resumed = crate::observer::Filter::of(&cfg, &st.gains);
        resumed.set_cov_words(&words, &fig);
        let m = resumed.as_mekf().expect("the MEKF flies");
        assert_eq!(m.cov, f.as_mekf().expect("the MEKF flies").cov);
        assert_eq!(*m.lfe(), Lfe::unknown(st.lfe_var_rad2));
        assert!(st.lfe_var_rad2 > 0.0);
    }

    #[test]
    fn the_inverse_of_an_spd_matrix_is_its_inverse() {
        let s = Matrix3::new(4.0, 1.0, 0.5, 1.0, 3.0, 0.2, 0.5, 0.2, 2.0);
        let inv = inverse_spd(&s).unwrap();
        assert!((s * inv - Matrix3::identity()).amax() < 1e-15);
        assert_eq!(inverse_spd(&Matrix3::zeros()), None);
    }
}
