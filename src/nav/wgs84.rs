//! WGS-84 Earth model: constants, gravitation with the J2 zonal term, gravity (with the
//! centrifugal term of the Earth's rotation) and the geodetic → ECEF conversion.
//!
//! References: NIMA TR8350.2, *Department of Defense World Geodetic System 1984*, 3rd ed.
//! (2000), tables 3.1–3.4 (a, f, GM, ω_ie) and eq. (5-1) for C̄₂,₀ (J2 = −√5 C̄₂,₀);
//! P. D. Groves, *Principles of GNSS, Inertial, and Multisensor Integrated Navigation
//! Systems*, 2nd ed. (2013), eq. (2.142) (J2 gravitation in ECEF) and eq. (2.112)
//! (curvilinear → Cartesian ECEF position).

use nalgebra::Vector3;

use crate::math;

/// Equatorial radius a, m (TR8350.2 table 3.1).
pub const EQUATORIAL_RADIUS_M: f64 = 6_378_137.0;
/// Flattening f = 1/298.257223563 (TR8350.2 table 3.1).
pub const FLATTENING: f64 = 1.0 / 298.257_223_563;
/// First eccentricity squared e² = f(2 − f).
pub const ECCENTRICITY_SQ: f64 = FLATTENING * (2.0 - FLATTENING);
/// Earth's gravitational constant GM (with the atmosphere), m³/s² (TR8350.2 table 3.1).
pub const GM_M3_S2: f64 = 3.986_004_418e14;
/// Second zonal harmonic J2 = −√5 C̄₂,₀ with C̄₂,₀ = −0.484166774985e−3 (TR8350.2 eq. 5-1).
pub const J2: f64 = 1.082_629_821_313_3e-3;
/// Earth's rotation rate ω_ie, rad/s (TR8350.2 table 3.1).
pub const EARTH_RATE_RAD_S: f64 = 7.292_115e-5;

/// Radius below which a position is refused as not physical (centre of the Earth, a
/// corrupted state): half the polar radius, m.
pub const MIN_RADIUS_M: f64 = 3.0e6;

/// Gravitational acceleration (mass attraction only) at ECEF position `r_e_m`, with the
/// J2 term (Groves eq. 2.142):
///
/// ```text
/// γ = −GM/r³ · { r + 1.5 J2 (a/r)² [ (1 − 5z²/r²) x, (1 − 5z²/r²) y, (3 − 5z²/r²) z ] }
/// ```
///
/// The field is symmetric about the polar axis, so the same expression holds in an
/// Earth-centred inertial frame whose Z is the polar axis. `None` below
/// [`MIN_RADIUS_M`] or for a non-finite position.
pub fn gravitation_m_s2(r_e_m: &Vector3<f64>) -> Option<Vector3<f64>> {
    let r2 = r_e_m.norm_squared();
    if !r2.is_finite() || r2 < MIN_RADIUS_M * MIN_RADIUS_M {
        return None;
    }
    let r = math::sqrt(r2);
    let inv_r2 = 1.0 / r2;
    let k = -GM_M3_S2 * inv_r2 / r; // −GM/r³
    let j = 1.5 * J2 * EQUATORIAL_RADIUS_M * EQUATORIAL_RADIUS_M * inv_r2;
    let z2 = 5.0 * r_e_m.z * r_e_m.z * inv_r2;
    let exy = 1.0 + j * (1.0 - z2);
    let ez = 1.0 + j * (3.0 - z2);
    Some(Vector3::new(k * r_e_m.x * exy, k * r_e_m.y * exy, k * r_e_m.z * ez))
}

/// Gravity in ECEF: gravitation plus the centrifugal term −ω_ie × (ω_ie × r)
/// = ω_ie² (x, y, 0) (Groves eq. 2.133). What a plumb line shows at rest on the Earth.
pub fn gravity_m_s2(r_e_m: &Vector3<f64>) -> Option<Vector3<f64>> {
    let w2 = EARTH_RATE_RAD_S * EARTH_RATE_RAD_S;
    gravitation_m_s2(r_e_m).map(|g| g + Vector3::new(w2 * r_e_m.x, w2 * r_e_m.y, 0.0))
}

/// ECEF position of geodetic latitude `lat_rad`, longitude `lon_rad` and ellipsoidal
/// height `h_m` (Groves eq. 2.112, with the transverse radius of curvature
/// R_E = a / √(1 − e² sin²L)).
pub fn ecef_from_geodetic(lat_rad: f64, lon_rad: f64, h_m: f64) -> Vector3<f64> {
    let (sl, cl) = crate::math::sin_cos(lat_rad);
    let (so, co) = crate::math::sin_cos(lon_rad);
    let re = EQUATORIAL_RADIUS_M / math::sqrt(1.0 - ECCENTRICITY_SQ * sl * sl);
    Vector3::new((re + h_m) * cl * co, (re + h_m) * cl * so, ((1.0 - ECCENTRICITY_SQ) * re + h_m) * sl)
}
