//! Least squares, linear in the coefficients, per FOG; held-out time blocks.
//!
//! Each fit scales the regressor columns to unit norm and factors them with nalgebra's
//! Householder QR. A regressor whose part not explained by the earlier columns is below
//! [`REL_TOL`] of its norm cannot be identified by the session (a constant field component
//! next to the bias, the scale factor in a static test): it is dropped, its coefficient is
//! left at zero and the fit says so. Terms earlier in the model keep priority.
//!
//! Held-out blocks: the session is cut into `n_blocks` consecutive blocks of equal sample
//! count; even blocks (0, 2, …) train, odd blocks test. "Held-out RMS" is the residual RMS
//! on the test blocks of a model fitted on the training blocks only.

use nalgebra::{DMatrix, DVector};

use super::model::{prepare, regressors, Kind, Model, Prepared};
use super::session::Session;
use super::{LabError, LabResult};

/// Relative size below which a regressor is not identifiable (see the module text).
pub const REL_TOL: f64 = 1e-6;

/// Default number of time blocks.
pub const DEFAULT_BLOCKS: usize = 10;

/// A least-squares solution over a set of rows.
#[derive(Debug, Clone)]
pub struct LsFit {
    /// Coefficient per column (zero where not identified).
    pub coef: Vec<f64>,
    /// Whether each column was identified.
    pub identified: Vec<bool>,
    /// Sum of squared residuals over the rows.
    pub sse: f64,
    /// Number of rows.
    pub n: usize,
    /// Number of identified columns.
    pub p: usize,
}

/// Least squares of `y` on `cols` over `rows`.
pub fn lstsq(cols: &[Vec<f64>], y: &[f64], rows: &[usize]) -> LsFit {
    let n = rows.len();
    let mut keep: Vec<usize> = Vec::new();
    let mut identified = vec![false; cols.len()];
    let mut scale = vec![0.0; cols.len()];
    for (k, c) in cols.iter().enumerate() {
        let norm = rows.iter().map(|&j| c[j] * c[j]).sum::<f64>().sqrt();
        if norm > 0.0 && norm.is_finite() {
            scale[k] = norm;
            keep.push(k);
        }
    }
    let yv = DVector::from_iterator(n, rows.iter().map(|&j| y[j]));
    loop {
        if keep.is_empty() || keep.len() > n {
            // Nothing to fit (or more columns than rows: keep the first n).
            keep.truncate(n);
            if keep.is_empty() {
                let sse = yv.norm_squared();
                return LsFit { coef: vec![0.0; cols.len()], identified, sse, n, p: 0 };
            }
        }
        let x = DMatrix::from_fn(n, keep.len(), |r, c| cols[keep[c]][rows[r]] / scale[keep[c]]);
        let qr = x.clone().qr();
        let rmat = qr.r();
        if let Some(bad) = (0..keep.len()).find(|&c| rmat[(c, c)].abs() < REL_TOL) {
            keep.remove(bad);
            continue;
        }
        let qty = qr.q().transpose() * &yv;
        let b = rmat.solve_upper_triangular(&qty).unwrap_or_else(|| DVector::zeros(keep.len()));
        let res = &yv - &x * &b;
        let mut coef = vec![0.0; cols.len()];
        for (c, &k) in keep.iter().enumerate() {
            coef[k] = b[c] / scale[k];
            identified[k] = true;
        }
        return LsFit { coef, identified, sse: res.norm_squared(), n, p: keep.len() };
    }
}

/// The regressor columns of a model's terms for one FOG, and which term owns each column.
#[derive(Debug, Clone)]
pub struct Design {
    /// Columns.
    pub cols: Vec<Vec<f64>>,
    /// (term index, regressor index within the term) per column.
    pub owner: Vec<(usize, usize)>,
}

/// Builds the design of `kinds` for FOG `fog`.
pub fn design(kinds: &[Kind], p: &Prepared, fog: usize) -> LabResult<Design> {
    let mut cols = Vec::new();
    let mut owner = Vec::new();
    for (t, k) in kinds.iter().enumerate() {
        for (m, c) in regressors(k, p, fog)?.into_iter().enumerate() {
            cols.push(c);
            owner.push((t, m));
        }
    }
    Ok(Design { cols, owner })
}

/// Held-out split of `n` samples into `n_blocks` consecutive blocks.
#[derive(Debug, Clone)]
pub struct Split {
    /// Rows of the even blocks.
    pub train: Vec<usize>,
    /// Rows of the odd blocks.
    pub test: Vec<usize>,
}

/// Even blocks train, odd blocks test.
pub fn split(n: usize, n_blocks: usize) -> Split {
    let nb = n_blocks.max(2);
    let (mut train, mut test) = (Vec::new(), Vec::new());
    for j in 0..n {
        if (j * nb / n).is_multiple_of(2) {
            train.push(j);
        } else {
            test.push(j);
        }
    }
    Split { train, test }
}

/// Residual `y − X c` on every row.
pub fn residual(d: &Design, y: &[f64], coef: &[f64]) -> Vec<f64> {
    (0..y.len()).map(|j| y[j] - d.cols.iter().zip(coef).map(|(c, k)| c[j] * k).sum::<f64>()).collect()
}

/// RMS of `v` over `rows`.
pub fn rms(v: &[f64], rows: &[usize]) -> f64 {
    if rows.is_empty() {
        return 0.0;
    }
    (rows.iter().map(|&j| v[j] * v[j]).sum::<f64>() / rows.len() as f64).sqrt()
}

/// Per-FOG figures of a model on a session.
#[derive(Debug, Clone)]
pub struct FogSummary {
    /// RMS of the error y (no model), rad/s.
    pub rms_error_rad_s: f64,
    /// RMS of the residual, rad/s.
    pub rms_residual_rad_s: f64,
    /// Largest |residual|, rad/s.
    pub max_abs_residual_rad_s: f64,
    /// 1 − Σres²/Σy²: the fraction of the error power the model explains.
    pub explained: f64,
}

/// A model fitted (or evaluated) on a session.
#[derive(Debug, Clone)]
pub struct Fitted {
    /// The model with the coefficients used.
    pub model: Model,
    /// Residual per FOG, every row, rad/s.
    pub residual: Vec<Vec<f64>>,
    /// Figures per FOG.
    pub summary: Vec<FogSummary>,
    /// Regressors the session could not identify, as "FOGi term.name".
    pub not_identified: Vec<String>,
}

fn summarize(y: &[f64], res: &[f64]) -> FogSummary {
    let all: Vec<usize> = (0..y.len()).collect();
    let (e, r) = (rms(y, &all), rms(res, &all));
    FogSummary {
        rms_error_rad_s: e,
        rms_residual_rad_s: r,
        max_abs_residual_rad_s: res.iter().fold(0.0, |m, v| f64::max(m, v.abs())),
        explained: if e > 0.0 { 1.0 - (r * r) / (e * e) } else { 0.0 },
    }
}

/// Fits every term of `model` on all rows of `session`, FOG by FOG.
pub fn fit_model(model: &Model, session: &Session) -> LabResult<Fitted> {
    let p = prepare(session, model);
    let kinds = model.kinds();
    let all: Vec<usize> = (0..session.len()).collect();
    let mut out = model.clone();
    for t in out.terms.iter_mut() {
        t.coef = vec![Vec::new(); session.fogs.len()];
    }
    let (mut residuals, mut summary, mut missing) = (Vec::new(), Vec::new(), Vec::new());
    for fog in 0..session.fogs.len() {
        let d = design(&kinds, &p, fog)?;
        let ls = lstsq(&d.cols, &p.y[fog], &all);
        for (c, &(t, m)) in d.owner.iter().enumerate() {
            let slot = &mut out.terms[t].coef[fog];
            slot.resize(m + 1, 0.0);
            slot[m] = ls.coef[c];
            if !ls.identified[c] {
                let lab = kinds[t].regressor_labels(fog);
                missing.push(format!("FOG{fog} {}.{}", kinds[t].label(), lab.get(m).map_or("?", |l| l.0.as_str())));
            }
        }
        let res = residual(&d, &p.y[fog], &ls.coef);
        summary.push(summarize(&p.y[fog], &res));
        residuals.push(res);
    }
    Ok(Fitted { model: out, residual: residuals, summary, not_identified: missing })
}

/// Evaluates `model` with its own coefficients (no fit).
pub fn evaluate_model(model: &Model, session: &Session) -> LabResult<Fitted> {
    let p = prepare(session, model);
    let kinds = model.kinds();
    let (mut residuals, mut summary) = (Vec::new(), Vec::new());
    for fog in 0..session.fogs.len() {
        let d = design(&kinds, &p, fog)?;
        let coef: Vec<f64> = d
            .owner
            .iter()
            .map(|&(t, m)| model.terms[t].coef.get(fog).and_then(|c| c.get(m)).copied().unwrap_or(0.0))
            .collect();
        let res = residual(&d, &p.y[fog], &coef);
        summary.push(summarize(&p.y[fog], &res));
        residuals.push(res);
    }
    Ok(Fitted { model: model.clone(), residual: residuals, summary, not_identified: Vec::new() })
}

/// Held-out residual RMS per FOG, rad/s: fit `kinds` on the training blocks, RMS on the
/// test blocks.
pub fn held_out_rms(kinds: &[Kind], p: &Prepared, sp: &Split) -> LabResult<Vec<f64>> {
    if sp.test.is_empty() || sp.train.is_empty() {
        return Err(LabError::Numeric(format!("{}: too few samples for held-out blocks", p.session.file)));
    }
    (0..p.y.len())
        .map(|fog| {
            let d = design(kinds, p, fog)?;
            let ls = lstsq(&d.cols, &p.y[fog], &sp.train);
            Ok(rms(&residual(&d, &p.y[fog], &ls.coef), &sp.test))
        })
        .collect()
}

/// RMS over FOGs of per-FOG RMS values (pooled, equal sample counts).
pub fn pooled(v: &[f64]) -> f64 {
    (v.iter().map(|x| x * x).sum::<f64>() / v.len().max(1) as f64).sqrt()
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
}

/// Adds `kind` to `model`, refits on `session` and measures the held-out RMS before and
/// after (same blocks as [`super::diagnose`]). The result has version + 1.
pub fn add_term(model: &Model, kind: &Kind, session: &Session, n_blocks: usize) -> LabResult<AddOutcome> {
    let kinds = model.kinds();
    if kinds.contains(kind) {
        return Err(LabError::Model(format!("the model already has `{}`", kind.label())));
    }
    let mut next = model.clone();
    next.version = model.version + 1;
    next.terms.push(kind.spec());
    next.note = format!("v{}: added {}", next.version, kind.label());
    let p = prepare(session, model);
    let sp = split(session.len(), n_blocks);
    let before = held_out_rms(&kinds, &p, &sp)?;
    let after = held_out_rms(&next.kinds(), &p, &sp)?;
    let fitted = fit_model(&next, session)?;
    let mut model = fitted.model;
    model.fit = Some(super::model::FitRecord {
        session: session.file.clone(),
        rows: session.len(),
        held_out_rms_deg_h: after.iter().map(|v| v * crate::DEG_H_PER_RAD_S).collect(),
        not_identified: fitted.not_identified.clone(),
    });
    Ok(AddOutcome { model, before_rad_s: before, after_rad_s: after, not_identified: fitted.not_identified })
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
