//! Launch-vehicle ascent truth: vertical rise, pitch program, staging-like steps of the
//! thrust acceleration, vibration; the exact body increments a strapdown unit would
//! measure over each step, and the truth state in ECEF to compare the navigation with.
//!
//! The motion is defined in an Earth-centred inertial frame I that coincides with ECEF
//! at t = 0 (Z the polar axis; ECEF turns at ω_ie about Z):
//!
//! - attitude, analytic: q_ib(t) = q_0 ∘ q_z(a(t)) ∘ q_y(b(t)) ∘ q_x(c(t)), where q_0
//!   puts body X up (geodetic normal at the pad), body Y downrange (launch azimuth) and
//!   body Z = X × Y across the pitch plane, frozen in inertial space at lift-off (an
//!   inertial launch frame, as launch vehicles fly their programs). a is the pitch program
//!   (a rotation about body Z tips X from up toward downrange) plus a pitch vibration; b
//!   and c are a yaw and a roll vibration in quadrature (a coning motion) and c carries a
//!   roll program. The body rate of this Z-Y-X sequence is
//!   ω = (ċ − ȧ sin b, ḃ cos c + ȧ cos b sin c, ȧ cos b cos c − ḃ sin c).
//! - specific force, analytic in body axes: thrust along body X whose magnitude follows
//!   the stages (each a linear ramp switched on and off by ½(1 + tanh(t/τ)) steps, so a
//!   staging drops it to zero within a few τ and an ignition brings it back), plus
//!   sinusoidal linear vibration; the Z-axis vibration is in phase with the yaw
//!   vibration (a sculling motion).
//! - translation: r̈_i = C_ib(t) f_b(t) + γ(r_i), γ the WGS-84 J2 gravitation (symmetric
//!   about Z, so the same function as in ECEF), integrated by classical RK4 with
//!   [`LaunchTruth::SUBSTEPS`] sub-steps per sensor step. Starting on the pad:
//!   r_i(0) = r_pad, v_i(0) = ω_ie × r_pad.
//! - increments: α = ∫ω dt and υ = ∫f_b dt over each step by 6-point Gauss–Legendre;
//!   the integrands are analytic with their fastest feature (47 Hz, τ = 10 ms) far
//!   slower than the step, so the quadrature error is at the rounding level.
//!
//! Truth in ECEF at t: r_e = R_z(−ω_ie t) r_i, v_e = R_z(−ω_ie t)(v_i − ω_ie × r_i),
//! q_eb = q_z(−ω_ie t) ∘ q_ib.

use nalgebra::{Matrix3, Quaternion, Rotation3, UnitQuaternion, Vector3};
use serde::{Deserialize, Serialize};
use ssis::nav::wgs84;

/// One propulsion stage: thrust acceleration (specific force along body X) ramping
/// linearly from `start_m_s2` to `end_m_s2` between ignition and cut-off.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Stage {
    /// Ignition time, s (centre of the tanh switch-on).
    pub ignition_s: f64,
    /// Cut-off time, s (centre of the tanh switch-off).
    pub cutoff_s: f64,
    /// Thrust acceleration at ignition, m/s².
    pub start_m_s2: f64,
    /// Thrust acceleration at cut-off, m/s².
    pub end_m_s2: f64,
}

/// A sinusoid amplitude·sin(2π f t + phase).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Sine {
    /// Amplitude (unit of the quantity it drives).
    pub amplitude: f64,
    /// Frequency, Hz.
    pub freq_hz: f64,
    /// Phase, rad.
    pub phase_rad: f64,
}

impl Sine {
    /// Value and time derivative at t.
    fn eval(&self, t: f64) -> (f64, f64) {
        let w = 2.0 * std::f64::consts::PI * self.freq_hz;
        let (s, c) = (w * t + self.phase_rad).sin_cos();
        (self.amplitude * s, self.amplitude * w * c)
    }
}

/// The ascent.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LaunchProfile {
    /// Pad geodetic latitude, degrees.
    pub lat_deg: f64,
    /// Pad longitude, degrees.
    pub lon_deg: f64,
    /// Pad ellipsoidal height, m.
    pub height_m: f64,
    /// Launch azimuth (downrange direction from north toward east), degrees.
    pub azimuth_deg: f64,
    /// End of the vertical rise (start of the pitch program), s.
    pub vertical_end_s: f64,
    /// End of the pitch program, s.
    pub pitch_end_s: f64,
    /// Pitch angle from the vertical at the end of the program, degrees (quintic
    /// smoothstep 10u³ − 15u⁴ + 6u⁵ from 0).
    pub pitch_final_deg: f64,
    /// Roll program: start, end (s) and angle (degrees), same smoothstep.
    pub roll_program: [f64; 3],
    /// Stages.
    pub stages: Vec<Stage>,
    /// Time constant τ of the tanh thrust switches, s.
    pub switch_tau_s: f64,
    /// Pitch vibration (rad), added to a.
    pub vib_pitch: Sine,
    /// Yaw vibration (rad), b.
    pub vib_yaw: Sine,
    /// Roll vibration (rad), added to c.
    pub vib_roll: Sine,
    /// Linear vibration along body X, Y, Z (m/s²).
    pub vib_linear: [Sine; 3],
}

impl Default for LaunchProfile {
    /// A 600 s three-stage ascent from 45.6° N, 63.3° E (a mid-latitude pad), azimuth
    /// 60°: 10 s vertical rise, pitch over to 92° from the vertical by 220 s, a 20° roll
    /// program in 4–12 s, stagings at 150 s and 420 s with 2 s and 1.5 s coasts, thrust
    /// 15 → 42, 9 → 22 and 6 → 14 m/s² (inside the unit's ±85 m/s² range); vibration:
    /// 5e-5 rad coning at 23 Hz (yaw/roll in quadrature), 2e-5 rad pitch at 11 Hz,
    /// linear 5 / 2 / 3 m/s² at 47 / 31 / 23 Hz (X / Y / Z; Z in phase with the yaw
    /// vibration: sculling).
    fn default() -> Self {
        let sine = |amplitude: f64, freq_hz: f64, phase_rad: f64| Sine { amplitude, freq_hz, phase_rad };
        LaunchProfile {
            lat_deg: 45.6,
            lon_deg: 63.3,
            height_m: 100.0,
            azimuth_deg: 60.0,
            vertical_end_s: 10.0,
            pitch_end_s: 220.0,
            pitch_final_deg: 92.0,
            roll_program: [4.0, 12.0, 20.0],
            stages: vec![
                Stage { ignition_s: -1.0, cutoff_s: 150.0, start_m_s2: 15.0, end_m_s2: 42.0 },
                Stage { ignition_s: 152.0, cutoff_s: 420.0, start_m_s2: 9.0, end_m_s2: 22.0 },
                Stage { ignition_s: 421.5, cutoff_s: 700.0, start_m_s2: 6.0, end_m_s2: 14.0 },
            ],
            switch_tau_s: 0.01,
            vib_pitch: sine(2e-5, 11.0, 0.0),
            vib_yaw: sine(5e-5, 23.0, 0.0),
            vib_roll: sine(5e-5, 23.0, std::f64::consts::FRAC_PI_2),
            vib_linear: [sine(5.0, 47.0, 0.3), sine(2.0, 31.0, 1.1), sine(3.0, 23.0, 0.0)],
        }
    }
}

/// Quintic smoothstep on [0, 1] and its derivative in u.
fn smoothstep(u: f64) -> (f64, f64) {
    if u <= 0.0 {
        (0.0, 0.0)
    } else if u >= 1.0 {
        (1.0, 0.0)
    } else {
        let u2 = u * u;
        (u2 * u * (10.0 - 15.0 * u + 6.0 * u2), 30.0 * u2 * (1.0 - 2.0 * u + u2))
    }
}

fn quat_axis(axis: usize, angle_rad: f64) -> Quaternion<f64> {
    let (s, c) = (0.5 * angle_rad).sin_cos();
    match axis {
        0 => Quaternion::new(c, s, 0.0, 0.0),
        1 => Quaternion::new(c, 0.0, s, 0.0),
        _ => Quaternion::new(c, 0.0, 0.0, s),
    }
}

/// Rotates v by unit quaternion q.
fn rot(q: &Quaternion<f64>, v: &Vector3<f64>) -> Vector3<f64> {
    (q * Quaternion::from_imag(*v) * q.conjugate()).imag()
}

impl LaunchProfile {
    /// Pad position, ECEF, m.
    pub fn pad_ecef_m(&self) -> Vector3<f64> {
        wgs84::ecef_from_geodetic(self.lat_deg.to_radians(), self.lon_deg.to_radians(), self.height_m)
    }

    /// q_0: body axes (up, downrange, cross-range) in the inertial frame at lift-off.
    pub fn q0(&self) -> Quaternion<f64> {
        let (lat, lon, az) = (self.lat_deg.to_radians(), self.lon_deg.to_radians(), self.azimuth_deg.to_radians());
        let up = Vector3::new(lat.cos() * lon.cos(), lat.cos() * lon.sin(), lat.sin());
        let east = Vector3::new(-lon.sin(), lon.cos(), 0.0);
        let north = up.cross(&east);
        let down_range = north * az.cos() + east * az.sin();
        let cross = up.cross(&down_range);
        let m = Matrix3::from_columns(&[up, down_range, cross]);
        *UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(m)).quaternion()
    }

    /// Euler angles (a, b, c) and their rates at t.
    fn angles(&self, t: f64) -> ([f64; 3], [f64; 3]) {
        let span = self.pitch_end_s - self.vertical_end_s;
        let (sp, dsp) = smoothstep((t - self.vertical_end_s) / span);
        let pf = self.pitch_final_deg.to_radians();
        let [r0, r1, rdeg] = self.roll_program;
        let (sr, dsr) = smoothstep((t - r0) / (r1 - r0));
        let rf = rdeg.to_radians();
        let (pv, dpv) = self.vib_pitch.eval(t);
        let (yv, dyv) = self.vib_yaw.eval(t);
        let (rv, drv) = self.vib_roll.eval(t);
        ([pf * sp + pv, yv, rf * sr + rv], [pf * dsp / span + dpv, dyv, rf * dsr / (r1 - r0) + drv])
    }

    /// Attitude of the body in the inertial frame, q_ib(t).
    pub fn q_ib(&self, t: f64) -> Quaternion<f64> {
        let ([a, b, c], _) = self.angles(t);
        self.q0() * quat_axis(2, a) * quat_axis(1, b) * quat_axis(0, c)
    }

    /// Body rate ω_ib^b at t, rad/s (the Z-Y-X Euler kinematics).
    pub fn omega_b_rad_s(&self, t: f64) -> Vector3<f64> {
        let ([_, b, c], [da, db, dc]) = self.angles(t);
        let (sb, cb) = b.sin_cos();
        let (sc, cc) = c.sin_cos();
        Vector3::new(dc - da * sb, db * cc + da * cb * sc, da * cb * cc - db * sc)
    }

    /// Thrust acceleration (specific force along body X, without vibration) at t, m/s².
    pub fn thrust_m_s2(&self, t: f64) -> f64 {
        let on = |x: f64| 0.5 * (1.0 + (x / self.switch_tau_s).tanh());
        self.stages
            .iter()
            .map(|s| {
                let u = (t - s.ignition_s) / (s.cutoff_s - s.ignition_s);
                let level = s.start_m_s2 + (s.end_m_s2 - s.start_m_s2) * u;
                level * on(t - s.ignition_s) * (1.0 - on(t - s.cutoff_s))
            })
            .sum()
    }

    /// Specific force in body axes at t, m/s².
    pub fn f_b_m_s2(&self, t: f64) -> Vector3<f64> {
        let [vx, vy, vz] = self.vib_linear;
        Vector3::new(self.thrust_m_s2(t) + vx.eval(t).0, vy.eval(t).0, vz.eval(t).0)
    }

    /// Inertial acceleration at (t, r_i).
    fn accel_i(&self, t: f64, q0: &Quaternion<f64>, r_i: &Vector3<f64>) -> Vector3<f64> {
        let ([a, b, c], _) = self.angles(t);
        let q = q0 * quat_axis(2, a) * quat_axis(1, b) * quat_axis(0, c);
        let g = wgs84::gravitation_m_s2(r_i).unwrap_or_else(Vector3::zeros);
        rot(&q, &self.f_b_m_s2(t)) + g
    }
}

/// Truth of one sensor step.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StepTruth {
    /// Time at the end of the step, s.
    pub t_s: f64,
    /// ∫ω_ib^b dt over the step, rad.
    pub dtheta_rad: Vector3<f64>,
    /// ∫f^b dt over the step, m/s.
    pub dv_m_s: Vector3<f64>,
    /// q_eb at the end of the step.
    pub q_eb: Quaternion<f64>,
    /// ECEF velocity at the end of the step, m/s.
    pub v_e_m_s: Vector3<f64>,
    /// ECEF position at the end of the step, m.
    pub r_e_m: Vector3<f64>,
}

/// Steps the ascent truth one sensor interval at a time.
pub struct LaunchTruth {
    profile: LaunchProfile,
    q0: Quaternion<f64>,
    dt_s: f64,
    k: u64,
    substeps: u32,
    r_i: Vector3<f64>,
    v_i: Vector3<f64>,
}

/// 6-point Gauss–Legendre nodes and weights on [−1, 1].
const GL6: [(f64, f64); 6] = [
    (-0.932_469_514_203_152, 0.171_324_492_379_170),
    (-0.661_209_386_466_265, 0.360_761_573_048_139),
    (-0.238_619_186_083_197, 0.467_913_934_572_691),
    (0.238_619_186_083_197, 0.467_913_934_572_691),
    (0.661_209_386_466_265, 0.360_761_573_048_139),
    (0.932_469_514_203_152, 0.171_324_492_379_170),
];

impl LaunchTruth {
    /// RK4 sub-steps per sensor step.
    pub const SUBSTEPS: u32 = 4;

    /// Starts on the pad at t = 0 with sensor step `dt_s`.
    pub fn new(profile: LaunchProfile, dt_s: f64) -> Self {
        Self::with_substeps(profile, dt_s, Self::SUBSTEPS)
    }

    /// As [`LaunchTruth::new`] with `substeps` RK4 sub-steps per sensor step (to check
    /// that the truth has converged).
    pub fn with_substeps(profile: LaunchProfile, dt_s: f64, substeps: u32) -> Self {
        let r_i = profile.pad_ecef_m();
        let v_i = Vector3::new(0.0, 0.0, wgs84::EARTH_RATE_RAD_S).cross(&r_i);
        let q0 = profile.q0();
        LaunchTruth { profile, q0, dt_s, k: 0, substeps: substeps.max(1), r_i, v_i }
    }

    /// The profile.
    pub fn profile(&self) -> &LaunchProfile {
        &self.profile
    }

    /// Time now, s.
    pub fn t_s(&self) -> f64 {
        self.k as f64 * self.dt_s
    }

    /// Truth state now (ECEF).
    pub fn state_now(&self) -> (Quaternion<f64>, Vector3<f64>, Vector3<f64>) {
        to_ecef(&self.profile, self.t_s(), &self.r_i, &self.v_i)
    }

    /// Advances one sensor step; returns its increments and the truth at its end.
    pub fn advance(&mut self) -> StepTruth {
        let t0 = self.t_s();
        let t1 = (self.k + 1) as f64 * self.dt_s;
        let p = &self.profile;
        // Increments by Gauss–Legendre.
        let (half, mid) = (0.5 * (t1 - t0), 0.5 * (t1 + t0));
        let mut dtheta = Vector3::zeros();
        let mut dv = Vector3::zeros();
        for (x, w) in GL6 {
            let t = mid + half * x;
            dtheta += p.omega_b_rad_s(t) * (w * half);
            dv += p.f_b_m_s2(t) * (w * half);
        }
        // Translation by RK4.
        let n = self.substeps;
        let h = (t1 - t0) / f64::from(n);
        for j in 0..n {
            let t = t0 + f64::from(j) * h;
            let (r, v) = (self.r_i, self.v_i);
            let a1 = p.accel_i(t, &self.q0, &r);
            let a2 = p.accel_i(t + 0.5 * h, &self.q0, &(r + v * (0.5 * h)));
            let v2 = v + a1 * (0.5 * h);
            let a3 = p.accel_i(t + 0.5 * h, &self.q0, &(r + v2 * (0.5 * h)));
            let v3 = v + a2 * (0.5 * h);
            let a4 = p.accel_i(t + h, &self.q0, &(r + v3 * h));
            let v4 = v + a3 * h;
            self.r_i = r + (v + v2 * 2.0 + v3 * 2.0 + v4) * (h / 6.0);
            self.v_i = v + (a1 + a2 * 2.0 + a3 * 2.0 + a4) * (h / 6.0);
        }
        self.k += 1;
        let (q_eb, v_e_m_s, r_e_m) = self.state_now();
        StepTruth { t_s: t1, dtheta_rad: dtheta, dv_m_s: dv, q_eb, v_e_m_s, r_e_m }
    }
}

/// Inertial state at t to ECEF (q_eb, v_e, r_e).
fn to_ecef(
    p: &LaunchProfile,
    t: f64,
    r_i: &Vector3<f64>,
    v_i: &Vector3<f64>,
) -> (Quaternion<f64>, Vector3<f64>, Vector3<f64>) {
    let w = wgs84::EARTH_RATE_RAD_S;
    let q_ei = quat_axis(2, -w * t);
    let r_e = rot(&q_ei, r_i);
    let v_rel = v_i - Vector3::new(0.0, 0.0, w).cross(r_i);
    (q_ei * p.q_ib(t), rot(&q_ei, &v_rel), r_e)
}
