//! Overlapping Allan variance of a static session (IEEE Std 952-1997, annex C), and the
//! noise terms read from it: angle random walk N (slope −1/2), bias instability B (the flat
//! flicker floor, σ = 0.664 B) and rate random walk K (slope +1/2).
//!
//! With θ_k = Σ_{l≤k} ω_l τ0 the integrated angle, for τ = m τ0:
//!
//! ```text
//! σ²(τ) = 1 / (2 τ² (L − 2m)) Σ_{k=0}^{L−2m−1} (θ_{k+2m} − 2 θ_{k+m} + θ_k)²
//! ```
//!
//! **Confidence intervals.** Each σ(τ) carries a chi-square interval with the equivalent
//! degrees of freedom of the overlapping estimate for the noise that gives the fewest: the
//! least of the white-FM, flicker-FM and random-walk-FM formulas (W. J. Riley, *Handbook of
//! Frequency Stability Analysis*, NIST SP 1065, table 5). Which noise dominates at τ is what
//! the fit is to find, so no point's interval assumes it is white noise; at τ = L/4 the
//! random-walk edf is 2, where the white-noise one would be 4.
//!
//! **Fit and intervals of the terms.** σ²(τ) = N²/τ + C + K² τ/3 (C = (0.664 B)², the
//! flicker floor) is fitted by weighted least squares (weights from the points' relative
//! errors). The fit gives the values; it does not give the intervals (the τ points are
//! strongly correlated, and a free fit trades a negative C for a positive K²). The
//! intervals are those of the set of non-negative (N², C, K²) consistent with *every*
//! point's interval at once: each point at level 1 − 0.05/n (Bonferroni over the n points,
//! so that the truth lies in the set with probability ≥ 95 % whatever the points'
//! correlation). The least and greatest N², C and K² over that polytope (a linear
//! program in three unknowns, solved at its vertices) bound each term.
//!
//! **What a session cannot resolve is a bound, not a value.** A term whose least value
//! over the set is 0 is not shown by the session: the other terms explain every point
//! without it. It is reported as a 95 % upper bound (its greatest value over the set),
//! never as a value with an interval. B is read from C, so B is resolved only where the
//! session shows a floor that white noise and a rate random walk cannot explain; a
//! minimum of σ(τ) alone is not a flicker floor. When no non-negative combination of the
//! three terms fits every point (another noise: quantisation, a sinusoid, a drift ramp),
//! each term is bounded alone (a term is at most the whole σ²(τ) at every τ) and none is
//! claimed resolved.
//!
//! **What a session must be** ([`static_rates`]): static (the reference rate constant to
//! within the FOG's white noise per sample), equally spaced, and long enough for four τ
//! with at least three non-overlapping clusters each.

use anyhow::{bail, Result};
use nalgebra::{DMatrix, DVector};
use statrs::distribution::{ChiSquared, ContinuousCDF};

/// One point of the Allan deviation.
#[derive(Debug, Clone, Copy)]
pub struct AdevPoint {
    /// τ, s.
    pub tau_s: f64,
    /// σ(τ), rad/s.
    pub adev_rad_s: f64,
    /// Lower and upper 95 % bounds, rad/s.
    pub ci95_rad_s: (f64, f64),
    /// Equivalent degrees of freedom used for the interval.
    pub edf: f64,
}

/// Overlapping Allan deviation of rates `rate_rad_s` sampled every `tau0_s`, at about
/// `per_decade` log-spaced cluster sizes up to L/4.
pub fn overlapping_adev(rate_rad_s: &[f64], tau0_s: f64, per_decade: usize) -> Result<Vec<AdevPoint>> {
    let l = rate_rad_s.len();
    if l < 16 {
        bail!("Allan variance: need at least 16 samples, have {l}");
    }
    if let Some(k) = rate_rad_s.iter().position(|w| !w.is_finite()) {
        bail!("Allan variance: rate sample {k} is {} (every sample must be a number)", rate_rad_s[k]);
    }
    if !(tau0_s.is_finite() && tau0_s > 0.0) {
        bail!("Allan variance: sample interval {tau0_s} s is not a positive time");
    }
    let mut theta = Vec::with_capacity(l + 1);
    theta.push(0.0);
    let mut acc = 0.0;
    // Remove the mean first (it does not change σ, it helps the rounding).
    let mean = rate_rad_s.iter().sum::<f64>() / l as f64;
    for w in rate_rad_s {
        acc += (w - mean) * tau0_s;
        theta.push(acc);
    }
    let mut ms = Vec::new();
    let mut m = 1usize;
    let step = 10f64.powf(1.0 / per_decade.max(1) as f64);
    while m <= l / 4 {
        if ms.last() != Some(&m) {
            ms.push(m);
        }
        m = ((m as f64 * step).ceil() as usize).max(m + 1);
    }
    let mut out = Vec::with_capacity(ms.len());
    for m in ms {
        let tau = m as f64 * tau0_s;
        let terms = l + 1 - 2 * m;
        let mut s = 0.0;
        for k in 0..terms {
            let d = theta[k + 2 * m] - 2.0 * theta[k + m] + theta[k];
            s += d * d;
        }
        let avar = s / (2.0 * tau * tau * terms as f64);
        let edf = edf(l, m);
        let chi = ChiSquared::new(edf).map_err(|e| anyhow::anyhow!("chi-square({edf}): {e}"))?;
        let lo = avar * edf / chi.inverse_cdf(0.975);
        let hi = avar * edf / chi.inverse_cdf(0.025);
        out.push(AdevPoint { tau_s: tau, adev_rad_s: avar.sqrt(), ci95_rad_s: (lo.sqrt(), hi.sqrt()), edf });
    }
    Ok(out)
}

/// A noise term as the session determines it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Estimate {
    /// Resolved: the value and its 95 % interval.
    Resolved {
        /// The value.
        value: f64,
        /// Lower 95 % bound.
        lo: f64,
        /// Upper 95 % bound.
        hi: f64,
    },
    /// Not resolved by this session: a 95 % upper bound only.
    UpperBound(f64),
}

impl Estimate {
    /// The value when resolved.
    pub fn value(&self) -> Option<f64> {
        match self {
            Estimate::Resolved { value, .. } => Some(*value),
            Estimate::UpperBound(_) => None,
        }
    }

    /// `0.00512 [0.00498, 0.00527]`, or `≤ 0.0123 (not resolved)`.
    pub fn text(&self, decimals: usize) -> String {
        match self {
            Estimate::Resolved { value, lo, hi } => format!("{value:.decimals$} [{lo:.decimals$}, {hi:.decimals$}]"),
            Estimate::UpperBound(b) => format!("≤ {b:.decimals$} (95 % upper bound: not resolved by this session)"),
        }
    }
}

/// The noise terms, in the units of the table's observer fields.
#[derive(Debug, Clone, Copy)]
pub struct NoiseTerms {
    /// N, angle random walk, °/√h.
    pub arw_deg_sqrt_h: Estimate,
    /// B, bias instability (min σ / 0.664), °/h.
    pub bias_instability_deg_h: Estimate,
    /// τ at the minimum, s.
    pub tau_min_s: f64,
    /// K, rate random walk, °/h/√h.
    pub rrw_deg_h_sqrt_h: Estimate,
    /// The longest τ of the fit, s.
    pub tau_max_s: f64,
}

const DEG_H: f64 = std::f64::consts::PI / 180.0 / 3600.0;

/// Equivalent degrees of freedom of the overlapping Allan variance at cluster size `m` of
/// `l` rate samples (`l + 1` angle points): the least of the white-FM, flicker-FM and
/// random-walk-FM formulas (module doc), at least 1.
fn edf(l: usize, m: usize) -> f64 {
    let (n, m) = (l as f64 + 1.0, m as f64);
    let white = (3.0 * (n - 1.0) / (2.0 * m) - 2.0 * (n - 2.0) / n) * 4.0 * m * m / (4.0 * m * m + 5.0);
    let flicker = if m < 1.5 { 2.0 * (n - 2.0) / (2.3 * n - 4.9) } else { 5.0 * n * n / (4.0 * m * (n + 3.0 * m)) };
    let walk = (n - 2.0) / m * ((n - 1.0).powi(2) - 3.0 * m * (n - 1.0) + 4.0 * m * m) / (n - 3.0).powi(2);
    white.min(flicker).min(walk).max(1.0)
}

/// The interval of σ²(τ) of `p` at two-sided level 1 − `alpha` (chi-square with its edf).
fn avar_interval(p: &AdevPoint, alpha: f64) -> Result<(f64, f64)> {
    let chi = ChiSquared::new(p.edf).map_err(|e| anyhow::anyhow!("chi-square({}): {e}", p.edf))?;
    let avar = p.adev_rad_s * p.adev_rad_s;
    Ok((avar * p.edf / chi.inverse_cdf(1.0 - alpha / 2.0), avar * p.edf / chi.inverse_cdf(alpha / 2.0)))
}

/// σ²(τ)'s three parts per unit coefficient: N²/τ, C, K²τ/3.
fn basis(tau_s: f64) -> [f64; 3] {
    [1.0 / tau_s, 1.0, tau_s / 3.0]
}

/// The least and greatest of each coefficient (N², C, K²) over the non-negative
/// coefficients with `lo_p ≤ basis(τ_p)·x ≤ hi_p` at every point, or `None` when no
/// non-negative x satisfies them all. `scale` puts the three unknowns at comparable size.
/// The polytope is bounded (every point bounds a positive combination), so each extreme is
/// at a vertex: the feasible intersections of three of its planes.
fn coefficient_ranges(rows: &[([f64; 3], f64, f64)], scale: [f64; 3]) -> Option<[(f64, f64); 3]> {
    // Planes a·y = b in scaled unknowns y (x = scale ⊙ y), each row divided by its upper end.
    let mut planes: Vec<([f64; 3], f64)> = Vec::with_capacity(2 * rows.len() + 3);
    let mut ineq: Vec<([f64; 3], f64, f64)> = Vec::with_capacity(rows.len());
    for (r, lo, hi) in rows {
        let a = [r[0] * scale[0] / hi, r[1] * scale[1] / hi, r[2] * scale[2] / hi];
        planes.push((a, lo / hi));
        planes.push((a, 1.0));
        ineq.push((a, lo / hi, 1.0));
    }
    for k in 0..3 {
        let mut a = [0.0; 3];
        a[k] = 1.0;
        planes.push((a, 0.0));
    }
    const TOL: f64 = 1e-9;
    let feasible = |y: &[f64; 3]| {
        y.iter().all(|v| *v >= -TOL)
            && ineq.iter().all(|(a, lo, hi)| {
                let v = a[0] * y[0] + a[1] * y[1] + a[2] * y[2];
                v >= lo - TOL && v <= hi + TOL
            })
    };
    let mut out: Option<[(f64, f64); 3]> = None;
    let np = planes.len();
    for i in 0..np {
        for j in i + 1..np {
            for k in j + 1..np {
                let m = nalgebra::Matrix3::from_rows(&[
                    nalgebra::RowVector3::from(planes[i].0),
                    nalgebra::RowVector3::from(planes[j].0),
                    nalgebra::RowVector3::from(planes[k].0),
                ]);
                if m.determinant().abs() < 1e-12 {
                    continue;
                }
                let Some(inv) = m.try_inverse() else { continue };
                let y = inv * nalgebra::Vector3::new(planes[i].1, planes[j].1, planes[k].1);
                let y = [y[0].max(0.0), y[1].max(0.0), y[2].max(0.0)];
                if !feasible(&y) {
                    continue;
                }
                let r = out.get_or_insert([(f64::INFINITY, f64::NEG_INFINITY); 3]);
                for (q, v) in r.iter_mut().zip(y) {
                    *q = (q.0.min(v), q.1.max(v));
                }
            }
        }
    }
    out.map(|r| std::array::from_fn(|k| (r[k].0 * scale[k], r[k].1 * scale[k])))
}

/// Fits the noise terms to an Allan deviation (module doc).
pub fn noise_terms(points: &[AdevPoint]) -> Result<NoiseTerms> {
    let use_: Vec<&AdevPoint> = points.iter().filter(|p| p.adev_rad_s.is_finite() && p.tau_s > 0.0).collect();
    if use_.len() < 4 {
        bail!(
            "Allan fit: {} τ with at least 3 non-overlapping clusters, 4 needed: the session is too short \
             (it needs at least 16 × its sample interval, and τ up to a quarter of its length)",
            use_.len()
        );
    }
    if use_.iter().any(|p| p.adev_rad_s <= 0.0) {
        bail!("Allan fit: σ(τ) = 0 at some τ: the rates are constant (no noise to read terms from)");
    }
    // σ² = N²/τ + C + K² τ/3; weight 1/(σ² · rel), rel = √(2/edf).
    let n = use_.len();
    let a = DMatrix::from_fn(n, 3, |r, c| {
        let p = use_[r];
        let w = 1.0 / (p.adev_rad_s.powi(2) * (2.0 / p.edf).sqrt());
        w * basis(p.tau_s)[c]
    });
    let b = DVector::from_iterator(n, use_.iter().map(|p| 1.0 / (2.0 / p.edf).sqrt()));
    let x = super::lstsq(&a, &b).map(|(x, _)| [x[0], x[1], x[2]]).unwrap_or([0.0; 3]);
    // Every point's interval at 1 − 0.05/n (Bonferroni: all n hold at once with ≥ 95 %).
    let alpha = 0.05 / n as f64;
    let rows = use_
        .iter()
        .map(|p| avar_interval(p, alpha).map(|(lo, hi)| (basis(p.tau_s), lo, hi)))
        .collect::<Result<Vec<_>>>()?;
    // Each term alone: at most the whole σ²_hi at every τ.
    let alone: [f64; 3] =
        std::array::from_fn(|k| rows.iter().map(|(r, _, hi)| hi / r[k]).fold(f64::INFINITY, f64::min));
    let (first, last) = (use_[0], use_[n - 1]);
    let min_avar = use_.iter().map(|p| p.adev_rad_s.powi(2)).fold(f64::INFINITY, f64::min);
    let scale = [first.adev_rad_s.powi(2) * first.tau_s, min_avar, 3.0 * last.adev_rad_s.powi(2) / last.tau_s];
    let ranges = coefficient_ranges(&rows, scale);
    // The coefficient k's estimate in the unit `conv` × √coefficient.
    let estimate = |k: usize, conv: f64| -> Estimate {
        match ranges {
            Some(r) if r[k].0 > 0.0 => {
                let (lo, hi) = (r[k].0.sqrt() * conv, r[k].1.sqrt() * conv);
                Estimate::Resolved { value: (x[k].max(0.0).sqrt() * conv).clamp(lo, hi), lo, hi }
            }
            Some(r) => Estimate::UpperBound(r[k].1.sqrt() * conv),
            None => Estimate::UpperBound(alone[k].sqrt() * conv),
        }
    };
    // N in rad/√s → °/√h: × (180/π) × 60.
    let arw = estimate(0, 180.0 / std::f64::consts::PI * 60.0);
    // C = (0.664 B)², B in °/h.
    let bias_instability_deg_h = estimate(1, 1.0 / 0.664 / DEG_H);
    // K in rad/s/√s → °/h/√h: × (180/π) × 3600 × 60.
    let rrw = estimate(2, 180.0 / std::f64::consts::PI * 3600.0 * 60.0);
    let min = use_.iter().copied().min_by(|a, b| a.adev_rad_s.total_cmp(&b.adev_rad_s)).unwrap_or(first);
    let tau_max_s = last.tau_s;
    Ok(NoiseTerms {
        arw_deg_sqrt_h: arw,
        bias_instability_deg_h,
        tau_min_s: min.tau_s,
        rrw_deg_h_sqrt_h: rrw,
        tau_max_s,
    })
}

/// The rates of FOG `fog` of a session, checked to be what the Allan variance needs (module
/// doc): equally spaced samples (within 1 %) and a static reference: the reference rate
/// vector departs from its first value by no more than the FOG's white noise per sample
/// (σ from the first differences of its output, 1.4826 · median |Δω| / √2). Refused with
/// what the session lacks.
pub fn static_rates(s: &ssis_session::Session, fog: usize) -> Result<Vec<f64>> {
    let file = &s.file;
    let Some(f) = s.fogs.get(fog) else {
        bail!("{file}: the session has no `fog{fog}_rad_s` (or `fog{fog}_rad`) column: no FOG{fog} output")
    };
    let t = s.t_s();
    let dt = s.median_dt_s();
    if let Some(k) = t.windows(2).position(|w| ((w[1] - w[0]) / dt - 1.0).abs() > 0.01) {
        bail!(
            "{file}: samples are not equally spaced (interval {} s at t = {} s, the session's is {dt} s): the \
             Allan variance needs a gap-free static session",
            ((t[k + 1] - t[k]) * 1e3).round() / 1e3,
            (t[k] * 1e3).round() / 1e3
        );
    }
    let mut d: Vec<f64> = f.rate_rad_s.windows(2).map(|w| (w[1] - w[0]).abs()).collect();
    d.sort_by(f64::total_cmp);
    let sigma = d.get(d.len() / 2).copied().unwrap_or(0.0) * 1.4826 / 2f64.sqrt();
    let w0 = s.ref_rad_s.first().copied().unwrap_or([0.0; 3]);
    let dev = |w: &[f64; 3]| ((w[0] - w0[0]).powi(2) + (w[1] - w0[1]).powi(2) + (w[2] - w0[2]).powi(2)).sqrt();
    let (k, worst) =
        s.ref_rad_s.iter().map(dev).enumerate().fold((0, 0.0), |m, (k, v)| if v > m.1 { (k, v) } else { m });
    if worst > sigma {
        bail!(
            "{file}: not a static session: the reference rate changes by {:.4} °/h (at t = {} s) against the FOG's \
             white noise of {:.4} °/h per sample; the Allan variance needs the rate input constant to within the \
             noise (a turntable run reads as noise of the wrong size: record a static run)",
            worst / DEG_H,
            t.get(k).map_or(f64::NAN, |t| (t * 1e3).round() / 1e3),
            sigma / DEG_H
        );
    }
    Ok(f.rate_rad_s.clone())
}

/// Rates of a static FOG with white rate noise (ARW) and a bias random walk (RRW), as
/// means over `tau0_s` (exact for the white part; the random walk is sampled at the
/// interval's end, a difference invisible at τ ≫ τ0). Units: °/√h and °/h/√h.
pub fn simulate_static(
    arw_deg_sqrt_h: f64,
    rrw_deg_h_sqrt_h: f64,
    bias_deg_h: f64,
    tau0_s: f64,
    n: usize,
    seed: u64,
) -> Vec<f64> {
    use rand::SeedableRng;
    use rand_distr::{Distribution, StandardNormal};
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let sv = arw_deg_sqrt_h.to_radians() / 60.0 / tau0_s.sqrt();
    let su = rrw_deg_h_sqrt_h.to_radians() / 3600.0 / 60.0 * tau0_s.sqrt();
    let mut walk = 0.0;
    (0..n)
        .map(|_| {
            let z1: f64 = StandardNormal.sample(&mut rng);
            let z2: f64 = StandardNormal.sample(&mut rng);
            walk += su * z2;
            bias_deg_h * DEG_H + walk + sv * z1
        })
        .collect()
}
