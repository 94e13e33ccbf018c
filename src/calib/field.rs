//! The table's numbers one by one: each [`Field`]'s name (its path in the TOML form), unit,
//! engineering unit and plausible range, and the typed refusal [`FieldError`] that names the
//! field, its value and the range.
//!
//! The order of [`Field::from_index`] is the binary storage order of [`super::binary::fields`]
//! for the first [`super::binary::N_F64`]; the last two, the star tracker's low-frequency
//! error, are stored in the gain override's first two slots ([`super::binary`]).
//! [`super::CalibrationTable::validate`] checks every field against its range (in
//! engineering units) and refuses the first that is outside, or not finite: on the host at
//! every write and at `to-bin`, on the target at every boot before a stored copy is
//! accepted ([`super::store::load`], called by the boot policy).
//!
//! **Why these ranges** (the unit's FOGs are the paper's medium-accuracy OIUS-501 class:
//! systematic zero signal ±1 °/h and random ±0.3 °/h (3σ) before calibration, noise
//! spectral density 0.005 °/√h, scale factor ±0.1 %, sensitive-axis orientation ±306″;
//! the chamber +10…+40 °C). Each range is generous but finite, so that only a number no
//! FOG of this class can have is refused:
//!
//! - bias: ±100 °/h, 100 × the systematic zero signal before calibration;
//! - scale-factor error: ±10,000 ppm (1 %), 10 × the pre-calibration ±0.1 %;
//! - T_ref: −60…+100 °C, the span the firmware trusts a FOG's temperature sensor over;
//! - thermal coefficients: each term alone at most the bias bound, 100 °/h, at the edge of
//!   |ΔT| = 50 °C and |G| = 0.1 °C/s (6 °C/min, beyond any chamber ramp): a1 ±2 °/h/°C,
//!   a2 ±0.04 °/h/°C², a3 ±8·10⁻⁴ °/h/°C³, g ±16.7 °/h per °C/min (±1000 °/h per °C/s),
//!   h ±0.333 °/h per °C·°C/min;
//! - misalignment angles: ±3600″ (1°), 12 × the ±306″ before calibration; γ within 1° of
//!   its nominal 125°15'52";
//! - star-tracker mount: each component of a unit quaternion in −1…1 (and |q| = 1);
//! - G-filter time constant: 0.1…3600 s;
//! - ARW: 0.0005…0.05 °/√h, a decade either side of the paper's 0.005 °/√h (an ARW of
//!   0.48 °/√h is a turntable run read as noise, not this FOG);
//! - RRW: 0.0001…0.1 °/h/√h (the paper's assumption 0.01; 0.1 would walk the bias by
//!   0.1 °/h in an hour, twice the post-calibration ±0.05 °/h; 53,954 °/h/√h is refused);
//! - star-tracker noise 0.1…100″ (1σ; the paper's tracker 6.7″), period 5 ms…10 s;
//! - gain override: K_B in 10⁻⁹…0.999, K_U in 0…0.999 1/s (a stable first-order loop);
//! - initial drift 1σ: 0.001…100 °/h (the paper's pre-calibration random zero signal is
//!   0.1 °/h 1σ; 100 °/h is the bias bound);
//! - acquisition time: 0…7200 s (0: the override flies throughout; the steady-state
//!   gains' own slowest pole is about 30 min at 4 Hz, so an acquisition of more than
//!   four of them would outlast the bias it is meant to find faster);
//! - star-tracker low-frequency error (LFE): 1σ 0…100″ per axis (the noise's own range;
//!   real trackers: a few arcseconds), correlation time 0…86,400 s (0: a white tracker;
//!   the time stars take to cross the field of view, tens to hundreds of seconds on an
//!   Earth-pointing satellite, and a day bounds an inertially pointing one's).

use core::fmt;

use super::{CalibrationTable, GAMMA_NOMINAL_RAD, N_FOG};

/// (°/h) per (rad/s).
const DEG_H: f64 = 180.0 / core::f64::consts::PI * 3600.0;
/// Arcseconds per radian.
const ARCSEC: f64 = 180.0 / core::f64::consts::PI * 3600.0;
/// Degrees per radian.
const DEG: f64 = 180.0 / core::f64::consts::PI;

/// One term of one FOG ([`super::FogCal`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub enum FogTerm {
    /// `bias_rad_s`.
    Bias,
    /// `scale_factor_error`.
    ScaleFactor,
    /// `t_ref_degc`.
    TRef,
    /// `thermal_t_rad_s[0]` (a1).
    ThermalT1,
    /// `thermal_t_rad_s[1]` (a2).
    ThermalT2,
    /// `thermal_t_rad_s[2]` (a3).
    ThermalT3,
    /// `thermal_g_rad_s_per_degc_s` (g).
    ThermalG,
    /// `thermal_tg_rad_s_per_degc2_s` (h).
    ThermalTg,
}

impl FogTerm {
    /// The terms in storage order.
    pub const ALL: [FogTerm; 8] = [
        FogTerm::Bias,
        FogTerm::ScaleFactor,
        FogTerm::TRef,
        FogTerm::ThermalT1,
        FogTerm::ThermalT2,
        FogTerm::ThermalT3,
        FogTerm::ThermalG,
        FogTerm::ThermalTg,
    ];

    /// Name in the TOML form, under `fog[i]`.
    pub fn name(self) -> &'static str {
        match self {
            FogTerm::Bias => "bias_rad_s",
            FogTerm::ScaleFactor => "scale_factor_error",
            FogTerm::TRef => "t_ref_degc",
            FogTerm::ThermalT1 => "thermal_t_rad_s[0]",
            FogTerm::ThermalT2 => "thermal_t_rad_s[1]",
            FogTerm::ThermalT3 => "thermal_t_rad_s[2]",
            FogTerm::ThermalG => "thermal_g_rad_s_per_degc_s",
            FogTerm::ThermalTg => "thermal_tg_rad_s_per_degc2_s",
        }
    }
}

/// One number of the calibration table.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub enum Field {
    /// A term of FOG i (0..3).
    Fog(u8, FogTerm),
    /// `misalignment.d12_rad`.
    D12,
    /// `misalignment.d13_rad`.
    D13,
    /// `misalignment.d21_rad`.
    D21,
    /// `misalignment.d23_rad`.
    D23,
    /// `misalignment.d31_rad`.
    D31,
    /// `misalignment.d32_rad`.
    D32,
    /// `misalignment.d42_rad`.
    D42,
    /// `misalignment.d43_rad`.
    D43,
    /// `gamma_rad`.
    Gamma,
    /// `st_mount_q[k]`, k = 0 (scalar) … 3.
    StMountQ(u8),
    /// `t_rate_filter_s`.
    TRateFilter,
    /// `observer.arw_deg_sqrt_h`.
    Arw,
    /// `observer.rrw_deg_h_sqrt_h`.
    Rrw,
    /// `observer.st_sigma_arcsec`.
    StSigma,
    /// `observer.st_period_s`.
    StPeriod,
    /// `observer.gains_override.k_b[k]`.
    GainKb(u8),
    /// `observer.gains_override.k_u_per_s[k]`.
    GainKu(u8),
    /// `observer.initial_drift_sigma_deg_h`.
    InitialDriftSigma,
    /// `observer.acquisition_s`.
    Acquisition,
    /// `observer.st_lfe_sigma_arcsec`.
    StLfeSigma,
    /// `observer.st_lfe_tau_s`.
    StLfeTau,
}

/// Units and plausible range of a field.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Spec {
    /// Unit of the table's value (in the field's name).
    pub unit: &'static str,
    /// Unit a person reads it in.
    pub eng_unit: &'static str,
    /// Engineering value per table unit (°/h per rad/s, ppm per 1, …).
    pub eng_per_unit: f64,
    /// Plausible range, engineering units, inclusive.
    pub eng_range: (f64, f64),
}

impl Spec {
    const fn new(unit: &'static str, eng_unit: &'static str, eng_per_unit: f64, lo: f64, hi: f64) -> Spec {
        Spec { unit, eng_unit, eng_per_unit, eng_range: (lo, hi) }
    }

    /// Whether `value` (table units) is finite and within the range.
    pub fn admits(&self, value: f64) -> bool {
        let e = value * self.eng_per_unit;
        e >= self.eng_range.0 && e <= self.eng_range.1
    }
}

/// Number of fields (the binary form's f64 count and the two LFE figures it stores in the
/// gain slots).
pub const N_FIELDS: usize = super::binary::N_F64 + 2;

const FOG_FIELDS: usize = 8 * N_FOG;

impl Field {
    /// The field at storage index `k` (0..[`N_FIELDS`]), `None` beyond.
    pub const fn from_index(k: usize) -> Option<Field> {
        if k < FOG_FIELDS {
            let term = match k % 8 {
                0 => FogTerm::Bias,
                1 => FogTerm::ScaleFactor,
                2 => FogTerm::TRef,
                3 => FogTerm::ThermalT1,
                4 => FogTerm::ThermalT2,
                5 => FogTerm::ThermalT3,
                6 => FogTerm::ThermalG,
                _ => FogTerm::ThermalTg,
            };
            return Some(Field::Fog((k / 8) as u8, term));
        }
        Some(match k - FOG_FIELDS {
            0 => Field::D12,
            1 => Field::D13,
            2 => Field::D21,
            3 => Field::D23,
            4 => Field::D31,
            5 => Field::D32,
            6 => Field::D42,
            7 => Field::D43,
            8 => Field::Gamma,
            j @ 9..=12 => Field::StMountQ((j - 9) as u8),
            13 => Field::TRateFilter,
            14 => Field::Arw,
            15 => Field::Rrw,
            16 => Field::StSigma,
            17 => Field::StPeriod,
            j @ 18..=20 => Field::GainKb((j - 18) as u8),
            j @ 21..=23 => Field::GainKu((j - 21) as u8),
            24 => Field::InitialDriftSigma,
            25 => Field::Acquisition,
            26 => Field::StLfeSigma,
            27 => Field::StLfeTau,
            _ => return None,
        })
    }

    /// Every field, in storage order.
    pub fn all() -> impl Iterator<Item = Field> {
        (0..N_FIELDS).filter_map(Field::from_index)
    }

    /// Whether it is part of the optional gain override (checked only when present).
    pub fn is_gain(self) -> bool {
        matches!(self, Field::GainKb(_) | Field::GainKu(_))
    }

    /// Units and plausible range (module doc: why).
    pub fn spec(self) -> Spec {
        match self {
            Field::Fog(_, t) => match t {
                FogTerm::Bias => Spec::new("rad/s", "°/h", DEG_H, -100.0, 100.0),
                FogTerm::ScaleFactor => Spec::new("", "ppm", 1e6, -10_000.0, 10_000.0),
                FogTerm::TRef => Spec::new("°C", "°C", 1.0, -60.0, 100.0),
                FogTerm::ThermalT1 => Spec::new("rad/s/°C", "°/h per °C", DEG_H, -2.0, 2.0),
                FogTerm::ThermalT2 => Spec::new("rad/s/°C²", "°/h per °C²", DEG_H, -0.04, 0.04),
                FogTerm::ThermalT3 => Spec::new("rad/s/°C³", "°/h per °C³", DEG_H, -8e-4, 8e-4),
                FogTerm::ThermalG => {
                    Spec::new("rad/s per °C/s", "°/h per °C/min", DEG_H / 60.0, -1000.0 / 60.0, 1000.0 / 60.0)
                }
                FogTerm::ThermalTg => {
                    Spec::new("rad/s per °C²/s", "°/h per °C·°C/min", DEG_H / 60.0, -20.0 / 60.0, 20.0 / 60.0)
                }
            },
            Field::D12 | Field::D13 | Field::D21 | Field::D23 | Field::D31 | Field::D32 | Field::D42 | Field::D43 => {
                Spec::new("rad", "″", ARCSEC, -3600.0, 3600.0)
            }
            Field::Gamma => Spec::new("rad", "°", DEG, GAMMA_NOMINAL_RAD * DEG - 1.0, GAMMA_NOMINAL_RAD * DEG + 1.0),
            Field::StMountQ(_) => Spec::new("", "", 1.0, -1.0, 1.0),
            Field::TRateFilter => Spec::new("s", "s", 1.0, 0.1, 3600.0),
            Field::Arw => Spec::new("°/√h", "°/√h", 1.0, 0.0005, 0.05),
            Field::Rrw => Spec::new("°/h/√h", "°/h/√h", 1.0, 0.0001, 0.1),
            Field::StSigma => Spec::new("″", "″", 1.0, 0.1, 100.0),
            Field::StPeriod => Spec::new("s", "s", 1.0, 0.005, 10.0),
            Field::GainKb(_) => Spec::new("", "", 1.0, 1e-9, 0.999),
            Field::GainKu(_) => Spec::new("1/s", "1/s", 1.0, 0.0, 0.999),
            Field::InitialDriftSigma => Spec::new("°/h", "°/h", 1.0, 0.001, 100.0),
            Field::Acquisition => Spec::new("s", "s", 1.0, 0.0, 7200.0),
            Field::StLfeSigma => Spec::new("″", "″", 1.0, 0.0, 100.0),
            Field::StLfeTau => Spec::new("s", "s", 1.0, 0.0, 86_400.0),
        }
    }

    /// Its value in `t` (a gain of an absent override reads 0, as the binary form stores it).
    pub fn get(self, t: &CalibrationTable) -> f64 {
        let m = &t.misalignment;
        let o = &t.observer;
        let gain = |k: u8, kb: bool| {
            o.gains_override
                .and_then(|g| {
                    if kb {
                        g.k_b.get(usize::from(k)).copied()
                    } else {
                        g.k_u_per_s.get(usize::from(k)).copied()
                    }
                })
                .unwrap_or(0.0)
        };
        match self {
            Field::Fog(i, term) => t.fog.get(usize::from(i)).map_or(f64::NAN, |f| match term {
                FogTerm::Bias => f.bias_rad_s,
                FogTerm::ScaleFactor => f.scale_factor_error,
                FogTerm::TRef => f.t_ref_degc,
                FogTerm::ThermalT1 => f.thermal_t_rad_s[0],
                FogTerm::ThermalT2 => f.thermal_t_rad_s[1],
                FogTerm::ThermalT3 => f.thermal_t_rad_s[2],
                FogTerm::ThermalG => f.thermal_g_rad_s_per_degc_s,
                FogTerm::ThermalTg => f.thermal_tg_rad_s_per_degc2_s,
            }),
            Field::D12 => m.d12_rad,
            Field::D13 => m.d13_rad,
            Field::D21 => m.d21_rad,
            Field::D23 => m.d23_rad,
            Field::D31 => m.d31_rad,
            Field::D32 => m.d32_rad,
            Field::D42 => m.d42_rad,
            Field::D43 => m.d43_rad,
            Field::Gamma => t.gamma_rad,
            Field::StMountQ(k) => t.st_mount_q.get(usize::from(k)).copied().unwrap_or(f64::NAN),
            Field::TRateFilter => t.t_rate_filter_s,
            Field::Arw => o.arw_deg_sqrt_h,
            Field::Rrw => o.rrw_deg_h_sqrt_h,
            Field::StSigma => o.st_sigma_arcsec,
            Field::StPeriod => o.st_period_s,
            Field::GainKb(k) => gain(k, true),
            Field::GainKu(k) => gain(k, false),
            Field::InitialDriftSigma => o.initial_drift_sigma_deg_h,
            Field::Acquisition => o.acquisition_s,
            Field::StLfeSigma => o.st_lfe_sigma_arcsec,
            Field::StLfeTau => o.st_lfe_tau_s,
        }
    }

    /// Sets its value in `t` (a gain only when `t` has an override).
    pub fn set(self, t: &mut CalibrationTable, v: f64) {
        let slot: Option<&mut f64> = match self {
            Field::Fog(i, term) => t.fog.get_mut(usize::from(i)).map(|f| match term {
                FogTerm::Bias => &mut f.bias_rad_s,
                FogTerm::ScaleFactor => &mut f.scale_factor_error,
                FogTerm::TRef => &mut f.t_ref_degc,
                FogTerm::ThermalT1 => &mut f.thermal_t_rad_s[0],
                FogTerm::ThermalT2 => &mut f.thermal_t_rad_s[1],
                FogTerm::ThermalT3 => &mut f.thermal_t_rad_s[2],
                FogTerm::ThermalG => &mut f.thermal_g_rad_s_per_degc_s,
                FogTerm::ThermalTg => &mut f.thermal_tg_rad_s_per_degc2_s,
            }),
            Field::D12 => Some(&mut t.misalignment.d12_rad),
            Field::D13 => Some(&mut t.misalignment.d13_rad),
            Field::D21 => Some(&mut t.misalignment.d21_rad),
            Field::D23 => Some(&mut t.misalignment.d23_rad),
            Field::D31 => Some(&mut t.misalignment.d31_rad),
            Field::D32 => Some(&mut t.misalignment.d32_rad),
            Field::D42 => Some(&mut t.misalignment.d42_rad),
            Field::D43 => Some(&mut t.misalignment.d43_rad),
            Field::Gamma => Some(&mut t.gamma_rad),
            Field::StMountQ(k) => t.st_mount_q.get_mut(usize::from(k)),
            Field::TRateFilter => Some(&mut t.t_rate_filter_s),
            Field::Arw => Some(&mut t.observer.arw_deg_sqrt_h),
            Field::Rrw => Some(&mut t.observer.rrw_deg_h_sqrt_h),
            Field::StSigma => Some(&mut t.observer.st_sigma_arcsec),
            Field::StPeriod => Some(&mut t.observer.st_period_s),
            Field::GainKb(k) => t.observer.gains_override.as_mut().and_then(|g| g.k_b.get_mut(usize::from(k))),
            Field::GainKu(k) => t.observer.gains_override.as_mut().and_then(|g| g.k_u_per_s.get_mut(usize::from(k))),
            Field::InitialDriftSigma => Some(&mut t.observer.initial_drift_sigma_deg_h),
            Field::Acquisition => Some(&mut t.observer.acquisition_s),
            Field::StLfeSigma => Some(&mut t.observer.st_lfe_sigma_arcsec),
            Field::StLfeTau => Some(&mut t.observer.st_lfe_tau_s),
        };
        if let Some(s) = slot {
            *s = v;
        }
    }
}

impl fmt::Display for Field {
    /// The field's path in the TOML form, under `[table]` (`fog[0].bias_rad_s`,
    /// `observer.rrw_deg_h_sqrt_h`).
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let plain = match self {
            Field::Fog(i, t) => return write!(f, "fog[{i}].{}", t.name()),
            Field::StMountQ(k) => return write!(f, "st_mount_q[{k}]"),
            Field::GainKb(k) => return write!(f, "observer.gains_override.k_b[{k}]"),
            Field::GainKu(k) => return write!(f, "observer.gains_override.k_u_per_s[{k}]"),
            Field::D12 => "misalignment.d12_rad",
            Field::D13 => "misalignment.d13_rad",
            Field::D21 => "misalignment.d21_rad",
            Field::D23 => "misalignment.d23_rad",
            Field::D31 => "misalignment.d31_rad",
            Field::D32 => "misalignment.d32_rad",
            Field::D42 => "misalignment.d42_rad",
            Field::D43 => "misalignment.d43_rad",
            Field::Gamma => "gamma_rad",
            Field::TRateFilter => "t_rate_filter_s",
            Field::Arw => "observer.arw_deg_sqrt_h",
            Field::Rrw => "observer.rrw_deg_h_sqrt_h",
            Field::StSigma => "observer.st_sigma_arcsec",
            Field::StPeriod => "observer.st_period_s",
            Field::InitialDriftSigma => "observer.initial_drift_sigma_deg_h",
            Field::Acquisition => "observer.acquisition_s",
            Field::StLfeSigma => "observer.st_lfe_sigma_arcsec",
            Field::StLfeTau => "observer.st_lfe_tau_s",
        };
        f.write_str(plain)
    }
}

/// A field refused by [`super::CalibrationTable::validate`]: which, and its value (as bits,
/// so that the error compares exactly, NaN included).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FieldError {
    /// The field.
    pub field: Field,
    /// `f64::to_bits` of its value.
    pub value_bits: u64,
}

impl FieldError {
    /// The refusal of `value` in `field`.
    pub fn new(field: Field, value: f64) -> Self {
        FieldError { field, value_bits: value.to_bits() }
    }

    /// The refused value, table units.
    pub fn value(&self) -> f64 {
        f64::from_bits(self.value_bits)
    }
}

impl fmt::Display for FieldError {
    /// `field observer.rrw_deg_h_sqrt_h = 53954 °/h/√h is outside its plausible range
    /// 0.0001 … 0.1 °/h/√h (docs/CALIBRATION.md)`; a value in other table units is also
    /// given in them.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let s = self.field.spec();
        let v = self.value();
        let what =
            if v.is_finite() { "is outside its plausible range" } else { "is not a finite number; plausible range" };
        write!(f, "field {} = {} {}", self.field, nine_digits(v * s.eng_per_unit), s.eng_unit)?;
        if s.unit != s.eng_unit {
            write!(f, " ({v:e}{}{})", if s.unit.is_empty() { "" } else { " " }, s.unit)?;
        }
        write!(f, " {what} {} … {} {} (docs/CALIBRATION.md)", s.eng_range.0, s.eng_range.1, s.eng_unit)
    }
}

/// `v` rounded to nine significant digits (so that 0.05 × 10⁶ prints as 50000, not
/// 50000.00000000001).
fn nine_digits(v: f64) -> f64 {
    if v == 0.0 || !v.is_finite() {
        return v;
    }
    let scale = libm::pow(10.0, 8.0 - libm::floor(libm::log10(libm::fabs(v))));
    libm::round(v * scale) / scale
}

#[cfg(target_os = "none")]
impl defmt::Format for FieldError {
    fn format(&self, f: defmt::Formatter) {
        let s = self.field.spec();
        defmt::write!(
            f,
            "field {} = {=f64} {=str} outside {=f64}..{=f64}",
            self.field,
            self.value() * s.eng_per_unit,
            s.eng_unit,
            s.eng_range.0,
            s.eng_range.1
        );
    }
}
