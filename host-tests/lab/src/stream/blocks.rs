//! The time blocks of a pass (even blocks train, odd blocks test), the per-block sums of
//! one FOG, and the bins of rows the noise model works on.

use super::*;

/// The block of sample j of n: `j · n_blocks / n` (even blocks train, odd blocks test).
pub fn block_of(j: usize, n: usize, n_blocks: usize) -> usize {
    j * n_blocks / n.max(1)
}

/// Whether block `b` trains (even) or tests (odd).
pub fn trains(b: usize) -> bool {
    b.is_multiple_of(2)
}

/// Sums of one FOG: all blocks, training blocks, test blocks.
#[derive(Debug, Clone)]
pub struct Sums {
    /// Every block.
    pub all: Gram,
    /// Even blocks.
    pub train: Gram,
    /// Odd blocks.
    pub test: Gram,
}

impl Sums {
    /// The sums of FOG `fog` of `d`.
    pub fn of(d: &Digest, fog: usize) -> Sums {
        Sums { all: d.gram_of(fog, |_| true), train: d.gram_of(fog, trains), test: d.gram_of(fog, |b| !trains(b)) }
    }
}

/// Bins at most (the covariance of a block is a dense matrix of its bins).
pub const MAX_BINS: usize = 2000;

/// Rows grouped into bins of consecutive rows of one block (rows of the session, or kept
/// rows of a pass).
#[derive(Debug, Clone, Default)]
pub struct Bins {
    /// Rows per bin (the last bin of a block may have fewer).
    pub rows: usize,
    /// First row of each bin, and the end (one more entry than bins).
    pub start: Vec<usize>,
    /// Block of each bin.
    pub block: Vec<usize>,
    /// Time between bins, s.
    pub dt_s: f64,
}

impl Bins {
    /// The bins of every row of a session of `n` rows `dt_s` apart in `n_blocks` blocks
    /// ([`block_of`]): at most [`MAX_BINS`] + `n_blocks`.
    pub fn every_row(n: usize, n_blocks: usize, dt_s: f64) -> Bins {
        let nb = n_blocks.max(1);
        let per = n.div_ceil(MAX_BINS).max(1);
        let (mut start, mut block) = (Vec::new(), Vec::new());
        for b in 0..nb {
            // The rows of block b: j with block_of(j) = b.
            let (s, e) = ((b * n).div_ceil(nb), if b + 1 == nb { n } else { ((b + 1) * n).div_ceil(nb) });
            debug_assert!(s >= e || block_of(s, n, nb) == b);
            let mut k = s;
            while k < e {
                start.push(k);
                block.push(b);
                k = (k + per).min(e);
            }
        }
        start.push(n);
        Bins { rows: per, start, block, dt_s: dt_s * per as f64 }
    }

    /// The bins of `d`'s kept rows (indices into them).
    pub fn of_kept(d: &Digest) -> Bins {
        Bins::group(&d.kept.block, d.dt_s * d.kept.stride.max(1) as f64)
    }

    /// The bins of the rows a line is searched and tested on ([`super::Kept::line_rows`]).
    pub fn of_line_rows(d: &Digest) -> Bins {
        Bins::group(d.kept.line_rows().1, d.dt_s * d.kept.stride.max(1) as f64)
    }

    /// Rows with blocks `blocks`, `dt_s` apart, in bins of at most n / [`MAX_BINS`] rows.
    fn group(blocks: &[usize], dt_s: f64) -> Bins {
        let n = blocks.len();
        let per = n.div_ceil(MAX_BINS).max(1);
        let (mut start, mut block) = (Vec::new(), Vec::new());
        let mut k = 0;
        while k < n {
            let b = blocks[k];
            start.push(k);
            block.push(b);
            let mut e = k + 1;
            while e < n && e - k < per && blocks[e] == b {
                e += 1;
            }
            k = e;
        }
        start.push(n);
        Bins { rows: per, start, block, dt_s: dt_s * per as f64 }
    }

    /// Number of bins.
    pub fn len(&self) -> usize {
        self.block.len()
    }

    /// Whether there are no bins.
    pub fn is_empty(&self) -> bool {
        self.block.is_empty()
    }

    /// Rows of bin `b`.
    pub fn count(&self, b: usize) -> usize {
        self.start[b + 1] - self.start[b]
    }

    /// The bins of each block, in order (bins of one block are consecutive).
    pub(crate) fn per_block(&self) -> Vec<(usize, std::ops::Range<usize>)> {
        let mut v: Vec<(usize, std::ops::Range<usize>)> = Vec::new();
        for (b, &blk) in self.block.iter().enumerate() {
            match v.last_mut() {
                Some((x, r)) if *x == blk => r.end = b + 1,
                _ => v.push((blk, b..b + 1)),
            }
        }
        v
    }
}
