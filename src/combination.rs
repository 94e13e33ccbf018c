//! Combination: compensated increments of four skewed FOGs (or any three) → body
//! increment in the instrument frame (ICS), by least squares over the calibrated axes.
//!
//! With H the 4×3 matrix whose rows are the calibrated sensitive axes s_i, the body
//! increment is Δθ = (Hᵀ H)⁻¹ Hᵀ m for the measurement vector m. Three orthogonal FOGs
//! plus one equally inclined leave one redundant dimension: the parity residual
//! p = v · m, with v the unit left null vector of H (v H = 0). p is zero for consistent
//! measurements and grows with any single-FOG fault (it detects; it cannot isolate).
//!
//! All five solutions (four FOGs, and each set of three) are computed once from the
//! table, so the step only multiplies a 3×4 matrix.

use nalgebra::{Matrix3, Matrix3x4, Matrix4x3, RowVector4, Vector3, Vector4};

use crate::calib::N_FOG;

/// Which FOGs take part: bit i set = FOG i used.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub struct FogSet(pub u8);

impl FogSet {
    /// All four FOGs.
    pub const ALL: FogSet = FogSet(0b1111);
    /// The orthogonal triad FOG1–FOG3 (launch-vehicle unit).
    pub const TRIAD: FogSet = FogSet(0b0111);

    /// Whether FOG `i` is in the set.
    pub fn contains(self, i: usize) -> bool {
        i < N_FOG && self.0 & (1 << i) != 0
    }

    /// Number of FOGs in the set.
    pub fn count(self) -> u32 {
        (self.0 & 0b1111).count_ones()
    }

    /// The set without FOG `i`.
    pub fn without(self, i: usize) -> FogSet {
        if i < N_FOG {
            FogSet(self.0 & !(1 << i))
        } else {
            self
        }
    }
}

/// Why a geometry or a combination was refused.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub enum CombineError {
    /// Fewer than three FOGs available.
    TooFewFogs,
    /// The selected axes do not span 3-D space (degenerate geometry).
    Singular,
}

/// Precomputed least-squares solutions over the calibrated geometry.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Combiner {
    /// Solution with all four FOGs.
    all: Option<Matrix3x4<f64>>,
    /// Solution without FOG i (the column of FOG i is zero).
    without: [Option<Matrix3x4<f64>>; N_FOG],
    /// Unit parity vector v (v H = 0), zero when four axes are not available.
    parity: RowVector4<f64>,
}

impl Combiner {
    /// Precomputes the solutions for axes `s` (rows of H).
    pub fn new(s: &[Vector3<f64>; N_FOG]) -> Self {
        let [s0, s1, s2, s3] = s;
        let h = Matrix4x3::from_rows(&[s0.transpose(), s1.transpose(), s2.transpose(), s3.transpose()]);
        let all = solve(&h, FogSet::ALL);
        let without = [
            solve(&h, FogSet::ALL.without(0)),
            solve(&h, FogSet::ALL.without(1)),
            solve(&h, FogSet::ALL.without(2)),
            solve(&h, FogSet::ALL.without(3)),
        ];
        Combiner { all, without, parity: parity_vector(&h) }
    }

    /// Body increment (ICS) from the compensated increments `m` of the FOGs in `set`;
    /// entries of FOGs outside `set` are ignored.
    pub fn combine(&self, m: &Vector4<f64>, set: FogSet) -> Result<Vector3<f64>, CombineError> {
        let p = self.solution(set)?;
        Ok(p * m)
    }

    /// The 3×4 least-squares matrix for `set`.
    pub fn solution(&self, set: FogSet) -> Result<&Matrix3x4<f64>, CombineError> {
        let sol = match set.0 & 0b1111 {
            0b1111 => &self.all,
            0b1110 => &self.without[0],
            0b1101 => &self.without[1],
            0b1011 => &self.without[2],
            0b0111 => &self.without[3],
            _ => return Err(CombineError::TooFewFogs),
        };
        sol.as_ref().ok_or(CombineError::Singular)
    }

    /// Parity residual p = v · m, rad (zero-mean noise when all four FOGs are healthy).
    pub fn parity(&self, m: &Vector4<f64>) -> f64 {
        (self.parity * m).x
    }

    /// The four triad solutions (FOG i left out), when every one exists.
    pub fn triads(&self) -> Option<[Matrix3x4<f64>; N_FOG]> {
        let [a, b, c, d] = self.without;
        Some([a?, b?, c?, d?])
    }

    /// The unit parity vector v.
    pub fn parity_vector(&self) -> RowVector4<f64> {
        self.parity
    }
}

/// (H_Sᵀ H_S)⁻¹ H_Sᵀ with the rows of FOGs outside `set` zeroed.
fn solve(h: &Matrix4x3<f64>, set: FogSet) -> Option<Matrix3x4<f64>> {
    let mut hs = *h;
    for (i, mut row) in hs.row_iter_mut().enumerate() {
        if !set.contains(i) {
            row.fill(0.0);
        }
    }
    let hth: Matrix3<f64> = hs.transpose() * hs;
    // Reject near-singular geometry: the determinant of HᵀH for unit axes is at most
    // ~(4/3)³; a thousandth of it means the axes are within a few degrees of a plane.
    if hth.determinant().abs() < 1e-3 {
        return None;
    }
    hth.try_inverse().map(|inv| inv * hs.transpose())
}

/// Unit left null vector of H: v_i = (−1)^i det(H without row i), normalised.
fn parity_vector(h: &Matrix4x3<f64>) -> RowVector4<f64> {
    let mut v = RowVector4::zeros();
    for (i, vi) in v.iter_mut().enumerate() {
        let minor = h.remove_row(i);
        let sign = if i % 2 == 0 { 1.0 } else { -1.0 };
        *vi = sign * minor.determinant();
    }
    let n = v.norm();
    if n > 1e-9 {
        v / n
    } else {
        RowVector4::zeros()
    }
}
