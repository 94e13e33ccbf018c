//! Misalignment of the FOG sensitive axes, the paper's **second method**: the SINS
//! algorithm over flat turns with 180° reversals in three installations, for the
//! orthogonal triad FOG1–FOG3 (section "Ground calibration of the FOG SA position", "The
//! second method"; the paper gives it "in general terms only", so the analytic basis is
//! written out here).
//!
//! **Why 180°.** With axis u vertical and the table turning about it at rate ω, a horizontal
//! FOG whose SA leans towards u by δ reads δ·ω besides its own rate: with the first-order
//! axes s1 = (1, δ13, −δ12), s2 = (−δ23, 1, δ21), s3 = (δ32, −δ31, 1) the triad solution
//! built on assumed angles δ̂ carries the body-rate error e·ω with
//!
//! ```text
//! Z up: e = (−Δδ12, Δδ21, 0);  X up: e = (0, −Δδ23, Δδ32);  Y up: e = (Δδ13, 0, −Δδ31)
//! ```
//!
//! (Δδ = δ − δ̂). The error vector turns with the body, so the SINS's tilt error after a
//! turn by Θ is ∫₀^Θ R_u(θ) e dθ: zero for 360°, largest, 2|e|, for 180° — the paper's
//! "turning 180° substantially impacts the errors". One installation gives the two angles
//! of the horizontal FOGs towards the vertical; three installations (Z, X, Y up) give all
//! six angles of FOG1–FOG3 (the paper: "two non-orthogonality parameters … in one single
//! installation; … all six parameters … requires three installations").
//!
//! **Algorithm.** Each reversal (a static position, a turn, a static position) is run
//! through a strapdown attitude algorithm in the local level frame (North, West, Up):
//!
//! ```text
//! R_nb ← R(−ω_ie^n Δt) · R_nb · R(Δθ_b),   Δθ_b = S(δ̂)⁻¹ (Δθ_FOG − δω* Δt)
//! ```
//!
//! S(δ̂) the triad's exact axes ([`ssis::calib::Misalignment::axes`]), Earth rate ω_ie^n
//! computed exactly, δω* the systematic drift of the static before the turn (its FOG means
//! minus S(δ̂) R_nbᵀ ω_ie^n). The start R_nb is the ideal installation at the encoder's
//! azimuth corrected by the measured deflections of the horizontal axes (the method's
//! "metrological support"); the residual is the SINS's deflections of the two horizontal
//! axes after the turn minus the measured ones. The six angles are found by Gauss–Newton
//! on all residuals (Jacobian by finite differences through the same SINS), starting from
//! the first method's angles (the method needs them within about 1′: "the error measuring
//! models are based on linearized equations").
//!
//! Independent of the turn angle's accuracy, the table's rate and its axis precession (the
//! SINS integrates what the FOGs saw); limited by the deflection measurements (an error ε
//! in one gives about ε/2 in an angle: the paper's "measurement error equals the error of
//! setting those angles"), FOG noise over the turn and the drift estimate.

use anyhow::{bail, Result};
use nalgebra::{DMatrix, DVector, Matrix2, Matrix3, Rotation3, Vector2, Vector3};
use ssis::calib::Misalignment;

use super::misalign_turns::{self, ideal_r_nb, Phase, TableSim};
use ssis_common::ARCSEC_PER_RAD;
use ssis_session::{Session, EARTH_RATE_RAD_S};

/// Names of the six triad angles in [`triad_angles`] order.
pub const TRIAD_NAMES: [&str; 6] = ["d12", "d13", "d21", "d23", "d31", "d32"];

/// δ12, δ13, δ21, δ23, δ31, δ32, rad.
pub fn triad_angles(m: &Misalignment) -> [f64; 6] {
    [m.d12_rad, m.d13_rad, m.d21_rad, m.d23_rad, m.d31_rad, m.d32_rad]
}

/// `m` with its six triad angles replaced (δ42, δ43 kept).
pub fn with_triad(m: &Misalignment, a: &[f64]) -> Misalignment {
    Misalignment { d12_rad: a[0], d13_rad: a[1], d21_rad: a[2], d23_rad: a[3], d31_rad: a[4], d32_rad: a[5], ..*m }
}

/// One reversal: the static before, the turn, the deflections measured before and after.
#[derive(Debug, Clone)]
pub struct Reversal {
    /// ICS axis up: 0 = X_P, 1 = Y_P, 2 = Z_P.
    pub up: usize,
    /// Encoder azimuth of the axis h1 = up+1 at the start, rad.
    pub psi0_rad: f64,
    /// Latitude, rad.
    pub lat_rad: f64,
    /// Measured elevations of h1, h2 before the turn, rad.
    pub tilt0_rad: [f64; 2],
    /// Measured elevations of h1, h2 after the turn, rad.
    pub tilt1_rad: [f64; 2],
    /// Mean FOG1–FOG3 outputs over the static before the turn, rad/s.
    pub static_mean_rad_s: [f64; 3],
    /// FOG1–FOG3 angle increments over the turn, rad, with their intervals, s.
    pub increments_rad: Vec<([f64; 3], f64)>,
    /// Turn angle from the encoder, rad (for the report only).
    pub turn_rad: f64,
}

/// R_nb of a static position: the ideal installation at azimuth ψ turned about horizontal
/// axes so that h1, h2 have the measured elevations (first order, exact enough for ″).
pub fn leveled_r_nb(up: usize, psi_rad: f64, tilt_rad: [f64; 2]) -> Matrix3<f64> {
    let r = ideal_r_nb(up, psi_rad);
    let (d1, d2) = (r.column((up + 1) % 3).into_owned(), r.column((up + 2) % 3).into_owned());
    // Elevation of d after a small rotation φ = (φx, φy, 0): (φ × d)_z = φx d_y − φy d_x.
    let a = Matrix2::new(d1.y, -d1.x, d2.y, -d2.x);
    let phi = a.try_inverse().map(|ai| ai * Vector2::new(tilt_rad[0], tilt_rad[1])).unwrap_or_else(Vector2::zeros);
    Rotation3::new(Vector3::new(phi.x, phi.y, 0.0)).matrix() * r
}

/// Elevations of the horizontal axes h1, h2 of attitude `r_nb`, rad.
pub fn elevations(r_nb: &Matrix3<f64>, up: usize) -> [f64; 2] {
    [r_nb[(2, (up + 1) % 3)].clamp(-1.0, 1.0).asin(), r_nb[(2, (up + 2) % 3)].clamp(-1.0, 1.0).asin()]
}

/// The SINS over one reversal with the triad angles of `m`: the computed deflections after
/// the turn, rad.
pub fn sins_deflections(rv: &Reversal, m: &Misalignment, gamma_rad: f64) -> [f64; 2] {
    let ax = m.axes(gamma_rad);
    let s = Matrix3::from_rows(&[ax[0].transpose(), ax[1].transpose(), ax[2].transpose()]);
    let s_inv = s.try_inverse().unwrap_or_else(Matrix3::identity);
    let w_ie_n = Vector3::new(EARTH_RATE_RAD_S * rv.lat_rad.cos(), 0.0, EARTH_RATE_RAD_S * rv.lat_rad.sin());
    let mut r = leveled_r_nb(rv.up, rv.psi0_rad, rv.tilt0_rad);
    // Systematic drift δω*: static means minus the Earth rate on the assumed axes.
    let earth_b = r.transpose() * w_ie_n;
    let drift = Vector3::from(rv.static_mean_rad_s) - s * earth_b;
    for (inc, dt) in &rv.increments_rad {
        let d_theta_b = s_inv * (Vector3::from(*inc) - drift * *dt);
        r = Rotation3::new(-w_ie_n * *dt).matrix() * r * Rotation3::new(d_theta_b).matrix();
    }
    elevations(&r, rv.up)
}

/// Residuals (computed − measured deflections) of all reversals, rad.
pub fn residuals(revs: &[Reversal], m: &Misalignment, gamma_rad: f64) -> DVector<f64> {
    let mut out = DVector::zeros(2 * revs.len());
    for (k, rv) in revs.iter().enumerate() {
        let c = sins_deflections(rv, m, gamma_rad);
        out[2 * k] = c[0] - rv.tilt1_rad[0];
        out[2 * k + 1] = c[1] - rv.tilt1_rad[1];
    }
    out
}

/// Result of the second method.
#[derive(Debug, Clone)]
pub struct SinsResult {
    /// The angles: six refined, δ42 and δ43 as given.
    pub misalignment: Misalignment,
    /// Residuals before the first iteration, rad (two per reversal).
    pub residual_start_rad: Vec<f64>,
    /// Residuals at the solution, rad.
    pub residual_rad: Vec<f64>,
    /// Gauss–Newton iterations made.
    pub iterations: usize,
    /// 1σ of each of the six angles from the residual scatter, rad (NaN without redundancy).
    pub sigma_rad: [f64; 6],
}

/// Refines the six triad angles of `start` (the first method's) from `revs`.
pub fn solve(revs: &[Reversal], start: &Misalignment, gamma_rad: f64) -> Result<SinsResult> {
    for up in 0..3 {
        if !revs.iter().any(|r| r.up == up) {
            bail!("second method: no reversal with {} up (three installations are needed)", ["X", "Y", "Z"][up]);
        }
    }
    let h = 1e-6; // rad (0.2″): the problem is linear at this scale
    let mut p = triad_angles(start);
    let r0 = residuals(revs, start, gamma_rad);
    let mut iterations = 0;
    let mut cov = DMatrix::zeros(6, 6);
    for _ in 0..8 {
        iterations += 1;
        let r = residuals(revs, &with_triad(start, &p), gamma_rad);
        let mut j = DMatrix::zeros(r.len(), 6);
        for k in 0..6 {
            let mut q = p;
            q[k] += h;
            let rk = residuals(revs, &with_triad(start, &q), gamma_rad);
            j.set_column(k, &((rk - &r) / h));
        }
        let (dx, c) = super::lstsq(&j, &(-&r))?;
        cov = c;
        for (pk, d) in p.iter_mut().zip(dx.iter()) {
            *pk += d;
        }
        if dx.amax() * ARCSEC_PER_RAD < 1e-3 {
            break;
        }
    }
    let m = with_triad(start, &p);
    let r = residuals(revs, &m, gamma_rad);
    let dof = r.len() as f64 - 6.0;
    let s2 = if dof > 0.0 { r.norm_squared() / dof } else { f64::NAN };
    let sigma_rad = std::array::from_fn(|k| (s2 * cov[(k, k)]).sqrt());
    Ok(SinsResult {
        misalignment: m,
        residual_start_rad: r0.iter().copied().collect(),
        residual_rad: r.iter().copied().collect(),
        iterations,
        sigma_rad,
    })
}

/// The reversals of a session written by [`second_method_sim`] (or logged the same way,
/// `misalign_turns::TableSim::HEADER`): each turn segment with a static segment before and
/// after it in the same installation; the deflections are the `tilt_h1_rad`,
/// `tilt_h2_rad` of those statics. FOG columns 0–2 are the triad; `scale` are the table's
/// scale-factor errors applied to them.
///
/// Refused when a FOG column does not follow the table's rotation as wired
/// ([`crate::wiring`]).
pub fn reversals_from_session(s: &Session, scale: [f64; 3]) -> Result<Vec<Reversal>> {
    crate::wiring::require_as_wired(s, &misalign_turns::reference_rates(s)?)?;
    let need = |n: &str| s.column(n).ok_or_else(|| anyhow::anyhow!("{}: needs the column `{n}`", s.file));
    let (psi, lat, rate, up) = (need("psi_rad")?, need("lat_rad")?, need("table_rate_rad_s")?, need("up_axis")?);
    let (t1, t2, seg) = (need("tilt_h1_rad")?, need("tilt_h2_rad")?, need("segment")?);
    if s.fogs.len() < 3 {
        bail!("{}: needs FOG0-FOG2 (the orthogonal triad)", s.file);
    }
    let t = s.t_s();
    let mut segs = Vec::new();
    let mut start = 0;
    for r in 1..=seg.len() {
        if r == seg.len() || seg[r] != seg[start] {
            segs.push((start, r));
            start = r;
        }
    }
    let mut out = Vec::new();
    for w in segs.windows(3) {
        let ((a0, a1), (b0, b1), (c0, c1)) = (w[0], w[1], w[2]);
        let is_static = |x0: usize, x1: usize| rate[x0..x1].iter().all(|r| *r == 0.0);
        if !is_static(a0, a1) || rate[b0..b1].contains(&0.0) || !is_static(c0, c1) {
            continue;
        }
        let u = up[b0].round() as usize;
        if u > 2 || up[a0].round() as usize != u || up[c0].round() as usize != u {
            continue; // a new installation between the statics
        }
        let n = (a1 - a0) as f64;
        let static_mean_rad_s =
            std::array::from_fn(|i| s.fogs[i].rate_rad_s[a0..a1].iter().sum::<f64>() / n / (1.0 + scale[i]));
        misalign_turns::require_no_gaps(s, b0..b1, "turn")?;
        let increments_rad = (b0..b1)
            .map(|r| {
                let dt = if r == 0 { s.median_dt_s() } else { t[r] - t[r - 1] };
                (std::array::from_fn(|i| s.fogs[i].rate_rad_s[r] * dt / (1.0 + scale[i])), dt)
            })
            .collect();
        out.push(Reversal {
            up: u,
            psi0_rad: psi[a1 - 1],
            lat_rad: lat[a0],
            tilt0_rad: [t1[a1 - 1], t2[a1 - 1]],
            tilt1_rad: [t1[c0], t2[c0]],
            static_mean_rad_s,
            increments_rad,
            turn_rad: psi[a1 - 1] - psi[b1 - 1],
        });
    }
    if out.is_empty() {
        bail!("{}: no static-turn-static sequence in one installation", s.file);
    }
    Ok(out)
}

/// The second-method campaign: in each of Z, X, Y up, 300 s static, +180° at 6 °/s, 120 s
/// static, −180° back, 120 s static; the same FOGs, table and instruments as
/// [`TableSim::first_method`] (2″ axis tilt, 10″ leveling, 1″ deflection measurements).
pub fn second_method_sim(truth: Misalignment) -> TableSim {
    let mut sim = TableSim::first_method(truth);
    let w = 6f64.to_radians();
    let turn_s = std::f64::consts::PI / w;
    sim.phases.clear();
    for up in [2, 0, 1] {
        sim.phases.push(Phase { up, rate_rad_s: 0.0, duration_s: 300.0 });
        sim.phases.push(Phase { up, rate_rad_s: w, duration_s: turn_s });
        sim.phases.push(Phase { up, rate_rad_s: 0.0, duration_s: 120.0 });
        sim.phases.push(Phase { up, rate_rad_s: -w, duration_s: turn_s });
        sim.phases.push(Phase { up, rate_rad_s: 0.0, duration_s: 120.0 });
    }
    sim
}

/// Errors of the six triad angles of `est` against `truth`, arcsec.
pub fn errors_arcsec(est: &Misalignment, truth: &Misalignment) -> [f64; 6] {
    let e = misalign_turns::errors_arcsec(est, truth);
    [e[0], e[1], e[2], e[3], e[4], e[5]]
}
