//! A model fitted to a session, linear in the coefficients, per FOG, from the sums of a
//! pass; held-out time blocks.
//!
//! A pass ([`super::stream::digest`]) leaves per FOG and block the Gram matrix of the basis;
//! a model's terms are a design, a set of linear functionals of the basis, solved on those
//! sums by [`super::lsq`] (regressors the session cannot identify, such as a constant field
//! component next to the bias or the scale factor in a static test, are dropped, their
//! coefficients left at zero, and the fit says so; terms earlier in the model keep
//! priority). The basis is centred on its first row so that no sum is a small difference of
//! large ones.
//!
//! Held-out blocks: the session is cut into `n_blocks` consecutive blocks of equal sample
//! count; even blocks (0, 2, …) train, odd blocks test. "Held-out RMS" is the residual RMS
//! on the test blocks of a model fitted on the training blocks only.

use indicatif::ProgressBar;

use super::lsq::{design_gram, lstsq_gram, residual_functional, sse_gram, LsFit};
use super::model::{FitRecord, Kind, Model};
use super::session::Session;
use super::stream::{digest, for_each_prepared, Digest, DigestSpec, Source, Sums, DEFAULT_KEEP};
use super::{LabError, LabResult, ModelErrorKind};
use ssis_common::DEG_H_PER_RAD_S;

/// Default number of time blocks.
pub const DEFAULT_BLOCKS: usize = 10;

impl<'a> From<&'a Session> for Source<'a> {
    fn from(s: &'a Session) -> Self {
        Source::Memory(s)
    }
}

impl<'a> From<&'a std::path::Path> for Source<'a> {
    fn from(p: &'a std::path::Path) -> Self {
        Source::File(p)
    }
}

impl<'a> From<&'a std::path::PathBuf> for Source<'a> {
    fn from(p: &'a std::path::PathBuf) -> Self {
        Source::File(p)
    }
}

/// The regressors of a model's terms for one FOG, as shifted functionals of a digest's
/// basis, with y last, and which term owns each.
#[derive(Debug, Clone)]
pub struct Design {
    /// Functionals (shifted), y last.
    pub cols: Vec<Vec<f64>>,
    /// (term index, regressor index within the term) per column (not y).
    pub owner: Vec<(usize, usize)>,
}

impl Design {
    /// Number of regressors.
    pub fn k(&self) -> usize {
        self.cols.len() - 1
    }

    /// The regressors followed by `extra` (shifted functionals), y last.
    pub fn with(&self, extra: &[Vec<f64>]) -> Vec<Vec<f64>> {
        let mut v = self.cols[..self.k()].to_vec();
        v.extend_from_slice(extra);
        v.push(self.cols[self.k()].clone());
        v
    }
}

/// The design of `kinds` for FOG `fog` on digest `d`.
pub fn design(d: &Digest, kinds: &[Kind], fog: usize) -> LabResult<Design> {
    let mut cols = Vec::new();
    let mut owner = Vec::new();
    for (t, k) in kinds.iter().enumerate() {
        let f = d.basis.functionals(k, fog).map_err(unfed)?;
        for (m, l) in f.iter().enumerate() {
            cols.push(d.shifted(fog, l));
            owner.push((t, m));
        }
    }
    cols.push(d.shifted(fog, &d.basis.y_functional()));
    Ok(Design { cols, owner })
}

/// One `add` of the history: the residuals of the version before and of the version after
/// at the kept rows of the session (each version's terms fitted on every row).
#[derive(Debug, Clone)]
pub struct AddStep {
    /// Version before and after.
    pub from: u32,
    /// Version after.
    pub to: u32,
    /// The terms the step added ("+temp_rate").
    pub added: String,
    /// Per FOG, the residual before, rad/s.
    pub before_rad_s: Vec<Vec<f64>>,
    /// Per FOG, the residual after, rad/s.
    pub after_rad_s: Vec<Vec<f64>>,
}

/// The kept rows' times and spacing, for [`AddStep`]'s residuals.
#[derive(Debug, Clone)]
pub struct KeptTimes {
    /// Time of each kept row, s.
    pub t_s: Vec<f64>,
    /// Time between kept rows, s.
    pub dt_s: f64,
}

/// Residual RMS on the test blocks of `cols` (y last) fitted on the training blocks, and
/// the training fit.
pub fn held_out(s: &Sums, cols: &[Vec<f64>]) -> (f64, LsFit) {
    let tr = lstsq_gram(&design_gram(&s.train, cols), s.train.n);
    let sse = sse_gram(&design_gram(&s.test, cols), &tr.coef);
    ((sse / s.test.n.max(1) as f64).sqrt(), tr)
}

/// Held-out residual RMS per FOG, rad/s: fit `kinds` on the training blocks, RMS on the
/// test blocks.
pub fn held_out_rms(kinds: &[Kind], d: &Digest) -> LabResult<Vec<f64>> {
    (0..d.basis.n_fog)
        .map(|fog| {
            let s = Sums::of(d, fog);
            if s.train.n == 0 || s.test.n == 0 {
                return Err(LabError::Numeric(format!("{}: too few samples for held-out blocks", d.file)));
            }
            Ok(held_out(&s, &design(d, kinds, fog)?.cols).0)
        })
        .collect()
}

/// RMS over FOGs of per-FOG RMS values (pooled, equal sample counts).
pub fn pooled(v: &[f64]) -> f64 {
    (v.iter().map(|x| x * x).sum::<f64>() / v.len().max(1) as f64).sqrt()
}

/// Per-FOG figures of a model on a session.
#[derive(Debug, Clone)]
pub struct FogSummary {
    /// RMS of the error y (no model), rad/s.
    pub rms_error_rad_s: f64,
    /// RMS of the residual, rad/s.
    pub rms_residual_rad_s: f64,
    /// Largest |residual|, rad/s (over every row, or the kept ones: [`Fitted::max_over_rows`]).
    pub max_abs_residual_rad_s: f64,
    /// 1 − Σres²/Σy²: the fraction of the error power the model explains.
    pub explained: f64,
}

/// Residuals at the kept rows, with the quantities they are plotted against.
#[derive(Debug, Clone)]
pub struct ResidualSample {
    /// Rows of the session.
    pub of_rows: usize,
    /// Per FOG: residual at the kept rows, rad/s.
    pub residual: Vec<Vec<f64>>,
    /// Per FOG: (label, values) of each quantity (time, T, G, ψ, input rate, field).
    pub axes: Vec<Vec<(String, Vec<f64>)>>,
}

/// A model fitted (or evaluated) on a session.
#[derive(Debug, Clone)]
pub struct Fitted {
    /// The model with the coefficients used.
    pub model: Model,
    /// Figures per FOG.
    pub summary: Vec<FogSummary>,
    /// Regressors the session could not identify, as "FOGi term.name".
    pub not_identified: Vec<String>,
    /// Rows the largest |residual| was taken over (all of them, or the kept sample).
    pub max_over_rows: usize,
    /// Rows read a second time to establish it (0: the pass's extremes proved it).
    pub max_rows_read_again: usize,
    /// Residuals at the kept rows.
    pub sample: ResidualSample,
    /// What the figures do not say about the session (gaps in time: [`Digest::notes`]).
    pub notes: Vec<String>,
}

/// The coefficient vector of `kinds` in a design from a model's terms (0 where absent).
fn coef_of(model: &Model, d: &Design, fog: usize) -> Vec<f64> {
    d.owner.iter().map(|&(t, m)| model.terms[t].coef.get(fog).and_then(|c| c.get(m)).copied().unwrap_or(0.0)).collect()
}

/// Residual y − Σ c x at every kept row of FOG `fog` for functionals `cols` (shifted, y last).
pub fn kept_residual(d: &Digest, fog: usize, cols: &[Vec<f64>], coef: &[f64]) -> Vec<f64> {
    let l = residual_functional(cols, coef);
    d.kept.z[fog].chunks_exact(d.basis.m).map(|z| z.iter().zip(&l).map(|(a, b)| a * b).sum()).collect()
}

/// The quantities residuals are plotted against, at the kept rows of FOG `fog`.
fn plot_axes(d: &Digest, fog: usize) -> Vec<(String, Vec<f64>)> {
    let k = &d.kept;
    let mut v = vec![("time, h".to_string(), k.t_s.iter().map(|t| t / 3600.0).collect())];
    if let Some((temp, g)) = &k.temp[fog] {
        v.push(("T, °C".into(), temp.clone()));
        v.push((format!("G = dT/dt, °C/min ({:.0} s window)", d.g_window_s), g.iter().map(|x| x * 60.0).collect()));
    }
    if let Some(psi) = &k.psi_rad {
        v.push(("azimuth ψ, °".into(), psi.iter().map(|x| x.to_degrees()).collect()));
    }
    let a = super::session::nominal_axes()[fog.min(3)];
    v.push((
        "input rate along the axis, °/s".into(),
        k.omega_rad_s.iter().map(|w| (a.x * w[0] + a.y * w[1] + a.z * w[2]).to_degrees()).collect(),
    ));
    if let Some(b) = &k.field_nt {
        let u = super::model::loop_plane(fog)[0];
        v.push((
            "field across the axis B.u, nT".into(),
            b.iter().map(|x| u.x * x[0] + u.y * x[1] + u.z * x[2]).collect(),
        ));
    }
    v
}

/// The figures of coefficients `coef` per FOG (`None`: fit them on every row) on digest `d`.
fn summarize(model: &Model, d: &Digest, fit: bool) -> LabResult<Fitted> {
    let kinds = model.kinds();
    let n_fog = d.basis.n_fog;
    let mut out = model.clone();
    if fit {
        for t in out.terms.iter_mut() {
            t.coef = vec![Vec::new(); n_fog];
        }
    }
    let (mut summary, mut missing, mut residual, mut axes) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
    for fog in 0..n_fog {
        let des = design(d, &kinds, fog)?;
        let all = d.gram_of(fog, |_| true);
        let a = design_gram(&all, &des.cols);
        let coef = if fit {
            let ls = lstsq_gram(&a, all.n);
            for (c, &(t, m)) in des.owner.iter().enumerate() {
                let slot = &mut out.terms[t].coef[fog];
                slot.resize(m + 1, 0.0);
                slot[m] = ls.coef[c];
                if !ls.identified[c] {
                    missing.push(super::model::regressor_id(fog, &kinds[t], m));
                }
            }
            ls.coef
        } else {
            coef_of(model, &des, fog)
        };
        let k = des.k();
        let n = all.n.max(1) as f64;
        let (yy, sse) = (a[(k, k)].max(0.0), sse_gram(&a, &coef));
        let res = kept_residual(d, fog, &des.cols, &coef);
        summary.push(FogSummary {
            rms_error_rad_s: (yy / n).sqrt(),
            rms_residual_rad_s: (sse / n).sqrt(),
            max_abs_residual_rad_s: res.iter().fold(0.0, |m, v| f64::max(m, v.abs())),
            explained: if yy > 0.0 { 1.0 - sse / yy } else { 0.0 },
        });
        residual.push(res);
        axes.push(plot_axes(d, fog));
    }
    Ok(Fitted {
        model: out,
        summary,
        not_identified: missing,
        max_over_rows: d.kept.rows.len(),
        max_rows_read_again: 0,
        sample: ResidualSample { of_rows: d.n, residual, axes },
        notes: d.notes(),
    })
}

/// Largest |residual| per FOG over the first `rows` samples of `source` (a second pass), for
/// the model's coefficients on the basis of `d`.
pub fn max_abs_residuals(source: Source, d: &Digest, model: &Model, rows: usize) -> LabResult<Vec<f64>> {
    let kinds = model.kinds();
    let b = &d.basis;
    let mut lin = Vec::new();
    for fog in 0..b.n_fog {
        let mut l = b.y_functional();
        for (t, k) in kinds.iter().enumerate() {
            for (m, x) in b.functionals(k, fog).map_err(unfed)?.iter().enumerate() {
                let c = model.terms[t].coef.get(fog).and_then(|c| c.get(m)).copied().unwrap_or(0.0);
                for (a, v) in l.iter_mut().zip(x) {
                    *a -= c * v;
                }
            }
        }
        lin.push(l);
    }
    let mut max = vec![0.0f64; b.n_fog];
    let mut z = vec![0.0; b.m];
    super::stream::for_each_prepared_until(source, b.n_fog, d.g_window_s, None, rows, |_, s, g| {
        for (fog, l) in lin.iter().enumerate() {
            b.fill(fog, s, g, &mut z)?;
            let r: f64 = z.iter().zip(l).map(|(a, b)| a * b).sum();
            max[fog] = max[fog].max(r.abs());
        }
        Ok(())
    })?;
    Ok(max)
}

/// The pass a model needs on a session (its terms, its T_ref and G window).
pub fn spec_for(model: &Model, extra: &[Kind], n_blocks: usize) -> DigestSpec {
    let mut kinds = model.kinds();
    kinds.extend(extra.iter().cloned());
    DigestSpec {
        kinds,
        t_ref_degc: model.t_ref_degc,
        g_window_s: model.g_window_s,
        n_blocks,
        keep: DEFAULT_KEEP,
        track: Some(model.kinds()),
    }
}

/// Fits every term of `model` on every row of a digest, FOG by FOG.
pub fn fit_digest(model: &Model, d: &Digest) -> LabResult<Fitted> {
    summarize(model, d, true)
}

/// Evaluates `model` with its own coefficients (no fit) on a digest.
pub fn evaluate_digest(model: &Model, d: &Digest) -> LabResult<Fitted> {
    summarize(model, d, false)
}

/// What the pass's [`Extremes`] prove about the largest |residual| of a model per FOG: the
/// largest over the stored and kept rows, and per segment the bound on its other rows.
#[derive(Debug, Clone)]
pub struct MaxProof {
    /// Samples in the first k segments, k = 0, 1, … (the segments' ends).
    pub ends: Vec<usize>,
    /// Per FOG: the largest |residual| over the rows the pass stored or kept.
    pub best: Vec<f64>,
    /// Per FOG, per segment: no other row of the segment exceeds this.
    pub bound: Vec<Vec<f64>>,
}

impl MaxProof {
    /// Samples (from the start) that must be read again: up to the end of the last segment whose
    /// bound is above the best for some FOG (0: the best is the maximum).
    pub fn rows_to_read(&self) -> usize {
        self.ends[self.segments_to_read()]
    }

    /// Segments (from the start) that must be read again: up to the last whose bound is above
    /// the best for some FOG (0: the best is the maximum).
    pub fn segments_to_read(&self) -> usize {
        self.bound
            .iter()
            .zip(&self.best)
            .filter_map(|(b, best)| b.iter().rposition(|x| x > best).map(|s| s + 1))
            .max()
            .unwrap_or(0)
    }
}

/// The proof of the largest |residual| of `model`'s coefficients from a digest's extremes
/// (see [`super::stream::Extremes`]); `None` without extremes.
pub fn max_proof(d: &Digest, model: &Model) -> LabResult<Option<MaxProof>> {
    let Some(ex) = &d.extremes else { return Ok(None) };
    let kinds = model.kinds();
    let m = d.basis.m;
    let (mut best, mut bound) = (Vec::new(), Vec::new());
    for fog in 0..d.basis.n_fog {
        let des = design(d, &kinds, fog)?;
        let ell = residual_functional(&des.cols, &coef_of(model, &des, fog));
        let eval = |z: &[f64]| z.iter().zip(&ell).map(|(a, b)| a * b).sum::<f64>().abs();
        let mut top = d.kept.z[fog].chunks_exact(m).map(eval).fold(0.0, f64::max);
        let mut bounds = Vec::new();
        for seg in &ex.segs {
            let x = &seg[fog];
            top = x.rows.chunks_exact(m).map(eval).fold(top, f64::max);
            bounds.push(x.bound(&ell));
        }
        best.push(top);
        bound.push(bounds);
    }
    let ends = (0..=ex.segs.len()).map(|k| ex.rows_in(k).min(d.n)).collect();
    Ok(Some(MaxProof { ends, best, bound }))
}

/// A fit or evaluation with the largest |residual| over every row: from the kept rows when
/// they are every row; else from the pass's extremes, reading again only the first segments
/// whose bound they cannot beat (all of the session without extremes).
pub fn complete<'a>(f: Fitted, source: impl Into<Source<'a>>, d: &Digest) -> LabResult<Fitted> {
    if d.all_kept() {
        return Ok(f);
    }
    let mut f = f;
    let max = match max_proof(d, &f.model)? {
        Some(p) => {
            let again = p.rows_to_read();
            f.max_rows_read_again = again;
            if again == 0 {
                p.best
            } else {
                let scanned = max_abs_residuals(source.into(), d, &f.model, again)?;
                p.best.iter().zip(scanned).map(|(a, b)| a.max(b)).collect()
            }
        }
        None => {
            f.max_rows_read_again = d.n;
            max_abs_residuals(source.into(), d, &f.model, usize::MAX)?
        }
    };
    for (s, m) in f.summary.iter_mut().zip(max) {
        s.max_abs_residual_rad_s = m;
    }
    f.max_over_rows = d.n;
    Ok(f)
}

/// Fits every term of `model` on every row of a session, FOG by FOG.
pub fn fit_model<'a>(model: &Model, source: impl Into<Source<'a>>) -> LabResult<Fitted> {
    let source = source.into();
    let d = digest(source, &spec_for(model, &[], DEFAULT_BLOCKS), None)?;
    complete(fit_digest(model, &d)?, source, &d)
}

/// What `compare` shows: the fit (or evaluation) and the held-out RMS per FOG.
#[derive(Debug, Clone)]
pub struct Comparison {
    /// The model fitted or evaluated.
    pub fitted: Fitted,
    /// Held-out residual RMS per FOG, rad/s.
    pub held_out_rad_s: Vec<f64>,
}

/// `compare`: one pass for the sums (and a second for the largest residual when the
/// session is longer than the kept rows).
pub fn compare<'a>(
    model: &Model,
    source: impl Into<Source<'a>>,
    evaluate: bool,
    n_blocks: usize,
    progress: Option<&ProgressBar>,
) -> LabResult<Comparison> {
    let source = source.into();
    let d = digest(source, &spec_for(model, &[], n_blocks), progress)?;
    let f = if evaluate { evaluate_digest(model, &d)? } else { fit_digest(model, &d)? };
    let held_out_rad_s = held_out_rms(&model.kinds(), &d)?;
    Ok(Comparison { fitted: complete(f, source, &d)?, held_out_rad_s })
}

/// Every residual of `model` (its coefficients) on a session in memory, per FOG, rad/s.
pub fn residuals(model: &Model, session: &Session) -> LabResult<Vec<Vec<f64>>> {
    let spec = spec_for(model, &[], DEFAULT_BLOCKS);
    let shape = Source::Memory(session).shape()?;
    let b = super::stream::Basis::new(&shape.header, &spec.kinds, shape.t_span_s[0], model.t_ref_degc)?;
    let window = super::stream::effective_window_s(model.g_window_s, shape.dt_s);
    let kinds = model.kinds();
    let mut out = vec![Vec::with_capacity(session.len()); b.n_fog];
    let mut z = vec![0.0; b.m];
    for_each_prepared(Source::Memory(session), b.n_fog, window, None, |_, s, g| {
        for (fog, o) in out.iter_mut().enumerate() {
            b.fill(fog, s, g, &mut z)?;
            let mut r = z[b.y];
            for (t, k) in kinds.iter().enumerate() {
                for (m, x) in b.functionals(k, fog).map_err(unfed)?.iter().enumerate() {
                    let c = model.terms[t].coef.get(fog).and_then(|c| c.get(m)).copied().unwrap_or(0.0);
                    r -= c * x.iter().zip(&z).map(|(a, b)| a * b).sum::<f64>();
                }
            }
            o.push(r);
        }
        Ok(())
    })?;
    Ok(out)
}

/// The 1σ of every coefficient of `kinds` per FOG (design order, SI; 0 where not
/// identified) under the noise model of the cross-fitted residual ([`super::noise::Cross`]): the generalised least-squares covariance (XᵀΣ⁻¹X)⁻¹ over every block,
/// scaled by the whitened residual's variance.
pub fn coef_sigma(d: &Digest, kinds: &[Kind]) -> LabResult<Vec<Vec<f64>>> {
    (0..d.basis.n_fog)
        .map(|fog| {
            let des = design(d, kinds, fog)?;
            let s = Sums::of(d, fog);
            let bd = super::noise::Binned::of_digest(d, fog);
            let nm = super::noise::NoiseModel::fit(&bd, &super::noise::Cross::of(&s, &des.cols));
            let ws = super::noise::whitened(&nm, &bd);
            let a = design_gram(&ws.all, &des.cols);
            let ls = lstsq_gram(&a, ws.all.n);
            let keep: Vec<usize> = (0..des.k()).filter(|&c| ls.identified[c]).collect();
            let s2 = ls.sse / ls.n.saturating_sub(ls.p).max(1) as f64;
            let sub = nalgebra::DMatrix::from_fn(keep.len(), keep.len(), |i, j| a[(keep[i], keep[j])]);
            let mut sigma = vec![0.0; des.k()];
            if let Some(inv) = sub.try_inverse() {
                for (i, &c) in keep.iter().enumerate() {
                    sigma[c] = (inv[(i, i)].max(0.0) * s2).sqrt();
                }
            }
            Ok(sigma)
        })
        .collect()
}

/// What adding a term did.
#[derive(Debug, Clone)]
pub struct AddOutcome {
    /// The next model version, fitted on all rows.
    pub model: Model,
    /// Held-out RMS per FOG without the term, rad/s.
    pub before_rad_s: Vec<f64>,
    /// Held-out RMS per FOG with the term, rad/s.
    pub after_rad_s: Vec<f64>,
    /// Regressors the session could not identify.
    pub not_identified: Vec<String>,
    /// 1σ of the coefficients per FOG, in the design order of the new model's terms, SI
    /// ([`coef_sigma`]).
    pub sigma: Vec<Vec<f64>>,
    /// Per FOG, the residual at the kept rows of the model before and after (each fitted on
    /// every row), rad/s.
    pub residual_before_rad_s: Vec<Vec<f64>>,
    /// After.
    pub residual_after_rad_s: Vec<Vec<f64>>,
    /// Time between kept rows, s.
    pub kept_dt_s: f64,
    /// What the figures do not say about the session ([`Digest::notes`]).
    pub notes: Vec<String>,
}

/// Adds `kind` to `model`, refits on the session and measures the held-out RMS before and
/// after (same blocks as [`super::diagnose`]), in one pass. The result has version + 1.
pub fn add_term<'a>(
    model: &Model,
    kind: &Kind,
    source: impl Into<Source<'a>>,
    n_blocks: usize,
) -> LabResult<AddOutcome> {
    let kinds = model.kinds();
    if kinds.contains(kind) {
        return Err(LabError::model(ModelErrorKind::Term, format!("the model already has `{}`", kind.label())));
    }
    let mut next = model.clone();
    next.version = model.version + 1;
    next.terms.push(kind.spec());
    next.note = format!("v{}: added {}", next.version, kind.label());
    let d = digest(source.into(), &spec_for(&next, &[], n_blocks), None)?;
    let before = held_out_rms(&kinds, &d)?;
    let after = held_out_rms(&next.kinds(), &d)?;
    let before_fit = fit_digest(model, &d)?;
    let fitted = fit_digest(&next, &d)?;
    let mut model = fitted.model;
    model.fit = Some(FitRecord {
        session: d.file.clone(),
        rows: d.n,
        held_out_rms_deg_h: after.iter().map(|v| v * DEG_H_PER_RAD_S).collect(),
        not_identified: fitted.not_identified.clone(),
    });
    let sigma = coef_sigma(&d, &next.kinds())?;
    Ok(AddOutcome {
        model,
        before_rad_s: before,
        after_rad_s: after,
        not_identified: fitted.not_identified,
        sigma,
        residual_before_rad_s: before_fit.sample.residual,
        residual_after_rad_s: fitted.sample.residual,
        kept_dt_s: d.dt_s * d.kept.stride.max(1) as f64,
        notes: d.notes(),
    })
}

/// The residuals before and after each `add` of a history of model versions (sorted by
/// version): for each version after the first, the previous version's and its own terms
/// fitted on every row of `d`, at the kept rows. A pair whose terms `d` has no slot for is
/// left out; so is a version that adds no term.
pub fn add_steps(versions: &[(u32, Model)], d: &Digest) -> LabResult<Vec<AddStep>> {
    let mut out = Vec::new();
    for pair in versions.windows(2) {
        let [(v0, m0), (v1, m1)] = pair else { continue };
        let (k0, k1) = (m0.kinds(), m1.kinds());
        let added: Vec<String> = k1.iter().filter(|k| !k0.contains(k)).map(|k| format!("+{}", k.label())).collect();
        if added.is_empty() {
            continue;
        }
        let (Ok(before), Ok(after)) = (fit_digest(m0, d), fit_digest(m1, d)) else { continue };
        out.push(AddStep {
            from: *v0,
            to: *v1,
            added: added.join(" "),
            before_rad_s: before.sample.residual,
            after_rad_s: after.sample.residual,
        });
    }
    Ok(out)
}

/// File name of version `v` of a model whose file is `path`: `stem.vN.toml` next to it.
/// `model.toml` and `model.v3.toml` share the stem `model`.
pub fn version_path(path: &std::path::Path, v: u32) -> std::path::PathBuf {
    path.with_file_name(format!("{}.v{v}.toml", model_stem(path)))
}

/// The stem shared by every version of a model file.
pub fn model_stem(path: &std::path::Path) -> String {
    let name = path.file_name().map(|n| n.to_string_lossy().to_string()).unwrap_or_default();
    let base = name.strip_suffix(".toml").unwrap_or(&name);
    match base.rsplit_once(".v") {
        Some((stem, n)) if !n.is_empty() && n.chars().all(|c| c.is_ascii_digit()) => stem.to_string(),
        _ => base.to_string(),
    }
}

/// Every version file of the model at `path` (`stem.vN.toml`, and `stem.toml` if present),
/// sorted by the version inside.
pub fn history_files(path: &std::path::Path) -> Vec<(u32, std::path::PathBuf)> {
    let stem = model_stem(path);
    let dir = path.parent().filter(|d| !d.as_os_str().is_empty()).unwrap_or(std::path::Path::new("."));
    let mut out = Vec::new();
    if let Ok(rd) = std::fs::read_dir(dir) {
        for e in rd.flatten() {
            let p = e.path();
            if p.extension().is_some_and(|x| x == "toml") && model_stem(&p) == stem {
                if let Ok(m) = Model::read(&p) {
                    out.push((m.version, p));
                }
            }
        }
    }
    out.sort();
    out
}

/// Held-out RMS per FOG of several models on one session, in as few passes as there are
/// distinct (T_ref, G window) among them.
pub fn held_out_many<'a>(
    models: &[Model],
    source: impl Into<Source<'a>>,
    n_blocks: usize,
    progress: Option<&ProgressBar>,
) -> LabResult<Vec<Vec<f64>>> {
    let source = source.into();
    let mut out: Vec<Option<Vec<f64>>> = vec![None; models.len()];
    for i in 0..models.len() {
        if out[i].is_some() {
            continue;
        }
        let same: Vec<usize> = (i..models.len())
            .filter(|&j| models[j].t_ref_degc == models[i].t_ref_degc && models[j].g_window_s == models[i].g_window_s)
            .collect();
        let kinds: Vec<Kind> = same.iter().flat_map(|&j| models[j].kinds()).collect();
        let d = digest(source, &spec_for(&models[i], &kinds, n_blocks), progress)?;
        for j in same {
            out[j] = Some(held_out_rms(&models[j].kinds(), &d)?);
        }
    }
    Ok(out.into_iter().map(|v| v.unwrap_or_default()).collect())
}

/// A term the session cannot feed, as [`super::stream::Basis::functionals`] says why.
fn unfed(why: String) -> LabError {
    LabError::model(ModelErrorKind::Unfed, why)
}
