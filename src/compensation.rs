//! Compensation: raw FOG angle increment and temperature → compensated increment along
//! its sensitive axis.
//!
//! Inverts the per-FOG error model of [`crate::calib`]:
//!
//! ```text
//! Δθ_i = (Δθ_i,raw − (b_i + a1 ΔT + a2 ΔT² + a3 ΔT³ + g G + h ΔT G) · Δt) / (1 + k_i)
//! ```
//!
//! The temperature rate G = dT/dt, which the paper found to be the dominant thermal
//! factor, is estimated on board from the FOG's own temperature samples by a
//! critically damped α-β tracker ([`TempRateEstimator`]); the 1/256 °C quantisation of
//! the frame would make a raw difference useless (0.8 °C/s per LSB at 5 ms). The
//! per-channel checks ([`crate::integrity::channel`]) judge each reading first; once a
//! sensor has failed, [`Thermal`] holds the last estimate with G = 0.

use crate::calib::FogCal;
use crate::state::Flag;

/// Compensated angle increment of one FOG over `dt_s`, rad.
///
/// `t_rate_degc_s` is G. Pure function: the same formula the lab and the simulator use.
#[inline]
pub fn compensate_increment(
    cal: &FogCal,
    dtheta_raw_rad: f64,
    dt_s: f64,
    temperature_degc: f64,
    t_rate_degc_s: f64,
) -> f64 {
    let drift = cal.drift_rad_s(temperature_degc, t_rate_degc_s);
    (dtheta_raw_rad - drift * dt_s) / (1.0 + cal.scale_factor_error)
}

/// Compensated rate, rad/s, from a raw rate (the same model in rate form).
#[inline]
pub fn compensate_rate(cal: &FogCal, rate_raw_rad_s: f64, temperature_degc: f64, t_rate_degc_s: f64) -> f64 {
    (rate_raw_rad_s - cal.drift_rad_s(temperature_degc, t_rate_degc_s)) / (1.0 + cal.scale_factor_error)
}

/// Temperature and its rate, as compensation uses them.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Thermal {
    /// Temperature T, °C.
    pub t_degc: f64,
    /// Temperature rate G = dT/dt, °C/s.
    pub g_degc_s: f64,
}

/// One FOG's temperature stage: T and G from the readings the channel checks pass.
#[derive(Debug, Clone, Copy, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
#[repr(transparent)]
pub struct ThermalTracker {
    estimator: TempRateEstimator,
}

impl ThermalTracker {
    /// A tracker for samples every `dt_s` with time constant `tau_s`.
    pub fn new(dt_s: f64, tau_s: f64) -> Self {
        ThermalTracker { estimator: TempRateEstimator::new(dt_s, tau_s) }
    }

    /// A new time constant `tau_s` (a table switch); the tracked T and G stay.
    pub fn set_time_constant(&mut self, dt_s: f64, tau_s: f64) {
        let fresh = TempRateEstimator::new(dt_s, tau_s);
        self.estimator.alpha = fresh.alpha;
        self.estimator.beta_per_s = fresh.beta_per_s;
    }

    /// The temperature predicted for a reading `dt_s` after the last one (`None` before
    /// the first).
    #[inline]
    pub fn predicted_degc(&self, dt_s: f64) -> Option<f64> {
        self.estimator.predicted(dt_s)
    }

    /// Feeds the sample's reading (`None`: the sensor is not trusted) and gives T and G
    /// for compensation: the tracked values, or the held T with G = 0.
    #[inline]
    pub fn update(&mut self, reading_degc: Option<f64>, dt_s: f64) -> Thermal {
        match reading_degc {
            Some(t) => self.estimator.update(t, dt_s),
            None => Thermal { t_degc: self.estimator.estimate().t_degc, g_degc_s: 0.0 },
        }
    }
}

/// α-β tracker of temperature T and its rate G = dT/dt.
///
/// Second-order loop with natural frequency 1/τ, critically damped: α = 2Δt/τ,
/// β = (Δt/τ)². Lag to a constant G: none in steady state; noise from the 1/256 °C
/// quantisation at τ = 30 s: below 1e-4 °C/s.
#[derive(Debug, Clone, Copy, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
#[repr(C)]
pub struct TempRateEstimator {
    t_degc: f64,
    g_degc_s: f64,
    alpha: f64,
    beta_per_s: f64,
    started: Flag,
    _pad: [u8; 7],
}

impl TempRateEstimator {
    /// A tracker for samples every `dt_s` with time constant `tau_s`.
    pub fn new(dt_s: f64, tau_s: f64) -> Self {
        let r = if tau_s > dt_s { dt_s / tau_s } else { 1.0 };
        TempRateEstimator {
            t_degc: 0.0,
            g_degc_s: 0.0,
            alpha: 2.0 * r,
            beta_per_s: r * r / dt_s,
            started: Flag::CLEAR,
            _pad: [0; 7],
        }
    }

    /// Feeds one temperature sample taken `dt_s` after the previous one; returns T and G.
    pub fn update(&mut self, temperature_degc: f64, dt_s: f64) -> Thermal {
        if !self.started.get() {
            self.t_degc = temperature_degc;
            self.g_degc_s = 0.0;
            self.started = Flag::SET;
        } else {
            let predicted = self.t_degc + self.g_degc_s * dt_s;
            let r = temperature_degc - predicted;
            self.t_degc = predicted + self.alpha * r;
            self.g_degc_s += self.beta_per_s * r;
        }
        self.estimate()
    }

    /// The prediction for a sample `dt_s` after the last (`None` before the first).
    #[inline]
    pub fn predicted(&self, dt_s: f64) -> Option<f64> {
        if self.started.get() {
            Some(self.t_degc + self.g_degc_s * dt_s)
        } else {
            None
        }
    }

    /// Last estimate of T and G.
    pub fn estimate(&self) -> Thermal {
        Thermal { t_degc: self.t_degc, g_degc_s: self.g_degc_s }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The step of the spacecraft unit, s.
    const DT_S: f64 = 0.005;
    /// The frame's temperature LSB, °C.
    const LSB_DEGC: f64 = 1.0 / 256.0;

    #[test]
    fn the_first_sample_sets_t_with_no_rate() {
        let mut e = TempRateEstimator::new(DT_S, 30.0);
        assert_eq!(e.predicted(DT_S), None);
        let th = e.update(21.5, DT_S);
        assert_eq!(th, Thermal { t_degc: 21.5, g_degc_s: 0.0 });
        assert_eq!(e.predicted(DT_S), Some(21.5));
    }

    /// Critically damped α-β loop: no lag to a constant G once settled, and the 1/256 °C
    /// quantisation of the frame leaves G noise below 1e-4 °C/s at τ = 30 s (the
    /// estimator's doc comment).
    #[test]
    fn tracks_a_quantised_ramp_without_lag() {
        let g_true_degc_s = 0.01;
        let mut e = TempRateEstimator::new(DT_S, 30.0);
        let quantised = |k: u32| (20.0 + g_true_degc_s * f64::from(k) * DT_S) / LSB_DEGC;
        let reading = |k: u32| libm::round(quantised(k)) * LSB_DEGC;
        // Ten time constants to settle, then one more to judge.
        let settle = (10.0 * 30.0 / DT_S) as u32;
        let judge = (30.0 / DT_S) as u32;
        let mut worst_g = 0.0f64;
        let mut worst_t = 0.0f64;
        for k in 0..settle + judge {
            let th = e.update(reading(k), DT_S);
            if k >= settle {
                worst_g = worst_g.max((th.g_degc_s - g_true_degc_s).abs());
                worst_t = worst_t.max((th.t_degc - quantised(k) * LSB_DEGC).abs());
            }
        }
        assert!(worst_g < 1e-4, "G error {worst_g} °C/s");
        assert!(worst_t < LSB_DEGC, "T error {worst_t} °C");
    }

    #[test]
    fn an_untrusted_reading_holds_t_with_g_zero() {
        // τ = 1 s: settled after the 10 s of ramp.
        let mut tr = ThermalTracker::new(DT_S, 1.0);
        for k in 0..2_000 {
            tr.update(Some(20.0 + 0.05 * f64::from(k) * DT_S), DT_S);
        }
        let before = tr.update(Some(20.0 + 0.05 * 2_000.0 * DT_S), DT_S);
        assert!((before.g_degc_s - 0.05).abs() < 1e-3, "the tracker follows the ramp: {before:?}");
        let held = tr.update(None, DT_S);
        assert_eq!(held, Thermal { t_degc: before.t_degc, g_degc_s: 0.0 });
    }

    #[test]
    fn a_new_time_constant_keeps_the_tracked_state() {
        let mut tr = ThermalTracker::new(DT_S, 30.0);
        for k in 0..1_000 {
            tr.update(Some(20.0 + 0.02 * f64::from(k) * DT_S), DT_S);
        }
        let p = tr.predicted_degc(DT_S);
        tr.set_time_constant(DT_S, 5.0);
        assert_eq!(tr.predicted_degc(DT_S), p);
        assert_eq!(tr.estimator.alpha, 2.0 * DT_S / 5.0);
    }

    /// Compensation inverts the error model: a raw increment made from a true one by
    /// the table's drift and scale factor gives the true one back.
    #[test]
    fn compensation_inverts_the_error_model() {
        let cal = FogCal {
            bias_rad_s: 3e-7,
            scale_factor_error: 2e-4,
            t_ref_degc: 20.0,
            thermal_t_rad_s: [1e-8, -2e-9, 3e-10],
            thermal_g_rad_s_per_degc_s: 5e-7,
            thermal_tg_rad_s_per_degc2_s: -1e-8,
        };
        let (t_degc, g_degc_s) = (27.5, 0.02);
        for true_rad in [0.0, 1e-5, -3e-4] {
            let drift = cal.drift_rad_s(t_degc, g_degc_s);
            let raw = true_rad * (1.0 + cal.scale_factor_error) + drift * DT_S;
            let back = compensate_increment(&cal, raw, DT_S, t_degc, g_degc_s);
            assert!((back - true_rad).abs() < 1e-18, "{true_rad} -> {back}");
            let rate = compensate_rate(&cal, raw / DT_S, t_degc, g_degc_s);
            assert!((rate - true_rad / DT_S).abs() < 1e-15, "{true_rad} -> {rate}");
        }
    }
}
