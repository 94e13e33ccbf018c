//! Which physical effect is the model missing?
//!
//! Candidates: every catalog term not in the model whose inputs the session has; a
//! sinusoid at each line of the training residual ([`super::spectral`]); and each user column
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
//! residual, with T in three levels at its tertiles and G falling / steady / rising.
//!
//! Everything comes from one pass over the session ([`super::stream::digest`]): the F-tests,
//! predicted drops and column correlations from the per-block sums, exactly. What needs
//! rows (the spectral search, the spectral candidate's own test, the ANOVA) uses the rows
//! the pass kept: every row of a session up to [`super::stream::DEFAULT_KEEP`] samples; of a
//! longer one, the spectral search and the line's test use the means of runs of consecutive
//! rows (every row counts: a line slower than a run loses nothing, and the origin says so),
//! the ANOVA a systematic sample.

use indicatif::ProgressBar;
use statrs::distribution::{ContinuousCDF, FisherSnedecor};

pub use super::detectable::f_critical;
use super::detectable::{lambda_required_f, min_coef, sinusoid_curve, Detectable, LineDesign, TermLimit, POWER};
use super::fit::{design, held_out, kept_residual, pooled, spec_for, Design};
use super::lsq::{design_gram, lstsq_gram, residual_functional, Gram};
use super::model::{Catalog, Kind, Model};
use super::noise::{held_out_gain, whitened, Binned, Cross, NoiseModel};
use super::spectral::{search_refit, searchable_range, time_spread_s, Line, Record};
use super::stream::{digest, trains, Bins, Digest, Source, Sums};
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
        Options { n_blocks: super::fit::DEFAULT_BLOCKS, fdr_level: 0.01, max_columns: 10, max_frequencies: 15_000 }
    }
}

/// One FOG's test of one candidate.
#[derive(Debug, Clone)]
pub struct FogTest {
    /// F statistic on the test blocks, of the GLS fits under the noise model.
    pub f: f64,
    /// Numerator degrees of freedom (identified candidate regressors).
    pub df1: usize,
    /// Denominator degrees of freedom.
    pub df2: usize,
    /// p-value of the candidate on this FOG: the larger of the F-test's and the held-out
    /// improvement's (both must reject).
    pub p: f64,
    /// p-value of the GLS F-test alone.
    pub p_f: f64,
    /// p-value of the held-out direction test alone (one-sided).
    pub p_dir: f64,
    /// Held-out improvement: the drop of the mean-square residual per test row, (rad/s)²,
    /// with its 1σ under the noise model; p-value of "no improvement" (one-sided).
    pub gain_rad2_s2: (f64, f64, f64),
    /// Held-out RMS without / with the candidate, rad/s.
    pub before_rad_s: f64,
    /// Held-out RMS with the candidate, rad/s.
    pub after_rad_s: f64,
    /// Information of the candidate's regressors on the test blocks under the noise model
    /// (whitened, beside the base model): q × q, row-major, in 1/(coefficient unit)².
    pub info: Vec<f64>,
    /// GLS estimate of the candidate's coefficients on the test blocks (the F-test's fit),
    /// SI, in the order of its regressors.
    pub coef: Vec<f64>,
    /// The F's denominator: the whitened residual's mean square of the fit with the
    /// candidate, SSE₁ / df2 (1 in expectation when the noise model is right).
    pub mse: f64,
    /// Test rows.
    pub n_test: usize,
}

impl FogTest {
    /// The systematic part the candidate removes on the test blocks, √(before² − after²),
    /// rad/s (0 when it removes nothing), and that figure's 1σ interval ends.
    pub fn removed_rad_s(&self) -> (f64, f64, f64) {
        let (g, sd, _) = self.gain_rad2_s2;
        let r = |x: f64| x.max(0.0).sqrt();
        (r(g), r(g - sd), r(g + sd))
    }
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
    /// FOGs the session cannot test it on, each with the terms it is mixed with there and
    /// the experiment that separates them.
    pub untested: Vec<(usize, String)>,
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
    /// What the figures do not say about the session (gaps in time).
    pub notes: Vec<String>,
    /// What the session could have shown: each candidate's minimum detectable effect.
    pub detectable: Detectable,
}

impl Candidate {
    /// The systematic part the candidate removes on the test blocks, pooled over FOGs,
    /// √(before² − after²) of the mean squares, rad/s, with the ends of its 1σ interval
    /// under the noise model.
    pub fn removed_rad_s(&self) -> (f64, f64, f64) {
        let n = self.per_fog.len().max(1) as f64;
        let g = self.per_fog.iter().flatten().map(|t| t.gain_rad2_s2.0).sum::<f64>() / n;
        let sd = self.per_fog.iter().flatten().map(|t| t.gain_rad2_s2.1.powi(2)).sum::<f64>().sqrt() / n;
        let r = |x: f64| x.max(0.0).sqrt();
        (r(g), r(g - sd), r(g + sd))
    }
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

/// The paper's ANOVA beside the main test, per FOG: for G (F_G against the candidate
/// `temp_rate`) and T (F_T against `thermal_t1`, or the first thermal term the model lacks),
/// each with its degrees of freedom and p-value, and a one-line reason where one is
/// significant at 5 % and the other not.
pub fn anova_beside_main(d: &Diagnosis) -> Vec<String> {
    let mut out = Vec::new();
    let find = |names: &[&'static str], fog: usize| -> Option<(&'static str, FogTest)> {
        names.iter().find_map(|&n| {
            d.candidates.iter().find(|c| c.kind.label() == n).and_then(|c| c.per_fog.get(fog)?.clone().map(|t| (n, t)))
        })
    };
    for a in &d.anova {
        for (factor, f, names) in
            [("G", a.f_g, &["temp_rate"][..]), ("T", a.f_t, &["thermal_t1", "thermal_t2", "thermal_t3"][..])]
        {
            let Some((name, t)) = find(names, a.fog) else { continue };
            let mut line = format!(
                "FOG{} {factor}: ANOVA F = {:.2} (ν {}, {}) p {:.2e} | main test {name}: F = {:.2} (ν {}, {}) p {:.2e}",
                a.fog, f.0, f.1, f.2, f.3, t.f, t.df1, t.df2, t.p
            );
            let (anova_sig, main_sig) = (f.3 < 0.05, t.p < 0.05);
            if anova_sig != main_sig {
                line.push_str(if main_sig {
                    " -- disagree: the ANOVA tests the factor against the T x G interaction mean square, \
                       with few degrees of freedom (the paper's design), so it has little power; the main test \
                       uses the residual under the noise model"
                } else {
                    " -- disagree: the ANOVA takes residual samples as independent and the levels as categories; \
                     under the fitted noise model the slow bias wander explains the level differences"
                });
            }
            out.push(line);
        }
    }
    out
}

/// What the tests of one FOG need: the binned sums of its rows.
struct NoiseCtx<'a> {
    bd: &'a Binned<'a>,
}

impl NoiseCtx<'_> {
    /// The noise model of the cross-fitted residual of `cols` (y last, [`Cross`]), and the GLS
    /// sums under it. The fit starts from the even split, not from the base model's noise
    /// model: that one is fitted on the residual without the candidate, which holds the effect
    /// if there is one, and its Gauss–Markov part takes up some of a slow effect; an
    /// iterative fit started there keeps some of it (the information of a column held for
    /// 10–40 min fell by 1.2 % on average, up to 5.6 %). From the even split the noise model
    /// is a function of the cross-fitted residual alone, which is the same with the effect
    /// in the data as without it.
    fn under(&self, s: &Sums, cols: &[Vec<f64>]) -> (NoiseModel, Sums) {
        let nm = NoiseModel::fit(self.bd, &Cross::of(s, cols));
        let ws = whitened(&nm, self.bd);
        (nm, ws)
    }
}

/// Tests one candidate (functionals `cand`) on one FOG against the base design `base` (y
/// last), under the noise model of the cross-fitted residual of base + candidate ([`Cross`]:
/// each half's residual of the fit on the other half, so a real effect left in the residual
/// is not taken for noise, and neither a slow effect nor the wander is fitted away where the
/// noise model looks at it):
///
/// - the GLS F-test on the test blocks (both nested models fitted there);
/// - the held-out direction test ([`direction_p`]): the candidate's prediction fitted on the
///   training blocks, tested as one regressor beside the base model on the test blocks;
/// - the held-out RMS before and after (ordinary fits on the training blocks, what `add`
///   reports) and the drop of the mean square with its 1σ under the noise model
///   ([`held_out_gain`]).
///
/// The candidate's p-value on the FOG is the larger of the two tests' (both must reject),
/// and 1 when its held-out RMS is not lower.
fn test_fog(s: &Sums, base: &Design, cand: &[Vec<f64>], nz: &NoiseCtx) -> Option<FogTest> {
    let cols = base.with(cand);
    let (nm, ws) = nz.under(s, &cols);
    let ws = &ws;
    let ls0 = lstsq_gram(&design_gram(&ws.test, &base.cols), ws.test.n);
    let ls1 = lstsq_gram(&design_gram(&ws.test, &cols), ws.test.n);
    let q = ls1.p.checked_sub(ls0.p).filter(|&q| q > 0)?;
    let df2 = ls1.n.checked_sub(ls1.p).filter(|&d| d > 0)?;
    let f = ((ls0.sse - ls1.sse).max(0.0) / q as f64) / (ls1.sse / df2 as f64);
    let p_f = f_sf(f, q, df2);
    let p_d = direction_p(ws, base, cand, &cols, ls0.sse);
    let (before, tr0) = held_out(s, &base.cols);
    let (after, tr1) = held_out(s, &cols);
    let l0 = residual_functional(&base.cols, &tr0.coef);
    let l1 = residual_functional(&cols, &tr1.coef);
    let gain = held_out_gain(&nm, nz.bd, &l0, &l1);
    let (g, sd) = gain.per_row();
    let p = if after < before { p_f.max(p_d) } else { 1.0 };
    let info = information(&ws.test, base, cand);
    let k = base.k();
    let coef = ls1.coef[k..k + cand.len()].to_vec();
    Some(FogTest {
        f,
        df1: q,
        df2,
        p,
        p_f,
        p_dir: p_d,
        gain_rad2_s2: (g, sd, gain.p()),
        before_rad_s: before,
        after_rad_s: after,
        info,
        coef,
        mse: ls1.sse / df2 as f64,
        n_test: s.test.n,
    })
}

/// The held-out direction test: the candidate's prediction fitted by GLS on the training
/// blocks, d = Σ ĉⱼ xⱼ, is one regressor on the test blocks beside the base model (GLS); the
/// one-sided p-value of its coefficient being ≤ 0 (the test residual does not move the way
/// the training fit predicts). Under the noise model it is exact given the training blocks,
/// and for a one-regressor candidate it has the power of the F-test (half its p-value when
/// the signs agree).
fn direction_p(ws: &Sums, base: &Design, cand: &[Vec<f64>], cols: &[Vec<f64>], sse0: f64) -> f64 {
    let k = base.k();
    let tr = lstsq_gram(&design_gram(&ws.train, cols), ws.train.n);
    let mut dir = vec![0.0; cols[0].len()];
    for (j, x) in cand.iter().enumerate() {
        let c = tr.coef[k + j];
        dir.iter_mut().zip(x).for_each(|(a, b)| *a += c * b);
    }
    let ls = lstsq_gram(&design_gram(&ws.test, &base.with(&[dir])), ws.test.n);
    let Some(df2) = ls.n.checked_sub(ls.p).filter(|&d| d > 0) else { return 1.0 };
    if !ls.identified[k] {
        return 1.0;
    }
    let fd = (sse0 - ls.sse).max(0.0) / (ls.sse / df2 as f64);
    let two_sided = f_sf(fd, 1, df2);
    if ls.coef[k] > 0.0 {
        0.5 * two_sided
    } else {
        1.0 - 0.5 * two_sided
    }
}

/// The information of the candidate's regressors on the test blocks beside the base model,
/// in the whitened metric: Xcᵀ (I − H₀) Xc (q × q, row-major), by polarisation of the
/// residual sums of squares of each regressor (and each pair's sum) on the base columns.
fn information(g: &Gram, base: &Design, cand: &[Vec<f64>]) -> Vec<f64> {
    let q = cand.len();
    let k = base.k();
    let resid = |x: &[f64]| -> f64 {
        let mut cols = base.cols[..k].to_vec();
        cols.push(x.to_vec());
        lstsq_gram(&design_gram(g, &cols), g.n).sse
    };
    let diag: Vec<f64> = cand.iter().map(|x| resid(x)).collect();
    let mut out = vec![0.0; q * q];
    for a in 0..q {
        out[a * q + a] = diag[a];
        for b in a + 1..q {
            let sum: Vec<f64> = cand[a].iter().zip(&cand[b]).map(|(u, v)| u + v).collect();
            let v = 0.5 * (resid(&sum) - diag[a] - diag[b]);
            out[a * q + b] = v;
            out[b * q + a] = v;
        }
    }
    out
}

/// Why a candidate (functionals `x`) cannot be identified next to the base design (`none`:
/// no regressor of it was), or can barely be (a regressor of which less than 5 % of the norm
/// is not explained by the base columns): the base terms its regressors are mixed with
/// (those whose share of the candidate's fit on the base columns is above 5 %), and the
/// experiment that separates them. `None` when it is well identified.
fn confounding(all: &Gram, base: &Design, kinds: &[Kind], x: &[Vec<f64>], cand: &Kind, none: bool) -> Option<String> {
    let k = base.k();
    let mut with: Vec<String> = Vec::new();
    let mut worst = 1.0f64;
    for xc in x {
        let mut cols = base.cols[..k].to_vec();
        cols.push(xc.clone());
        let a = design_gram(all, &cols);
        let fit = lstsq_gram(&a, all.n);
        let norm = a[(k, k)].max(0.0).sqrt();
        worst = worst.min(if norm > 0.0 { fit.sse.sqrt() / norm } else { 0.0 });
        for (c, &(t, _)) in base.owner.iter().enumerate() {
            let share = fit.coef[c].abs() * a[(c, c)].max(0.0).sqrt() / norm.max(f64::MIN_POSITIVE);
            let name = kinds[t].label();
            if share > 0.05 && !with.contains(&name) {
                with.push(name);
            }
        }
    }
    if !none && worst >= 0.05 {
        return None;
    }
    let mixed = if with.is_empty() {
        "it does not vary in this session".to_string()
    } else {
        format!("mixed with {}", with.join(", "))
    };
    let what = if none {
        "not identifiable in this session".to_string()
    } else {
        format!("barely identifiable in this session ({:.1} % of a regressor is its own)", 100.0 * worst)
    };
    Some(format!("{what}: {mixed}; separate with {}", separating_experiment(cand)))
}

/// The experiment that separates a term from those a simple session mixes it with.
pub fn separating_experiment(kind: &Kind) -> &'static str {
    match kind {
        Kind::Catalog(c) => match c {
            Catalog::Magnetic => {
                "a screened turn (the paper's eq. 2: the difference of an unscreened and a screened run removes bias, \
                 scale factor and the Earth-rate leak of misalignment) or a second set of azimuths with another axis up"
            }
            Catalog::ScaleFactor | Catalog::SfAsymmetry | Catalog::SfNonlinearity | Catalog::Misalignment => {
                "a rate table (several rates of both signs about each axis) or turns with each axis up"
            }
            Catalog::ThermalT1 | Catalog::ThermalT2 | Catalog::ThermalT3 => {
                "temperature levels (chamber holds at several T)"
            }
            Catalog::TempRate | Catalog::TTimesG => "temperature ramps at several rates G (the paper's Table 1 levels)",
            Catalog::Aging => "a repeat run on another day, or a longer session",
            Catalog::Bias => "any session",
        },
        Kind::Sinusoid(_) => "a longer session (more periods)",
        Kind::Expr(_) => "a session in which that quantity varies on its own",
    }
}

/// Lines of the training residuals at the kept training rows, at their real times
/// ([`super::spectral::search`]).
fn spectral_lines(d: &Digest, base: &BaseFit, max_f: usize, exclude: &[f64]) -> Vec<Line> {
    let train_res = &base.train_res;
    let (t_s, blocks, _) = d.kept.line_rows();
    let train: Vec<usize> = (0..blocks.len()).filter(|&k| trains(blocks[k])).collect();
    let t: Vec<f64> = train.iter().map(|&k| t_s[k]).collect();
    let block: Vec<usize> = train.iter().map(|&k| blocks[k]).collect();
    let res = train_res.iter().map(|r| train.iter().map(|&k| r[k]).collect()).collect();
    let span_s = d.t_span_s[1] - d.t_span_s[0];
    let rec = Record {
        t_s: &t,
        block: &block,
        res,
        dt_s: d.dt_s * d.kept.stride as f64,
        span_s,
        noise: Some(&base.noise),
        rows_averaged: d.kept.stride.max(1),
    };
    // The noise model of each FOG's residual with a line at f taken out (on the line rows).
    let refit = |f: f64| -> Option<Vec<NoiseModel>> {
        (0..d.basis.n_fog)
            .map(|fog| {
                let m = d.basis.m;
                let (z, s) = kept_with_sinusoid(d, fog, f);
                let b = &base.bases[fog];
                let mut cols: Vec<Vec<f64>> = b
                    .cols
                    .iter()
                    .map(|c| {
                        let mut w = c.clone();
                        w.extend([0.0, 0.0]);
                        w
                    })
                    .collect();
                let y = cols.pop()?;
                for k in [m, m + 1] {
                    let mut w = vec![0.0; m + 2];
                    w[k] = 1.0;
                    cols.push(w);
                }
                cols.push(y);
                let bd = Binned::of_rows(&base.kept_bins, &z, m + 2, d.n_blocks);
                Some(NoiseModel::fit_from(&bd, &Cross::of(&s, &cols), Some(&base.noise[fog])))
            })
            .collect()
    };
    search_refit(&rec, max_f, exclude, Some(&refit))
}

/// Residual y − Σ c x of FOG `fog` at the rows a line is searched on ([`super::stream::Kept::line_rows`]).
fn line_residual(d: &Digest, fog: usize, cols: &[Vec<f64>], coef: &[f64]) -> Vec<f64> {
    let l = residual_functional(cols, coef);
    d.kept.line_rows().2[fog].chunks_exact(d.basis.m).map(|z| z.iter().zip(&l).map(|(a, b)| a * b).sum()).collect()
}

/// The line rows ([`super::stream::Kept::line_rows`]) of FOG `fog` with the basis extended by sin 2πft and cos 2πft (rows × (m + 2)),
/// and their sums.
fn kept_with_sinusoid(d: &Digest, fog: usize, f_hz: f64) -> (Vec<f64>, Sums) {
    let m = d.basis.m;
    let mut s = Sums { all: Gram::new(m + 2), train: Gram::new(m + 2), test: Gram::new(m + 2) };
    let (t_s, blocks, z) = d.kept.line_rows();
    let mut out = Vec::with_capacity(t_s.len() * (m + 2));
    for (k, zk) in z[fog].chunks_exact(m).enumerate() {
        let (sn, cs) = (2.0 * std::f64::consts::PI * f_hz * t_s[k]).sin_cos();
        let at = out.len();
        out.extend_from_slice(zk);
        out.extend([sn, cs]);
        let z = &out[at..];
        let g = if trains(blocks[k]) { &mut s.train } else { &mut s.test };
        for a in 0..m + 2 {
            for b in a..m + 2 {
                g.upper[a * (m + 2) + b] += z[a] * z[b];
            }
        }
        g.n += 1;
    }
    s.all.add(&s.train);
    s.all.add(&s.test);
    (out, s)
}

/// Diagnoses `model` on a session (one pass).
pub fn diagnose<'a>(model: &Model, source: impl Into<Source<'a>>, opt: &Options) -> LabResult<Diagnosis> {
    diagnose_with_progress(model, source, opt, None)
}

/// [`diagnose`] with a progress bar over the bytes of the session file.
pub fn diagnose_with_progress<'a>(
    model: &Model,
    source: impl Into<Source<'a>>,
    opt: &Options,
    progress: Option<&ProgressBar>,
) -> LabResult<Diagnosis> {
    let source = source.into();
    let terms = candidate_terms(&source.header()?);
    let mut spec = spec_for(model, &terms, opt.n_blocks);
    spec.track = None;
    let d = digest(source, &spec, progress)?;
    diagnose_digest(model, &d, opt)
}

/// Every term a diagnosis may test on a session with `header`: the catalog and each user
/// column (the pass that feeds [`diagnose_digest`] needs them all).
pub fn candidate_terms(header: &super::session::Header) -> Vec<Kind> {
    let mut v: Vec<Kind> = Catalog::ALL.iter().map(|c| Kind::Catalog(*c)).collect();
    v.extend(
        header
            .names
            .iter()
            .zip(&header.roles)
            .filter(|(_, r)| **r == super::session::Role::Extra)
            .map(|(n, _)| Kind::Expr(n.clone())),
    );
    v
}

/// Diagnoses `model` on a digest whose pass had slots for every user column: the model
/// fitted per FOG, the candidates tested on the sums (catalog terms, unused columns, the
/// residual's spectral line), then ranked under the false-discovery rate.
pub fn diagnose_digest(model: &Model, d: &Digest, opt: &Options) -> LabResult<Diagnosis> {
    let kinds = model.kinds();
    let n_fog = d.basis.n_fog;
    let base = BaseFit::of(d, &kinds)?;
    let mut ranked = Ranked::default();
    for (kind, origin) in candidate_list(d, &kinds, &base, opt) {
        let mut per_fog = Vec::new();
        let mut why = None;
        let mut untested = Vec::new();
        for fog in 0..n_fog {
            match d.basis.functionals(&kind, fog) {
                Ok(x) => {
                    let x: Vec<Vec<f64>> = x.iter().map(|l| d.shifted(fog, l)).collect();
                    let t = test_fog(&base.sums[fog], &base.bases[fog], &x, &base.ctx(fog));
                    if let Some(c) = confounding(&base.sums[fog].all, &base.bases[fog], &kinds, &x, &kind, t.is_none())
                    {
                        why.get_or_insert_with(|| c.clone());
                        untested.push((fog, c));
                    }
                    per_fog.push(t)
                }
                Err(e) => {
                    why = Some(e);
                    per_fog.push(None);
                }
            }
        }
        ranked.consider(kind, origin, per_fog, why, &base.base_ho);
        if let Some(c) = ranked.cands.last_mut() {
            c.untested = untested;
        }
    }
    // The strongest spectral line of the training residual, tested on the kept rows.
    let existing_f: Vec<f64> =
        kinds.iter().filter_map(|k| if let Kind::Sinusoid(f) = k { Some(*f) } else { None }).collect();
    for line in spectral_lines(d, &base, opt.max_frequencies, &existing_f) {
        let (per_fog, origin) = spectral_line(d, &base, &line);
        ranked.consider(Kind::Sinusoid(line.f_hz), origin, per_fog, None, &base.base_ho);
    }
    let Ranked { mut cands, skipped } = ranked;
    cands.sort_by(|a, b| a.p_value.total_cmp(&b.p_value).then(a.after_rad_s.total_cmp(&b.after_rad_s)));
    let pv: Vec<f64> = cands.iter().map(|c| c.p_value).collect();
    let k = benjamini_hochberg(&pv, opt.fdr_level);
    for c in cands.iter_mut().take(k) {
        c.significant = true;
    }
    let anova = (0..n_fog).filter_map(|fog| anova_fog(d, &base.bases[fog], &base.sums[fog], fog)).collect();
    let (n_train, n_test) = (base.sums[0].train.n, base.sums[0].test.n);
    let detectable = limits(d, &base, &cands, &skipped, opt);
    Ok(Diagnosis {
        detectable,
        candidates: cands,
        skipped,
        anova,
        base_rms_rad_s: base.base_ho,
        fdr_level: opt.fdr_level,
        n_train,
        n_test,
        notes: d.notes(),
    })
}

/// Each candidate's minimum detectable effect on this session and a sinusoid's over the
/// searched periods ([`super::detectable`]).
fn limits(d: &Digest, base: &BaseFit, cands: &[Candidate], skipped: &[(String, String)], opt: &Options) -> Detectable {
    let n_fog = d.basis.n_fog.max(1);
    let alpha = opt.fdr_level / (cands.len().max(1) * n_fog) as f64;
    let mut terms = Vec::new();
    for c in cands.iter().filter(|c| !matches!(c.kind, Kind::Sinusoid(_))) {
        let per_fog = c
            .per_fog
            .iter()
            .map(|t| {
                let t = t.as_ref()?;
                let q = (t.info.len() as f64).sqrt().round() as usize;
                min_coef(&t.info, lambda_required_f(q, t.df2, alpha, POWER))
            })
            .collect();
        let unit = c.kind.eng_units(0).first().copied().unwrap_or(("SI", 1.0));
        terms.push(TermLimit { term: c.kind.label(), unit, per_fog, not_identifiable: None });
    }
    for (label, why) in skipped {
        let unit = Kind::parse_arg(label).ok().and_then(|k| k.eng_units(0).first().copied()).unwrap_or(("SI", 1.0));
        terms.push(TermLimit {
            term: label.clone(),
            unit,
            per_fog: vec![None; n_fog],
            not_identifiable: Some(why.clone()),
        });
    }
    let (line_t, line_blocks, _) = d.kept.line_rows();
    let train_t: Vec<f64> = line_t.iter().zip(line_blocks).filter(|(_, &b)| trains(b)).map(|(t, _)| *t).collect();
    let n_train = train_t.len();
    let span_s = d.t_span_s[1] - d.t_span_s[0];
    let dt_s = d.dt_s * d.kept.stride as f64;
    let ld = LineDesign {
        n_train,
        n_test: line_blocks.len() - n_train,
        rows_averaged: d.kept.stride.max(1),
        dt_s,
        range_hz: searchable_range(span_s, dt_s, opt.max_frequencies),
        t_sd_s: time_spread_s(&train_t, &vec![1.0; n_train]),
        n_fog,
        base_cols: base.bases.iter().map(Design::k).max().unwrap_or(0),
    };
    let share = |fog: usize, f: f64| line_share(d, base, fog, f);
    let sinusoid =
        (ld.range_hz.1 > ld.range_hz.0 && n_train > 16).then(|| sinusoid_curve(&base.noise, &ld, alpha, 48, &share));
    Detectable { alpha_per_fog: alpha, terms, sinusoid }
}

/// The share of a line's information at `f_hz` on FOG `fog` that the base design leaves
/// on the line rows, the smaller of the training and the test blocks', in the line's least
/// informative phase: μ_min of the (sin, cos) information beside the base over n/2
/// ([`super::detectable::SinusoidCurve::base_share`]).
fn line_share(d: &Digest, base: &BaseFit, fog: usize, f_hz: f64) -> f64 {
    let (_, s) = kept_with_sinusoid(d, fog, f_hz);
    let (design, line) = with_line(&base.bases[fog], d.basis.m);
    [&s.train, &s.test]
        .iter()
        .map(|g| {
            let info = information(g, &design, &line);
            let mu = nalgebra::Matrix2::new(info[0], info[1], info[2], info[3])
                .symmetric_eigenvalues()
                .iter()
                .copied()
                .fold(f64::INFINITY, f64::min);
            if g.n > 0 {
                (mu / (0.5 * g.n as f64)).clamp(0.0, 1.0)
            } else {
                1.0
            }
        })
        .fold(1.0, f64::min)
}

/// The model as it stands, per FOG: its design, the sums, the held-out RMS, the training
/// fit's coefficients and its residual on the kept rows; the binned sums of every row and
/// the noise model of its cross-fitted residual; the bins of the kept
/// rows (for the spectral line, tested on them).
struct BaseFit<'a> {
    bases: Vec<Design>,
    sums: Vec<Sums>,
    train_res: Vec<Vec<f64>>,
    train_coef: Vec<Vec<f64>>,
    base_ho: Vec<f64>,
    binned: Vec<Binned<'a>>,
    kept_bins: Bins,
    noise: Vec<NoiseModel>,
}

impl<'a> BaseFit<'a> {
    fn of(d: &'a Digest, kinds: &[Kind]) -> LabResult<BaseFit<'a>> {
        let mut f = BaseFit {
            bases: Vec::new(),
            sums: Vec::new(),
            train_res: Vec::new(),
            train_coef: Vec::new(),
            base_ho: Vec::new(),
            binned: Vec::new(),
            kept_bins: Bins::of_line_rows(d),
            noise: Vec::new(),
        };
        for fog in 0..d.basis.n_fog {
            let des = design(d, kinds, fog)?;
            let s = Sums::of(d, fog);
            let (ho, tr) = held_out(&s, &des.cols);
            let bd = Binned::of_digest(d, fog);
            let nm = NoiseModel::fit(&bd, &Cross::of(&s, &des.cols));
            f.binned.push(bd);
            f.noise.push(nm);
            f.base_ho.push(ho);
            f.train_res.push(line_residual(d, fog, &des.cols, &tr.coef));
            f.train_coef.push(tr.coef);
            f.bases.push(des);
            f.sums.push(s);
        }
        Ok(f)
    }

    /// The noise context of FOG `fog` on the digest's own basis (every row).
    fn ctx(&self, fog: usize) -> NoiseCtx<'_> {
        NoiseCtx { bd: &self.binned[fog] }
    }
}

/// The terms to test, each with where it came from: the catalog terms the model lacks, then
/// the unused columns most correlated with the training residual.
fn candidate_list(d: &Digest, kinds: &[Kind], base: &BaseFit, opt: &Options) -> Vec<(Kind, String)> {
    let mut list: Vec<(Kind, String)> = Vec::new();
    for c in Catalog::ALL {
        if !kinds.contains(&Kind::Catalog(c)) {
            list.push((Kind::Catalog(c), "catalog".into()));
        }
    }
    let used_vars: Vec<String> = kinds
        .iter()
        .filter_map(|k| if let Kind::Expr(e) = k { Some(e.clone()) } else { None })
        .flat_map(|e| {
            use exmex::Express;
            exmex::parse::<f64>(&e).map(|x| x.var_names().to_vec()).unwrap_or_else(|_| vec![e.clone()])
        })
        .collect();
    let mut cols: Vec<(f64, String)> = Vec::new();
    for c in d.extra_columns.iter().filter(|c| !used_vars.contains(c)) {
        let kind = Kind::Expr(c.clone());
        let mut r = 0.0f64;
        for fog in 0..d.basis.n_fog {
            let Ok(x) = d.basis.functionals(&kind, fog) else { continue };
            let res = residual_functional(&base.bases[fog].cols, &base.train_coef[fog]);
            let unit = d.shifted(fog, &{
                let mut v = vec![0.0; d.basis.m];
                v[super::stream::ONE] = 1.0;
                v
            });
            let a = design_gram(&base.sums[fog].train, &[unit, d.shifted(fog, &x[0]), res]);
            r = r.max(correlation(&a).abs());
        }
        cols.push((r, c.clone()));
    }
    cols.sort_by(|a, b| b.0.total_cmp(&a.0));
    for (r, c) in cols.into_iter().take(opt.max_columns) {
        list.push((Kind::Expr(c), format!("unused column, |r| = {r:.2} with the training residual")));
    }
    list
}

/// The base design `b` on a basis of `m` extended by sin and cos ([`kept_with_sinusoid`]),
/// and the line's two functionals there.
fn with_line(b: &Design, m: usize) -> (Design, [Vec<f64>; 2]) {
    let pad = |v: &Vec<f64>| {
        let mut w = v.clone();
        w.extend([0.0, 0.0]);
        w
    };
    let unit = |k: usize| {
        let mut w = vec![0.0; m + 2];
        w[k] = 1.0;
        w
    };
    (Design { cols: b.cols.iter().map(pad).collect(), owner: b.owner.clone() }, [unit(m), unit(m + 1)])
}

/// The spectral line at `f`, Hz, tested per FOG on the kept rows; the tests and the origin.
fn spectral_line(d: &Digest, base: &BaseFit, line: &Line) -> (Vec<Option<FogTest>>, String) {
    let (m, f) = (d.basis.m, line.f_hz);
    let per_fog = (0..d.basis.n_fog)
        .map(|fog| {
            let (z, s) = kept_with_sinusoid(d, fog, f);
            let (design, sc) = with_line(&base.bases[fog], m);
            let bd = Binned::of_rows(&base.kept_bins, &z, m + 2, d.n_blocks);
            let ctx = NoiseCtx { bd: &bd };
            let mut t = test_fog(&s, &design, &sc, &ctx)?;
            if d.kept.stride > 1 {
                // On means of runs the white part is smaller; the line's systematic drop of the
                // mean square (a line slower than a run) is what it removes from every row.
                let drop = t.before_rad_s.powi(2) - t.after_rad_s.powi(2);
                t.before_rad_s = base.base_ho[fog];
                t.after_rad_s = (t.before_rad_s.powi(2) - drop).max(0.0).sqrt();
            }
            Some(t)
        })
        .collect();
    let mut origin = match line.harmonic_of {
        None => format!(
            "spectral line of the training residual, period {:.4} h, false-alarm probability {:.1e}",
            1.0 / f / 3600.0,
            line.fap
        ),
        Some((k, f0)) => {
            format!("harmonic {k} of the line of period {:.4} h (training p {:.1e})", 1.0 / f0 / 3600.0, line.fap)
        }
    };
    if !d.all_kept() {
        origin.push_str(&format!(
            " (searched and tested on {} means of {} rows)",
            d.kept.line_rows().0.len(),
            d.kept.stride
        ));
    }
    (per_fog, origin)
}

/// The candidates tested so far, and the terms no FOG could test (with why).
#[derive(Default)]
struct Ranked {
    cands: Vec<Candidate>,
    skipped: Vec<(String, String)>,
}

impl Ranked {
    /// Adds `kind`'s per-FOG tests: a candidate with its Bonferroni p-value over the FOGs
    /// tested and the pooled RMS before and after (`base_ho` where a FOG was not tested),
    /// or a skipped term when no FOG was.
    fn consider(
        &mut self,
        kind: Kind,
        origin: String,
        per_fog: Vec<Option<FogTest>>,
        why: Option<String>,
        base_ho: &[f64],
    ) {
        let tested: Vec<&FogTest> = per_fog.iter().flatten().collect();
        if tested.is_empty() {
            self.skipped.push((kind.label(), why.unwrap_or_else(|| "not identifiable in this session".into())));
            return;
        }
        let pmin = tested.iter().map(|t| t.p).fold(1.0, f64::min);
        let n_tested = tested.len() as f64;
        let before: Vec<f64> =
            per_fog.iter().enumerate().map(|(i, t)| t.as_ref().map_or(base_ho[i], |t| t.before_rad_s)).collect();
        let after: Vec<f64> =
            per_fog.iter().enumerate().map(|(i, t)| t.as_ref().map_or(base_ho[i], |t| t.after_rad_s)).collect();
        self.cands.push(Candidate {
            kind,
            origin,
            per_fog,
            p_value: (pmin * n_tested).min(1.0),
            before_rad_s: pooled(&before),
            after_rad_s: pooled(&after),
            significant: false,
            untested: Vec::new(),
        });
    }
}

/// Correlation of x and y from the normal-equation matrix of (1, x, y).
fn correlation(a: &nalgebra::DMatrix<f64>) -> f64 {
    let n = a[(0, 0)];
    if n <= 0.0 {
        return 0.0;
    }
    let (mx, my) = (a[(0, 1)] / n, a[(0, 2)] / n);
    let sxx = a[(1, 1)] - n * mx * mx;
    let syy = a[(2, 2)] - n * my * my;
    let sxy = a[(1, 2)] - n * mx * my;
    if sxx > 0.0 && syy > 0.0 {
        sxy / (sxx * syy).sqrt()
    } else {
        0.0
    }
}

/// Number of hypotheses rejected by Benjamini–Hochberg at level `q` (p-values sorted ascending).
pub fn benjamini_hochberg(sorted_p: &[f64], q: f64) -> usize {
    let m = sorted_p.len() as f64;
    sorted_p.iter().enumerate().filter(|(i, &p)| p <= (*i as f64 + 1.0) / m * q).map(|(i, _)| i + 1).max().unwrap_or(0)
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

/// The paper's two-factor ANOVA on the residual of the base design fitted on all rows, at
/// the kept rows (every row of a session up to [`super::stream::DEFAULT_KEEP`] samples).
///
/// Cell (j, g) holds the residuals with T in level j and G in level g. With cell means Ȳ_jg,
/// level means Ȳ_j, Ȳ'_g and the grand mean Ȳ (the paper's formulas, weighted by the cell
/// counts where the design is unbalanced, which makes the split of the sums of squares
/// approximate): s_ε² within cells (ν_ε = M − n), s_T² and s_G² between levels
/// (ν_T = u₁ − 1, ν_G = u₂ − 1), s_TG² of the interaction (ν_TG = n − u₁ − u₂ + 1), and
/// F_T = s_T²/s_TG², F_G = s_G²/s_TG², F_TG = s_TG²/s_ε² as in the paper.
fn anova_fog(d: &Digest, base: &Design, sums: &Sums, fog: usize) -> Option<Anova> {
    let (temp, g) = d.kept.temp[fog].as_ref()?;
    let dt: Vec<f64> = temp.iter().map(|t| t - d.basis.t_ref_degc).collect();
    let (tmin, tmax) = dt.iter().fold((f64::MAX, f64::MIN), |(a, b), &v| (a.min(v), b.max(v)));
    let gstd = {
        let m = g.iter().sum::<f64>() / g.len() as f64;
        (g.iter().map(|v| (v - m) * (v - m)).sum::<f64>() / g.len() as f64).sqrt()
    };
    if tmax - tmin < 1.0 || gstd < 1e-6 || g.len() < 30 {
        return None;
    }
    let fit = lstsq_gram(&design_gram(&sums.all, &base.cols), sums.all.n);
    let res = kept_residual(d, fog, &base.cols, &fit.coef);
    // T levels at its tertiles; G levels falling / steady / rising, steady meaning |G| within
    // a tenth of the 95th percentile of |G| (the paper's G levels are set rates and holds).
    let mut ag: Vec<f64> = g.iter().map(|v| v.abs()).collect();
    ag.sort_by(f64::total_cmp);
    let eps = 0.1 * ag[ag.len() * 95 / 100];
    let (te, ge) = (tertiles(&dt), [-eps, eps]);
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
        t_edges_degc: [te[0] + d.basis.t_ref_degc, te[1] + d.basis.t_ref_degc],
        g_edges_degc_s: ge,
    })
}
