//! Orbital calibration on telemetry as the firmware records it (section "The methodology
//! of orbital calibration"): the output frames of every step (`docs/ICD.md`: Λ, the ICS
//! rate with the drift estimate removed, the drift estimate Δω̂, flags, FOG health) and the
//! star-tracker frames the unit received (Λ* of eq. 5, time tag, valid flag). Three
//! estimates, in the paper's order ("advisable to apply after calibration of zero bias and
//! scaling factors"):
//!
//! 1. **Zero bias** ([`bias_from_observer`]): the observer of eq. (6) estimates the ICS
//!    drift Δω; "the final value of zero bias must be received by averaging it on a steady
//!    plot of evaluation". Steady part: from the converged flag plus a settling time to the
//!    first maneuver. The body drift d maps to the FOGs as Δb_i = s_i · d (the minimum-norm
//!    FOG biases whose least-squares combination is d; the parity part of four FOG biases is
//!    not observable through the observer).
//! 2. **Scale factors** ([`scale_from_maneuvers`]): under star-tracker reference, a 360°
//!    maneuver about an axis u; the angle the gyros saw, Θ_FOG = Σ (ω_out + Δω̂ − d) Δt (the
//!    output rate with the observer's drift put back, so that its absorbing the scale error
//!    during the turn does not hide it), against the star tracker's,
//!    Θ_ST = Σ rotvec(Λ_b,k−1⁻¹ ∘ Λ_b,k), Λ_b = Λ* ∘ q_bs⁻¹ (the sum telescopes: only the
//!    noise of the first and last frames stays). With D = H⁺ diag(Δk) H (H the table's axes,
//!    H⁺ the unit's least-squares combination), uᵀ D u = (Θ_FOG − Θ_ST)·u / |Θ_ST| for each
//!    maneuver; Δk of the FOGs by least squares (as many maneuvers with independent rows as
//!    FOGs: for four FOGs the X, Y, Z axes and the FOG4 axis).
//! 3. **FOG-to-star-tracker misalignment** ([`mount_rls`]): "the interconnection of
//!    equations of angular velocity by recursive least squares": between consecutive star
//!    frames, ω_ST Δt = R(η)ᵀ ω_FOG Δt ≈ ω_FOG Δt + [ω_FOG Δt ×] η, with ω_FOG the gyro rate
//!    corrected by steps 1 and 2 and Λ_b = Λ_ICS ∘ η (η the mount error in the ICS); RLS
//!    on η (three unknowns, rank two per sample, so turns about two axes at least). The new
//!    mount is q_bs ← exp(η̂) ∘ q_bs.
//!
//! [`fly`] makes such telemetry: a scenario through the flight core (the harness's
//! simulator and mock links), capturing the bytes of the output link and of the star link.
//! [`calibration_flight`] is a scenario for it: inertial hold, then 360° maneuvers about
//! X, Y, Z and the FOG4 axis, FOG errors of the paper's "before" size.

use anyhow::{anyhow, bail, Result};
use nalgebra::{DMatrix, DVector, Matrix3, Quaternion, Vector3, Vector4};
use ssis::calib::{CalibrationTable, FogCal, Misalignment, N_FOG};
use ssis::combination::{Combiner, FogSet};
use ssis::flight::{flags, FlightCore, FogLinks, Links};
use ssis::frames::decoder::StreamDecoder;
use ssis::frames::output::OutputFrame;
use ssis::frames::star::StarFrame;
use ssis::math::{quat_from_rotvec, rotvec_from_quat};

use ssis_common::mock::{MockLink, MockSink};
use ssis_common::{ARCSEC_PER_RAD, DEG_H_PER_RAD_S};
use ssis_sim::fog::{FogSpec, TrueErrors};
use ssis_sim::harness::Simulation;
use ssis_sim::scenario::{ProfileName, Scenario, TableSource, TableSpec};
use ssis_sim::star::StarSpec;
use ssis_sim::truth::{MotionSpec, Slew};

/// One output frame, physical.
#[derive(Debug, Clone, Copy)]
pub struct OutSample {
    /// Time tag (end of the step), µs.
    pub time_us: u64,
    /// ICS rate, drift removed, rad/s.
    pub rate_rad_s: Vector3<f64>,
    /// Drift estimate Δω̂, rad/s.
    pub drift_rad_s: Vector3<f64>,
    /// Flags.
    pub flags: u8,
    /// FOGs combined.
    pub used: FogSet,
}

/// One star-tracker frame, physical.
#[derive(Debug, Clone, Copy)]
pub struct StarSample {
    /// Time tag (instant of the solution), µs.
    pub time_us: u64,
    /// Λ*, the tracker's frame in 2ECS.
    pub q: Quaternion<f64>,
    /// Valid flag.
    pub valid: bool,
}

/// Decoded telemetry.
#[derive(Debug, Clone, Default)]
pub struct Telemetry {
    /// Output frames, in time order.
    pub out: Vec<OutSample>,
    /// Star frames, in time order.
    pub star: Vec<StarSample>,
    /// Frames refused by the decoders (output, star).
    pub bad_frames: (u64, u64),
}

impl Telemetry {
    /// Decodes the two captures with the flight code's decoders; frames whose time tag does
    /// not increase are dropped.
    pub fn decode(out_bytes: &[u8], star_bytes: &[u8]) -> Self {
        let mut t = Telemetry::default();
        let mut od: StreamDecoder<OutputFrame, 256> = StreamDecoder::new();
        od.push_slice(out_bytes, |r| match r {
            Ok(f) => {
                if t.out.last().is_none_or(|l: &OutSample| f.time_us > l.time_us) {
                    let mut used = 0u8;
                    for (i, h) in f.fog_health.iter().enumerate() {
                        if h & ssis::flight::health::USED != 0 {
                            used |= 1 << i;
                        }
                    }
                    t.out.push(OutSample {
                        time_us: f.time_us,
                        rate_rad_s: Vector3::from(f.rate_rad_s()),
                        drift_rad_s: Vector3::from(f.drift_rad_s()),
                        flags: f.flags,
                        used: FogSet(used),
                    });
                }
            }
            Err(_) => t.bad_frames.0 += 1,
        });
        let mut sd: StreamDecoder<StarFrame, 256> = StreamDecoder::new();
        sd.push_slice(star_bytes, |r| match r {
            Ok(f) => {
                if t.star.last().is_none_or(|l: &StarSample| f.time_us > l.time_us) {
                    let [w, x, y, z] = f.quaternion();
                    t.star.push(StarSample {
                        time_us: f.time_us,
                        q: Quaternion::new(w, x, y, z).normalize(),
                        valid: f.valid(),
                    });
                }
            }
            Err(_) => t.bad_frames.1 += 1,
        });
        t
    }

    /// Reads two capture files.
    pub fn read(out_path: &std::path::Path, star_path: &std::path::Path) -> Result<Self> {
        let o = std::fs::read(out_path).map_err(|e| anyhow!("cannot read {}: {e}", out_path.display()))?;
        let s = std::fs::read(star_path).map_err(|e| anyhow!("cannot read {}: {e}", star_path.display()))?;
        let t = Self::decode(&o, &s);
        if t.out.len() < 2 {
            bail!("{}: fewer than two output frames decoded", out_path.display());
        }
        Ok(t)
    }

    /// Step length from the output time tags, s.
    pub fn dt_s(&self) -> f64 {
        let mut d: Vec<u64> = self.out.windows(2).take(1000).map(|w| w[1].time_us - w[0].time_us).collect();
        d.sort_unstable();
        d.get(d.len() / 2).copied().unwrap_or(5000) as f64 * 1e-6
    }
}

// ------------------------------------------------------------------ maneuvers

/// A maneuver found in the output rate: output frame indices [start, end).
#[derive(Debug, Clone, Copy)]
pub struct Maneuver {
    /// First output frame of the maneuver.
    pub start: usize,
    /// One past the last.
    pub end: usize,
}

/// Maneuvers: runs where |ω_out − ω_median| exceeds `threshold_rad_s`, joined across gaps
/// shorter than 1 s, at least 10 s long.
pub fn find_maneuvers(t: &Telemetry, threshold_rad_s: f64) -> Vec<Maneuver> {
    let med = |k: usize| {
        let mut v: Vec<f64> = t.out.iter().map(|o| o.rate_rad_s[k]).collect();
        v.sort_by(f64::total_cmp);
        v[v.len() / 2]
    };
    let base = Vector3::new(med(0), med(1), med(2));
    let dt = t.dt_s();
    let gap = (1.0 / dt) as usize;
    let mut out: Vec<Maneuver> = Vec::new();
    let mut k = 0;
    while k < t.out.len() {
        if (t.out[k].rate_rad_s - base).norm() > threshold_rad_s {
            let s = k;
            while k < t.out.len() && (t.out[k].rate_rad_s - base).norm() > threshold_rad_s {
                k += 1;
            }
            match out.last_mut() {
                Some(m) if s - m.end < gap => m.end = k,
                _ => out.push(Maneuver { start: s, end: k }),
            }
        } else {
            k += 1;
        }
    }
    out.retain(|m| (m.end - m.start) as f64 * dt >= 10.0);
    out
}

// ------------------------------------------------------------------ 1. bias

/// Result of the bias step.
#[derive(Debug, Clone)]
pub struct BiasResult {
    /// Mean drift estimate over the steady part, ICS, rad/s.
    pub drift_rad_s: Vector3<f64>,
    /// Its standard error from 60-s block means, rad/s.
    pub sigma_rad_s: Vector3<f64>,
    /// Steady part used, s (from, to).
    pub window_s: (f64, f64),
    /// Per-FOG bias corrections Δb_i = s_i · d, rad/s.
    pub fog_delta_rad_s: [f64; N_FOG],
}

/// Slowest time constant of the observer's per-axis loop for the gains of `table`, s. Per
/// star-tracker update (period T) the errors (a attitude, δ = Δω̂ − Δω) evolve by
/// M = [[1 − K_B, −(1 − K_B) T], [K_U, 1 − K_U T]]; τ = −T / ln |λ_max(M)|. With the paper's
/// figures (K_B = 0.0224, K_U = 1.24e-5 /s at 4 Hz) the loop is overdamped and
/// τ ≈ T K_B / (K_U T) ≈ 1800 s: the drift estimate needs hours to settle.
pub fn observer_time_constant_s(table: &CalibrationTable) -> Result<f64> {
    let cfg = &table.observer;
    let g = match cfg.gains_override {
        Some(g) => g,
        None => ssis::observer::steady_state_gains(cfg).map_err(|e| anyhow!("observer gains: {e:?}"))?,
    };
    let t = cfg.st_period_s;
    let mut tau: f64 = 0.0;
    for k in 0..3 {
        let (kb, ku) = (g.k_b[k], g.k_u_per_s[k]);
        let m = [[1.0 - kb, -(1.0 - kb) * t], [ku, 1.0 - ku * t]];
        let (tr, det) = (m[0][0] + m[1][1], m[0][0] * m[1][1] - m[0][1] * m[1][0]);
        let disc = tr * tr / 4.0 - det;
        let lmax = if disc >= 0.0 { (tr / 2.0).abs() + disc.sqrt() } else { det.sqrt() };
        if !(lmax < 1.0 && lmax > 0.0) {
            bail!("observer loop not stable for the table's gains (|λ| = {lmax})");
        }
        tau = tau.max(-t / lmax.ln());
    }
    Ok(tau)
}

/// Zero bias: the observer's drift estimate averaged over its steady part: from the
/// converged flag plus `settle_s` to the first maneuver, or to the end.
pub fn bias_from_observer(
    t: &Telemetry,
    maneuvers: &[Maneuver],
    settle_s: f64,
    table: &CalibrationTable,
) -> Result<BiasResult> {
    let conv = t
        .out
        .iter()
        .position(|o| o.flags & flags::CONVERGED != 0)
        .ok_or_else(|| anyhow!("the observer never reported convergence: no steady part to average"))?;
    let dt = t.dt_s();
    let from = conv + (settle_s / dt) as usize;
    let to = maneuvers.iter().map(|m| m.start).find(|s| *s > from).unwrap_or(t.out.len());
    if to <= from + (60.0 / dt) as usize {
        bail!(
            "steady part too short: converged at {:.0} s, +{settle_s} s settling, next maneuver at {:.0} s",
            t.out[conv].time_us as f64 * 1e-6,
            t.out[to.min(t.out.len() - 1)].time_us as f64 * 1e-6
        );
    }
    let block = (60.0 / dt) as usize;
    let means: Vec<Vector3<f64>> = t.out[from..to]
        .chunks(block)
        .filter(|c| c.len() == block)
        .map(|c| c.iter().map(|o| o.drift_rad_s).sum::<Vector3<f64>>() / c.len() as f64)
        .collect();
    let n = means.len() as f64;
    let mean = means.iter().sum::<Vector3<f64>>() / n;
    let var = means.iter().map(|m| (m - mean).component_mul(&(m - mean))).sum::<Vector3<f64>>() / (n - 1.0).max(1.0);
    let axes = table.axes();
    Ok(BiasResult {
        drift_rad_s: mean,
        sigma_rad_s: (var / n).map(f64::sqrt),
        window_s: (t.out[from].time_us as f64 * 1e-6, t.out[to - 1].time_us as f64 * 1e-6),
        fog_delta_rad_s: std::array::from_fn(|i| axes[i].dot(&mean)),
    })
}

// ------------------------------------------------------------------ 2. scale factors

/// One maneuver's angles.
#[derive(Debug, Clone, Copy)]
pub struct ManeuverAngles {
    /// The maneuver.
    pub maneuver: Maneuver,
    /// Θ_ST, ICS, rad (from the star tracker, through the table's mount).
    pub theta_st_rad: Vector3<f64>,
    /// Θ_FOG, ICS, rad (gyros, bias removed).
    pub theta_fog_rad: Vector3<f64>,
    /// Time span (from, to), s.
    pub span_s: (f64, f64),
    /// FOGs used throughout.
    pub used: FogSet,
}

impl ManeuverAngles {
    /// Unit axis of the maneuver.
    pub fn axis(&self) -> Vector3<f64> {
        self.theta_st_rad.normalize()
    }
    /// uᵀ D u = (Θ_FOG − Θ_ST)·u / |Θ_ST|: the relative scale-factor error about u.
    pub fn relative_error(&self) -> f64 {
        (self.theta_fog_rad - self.theta_st_rad).dot(&self.axis()) / self.theta_st_rad.norm()
    }
}

/// Λ_b = Λ* ∘ q_bs⁻¹ of a star frame.
fn body_q(s: &StarSample, mount: &Quaternion<f64>) -> Quaternion<f64> {
    s.q * mount.conjugate()
}

/// The gyro increment of output frame `o` (drift put back, `bias` removed), rad.
fn gyro_increment(o: &OutSample, dt_s: f64, bias: &Vector3<f64>) -> Vector3<f64> {
    (o.rate_rad_s + o.drift_rad_s - bias) * dt_s
}

/// Θ_ST and Θ_FOG over each maneuver, between the last valid star frame before it and the
/// first after it; consecutive star frames must be valid and at most `max_gap_s` apart.
pub fn maneuver_angles(
    t: &Telemetry,
    maneuvers: &[Maneuver],
    bias_rad_s: &Vector3<f64>,
    mount: &Quaternion<f64>,
    max_gap_s: f64,
) -> Result<Vec<ManeuverAngles>> {
    let dt = t.dt_s();
    let mut out = Vec::new();
    for m in maneuvers {
        let (t0, t1) = (t.out[m.start].time_us, t.out[m.end - 1].time_us);
        let Some(a) = t.star.iter().rposition(|s| s.valid && s.time_us < t0) else {
            bail!("maneuver at {:.0} s: no valid star frame before it", t0 as f64 * 1e-6)
        };
        let Some(b) = t.star.iter().position(|s| s.valid && s.time_us > t1) else {
            bail!("maneuver at {:.0} s: no valid star frame after it", t0 as f64 * 1e-6)
        };
        let mut theta_st = Vector3::zeros();
        for w in t.star[a..=b].windows(2) {
            if !w[1].valid || (w[1].time_us - w[0].time_us) as f64 * 1e-6 > max_gap_s {
                bail!(
                    "maneuver at {:.0} s: star-tracker gap or invalid frame at {:.1} s (the method needs the reference throughout)",
                    t0 as f64 * 1e-6,
                    w[1].time_us as f64 * 1e-6
                );
            }
            theta_st += rotvec_from_quat(&(body_q(&w[0], mount).conjugate() * body_q(&w[1], mount)));
        }
        let (ta, tb) = (t.star[a].time_us, t.star[b].time_us);
        let mut theta_fog = Vector3::zeros();
        let mut used = FogSet(0xFF);
        for o in t.out.iter().filter(|o| o.time_us > ta && o.time_us <= tb) {
            theta_fog += gyro_increment(o, dt, bias_rad_s);
            used = FogSet(used.0 & o.used.0);
        }
        out.push(ManeuverAngles {
            maneuver: *m,
            theta_st_rad: theta_st,
            theta_fog_rad: theta_fog,
            span_s: (ta as f64 * 1e-6, tb as f64 * 1e-6),
            used,
        });
    }
    Ok(out)
}

/// D = H⁺ diag(Δk) H for the FOG set `set` of `table`.
pub fn scale_matrix(table: &CalibrationTable, set: FogSet, dk: &[f64; N_FOG]) -> Result<Matrix3<f64>> {
    let axes = table.axes();
    let comb = Combiner::new(&axes);
    let hp = comb.solution(set).map_err(|e| anyhow!("FOG set {:#06b}: {e:?}", set.0))?;
    let mut d = Matrix3::zeros();
    for i in 0..N_FOG {
        if set.contains(i) {
            d += hp.column(i) * axes[i].transpose() * dk[i];
        }
    }
    Ok(d)
}

/// Result of the scale-factor step.
#[derive(Debug, Clone)]
pub struct ScaleResult {
    /// Per maneuver: axis and uᵀ D u.
    pub maneuvers: Vec<ManeuverAngles>,
    /// Δk per FOG (FOGs not used: 0).
    pub dk: [f64; N_FOG],
    /// Residual of each maneuver's equation.
    pub residual: Vec<f64>,
}

/// Δk_i from the maneuvers: Σ_i Δk_i (H⁺ᵀ u)_i (s_i · u) = uᵀ D u per maneuver.
pub fn scale_from_maneuvers(angles: Vec<ManeuverAngles>, table: &CalibrationTable) -> Result<ScaleResult> {
    let Some(first) = angles.first() else { bail!("no maneuver: the scale factors need 360° turns") };
    let set = first.used;
    if angles.iter().any(|a| a.used != set) {
        bail!("the FOGs combined changed between maneuvers; the method needs one FOG set");
    }
    let fogs: Vec<usize> = (0..N_FOG).filter(|i| set.contains(*i)).collect();
    if angles.len() < fogs.len() {
        bail!(
            "{} maneuvers for {} FOG scale factors: one 360° turn per FOG is needed (X, Y, Z and the FOG4 axis)",
            angles.len(),
            fogs.len()
        );
    }
    let axes = table.axes();
    let hp = *Combiner::new(&axes).solution(set).map_err(|e| anyhow!("{e:?}"))?;
    let mut a = DMatrix::zeros(angles.len(), fogs.len());
    let mut b = DVector::zeros(angles.len());
    for (r, m) in angles.iter().enumerate() {
        let u = m.axis();
        let w = hp.transpose() * u;
        for (c, &i) in fogs.iter().enumerate() {
            a[(r, c)] = w[i] * axes[i].dot(&u);
        }
        b[r] = m.relative_error();
    }
    if a.clone().svd(false, false).singular_values.min() < 1e-3 {
        bail!("the maneuver axes do not separate the FOG scale factors (turn about X, Y, Z and the FOG4 axis)");
    }
    let (x, _) = super::lstsq(&a, &b)?;
    let res = &a * &x - &b;
    let mut dk = [0.0; N_FOG];
    for (c, &i) in fogs.iter().enumerate() {
        dk[i] = x[c];
    }
    Ok(ScaleResult { maneuvers: angles, dk, residual: res.iter().copied().collect() })
}

// ------------------------------------------------------------------ 3. mount

/// Result of the misalignment step.
#[derive(Debug, Clone)]
pub struct MountResult {
    /// η̂, the mount error in the ICS (Λ_b = Λ_ICS ∘ η), rad.
    pub eta_rad: Vector3<f64>,
    /// The RLS estimate after each update that carried rotation, (t s, η rad).
    pub history: Vec<(f64, Vector3<f64>)>,
    /// Star-frame pairs used.
    pub samples: usize,
}

/// RLS on ω_ST Δt − ω_FOG Δt = [ω_FOG Δt ×] η over consecutive valid star frames (at most
/// `max_gap_s` apart), gyro increments corrected by `bias_rad_s` and the scale matrix `d`
/// ((I + D)⁻¹). Pairs with a rotation below `min_angle_rad` carry no information and are
/// skipped (their noise would only enter through the sum).
pub fn mount_rls(
    t: &Telemetry,
    bias_rad_s: &Vector3<f64>,
    d: &Matrix3<f64>,
    mount: &Quaternion<f64>,
    max_gap_s: f64,
    min_angle_rad: f64,
) -> Result<MountResult> {
    let dt = t.dt_s();
    let corr = (Matrix3::identity() + d).try_inverse().ok_or_else(|| anyhow!("scale matrix singular"))?;
    let mut eta = Vector3::zeros();
    let mut p = Matrix3::identity() * 1.0; // rad², a prior far wider than any mount error
    let mut history = Vec::new();
    let mut samples = 0;
    let mut k = 0; // output frame cursor
    for w in t.star.windows(2) {
        let (s0, s1) = (&w[0], &w[1]);
        while k < t.out.len() && t.out[k].time_us <= s0.time_us {
            k += 1;
        }
        if !(s0.valid && s1.valid) || (s1.time_us - s0.time_us) as f64 * 1e-6 > max_gap_s {
            continue;
        }
        let mut g = Vector3::zeros();
        let mut j = k;
        while j < t.out.len() && t.out[j].time_us <= s1.time_us {
            g += gyro_increment(&t.out[j], dt, bias_rad_s);
            j += 1;
        }
        let g = corr * g;
        if g.norm() < min_angle_rad {
            continue;
        }
        let y = rotvec_from_quat(&(body_q(s0, mount).conjugate() * body_q(s1, mount))) - g;
        let h = g.cross_matrix();
        // RLS with equal weights (λ = 1): K = P Hᵀ (H P Hᵀ + I r)⁻¹, r the noise of one pair
        // relative to the prior (only the ratio matters).
        let s = h * p * h.transpose() + Matrix3::identity() * 1e-9;
        let Some(si) = s.try_inverse() else { continue };
        let kg = p * h.transpose() * si;
        eta += kg * (y - h * eta);
        p = (Matrix3::identity() - kg * h) * p;
        p = (p + p.transpose()) * 0.5;
        samples += 1;
        history.push((s1.time_us as f64 * 1e-6, eta));
    }
    if samples == 0 {
        bail!("no star-frame pair with rotation: the misalignment needs maneuvers");
    }
    let eig = p.symmetric_eigenvalues();
    if eig.max() > 1e-3 {
        bail!("the maneuvers turned about one axis only: the mount error about it is not observable");
    }
    Ok(MountResult { eta_rad: eta, history, samples })
}

/// The new mount q_bs ← exp(η̂) ∘ q_bs, scalar first.
pub fn corrected_mount(table: &CalibrationTable, eta_rad: &Vector3<f64>) -> [f64; 4] {
    let q = (quat_from_rotvec(eta_rad) * table.st_mount()).normalize();
    [q.w, q.i, q.j, q.k]
}

// ------------------------------------------------------------------ all three

/// Settings of [`calibrate`].
#[derive(Debug, Clone, Copy)]
pub struct Settings {
    /// Maneuver threshold on |ω_out − median|, rad/s.
    pub maneuver_threshold_rad_s: f64,
    /// Settling after the converged flag before the bias average starts, s (None: five
    /// of the observer's slowest time constants, [`observer_time_constant_s`]).
    pub settle_s: Option<f64>,
    /// Longest gap between star frames inside a maneuver, s.
    pub max_star_gap_s: f64,
}

impl Default for Settings {
    fn default() -> Self {
        Settings { maneuver_threshold_rad_s: 1e-3, settle_s: None, max_star_gap_s: 1.0 }
    }
}

/// Everything the orbital calibration found.
#[derive(Debug, Clone)]
pub struct OrbitalResult {
    /// Maneuvers found.
    pub maneuvers: Vec<Maneuver>,
    /// Step 1.
    pub bias: BiasResult,
    /// Step 2 (None when there are no maneuvers).
    pub scale: Option<ScaleResult>,
    /// Step 3 (None when there are no maneuvers).
    pub mount: Option<MountResult>,
    /// Per maneuver, what the scale factors and the mount leave unexplained between the
    /// gyros' and the tracker's rotation, per radian turned, rad ([`unexplained_coupling`]).
    pub unexplained_rad_per_rad: Vec<f64>,
    /// The table with the three results applied.
    pub table: CalibrationTable,
}

impl OrbitalResult {
    /// The time of the first maneuver, s, when the observer settles (convergence + 5τ) only
    /// after it: the bias average then has no steady part before the maneuvers, and
    /// `ssis-cal orbital` refuses.
    pub fn settles_after_first_maneuver(&self, t: &Telemetry) -> Option<f64> {
        let m = self.maneuvers.first()?;
        let t_m = t.out.get(m.start)?.time_us as f64 * 1e-6;
        (self.bias.window_s.0 > t_m).then_some(t_m)
    }

    /// The table fields the result sets: the four FOG biases, and the scale factors and the
    /// star-tracker mount when there were maneuvers to estimate them.
    pub fn fields_set(&self) -> Vec<ssis::calib::Field> {
        use ssis::calib::{Field, FogTerm};
        let mut set: Vec<Field> = (0..N_FOG as u8).map(|i| Field::Fog(i, FogTerm::Bias)).collect();
        if self.scale.is_some() {
            set.extend((0..N_FOG as u8).map(|i| Field::Fog(i, FogTerm::ScaleFactor)));
        }
        if self.mount.is_some() {
            set.extend((0..4u8).map(Field::StMountQ));
        }
        set
    }
}

/// Largest disagreement per radian turned that the fitted scale factors and mount may leave
/// ([`unexplained_coupling`]): 30″ (1.5e-4), the paper's accuracy of its first ground method
/// for the FOG axes. The mount absorbs the skew part of a misalignment the table lacks; the
/// symmetric part stays here and leaks into the scale factors at about the same size (rad
/// per rad ≈ relative Δk error). Measured on `ssis-cal simulate orbital` (example unit,
/// misalignment up to 200″): flown with a nominal table 38–90″ per radian and Δk off by up to
/// 0.044 % (the paper's goal 0.002 %); with the first method's angles 2.0–4.3″ and Δk within
/// 0.0018 %. The noise floor (20″ 3σ tracker, ARW 0.005 °/√h, 500-s maneuvers) is about 2″.
pub const MAX_UNEXPLAINED_RAD_PER_RAD: f64 = 30.0 / ARCSEC_PER_RAD;

/// Per maneuver, |Θ_ST − Θ_c − Θ_c × η| / |Θ_ST|, with Θ_c = (I + D)⁻¹ Θ_FOG the gyros'
/// rotation corrected by the fitted scale factors and η the fitted mount error (the model
/// of [`mount_rls`]): the coupling between gyro and tracker rotation that neither explains,
/// rad per rad. Non-zero by the tracker and gyro noise (a few ″ per radian) and by what the
/// table flown misses of the FOG axes' misalignment.
pub fn unexplained_coupling(angles: &[ManeuverAngles], d: &Matrix3<f64>, eta_rad: &Vector3<f64>) -> Result<Vec<f64>> {
    let corr = (Matrix3::identity() + d).try_inverse().ok_or_else(|| anyhow!("scale matrix singular"))?;
    Ok(angles
        .iter()
        .map(|a| {
            let c = corr * a.theta_fog_rad;
            (a.theta_st_rad - c - c.cross(eta_rad)).norm() / a.theta_st_rad.norm()
        })
        .collect())
}

/// Runs the three steps on `t` recorded by a unit flying `table`; returns the new table
/// (revision not changed: the caller raises it when it writes the table).
pub fn calibrate(t: &Telemetry, table: &CalibrationTable, s: &Settings) -> Result<OrbitalResult> {
    let maneuvers = find_maneuvers(t, s.maneuver_threshold_rad_s);
    let settle_s = match s.settle_s {
        Some(v) => v,
        None => 5.0 * observer_time_constant_s(table)?,
    };
    let bias = bias_from_observer(t, &maneuvers, settle_s, table)?;
    let mut new = *table;
    for (f, db) in new.fog.iter_mut().zip(bias.fog_delta_rad_s) {
        f.bias_rad_s += db * (1.0 + f.scale_factor_error);
    }
    let (mut scale, mut mount, mut unexplained) = (None, None, Vec::new());
    if !maneuvers.is_empty() {
        let mount_q = table.st_mount();
        let angles = maneuver_angles(t, &maneuvers, &bias.drift_rad_s, &mount_q, s.max_star_gap_s)?;
        let set = angles[0].used;
        let sc = scale_from_maneuvers(angles, table)?;
        let d = scale_matrix(table, set, &sc.dk)?;
        for (f, dk) in new.fog.iter_mut().zip(sc.dk) {
            f.scale_factor_error = (1.0 + f.scale_factor_error) * (1.0 + dk) - 1.0;
        }
        let m = mount_rls(t, &bias.drift_rad_s, &d, &mount_q, s.max_star_gap_s, 1e-3)?;
        new.st_mount_q = corrected_mount(table, &m.eta_rad);
        unexplained = unexplained_coupling(&sc.maneuvers, &d, &m.eta_rad)?;
        let worst = unexplained.iter().copied().fold(0.0, f64::max);
        if worst > MAX_UNEXPLAINED_RAD_PER_RAD {
            bail!(
                "the gyros and the star tracker disagree about the maneuvers by up to {:.0}″ per radian turned \
                 after the scale factors and the mount are fitted (at most {:.0}″; 2-5″ when the table flown carries \
                 the unit's misalignment from the ground calibration, docs/TUTORIAL-CALIBRATION.md sections 4-5): the \
                 table flown does not describe this unit's FOG axes (ground misalignment calibration missing, \
                 or the wrong table given); no field is written",
                worst * ARCSEC_PER_RAD,
                MAX_UNEXPLAINED_RAD_PER_RAD * ARCSEC_PER_RAD
            );
        }
        scale = Some(sc);
        mount = Some(m);
    }
    new.validate().map_err(|e| anyhow!("the calibrated table is refused: {e}"))?;
    Ok(OrbitalResult { maneuvers, bias, scale, mount, unexplained_rad_per_rad: unexplained, table: new })
}

// ------------------------------------------------------------------ simulated flight

/// Captured bytes of a flight.
pub struct Capture {
    /// Output link.
    pub out: Vec<u8>,
    /// Star-tracker link (what the unit received).
    pub star: Vec<u8>,
    /// The table the unit flew with.
    pub table: CalibrationTable,
}

/// Flies `sc` through the flight core (ideal links) and captures both links.
pub fn fly(sc: &Scenario) -> Result<Capture> {
    let mut sim = Simulation::new(sc)?;
    let profile = sim.profile;
    let mut core = FlightCore::new(profile, &sim.table, false).map_err(|e| anyhow!("core: {e:?}"))?;
    if sim.needs_pad_alignment() {
        core.align(sim.initial_q());
    }
    let mut fog_links = [0, 1, 2, 3].map(|_| MockLink::ideal());
    let mut star_link = MockLink::ideal();
    let mut out_link = MockSink::default();
    let mut cap =
        Capture { out: Vec::with_capacity(sim.steps as usize * OutputFrame::LEN), star: Vec::new(), table: sim.table };
    while let Some(input) = sim.next_step() {
        for l in fog_links.iter_mut() {
            l.tick();
        }
        star_link.tick();
        for (i, (link, f)) in fog_links.iter_mut().zip(input.fog_frames.iter()).enumerate() {
            if profile.fogs.contains(i) {
                link.send(f);
            }
        }
        star_link.send(&input.st_bytes);
        cap.star.extend_from_slice(&input.st_bytes);
        let mut links = Links { fog: FogLinks::PerFog(fog_links.each_mut()), star: &mut star_link, out: &mut out_link };
        core.step(&mut links);
        cap.out.append(&mut out_link.bytes);
    }
    Ok(cap)
}

/// The unit of the orbital examples: the paper's "before" errors (biases about 1 °/h,
/// scale factors about 0.1 %), the first-method example misalignment, a star tracker
/// mounted 40″, −30″, 25″ off what the table says. Deterministic (no random draws), so a
/// short check flight with the same errors is the same unit.
pub fn example_unit(misalignment: Misalignment) -> (FogSpec, StarSpec) {
    let dh = 1.0 / DEG_H_PER_RAD_S;
    let fog = |b_deg_h: f64, k: f64| FogCal { bias_rad_s: b_deg_h * dh, scale_factor_error: k, ..FogCal::IDEAL };
    let spec = FogSpec {
        arw_deg_sqrt_h: 0.005,
        rrw_deg_h_sqrt_h: 0.01,
        errors: Some(TrueErrors {
            fog: [fog(0.8, 1.0e-3), fog(-0.6, -0.8e-3), fog(0.5, 0.6e-3), fog(-0.9, -1.2e-3)],
            misalignment,
        }),
        ..Default::default()
    };
    let star = StarSpec {
        rate_hz: 4.0,
        sigma_3sigma_arcsec: 20.0,
        misalignment_arcsec: [40.0, -30.0, 25.0],
        ..Default::default()
    };
    (spec, star)
}

/// The calibration flight: inertial hold for `hold_s`, then 360° maneuvers of `turn_s`
/// each (versine rate, peak 2·360°/turn_s) about X, Y, Z and the FOG4 axis, `gap_s` apart.
pub fn calibration_flight(fog: FogSpec, star: StarSpec, hold_s: f64, turn_s: f64, gap_s: f64) -> Scenario {
    let axes = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 1.0, 1.0]];
    let slews = axes
        .iter()
        .enumerate()
        .map(|(k, a)| Slew {
            start_s: hold_s + k as f64 * (turn_s + gap_s),
            duration_s: turn_s,
            axis: *a,
            angle_deg: 360.0,
        })
        .collect();
    Scenario {
        name: "orbital-calibration".into(),
        description: "Orbital calibration: inertial hold, then 360° maneuvers about X, Y, Z and the FOG4 axis".into(),
        profile: ProfileName::Spacecraft,
        duration_s: hold_s + 4.0 * (turn_s + gap_s),
        seed: 6,
        settle_s: 0.0,
        motion: MotionSpec { slews, ..Default::default() },
        fog,
        star_tracker: star,
        table: TableSpec { source: TableSource::Nominal, file: None, observer: None, estimator: None },
        links: Default::default(),
        base_dir: Default::default(),
    }
}

/// Truth of the orbital quantities for a unit with FOG errors `truth` flying `table`:
/// body drift d (what the observer should see), Δk per FOG, η (rad).
pub fn truth_of(
    truth: &CalibrationTable,
    table: &CalibrationTable,
    star: &StarSpec,
) -> (Vector3<f64>, [f64; N_FOG], Vector3<f64>) {
    let comb = Combiner::new(&table.axes());
    let b = Vector4::from_fn(|i, _| {
        truth.fog[i].bias_rad_s / (1.0 + table.fog[i].scale_factor_error) - table.fog[i].bias_rad_s
    });
    let d = comb.combine(&b, FogSet::ALL).unwrap_or_else(|_| Vector3::zeros());
    let dk = std::array::from_fn(|i| {
        (1.0 + truth.fog[i].scale_factor_error) / (1.0 + table.fog[i].scale_factor_error) - 1.0
    });
    // Star model: true mount = table mount ∘ exp(mis); Λ_b = Λ ∘ η with η = q_true q_bs⁻¹.
    let m = table.st_mount();
    let q_true = m * quat_from_rotvec(&(Vector3::from(star.misalignment_arcsec) / ARCSEC_PER_RAD));
    let eta = rotvec_from_quat(&(q_true * m.conjugate()));
    (d, dk, eta)
}
