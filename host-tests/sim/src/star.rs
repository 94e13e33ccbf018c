//! Star-tracker model, the paper's eq. (5): Λ* = Λ ∘ δΨ_Λ ∘ δΞ.
//!
//! δΨ_Λ is the true mount (the table's mount times a misalignment the table does not
//! know), δΞ white noise per axis. Frames are taken every `1/rate` s at step boundaries
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
            let noise = Vector3::from_fn(|_, _| self.sigma_rad * rng.sample::<f64, _>(StandardNormal));
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
}
