//! Combination and attitude for one sample: the compensated increments of the FOGs that
//! fly combined into the body increment (held when no set can be combined), and the
//! attitude propagated on it less the drift estimate, its history recorded for the
//! star-tracker aid; samples lost on every link bridged on the last increment. Λ and Δω
//! are compared with their twins before each change and Λ's twin sealed after
//! ([`super::twin`]).

use nalgebra::Vector3;

use super::fog::Sample;
use super::FlightCore;
use crate::calib::N_FOG;
use crate::combination::FogSet;
use crate::telemetry::health;

/// What the samples of one step gave so far.
pub(super) struct Integrated {
    /// Health bits per FOG, or-ed over the samples.
    pub(super) fog_health: [u8; N_FOG],
    /// FOGs combined in the last sample.
    pub(super) used: FogSet,
    /// Parity residual of the last sample, rad.
    pub(super) parity_rad: f64,
    /// The last attitude increment, drift removed, rad.
    pub(super) rate_dtheta: Vector3<f64>,
    /// Samples integrated.
    pub(super) integrated: u32,
    /// Fewer FOGs than fitted, a parity alarm, or no sample.
    pub(super) degraded: bool,
    /// No usable gyro set in a sample: the attitude turned on a held increment, an error
    /// the estimator's σ does not hold.
    pub(super) held: bool,
}

impl Integrated {
    /// Nothing integrated yet.
    pub(super) const NONE: Integrated = Integrated {
        fog_health: [0; N_FOG],
        used: FogSet(0),
        parity_rad: 0.0,
        rate_dtheta: Vector3::new(0.0, 0.0, 0.0),
        integrated: 0,
        degraded: false,
        held: false,
    };
}

impl FlightCore {
    /// Samples lost on every link: turns through them on the last body increment, as a
    /// bridge does, so the attitude and its history keep up with the clock (skipping them
    /// would drop their rotation).
    #[inline(always)]
    pub(super) fn bridge_lost(&mut self, dt_s: f64, on_increment: &mut impl FnMut(u64, &Vector3<f64>)) {
        let lost = self.fog_intake.take_lost();
        if lost > 0 {
            self.twin_check_rare();
            let held = self.last_body_dtheta - self.observer.drift_rad_s() * dt_s;
            let _ = self.attitude.bridge(&held, lost);
            self.twin_seal_q();
            let span_end_us = self.fog_intake.time_us(self.profile.dt_us);
            self.observer.record(span_end_us, self.attitude.quaternion());
            on_increment(span_end_us, &(self.last_body_dtheta * f64::from(lost)));
        }
    }

    /// Combination: the body increment of `sample`'s FOGs (the last one held when no set
    /// can be combined); the sample's health and use go into `acc`.
    #[inline(always)]
    pub(super) fn combine(&mut self, sample: &Sample, acc: &mut Integrated) -> Vector3<f64> {
        acc.degraded |= self.fdi.as_ref().is_some_and(|m| m.alarm());
        for (h, bits) in acc.fog_health.iter_mut().zip(sample.health) {
            *h |= bits;
        }
        acc.used = sample.used;
        acc.degraded |= sample.used != self.profile.fogs;
        let body = match self.combiner.combine(&sample.dtheta, sample.used) {
            Ok(v) => v,
            Err(_) => {
                // No usable gyro set in this sample: hold the last body increment.
                acc.degraded = true;
                acc.held = true;
                self.last_body_dtheta
            }
        };
        self.last_body_dtheta = body;
        body
    }

    /// Attitude: one step on `body` less the drift estimate, recorded at `time_us`.
    #[inline(always)]
    pub(super) fn propagate(&mut self, body: &Vector3<f64>, time_us: u64, dt_s: f64, acc: &mut Integrated) {
        // Λ and Δω as sealed ([`super::twin`]), then Λ sealed again after its change.
        self.twin_check();
        acc.rate_dtheta = body - self.observer.drift_rad_s() * dt_s;
        let _ = self.attitude.step(&acc.rate_dtheta);
        self.twin_seal_q();
        self.observer.record(time_us, self.attitude.quaternion());
        acc.integrated += 1;
    }

    /// No sample this step: the output rate is the last body increment, corrected, and
    /// every fitted FOG is missing.
    #[inline(always)]
    pub(super) fn nothing_integrated(&mut self, dt_s: f64, acc: &mut Integrated) {
        acc.rate_dtheta = self.last_body_dtheta - self.observer.drift_rad_s() * dt_s;
        self.fog_intake.waited_a_step();
        acc.degraded = true;
        for (i, h) in acc.fog_health.iter_mut().enumerate() {
            *h = if self.profile.fogs.contains(i) { health::MISSING } else { health::EXCLUDED };
        }
    }
}
