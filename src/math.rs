//! Small f64 helpers shared by the attitude, observer and combination stages.
//!
//! Quaternions are nalgebra's [`Quaternion`] (Hamilton product, scalar `w` first in
//! the paper's notation Λ = (λ0; λ1, λ2, λ3)). The paper's product "∘" is the Hamilton
//! product `*`. See `docs/CONVENTIONS.md`.

use nalgebra::{Quaternion, Vector3};

/// Square root (libm: no hardware VSQRT is assumed here; see NOTES.md).
#[inline]
pub fn sqrt(x: f64) -> f64 {
    libm::sqrt(x)
}

/// Unit quaternion of a rotation vector `phi_rad` (axis × angle), exact for any angle.
///
/// Below 1e-2 rad the half-angle sine and cosine are replaced by their Taylor series to
/// the 6th power (error < 1e-19), which avoids two library calls in the flight step.
pub fn quat_from_rotvec(phi_rad: &Vector3<f64>) -> Quaternion<f64> {
    let a2 = phi_rad.norm_squared();
    let (c, s_over_a) = if a2 < 1e-4 {
        // cos(a/2) and sin(a/2)/a.
        let c = 1.0 - a2 / 8.0 + a2 * a2 / 384.0 - a2 * a2 * a2 / 46_080.0;
        let s = 0.5 - a2 / 48.0 + a2 * a2 / 3_840.0 - a2 * a2 * a2 / 645_120.0;
        (c, s)
    } else {
        let a = sqrt(a2);
        (libm::cos(0.5 * a), libm::sin(0.5 * a) / a)
    };
    Quaternion::new(c, s_over_a * phi_rad.x, s_over_a * phi_rad.y, s_over_a * phi_rad.z)
}

/// Rotation vector (axis × angle, rad) of a quaternion, on the short way round
/// (the sign of `q` is chosen so that the angle is in [0, π]).
///
/// With s = ‖vect(q)‖ the angle is 2 atan(s / w). Below s² = 1e-6 (0.11°, every
/// star-tracker mismatch and every step increment) the series
/// 2 atan(x)/s = (2/w)(1 − x²/3 + x⁴/5 − x⁶/7), x = s/w, needs only s², so neither a
/// square root nor atan2 (two library routines on the M7); the first omitted term,
/// x⁸/9, is below 1.2e-25 relative there (w > 0.99).
pub fn rotvec_from_quat(q: &Quaternion<f64>) -> Vector3<f64> {
    let (w, v) = if q.w < 0.0 { (-q.w, -q.imag()) } else { (q.w, q.imag()) };
    let s2 = v.norm_squared();
    if s2 < 1e-6 && w > 0.5 {
        let x2 = s2 / (w * w);
        v * ((2.0 / w) * (1.0 - x2 / 3.0 + x2 * x2 / 5.0 - x2 * x2 * x2 / 7.0))
    } else if s2 == 0.0 {
        Vector3::zeros()
    } else {
        // Also the path of a NaN, which stays NaN for the caller to see.
        let s = sqrt(s2);
        v * (2.0 * libm::atan2(s, w) / s)
    }
}

/// Normalises `q` to unit length; a zero or non-finite quaternion becomes identity and
/// the function returns `false`, so a caller can flag it instead of propagating NaN.
///
/// Near unit length (|‖q‖² − 1| < 1e-6, every step of the propagation) one Newton step
/// of 1/√x at x = 1, the factor (3 − ‖q‖²)/2, leaves an error of order (‖q‖² − 1)²,
/// below f64 rounding, without a square root (a software routine on the M7).
pub fn normalize(q: &mut Quaternion<f64>) -> bool {
    let n2 = q.norm_squared();
    if (n2 - 1.0).abs() < 1e-6 {
        *q *= 0.5 * (3.0 - n2);
        true
    } else if n2.is_finite() && n2 > 1e-12 {
        *q /= sqrt(n2);
        true
    } else {
        *q = Quaternion::identity();
        false
    }
}

/// Rotates vector `v` by unit quaternion `q`: returns q ∘ v ∘ q̃.
pub fn rotate(q: &Quaternion<f64>, v: &Vector3<f64>) -> Vector3<f64> {
    let p = Quaternion::from_imag(*v);
    (q * p * q.conjugate()).imag()
}

/// Component-wise product of two vectors (per-axis gains).
#[inline]
pub fn mul_elem(a: &Vector3<f64>, b: &Vector3<f64>) -> Vector3<f64> {
    Vector3::new(a.x * b.x, a.y * b.y, a.z * b.z)
}

/// Normalised linear interpolation between two nearby unit quaternions (same hemisphere
/// enforced). Exact enough for steps of a few milliseconds (error ~ angle³).
pub fn nlerp(a: &Quaternion<f64>, b: &Quaternion<f64>, t: f64) -> Quaternion<f64> {
    let b_same = if a.dot(b) < 0.0 { -*b } else { *b };
    let mut q = *a * (1.0 - t) + b_same * t;
    normalize(&mut q);
    q
}
