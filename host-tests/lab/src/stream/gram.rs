//! The pass's inner sums: a batch of basis vectors added to each FOG's Gram matrix, one dot
//! product per entry (AVX2 where the machine has it, the same bits either way).

use super::*;

/// Adds one batch per FOG to that FOG's sums (`grams[f]`, batch `batches[f]`: m columns
/// of [`BATCH`] values, [`COL`] apart, rows past `rows` zero, then a column of zeros).
/// The slots `order[..shared]` hold the same values for every FOG (quantities of the
/// sample, not of a FOG: 1, ω_ref, hours, B, user columns): their entries are summed
/// once, from the first FOG, and added to every FOG's sums. Each entry is one dot
/// product ([`gram_entry`]), the same bits whichever entries are summed with it.
pub(super) fn accumulate_gram(
    grams: &mut [&mut Gram],
    batches: &[Vec<f64>],
    rows: usize,
    order: &[usize],
    shared: usize,
) {
    let Some(m) = grams.first().map(|g| g.m) else { return };
    // Per row of the triangle, in `order`: the other slots of its entries.
    let mut bs: Vec<usize> = Vec::with_capacity(m + 3);
    let mut vals = vec![0.0f64; m + 3];
    let mut first_shared = vec![0.0f64; m * m];
    for (f, (g, cols)) in grams.iter_mut().zip(batches).enumerate() {
        g.n += rows;
        for (i, &a) in order.iter().enumerate() {
            bs.clear();
            let from = if f > 0 && i < shared { shared } else { i };
            bs.extend_from_slice(&order[from..]);
            if f > 0 && i < shared {
                for &b in &order[i..shared] {
                    let k = a.min(b) * m + a.max(b);
                    g.upper[k] += first_shared[k];
                }
            }
            let n = bs.len();
            // Groups of four: the last padded with the zero column (m).
            while !bs.len().is_multiple_of(4) {
                bs.push(m);
            }
            gram_entries(cols, a, &bs, &mut vals[..bs.len()]);
            for (&b, &v) in bs.iter().zip(&vals).take(n) {
                let k = a.min(b) * m + a.max(b);
                g.upper[k] += v;
                if f == 0 && i < shared {
                    first_shared[k] = v;
                }
            }
        }
    }
}

/// The dot products of column a with columns `bs` (a multiple of four of them) of a batch
/// (columns of [`BATCH`] values, [`COL`] apart), into `out`.
#[inline]
fn gram_entries(cols: &[f64], a: usize, bs: &[usize], out: &mut [f64]) {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") {
        // SAFETY: the CPU has AVX2 (checked above).
        unsafe { gram_entries_avx2(cols, a, bs, out) };
        return;
    }
    for (o, &b) in out.iter_mut().zip(bs) {
        *o = gram_entry(cols, a, b);
    }
}

/// One entry of the Gram sums of a batch: columns a and b, eight partial sums (partial sum
/// l takes rows l, l + 8, ...), added pairwise in a fixed order, so the result does not
/// depend on the vector width the compiler uses (and no fused multiply-add changes the
/// rounding).
#[inline(always)]
fn gram_entry(cols: &[f64], a: usize, b: usize) -> f64 {
    let (ca, cb) = (&cols[a * COL..a * COL + BATCH], &cols[b * COL..b * COL + BATCH]);
    let mut acc = [0.0f64; 8];
    for (x, y) in ca.chunks_exact(8).zip(cb.chunks_exact(8)) {
        for l in 0..8 {
            acc[l] += x[l] * y[l];
        }
    }
    combine8(&acc)
}

/// The eight partial sums of a Gram entry added in their fixed order.
#[inline(always)]
fn combine8(acc: &[f64; 8]) -> f64 {
    ((acc[0] + acc[1]) + (acc[2] + acc[3])) + ((acc[4] + acc[5]) + (acc[6] + acc[7]))
}

/// [`gram_entries`] with AVX2: four entries at a time (eight vector sums in flight instead
/// of two, so the adds do not wait on each other); partial sums l = 0–3 and 4–7 of each
/// entry in two vectors, separate multiply and add, the same operations in the same order
/// as [`gram_entry`] (the same bits).
///
/// # Safety
///
/// The CPU must have AVX2; `bs` a multiple of four columns, each (and a) in `cols`.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn gram_entries_avx2(cols: &[f64], a: usize, bs: &[usize], out: &mut [f64]) {
    use std::arch::x86_64::{
        __m256d, _mm256_add_pd, _mm256_loadu_pd, _mm256_mul_pd, _mm256_setzero_pd, _mm256_storeu_pd,
    };
    let ca = &cols[a * COL..a * COL + BATCH];
    for (group, out) in bs.chunks_exact(4).zip(out.chunks_exact_mut(4)) {
        let cb: [&[f64]; 4] = [0, 1, 2, 3].map(|k| &cols[group[k] * COL..group[k] * COL + BATCH]);
        let mut lo: [__m256d; 4] = [_mm256_setzero_pd(); 4];
        let mut hi: [__m256d; 4] = [_mm256_setzero_pd(); 4];
        for i in (0..BATCH).step_by(8) {
            // SAFETY: i + 8 ≤ BATCH, the length of every column slice.
            let (xl, xh) = unsafe { (_mm256_loadu_pd(ca.as_ptr().add(i)), _mm256_loadu_pd(ca.as_ptr().add(i + 4))) };
            for (k, (l, h)) in lo.iter_mut().zip(hi.iter_mut()).enumerate() {
                // SAFETY: as above.
                let (yl, yh) = unsafe {
                    let q = cb[k].as_ptr().add(i);
                    (_mm256_loadu_pd(q), _mm256_loadu_pd(q.add(4)))
                };
                *l = _mm256_add_pd(*l, _mm256_mul_pd(xl, yl));
                *h = _mm256_add_pd(*h, _mm256_mul_pd(xh, yh));
            }
        }
        for (o, (l, h)) in out.iter_mut().zip(lo.iter().zip(&hi)) {
            let mut acc = [0.0f64; 8];
            // SAFETY: `acc` has room for two vectors of four.
            unsafe {
                _mm256_storeu_pd(acc.as_mut_ptr(), *l);
                _mm256_storeu_pd(acc.as_mut_ptr().add(4), *h);
            }
            *o = combine8(&acc);
        }
    }
}
