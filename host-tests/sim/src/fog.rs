//! FOG error model: every term of the calibration table, plus noise.
//!
//! For FOG i with true sensitive axis s_i (from the true misalignment angles):
//!
//! ```text
//! Δθ_i,raw = (1 + k_i) s_i · Δθ' + (b_i + b_i,rand + b_i,rw(t) + thermal_i(T, G)) Δt + n_i
//! ```
//!
//! - Δθ' is the truth increment, or with a triad error (the paper's eq. 4, used for the
//!   Fig. 7 case) Δθ' = Δθ + Δω Δt + (−δK + δΨ) Δθ;
//! - b_i,rand is the turn-on bias drawn once per run, b_i,rw a random walk (rate random
//!   walk σ_u), n_i white angle noise with σ = ARW·√Δt;
//! - T(t) follows [`TemperatureSpec`], G = dT/dt analytic, both at the interval's middle;
//! - the output is quantised by counting: the frame carries the difference of the rounded
//!   running totals, so quantisation never accumulates (like a real FOG's counter).
//!
//! [`FogModel::sample`] also returns the noise-free raw increments, from which the harness
//! computes the systematic rate error the observer ought to estimate.

use nalgebra::{Matrix3, Vector3};
use rand::Rng;
use rand_chacha::ChaCha20Rng;
use rand_distr::{Distribution, StandardNormal};
use serde::{Deserialize, Serialize};
use ssis::calib::{CalibrationTable, FogCal, Misalignment, N_FOG};
use ssis::frames::fog::FogFrame;

use ssis_common::ARCSEC_PER_RAD;

const DEG_H: f64 = std::f64::consts::PI / 180.0 / 3600.0; // rad/s per °/h

/// The paper's triad error form, eq. (4): δω* = Δω + (−δK + δΨ) ω.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TriadError {
    /// Diagonal of δK (scale-factor errors).
    pub dk: [f64; 3],
    /// δΨ, row by row (misalignment matrix as printed in the paper).
    pub dpsi: [[f64; 3]; 3],
    /// Δω, rad/s.
    pub bias_rad_s: [f64; 3],
}

impl TriadError {
    /// The paper's Fig. 7 case.
    pub const FIG7: TriadError = TriadError {
        dk: [-0.005, -0.002, -0.004],
        dpsi: [[0.0, 2.5e-5, -3e-5], [-2.5e-5, 0.0, -2e-5], [3e-5, 2e-5, 0.0]],
        bias_rad_s: [1e-4, 2e-4, -1.5e-4],
    };

    /// −δK + δΨ.
    pub fn matrix(&self) -> Matrix3<f64> {
        let [r0, r1, r2] = self.dpsi;
        Matrix3::from_row_slice(&[r0[0], r0[1], r0[2], r1[0], r1[1], r1[2], r2[0], r2[1], r2[2]])
            - Matrix3::from_diagonal(&Vector3::from(self.dk))
    }
}

/// Temperature of the FOGs: T(t) = T0 + ramp·t + A sin(2π t / P).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct TemperatureSpec {
    /// T0, °C.
    pub t0_degc: f64,
    /// Ramp, °C/min.
    pub ramp_degc_per_min: f64,
    /// Sine amplitude, °C.
    pub sine_amp_degc: f64,
    /// Sine period, s.
    pub sine_period_s: f64,
}

impl Default for TemperatureSpec {
    fn default() -> Self {
        TemperatureSpec { t0_degc: 25.0, ramp_degc_per_min: 0.0, sine_amp_degc: 0.0, sine_period_s: 3600.0 }
    }
}

impl TemperatureSpec {
    /// (T, G) at `t_s`, in °C and °C/s.
    pub fn at(&self, t_s: f64) -> (f64, f64) {
        let w = 2.0 * std::f64::consts::PI / self.sine_period_s.max(1e-9);
        let t = self.t0_degc + self.ramp_degc_per_min / 60.0 * t_s + self.sine_amp_degc * (w * t_s).sin();
        let g = self.ramp_degc_per_min / 60.0 + self.sine_amp_degc * w * (w * t_s).cos();
        (t, g)
    }
}

/// Deterministic true errors, in the calibration table's own terms.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TrueErrors {
    /// Per-FOG terms.
    pub fog: [FogCal; N_FOG],
    /// True misalignment angles.
    pub misalignment: Misalignment,
}

/// What the scenario says about the FOGs.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct FogSpec {
    /// Angle random walk, °/√h (paper: 0.005).
    pub arw_deg_sqrt_h: f64,
    /// Rate random walk of the bias, °/h/√h.
    pub rrw_deg_h_sqrt_h: f64,
    /// Turn-on bias, 3σ, °/h, drawn per FOG (paper after calibration: 0.05).
    pub random_bias_3sigma_deg_h: f64,
    /// Scale-factor error, 3σ, drawn per FOG (paper after calibration: 0.002 % = 2e-5).
    pub random_scale_3sigma: f64,
    /// Sensitive-axis angle errors, 3σ, arcsec, drawn per angle (paper: 20″ total).
    pub random_axis_3sigma_arcsec: f64,
    /// Deterministic errors added to the random ones.
    pub errors: Option<TrueErrors>,
    /// The paper's triad form (eq. 4), applied to the body increment.
    pub triad: Option<TriadError>,
    /// FOG temperature.
    pub temperature: TemperatureSpec,
    /// Quantise to the frame's LSB (true) or send the nearest count without carrying
    /// the residual (false: only for tests of quantisation).
    pub carry_quantisation: bool,
}

impl Default for FogSpec {
    fn default() -> Self {
        FogSpec {
            arw_deg_sqrt_h: 0.005,
            rrw_deg_h_sqrt_h: 0.0,
            random_bias_3sigma_deg_h: 0.0,
            random_scale_3sigma: 0.0,
            random_axis_3sigma_arcsec: 0.0,
            errors: None,
            triad: None,
            temperature: TemperatureSpec::default(),
            carry_quantisation: true,
        }
    }
}

impl FogSpec {
    /// The paper's post-calibration figures: random zero signal ±0.05 °/h (3σ), ARW
    /// 0.005 °/√h, scale factor ±0.002 %, SA orientation ±20″.
    pub fn paper_post_calibration() -> Self {
        FogSpec {
            arw_deg_sqrt_h: 0.005,
            rrw_deg_h_sqrt_h: 0.0,
            random_bias_3sigma_deg_h: 0.05,
            random_scale_3sigma: 2e-5,
            random_axis_3sigma_arcsec: 20.0,
            ..Default::default()
        }
    }
}

/// One sample of all FOGs.
#[derive(Debug, Clone, Copy)]
pub struct FogSample {
    /// Frames to send.
    pub frames: [FogFrame; N_FOG],
    /// Noise-free raw increments (what the frames would carry without white noise and
    /// quantisation), rad.
    pub raw_sys_rad: [f64; N_FOG],
    /// True temperature and rate at the interval's middle.
    pub t_degc: f64,
    /// G, °C/s.
    pub g_degc_s: f64,
}

/// How the FOGs are really mounted, against the table's axes (integration errors).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Mounting {
    /// As the table says.
    AsTable,
    /// FOG i mounted backwards: it reads −s_i · ω (its own errors unchanged).
    Flipped(usize),
    /// FOGs i and j in each other's mounts: each reads the other's axis with its own
    /// errors (its frames still carry its own id and temperature).
    Swapped(usize, usize),
}

/// The four FOGs of a run.
pub struct FogModel {
    /// The true deterministic errors as a table (what perfect calibration would store).
    pub truth: CalibrationTable,
    axes: [Vector3<f64>; N_FOG],
    rand_bias_rad_s: [f64; N_FOG],
    rw_rad_s: [f64; N_FOG],
    sigma_v: f64,
    sigma_u: f64,
    triad: Option<(Matrix3<f64>, Vector3<f64>)>,
    temp: TemperatureSpec,
    total_rad: [f64; N_FOG],
    sent_counts: [i64; N_FOG],
    counter: u16,
    carry: bool,
}

impl FogModel {
    /// Draws the random errors of `spec` from `rng`.
    pub fn new(spec: &FogSpec, rng: &mut ChaCha20Rng) -> Self {
        let mut truth = CalibrationTable::DEFAULT;
        if let Some(e) = &spec.errors {
            truth.fog = e.fog;
            truth.misalignment = e.misalignment;
        }
        let mut n = |s3: f64| -> f64 {
            let z: f64 = StandardNormal.sample(rng);
            s3 / 3.0 * z
        };
        let mut rand_bias = [0.0; N_FOG];
        for (b, f) in rand_bias.iter_mut().zip(truth.fog.iter_mut()) {
            *b = n(spec.random_bias_3sigma_deg_h) * DEG_H;
            f.scale_factor_error += n(spec.random_scale_3sigma);
        }
        let a = spec.random_axis_3sigma_arcsec / ARCSEC_PER_RAD;
        let m = &mut truth.misalignment;
        for d in [
            &mut m.d12_rad,
            &mut m.d13_rad,
            &mut m.d21_rad,
            &mut m.d23_rad,
            &mut m.d31_rad,
            &mut m.d32_rad,
            &mut m.d42_rad,
            &mut m.d43_rad,
        ] {
            *d += n(a);
        }
        let triad = spec.triad.map(|t| (t.matrix(), Vector3::from(t.bias_rad_s)));
        FogModel {
            axes: truth.axes(),
            truth,
            rand_bias_rad_s: rand_bias,
            rw_rad_s: [0.0; N_FOG],
            sigma_v: spec.arw_deg_sqrt_h.to_radians() / 60.0,
            sigma_u: spec.rrw_deg_h_sqrt_h.to_radians() / 3600.0 / 60.0,
            triad,
            temp: spec.temperature,
            total_rad: [0.0; N_FOG],
            sent_counts: [0; N_FOG],
            counter: 0,
            carry: spec.carry_quantisation,
        }
    }

    /// Mounts the FOGs as `m` says from now on (an integration error from power-on when
    /// called before the first sample).
    pub fn mount(&mut self, m: Mounting) {
        match m {
            Mounting::AsTable => self.axes = self.truth.axes(),
            Mounting::Flipped(i) => {
                if let Some(a) = self.axes.get_mut(i) {
                    *a = -*a;
                }
            }
            Mounting::Swapped(i, j) => {
                if i < N_FOG && j < N_FOG {
                    self.axes.swap(i, j);
                }
            }
        }
    }

    /// Turn-on biases drawn for this run, rad/s.
    pub fn random_bias_rad_s(&self) -> [f64; N_FOG] {
        self.rand_bias_rad_s
    }

    /// The sample of the interval (t_end − dt, t_end] for truth increment `dtheta`.
    pub fn sample(&mut self, dtheta: &Vector3<f64>, t_end_s: f64, dt_s: f64, rng: &mut ChaCha20Rng) -> FogSample {
        let (t_mid, g_mid) = self.temp.at(t_end_s - dt_s / 2.0);
        let (t_end, _) = self.temp.at(t_end_s);
        let body = match &self.triad {
            Some((m, b)) => dtheta + b * dt_s + m * dtheta,
            None => *dtheta,
        };
        let mut frames = [FogFrame::from_physical(0, 0, 0, 0.0, 0.0); N_FOG];
        let mut raw_sys = [0.0; N_FOG];
        self.counter = self.counter.wrapping_add(1);
        for i in 0..N_FOG {
            let cal = &self.truth.fog[i];
            self.rw_rad_s[i] += self.sigma_u * dt_s.sqrt() * rng.sample::<f64, _>(StandardNormal);
            let drift = cal.drift_rad_s(t_mid, g_mid) + self.rand_bias_rad_s[i] + self.rw_rad_s[i];
            let sys = (1.0 + cal.scale_factor_error) * self.axes[i].dot(&body) + drift * dt_s;
            let noise = self.sigma_v * dt_s.sqrt() * rng.sample::<f64, _>(StandardNormal);
            raw_sys[i] = sys;
            let lsb = FogFrame::DTHETA_LSB_RAD;
            let counts = if self.carry {
                self.total_rad[i] += sys + noise;
                let now = (self.total_rad[i] / lsb).round() as i64;
                let d = now - self.sent_counts[i];
                self.sent_counts[i] = now;
                d
            } else {
                ((sys + noise) / lsb).round() as i64
            };
            let mut f = FogFrame::from_physical(i as u8, self.counter, 0, 0.0, t_end);
            f.dtheta_counts = counts.clamp(i32::MIN as i64, i32::MAX as i64) as i32;
            frames[i] = f;
        }
        FogSample { frames, raw_sys_rad: raw_sys, t_degc: t_mid, g_degc_s: g_mid }
    }
}
