//! Magnetic sensitivity of the FOGs (the paper's section "Studying the FOG magnetic
//! sensitivity", eqs. 1–3).
//!
//! The unit stands on a turntable with Z_P up; X_P is set to 25 azimuths ψ_i (15° steps,
//! 0° … 360°). At each the FOG error y = ω_raw − s⁰·ω_Earth is averaged. Eq. (1):
//!
//! ```text
//! f_x(ψ) = δΩ_x + S_x sin(ψ + Δφ_x),     f_y(ψ) = δΩ_y + S_y cos(ψ + Δφ_y)
//! ```
//!
//! fitted (linear least squares in δΩ, S cos Δφ, S sin Δφ) to the unscreened and the
//! screened runs; eq. (2) is the fit of their difference (unscreened − screened), which
//! removes everything the screen does not change: bias, the Earth-rate leak of axis
//! misalignment (also at frequency ψ), scale factor.
//!
//! The Earth field of a simulated test ([`MagneticSim::kharkov`]) and of the prediction
//! with a site and date is the World Magnetic Model (WMM2025, the real field); the paper's
//! "dipole tilt" model is kept for reproducing its example (`--field paper`,
//! `--paper-field`), OCS components:
//!
//! ```text
//! B0X = B0 sin ξm sin(u − ηm),  B0Y = B0 cos ξm,  B0Z = −2 B0 sin ξm cos(u − ηm)
//! sin ξm = √(1 − (sin φm cos i + cos φm sin i sin ΩΣ)²)
//! ```
//!
//! **ηm.** The paper prints ηm = arctg[(sin φm sin i − cos φm cos i sin ΩΣ)/(cos φm cos Ωm)].
//! With the paper's inputs (B0 = 31 000 nT, φm = 78.5°, Ωm = 69.1°, λ = 36°17′,
//! u = φ = 50°03′, i = 90°) that gives ηm = 85.85° and B0X = −17 791 nT, not the printed
//! 21 846.0. The reciprocal, ηm = arcctg[…] = arctg[cos φm cos Ωm /(sin φm sin i −
//! cos φm cos i sin ΩΣ)] = 4.15°, gives B0X = 21 845.6, B0Y = 5 959.1, B0Z = −42 343 nT,
//! the paper's numbers to 0.01 %, 0.13 % and 0.01 %. [`DipoleTilt::field_ocs_nt`] uses the
//! form that reproduces the worked example; [`DipoleTilt::eta_as_printed_rad`] keeps the
//! printed one for comparison.
//!
//! Projection into the ICS (the paper's matrix, a turn by ψ_Π about Z):
//! B_Π = (B0X cos ψ_Π + B0Y sin ψ_Π, −B0X sin ψ_Π + B0Y cos ψ_Π, B0Z), with (B0X, B0Y, B0Z)
//! the (north, west, up) components; eq. (3): cos α_j = B_Πj / |B_Π|. The maximum of |Δf_x|
//! is where α_x = 90°, which gives the phase Δφ = −arctg(B0Y/B0X) (−15.28° for Kharkov; the
//! paper: −15.3°).
//!
//! **Azimuth.** The paper's ψ_Π turns counter-clockwise; a session's `psi_rad` is clockwise
//! from north (`docs/SESSION-FORMAT.md`), so ψ_Π = −ψ. Fields and Earth rates here are in the
//! session's frame ([`field_ics_nt`] is `ssis_session::field_ics_nt`, which equals B_Π at
//! ψ_Π = −ψ); eqs. (1) and (2) are fitted in the paper's ψ_Π, so Δφ is the paper's.

use std::path::Path;

use anyhow::{bail, Result};
use nalgebra::{DMatrix, DVector};
use rand::SeedableRng;
use rand_chacha::ChaCha20Rng;
use rand_distr::{Distribution, StandardNormal};

use ssis_common::DEG_H_PER_RAD_S;
use ssis_session::{earth_rate_ics, nominal_axes, Session};

/// The paper's "dipole tilt" Earth-field model.
#[derive(Debug, Clone, Copy)]
pub struct DipoleTilt {
    /// B0, field modulus at the magnetic equator, nT.
    pub b0_nt: f64,
    /// φm, latitude of the dipole axis, rad.
    pub phi_m_rad: f64,
    /// Ωm, longitude angle of the dipole axis, rad.
    pub omega_m_rad: f64,
}

/// Inputs of the paper's Kharkov example.
#[derive(Debug, Clone, Copy)]
pub struct Site {
    /// u, argument of latitude (= the site latitude φ for i = 90°), rad.
    pub u_rad: f64,
    /// i, inclination (90° for a site on the ground), rad.
    pub incl_rad: f64,
    /// ΩΣ = Ωm + λ at 00:00:00, rad.
    pub omega_sigma_rad: f64,
}

impl DipoleTilt {
    /// The paper's values: B0 = 31·10³ nT, φm = 78.5°, Ωm = 69.1°.
    pub const PAPER: DipoleTilt = DipoleTilt { b0_nt: 31.0e3, phi_m_rad: 78.5 * DEG, omega_m_rad: 69.1 * DEG };

    /// The paper's test site: Kharkov, φ = 50°03′, λ = 36°17′, i = 90°, t = 0.
    pub fn kharkov(&self) -> Site {
        let lat = (50.0 + 3.0 / 60.0) * DEG;
        let lon = (36.0 + 17.0 / 60.0) * DEG;
        Site { u_rad: lat, incl_rad: 90.0 * DEG, omega_sigma_rad: self.omega_m_rad + lon }
    }

    /// sin ξm.
    pub fn sin_xi(&self, s: &Site) -> f64 {
        let c =
            self.phi_m_rad.sin() * s.incl_rad.cos() + self.phi_m_rad.cos() * s.incl_rad.sin() * s.omega_sigma_rad.sin();
        (1.0 - c * c).max(0.0).sqrt()
    }

    /// ηm as printed: arctg[(sin φm sin i − cos φm cos i sin ΩΣ)/(cos φm cos Ωm)].
    pub fn eta_as_printed_rad(&self, s: &Site) -> f64 {
        let (num, den) = self.eta_terms(s);
        (num / den).atan()
    }

    /// ηm that reproduces the worked example: arcctg of the printed ratio.
    pub fn eta_rad(&self, s: &Site) -> f64 {
        let (num, den) = self.eta_terms(s);
        (den / num).atan()
    }

    fn eta_terms(&self, s: &Site) -> (f64, f64) {
        let (sp, cp) = self.phi_m_rad.sin_cos();
        let num = sp * s.incl_rad.sin() - cp * s.incl_rad.cos() * s.omega_sigma_rad.sin();
        (num, cp * self.omega_m_rad.cos())
    }

    /// B0 in the local OCS, nT, with ηm as given.
    pub fn field_with_eta_nt(&self, s: &Site, eta_rad: f64) -> [f64; 3] {
        let sx = self.sin_xi(s);
        let cx = (1.0 - sx * sx).max(0.0).sqrt();
        let a = s.u_rad - eta_rad;
        [self.b0_nt * sx * a.sin(), self.b0_nt * cx, -2.0 * self.b0_nt * sx * a.cos()]
    }

    /// B0 in the local OCS, nT (the worked example's form, see the module doc).
    pub fn field_ocs_nt(&self, s: &Site) -> [f64; 3] {
        self.field_with_eta_nt(s, self.eta_rad(s))
    }
}

const DEG: f64 = std::f64::consts::PI / 180.0;

/// The Earth's main field at a site and date from the World Magnetic Model (WMM2025,
/// `ssis_session::wmm_field_nwu_nt`), as (north, west, up) components, nT — the real field,
/// where the paper's dipole tilt ([`DipoleTilt`]) is 2.5–9 µT off at Kharkov. `lat_deg`,
/// `lon_deg` WGS 84, `height_m` above the ellipsoid.
pub fn wmm_field_nwu_nt(lat_deg: f64, lon_deg: f64, height_m: f64, year: i32, day_of_year: u16) -> Result<[f64; 3]> {
    ssis_session::wmm_field_nwu_nt(ssis_session::Site { lat_deg, lon_deg, height_m }, (year, day_of_year))
        .map_err(anyhow::Error::msg)
}

/// The field in the ICS at the session's azimuth ψ (clockwise), from (north, west, up)
/// components: the paper's B_Π at ψ_Π = −ψ (module text).
pub fn field_ics_nt(b0_nt: [f64; 3], psi_rad: f64) -> [f64; 3] {
    ssis_session::field_ics_nt(b0_nt, psi_rad)
}

/// α_j (eq. 3): angle between B_Π and the sensitive axis `axis` (unit), rad.
pub fn alpha_rad(b_ics_nt: [f64; 3], axis: [f64; 3]) -> f64 {
    let n = b_ics_nt.iter().map(|v| v * v).sum::<f64>().sqrt();
    let c = b_ics_nt.iter().zip(axis).map(|(b, a)| b * a).sum::<f64>() / n;
    c.clamp(-1.0, 1.0).acos()
}

/// The predicted phase Δφ = −arctg(B0Y/B0X), rad.
pub fn predicted_phase_rad(b0_nt: [f64; 3]) -> f64 {
    -(b0_nt[1] / b0_nt[0]).atan()
}

/// Which form of eq. (1).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Form {
    /// f_x: δΩ + S sin(ψ + Δφ).
    Sin,
    /// f_y: δΩ + S cos(ψ + Δφ).
    Cos,
}

/// A fit of eq. (1) or (2).
#[derive(Debug, Clone, Copy)]
pub struct SinusoidFit {
    /// δΩ (or ΔΩ), rad/s.
    pub offset_rad_s: f64,
    /// S ≥ 0, rad/s.
    pub amplitude_rad_s: f64,
    /// Δφ in (−π, π], rad.
    pub phase_rad: f64,
    /// 1σ of Δφ from the fit (residual scatter), rad.
    pub phase_sigma_rad: f64,
    /// 1σ of S, rad/s.
    pub amplitude_sigma_rad_s: f64,
    /// Residual RMS, rad/s.
    pub rms_rad_s: f64,
}

impl SinusoidFit {
    /// Value at ψ.
    pub fn eval(&self, form: Form, psi_rad: f64) -> f64 {
        let a = psi_rad + self.phase_rad;
        self.offset_rad_s + self.amplitude_rad_s * if form == Form::Sin { a.sin() } else { a.cos() }
    }
}

/// Fits eq. (1) of `form` to (ψ_i, y_i).
pub fn fit(form: Form, psi_rad: &[f64], y_rad_s: &[f64]) -> Result<SinusoidFit> {
    let n = psi_rad.len();
    if n < 4 || y_rad_s.len() != n {
        bail!("magnetic fit: need at least 4 positions, have {n}");
    }
    // Sin form: S sin(ψ+Δφ) = (S cos Δφ) sin ψ + (S sin Δφ) cos ψ.
    // Cos form: S cos(ψ+Δφ) = (S cos Δφ) cos ψ − (S sin Δφ) sin ψ.
    let a = DMatrix::from_fn(n, 3, |r, c| {
        let (s, co) = psi_rad[r].sin_cos();
        match (form, c) {
            (_, 0) => 1.0,
            (Form::Sin, 1) => s,
            (Form::Sin, _) => co,
            (Form::Cos, 1) => co,
            (Form::Cos, _) => -s,
        }
    });
    let b = DVector::from_column_slice(y_rad_s);
    let (x, cov) = super::lstsq(&a, &b)?;
    let res = &a * &x - &b;
    let rms = (res.norm_squared() / n as f64).sqrt();
    let s2 = res.norm_squared() / (n as f64 - 3.0).max(1.0);
    let (p, q) = (x[1], x[2]); // S cos Δφ, S sin Δφ
    let amp = p.hypot(q);
    let phase = q.atan2(p);
    // Linearised: σ_S² = (p² σp² + q² σq² + 2pq cpq)/S², σ_φ² = (q² σp² + p² σq² − 2pq cpq)/S⁴.
    let (vp, vq, cpq) = (cov[(1, 1)] * s2, cov[(2, 2)] * s2, cov[(1, 2)] * s2);
    let amp_sigma = ((p * p * vp + q * q * vq + 2.0 * p * q * cpq) / (amp * amp)).max(0.0).sqrt();
    let phase_sigma = ((q * q * vp + p * p * vq - 2.0 * p * q * cpq) / amp.powi(4)).max(0.0).sqrt();
    Ok(SinusoidFit {
        offset_rad_s: x[0],
        amplitude_rad_s: amp,
        phase_rad: phase,
        phase_sigma_rad: phase_sigma,
        amplitude_sigma_rad_s: amp_sigma,
        rms_rad_s: rms,
    })
}

/// Mean FOG error y = ω_raw − s⁰·ω_ref per azimuth position of a turntable session
/// (consecutive rows with the same `psi_rad`): (ψ_i, [y per FOG]).
pub fn position_means(s: &Session) -> Result<Vec<(f64, Vec<f64>)>> {
    let Some(psi) = s.column("psi_rad") else {
        bail!("{}: the magnetic method needs the turntable column psi_rad", s.file);
    };
    let axes = nominal_axes();
    let mut out: Vec<(f64, Vec<f64>, usize)> = Vec::new();
    for (r, &p_r) in psi.iter().enumerate() {
        let same = out.last().is_some_and(|(p, _, _)| (p - p_r).abs() < 1e-9);
        if !same {
            out.push((p_r, vec![0.0; s.fogs.len()], 0));
        }
        let w = s.ref_rad_s[r];
        let last = out.last_mut().expect("pushed");
        for (i, f) in s.fogs.iter().enumerate() {
            let expect = axes[i].x * w[0] + axes[i].y * w[1] + axes[i].z * w[2];
            last.1[i] += f.rate_rad_s[r] - expect;
        }
        last.2 += 1;
    }
    Ok(out.into_iter().map(|(p, sum, n)| (p, sum.into_iter().map(|v| v / n as f64).collect())).collect())
}

/// Result of the unscreened/screened analysis.
#[derive(Debug, Clone)]
pub struct MagneticResult {
    /// Azimuths of the positions in the paper's sense, ψ_Π = −ψ of the session, rad (the
    /// fits' argument).
    pub psi_rad: Vec<f64>,
    /// Δf_x, Δf_y at each position (unscreened − screened), rad/s.
    pub diff_rad_s: [Vec<f64>; 2],
    /// Eq. (1) fits of the unscreened run, FOGX and FOGY.
    pub unscreened: [SinusoidFit; 2],
    /// Eq. (1) fits of the screened run.
    pub screened: [SinusoidFit; 2],
    /// Eq. (2): fits of the difference.
    pub magnetic: [SinusoidFit; 2],
}

/// Eq. (1) on both runs and eq. (2) on their difference, in the paper's azimuth ψ_Π = −ψ.
/// The runs must visit the same azimuths in the same order.
///
/// Refused when a FOG column does not follow the Earth rate over the azimuths as wired
/// ([`crate::wiring`]: a reversed FOG would turn the Earth-rate leak, and the fits, over).
pub fn analyse(unscreened: &Session, screened: &Session) -> Result<MagneticResult> {
    for session in [unscreened, screened] {
        let reference: Vec<nalgebra::Vector3<f64>> = session.ref_rad_s.iter().map(|w| (*w).into()).collect();
        crate::wiring::require_as_wired(session, &reference)?;
    }
    let u = position_means(unscreened)?;
    let s = position_means(screened)?;
    if u.len() != s.len() || u.iter().zip(&s).any(|(a, b)| (a.0 - b.0).abs() > 1e-6) {
        bail!(
            "{} and {}: the runs must visit the same azimuths ({} and {} positions)",
            unscreened.file,
            screened.file,
            u.len(),
            s.len()
        );
    }
    if u.first().is_none_or(|p| p.1.len() < 2) {
        bail!("{}: the magnetic method needs FOG0 (X) and FOG1 (Y)", unscreened.file);
    }
    let psi: Vec<f64> = u.iter().map(|p| -p.0).collect();
    let col = |v: &[(f64, Vec<f64>)], i: usize| -> Vec<f64> { v.iter().map(|p| p.1[i]).collect() };
    let forms = [Form::Sin, Form::Cos];
    let mut fu = Vec::new();
    let mut fs = Vec::new();
    let mut fd = Vec::new();
    let mut diffs = Vec::new();
    for (i, form) in forms.into_iter().enumerate() {
        let (yu, ys) = (col(&u, i), col(&s, i));
        let d: Vec<f64> = yu.iter().zip(&ys).map(|(a, b)| a - b).collect();
        fu.push(fit(form, &psi, &yu)?);
        fs.push(fit(form, &psi, &ys)?);
        fd.push(fit(form, &psi, &d)?);
        diffs.push(d);
    }
    Ok(MagneticResult {
        psi_rad: psi,
        diff_rad_s: [diffs[0].clone(), diffs[1].clone()],
        unscreened: [fu[0], fu[1]],
        screened: [fs[0], fs[1]],
        magnetic: [fd[0], fd[1]],
    })
}

/// A simulated magnetic test (two sessions: unscreened and screened).
#[derive(Debug, Clone)]
pub struct MagneticSim {
    /// B0 at the site, OCS, nT.
    pub b0_nt: [f64; 3],
    /// Latitude, rad.
    pub lat_rad: f64,
    /// Sensitivity of FOGX to the field along −Y_P and of FOGY to the field along X_P
    /// (the in-loop-plane components that turn with ψ), (rad/s)/nT. With these signs the
    /// error is S sin(ψ + Δφ) for X and S cos(ψ + Δφ) for Y, Δφ = −arctg(B0Y/B0X).
    pub k_inplane_rad_s_per_nt: [f64; 2],
    /// Sensitivity to the vertical field (constant with ψ), (rad/s)/nT.
    pub k_vertical_rad_s_per_nt: [f64; 2],
    /// Fraction of the field left inside the screen.
    pub screen_residual: f64,
    /// Biases of FOG0..2, rad/s.
    pub bias_rad_s: [f64; 3],
    /// True misalignment δ13 (FOGX toward Y) and δ23 (FOGY toward −X), rad: their Earth-rate
    /// leak is also at frequency ψ and cancels in eq. (2).
    pub d13_d23_rad: [f64; 2],
    /// Angle random walk, °/√h.
    pub arw_deg_sqrt_h: f64,
    /// Dwell per position, s (the session has one row per `row_s`).
    pub dwell_s: f64,
    /// Row interval, s.
    pub row_s: f64,
}

impl MagneticSim {
    /// Kharkov in the real field (WMM2025 on 2025-001, [`MagneticSim::kharkov_in`]).
    pub fn kharkov() -> Result<Self> {
        MagneticSim::kharkov_in(ssis_session::FieldModel::default())
    }

    /// Kharkov in the field of `model` (the paper's dipole tilt reproduces its example), a
    /// 0.10 °/h in-plane effect (the paper: 0.05–0.15 °/h), 2 % residual in the screen,
    /// 0.005 °/√h, the paper's "before" axis errors (300″, −250″), 30-min dwells as 10-s means.
    pub fn kharkov_in(model: ssis_session::FieldModel) -> Result<Self> {
        let b0 = match model {
            ssis_session::FieldModel::PaperDipole => DipoleTilt::PAPER.field_ocs_nt(&DipoleTilt::PAPER.kharkov()),
            m => m.nwu_nt(ssis_session::KHARKOV_SITE, ssis_session::FIELD_EPOCH).map_err(anyhow::Error::msg)?,
        };
        let bh = b0[0].hypot(b0[1]);
        let k = 0.10 / DEG_H_PER_RAD_S / bh;
        Ok(MagneticSim {
            b0_nt: b0,
            lat_rad: (50.0 + 3.0 / 60.0) * DEG,
            k_inplane_rad_s_per_nt: [k, 0.8 * k],
            k_vertical_rad_s_per_nt: [0.3 * k, -0.2 * k],
            screen_residual: 0.02,
            bias_rad_s: [0.3 / DEG_H_PER_RAD_S, -0.2 / DEG_H_PER_RAD_S, 0.1 / DEG_H_PER_RAD_S],
            d13_d23_rad: [300.0 / ssis_common::ARCSEC_PER_RAD, -250.0 / ssis_common::ARCSEC_PER_RAD],
            arw_deg_sqrt_h: 0.005,
            dwell_s: 1800.0,
            row_s: 10.0,
        })
    }

    /// The true magnetic error of FOGX, FOGY at ψ with field fraction `f`, rad/s.
    pub fn magnetic_rad_s(&self, psi_rad: f64, f: f64) -> [f64; 2] {
        let b = field_ics_nt(self.b0_nt, psi_rad);
        let k = self.k_inplane_rad_s_per_nt;
        let kv = self.k_vertical_rad_s_per_nt;
        [f * (-k[0] * b[1] + kv[0] * b[2]), f * (k[1] * b[0] + kv[1] * b[2])]
    }

    /// The true eq. (2) parameters: (ΔS, Δφ) for FOGX and FOGY.
    pub fn truth(&self) -> [(f64, f64); 2] {
        let f = 1.0 - self.screen_residual;
        let bh = self.b0_nt[0].hypot(self.b0_nt[1]);
        let ph = predicted_phase_rad(self.b0_nt);
        [(f * self.k_inplane_rad_s_per_nt[0] * bh, ph), (f * self.k_inplane_rad_s_per_nt[1] * bh, ph)]
    }

    /// Writes the unscreened and screened sessions (25 positions, ψ = 0°, 15°, … 360°).
    pub fn write(&self, unscreened: &Path, screened: &Path, seed: u64) -> Result<()> {
        let mut rng = ChaCha20Rng::seed_from_u64(seed);
        for (path, frac, name) in [(unscreened, 1.0, "unscreened"), (screened, self.screen_residual, "screened")] {
            let mut rows = Vec::new();
            let per = (self.dwell_s / self.row_s).round().max(1.0) as usize;
            let sigma = self.arw_deg_sqrt_h.to_radians() / 60.0 / self.row_s.sqrt();
            let [d13, d23] = self.d13_d23_rad;
            let mut t = 0.0;
            for p in 0..25 {
                let psi = (15.0 * p as f64) * DEG;
                let w = earth_rate_ics(psi, self.lat_rad);
                let b = field_ics_nt(self.b0_nt, psi);
                let mag = self.magnetic_rad_s(psi, frac);
                // First-order axes: s1 = (1, δ13, 0), s2 = (−δ23, 1, 0), s3 = (0, 0, 1).
                let true_rate = [w[0] + d13 * w[1], w[1] - d23 * w[0], w[2]];
                for _ in 0..per {
                    t += self.row_s;
                    let mut row = vec![t];
                    for i in 0..3 {
                        let m = if i < 2 { mag[i] } else { 0.0 };
                        let z: f64 = StandardNormal.sample(&mut rng);
                        row.push(true_rate[i] + self.bias_rad_s[i] + m + sigma * z);
                    }
                    row.extend_from_slice(&[psi, self.lat_rad, frac * b[0], frac * b[1], frac * b[2]]);
                    rows.push(row);
                }
            }
            let header =
                ["t_s", "fog0_rad_s", "fog1_rad_s", "fog2_rad_s", "psi_rad", "lat_rad", "b_x_nt", "b_y_nt", "b_z_nt"];
            let comment = vec![
                format!(
                    "magnetic test, {name}: 25 azimuths x {} s, {} s means (ssis-cal simulate)",
                    self.dwell_s, self.row_s
                ),
                format!(
                    "truth: in-plane sensitivity {:?} (rad/s)/nT, field fraction {frac}",
                    self.k_inplane_rad_s_per_nt
                ),
            ];
            super::write_session_csv(path, &comment, &header, &rows)?;
        }
        Ok(())
    }
}
