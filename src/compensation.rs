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
#[derive(Debug, Clone, Copy, PartialEq)]
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
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TempRateEstimator {
    t_degc: f64,
    g_degc_s: f64,
    alpha: f64,
    beta_per_s: f64,
    started: bool,
}

impl TempRateEstimator {
    /// A tracker for samples every `dt_s` with time constant `tau_s`.
    pub fn new(dt_s: f64, tau_s: f64) -> Self {
        let r = if tau_s > dt_s { dt_s / tau_s } else { 1.0 };
        TempRateEstimator { t_degc: 0.0, g_degc_s: 0.0, alpha: 2.0 * r, beta_per_s: r * r / dt_s, started: false }
    }

    /// Feeds one temperature sample taken `dt_s` after the previous one; returns T and G.
    pub fn update(&mut self, temperature_degc: f64, dt_s: f64) -> Thermal {
        if !self.started {
            self.t_degc = temperature_degc;
            self.g_degc_s = 0.0;
            self.started = true;
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
        if self.started {
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

    /// A temperature ramp of 0.01 °C/s sampled every 5 ms: the tracker's G settles on the
    /// ramp with no lag in steady state, and T on the reading.
    #[test]
    fn a_ramp_is_tracked_without_steady_state_lag() {
        let (dt_s, tau_s, g) = (0.005, 30.0, 0.01);
        let mut tr = ThermalTracker::new(dt_s, tau_s);
        assert_eq!(tr.predicted_degc(dt_s), None);
        let mut last = Thermal { t_degc: 0.0, g_degc_s: 0.0 };
        // 20 time constants.
        for k in 0..(20.0 * tau_s / dt_s) as u32 {
            last = tr.update(Some(20.0 + g * f64::from(k) * dt_s), dt_s);
        }
        assert!((last.g_degc_s - g).abs() < 1e-6 * g, "G {} °C/s", last.g_degc_s);
        let t_end = 20.0 + g * (20.0 * tau_s - dt_s);
        assert!((last.t_degc - t_end).abs() < 1e-6, "T {} °C, reading {t_end}", last.t_degc);
        let p = tr.predicted_degc(dt_s).unwrap_or(f64::NAN);
        assert!((p - (t_end + g * dt_s)).abs() < 1e-6, "prediction {p}");
    }

    /// An untrusted reading holds T and gives G = 0; tracking resumes from the held state.
    #[test]
    fn an_untrusted_reading_holds_t_with_no_rate() {
        let mut tr = ThermalTracker::new(0.005, 30.0);
        tr.update(Some(25.0), 0.005);
        let held = tr.update(None, 0.005);
        assert_eq!(held, Thermal { t_degc: 25.0, g_degc_s: 0.0 });
        // The time constant can change (table switch) without losing T.
        tr.set_time_constant(0.005, 10.0);
        assert_eq!(tr.update(Some(25.0), 0.005).t_degc, 25.0);
    }

    /// The first reading starts the tracker at that temperature with no rate.
    #[test]
    fn the_first_reading_starts_the_tracker() {
        let mut e = TempRateEstimator::new(0.005, 30.0);
        assert_eq!(e.update(-12.5, 0.005), Thermal { t_degc: -12.5, g_degc_s: 0.0 });
        assert_eq!(e.predicted(1.0), Some(-12.5));
    }
}
