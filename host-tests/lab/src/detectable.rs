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
//!   and c the coefficients. The test reaches 80 % power when λ reaches λ*(q, df2, α), the
//!   root of P(F'(q, df2, λ) > F_crit) = 0.8 with F_crit the test's own critical value of
//!   F(q, df2) ([`lambda_required_f`]; χ²_q/q in the limit of many test rows, which states
//!   a λ* about 1 % too small at 700 rows and α 3e-4). The minimum detectable coefficient is
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
//!   P_search(λ) = ∫ P(χ²_ν(λ) > u) dF_max(u). The test on the test blocks is the one every
//!   candidate gets (`diagnose`'s `test_fog`): the GLS F-test of (sin, cos) beside the base
//!   model, F(2, df2) at its own critical value, **and** the held-out direction test (the
//!   line fitted on the training blocks is one regressor on the test blocks, one-sided,
//!   F(1, df2 + 1) at 2α); its power P_test(λ_test, λ_train) ([`line_test_power`]) is
//!   that of both rejecting, λ_test = A² n_test / (2 S(f)): the F-test needs the test
//!   estimate's norm, the direction test its projection on the training estimate's
//!   direction, which misses the line's phase by an angle whose law is the projected normal
//!   of λ_train. The search and the F-test use disjoint rows, so the probability of finding
//!   the line is P_search × P_test, and the minimum detectable amplitude is the one at
//!   which it reaches [`POWER`]. The non-centrality that does it is the same at every
//!   period (only S(f) changes), so it is solved for once. The line's non-centrality is
//!   what the base model leaves of it: the search fits the training residual of the base
//!   model, the test fits the line beside it, so n is scaled by the least share of the
//!   line's information left beside the base design on either half, in the line's least
//!   informative phase (μ_min of its (sin, cos) information over n/2;
//!   [`SinusoidCurve::base_share`]), as a term's statement holds in any direction of its
//!   regressors.
//!
//! The power study (`host-tests/lab/tests/power.rs`) measures the detection rate at the
//! stated size and at half of it.

use statrs::distribution::{ChiSquared, ContinuousCDF, Discrete, FisherSnedecor, Poisson};

use super::noise::{row_spectrum_of_means, NoiseModel};
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

/// Upper tail of the non-central F with `d1`, `d2` degrees of freedom and non-centrality
/// `lambda` at `x`: the Poisson(λ/2) mixture of the central F's of (d1 + 2j, d2), each the
/// regularised incomplete beta I_y(d1/2 + j, d2/2) at y = d1 x / (d1 x + d2).
pub fn ncf_sf(x: f64, d1: f64, d2: f64, lambda: f64) -> f64 {
    use statrs::function::beta::checked_beta_reg;
    if x.is_nan() || x <= 0.0 {
        return 1.0;
    }
    let y = d1 * x / (d1 * x + d2);
    let half = 0.5 * lambda.max(0.0);
    let tail = |j: u64| checked_beta_reg(0.5 * d1 + j as f64, 0.5 * d2, y).map_or(0.0, |c| 1.0 - c);
    if half == 0.0 {
        return tail(0).clamp(0.0, 1.0);
    }
    let Ok(pois) = Poisson::new(half) else { return 1.0 };
    let j_max = (half + 12.0 * half.sqrt() + 30.0) as u64;
    let j_min = (half - 12.0 * half.sqrt()).max(0.0) as u64;
    (j_min..=j_max).map(|j| pois.pmf(j) * tail(j)).sum::<f64>().clamp(0.0, 1.0)
}

/// The non-centrality at which a χ²_q test at level `alpha` has power `power`.
pub fn lambda_required(q: usize, alpha: f64, power: f64) -> f64 {
    let q = q.max(1) as f64;
    let Ok(c) = ChiSquared::new(q) else { return f64::NAN };
    let crit = c.inverse_cdf(1.0 - alpha.clamp(1e-300, 0.5));
    lambda_to_beat(crit, q, power)
}

/// The non-centrality at which the F-test of `q` regressors with `df2` denominator degrees of
/// freedom at level `alpha` has power `power`: the root of P(F'(q, df2, λ) > F_crit) = power,
/// F_crit the upper-`alpha` point of F(q, df2) ([`f_critical`]), the test
/// `diagnose` performs (its χ²_q root, [`lambda_required`], is the limit df2 → ∞).
pub fn lambda_required_f(q: usize, df2: usize, alpha: f64, power: f64) -> f64 {
    let crit = f_critical(alpha.clamp(1e-300, 0.5), q.max(1), df2);
    if !crit.is_finite() {
        return lambda_required(q, alpha, power);
    }
    let (q, d2) = (q.max(1) as f64, df2 as f64);
    first_reached(|l| ncf_sf(crit, q, d2, l) < power, 1.0, 1e9, |_, _, k| k < 60)
        .map_or(f64::INFINITY, |(lo, hi)| 0.5 * (lo + hi))
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
    /// Regressors of the base design the line is tested beside (the F-test's denominator
    /// has n_test − base_cols − 2 degrees of freedom).
    pub base_cols: usize,
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
    let ratio = ld.n_test as f64 / ld.n_train.max(1) as f64;
    let df2 = ld.n_test.saturating_sub(ld.base_cols + 2).max(1);
    let found = |l: f64| search_power(l, ld) * line_test_power(l * ratio, l, df2, alpha);
    first_reached(|l| found(l) < power, 8.0, 1e7, |lo, hi, _| hi - lo > 1e-3 * hi).map_or(f64::INFINITY, |(_, hi)| hi)
}

/// Probability that `diagnose`'s test of a line at the right frequency rejects on one FOG
/// (see the module text): the GLS F-test of (sin, cos) beside the base model, F(2, `df2`) at
/// its critical value for `alpha`, and the held-out direction test, one-sided at `alpha`
/// (F(1, df2 + 1) at 2α), both; `lambda_test` the line's non-centrality on the test rows,
/// `lambda_train` on the training rows (the direction's).
///
/// In the test rows' whitened coordinates, with the axis on the training estimate's
/// direction, the test estimate is z ~ N(√λ_test (cos ψ, sin ψ), I₂), ψ the training
/// estimate's angle from the line's phase (the projected normal of √λ_train: density
/// e^(−ρ²/2)/(2π) + ρ cos ψ Φ(ρ cos ψ) e^(−ρ² sin²ψ/2)/√(2π), ρ = √λ_train), and the fit's
/// mean square s² ~ χ²_df2/df2 independent of z (the direction fit's differs from it by
/// one row's worth of a residual of hundreds, neglected). The F-test rejects when
/// |z|² ≥ 2 F_crit s² = R², the direction test when z₁ ≥ t_crit s = B; the probability of
/// both is P(z₁ ≥ max(B, R)) + ∫_B^R φ(z₁ − m₁) P(|z₂| ≥ √(R² − z₁²)) dz₁, integrated
/// over ψ and s². The (sin, cos) information is taken as isotropic (its two eigenvalues
/// agree to a few per cent over a session of many periods; the base share scales λ to the
/// least of them).
pub fn line_test_power(lambda_test: f64, lambda_train: f64, df2: usize, alpha: f64) -> f64 {
    use statrs::function::erf::erfc;
    let alpha = alpha.clamp(1e-300, 0.25);
    let f_crit = f_critical(alpha, 2, df2);
    let t_crit = f_critical(2.0 * alpha, 1, df2 + 1).sqrt();
    if !(f_crit.is_finite() && t_crit.is_finite()) {
        return 0.0;
    }
    let upper = |x: f64| 0.5 * erfc(x / std::f64::consts::SQRT_2);
    let pdf = |x: f64| (-0.5 * x * x).exp() / (2.0 * std::f64::consts::PI).sqrt();
    let rho = lambda_train.max(0.0).sqrt();
    let mu = lambda_test.max(0.0).sqrt();
    let psi_density = |psi: f64| {
        let c = rho * psi.cos();
        (-0.5 * rho * rho).exp() / (2.0 * std::f64::consts::PI)
            + c * (1.0 - upper(c)) * (-0.5 * (rho * psi.sin()).powi(2)).exp() / (2.0 * std::f64::consts::PI).sqrt()
    };
    // Given ψ and s: the probability that both reject.
    let both = |psi: f64, s: f64| {
        let (m1, m2) = (mu * psi.cos(), mu * psi.sin());
        let (r, b) = ((2.0 * f_crit).sqrt() * s, t_crit * s);
        if b >= r {
            return upper(b - m1);
        }
        // z₁ = R cos θ over θ from 0 (z₁ = R) to acos(B/R) (z₁ = B), Simpson.
        let th_b = (b / r).clamp(-1.0, 1.0).acos();
        let g = |th: f64| {
            let (z1, w) = (r * th.cos(), r * th.sin());
            pdf(z1 - m1) * (upper(w - m2) + upper(w + m2)) * r * th.sin()
        };
        upper(r - m1) + simpson(&g, 0.0, th_b, 64)
    };
    // s² at the midpoints of equal-probability bins of χ²_df2 / df2.
    const S_BINS: usize = 16;
    let chi = ChiSquared::new(df2.max(1) as f64).ok();
    let s_nodes: Vec<f64> = (0..S_BINS)
        .map(|i| {
            chi.as_ref().map_or(1.0, |c| (c.inverse_cdf((i as f64 + 0.5) / S_BINS as f64) / df2.max(1) as f64).sqrt())
        })
        .collect();
    // ψ over [0, π] (the law is symmetric in ψ).
    let p = simpson(
        &|psi: f64| 2.0 * psi_density(psi) * s_nodes.iter().map(|&s| both(psi, s)).sum::<f64>() / S_BINS as f64,
        0.0,
        std::f64::consts::PI,
        96,
    );
    p.clamp(0.0, 1.0)
}

/// Simpson's rule for `g` on [a, b] with `n` (even) intervals.
fn simpson(g: &impl Fn(f64) -> f64, a: f64, b: f64, n: usize) -> f64 {
    let n = (n.max(2) + 1) & !1;
    let h = (b - a) / n as f64;
    let inner: f64 = (1..n).map(|i| if i % 2 == 1 { 4.0 } else { 2.0 } * g(a + h * i as f64)).sum();
    h / 3.0 * (g(a) + inner + g(b))
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
    /// A summary: the run of periods around the smallest amplitude over which it stays within
    /// 1.5× of it, and the largest amplitude there: (amplitude rad/s, period from s, period to s).
    pub fn summary(&self) -> Option<(f64, f64, f64)> {
        let min = self.amp_rad_s.iter().copied().fold(f64::INFINITY, f64::min);
        if !min.is_finite() {
            return None;
        }
        // The run of consecutive periods around the smallest amplitude.
        let ok = |i: &usize| self.amp_rad_s[*i] <= 1.5 * min;
        let best = (0..self.amp_rad_s.len()).find(|&i| self.amp_rad_s[i] == min)?;
        let a = (0..=best).rev().take_while(ok).last()?;
        let b = (best..self.amp_rad_s.len()).take_while(ok).last()?;
        let amp = (a..=b).map(|i| self.amp_rad_s[i]).fold(0.0, f64::max);
        Some((amp, self.period_s[a], self.period_s[b]))
    }

    /// The runs of consecutive periods where the base model leaves a share of a line's
    /// information ([`SinusoidCurve::base_share`]) in `[from, below)`, each with the least
    /// share in it: (period from s, period to s, share).
    pub fn base_taken(&self, from: f64, below: f64) -> Vec<(f64, f64, f64)> {
        let mut out: Vec<(f64, f64, f64)> = Vec::new();
        let mut open = false;
        for (&p, &sh) in self.period_s.iter().zip(&self.base_share) {
            if !(from..below).contains(&sh) {
                open = false;
            } else if let (true, Some(last)) = (open, out.last_mut()) {
                last.1 = p;
                last.2 = last.2.min(sh);
            } else {
                out.push((p, p, sh));
                open = true;
            }
        }
        out
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

/// Below this share of a line's information left by the base model
/// ([`SinusoidCurve::base_share`]) the statement names the period.
pub const BASE_SHARE_FULL: f64 = 0.95;

/// Below this share the base model takes the whole line (its stated size more than 30×
/// the line's alone): the sinusoid is called not identifiable there.
pub const BASE_SHARE_NONE: f64 = 1e-3;

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
            let ranges = |r: &[(f64, f64, f64)]| -> String {
                let v: Vec<String> =
                    r.iter()
                        .map(|&(lo, hi, _)| {
                            if lo == hi {
                                period_text(lo)
                            } else {
                                format!("{}–{}", period_text(lo), period_text(hi))
                            }
                        })
                        .collect();
                v.join(", ")
            };
            let taken = s.base_taken(BASE_SHARE_NONE, BASE_SHARE_FULL);
            if !taken.is_empty() {
                let worst = taken.iter().map(|r| r.2).fold(1.0, f64::min);
                out.push(format!(
                    "  {:<30}   at periods {} the base model takes up to {:.0} % of a line (a base term follows \
                     it over a block); the sizes stated there are larger by up to {:.0} %",
                    "",
                    ranges(&taken),
                    100.0 * (1.0 - worst),
                    100.0 * (1.0 / worst.sqrt() - 1.0)
                ));
            }
            let none = s.base_taken(0.0, BASE_SHARE_NONE);
            if !none.is_empty() {
                out.push(format!(
                    "  {:<30}   at periods {} a sinusoid is not identifiable: the base model takes the whole line",
                    "",
                    ranges(&none)
                ));
            }
        }
        out
    }
}

/// F quantile (critical value) at upper-tail probability `q`: the root of sf(x) = q by
/// bisection on the upper tail to a relative 1e-13 (statrs' own inverse stops early: 2.37075
/// for F(4, 2,399,990) at 5 %, where the value is 2.37194).
pub fn f_critical(q: f64, d1: usize, d2: usize) -> f64 {
    if !(q > 0.0 && q < 1.0) || d1 == 0 || d2 == 0 {
        return f64::NAN;
    }
    let Ok(dist) = FisherSnedecor::new(d1 as f64, d2 as f64) else { return f64::NAN };
    first_reached(|x| dist.sf(x) > q, 1.0, 1e300, |lo, hi, _| hi - lo > 1e-13 * hi)
        .map_or(f64::INFINITY, |(lo, hi)| 0.5 * (lo + hi))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A curve over the periods 100, 200, … s with the base model's share of a line given.
    fn curve(share: &[f64]) -> Detectable {
        let period_s: Vec<f64> = (1..=share.len()).map(|i| 100.0 * i as f64).collect();
        let amp_rad_s = share.iter().map(|s| 1e-7 / s.sqrt()).collect();
        let sinusoid = SinusoidCurve {
            searched_s: (period_s[0], period_s[share.len() - 1]),
            period_s,
            amp_rad_s,
            base_share: share.to_vec(),
        };
        Detectable { alpha_per_fog: 1e-3, terms: Vec::new(), sinusoid: Some(sinusoid) }
    }

    /// The line test's power against a Monte Carlo of the two tests in the test rows' whitened
    /// coordinates, and against the F-test alone (which it cannot exceed).
    #[test]
    fn line_test_power_is_both_tests() {
        use rand::SeedableRng;
        use rand_distr::{ChiSquared as Chi2, Distribution, Normal};
        let (df2, alpha) = (715usize, 3.1e-4);
        let f_crit = f_critical(alpha, 2, df2);
        let t_crit = f_critical(2.0 * alpha, 1, df2 + 1).sqrt();
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        let n01 = Normal::new(0.0, 1.0).unwrap();
        let chi = Chi2::new(df2 as f64).unwrap();
        for (l_test, l_train) in [(22.0, 22.0), (30.0, 12.0)] {
            let n = 40_000;
            let mut hit = 0usize;
            for _ in 0..n {
                let s2: f64 = chi.sample(&mut rng) / df2 as f64;
                let (a, b) = (f64::sqrt(l_train) + n01.sample(&mut rng), n01.sample(&mut rng));
                let (x, y) = (f64::sqrt(l_test) + n01.sample(&mut rng), n01.sample(&mut rng));
                let f_ok = 0.5 * (x * x + y * y) / s2 >= f_crit;
                let d_ok = (x * a + y * b) / a.hypot(b) >= t_crit * s2.sqrt();
                hit += usize::from(f_ok && d_ok);
            }
            let mc = hit as f64 / n as f64;
            let p = line_test_power(l_test, l_train, df2, alpha);
            assert!((p - mc).abs() < 0.01, "λ {l_test}/{l_train}: {p:.4} against Monte Carlo {mc:.4}");
            let f_alone = ncf_sf(f_crit, 2.0, df2 as f64, l_test);
            assert!(p <= f_alone + 1e-3 && p > f_alone - 0.1, "{p:.4} against the F-test alone {f_alone:.4}");
        }
    }

    #[test]
    fn base_share_names_each_run_of_periods() {
        // Two runs apart: 200–300 s and 600 s, not one range 200–600 s.
        let text = curve(&[1.0, 0.5, 0.9, 1.0, 1.0, 0.8, 1.0]).lines().join("\n");
        assert!(text.contains("at periods 3 min–5 min, 10 min the base model takes up to 50 %"), "{text}");
        assert!(!text.contains("3 min–10 min"), "{text}");
        assert!(!text.contains("not identifiable"), "{text}");
    }

    #[test]
    fn a_line_the_base_takes_whole_is_not_identifiable() {
        let text = curve(&[0.9, 1e-6, 1e-6, 1.0, 0.64]).lines().join("\n");
        assert!(text.contains("at periods 3 min–5 min a sinusoid is not identifiable"), "{text}");
        // The finite statement covers only the period where a size is stated.
        assert!(text.contains("at periods 100 s, 8 min the base model takes up to 36 %"), "{text}");
        assert!(text.contains("larger by up to 25 %"), "{text}");
        assert!(!text.contains("99900"), "{text}");
        // The stated range is the run around the smallest size, not across the gap.
        assert!(text.contains("at periods 7 min–8 min (searched"), "{text}");
    }
}
