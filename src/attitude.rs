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

/// Strapdown attitude integrator.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Attitude {
    q: Quaternion<f64>,
    prev1: Vector3<f64>,
    prev2: Vector3<f64>,
    coning: Coning,
    renorm_failures: u32,
}

impl Attitude {
    /// Starts at `q` (normalised; identity if degenerate).
    pub fn new(q: Quaternion<f64>, coning: Coning) -> Self {
        let mut a = Attitude { q, prev1: Vector3::zeros(), prev2: Vector3::zeros(), coning, renorm_failures: 0 };
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

    /// Times the quaternion was degenerate and reset to identity.
    pub fn renorm_failures(&self) -> u32 {
        self.renorm_failures
    }

    /// Rotation vector of the step for increment `dtheta_rad`, with the coning terms.
    pub fn rotation_vector(&self, dtheta_rad: &Vector3<f64>) -> Vector3<f64> {
        match self.coning {
            Coning::None => *dtheta_rad,
            Coning::TwoSample => dtheta_rad + self.prev1.cross(dtheta_rad) / 12.0,
            Coning::ThreeSample => {
                dtheta_rad + self.prev1.cross(dtheta_rad) * (7.0 / 60.0) - self.prev2.cross(dtheta_rad) / 60.0
            }
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
