//! GNSS receiver model for the launch vehicle: position and velocity fixes in ECEF at a
//! fixed rate, white noise per axis, outage windows with no fix at all.
//!
//! Simplifications (stated so the figures are read right): no time-correlated errors
//! (real pseudorange-derived position errors wander over minutes), no latency, antenna at
//! the IMU (no lever arm), no re-acquisition delay after an outage.

use nalgebra::Vector3;
use rand::Rng;
use rand_chacha::ChaCha20Rng;
use rand_distr::StandardNormal;
use serde::{Deserialize, Serialize};
use ssis::nav::gnss::GnssFix;
use ssis::nav::NavState;

/// What a run says about the receiver.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct GnssSpec {
    /// Fix rate, Hz.
    pub rate_hz: f64,
    /// Position noise per axis, 1σ, m.
    pub sigma_pos_m: f64,
    /// Velocity noise per axis, 1σ, m/s.
    pub sigma_vel_m_s: f64,
    /// Outages: [start, end) in s.
    pub outages_s: Vec<[f64; 2]>,
}

impl Default for GnssSpec {
    /// 1 Hz, 5 m and 0.1 m/s per axis (a single-frequency code receiver), no outage.
    fn default() -> Self {
        GnssSpec { rate_hz: 1.0, sigma_pos_m: 5.0, sigma_vel_m_s: 0.1, outages_s: Vec::new() }
    }
}

impl GnssSpec {
    /// Whether `t_s` is inside an outage.
    pub fn in_outage(&self, t_s: f64) -> bool {
        self.outages_s.iter().any(|[a, b]| t_s >= *a && t_s < *b)
    }

    /// The fix at the end of navigation step `k` (1-based) of `dt_s`, if one is due and
    /// the receiver is not in an outage.
    pub fn fix(&self, k: u64, dt_s: f64, truth: &NavState, rng: &mut ChaCha20Rng) -> Option<GnssFix> {
        let per = (1.0 / (self.rate_hz * dt_s)).round().max(1.0) as u64;
        let t = k as f64 * dt_s;
        if !k.is_multiple_of(per) || self.in_outage(t) {
            return None;
        }
        let mut n = || Vector3::new(rng.sample(StandardNormal), rng.sample(StandardNormal), rng.sample(StandardNormal));
        Some(GnssFix {
            r_e_m: truth.r_e_m + n() * self.sigma_pos_m,
            v_e_m_s: truth.v_e_m_s + n() * self.sigma_vel_m_s,
            sigma_pos_m: self.sigma_pos_m,
            sigma_vel_m_s: self.sigma_vel_m_s,
        })
    }
}
