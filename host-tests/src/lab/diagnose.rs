//! Which physical effect is the model missing?
//!
//! Candidates: every catalog term not in the model whose inputs the session has; a
//! sinusoid at the strongest spectral line of the training residual; and each user column
//! no term uses (a correlation with an unused column). Each candidate gets, per FOG:
//!
//! - a nested-model F-test on the **held-out** blocks only: the base model and the base model
//!   plus the candidate are both fitted on the test blocks, F = ((SSE₀ − SSE₁)/q) / (SSE₁/(n − p₁)),
//!   p-value from statrs' Fisher–Snedecor distribution. Anything chosen from data (the
//!   spectral line's frequency, which columns to try) is chosen on the training blocks, so the
//!   test data have not been used to shape the candidate and the p-value is exact for white
//!   Gaussian noise;
//! - the predicted drop: held-out RMS of the base model and of base + candidate, both fitted
//!   on the training blocks and evaluated on the test blocks (what `add` will report).
//!
//! A candidate's p-value is the smallest over FOGs times the number of FOGs (Bonferroni);
//! across candidates the Benjamini–Hochberg procedure controls the false discovery rate at
//! the chosen level (default 1 %). Ranking: p-value, then predicted drop.
//!
//! Also, when the session has FOG temperatures with both T and G = dT/dt varying, the
//! paper's two-factor analysis of variance (T × G, its Tables 1–2) on the current model's
//! residual, with T and G each cut into three levels at their tertiles.

use statrs::distribution::{ContinuousCDF, FisherSnedecor};

use super::fit::{design, lstsq, residual, rms, split, Split};
use super::model::{prepare, regressors, Catalog, Kind, Model, Prepared};
use super::session::Session;
use super::LabResult;

/// Options of a diagnosis.
#[derive(Debug, Clone, Copy)]
pub struct Options {
    /// Number of time blocks (even train, odd test).
    pub n_blocks: usize,
    /// False-discovery-rate level (Benjamini–Hochberg), e.g. 0.01.
    pub fdr_level: f64,
    /// At most this many unused columns are tried (those most correlated with the training residual).
    pub max_columns: usize,
    /// At most this many frequencies in the spectral search.
    pub max_frequencies: usize,
}

impl Default for Options {
    fn default() -> Self {
        Options { n_blocks: super::fit::DEFAULT_BLOCKS, fdr_level: 0.01, max_columns: 10, max_frequencies: 1000 }
    }
}

/// One FOG's test of one candidate.
#[derive(Debug, Clone)]
pub struct FogTest {
    /// F statistic on the test blocks.
    pub f: f64,
    /// Numerator degrees of freedom (identified candidate regressors).
    pub df1: usize,
    /// Denominator degrees of freedom.
    pub df2: usize,
    /// p-value.
    pub p: f64,
    /// Held-out RMS without / with the candidate, rad/s.
    pub before_rad_s: f64,
    /// Held-out RMS with the candidate, rad/s.
    pub after_rad_s: f64,
}

/// A candidate term and its evidence.
#[derive(Debug, Clone)]
pub struct Candidate {
    /// The term.
    pub kind: Kind,
    /// Where it came from.
    pub origin: String,
    /// Per FOG (None where the session cannot identify it for that FOG).
    pub per_fog: Vec<Option<FogTest>>,
    /// Bonferroni-combined p-value over FOGs.
    pub p_value: f64,
    /// Pooled held-out RMS before / after, rad/s.
    pub before_rad_s: f64,
    /// Pooled held-out RMS after adding it, rad/s.
    pub after_rad_s: f64,
    /// Passes Benjamini–Hochberg at the level.
    pub significant: bool,
}

/// The paper's two-factor ANOVA for one FOG (Table 2's ratios).
#[derive(Debug, Clone)]
pub struct Anova {
    /// FOG number.
    pub fog: usize,
    /// Cells (T level × G level) with data.
    pub cells: usize,
    /// (ratio, ν1, ν2, p) for T, G, T×G.
    pub f_t: (f64, usize, usize, f64),
    /// G factor.
    pub f_g: (f64, usize, usize, f64),
    /// Interaction.
    pub f_tg: (f64, usize, usize, f64),
    /// T level edges (tertiles), °C.
    pub t_edges_degc: [f64; 2],
    /// G level edges (±a tenth of the 95th percentile of |G|), °C/s.
    pub g_edges_degc_s: [f64; 2],
}

/// A diagnosis.
#[derive(Debug, Clone)]
pub struct Diagnosis {
    /// Candidates, best first.
    pub candidates: Vec<Candidate>,
    /// Candidates that could not be tested, with the reason.
    pub skipped: Vec<(String, String)>,
    /// Two-factor ANOVA per FOG with temperature.
    pub anova: Vec<Anova>,
    /// Held-out RMS of the model as it is, per FOG, rad/s.
    pub base_rms_rad_s: Vec<f64>,
    /// Level used.
    pub fdr_level: f64,
    /// Training and test sample counts.
    pub n_train: usize,
    /// Test samples.
    pub n_test: usize,
}

impl Diagnosis {
    /// The significant candidates, best first.
    pub fn significant(&self) -> impl Iterator<Item = &Candidate> {
        self.candidates.iter().filter(|c| c.significant)
    }
}

fn f_sf(f: f64, d1: usize, d2: usize) -> f64 {
    if !(f.is_finite()) || d1 == 0 || d2 == 0 {
        return if f.is_infinite() { 0.0 } else { 1.0 };
    }
    match FisherSnedecor::new(d1 as f64, d2 as f64) {
        Ok(dist) => dist.sf(f.max(0.0)),
        Err(_) => 1.0,
    }
}

/// F quantile (critical value) at upper-tail probability `q`.
pub fn f_critical(q: f64, d1: usize, d2: usize) -> f64 {
    FisherSnedecor::new(d1 as f64, d2 as f64).map_or(f64::NAN, |d| d.inverse_cdf(1.0 - q))
}

/// Tests one candidate on one FOG.
fn test_fog(base: &[Vec<f64>], cand: Vec<Vec<f64>>, y: &[f64], sp: &Split, base_ho: f64) -> Option<FogTest> {
    let mut cols: Vec<Vec<f64>> = base.to_vec();
    cols.extend(cand);
    let ls0 = lstsq(base, y, &sp.test);
    let ls1 = lstsq(&cols, y, &sp.test);
    let q = ls1.p.checked_sub(ls0.p).filter(|&q| q > 0)?;
    let df2 = ls1.n.checked_sub(ls1.p).filter(|&d| d > 0)?;
    let f = ((ls0.sse - ls1.sse) / q as f64) / (ls1.sse / df2 as f64);
    let tr = lstsq(&cols, y, &sp.train);
    let d = super::fit::Design { cols, owner: Vec::new() };
    let after = rms(&residual(&d, y, &tr.coef), &sp.test);
    Some(FogTest { f, df1: q, df2, p: f_sf(f, q, df2), before_rad_s: base_ho, after_rad_s: after })
}

/// Strongest sinusoid in the training residuals (pooled over FOGs): frequency, Hz.
fn spectral_peak(p: &Prepared, train_res: &[Vec<f64>], sp: &Split, max_f: usize, exclude: &[f64]) -> Option<f64> {
    let t = p.session.t_s();
    let stride = sp.train.len().div_ceil(20_000).max(1);
    let rows: Vec<usize> = sp.train.iter().copied().step_by(stride).collect();
    if rows.len() < 8 {
        return None;
    }
    let span = t[t.len() - 1] - t[0];
    let f_min = 1.5 / span;
    let f_max = 0.5 / (p.session.median_dt_s() * stride as f64);
    if f_max <= f_min {
        return None;
    }
    let nf = (((f_max - f_min) * 4.0 * span).ceil() as usize).clamp(2, max_f);
    let mut best = (0.0, None);
    for k in 0..nf {
        let f = f_min + (f_max - f_min) * k as f64 / (nf - 1) as f64;
        if exclude.iter().any(|&e| (f - e).abs() < 1.0 / span) {
            continue;
        }
        let w = 2.0 * std::f64::consts::PI * f;
        let sc: Vec<(f64, f64)> = rows.iter().map(|&j| (w * t[j]).sin_cos()).collect();
        let mut power = 0.0;
        for res in train_res {
            // Regress the residual on (1, sin, cos): the drop in its sum of squares.
            let mut a = nalgebra::Matrix3::<f64>::zeros();
            let mut b = nalgebra::Vector3::<f64>::zeros();
            for (&j, &(s, c)) in rows.iter().zip(&sc) {
                let x = nalgebra::Vector3::new(1.0, s, c);
                a += x * x.transpose();
                b += x * res[j];
            }
            if let Some(sol) = a.lu().solve(&b) {
                let mean = b[0] / rows.len() as f64;
                power += sol.dot(&b) - mean * b[0];
            }
        }
        if power > best.0 {
            best = (power, Some(f));
        }
    }
    best.1
}

/// Diagnoses `model` on `session`.
pub fn diagnose(model: &Model, session: &Session, opt: &Options) -> LabResult<Diagnosis> {
    let p = prepare(session, model);
    let kinds = model.kinds();
    let n_fog = session.fogs.len();
    let sp = split(session.len(), opt.n_blocks);
    let mut bases = Vec::new();
    let mut train_res = Vec::new();
    let mut base_ho = Vec::new();
    for fog in 0..n_fog {
        let d = design(&kinds, &p, fog)?;
        let tr = lstsq(&d.cols, &p.y[fog], &sp.train);
        let res = residual(&d, &p.y[fog], &tr.coef);
        base_ho.push(rms(&res, &sp.test));
        train_res.push(res);
        bases.push(d.cols);
    }

    // Candidate list.
    let mut list: Vec<(Kind, String)> = Vec::new();
    let mut skipped = Vec::new();
    for c in Catalog::ALL {
        if !kinds.contains(&Kind::Catalog(c)) {
            list.push((Kind::Catalog(c), "catalog".into()));
        }
    }
    let existing_f: Vec<f64> =
        kinds.iter().filter_map(|k| if let Kind::Sinusoid(f) = k { Some(*f) } else { None }).collect();
    if let Some(f) = spectral_peak(&p, &train_res, &sp, opt.max_frequencies, &existing_f) {
        list.push((
            Kind::Sinusoid(f),
            format!("spectral line of the training residual, period {:.4} h", 1.0 / f / 3600.0),
        ));
    }
    let used_vars: Vec<String> = kinds
        .iter()
        .filter_map(|k| if let Kind::Expr(e) = k { Some(e.clone()) } else { None })
        .flat_map(|e| {
            use exmex::Express;
            exmex::parse::<f64>(&e).map(|x| x.var_names().to_vec()).unwrap_or_default()
        })
        .collect();
    let mut cols: Vec<(f64, String)> = session
        .extra_columns()
        .into_iter()
        .filter(|c| !used_vars.iter().any(|u| u == c))
        .map(|c| {
            let x = session.column(c).unwrap_or(&[]);
            let r: f64 = train_res.iter().map(|res| correlation(x, res, &sp.train).abs()).fold(0.0, f64::max);
            (r, c.to_string())
        })
        .collect();
    cols.sort_by(|a, b| b.0.total_cmp(&a.0));
    for (r, c) in cols.into_iter().take(opt.max_columns) {
        list.push((Kind::Expr(c), format!("unused column, |r| = {r:.2} with the training residual")));
    }

    // Tests.
    let mut cands = Vec::new();
    for (kind, origin) in list {
        let mut per_fog = Vec::new();
        let mut why = None;
        for fog in 0..n_fog {
            match regressors(&kind, &p, fog) {
                Ok(x) => per_fog.push(test_fog(&bases[fog], x, &p.y[fog], &sp, base_ho[fog])),
                Err(e) => {
                    why = Some(e.to_string());
                    per_fog.push(None);
                }
            }
        }
        let tested: Vec<&FogTest> = per_fog.iter().flatten().collect();
        if tested.is_empty() {
            skipped.push((kind.label(), why.unwrap_or_else(|| "not identifiable in this session".into())));
            continue;
        }
        let pmin = tested.iter().map(|t| t.p).fold(1.0, f64::min);
        let n_tested = tested.len() as f64;
        let after: Vec<f64> =
            per_fog.iter().enumerate().map(|(i, t)| t.as_ref().map_or(base_ho[i], |t| t.after_rad_s)).collect();
        cands.push(Candidate {
            kind,
            origin,
            per_fog,
            p_value: (pmin * n_tested).min(1.0),
            before_rad_s: super::fit::pooled(&base_ho),
            after_rad_s: super::fit::pooled(&after),
            significant: false,
        });
    }
    cands.sort_by(|a, b| a.p_value.total_cmp(&b.p_value).then(a.after_rad_s.total_cmp(&b.after_rad_s)));
    let pv: Vec<f64> = cands.iter().map(|c| c.p_value).collect();
    let k = benjamini_hochberg(&pv, opt.fdr_level);
    for c in cands.iter_mut().take(k) {
        c.significant = true;
    }
    let anova = (0..n_fog).filter_map(|fog| anova_fog(&p, &kinds, fog)).collect();
    Ok(Diagnosis {
        candidates: cands,
        skipped,
        anova,
        base_rms_rad_s: base_ho,
        fdr_level: opt.fdr_level,
        n_train: sp.train.len(),
        n_test: sp.test.len(),
    })
}

/// Number of hypotheses rejected by Benjamini–Hochberg at level `q` (p-values sorted ascending).
pub fn benjamini_hochberg(sorted_p: &[f64], q: f64) -> usize {
    let m = sorted_p.len() as f64;
    sorted_p.iter().enumerate().filter(|(i, &p)| p <= (*i as f64 + 1.0) / m * q).map(|(i, _)| i + 1).max().unwrap_or(0)
}

fn correlation(x: &[f64], y: &[f64], rows: &[usize]) -> f64 {
    let n = rows.len() as f64;
    let (mx, my) = (rows.iter().map(|&j| x[j]).sum::<f64>() / n, rows.iter().map(|&j| y[j]).sum::<f64>() / n);
    let (mut sxy, mut sxx, mut syy) = (0.0, 0.0, 0.0);
    for &j in rows {
        let (a, b) = (x[j] - mx, y[j] - my);
        sxy += a * b;
        sxx += a * a;
        syy += b * b;
    }
    if sxx > 0.0 && syy > 0.0 {
        sxy / (sxx * syy).sqrt()
    } else {
        0.0
    }
}

fn tertiles(v: &[f64]) -> [f64; 2] {
    let mut s = v.to_vec();
    s.sort_by(f64::total_cmp);
    [s[s.len() / 3], s[2 * s.len() / 3]]
}

fn level(x: f64, e: &[f64; 2]) -> usize {
    if x < e[0] {
        0
    } else if x < e[1] {
        1
    } else {
        2
    }
}

/// The paper's two-factor ANOVA on the residual of `kinds` fitted on all rows.
///
/// Cell (j, g) holds the residuals with T in level j and G in level g. With cell means Ȳ_jg,
/// level means Ȳ_j, Ȳ'_g and the grand mean Ȳ (the paper's formulas, weighted by the cell
/// counts where the design is unbalanced, which makes the split of the sums of squares
/// approximate): s_ε² within cells (ν_ε = M − n), s_T² and s_G² between levels
/// (ν_T = u₁ − 1, ν_G = u₂ − 1), s_TG² of the interaction (ν_TG = n − u₁ − u₂ + 1), and
/// F_T = s_T²/s_TG², F_G = s_G²/s_TG², F_TG = s_TG²/s_ε² as in the paper.
fn anova_fog(p: &Prepared, kinds: &[Kind], fog: usize) -> Option<Anova> {
    let (dt, g) = (p.dtemp_degc[fog].as_ref()?, p.g_degc_s[fog].as_ref()?);
    let (tmin, tmax) = dt.iter().fold((f64::MAX, f64::MIN), |(a, b), &v| (a.min(v), b.max(v)));
    let gstd = {
        let m = g.iter().sum::<f64>() / g.len() as f64;
        (g.iter().map(|v| (v - m) * (v - m)).sum::<f64>() / g.len() as f64).sqrt()
    };
    if tmax - tmin < 1.0 || gstd < 1e-6 || g.len() < 30 {
        return None;
    }
    let all: Vec<usize> = (0..g.len()).collect();
    let d = design(kinds, p, fog).ok()?;
    let res = residual(&d, &p.y[fog], &lstsq(&d.cols, &p.y[fog], &all).coef);
    // T levels at its tertiles; G levels falling / steady / rising, steady meaning |G| within
    // a tenth of the 95th percentile of |G| (the paper's G levels are set rates and holds).
    let mut ag: Vec<f64> = g.iter().map(|v| v.abs()).collect();
    ag.sort_by(f64::total_cmp);
    let eps = 0.1 * ag[ag.len() * 95 / 100];
    let (te, ge) = (tertiles(dt), [-eps, eps]);
    let mut sum = [[0.0f64; 3]; 3];
    let mut cnt = [[0usize; 3]; 3];
    for j in 0..g.len() {
        let (a, b) = (level(dt[j], &te), level(g[j], &ge));
        sum[a][b] += res[j];
        cnt[a][b] += 1;
    }
    let cells: Vec<(usize, usize)> =
        (0..3).flat_map(|a| (0..3).map(move |b| (a, b))).filter(|&(a, b)| cnt[a][b] >= 2).collect();
    let m_obs: usize = cells.iter().map(|&(a, b)| cnt[a][b]).sum();
    let mean = |a: usize, b: usize| sum[a][b] / cnt[a][b] as f64;
    let grand: f64 = cells.iter().map(|&(a, b)| sum[a][b]).sum::<f64>() / m_obs as f64;
    let row_mean = |a: usize| -> Option<(f64, usize)> {
        let (s, n) = cells.iter().filter(|c| c.0 == a).fold((0.0, 0), |(s, n), &(x, y)| (s + sum[x][y], n + cnt[x][y]));
        (n > 0).then(|| (s / n as f64, n))
    };
    let col_mean = |b: usize| -> Option<(f64, usize)> {
        let (s, n) = cells.iter().filter(|c| c.1 == b).fold((0.0, 0), |(s, n), &(x, y)| (s + sum[x][y], n + cnt[x][y]));
        (n > 0).then(|| (s / n as f64, n))
    };
    let rows: Vec<usize> = (0..3).filter(|&a| row_mean(a).is_some()).collect();
    let colsl: Vec<usize> = (0..3).filter(|&b| col_mean(b).is_some()).collect();
    let (u1, u2, n_cells) = (rows.len(), colsl.len(), cells.len());
    if u1 < 2 || u2 < 2 || n_cells < u1 + u2 {
        return None;
    }
    let mut ss_e = 0.0;
    for j in 0..g.len() {
        let (a, b) = (level(dt[j], &te), level(g[j], &ge));
        if cnt[a][b] >= 2 {
            ss_e += (res[j] - mean(a, b)).powi(2);
        }
    }
    let ss_t: f64 = rows.iter().map(|&a| row_mean(a).map_or(0.0, |(m, n)| n as f64 * (m - grand).powi(2))).sum();
    let ss_g: f64 = colsl.iter().map(|&b| col_mean(b).map_or(0.0, |(m, n)| n as f64 * (m - grand).powi(2))).sum();
    let ss_tg: f64 = cells
        .iter()
        .map(|&(a, b)| {
            let (ra, cb) = (row_mean(a).map_or(0.0, |x| x.0), col_mean(b).map_or(0.0, |x| x.0));
            cnt[a][b] as f64 * (mean(a, b) - ra - cb + grand).powi(2)
        })
        .sum();
    let (nu_e, nu_t, nu_g) = (m_obs - n_cells, u1 - 1, u2 - 1);
    let nu_tg = n_cells + 1 - u1 - u2;
    if nu_e == 0 || nu_tg == 0 {
        return None;
    }
    let (s_e, s_t, s_g, s_tg) = (ss_e / nu_e as f64, ss_t / nu_t as f64, ss_g / nu_g as f64, ss_tg / nu_tg as f64);
    let ft = s_t / s_tg;
    let fg = s_g / s_tg;
    let ftg = s_tg / s_e;
    Some(Anova {
        fog,
        cells: n_cells,
        f_t: (ft, nu_t, nu_tg, f_sf(ft, nu_t, nu_tg)),
        f_g: (fg, nu_g, nu_tg, f_sf(fg, nu_g, nu_tg)),
        f_tg: (ftg, nu_tg, nu_e, f_sf(ftg, nu_tg, nu_e)),
        t_edges_degc: [te[0] + p.t_ref_degc, te[1] + p.t_ref_degc],
        g_edges_degc_s: ge,
    })
}
