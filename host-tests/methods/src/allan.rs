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

/// The noise terms, in the units of the table's observer fields.
#[derive(Debug, Clone, Copy)]
pub struct NoiseTerms {
    /// N, angle random walk, °/√h, and its 95 % interval.
    pub arw_deg_sqrt_h: (f64, f64, f64),
    /// B, bias instability (min σ / 0.664), °/h, with the interval of that σ point.
    pub bias_instability_deg_h: (f64, f64, f64),
    /// τ at the minimum, s.
    pub tau_min_s: f64,
    /// K, rate random walk, °/h/√h, and its 95 % interval.
    pub rrw_deg_h_sqrt_h: (f64, f64, f64),
}

const DEG_H: f64 = std::f64::consts::PI / 180.0 / 3600.0;

/// Fits the noise terms to an Allan deviation (module doc).
pub fn noise_terms(points: &[AdevPoint]) -> Result<NoiseTerms> {
    let use_: Vec<&AdevPoint> = points.iter().filter(|p| p.edf >= 3.0).collect();
    if use_.len() < 4 {
        bail!("Allan fit: fewer than 4 usable τ");
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
    let interval = |k: usize, conv: f64| -> (f64, f64, f64) {
        let v = x[k].max(0.0).sqrt() * conv;
        let p = best(k);
        (v, v * p.ci95_rad_s.0 / p.adev_rad_s, v * p.ci95_rad_s.1 / p.adev_rad_s)
    };
    // N in rad/√s → °/√h: × (180/π) × 60.
    let arw = interval(0, 180.0 / std::f64::consts::PI * 60.0);
    // K in rad/s/√s → °/h/√h: × (180/π) × 3600 × 60.
    let rrw = interval(2, 180.0 / std::f64::consts::PI * 3600.0 * 60.0);
    let min = points.iter().min_by(|a, b| a.adev_rad_s.total_cmp(&b.adev_rad_s)).expect("non-empty");
    Ok(NoiseTerms {
        arw_deg_sqrt_h: arw,
        bias_instability_deg_h: (
            min.adev_rad_s / 0.664 / DEG_H,
            min.ci95_rad_s.0 / 0.664 / DEG_H,
            min.ci95_rad_s.1 / 0.664 / DEG_H,
        ),
        tau_min_s: min.tau_s,
        rrw_deg_h_sqrt_h: rrw,
    })
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
