//! Small f64 helpers shared by the attitude, observer and combination stages.
//!
//! Quaternions are nalgebra's [`Quaternion`] (Hamilton product, scalar `w` first in
//! the paper's notation Λ = (λ0; λ1, λ2, λ3)). The paper's product "∘" is the Hamilton
//! product `*`. See `docs/CONVENTIONS.md`.

use nalgebra::{Quaternion, Vector3};

/// Square root (libm: no hardware VSQRT is assumed here).
#[inline]
pub fn sqrt(x: f64) -> f64 {
    libm::sqrt(x)
}

/// Largest |x| that [`sin_cos`] reduces; beyond it the result is NaN (no flight angle
/// comes near: 2^30 quarter turns, 1.7e9 rad).
pub const SIN_COS_MAX_RAD: f64 = 1_686_629_713.0;

/// π/2 in three parts for the Cody–Waite reduction: P1 and P2 carry 33 significant bits
/// each, so k·P1 and k·P2 are exact for |k| < 2^20, and P1 + P2 + P3 = π/2 to 2^-120.
const PIO2_1: f64 = f64::from_bits(0x3FF9_21FB_5440_0000);
const PIO2_2: f64 = f64::from_bits(0x3DD0_B461_1A60_0000);
const PIO2_3: f64 = f64::from_bits(0x3BA3_198A_2E03_7073);

/// sin and cos of `x_rad`, within about one unit in the last place for |x| < 1.6e6 rad
/// (every angle of the flight code: mounting angles, half rotation angles, latitudes).
///
/// x = k·π/2 + r with k the nearest integer and |r| ≤ π/4 (Cody–Waite, three parts of
/// π/2), then Taylor series of sin r to r^17 and cos r to r^18 (first omitted terms
/// below 1e-19), cos summed as 1 − r²/2 with its rounding error carried, and the
/// quadrant k mod 4. Written here instead of calling `libm::sin`/`cos`, whose reduction
/// for arbitrary arguments (`rem_pio2`, 4 KB) does not fit the firmware's flash; the host
/// tests compare it with the standard library over the range. Not finite or beyond
/// [`SIN_COS_MAX_RAD`]: NaN.
#[inline(never)]
pub fn sin_cos(x_rad: f64) -> (f64, f64) {
    if x_rad.is_nan() || x_rad.abs() > SIN_COS_MAX_RAD {
        return (f64::NAN, f64::NAN);
    }
    let kf = x_rad * core::f64::consts::FRAC_2_PI;
    // Nearest integer (ties away from zero); |kf| < 2^30 so the cast is exact.
    let k = (if kf >= 0.0 { kf + 0.5 } else { kf - 0.5 }) as i32;
    let kd = f64::from(k);
    let r = ((x_rad - kd * PIO2_1) - kd * PIO2_2) - kd * PIO2_3;
    let z = r * r;
    let sin_r = r + r
        * z
        * (-1.0 / 6.0
            + z * (1.0 / 120.0
                + z * (-1.0 / 5_040.0
                    + z * (1.0 / 362_880.0
                        + z * (-1.0 / 39_916_800.0
                            + z * (1.0 / 6_227_020_800.0
                                + z * (-1.0 / 1_307_674_368_000.0 + z * (1.0 / 355_687_428_096_000.0))))))));
    let tail = 1.0 / 24.0
        + z * (-1.0 / 720.0
            + z * (1.0 / 40_320.0
                + z * (-1.0 / 3_628_800.0
                    + z * (1.0 / 479_001_600.0
                        + z * (-1.0 / 87_178_291_200.0
                            + z * (1.0 / 20_922_789_888_000.0 + z * (-1.0 / 6_402_373_705_728_000.0)))))));
    let hz = 0.5 * z;
    let w = 1.0 - hz;
    let cos_r = w + (((1.0 - w) - hz) + z * z * tail);
    match k & 3 {
        0 => (sin_r, cos_r),
        1 => (cos_r, -sin_r),
        2 => (-sin_r, -cos_r),
        _ => (-cos_r, sin_r),
    }
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
        let (s, c) = sin_cos(0.5 * a);
        (c, s / a)
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
