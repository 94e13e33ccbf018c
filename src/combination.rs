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
use crate::state_map::{state_map, StateField};

/// Which FOGs take part: bit i set = FOG i used.
#[derive(Debug, Clone, Copy, PartialEq, Eq, bytemuck::Pod, bytemuck::Zeroable)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
#[repr(transparent)]
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
#[derive(Debug, Clone, Copy, PartialEq, bytemuck::AnyBitPattern)]
pub struct Combiner {
    /// Solution with all four FOGs (if `solved` bit 4).
    all: Matrix3x4<f64>,
    /// Solution without FOG i (the column of FOG i is zero; if `solved` bit i).
    without: [Matrix3x4<f64>; N_FOG],
    /// Which solutions exist: bit i `without[i]`, bit 4 `all` (any value means a set).
    solved: u8,
    /// Unit parity vector v (v H = 0), zero when four axes are not available.
    parity: RowVector4<f64>,
}

impl Combiner {
    /// Where each field lies in the value ([`crate::state_map`]).
    pub const STATE_MAP: &'static [StateField] = state_map!(Combiner {
        all: Matrix3x4<f64>,
        without: [Matrix3x4<f64>; N_FOG],
        solved: u8,
        parity: RowVector4<f64>,
    });

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
        let solved = without
            .iter()
            .enumerate()
            .fold(u8::from(all.is_some()) << 4, |acc, (i, w)| acc | u8::from(w.is_some()) << i);
        Combiner {
            all: all.unwrap_or_else(Matrix3x4::zeros),
            without: without.map(|w| w.unwrap_or_else(Matrix3x4::zeros)),
            solved,
            parity: parity_vector(&h),
        }
    }

    /// Body increment (ICS) from the compensated increments `m` of the FOGs in `set`;
    /// entries of FOGs outside `set` are ignored.
    pub fn combine(&self, m: &Vector4<f64>, set: FogSet) -> Result<Vector3<f64>, CombineError> {
        let p = self.solution(set)?;
        Ok(p * m)
    }

    /// The 3×4 least-squares matrix for `set`.
    pub fn solution(&self, set: FogSet) -> Result<&Matrix3x4<f64>, CombineError> {
        let (sol, bit) = match set.0 & 0b1111 {
            0b1111 => (&self.all, 1 << 4),
            0b1110 => (&self.without[0], 1 << 0),
            0b1101 => (&self.without[1], 1 << 1),
            0b1011 => (&self.without[2], 1 << 2),
            0b0111 => (&self.without[3], 1 << 3),
            _ => return Err(CombineError::TooFewFogs),
        };
        if self.solved & bit == 0 {
            return Err(CombineError::Singular);
        }
        Ok(sol)
    }

    /// Parity residual p = v · m, rad (zero-mean noise when all four FOGs are healthy).
    pub fn parity(&self, m: &Vector4<f64>) -> f64 {
        (self.parity * m).x
    }

    /// The four triad solutions (FOG i left out), when every one exists.
    pub fn triads(&self) -> Option<[Matrix3x4<f64>; N_FOG]> {
        (self.solved & 0b1111 == 0b1111).then_some(self.without)
    }

    /// The unit parity vector v.
    pub fn parity_vector(&self) -> RowVector4<f64> {
        self.parity
    }

    /// The four-FOG solution and the parity vector (used every sample), for the state
    /// guard ([`crate::shadow`]).
    #[inline(always)]
    pub fn visit_nominal<V: crate::shadow::Visit>(&mut self, v: &mut V) {
        v.f64s(self.all.as_mut_slice());
        let mut solved = u64::from(self.solved);
        v.word(&mut solved);
        if V::WRITES {
            self.solved = u8::try_from(solved).unwrap_or(0);
        }
        v.f64s(self.parity.as_mut_slice());
    }

    /// The solution without FOG `i` (used after an isolation), for the state guard.
    #[inline(always)]
    pub fn visit_without<V: crate::shadow::Visit>(&mut self, i: usize, v: &mut V) {
        if let Some(m) = self.without.get_mut(i) {
            v.f64s(m.as_mut_slice());
        }
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

#[cfg(test)]
mod tests {
    use super::*;

    /// The paper's geometry: three orthogonal axes and one equally inclined.
    fn paper_axes() -> [Vector3<f64>; N_FOG] {
        let k = 1.0 / libm::sqrt(3.0);
        [Vector3::x(), Vector3::y(), Vector3::z(), Vector3::new(k, k, k)]
    }

    /// The measurements of the axes `s` for the body increment `w`: m_i = s_i · w.
    fn measure(s: &[Vector3<f64>; N_FOG], w: &Vector3<f64>) -> Vector4<f64> {
        Vector4::from_fn(|i, _| s[i].dot(w))
    }

    #[test]
    fn every_set_of_three_or_four_recovers_the_increment() {
        // A skewed, non-orthogonal geometry, so that least squares is not a copy.
        let s = [
            Vector3::new(1.0, 0.01, -0.02).normalize(),
            Vector3::new(0.015, 1.0, 0.01).normalize(),
            Vector3::new(-0.01, 0.02, 1.0).normalize(),
            Vector3::new(0.6, 0.55, 0.58).normalize(),
        ];
        let c = Combiner::new(&s);
        let w = Vector3::new(1.2e-5, -3.4e-6, 7.0e-7);
        let m = measure(&s, &w);
        for set in [FogSet::ALL, FogSet(0b1110), FogSet(0b1101), FogSet(0b1011), FogSet(0b0111)] {
            let got = c.combine(&m, set).unwrap();
            assert!((got - w).norm() < 1e-18, "{set:?}: {got} vs {w}");
        }
        // A triad ignores the FOG it leaves out, however wrong.
        let mut bad = m;
        bad[3] += 1.0;
        assert!((c.combine(&bad, FogSet::TRIAD).unwrap() - w).norm() < 1e-18);
    }

    /// v H = 0 with |v| = 1: consistent measurements give p = 0, and a fault e on FOG i
    /// gives p = v_i e.
    #[test]
    fn the_parity_residual_sees_a_single_fault() {
        let s = paper_axes();
        let c = Combiner::new(&s);
        let v = c.parity_vector();
        assert!((v.norm() - 1.0).abs() < 1e-15);
        for axis in [Vector3::x(), Vector3::y(), Vector3::z()] {
            let vh: f64 = v.iter().zip(&s).map(|(vi, si)| vi * si.dot(&axis)).sum();
            assert!(vh.abs() < 1e-15, "v H = {vh} along {axis}");
        }
        let w = Vector3::new(3e-6, -2e-6, 1e-6);
        let m = measure(&s, &w);
        assert!(c.parity(&m).abs() < 1e-20);
        for i in 0..N_FOG {
            let mut f = m;
            f[i] += 1e-6;
            let p = c.parity(&f);
            assert!((p - v[i] * 1e-6).abs() < 1e-20, "FOG {i}: p {p}");
            assert!(p.abs() > 4e-7, "FOG {i} is seen: p {p}");
        }
    }

    #[test]
    fn too_few_fogs_or_a_flat_geometry_is_refused() {
        let c = Combiner::new(&paper_axes());
        let m = Vector4::zeros();
        assert_eq!(c.combine(&m, FogSet(0b0011)), Err(CombineError::TooFewFogs));
        assert_eq!(c.combine(&m, FogSet(0)), Err(CombineError::TooFewFogs));
        assert!(c.triads().is_some());
        // Four axes in the x-y plane span no 3-D space.
        let flat = [
            Vector3::x(),
            Vector3::y(),
            Vector3::new(1.0, 1.0, 0.0).normalize(),
            Vector3::new(1.0, -1.0, 0.0).normalize(),
        ];
        let c = Combiner::new(&flat);
        assert_eq!(c.combine(&m, FogSet::ALL), Err(CombineError::Singular));
        assert!(c.triads().is_none());
    }

    #[test]
    fn a_set_counts_and_drops_its_members() {
        assert_eq!(FogSet::ALL.count(), 4);
        assert_eq!(FogSet::ALL.without(1), FogSet(0b1101));
        assert_eq!(FogSet::ALL.without(N_FOG), FogSet::ALL);
        assert!(FogSet::TRIAD.contains(2) && !FogSet::TRIAD.contains(3));
        assert!(!FogSet::ALL.contains(N_FOG));
    }
}
