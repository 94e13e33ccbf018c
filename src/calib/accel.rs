//! Accelerometer section of the calibration (launch-vehicle unit: three pendulous
//! accelerometers on the FOG triad's orthogonal axes).
//!
//! Kept as its own section with its own binary form ([`AccelTable::to_bytes`], magic
//! `SSCA`) rather than inside the FOG table: the FOG table's binary layout (format
//! version 1, 464 bytes) is fixed by its tests and by stored tables, and the spacecraft
//! unit has no accelerometers. `docs/CALIBRATION.md` describes the FOG table.
//!
//! Error model of accelerometer *i* (X, Y, Z), which [`AccelCompensator::compensate`] inverts
//! and the simulator generates:
//!
//! ```text
//! f_i,raw = (1 + k_i + k_T,i ΔT) · a_i + k2_i · a_i² + b_i + c1_i ΔT + c2_i ΔT² + noise
//! a_i = u_i · f,   ΔT = T − T_ref,i
//! ```
//!
//! with f the specific force in the instrument (body) frame and u_i the unit sensitive
//! axis, tilted from the body axis by two small angles (linear form
//! u_x = (1, m_xy, m_xz), u_y = (m_yx, 1, m_yz), u_z = (m_zx, m_zy, 1), normalised).
//! In increment form over Δt the terms are multiplied by Δt and a_i² Δt ≈ (a_i Δt)²/Δt.

use nalgebra::{Matrix3, Vector3};

use super::section::{self, SectionError};
use crate::math;

/// Number of accelerometers.
pub const N_ACCEL: usize = 3;

/// Error terms of one accelerometer (units in the names).
#[derive(Debug, Clone, Copy, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
#[cfg_attr(feature = "serde", serde(deny_unknown_fields))]
#[repr(C)]
pub struct AccelCal {
    /// Bias b, m/s².
    pub bias_m_s2: f64,
    /// Scale-factor error k (dimensionless).
    pub scale_factor_error: f64,
    /// Second-order (pendulum) nonlinearity k2, (m/s²)⁻¹.
    pub k2_per_m_s2: f64,
    /// Reference temperature, °C.
    pub t_ref_degc: f64,
    /// Bias thermal coefficients c1, c2: m/s² per °C and per °C².
    pub bias_thermal_m_s2: [f64; 2],
    /// Scale-factor thermal coefficient k_T, per °C.
    pub scale_thermal_per_degc: f64,
}

impl AccelCal {
    /// An accelerometer with no errors.
    pub const IDEAL: AccelCal = AccelCal {
        bias_m_s2: 0.0,
        scale_factor_error: 0.0,
        k2_per_m_s2: 0.0,
        t_ref_degc: 25.0,
        bias_thermal_m_s2: [0.0; 2],
        scale_thermal_per_degc: 0.0,
    };

    /// Bias at temperature T, m/s².
    pub fn bias_at_m_s2(&self, temperature_degc: f64) -> f64 {
        let dt = temperature_degc - self.t_ref_degc;
        let [c1, c2] = self.bias_thermal_m_s2;
        self.bias_m_s2 + dt * (c1 + dt * c2)
    }

    /// Scale factor 1 + k + k_T ΔT at temperature T.
    pub fn scale_at(&self, temperature_degc: f64) -> f64 {
        1.0 + self.scale_factor_error + self.scale_thermal_per_degc * (temperature_degc - self.t_ref_degc)
    }
}

/// Sensitive-axis misalignment of the three accelerometers, rad (small angles, see the
/// module documentation for the axes they build).
#[derive(Debug, Clone, Copy, PartialEq, Default, bytemuck::AnyBitPattern)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
#[cfg_attr(feature = "serde", serde(deny_unknown_fields))]
pub struct AccelMisalignment {
    /// m_xy, m_xz: X accelerometer's tilt toward Y and Z, rad.
    pub x_rad: [f64; 2],
    /// m_yx, m_yz.
    pub y_rad: [f64; 2],
    /// m_zx, m_zy.
    pub z_rad: [f64; 2],
}

impl AccelMisalignment {
    /// Matrix whose rows are the unit sensitive axes u_x, u_y, u_z (body components).
    pub fn axes(&self) -> Matrix3<f64> {
        let [xy, xz] = self.x_rad;
        let [yx, yz] = self.y_rad;
        let [zx, zy] = self.z_rad;
        let unit = |v: Vector3<f64>| {
            let n = math::sqrt(v.norm_squared());
            v / n
        };
        let ux = unit(Vector3::new(1.0, xy, xz));
        let uy = unit(Vector3::new(yx, 1.0, yz));
        let uz = unit(Vector3::new(zx, zy, 1.0));
        Matrix3::from_rows(&[ux.transpose(), uy.transpose(), uz.transpose()])
    }
}

/// Why an accelerometer table was refused.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub enum AccelTableError {
    /// Wrong length.
    Length,
    /// Wrong magic.
    Magic,
    /// Unknown format version.
    Version,
    /// CRC mismatch.
    Crc,
    /// A value is not finite, a scale factor not near 1, or a misalignment above
    /// [`AccelTable::MAX_MISALIGNMENT_RAD`] (the axes would not be invertible safely).
    Value,
}

impl From<SectionError> for AccelTableError {
    fn from(e: SectionError) -> Self {
        match e {
            SectionError::Length => AccelTableError::Length,
            SectionError::Magic => AccelTableError::Magic,
            SectionError::Version => AccelTableError::Version,
            SectionError::Crc => AccelTableError::Crc,
        }
    }
}

/// The accelerometer calibration section.
#[derive(Debug, Clone, Copy, PartialEq, bytemuck::AnyBitPattern)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
#[cfg_attr(feature = "serde", serde(deny_unknown_fields))]
pub struct AccelTable {
    /// Table revision.
    pub revision: u32,
    /// Accelerometers X, Y, Z.
    pub accel: [AccelCal; N_ACCEL],
    /// Sensitive-axis misalignment.
    pub misalignment: AccelMisalignment,
}

/// Magic bytes of the binary accelerometer section.
pub const MAGIC: [u8; 4] = *b"SSCA";
/// Format version.
pub const FORMAT_VERSION: u16 = 1;
/// f64 fields: 8 per accelerometer, then 6 misalignment angles.
pub const N_F64: usize = 8 * N_ACCEL + 6;
/// Binary length: magic 4, version 2, payload length 2, revision 4, fields, CRC-32 4.
pub const TABLE_LEN: usize = section::section_len(N_F64);

/// Compensated body velocity increments need the inverse of the axes matrix; it is
/// computed once when the table is accepted ([`AccelTable::compensator`]).
#[derive(Debug, Clone, Copy, PartialEq, bytemuck::AnyBitPattern)]
pub struct AccelCompensator {
    table: AccelTable,
    axes_inv: Matrix3<f64>,
}

impl AccelTable {
    /// Largest accepted misalignment angle, rad (10 mrad; real ones are ~1e-4).
    pub const MAX_MISALIGNMENT_RAD: f64 = 0.01;

    /// No errors.
    pub const IDEAL: AccelTable = AccelTable {
        revision: 0,
        accel: [AccelCal::IDEAL; N_ACCEL],
        misalignment: AccelMisalignment { x_rad: [0.0; 2], y_rad: [0.0; 2], z_rad: [0.0; 2] },
    };

    /// The f64 fields in storage order: per accelerometer (bias, k, k2, T_ref, c1, c2,
    /// k_T, reserved 0), then m_xy m_xz m_yx m_yz m_zx m_zy.
    pub fn fields(&self) -> [f64; N_F64] {
        let mut out = [0.0; N_F64];
        let per = self.accel.iter().flat_map(|a| {
            let [c1, c2] = a.bias_thermal_m_s2;
            [a.bias_m_s2, a.scale_factor_error, a.k2_per_m_s2, a.t_ref_degc, c1, c2, a.scale_thermal_per_degc, 0.0]
        });
        let m = &self.misalignment;
        let all = per.chain(m.x_rad).chain(m.y_rad).chain(m.z_rad);
        for (slot, v) in out.iter_mut().zip(all) {
            *slot = v;
        }
        out
    }

    fn from_fields(revision: u32, f: &[f64; N_F64]) -> Self {
        let mut t = AccelTable { revision, ..AccelTable::IDEAL };
        for (a, c) in t.accel.iter_mut().zip(f.chunks_exact(8)) {
            if let [bias, k, k2, tref, c1, c2, kt, _] = *c {
                *a = AccelCal {
                    bias_m_s2: bias,
                    scale_factor_error: k,
                    k2_per_m_s2: k2,
                    t_ref_degc: tref,
                    bias_thermal_m_s2: [c1, c2],
                    scale_thermal_per_degc: kt,
                };
            }
        }
        if let Some([a, b, c, d, e, g]) = f.get(8 * N_ACCEL..).and_then(|s| <[f64; 6]>::try_from(s).ok()) {
            t.misalignment = AccelMisalignment { x_rad: [a, b], y_rad: [c, d], z_rad: [e, g] };
        }
        t
    }

    /// Checks every value (finite; |k| < 0.1; |misalignment| ≤ [`Self::MAX_MISALIGNMENT_RAD`]).
    pub fn validate(&self) -> Result<(), AccelTableError> {
        let f = self.fields();
        if !f.iter().all(|v| v.is_finite()) {
            return Err(AccelTableError::Value);
        }
        if self.accel.iter().any(|a| a.scale_factor_error.abs() >= 0.1) {
            return Err(AccelTableError::Value);
        }
        let m = f.get(8 * N_ACCEL..).unwrap_or(&[]);
        if m.iter().any(|v| v.abs() > Self::MAX_MISALIGNMENT_RAD) {
            return Err(AccelTableError::Value);
        }
        Ok(())
    }

    /// Binary form (little-endian; CRC-32/ISO-HDLC over everything before it;
    /// [`super::section`]).
    pub fn to_bytes(&self) -> [u8; TABLE_LEN] {
        let mut out = [0u8; TABLE_LEN];
        section::encode(MAGIC, FORMAT_VERSION, self.revision, &self.fields(), &mut out);
        out
    }

    /// Decodes and validates a binary section. Checks, in order: length, magic,
    /// version, declared payload length, CRC, values ([`AccelTable::validate`]).
    pub fn from_bytes(bytes: &[u8]) -> Result<Self, AccelTableError> {
        let (revision, f) = section::decode::<N_F64>(bytes, MAGIC, FORMAT_VERSION)?;
        let t = AccelTable::from_fields(revision, &f);
        t.validate()?;
        Ok(t)
    }

    /// The compensator for this table (validates it and inverts the axes matrix once).
    pub fn compensator(&self) -> Result<AccelCompensator, AccelTableError> {
        self.validate()?;
        let axes_inv = self.misalignment.axes().try_inverse().ok_or(AccelTableError::Value)?;
        Ok(AccelCompensator { table: *self, axes_inv })
    }
}

impl AccelCompensator {
    /// The table it compensates with.
    pub fn table(&self) -> &AccelTable {
        &self.table
    }

    /// Compensated body velocity increment over `dt_s` from the three raw increments
    /// `dv_raw_m_s` (X, Y, Z accelerometers, m/s) at temperatures `temperature_degc`:
    /// per channel y = (Δv_raw − b(T) Δt − k2 y²/Δt) / (1 + k + k_T ΔT), solved by two
    /// fixed-point passes from y₀ = (Δv_raw − b Δt)/(1 + k + k_T ΔT) (each pass multiplies
    /// the error by ~2 k2 a: after two, ~4 k2³ a⁴ Δt, 5e-14 m/s per step for k2 = 10 µg/g²
    /// at 85 m/s²; one pass would leave ~2 k2² a³ Δt = 1.6e-9 m/s per step, which adds up),
    /// then Δv_b = U⁻¹ y with U the axes matrix. `None` for a non-positive `dt_s`.
    pub fn compensate(
        &self,
        dv_raw_m_s: &Vector3<f64>,
        temperature_degc: &[f64; N_ACCEL],
        dt_s: f64,
    ) -> Option<Vector3<f64>> {
        if !(dt_s.is_finite() && dt_s > 0.0) {
            return None;
        }
        let inv_dt = 1.0 / dt_s;
        let mut y = Vector3::zeros();
        for ((out, (cal, t)), raw) in
            y.iter_mut().zip(self.table.accel.iter().zip(temperature_degc.iter())).zip(dv_raw_m_s.iter())
        {
            let inv_s = 1.0 / cal.scale_at(*t);
            let lin = raw - cal.bias_at_m_s2(*t) * dt_s;
            let y0 = lin * inv_s;
            let y1 = (lin - cal.k2_per_m_s2 * y0 * y0 * inv_dt) * inv_s;
            *out = (lin - cal.k2_per_m_s2 * y1 * y1 * inv_dt) * inv_s;
        }
        Some(self.axes_inv * y)
    }
}
