//! The Earth at the test site: its rotation rate and magnetic field in the instrument frame
//! of a turntable session (`docs/SESSION-FORMAT.md`), the site and the field models (WMM2025,
//! the paper's dipole), and the unit's nominal axes.

use crate::*;

/// Earth rotation rate, rad/s (15.041068 °/h, the paper's ω_E).
pub const EARTH_RATE_RAD_S: f64 = 15.041_068 / 3600.0 * std::f64::consts::PI / 180.0;

/// Nominal sensitive axes s_i of the unit (misalignment zero, γ nominal), ICS.
pub fn nominal_axes() -> [nalgebra::Vector3<f64>; 4] {
    Misalignment::default().axes(GAMMA_NOMINAL_RAD)
}

/// Earth rate in ICS for the turntable geometry of `docs/SESSION-FORMAT.md`: Z_P up,
/// X_P at azimuth ψ (from north, clockwise), so ω = (Ω_N cos ψ, Ω_N sin ψ, Ω_U), with
/// Ω_N = ω_E cos φ, Ω_U = ω_E sin φ (the paper's reference ω* = ω_E sin φ for a vertical SA).
pub fn earth_rate_ics(psi_rad: f64, lat_rad: f64) -> [f64; 3] {
    let (n, u) = (EARTH_RATE_RAD_S * lat_rad.cos(), EARTH_RATE_RAD_S * lat_rad.sin());
    [n * psi_rad.cos(), n * psi_rad.sin(), u]
}

/// The Earth's field in ICS for the turntable geometry of `docs/SESSION-FORMAT.md` (the frame
/// of [`earth_rate_ics`]: Z_P up, X_P at azimuth ψ from north, clockwise), from its local
/// components (north, west, up), nT: X_P = (cos ψ, −sin ψ, 0) and Y_P = (sin ψ, cos ψ, 0) in
/// (north, west, up), so
///
/// ```text
/// B = (B_N cos ψ − B_W sin ψ,  B_N sin ψ + B_W cos ψ,  B_U)
/// ```
///
/// The paper's B_Π matrix (eq. 3) is this with its azimuth counted counter-clockwise,
/// ψ_Π = −ψ. At ψ = 90° the paper's Kharkov field (21846, 5959, −42343) gives
/// (−5959, 21846, −42343).
pub fn field_ics_nt(b_nwu_nt: [f64; 3], psi_rad: f64) -> [f64; 3] {
    let (s, c) = psi_rad.sin_cos();
    [b_nwu_nt[0] * c - b_nwu_nt[1] * s, b_nwu_nt[0] * s + b_nwu_nt[1] * c, b_nwu_nt[2]]
}

/// The paper's test site, Kharkov: latitude φ = 50°03′ and longitude λ = 36°17′ (degrees),
/// height 150 m.
pub const KHARKOV_SITE: Site = Site { lat_deg: 50.0 + 3.0 / 60.0, lon_deg: 36.0 + 17.0 / 60.0, height_m: 150.0 };

/// The date the simulators take for the field: 2025, day 1 (WMM2025's epoch).
pub const FIELD_EPOCH: (i32, u16) = (2025, 1);

/// The paper's dipole-tilt field at Kharkov, (north, west, up), nT: its worked example
/// (21 846, 5 959, −42 343), as `ssis_methods::magnetic::DipoleTilt::PAPER` computes it.
pub const PAPER_DIPOLE_KHARKOV_NWU_NT: [f64; 3] = [21846.305885789792, 5958.978155627933, -42342.86237302601];

/// A place on the Earth (WGS 84).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Site {
    /// Latitude, degrees north.
    pub lat_deg: f64,
    /// Longitude, degrees east.
    pub lon_deg: f64,
    /// Height above the ellipsoid, m.
    pub height_m: f64,
}

/// Which Earth field a magnetic session is simulated with, or calibrated against.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum FieldModel {
    /// The World Magnetic Model 2025 at the site and date (the real main field; the default).
    #[default]
    Wmm2025,
    /// The paper's dipole tilt (its worked example, Kharkov only): 2.5–9 µT off the real field.
    PaperDipole,
}

impl FieldModel {
    /// The field at `site` on `date` (year, day of the year), (north, west, up), nT. The
    /// paper's dipole is only given at Kharkov: another site is refused.
    pub fn nwu_nt(self, site: Site, date: (i32, u16)) -> Result<[f64; 3], String> {
        match self {
            FieldModel::Wmm2025 => wmm_field_nwu_nt(site, date),
            FieldModel::PaperDipole if site == KHARKOV_SITE => Ok(PAPER_DIPOLE_KHARKOV_NWU_NT),
            FieldModel::PaperDipole => Err(format!(
                "the paper's dipole field is given for Kharkov only ({:.4}°, {:.4}°), not {:.4}°, {:.4}°",
                KHARKOV_SITE.lat_deg, KHARKOV_SITE.lon_deg, site.lat_deg, site.lon_deg
            )),
        }
    }

    /// Its name in messages and on the command line.
    pub fn name(self) -> &'static str {
        match self {
            FieldModel::Wmm2025 => "WMM2025",
            FieldModel::PaperDipole => "the paper's dipole tilt",
        }
    }
}

/// The Earth's main field at `site` on `date` (year, day of the year) from the World
/// Magnetic Model 2025 (the `world_magnetic_model` crate), (north, west, up), nT.
pub fn wmm_field_nwu_nt(site: Site, date: (i32, u16)) -> Result<[f64; 3], String> {
    use world_magnetic_model::time::Date;
    use world_magnetic_model::uom::si::angle::degree;
    use world_magnetic_model::uom::si::f32::{Angle, Length};
    use world_magnetic_model::uom::si::length::meter;
    use world_magnetic_model::uom::si::magnetic_flux_density::nanotesla;
    use world_magnetic_model::GeomagneticField;
    let (year, day) = date;
    let d = Date::from_ordinal_date(year, day).map_err(|e| format!("date {year}-{day:03}: {e}"))?;
    let f = GeomagneticField::new(
        Length::new::<meter>(site.height_m as f32),
        Angle::new::<degree>(site.lat_deg as f32),
        Angle::new::<degree>(site.lon_deg as f32),
        d,
    )
    .map_err(|e| format!("WMM at {}°, {}°, {} m, {year}-{day:03}: {e}", site.lat_deg, site.lon_deg, site.height_m))?;
    // WMM gives X north, Y east, Z down.
    let (x, y, z) = (f.x().get::<nanotesla>() as f64, f.y().get::<nanotesla>() as f64, f.z().get::<nanotesla>() as f64);
    Ok([x, -y, -z])
}

/// The inverse of [`field_ics_nt`]: (north, west, up) components from the ICS ones at ψ.
pub fn field_nwu_nt(b_ics_nt: [f64; 3], psi_rad: f64) -> [f64; 3] {
    let (s, c) = psi_rad.sin_cos();
    [b_ics_nt[0] * c + b_ics_nt[1] * s, -b_ics_nt[0] * s + b_ics_nt[1] * c, b_ics_nt[2]]
}
