//! Launch-vehicle navigation studies: the ascent truth recorded once, then
//! free-inertial runs of the flight core's [`ssis::nav::Strapdown`] on sensor data with
//! errors (FOGs: [`crate::fog`], accelerometers: [`crate::accel`]), errors
//! against truth at fixed times.
//!
//! The sensor data go through the frames (FOG frames 2^-36 rad, accelerometer frames
//! 2^-28 m/s, quantisation carried) and are compensated with the *nominal* (ideal)
//! tables: the drawn errors are the residual errors after calibration that the unit
//! does not know. FOG1..FOG3 are the orthogonal triad (FOG4 of the model is not used).
//! The initial state is the truth (no alignment error).

use nalgebra::{Quaternion, Vector3};
use rand::SeedableRng;
use rand_chacha::ChaCha20Rng;
use ssis::calib::accel::AccelTable;
use ssis::nav::gnss::{AidedNav, GnssConfig};
use ssis::nav::{Corrections, NavState, Strapdown};

use crate::accel::{AccelModel, AccelSpec};
use crate::fog::{FogModel, FogSpec};
use crate::gnss::GnssSpec;
use crate::launch::{LaunchProfile, LaunchTruth};

/// One recorded ascent: per-step increments and truth.
pub struct AscentRecord {
    /// Step, s.
    pub dt_s: f64,
    /// Truth at t = 0: (q_eb, v_e, r_e).
    pub initial: NavState,
    /// Per step: (∫ω dt, ∫f dt).
    pub increments: Vec<(Vector3<f64>, Vector3<f64>)>,
    /// Per step: truth at the step's end.
    pub truth: Vec<NavState>,
}

impl AscentRecord {
    /// Records `duration_s` of `profile` at `dt_s`.
    pub fn record(profile: LaunchProfile, dt_s: f64, duration_s: f64) -> Self {
        let mut t = LaunchTruth::new(profile, dt_s);
        let (q_eb, v_e_m_s, r_e_m) = t.state_now();
        let n = (duration_s / dt_s).round() as usize;
        let mut increments = Vec::with_capacity(n);
        let mut truth = Vec::with_capacity(n);
        for _ in 0..n {
            let s = t.advance();
            increments.push((s.dtheta_rad, s.dv_m_s));
            truth.push(NavState { q_eb: s.q_eb, v_e_m_s: s.v_e_m_s, r_e_m: s.r_e_m });
        }
        AscentRecord { dt_s, initial: NavState { q_eb, v_e_m_s, r_e_m }, increments, truth }
    }
}

/// Navigation error at one time.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct NavError {
    /// Time, s.
    pub t_s: f64,
    /// |r − r_true|, m.
    pub pos_m: f64,
    /// |v − v_true|, m/s.
    pub vel_m_s: f64,
    /// Attitude error angle, rad.
    pub att_rad: f64,
}

/// Angle between two attitudes, rad.
pub fn angle_between(a: &Quaternion<f64>, b: &Quaternion<f64>) -> f64 {
    let d = a.conjugate() * b;
    2.0 * d.imag().norm().atan2(d.w.abs())
}

/// Error of `nav` against `truth`.
pub fn error_of(t_s: f64, nav: &NavState, truth: &NavState) -> NavError {
    NavError {
        t_s,
        pos_m: (nav.r_e_m - truth.r_e_m).norm(),
        vel_m_s: (nav.v_e_m_s - truth.v_e_m_s).norm(),
        att_rad: angle_between(&nav.q_eb, &truth.q_eb),
    }
}

/// Free-inertial run on sensor data with the errors of `fog` and `accel` drawn from
/// `seed` (`None`: that sensor is ideal, no quantisation either). Returns the error
/// every `every_s`.
pub fn free_inertial(
    rec: &AscentRecord,
    fog: Option<&FogSpec>,
    accel: Option<&AccelSpec>,
    seed: u64,
    every_s: f64,
) -> Vec<NavError> {
    run(rec, fog, accel, None, seed, every_s).errors
}

/// What a run gives.
#[derive(Debug, Clone, Default)]
pub struct RunResult {
    /// Error every `every_s`.
    pub errors: Vec<NavError>,
    /// The filter's 1σ (position m, velocity m/s) at the same times (aided runs).
    pub sigma: Vec<(f64, f64)>,
    /// Fixes used and refused (aided runs).
    pub fixes: (u32, u32),
}

/// Filter tuning matched to the sensor specs (initial state: the truth, so small initial
/// uncertainties; accelerometer bias random walk large enough to absorb the scale-factor
/// and misalignment errors, which change with the thrust level).
pub fn filter_config(fog: &FogSpec, acc: &AccelSpec) -> GnssConfig {
    let ug = crate::accel::G0_M_S2 * 1e-6;
    let deg_h = std::f64::consts::PI / 180.0 / 3600.0;
    GnssConfig {
        init_att_rad: 20.0 / ssis_common::ARCSEC_PER_RAD,
        init_vel_m_s: 0.01,
        init_pos_m: 1.0,
        init_accel_bias_m_s2: (acc.bias_1sigma_ug * 2.0).max(10.0) * ug,
        init_gyro_bias_rad_s: (fog.random_bias_3sigma_deg_h / 3.0 * 2.0).max(0.01) * deg_h,
        arw_rad_sqrt_s: fog.arw_deg_sqrt_h.max(1e-3).to_radians() / 60.0,
        vrw_m_s_sqrt_s: acc.vrw_ug_sqrt_hz.max(1.0) * ug,
        accel_bias_rw_m_s2_sqrt_s: 2e-4,
        gyro_bias_rw_rad_s_sqrt_s: 1e-7,
        gate_sigma: 5.0,
    }
}

/// A run, free-inertial or (with `gnss`) aided by the loosely coupled filter. The sensor
/// errors depend only on `seed`, so a free and an aided run with the same seed see the
/// same sensor data; the GNSS noise comes from its own generator.
pub fn run(
    rec: &AscentRecord,
    fog: Option<&FogSpec>,
    accel: Option<&AccelSpec>,
    gnss: Option<(&GnssSpec, &GnssConfig)>,
    seed: u64,
    every_s: f64,
) -> RunResult {
    let mut rng = ChaCha20Rng::seed_from_u64(seed);
    let mut gnss_rng = ChaCha20Rng::seed_from_u64(seed.wrapping_add(1_000_003));
    let mut fogs = fog.map(|s| FogModel::new(s, &mut rng));
    let mut accs = accel.map(|s| AccelModel::new(s, &mut rng));
    let nominal = AccelTable::IDEAL.compensator().ok();
    let dt = rec.dt_s;
    let mut out = RunResult::default();
    let mut free = match Strapdown::new(rec.initial, dt, Corrections::ALL) {
        Ok(n) => n,
        Err(_) => return out,
    };
    let mut aided = match gnss {
        Some((_, cfg)) => match AidedNav::new(rec.initial, dt, *cfg) {
            Ok(a) => Some(a),
            Err(_) => return out,
        },
        None => None,
    };
    let every = ((every_s / dt).round() as usize).max(1);
    for (k, ((dth, dv), truth)) in rec.increments.iter().zip(&rec.truth).enumerate() {
        let t_end = (k + 1) as f64 * dt;
        let dtheta_b = match fogs.as_mut() {
            Some(m) => {
                let s = m.sample(dth, t_end, dt, &mut rng);
                Vector3::new(s.frames[0].dtheta_rad(), s.frames[1].dtheta_rad(), s.frames[2].dtheta_rad())
            }
            None => *dth,
        };
        let dv_b = match (accs.as_mut(), nominal.as_ref()) {
            (Some(m), Some(c)) => {
                let f = m.sample(dv, t_end, dt, &mut rng);
                let raw = Vector3::new(f[0].dv_m_s(), f[1].dv_m_s(), f[2].dv_m_s());
                c.compensate(&raw, &f.map(|x| x.temperature_degc()), dt).unwrap_or(raw)
            }
            _ => *dv,
        };
        let state = match (aided.as_mut(), gnss) {
            (Some(a), Some((spec, _))) => {
                if a.step(&dtheta_b, &dv_b).is_err() {
                    break;
                }
                if let Some(fix) = spec.fix(k as u64 + 1, dt, truth, &mut gnss_rng) {
                    let _ = a.gnss_update(&fix);
                }
                *a.state()
            }
            _ => {
                if free.step(&dtheta_b, &dv_b).is_err() {
                    break;
                }
                *free.state()
            }
        };
        if (k + 1) % every == 0 {
            out.errors.push(error_of(t_end, &state, truth));
            if let Some(a) = aided.as_ref() {
                out.sigma.push(a.sigma_pos_vel());
            }
        }
    }
    if let Some(a) = aided.as_ref() {
        out.fixes = a.counts();
    }
    out
}

/// Root mean square over runs, time by time (runs of equal length).
pub fn rms_over_runs(runs: &[Vec<NavError>]) -> Vec<NavError> {
    let n = runs.len().max(1) as f64;
    let len = runs.iter().map(Vec::len).min().unwrap_or(0);
    (0..len)
        .map(|i| {
            let sq = |f: fn(&NavError) -> f64| (runs.iter().map(|r| f(&r[i]).powi(2)).sum::<f64>() / n).sqrt();
            NavError {
                t_s: runs[0][i].t_s,
                pos_m: sq(|e| e.pos_m),
                vel_m_s: sq(|e| e.vel_m_s),
                att_rad: sq(|e| e.att_rad),
            }
        })
        .collect()
}
