//! Thermal sensitivity: the paper's two-factor analysis of variance (Tables 1 and 2) and the
//! 3rd-order polynomial model in T and G, fitted only when the analysis says it is worth it.
//!
//! Design (Table 1): factor T at u1 = 4 levels (10, 20, 30, 40 °C), factor G at u2 = 3
//! levels (−0.25, 0, +0.25 °C/min); cell (j, g) holds m_v plots (2, or 4 for G = 0) of N
//! measurements over 20 min (N = 240 000 at 5 ms); the plots are averaged, Y_jgi =
//! (1/m_v) Σ_k Y_jgi^(k), Y = ω − ω*, ω* = ω_E sin φ. Table 1 leaves out the cells
//! (10 °C, −0.25 °C/min) and (40 °C, +0.25 °C/min), so n = 10 cells (the paper's "ten
//! experiments"); its (40 °C, 0) row shows two plots, so m_v = 2 there.
//!
//! The paper's estimates, as printed (the row and column means over the cells present):
//!
//! ```text
//! s0²  = Σ(Y − Ȳ)²/(M − 1),                            ν0 = M − 1,      M = nN
//! sε²  = (1/n) Σ_jg Σ_i (Y_jgi − Ȳ_jg)²/(N − 1),       νε = n(N − 1)
//! sT²  = u2 N/(u1 − 1) Σ_j (Ȳ_j − Ȳ)²,                  νT = u1 − 1
//! sG²  = u1 N/(u2 − 1) Σ_g (Ȳ'_g − Ȳ)²,                 νG = u2 − 1
//! sTG² = N/νTG Σ_jg (Ȳ_jg − Ȳ_j − Ȳ'_g + Ȳ)²,           νTG = ν0 − νε − νT − νG
//! F_T = sT²/sTG² vs F_q(νT, νTG),  F_G = sG²/sTG² vs F_q(νG, νTG),  F_TG = sTG²/sε² vs F_q(νTG, νε)
//! ```
//!
//! For the paper's design νT = 3, νG = 2, νTG = n − 6 = 4, νε = 10·239 999; the critical
//! values are F_0.05(3,4) = 6.59, F_0.01(3,4) = 16.69, F_0.05(2,4) = 6.94,
//! F_0.01(2,4) = 18.00 (Table 2 exactly), F_0.01(4, νε) = 3.32 (Table 2) and
//! F_0.05(4, νε) = 2.37, where Table 2 prints 2.32: F_0.05(4, ν) decreases with ν to its
//! limit 2.372, so no ν gives 2.32 — a misprint in the paper.
//!
//! **What the printed formulas do with an unbalanced design.** The row mean Ȳ_j runs over
//! different G levels in different rows (row 1 lacks G = −0.25, row 4 lacks G = +0.25), so
//! purely additive effects leave a residue in the "interaction" sum and the ratios are
//! capped: noise-free, a pure linear T effect gives F_T = 13.33 (and F_G = 2.67), a pure
//! linear G effect F_G = 16.0 (and F_T = 2.0), whatever their size. The paper's batch I
//! F_G = 20.42 is above that cap, so its G effect was not linear in G. On this design the
//! F-ratios are set by the shape of the effects more than by the noise; F_TG (against the
//! within-cell noise, νε ≈ 2.4·10⁶) is large whenever any effect is.
//!
//! **Decision.** The paper builds a temperature-drift model for batch I (F_T significant at
//! q = 5 %) and calls it inefficient for batch II (F_T not significant, although F_G and F_TG
//! are). [`Anova::model_worth_building`] follows that: the temperature factor T must be
//! significant at 5 %.
//!
//! The model (the table's thermal terms, `docs/CALIBRATION.md`):
//! y = b + a1 ΔT + a2 ΔT² + a3 ΔT³ + g G + h ΔT G, ΔT = T − T_ref.

use anyhow::{bail, Result};
use nalgebra::{DMatrix, DVector};
use rand::SeedableRng;
use rand_chacha::ChaCha20Rng;
use rand_distr::{Distribution, StandardNormal};
use statrs::distribution::{ContinuousCDF, FisherSnedecor};

/// One cell of Table 1: factor levels and the (plot-averaged) measurements Y_jgi.
#[derive(Debug, Clone)]
pub struct Cell {
    /// j, level of T (0-based).
    pub t_level: usize,
    /// g, level of G (0-based).
    pub g_level: usize,
    /// Y_jgi, i = 1…N (already averaged over the m_v plots), any unit.
    pub y: Vec<f64>,
}

/// One F-test of Table 2.
#[derive(Debug, Clone, Copy)]
pub struct FTest {
    /// The ratio of variances.
    pub f: f64,
    /// Numerator degrees of freedom.
    pub nu1: f64,
    /// Denominator degrees of freedom.
    pub nu2: f64,
    /// Critical value at q = 5 %.
    pub crit_5: f64,
    /// Critical value at q = 1 %.
    pub crit_1: f64,
    /// p-value.
    pub p: f64,
}

impl FTest {
    /// Significant at q = 5 %.
    pub fn significant_5(&self) -> bool {
        self.f > self.crit_5
    }
    /// Significant at q = 1 %.
    pub fn significant_1(&self) -> bool {
        self.f > self.crit_1
    }
}

/// The analysis of variance of Table 2.
#[derive(Debug, Clone)]
pub struct Anova {
    /// u1, u2: numbers of levels of T and G.
    pub levels: (usize, usize),
    /// n: cells present.
    pub n_cells: usize,
    /// N: measurements per cell.
    pub n_per_cell: usize,
    /// s0², sε², sT², sG², sTG².
    pub s2: [f64; 5],
    /// ν0, νε, νT, νG, νTG.
    pub nu: [f64; 5],
    /// F_T.
    pub t: FTest,
    /// F_G.
    pub g: FTest,
    /// F_TG.
    pub tg: FTest,
}

impl Anova {
    /// The paper's decision: a temperature-drift model is worth building when T is
    /// significant at q = 5 % (batch I), not otherwise (batch II).
    pub fn model_worth_building(&self) -> bool {
        self.t.significant_5()
    }
}

/// Upper-q critical value of F(ν1, ν2).
pub fn f_critical(nu1: f64, nu2: f64, q: f64) -> Result<f64> {
    let d = FisherSnedecor::new(nu1, nu2).map_err(|e| anyhow::anyhow!("F({nu1}, {nu2}): {e}"))?;
    Ok(d.inverse_cdf(1.0 - q))
}

fn ftest(f: f64, nu1: f64, nu2: f64) -> Result<FTest> {
    let d = FisherSnedecor::new(nu1, nu2).map_err(|e| anyhow::anyhow!("F({nu1}, {nu2}): {e}"))?;
    Ok(FTest { f, nu1, nu2, crit_5: d.inverse_cdf(0.95), crit_1: d.inverse_cdf(0.99), p: d.sf(f) })
}

/// Degrees of freedom of the paper's design for `n_cells` cells of `n` measurements,
/// `u1` × `u2` levels: (ν0, νε, νT, νG, νTG).
pub fn degrees_of_freedom(u1: usize, u2: usize, n_cells: usize, n: usize) -> [f64; 5] {
    let m = (n_cells * n) as f64;
    let nu0 = m - 1.0;
    let nue = (n_cells * (n - 1)) as f64;
    let nut = u1 as f64 - 1.0;
    let nug = u2 as f64 - 1.0;
    [nu0, nue, nut, nug, nu0 - nue - nut - nug]
}

/// The paper's two-factor analysis of variance (module doc) of `cells`.
pub fn anova(cells: &[Cell], u1: usize, u2: usize) -> Result<Anova> {
    let n_cells = cells.len();
    let Some(n) = cells.first().map(|c| c.y.len()) else { bail!("ANOVA: no cells") };
    if n < 2 || cells.iter().any(|c| c.y.len() != n) {
        bail!("ANOVA: every cell needs the same number N ≥ 2 of measurements");
    }
    if cells.iter().any(|c| c.t_level >= u1 || c.g_level >= u2) {
        bail!("ANOVA: a cell's level is outside {u1} x {u2}");
    }
    for j in 0..u1 {
        if !cells.iter().any(|c| c.t_level == j) {
            bail!("ANOVA: T level {} has no cell", j + 1);
        }
    }
    for g in 0..u2 {
        if !cells.iter().any(|c| c.g_level == g) {
            bail!("ANOVA: G level {} has no cell", g + 1);
        }
    }
    let nf = n as f64;
    let means: Vec<f64> = cells.iter().map(|c| c.y.iter().sum::<f64>() / nf).collect();
    let total = means.iter().sum::<f64>() / n_cells as f64;
    let row = |j: usize| {
        let v: Vec<f64> = cells.iter().zip(&means).filter(|(c, _)| c.t_level == j).map(|(_, m)| *m).collect();
        v.iter().sum::<f64>() / v.len() as f64
    };
    let colm = |g: usize| {
        let v: Vec<f64> = cells.iter().zip(&means).filter(|(c, _)| c.g_level == g).map(|(_, m)| *m).collect();
        v.iter().sum::<f64>() / v.len() as f64
    };
    let rows: Vec<f64> = (0..u1).map(row).collect();
    let cols: Vec<f64> = (0..u2).map(colm).collect();
    let mut ss0 = 0.0;
    let mut se = 0.0;
    for (c, m) in cells.iter().zip(&means) {
        let mut within = 0.0;
        for y in &c.y {
            ss0 += (y - total) * (y - total);
            within += (y - m) * (y - m);
        }
        se += within / (nf - 1.0);
    }
    let nu = degrees_of_freedom(u1, u2, n_cells, n);
    if nu[4] < 1.0 {
        bail!("ANOVA: no degrees of freedom left for the interaction ({n_cells} cells, {u1} x {u2} levels)");
    }
    let s0 = ss0 / nu[0];
    let se2 = se / n_cells as f64;
    let st = u2 as f64 * nf / nu[2] * rows.iter().map(|r| (r - total).powi(2)).sum::<f64>();
    let sg = u1 as f64 * nf / nu[3] * cols.iter().map(|c| (c - total).powi(2)).sum::<f64>();
    let stg = nf / nu[4]
        * cells.iter().zip(&means).map(|(c, m)| (m - rows[c.t_level] - cols[c.g_level] + total).powi(2)).sum::<f64>();
    Ok(Anova {
        levels: (u1, u2),
        n_cells,
        n_per_cell: n,
        s2: [s0, se2, st, sg, stg],
        nu,
        t: ftest(st / stg, nu[2], nu[4])?,
        g: ftest(sg / stg, nu[3], nu[4])?,
        tg: ftest(stg / se2, nu[4], nu[1])?,
    })
}

/// The cells of Table 1: (j, g, m_v), 0-based levels; (10 °C, −0.25) and (40 °C, +0.25)
/// absent.
pub const TABLE1_CELLS: [(usize, usize, usize); 10] =
    [(0, 1, 4), (0, 2, 2), (1, 0, 2), (1, 1, 4), (1, 2, 2), (2, 0, 2), (2, 1, 4), (2, 2, 2), (3, 0, 2), (3, 1, 2)];
/// T levels of Table 1, °C.
pub const TABLE1_T_DEGC: [f64; 4] = [10.0, 20.0, 30.0, 40.0];
/// G levels of Table 1, °C/min.
pub const TABLE1_G_DEGC_MIN: [f64; 3] = [-0.25, 0.0, 0.25];
/// N of the paper: 20 min at 5 ms.
pub const TABLE1_N: usize = 240_000;

/// A simulated batch: FOG drift y = a1 ΔT + a2 ΔT² + g G + h ΔT G + per-plot offset
/// (run-to-run repeatability) + white noise, in the Table 1 design.
#[derive(Debug, Clone, Copy)]
pub struct BatchSim {
    /// a1, a2, a3: rad/s per °C^k (ΔT = T − 25 °C).
    pub a_rad_s: [f64; 3],
    /// g: rad/s per °C/s.
    pub g_rad_s_per_degc_s: f64,
    /// h: rad/s per °C²/s.
    pub h_rad_s_per_degc2_s: f64,
    /// Per-plot offset, 1σ, rad/s (turn-on repeatability: what makes the cell means scatter).
    pub plot_sigma_rad_s: f64,
    /// Angle random walk, °/√h.
    pub arw_deg_sqrt_h: f64,
    /// Sample interval, s (5 ms in the paper).
    pub dt_s: f64,
    /// N per plot.
    pub n: usize,
}

const DEG_H: f64 = std::f64::consts::PI / 180.0 / 3600.0;

impl BatchSim {
    /// Batch I: a temperature effect −0.005 °/h/°C + 0.0003 °/h/°C² (about 25 °C), a
    /// gradient effect 0.3 °/h per °C/min, 0.005 °/h plot-to-plot scatter.
    pub fn batch_i() -> Self {
        BatchSim {
            a_rad_s: [-0.005 * DEG_H, 0.0003 * DEG_H, 0.0],
            g_rad_s_per_degc_s: 0.3 * 60.0 * DEG_H,
            h_rad_s_per_degc2_s: 0.0,
            plot_sigma_rad_s: 0.005 * DEG_H,
            arw_deg_sqrt_h: 0.005,
            dt_s: 0.005,
            n: TABLE1_N,
        }
    }
    /// Batch II: the same gradient effect, no temperature effect.
    pub fn batch_ii() -> Self {
        BatchSim { a_rad_s: [0.0; 3], ..Self::batch_i() }
    }

    /// The drift at (T, G), rad/s.
    pub fn drift_rad_s(&self, t_degc: f64, g_degc_s: f64) -> f64 {
        let dt = t_degc - 25.0;
        self.a_rad_s[0] * dt
            + self.a_rad_s[1] * dt * dt
            + self.a_rad_s[2] * dt.powi(3)
            + self.g_rad_s_per_degc_s * g_degc_s
            + self.h_rad_s_per_degc2_s * dt * g_degc_s
    }

    /// The Table 1 cells (plots averaged), and all plots as (T, G, y) means over blocks of
    /// `decimate` samples, for the model fit (none for 0).
    pub fn simulate(&self, seed: u64, decimate: usize) -> (Vec<Cell>, Vec<[f64; 3]>) {
        let mut rng = ChaCha20Rng::seed_from_u64(seed);
        let sigma = self.arw_deg_sqrt_h.to_radians() / 60.0 / self.dt_s.sqrt();
        let mut cells = Vec::new();
        let mut samples = Vec::new();
        let span_s = self.n as f64 * self.dt_s;
        for &(j, g, mv) in &TABLE1_CELLS {
            let g_degc_s = TABLE1_G_DEGC_MIN[g] / 60.0;
            let mut y = vec![0.0; self.n];
            for _ in 0..mv {
                let z: f64 = StandardNormal.sample(&mut rng);
                let offset = self.plot_sigma_rad_s * z;
                let mut acc = [0.0; 2];
                for (i, yi) in y.iter_mut().enumerate() {
                    // The chamber ramps through the level: T = T_j + G (t − span/2).
                    let t = (i as f64 + 0.5) * self.dt_s;
                    let temp = TABLE1_T_DEGC[j] + g_degc_s * (t - span_s / 2.0);
                    let n: f64 = StandardNormal.sample(&mut rng);
                    let v = self.drift_rad_s(temp, g_degc_s) + offset + sigma * n;
                    *yi += v / mv as f64;
                    if decimate > 0 {
                        acc[0] += temp;
                        acc[1] += v;
                        if (i + 1) % decimate == 0 {
                            samples.push([acc[0] / decimate as f64, g_degc_s, acc[1] / decimate as f64]);
                            acc = [0.0; 2];
                        }
                    }
                }
            }
            cells.push(Cell { t_level: j, g_level: g, y });
        }
        (cells, samples)
    }
}

/// The 3rd-order thermal model of the table: y = b + a1 ΔT + a2 ΔT² + a3 ΔT³ + g G + h ΔT G.
#[derive(Debug, Clone, Copy)]
pub struct ThermalModel {
    /// T_ref, °C.
    pub t_ref_degc: f64,
    /// b, rad/s (goes into the bias).
    pub bias_rad_s: f64,
    /// a1, a2, a3.
    pub a_rad_s: [f64; 3],
    /// g.
    pub g_rad_s_per_degc_s: f64,
    /// h.
    pub h_rad_s_per_degc2_s: f64,
    /// Residual RMS, rad/s.
    pub rms_rad_s: f64,
}

/// Fits the model to (T °C, G °C/s, y rad/s) samples. With fewer than 4 distinct
/// temperatures the cubic is not identifiable and the fit refuses.
pub fn fit_model(samples: &[[f64; 3]], t_ref_degc: f64) -> Result<ThermalModel> {
    if samples.len() < 10 {
        bail!("thermal model: too few samples ({})", samples.len());
    }
    // Scale the regressors to order 1 for conditioning.
    let (ts, gs) = (10.0, 0.25 / 60.0);
    let a = DMatrix::from_fn(samples.len(), 6, |r, c| {
        let dt = (samples[r][0] - t_ref_degc) / ts;
        let g = samples[r][1] / gs;
        match c {
            0 => 1.0,
            1 => dt,
            2 => dt * dt,
            3 => dt * dt * dt,
            4 => g,
            _ => dt * g,
        }
    });
    let b = DVector::from_iterator(samples.len(), samples.iter().map(|s| s[2]));
    let (x, _) = super::lstsq(&a, &b)?;
    let rms = ((&a * &x - &b).norm_squared() / samples.len() as f64).sqrt();
    Ok(ThermalModel {
        t_ref_degc,
        bias_rad_s: x[0],
        a_rad_s: [x[1] / ts, x[2] / (ts * ts), x[3] / ts.powi(3)],
        g_rad_s_per_degc_s: x[4] / gs,
        h_rad_s_per_degc2_s: x[5] / (ts * gs),
        rms_rad_s: rms,
    })
}

/// The paper's procedure: the analysis of variance first, the model only when worth it
/// (Table 1's 4 × 3 levels).
pub fn analyse_and_fit(cells: &[Cell], samples: &[[f64; 3]], t_ref_degc: f64) -> Result<(Anova, Option<ThermalModel>)> {
    analyse_and_fit_levels(cells, samples, (TABLE1_T_DEGC.len(), TABLE1_G_DEGC_MIN.len()), t_ref_degc)
}

/// [`analyse_and_fit`] for `levels` = (u1, u2) levels of T and G.
pub fn analyse_and_fit_levels(
    cells: &[Cell],
    samples: &[[f64; 3]],
    levels: (usize, usize),
    t_ref_degc: f64,
) -> Result<(Anova, Option<ThermalModel>)> {
    let a = anova(cells, levels.0, levels.1)?;
    let m = if a.model_worth_building() { Some(fit_model(samples, t_ref_degc)?) } else { None };
    Ok((a, m))
}

/// The levels a chamber session is sorted into: a sample belongs to level j of T when its
/// temperature is within half the smallest spacing of the levels from T_j, likewise for G.
#[derive(Debug, Clone, PartialEq)]
pub struct Levels {
    /// T levels, °C.
    pub t_degc: Vec<f64>,
    /// G levels, °C/min.
    pub g_degc_min: Vec<f64>,
}

impl Default for Levels {
    /// Table 1's design.
    fn default() -> Self {
        Levels { t_degc: TABLE1_T_DEGC.to_vec(), g_degc_min: TABLE1_G_DEGC_MIN.to_vec() }
    }
}

/// The level of `levels` that `x` belongs to (within half the smallest spacing).
fn level_of(levels: &[f64], x: f64) -> Option<usize> {
    let half = half_spacing(levels);
    levels.iter().position(|l| (x - l).abs() < half)
}

/// The temperature rate G = dT/dt at each sample, °C/s: the slope of the least-squares line
/// through the temperatures within ±`window_s`/2 (prefix sums, one pass).
pub fn temperature_rate(t_s: &[f64], temp_degc: &[f64], window_s: f64) -> Vec<f64> {
    let n = t_s.len();
    let t0 = t_s.first().copied().unwrap_or(0.0);
    let mut pre = vec![[0.0f64; 5]; n + 1];
    for k in 0..n {
        let (t, y) = (t_s[k] - t0, temp_degc[k]);
        let p = pre[k];
        pre[k + 1] = [p[0] + 1.0, p[1] + t, p[2] + y, p[3] + t * t, p[4] + t * y];
    }
    let (mut lo, mut hi) = (0usize, 0usize);
    (0..n)
        .map(|k| {
            while t_s[lo] < t_s[k] - window_s / 2.0 {
                lo += 1;
            }
            while hi < n && t_s[hi] <= t_s[k] + window_s / 2.0 {
                hi += 1;
            }
            let s: Vec<f64> = (0..5).map(|j| pre[hi][j] - pre[lo][j]).collect();
            let den = s[0] * s[3] - s[1] * s[1];
            if s[0] < 2.0 || den <= 0.0 {
                0.0
            } else {
                (s[0] * s[4] - s[1] * s[2]) / den
            }
        })
        .collect()
}

/// A user's chamber session sorted into the design's cells, for FOG `fog`.
#[derive(Debug, Clone)]
pub struct Chamber {
    /// The cells present, each cut to the same N (the smallest cell's).
    pub cells: Vec<Cell>,
    /// (T °C, G °C/s, y rad/s), block means of the samples in cells, for the model fit.
    pub samples: Vec<[f64; 3]>,
    /// Samples that fell in no cell (between levels: transitions).
    pub outside: usize,
    /// Samples per cell before the cut, in the order of `cells`.
    pub counts: Vec<usize>,
}

/// Sorts FOG `fog` of a chamber session into the cells of `levels` (module doc), with
/// Y = ω − s⁰·ω_ref (the FOG's output less the reference rate along its nominal axis) and G
/// from the FOG's temperature over a `window_s` window. Refused, saying what the session
/// lacks: the FOG, its temperature column, a level of T or G with no sample, or cells too
/// small.
pub fn chamber_cells(s: &ssis_session::Session, fog: usize, levels: &Levels, window_s: f64) -> Result<Chamber> {
    let file = &s.file;
    let Some(f) = s.fogs.get(fog) else {
        bail!("{file}: the session has no `fog{fog}_rad_s` (or `fog{fog}_rad`) column: no FOG{fog} output")
    };
    let Some(temp) = f.t_degc.as_ref() else {
        bail!(
            "{file}: the session lacks `fog{fog}_t_degc`: the thermal analysis needs the FOG's temperature \
             (docs/SESSION-FORMAT.md)"
        )
    };
    let axis = ssis_session::nominal_axes()[fog.min(3)];
    let t_s = s.t_s();
    let g = temperature_rate(t_s, temp, window_s);
    let mut by_cell: Vec<((usize, usize), Vec<usize>)> = Vec::new();
    let mut outside = 0;
    for k in 0..t_s.len() {
        match (level_of(&levels.t_degc, temp[k]), level_of(&levels.g_degc_min, g[k] * 60.0)) {
            (Some(j), Some(l)) => match by_cell.iter_mut().find(|c| c.0 == (j, l)) {
                Some(c) => c.1.push(k),
                None => by_cell.push(((j, l), vec![k])),
            },
            _ => outside += 1,
        }
    }
    for (j, tl) in levels.t_degc.iter().enumerate() {
        if !by_cell.iter().any(|c| c.0 .0 == j) {
            bail!(
                "{file}: no sample of FOG{fog} at T = {tl} °C (±{:.3} °C) at any of the G levels: the session lacks \
                 that temperature level (levels {:?} °C; --t-levels-degc sets them)",
                half_spacing(&levels.t_degc),
                levels.t_degc
            );
        }
    }
    for (l, gl) in levels.g_degc_min.iter().enumerate() {
        if !by_cell.iter().any(|c| c.0 .1 == l) {
            bail!(
                "{file}: no sample of FOG{fog} at G = {gl} °C/min (±{:.3} °C/min, G from `fog{fog}_t_degc` over \
                 {window_s:.0} s) at any T level: the session lacks that gradient level (levels {:?} °C/min; \
                 --g-levels-degc-min sets them)",
                half_spacing(&levels.g_degc_min),
                levels.g_degc_min
            );
        }
    }
    by_cell.sort_by_key(|c| c.0);
    let n = by_cell.iter().map(|c| c.1.len()).min().unwrap_or(0);
    if n < 2 {
        let thin = by_cell
            .iter()
            .filter(|c| c.1.len() < 2)
            .map(|((j, l), ks)| {
                format!("T {} °C, G {} °C/min: {} sample(s)", levels.t_degc[*j], levels.g_degc_min[*l], ks.len())
            })
            .collect::<Vec<_>>()
            .join("; ");
        bail!("{file}: FOG{fog}: a cell of the design needs at least 2 samples: {thin}");
    }
    let y = |k: usize| {
        let w = s.ref_rad_s[k];
        f.rate_rad_s[k] - (axis.x * w[0] + axis.y * w[1] + axis.z * w[2])
    };
    let cells = by_cell
        .iter()
        .map(|((j, l), ks)| Cell { t_level: *j, g_level: *l, y: ks.iter().take(n).map(|&k| y(k)).collect() })
        .collect();
    let used: usize = by_cell.iter().map(|c| c.1.len()).sum();
    let block = used.div_ceil(20_000).max(1);
    let mut samples = Vec::new();
    for (_, ks) in &by_cell {
        for chunk in ks.chunks(block) {
            let m = chunk.len() as f64;
            let mean = |v: &dyn Fn(usize) -> f64| chunk.iter().map(|&k| v(k)).sum::<f64>() / m;
            samples.push([mean(&|k| temp[k]), mean(&|k| g[k]), mean(&y)]);
        }
    }
    Ok(Chamber { cells, samples, outside, counts: by_cell.iter().map(|c| c.1.len()).collect() })
}

fn half_spacing(levels: &[f64]) -> f64 {
    levels.windows(2).map(|w| (w[1] - w[0]).abs()).fold(f64::INFINITY, f64::min) / 2.0
}
