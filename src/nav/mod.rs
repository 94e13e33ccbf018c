//! Strapdown navigation in the Earth-centred Earth-fixed frame (launch-vehicle unit).
//!
//! State, all f64: the attitude quaternion q_eb (body frame B in ECEF E: a vector with
//! body components v_b has ECEF components q_eb ∘ v_b ∘ q̃_eb), the ECEF velocity v_e
//! (velocity relative to the Earth, ECEF components) and the ECEF position r_e.
//!
//! Inputs per step m (interval (t_{m−1}, t_m], Δt = 1.25 ms on the launch vehicle): the
//! angle increment α_m = ∫ ω_ib^b dt and the velocity increment υ_m = ∫ f^b dt
//! (integrated specific force), both in body axes, already compensated.
//!
//! The algorithms are those of P. G. Savage, *Strapdown Inertial Navigation Integration
//! Algorithm Design*, Part 1 (attitude) and Part 2 (velocity and position), J. Guidance,
//! Control, and Dynamics 21(1) and 21(2), 1998, in the two-sample forms, with the
//! navigation frame taken as ECEF (nav-frame rate ω_ie, no transport rate):
//!
//! (Equation numbers are not quoted here; the forms are the papers' two-sample ones.)
//!
//! - attitude (Part 1, quaternion update with the two-sample coning algorithm):
//!   ```text
//!   φ_m = α_m + (1/12) α_{m−1} × α_m
//!   q_eb(m) = q(−ω_ie Δt ẑ) ∘ q_eb(m−1) ∘ q(φ_m)
//!   ```
//!   q(·) is the exact quaternion of a rotation vector; the Earth-rate factor is the
//!   exact rotation of ECEF in inertial space over the step.
//! - specific-force velocity increment (Part 2: rotation compensation and the
//!   two-sample sculling algorithm, nav-frame rotation to first order in ζ):
//!   ```text
//!   Δv_rot  = ½ α_m × υ_m
//!   Δv_scul = (1/12) (α_{m−1} × υ_m + υ_{m−1} × α_m)
//!   Δv_SF^e = [I − ½ (ζ_m ×)] C_eb(m−1) (υ_m + Δv_rot + Δv_scul),   ζ_m = ω_ie Δt ẑ
//!   ```
//! - gravity and Coriolis increment (Part 2), evaluated at the mid-step
//!   point extrapolated with the step's own specific-force increment:
//!   ```text
//!   v_mid = v(m−1) + ½ (Δv_SF^e + a_gc(m−1) Δt),   r_mid = r(m−1) + ¼ Δt (v(m−1) + v_mid)
//!   Δv_G/Cor = [γ(r_mid) − ω_ie × (ω_ie × r_mid) − 2 ω_ie × v_mid] Δt
//!   ```
//!   with γ the WGS-84 gravitation with J2 ([`wgs84::gravitation_m_s2`]) and
//!   a_gc(m−1) the previous step's gravity/Coriolis acceleration.
//! - velocity and position (Part 2; position in the trapezoidal form, whose global
//!   error is −(Δt²/12)(a(end) − a(start)), micrometres here):
//!   ```text
//!   v(m) = v(m−1) + Δv_SF^e + Δv_G/Cor
//!   r(m) = r(m−1) + ½ (v(m−1) + v(m)) Δt
//!   ```
//!
//! The step never panics and never allocates; a non-finite input or state is refused
//! with a [`NavError`] and the state is left as it was.

pub mod gnss;
pub mod init;
pub mod snapshot;
pub mod unit;
pub mod wgs84;

use nalgebra::{Quaternion, Vector3};

pub use crate::frames::navout::NavState;
use crate::math;
use crate::state::Flag;
use crate::state_map::state_struct;

/// Why a navigation step or initialisation was refused (the state is unchanged).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub enum NavError {
    /// An increment was NaN or infinite.
    NonFiniteIncrement,
    /// The step period is not positive and finite.
    BadStep,
    /// The position is not finite or inside [`wgs84::MIN_RADIUS_M`].
    BadPosition,
    /// The result of the step was not finite (state kept).
    NonFiniteState,
}

/// Which high-rate corrections are applied (all on in flight; the switches exist to
/// measure what each one is worth).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub struct Corrections {
    /// Two-sample coning term (1/12) α_{m−1} × α_m.
    pub coning: bool,
    /// Rotation compensation ½ α_m × υ_m.
    pub rotation: bool,
    /// Two-sample sculling term.
    pub sculling: bool,
}

impl Corrections {
    /// Every correction applied.
    pub const ALL: Corrections = Corrections { coning: true, rotation: true, sculling: true };
    /// None applied (first-order strapdown).
    pub const NONE: Corrections = Corrections { coning: false, rotation: false, sculling: false };
}

/// [`Corrections`] as the state stores it (every bit pattern a value: [`Flag`]s).
#[derive(Debug, Clone, Copy, PartialEq, bytemuck::AnyBitPattern)]
struct CorrectionFlags {
    coning: Flag,
    rotation: Flag,
    sculling: Flag,
}

impl CorrectionFlags {
    fn of(c: Corrections) -> Self {
        CorrectionFlags { coning: c.coning.into(), rotation: c.rotation.into(), sculling: c.sculling.into() }
    }
}

state_struct! {
    /// The strapdown mechanisation (see the module documentation for the equations).
    /// Every bit pattern of it is a value (`crate::state`). Declared once
    /// ([`crate::state_map::state_struct!`]): `reset(Keep)` marks what the launch
    /// vehicle's reset snapshot carries ([`snapshot`]); the rest is the setup, checked by
    /// the snapshot's setup digest, or rebuilt from the state.
    #[derive(Debug, Clone, Copy, PartialEq, bytemuck::AnyBitPattern)]
    pub struct Strapdown {
        state: NavState = state, reset(Keep);
        dt_s: f64 = dt_s;
        corrections: CorrectionFlags = CorrectionFlags::of(corrections);
        /// Previous step's angle increment α_{m−1}, rad.
        prev_dtheta_rad: Vector3<f64> = Vector3::zeros(), reset(Keep);
        /// Previous step's velocity increment υ_{m−1}, m/s.
        prev_dv_m_s: Vector3<f64> = Vector3::zeros(), reset(Keep);
        /// Previous step's gravity + Coriolis + centrifugal acceleration, m/s² (rebuilt
        /// from the state by [`Strapdown::set_state`]).
        prev_gc_m_s2: Vector3<f64> = Vector3::zeros();
        /// Earth rotation over one step, as the quaternion q(−ω_ie Δt ẑ).
        q_earth: Quaternion<f64> = math::quat_from_rotvec(&Vector3::new(0.0, 0.0, -zeta_rad));
        /// ζ = ω_ie Δt (about ẑ), rad.
        zeta_rad: f64 = zeta_rad;
        /// Steps integrated.
        steps: u64 = 0, reset(Keep);
    }
    snapshot {
        /// The strapdown's fields a reset snapshot carries ([`snapshot`]).
        record: StrapdownKept
    }
    constructor
    /// The strapdown as built, before its state is checked ([`Strapdown::new`]).
    fn build(state: NavState, dt_s: f64, corrections: Corrections) -> Self => core::convert::identity {
        let zeta_rad = wgs84::EARTH_RATE_RAD_S * dt_s;
    }
}

/// Gravity and Coriolis acceleration in ECEF at (r, v):
/// γ(r) − ω_ie × (ω_ie × r) − 2 ω_ie × v.
fn gravity_coriolis_m_s2(r_e_m: &Vector3<f64>, v_e_m_s: &Vector3<f64>) -> Option<Vector3<f64>> {
    let w = wgs84::EARTH_RATE_RAD_S;
    // −2 ω × v with ω = (0, 0, w): (2w v_y, −2w v_x, 0).
    wgs84::gravity_m_s2(r_e_m).map(|g| g + Vector3::new(2.0 * w * v_e_m_s.y, -2.0 * w * v_e_m_s.x, 0.0))
}

fn finite(v: &Vector3<f64>) -> bool {
    v.x.is_finite() && v.y.is_finite() && v.z.is_finite()
}

impl Strapdown {
    /// Starts from `state` with step period `dt_s`. The quaternion is normalised.
    pub fn new(state: NavState, dt_s: f64, corrections: Corrections) -> Result<Self, NavError> {
        if !(dt_s.is_finite() && dt_s > 0.0) {
            return Err(NavError::BadStep);
        }
        let mut s = Strapdown::build(state, dt_s, corrections);
        s.set_state(state)?;
        Ok(s)
    }

    /// Replaces the state (alignment, an aiding correction). The increment history is
    /// kept: the corrections stay valid across a state reset.
    pub fn set_state(&mut self, mut state: NavState) -> Result<(), NavError> {
        if !finite(&state.v_e_m_s) {
            return Err(NavError::NonFiniteState);
        }
        let gc = gravity_coriolis_m_s2(&state.r_e_m, &state.v_e_m_s).ok_or(NavError::BadPosition)?;
        if !math::normalize(&mut state.q_eb) {
            return Err(NavError::NonFiniteState);
        }
        self.state = state;
        self.prev_gc_m_s2 = gc;
        Ok(())
    }

    /// Current state.
    pub fn state(&self) -> &NavState {
        &self.state
    }

    /// Step period, s.
    pub fn dt_s(&self) -> f64 {
        self.dt_s
    }

    /// Steps integrated.
    pub fn steps(&self) -> u64 {
        self.steps
    }

    /// Its words in a fixed order for a guard's pass ([`crate::shadow::Visit`]): the
    /// state, the setup (step, corrections, Earth rotation) and the increment history
    /// (the navigation unit's guard, [`unit`]).
    #[inline(always)]
    pub(super) fn visit<V: crate::shadow::Visit>(&mut self, v: &mut V) {
        v.f64s(self.state.q_eb.coords.as_mut_slice());
        v.f64s(self.state.v_e_m_s.as_mut_slice());
        v.f64s(self.state.r_e_m.as_mut_slice());
        v.f64(&mut self.dt_s);
        let c = &mut self.corrections;
        let mut bits = u64::from(c.coning.get()) | u64::from(c.rotation.get()) << 1 | u64::from(c.sculling.get()) << 2;
        v.word(&mut bits);
        if V::WRITES {
            *c = CorrectionFlags {
                coning: Flag::new(bits & 1 != 0),
                rotation: Flag::new(bits & 2 != 0),
                sculling: Flag::new(bits & 4 != 0),
            };
        }
        v.f64s(self.prev_dtheta_rad.as_mut_slice());
        v.f64s(self.prev_dv_m_s.as_mut_slice());
        v.f64s(self.prev_gc_m_s2.as_mut_slice());
        v.f64s(self.q_earth.coords.as_mut_slice());
        v.f64(&mut self.zeta_rad);
        v.word(&mut self.steps);
    }

    /// Integrates one step of body increments: `dtheta_rad` = ∫ω_ib^b dt and
    /// `dv_m_s` = ∫f^b dt over the step. On error the state is unchanged.
    pub fn step(&mut self, dtheta_rad: &Vector3<f64>, dv_m_s: &Vector3<f64>) -> Result<(), NavError> {
        if !(finite(dtheta_rad) && finite(dv_m_s)) {
            return Err(NavError::NonFiniteIncrement);
        }
        let c = self.corrections;
        let dt = self.dt_s;
        let s0 = self.state;

        // Specific-force increment in body axes at the start of the step (Savage Part 2).
        let mut dv_b = *dv_m_s;
        if c.rotation.get() {
            dv_b += dtheta_rad.cross(dv_m_s) * 0.5;
        }
        if c.sculling.get() {
            dv_b += (self.prev_dtheta_rad.cross(dv_m_s) + self.prev_dv_m_s.cross(dtheta_rad)) / 12.0;
        }
        // To ECEF with the start-of-step attitude, then the nav-frame rotation [I − ½ζ×].
        let dv_e0 = math::rotate(&s0.q_eb, &dv_b);
        let hz = 0.5 * self.zeta_rad;
        // −½ ζ × u with ζ = (0, 0, ζ): (½ζ u_y, −½ζ u_x, 0).
        let dv_sf_e = dv_e0 + Vector3::new(hz * dv_e0.y, -hz * dv_e0.x, 0.0);

        // Gravity and Coriolis at the extrapolated mid-step point.
        let v_mid = s0.v_e_m_s + (dv_sf_e + self.prev_gc_m_s2 * dt) * 0.5;
        let r_mid = s0.r_e_m + (s0.v_e_m_s + v_mid) * (0.25 * dt);
        let gc = gravity_coriolis_m_s2(&r_mid, &v_mid).ok_or(NavError::BadPosition)?;
        let v1 = s0.v_e_m_s + dv_sf_e + gc * dt;
        let r1 = s0.r_e_m + (s0.v_e_m_s + v1) * (0.5 * dt);

        // Attitude (Savage Part 1): body rotation with coning, then Earth rotation.
        let phi = if c.coning.get() { dtheta_rad + self.prev_dtheta_rad.cross(dtheta_rad) / 12.0 } else { *dtheta_rad };
        let mut q1 = self.q_earth * s0.q_eb * math::quat_from_rotvec(&phi);
        let q_ok = math::normalize(&mut q1);

        if !(q_ok && finite(&v1) && finite(&r1)) {
            return Err(NavError::NonFiniteState);
        }
        self.state = NavState { q_eb: q1, v_e_m_s: v1, r_e_m: r1 };
        self.prev_dtheta_rad = *dtheta_rad;
        self.prev_dv_m_s = *dv_m_s;
        self.prev_gc_m_s2 = gc;
        self.steps = self.steps.saturating_add(1);
        Ok(())
    }
}
