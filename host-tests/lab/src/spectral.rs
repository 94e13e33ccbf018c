//! The spectral search of the training residual: lines (a periodic bias that follows no
//! column) found on the training blocks' real time stamps, to be judged on the test blocks.
//!
//! The training blocks are the even blocks of ten, separated by gaps as long as a block; a
//! periodogram that joined them into one record would break a line's phase at every gap and
//! move its peak to a sidelobe. The search here is the generalised least-squares
//! (Lomb–Scargle with a floating mean) periodogram over the gapped record, every sample at
//! its own time:
//!
//! 1. **Grid.** The training rows, in runs of `g` consecutive rows inside one block (their
//!    means, weighted by their count, at their mean time; `g` = 1 unless the grid would
//!    pass `max_frequencies`), are fitted by (1, sin 2πft, cos 2πft) at frequencies from
//!    1.5/span to the runs' Nyquist frequency, spaced 1/(3 span): the drop in the weighted
//!    sum of squares is each FOG's power P(f).
//! 2. **Background.** Each FOG's power is divided by its background: the residual's spectrum
//!    under the FOG's noise model (white plus its Gauss–Markov Lorentzians,
//!    [`super::noise::row_spectrum_of_means`]; flat without one) times the median over
//!    the whole grid of the power over that spectrum, times 2 ln 2. The median of hundreds of
//!    independent frequencies is known to a few per cent, so the normalised power of a FOG
//!    without a line is χ²₂ far into its tail (a median over a few tens of neighbours, off by
//!    a third, would multiply the tail at the search's threshold by orders of magnitude).
//!    The FOGs' normalised powers add (χ² with ν = 2 × FOGs degrees of freedom).
//! 3. **Peak.** The largest normalised powers of the grid, each refined by nonlinear least
//!    squares in the frequency (amplitude and phase profiled out: golden-section search of
//!    the exact power of every training row at its real time, over one grid step either
//!    side); the largest refined power is the peak.
//! 4. **False-alarm probability.** The maximum of a χ²_ν process over a band B of
//!    frequencies, not of B × span independent ones: by Rice's formula the expected number
//!    of upcrossings of a level u is B · 2√π σ_t · u^((ν−1)/2) e^(−u/2) / (2^((ν−2)/2) Γ(ν/2)),
//!    σ_t the spread of the training rows' times (the rate at which the periodogram
//!    decorrelates in frequency), and the probability that the maximum passes u is
//!    1 − exp(−(tail_ν(u) + upcrossings)) ([`max_tail`]).
//! 5. **More lines.** The line's fit is taken out of the training residual and the search
//!    repeated, while the false-alarm probability stays below [`LINE_FAP`] (at most
//!    [`MAX_LINES`] lines); then, for each line found, its harmonics 2f … 4f (an orbital
//!    period and its multiples) at their exact frequencies, kept when their power's tail
//!    is below [`LINE_FAP`] / 3 (three frequencies tried, none searched).
//!
//! The first line is always returned (as the strongest line of the residual, whatever its
//! false-alarm probability): the test blocks judge it, as they judge every candidate.

use statrs::distribution::{ChiSquared, ContinuousCDF};
use statrs::function::gamma::ln_gamma;

use super::noise::{row_spectrum_of_means, NoiseModel};

/// Largest false-alarm probability of a line after the first (and of a harmonic, ×3).
pub const LINE_FAP: f64 = 0.01;
/// At most this many lines are searched for.
pub const MAX_LINES: usize = 4;
/// Local maxima of the grid refined, per line.
const PEAKS_JUDGED: usize = 6;
/// Local maxima against a flat background added to those (first line, with a refit).
const PEAKS_REFIT: usize = 2;

/// A line found in the training residual.
#[derive(Debug, Clone, PartialEq)]
pub struct Line {
    /// Frequency, Hz (refined).
    pub f_hz: f64,
    /// False-alarm probability corrected for the frequencies searched (for a harmonic: the
    /// tail at its one frequency, × 3).
    pub fap: f64,
    /// Normalised power, pooled over FOGs (χ² with 2 × FOGs degrees of freedom under no line).
    pub power: f64,
    /// `Some((k, f0))`: the k-th harmonic of the line at f0 Hz.
    pub harmonic_of: Option<(usize, f64)>,
}

/// The search's inputs: training rows' times, s, and per FOG their residual.
#[derive(Debug, Clone)]
pub struct Record<'a> {
    /// Times of the training rows, s (increasing).
    pub t_s: &'a [f64],
    /// Block of each training row.
    pub block: &'a [usize],
    /// Per FOG, the residual at those rows.
    pub res: Vec<Vec<f64>>,
    /// Interval of the rows, s (the session's interval times the kept stride).
    pub dt_s: f64,
    /// The session's span, s.
    pub span_s: f64,
    /// Per FOG, the noise model of the residual (the background's shape); `None`: white.
    pub noise: Option<&'a [NoiseModel]>,
    /// Session rows each of the rows is the mean of.
    pub rows_averaged: usize,
}

/// Probability that the maximum over a band of `band_hz` of the pooled normalised power
/// (χ² with `nu` degrees of freedom at each frequency) of a record whose times spread
/// `t_sd_s` (standard deviation) passes `u`: 1 − exp(−(tail_ν(u) + expected upcrossings of
/// u)), Rice's formula (see the module text), for u above ν − 1 (below, its value at ν − 1).
pub fn max_tail(u: f64, nu: f64, band_hz: f64, t_sd_s: f64) -> f64 {
    let Ok(chi) = ChiSquared::new(nu) else { return 1.0 };
    if u <= 0.0 {
        return 1.0;
    }
    // The upcrossing rate peaks at u = ν − 1; below, the tail's bound is its value there.
    let uu = u.max(nu - 1.0);
    let ln_up = (band_hz * 2.0 * std::f64::consts::PI.sqrt() * t_sd_s).max(f64::MIN_POSITIVE).ln()
        + 0.5 * (nu - 1.0) * uu.ln()
        - 0.5 * uu
        - 0.5 * (nu - 2.0) * std::f64::consts::LN_2
        - ln_gamma(0.5 * nu);
    let e = chi.sf(u) + ln_up.exp();
    (-(-e).exp_m1()).clamp(0.0, 1.0)
}

/// Weighted standard deviation of times `t` (weights `w`), s.
pub fn time_spread_s(t: &[f64], w: &[f64]) -> f64 {
    let sw: f64 = w.iter().sum();
    if sw <= 0.0 {
        return 0.0;
    }
    let m = t.iter().zip(w).map(|(t, w)| t * w).sum::<f64>() / sw;
    (t.iter().zip(w).map(|(t, w)| w * (t - m) * (t - m)).sum::<f64>() / sw).sqrt()
}

/// Frequencies the search covers on a session of `span_s` sampled every `dt_s`, with at
/// most `max_frequencies` grid points: (f_min, f_max), Hz.
pub fn searchable_range(span_s: f64, dt_s: f64, max_frequencies: usize) -> (f64, f64) {
    let g = group_rows(span_s, dt_s, max_frequencies);
    (1.5 / span_s, 0.5 / (g as f64 * dt_s))
}

/// Rows per run so that the grid stays within `max_frequencies` points.
fn group_rows(span_s: f64, dt_s: f64, max_frequencies: usize) -> usize {
    (3.0 * span_s * 0.5 / dt_s / max_frequencies.max(1) as f64).ceil().max(1.0) as usize
}

/// Weighted series: per run the mean time, weight and per FOG the mean residual.
struct Runs {
    t: Vec<f64>,
    w: Vec<f64>,
    y: Vec<Vec<f64>>,
}

fn runs(r: &Record, g: usize) -> Runs {
    let n_fog = r.res.len();
    let mut out = Runs { t: Vec::new(), w: Vec::new(), y: vec![Vec::new(); n_fog] };
    let mut start = 0;
    while start < r.t_s.len() {
        let mut end = start + 1;
        while end < r.t_s.len() && end - start < g && r.block[end] == r.block[start] {
            end += 1;
        }
        let n = (end - start) as f64;
        out.t.push(r.t_s[start..end].iter().sum::<f64>() / n);
        out.w.push(n);
        for (y, res) in out.y.iter_mut().zip(&r.res) {
            y.push(res[start..end].iter().sum::<f64>() / n);
        }
        start = end;
    }
    out
}

/// Weighted LS power per FOG at grid frequencies f_min + k df (k < nf), by rotation.
fn grid_power(s: &Runs, f_min: f64, df: f64, nf: usize) -> Vec<Vec<f64>> {
    let n_fog = s.y.len();
    let two_pi = 2.0 * std::f64::consts::PI;
    let mut acc = vec![[0.0f64; 5]; nf];
    let mut rsc = vec![0.0f64; nf * 2 * n_fog];
    let mut sum_w = 0.0;
    let mut sum_y = vec![0.0; n_fog];
    let mut sum_yy = vec![0.0; n_fog];
    let mut r = vec![0.0; n_fog];
    for j in 0..s.t.len() {
        let w = s.w[j];
        let (mut sn, mut cs) = (two_pi * f_min * s.t[j]).sin_cos();
        let (ds, dc) = (two_pi * df * s.t[j]).sin_cos();
        sum_w += w;
        for (i, v) in r.iter_mut().enumerate() {
            *v = w * s.y[i][j];
            sum_y[i] += *v;
            sum_yy[i] += *v * s.y[i][j];
        }
        for (k, a) in acc.iter_mut().enumerate() {
            let (ws, wc) = (w * sn, w * cs);
            a[0] += ws;
            a[1] += wc;
            a[2] += ws * sn;
            a[3] += ws * cs;
            a[4] += wc * cs;
            let x = &mut rsc[k * 2 * n_fog..(k + 1) * 2 * n_fog];
            for (i, v) in r.iter().enumerate() {
                x[2 * i] += v * sn;
                x[2 * i + 1] += v * cs;
            }
            (sn, cs) = (sn * dc + cs * ds, cs * dc - sn * ds);
        }
    }
    let mut out = vec![vec![0.0; nf]; n_fog];
    for (k, a) in acc.iter().enumerate() {
        let m = nalgebra::Matrix3::new(sum_w, a[0], a[1], a[0], a[2], a[3], a[1], a[3], a[4]);
        let lu = m.lu();
        for i in 0..n_fog {
            let b = nalgebra::Vector3::new(sum_y[i], rsc[k * 2 * n_fog + 2 * i], rsc[k * 2 * n_fog + 2 * i + 1]);
            if let Some(sol) = lu.solve(&b) {
                out[i][k] = (sol.dot(&b) - sum_y[i] * sum_y[i] / sum_w).max(0.0);
            }
        }
    }
    out
}

/// Exact LS power per FOG at one frequency over weighted points (t, w, y per FOG), and the
/// fitted (mean, sin, cos) coefficients.
fn power_at(t: &[f64], w: &[f64], y: &[Vec<f64>], f: f64) -> Vec<(f64, [f64; 3])> {
    let two_pi = 2.0 * std::f64::consts::PI;
    let mut m = nalgebra::Matrix3::<f64>::zeros();
    let n_fog = y.len();
    let mut b = vec![nalgebra::Vector3::<f64>::zeros(); n_fog];
    for j in 0..t.len() {
        let (sn, cs) = (two_pi * f * t[j]).sin_cos();
        let x = nalgebra::Vector3::new(1.0, sn, cs);
        m += w[j] * x * x.transpose();
        for (bi, yi) in b.iter_mut().zip(y) {
            *bi += w[j] * yi[j] * x;
        }
    }
    let lu = m.lu();
    b.iter()
        .map(|bi| match lu.solve(bi) {
            Some(sol) => ((sol.dot(bi) - bi[0] * bi[0] / m[(0, 0)]).max(0.0), [sol[0], sol[1], sol[2]]),
            None => (0.0, [0.0; 3]),
        })
        .collect()
}

/// The background of one FOG's power `p` on the grid f_min + k df (see the module text):
/// the shape `shape(f)` times the median over the grid of p / shape.
fn background(p: &[f64], f_min: f64, df: f64, shape: &impl Fn(f64) -> f64) -> (Vec<f64>, f64) {
    let sh: Vec<f64> = (0..p.len()).map(|k| shape(f_min + df * k as f64)).collect();
    let mut ratio: Vec<f64> = p.iter().zip(&sh).map(|(p, s)| if *s > 0.0 { p / s } else { 0.0 }).collect();
    let mid = ratio.len() / 2;
    let med = if ratio.is_empty() { 0.0 } else { *ratio.select_nth_unstable_by(mid, f64::total_cmp).1 };
    (sh.iter().map(|s| s * med).collect(), med)
}

/// Lines in the training residual (see the module text), strongest first; frequencies within
/// 1/span of one in `exclude` (lines the model already has) are not searched.
pub fn search(r: &Record, max_frequencies: usize, exclude: &[f64]) -> Vec<Line> {
    search_refit(r, max_frequencies, exclude, None)
}

/// Per FOG, the noise model of the residual with a line at a frequency (Hz) taken out, on the
/// rows searched (each row its own: no averaging); `None` where it cannot be fitted.
pub type Refit<'a> = &'a dyn Fn(f64) -> Option<Vec<NoiseModel>>;

/// [`search`] where each peak is judged against the background shape of the noise model of
/// the residual without it (`refit`): a line in the residual is partly taken up by the noise
/// model's Gauss–Markov terms (a bump of the background under the line, which lowers its
/// normalised power); the residual without the line has none.
pub fn search_refit(r: &Record, max_frequencies: usize, exclude: &[f64], refit: Option<Refit>) -> Vec<Line> {
    let n_fog = r.res.len();
    if r.t_s.len() < 16 || n_fog == 0 || r.span_s <= 0.0 {
        return Vec::new();
    }
    let g = group_rows(r.span_s, r.dt_s, max_frequencies);
    let (f_min, f_max) = searchable_range(r.span_s, r.dt_s, max_frequencies);
    if f_max <= f_min {
        return Vec::new();
    }
    let df = 1.0 / (3.0 * r.span_s);
    let nf = ((f_max - f_min) / df).floor() as usize + 1;
    if nf < 8 {
        return Vec::new();
    }
    let nu = 2.0 * n_fog as f64;
    let chi = ChiSquared::new(nu).ok();
    let tail = |z: f64| chi.as_ref().map_or(1.0, |c| c.sf(z));
    let ln4 = 2.0 * std::f64::consts::LN_2;
    let shape = |i: usize, f: f64| -> f64 {
        r.noise.and_then(|nm| nm.get(i)).map_or(1.0, |nm| row_spectrum_of_means(nm, f, r.dt_s, r.rows_averaged))
    };
    let mut rows = runs(r, 1);
    let t_sd = time_spread_s(&rows.t, &rows.w);
    let mut lines: Vec<Line> = Vec::new();
    for _ in 0..MAX_LINES {
        let grouped = if g > 1 { runs(&Record { res: rows.y.clone(), ..r.clone() }, g) } else { runs_clone(&rows) };
        let p = grid_power(&grouped, f_min, df, nf);
        let bgm: Vec<(Vec<f64>, f64)> =
            p.iter().enumerate().map(|(i, pf)| background(pf, f_min, df, &|f| shape(i, f))).collect();
        let z = |k: usize| -> f64 {
            (0..n_fog).map(|i| if bgm[i].0[k] > 0.0 { ln4 * p[i][k] / bgm[i].0[k] } else { 0.0 }).sum::<f64>()
        };
        // The exact pooled normalised power at any frequency.
        let exact = |rows: &Runs, f: f64| -> f64 {
            power_at(&rows.t, &rows.w, &rows.y, f)
                .iter()
                .enumerate()
                .map(|(i, (pw, _))| {
                    let b = shape(i, f) * bgm[i].1;
                    if b > 0.0 {
                        ln4 * pw / b
                    } else {
                        0.0
                    }
                })
                .sum()
        };
        // The strongest local maxima of the grid's normalised power, each refined; with a
        // refit, also those against a flat background (a line the noise model took up in part
        // may rank low against its shape).
        let flat_med: Vec<f64> = p.iter().map(|pf| background(pf, f_min, df, &|_| 1.0).1).collect();
        let z_flat = |k: usize| -> f64 {
            (0..n_fog).map(|i| if flat_med[i] > 0.0 { ln4 * p[i][k] / flat_med[i] } else { 0.0 }).sum::<f64>()
        };
        let top = |zf: &dyn Fn(usize) -> f64, count: usize| -> Vec<usize> {
            let mut peaks: Vec<(usize, f64)> = Vec::new();
            for k in 0..nf {
                let f = f_min + df * k as f64;
                let near = |e: &f64| (f - e).abs() < 1.0 / r.span_s;
                if exclude.iter().any(near) || lines.iter().any(|l| near(&l.f_hz)) {
                    continue;
                }
                let zk = zf(k);
                let left = k == 0 || zf(k - 1) <= zk;
                let right = k + 1 >= nf || zf(k + 1) < zk;
                if left && right {
                    peaks.push((k, zk));
                }
            }
            peaks.sort_by(|a, b| b.1.total_cmp(&a.1));
            peaks.into_iter().take(count).map(|(k, _)| k).collect()
        };
        let use_refit = refit.is_some() && lines.is_empty();
        let mut peaks = top(&z, PEAKS_JUDGED);
        if use_refit {
            for k in top(&z_flat, PEAKS_REFIT) {
                if !peaks.contains(&k) {
                    peaks.push(k);
                }
            }
        }
        // Refine on every training row at its own time (amplitude and phase profiled out).
        let mut refined: Vec<(f64, f64)> = peaks
            .iter()
            .map(|&k| {
                let f0 = f_min + df * k as f64;
                let f = golden_max(&|f| exact(&rows, f), (f0 - df).max(0.5 * f_min), f0 + df, 1e-6 * df);
                (f, exact(&rows, f))
            })
            .collect();
        // Each judged again against the noise model of the residual without it.
        if let Some(rf) = refit.filter(|_| use_refit) {
            for (f, zf) in refined.iter_mut() {
                let Some(nms) = rf(*f) else { continue };
                let pw = power_at(&rows.t, &rows.w, &rows.y, *f);
                *zf = (0..n_fog)
                    .map(|i| {
                        let Some(nm) = nms.get(i) else { return 0.0 };
                        let sh = |f: f64| row_spectrum_of_means(nm, f, r.dt_s, 1);
                        let b = sh(*f) * background(&p[i], f_min, df, &sh).1;
                        if b > 0.0 {
                            ln4 * pw[i].0 / b
                        } else {
                            0.0
                        }
                    })
                    .sum();
            }
        }
        let best = refined.iter().copied().max_by(|a, b| a.1.total_cmp(&b.1));
        let Some((f, pz)) = best else { break };
        let fap = max_tail(pz, nu, f_max - f_min, t_sd);
        if !lines.is_empty() && fap > LINE_FAP {
            break;
        }
        lines.push(Line { f_hz: f, fap, power: pz, harmonic_of: None });
        if fap > LINE_FAP {
            break;
        }
        remove_line(&mut rows, f);
    }
    // Harmonics of each significant line, at their exact frequencies, against the background
    // of the residual without the lines found.
    let fundamentals: Vec<f64> = lines.iter().filter(|l| l.fap <= LINE_FAP).map(|l| l.f_hz).collect();
    let meds: Vec<f64> = if fundamentals.is_empty() {
        Vec::new()
    } else {
        let grouped = if g > 1 { runs(&Record { res: rows.y.clone(), ..r.clone() }, g) } else { runs_clone(&rows) };
        let p = grid_power(&grouped, f_min, df, nf);
        p.iter().enumerate().map(|(i, pf)| background(pf, f_min, df, &|f| shape(i, f)).1).collect()
    };
    for f0 in fundamentals {
        for h in 2..=4usize {
            let f = h as f64 * f0;
            if f > f_max || lines.iter().any(|l| (l.f_hz - f).abs() < 1.0 / r.span_s) {
                continue;
            }
            let zh: f64 = power_at(&rows.t, &rows.w, &rows.y, f)
                .iter()
                .enumerate()
                .map(|(i, (pw, _))| {
                    let b = shape(i, f) * meds[i];
                    if b > 0.0 {
                        ln4 * pw / b
                    } else {
                        0.0
                    }
                })
                .sum();
            let p_h = (3.0 * tail(zh)).min(1.0);
            if p_h <= LINE_FAP / 3.0 {
                lines.push(Line { f_hz: f, fap: p_h, power: zh, harmonic_of: Some((h, f0)) });
                remove_line(&mut rows, f);
            }
        }
    }
    lines
}

fn runs_clone(r: &Runs) -> Runs {
    Runs { t: r.t.clone(), w: r.w.clone(), y: r.y.clone() }
}

/// Takes each FOG's LS fit of (1, sin, cos) at `f` out of the rows.
fn remove_line(rows: &mut Runs, f: f64) {
    let fits = power_at(&rows.t, &rows.w, &rows.y, f);
    let two_pi = 2.0 * std::f64::consts::PI;
    for (y, (_, c)) in rows.y.iter_mut().zip(fits) {
        for (v, t) in y.iter_mut().zip(&rows.t) {
            let (sn, cs) = (two_pi * f * t).sin_cos();
            *v -= c[0] + c[1] * sn + c[2] * cs;
        }
    }
}

/// Maximum of `h` on [a, b] by golden-section search to a width `tol`.
fn golden_max(h: &impl Fn(f64) -> f64, mut a: f64, mut b: f64, tol: f64) -> f64 {
    let r = 0.5 * (5f64.sqrt() - 1.0);
    let (mut c, mut d) = (b - r * (b - a), a + r * (b - a));
    let (mut hc, mut hd) = (h(c), h(d));
    for _ in 0..100 {
        if b - a <= tol {
            break;
        }
        if hc > hd {
            b = d;
            d = c;
            hd = hc;
            c = b - r * (b - a);
            hc = h(c);
        } else {
            a = c;
            c = d;
            hc = hd;
            d = a + r * (b - a);
            hd = h(d);
        }
    }
    0.5 * (a + b)
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_distr::{Distribution, Normal};

    /// A line whose phase runs through the gaps of the even blocks is found at its frequency.
    #[test]
    fn line_through_gaps() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(1);
        let n01 = Normal::new(0.0, 1.0).unwrap();
        let (n, dt) = (36_000usize, 1.0);
        let f_true = 1.0 / 2400.0;
        let mut t = Vec::new();
        let mut block = Vec::new();
        let mut res = vec![Vec::new(); 2];
        for j in 0..n {
            let b = j * 10 / n;
            if b % 2 == 1 {
                continue;
            }
            let tj = j as f64 * dt;
            t.push(tj);
            block.push(b);
            for y in res.iter_mut() {
                y.push(0.05 * (2.0 * std::f64::consts::PI * f_true * tj).sin() + n01.sample(&mut rng));
            }
        }
        let r = Record { t_s: &t, block: &block, res, dt_s: dt, span_s: n as f64 * dt, noise: None, rows_averaged: 1 };
        let lines = search(&r, 15_000, &[]);
        assert!(!lines.is_empty());
        assert!((lines[0].f_hz / f_true - 1.0).abs() < 0.01, "{lines:?}");
        assert!(lines[0].fap < 1e-3, "{lines:?}");
    }
}
