//! The largest |residual| of a fit on every row, made provable without a second pass: per
//! segment of rows the box of its basis vectors and the rows that may reach the bound.

use super::*;

/// Rows of the first segment (held until the fit on them ranks them).
pub const FIRST_SEGMENT: usize = 16_384;

impl Extremes {
    /// Rows of segment k: the first, then twice as many as the segment before, up to
    /// `segment`.
    pub fn len_of(&self, k: usize) -> usize {
        match k {
            0 => self.first,
            _ => self.first.saturating_mul(1 << (k - 1).min(32)).min(self.segment),
        }
    }

    /// Samples in the first `k` segments.
    pub fn rows_in(&self, k: usize) -> usize {
        (0..k).map(|i| self.len_of(i)).sum()
    }
}

/// One segment's candidates for the largest |residual| of one FOG: its rows, in order, cut
/// into boxes of a few seconds; per box, the range of each z̃_a, the two largest and the two
/// smallest r = ell·z̃ under the segment's ranking functional, and the rows of the largest and
/// the smallest.
#[derive(Debug, Clone, Default)]
pub struct SegmentExtremes {
    /// The ranking functional ℓ_s (shifted basis): the all-rows fit of the rows before.
    pub ell: Vec<f64>,
    /// Rows per box.
    pub box_rows: usize,
    /// Per box, per slot, the smallest z̃_a (box-major, m a box).
    pub lo: Vec<f64>,
    /// Per box, per slot, the largest z̃_a.
    pub hi: Vec<f64>,
    /// Per box: the largest r, the second largest, the smallest, the second smallest (−∞ or
    /// +∞ where the box has too few rows).
    pub r: Vec<[f64; 4]>,
    /// Per box, the rows of the largest and of the smallest r (box-major, 2m a box).
    pub rows: Vec<f64>,
    /// Rows offered so far.
    seen: usize,
}

impl SegmentExtremes {
    fn new(box_rows: usize) -> Self {
        SegmentExtremes { box_rows: box_rows.max(1), ..Default::default() }
    }

    /// The bound on |ℓ·z̃| of the segment's rows not stored, for a residual functional ℓ.
    /// In a box (lo ≤ z̃ ≤ hi, centre c, half widths h), with d = ℓ − ℓ_s, a row has
    /// ℓ·z̃ = ℓ_s·z̃ + d·z̃ and d·z̃ within d·c ± Σ_a |d_a| h_a; a row not stored has ℓ_s·z̃
    /// between the box's second smallest and second largest. The largest over the boxes, plus
    /// 10⁻¹² of Σ_a max|z̃_a| (|ℓ_a| + |ℓ_s,a|) for the rounding of the sums (each a few
    /// ulps). A box is a few seconds of a session, where the reference rate and the
    /// temperature hardly move: d·z̃ is nearly the constant d·c there, however far the two
    /// fits are apart, and the bound is close to the box's own extremes under ℓ.
    pub fn bound(&self, ell: &[f64]) -> f64 {
        let m = ell.len().max(1);
        let mut worst = 0.0f64;
        for ((lo, hi), r) in self.lo.chunks_exact(m).zip(self.hi.chunks_exact(m)).zip(&self.r) {
            let [_, below_top, _, above_bottom] = *r;
            if below_top < above_bottom {
                continue; // every row of the box stored
            }
            let (mut dc, mut dh, mut scale) = (0.0, 0.0, 0.0);
            for (((&lo, &hi), &l), &ls) in lo.iter().zip(hi).zip(ell).zip(&self.ell) {
                let (c, h, d) = (0.5 * (lo + hi), 0.5 * (hi - lo), l - ls);
                dc += d * c;
                dh += d.abs() * h;
                scale += lo.abs().max(hi.abs()) * (l.abs() + ls.abs());
            }
            let b = (below_top + dc + dh).max(-(above_bottom + dc - dh)) + 1e-12 * scale;
            worst = worst.max(b);
        }
        worst
    }

    /// Takes `rows` rows with their r: slot a of the k-th is `cols[a * stride + k]`.
    fn take(&mut self, rows: usize, m: usize, r: &[f64], cols: &[f64], stride: usize) {
        let mut k0 = 0;
        while k0 < rows {
            let (bx, within) = ((self.seen + k0) / self.box_rows, (self.seen + k0) % self.box_rows);
            let k1 = rows.min(k0 + self.box_rows - within);
            if self.r.len() <= bx {
                self.lo.resize((bx + 1) * m, f64::INFINITY);
                self.hi.resize((bx + 1) * m, f64::NEG_INFINITY);
                self.r.resize(bx + 1, [f64::NEG_INFINITY, f64::NEG_INFINITY, f64::INFINITY, f64::INFINITY]);
                self.rows.resize((bx + 1) * 2 * m, 0.0);
            }
            let (lo, hi) = (&mut self.lo[bx * m..(bx + 1) * m], &mut self.hi[bx * m..(bx + 1) * m]);
            for (a, (lo, hi)) in lo.iter_mut().zip(hi.iter_mut()).enumerate() {
                // Four running minima and maxima (exact, the values finite: any order gives
                // the same values).
                let col = &cols[a * stride + k0..a * stride + k1];
                let (mut l, mut h) = ([*lo; 4], [*hi; 4]);
                let mut quads = col.chunks_exact(4);
                for c in &mut quads {
                    for q in 0..4 {
                        l[q] = if c[q] < l[q] { c[q] } else { l[q] };
                        h[q] = if c[q] > h[q] { c[q] } else { h[q] };
                    }
                }
                for &v in quads.remainder() {
                    l[0] = if v < l[0] { v } else { l[0] };
                    h[0] = if v > h[0] { v } else { h[0] };
                }
                *lo = l[0].min(l[1]).min(l[2].min(l[3]));
                *hi = h[0].max(h[1]).max(h[2].max(h[3]));
            }
            let t = &mut self.r[bx];
            let stored = &mut self.rows[bx * 2 * m..(bx + 1) * 2 * m];
            for (k, &v) in r.iter().enumerate().take(k1).skip(k0) {
                if v > t[1] {
                    if v > t[0] {
                        (t[1], t[0]) = (t[0], v);
                        stored[..m].iter_mut().enumerate().for_each(|(a, x)| *x = cols[a * stride + k]);
                    } else {
                        t[1] = v;
                    }
                }
                if v < t[3] {
                    if v < t[2] {
                        (t[3], t[2]) = (t[2], v);
                        stored[m..].iter_mut().enumerate().for_each(|(a, x)| *x = cols[a * stride + k]);
                    } else {
                        t[3] = v;
                    }
                }
            }
            k0 = k1;
        }
        self.seen += rows;
    }

    /// Takes row `z` (r = ell·z summed in slot order).
    fn offer(&mut self, z: &[f64], m: usize) {
        let r: f64 = self.ell.iter().zip(z).fold(0.0, |s, (a, b)| s + a * b);
        self.take(1, m, &[r], z, 1);
    }

    /// [`SegmentExtremes::offer`] for a batch of rows held column-major in `cols` (m columns
    /// of [`BATCH`] values, [`COL`] apart, rows past `rows` zero): every r summed side by side over the
    /// rows, each in slot order from 0 (as `offer` sums it: the same bits).
    fn offer_batch(&mut self, cols: &[f64], rows: usize, m: usize) {
        let mut r = [0.0f64; BATCH];
        for (e, col) in self.ell.iter().zip(cols.chunks_exact(COL)) {
            for (r, v) in r.iter_mut().zip(col) {
                *r += e * v;
            }
        }
        self.take(rows, m, &r, cols, COL);
    }
}

/// What makes the largest |residual| over every row provable after one pass: the session cut
/// into segments (the first [`FIRST_SEGMENT`] rows, then each twice the one before up to 1/64
/// of the session or that many, whichever is more; the early fits are the least sure, their
/// segments the shortest), each segment's rows ranked under the fit of every row before it
/// (the first segment: under its own fit) box by box, a few seconds a box, at most 8192
/// boxes (the memory is bounded): [`SegmentExtremes`]. For final coefficients with residual
/// functional ℓ, the rows stored are evaluated and every other row is bounded
/// ([`SegmentExtremes::bound`]); when the largest |ℓ·z̃| of the stored rows is at least every
/// segment's bound, it is the maximum over all rows (`super::fit` checks; otherwise it reads
/// again the segments up to the last whose bound is above).
#[derive(Debug, Clone, Default)]
pub struct Extremes {
    /// Rows in the first segment.
    pub first: usize,
    /// Rows per later segment at most ([`Extremes::len_of`]).
    pub segment: usize,
    /// Per segment, per FOG.
    pub segs: Vec<Vec<SegmentExtremes>>,
}

/// The running side of [`Extremes`] during a pass.
pub(super) struct Tracker {
    pub(super) kinds: Vec<Kind>,
    pub(super) out: Extremes,
    /// Rows of the first segment, per FOG (ranked once its fit is known).
    pub(super) first: Vec<Vec<f64>>,
}

impl Tracker {
    /// Offers a summed batch (`rows` rows, m columns [`COL`] apart per FOG) to the current
    /// segment's extremes, or holds its rows (row-major) while the first segment is open.
    pub(super) fn offer_batch(&mut self, batch: &[Vec<f64>], rows: usize, m: usize) {
        match self.out.segs.last_mut() {
            None => {
                for (f, b) in self.first.iter_mut().zip(batch.iter()) {
                    for i in 0..rows {
                        f.extend((0..m).map(|a| b[a * COL + i]));
                    }
                }
            }
            Some(seg) => {
                for (x, b) in seg.iter_mut().zip(batch.iter()) {
                    x.offer_batch(b, rows, m);
                }
            }
        }
    }

    /// Starts a segment ranked under the all-rows fit of the sums so far; at the end of the
    /// first segment, first ranks the rows held under that same fit.
    pub(super) fn open_segment(&mut self, basis: &Basis, shift: &[Vec<f64>], gram: &[Vec<Gram>], box_rows: usize) {
        let m = basis.m;
        let ells: Vec<Vec<f64>> =
            (0..shift.len()).map(|fog| self.running_ell(basis, &shift[fog], &gram[fog], fog)).collect();
        if self.out.segs.is_empty() {
            // The first segment, ranked under its own fit.
            let mut seg = Vec::new();
            for (fog, ell) in ells.iter().enumerate() {
                let mut x = SegmentExtremes::new(box_rows);
                x.ell = ell.clone();
                for row in self.first[fog].chunks_exact(m) {
                    x.offer(row, m);
                }
                seg.push(x);
            }
            self.out.segs.push(seg);
            self.first = Vec::new();
        }
        self.out.segs.push(
            ells.into_iter()
                .map(|ell| {
                    let mut x = SegmentExtremes::new(box_rows);
                    x.ell = ell;
                    x
                })
                .collect(),
        );
    }

    /// The residual functional of the all-rows fit of the sums so far, FOG `fog`.
    fn running_ell(&self, basis: &Basis, shift: &[f64], gram: &[Gram], fog: usize) -> Vec<f64> {
        let mut g = Gram::new(basis.m);
        for x in gram {
            g.add(x);
        }
        let sh = |l: &[f64]| shifted(l, shift);
        let mut cols: Vec<Vec<f64>> = Vec::new();
        for k in &self.kinds {
            if let Ok(f) = basis.functionals(k, fog) {
                cols.extend(f.iter().map(|l| sh(l)));
            }
        }
        cols.push(sh(&basis.y_functional()));
        let ls = lstsq_gram(&design_gram(&g, &cols), g.n);
        residual_functional(&cols, &ls.coef)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    /// The box bound holds for every row: a segment of rows with a slow drift in one slot
    /// (a temperature) and steps in others (a rate table), ranked under one functional and
    /// checked under others far from it; every row's |ℓ·z̃| is at most the larger of the
    /// bound and the stored rows' largest. Batches of odd sizes cross the boxes' edges.
    #[test]
    fn box_bound_holds_for_every_row() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        let (m, n, box_rows) = (5usize, 5000usize, 300usize);
        let rows: Vec<Vec<f64>> = (0..n)
            .map(|k| {
                let step = ((k / 700) % 3) as f64 - 1.0;
                vec![1.0, step, 0.002 * k as f64, step.abs(), rng.random_range(-1.0..1.0)]
            })
            .collect();
        for trial in 0..20 {
            let ell_s: Vec<f64> = (0..m).map(|a| if a == m - 1 { 1.0 } else { rng.random_range(-1.0..1.0) }).collect();
            let mut x = SegmentExtremes::new(box_rows);
            x.ell = ell_s;
            let mut k = 0;
            while k < n {
                let rows_now = (1 + (k * 7 + trial) % BATCH).min(n - k);
                let mut cols = vec![0.0; COL * m];
                for i in 0..rows_now {
                    for a in 0..m {
                        cols[a * COL + i] = rows[k + i][a];
                    }
                }
                x.offer_batch(&cols, rows_now, m);
                k += rows_now;
            }
            assert_eq!(x.r.len(), n.div_ceil(box_rows));
            for _ in 0..20 {
                let ell: Vec<f64> =
                    (0..m).map(|a| if a == m - 1 { 1.0 } else { rng.random_range(-2.0..2.0) }).collect();
                let eval = |z: &[f64]| z.iter().zip(&ell).map(|(a, b)| a * b).sum::<f64>().abs();
                let stored = x.rows.chunks_exact(m).map(eval).fold(0.0, f64::max);
                let worst = rows.iter().map(|z| eval(z)).fold(0.0, f64::max);
                let bound = x.bound(&ell);
                assert!(worst <= stored.max(bound), "trial {trial}: a row at {worst}, stored {stored}, bound {bound}");
                // The stored rows are rows of the segment.
                assert!(stored <= worst);
            }
        }
    }
}
