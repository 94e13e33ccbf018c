//! Misalignment of the FOG sensitive axes, the paper's **first method**: three calibration
//! turns with Earth rate, the eight angles δ12, δ13, δ21, δ23, δ31, δ32, δ42, δ43 by least
//! squares (section "Ground calibration of the FOG SA position").
//!
//! Turn k brings one ICS axis up (k = 1: Z_P, k = 2: X_P, k = 3: Y_P) and turns the table by
//! Θ_T* at the reference rate ω* (T = Θ_T*/ω*). The reference angles about the ICS axes,
//! from the initial azimuth ψ0, Ω_N = ω_E cos φ and Ω_H = ω_E sin φ, with
//! A = (Ω_N/ω*)(sin ψ0 − sin(ψ0 − Θ_T*)), B = (Ω_N/ω*)(cos(ψ0 − Θ_T*) − cos ψ0),
//! C = Ω_H T + Θ_T*:
//!
//! ```text
//! k = 1: (Θ_XП, Θ_YП, Θ_ZП) = (A, B, C);  k = 2: (C, A, B);  k = 3: (B, C, A)
//! ```
//!
//! and per turn the four equations (Θ_i = Σ ω_i Δt over the turn, δω_i* the systematic
//! drift estimated at the start position):
//!
//! ```text
//! Θ_YП δ13 − Θ_ZП δ12 = Θ1 − δω1* T − Θ_XП
//! −Θ_XП δ23 + Θ_ZП δ21 = Θ2 − δω2* T − Θ_YП
//! Θ_XП δ32 − Θ_YП δ31 = Θ3 − δω3* T − Θ_ZП
//! (c_γ Θ_ZП − s_γ2 (Θ_XП + Θ_YП)) δ42 + c_γ2 (Θ_XП − Θ_YП) δ43 = Θ4 − δω4* T + c_γ2 Θ_XП + c_γ2 Θ_YП + s_γ Θ_ZП
//! ```
//!
//! with the paper's constants c_γ = 0.816497, s_γ = 0.577350, c_γ2 = 0.577351,
//! s_γ2 = 0.408248 (here computed from the table's γ: c_γ = cos β0, s_γ = sin β0,
//! c_γ2 = cos β0 cos 45°, s_γ2 = sin β0 cos 45°, β0 = γ − 90°). Twelve equations, eight
//! unknowns; the three rows of a FOG turned about its own axis hold only its unmodelled
//! scale-factor error and are left out, the other nine are solved by least squares.
//!
//! Geometry of the turntable (the session format's form 2, generalised to the axis that is
//! up): the up axis u, the axis h1 = u+1 (cyclic) at azimuth ψ from north (clockwise), h2 =
//! u × h1; Earth rate in the ICS: (Ω_N cos ψ, Ω_N sin ψ, Ω_H) on (h1, h2, u); the table
//! turns counter-clockwise for ω* > 0, so ψ = ψ0 − ω* t.
//!
//! [`TableSim`] makes turntable sessions with the simulator's FOG model (`sim::fog`: true
//! axes from the true angles, bias, scale factor, ARW, bias random walk), 200 Hz samples
//! summed into 0.1-s rows, a tilt between the table axis and the ICS axis that should be
//! parallel to it, and the encoder's error on the turn angle; it also records measured
//! deflections of the horizontal axes at each static position (for a second method).

use std::path::Path;

use anyhow::{bail, Result};
use nalgebra::{DMatrix, DVector, Matrix3, Rotation3, Vector3};
use rand::SeedableRng;
use rand_chacha::ChaCha20Rng;
use rand_distr::{Distribution, StandardNormal};
use ssis::calib::{Misalignment, GAMMA_NOMINAL_RAD};

use crate::wiring;
use ssis_common::ARCSEC_PER_RAD;
use ssis_session::{nominal_axes, Session, EARTH_RATE_RAD_S};
use ssis_sim::fog::{FogModel, FogSpec, TrueErrors};

/// One calibration turn as the method needs it.
#[derive(Debug, Clone, Copy)]
pub struct Turn {
    /// ICS axis that is up: 0 = X_P (k = 2), 1 = Y_P (k = 3), 2 = Z_P (k = 1).
    pub up: usize,
    /// ψ0, initial azimuth of the axis h1, rad.
    pub psi0_rad: f64,
    /// Θ_T*, measured turn angle (sign of ω*), rad.
    pub theta_t_rad: f64,
    /// ω*, reference table rate, rad/s.
    pub omega_rad_s: f64,
    /// Θ_1 … Θ_4: FOG angle sums over the turn, rad.
    pub theta_fog_rad: [f64; 4],
    /// δω_1* … δω_4*: systematic drift estimates at the start position, rad/s.
    pub drift_rad_s: [f64; 4],
}

/// (Θ_XП, Θ_YП, Θ_ZП) of a turn at latitude φ (module doc).
pub fn reference_angles(t: &Turn, lat_rad: f64) -> [f64; 3] {
    let (on, oh) = (EARTH_RATE_RAD_S * lat_rad.cos(), EARTH_RATE_RAD_S * lat_rad.sin());
    let w = t.omega_rad_s;
    let dur = t.theta_t_rad / w;
    let a = on / w * (t.psi0_rad.sin() - (t.psi0_rad - t.theta_t_rad).sin());
    let b = on / w * ((t.psi0_rad - t.theta_t_rad).cos() - t.psi0_rad.cos());
    let c = oh * dur + t.theta_t_rad;
    let mut out = [0.0; 3];
    out[(t.up + 1) % 3] = a;
    out[(t.up + 2) % 3] = b;
    out[t.up] = c;
    out
}

/// The paper's constants (c_γ, s_γ, c_γ2, s_γ2) for FOG4 angle γ.
pub fn gamma_constants(gamma_rad: f64) -> [f64; 4] {
    let b0 = gamma_rad - std::f64::consts::FRAC_PI_2;
    let c45 = std::f64::consts::FRAC_1_SQRT_2;
    [b0.cos(), b0.sin(), b0.cos() * c45, b0.sin() * c45]
}

/// Result of the first method.
#[derive(Debug, Clone)]
pub struct TurnsResult {
    /// The eight angles.
    pub misalignment: Misalignment,
    /// Residual of each equation kept, rad (turn-major, FOG-minor).
    pub residual_rad: Vec<f64>,
}

/// Angles in the order δ12, δ13, δ21, δ23, δ31, δ32, δ42, δ43, rad.
pub fn angles(m: &Misalignment) -> [f64; 8] {
    [m.d12_rad, m.d13_rad, m.d21_rad, m.d23_rad, m.d31_rad, m.d32_rad, m.d42_rad, m.d43_rad]
}

/// The inverse of [`angles`].
pub fn from_angles(a: &[f64]) -> Misalignment {
    Misalignment {
        d12_rad: a[0],
        d13_rad: a[1],
        d21_rad: a[2],
        d23_rad: a[3],
        d31_rad: a[4],
        d32_rad: a[5],
        d42_rad: a[6],
        d43_rad: a[7],
    }
}

/// Names of the angles in [`angles`] order.
pub const ANGLE_NAMES: [&str; 8] = ["d12", "d13", "d21", "d23", "d31", "d32", "d42", "d43"];

/// Solves the paper's system for the eight angles.
pub fn solve(turns: &[Turn], lat_rad: f64, gamma_rad: f64) -> Result<TurnsResult> {
    if turns.len() < 3 {
        bail!("first method: need three turns (Z, X and Y up), have {}", turns.len());
    }
    let [cg, sg, cg2, sg2] = gamma_constants(gamma_rad);
    let rows = 4 * turns.len();
    let mut a = DMatrix::zeros(rows, 8);
    let mut b = DVector::zeros(rows);
    for (k, t) in turns.iter().enumerate() {
        let [tx, ty, tz] = reference_angles(t, lat_rad);
        let dur = t.theta_t_rad / t.omega_rad_s;
        let m = |i: usize| t.theta_fog_rad[i] - t.drift_rad_s[i] * dur;
        let r = 4 * k;
        a[(r, 1)] = ty;
        a[(r, 0)] = -tz;
        b[r] = m(0) - tx;
        a[(r + 1, 3)] = -tx;
        a[(r + 1, 2)] = tz;
        b[r + 1] = m(1) - ty;
        a[(r + 2, 5)] = tx;
        a[(r + 2, 4)] = -ty;
        b[r + 2] = m(2) - tz;
        a[(r + 3, 6)] = cg * tz - sg2 * (tx + ty);
        a[(r + 3, 7)] = cg2 * (tx - ty);
        b[r + 3] = m(3) + cg2 * tx + cg2 * ty + sg * tz;
    }
    // Rows of a FOG turned about its own axis (FOG i = up, i < 3) carry only Earth-rate
    // coefficients and the FOG's scale-factor error k_i Θ_T*, which the equations do not
    // model; they are left out (the "reduced system").
    let keep: Vec<usize> = (0..rows).filter(|r| r % 4 == 3 || r % 4 != turns[r / 4].up).collect();
    let a = a.select_rows(keep.iter());
    let b = b.select_rows(keep.iter());
    // FOG1-3 keep two rows for two angles (no redundancy); FOG4 three rows for two, whose
    // residual holds FOG4's scale-factor error (it cancels in δ42, δ43 for the symmetric
    // turn set). No scatter-based σ is reported: it would measure that, not the noise.
    let (x, _) = super::lstsq(&a, &b)?;
    let res = &a * &x - &b;
    Ok(TurnsResult { misalignment: from_angles(x.as_slice()), residual_rad: res.iter().copied().collect() })
}

/// Segments of a turntable session: consecutive rows with the same `segment` value.
fn segments(s: &Session) -> Result<Vec<(usize, usize)>> {
    let Some(seg) = s.column("segment") else { bail!("{}: needs the user column `segment`", s.file) };
    let mut out = Vec::new();
    let mut start = 0;
    for r in 1..=seg.len() {
        if r == seg.len() || seg[r] != seg[start] {
            out.push((start, r));
            start = r;
        }
    }
    Ok(out)
}

/// The turns of a session written by [`TableSim`] (or logged the same way): columns
/// `psi_rad`, `lat_rad`, `table_rate_rad_s` and user columns `up_axis` (0 = X_P, 1 = Y_P,
/// 2 = Z_P) and `segment` (even: static at the start position of the next turn, odd: the
/// turn). The drift estimate of each turn is the mean FOG output of the static segment
/// before it minus the Earth rate on the nominal axis.
///
/// Refused when a FOG column does not follow the table's rotation as wired ([`wiring`]).
pub fn turns_from_session(s: &Session) -> Result<(Vec<Turn>, f64)> {
    wiring::require_as_wired(s, &reference_rates(s)?)?;
    let need = |n: &str| s.column(n).ok_or_else(|| anyhow::anyhow!("{}: needs the column `{n}`", s.file));
    let (psi, lat, rate, up) = (need("psi_rad")?, need("lat_rad")?, need("table_rate_rad_s")?, need("up_axis")?);
    let t = s.t_s();
    let segs = segments(s)?;
    let axes = nominal_axes();
    let mut turns = Vec::new();
    for w in segs.windows(2) {
        let ((s0, s1), (t0, t1)) = (w[0], w[1]);
        if rate[s0..s1].iter().any(|r| *r != 0.0) || rate[t0..t1].contains(&0.0) {
            continue; // not a static segment followed by a turn
        }
        let u = up[t0].round() as usize;
        if u > 2 {
            bail!("{}: line {}: field `up_axis`: {} is not 0, 1 or 2", s.file, s.lines[t0], up[t0]);
        }
        // Earth rate on the static position (ψ of the static segment).
        let earth = earth_rate_installed(u, psi[s0], lat[s0]);
        let mut drift = [0.0; 4];
        let n_static = (s1 - s0) as f64;
        for (i, f) in s.fogs.iter().enumerate().take(4) {
            let mean = f.rate_rad_s[s0..s1].iter().sum::<f64>() / n_static;
            drift[i] = mean - axes[i].dot(&earth);
        }
        require_no_gaps(s, t0..t1, "turn")?;
        let mut theta = [0.0; 4];
        for r in t0..t1 {
            let dt = if r == 0 { s.median_dt_s() } else { t[r] - t[r - 1] };
            for (i, f) in s.fogs.iter().enumerate().take(4) {
                theta[i] += f.rate_rad_s[r] * dt;
            }
        }
        let psi0 = psi[s1 - 1];
        turns.push(Turn {
            up: u,
            psi0_rad: psi0,
            theta_t_rad: psi0 - psi[t1 - 1],
            omega_rad_s: rate[t0],
            theta_fog_rad: theta,
            drift_rad_s: drift,
        });
    }
    if turns.is_empty() {
        bail!("{}: no static segment followed by a turn", s.file);
    }
    Ok((turns, lat[0]))
}

/// Largest sample interval, in sample intervals, within a turn (half a sample's tolerance for a
/// logger's jitter).
pub const MAX_INTERVAL_SAMPLES: f64 = 1.5;

/// Refuses `rows` of a session when a sample interval among them (each row's interval ends at
/// its time) exceeds [`MAX_INTERVAL_SAMPLES`] sample intervals: samples were lost there, and an
/// angle summed over the rows would be short by what they carried (one lost 0.1-s row in a
/// 6 °/s turn is 0.35° on FOG4, 160″ on δ42).
pub fn require_no_gaps(s: &Session, rows: std::ops::Range<usize>, what: &str) -> Result<()> {
    let (t, dt) = (s.t_s(), s.median_dt_s());
    for r in rows.start.max(1)..rows.end {
        let step = t[r] - t[r - 1];
        if step > MAX_INTERVAL_SAMPLES * dt {
            bail!(
                "{}: line {}: field `t_s`: time jumps by {step:.3} s within a {what} (the sample interval is \
                 {dt:.3} s): samples were lost there and the {what}'s angle would be short by what they carried; \
                 record the {what} again or cut it from the session",
                s.file,
                s.lines[r]
            );
        }
    }
    Ok(())
}

/// The reference rate of every row of a turntable session (columns `psi_rad`, `lat_rad`,
/// `table_rate_rad_s`, `up_axis`): Earth rate in the installation plus the table's rate
/// about the up axis (counter-clockwise from above for a positive rate), ICS, rad/s.
pub fn reference_rates(s: &Session) -> Result<Vec<Vector3<f64>>> {
    let need = |n: &str| s.column(n).ok_or_else(|| anyhow::anyhow!("{}: needs the column `{n}`", s.file));
    let (psi, lat, rate, up) = (need("psi_rad")?, need("lat_rad")?, need("table_rate_rad_s")?, need("up_axis")?);
    (0..s.len())
        .map(|r| {
            let u = up[r].round() as usize;
            if u > 2 {
                bail!("{}: line {}: field `up_axis`: {} is not 0, 1 or 2", s.file, s.lines[r], up[r]);
            }
            let mut w = earth_rate_installed(u, psi[r], lat[r]);
            w[u] += rate[r];
            Ok(w)
        })
        .collect()
}

/// Earth rate in ICS components with axis `up` vertical and h1 = up+1 at azimuth ψ.
pub fn earth_rate_installed(up: usize, psi_rad: f64, lat_rad: f64) -> Vector3<f64> {
    let (on, oh) = (EARTH_RATE_RAD_S * lat_rad.cos(), EARTH_RATE_RAD_S * lat_rad.sin());
    let mut w = Vector3::zeros();
    w[(up + 1) % 3] = on * psi_rad.cos();
    w[(up + 2) % 3] = on * psi_rad.sin();
    w[up] = oh;
    w
}

/// R_nb of the ideal installation: body → local (North, West, Up); `up` vertical, h1 at
/// azimuth ψ (clockwise from north), h2 = up × h1.
pub fn ideal_r_nb(up: usize, psi_rad: f64) -> Matrix3<f64> {
    let (s, c) = psi_rad.sin_cos();
    let mut m = Matrix3::zeros();
    m.set_column((up + 1) % 3, &Vector3::new(c, -s, 0.0));
    m.set_column((up + 2) % 3, &Vector3::new(s, c, 0.0));
    m.set_column(up, &Vector3::new(0.0, 0.0, 1.0));
    m
}

/// One phase of a turntable run.
#[derive(Debug, Clone, Copy)]
pub struct Phase {
    /// Axis up (a new value starts a new installation).
    pub up: usize,
    /// Table rate, rad/s (0: static).
    pub rate_rad_s: f64,
    /// Duration, s.
    pub duration_s: f64,
}

/// A turntable run: what the simulator makes.
#[derive(Debug, Clone)]
pub struct TableSim {
    /// Latitude, rad.
    pub lat_rad: f64,
    /// The FOGs (truth misalignment in `errors`).
    pub fog: FogSpec,
    /// Initial azimuth of h1 in each installation, rad.
    pub psi0_rad: f64,
    /// Tilt between the table axis and the ICS axis meant to be parallel to it, 1σ per
    /// component, arcsec (drawn per installation).
    pub axis_tilt_sigma_arcsec: f64,
    /// Tilt of the table axis from the vertical, 1σ per component, arcsec (per installation).
    pub leveling_sigma_arcsec: f64,
    /// Error of the measured turn angle (encoder), 1σ, arcsec (per turn).
    pub encoder_sigma_arcsec: f64,
    /// Error of the measured deflections of the horizontal axes, 1σ, arcsec (per static).
    pub tilt_meas_sigma_arcsec: f64,
    /// FOG sample interval, s.
    pub dt_s: f64,
    /// Row interval of the session, s (a multiple of `dt_s`).
    pub row_s: f64,
    /// The phases.
    pub phases: Vec<Phase>,
}

/// The misalignment of the paper's "before" figure scale: a few arcminutes per angle.
pub fn example_truth() -> Misalignment {
    let a = |x: f64| x / ARCSEC_PER_RAD;
    Misalignment {
        d12_rad: a(120.0),
        d13_rad: a(-85.0),
        d21_rad: a(60.0),
        d23_rad: a(140.0),
        d31_rad: a(-110.0),
        d32_rad: a(45.0),
        d42_rad: a(200.0),
        d43_rad: a(-150.0),
    }
}

impl TableSim {
    /// The paper's first-method campaign: in each of Z, X, Y up, 300 s static then one
    /// 360° turn at 6 °/s; FOGs at the paper's post-calibration noise (ARW 0.005 °/√h) with
    /// a 0.01 °/h/√h bias random walk, 1 °/h turn-on biases (the "before" systematic
    /// zero signal), 0.1 % scale-factor errors; 2″ axis tilt, 1″ encoder.
    pub fn first_method(truth: Misalignment) -> Self {
        let mut fog = FogSpec {
            arw_deg_sqrt_h: 0.005,
            rrw_deg_h_sqrt_h: 0.01,
            random_bias_3sigma_deg_h: 3.0,
            random_scale_3sigma: 3e-3,
            ..Default::default()
        };
        fog.errors = Some(TrueErrors { fog: [ssis::calib::FogCal::IDEAL; 4], misalignment: truth });
        let w = 6f64.to_radians();
        let mut phases = Vec::new();
        for up in [2, 0, 1] {
            phases.push(Phase { up, rate_rad_s: 0.0, duration_s: 300.0 });
            phases.push(Phase { up, rate_rad_s: w, duration_s: 60.0 });
        }
        TableSim {
            lat_rad: (50.0 + 3.0 / 60.0) * std::f64::consts::PI / 180.0,
            fog,
            psi0_rad: 0.0,
            axis_tilt_sigma_arcsec: 2.0,
            leveling_sigma_arcsec: 10.0,
            encoder_sigma_arcsec: 1.0,
            tilt_meas_sigma_arcsec: 1.0,
            dt_s: 0.005,
            row_s: 0.1,
            phases,
        }
    }

    /// Runs the simulation: the session rows (header [`TableSim::HEADER`]) and the true
    /// table the FOG model drew (its misalignment is the truth).
    pub fn run(&self, seed: u64) -> (Vec<Vec<f64>>, ssis::calib::CalibrationTable) {
        let mut rng = ChaCha20Rng::seed_from_u64(seed);
        let mut fog = FogModel::new(&self.fog, &mut rng);
        let truth = fog.truth;
        let gauss = |rng: &mut ChaCha20Rng, s: f64| -> f64 {
            let z: f64 = StandardNormal.sample(rng);
            z * s / ARCSEC_PER_RAD
        };
        let w_ie_n = Vector3::new(EARTH_RATE_RAD_S * self.lat_rad.cos(), 0.0, EARTH_RATE_RAD_S * self.lat_rad.sin());
        let per_row = (self.row_s / self.dt_s).round().max(1.0) as usize;
        let mut rows = Vec::new();
        let mut t = 0.0;
        let mut n = 0u64;
        let mut current_up = usize::MAX;
        let mut r_nb = Matrix3::identity();
        let mut axis_n = Vector3::z();
        let mut psi_enc = 0.0;
        let mut segment = -1.0;
        // First row: a zero increment at t = 0 (the reader drops the first increment row).
        let mut first = true;
        for ph in &self.phases {
            if ph.up != current_up {
                current_up = ph.up;
                let tilt_b = Vector3::new(
                    gauss(&mut rng, self.axis_tilt_sigma_arcsec),
                    gauss(&mut rng, self.axis_tilt_sigma_arcsec),
                    0.0,
                );
                let mut mu = Vector3::zeros();
                mu[(ph.up + 1) % 3] = tilt_b.x;
                mu[(ph.up + 2) % 3] = tilt_b.y;
                let tau = Vector3::new(
                    gauss(&mut rng, self.leveling_sigma_arcsec),
                    gauss(&mut rng, self.leveling_sigma_arcsec),
                    0.0,
                );
                // Body sits on the table with mounting tilt μ; the table axis is tilted by τ.
                r_nb = Rotation3::new(tau).matrix() * ideal_r_nb(ph.up, self.psi0_rad) * Rotation3::new(mu).matrix();
                // The table axis in n: the body's up axis before the mounting tilt.
                axis_n = Rotation3::new(tau).matrix() * Vector3::z();
                psi_enc = self.psi0_rad;
            }
            let is_static = ph.rate_rad_s == 0.0;
            segment += 1.0;
            // One measurement of the deflections per static position (0 during turns).
            let tilts = if is_static { self.measured_tilts(&r_nb, ph.up, &mut rng) } else { [0.0; 2] };
            if first {
                let mut row = vec![0.0, 0.0, 0.0, 0.0, 0.0];
                row.extend_from_slice(&[psi_enc, self.lat_rad, 0.0, ph.up as f64, segment]);
                row.extend_from_slice(&tilts);
                rows.push(row);
                first = false;
            }
            let n_rows = (ph.duration_s / self.row_s).round() as usize;
            let dpsi_meas = if is_static { 0.0 } else { gauss(&mut rng, self.encoder_sigma_arcsec) };
            let psi_start = psi_enc;
            for k in 0..n_rows {
                let mut inc = [0.0; 4];
                for _ in 0..per_row {
                    // Body rate relative to inertial, ICS: R_nbᵀ (θ̇ a_n + ω_ie^n), at the middle.
                    let half = Rotation3::new(axis_n * (ph.rate_rad_s * self.dt_s / 2.0)).matrix() * r_nb;
                    let w_b = half.transpose() * (axis_n * ph.rate_rad_s + w_ie_n);
                    n += 1;
                    let s = fog.sample(&(w_b * self.dt_s), n as f64 * self.dt_s, self.dt_s, &mut rng);
                    for (i, f) in s.frames.iter().enumerate() {
                        inc[i] += f.dtheta_rad();
                    }
                    r_nb = Rotation3::new(axis_n * (ph.rate_rad_s * self.dt_s)).matrix() * r_nb;
                }
                t += self.row_s;
                // Encoder: ψ decreases for a counter-clockwise (positive) table rate; its
                // error appears at the end of the turn.
                let frac = (k + 1) as f64 / n_rows as f64;
                psi_enc = psi_start - ph.rate_rad_s * self.row_s * (k + 1) as f64 + dpsi_meas * frac;
                let mut row = vec![t];
                row.extend_from_slice(&inc);
                row.extend_from_slice(&[psi_enc, self.lat_rad, ph.rate_rad_s, ph.up as f64, segment]);
                row.extend_from_slice(&tilts);
                rows.push(row);
            }
        }
        (rows, truth)
    }

    /// Measured elevations of the horizontal axes h1, h2 (rad), with the measurement error.
    fn measured_tilts(&self, r_nb: &Matrix3<f64>, up: usize, rng: &mut ChaCha20Rng) -> [f64; 2] {
        let mut out = [0.0; 2];
        for (k, o) in out.iter_mut().enumerate() {
            let h = r_nb.column((up + 1 + k) % 3);
            let z: f64 = StandardNormal.sample(rng);
            *o = h[2].clamp(-1.0, 1.0).asin() + z * self.tilt_meas_sigma_arcsec / ARCSEC_PER_RAD;
        }
        out
    }

    /// Columns of the session rows.
    pub const HEADER: [&'static str; 12] = [
        "t_s",
        "fog0_rad",
        "fog1_rad",
        "fog2_rad",
        "fog3_rad",
        "psi_rad",
        "lat_rad",
        "table_rate_rad_s",
        "up_axis",
        "segment",
        "tilt_h1_rad",
        "tilt_h2_rad",
    ];

    /// Runs and writes the session; returns the true table.
    pub fn write(&self, path: &Path, seed: u64) -> Result<ssis::calib::CalibrationTable> {
        let (rows, truth) = self.run(seed);
        let t = angles(&truth.misalignment).map(|a| format!("{:.2}", a * ARCSEC_PER_RAD));
        let comment = vec![
            "turntable session (ssis-cal simulate): segment even = static, odd = turn; up_axis 0 X, 1 Y, 2 Z"
                .to_string(),
            format!("truth d12 d13 d21 d23 d31 d32 d42 d43 (arcsec): {}", t.join(" ")),
        ];
        super::write_session_csv(path, &comment, &Self::HEADER, &rows)?;
        Ok(truth)
    }
}

/// Errors of `est` against `truth`, arcsec, in [`angles`] order.
pub fn errors_arcsec(est: &Misalignment, truth: &Misalignment) -> [f64; 8] {
    let (e, t) = (angles(est), angles(truth));
    std::array::from_fn(|k| (e[k] - t[k]) * ARCSEC_PER_RAD)
}

/// The exact sensitive axes for a check of the linearisation (re-exported for tests).
pub fn exact_axes(m: &Misalignment) -> [Vector3<f64>; 4] {
    m.axes(GAMMA_NOMINAL_RAD)
}
