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
//! 2. **Background.** Each FOG's power is divided by its local background, the median of P
//!    over the grid frequencies within a factor 1.25 of f (at least ±15 and at most ±200
//!    grid points), times 2 ln 2: a line stands against the residual's own spectrum, red
//!    (bias wander) or white, and the normalised power of a FOG without a line is about
//!    χ²₂. The FOGs' normalised powers add (χ² with 2 × FOGs degrees of freedom).
//! 3. **Peak.** The largest normalised power, refined by nonlinear least squares in the
//!    frequency (amplitude and phase profiled out: golden-section search of the exact power
//!    of every training row at its real time, over one grid step either side).
//! 4. **False-alarm probability.** The tail of the χ² at the peak, corrected for the
//!    (f_max − f_min) × span independent frequencies searched: 1 − (1 − p)^M.
//! 5. **More lines.** The line's fit is taken out of the training residual and the search
//!    repeated, while the false-alarm probability stays below [`LINE_FAP`] (at most
//!    [`MAX_LINES`] lines); then, for each line found, its harmonics 2f … 4f (an orbital
//!    period and its multiples) at their exact frequencies, kept when their power's tail
//!    is below [`LINE_FAP`] / 3 (three frequencies tried, none searched).
//!
//! The first line is always returned (as the strongest line of the residual, whatever its
//! false-alarm probability): the test blocks judge it, as they judge every candidate.

use statrs::distribution::{ChiSquared, ContinuousCDF};

/// Largest false-alarm probability of a line after the first (and of a harmonic, ×3).
pub const LINE_FAP: f64 = 0.01;
/// At most this many lines are searched for.
pub const MAX_LINES: usize = 4;
/// Local maxima of the grid judged against the background without them, per line.
const PEAKS_JUDGED: usize = 6;

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

/// Running local median of `p` (see the module text): the background per grid point.
fn background(p: &[f64], f_min: f64, df: f64) -> Vec<f64> {
    let nf = p.len();
    let mut out = vec![0.0; nf];
    let mut win = Vec::new();
    for (k, o) in out.iter_mut().enumerate() {
        let f = f_min + df * k as f64;
        let half = ((0.25 * f / df).round() as usize).clamp(15, 200);
        let (lo, hi) = (k.saturating_sub(half), (k + half + 1).min(nf));
        win.clear();
        win.extend_from_slice(&p[lo..hi]);
        let mid = win.len() / 2;
        let (_, m, _) = win.select_nth_unstable_by(mid, f64::total_cmp);
        *o = *m;
    }
    out
}

/// Lines in the training residual (see the module text), strongest first; frequencies within
/// 1/span of one in `exclude` (lines the model already has) are not searched.
pub fn search(r: &Record, max_frequencies: usize, exclude: &[f64]) -> Vec<Line> {
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
    let m_indep = ((f_max - f_min) * r.span_s).max(1.0);
    let chi = ChiSquared::new(2.0 * n_fog as f64).ok();
    let tail = |z: f64| chi.as_ref().map_or(1.0, |c| c.sf(z));
    let ln4 = 2.0 * std::f64::consts::LN_2;
    let mut rows = runs(r, 1);
    let mut lines: Vec<Line> = Vec::new();
    let mut scale = vec![1.0; n_fog];
    for _ in 0..MAX_LINES {
        let grouped = if g > 1 { runs(&Record { res: rows.y.clone(), ..r.clone() }, g) } else { runs_clone(&rows) };
        let p = grid_power(&grouped, f_min, df, nf);
        let bg: Vec<Vec<f64>> = p.iter().map(|pf| background(pf, f_min, df)).collect();
        let z = |k: usize| -> f64 {
            (0..n_fog).map(|i| if bg[i][k] > 0.0 { ln4 * p[i][k] / bg[i][k] } else { 0.0 }).sum::<f64>()
        };
        // The strongest local maxima of the normalised power (a strong line's sidelobes
        // raise the local median around it: each is judged again against the background of
        // the residual without it).
        let mut peaks: Vec<(usize, f64)> = Vec::new();
        for k in 0..nf {
            let f = f_min + df * k as f64;
            let near = |e: &f64| (f - e).abs() < 1.0 / r.span_s;
            if exclude.iter().any(near) || lines.iter().any(|l| near(&l.f_hz)) {
                continue;
            }
            let zk = z(k);
            let left = k == 0 || z(k - 1) <= zk;
            let right = k + 1 >= nf || z(k + 1) < zk;
            if left && right {
                peaks.push((k, zk));
            }
        }
        peaks.sort_by(|a, b| b.1.total_cmp(&a.1));
        peaks.truncate(PEAKS_JUDGED);
        let mut best: Option<(f64, f64)> = None;
        for &(k, _) in &peaks {
            for (i, s) in scale.iter_mut().enumerate() {
                *s = if bg[i][k] > 0.0 { ln4 / bg[i][k] } else { 0.0 };
            }
            // Refine on every training row at its own time (amplitude and phase profiled out).
            let f0 = f_min + df * k as f64;
            let exact = |f: f64| -> f64 {
                power_at(&rows.t, &rows.w, &rows.y, f).iter().zip(&scale).map(|((p, _), s)| p * s).sum()
            };
            let f = golden_max(&exact, (f0 - df).max(0.5 * f_min), f0 + df, 1e-6 * df);
            let zf = line_free_power(&rows, r, g, f, f_min, df, nf);
            if best.is_none_or(|b| zf > b.1) {
                best = Some((f, zf));
            }
        }
        let Some((f, pz)) = best else { break };
        let fap = 1.0 - (1.0 - tail(pz)).powf(m_indep);
        let fap = if fap.is_finite() { fap.clamp(0.0, 1.0) } else { 1.0 };
        if !lines.is_empty() && fap > LINE_FAP {
            break;
        }
        lines.push(Line { f_hz: f, fap, power: pz, harmonic_of: None });
        if fap > LINE_FAP {
            break;
        }
        remove_line(&mut rows, f);
    }
    // Harmonics of each significant line, at their exact frequencies.
    let fundamentals: Vec<f64> = lines.iter().filter(|l| l.fap <= LINE_FAP).map(|l| l.f_hz).collect();
    for f0 in fundamentals {
        for h in 2..=4usize {
            let f = h as f64 * f0;
            if f > f_max || lines.iter().any(|l| (l.f_hz - f).abs() < 1.0 / r.span_s) {
                continue;
            }
            // Background at the harmonic from the grid's neighbourhood of the current residual.
            let k0 = ((f - f_min) / df).round().max(0.0) as usize;
            let (lo, hi) = (k0.saturating_sub(60), (k0 + 61).min(nf));
            let sub_f = f_min + df * lo as f64;
            let grouped = if g > 1 { runs(&Record { res: rows.y.clone(), ..r.clone() }, g) } else { runs_clone(&rows) };
            let p = grid_power(&grouped, sub_f, df, hi - lo);
            let pw = power_at(&rows.t, &rows.w, &rows.y, f);
            let zh = pooled_power(&p, &pw);
            let p_h = (3.0 * tail(zh)).min(1.0);
            if p_h <= LINE_FAP / 3.0 {
                lines.push(Line { f_hz: f, fap: p_h, power: zh, harmonic_of: Some((h, f0)) });
                remove_line(&mut rows, f);
            }
        }
    }
    lines
}

/// Each FOG's power at a frequency `pw` over the median of its power on a grid window `p`
/// (2 ln 2 × power / median: χ²₂-scaled), summed over the FOGs.
fn pooled_power(p: &[Vec<f64>], pw: &[(f64, [f64; 3])]) -> f64 {
    let ln4 = 2.0 * std::f64::consts::LN_2;
    p.iter()
        .zip(pw)
        .map(|(pf, (ph, _))| {
            let mut v = pf.clone();
            let mid = v.len() / 2;
            let med = *v.select_nth_unstable_by(mid, f64::total_cmp).1;
            if med > 0.0 {
                ln4 * ph / med
            } else {
                0.0
            }
        })
        .sum()
}

/// The normalised power at `f` pooled over FOGs against the background of the rows with the
/// line at `f` taken out (the median of the grid's power within the usual window about f).
fn line_free_power(rows: &Runs, r: &Record, g: usize, f: f64, f_min: f64, df: f64, nf: usize) -> f64 {
    let pw = power_at(&rows.t, &rows.w, &rows.y, f);
    let mut clean = runs_clone(rows);
    remove_line(&mut clean, f);
    let k = ((f - f_min) / df).round().max(0.0) as usize;
    let half = ((0.25 * f / df).round() as usize).clamp(40, 200);
    let (lo, hi) = (k.saturating_sub(half), (k + half + 1).min(nf));
    let (lo, hi) =
        if hi - lo < 2 * half { (hi.saturating_sub(2 * half), (lo + 2 * half + 1).min(nf)) } else { (lo, hi) };
    let grouped = if g > 1 { runs(&Record { res: clean.y.clone(), ..r.clone() }, g) } else { clean };
    let p = grid_power(&grouped, f_min + df * lo as f64, df, hi - lo);
    pooled_power(&p, &pw)
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
        let r = Record { t_s: &t, block: &block, res, dt_s: dt, span_s: n as f64 * dt };
        let lines = search(&r, 15_000, &[]);
        assert!(!lines.is_empty());
        assert!((lines[0].f_hz / f_true - 1.0).abs() < 0.01, "{lines:?}");
        assert!(lines[0].fap < 1e-3, "{lines:?}");
    }
}
