//! Accelerometer triad model (launch-vehicle unit): every term of the accelerometer
//! calibration section ([`ssis::calib::accel`]), drawn per run, plus white noise
//! (velocity random walk), quantised by counting into [`AccelFrame`]s.
//!
//! For accelerometer i with true sensitive axis u_i, over (t − Δt, t]:
//!
//! ```text
//! Δv_i,raw = (1 + k_i + k_T,i ΔT) u_i·Δv + k2_i (u_i·Δv)²/Δt + (b_i + c1_i ΔT + c2_i ΔT²) Δt + n_i
//! ```
//!
//! n_i white with σ = VRW·√Δt. The frame carries the difference of rounded running
//! totals, so quantisation never accumulates (a pulse-counting output).
//!
//! The paper gives the AK-30's type (pendulous) and range (±85 m/s²) but no accuracy
//! figures. [`AccelSpec::typical_pendulous`] takes figures typical of
//! navigation-grade quartz pendulous (servo) accelerometers after calibration; they are
//! assumptions, listed with their values in `docs/LAUNCH-VEHICLE.md`.

use nalgebra::Vector3;
use rand::Rng;
use rand_chacha::ChaCha20Rng;
use rand_distr::StandardNormal;
use serde::{Deserialize, Serialize};
use ssis::calib::accel::{AccelTable, N_ACCEL};
use ssis::frames::accel::AccelFrame;

/// Standard gravity, m/s² (for µg figures).
pub const G0_M_S2: f64 = 9.806_65;

/// What a run says about the accelerometers (1σ values, drawn per accelerometer).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct AccelSpec {
    /// Residual bias, 1σ, µg.
    pub bias_1sigma_ug: f64,
    /// Residual scale-factor error, 1σ, ppm.
    pub scale_1sigma_ppm: f64,
    /// Residual second-order nonlinearity, 1σ, µg/g².
    pub k2_1sigma_ug_per_g2: f64,
    /// Residual misalignment, 1σ, arcsec (each of the six angles).
    pub misalignment_1sigma_arcsec: f64,
    /// Residual bias thermal coefficient, 1σ, µg/°C.
    pub bias_thermal_1sigma_ug_per_degc: f64,
    /// Velocity random walk, µg/√Hz.
    pub vrw_ug_sqrt_hz: f64,
    /// Temperature: start, °C, and rate, °C/s (linear).
    pub temperature: [f64; 2],
}

impl Default for AccelSpec {
    fn default() -> Self {
        AccelSpec {
            bias_1sigma_ug: 0.0,
            scale_1sigma_ppm: 0.0,
            k2_1sigma_ug_per_g2: 0.0,
            misalignment_1sigma_arcsec: 0.0,
            bias_thermal_1sigma_ug_per_degc: 0.0,
            vrw_ug_sqrt_hz: 0.0,
            temperature: [25.0, 0.0],
        }
    }
}

impl AccelSpec {
    /// Residual errors typical of a calibrated navigation-grade quartz pendulous
    /// accelerometer (assumed for the AK-30, see the module documentation): bias 50 µg,
    /// scale factor 50 ppm, K2 10 µg/g², misalignment 20″ (the paper's FOG axis figure),
    /// thermal bias residual 2 µg/°C over a 10 °C rise in 600 s, VRW 10 µg/√Hz.
    pub fn typical_pendulous() -> Self {
        AccelSpec {
            bias_1sigma_ug: 50.0,
            scale_1sigma_ppm: 50.0,
            k2_1sigma_ug_per_g2: 10.0,
            misalignment_1sigma_arcsec: 20.0,
            bias_thermal_1sigma_ug_per_degc: 2.0,
            vrw_ug_sqrt_hz: 10.0,
            temperature: [20.0, 10.0 / 600.0],
        }
    }
}

/// The three accelerometers of a run.
pub struct AccelModel {
    /// The true errors as an accelerometer table (what perfect calibration would store).
    pub truth: AccelTable,
    axes: [Vector3<f64>; N_ACCEL],
    sigma_vrw_m_s2_sqrt_s: f64,
    temperature: [f64; 2],
    total_m_s: [f64; N_ACCEL],
    sent_counts: [i64; N_ACCEL],
    counter: u16,
}

impl AccelModel {
    /// Draws the errors of `spec` from `rng`.
    pub fn new(spec: &AccelSpec, rng: &mut ChaCha20Rng) -> Self {
        let mut n = |s: f64| -> f64 { s * rng.sample::<f64, _>(StandardNormal) };
        let ug = G0_M_S2 * 1e-6;
        let mut truth = AccelTable::IDEAL;
        for a in truth.accel.iter_mut() {
            a.bias_m_s2 = n(spec.bias_1sigma_ug * ug);
            a.scale_factor_error = n(spec.scale_1sigma_ppm * 1e-6);
            a.k2_per_m_s2 = n(spec.k2_1sigma_ug_per_g2 * 1e-6 / G0_M_S2);
            a.t_ref_degc = spec.temperature[0];
            a.bias_thermal_m_s2 = [n(spec.bias_thermal_1sigma_ug_per_degc * ug), 0.0];
        }
        let m = spec.misalignment_1sigma_arcsec / ssis_common::ARCSEC_PER_RAD;
        let mis = &mut truth.misalignment;
        for d in mis.x_rad.iter_mut().chain(mis.y_rad.iter_mut()).chain(mis.z_rad.iter_mut()) {
            *d = n(m);
        }
        let u = truth.misalignment.axes();
        let axes = [u.row(0).transpose(), u.row(1).transpose(), u.row(2).transpose()];
        AccelModel {
            truth,
            axes,
            sigma_vrw_m_s2_sqrt_s: spec.vrw_ug_sqrt_hz * ug,
            temperature: spec.temperature,
            total_m_s: [0.0; N_ACCEL],
            sent_counts: [0; N_ACCEL],
            counter: 0,
        }
    }

    /// Temperature at t, °C.
    pub fn temperature_degc(&self, t_s: f64) -> f64 {
        self.temperature[0] + self.temperature[1] * t_s
    }

    /// Frames of the interval (t_end − Δt, t_end] for the true body increment `dv_m_s`.
    pub fn sample(
        &mut self,
        dv_m_s: &Vector3<f64>,
        t_end_s: f64,
        dt_s: f64,
        rng: &mut ChaCha20Rng,
    ) -> [AccelFrame; N_ACCEL] {
        let temp = self.temperature_degc(t_end_s - 0.5 * dt_s);
        self.counter = self.counter.wrapping_add(1);
        let mut frames = [AccelFrame::default(); N_ACCEL];
        for (i, frame) in frames.iter_mut().enumerate() {
            let cal = &self.truth.accel[i];
            let a_dv = self.axes[i].dot(dv_m_s);
            let sys = cal.scale_at(temp) * a_dv + cal.k2_per_m_s2 * a_dv * a_dv / dt_s + cal.bias_at_m_s2(temp) * dt_s;
            let noise = self.sigma_vrw_m_s2_sqrt_s * dt_s.sqrt() * rng.sample::<f64, _>(StandardNormal);
            self.total_m_s[i] += sys + noise;
            let total_counts = (self.total_m_s[i] / AccelFrame::DV_LSB_M_S).round() as i64;
            let counts = total_counts - self.sent_counts[i];
            self.sent_counts[i] = total_counts;
            *frame = AccelFrame {
                accel_id: i as u8,
                counter: self.counter,
                status: 0,
                dv_counts: counts.clamp(i64::from(i32::MIN), i64::from(i32::MAX)) as i32,
                temperature_counts: (temp * 256.0).round() as i16,
            };
        }
        frames
    }
}
