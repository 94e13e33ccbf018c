//! Overlapping Allan variance of a static session (IEEE Std 952-1997, annex C), and the
//! noise terms read from it: angle random walk N (slope −1/2), bias instability B (flat
//! part, B = min σ / 0.664) and rate random walk K (slope +1/2).
//!
//! With θ_k = Σ_{l≤k} ω_l τ0 the integrated angle, for τ = m τ0:
//!
//! ```text
//! σ²(τ) = 1 / (2 τ² (L − 2m)) Σ_{k=0}^{L−2m−1} (θ_{k+2m} − 2 θ_{k+m} + θ_k)²
//! ```
//!
//! **Confidence intervals.** Each σ(τ) carries a chi-square interval with the equivalent
//! degrees of freedom of the non-overlapping estimate, edf = L/m − 1 (conservative: the
//! overlapping estimate has more). The 1σ relative error is then about 1/√(2 edf)
//! (IEEE 952: 1/√(2(L/m − 1))).
//!
//! **Fit.** σ²(τ) = N²/τ + C + K² τ/3 is fitted by weighted least squares (weights from
//! the relative errors above, only over τ with edf ≥ 3); N and K come from the fit. Their
//! 95 % intervals are the relative interval of the σ(τ) point where each term dominates
//! most (the fit's own covariance ignores the strong correlation of overlapping points).
//! B = min σ(τ)/0.664 over the computed τ (the flicker reading; when the data hold only
//! white noise and rate random walk, this minimum is √(2NK/√3) at τ = √3 N/K).
//!
//! **What a session cannot resolve is a bound, not a value.** A term is resolved when its
//! fitted variance is positive and it carries at least half of σ²(τ) at some computed τ.
//! Otherwise (the fit clamps K² to 0 because the session is too short for the random walk
//! to show, say) it is reported as a 95 % upper bound from the σ(τ) point that limits it
//! best: N ≤ min √(σ²_hi τ), K ≤ min √(3 σ²_hi / τ); B, when σ still falls at the longest τ
//! (no flat part reached), as B ≤ σ_hi(τ_max)/0.664. Never a zero-width interval.
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
        let edf = (l as f64 / m as f64 - 1.0).max(1.0);
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

/// Fits the noise terms to an Allan deviation (module doc).
pub fn noise_terms(points: &[AdevPoint]) -> Result<NoiseTerms> {
    let use_: Vec<&AdevPoint> = points.iter().filter(|p| p.edf >= 3.0).collect();
    if use_.len() < 4 {
        bail!(
            "Allan fit: {} τ with at least 3 non-overlapping clusters, 4 needed: the session is too short \
             (it needs at least 16 × its sample interval, and τ up to a quarter of its length)",
            use_.len()
        );
    }
    // σ² = N²/τ + C + K² τ/3; weight 1/(σ² · rel), rel = √(2/edf).
    let n = use_.len();
    let a = DMatrix::from_fn(n, 3, |r, c| {
        let p = use_[r];
        let w = 1.0 / (p.adev_rad_s.powi(2) * (2.0 / p.edf).sqrt());
        w * match c {
            0 => 1.0 / p.tau_s,
            1 => 1.0,
            _ => p.tau_s / 3.0,
        }
    });
    let b = DVector::from_iterator(n, use_.iter().map(|p| 1.0 / (2.0 / p.edf).sqrt()));
    let (x, _) = super::lstsq(&a, &b)?;
    // Intervals: the τ points are strongly correlated (overlapping clusters), so the fit's
    // covariance would be far too narrow. Each term takes the relative 95 % interval of the
    // single σ(τ) point where it dominates most: ARW the point with the largest share of
    // N²/τ, RRW the one with the largest share of K²τ/3 (usually the longest τ).
    let share = |p: &AdevPoint, k: usize| {
        let parts = [x[0] / p.tau_s, x[1], x[2] * p.tau_s / 3.0];
        parts[k] / parts.iter().map(|v| v.abs()).sum::<f64>()
    };
    let best = |k: usize| -> &AdevPoint {
        use_.iter().copied().max_by(|a, b| share(a, k).total_cmp(&share(b, k))).expect("non-empty")
    };
    // basis(τ): N²/τ for k = 0, K²τ/3 for k = 2; the upper bound of the coefficient from σ²_hi.
    let basis = |k: usize, tau: f64| if k == 0 { 1.0 / tau } else { tau / 3.0 };
    let estimate = |k: usize, conv: f64| -> Estimate {
        let p = best(k);
        if x[k] > 0.0 && share(p, k) >= 0.5 {
            let v = x[k].sqrt() * conv;
            Estimate::Resolved {
                value: v,
                lo: v * p.ci95_rad_s.0 / p.adev_rad_s,
                hi: v * p.ci95_rad_s.1 / p.adev_rad_s,
            }
        } else {
            let ub =
                use_.iter().map(|p| (p.ci95_rad_s.1.powi(2) / basis(k, p.tau_s)).sqrt()).fold(f64::INFINITY, f64::min);
            Estimate::UpperBound(ub * conv)
        }
    };
    // N in rad/√s → °/√h: × (180/π) × 60.
    let arw = estimate(0, 180.0 / std::f64::consts::PI * 60.0);
    // K in rad/s/√s → °/h/√h: × (180/π) × 3600 × 60.
    let rrw = estimate(2, 180.0 / std::f64::consts::PI * 3600.0 * 60.0);
    let min = points.iter().min_by(|a, b| a.adev_rad_s.total_cmp(&b.adev_rad_s)).expect("non-empty");
    let tau_max_s = use_.iter().map(|p| p.tau_s).fold(0.0, f64::max);
    let bias_instability_deg_h = if min.tau_s >= tau_max_s {
        // Still falling at the longest τ: the flat part lies beyond this session.
        Estimate::UpperBound(min.ci95_rad_s.1 / 0.664 / DEG_H)
    } else {
        Estimate::Resolved {
            value: min.adev_rad_s / 0.664 / DEG_H,
            lo: min.ci95_rad_s.0 / 0.664 / DEG_H,
            hi: min.ci95_rad_s.1 / 0.664 / DEG_H,
        }
    };
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
