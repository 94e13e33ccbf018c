//! The firmware's own logs as sessions: a raw capture of the output link, and the per-step
//! CSV that `ssis-qemu` (and `ssis-sim run --csv`) write.
//!
//! The unit's output is its body rate (the ICS angular rate, compensated, combined and with
//! the drift estimate removed) and its attitude Λ, not the raw FOG outputs. As a session its
//! three "FOGs" are the body axes: `fog0_rad_s`, `fog1_rad_s`, `fog2_rad_s` are the rate about
//! X_P, Y_P, Z_P, which are the nominal axes of FOG0–2 (`docs/SESSION-FORMAT.md`), so the
//! model's terms describe what is left in the unit's output per axis (a residual bias, scale
//! factor or cross-axis error, a drift the observer did not remove).
//!
//! - **Output capture** ([`read_output_capture`]): the bytes of the output link, output
//!   frames (`docs/ICD.md`) decoded by the flight code's own
//!   [`ssis::frames::decoder::StreamDecoder`]. The measurement is the frame's rate (LSB
//!   2^-30 rad/s) at t = its time tag (the end of the step, the rate the mean over that
//!   step). The link carries no reference: the capture is taken on a turntable whose
//!   azimuth, latitude and rate are given ([`Turntable`], the session's reference form 2).
//!   Frames that fail to decode (CRC, kind, field), bytes between frames and frames whose
//!   time tag does not increase are counted and reported ([`LogReport`]), not fatal; they
//!   are left out, as are gaps in the frame counter (counted).
//! - **`ssis-qemu` CSV** ([`read_qemu_csv`], `harness::CSV_HEADER`): every logged step's Λ
//!   (q0..q3) and attitude error against the truth e = rotvec(Λ_true⁻¹ ∘ Λ) (err_*_arcsec).
//!   The measurement is the attitude: the body rate over each interval between logged rows
//!   is rotvec(Λ_{k−1}⁻¹ ∘ Λ_k)/Δt (the attitude step's own convention, `src/attitude.rs`),
//!   and the reference is the same from the truth Λ_true = Λ ∘ exp(e)⁻¹. The first row has
//!   no interval and gives no sample. A malformed line is refused like a session's (file,
//!   line, column).
//!
//! Both keep the drift estimate (`drift_x_rad_s`, … as user columns) and write a session
//! file with [`super::session::write_session_csv`].

use std::path::Path;

use nalgebra::{Quaternion, Vector3};
use ssis::frames::decoder::StreamDecoder;
use ssis::frames::output::OutputFrame;
use ssis::math::{quat_from_rotvec, rotvec_from_quat};

use super::session::{session_from_columns, Header, RowReader, Session, SessionError, SessionErrorKind};
use super::{LabError, LabResult};
use ssis_common::ARCSEC_PER_RAD;

/// The turntable an output capture was taken on (the session's reference form 2).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Turntable {
    /// Azimuth ψ of X_P from north, clockwise, rad.
    pub psi_rad: f64,
    /// Latitude φ, rad.
    pub lat_rad: f64,
    /// Table rate about Z_P (up), rad/s.
    pub table_rate_rad_s: f64,
}

/// What reading a log found.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct LogReport {
    /// The file.
    pub file: String,
    /// Bytes (capture) or data lines (CSV) read.
    pub read: u64,
    /// Frames decoded (capture) or rows read (CSV).
    pub frames: u64,
    /// Frame candidates rejected by the decoder (CRC, kind, field).
    pub bad_frames: u64,
    /// Bytes the decoder dropped (between frames, and of rejected candidates).
    pub bytes_skipped: u64,
    /// Frames left out because their time tag did not increase.
    pub out_of_order: u64,
    /// Output frames missing by the frame counter (gaps).
    pub missing: u64,
    /// Samples in the session.
    pub samples: usize,
}

impl std::fmt::Display for LogReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{}: {} read, {} frames decoded, {} bad frames, {} bytes skipped, {} out of order, {} missing by the \
             counter; {} samples",
            self.file,
            self.read,
            self.frames,
            self.bad_frames,
            self.bytes_skipped,
            self.out_of_order,
            self.missing,
            self.samples
        )
    }
}

/// A raw capture of the output link as a session (see the module text).
pub fn read_output_capture(path: &Path, table: &Turntable) -> LabResult<(Session, LogReport)> {
    let file = path.display().to_string();
    let bytes =
        std::fs::read(path).map_err(|e| refusal(&file, SessionErrorKind::Io, 0, format!("cannot read: {e}")))?;
    let mut dec: StreamDecoder<OutputFrame, 256> = StreamDecoder::new();
    let names = [
        "t_s",
        "fog0_rad_s",
        "fog1_rad_s",
        "fog2_rad_s",
        "psi_rad",
        "lat_rad",
        "table_rate_rad_s",
        "drift_x_rad_s",
        "drift_y_rad_s",
        "drift_z_rad_s",
    ];
    let mut cols: Vec<Vec<f64>> = vec![Vec::new(); names.len()];
    let mut rep = LogReport { file: file.clone(), read: bytes.len() as u64, ..LogReport::default() };
    let mut last: Option<(u64, u16)> = None;
    for chunk in bytes.chunks(4096) {
        dec.push_slice(chunk, |r| {
            let Ok(f) = r else { return };
            rep.frames += 1;
            if let Some((t, c)) = last {
                if f.time_us <= t {
                    rep.out_of_order += 1;
                    return;
                }
                rep.missing += u64::from(f.counter.wrapping_sub(c).wrapping_sub(1));
            }
            last = Some((f.time_us, f.counter));
            let (w, d) = (f.rate_rad_s(), f.drift_rad_s());
            let row = [
                f.time_us as f64 * 1e-6,
                w[0],
                w[1],
                w[2],
                table.psi_rad,
                table.lat_rad,
                table.table_rate_rad_s,
                d[0],
                d[1],
                d[2],
            ];
            for (c, v) in cols.iter_mut().zip(row) {
                c.push(v);
            }
        });
    }
    let st = dec.stats();
    rep.bad_frames = u64::from(st.rejected());
    rep.bytes_skipped = u64::from(st.bytes_skipped) + dec.buffered() as u64;
    if cols[0].len() < 2 {
        let read = rep.to_string();
        let what = read.strip_prefix(&format!("{file}: ")).unwrap_or(&read);
        return Err(refusal(
            &file,
            SessionErrorKind::NoRows,
            0,
            format!("{what}: fewer than 2 output frames, no session"),
        ));
    }
    let s = session_from_columns(&file, names.iter().map(|n| n.to_string()).collect(), &cols)?;
    rep.samples = s.len();
    Ok((s, rep))
}

/// The per-step CSV of `ssis-qemu` / `ssis-sim run --csv` as a session (see the module text).
pub fn read_qemu_csv(path: &Path) -> LabResult<(Session, LogReport)> {
    const NEEDED: [&str; 7] = ["q0", "q1", "q2", "q3", "err_x_arcsec", "err_y_arcsec", "err_z_arcsec"];
    let mut rr = RowReader::open_with(path, |f, n, l| Header::plain(f, n, l, &NEEDED))?;
    let h = rr.header().clone();
    let col = |n: &str| h.names.iter().position(|x| x == n);
    let q_col: Vec<usize> = NEEDED[..4].iter().filter_map(|n| col(n)).collect();
    let e_col: Vec<usize> = NEEDED[4..].iter().filter_map(|n| col(n)).collect();
    let drift_col: Option<Vec<usize>> =
        ["drift_x_deg_h", "drift_y_deg_h", "drift_z_deg_h"].iter().map(|n| col(n)).collect();
    let mut names: Vec<String> =
        ["t_s", "fog0_rad_s", "fog1_rad_s", "fog2_rad_s", "ref_x_rad_s", "ref_y_rad_s", "ref_z_rad_s"]
            .iter()
            .map(|s| s.to_string())
            .collect();
    if drift_col.is_some() {
        names.extend(["drift_x_rad_s", "drift_y_rad_s", "drift_z_rad_s"].map(String::from));
    }
    let mut cols: Vec<Vec<f64>> = vec![Vec::new(); names.len()];
    let file = h.file.clone();
    let mut rep = LogReport { file: file.clone(), ..LogReport::default() };
    let mut prev: Option<(f64, Quaternion<f64>, Quaternion<f64>)> = None;
    while let Some(row) = rr.next_row()? {
        rep.read += 1;
        rep.frames += 1;
        let t = row[h.layout.t];
        let q = Quaternion::new(row[q_col[0]], row[q_col[1]], row[q_col[2]], row[q_col[3]]);
        let qn = q.norm();
        if !(qn > 0.5 && qn < 1.5) {
            let why = format!("the quaternion q0..q3 has norm {qn:.3}, not 1");
            return Err(refusal(&file, SessionErrorKind::BadValue, rr.line(), why));
        }
        let q = q / qn;
        let e = Vector3::new(row[e_col[0]], row[e_col[1]], row[e_col[2]]) / ARCSEC_PER_RAD;
        let q_true = q * quat_from_rotvec(&-e);
        if let Some((t0, q0, qt0)) = prev {
            let dt = t - t0;
            let w = rotvec_from_quat(&(q0.conjugate() * q)) / dt;
            let wt = rotvec_from_quat(&(qt0.conjugate() * q_true)) / dt;
            let mut v = vec![t, w.x, w.y, w.z, wt.x, wt.y, wt.z];
            if let Some(dc) = &drift_col {
                v.extend(dc.iter().map(|&c| row[c] / ssis_common::DEG_H_PER_RAD_S));
            }
            for (c, x) in cols.iter_mut().zip(v) {
                c.push(x);
            }
        }
        prev = Some((t, q, q_true));
    }
    let s = session_from_columns(&file, names, &cols)?;
    rep.samples = s.len();
    Ok((s, rep))
}

/// A log refused: its file, the kind, the line (0: none) and the words.
fn refusal(file: &str, kind: SessionErrorKind, line: u64, message: String) -> LabError {
    LabError::Session(SessionError { kind, file: file.to_string(), line, column: None, message })
}
