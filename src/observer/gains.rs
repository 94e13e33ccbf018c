//! The steady-state gains of eq. (6) and the noise figures the estimators share.
//!
//! [`steady_state`] iterates the discrete Riccati equation of the per-axis model
//! x = (attitude error, drift error) between star-tracker frames every T:
//!
//! ```text
//! F = [[1, −T], [0, 1]],   Q = [[σ_v² T + σ_u² T³/3, −σ_u² T²/2], [−σ_u² T²/2, σ_u² T]],
//! H = [1, 0],              R = σ_st²
//! ```
//!
//! (σ_v the gyro's angle random walk, σ_u its rate random walk, σ_st the star tracker's
//! 1σ) until the gain K = (K_B, −K_U) settles: the Kalman filter's steady state
//! (Farrenkopf 1978). A fixed-gain observer of eq. (6) with these gains matches the Kalman
//! filter in steady state (4 Hz, the paper's sensors: K = [0.0224, −1.24e-5 /s]).
//!
//! [`Figures`] carries the result with the noise of the FOG combination flying on each
//! body axis, for whichever estimator flies.

use nalgebra::Matrix3;

use crate::calib::{ObserverConfig, ObserverGains};

/// One arcsecond, rad.
pub(super) const ARCSEC_RAD: f64 = core::f64::consts::PI / 180.0 / 3600.0;
const DEG_RAD: f64 = core::f64::consts::PI / 180.0;

/// Why gains could not be computed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub enum GainError {
    /// A noise figure is zero, negative or not finite.
    BadFigures,
    /// The Riccati iteration did not settle within its bound.
    NotConverged,
}

/// Steady-state Kalman gains of the per-axis model x = (attitude error, drift error):
/// F = [[1, −T], [0, 1]], Q from ARW σ_v and rate random walk σ_u, R = σ_st².
/// Bounded iteration of the discrete Riccati equation.
pub fn steady_state_gains(cfg: &ObserverConfig) -> Result<ObserverGains, GainError> {
    steady_state(cfg).map(|s| s.gains)
}

/// The steady state of the per-axis Kalman filter: gains and the variances the gate needs.
#[derive(Debug, Clone, Copy, PartialEq, bytemuck::AnyBitPattern)]
pub struct SteadyState {
    /// Gains K_B, K_U.
    pub gains: ObserverGains,
    /// Prior attitude-error variance at an update, rad² per axis.
    pub prior_var_rad2: f64,
    /// Posterior drift-error variance, (rad/s)² per axis.
    pub drift_var_rad2_s2: f64,
    /// Star-tracker noise variance R, rad² per axis.
    pub r_rad2: f64,
    /// ARW variance rate σ_v², rad²/s.
    pub arw_var_rad2_s: f64,
    /// Rate random walk variance rate σ_u², rad²/s³.
    pub rrw_var_rad2_s3: f64,
    /// The star tracker's low-frequency error (LFE) variance per axis σ_c², rad² (0: a
    /// white tracker; the MEKF's LFE states, [`super::mekf`]).
    pub lfe_var_rad2: f64,
    /// The LFE's correlation time τ_c, s (0: a white tracker).
    pub lfe_tau_s: f64,
}

impl SteadyState {
    /// Whether the table describes an LFE the MEKF carries.
    #[inline(always)]
    pub fn lfe(&self) -> bool {
        self.lfe_tau_s > 0.0 && self.lfe_var_rad2 > 0.0
    }
}

/// [`steady_state_gains`] with the variances at steady state.
pub fn steady_state(cfg: &ObserverConfig) -> Result<SteadyState, GainError> {
    let t = cfg.st_period_s;
    let sv = cfg.arw_deg_sqrt_h * DEG_RAD / 60.0; // rad/√s
    let su = cfg.rrw_deg_h_sqrt_h * DEG_RAD / 3600.0 / 60.0; // rad/s/√s
    let r = (cfg.st_sigma_arcsec * ARCSEC_RAD) * (cfg.st_sigma_arcsec * ARCSEC_RAD);
    let lfe = cfg.st_lfe_sigma_arcsec * ARCSEC_RAD;
    let ok = |x: f64| x.is_finite() && x > 0.0;
    if !(ok(t) && ok(sv) && ok(su) && ok(r)) {
        return Err(GainError::BadFigures);
    }
    let q11 = sv * sv * t + su * su * t * t * t / 3.0;
    let q12 = -su * su * t * t / 2.0;
    let q22 = su * su * t;
    // Start from a posterior that is surely larger than the steady state.
    let (mut p11, mut p12, mut p22) = (r, 0.0, 1e-8);
    let (mut k1, mut k2) = (0.0f64, 0.0f64);
    for _ in 0..2_000_000u32 {
        let m11 = p11 - 2.0 * t * p12 + t * t * p22 + q11;
        let m12 = p12 - t * p22 + q12;
        let m22 = p22 + q22;
        let s = m11 + r;
        let (n1, n2) = (m11 / s, m12 / s);
        p11 = (1.0 - n1) * m11;
        p12 = (1.0 - n1) * m12;
        p22 = m22 - n2 * m12;
        let settled = (n1 - k1).abs() <= 1e-13 * n1.abs() && (n2 - k2).abs() <= 1e-13 * n2.abs();
        k1 = n1;
        k2 = n2;
        if settled {
            return Ok(SteadyState {
                gains: ObserverGains { k_b: [k1; 3], k_u_per_s: [-k2; 3] },
                prior_var_rad2: m11,
                drift_var_rad2_s2: p22,
                r_rad2: r,
                arw_var_rad2_s: sv * sv,
                rrw_var_rad2_s3: su * su,
                lfe_var_rad2: if cfg.lfe() { lfe * lfe } else { 0.0 },
                lfe_tau_s: if cfg.lfe() && lfe.is_finite() { cfg.st_lfe_tau_s } else { 0.0 },
            });
        }
    }
    Err(GainError::NotConverged)
}

/// Each FOG's drift variance at alignment of the table's initial drift 1σ, (rad/s)².
pub(super) fn initial_drift_var_rad2_s2(cfg: &ObserverConfig) -> f64 {
    let s = cfg.initial_drift_sigma_deg_h * DEG_RAD / 3600.0;
    s * s
}

/// The noise figures every estimator works with: one FOG's (the table's, [`SteadyState`])
/// and what they become on each body axis through the FOG combination flying.
#[derive(Debug, Clone, Copy, PartialEq, bytemuck::AnyBitPattern)]
pub struct Figures {
    /// The table's figures and steady state.
    pub steady: SteadyState,
    /// N = (SᵀS)⁻¹ of the FOG combination flying ([`super::mekf::noise_of`]): one FOG's
    /// noise variance becomes σ² N on the body axes.
    pub noise: Matrix3<f64>,
    /// N_kk per axis (equal on every axis when they differ only by rounding).
    pub noise_axis: [f64; 3],
    /// ARW variance rate per axis, σ_v² N_kk, rad²/s.
    pub arw_axis_rad2_s: [f64; 3],
    /// Rate random walk variance rate per axis, σ_u² N_kk, rad²/s³.
    pub rrw_axis_rad2_s3: [f64; 3],
}

impl Figures {
    /// Its words, for the state guard ([`crate::shadow`]).
    pub fn visit<V: crate::shadow::Visit>(&mut self, v: &mut V) {
        let s = &mut self.steady;
        v.f64s(&mut s.gains.k_b);
        v.f64s(&mut s.gains.k_u_per_s);
        for x in [
            &mut s.prior_var_rad2,
            &mut s.drift_var_rad2_s2,
            &mut s.r_rad2,
            &mut s.arw_var_rad2_s,
            &mut s.rrw_var_rad2_s3,
        ] {
            v.f64(x);
        }
        v.f64s(self.noise.as_mut_slice());
        v.f64s(&mut self.noise_axis);
        v.f64s(&mut self.arw_axis_rad2_s);
        v.f64s(&mut self.rrw_axis_rad2_s3);
    }

    /// One FOG's figures on every axis (N = I) until [`Figures::set_noise`].
    pub fn new(steady: SteadyState) -> Self {
        Figures {
            steady,
            noise: Matrix3::identity(),
            noise_axis: [1.0; 3],
            arw_axis_rad2_s: [steady.arw_var_rad2_s; 3],
            rrw_axis_rad2_s3: [steady.rrw_var_rad2_s3; 3],
        }
    }

    /// The combination flying has N = `noise`: the per-axis figures σ² N_kk. Diagonals
    /// equal but for rounding (the nominal four FOGs: 5/6 each) are made equal, so one
    /// axis can stand for all.
    pub fn set_noise(&mut self, noise: &Matrix3<f64>) {
        self.noise = *noise;
        let st = &self.steady;
        let d = [noise.m11, noise.m22, noise.m33];
        let mean = (d[0] + d[1] + d[2]) / 3.0;
        let equal = d.iter().all(|x| (x - mean).abs() <= 1e-9 * mean.abs());
        for ((n, na), (v, u)) in d
            .iter()
            .zip(self.noise_axis.iter_mut())
            .zip(self.arw_axis_rad2_s.iter_mut().zip(self.rrw_axis_rad2_s3.iter_mut()))
        {
            let n = if equal { mean } else { *n };
            *na = n;
            *v = st.arw_var_rad2_s * n;
            *u = st.rrw_var_rad2_s3 * n;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn four_hz_gains_are_the_notes_within_their_digits() {
        // docs/REFERENCES.md (steady-state Kalman gains): the paper's sensors (ARW 0.005 °/√h, 20″ 3σ at 4 Hz,
        // RRW 0.01 °/h/√h) give K = [0.0224, −1.24e-5 /s]: three significant digits each.
        let g = steady_state_gains(&ObserverConfig::PAPER).unwrap();
        assert!((g.k_b[0] - 0.0224).abs() <= 0.00005, "K_B {}", g.k_b[0]);
        assert!((g.k_u_per_s[0] - 1.24e-5).abs() <= 0.005e-5, "K_U {}", g.k_u_per_s[0]);
        assert_eq!(g.k_b[0], g.k_b[2]);
    }

    #[test]
    fn the_steady_state_is_a_fixed_point_of_the_riccati_step() {
        let s = steady_state(&ObserverConfig::PAPER).unwrap();
        let t = ObserverConfig::PAPER.st_period_s;
        let (k1, k2) = (s.gains.k_b[0], -s.gains.k_u_per_s[0]);
        // The prior variance M11 gives back K_B = M11 / (M11 + R).
        assert!((s.prior_var_rad2 / (s.prior_var_rad2 + s.r_rad2) - k1).abs() <= 1e-12);
        // P22 propagated over T and updated returns to itself.
        let q22 = s.rrw_var_rad2_s3 * t;
        let m22 = s.drift_var_rad2_s2 + q22;
        let m12 = k2 * (s.prior_var_rad2 + s.r_rad2);
        assert!(((m22 - k2 * m12) - s.drift_var_rad2_s2).abs() <= 1e-9 * s.drift_var_rad2_s2);
    }

    #[test]
    fn bad_figures_are_refused() {
        let bad = ObserverConfig { st_sigma_arcsec: 0.0, ..ObserverConfig::PAPER };
        assert_eq!(steady_state_gains(&bad), Err(GainError::BadFigures));
        let nan = ObserverConfig { arw_deg_sqrt_h: f64::NAN, ..ObserverConfig::PAPER };
        assert_eq!(steady_state_gains(&nan), Err(GainError::BadFigures));
    }

    #[test]
    fn nearly_equal_diagonals_fly_as_one() {
        let mut f = Figures::new(steady_state(&ObserverConfig::PAPER).unwrap());
        let n = Matrix3::new(
            5.0 / 6.0,
            -1.0 / 6.0,
            -1.0 / 6.0,
            -1.0 / 6.0,
            5.0 / 6.0 + 1e-15,
            -1.0 / 6.0,
            -1.0 / 6.0,
            -1.0 / 6.0,
            5.0 / 6.0,
        );
        f.set_noise(&n);
        assert_eq!(f.noise_axis[0].to_bits(), f.noise_axis[1].to_bits());
        f.set_noise(&Matrix3::from_diagonal(&nalgebra::Vector3::new(5.0, 1.0, 1.0)));
        assert_eq!(f.noise_axis, [5.0, 1.0, 1.0]);
    }
}
