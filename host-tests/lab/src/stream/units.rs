//! The check that a FOG column holds that FOG's rate in rad/s, where the session can tell.

use super::*;

/// The smallest RMS swing of a FOG's reference rate about its mean, °/h, for which the slope
/// of its output on the reference is judged.
const MIN_REFERENCE_SWING_DEG_H: f64 = 2.0;

/// Refuses a FOG column whose values are not that FOG's rate in rad/s, judging only what the
/// session can tell: how the FOG's output ω follows its reference rate r = s⁰·ω_ref where r
/// changes (a rate table, a turntable: the RMS of r about its mean above
/// [`MIN_REFERENCE_SWING_DEG_H`]). There the slope q = Σ(ω−ω̄)(r−r̄) / Σ(r−r̄)² over the kept
/// rows is near 1 (scale factor and misalignment move it by far less than 0.5); near −1 the
/// sign is flipped (a FOG wired or mounted the other way), near 57.3 or 206,265 the column
/// holds °/s or °/h, and any other q far from 1 is named too. A constant reference (a static
/// run) tells nothing of the unit: a constant offset of ω is a bias whatever its size (a MEMS
/// gyro's is often a thousand °/h, a hundred times the Earth rate), so such a column is not
/// judged.
pub(super) fn check_rate_columns(h: &Header, basis: &Basis, shift: &[Vec<f64>], kept: &Kept) -> LabResult<()> {
    let axes = nominal_axes();
    for (fog, z) in kept.z.iter().enumerate() {
        let Some(sh) = shift.get(fog) else { continue };
        let a = axes[fog.min(3)];
        let (mut sw, mut sr, mut swr, mut srr) = (0.0, 0.0, 0.0, 0.0);
        for (zk, w) in z.chunks_exact(basis.m).zip(&kept.omega_rad_s) {
            let r = a.x * w[0] + a.y * w[1] + a.z * w[2];
            let omega = zk[basis.y] + sh[basis.y] + r;
            sw += omega;
            sr += r;
            swr += omega * r;
            srr += r * r;
        }
        let n = kept.omega_rad_s.len().max(1) as f64;
        let var_r = (srr / n - (sr / n) * (sr / n)).max(0.0);
        let swing_deg_h = var_r.sqrt() * ssis_common::DEG_H_PER_RAD_S;
        if swing_deg_h < MIN_REFERENCE_SWING_DEG_H {
            continue;
        }
        let q = (swr / n - (sw / n) * (sr / n)) / var_r;
        let near = |x: f64, tol: f64| (q / x - 1.0).abs() < tol;
        if (q - 1.0).abs() < 0.5 {
            continue;
        }
        let why = if (q + 1.0).abs() < 0.5 {
            "its sign looks flipped (the FOG's output is minus its reference rate)".to_string()
        } else if near(180.0 / std::f64::consts::PI, 0.2) {
            "it looks like °/s, not rad/s (57.3 × the reference rate)".to_string()
        } else if near(ssis_common::DEG_H_PER_RAD_S, 0.2) {
            "it looks like °/h, not rad/s (206,265 × the reference rate)".to_string()
        } else {
            format!("its values are {q:.4} × the reference rate (another unit or another FOG's axis?)")
        };
        let what = format!(
            "{why}: Σ(ω−ω̄)(r−r̄)/Σ(r−r̄)² = {q:.4} over {} rows against the reference rate r = s⁰·ω_ref \
             (it swings by {swing_deg_h:.2} °/h RMS about its mean); a FOG's rate in rad/s gives about 1",
            kept.omega_rad_s.len(),
        );
        let name = format!("fog{fog}_rad_s");
        let column = h.names.iter().position(|c| *c == name).map(|k| (k + 1, name));
        return Err(LabError::Session(crate::session::SessionError {
            kind: crate::session::SessionErrorKind::BadValue,
            file: h.file.clone(),
            line: h.line.max(1),
            column,
            message: what,
        }));
    }
    Ok(())
}
