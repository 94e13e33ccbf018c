//! The mismatch of a star-tracker frame, the gate on it and the re-acquisition
//! bookkeeping, shared by every estimator.
//!
//! - The mismatch of eq. (6), e = 2 vect(ΔΛ) with ΔΛ = Λ(t_s)⁻¹ ∘ Λ*, exact as a rotation
//!   vector ([`mismatch_rad`]), Λ* taken back from the star tracker to the ICS through the
//!   mount, eq. (5).
//! - The gate: a frame whose normalised mismatch exceeds the χ²₃ quantile [`CHI2_GATE`]
//!   is refused (0.1 % of nominal frames). The variance it is normalised by is the
//!   estimator's ([`super::Filter::mismatch_var_rad2`]).
//! - Re-acquisition ([`Streak`]): [`REACQUIRE_FRAMES`] refused in a row that agree with
//!   each other say the attitude, not the star tracker, is off (after a long outage or a
//!   fault): the estimator takes the frame and reopens its gate.
//! - Convergence ([`Convergence`]): the running mean-square mismatch the fixed-gain
//!   observer's gate waits for.
//! - The consistency monitor ([`Monitor`]): from the [`SUSPECT_FRAMES`]-th gated frame in
//!   a row the estimate is not reported converged; [`REALIGN_FRAMES`] in a row whose
//!   inertial corrections Λ* ∘ Λ(t_s)⁻¹ agree with each other (the tracker's attitude
//!   changed between them as the gyros propagated it: the propagated attitude, not the
//!   tracker, is off) re-align the attitude on the tracker at once.

use nalgebra::{Quaternion, Vector3};

use crate::math;
use crate::state::Flag;

/// χ²₃ gate on the normalised mismatch: 16.27 refuses 0.1 % of nominal frames.
pub const CHI2_GATE: f64 = 16.266;
/// Consecutive gated frames that agree with each other and re-acquire (8 at 4 Hz: 2 s):
/// the attitude, not the star tracker, is off (after a long outage or a fault).
pub const REACQUIRE_FRAMES: u32 = 8;

/// Consecutive gated frames from which the estimate is no longer reported converged (2
/// at 4 Hz: 0.25 s): two gated frames in a row happen once in 10⁶ nominal frames.
pub const SUSPECT_FRAMES: u32 = 2;
/// Consecutive gated frames whose inertial corrections agree that re-align the attitude
/// on the tracker (4 at 4 Hz: 0.75 s after the first).
pub const REALIGN_FRAMES: u32 = 4;

/// How far beyond the gate a run's mean correction must lie to re-align, in |d|² per
/// gate: twice the gate's radius. A jump of the attitude lies far beyond; an estimator
/// lagging just beyond its gate (an uncalibrated drift being learned) does not, and is
/// left to re-acquisition ([`Streak`]), which keeps learning the drift.
pub const REALIGN_GATES: f64 = 4.0;

/// Whether a frame's star-tracker quaternion can be used: finite and unit (to 1e-5 in
/// |q|²).
#[inline]
pub fn quaternion_ok(q: &Quaternion<f64>) -> bool {
    let n2 = q.norm_squared();
    n2.is_finite() && (n2 - 1.0).abs() <= 1e-5
}

/// The mismatch e = 2 vect(Λ(t_s)⁻¹ ∘ Λ*) of eq. (6), rad (ICS at t_s), exact
/// ([`math::rotvec_from_quat`]).
#[inline]
pub fn mismatch_rad(q_at: &Quaternion<f64>, q_meas: &Quaternion<f64>) -> Vector3<f64> {
    math::rotvec_from_quat(&(q_at.conjugate() * q_meas))
}

/// Whether a squared normalised mismatch `e2` (|e|² for variance `var` per axis) lies
/// outside the gate: |e|² > [`CHI2_GATE`] · var.
#[inline]
pub fn outside(e2: f64, var: f64) -> bool {
    e2 > CHI2_GATE * var
}

/// Consecutive gated frames and the running sums of a vector each gives: whether they
/// agree with each other ([`Streak`], [`Monitor`]).
#[derive(Debug, Clone, Copy, PartialEq, Default, bytemuck::AnyBitPattern)]
struct Run {
    n: u32,
    sum: Vector3<f64>,
    sum_sq: f64,
}

impl Run {
    /// One more frame's vector `v`: `Some` of the run's sum and length once `frames` in
    /// a row spread about their mean within the gate (per-axis variance `var`), else
    /// `None`.
    fn agree(&mut self, v: &Vector3<f64>, var: f64, frames: u32) -> Option<(Vector3<f64>, f64)> {
        self.n = self.n.saturating_add(1);
        self.sum += v;
        self.sum_sq += v.norm_squared();
        // Spread of the run's vectors about their mean, per frame.
        let n = f64::from(self.n);
        let spread = (self.sum_sq - self.sum.norm_squared() / n) / n;
        if self.n < frames || outside(spread, var) {
            return None;
        }
        Some((self.sum, n))
    }
}

/// Consecutive gated frames and their running sums (re-acquisition).
#[derive(Debug, Clone, Copy, PartialEq, Default, bytemuck::AnyBitPattern)]
pub struct Streak(Run);

impl Streak {
    /// A gated frame's mismatch `e` into the streak: `Some(mean²)` of the streak's
    /// mismatch when [`REACQUIRE_FRAMES`] in a row agree with each other within the gate
    /// (per-axis variance `var`): re-acquire; else `None` (the frame stays refused).
    pub fn reacquires(&mut self, e: &Vector3<f64>, var: f64) -> Option<f64> {
        let (sum, n) = self.0.agree(e, var, REACQUIRE_FRAMES)?;
        Some(sum.norm_squared() / (n * n))
    }

    /// Its words, for the state guard ([`crate::shadow`]).
    pub fn visit<V: crate::shadow::Visit>(&mut self, v: &mut V) {
        v.u32(&mut self.0.n);
        v.f64s(self.0.sum.as_mut_slice());
        v.f64(&mut self.0.sum_sq);
    }

    /// A frame was used: the streak ends.
    #[inline]
    pub fn end(&mut self) {
        *self = Streak::default();
    }
}

/// The consistency monitor between the star tracker and the propagated attitude:
/// consecutive gated frames and the running sums of their inertial corrections
/// d = 2 vect(Λ* ∘ Λ(t_s)⁻¹) (the rotation that takes the propagated attitude onto the
/// tracker's, in the ICS: constant over frames when the attitude took a jump, however the
/// body turns; scattered for tracker outliers).
#[derive(Debug, Clone, Copy, PartialEq, Default, bytemuck::AnyBitPattern)]
pub struct Monitor {
    run: Run,
    /// The next frame re-aligns whatever its mismatch ([`Monitor::force`]).
    forced: Flag,
}

impl Monitor {
    /// A gated frame's inertial correction `d` (rad) into the run, the mismatch variance
    /// per axis `var` (rad²): `Some` of the run's mean correction (rad) and its length
    /// when [`REALIGN_FRAMES`] in a row or more agree with each other within the gate and
    /// their mean lies [`REALIGN_GATES`] beyond it: re-align; else `None`.
    pub fn realigns(&mut self, d: &Vector3<f64>, var: f64) -> Option<(Vector3<f64>, f64)> {
        let (sum, n) = self.run.agree(d, var, REALIGN_FRAMES)?;
        let mean = sum / n;
        outside(mean.norm_squared(), REALIGN_GATES * var).then_some((mean, n))
    }

    /// Whether the last [`SUSPECT_FRAMES`] frames or more were gated in a row (or a
    /// re-alignment was asked for): the propagated attitude may be off, the estimate is
    /// not reported converged.
    #[inline]
    pub fn suspect(&self) -> bool {
        self.run.n >= SUSPECT_FRAMES || self.forced.get()
    }

    /// The next frame re-aligns the attitude whatever its mismatch (the state was found
    /// corrupted); until then the estimate is suspect.
    pub fn force(&mut self) {
        self.forced.set(true);
    }

    /// Whether a re-alignment was asked for ([`Monitor::force`]).
    #[inline]
    pub fn forced(&self) -> bool {
        self.forced.get()
    }

    /// A frame was used (or the attitude re-aligned): the run ends.
    #[inline]
    pub fn end(&mut self) {
        *self = Monitor::default();
    }
}

/// Updates since alignment and the running mean-square mismatch per axis: whether the
/// estimate has converged.
#[derive(Debug, Clone, Copy, PartialEq, bytemuck::AnyBitPattern)]
pub struct Convergence {
    /// Updates since alignment (the alignment included).
    updates: u32,
    /// Running mean-square mismatch per axis, rad².
    innov_ms_rad2: f64,
    /// The star tracker's 1σ, rad.
    sigma_st_rad: f64,
}

impl Convergence {
    /// Nothing seen yet, for a star tracker of 1σ `sigma_st_rad`.
    pub fn new(sigma_st_rad: f64) -> Self {
        Convergence { updates: 0, innov_ms_rad2: 0.0, sigma_st_rad }
    }

    /// A new table's star-tracker 1σ; what was seen stays.
    pub fn set_sigma_st_rad(&mut self, sigma_st_rad: f64) {
        self.sigma_st_rad = sigma_st_rad;
    }

    /// Its words, for the state guard ([`crate::shadow`]).
    #[inline(always)]
    pub fn visit<V: crate::shadow::Visit>(&mut self, v: &mut V) {
        v.u32(&mut self.updates);
        v.f64(&mut self.innov_ms_rad2);
        v.f64(&mut self.sigma_st_rad);
    }

    /// Starts again (a new alignment).
    pub fn reset(&mut self) {
        *self = Convergence::new(self.sigma_st_rad);
    }

    /// The alignment: one update, no mismatch.
    pub fn aligned(&mut self) {
        self.updates = self.updates.saturating_add(1);
    }

    /// Updates seen and the running mean square (a reset's snapshot).
    pub fn state(&self) -> (u32, f64) {
        (self.updates, self.innov_ms_rad2)
    }

    /// The inverse of [`Convergence::state`] (a reset resumed).
    pub fn restore(&mut self, updates: u32, innov_ms_rad2: f64) {
        self.updates = updates;
        self.innov_ms_rad2 = innov_ms_rad2;
    }

    /// An update with mismatch |e|² = `e2`: the running mean square per axis (an
    /// exponential mean over about 20 updates) and the update count.
    pub fn note(&mut self, e2: f64) {
        let e2 = e2 / 3.0;
        self.innov_ms_rad2 = if self.updates <= 1 { e2 } else { self.innov_ms_rad2 + 0.05 * (e2 - self.innov_ms_rad2) };
        self.updates = self.updates.saturating_add(1);
    }

    /// Converged: at least 40 updates, and the mean-square mismatch (per axis) within 3σ
    /// of the star tracker's.
    #[inline]
    pub fn converged(&self) -> bool {
        self.updates >= 40 && self.innov_ms_rad2 < 9.0 * self.sigma_st_rad * self.sigma_st_rad
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// P(χ²₃ > x) = erfc(√(x/2)) + √(2x/π) e^(−x/2).
    fn chi2_3_tail(x: f64) -> f64 {
        libm::erfc(libm::sqrt(x / 2.0)) + libm::sqrt(2.0 * x / core::f64::consts::PI) * libm::exp(-x / 2.0)
    }

    #[test]
    fn the_gate_refuses_one_nominal_frame_in_a_thousand() {
        // 16.266 is the 0.1 % quantile to its five digits: the tail 0.0005 either side of
        // it brackets 1e-3.
        assert!(chi2_3_tail(CHI2_GATE - 0.0005) > 1e-3, "tail {}", chi2_3_tail(CHI2_GATE - 0.0005));
        assert!(chi2_3_tail(CHI2_GATE + 0.0005) < 1e-3, "tail {}", chi2_3_tail(CHI2_GATE + 0.0005));
        // The threshold scales with the variance and is strict.
        let var = 2.5e-9;
        assert!(!outside(CHI2_GATE * var, var));
        assert!(outside(CHI2_GATE * var * (1.0 + 1e-12), var));
    }

    #[test]
    fn agreeing_gated_frames_reacquire_on_the_eighth() {
        let var = 1e-10;
        let mut s = Streak::default();
        let e = Vector3::new(1e-3, -2e-3, 5e-4);
        for k in 1..REACQUIRE_FRAMES {
            assert_eq!(s.reacquires(&(e * (1.0 + 1e-4 * f64::from(k))), var), None, "frame {k}");
        }
        let mean2 = s.reacquires(&e, var).expect("re-acquires");
        assert!((mean2 / e.norm_squared() - 1.0).abs() < 1e-3);
    }

    #[test]
    fn scattered_gated_frames_do_not_reacquire() {
        let var = 1e-10;
        let mut s = Streak::default();
        for k in 0..3 * REACQUIRE_FRAMES {
            let sign = if k % 2 == 0 { 1.0 } else { -1.0 };
            assert_eq!(s.reacquires(&Vector3::new(sign * 1e-3, 0.0, 0.0), var), None);
        }
        s.end();
        assert_eq!(s, Streak::default());
    }

    #[test]
    fn a_jump_the_frames_agree_on_realigns_on_the_fourth_and_is_suspect_from_the_second() {
        let var = 1e-10;
        let mut m = Monitor::default();
        let d = Vector3::new(2e-3, -1e-3, 5e-4);
        for k in 1..REALIGN_FRAMES {
            assert_eq!(m.suspect(), k > SUSPECT_FRAMES, "frame {k}");
            assert_eq!(m.realigns(&(d * (1.0 + 1e-4 * f64::from(k))), var), None, "frame {k}");
            assert_eq!(m.suspect(), k >= SUSPECT_FRAMES, "frame {k}");
        }
        let (mean, n) = m.realigns(&d, var).expect("re-aligns");
        assert_eq!(n, f64::from(REALIGN_FRAMES));
        assert!((mean - d).norm() < 1e-3 * d.norm());
        m.end();
        assert!(!m.suspect());
    }

    #[test]
    fn agreeing_frames_just_beyond_the_gate_do_not_realign() {
        let var = 1e-10;
        let mut m = Monitor::default();
        // 1.5 gate radii: beyond the gate, within twice its radius (a lagging estimate).
        let d = Vector3::new(1.5 * libm::sqrt(CHI2_GATE * var), 0.0, 0.0);
        for _ in 0..3 * REALIGN_FRAMES {
            assert_eq!(m.realigns(&d, var), None);
        }
        assert!(m.suspect());
    }

    #[test]
    fn scattered_gated_frames_are_suspect_but_never_realign() {
        let var = 1e-10;
        let mut m = Monitor::default();
        for k in 0..3 * REALIGN_FRAMES {
            let sign = if k % 2 == 0 { 1.0 } else { -1.0 };
            assert_eq!(m.realigns(&Vector3::new(0.0, sign * 1e-3, 0.0), var), None);
        }
        assert!(m.suspect());
    }

    #[test]
    fn convergence_waits_for_forty_updates_within_three_sigma() {
        let sigma = 1e-4;
        let mut c = Convergence::new(sigma);
        c.aligned();
        for _ in 0..38 {
            c.note(3.0 * sigma * sigma);
        }
        assert!(!c.converged());
        c.note(3.0 * sigma * sigma);
        assert!(c.converged());
        c.reset();
        assert!(!c.converged());
    }
}
