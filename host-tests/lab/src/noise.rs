//! The residual's noise model, and the tests and intervals that hold under it.
//!
//! A FOG's output error is not white: besides angle random walk (white rate noise) its bias
//! wanders (bias instability, flicker, Gauss–Markov drift of 0.005–0.01 °/h with correlation
//! times of hours). Tests that treat residuals as independent then find "effects" in the
//! wander. The lab models the residual e of the model under test, per FOG, as
//!
//! ```text
//! e_t = w_t + Σ_j x_j,t        w white (σ_w²),  x_j first-order Gauss–Markov (q_j, τ_j)
//! ```
//!
//! on **bins**: the rows of a session are grouped into at most [`MAX_BINS`](super::stream::MAX_BINS) bins of
//! consecutive rows inside one time block. Within a bin the wander is constant, so the
//! deviations from the bin mean are white with the row variance σ_w² (estimated from them).
//! The series of bin means ē_b has the spectrum
//!
//! ```text
//! S(ω) = θ₀ + Σ_j θ_j (1 − ρ_j²) / (1 − 2 ρ_j cos ω + ρ_j²),   ρ_j = exp(−1/τ_j),
//! ```
//!
//! with τ_j = 1, 2, 4, … bins up to the session's length (a fixed bank; θ ≥ 0). The θ are
//! fitted to the periodogram of the bin means of every block, in time order, of the model's
//! cross-fitted residual ([`Cross`]: on each half the residual of the fit on the other half,
//! so that neither a real effect nor a slow wander is fitted away where the model looks) by
//! Whittle's likelihood, with the multiplicative updates of Itakura–Saito NMF (exponent ½, which never
//! lowers the likelihood; Févotte & Idier 2011). The autocovariance of the bin means is then
//! γ(k) = θ₀ δ_k + Σ θ_j ρ_j^|k|.
//!
//! Every row counts: the pass ([`super::stream::digest`]) sums each FOG's basis vectors z
//! over each bin of **every** row, beside the per-block Gram sums ([`Binned`]). A residual
//! functional ℓ gives each bin's mean residual ℓ·Σz / n_b, and the within-bin sum of squares
//! of a block is ℓᵀGℓ − Σ_b (ℓ·Σz)² / n_b; so the fit of the noise model, the whitened sums
//! and the held-out gain below need no row, and their power grows with the session's length
//! (a sample of rows would give up all but that sample's share of the white part's
//! information). Only the spectral line, whose frequency is chosen on the kept rows, is
//! tested on the kept rows' own bins.
//!
//! Under that model:
//! - [`whitened`]: generalised least squares. In each block the bin means of the basis are
//!   whitened by the Cholesky factor of the block's covariance (L⁻¹ z̄), the within-bin
//!   scatter (the block's Gram less Σ n_b z̄ z̄ᵀ) is divided by σ_w²; their sum is a Gram
//!   matrix like the pass's, so every design's GLS fit and nested F-test follows from it
//!   exactly as the white ones do.
//!   Blocks are whitened separately (their mutual correlation is ignored).
//! - [`held_out_gain`]: the held-out improvement D = Σ (r₀² − r₁²) over the test rows of two
//!   models fitted on the training rows and its standard deviation, 2 √(δᵀ Σ δ) with δ = r₀ − r₁
//!   and Σ the model's covariance of the test rows (between-bin and within-bin parts). Given
//!   the training fit, D's randomness is the test noise only; its mean is
//!   Σ δ (2 s − δ) for the systematic part s, negative when the candidate only fitted noise.

use std::borrow::Cow;

use nalgebra::DMatrix;

use super::lsq::{design_gram, lstsq_gram, residual_functional, Gram};
use super::stream::{trains, Bins, Digest, Sums};

/// Iterations of the Whittle fit.
const WHITTLE_ITER: usize = 300;

/// What every test under the noise model needs of one FOG's rows: per bin the sum of the
/// (shifted) basis vectors, and per block their Gram sums. A residual functional ℓ then
/// gives each bin's mean residual ℓ·Σz / n_b and, with ℓᵀGℓ, the within-bin sum of squares
/// of each block: no row is needed, so the tests use every row of a session.
#[derive(Debug, Clone)]
pub struct Binned<'a> {
    /// The bins.
    pub bins: &'a Bins,
    /// Basis length.
    pub m: usize,
    /// Per bin, Σ z (bins × m).
    pub sum: Cow<'a, [f64]>,
    /// Per block (by block number), Σ z zᵀ over the same rows.
    pub gram: Cow<'a, [Gram]>,
}

impl<'a> Binned<'a> {
    /// Every row of FOG `fog` of a pass.
    pub fn of_digest(d: &'a Digest, fog: usize) -> Binned<'a> {
        Binned { bins: &d.bins, m: d.basis.m, sum: Cow::Borrowed(&d.bin_sum[fog]), gram: Cow::Borrowed(&d.gram[fog]) }
    }

    /// Rows `z` (rows × m, row-major) grouped by `bins` (of the same rows) in `n_blocks` blocks.
    pub fn of_rows(bins: &'a Bins, z: &[f64], m: usize, n_blocks: usize) -> Binned<'a> {
        let mut sum = vec![0.0; bins.len() * m];
        let mut gram = vec![Gram::new(m); n_blocks.max(bins.block.iter().max().map_or(0, |b| b + 1))];
        for b in 0..bins.len() {
            let g = &mut gram[bins.block[b]];
            for zk in z[bins.start[b] * m..bins.start[b + 1] * m].chunks_exact(m) {
                for a in 0..m {
                    sum[b * m + a] += zk[a];
                    for c in a..m {
                        g.upper[a * m + c] += zk[a] * zk[c];
                    }
                }
                g.n += 1;
            }
        }
        Binned { bins, m, sum: Cow::Owned(sum), gram: Cow::Owned(gram) }
    }

    /// ℓ · Σ z over bin `b`.
    fn dot(&self, b: usize, l: &[f64]) -> f64 {
        self.sum[b * self.m..(b + 1) * self.m].iter().zip(l).map(|(a, c)| a * c).sum()
    }

    /// Σ over the test blocks of aᵀ G c.
    fn test_quad(&self, a: &[f64], c: &[f64]) -> f64 {
        self.gram.iter().enumerate().filter(|(blk, _)| !trains(*blk)).map(|(_, g)| quad(g, a, c)).sum()
    }

    /// Σ over every block of ℓᵀ G ℓ, ℓ the block's residual functional (`cross`).
    fn all_quad(&self, cross: &Cross) -> f64 {
        self.gram.iter().enumerate().map(|(blk, g)| quad(g, cross.at(blk), cross.at(blk))).sum()
    }

    /// Every bin, in time order: (index, rows, ℓ · Σ z), ℓ its block's residual functional.
    fn all_bins(&self, cross: &Cross) -> Vec<(usize, usize, f64)> {
        (0..self.bins.len()).map(|b| (b, self.bins.count(b), self.dot(b, cross.at(self.bins.block[b])))).collect()
    }

    /// Test bins: (index, rows, ℓ · Σ z).
    fn test_bins(&self, l: &[f64]) -> Vec<(usize, usize, f64)> {
        (0..self.bins.len())
            .filter(|&b| !trains(self.bins.block[b]))
            .map(|b| (b, self.bins.count(b), self.dot(b, l)))
            .collect()
    }
}

/// A design's cross-fitted residual functionals: on the test blocks the residual of its fit
/// on the training blocks, on the training blocks the residual of its fit on the test blocks.
/// Every bin's residual is then out of sample: a slow effect or wander is not fitted away
/// where the noise model looks at it, and the model sees the whole session in time order.
#[derive(Debug, Clone)]
pub struct Cross {
    /// Functional on the training blocks (the test blocks' fit).
    pub on_train: Vec<f64>,
    /// Functional on the test blocks (the training blocks' fit).
    pub on_test: Vec<f64>,
}

impl Cross {
    /// Of the design `cols` (y last) on the sums `s`.
    pub fn of(s: &Sums, cols: &[Vec<f64>]) -> Cross {
        let tr = lstsq_gram(&design_gram(&s.train, cols), s.train.n);
        let te = lstsq_gram(&design_gram(&s.test, cols), s.test.n);
        Cross { on_train: residual_functional(cols, &te.coef), on_test: residual_functional(cols, &tr.coef) }
    }

    /// The functional of block `blk`.
    fn at(&self, blk: usize) -> &[f64] {
        if trains(blk) {
            &self.on_train
        } else {
            &self.on_test
        }
    }
}

/// aᵀ G c of a Gram's symmetric matrix.
fn quad(g: &Gram, a: &[f64], c: &[f64]) -> f64 {
    let m = g.m;
    let mut s = 0.0;
    for (i, ai) in a.iter().enumerate().take(m) {
        for (j, cj) in c.iter().enumerate().take(m) {
            let v = if i <= j { g.upper[i * m + j] } else { g.upper[j * m + i] };
            s += ai * v * cj;
        }
    }
    s
}

/// One FOG's noise model (see the module text). Variances in (rad/s)².
#[derive(Debug, Clone)]
pub struct NoiseModel {
    /// Variance of one row's white part (within bins); 0 when bins are single rows.
    pub white_row_var: f64,
    /// θ₀: the white variance of a full bin's mean.
    pub white_bin_var: f64,
    /// Gauss–Markov components of the bin means: (variance θ_j, correlation time τ_j in bins).
    pub gm: Vec<(f64, f64)>,
    /// Rows per bin.
    pub bin_rows: usize,
    /// Time between bins, s.
    pub bin_dt_s: f64,
}

impl NoiseModel {
    /// The model of a design's cross-fitted residual ([`Cross`]) on every bin, in time order.
    pub fn fit(bd: &Binned, cross: &Cross) -> NoiseModel {
        NoiseModel::fit_from(bd, cross, None)
    }

    /// [`NoiseModel::fit`] starting from another fit on the same bins (fewer iterations).
    pub fn fit_from(bd: &Binned, cross: &Cross, start: Option<&NoiseModel>) -> NoiseModel {
        let tb = bd.all_bins(cross);
        let means: Vec<f64> = tb.iter().map(|&(_, n, s)| s / n.max(1) as f64).collect();
        let between: f64 = tb.iter().map(|&(_, n, s)| s * s / n.max(1) as f64).sum();
        let dof: usize = tb.iter().map(|&(_, n, _)| n.saturating_sub(1)).sum();
        let within = (bd.all_quad(cross) - between).max(0.0);
        let white_row_var = if dof > 0 { within / dof as f64 } else { 0.0 };
        let mut taus = Vec::new();
        let mut tau = 1.0;
        while tau <= means.len() as f64 {
            taus.push(tau);
            tau *= 2.0;
        }
        let rho: Vec<f64> = taus.iter().map(|t| (-1.0 / t).exp()).collect();
        let init = start.filter(|s| s.gm.len() == rho.len()).map(|s| {
            let mut t = vec![s.white_bin_var];
            t.extend(s.gm.iter().map(|g| g.0));
            t
        });
        let iter = if init.is_some() { WHITTLE_ITER / 4 } else { WHITTLE_ITER };
        let theta = whittle(&means, &rho, init, iter);
        NoiseModel {
            white_row_var,
            white_bin_var: theta[0],
            gm: theta[1..].iter().zip(&taus).map(|(&q, &t)| (q, t)).collect(),
            bin_rows: bd.bins.rows,
            bin_dt_s: bd.bins.dt_s,
        }
    }

    /// Covariance of the means of bins `lag` apart, the first of `n_a` rows.
    pub fn cov(&self, lag: usize, n_a: usize) -> f64 {
        let mut c: f64 = self.gm.iter().map(|&(q, t)| q * (-(lag as f64) / t).exp()).sum();
        if lag == 0 {
            c += self.white_bin_var * self.bin_rows as f64 / n_a.max(1) as f64;
        }
        c
    }

    /// RMS of one row's white noise, rad/s (the sample-level noise floor).
    pub fn white_floor_rad_s(&self) -> f64 {
        if self.bin_rows > 1 {
            self.white_row_var.sqrt()
        } else {
            self.white_bin_var.sqrt()
        }
    }

    /// Variance of the Gauss–Markov part, (rad/s)².
    pub fn wander_var(&self) -> f64 {
        self.gm.iter().map(|g| g.0).sum()
    }
}

/// Whittle fit of θ (white first, then one per ρ) to the periodogram of `x`: `iter`
/// multiplicative updates from `init` (or an even split of the variance).
fn whittle(x: &[f64], rho: &[f64], init: Option<Vec<f64>>, iter: usize) -> Vec<f64> {
    let n = x.len();
    let mean = x.iter().sum::<f64>() / n.max(1) as f64;
    let var = x.iter().map(|v| (v - mean) * (v - mean)).sum::<f64>() / n.max(1) as f64;
    let mut theta = vec![var.max(f64::MIN_POSITIVE); rho.len() + 1];
    if n < 4 || var <= 0.0 {
        theta[1..].iter_mut().for_each(|t| *t = 0.0);
        return theta;
    }
    match init {
        Some(t) => theta.iter_mut().zip(t).for_each(|(a, b)| *a = b.max(1e-6 * var)),
        None => {
            theta[0] = 0.5 * var;
            theta[1..].iter_mut().for_each(|t| *t = 0.5 * var / rho.len().max(1) as f64);
        }
    }
    // Periodogram at the Fourier frequencies 2πk/n, k = 1 … n/2 (rotation per frequency).
    let k_max = n / 2;
    let mut per = Vec::with_capacity(k_max);
    let mut h: Vec<Vec<f64>> = vec![Vec::with_capacity(k_max); rho.len() + 1];
    for k in 1..=k_max {
        let w = 2.0 * std::f64::consts::PI * k as f64 / n as f64;
        let (ds, dc) = w.sin_cos();
        let (mut s, mut c) = (0.0f64, 1.0f64);
        let (mut re, mut im) = (0.0, 0.0);
        for v in x {
            let y = v - mean;
            re += y * c;
            im -= y * s;
            (s, c) = (s * dc + c * ds, c * dc - s * ds);
        }
        per.push((re * re + im * im) / n as f64);
        h[0].push(1.0);
        for (j, &r) in rho.iter().enumerate() {
            h[j + 1].push((1.0 - r * r) / (1.0 - 2.0 * r * w.cos() + r * r));
        }
    }
    let mut s = vec![0.0; k_max];
    for _ in 0..iter {
        for (k, sk) in s.iter_mut().enumerate() {
            *sk = theta.iter().zip(&h).map(|(t, hj)| t * hj[k]).sum::<f64>().max(f64::MIN_POSITIVE);
        }
        for (t, hj) in theta.iter_mut().zip(&h) {
            let (mut a, mut b) = (0.0, 0.0);
            for k in 0..k_max {
                a += hj[k] * per[k] / (s[k] * s[k]);
                b += hj[k] / s[k];
            }
            if b > 0.0 {
                *t *= (a / b).sqrt();
            }
        }
    }
    theta
}

/// GLS sums of `bd`'s rows whitened under `nm` (see the module text), per training / test
/// blocks. `n` of each is the number of whitened rows (bins plus within-bin degrees of
/// freedom).
pub fn whitened(nm: &NoiseModel, bd: &Binned) -> Sums {
    let (bins, m) = (bd.bins, bd.m);
    let mut s = Sums { all: Gram::new(m), train: Gram::new(m), test: Gram::new(m) };
    let blocks = bins.per_block();
    let longest = blocks.iter().map(|(_, r)| r.len()).max().unwrap_or(0);
    let acov: Vec<f64> = (0..longest).map(|k| nm.cov(k, nm.bin_rows)).collect();
    for (blk, r) in blocks {
        let nb = r.len();
        let zbar =
            DMatrix::from_fn(nb, m, |i, a| bd.sum[(r.start + i) * m + a] / bins.count(r.start + i).max(1) as f64);
        // Within-bin scatter: the block's Gram less the bins' n z̄ z̄ᵀ.
        let mut within = DMatrix::<f64>::zeros(m, m);
        let mut dof = 0;
        if nm.white_row_var > 0.0 {
            if let Some(g) = bd.gram.get(blk) {
                within = g.full();
            }
            for (i, b) in r.clone().enumerate() {
                let n = bins.count(b) as f64;
                let row = zbar.row(i);
                within -= n * row.transpose() * row;
                dof += bins.count(b).saturating_sub(1);
            }
        }
        let cov =
            DMatrix::from_fn(
                nb,
                nb,
                |a, c| if a == c { nm.cov(0, bins.count(r.start + a)) } else { acov[a.abs_diff(c)] },
            );
        let Some(ch) = nalgebra::Cholesky::new(cov) else { continue };
        let x = ch.l().solve_lower_triangular(&zbar).unwrap_or(zbar);
        let xtx = x.transpose() * &x;
        let g = if trains(blk) { &mut s.train } else { &mut s.test };
        for a in 0..m {
            for c in a..m {
                let w = if nm.white_row_var > 0.0 { within[(a, c)] / nm.white_row_var } else { 0.0 };
                g.upper[a * m + c] += xtx[(a, c)] + w;
            }
        }
        g.n += nb + dof;
    }
    s.all.add(&s.train);
    s.all.add(&s.test);
    s
}

/// A held-out improvement and its standard deviation under the noise model.
#[derive(Debug, Clone, Copy)]
pub struct Gain {
    /// Σ (r₀² − r₁²) over the kept test rows, (rad/s)².
    pub d: f64,
    /// Its standard deviation, (rad/s)².
    pub sd: f64,
    /// Kept test rows.
    pub n: usize,
}

impl Gain {
    /// D / sd: how many standard deviations the improvement is above zero.
    pub fn z(&self) -> f64 {
        if self.sd > 0.0 {
            self.d / self.sd
        } else if self.d > 0.0 {
            f64::INFINITY
        } else {
            f64::NEG_INFINITY
        }
    }

    /// One-sided p-value of "no improvement" (D ≤ 0).
    pub fn p(&self) -> f64 {
        normal_sf(self.z())
    }

    /// The mean-square drop per test row and its 1σ, (rad/s)².
    pub fn per_row(&self) -> (f64, f64) {
        let n = self.n.max(1) as f64;
        (self.d / n, self.sd / n)
    }
}

/// Upper tail of the unit normal.
pub fn normal_sf(z: f64) -> f64 {
    use statrs::distribution::{ContinuousCDF, Normal};
    if z.is_nan() {
        return 1.0;
    }
    Normal::new(0.0, 1.0).map_or(1.0, |n| n.sf(z))
}

/// The held-out improvement of residual functional `l1` over `l0` (both fitted on the
/// training blocks) on the test rows of `bd`, with its standard deviation under `nm`.
pub fn held_out_gain(nm: &NoiseModel, bd: &Binned, l0: &[f64], l1: &[f64]) -> Gain {
    let delta: Vec<f64> = l0.iter().zip(l1).map(|(a, b)| a - b).collect();
    let both: Vec<f64> = l0.iter().zip(l1).map(|(a, b)| a + b).collect();
    // Σ (r₀² − r₁²) = Σ δ (r₀ + r₁).
    let d = bd.test_quad(&delta, &both);
    let tb = bd.test_bins(&delta);
    let between: f64 = tb.iter().map(|&(_, n, s)| s * s / n.max(1) as f64).sum();
    let within = (bd.test_quad(&delta, &delta) - between).max(0.0);
    let n: usize = tb.iter().map(|&(_, n, _)| n).sum();
    let mut var = nm.white_row_var * within;
    let max_lag = bd.bins.len();
    let acov: Vec<f64> = (0..max_lag.max(1)).map(|k| nm.cov(k, nm.bin_rows)).collect();
    for (i, &(a, na, sa)) in tb.iter().enumerate() {
        var += sa * sa * nm.cov(0, na);
        for &(b, _, sb) in &tb[i + 1..] {
            let c = acov.get(b - a).copied().unwrap_or(0.0);
            var += 2.0 * sa * sb * c;
        }
    }
    Gain { d, sd: 2.0 * var.max(0.0).sqrt(), n }
}

/// RMS of the means of `x` (equally spaced by `dt_s`) over consecutive windows of about
/// `tau_s` (a whole number of samples, about the overall mean) and the window used, s; `None`
/// when τ is shorter than a sample or fewer than two windows fit.
pub fn tau_mean_rms(x: &[f64], dt_s: f64, tau_s: f64) -> Option<(f64, f64)> {
    let k = (tau_s / dt_s).round() as usize;
    if k == 0 || tau_s < 0.5 * dt_s || x.len() / k < 2 {
        return None;
    }
    let means: Vec<f64> = x.chunks_exact(k).map(|c| c.iter().sum::<f64>() / k as f64).collect();
    let m = means.iter().sum::<f64>() / means.len() as f64;
    Some((k as f64 * dt_s, (means.iter().map(|v| (v - m) * (v - m)).sum::<f64>() / means.len() as f64).sqrt()))
}

/// Overlapping Allan deviation of the rate series `x` (equally spaced by `dt_s`) at cluster
/// sizes 1, 2, 4, … up to a quarter of the series: (τ in s, σ_A in the unit of x).
pub fn allan_deviation(x: &[f64], dt_s: f64) -> Vec<(f64, f64)> {
    // Angle θ_k = Σ x dt; σ²(m) = Σ (θ_{k+2m} − 2θ_{k+m} + θ_k)² / (2 τ² (N − 2m)).
    let mut theta = Vec::with_capacity(x.len() + 1);
    theta.push(0.0);
    let mut acc = 0.0;
    for v in x {
        acc += v * dt_s;
        theta.push(acc);
    }
    let n = theta.len();
    let mut out = Vec::new();
    let mut m = 1;
    while 4 * m <= x.len() {
        let tau = m as f64 * dt_s;
        let terms = n - 2 * m;
        let s: f64 = (0..terms).map(|k| (theta[k + 2 * m] - 2.0 * theta[k + m] + theta[k]).powi(2)).sum();
        out.push((tau, (s / (2.0 * tau * tau * terms as f64)).sqrt()));
        m *= 2;
    }
    out
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
