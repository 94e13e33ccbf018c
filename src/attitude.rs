//! Attitude: integration of body angle increments into the orientation quaternion Λ.
//!
//! Λ is the quaternion of the instrument frame ICS (O X_P Y_P Z_P) in the inertial frame
//! 2ECS (O X_I Y_I Z_I): a vector with ICS components v_P has 2ECS components
//! v_I = Λ ∘ v_P ∘ Λ̃. Kinematics (the paper's system after eq. 5): Λ̇ = ½ Λ ∘ ω, with
//! ω in ICS. Over one step the exact solution is Λ_{k+1} = Λ_k ∘ q(φ_k), where φ_k is the
//! rotation vector of the step (Bortz). For increments Δθ_k measured by the gyros,
//!
//! ```text
//! φ_k = Δθ_k + (7/60) Δθ_{k−1} × Δθ_k − (1/60) Δθ_{k−2} × Δθ_k
//! ```
//!
//! The cross-product terms are the coning correction: the classical two-sample term is
//! (1/12) Δθ_{k−1} × Δθ_k (Savage 1998); using one more previous increment and matching
//! the pure-coning series to (ωΔt)⁵ gives 7/60 and −1/60, which cuts the residual
//! coning drift by another factor ~(ωΔt)² (see `tests/attitude.rs` on the host).
//! q(φ) is exact ([`crate::math::quat_from_rotvec`]); Λ is renormalised every step.

use nalgebra::{Quaternion, Vector3};

use crate::math;
use crate::state_map::{state_map, StateField};

/// Coning-correction order.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub enum Coning {
    /// No correction: φ = Δθ.
    None,
    /// Two-sample: (1/12) Δθ_{k−1} × Δθ_k.
    TwoSample,
    /// Three-sample with two previous increments (default).
    ThreeSample,
}

impl Coning {
    /// Its code in the state (the attitude's state holds a byte, not the enum).
    pub const fn code(self) -> u8 {
        match self {
            Coning::None => 0,
            Coning::TwoSample => 1,
            Coning::ThreeSample => 2,
        }
    }

    /// The coning terms of code `c`: every byte decodes, an unknown one as
    /// [`Coning::ThreeSample`] (the flight cores' choice).
    pub const fn from_code(c: u8) -> Coning {
        match c {
            0 => Coning::None,
            1 => Coning::TwoSample,
            _ => Coning::ThreeSample,
        }
    }
}

/// Strapdown attitude integrator.
#[derive(Debug, Clone, Copy, PartialEq, bytemuck::AnyBitPattern)]
pub struct Attitude {
    q: Quaternion<f64>,
    prev1: Vector3<f64>,
    prev2: Vector3<f64>,
    /// [`Coning::code`].
    coning: u8,
    renorm_failures: u32,
}

impl Attitude {
    /// Where each field lies in the value ([`crate::state_map`]).
    pub const STATE_MAP: &'static [StateField] = state_map!(Attitude {
        q: Quaternion<f64>,
        prev1: Vector3<f64>,
        prev2: Vector3<f64>,
        coning: u8,
        renorm_failures: u32,
    });

    /// Starts at `q` (normalised; identity if degenerate).
    pub fn new(q: Quaternion<f64>, coning: Coning) -> Self {
        let mut a =
            Attitude { q, prev1: Vector3::zeros(), prev2: Vector3::zeros(), coning: coning.code(), renorm_failures: 0 };
        if !math::normalize(&mut a.q) {
            a.renorm_failures = 1;
        }
        a
    }

    /// Current Λ (ICS in 2ECS).
    pub fn quaternion(&self) -> Quaternion<f64> {
        self.q
    }

    /// Replaces Λ (alignment, observer correction); the increment history is kept.
    pub fn set_quaternion(&mut self, q: Quaternion<f64>) {
        self.q = q;
        if !math::normalize(&mut self.q) {
            self.renorm_failures = self.renorm_failures.saturating_add(1);
        }
    }

    /// Λ's storage (i, j, k, w), written back bit for bit by the in-step twin's repair
    /// (`flight::twin`; no renormalisation).
    pub fn words_mut(&mut self) -> &mut [f64] {
        self.q.coords.as_mut_slice()
    }

    /// Flips bit `bit` of Λ's storage word `word` (i, j, k, w; tests: an upset).
    #[cfg(test)]
    pub fn flip_q(&mut self, word: usize, bit: u32) {
        let c = &mut self.q.coords[word];
        *c = f64::from_bits(c.to_bits() ^ 1 << bit);
    }

    /// Λ's words, for the state guard ([`crate::shadow`]).
    #[inline(always)]
    pub fn visit_q<V: crate::shadow::Visit>(&mut self, v: &mut V) {
        v.f64s(self.q.coords.as_mut_slice());
    }

    /// The two previous increments of the coning terms, for the state guard.
    #[inline(always)]
    pub fn visit_increments<V: crate::shadow::Visit>(&mut self, v: &mut V) {
        v.f64s(self.prev1.as_mut_slice());
        v.f64s(self.prev2.as_mut_slice());
    }

    /// Times the quaternion was degenerate and reset to identity.
    pub fn renorm_failures(&self) -> u32 {
        self.renorm_failures
    }

    /// Rotation vector of the step for increment `dtheta_rad`, with the coning terms.
    ///
    /// The coning term is second order in the increments (|term| ≲ |Δθ_prev|·|Δθ|/10, a
    /// millionth of |Δθ| at this unit's rates): a rotation vector more than twice the
    /// increment, or not finite, can only come from a corrupted increment history (an upset between
    /// the state guard's check and this use), and is left out: the step
    /// integrates the increment alone.
    pub fn rotation_vector(&self, dtheta_rad: &Vector3<f64>) -> Vector3<f64> {
        let phi = match Coning::from_code(self.coning) {
            Coning::None => return *dtheta_rad,
            Coning::TwoSample => dtheta_rad + self.prev1.cross(dtheta_rad) / 12.0,
            Coning::ThreeSample => {
                dtheta_rad + self.prev1.cross(dtheta_rad) * (7.0 / 60.0) - self.prev2.cross(dtheta_rad) / 60.0
            }
        };
        // |φ| ≤ 2|Δθ| holds whenever the term is no larger than the increment (the
        // triangle inequality), and is cheaper to test than the term itself; a NaN
        // fails the comparison and is left out too.
        if phi.norm_squared() <= 4.0 * dtheta_rad.norm_squared() {
            phi
        } else {
            *dtheta_rad
        }
    }

    /// Bridges `samples` sample intervals lost on every link with the held per-sample
    /// increment `held_rad` (rad, bias removed): one rotation by `samples × held_rad`,
    /// which is exact at constant rate, with no coning term (parallel increments). The
    /// increment history becomes the held one, as if each lost sample had been it.
    /// A non-finite increment is refused: Λ is kept and `false` returned.
    pub fn bridge(&mut self, held_rad: &Vector3<f64>, samples: u16) -> bool {
        let span = held_rad * f64::from(samples);
        if !(span.x.is_finite() && span.y.is_finite() && span.z.is_finite()) {
            return false;
        }
        self.q *= math::quat_from_rotvec(&span);
        if !math::normalize(&mut self.q) {
            self.renorm_failures = self.renorm_failures.saturating_add(1);
        }
        self.prev2 = *held_rad;
        self.prev1 = *held_rad;
        true
    }

    /// Integrates one body increment Δθ (rad, ICS, bias already removed).
    /// A non-finite increment is refused: Λ is kept and `false` returned.
    pub fn step(&mut self, dtheta_rad: &Vector3<f64>) -> bool {
        if !(dtheta_rad.x.is_finite() && dtheta_rad.y.is_finite() && dtheta_rad.z.is_finite()) {
            return false;
        }
        let phi = self.rotation_vector(dtheta_rad);
        self.q *= math::quat_from_rotvec(&phi);
        if !math::normalize(&mut self.q) {
            self.renorm_failures = self.renorm_failures.saturating_add(1);
        }
        self.prev2 = self.prev1;
        self.prev1 = *dtheta_rad;
        true
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// An exponent bit of a previous increment flipped (the QEMU campaign's silent flip:
    /// bit 62 of `prev2.y`, between the guard's check and the step's use) makes the
    /// coning term astronomically large: it is left out, and the step turns Λ by the
    /// increment alone, as it would have to a few parts in 10⁶.
    #[test]
    fn a_corrupted_increment_history_does_not_turn_the_attitude() {
        let dtheta = Vector3::new(2e-5, -1e-5, 3e-5);
        let mut good = Attitude::new(Quaternion::identity(), Coning::ThreeSample);
        good.step(&Vector3::new(1e-5, 2e-5, -1e-5));
        good.step(&Vector3::new(1.5e-5, 2e-5, -0.5e-5));
        let mut hit = good;
        hit.prev2.y = f64::from_bits(hit.prev2.y.to_bits() ^ 1 << 62);
        assert!(hit.prev2.y.abs() > 1e290, "{}", hit.prev2.y);
        let (mut plain, q0) = (good, good.quaternion());
        plain.coning = Coning::None.code();
        good.step(&dtheta);
        hit.step(&dtheta);
        plain.step(&dtheta);
        let angle = |a: &Attitude| 2.0_f64 * (a.quaternion() * q0.conjugate()).vector().norm();
        assert!((angle(&hit) - angle(&plain)).abs() < 1e-15, "{} {}", angle(&hit), angle(&plain));
        assert!((angle(&good) - dtheta.norm()).abs() < 1e-6 * dtheta.norm());
        // A NaN in the history is left out the same way.
        let mut nan = good;
        nan.prev1.x = f64::NAN;
        let before = nan.quaternion();
        nan.step(&dtheta);
        assert!(nan.quaternion().coords.iter().all(|c| c.is_finite()));
        assert!((2.0_f64 * (nan.quaternion() * before.conjugate()).vector().norm() - dtheta.norm()).abs() < 1e-12);
    }

    /// Λ after a constant rate about a fixed axis for `n` steps of `dtheta`: the coning
    /// terms vanish (parallel increments) and the exact step compounds to one rotation.
    #[test]
    fn a_constant_rate_compounds_to_the_exact_rotation() {
        let dtheta = Vector3::new(2e-4, -1e-4, 3e-4);
        let n = 10_000;
        for coning in [Coning::None, Coning::TwoSample, Coning::ThreeSample] {
            let mut a = Attitude::new(Quaternion::identity(), coning);
            for _ in 0..n {
                assert!(a.step(&dtheta));
            }
            let exact = math::quat_from_rotvec(&(dtheta * f64::from(n)));
            let err = (a.quaternion() - exact).norm().min((a.quaternion() + exact).norm());
            // 10,000 steps of a few ulp of rounding each.
            assert!(err < 1e-11, "{coning:?}: |Λ − exact| {err}");
        }
    }

    /// The rotation vector carries the coning terms of the module's formula, with the
    /// history the steps left.
    #[test]
    fn the_coning_terms_use_the_previous_increments() {
        let (d2, d1, d0) = (Vector3::new(1e-3, 0.0, 0.0), Vector3::new(0.0, 1e-3, 0.0), Vector3::new(0.0, 0.0, 1e-3));
        let mut three = Attitude::new(Quaternion::identity(), Coning::ThreeSample);
        let mut two = Attitude::new(Quaternion::identity(), Coning::TwoSample);
        for a in [&mut three, &mut two] {
            a.step(&d2);
            a.step(&d1);
        }
        let want3 = d0 + d1.cross(&d0) * (7.0 / 60.0) - d2.cross(&d0) / 60.0;
        let want2 = d0 + d1.cross(&d0) / 12.0;
        assert!((three.rotation_vector(&d0) - want3).norm() < 1e-20);
        assert!((two.rotation_vector(&d0) - want2).norm() < 1e-20);
        // A term that is present: the history moves φ off Δθ.
        assert!((three.rotation_vector(&d0) - d0).norm() > 1e-8);
    }

    #[test]
    fn a_non_finite_increment_is_refused_and_keeps_the_attitude() {
        let mut a = Attitude::new(Quaternion::identity(), Coning::ThreeSample);
        a.step(&Vector3::new(1e-3, 2e-3, -1e-3));
        let q = a.quaternion();
        assert!(!a.step(&Vector3::new(f64::NAN, 0.0, 0.0)));
        assert!(!a.step(&Vector3::new(0.0, f64::INFINITY, 0.0)));
        assert!(!a.bridge(&Vector3::new(0.0, 0.0, f64::NAN), 3));
        assert_eq!(a.quaternion(), q);
    }

    /// Bridging n lost samples at a held rate is one rotation by n times the increment.
    #[test]
    fn a_bridge_is_the_held_rate_over_the_gap() {
        let held = Vector3::new(1e-4, 5e-5, -2e-4);
        let mut bridged = Attitude::new(Quaternion::identity(), Coning::ThreeSample);
        assert!(bridged.bridge(&held, 7));
        let exact = math::quat_from_rotvec(&(held * 7.0));
        assert!((bridged.quaternion() - exact).norm() < 1e-15);
    }

    #[test]
    fn a_degenerate_quaternion_is_counted() {
        let a = Attitude::new(Quaternion::new(0.0, 0.0, 0.0, 0.0), Coning::None);
        assert_eq!(a.renorm_failures(), 1);
        assert!((a.quaternion().norm() - 1.0).abs() < 1e-15);
    }
}
