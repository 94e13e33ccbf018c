//! Truth motion of the instrument frame (ICS) in the inertial frame (2ECS).
//!
//! The body rate ω(t) (ICS components) is the sum of a constant base rate (orbital-rate
//! Earth pointing: −ω_orb about Y), rest-to-rest slews with a versine rate profile
//! (the paper's 360° calibration maneuver is one long slew), an optional coning motion,
//! and optional flexible-appendage modes after the paper's dynamics
//!
//! ```text
//! I ω̇ + ω × I ω + L ẍ = M,     ẍ + K ẋ + C x = Q ω̇
//! ```
//!
//! taken one mode at a time and linearised: the appendage coordinate x_j is driven by the
//! rigid slew acceleration along its axis, and the hub's rate is reduced by the momentum
//! the appendage takes, δω = −(I⁻¹L)_j ẋ_j.
//!
//! [`Truth::advance`] integrates one sensor interval: the exact angle increment ∫ω dt
//! (Gauss–Legendre, 3 points per sub-step) and Λ at the end (RK4 on Λ̇ = ½ Λ ∘ ω, same
//! sub-steps), both to ~1e-15 rad for the motions here. For pure coning the attitude
//! is analytic.

use nalgebra::{Quaternion, UnitQuaternion, Vector3};
use serde::{Deserialize, Serialize};

/// One rest-to-rest slew: rate u·A/D·(1 − cos 2πτ/D), τ ∈ [0, D].
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Slew {
    /// Start time, s.
    pub start_s: f64,
    /// Duration, s.
    pub duration_s: f64,
    /// Axis in ICS (normalised on use).
    pub axis: [f64; 3],
    /// Angle, degrees.
    pub angle_deg: f64,
}

impl Slew {
    fn rate_and_accel(&self, t: f64) -> (Vector3<f64>, Vector3<f64>) {
        let tau = t - self.start_s;
        if !(0.0..=self.duration_s).contains(&tau) || self.duration_s <= 0.0 {
            return (Vector3::zeros(), Vector3::zeros());
        }
        let u = Vector3::from(self.axis).normalize();
        let a = self.angle_deg.to_radians();
        let w = 2.0 * std::f64::consts::PI / self.duration_s;
        let rate = a / self.duration_s * (1.0 - (w * tau).cos());
        let acc = a / self.duration_s * w * (w * tau).sin();
        (u * rate, u * acc)
    }
}

/// Coning: Λ(t) = Λ0 ∘ (cos(α/2), sin(α/2) cos Ωt, sin(α/2) sin Ωt, 0).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ConingMotion {
    /// Half-angle α, degrees.
    pub half_angle_deg: f64,
    /// Coning frequency Ω/2π, Hz.
    pub freq_hz: f64,
}

/// One flexible-appendage mode (see the module doc).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FlexMode {
    /// Natural frequency, Hz (C = ω_n²).
    pub freq_hz: f64,
    /// Damping ratio (K = 2 ζ ω_n).
    pub damping: f64,
    /// Axis in ICS along which the mode couples (normalised on use).
    pub axis: [f64; 3],
    /// Q: modal excitation per rad/s² of hub acceleration along the axis.
    pub q_gain: f64,
    /// (I⁻¹L): hub rate per unit modal velocity, rad/s per (1/s).
    pub l_gain: f64,
}

/// The motion of a scenario.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
#[serde(deny_unknown_fields)]
pub struct MotionSpec {
    /// Constant body rate, °/s (Earth pointing at orbital rate: [0, −360/T_orb, 0]).
    #[serde(default)]
    pub base_rate_deg_s: [f64; 3],
    /// Slews (and calibration maneuvers).
    #[serde(default)]
    pub slews: Vec<Slew>,
    /// Optional coning (replaces everything else: analytic truth).
    #[serde(default)]
    pub coning: Option<ConingMotion>,
    /// Optional flexible modes.
    #[serde(default)]
    pub modes: Vec<FlexMode>,
    /// Initial attitude Λ0, scalar first (default identity).
    #[serde(default)]
    pub initial_q: Option<[f64; 4]>,
}

impl MotionSpec {
    /// Orbital-rate Earth pointing for an orbit of `period_s`, plus `slews`.
    pub fn earth_pointing(period_s: f64, slews: Vec<Slew>) -> Self {
        MotionSpec { base_rate_deg_s: [0.0, -360.0 / period_s, 0.0], slews, ..Default::default() }
    }

    fn rigid_rate_accel(&self, t: f64) -> (Vector3<f64>, Vector3<f64>) {
        let mut w = Vector3::from(self.base_rate_deg_s).map(f64::to_radians);
        let mut a = Vector3::zeros();
        for s in &self.slews {
            let (ws, as_) = s.rate_and_accel(t);
            w += ws;
            a += as_;
        }
        (w, a)
    }
}

/// One interval of truth.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TruthStep {
    /// Time at the end of the interval, s.
    pub t_s: f64,
    /// ∫ ω dt over the interval (ICS), rad.
    pub dtheta_rad: Vector3<f64>,
    /// Λ at the end of the interval.
    pub q: Quaternion<f64>,
    /// ω at the end of the interval, rad/s.
    pub rate_rad_s: Vector3<f64>,
}

/// Truth generator.
#[derive(Debug, Clone)]
pub struct Truth {
    spec: MotionSpec,
    t_s: f64,
    q: Quaternion<f64>,
    q0: Quaternion<f64>,
    /// Per mode: (x, ẋ).
    modes: Vec<(f64, f64)>,
    substeps: usize,
}

const GL3: [(f64, f64); 3] =
    [(-0.774_596_669_241_483_4, 5.0 / 9.0), (0.0, 8.0 / 9.0), (0.774_596_669_241_483_4, 5.0 / 9.0)];

impl Truth {
    /// Starts the motion at t = 0.
    pub fn new(spec: MotionSpec) -> Self {
        let q0 = spec
            .initial_q
            .map(|[w, x, y, z]| UnitQuaternion::from_quaternion(Quaternion::new(w, x, y, z)).into_inner())
            .unwrap_or_else(Quaternion::identity);
        let n = spec.modes.len();
        // Coning: Λ(0) = Λ0 ∘ (cos α/2, sin α/2, 0, 0).
        let q = match &spec.coning {
            Some(c) => {
                let a = c.half_angle_deg.to_radians();
                q0 * Quaternion::new((a / 2.0).cos(), (a / 2.0).sin(), 0.0, 0.0)
            }
            None => q0,
        };
        Truth { spec, t_s: 0.0, q, q0, modes: vec![(0.0, 0.0); n], substeps: 4 }
    }

    /// Λ now.
    pub fn quaternion(&self) -> Quaternion<f64> {
        self.q
    }

    /// Time now, s.
    pub fn time_s(&self) -> f64 {
        self.t_s
    }

    /// Rate at time `t` with mode state `modes` (flexible part included).
    fn rate(&self, t: f64, modes: &[(f64, f64)]) -> Vector3<f64> {
        if let Some(c) = &self.spec.coning {
            let (a, w) = (c.half_angle_deg.to_radians(), 2.0 * std::f64::consts::PI * c.freq_hz);
            return Vector3::new(-w * a.sin() * (w * t).sin(), w * a.sin() * (w * t).cos(), -w * (1.0 - a.cos()));
        }
        let (mut w, _) = self.spec.rigid_rate_accel(t);
        for (m, (_, xd)) in self.spec.modes.iter().zip(modes) {
            w -= Vector3::from(m.axis).normalize() * (m.l_gain * xd);
        }
        w
    }

    /// Derivative of the mode states at `t`.
    fn mode_deriv(&self, t: f64, modes: &[(f64, f64)]) -> Vec<(f64, f64)> {
        let (_, acc) = self.spec.rigid_rate_accel(t);
        self.spec
            .modes
            .iter()
            .zip(modes)
            .map(|(m, &(x, xd))| {
                let wn = 2.0 * std::f64::consts::PI * m.freq_hz;
                let drive = m.q_gain * Vector3::from(m.axis).normalize().dot(&acc);
                (xd, drive - 2.0 * m.damping * wn * xd - wn * wn * x)
            })
            .collect()
    }

    /// Advances by `dt_s`; returns the increment and the new attitude.
    pub fn advance(&mut self, dt_s: f64) -> TruthStep {
        let t0 = self.t_s;
        let t1 = t0 + dt_s;
        if let Some(c) = self.spec.coning {
            // Analytic: ∫ω and Λ(t).
            let (a, w) = (c.half_angle_deg.to_radians(), 2.0 * std::f64::consts::PI * c.freq_hz);
            let dth = Vector3::new(
                a.sin() * ((w * t1).cos() - (w * t0).cos()),
                a.sin() * ((w * t1).sin() - (w * t0).sin()),
                -w * (1.0 - a.cos()) * dt_s,
            );
            let (s, ch) = ((a / 2.0).sin(), (a / 2.0).cos());
            self.q = self.q0 * Quaternion::new(ch, s * (w * t1).cos(), s * (w * t1).sin(), 0.0);
            self.t_s = t1;
            return TruthStep { t_s: t1, dtheta_rad: dth, q: self.q, rate_rad_s: self.rate(t1, &[]) };
        }
        let h = dt_s / self.substeps as f64;
        let mut dth = Vector3::zeros();
        for k in 0..self.substeps {
            let ta = t0 + k as f64 * h;
            // Modes: RK4 state at the sub-step nodes (needed for the rates used below).
            let m0 = self.modes.clone();
            let mid_modes = self.rk4_modes(ta, h / 2.0, &m0);
            let end_modes = self.rk4_modes(ta, h, &m0);
            // Gauss–Legendre increment, rates with modes interpolated linearly in the sub-step.
            for (xi, wgt) in GL3 {
                let f = 0.5 * (1.0 + xi);
                let mm: Vec<(f64, f64)> =
                    m0.iter().zip(&end_modes).map(|(a, b)| (a.0 + f * (b.0 - a.0), a.1 + f * (b.1 - a.1))).collect();
                dth += self.rate(ta + f * h, &mm) * (0.5 * h * wgt);
            }
            // RK4 on Λ̇ = ½ Λ ∘ ω.
            let w1 = self.rate(ta, &m0);
            let w2 = self.rate(ta + h / 2.0, &mid_modes);
            let w4 = self.rate(ta + h, &end_modes);
            let f = |q: &Quaternion<f64>, w: &Vector3<f64>| q * Quaternion::from_imag(*w) * 0.5;
            let k1 = f(&self.q, &w1);
            let k2 = f(&(self.q + k1 * (h / 2.0)), &w2);
            let k3 = f(&(self.q + k2 * (h / 2.0)), &w2);
            let k4 = f(&(self.q + k3 * h), &w4);
            self.q += (k1 + k2 * 2.0 + k3 * 2.0 + k4) * (h / 6.0);
            self.q = self.q.normalize();
            self.modes = end_modes;
        }
        self.t_s = t1;
        TruthStep { t_s: t1, dtheta_rad: dth, q: self.q, rate_rad_s: self.rate(t1, &self.modes) }
    }

    fn rk4_modes(&self, t: f64, h: f64, m0: &[(f64, f64)]) -> Vec<(f64, f64)> {
        if m0.is_empty() {
            return Vec::new();
        }
        let add = |a: &[(f64, f64)], d: &[(f64, f64)], s: f64| -> Vec<(f64, f64)> {
            a.iter().zip(d).map(|(x, dx)| (x.0 + s * dx.0, x.1 + s * dx.1)).collect()
        };
        let k1 = self.mode_deriv(t, m0);
        let k2 = self.mode_deriv(t + h / 2.0, &add(m0, &k1, h / 2.0));
        let k3 = self.mode_deriv(t + h / 2.0, &add(m0, &k2, h / 2.0));
        let k4 = self.mode_deriv(t + h, &add(m0, &k3, h));
        m0.iter()
            .enumerate()
            .map(|(i, x)| {
                let g = |k: &Vec<(f64, f64)>| k.get(i).copied().unwrap_or((0.0, 0.0));
                let (a, b, c, d) = (g(&k1), g(&k2), g(&k3), g(&k4));
                (
                    x.0 + h / 6.0 * (a.0 + 2.0 * b.0 + 2.0 * c.0 + d.0),
                    x.1 + h / 6.0 * (a.1 + 2.0 * b.1 + 2.0 * c.1 + d.1),
                )
            })
            .collect()
    }
}
