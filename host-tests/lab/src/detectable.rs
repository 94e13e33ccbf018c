//! What a session could have shown: the minimum detectable effect of each candidate.
//!
//! "No significant missing effect" reads the same whether the session could have shown a
//! 0.01 °/h effect or only a 1 °/h one. So beside its verdict `diagnose` states, for each
//! candidate term and for a sinusoid over the periods its spectral search covers, the
//! smallest effect that this session would have called significant with probability
//! [`POWER`] (80 %) on any one FOG, at the level the diagnosis really applies to one
//! candidate on one FOG: α = level / (candidates × FOGs) (a single missing effect is
//! first under Benjamini–Hochberg when its Bonferroni-combined p-value is at most
//! level / candidates).
//!
//! - **A catalog term or a column.** Under the noise model, the GLS F-test of the candidate's
//!   q regressors on the test blocks has non-centrality λ = cᵀ I c, with I = Xᵀ(I − H₀)X the
//!   candidate's information beside the base model (whitened; [`super::diagnose::FogTest::info`])
//!   and c the coefficients. The test reaches 80 % power when λ reaches λ*(q, α), the root
//!   of P(χ²_q(λ) > χ²_q,α) = 0.8 (the F's denominator has as many degrees of freedom as
//!   test rows, so χ²_q/q stands for it). The minimum detectable coefficient is
//!   √(λ*/μ_min), μ_min the smallest eigenvalue of I (any direction of that norm is
//!   detected): for a one-regressor term, √(λ*/I).
//! - **A sinusoid** of amplitude A at frequency f is found when two things happen: the
//!   search picks its frequency on the training blocks, and its test on the test blocks
//!   rejects. With S(f) the residual's spectrum per row under the noise model (the white part
//!   plus each Gauss–Markov term's Lorentzian), the line on one FOG adds a non-central
//!   χ²₂(λ_train) to the search's pooled normalised power (χ²_ν, ν = 2 × FOGs, at every
//!   other frequency), λ_train = A² n_train / (2 S(f)) for n_train training rows; it is picked
//!   when that power beats the maximum of the rest of the band, whose distribution is the
//!   search's own false-alarm law ([`super::spectral::max_tail`], Rice's formula):
//!   P_search(λ) = ∫ P(χ²_ν(λ) > u) dF_max(u). The test's χ²₂ then rejects at level α with
//!   P_test = P(χ²₂(λ_test) > χ²₂,α), λ_test = A² n_test / (2 S(f)). The two happen on
//!   disjoint rows, so the probability of finding the line is their product, and the
//!   minimum detectable amplitude is the one at which the product reaches [`POWER`]. The
//!   non-centrality that does it is the same at every period (only S(f) changes), so it is
//!   solved for once. The line's non-centrality is what the base model leaves of it: the
//!   search fits the training residual of the base model, the test fits the line beside
//!   it, so n is scaled by the least share of the line's information left beside the base
//!   design on either half, in the line's least informative phase (μ_min of its (sin, cos)
//!   information over n/2; [`SinusoidCurve::base_share`]), as a term's statement holds in
//!   any direction of its regressors.
//!
//! The power study (`host-tests/lab/tests/power.rs`) measures the detection rate at the
//! stated size and at half of it.

use statrs::distribution::{ChiSquared, ContinuousCDF, Discrete, Poisson};

use super::noise::NoiseModel;
use super::spectral::max_tail;

/// Detection probability the minimum detectable effect is stated at.
pub const POWER: f64 = 0.8;

/// Upper tail of the non-central χ² with `q` degrees of freedom and non-centrality `lambda`
/// at `x`: the Poisson(λ/2) mixture of central χ²_{q+2j} tails.
pub fn ncx2_sf(x: f64, q: f64, lambda: f64) -> f64 {
    if lambda <= 0.0 {
        return ChiSquared::new(q).map_or(1.0, |c| c.sf(x));
    }
    let half = 0.5 * lambda;
    let Ok(pois) = Poisson::new(half) else { return 1.0 };
    let j_max = (half + 12.0 * half.sqrt() + 30.0) as u64;
    let j_min = (half - 12.0 * half.sqrt()).max(0.0) as u64;
    let mut s = 0.0;
    for j in j_min..=j_max {
        let w = pois.pmf(j);
        if let Ok(c) = ChiSquared::new(q + 2.0 * j as f64) {
            s += w * c.sf(x);
        }
    }
    s.clamp(0.0, 1.0)
}

/// The non-centrality at which a χ²_q test at level `alpha` has power `power`.
pub fn lambda_required(q: usize, alpha: f64, power: f64) -> f64 {
    let q = q.max(1) as f64;
    let Ok(c) = ChiSquared::new(q) else { return f64::NAN };
    let crit = c.inverse_cdf(1.0 - alpha.clamp(1e-300, 0.5));
    lambda_to_beat(crit, q, power)
}

/// The non-centrality at which χ²_q(λ) exceeds `crit` with probability `power`.
fn lambda_to_beat(crit: f64, q: f64, power: f64) -> f64 {
    first_reached(|l| ncx2_sf(crit, q, l) < power, 1.0, 1e9, |_, _, k| k < 60)
        .map_or(f64::INFINITY, |(lo, hi)| 0.5 * (lo + hi))
}

/// The bracket `(lo, hi)` of the point where a criterion stops falling `short` as its
/// argument grows: `hi` doubles from `start` while short (`None` once `hi` passes `cap`),
/// then the bracket is halved while `narrow(lo, hi, halvings so far)` asks for more.
pub(crate) fn first_reached(
    short: impl Fn(f64) -> bool,
    start: f64,
    cap: f64,
    narrow: impl Fn(f64, f64, usize) -> bool,
) -> Option<(f64, f64)> {
    let (mut lo, mut hi) = (0.0f64, start);
    while short(hi) {
        lo = hi;
        hi *= 2.0;
        if hi > cap {
            return None;
        }
    }
    let mut k = 0;
    while narrow(lo, hi, k) {
        let mid = 0.5 * (lo + hi);
        if short(mid) {
            lo = mid;
        } else {
            hi = mid;
        }
        k += 1;
    }
    Some((lo, hi))
}

/// Minimum detectable coefficient norm from a candidate's information `info` (q × q,
/// row-major) at non-centrality `lambda`: √(λ/μ_min); `None` when not identified.
pub fn min_coef(info: &[f64], lambda: f64) -> Option<f64> {
    let q = (info.len() as f64).sqrt().round() as usize;
    if q == 0 || q * q != info.len() {
        return None;
    }
    let m = nalgebra::DMatrix::from_row_slice(q, q, info);
    let mu = m.symmetric_eigenvalues().iter().copied().fold(f64::INFINITY, f64::min);
    let scale = (0..q).map(|i| info[i * q + i].abs()).fold(0.0, f64::max);
    (mu > 1e-12 * scale && mu > 0.0).then(|| (lambda / mu).sqrt())
}

/// The residual's spectral density per row at `f_hz` under a noise model, (rad/s)² (a white
/// residual of row variance σ² has σ²), for rows every `dt_s`.
pub fn row_spectrum(nm: &NoiseModel, f_hz: f64, dt_s: f64) -> f64 {
    row_spectrum_of_means(nm, f_hz, dt_s, 1)
}

/// [`row_spectrum`] of rows that are each the mean of `averaged` consecutive rows of the
/// session (their white part is `averaged` times smaller; the wander's, at `f_hz` well below
/// their rate, the same).
pub fn row_spectrum_of_means(nm: &NoiseModel, f_hz: f64, dt_s: f64, averaged: usize) -> f64 {
    let white = if nm.bin_rows > 1 { nm.white_row_var } else { nm.white_bin_var } / averaged.max(1) as f64;
    // Rows per bin of this spacing (kept rows may be a sample of every row).
    let rows_per_bin = (nm.bin_dt_s / dt_s).max(1.0);
    let w = 2.0 * std::f64::consts::PI * f_hz * dt_s;
    let gm: f64 = nm
        .gm
        .iter()
        .map(|&(theta, tau_bins)| {
            let r = (-1.0 / (tau_bins * rows_per_bin)).exp();
            theta * (1.0 - r * r) / (1.0 - 2.0 * r * w.cos() + r * r)
        })
        .sum();
    white + gm
}

/// The sinusoid's minimum detectable amplitude against period on one FOG.
#[derive(Debug, Clone)]
pub struct SinusoidCurve {
    /// Periods, s (increasing).
    pub period_s: Vec<f64>,
    /// Per period, the largest over FOGs of the minimum detectable amplitude, rad/s.
    pub amp_rad_s: Vec<f64>,
    /// The period range the search covers, s.
    pub searched_s: (f64, f64),
    /// Per period, the smallest over FOGs of the share of a line's information the base
    /// model leaves, on the training rows (the search) or the test rows (the test), in the
    /// line's least informative phase: μ_min of the (sin, cos) information beside the base
    /// design over n/2. Below 1 where a base regressor follows the line over a block (a
    /// slow temperature profile, a drift against a period comparable to a block); the
    /// amplitude is divided by its square root.
    pub base_share: Vec<f64>,
}

/// Inputs of [`sinusoid_curve`].
#[derive(Debug, Clone, Copy)]
pub struct LineDesign {
    /// Kept training rows (the line is searched on them).
    pub n_train: usize,
    /// Kept test rows (the line is tested on them).
    pub n_test: usize,
    /// Interval of the kept rows, s.
    pub dt_s: f64,
    /// Frequencies searched: (f_min, f_max), Hz.
    pub range_hz: (f64, f64),
    /// Standard deviation of the training rows' times, s.
    pub t_sd_s: f64,
    /// FOGs the search pools.
    pub n_fog: usize,
    /// Session rows each of those rows is the mean of.
    pub rows_averaged: usize,
}

/// Probability that the search picks a line of non-centrality `lambda` on one FOG (see the
/// module text).
pub fn search_power(lambda: f64, ld: &LineDesign) -> f64 {
    let nu = 2.0 * ld.n_fog.max(1) as f64;
    let band = ld.range_hz.1 - ld.range_hz.0;
    let cdf_max = |u: f64| 1.0 - max_tail(u, nu, band, ld.t_sd_s);
    // ∫ P(χ²_ν(λ) > u) dF_max(u) over the steps of u where F_max moves.
    let du = 0.25;
    let mut p = 0.0;
    let mut prev = cdf_max(0.0);
    let mut u = 0.0;
    while prev < 1.0 - 1e-9 && u < 2000.0 {
        u += du;
        let next = cdf_max(u);
        let w = next - prev;
        if w > 1e-10 {
            p += w * ncx2_sf(u - 0.5 * du, nu, lambda);
        }
        prev = next;
    }
    p.clamp(0.0, 1.0)
}

/// The training non-centrality λ_train at which a line on one FOG is found (picked and
/// significant) with probability `power`; the test's is λ_train × n_test / n_train.
pub fn line_lambda(ld: &LineDesign, alpha: f64, power: f64) -> f64 {
    let crit = ChiSquared::new(2.0).map_or(f64::INFINITY, |c| c.inverse_cdf(1.0 - alpha.clamp(1e-300, 0.5)));
    let ratio = ld.n_test as f64 / ld.n_train.max(1) as f64;
    let found = |l: f64| search_power(l, ld) * ncx2_sf(crit, 2.0, l * ratio);
    first_reached(|l| found(l) < power, 8.0, 1e7, |lo, hi, _| hi - lo > 1e-3 * hi).map_or(f64::INFINITY, |(_, hi)| hi)
}

/// Minimum detectable sinusoid amplitude over `points` periods log-spaced across the
/// searched range (see the module text), the largest over the FOGs' noise models.
/// `share(fog, f)` is the share of a line's information at `f` Hz on FOG `fog` that the
/// base model leaves, in its least informative phase (1: none taken; see
/// [`SinusoidCurve::base_share`]).
pub fn sinusoid_curve(
    noise: &[NoiseModel],
    ld: &LineDesign,
    alpha: f64,
    points: usize,
    share: &dyn Fn(usize, f64) -> f64,
) -> SinusoidCurve {
    let (f_min, f_max) = ld.range_hz;
    let lam = line_lambda(ld, alpha, POWER);
    let (p_lo, p_hi) = (1.0 / f_max, 1.0 / f_min);
    let mut period_s = Vec::new();
    let mut amp_rad_s = Vec::new();
    let mut base_share = Vec::new();
    for i in 0..points.max(2) {
        let p = p_lo * (p_hi / p_lo).powf(i as f64 / (points.max(2) - 1) as f64);
        let f = 1.0 / p;
        let (mut a, mut worst) = (0.0f64, 1.0f64);
        for (fog, nm) in noise.iter().enumerate() {
            let s = row_spectrum_of_means(nm, f, ld.dt_s, ld.rows_averaged);
            let sh = share(fog, f).clamp(1e-6, 1.0);
            worst = worst.min(sh);
            a = a.max((2.0 * s * lam / (sh * ld.n_train.max(1) as f64)).sqrt());
        }
        period_s.push(p);
        amp_rad_s.push(a);
        base_share.push(worst);
    }
    SinusoidCurve { period_s, amp_rad_s, searched_s: (p_lo, p_hi), base_share }
}

impl SinusoidCurve {
    /// A summary: the periods over which the amplitude stays within 1.5× its smallest value,
    /// and the largest amplitude there: (amplitude rad/s, period from s, period to s).
    pub fn summary(&self) -> Option<(f64, f64, f64)> {
        let min = self.amp_rad_s.iter().copied().fold(f64::INFINITY, f64::min);
        if !min.is_finite() {
            return None;
        }
        let ok: Vec<usize> = (0..self.amp_rad_s.len()).filter(|&i| self.amp_rad_s[i] <= 1.5 * min).collect();
        let (&a, &b) = (ok.first()?, ok.last()?);
        let amp = ok.iter().map(|&i| self.amp_rad_s[i]).fold(0.0, f64::max);
        Some((amp, self.period_s[a], self.period_s[b]))
    }

    /// The periods where the base model leaves less than `share` of a line's information
    /// ([`SinusoidCurve::base_share`]) and the least share there: (from s, to s, share).
    pub fn base_taken(&self, share: f64) -> Option<(f64, f64, f64)> {
        let low: Vec<usize> = (0..self.base_share.len()).filter(|&i| self.base_share[i] < share).collect();
        let (&a, &b) = (low.first()?, low.last()?);
        let worst = low.iter().map(|&i| self.base_share[i]).fold(1.0, f64::min);
        Some((self.period_s[a], self.period_s[b], worst))
    }

    /// The amplitude at period `p_s` (log-interpolated), rad/s.
    pub fn at(&self, p_s: f64) -> Option<f64> {
        let i = self.period_s.partition_point(|&p| p < p_s);
        if i == 0 || i >= self.period_s.len() {
            return (self.period_s.first() == Some(&p_s)).then(|| self.amp_rad_s[0]);
        }
        let (p0, p1) = (self.period_s[i - 1].ln(), self.period_s[i].ln());
        let (a0, a1) = (self.amp_rad_s[i - 1].ln(), self.amp_rad_s[i].ln());
        Some((a0 + (a1 - a0) * (p_s.ln() - p0) / (p1 - p0)).exp())
    }
}

/// One candidate's minimum detectable effect on a session.
#[derive(Debug, Clone)]
pub struct TermLimit {
    /// The term's label.
    pub term: String,
    /// Engineering unit of its coefficient and the factor from SI.
    pub unit: (&'static str, f64),
    /// Per FOG, the minimum detectable coefficient (norm over its regressors), SI; `None`
    /// where the FOG cannot test it.
    pub per_fog: Vec<Option<f64>>,
    /// Why no FOG can test it (and what would), when none can.
    pub not_identifiable: Option<String>,
}

impl TermLimit {
    /// The largest over the FOGs that can test it, in engineering units.
    pub fn worst_eng(&self) -> Option<f64> {
        let v = self.per_fog.iter().flatten().copied().fold(f64::NAN, f64::max);
        v.is_finite().then_some(v * self.unit.1)
    }
}

/// What the session could have shown (see the module text).
#[derive(Debug, Clone)]
pub struct Detectable {
    /// The level one candidate on one FOG is tested at.
    pub alpha_per_fog: f64,
    /// Per candidate term (catalog terms the model lacks, user columns), in the diagnosis's
    /// order of candidate kinds.
    pub terms: Vec<TermLimit>,
    /// A sinusoid over the searched periods.
    pub sinusoid: Option<SinusoidCurve>,
}

/// A period in the unit that reads best: s below 2 min, min below 2 h, else h.
pub fn period_text(p_s: f64) -> String {
    if p_s < 120.0 {
        format!("{p_s:.0} s")
    } else if p_s < 7200.0 {
        format!("{:.0} min", p_s / 60.0)
    } else {
        format!("{:.1} h", p_s / 3600.0)
    }
}

impl Detectable {
    /// The blind-spot table as `diagnose` prints it, one line per term.
    pub fn lines(&self) -> Vec<String> {
        let dh = ssis_common::DEG_H_PER_RAD_S;
        let mut out = vec![format!(
            "what this session could have shown ({:.0} % detection at α {:.1e} per candidate and FOG, on any one FOG):",
            100.0 * POWER,
            self.alpha_per_fog
        )];
        for t in &self.terms {
            match (t.worst_eng(), &t.not_identifiable) {
                (Some(v), _) => out.push(format!("  {:<30} ≥ {:.3e} {}", t.term, v, t.unit.0)),
                (None, Some(why)) => out.push(format!("  {:<30} not identifiable: {why}", t.term)),
                (None, None) => out.push(format!("  {:<30} not identifiable on any FOG", t.term)),
            }
        }
        if let Some(s) = &self.sinusoid {
            if let Some((a, p0, p1)) = s.summary() {
                out.push(format!(
                    "  {:<30} ≥ {:.3e} °/h at periods {}–{} (searched {}–{}; the report draws it)",
                    "sinusoid",
                    a * dh,
                    period_text(p0),
                    period_text(p1),
                    period_text(s.searched_s.0),
                    period_text(s.searched_s.1)
                ));
            }
            if let Some((lo, hi, worst)) = s.base_taken(0.95) {
                out.push(format!(
                    "  {:<30}   at periods {}–{} the base model takes up to {:.0} % of a line (a base term follows \
                     it over a block); the sizes stated there are larger by up to {:.0} %",
                    "",
                    period_text(lo),
                    period_text(hi),
                    100.0 * (1.0 - worst),
                    100.0 * (1.0 / worst.sqrt() - 1.0)
                ));
            }
        }
        out
    }
}
