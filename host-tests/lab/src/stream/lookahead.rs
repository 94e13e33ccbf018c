//! G = dT/dt over a stream: samples held back a half window ([`temperature_rate`] on one
//! series, the passes' [`for_each_prepared`]), and [`prepare`] of a session in memory.

use super::*;

/// G = dT/dt of every FOG, as [`temperature_rate`] defines it, over a stream:
/// samples are held until the window ahead of the oldest is complete. They are held as flat
/// records in one array (written and read in order, so the memory is streamed, not chased
/// through each sample's own vectors), with the times and temperatures in flat arrays beside
/// them (the window sums read those); the arrays drop what no later window can use, in
/// chunks.
struct Lookahead {
    half_s: f64,
    n_fog: usize,
    /// Held samples of global index `base ..`, one record each ([`Lookahead::push`]).
    records: Vec<f64>,
    /// f64 per record (0 before the first sample).
    rec: usize,
    /// Times and temperatures (n_fog per sample) of global index `base ..`.
    times: Vec<f64>,
    temps: Vec<f64>,
    base: usize,
    /// Next sample to emit.
    next: usize,
    /// Window of the last emitted sample (true window, before the fallback).
    lo: usize,
    hi: usize,
    /// Summed range [a, b] and its sums about the origin: n, Σu, Σu² (the same for every
    /// FOG), and per FOG Σv, Σuv.
    a: usize,
    b: usize,
    summed: bool,
    sums_t: [f64; 3],
    sums: Vec<[f64; 2]>,
    origin_t: f64,
    origin_temp: Vec<f64>,
    since_origin: usize,
    g: Vec<f64>,
}

impl Lookahead {
    fn new(n_fog: usize, window_s: f64) -> Self {
        Lookahead {
            half_s: window_s / 2.0 * (1.0 + 1e-9),
            n_fog,
            records: Vec::new(),
            rec: 0,
            times: Vec::new(),
            temps: Vec::new(),
            base: 0,
            next: 0,
            lo: 0,
            hi: 0,
            a: 0,
            b: 0,
            summed: false,
            sums_t: [0.0; 3],
            sums: vec![[0.0; 2]; n_fog],
            origin_t: 0.0,
            origin_temp: vec![0.0; n_fog],
            since_origin: 0,
            g: vec![0.0; n_fog],
        }
    }

    #[inline]
    fn t(&self, k: usize) -> f64 {
        self.times[k - self.base]
    }

    /// Holds a copy of a sample's record ([`SampleRef`]; all records of a stream are as
    /// long).
    fn push(&mut self, r: &[f64]) {
        let n = self.n_fog;
        if self.rec == 0 {
            self.rec = r.len();
        }
        self.times.push(r[0]);
        self.temps.extend_from_slice(&r[1 + n..1 + 2 * n]);
        self.records.extend_from_slice(&r[..self.rec]);
    }

    /// Sample k, borrowed from its record.
    #[inline]
    fn load(records: &[f64], rec: usize, n: usize, k: usize) -> SampleRef<'_> {
        SampleRef::of_record(&records[k * rec..(k + 1) * rec], n)
    }

    #[inline]
    fn add(&mut self, k: usize, sign: f64) {
        let u = self.t(k) - self.origin_t;
        let st = &mut self.sums_t;
        st[0] += sign;
        st[1] += sign * u;
        st[2] += sign * u * u;
        let row = (k - self.base) * self.n_fog;
        let temps = &self.temps[row..row + self.n_fog];
        for ((s, &t), &o) in self.sums.iter_mut().zip(temps).zip(&self.origin_temp) {
            let v = t - o;
            s[0] += sign * v;
            s[1] += sign * u * v;
        }
    }

    fn resum(&mut self, a: usize, b: usize, j: usize) {
        self.origin_t = self.t(j);
        let row = (j - self.base) * self.n_fog;
        self.origin_temp.copy_from_slice(&self.temps[row..row + self.n_fog]);
        self.sums_t = [0.0; 3];
        self.sums.iter_mut().for_each(|s| *s = [0.0; 2]);
        for k in a..=b {
            self.add(k, 1.0);
        }
        (self.a, self.b, self.summed, self.since_origin) = (a, b, true, 0);
    }

    /// Drops what no later window can use (from the window's start or the previous sample),
    /// once it is four times what stays (each held record is moved a quarter of a time on
    /// average).
    fn trim(&mut self) {
        let keep_from = self.a.min(self.lo).min(self.next.saturating_sub(1));
        let d = keep_from.saturating_sub(self.base);
        if d >= 4096 && d >= 4 * (self.times.len() - d) {
            self.records.drain(..d * self.rec);
            self.times.drain(..d);
            self.temps.drain(..d * self.n_fog);
            self.base += d;
        }
    }

    /// Emits every sample whose window is complete (all of them at the end, `last`).
    fn drain(&mut self, last: bool, mut f: impl FnMut(usize, &SampleRef, &[f64]) -> LabResult<()>) -> LabResult<()> {
        let end = self.base + self.times.len();
        while self.next < end {
            let j = self.next;
            let tj = self.t(j);
            if !last && self.t(end - 1) <= tj + self.half_s {
                break;
            }
            self.lo = self.lo.max(self.base);
            while self.t(self.lo) < tj - self.half_s {
                self.lo += 1;
            }
            self.hi = self.hi.max(self.lo);
            while self.hi + 1 < end && self.t(self.hi + 1) <= tj + self.half_s {
                self.hi += 1;
            }
            let (a, b) =
                if self.hi > self.lo { (self.lo, self.hi) } else { (j.saturating_sub(1), (j + 1).min(end - 1)) };
            if !self.summed || a < self.a || b < self.b || self.since_origin > 4096.max(4 * (b - a + 1)) {
                self.resum(a, b, j);
            } else {
                while self.b < b {
                    self.b += 1;
                    self.add(self.b, 1.0);
                }
                while self.a < a {
                    self.add(self.a, -1.0);
                    self.a += 1;
                }
            }
            self.since_origin += 1;
            // The least-squares slope of T over the window: (n Σuv − Σu Σv) / (n Σu² − (Σu)²).
            let [n, su, suu] = self.sums_t;
            let den = n * suu - su * su;
            for (g, s) in self.g.iter_mut().zip(&self.sums) {
                *g = if den.abs() < 1e-300 { 0.0 } else { (n * s[1] - su * s[0]) / den };
            }
            f(j, &Self::load(&self.records, self.rec, self.n_fog, j - self.base), &self.g)?;
            self.next += 1;
        }
        self.trim();
        Ok(())
    }
}

/// Runs the samples of `source` through the G window: `f(j, sample, G per FOG)` for every
/// sample j in order.
pub fn for_each_prepared(
    source: Source,
    n_fog: usize,
    g_window_s: f64,
    progress: Option<&ProgressBar>,
    f: impl FnMut(usize, &SampleRef, &[f64]) -> LabResult<()>,
) -> LabResult<usize> {
    for_each_prepared_until(source, n_fog, g_window_s, progress, usize::MAX, f)
}

/// [`for_each_prepared`] for the samples before `limit` only (reading stops once they are
/// out, a G window past the last of them).
pub fn for_each_prepared_until(
    source: Source,
    n_fog: usize,
    g_window_s: f64,
    progress: Option<&ProgressBar>,
    limit: usize,
    mut f: impl FnMut(usize, &SampleRef, &[f64]) -> LabResult<()>,
) -> LabResult<usize> {
    let mut la = Lookahead::new(n_fog, g_window_s);
    let mut g = |j: usize, s: &SampleRef, g: &[f64]| if j < limit { f(j, s, g) } else { Ok(()) };
    source.for_each(progress, |r| {
        la.push(r);
        la.drain(false, &mut g)?;
        Ok(la.next < limit)
    })?;
    la.drain(true, &mut g)?;
    Ok(la.next.min(limit))
}

/// Temperature rate G = dT/dt of one series: at each sample the slope of the least-squares
/// line through the temperature samples within ±`window_s`/2 (at least the two neighbours;
/// one-sided at the ends). A local line, not a raw difference: the frame's 1/256 °C
/// quantisation would otherwise dominate at short sample intervals. The passes over a
/// session compute the same per FOG with running sums over the window (`Lookahead`).
pub fn temperature_rate(t_s: &[f64], temp_degc: &[f64], window_s: f64) -> Vec<f64> {
    let mut la = Lookahead::new(1, window_s);
    let mut out = Vec::with_capacity(t_s.len());
    let mut rec = Vec::new();
    let mut emit = |_: usize, _: &SampleRef, g: &[f64]| {
        out.push(g[0]);
        Ok(())
    };
    for (&t, &temp) in t_s.iter().zip(temp_degc) {
        write_record(&mut rec, t, [0.0], [temp], [0.0; 3], [0.0; 3], []);
        la.push(&rec);
        let _ = la.drain(false, &mut emit);
    }
    let _ = la.drain(true, &mut emit);
    out
}

/// The quantities every term of a model is built from, per FOG and sample, for a session in
/// memory (for tests and tools that want every row).
#[derive(Debug, Clone)]
pub struct Prepared {
    /// Error of each FOG, y_i = ω_i,raw − s_i⁰·ω_ref, rad/s.
    pub y: Vec<Vec<f64>>,
    /// Nominal input rate of each FOG, r_i = s_i⁰·ω_ref, rad/s.
    pub r: Vec<Vec<f64>>,
    /// ΔT = T_i − T_ref per FOG, °C.
    pub dtemp_degc: Vec<Option<Vec<f64>>>,
    /// G_i, °C/s.
    pub g_degc_s: Vec<Option<Vec<f64>>>,
    /// T_ref, °C.
    pub t_ref_degc: f64,
}

/// y, r, ΔT and G of `session` with the model's T_ref and G window.
pub fn prepare(session: &Session, model: &crate::model::Model) -> LabResult<Prepared> {
    let n_fog = session.fogs.len();
    let window = effective_window_s(model.g_window_s, session.median_dt_s());
    let axes = nominal_axes();
    let has_t: Vec<bool> = session.fogs.iter().map(|f| f.t_degc.is_some()).collect();
    let mut p = Prepared {
        y: vec![Vec::new(); n_fog],
        r: vec![Vec::new(); n_fog],
        dtemp_degc: has_t.iter().map(|&h| h.then(Vec::new)).collect(),
        g_degc_s: has_t.iter().map(|&h| h.then(Vec::new)).collect(),
        t_ref_degc: model.t_ref_degc,
    };
    for_each_prepared(Source::Memory(session), n_fog, window, None, |_, s, g| {
        for i in 0..n_fog {
            let a = axes[i.min(3)];
            let r = a.x * s.ref_rad_s[0] + a.y * s.ref_rad_s[1] + a.z * s.ref_rad_s[2];
            p.r[i].push(r);
            p.y[i].push(s.rate_rad_s[i] - r);
            if let Some(d) = p.dtemp_degc[i].as_mut() {
                d.push(s.t_degc[i] - model.t_ref_degc);
            }
            if let Some(x) = p.g_degc_s[i].as_mut() {
                x.push(g[i]);
            }
        }
        Ok(())
    })?;
    Ok(p)
}
