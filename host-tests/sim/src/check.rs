//! The ground consistency check of a recorded log (`ssis-sim replay --check`): is each
//! FOG mounted and wired as the calibration table says? Needs no truth.
//!
//! - **Star tracker**: over windows of [`WINDOW_S`] between two star-tracker solutions,
//!   the body rotation Δ = rotvec((Λ*_a ∘ q_bs⁻¹)⁻¹ ∘ (Λ*_b ∘ q_bs⁻¹)) and each FOG's summed
//!   increments M_i over the same span (interpolated within a sample at the tags). Least
//!   squares M_i ≈ a_i · Δ gives FOG i's apparent sensitive axis a_i (its scale in its
//!   length). No bias term: under nadir pointing the body turns at a constant rate, which
//!   a bias term would absorb; a bias of 1 °/h is 2″ over a window, against the hundreds
//!   of arcseconds the body turns. The channel assignment is the permutation π of the table's axes s_j
//!   with the largest Σ |cos(a_i, s_π(i))|; polarity the sign of a_i · s_π(i); scale its
//!   magnitude.
//! - **Parity**: the parity residual v · m per sample (v the null vector of the table's
//!   axes), as the log is and with each single polarity flip or channel swap undone: a
//!   wrong sign or a swap that involves the skewed FOG leaves a residual that follows the
//!   motion; undoing the right hypothesis brings it to the noise. (Swaps among three FOGs
//!   of equal parity weight, the orthogonal triad's, leave it unchanged: there the star
//!   tracker decides.)

use anyhow::{bail, Result};
use nalgebra::{Matrix4, Quaternion, SMatrix, Vector3, Vector4};
use ssis::calib::{CalibrationTable, N_FOG};
use ssis::combination::Combiner;
use ssis::math::rotvec_from_quat;

use crate::recorded::Recorded;
use ssis_common::ARCSEC_PER_RAD;

/// Span of one star-tracker window, s.
pub const WINDOW_S: f64 = 2.0;
/// A scale further than this from 1 is reported (and at least 5 standard errors).
pub const SCALE_TOL: f64 = 0.01;
/// An apparent axis further than this from the table's is reported, arcsec.
pub const AXIS_TOL_ARCSEC: f64 = 600.0;

/// What the check found for one FOG slot (channel).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FogFinding {
    /// The channel (slot i: FOG i+1 of the table).
    pub channel: usize,
    /// The table's FOG whose axis this channel carries (best permutation).
    pub carries: usize,
    /// +1 or −1.
    pub polarity: f64,
    /// |a_i · s_π(i)|.
    pub scale: f64,
    /// Standard error of the scale.
    pub scale_se: f64,
    /// Angle between a_i and ±s_π(i), arcsec.
    pub axis_off_arcsec: f64,
}

/// The check's result.
#[derive(Debug, Clone, PartialEq)]
pub struct CheckReport {
    /// Per channel (only the FOGs in the log).
    pub fogs: Vec<FogFinding>,
    /// Windows used.
    pub windows: usize,
    /// Smallest singular value of the windows' rotations, ″ (motion about every axis).
    pub excitation_arcsec: f64,
    /// Parity residual RMS per sample as logged, rad.
    pub parity_rms_rad: f64,
    /// The single flip or swap whose undoing lowers the parity residual most, and the
    /// RMS then (none when nothing lowers it by half).
    pub parity_best: Option<(String, f64)>,
    /// The findings in words (empty: clean).
    pub findings: Vec<String>,
}

impl FogFinding {
    /// What is wrong with the FOG in words (nothing: none), added to `out`.
    fn findings(&self, out: &mut Vec<String>) {
        let (i, j, polarity, scale, scale_se) = (self.channel, self.carries, self.polarity, self.scale, self.scale_se);
        if j != i {
            out.push(format!(
                "FOG{} (channel {i}, columns fog{i}_*) carries FOG{}'s axis: wired to the wrong channel",
                i + 1,
                j + 1
            ));
        }
        if polarity < 0.0 {
            out.push(format!(
                "FOG{} (channel {i}) reads with reversed polarity (×{:.4}): mounted backwards or its sign flipped",
                i + 1,
                -scale
            ));
        }
        if (scale - 1.0).abs() > SCALE_TOL.max(5.0 * scale_se) {
            out.push(format!("FOG{} (channel {i}): scale {:.4} ± {:.4} relative to the table", i + 1, scale, scale_se));
        }
        if self.axis_off_arcsec > AXIS_TOL_ARCSEC {
            out.push(format!(
                "FOG{} (channel {i}): apparent axis {:.0}″ from the table's FOG{}",
                i + 1,
                self.axis_off_arcsec,
                j + 1
            ));
        }
    }
}

/// Runs the check on `rec` against `table`'s axes.
pub fn check(rec: &Recorded, table: &CalibrationTable, dt_us: u32) -> Result<CheckReport> {
    let axes = table.axes();
    let dt_s = f64::from(dt_us) * 1e-6;
    // Cumulative FOG sums at each step's end, over steps with every FOG of the log.
    let present = |s: &crate::recorded::LogStep| (0..N_FOG).all(|i| !rec.fogs.contains(i) || s.fog[i].is_some());
    let mut cum = Vec::with_capacity(rec.steps.len() + 1);
    let mut complete = Vec::with_capacity(rec.steps.len() + 1);
    let mut c = Vector4::zeros();
    cum.push(c);
    complete.push(true);
    for s in &rec.steps {
        for (i, f) in s.fog.iter().enumerate() {
            c[i] += f.map_or(0.0, |f| f.dtheta_rad);
        }
        cum.push(c);
        complete.push(present(s));
    }
    let at = |t_us: u64| -> Option<Vector4<f64>> {
        let x = t_us as f64 * 1e-6 / dt_s;
        let k = x.floor() as usize;
        let (a, b) = (cum.get(k)?, cum.get(k + 1)?);
        complete.get(k + 1).copied().filter(|&ok| ok)?;
        Some(a + (b - a) * (x - k as f64))
    };
    let mount_inv = table.st_mount().conjugate();
    let st: Vec<(u64, Quaternion<f64>)> = rec
        .steps
        .iter()
        .flat_map(|s| s.st.iter())
        .filter(|s| s.valid)
        .map(|s| (s.time_us, Quaternion::new(s.q[0], s.q[1], s.q[2], s.q[3]) * mount_inv))
        .collect();
    if st.len() < 10 {
        bail!("{}: the check needs star-tracker solutions: {} valid in the log", rec.origin, st.len());
    }
    // Normal equations of Δ → M_i for every FOG at once.
    let mut ata = SMatrix::<f64, 3, 3>::zeros();
    let mut atm = SMatrix::<f64, 3, 4>::zeros();
    let mut rows = Vec::new();
    let mut b = 0usize;
    for a in 0..st.len() {
        let (ta, qa) = st[a];
        while b < st.len() && (st[b].0 as f64 - ta as f64) * 1e-6 < WINDOW_S {
            b += 1;
        }
        let Some(&(tb, qb)) = st.get(b) else { break };
        let (Some(ca), Some(cb)) = (at(ta), at(tb)) else { continue };
        if (tb - ta) as f64 * 1e-6 > 1.5 * WINDOW_S {
            continue;
        }
        let d = rotvec_from_quat(&(qa.conjugate() * qb));
        let x = d;
        let m = cb - ca;
        ata += x * x.transpose();
        atm += x * m.transpose();
        rows.push((x, m));
    }
    if rows.len() < 20 {
        bail!("{}: too few star-tracker windows of {WINDOW_S} s with every FOG sample ({})", rec.origin, rows.len());
    }
    let Some(inv) = ata.try_inverse() else {
        bail!("{}: the log's motion does not turn the unit about every axis: no check possible", rec.origin)
    };
    let sol = inv * atm; // column i: a_i
    let excitation_arcsec = ata.symmetric_eigenvalues().min().max(0.0).sqrt() * ARCSEC_PER_RAD;
    let resid_var: Vector4<f64> = rows.iter().fold(Vector4::zeros(), |acc, (x, m)| {
        let r = m - sol.transpose() * x;
        acc + r.component_mul(&r)
    }) / (rows.len() as f64 - 3.0);
    let fogs_in: Vec<usize> = (0..N_FOG).filter(|&i| rec.fogs.contains(i)).collect();
    let apparent: Vec<Vector3<f64>> = (0..N_FOG).map(|i| Vector3::new(sol[(0, i)], sol[(1, i)], sol[(2, i)])).collect();
    let perm = best_permutation(&apparent, &axes, &fogs_in);
    let mut fogs = Vec::new();
    let mut findings = Vec::new();
    for &i in &fogs_in {
        let j = perm[i];
        let a = apparent[i];
        let dot = a.dot(&axes[j]);
        let polarity = dot.signum();
        let scale = dot.abs();
        let cos = (dot.abs() / (a.norm() * axes[j].norm()).max(1e-300)).min(1.0);
        // Standard error of the slope along s_j: sqrt(σ² sⱼᵀ (AᵀA)⁻¹ sⱼ). Overlapping
        // windows share samples: counted as independent, this understates it.
        let scale_se = (resid_var[i] * (axes[j].transpose() * inv * axes[j])[(0, 0)]).max(0.0).sqrt();
        let f = FogFinding {
            channel: i,
            carries: j,
            polarity,
            scale,
            scale_se,
            axis_off_arcsec: cos.acos() * ARCSEC_PER_RAD,
        };
        f.findings(&mut findings);
        fogs.push(f);
    }
    let (parity_rms_rad, parity_best) = parity_hypotheses(rec, &axes);
    Ok(CheckReport { fogs, windows: rows.len(), excitation_arcsec, parity_rms_rad, parity_best, findings })
}

/// The permutation of the table's axes over the log's channels with the largest
/// Σ |cos(a_i, s_π(i))|.
fn best_permutation(a: &[Vector3<f64>], axes: &[Vector3<f64>; N_FOG], fogs: &[usize]) -> [usize; N_FOG] {
    let mut best = ([0, 1, 2, 3], f64::NEG_INFINITY);
    let mut p = [0usize, 1, 2, 3];
    permute(&mut p, 0, &mut |p| {
        let score: f64 = fogs.iter().map(|&i| (a[i].dot(&axes[p[i]]) / a[i].norm().max(1e-300)).abs()).sum();
        // Prefer the identity on a tie (a clean log stays clean).
        if score > best.1 + 1e-9 {
            best = (*p, score);
        }
    });
    best.0
}

fn permute(p: &mut [usize; N_FOG], k: usize, f: &mut impl FnMut(&[usize; N_FOG])) {
    if k == N_FOG {
        f(p);
        return;
    }
    for i in k..N_FOG {
        p.swap(k, i);
        permute(p, k + 1, f);
        p.swap(k, i);
    }
}

/// Parity residual RMS of the log as it is, and the single flip or swap whose undoing
/// lowers it most (if by more than half).
fn parity_hypotheses(rec: &Recorded, axes: &[Vector3<f64>; N_FOG]) -> (f64, Option<(String, f64)>) {
    if !(0..N_FOG).all(|i| rec.fogs.contains(i)) {
        return (0.0, None);
    }
    let comb = Combiner::new(axes);
    let v = Vector4::from_fn(|i, _| comb.parity(&Vector4::from_fn(|k, _| f64::from(u8::from(k == i)))));
    let mut hyps: Vec<(String, Matrix4<f64>)> = vec![("as logged".into(), Matrix4::identity())];
    for i in 0..N_FOG {
        let mut m = Matrix4::identity();
        m[(i, i)] = -1.0;
        hyps.push((format!("FOG{} reversed", i + 1), m));
        for j in i + 1..N_FOG {
            let mut m = Matrix4::identity();
            m.swap_rows(i, j);
            hyps.push((format!("FOG{} and FOG{} swapped", i + 1, j + 1), m));
        }
    }
    let mut sums = vec![0.0; hyps.len()];
    let mut n = 0u64;
    for s in &rec.steps {
        let [Some(a), Some(b), Some(c), Some(d)] = s.fog else { continue };
        let m = Vector4::new(a.dtheta_rad, b.dtheta_rad, c.dtheta_rad, d.dtheta_rad);
        for (k, (_, h)) in hyps.iter().enumerate() {
            sums[k] += (v.transpose() * (h * m))[(0, 0)].powi(2);
        }
        n += 1;
    }
    let rms: Vec<f64> = sums.iter().map(|s| (s / n.max(1) as f64).sqrt()).collect();
    let best = (1..hyps.len()).min_by(|&a, &b| rms[a].total_cmp(&rms[b]));
    let best = best.filter(|&k| rms[k] < 0.5 * rms[0]).map(|k| (hyps[k].0.clone(), rms[k]));
    (rms[0], best)
}

impl CheckReport {
    /// The report a person reads.
    pub fn report(&self) -> String {
        let mut s = format!(
            "consistency check: {} star-tracker windows of {WINDOW_S} s (weakest motion {:.0}″ over them)\n",
            self.windows, self.excitation_arcsec
        );
        s.push_str("channel  carries  polarity    scale (± 1σ)   axis off, ″\n");
        for f in &self.fogs {
            s.push_str(&format!(
                "FOG{}     FOG{}     {:>+3.0}      {:.5} ± {:.5}  {:>8.0}\n",
                f.channel + 1,
                f.carries + 1,
                f.polarity,
                f.scale,
                f.scale_se,
                f.axis_off_arcsec
            ));
        }
        s.push_str(&format!("parity residual RMS as logged {:.3e} rad per sample", self.parity_rms_rad));
        match &self.parity_best {
            Some((h, r)) => s.push_str(&format!("; undoing \"{h}\" brings it to {r:.3e} rad\n")),
            None => s.push_str("; no single flip or swap lowers it\n"),
        }
        if self.findings.is_empty() {
            s.push_str("clean: every FOG's polarity, channel and scale agree with the table\n");
        } else {
            for f in &self.findings {
                s.push_str(&format!("FOUND: {f}\n"));
            }
        }
        s
    }
}
