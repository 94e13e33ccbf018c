//! The check that a FOG column holds that FOG's rate in rad/s, where the session can tell.

use super::*;

/// Refuses a FOG column whose values are not that FOG's rate in rad/s: at the kept rows, the
/// FOG's output ω against its reference rate r = s⁰·ω_ref (where r varies or is large:
/// RMS above 2 °/h, the Earth rate on most axes) has q = Σωr / Σr² near 1 (scale factor,
/// bias and misalignment move it by far less than 0.5). Near −1 the sign is flipped (a FOG
/// wired or mounted the other way); near 57.3 or 206,265 the column holds °/s or °/h; any
/// other q far from 1 is named too. Where r is too small for q (an east axis on a level
/// turntable), an error ω − r of more than [`MAX_ERROR_DEG_H`] RMS is named instead.
/// The largest RMS of a FOG's error about its reference rate a session may have, °/h (a
/// bias of the lab's FOGs is a fraction of a °/h; the table's plausible range ends far below).
pub(super) const MAX_ERROR_DEG_H: f64 = 360.0;

pub(super) fn check_rate_columns(h: &Header, basis: &Basis, shift: &[Vec<f64>], kept: &Kept) -> LabResult<()> {
    let axes = nominal_axes();
    for (fog, z) in kept.z.iter().enumerate() {
        let Some(sh) = shift.get(fog) else { continue };
        let a = axes[fog.min(3)];
        let (mut sxr, mut srr, mut syy) = (0.0, 0.0, 0.0);
        for (zk, w) in z.chunks_exact(basis.m).zip(&kept.omega_rad_s) {
            let r = a.x * w[0] + a.y * w[1] + a.z * w[2];
            let y = zk[basis.y] + sh[basis.y];
            sxr += (y + r) * r;
            srr += r * r;
            syy += y * y;
        }
        let n = kept.omega_rad_s.len().max(1) as f64;
        let dh = |x: f64| (x / n).sqrt() * ssis_common::DEG_H_PER_RAD_S;
        let q = if dh(srr) < 2.0 { 1.0 } else { sxr / srr };
        let near = |x: f64, tol: f64| (q / x - 1.0).abs() < tol;
        let what = if (q - 1.0).abs() < 0.5 {
            // The error ω − r: bias and drift of a few °/h at most.
            if dh(syy) < MAX_ERROR_DEG_H {
                continue;
            }
            format!(
                "its error about the reference rate is {:.0} °/h RMS, beyond any FOG's bias and drift ({MAX_ERROR_DEG_H} °/h): \
                 a column in another unit (°/h or °/s)?",
                dh(syy)
            )
        } else {
            let why = if (q + 1.0).abs() < 0.5 {
                "its sign looks flipped (the FOG's output is minus its reference rate)".to_string()
            } else if near(180.0 / std::f64::consts::PI, 0.2) {
                "it looks like °/s, not rad/s (57.3 × the reference rate)".to_string()
            } else if near(ssis_common::DEG_H_PER_RAD_S, 0.2) {
                "it looks like °/h, not rad/s (206,265 × the reference rate)".to_string()
            } else {
                format!("its values are {q:.4} × the reference rate (another unit or another FOG's axis?)")
            };
            format!(
                "{why}: Σωr/Σr² = {q:.4} over {} rows against the reference rate r = s⁰·ω_ref ({:.2} °/h RMS); a \
                 FOG's rate in rad/s gives about 1",
                kept.omega_rad_s.len(),
                dh(srr)
            )
        };
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
