//! One pass over a session ([`digest`]): the Gram sums per FOG and block, the bins' sums,
//! the kept rows and the gaps in time.

use super::*;

/// What a pass needs to know.
#[derive(Debug, Clone)]
pub struct DigestSpec {
    /// Every term any fit on the digest will use (its sinusoids and expressions get slots).
    pub kinds: Vec<Kind>,
    /// T_ref, °C.
    pub t_ref_degc: f64,
    /// The model's G window, s (0: automatic, [`effective_window_s`]).
    pub g_window_s: f64,
    /// Time blocks.
    pub n_blocks: usize,
    /// Rows kept at most.
    pub keep: usize,
    /// Terms whose all-rows fit's largest |residual| the pass is to make provable without a
    /// second pass ([`Extremes`]), when it does not keep every row.
    pub track: Option<Vec<Kind>>,
}

/// The G window in use: `g_window_s`, or max(2 × the sample interval, 60 s) when it is 0.
pub fn effective_window_s(g_window_s: f64, dt_s: f64) -> f64 {
    if g_window_s > 0.0 {
        g_window_s
    } else {
        (2.0 * dt_s).max(60.0)
    }
}

/// Rows kept by a pass: every `stride`-th, with their basis vectors (shifted) and the
/// quantities residuals are plotted against.
#[derive(Debug, Clone, Default)]
pub struct Kept {
    /// Every this many rows.
    pub stride: usize,
    /// Row indices.
    pub rows: Vec<usize>,
    /// Their times, s.
    pub t_s: Vec<f64>,
    /// Their blocks.
    pub block: Vec<usize>,
    /// Azimuth ψ where the session has it, rad.
    pub psi_rad: Option<Vec<f64>>,
    /// Reference rate, rad/s.
    pub omega_rad_s: Vec<[f64; 3]>,
    /// Field, nT, where the session has it.
    pub field_nt: Option<Vec<[f64; 3]>>,
    /// Per FOG with a temperature: T, °C, and G, °C/s.
    pub temp: Vec<Option<(Vec<f64>, Vec<f64>)>>,
    /// Per FOG, the shifted basis vectors, row-major (rows × m).
    pub z: Vec<Vec<f64>>,
    /// When `stride` > 1, the means of each run of `stride` consecutive rows inside one block
    /// (every row counted; a run across two blocks and the last, shorter run are left out):
    /// their times, s. What a line is searched and tested on ([`Kept::line_rows`]).
    pub mean_t_s: Vec<f64>,
    /// Their blocks.
    pub mean_block: Vec<usize>,
    /// Per FOG, their mean shifted basis vectors, row-major.
    pub mean_z: Vec<Vec<f64>>,
}

/// The running sum of one run of `stride` rows for [`Kept`]'s means.
#[derive(Debug, Clone, Default)]
struct RunSum {
    sum: Vec<f64>,
    block: usize,
    whole: bool,
}

impl RunSum {
    /// Adds row `j` of block `block` (values `v`); `Some(mean)` when it closes a run of
    /// `stride` rows in one block.
    fn add(&mut self, j: usize, block: usize, stride: usize, v: impl Iterator<Item = f64>) -> Option<Vec<f64>> {
        if j.is_multiple_of(stride) {
            self.sum.clear();
            (self.block, self.whole) = (block, true);
        } else if block != self.block {
            self.whole = false;
        }
        if self.sum.is_empty() {
            self.sum.extend(v);
        } else {
            self.sum.iter_mut().zip(v).for_each(|(a, b)| *a += b);
        }
        let n = stride as f64;
        ((j + 1).is_multiple_of(stride) && self.whole).then(|| self.sum.iter().map(|a| a / n).collect())
    }
}

impl Kept {
    /// The rows a spectral line is searched and tested on: (times, s; blocks; per FOG the
    /// shifted basis vectors). Every row of a session kept whole; of a longer one, the means of
    /// runs of `stride` rows, so that every row's information about a line slower than the
    /// run is used (a systematic sample would give up all but one row in `stride`).
    pub fn line_rows(&self) -> (&[f64], &[usize], &[Vec<f64>]) {
        if self.stride > 1 {
            (&self.mean_t_s, &self.mean_block, &self.mean_z)
        } else {
            (&self.t_s, &self.block, &self.z)
        }
    }

    /// Keeps row `j` of block `block`: sample `s`, its G per FOG `g`, its azimuth from
    /// column `psi_col` (the basis vectors are kept by the pass).
    fn push_row(&mut self, j: usize, block: usize, s: &SampleRef, g: &[f64], psi_col: Option<usize>) {
        self.rows.push(j);
        self.t_s.push(s.t_s);
        self.block.push(block);
        if let (Some(p), Some(c)) = (self.psi_rad.as_mut(), psi_col) {
            p.push(s.values[c]);
        }
        self.omega_rad_s.push(s.ref_rad_s);
        if let Some(f) = self.field_nt.as_mut() {
            f.push(s.field_nt);
        }
        for (i, t) in self.temp.iter_mut().enumerate() {
            if let Some((temp, rate)) = t.as_mut() {
                temp.push(s.t_degc[i]);
                rate.push(g[i]);
            }
        }
    }
}

/// One pass over a session: per FOG and block the Gram of the shifted basis, and kept rows.
#[derive(Debug, Clone)]
pub struct Digest {
    /// Session file.
    pub file: String,
    /// Header names.
    pub names: Vec<String>,
    /// User (extra) columns.
    pub extra_columns: Vec<String>,
    /// Samples.
    pub n: usize,
    /// Time blocks.
    pub n_blocks: usize,
    /// Sample interval, s.
    pub dt_s: f64,
    /// Time of the first and last sample, s.
    pub t_span_s: [f64; 2],
    /// The G window used, s.
    pub g_window_s: f64,
    /// The basis.
    pub basis: Basis,
    /// Per FOG, the shift subtracted from each slot (slot 0: none).
    pub shift: Vec<Vec<f64>>,
    /// Per FOG, per block.
    pub gram: Vec<Vec<Gram>>,
    /// Kept rows.
    pub kept: Kept,
    /// Bins of every row (consecutive rows of one block; [`crate::noise`]).
    pub bins: Bins,
    /// Per FOG, the sums of the shifted basis over each bin (bins × m, row-major).
    pub bin_sum: Vec<Vec<f64>>,
    /// Gaps in time: steps of more than [`GAP_FACTOR`] sample intervals.
    pub gaps: Gaps,
    /// Candidates for the largest |residual| (when the spec tracks terms and not every row
    /// is kept).
    pub extremes: Option<Extremes>,
}

/// A step in time of more than this many sample intervals (the median) is a gap.
pub const GAP_FACTOR: f64 = 2.5;

/// The gaps in time of a session ([`GAP_FACTOR`]).
#[derive(Debug, Clone, Default)]
pub struct Gaps {
    /// How many.
    pub count: usize,
    /// The largest: the time before it, s, and its length, s.
    pub largest: Option<(f64, f64)>,
    /// Time missing in all, s (the gaps less one sample interval each).
    pub missing_s: f64,
}

/// Rows summed at a time before they are added to a block's sums (a multiple of 8).
pub(super) const BATCH: usize = 256;

/// The per-bin sums of the basis a pass accumulates, a batch at a time.
struct BinAcc {
    bins: Bins,
    sum: Vec<Vec<f64>>,
    /// The bin of the last row added.
    at: usize,
}

impl BinAcc {
    /// Adds the `rows` rows of a batch (per FOG, m columns [`COL`] apart) whose first row
    /// is row `j0` of the session.
    fn add(&mut self, batch: &[Vec<f64>], j0: usize, rows: usize, m: usize) {
        let mut i = 0;
        while i < rows {
            while self.bins.start.get(self.at + 1).is_some_and(|&e| e <= j0 + i) {
                self.at += 1;
            }
            if self.at >= self.bins.len() {
                return; // rows past the count of the pre-pass (refused after the pass)
            }
            let end = self.bins.start.get(self.at + 1).map_or(rows, |&e| (e - j0).min(rows));
            for (sum, cols) in self.sum.iter_mut().zip(batch) {
                let out = &mut sum[self.at * m..(self.at + 1) * m];
                for (a, o) in out.iter_mut().enumerate() {
                    *o += cols[a * COL + i..a * COL + end].iter().sum::<f64>();
                }
            }
            i = end.max(i + 1);
        }
    }
}

/// The quantities a batch's columns are computed from ([`Basis::fill_batch`]), staged a
/// row at a time, one array of [`BATCH`] rows per quantity (per FOG where it is one).
pub(super) struct Staged {
    pub(super) t_s: Vec<f64>,
    /// Raw rate, rad/s, FOG-major.
    pub(super) rate: Vec<f64>,
    /// T, °C, FOG-major.
    pub(super) temp: Vec<f64>,
    /// G, °C/s, FOG-major.
    pub(super) g: Vec<f64>,
    /// ω_ref, component-major.
    pub(super) w: Vec<f64>,
    /// Field, nT, component-major.
    pub(super) field: Vec<f64>,
    /// The table's bare columns, column-major.
    pub(super) cols: Vec<f64>,
}

impl Staged {
    fn new(n_fog: usize, n_cols: usize) -> Self {
        Staged {
            t_s: vec![0.0; BATCH],
            rate: vec![0.0; n_fog * BATCH],
            temp: vec![0.0; n_fog * BATCH],
            g: vec![0.0; n_fog * BATCH],
            w: vec![0.0; 3 * BATCH],
            field: vec![0.0; 3 * BATCH],
            cols: vec![0.0; n_cols * BATCH],
        }
    }

    /// Stages sample `s` with its G per FOG as row i of the batch.
    #[inline]
    fn put(&mut self, i: usize, s: &SampleRef, g_degc_s: &[f64], gather_cols: &[usize]) {
        self.t_s[i] = s.t_s;
        for (k, ((&x, &t), &g)) in s.rate_rad_s.iter().zip(s.t_degc).zip(g_degc_s).enumerate() {
            self.rate[k * BATCH + i] = x;
            self.temp[k * BATCH + i] = t;
            self.g[k * BATCH + i] = g;
        }
        for k in 0..3 {
            self.w[k * BATCH + i] = s.ref_rad_s[k];
            self.field[k * BATCH + i] = s.field_nt[k];
        }
        for (k, &c) in gather_cols.iter().enumerate() {
            self.cols[k * BATCH + i] = s.values[c];
        }
    }
}

/// Distance between two columns of a batch, f64: a batch's column is [`BATCH`] values and
/// then a gap, so that the columns (written a row at a time, one value each) do not all fall
/// in the same few sets of the L1 cache, as a power-of-two distance makes them.
pub(super) const COL: usize = BATCH + 8;

/// ℓ of the raw basis as a functional of the basis shifted by `shift`: ℓ·z = ℓ·z̃ + (ℓ·shift)·1.
pub(super) fn shifted(l: &[f64], shift: &[f64]) -> Vec<f64> {
    let mut v = l.to_vec();
    v[ONE] += l.iter().zip(shift).map(|(a, b)| a * b).sum::<f64>();
    v
}

/// One pass over `source`.
///
/// Longer than a function should be, for a reason: it is the lab's hot loop. The per-row
/// closure and the batch flush share a dozen locals (the batch, the Gram sums, the counters
/// of block, segment and kept row, the first row's shift); held in one frame they stay
/// registers and stack slots the compiler sees whole, and the pass's speed (BENCHMARKS.md)
/// depends on that. What runs once per segment, batch or kept row is in methods of
/// `Tracker` and [`Kept`].
pub fn digest(source: Source, spec: &DigestSpec, progress: Option<&ProgressBar>) -> LabResult<Digest> {
    let shape = source.shape()?;
    if let Some(pb) = progress {
        pb.set_length(shape.bytes);
    }
    let h = &shape.header;
    let n = shape.samples;
    let nb = spec.n_blocks.max(2);
    let basis = Basis::new(h, &spec.kinds, shape.t_span_s[0], spec.t_ref_degc)?;
    let (m, n_fog) = (basis.m, basis.n_fog);
    let g_window_s = effective_window_s(spec.g_window_s, shape.dt_s);
    let stride = n.div_ceil(spec.keep.max(1)).max(1);
    let psi_col = h.layout.turntable.map(|[p, _]| p);
    let mut kept = Kept {
        stride,
        psi_rad: psi_col.map(|_| Vec::new()),
        field_nt: basis.has_field.then(Vec::new),
        temp: basis.has_temp.iter().map(|&t| t.then(|| (Vec::new(), Vec::new()))).collect(),
        z: vec![Vec::new(); n_fog],
        mean_z: vec![Vec::new(); n_fog],
        ..Kept::default()
    };
    // The runs of the kept means: the time's, and each FOG's basis vectors'.
    let mut run_t = RunSum::default();
    let mut run_z = vec![RunSum::default(); n_fog];
    let mut gram = vec![vec![Gram::new(m); nb]; n_fog];
    let bins = Bins::every_row(n, nb, shape.dt_s);
    let mut bin_acc = BinAcc { sum: vec![vec![0.0; bins.len() * m]; n_fog], bins, at: 0 };
    let mut shift: Vec<Vec<f64>> = Vec::new();
    // Per FOG a batch of rows, column-major (m columns of BATCH values, COL apart) for the Gram sums,
    // and a column of zeros after them (what pads the Gram sums' groups of four).
    let mut batch: Vec<Vec<f64>> = vec![vec![0.0; COL * (m + 1)]; n_fog];
    let (order, shared) = basis.gram_order();
    let (mut batch_rows, mut batch_block) = (0usize, 0usize);
    let mut z = vec![0.0; m];
    // Boxes of a few seconds, at most 8192 in a session (the memory is bounded).
    let box_rows = n.div_ceil(8192).max(1024);
    let mut tracker = spec.track.clone().filter(|_| stride > 1).map(|kinds| Tracker {
        kinds,
        out: Extremes { first: FIRST_SEGMENT, segment: (n / 64).max(FIRST_SEGMENT), segs: Vec::new() },
        first: vec![Vec::new(); n_fog],
    });
    // Rows of the batch staged for their columns ([`Basis::fill_batch`]) and, of these, the
    // kept ones (their basis vectors are kept once computed).
    let batched = basis.batched();
    let mut staged = Staged::new(n_fog, basis.gather_cols.len());
    let mut kept_at: Vec<usize> = Vec::new();
    // A batch summed: its staged columns computed, added to the Gram sums and offered to the
    // extremes (the first segment's rows held, row-major, until its fit ranks them).
    let flush = |batch: &mut [Vec<f64>],
                 rows: usize,
                 gram: &mut Vec<Vec<Gram>>,
                 block: usize,
                 tracker: Option<&mut Tracker>,
                 shift: &[Vec<f64>],
                 staged: &Staged,
                 kept_at: &mut Vec<usize>,
                 kept_z: &mut [Vec<f64>],
                 mean_z: &mut [Vec<f64>],
                 run_z: &mut [RunSum],
                 bin_acc: &mut BinAcc,
                 j0: usize| {
        if rows == 0 {
            return;
        }
        if batched {
            for (fog, (b, kz)) in batch.iter_mut().zip(kept_z.iter_mut()).enumerate() {
                basis.fill_batch(fog, staged, rows, &shift[fog], b);
                for &i in kept_at.iter() {
                    kz.extend((0..m).map(|a| b[a * COL + i]));
                }
                if stride > 1 {
                    for i in 0..rows {
                        let col = (0..m).map(|a| b[a * COL + i]);
                        if let Some(mean) = run_z[fog].add(j0 + i, block, stride, col) {
                            mean_z[fog].extend(mean);
                        }
                    }
                }
            }
            kept_at.clear();
        }
        if rows < BATCH {
            for b in batch.iter_mut() {
                b.chunks_exact_mut(COL).for_each(|col| col[rows..BATCH].fill(0.0));
            }
        }
        bin_acc.add(batch, j0, rows, m);
        let mut grams: Vec<&mut Gram> = gram.iter_mut().map(|g| &mut g[block]).collect();
        accumulate_gram(&mut grams, batch, rows, &order, shared);
        if let Some(t) = tracker {
            t.offer_batch(batch, rows, m);
        }
    };
    // The batch so far summed; its first row is row `$j0` of the session.
    macro_rules! flush_batch {
        ($j0:expr) => {
            flush(
                &mut batch,
                batch_rows,
                &mut gram,
                batch_block,
                tracker.as_mut(),
                &shift,
                &staged,
                &mut kept_at,
                &mut kept.z,
                &mut kept.mean_z,
                &mut run_z,
                &mut bin_acc,
                $j0,
            )
        };
    }
    // The block, segment and kept-row tests by counters (j goes 0, 1, 2, ...): the block of j
    // changes at the first j with j · nb / n above the current block.
    let (mut block, mut next_block) = (0usize, 0usize);
    let mut next_segment = tracker.as_ref().map_or(usize::MAX, |t| t.out.first);
    let mut next_keep = 0usize;
    let (mut gaps, mut prev_t) = (Gaps::default(), f64::NAN);
    let seen = for_each_prepared(source, n_fog, g_window_s, progress, |j, s, g| {
        let step = s.t_s - prev_t;
        if step > GAP_FACTOR * shape.dt_s {
            gaps.count += 1;
            gaps.missing_s += step - shape.dt_s;
            if gaps.largest.is_none_or(|(_, l)| step > l) {
                gaps.largest = Some((prev_t, step));
            }
        }
        prev_t = s.t_s;
        if j >= next_block {
            block = block_of(j, n, nb).min(nb - 1);
            next_block = if block + 1 >= nb { usize::MAX } else { ((block + 1) * n.max(1)).div_ceil(nb) };
        }
        let new_segment = j == next_segment;
        if let (true, Some(t)) = (new_segment, tracker.as_ref()) {
            // The segment starting here is the second when none is out yet.
            next_segment += t.out.len_of(t.out.segs.len().max(1));
        }
        if block != batch_block || batch_rows == BATCH || new_segment {
            flush_batch!(j - batch_rows);
            (batch_rows, batch_block) = (0, block);
        }
        if let (Some(t), true) = (tracker.as_mut(), new_segment) {
            t.open_segment(&basis, &shift, &gram, box_rows);
        }
        let keep = j == next_keep;
        if keep {
            next_keep += stride;
            kept.push_row(j, block, s, g, psi_col);
        }
        if stride > 1 {
            if let Some(t) = run_t.add(j, block, stride, std::iter::once(s.t_s)) {
                kept.mean_t_s.extend(t);
                kept.mean_block.push(block);
            }
        }
        if shift.len() < n_fog {
            // The first row: the shift is its basis vector (slot 0 stays 1).
            for _ in 0..n_fog {
                basis.fill(shift.len(), s, g, &mut z)?;
                let mut sh = z.clone();
                sh[ONE] = 0.0;
                shift.push(sh);
            }
        }
        if batched {
            staged.put(batch_rows, s, g, &basis.gather_cols);
            if keep {
                kept_at.push(batch_rows);
            }
        } else {
            for fog in 0..n_fog {
                basis.fill(fog, s, g, &mut z)?;
                let col = &mut batch[fog][batch_rows..];
                for (a, (v, sh)) in z.iter_mut().zip(&shift[fog]).enumerate() {
                    *v -= sh;
                    col[a * COL] = *v;
                }
                if keep {
                    kept.z[fog].extend_from_slice(&z);
                }
                if stride > 1 {
                    if let Some(mean) = run_z[fog].add(j, block, stride, z.iter().copied()) {
                        kept.mean_z[fog].extend(mean);
                    }
                }
            }
        }
        batch_rows += 1;
        Ok(())
    })?;
    flush_batch!(seen - batch_rows);
    if seen != n {
        return Err(LabError::Numeric(format!(
            "{}: {seen} samples read, {n} counted before: did the file change while it was read?",
            h.file
        )));
    }
    check_rate_columns(h, &basis, &shift, &kept)?;
    let extra_columns = h
        .names
        .iter()
        .zip(&h.roles)
        .filter(|(_, r)| **r == crate::session::Role::Extra)
        .map(|(n, _)| n.clone())
        .collect();
    Ok(Digest {
        file: h.file.clone(),
        names: h.names.clone(),
        extra_columns,
        n,
        n_blocks: nb,
        dt_s: shape.dt_s,
        t_span_s: shape.t_span_s,
        g_window_s,
        basis,
        shift,
        gram,
        kept,
        bins: bin_acc.bins,
        bin_sum: bin_acc.sum,
        gaps,
        extremes: tracker.map(|t| t.out).filter(|e| !e.segs.is_empty()),
    })
}

impl Digest {
    /// What the user should know about the session the figures do not say: its gaps in time
    /// (the lab takes rows as equally spaced: the time blocks, the noise model's bins, τ-means
    /// and Allan deviations count rows, so a window or bin over a gap joins times apart).
    pub fn notes(&self) -> Vec<String> {
        let mut v = Vec::new();
        if let Some((t, len)) = self.gaps.largest {
            v.push(format!(
                "{}: {} gap(s) in time, {:.1} s missing in all, the largest {:.1} s after t = {} s (sample interval \
                 {} s): the lab takes rows as equally spaced (time blocks, the noise model's bins, tau-means and \
                 Allan deviations count rows), so figures over a gap join times apart",
                self.file, self.gaps.count, self.gaps.missing_s, len, t, self.dt_s
            ));
        }
        v
    }

    /// A functional of the raw basis as one of the shifted basis: x = ℓ·z = ℓ·z̃ + (ℓ·shift)·1.
    pub fn shifted(&self, fog: usize, l: &[f64]) -> Vec<f64> {
        shifted(l, &self.shift[fog])
    }

    /// The sums of FOG `fog` over the blocks `pick` selects.
    pub fn gram_of(&self, fog: usize, pick: impl Fn(usize) -> bool) -> Gram {
        let mut g = Gram::new(self.basis.m);
        for (b, x) in self.gram[fog].iter().enumerate() {
            if pick(b) {
                g.add(x);
            }
        }
        g
    }

    /// Whether every sample is kept.
    pub fn all_kept(&self) -> bool {
        self.kept.stride == 1
    }
}
