//! The calibration table: one definition for the firmware, the simulator and the lab.
//!
//! Capabilities:
//! - per-FOG zero bias, scale-factor error and thermal model (3rd-order polynomial in
//!   temperature T plus the temperature rate G = dT/dt and the product T·G; the paper
//!   found G dominant),
//! - the eight misalignment angles δ12, δ13, δ21, δ23, δ31, δ32, δ42, δ43 of the paper's
//!   first ground-calibration method and the nominal FOG4 angle γ = 125°15'52",
//! - the star-tracker mounting (FOG/ICS to star-tracker instrument frame, δΨ_Λ of eq. 5),
//! - the observer's noise figures, an optional gain override and how long it flies,
//! - a versioned binary form with CRC-32 ([`binary`]), stored as two generation-numbered
//!   copies with their own CRC-32 ([`store`]: fallback and atomic update), and, with feature `serde`, the
//!   readable TOML form used on the host. `docs/CALIBRATION.md` documents both.
//!
//! Error model of FOG *i* that this table compensates (the simulator generates it):
//!
//! ```text
//! ω_i,raw = (1 + k_i) · (s_i · ω) + b_i + a1 ΔT + a2 ΔT² + a3 ΔT³ + g G + h ΔT G + noise
//! ΔT = T − T_ref,   G = dT/dt
//! ```
//!
//! where `s_i` is the calibrated sensitive axis ([`Misalignment::axes`]).

pub mod accel;
pub mod binary;
pub mod field;
pub mod section;
pub mod store;

pub use field::{Field, FieldError, FogTerm};

use crate::math;
use nalgebra::Vector3;

/// Number of FOG slots in the table (spacecraft unit: four; launch vehicle: first three).
pub const N_FOG: usize = 4;

/// Nominal angle γ of the paper's FOG4 definition: 125°15'52" = 2.186276 rad
/// (the angle whose cosine is −1/√3: FOG4 equally inclined to the orthogonal three).
pub const GAMMA_NOMINAL_RAD: f64 = 2.186_276_035_465_284;

/// Error terms of one FOG, in the units of the names (rad/s, °C, °C/s).
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
#[cfg_attr(feature = "serde", serde(deny_unknown_fields))]
pub struct FogCal {
    /// Zero bias b, rad/s (systematic, temperature-independent part).
    pub bias_rad_s: f64,
    /// Scale-factor error k: output = (1 + k) × input (dimensionless; 2e-5 = 0.002 %).
    pub scale_factor_error: f64,
    /// Reference temperature T_ref of the thermal polynomial, °C.
    pub t_ref_degc: f64,
    /// Coefficients a1, a2, a3 of ΔT, ΔT², ΔT³ (rad/s per °C, °C², °C³).
    pub thermal_t_rad_s: [f64; 3],
    /// Coefficient g of the temperature rate G, rad/s per (°C/s).
    pub thermal_g_rad_s_per_degc_s: f64,
    /// Coefficient h of ΔT·G, rad/s per (°C·°C/s).
    pub thermal_tg_rad_s_per_degc2_s: f64,
}

impl FogCal {
    /// A FOG with no errors (the default when nothing is known).
    pub const IDEAL: FogCal = FogCal {
        bias_rad_s: 0.0,
        scale_factor_error: 0.0,
        t_ref_degc: 25.0,
        thermal_t_rad_s: [0.0; 3],
        thermal_g_rad_s_per_degc_s: 0.0,
        thermal_tg_rad_s_per_degc2_s: 0.0,
    };

    /// Total systematic drift b + thermal(T, G), rad/s.
    pub fn drift_rad_s(&self, temperature_degc: f64, t_rate_degc_s: f64) -> f64 {
        let dt = temperature_degc - self.t_ref_degc;
        let [a1, a2, a3] = self.thermal_t_rad_s;
        self.bias_rad_s
            + dt * (a1 + dt * (a2 + dt * a3))
            + t_rate_degc_s * (self.thermal_g_rad_s_per_degc_s + dt * self.thermal_tg_rad_s_per_degc2_s)
    }
}

/// Sensitive-axis misalignment angles of the paper's first method, rad.
///
/// FOG1: rotate X_P by δ13 about Z_P, then by δ12 about the new Y'; FOG2 and FOG3 alike;
/// FOG4 (opposite to its SA): α = π/4 + δ43 about Z_P, then clockwise β = (γ − π/2) − δ42
/// about Y'. To first order: s1 = (1, δ13, −δ12), s2 = (−δ23, 1, δ21), s3 = (δ32, −δ31, 1),
/// s4 = −(c_γ2, c_γ2, s_γ) + δ42 (−s_γ2, −s_γ2, c_γ) + δ43 c_γ2 (1, −1, 0), which are the
/// rows of the paper's calibration equations.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
#[cfg_attr(feature = "serde", serde(deny_unknown_fields))]
pub struct Misalignment {
    /// δ12, rad.
    pub d12_rad: f64,
    /// δ13, rad.
    pub d13_rad: f64,
    /// δ21, rad.
    pub d21_rad: f64,
    /// δ23, rad.
    pub d23_rad: f64,
    /// δ31, rad.
    pub d31_rad: f64,
    /// δ32, rad.
    pub d32_rad: f64,
    /// δ42, rad.
    pub d42_rad: f64,
    /// δ43, rad.
    pub d43_rad: f64,
}

impl Misalignment {
    /// Unit sensitive axes s1..s4 in the instrument frame (ICS), exact (not linearised).
    pub fn axes(&self, gamma_rad: f64) -> [Vector3<f64>; N_FOG] {
        // FOG1: Rz(δ13) then Ry'(δ12) applied to X: (cos δ12 cos δ13, cos δ12 sin δ13, −sin δ12).
        let s1 = two_turns(self.d13_rad, self.d12_rad);
        // FOG2: the same construction with the axes cycled (Y ← X, Z ← Y, X ← Z):
        // first δ21 about X_P toward Z then δ23 about Z toward −X; linear: (−δ23, 1, δ21).
        let t2 = two_turns(self.d21_rad, self.d23_rad);
        let s2 = Vector3::new(t2.z, t2.x, t2.y);
        // FOG3: cycled again; linear: (δ32, −δ31, 1).
        let t3 = two_turns(self.d32_rad, self.d31_rad);
        let s3 = Vector3::new(t3.y, t3.z, t3.x);
        // FOG4: the vector opposite to its SA, α = π/4 + δ43, clockwise β = γ − π/2 − δ42.
        let alpha = core::f64::consts::FRAC_PI_4 + self.d43_rad;
        let beta = (gamma_rad - core::f64::consts::FRAC_PI_2) - self.d42_rad;
        let (sa, ca) = crate::math::sin_cos(alpha);
        let (sb, cb) = crate::math::sin_cos(beta);
        let s4 = -Vector3::new(cb * ca, cb * sa, sb);
        [s1, s2, s3, s4]
    }
}

/// X axis turned by `first` about Z, then by `second` about the new Y (right-handed):
/// (cos second · cos first, cos second · sin first, −sin second).
fn two_turns(first_rad: f64, second_rad: f64) -> Vector3<f64> {
    let (s1, c1) = crate::math::sin_cos(first_rad);
    let (s2, c2) = crate::math::sin_cos(second_rad);
    Vector3::new(c2 * c1, c2 * s1, -s2)
}

/// Observer gains of eq. (6), per axis, for the discrete update at each star-tracker frame.
#[derive(Debug, Clone, Copy, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
#[cfg_attr(feature = "serde", serde(deny_unknown_fields))]
#[repr(C)]
pub struct ObserverGains {
    /// K_B: fraction of the attitude mismatch removed per update (dimensionless).
    pub k_b: [f64; 3],
    /// K_U: drift-estimate change per update per rad of mismatch, 1/s.
    pub k_u_per_s: [f64; 3],
}

impl ObserverGains {
    /// Gains "selected from a given performance" (the paper, after eq. 6): per axis a
    /// critically damped loop s² + (2/τ) s + 1/τ² with time constant `tau_s`, for updates
    /// every `period_s`: K_B = 2T/τ, K_U = T/τ². Zero or negative inputs give zero gains.
    pub fn critically_damped(tau_s: f64, period_s: f64) -> Self {
        let (kb, ku) = if tau_s > 0.0 && period_s > 0.0 {
            ((2.0 * period_s / tau_s).min(0.9), period_s / (tau_s * tau_s))
        } else {
            (0.0, 0.0)
        };
        ObserverGains { k_b: [kb; 3], k_u_per_s: [ku; 3] }
    }
}

/// Noise figures from which the observer computes its steady-state Kalman gains.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
#[cfg_attr(feature = "serde", serde(deny_unknown_fields))]
pub struct ObserverConfig {
    /// Gyro angle random walk, °/√h (paper: spectral density 0.005 °/√h).
    pub arw_deg_sqrt_h: f64,
    /// Gyro rate random walk (bias instability drift), °/h/√h.
    pub rrw_deg_h_sqrt_h: f64,
    /// Star-tracker noise, 1σ per axis, arcsec.
    pub st_sigma_arcsec: f64,
    /// Nominal star-tracker update period, s (the gains are computed for it).
    pub st_period_s: f64,
    /// Gains that replace the computed ones when present (the Luenberger observer's).
    pub gains_override: Option<ObserverGains>,
    /// The estimator that flies (default: the paper's eq. (6) observer).
    #[cfg_attr(feature = "serde", serde(default))]
    pub estimator: Estimator,
    /// Drift (gyro bias) 1σ per axis at alignment, °/h: the MEKF's initial bias covariance
    /// (the paper: random zero signal ±0.3 °/h, 3σ, before calibration, so 0.1).
    #[cfg_attr(feature = "serde", serde(default = "paper_initial_drift_sigma_deg_h"))]
    pub initial_drift_sigma_deg_h: f64,
    /// Acquisition time t_acq after alignment, s, of a two-stage ("gear shift") observer:
    /// `gains_override` flies for t_acq, then the steady-state Kalman gains
    /// ([`crate::observer::steady_state_gains`]); each stage is eq. (6) with fixed gains.
    /// 0 (the default, and what a table without the field means): `gains_override`, when
    /// present, flies throughout. No effect without an override, nor on the MEKF.
    ///
    /// For override gains of a critically damped loop with time constant τ the drift
    /// error left of an initial δb₀ after t is δb₀ (1 + t/τ) e^(−t/τ): choose t_acq = n τ
    /// with (1 + n) e^(−n) ≤ σ_b / (3 σ_b0), σ_b the steady-state drift 1σ and σ_b0 the
    /// initial one (`initial_drift_sigma_deg_h`); the Fig. 7 table: 30 °/h, 0.0071 °/h,
    /// τ = 60 s → n = 12, 720 s.
    #[cfg_attr(feature = "serde", serde(default))]
    pub acquisition_s: f64,
    /// The star tracker's low-frequency error (LFE), 1σ per tracker axis, arcsec: a
    /// first-order Gauss–Markov error with correlation time `st_lfe_tau_s`, which the MEKF
    /// carries as three more states ([`crate::observer::mekf`]). Ignored while
    /// `st_lfe_tau_s` is 0.
    #[cfg_attr(feature = "serde", serde(default))]
    pub st_lfe_sigma_arcsec: f64,
    /// The LFE's correlation time, s; 0 (the default, and what a table without the field
    /// means): a white star tracker, the 6-state MEKF.
    #[cfg_attr(feature = "serde", serde(default))]
    pub st_lfe_tau_s: f64,
}

impl ObserverConfig {
    /// Whether the table describes a star-tracker LFE (both its 1σ and its correlation
    /// time above 0): the MEKF then carries it.
    #[inline]
    pub fn lfe(&self) -> bool {
        self.st_lfe_sigma_arcsec > 0.0 && self.st_lfe_tau_s > 0.0
    }
}

/// The paper's pre-calibration random zero signal, ±0.3 °/h (3σ), as 1σ.
pub const PAPER_INITIAL_DRIFT_SIGMA_DEG_H: f64 = 0.1;

#[cfg(feature = "serde")]
fn paper_initial_drift_sigma_deg_h() -> f64 {
    PAPER_INITIAL_DRIFT_SIGMA_DEG_H
}

/// Which estimator corrects the attitude and drift at star-tracker frames.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
#[cfg_attr(feature = "serde", serde(rename_all = "snake_case"))]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub enum Estimator {
    /// The paper's eq. (6) Luenberger observer with fixed (steady-state Kalman) gains.
    #[default]
    Luenberger,
    /// A multiplicative extended Kalman filter: attitude error and gyro bias, 6 states,
    /// its own running covariance gives the gains, the gate and the 1σ.
    Mekf,
}

impl Estimator {
    /// Its code in the binary table (byte 461).
    pub const fn code(self) -> u8 {
        match self {
            Estimator::Luenberger => 0,
            Estimator::Mekf => 1,
        }
    }

    /// The estimator of binary code `c`, `None` for a code this format does not define.
    pub const fn from_code(c: u8) -> Option<Estimator> {
        match c {
            0 => Some(Estimator::Luenberger),
            1 => Some(Estimator::Mekf),
            _ => None,
        }
    }
}

impl ObserverConfig {
    /// The paper's sensors: ARW 0.005 °/√h, 20″ (3σ) star tracker at 4 Hz, and an assumed
    /// rate random walk of 0.01 °/h/√h.
    pub const PAPER: ObserverConfig = ObserverConfig {
        arw_deg_sqrt_h: 0.005,
        rrw_deg_h_sqrt_h: 0.01,
        st_sigma_arcsec: 20.0 / 3.0,
        st_period_s: 0.25,
        gains_override: None,
        estimator: Estimator::Luenberger,
        initial_drift_sigma_deg_h: PAPER_INITIAL_DRIFT_SIGMA_DEG_H,
        acquisition_s: 0.0,
        st_lfe_sigma_arcsec: 0.0,
        st_lfe_tau_s: 0.0,
    };
}

/// The whole calibration table.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
#[cfg_attr(feature = "serde", serde(deny_unknown_fields))]
pub struct CalibrationTable {
    /// Revision of this table's content (chosen by whoever writes it; not the format).
    pub revision: u32,
    /// Per-FOG error terms.
    pub fog: [FogCal; N_FOG],
    /// Sensitive-axis misalignment (first ground-calibration method).
    pub misalignment: Misalignment,
    /// FOG4 angle γ, rad (nominal [`GAMMA_NOMINAL_RAD`]).
    pub gamma_rad: f64,
    /// Star-tracker mounting q_bs, scalar first: Λ_st = Λ_ICS ∘ q_bs (eq. 5's δΨ_Λ plus
    /// the nominal mount).
    pub st_mount_q: [f64; 4],
    /// Time constant of the temperature-rate (G) estimator, s.
    pub t_rate_filter_s: f64,
    /// Observer noise figures and optional gains.
    pub observer: ObserverConfig,
}

impl CalibrationTable {
    /// Nominal geometry, ideal FOGs, the paper's observer figures: what the unit flies
    /// with (flagged) when no valid table is stored.
    pub const DEFAULT: CalibrationTable = CalibrationTable {
        revision: 0,
        fog: [FogCal::IDEAL; N_FOG],
        misalignment: Misalignment {
            d12_rad: 0.0,
            d13_rad: 0.0,
            d21_rad: 0.0,
            d23_rad: 0.0,
            d31_rad: 0.0,
            d32_rad: 0.0,
            d42_rad: 0.0,
            d43_rad: 0.0,
        },
        gamma_rad: GAMMA_NOMINAL_RAD,
        st_mount_q: [1.0, 0.0, 0.0, 0.0],
        t_rate_filter_s: 30.0,
        observer: ObserverConfig::PAPER,
    };

    /// Checks that every number is finite and within its plausible range ([`field`]: the
    /// ranges and why), and that the star-tracker mount is a unit quaternion. The refusal
    /// names the first field outside, in storage order, with its value. No allocation, no
    /// panic: the boot policy runs it on every stored copy before accepting it.
    pub fn validate(&self) -> Result<(), TableError> {
        for f in Field::all() {
            if f.is_gain() && self.observer.gains_override.is_none() {
                continue;
            }
            let v = f.get(self);
            if !f.spec().admits(v) {
                return Err(TableError::Field(FieldError::new(f, v)));
            }
        }
        if self.observer.lfe() && self.observer.gains_override.is_some() {
            return Err(TableError::LfeWithGains);
        }
        let n2: f64 = self.st_mount_q.iter().map(|x| x * x).sum();
        if (n2 - 1.0).abs() > 1e-9 {
            return Err(TableError::MountNotUnit);
        }
        Ok(())
    }

    /// Calibrated sensitive axes of the four FOGs in the instrument frame.
    pub fn axes(&self) -> [Vector3<f64>; N_FOG] {
        self.misalignment.axes(self.gamma_rad)
    }

    /// Star-tracker mount as a normalised quaternion.
    pub fn st_mount(&self) -> nalgebra::Quaternion<f64> {
        let [w, x, y, z] = self.st_mount_q;
        let mut q = nalgebra::Quaternion::new(w, x, y, z);
        math::normalize(&mut q);
        q
    }
}

/// Why a table was refused.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub enum TableError {
    /// Buffer shorter than the header or the length it declares.
    Truncated,
    /// Magic bytes are not `SSCT`.
    BadMagic,
    /// Format version this firmware does not read.
    UnsupportedVersion,
    /// Declared payload length does not match the format version.
    BadLength,
    /// CRC-32 mismatch.
    BadCrc,
    /// A number that is not finite or outside its plausible range: which, and its value.
    Field(FieldError),
    /// The star-tracker mount quaternion is not of unit length (within 1e-9 in |q|²).
    MountNotUnit,
    /// Flag or padding bits that this format does not define are set.
    BadFlags,
    /// A star-tracker LFE and a gain override together: the binary form stores the LFE in
    /// the override's slots ([`binary`]), and the LFE is the MEKF's, the override the
    /// fixed-gain observer's.
    LfeWithGains,
    /// The encoded table does not decode back to the same table.
    RoundTrip,
    /// Output buffer too small for encoding.
    BufferTooSmall,
}

impl core::fmt::Display for TableError {
    /// The variant's name, and for a refused field its name, value and range.
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            TableError::Field(e) => write!(f, "{e}"),
            TableError::LfeWithGains => f.write_str(
                "observer.st_lfe_sigma_arcsec and st_lfe_tau_s with observer.gains_override: a table holds one \
                 or the other (docs/CALIBRATION.md)",
            ),
            other => write!(f, "{other:?}"),
        }
    }
}
