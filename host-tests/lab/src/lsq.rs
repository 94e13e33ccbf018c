//! Least-squares algebra on sums: the Gram matrix of a basis over a set of rows, the normal
//! equations of a design (a set of linear functionals of the basis) and their solution.
//!
//! A design's normal equations over any rows are Λ G Λᵀ, a (k+1) × (k+1) matrix with y last
//! ([`design_gram`]). [`lstsq_gram`] scales the columns to unit norm and factors that matrix
//! column by column (Cholesky, in the design's order). A regressor whose part not explained
//! by the earlier columns is below [`REL_TOL`] of its norm (the diagonal of the factor, the
//! R of a QR of the scaled columns) cannot be identified: it is dropped and its coefficient
//! left at zero; earlier columns keep priority. The residual sum of squares follows from
//! the same matrix, as does the sum of squares of coefficients fitted elsewhere
//! ([`sse_gram`]).

use nalgebra::DMatrix;

/// Relative size below which a regressor is not identifiable (see the module text).
pub const REL_TOL: f64 = 1e-6;

/// The sums z zᵀ of one FOG over one block (upper triangle filled; see [`Gram::full`]).
#[derive(Debug, Clone)]
pub struct Gram {
    /// Rows summed.
    pub n: usize,
    /// m × m, row-major, upper triangle.
    pub upper: Vec<f64>,
    /// m.
    pub m: usize,
}

impl Gram {
    /// Zero sums of size m.
    pub fn new(m: usize) -> Gram {
        Gram { n: 0, upper: vec![0.0; m * m], m }
    }

    /// Adds another Gram.
    pub fn add(&mut self, o: &Gram) {
        self.n += o.n;
        for (a, b) in self.upper.iter_mut().zip(&o.upper) {
            *a += b;
        }
    }

    /// The symmetric matrix.
    pub fn full(&self) -> DMatrix<f64> {
        DMatrix::from_fn(
            self.m,
            self.m,
            |r, c| if r <= c { self.upper[r * self.m + c] } else { self.upper[c * self.m + r] },
        )
    }
}

/// A least-squares solution over a set of rows.
#[derive(Debug, Clone)]
pub struct LsFit {
    /// Coefficient per column (zero where not identified).
    pub coef: Vec<f64>,
    /// Whether each column was identified.
    pub identified: Vec<bool>,
    /// Sum of squared residuals over the rows.
    pub sse: f64,
    /// Number of rows.
    pub n: usize,
    /// Number of identified columns.
    pub p: usize,
}

/// The normal-equation matrix of functionals `cols` (y last) over the sums `g`: Λ G Λᵀ.
pub fn design_gram(g: &Gram, cols: &[Vec<f64>]) -> DMatrix<f64> {
    let full = g.full();
    let lam = DMatrix::from_fn(cols.len(), g.m, |r, c| cols[r][c]);
    &lam * full * lam.transpose()
}

/// Least squares of the last column on the others, from their normal-equation matrix `a`
/// over `n` rows.
pub fn lstsq_gram(a: &DMatrix<f64>, n: usize) -> LsFit {
    let k = a.nrows() - 1;
    let yy = a[(k, k)].max(0.0);
    let scale: Vec<f64> = (0..k).map(|c| a[(c, c)].max(0.0).sqrt()).collect();
    let mut keep: Vec<usize> = Vec::new();
    // Rows of the Cholesky factor of the scaled matrix, for the kept columns.
    let mut l: Vec<Vec<f64>> = Vec::new();
    for c in 0..k {
        if !(scale[c] > 0.0 && scale[c].is_finite()) {
            continue;
        }
        let row: Vec<f64> = keep.iter().map(|&kc| a[(c, kc)] / (scale[c] * scale[kc])).collect();
        // Forward substitution: l_c = L⁻¹ row.
        let mut lc = vec![0.0; keep.len()];
        for i in 0..keep.len() {
            let s: f64 = (0..i).map(|j| l[i][j] * lc[j]).sum();
            lc[i] = (row[i] - s) / l[i][i];
        }
        let d = 1.0 - lc.iter().map(|v| v * v).sum::<f64>();
        if d < REL_TOL * REL_TOL || keep.len() >= n {
            continue;
        }
        lc.push(d.sqrt());
        l.push(lc);
        keep.push(c);
    }
    let p = keep.len();
    // L z = ĝ (scaled Xᵀy), then Lᵀ b̂ = z.
    let mut zv = vec![0.0; p];
    for i in 0..p {
        let g = a[(keep[i], k)] / scale[keep[i]];
        let s: f64 = (0..i).map(|j| l[i][j] * zv[j]).sum();
        zv[i] = (g - s) / l[i][i];
    }
    let mut bh = vec![0.0; p];
    for i in (0..p).rev() {
        let s: f64 = (i + 1..p).map(|j| l[j][i] * bh[j]).sum();
        bh[i] = (zv[i] - s) / l[i][i];
    }
    let mut coef = vec![0.0; k];
    let mut identified = vec![false; k];
    for (i, &c) in keep.iter().enumerate() {
        coef[c] = bh[i] / scale[c];
        identified[c] = true;
    }
    let sse = (yy - zv.iter().map(|v| v * v).sum::<f64>()).max(0.0);
    LsFit { coef, identified, sse, n, p }
}

/// Σ (y − Σ c_k x_k)² from the normal-equation matrix `a` (y last).
pub fn sse_gram(a: &DMatrix<f64>, coef: &[f64]) -> f64 {
    let k = a.nrows() - 1;
    let mut v: Vec<f64> = coef.iter().map(|c| -c).collect();
    v.push(1.0);
    let mut s = 0.0;
    for r in 0..=k {
        for c in 0..=k {
            s += v[r] * a[(r, c)] * v[c];
        }
    }
    s.max(0.0)
}

/// The functional y − Σ c_k x_k of the residual, for functionals `cols` (y last).
pub fn residual_functional(cols: &[Vec<f64>], coef: &[f64]) -> Vec<f64> {
    let k = cols.len() - 1;
    let mut l = cols[k].clone();
    for (c, x) in coef.iter().zip(&cols[..k]) {
        for (a, b) in l.iter_mut().zip(x) {
            *a -= c * b;
        }
    }
    l
}
