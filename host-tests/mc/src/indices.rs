//! The ECSS pointing error indices on the knowledge error (ECSS-E-ST-60-10C; ESA pointing
//! error engineering handbook, ESSB-HB-E-003), one per axis, each reduced over time to one
//! number per run (docs/MONTE-CARLO.md, "Indices"):
//!
//! - **AKE** (absolute knowledge error): e(t), the estimated attitude against the true one.
//! - **RKE** (relative knowledge error) over Δt: e(t) − ē_j, ē_j the mean of e over the
//!   window j of length Δt that contains t; the windows are consecutive from `from_s`
//!   (the last one, if incomplete, is left out).
//! - **KDE** (knowledge drift error) of windows Δt separated by Δt_s: ē(t + Δt_s) − ē(t),
//!   ē(t) the mean of e over [t, t + Δt), for every sample time t whose two windows are
//!   complete.
//!
//! The statistic over time of a run is the `time_fraction` quantile of |index| over the
//! samples from `from_s` on (1: the maximum, the index "at all times"; 0.95: the value
//! not exceeded 95 % of the time, the smallest order statistic with at least that
//! fraction at or below it).

use serde::{Deserialize, Serialize};

/// An index's kind, as a campaign file names it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "UPPERCASE")]
pub enum IndexKind {
    /// Absolute knowledge error.
    Ake,
    /// Relative knowledge error.
    Rke,
    /// Knowledge drift error.
    Kde,
}

/// One index with its windows.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "UPPERCASE")]
pub enum Index {
    /// Absolute knowledge error.
    Ake,
    /// Relative knowledge error over windows of `window_s`.
    Rke {
        /// Δt, s.
        window_s: f64,
    },
    /// Knowledge drift error: windows of `window_s`, their starts `separation_s` apart.
    Kde {
        /// Δt, s.
        window_s: f64,
        /// Δt_s, s.
        separation_s: f64,
    },
}

impl Index {
    /// Its name, the stem of its keys: `AKE`, `RKE_10s`, `KDE_10s_100s`.
    pub fn name(&self) -> String {
        match self {
            Index::Ake => "AKE".into(),
            Index::Rke { window_s } => format!("RKE_{window_s}s"),
            Index::Kde { window_s, separation_s } => format!("KDE_{window_s}s_{separation_s}s"),
        }
    }
}

/// What to compute: the indices, from when, and the statistic over time.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct IndexSpec {
    /// Samples before this time are left out, s.
    pub from_s: f64,
    /// The quantile of |index| over time (1: the maximum).
    pub time_fraction: f64,
    /// The indices.
    pub index: Vec<Index>,
}

/// The axis suffixes of the keys.
pub const AXES: [&str; 3] = ["x", "y", "z"];

/// The indices of one run.
pub struct Indices;

impl Indices {
    /// The keys computed for `spec`, in order: `AKE_x`, `AKE_y`, `AKE_z`, `RKE_10s_x`, …
    pub fn keys(spec: &IndexSpec) -> Vec<String> {
        spec.index.iter().flat_map(|i| AXES.map(|a| format!("{}_{a}", i.name()))).collect()
    }

    /// The indices of the knowledge error `err_arcsec` (per axis) sampled at `t_s`
    /// (increasing), as (key, statistic over time) in the order of [`Indices::keys`]; NaN
    /// for an index with no complete window.
    pub fn compute(spec: &IndexSpec, t_s: &[f64], err_arcsec: &[[f64; 3]]) -> Vec<(String, f64)> {
        let n = t_s.len().min(err_arcsec.len());
        let first = t_s[..n].partition_point(|t| *t < spec.from_s);
        let (t, e) = (&t_s[first..n], &err_arcsec[first..n]);
        let mut out = Vec::with_capacity(spec.index.len() * 3);
        let mut values = Vec::with_capacity(t.len());
        for index in &spec.index {
            for (k, axis) in AXES.iter().enumerate() {
                values.clear();
                let x = |j: usize| e[j][k];
                match *index {
                    Index::Ake => values.extend((0..t.len()).map(|j| x(j).abs())),
                    Index::Rke { window_s } => rke(t, &x, spec.from_s, window_s, &mut values),
                    Index::Kde { window_s, separation_s } => kde(t, &x, window_s, separation_s, &mut values),
                }
                out.push((format!("{}_{axis}", index.name()), quantile(&mut values, spec.time_fraction)));
            }
        }
        out
    }
}

/// |e(t) − ē_j| for every sample of every complete window.
fn rke(t: &[f64], x: &impl Fn(usize) -> f64, from_s: f64, window_s: f64, out: &mut Vec<f64>) {
    let Some(&last) = t.last() else { return };
    // Windows wholly before the last sample's time are complete.
    let complete = ((last - from_s) / window_s + 1e-9).floor() as i64;
    let window_of = |tj: f64| ((tj - from_s) / window_s + 1e-9).floor() as i64;
    let mut a = 0;
    while a < t.len() {
        let w = window_of(t[a]);
        let mut b = a;
        while b < t.len() && window_of(t[b]) == w {
            b += 1;
        }
        if w < complete {
            let mean = (a..b).map(x).sum::<f64>() / (b - a) as f64;
            out.extend((a..b).map(|j| (x(j) - mean).abs()));
        }
        a = b;
    }
}

/// |ē(t + Δt_s) − ē(t)| for every sample time t whose two windows are complete.
fn kde(t: &[f64], x: &impl Fn(usize) -> f64, window_s: f64, separation_s: f64, out: &mut Vec<f64>) {
    let n = t.len();
    let mut prefix = Vec::with_capacity(n + 1);
    prefix.push(0.0);
    let mut s = 0.0;
    for j in 0..n {
        s += x(j);
        prefix.push(s);
    }
    let eps = 1e-9 * window_s.max(separation_s);
    // The first sample at or after a time, moving forward with it.
    let first_from = |from: &mut usize, time: f64| {
        while *from < n && t[*from] < time - eps {
            *from += 1;
        }
        *from
    };
    let mean = |a: usize, b: usize| (prefix[b] - prefix[a]) / (b - a) as f64;
    let (mut end1, mut start2, mut end2) = (0, 0, 0);
    for (a, &ta) in t.iter().enumerate() {
        let b = first_from(&mut end1, ta + window_s);
        let c = first_from(&mut start2, ta + separation_s);
        let d = first_from(&mut end2, ta + separation_s + window_s);
        // Complete: a sample at or after each window's end exists.
        if d >= n || b <= a || d <= c {
            break;
        }
        out.push((mean(c, d) - mean(a, b)).abs());
    }
}

/// The `q` quantile of `v` (the smallest order statistic with at least q·n at or below
/// it; q = 1: the maximum); NaN when empty.
pub fn quantile(v: &mut [f64], q: f64) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    if q >= 1.0 {
        return v.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    }
    let k = ((q * v.len() as f64).ceil() as usize).clamp(1, v.len()) - 1;
    let (_, x, _) = v.select_nth_unstable_by(k, f64::total_cmp);
    *x
}

#[cfg(test)]
mod tests {
    use super::*;

    fn spec(index: Vec<Index>, q: f64) -> IndexSpec {
        IndexSpec { from_s: 0.0, time_fraction: q, index }
    }

    #[test]
    fn a_constant_error_has_no_relative_error_and_no_drift() {
        let t: Vec<f64> = (0..1000).map(|k| k as f64 * 0.1).collect();
        let e = vec![[3.0, -2.0, 0.5]; 1000];
        let s = spec(
            vec![Index::Ake, Index::Rke { window_s: 10.0 }, Index::Kde { window_s: 5.0, separation_s: 20.0 }],
            1.0,
        );
        let r = Indices::compute(&s, &t, &e);
        assert_eq!(r[0], ("AKE_x".to_string(), 3.0));
        assert_eq!(r[1].1, 2.0);
        for (k, v) in &r[3..] {
            assert!(v.abs() < 1e-12, "{k} = {v}");
        }
    }

    #[test]
    fn a_ramp_drifts_by_its_rate_times_the_separation() {
        // e = 0.5 t: KDE = 0.5 Δt_s exactly, RKE max = 0.5 (Δt − dt)/2 (window mean at its middle).
        let dt = 0.01;
        let t: Vec<f64> = (0..10_000).map(|k| k as f64 * dt).collect();
        let e: Vec<[f64; 3]> = t.iter().map(|t| [0.5 * t, 0.0, 0.0]).collect();
        let s = spec(vec![Index::Rke { window_s: 2.0 }, Index::Kde { window_s: 1.0, separation_s: 7.0 }], 1.0);
        let r = Indices::compute(&s, &t, &e);
        assert!((r[0].1 - 0.5 * (2.0 - dt) / 2.0).abs() < 1e-9, "{r:?}");
        assert!((r[3].1 - 3.5).abs() < 1e-9, "{r:?}");
    }

    #[test]
    fn quantile_is_an_order_statistic() {
        let mut v: Vec<f64> = (1..=100).map(f64::from).collect();
        assert_eq!(quantile(&mut v, 0.95), 95.0);
        assert_eq!(quantile(&mut v, 1.0), 100.0);
        assert_eq!(quantile(&mut v, 0.001), 1.0);
        assert!(quantile(&mut [], 0.5).is_nan());
    }
}
