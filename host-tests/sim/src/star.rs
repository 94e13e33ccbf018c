//! Star-tracker model, the paper's eq. (5): Λ* = Λ ∘ δΨ_Λ ∘ δΞ.
//!
//! δΨ_Λ is the true mount (the table's mount times a misalignment the table does not
//! know), δΞ white noise per axis plus, when the scenario gives one, a low-frequency
//! error (LFE) per tracker axis: a first-order Gauss–Markov process of 1σ
//! `lfe_sigma_arcsec` and correlation time `lfe_tau_s` (c_k = φ c_(k−1) + σ √(1 − φ²) w,
//! φ = e^(−Δt/τ) over the time Δt since the last frame, c_0 ~ N(0, σ²)), the model the
//! MEKF carries (`ssis::observer::mekf`). Without it no number is drawn for it, so a
//! white scenario's frames are as they were. Frames are taken every `1/rate` s at step boundaries
//! with the time tag of the instant they hold, and delivered `latency` later. Above
//! `max_rate_deg_s` the solution is flagged invalid; in an outage nothing is sent.

use nalgebra::{Quaternion, Vector3};
use rand::Rng;
use rand_chacha::ChaCha20Rng;
use rand_distr::StandardNormal;
use serde::{Deserialize, Serialize};
use ssis::frames::star::StarFrame;
use ssis::math::quat_from_rotvec;

use ssis_common::ARCSEC_PER_RAD;

/// What the scenario says about the star tracker.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct StarSpec {
    /// Whether a star tracker is fitted.
    pub enabled: bool,
    /// Update rate, Hz (the period is rounded to whole steps).
    pub rate_hz: f64,
    /// Noise, 3σ per axis, arcsec (paper: 20″).
    pub sigma_3sigma_arcsec: f64,
    /// Delivery latency after the time tag, ms.
    pub latency_ms: f64,
    /// Mount misalignment the table does not know (rotation vector, ICS), arcsec.
    pub misalignment_arcsec: [f64; 3],
    /// Above this body rate the solution is invalid, °/s.
    pub max_rate_deg_s: f64,
    /// Outages: [start, end) in s.
    pub outages: Vec<[f64; 2]>,
    /// Low-frequency error, 1σ per tracker axis, arcsec (0: none).
    pub lfe_sigma_arcsec: f64,
    /// Its correlation time, s (0: none).
    pub lfe_tau_s: f64,
}

impl Default for StarSpec {
    fn default() -> Self {
        StarSpec {
            enabled: true,
            rate_hz: 4.0,
            sigma_3sigma_arcsec: 20.0,
            latency_ms: 0.0,
            misalignment_arcsec: [0.0; 3],
            max_rate_deg_s: 2.0,
            outages: Vec::new(),
            lfe_sigma_arcsec: 0.0,
            lfe_tau_s: 0.0,
        }
    }
}

/// Star tracker of a run.
pub struct StarModel {
    spec: StarSpec,
    period_steps: u64,
    latency_us: u64,
    true_mount: Quaternion<f64>,
    sigma_rad: f64,
    counter: u16,
    pending: std::collections::VecDeque<(u64, [u8; StarFrame::LEN])>,
    /// The LFE (tracker frame, rad) and the time of the frame it was last drawn for, µs.
    lfe: Option<(Vector3<f64>, u64)>,
}

impl StarModel {
    /// For steps of `dt_us`, with the table's mount `table_mount`.
    pub fn new(spec: &StarSpec, dt_us: u32, table_mount: Quaternion<f64>) -> Self {
        let period_us = 1e6 / spec.rate_hz.max(1e-6);
        let period_steps = ((period_us / f64::from(dt_us)).round() as u64).max(1);
        let mis = Vector3::from(spec.misalignment_arcsec) / ARCSEC_PER_RAD;
        StarModel {
            period_steps,
            latency_us: (spec.latency_ms * 1000.0).round() as u64,
            true_mount: table_mount * quat_from_rotvec(&mis),
            sigma_rad: spec.sigma_3sigma_arcsec / 3.0 / ARCSEC_PER_RAD,
            counter: 0,
            pending: Default::default(),
            lfe: None,
            spec: spec.clone(),
        }
    }

    /// Step `n` ended at `now_us` with truth Λ `q` and rate `rate`: takes a frame if one
    /// is due, and returns the bytes of every frame delivered by `now_us`.
    pub fn step(
        &mut self,
        n: u64,
        now_us: u64,
        q: &Quaternion<f64>,
        rate: &Vector3<f64>,
        rng: &mut ChaCha20Rng,
    ) -> Vec<u8> {
        let t_s = now_us as f64 * 1e-6;
        let in_outage = self.spec.outages.iter().any(|[a, b]| t_s >= *a && t_s < *b);
        if self.spec.enabled && n.is_multiple_of(self.period_steps) && !in_outage {
            let mut noise = Vector3::from_fn(|_, _| self.sigma_rad * rng.sample::<f64, _>(StandardNormal));
            if let Some(c) = self.lfe_at(now_us, rng) {
                noise += c;
            }
            let q_st = q * self.true_mount * quat_from_rotvec(&noise);
            let valid = rate.norm().to_degrees() <= self.spec.max_rate_deg_s;
            self.counter = self.counter.wrapping_add(1);
            let f = StarFrame::from_physical(u8::from(valid), self.counter, now_us, [q_st.w, q_st.i, q_st.j, q_st.k]);
            self.pending.push_back((now_us + self.latency_us, f.to_bytes()));
        }
        let mut out = Vec::new();
        while let Some((due, _)) = self.pending.front() {
            if *due > now_us {
                break;
            }
            if let Some((_, bytes)) = self.pending.pop_front() {
                out.extend_from_slice(&bytes);
            }
        }
        out
    }

    /// The LFE at `now_us` (module doc), `None` without one.
    fn lfe_at(&mut self, now_us: u64, rng: &mut ChaCha20Rng) -> Option<Vector3<f64>> {
        let (sigma_rad, tau_s) = (self.spec.lfe_sigma_arcsec / ARCSEC_PER_RAD, self.spec.lfe_tau_s);
        if !(sigma_rad > 0.0 && tau_s > 0.0) {
            return None;
        }
        let mut w = || rng.sample::<f64, _>(StandardNormal);
        let c = match self.lfe {
            None => Vector3::new(w(), w(), w()) * sigma_rad,
            Some((c, t_us)) => {
                let phi = (-(now_us.saturating_sub(t_us) as f64 * 1e-6) / tau_s).exp();
                let k = sigma_rad * (1.0 - phi * phi).sqrt();
                c * phi + Vector3::new(w(), w(), w()) * k
            }
        };
        self.lfe = Some((c, now_us));
        Some(c)
    }
}
