//! Polarity and channel check of a session's FOG columns against its reference rotation,
//! before any method fits angles to them.
//!
//! A FOG mounted backwards or two FOG cables swapped on the bench does not stop the
//! misalignment methods: the first method leaves out the rows of a FOG turned about its
//! own axis (the only rows where a reversal shows), and every other row sees only a small
//! angle, so a reversed FOG yields its misalignment angles with the wrong sign and a table
//! that looks plausible. This check looks at the evidence the methods leave out.
//!
//! The sensitive axis each column actually follows is measured by least squares: y_j =
//! b_j + g_j · ω_ref + e_j, with ω_ref the reference rate (ICS), y_j the column's rate, e_j
//! noise and bias wander. As wired, g_j is FOG j's nominal axis s_j to within its
//! misalignment (±3,600″ at most in the table, 0.017 per component) and scale-factor error
//! (±0.1 % before calibration in the paper). Only the directions the reference moves in are
//! measured (the eigenvectors of ω_ref's covariance whose slope standard error, with the
//! residual's lag-1 autocorrelation ρ₁ inflating it by (1 + ρ₁)/(1 − ρ₁), is at most
//! [`MAX_SLOPE_SE`]); with P the projector on them, and ‖P s_j‖ ≥ ½:
//!
//! - ‖P (g_j − s_j)‖ ≤ [`AXIS_TOLERANCE`]: as wired;
//! - ‖P (g_j + s_j)‖ ≤ [`AXIS_TOLERANCE`]: reversed (the column's sign is the opposite of
//!   the FOG's sensitive axis);
//! - ‖P (g_j ∓ s_m)‖ ≤ [`AXIS_TOLERANCE`] for another FOG m: the column carries FOG m
//!   (channels swapped); none of these: a dead FOG or a wrong column;
//! - ‖P s_j‖ < ½: not judged, and said so. A static session at one position cannot show a
//!   reversal; a turntable session does, and azimuth positions do for horizontal axes.
//!
//! A FOG along a direction the reference does not move in (the vertical FOG of a level
//! turntable session) can still show a reversal in its mean: its offset from the reference,
//! mean(y_j) − s_j · mean(ω_ref), is its bias (±1 °/h systematic before calibration in the
//! paper); one beyond [`MAX_BIAS_RAD_S`] (5 °/h) that the reversed reference explains to within
//! the same bound is a reversal "by the mean". Nothing else is judged there.
//!
//! When every judged FOG reads reversed, the session's turn direction is the likelier
//! culprit (`table_rate_rad_s` positive counter-clockwise seen from above, ψ decreasing:
//! docs/SESSION-FORMAT.md), and the message says so.

use std::fmt::Write as _;

use anyhow::{bail, Result};
use nalgebra::{Matrix3, Vector3};
use ssis_session::{nominal_axes, Session};

/// Largest distance ‖P (g − s)‖ of a FOG's measured axis from its nominal one as wired
/// (0.1: six times the largest misalignment the table allows, a hundred times the paper's
/// scale-factor error, and far from the 2 of a reversal or the ≈ 1.2–1.4 of another axis).
pub const AXIS_TOLERANCE: f64 = 0.1;

/// Largest standard error of the slope along a direction for it to count as measured.
pub const MAX_SLOPE_SE: f64 = 0.03;

/// Largest bias a FOG as wired can show against the reference before calibration, rad/s
/// (5 °/h: five times the paper's systematic zero signal of ±1 °/h).
pub const MAX_BIAS_RAD_S: f64 = 5.0 / 3600.0 * std::f64::consts::PI / 180.0;

/// What the check found for one FOG column.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Verdict {
    /// The measured axis is the nominal one.
    AsWired,
    /// The measured axis is the nominal one reversed.
    Reversed,
    /// The column follows another FOG's nominal axis (index), with this sign.
    CarriesAxisOf(usize, f64),
    /// The column follows no FOG's axis.
    NoMatch,
    /// The reference does not move along the FOG's axis, but the column's mean is the
    /// reversed reference (its offset from the reference as wired, rad/s, beyond
    /// [`MAX_BIAS_RAD_S`]).
    ReversedByMean(f64),
    /// The reference does not move along the FOG's axis enough to tell.
    NotJudged,
}

/// One FOG column's measured axis and verdict.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FogWiring {
    /// FOG index (column `fog{index}_…`).
    pub fog: usize,
    /// Measured axis g projected on the measured directions, ICS.
    pub axis: Vector3<f64>,
    /// Its nominal axis projected the same way.
    pub nominal: Vector3<f64>,
    /// Largest slope standard error among the measured directions.
    pub slope_se: f64,
    /// What the check concludes.
    pub verdict: Verdict,
}

/// The measured directions of a reference: the covariance's eigenvectors with their
/// eigenvalues, and the reference's mean.
fn directions(reference: &[Vector3<f64>]) -> (Vector3<f64>, Vec<(Vector3<f64>, f64)>) {
    let n = reference.len().max(1) as f64;
    let mean = reference.iter().fold(Vector3::zeros(), |a, w| a + w) / n;
    let cov = reference.iter().fold(Matrix3::zeros(), |a, w| a + (w - mean) * (w - mean).transpose()) / n;
    let eig = cov.symmetric_eigen();
    let dirs = (0..3).map(|k| (eig.eigenvectors.column(k).into_owned(), eig.eigenvalues[k])).collect();
    (mean, dirs)
}

/// Checks every FOG column of `s` against `reference` (ω_ref per row, ICS, rad/s).
pub fn check(s: &Session, reference: &[Vector3<f64>]) -> Vec<FogWiring> {
    let axes = nominal_axes();
    let n_fog = s.fogs.len().min(axes.len());
    let (mean, dirs) = directions(reference);
    let n = reference.len() as f64;
    (0..n_fog)
        .map(|j| {
            let y = &s.fogs[j].rate_rad_s;
            let my = y.iter().sum::<f64>() / n;
            // slope along each direction (the directions are uncorrelated by construction)
            let fits: Vec<(Vector3<f64>, f64)> = dirs
                .iter()
                .filter(|(_, lambda)| *lambda > 0.0)
                .map(|(v, lambda)| {
                    let c = reference.iter().zip(y).map(|(w, yi)| v.dot(&(w - mean)) * (yi - my)).sum::<f64>() / n;
                    (*v, c / lambda)
                })
                .collect();
            let resid: Vec<f64> = reference
                .iter()
                .zip(y)
                .map(|(w, yi)| yi - my - fits.iter().map(|(v, k)| k * v.dot(&(w - mean))).sum::<f64>())
                .collect();
            let rss: f64 = resid.iter().map(|r| r * r).sum();
            let rho = if rss > 0.0 { resid.windows(2).map(|w| w[0] * w[1]).sum::<f64>() / rss } else { 0.0 };
            let rho = rho.clamp(0.0, 0.999);
            let dof = (n - 1.0 - fits.len() as f64).max(1.0);
            let measured: Vec<(Vector3<f64>, f64, f64)> = dirs
                .iter()
                .filter(|(_, lambda)| *lambda > 0.0)
                .zip(&fits)
                .map(|((v, lambda), (_, k))| {
                    let se = (rss / dof / (n * lambda) * (1.0 + rho) / (1.0 - rho)).sqrt();
                    (*v, *k, se)
                })
                .filter(|(_, _, se)| *se <= MAX_SLOPE_SE)
                .collect();
            let project = |a: &Vector3<f64>| measured.iter().fold(Vector3::zeros(), |p, (v, _, _)| p + v * v.dot(a));
            let axis = measured.iter().fold(Vector3::zeros(), |p, (v, k, _)| p + v * *k);
            let nominal = project(&axes[j]);
            let slope_se = measured.iter().map(|m| m.2).fold(0.0, f64::max);
            let near = |a: Vector3<f64>| (axis - project(&a)).norm() <= AXIS_TOLERANCE;
            let verdict = if nominal.norm() < 0.5 {
                let along = axes[j].dot(&mean);
                let offset = my - along;
                if offset.abs() > MAX_BIAS_RAD_S && (my + along).abs() <= MAX_BIAS_RAD_S {
                    Verdict::ReversedByMean(offset)
                } else {
                    Verdict::NotJudged
                }
            } else if near(axes[j]) {
                Verdict::AsWired
            } else if near(-axes[j]) {
                Verdict::Reversed
            } else {
                (0..n_fog)
                    .filter(|m| *m != j && project(&axes[*m]).norm() >= 0.5)
                    .find_map(|m| {
                        [1.0, -1.0]
                            .into_iter()
                            .find(|sign| near(axes[m] * *sign))
                            .map(|sign| Verdict::CarriesAxisOf(m, sign))
                    })
                    .unwrap_or(Verdict::NoMatch)
            };
            FogWiring { fog: j, axis, nominal, slope_se, verdict }
        })
        .collect()
}

/// The check's findings as a refusal: `Ok` when no judged FOG is miswired, otherwise an
/// error naming the file, each miswired FOG's column and what it reads like.
pub fn require_as_wired(s: &Session, reference: &[Vector3<f64>]) -> Result<Vec<FogWiring>> {
    let found = check(s, reference);
    let bad: Vec<&FogWiring> =
        found.iter().filter(|f| !matches!(f.verdict, Verdict::AsWired | Verdict::NotJudged)).collect();
    if bad.is_empty() {
        return Ok(found);
    }
    let column = |i: usize| {
        let rate = format!("fog{i}_rad_s");
        let increment = format!("fog{i}_rad");
        s.names.iter().find(|n| **n == rate || **n == increment).cloned().unwrap_or(rate)
    };
    let mut msg = format!(
        "{}: the FOG columns do not follow the reference rotation as the unit is wired; nothing is \
         fitted and no table is written:",
        s.file
    );
    for f in &bad {
        let what = match f.verdict {
            Verdict::Reversed => {
                "reads the reference reversed: the FOG is mounted backwards or its sign is inverted".into()
            }
            Verdict::CarriesAxisOf(m, sign) => format!(
                "follows the axis of FOG{m} ({}{}), not its own: channels swapped",
                if sign < 0.0 { "reversed, column " } else { "column " },
                column(m)
            ),
            Verdict::ReversedByMean(offset) => format!(
                "its mean is {:+.1} °/h off the reference, more than a bias before calibration (±1 °/h) can \
                 explain, and matches the reference reversed: mounted backwards or sign inverted",
                offset * 3600.0 * 180.0 / std::f64::consts::PI
            ),
            _ => "follows no FOG axis: a dead FOG or the wrong column".into(),
        };
        let measured = if matches!(f.verdict, Verdict::ReversedByMean(_)) {
            String::new()
        } else {
            let (a, n) = (f.axis, f.nominal);
            format!(
                "measured axis ({:+.3}, {:+.3}, {:+.3}), nominal ({:+.3}, {:+.3}, {:+.3}) (slope 1σ {:.1e}): ",
                a.x, a.y, a.z, n.x, n.y, n.z, f.slope_se
            )
        };
        let _ = write!(msg, "\n  FOG{} (column `{}`): {measured}{what}", f.fog, column(f.fog));
    }
    let judged = found.iter().filter(|f| f.verdict != Verdict::NotJudged).count();
    if judged > 1 && found.iter().filter(|f| f.verdict == Verdict::Reversed).count() == judged {
        msg.push_str(
            "\n  every FOG reads reversed: more likely the session's turn direction is the opposite of the \
             format's (table_rate_rad_s positive counter-clockwise seen from above, ψ decreasing; \
             docs/SESSION-FORMAT.md)",
        );
    }
    bail!(msg)
}
