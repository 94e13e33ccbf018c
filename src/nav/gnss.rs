//! Loosely coupled GNSS aiding of the strapdown navigation: a 15-state error-state
//! Kalman filter in ECEF, after P. D. Groves, *Principles of GNSS, Inertial, and
//! Multisensor Integrated Navigation Systems*, 2nd ed. (2013), §14.2 (ECEF system model)
//! and §14.3 (loosely coupled measurement model), simplified as noted below.
//!
//! Error state x = (φ, δv, δr, δb_a, δb_g), each "truth − estimate":
//! - φ: attitude error, q_eb,true = q(φ) ∘ q_eb,est (ECEF-side small rotation), rad;
//! - δv, δr: ECEF velocity and position errors, m/s and m;
//! - δb_a, δb_g: errors of the estimated accelerometer and gyro biases (body axes; a
//!   sensor reads truth + bias, the filter's estimate is subtracted from the increments).
//!
//! System model (continuous, C = C_eb, f_e = C f_b, Ω = ω_ie ẑ):
//!
//! ```text
//! φ̇  = −Ω × φ − C δb_g
//! δv̇ = −[f_e ×] φ − 2 Ω × δv + Γ δr − C δb_a,    Γ = (GM/r³)(3 r̂ r̂ᵀ − I)
//! δṙ = δv,    δḃ_a = w_a,    δḃ_g = w_g
//! ```
//!
//! (Γ is the point-mass gravity gradient; the J2 and centrifugal gradients are left out,
//! they change a 30 s outage's error growth by well under a percent.) The covariance is
//! propagated every [`PROPAGATE_STEPS`] navigation steps with Φ = I + F T + (F T)²/2,
//! f_e the mean specific force over the interval, and Q = Q_c T.
//!
//! Measurement: a GNSS fix (position and velocity, ECEF, antenna at the IMU — no lever
//! arm), z = (r_gnss − r, v_gnss − v), H = [0 0 I 0 0; 0 I 0 0 0], R diagonal from the
//! fix's sigmas. The update is the Joseph form; a fix whose innovation exceeds
//! [`GnssConfig::gate_sigma`] standard deviations in any component is refused and
//! counted. After an update the error estimate is fed back (position, velocity, attitude
//! q ← q(φ̂) ∘ q, biases) and reset to zero.
//!
//! No heap, no panics: matrix sizes are fixed; a failed factorisation refuses the fix.

use nalgebra::{Cholesky, Matrix3, SMatrix, SVector, UnitQuaternion, Vector3};

use super::{wgs84, Corrections, NavError, NavState, Strapdown};
pub use crate::frames::gnss::GnssFix;
use crate::math;
use crate::state_map::state_struct;

/// Error-state dimension.
pub const N_X: usize = 15;
/// Navigation steps per covariance propagation (80 × 1.25 ms = 0.1 s).
pub const PROPAGATE_STEPS: u32 = 80;

pub(super) type MatX = SMatrix<f64, N_X, N_X>;
type VecX = SVector<f64, N_X>;

/// Filter tuning (1σ initial uncertainties and noise densities).
#[derive(Debug, Clone, Copy, PartialEq, bytemuck::AnyBitPattern)]
pub struct GnssConfig {
    /// Initial attitude uncertainty, rad.
    pub init_att_rad: f64,
    /// Initial velocity uncertainty, m/s.
    pub init_vel_m_s: f64,
    /// Initial position uncertainty, m.
    pub init_pos_m: f64,
    /// Initial accelerometer bias uncertainty, m/s².
    pub init_accel_bias_m_s2: f64,
    /// Initial gyro bias uncertainty, rad/s.
    pub init_gyro_bias_rad_s: f64,
    /// Angle random walk, rad/√s.
    pub arw_rad_sqrt_s: f64,
    /// Velocity random walk, m/s/√s.
    pub vrw_m_s_sqrt_s: f64,
    /// Accelerometer bias random walk, m/s²/√s (also absorbs scale and misalignment).
    pub accel_bias_rw_m_s2_sqrt_s: f64,
    /// Gyro bias random walk, rad/s/√s.
    pub gyro_bias_rw_rad_s_sqrt_s: f64,
    /// Innovation gate, standard deviations.
    pub gate_sigma: f64,
}

/// Why a fix was not used.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub enum GnssError {
    /// A value of the fix is not finite or a sigma not positive.
    BadFix,
    /// The innovation is outside the gate.
    Gated,
    /// The innovation covariance could not be factorised.
    Singular,
    /// The corrected state was refused by the navigation.
    Nav(NavError),
}

state_struct! {
    /// Strapdown navigation with loosely coupled GNSS aiding. Every bit pattern of it is
    /// a value (`crate::state`). Declared once ([`crate::state_map::state_struct!`]):
    /// `reset(Keep)`/`reset(Part)` mark what the reset snapshot carries
    /// ([`super::snapshot`]); the tuning is checked by the snapshot's setup digest.
    #[derive(Debug, Clone, Copy, PartialEq, bytemuck::AnyBitPattern)]
    pub struct AidedNav {
        pub(super) nav: Strapdown = nav, map(Strapdown::STATE_MAP), reset(Part);
        pub(super) cfg: GnssConfig = cfg;
        pub(super) p: MatX = MatX::from_diagonal(&d), reset(Keep);
        pub(super) accel_bias_m_s2: Vector3<f64> = Vector3::zeros(), reset(Keep);
        pub(super) gyro_bias_rad_s: Vector3<f64> = Vector3::zeros(), reset(Keep);
        /// Σ of the specific-force increments in ECEF since the last propagation, m/s.
        pub(super) sum_dv_e_m_s: Vector3<f64> = Vector3::zeros(), reset(Keep);
        /// Steps since the last propagation.
        pub(super) pending_steps: u32 = 0, reset(Keep);
        pub(super) updates: u32 = 0, reset(Keep);
        pub(super) refused: u32 = 0, reset(Keep);
    }
    snapshot {
        /// The filter's fields a reset snapshot carries ([`super::snapshot`]).
        record: AidedNavKept
    }
    constructor
    /// Starts from `state` with step `dt_s`.
    pub fn new(state: NavState, dt_s: f64, cfg: GnssConfig) -> Result<Self, NavError> => Ok {
        let nav = Strapdown::new(state, dt_s, Corrections::ALL)?;
        let mut d = VecX::zeros();
        let sig =
            [cfg.init_att_rad, cfg.init_vel_m_s, cfg.init_pos_m, cfg.init_accel_bias_m_s2, cfg.init_gyro_bias_rad_s];
        for (i, v) in d.iter_mut().enumerate() {
            let s = sig.get(i / 3).copied().unwrap_or(0.0);
            *v = s * s;
        }
    }
}

fn skew(v: &Vector3<f64>) -> Matrix3<f64> {
    Matrix3::new(0.0, -v.z, v.y, v.z, 0.0, -v.x, -v.y, v.x, 0.0)
}

fn finite(v: &Vector3<f64>) -> bool {
    v.x.is_finite() && v.y.is_finite() && v.z.is_finite()
}

/// What [`AidedNav::step_deferred`] reads and advances, borrowed: the navigation unit
/// runs the step on copies of them (`crate::nav::unit`, the step computed twice).
pub(super) struct StepParts<'a> {
    pub(super) nav: &'a mut Strapdown,
    pub(super) accel_bias_m_s2: &'a Vector3<f64>,
    pub(super) gyro_bias_rad_s: &'a Vector3<f64>,
    pub(super) sum_dv_e_m_s: &'a mut Vector3<f64>,
    pub(super) pending_steps: &'a mut u32,
}

impl StepParts<'_> {
    /// [`AidedNav::step_deferred`] on the parts (one compiled copy for the unit's runs
    /// and a resume's bridge).
    #[inline(never)]
    pub(super) fn step(&mut self, dtheta_rad: &Vector3<f64>, dv_m_s: &Vector3<f64>) -> Result<(), NavError> {
        let dt = self.nav.dt_s();
        let dth = dtheta_rad - self.gyro_bias_rad_s * dt;
        let dv = dv_m_s - self.accel_bias_m_s2 * dt;
        self.nav.step(&dth, &dv)?;
        *self.sum_dv_e_m_s += math::rotate(&self.nav.state().q_eb, &dv);
        *self.pending_steps = self.pending_steps.saturating_add(1);
        Ok(())
    }
}

impl AidedNav {
    /// Navigation state.
    pub fn state(&self) -> &NavState {
        self.nav.state()
    }

    /// Estimated accelerometer bias (body), m/s², and gyro bias (body), rad/s.
    pub fn biases(&self) -> (Vector3<f64>, Vector3<f64>) {
        (self.accel_bias_m_s2, self.gyro_bias_rad_s)
    }

    /// 1σ position and velocity uncertainty (root of the trace of each 3×3 block), m, m/s.
    pub fn sigma_pos_vel(&self) -> (f64, f64) {
        let d = self.p.diagonal();
        let pos = d.fixed_rows::<3>(6).sum().max(0.0);
        let vel = d.fixed_rows::<3>(3).sum().max(0.0);
        (math::sqrt(pos), math::sqrt(vel))
    }

    /// Fixes used and refused.
    pub fn counts(&self) -> (u32, u32) {
        (self.updates, self.refused)
    }

    /// One navigation step with the increments of the step (the bias estimates are
    /// removed here); propagates the covariance every [`PROPAGATE_STEPS`] steps.
    /// Equal to [`AidedNav::step_deferred`] followed, when [`AidedNav::propagation_due`],
    /// by [`AidedNav::propagate`].
    pub fn step(&mut self, dtheta_rad: &Vector3<f64>, dv_m_s: &Vector3<f64>) -> Result<(), NavError> {
        self.step_deferred(dtheta_rad, dv_m_s)?;
        if self.propagation_due() {
            self.propagate();
        }
        Ok(())
    }

    /// The strapdown part of [`AidedNav::step`] alone: the covariance propagation, even
    /// when due, is left to the caller ([`AidedNav::propagate`], or the next
    /// [`AidedNav::gnss_update`], which propagates first). Lets a unit run the heavy
    /// 15×15 products after the step's output (`crate::nav::unit`).
    pub fn step_deferred(&mut self, dtheta_rad: &Vector3<f64>, dv_m_s: &Vector3<f64>) -> Result<(), NavError> {
        let mut parts = StepParts {
            nav: &mut self.nav,
            accel_bias_m_s2: &self.accel_bias_m_s2,
            gyro_bias_rad_s: &self.gyro_bias_rad_s,
            sum_dv_e_m_s: &mut self.sum_dv_e_m_s,
            pending_steps: &mut self.pending_steps,
        };
        parts.step(dtheta_rad, dv_m_s)
    }

    /// Whether [`PROPAGATE_STEPS`] or more steps have passed since the last propagation.
    pub fn propagation_due(&self) -> bool {
        self.pending_steps >= PROPAGATE_STEPS
    }

    /// Propagates the covariance over the steps since the last propagation (nothing
    /// when there were none): Φ = I + F T + (F T)²/2, P ← Φ P Φᵀ + Q_c T.
    pub fn propagate(&mut self) {
        if self.pending_steps == 0 {
            return;
        }
        let t = f64::from(self.pending_steps) * self.nav.dt_s();
        let f_e = self.sum_dv_e_m_s / t;
        self.sum_dv_e_m_s = Vector3::zeros();
        self.pending_steps = 0;
        let s = self.nav.state();
        let c = UnitQuaternion::new_unchecked(s.q_eb).to_rotation_matrix().into_inner();
        let w = Vector3::new(0.0, 0.0, wgs84::EARTH_RATE_RAD_S);
        let r2 = s.r_e_m.norm_squared().max(wgs84::MIN_RADIUS_M * wgs84::MIN_RADIUS_M);
        let r = math::sqrt(r2);
        let u = s.r_e_m / r;
        let gamma = (u * u.transpose() * 3.0 - Matrix3::identity()) * (wgs84::GM_M3_S2 / (r2 * r));
        let mut f = MatX::zeros();
        f.fixed_view_mut::<3, 3>(0, 0).copy_from(&(-skew(&w)));
        f.fixed_view_mut::<3, 3>(0, 12).copy_from(&(-c));
        f.fixed_view_mut::<3, 3>(3, 0).copy_from(&(-skew(&f_e)));
        f.fixed_view_mut::<3, 3>(3, 3).copy_from(&(-skew(&w) * 2.0));
        f.fixed_view_mut::<3, 3>(3, 6).copy_from(&gamma);
        f.fixed_view_mut::<3, 3>(3, 9).copy_from(&(-c));
        f.fixed_view_mut::<3, 3>(6, 3).copy_from(&Matrix3::identity());
        let ft = f * t;
        let phi = MatX::identity() + ft + ft * ft * 0.5;
        let q = [
            self.cfg.arw_rad_sqrt_s,
            self.cfg.vrw_m_s_sqrt_s,
            0.0,
            self.cfg.accel_bias_rw_m_s2_sqrt_s,
            self.cfg.gyro_bias_rw_rad_s_sqrt_s,
        ];
        let mut qd = VecX::zeros();
        for (i, v) in qd.iter_mut().enumerate() {
            let s = q.get(i / 3).copied().unwrap_or(0.0);
            *v = s * s * t;
        }
        let p = phi * self.p * phi.transpose() + MatX::from_diagonal(&qd);
        self.p = (p + p.transpose()) * 0.5;
    }

    /// Applies a GNSS fix valid now (at the end of the last step).
    pub fn gnss_update(&mut self, fix: &GnssFix) -> Result<(), GnssError> {
        let ok = finite(&fix.r_e_m)
            && finite(&fix.v_e_m_s)
            && fix.sigma_pos_m.is_finite()
            && fix.sigma_pos_m > 0.0
            && fix.sigma_vel_m_s.is_finite()
            && fix.sigma_vel_m_s > 0.0;
        if !ok {
            self.refused = self.refused.saturating_add(1);
            return Err(GnssError::BadFix);
        }
        self.propagate();
        let s = *self.nav.state();
        let dr = fix.r_e_m - s.r_e_m;
        let dv = fix.v_e_m_s - s.v_e_m_s;
        let z = SVector::<f64, 6>::new(dr.x, dr.y, dr.z, dv.x, dv.y, dv.z);
        let mut h = SMatrix::<f64, 6, N_X>::zeros();
        h.fixed_view_mut::<3, 3>(0, 6).copy_from(&Matrix3::identity());
        h.fixed_view_mut::<3, 3>(3, 3).copy_from(&Matrix3::identity());
        let (vp, vv) = (fix.sigma_pos_m * fix.sigma_pos_m, fix.sigma_vel_m_s * fix.sigma_vel_m_s);
        let r = SMatrix::<f64, 6, 6>::from_diagonal(&SVector::<f64, 6>::new(vp, vp, vp, vv, vv, vv));
        let hp = h * self.p;
        let s_mat = hp * h.transpose() + r;
        let gate2 = self.cfg.gate_sigma * self.cfg.gate_sigma;
        if z.iter().zip(s_mat.diagonal().iter()).any(|(zi, si)| zi * zi > gate2 * si) {
            self.refused = self.refused.saturating_add(1);
            return Err(GnssError::Gated);
        }
        let Some(chol) = Cholesky::new(s_mat) else {
            self.refused = self.refused.saturating_add(1);
            return Err(GnssError::Singular);
        };
        // K = P Hᵀ S⁻¹ = (S⁻¹ H P)ᵀ (P and S symmetric).
        let k = chol.solve(&hp).transpose();
        let x = k * z;
        let ikh = MatX::identity() - k * h;
        let p = ikh * self.p * ikh.transpose() + k * r * k.transpose();
        // Feedback.
        let part = |i: usize| -> Vector3<f64> { x.fixed_rows::<3>(i).into_owned() };
        let corrected = NavState {
            q_eb: math::quat_from_rotvec(&part(0)) * s.q_eb,
            v_e_m_s: s.v_e_m_s + part(3),
            r_e_m: s.r_e_m + part(6),
        };
        self.nav.set_state(corrected).map_err(GnssError::Nav)?;
        self.accel_bias_m_s2 += part(9);
        self.gyro_bias_rad_s += part(12);
        self.p = (p + p.transpose()) * 0.5;
        self.updates = self.updates.saturating_add(1);
        Ok(())
    }
}
