//! The conventions of a recorded log checked against its own data
//! (`docs/RECORDED-LOG.md`, "Conventions"): run before every replay and by `--check`.
//!
//! A log from another tool most often goes wrong in its conventions, and then it replays
//! without an error: the unit flies on it and reports an attitude thousands of arcseconds
//! off. The FOGs and the star tracker see the same motion, so the data can say which
//! convention they were written in:
//!
//! - **Star-tracker quaternion form.** Between two solutions a, b the body turns by
//!   Δ_s = rotvec((Λ*_a ∘ q_bs⁻¹)⁻¹ ∘ (Λ*_b ∘ q_bs⁻¹)) (ICS), and the FOGs, combined by
//!   least squares on the table's axes, by S_g (the sum of the body increments between
//!   the tags). Each reading of the four columns is tried: as logged (scalar first, Λ the
//!   body in the inertial frame), conjugated (the inertial frame in the body), scalar last,
//!   scalar last and conjugated. Only the right one makes Δ_s follow S_g; a wrong one turns
//!   Δ_s into the rotation seen in another frame, or into no rotation at all.
//! - **FOG units.** The slope s of Δ_s ≈ s S_g over the same pairs is 1 for increments in
//!   radians; a log in degrees gives π/180, rates in rad/s written as increments give Δt,
//!   and so on: the nearest such unit is named. A slope of −1 is every FOG reversed.
//! - **Star-tracker time tags.** A tag that is not the instant the quaternion holds (the
//!   time it was sent, say) shifts Δ_s against the FOGs by δ: over windows of
//!   [`TAG_WINDOW_S`] the FOG rotation between the tags moved by δ, Δ_g(δ), is fitted to
//!   Δ_s by Gauss–Newton. At a constant body rate a shift changes nothing; it shows where
//!   the rate changes (slews), and the report says how much the log constrains it.
//!
//! Each finding names the convention and the figure that shows it; a log whose motion
//! cannot tell the hypotheses apart is reported as not checked, not as clean.

use anyhow::Result;
use nalgebra::{Matrix3, Quaternion, Vector3};
use ssis::calib::{CalibrationTable, N_FOG};
use ssis::combination::FogSet;
use ssis::frames::navout::NavState;
use ssis::math::{nlerp, quat_from_rotvec, rotvec_from_quat};
use ssis::nav::{Corrections, Strapdown};
use ssis_common::ARCSEC_PER_RAD;

use crate::recorded::Recorded;

/// Longest gap between two consecutive star-tracker solutions that still makes a pair, s.
pub const MAX_PAIR_S: f64 = 1.0;
/// Span of a window for the time-tag fit, s.
pub const TAG_WINDOW_S: f64 = 2.0;
/// A form other than "as logged" is reported when its residual is below this fraction of
/// the logged form's.
pub const FORM_RATIO: f64 = 0.5;
/// A FOG scale is reported when further than this from 1 (and 5 standard errors).
pub const SCALE_TOL: f64 = 0.01;
/// A time-tag offset is reported when larger than this, s (and 5 standard errors):
/// 5 ms at a 1 °/s slew is 18″.
pub const TAG_TOL_S: f64 = 0.005;
/// Pairs needed for any verdict.
pub const MIN_PAIRS: usize = 20;
/// Truth quaternions are checked at this spacing, s.
pub const TRUTH_EVERY_S: f64 = 0.25;

/// How the four star-tracker quaternion columns are read.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum QuatForm {
    /// `st_q0` … `st_q3` = Λ*, scalar first (the log format's convention).
    AsLogged,
    /// Λ*⁻¹: the inertial frame in the tracker's frame.
    Conjugate,
    /// (x, y, z, w): the scalar in `st_q3`.
    ScalarLast,
    /// Scalar last and Λ*⁻¹.
    ScalarLastConjugate,
}

impl QuatForm {
    /// Every form, the log format's first.
    pub const ALL: [QuatForm; 4] =
        [QuatForm::AsLogged, QuatForm::Conjugate, QuatForm::ScalarLast, QuatForm::ScalarLastConjugate];

    /// The quaternion Λ* a log's four columns `c` hold under this form.
    pub fn read(self, c: [f64; 4]) -> Quaternion<f64> {
        let q = match self {
            QuatForm::AsLogged | QuatForm::Conjugate => Quaternion::new(c[0], c[1], c[2], c[3]),
            QuatForm::ScalarLast | QuatForm::ScalarLastConjugate => Quaternion::new(c[3], c[0], c[1], c[2]),
        };
        match self {
            QuatForm::Conjugate | QuatForm::ScalarLastConjugate => q.conjugate(),
            _ => q,
        }
    }

    /// In words.
    pub fn describe(self) -> &'static str {
        match self {
            QuatForm::AsLogged => "as logged (scalar first, the body in the inertial frame)",
            QuatForm::Conjugate => "conjugated (the inertial frame in the body: the quaternion written as its inverse)",
            QuatForm::ScalarLast => "scalar last ((x, y, z, w) in st_q0 … st_q3)",
            QuatForm::ScalarLastConjugate => "scalar last and conjugated",
        }
    }

    /// A short name (JSON).
    pub fn name(self) -> &'static str {
        match self {
            QuatForm::AsLogged => "as_logged",
            QuatForm::Conjugate => "conjugate",
            QuatForm::ScalarLast => "scalar_last",
            QuatForm::ScalarLastConjugate => "scalar_last_conjugate",
        }
    }
}

/// One form's fit: the slope of Δ_s on S_g and the residual.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FormFit {
    /// The form.
    pub form: QuatForm,
    /// Slope s of Δ_s ≈ s S_g.
    pub scale: f64,
    /// Its standard error.
    pub scale_se: f64,
    /// RMS of |Δ_s − s S_g| over the pairs, arcsec.
    pub rms_arcsec: f64,
}

/// The fitted time-tag offset.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TagFit {
    /// δ: the FOG time at which the quaternion holds, less its tag, s (positive: the tag
    /// is earlier than the instant; a tag written on arrival gives minus the latency).
    pub offset_s: f64,
    /// Its standard error, s (from the windows' residual and the rate changes in them).
    pub offset_se_s: f64,
    /// Windows used.
    pub windows: usize,
    /// RMS window residual at δ = 0 and at the fitted δ, arcsec.
    pub rms_at_zero_arcsec: f64,
    /// See `rms_at_zero_arcsec`.
    pub rms_fitted_arcsec: f64,
}

/// What the conventions check found.
#[derive(Debug, Clone, PartialEq)]
pub struct ConventionReport {
    /// Pairs of consecutive solutions used.
    pub pairs: usize,
    /// The FOGs whose body rotation was used (all the log's, or the triad that fits the
    /// tracker when one FOG spoils it).
    pub fogs: FogSet,
    /// Whether the star tracker's quaternions, tags and the FOG units were found right
    /// (or could not be judged): the FOG check (`--check`) reads the FOGs against them.
    pub tracker_ok: bool,
    /// The truth quaternions' fits, every reading, the log format's first (empty: no
    /// truth, or too little of it).
    pub truth: Vec<FormFit>,
    /// The body rotation between solutions, RMS, arcsec (how much the log moves).
    pub motion_rms_arcsec: f64,
    /// Every form's fit, the log format's first.
    pub forms: Vec<FormFit>,
    /// The form that fits best (the logged one on a tie).
    pub best: QuatForm,
    /// The time-tag fit (with the best form), if the log has windows for it.
    pub tags: Option<TagFit>,
    /// The findings in words (empty: nothing wrong found).
    pub findings: Vec<String>,
    /// What could not be checked, and why.
    pub unchecked: Vec<String>,
    /// The span at the log's start the check ran on, s, when the log is longer
    /// (`crate::streamed`: a long log is checked on its first [`crate::streamed::CHECK_SPAN_S`]);
    /// `None`: the whole log.
    pub span_s: Option<f64>,
}

/// Units a FOG column may have been written in, as the slope s they give (s = the log's
/// value → radians of increment), with their names.
fn unit_candidates(dt_s: f64) -> [(f64, &'static str); 6] {
    let deg = core::f64::consts::PI / 180.0;
    [
        (deg, "degrees, not radians (×π/180)"),
        (deg / 3600.0, "arcseconds, not radians"),
        (dt_s, "rates in rad/s, not increments over the sample (×Δt)"),
        (dt_s * deg, "rates in °/s, not increments in rad"),
        (dt_s * deg / 3600.0, "rates in °/h, not increments in rad"),
        (-1.0, "every FOG reversed (or the star tracker's direction)"),
    ]
}

/// The unit of [`unit_candidates`] within 3 % of the slope `s`, if any.
fn named_unit(s: f64, dt_s: f64) -> Option<(f64, &'static str)> {
    unit_candidates(dt_s)
        .into_iter()
        .filter(|(u, _)| ((s - u) / u).abs() < 0.03)
        .min_by(|a, b| ((s - a.0) / a.0).abs().total_cmp(&((s - b.0) / b.0).abs()))
}

/// The closing line of a replay of a log with `findings`.
fn warning(findings: &[String]) -> Option<&'static str> {
    (!findings.is_empty())
        .then_some("the log breaks a convention (FOUND above): its replay is not the unit's behaviour on the real data")
}

/// A report's last lines: what was not checked, and the findings.
fn footer(s: &mut String, unchecked: &[String], findings: &[String]) {
    for u in unchecked {
        s.push_str(&format!("  not checked: {u}\n"));
    }
    if findings.is_empty() {
        s.push_str("  no convention found wrong\n");
    }
    for f in findings {
        s.push_str(&format!("FOUND: {f}\n"));
    }
}

/// The body increments the log's FOGs give per step (least squares on the table's axes,
/// over the FOGs present; `None` with fewer than three).
fn body_increments(rec: &Recorded, table: &CalibrationTable, fogs: FogSet) -> Vec<Option<Vector3<f64>>> {
    let axes = table.axes();
    rec.steps
        .iter()
        .map(|s| {
            let mut ata = Matrix3::zeros();
            let mut atm = Vector3::zeros();
            let mut n = 0;
            for (i, f) in s.fog.iter().enumerate().take(N_FOG) {
                if let (Some(f), true) = (f, fogs.contains(i)) {
                    ata += axes[i] * axes[i].transpose();
                    atm += axes[i] * f.dtheta_rad;
                    n += 1;
                }
            }
            if n < 3 {
                return None;
            }
            ata.try_inverse().map(|inv| inv * atm)
        })
        .collect()
}

/// The FOGs' motion on the log's clock: sums and attitude at each step's end.
struct Gyro {
    dt_s: f64,
    /// Σ body increments at the end of step k (k = 0: unit time 0).
    sum: Vec<Vector3<f64>>,
    /// The FOG attitude (any start) at the end of step k.
    q: Vec<Quaternion<f64>>,
    /// Whether step k had a body increment.
    ok: Vec<bool>,
}

impl Gyro {
    fn new(rec: &Recorded, table: &CalibrationTable, fogs: FogSet, dt_s: f64) -> Gyro {
        let inc = body_increments(rec, table, fogs);
        let mut sum = vec![Vector3::zeros()];
        let mut q = vec![Quaternion::identity()];
        let mut ok = vec![true];
        let (mut s, mut a) = (Vector3::zeros(), Quaternion::identity());
        for b in &inc {
            let b = b.unwrap_or_else(Vector3::zeros);
            s += b;
            a *= quat_from_rotvec(&b);
            a /= a.norm();
            sum.push(s);
            q.push(a);
        }
        ok.extend(inc.iter().map(Option::is_some));
        Gyro { dt_s, sum, q, ok }
    }

    /// Step index and fraction of unit time `t_s`, if its step had FOG data.
    fn index(&self, t_s: f64) -> Option<(usize, f64)> {
        let x = t_s / self.dt_s;
        if !x.is_finite() || x < 0.0 {
            return None;
        }
        let k = x.floor() as usize;
        (*self.ok.get(k + 1)?).then_some((k, x - k as f64))
    }

    fn sum_at(&self, t_s: f64) -> Option<Vector3<f64>> {
        let (k, f) = self.index(t_s)?;
        Some(self.sum[k] + (self.sum[k + 1] - self.sum[k]) * f)
    }

    fn q_at(&self, t_s: f64) -> Option<Quaternion<f64>> {
        let (k, f) = self.index(t_s)?;
        Some(nlerp(&self.q[k], &self.q[k + 1], f))
    }

    /// Every step between `a` and `b` had FOG data.
    fn complete(&self, a_s: f64, b_s: f64) -> bool {
        let (ka, kb) = ((a_s / self.dt_s).floor() as usize, (b_s / self.dt_s).ceil() as usize);
        self.ok.get(ka..=kb.min(self.ok.len().saturating_sub(1))).is_some_and(|s| s.iter().all(|&o| o))
    }
}

/// The pairs of consecutive solutions with FOG data between them, and every form's fit
/// on them, for the FOGs in `fogs`.
struct Fits {
    fogs: FogSet,
    gyro: Gyro,
    pairs: Vec<(usize, usize, Vector3<f64>)>,
    forms: Vec<FormFit>,
}

impl Fits {
    fn new(rec: &Recorded, table: &CalibrationTable, fogs: FogSet, st: &[(f64, [f64; 4])], dt_s: f64) -> Fits {
        let gyro = Gyro::new(rec, table, fogs, dt_s);
        let (pairs, forms) = fit_forms(&gyro, st, table.st_mount().conjugate());
        Fits { fogs, gyro, pairs, forms }
    }

    /// The form that fits best (the logged one on a tie).
    fn best(&self) -> Option<FormFit> {
        self.forms.iter().copied().min_by(|a, b| a.rms_arcsec.total_cmp(&b.rms_arcsec))
    }
}

/// Every reading's fit of the quaternion series `qs` ((time s, four columns), the body in
/// the inertial frame after `mount_inv`) to the FOGs over consecutive pairs at most
/// [`MAX_PAIR_S`] apart: the pairs (indices, S_g) and the fits (none below [`MIN_PAIRS`]).
#[allow(clippy::type_complexity)]
fn fit_forms(
    gyro: &Gyro,
    qs: &[(f64, [f64; 4])],
    mount_inv: Quaternion<f64>,
) -> (Vec<(usize, usize, Vector3<f64>)>, Vec<FormFit>) {
    let pairs: Vec<(usize, usize, Vector3<f64>)> = qs
        .windows(2)
        .enumerate()
        .filter_map(|(k, w)| {
            let ((ta, _), (tb, _)) = (w[0], w[1]);
            if tb <= ta || tb - ta > MAX_PAIR_S || !gyro.complete(ta, tb) {
                return None;
            }
            Some((k, k + 1, gyro.sum_at(tb)? - gyro.sum_at(ta)?))
        })
        .collect();
    if pairs.len() < MIN_PAIRS {
        return (pairs, Vec::new());
    }
    let delta = |form: QuatForm, a: usize, b: usize| {
        let body = |k: usize| form.read(qs[k].1) * mount_inv;
        rotvec_from_quat(&(body(a).conjugate() * body(b)))
    };
    let forms = QuatForm::ALL
        .iter()
        .map(|&form| {
            let (mut sgg, mut sgs) = (0.0, 0.0);
            for &(a, b, g) in &pairs {
                sgg += g.norm_squared();
                sgs += g.dot(&delta(form, a, b));
            }
            let scale = if sgg > 0.0 { sgs / sgg } else { 0.0 };
            let ss: f64 = pairs.iter().map(|&(a, b, g)| (delta(form, a, b) - g * scale).norm_squared()).sum();
            let n = pairs.len() as f64;
            let var = ss / (3.0 * n - 1.0).max(1.0);
            FormFit {
                form,
                scale,
                scale_se: if sgg > 0.0 { (var / sgg).sqrt() } else { f64::INFINITY },
                rms_arcsec: (ss / n).sqrt() * ARCSEC_PER_RAD,
            }
        })
        .collect();
    (pairs, forms)
}

/// Truth sampled every [`TRUTH_EVERY_S`] (time of the step's end, Λ scalar first).
fn truth_series(rec: &Recorded, dt_s: f64) -> Vec<(f64, [f64; 4])> {
    let mut out: Vec<(f64, [f64; 4])> = Vec::new();
    for (k, s) in rec.steps.iter().enumerate() {
        let Some(t) = s.truth else { continue };
        let t_s = (k + 1) as f64 * dt_s;
        if out.last().is_none_or(|l| t_s - l.0 >= TRUTH_EVERY_S - 0.5 * dt_s) {
            out.push((t_s, [t.q.w, t.q.i, t.q.j, t.q.k]));
        }
    }
    out
}

/// Checks `rec`'s conventions against `table` (its FOG axes and star-tracker mount).
///
/// A FOG mounted backwards or wired to another channel spoils the body rotation the FOGs
/// give, and with it every form's fit: with four FOGs each triad is tried too, and one
/// that fits the tracker clearly better (half the residual) is used for the verdicts on
/// the tracker (the FOG check, `--check`, names the FOG).
pub fn check_conventions(rec: &Recorded, table: &CalibrationTable, dt_us: u32) -> Result<ConventionReport> {
    let dt_s = f64::from(dt_us) * 1e-6;
    let st: Vec<(f64, [f64; 4])> = rec
        .steps
        .iter()
        .flat_map(|s| s.st.iter())
        .filter(|s| s.valid)
        .map(|s| (s.time_us as f64 * 1e-6, s.q))
        .collect();
    let mut unchecked = Vec::new();
    let mut findings = Vec::new();
    let fits = fits_of_fogs(rec, table, &st, dt_s);
    let (Some(best), Some(&logged)) = (fits.best(), fits.forms.first()) else {
        unchecked.push(format!(
            "star-tracker conventions: {} pairs of solutions with FOG data between them (need {MIN_PAIRS})",
            fits.pairs.len()
        ));
        let truth = check_truth(rec, &fits.gyro, dt_s, &mut findings, &mut unchecked);
        return Ok(ConventionReport {
            pairs: fits.pairs.len(),
            fogs: fits.fogs,
            tracker_ok: true,
            truth,
            motion_rms_arcsec: 0.0,
            forms: Vec::new(),
            best: QuatForm::AsLogged,
            tags: None,
            findings,
            unchecked,
            span_s: None,
        });
    };
    let mount_inv = table.st_mount().conjugate();
    let motion_rms_arcsec = (fits
        .pairs
        .iter()
        .map(|&(a, b, _)| {
            let body = |k: usize| QuatForm::AsLogged.read(st[k].1) * mount_inv;
            rotvec_from_quat(&(body(a).conjugate() * body(b))).norm_squared()
        })
        .sum::<f64>()
        / fits.pairs.len() as f64)
        .sqrt()
        * ARCSEC_PER_RAD;
    // The forms differ only where the body turns: with the rotation between solutions no
    // larger than the fit's residual, they cannot be told apart.
    let spread = fits.forms.iter().map(|f| f.rms_arcsec).fold(0.0, f64::max) - best.rms_arcsec;
    let decisive = spread >= 3.0 * best.rms_arcsec;
    let best = if best.form != QuatForm::AsLogged && best.rms_arcsec < FORM_RATIO * logged.rms_arcsec {
        findings.push(format!(
            "the star-tracker quaternions read {}: the FOGs follow them with a residual of {:.1}″ per pair, \
             against {:.1}″ as logged (scalar first, the body in the inertial frame; docs/RECORDED-LOG.md)",
            best.form.describe(),
            best.rms_arcsec,
            logged.rms_arcsec
        ));
        best
    } else {
        if !decisive {
            unchecked.push(format!(
                "star-tracker quaternion form and FOG units: the body turns {motion_rms_arcsec:.1}″ RMS between \
                 solutions, and the FOGs follow no form of the tracker's quaternions closer than {:.1}″ \
                 (too little motion, or a FOG wired or mounted wrong: the FOG check names it)",
                best.rms_arcsec
            ));
        }
        logged
    };
    // FOG units: the slope under the form that fits, where the fit tells the forms apart.
    let s = best.scale;
    if decisive && (s - 1.0).abs() > SCALE_TOL.max(5.0 * best.scale_se) {
        findings.push(match named_unit(s, dt_s) {
            Some((u, what)) => format!(
                "the FOG columns look like {what}: the star tracker turns {s:.6} rad per radian the FOGs give \
                 (± {:.6}; that unit gives {u:.6})",
                best.scale_se
            ),
            None => format!(
                "the FOGs' scale against the star tracker is {s:.5} ± {:.5} (1 expected): check the FOG \
                 columns' unit and the table's scale factors",
                best.scale_se
            ),
        });
    }
    // Time tags, if the FOGs are in radians and the form is known.
    let tags =
        if findings.is_empty() && decisive { fit_tag_offset(&st, &fits.gyro, best.form, mount_inv) } else { None };
    tag_verdict(tags.as_ref(), decisive, &mut findings, &mut unchecked);
    let tracker_ok = findings.is_empty();
    let truth = check_truth(rec, &fits.gyro, dt_s, &mut findings, &mut unchecked);
    Ok(ConventionReport {
        pairs: fits.pairs.len(),
        fogs: fits.fogs,
        tracker_ok,
        truth,
        motion_rms_arcsec,
        forms: fits.forms,
        best: best.form,
        tags,
        findings,
        unchecked,
        span_s: None,
    })
}

/// The fits of the FOGs against the tracker's solutions `st`: all the log's FOGs, or with
/// four a triad that fits the tracker clearly better (a FOG wired or mounted wrong).
fn fits_of_fogs(rec: &Recorded, table: &CalibrationTable, st: &[(f64, [f64; 4])], dt_s: f64) -> Fits {
    let mut fits = Fits::new(rec, table, rec.fogs, st, dt_s);
    if rec.fogs.count() == 4 {
        for i in 0..N_FOG {
            let triad = Fits::new(rec, table, rec.fogs.without(i), st, dt_s);
            if let (Some(t), Some(b)) = (triad.best(), fits.best()) {
                if t.rms_arcsec < FORM_RATIO * b.rms_arcsec {
                    fits = triad;
                }
            }
        }
    }
    fits
}

/// The verdict on the star-tracker time tags `tags` (fitted only when the FOGs and the
/// form are `decisive` and nothing else was found): a finding if the tags are off, a
/// note if the log cannot fix them.
fn tag_verdict(tags: Option<&TagFit>, decisive: bool, findings: &mut Vec<String>, unchecked: &mut Vec<String>) {
    match tags {
        Some(t) if t.offset_s.abs() > TAG_TOL_S.max(5.0 * t.offset_se_s) => findings.push(format!(
            "the star-tracker time tags are {:.1} ms {} the instant the quaternion holds (± {:.1} ms; residual \
             {:.1}″ per window at the tags as logged, {:.1}″ moved): a tag must be the instant of the \
             quaternion, not the time it was sent or logged",
            1e3 * t.offset_s.abs(),
            if t.offset_s < 0.0 { "after" } else { "before" },
            1e3 * t.offset_se_s,
            t.rms_at_zero_arcsec,
            t.rms_fitted_arcsec
        )),
        Some(t) if t.offset_se_s > TAG_TOL_S => unchecked.push(format!(
            "star-tracker time tags: the log's rate changes fix them only to ± {:.0} ms",
            1e3 * t.offset_se_s
        )),
        Some(_) => {}
        None if findings.is_empty() && decisive => {
            unchecked.push(format!(
                "star-tracker time tags: fewer than {MIN_PAIRS} windows of {TAG_WINDOW_S} s with FOG data throughout"
            ));
        }
        None => {}
    }
}

/// The truth quaternions' reading against the FOGs, as for the star tracker: a log whose
/// truth is conjugated or scalar last would score the unit against the wrong attitude.
fn check_truth(
    rec: &Recorded,
    gyro: &Gyro,
    dt_s: f64,
    findings: &mut Vec<String>,
    unchecked: &mut Vec<String>,
) -> Vec<FormFit> {
    if !rec.has_truth {
        return Vec::new();
    }
    let (_, forms) = fit_forms(gyro, &truth_series(rec, dt_s), Quaternion::identity());
    let (Some(best), Some(&logged)) =
        (forms.iter().copied().min_by(|a, b| a.rms_arcsec.total_cmp(&b.rms_arcsec)), forms.first())
    else {
        unchecked.push(format!("truth quaternions: fewer than {MIN_PAIRS} pairs with FOG data between them"));
        return forms;
    };
    if best.form != QuatForm::AsLogged && best.rms_arcsec < FORM_RATIO * logged.rms_arcsec {
        findings.push(format!(
            "the truth quaternions read {}: the FOGs follow them with a residual of {:.1}″ per {TRUTH_EVERY_S} s, \
             against {:.1}″ as logged: the errors against truth would be the convention's, not the unit's",
            best.form.describe(),
            best.rms_arcsec,
            logged.rms_arcsec
        ));
    }
    forms
}

/// Gauss–Newton fit of the tag offset δ: Δ_s(a, b) ≈ rotvec(q_g(t_a + δ)⁻¹ ∘ q_g(t_b + δ))
/// over non-overlapping windows of [`TAG_WINDOW_S`].
fn fit_tag_offset(st: &[(f64, [f64; 4])], gyro: &Gyro, form: QuatForm, mount_inv: Quaternion<f64>) -> Option<TagFit> {
    let body = |k: usize| form.read(st[k].1) * mount_inv;
    let mut windows = Vec::new();
    let mut a = 0;
    while a < st.len() {
        let Some(b) = (a + 1..st.len()).find(|&b| st[b].0 - st[a].0 >= TAG_WINDOW_S) else { break };
        if st[b].0 - st[a].0 <= 1.5 * TAG_WINDOW_S && gyro.complete(st[a].0 - 0.6, st[b].0 + 0.6) {
            windows.push((st[a].0, st[b].0, rotvec_from_quat(&(body(a).conjugate() * body(b)))));
        }
        a = b;
    }
    if windows.len() < MIN_PAIRS {
        return None;
    }
    let resid = |d: f64, w: &(f64, f64, Vector3<f64>)| -> Option<Vector3<f64>> {
        let (qa, qb) = (gyro.q_at(w.0 + d)?, gyro.q_at(w.1 + d)?);
        Some(w.2 - rotvec_from_quat(&(qa.conjugate() * qb)))
    };
    let rms = |d: f64| -> Option<f64> {
        let ss: Option<f64> = windows.iter().map(|w| resid(d, w).map(|r| r.norm_squared())).sum();
        Some((ss? / windows.len() as f64).sqrt())
    };
    let h = 1e-3;
    let mut d = 0.0;
    let mut se = f64::INFINITY;
    for _ in 0..8 {
        let (mut jj, mut jr, mut ss) = (0.0, 0.0, 0.0);
        for w in &windows {
            let (r, rp, rm) = (resid(d, w)?, resid(d + h, w)?, resid(d - h, w)?);
            // ∂r/∂δ by central difference.
            let j = (rp - rm) / (2.0 * h);
            jj += j.norm_squared();
            jr += j.dot(&r);
            ss += r.norm_squared();
        }
        if jj <= 0.0 {
            return None;
        }
        let step = -jr / jj;
        d = (d + step).clamp(-0.5, 0.5);
        se = (ss / (3.0 * windows.len() as f64 - 1.0) / jj).sqrt();
        if step.abs() < 1e-6 {
            break;
        }
    }
    Some(TagFit {
        offset_s: d,
        offset_se_s: se,
        windows: windows.len(),
        rms_at_zero_arcsec: rms(0.0)? * ARCSEC_PER_RAD,
        rms_fitted_arcsec: rms(d)? * ARCSEC_PER_RAD,
    })
}

impl ConventionReport {
    /// The closing line of a replay of a log that breaks a convention.
    pub fn warning(&self) -> Option<&'static str> {
        warning(&self.findings)
    }

    /// The report a person reads.
    pub fn report(&self) -> String {
        let mut s = format!(
            "conventions: {} pairs of star-tracker solutions against {} (body turns {:.1}″ RMS between them){}\n",
            self.pairs,
            crate::replay::fog_names(self.fogs),
            self.motion_rms_arcsec,
            self.span_s.map_or(String::new(), |t| format!(", over the log's first {t:.0} s"))
        );
        for f in &self.forms {
            s.push_str(&format!(
                "  quaternions {:<22} residual {:>10.1}″  FOG scale {:>10.6} ± {:.6}{}\n",
                f.form.name(),
                f.rms_arcsec,
                f.scale,
                f.scale_se,
                if f.form == self.best { "  <- fits" } else { "" }
            ));
        }
        if let (Some(l), Some(b)) =
            (self.truth.first(), self.truth.iter().min_by(|a, b| a.rms_arcsec.total_cmp(&b.rms_arcsec)))
        {
            s.push_str(&format!(
                "  truth quaternions: residual {:.1}″ as logged, best reading {} ({:.1}″)\n",
                l.rms_arcsec,
                b.form.name(),
                b.rms_arcsec
            ));
        }
        if let Some(t) = &self.tags {
            s.push_str(&format!(
                "  time tags: offset {:+.1} ± {:.1} ms over {} windows of {TAG_WINDOW_S} s (residual {:.1}″ as logged, {:.1}″ moved)\n",
                1e3 * t.offset_s,
                1e3 * t.offset_se_s,
                t.windows,
                t.rms_at_zero_arcsec,
                t.rms_fitted_arcsec
            ));
        }
        footer(&mut s, &self.unchecked, &self.findings);
        s
    }
}

/// Earth's surface to 2,000 km up, ECEF radius, m: where a launch vehicle's position is.
pub const LV_RADIUS_M: (f64, f64) = (6.2e6, 8.5e6);
/// The longest span of a launch-vehicle log the free-inertial check integrates, s (the
/// calibrated sensors' own error stays metres there; docs/LAUNCH-VEHICLE.md).
pub const LV_CHECK_SPAN_S: f64 = 60.0;

/// One unit hypothesis of a launch-vehicle log's increments: the free-inertial
/// navigation's miss of the reference positions.
#[derive(Debug, Clone, PartialEq)]
pub struct LvUnitFit {
    /// The units in words (as logged first).
    pub what: String,
    /// RMS position miss against the reference over the span, m.
    pub rms_m: f64,
}

/// The conventions of a launch-vehicle log checked against its own data.
#[derive(Debug, Clone, PartialEq)]
pub struct LvConventionReport {
    /// The reference positions (`gnss` fixes or `truth`) and how many.
    pub reference: (&'static str, usize),
    /// Span integrated, s.
    pub span_s: f64,
    /// Each hypothesis (the accelerometers' units, then the FOGs' when the navigation
    /// judges them), as logged first.
    pub fits: Vec<LvUnitFit>,
    /// The FOGs' scale against truth's attitude and its 1σ (`None`: no truth attitude).
    pub fog_truth_scale: Option<(f64, f64)>,
    /// What was found wrong.
    pub findings: Vec<String>,
    /// What could not be checked.
    pub unchecked: Vec<String>,
}

/// Checks a launch-vehicle log's conventions: every position (GNSS fixes, the initial
/// state, truth) is an ECEF radius in metres between the Earth's surface and 2,000 km up
/// ([`LV_RADIUS_M`]: kilometres are named); and the FOG and accelerometer increments,
/// integrated free-inertial from the initial state `init` over the first
/// [`LV_CHECK_SPAN_S`], follow the GNSS fixes (or truth): each reading of the units the
/// spacecraft check knows (degrees, rates; for the accelerometers g, rates in m/s² or g)
/// is tried, and one that follows the reference with a quarter of the logged reading's
/// miss is named. A log whose every reading misses by more than 20 receiver σ is named as
/// such (axes, signs or the initial state).
pub fn check_lv(rec: &Recorded, table: &CalibrationTable, init: &NavState) -> LvConventionReport {
    let dt_s = f64::from(rec.unit.profile().dt_us) * 1e-6;
    let (mut findings, fixes, truth) = lv_positions(rec, init, dt_s);
    let mut unchecked = Vec::new();
    let positions_ok = findings.is_empty();
    let (name, refs, sigma_m) = lv_reference(&fixes, truth);
    let span_s = (rec.steps.len() as f64 * dt_s).min(LV_CHECK_SPAN_S);
    let refs: Vec<(f64, Vector3<f64>)> = refs.into_iter().filter(|r| r.0 <= span_s).collect();
    if !positions_ok || refs.len() < 3 {
        if positions_ok {
            unchecked.push(format!("increment units: {} reference positions in the first {span_s:.0} s", refs.len()));
        }
        return LvConventionReport {
            reference: (name, refs.len()),
            span_s,
            fits: Vec::new(),
            fog_truth_scale: None,
            findings,
            unchecked,
        };
    }
    let deg = core::f64::consts::PI / 180.0;
    let g = 9.806_65;
    let acc_units: [(f64, &str); 4] =
        [(1.0, "m/s (as logged)"), (g, "g·s (g, not m/s)"), (dt_s, "m/s² rates"), (g * dt_s, "g rates")];
    let fog_units: [(f64, &str); 3] = [(1.0, "rad (as logged)"), (deg, "degrees"), (dt_s, "rad/s rates")];
    let mut fits = Vec::new();
    let miss = |kf: f64, ka: f64| free_inertial_miss(rec, init, dt_s, kf, ka, span_s, &refs);
    // The accelerometers' unit, the FOGs as logged.
    let mut acc_fits = Vec::new();
    for (ka, wa) in acc_units {
        if let Some(rms_m) = miss(1.0, ka) {
            acc_fits.push((ka, LvUnitFit { what: format!("accelerometers in {wa}"), rms_m }));
        }
    }
    let Some((_, logged)) = acc_fits.first().cloned() else {
        unchecked.push("increment units: the free-inertial navigation could not run on the log".into());
        return LvConventionReport {
            reference: (name, refs.len()),
            span_s,
            fits,
            fog_truth_scale: None,
            findings,
            unchecked,
        };
    };
    let (ka, best) =
        acc_fits.iter().min_by(|a, b| a.1.rms_m.total_cmp(&b.1.rms_m)).cloned().unwrap_or((1.0, logged.clone()));
    let bound_m = 20.0 * sigma_m;
    let ka = if ka != 1.0 && best.rms_m < 0.25 * logged.rms_m && best.rms_m <= bound_m {
        findings.push(format!(
            "the {} look like {}: the free-inertial navigation follows the {name} with {:.1} m RMS over \
             {span_s:.0} s read so, against {:.1} m as logged",
            "accelerometer columns",
            &best.what["accelerometers in ".len()..],
            best.rms_m,
            logged.rms_m
        ));
        ka
    } else {
        1.0
    };
    fits.extend(acc_fits.into_iter().map(|(_, f)| f));
    // The FOGs' unit: against truth's attitude where the log has it (as the spacecraft
    // check reads the tracker), else by the navigation, if their readings differ.
    let truth_q = truth_series(rec, dt_s);
    let gyro = Gyro::new(rec, table, rec.fogs, dt_s);
    let (_, tforms) = fit_forms(&gyro, &truth_q, Quaternion::identity());
    if let Some(t) = tforms.first() {
        let s = t.scale;
        if (s - 1.0).abs() > SCALE_TOL.max(5.0 * t.scale_se) {
            findings.push(match named_unit(s, dt_s) {
                Some((_, what)) => format!(
                    "the FOG columns look like {what}: truth turns {s:.6} rad per radian the FOGs give (± {:.6})",
                    t.scale_se
                ),
                None => format!("the FOGs' scale against truth is {s:.5} ± {:.5} (1 expected)", t.scale_se),
            });
        }
    } else {
        let fog_fits: Vec<LvUnitFit> = fog_units
            .iter()
            .filter_map(|&(kf, wf)| miss(kf, ka).map(|rms_m| LvUnitFit { what: format!("FOGs in {wf}"), rms_m }))
            .collect();
        let lo = fog_fits.iter().map(|f| f.rms_m).fold(f64::INFINITY, f64::min);
        let hi = fog_fits.iter().map(|f| f.rms_m).fold(0.0, f64::max);
        match (fog_fits.first(), fog_fits.iter().min_by(|a, b| a.rms_m.total_cmp(&b.rms_m))) {
            (Some(l), Some(b)) if hi >= 4.0 * lo => {
                if b.what != l.what && b.rms_m < 0.25 * l.rms_m {
                    findings.push(format!(
                        "the FOG columns look like {}: the navigation follows the {name} with {:.1} m RMS read so, \
                         against {:.1} m as logged",
                        &b.what["FOGs in ".len()..],
                        b.rms_m,
                        l.rms_m
                    ));
                }
            }
            _ => unchecked.push(format!(
                "FOG units: the first {span_s:.0} s do not turn the thrust enough to tell them apart by the \
                 navigation ({lo:.1} … {hi:.1} m), and the log has no truth attitude"
            )),
        }
        fits.extend(fog_fits);
    }
    // With the units found, the navigation must still follow the reference.
    let as_read = miss(1.0, ka).unwrap_or(f64::INFINITY);
    if findings.is_empty() && as_read > bound_m {
        findings.push(format!(
            "the free-inertial navigation from the log's increments misses the {name} by {as_read:.1} m RMS over the \
             first {span_s:.0} s (20 × their {sigma_m:.1} m is the bound), and no unit of the increments explains \
             it: check the axes and signs of the FOG and accelerometer columns and the initial state against \
             docs/RECORDED-LOG.md"
        ));
    }
    let fog_truth_scale = tforms.first().map(|t| (t.scale, t.scale_se));
    LvConventionReport { reference: (name, refs.len()), span_s, fits, fog_truth_scale, findings, unchecked }
}

/// The log's positions checked as ECEF radii in metres ([`LV_RADIUS_M`]): the findings,
/// the GNSS fixes (time s, position, σ) and the truth positions (time s, position).
#[allow(clippy::type_complexity)]
fn lv_positions(
    rec: &Recorded,
    init: &NavState,
    dt_s: f64,
) -> (Vec<String>, Vec<(f64, Vector3<f64>, f64)>, Vec<(f64, Vector3<f64>)>) {
    let mut findings = Vec::new();
    // Positions: an ECEF radius in metres.
    let (lo, hi) = LV_RADIUS_M;
    let mut radius = |what: &str, r: Vector3<f64>| {
        let n = r.norm();
        if (lo..=hi).contains(&n) || findings.iter().any(|f: &String| f.starts_with(what)) {
            return;
        }
        findings.push(if (lo..=hi).contains(&(n * 1e3)) {
            format!("{what} look like kilometres, not metres (|r| = {n:.1}: an ECEF radius is {lo:.1e} … {hi:.1e} m)")
        } else {
            format!("{what} are not an ECEF position in metres (|r| = {n:.4e}; {lo:.1e} … {hi:.1e} m expected)")
        });
    };
    radius("the initial position (init_x_m …)", init.r_e_m);
    let fixes: Vec<(f64, Vector3<f64>, f64)> = rec
        .steps
        .iter()
        .flat_map(|s| s.gnss.iter())
        .map(|g| (g.time_us as f64 * 1e-6, g.r_e_m, g.sigma_pos_m))
        .collect();
    for f in &fixes {
        radius("the GNSS positions (gnss_x_m …)", f.1);
    }
    let truth: Vec<(f64, Vector3<f64>)> = rec
        .steps
        .iter()
        .enumerate()
        .filter_map(|(k, s)| s.truth.and_then(|t| t.pos_vel).map(|(r, _)| ((k + 1) as f64 * dt_s, r)))
        .collect();
    for t in &truth {
        radius("the truth positions (true_x_m …)", t.1);
    }
    (findings, fixes, truth)
}

/// The reference the increments are judged against: the GNSS fixes (with their median
/// σ) if there are three, else truth (σ 1 m).
fn lv_reference(
    fixes: &[(f64, Vector3<f64>, f64)],
    truth: Vec<(f64, Vector3<f64>)>,
) -> (&'static str, Vec<(f64, Vector3<f64>)>, f64) {
    if fixes.len() >= 3 {
        let mut s: Vec<f64> = fixes.iter().map(|f| f.2).filter(|s| s.is_finite() && *s > 0.0).collect();
        s.sort_by(f64::total_cmp);
        ("GNSS fixes", fixes.iter().map(|f| (f.0, f.1)).collect(), s.get(s.len() / 2).copied().unwrap_or(5.0))
    } else {
        ("truth", truth, 1.0)
    }
}

/// The RMS miss of a free-inertial navigation over the first `span_s` of `rec` from
/// `init`, with the FOG increments × `kf` and the accelerometer increments × `ka`,
/// against `refs` (time s, ECEF position).
fn free_inertial_miss(
    rec: &Recorded,
    init: &NavState,
    dt_s: f64,
    kf: f64,
    ka: f64,
    span_s: f64,
    refs: &[(f64, Vector3<f64>)],
) -> Option<f64> {
    let mut nav = Strapdown::new(*init, dt_s, Corrections::ALL).ok()?;
    let mut next = 0;
    let mut ss = 0.0;
    let mut n = 0usize;
    let (mut a_last, mut v_last) = (Vector3::zeros(), Vector3::zeros());
    for (k, s) in rec.steps.iter().enumerate() {
        let t_s = (k + 1) as f64 * dt_s;
        if t_s > span_s + 0.5 * dt_s {
            break;
        }
        let a = Vector3::from_fn(|i, _| s.fog.get(i).copied().flatten().map(|f| f.dtheta_rad * kf));
        let v = Vector3::from_fn(|i, _| s.accel.get(i).copied().flatten().map(|f| f.dv_m_s * ka));
        // A missing sample repeats the last (the unit bridges the same way).
        let a = Vector3::from_fn(|i, _| a[i].unwrap_or(a_last[i]));
        let v = Vector3::from_fn(|i, _| v[i].unwrap_or(v_last[i]));
        (a_last, v_last) = (a, v);
        nav.step(&a, &v).ok()?;
        while let Some(&(tr, r)) = refs.get(next) {
            if tr > t_s + 0.5 * dt_s {
                break;
            }
            if (tr - t_s).abs() <= 0.5 * dt_s {
                ss += (nav.state().r_e_m - r).norm_squared();
                n += 1;
            }
            next += 1;
        }
    }
    (n > 0).then(|| (ss / n as f64).sqrt()).filter(|x| x.is_finite())
}

impl LvConventionReport {
    /// The closing line of a replay of a log that breaks a convention.
    pub fn warning(&self) -> Option<&'static str> {
        warning(&self.findings)
    }

    /// The report a person reads.
    pub fn report(&self) -> String {
        let mut s = format!(
            "conventions: free-inertial navigation over the first {:.0} s against {} {} \n",
            self.span_s, self.reference.1, self.reference.0
        );
        for f in &self.fits {
            s.push_str(&format!("  {:<40} miss {:>14.1} m RMS\n", f.what, f.rms_m));
        }
        if let Some((k, se)) = self.fog_truth_scale {
            s.push_str(&format!("  FOGs against truth's attitude: scale {k:.6} ± {se:.6} (1 for radians)\n"));
        }
        footer(&mut s, &self.unchecked, &self.findings);
        s
    }
}
