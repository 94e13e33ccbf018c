//! The calibration table the firmware loads, from a fitted model.
//!
//! Onboard (`docs/CALIBRATION.md`, `src/compensation.rs`): per FOG the bias b, the scale
//! factor k, T_ref, a1..a3 of ΔT, ΔT², ΔT³, g of G, h of ΔT·G, and the eight misalignment
//! angles. All in the table's units (rad/s, rad). The firmware computes G itself with its
//! α-β tracker (time constant `t_rate_filter_s`); the lab's G is a local line fit
//! ([`super::stream::temperature_rate`]): both estimate the same dT/dt.
//!
//! The lab's scale factor and misalignment are linear coefficients: the fitted axis is
//! v = (1 + k′) s⁰ + δ′_a ∂s/∂δ_a + δ′_b ∂s/∂δ_b. The export finds the exact angles whose
//! axis [`ssis::calib::Misalignment::axes`] has the direction of v (Gauss–Newton, from δ′),
//! and 1 + k = |v|, so the flight's (1 + k) s(δ) equals the lab's axis to rounding.
//!
//! Not onboard, reported as such: `sf_asymmetry`, `sf_nonlinearity`, `magnetic`, `aging`,
//! sinusoids and expressions.

use ssis::calib::{CalibrationTable, FogCal, Misalignment, N_FOG};

use super::model::{axis_with, misalignment_partials, partials_at, set_angle, Catalog, Kind, Model};
use super::session::nominal_axes;
use super::{LabError, LabResult};

/// A table made from a model, and what it leaves out.
#[derive(Debug, Clone)]
pub struct Export {
    /// The table.
    pub table: CalibrationTable,
    /// Terms written to the table.
    pub applied: Vec<String>,
    /// Terms the firmware cannot apply, with the reason.
    pub not_applied: Vec<(String, String)>,
}

/// Why the firmware cannot apply a term.
pub fn not_onboard_reason(kind: &Kind) -> &'static str {
    match kind {
        Kind::Catalog(Catalog::SfAsymmetry) => "the onboard compensation has one scale factor for both signs of rate",
        Kind::Catalog(Catalog::SfNonlinearity) => "the onboard compensation is linear in rate",
        Kind::Catalog(Catalog::Magnetic) => "the unit has no magnetometer; screen the FOGs or budget the error",
        Kind::Catalog(Catalog::Aging) => "the onboard table has no time term; the observer (eq. 6) tracks slow drift",
        Kind::Sinusoid(_) => "a test-rig periodicity, no onboard term",
        Kind::Expr(_) => "user expressions are lab-only",
        Kind::Catalog(_) => "",
    }
}

/// Exact angles and scale factor of FOG `fog` from the lab's linear k′ and δ′.
pub fn exact_axis(fog: usize, k_lin: f64, d_lin: [f64; 2]) -> (f64, [f64; 2]) {
    let [pa, pb] = misalignment_partials(fog);
    let v = nominal_axes()[fog] * (1.0 + k_lin) + pa * d_lin[0] + pb * d_lin[1];
    let (norm, dir) = (v.norm(), v.normalize());
    let mut d = d_lin;
    for _ in 0..8 {
        let f = axis_with(fog, d) - dir;
        let [ja, jb] = partials_at(fog, d);
        let j = nalgebra::Matrix3x2::from_columns(&[ja, jb]);
        let Some(step) = (j.transpose() * j).try_inverse().map(|m| m * j.transpose() * f) else { break };
        d = [d[0] - step[0], d[1] - step[1]];
        if step.norm() < 1e-15 {
            break;
        }
    }
    (norm - 1.0, d)
}

/// Builds the table from `model` (fitted), on top of `base` for everything the model does
/// not describe (geometry γ, star-tracker mount, observer, G filter).
pub fn to_table(model: &Model, base: &CalibrationTable) -> LabResult<Export> {
    let kinds = model.kinds();
    let n_fog = model.terms.iter().map(|t| t.coef.len()).max().unwrap_or(0);
    if n_fog > N_FOG {
        return Err(LabError::Model(format!("the table holds {N_FOG} FOGs, the model has {n_fog}")));
    }
    let coef = |c: Catalog, fog: usize, m: usize| -> f64 {
        kinds
            .iter()
            .position(|k| *k == Kind::Catalog(c))
            .and_then(|t| model.terms[t].coef.get(fog))
            .and_then(|v| v.get(m))
            .copied()
            .unwrap_or(0.0)
    };
    let mut table = *base;
    table.revision = model.version;
    let mut mis = Misalignment::default();
    for fog in 0..n_fog {
        let (k, d) = exact_axis(
            fog,
            coef(Catalog::ScaleFactor, fog, 0),
            [coef(Catalog::Misalignment, fog, 0), coef(Catalog::Misalignment, fog, 1)],
        );
        set_angle(&mut mis, fog, 0, d[0]);
        set_angle(&mut mis, fog, 1, d[1]);
        table.fog[fog] = FogCal {
            bias_rad_s: coef(Catalog::Bias, fog, 0),
            scale_factor_error: k,
            t_ref_degc: model.t_ref_degc,
            thermal_t_rad_s: [
                coef(Catalog::ThermalT1, fog, 0),
                coef(Catalog::ThermalT2, fog, 0),
                coef(Catalog::ThermalT3, fog, 0),
            ],
            thermal_g_rad_s_per_degc_s: coef(Catalog::TempRate, fog, 0),
            thermal_tg_rad_s_per_degc2_s: coef(Catalog::TTimesG, fog, 0),
        };
    }
    table.misalignment = mis;
    table.validate().map_err(|e| LabError::Model(format!("the exported table is refused: {e}")))?;
    let mut applied = Vec::new();
    let mut not_applied = Vec::new();
    for k in &kinds {
        if k.onboard() {
            applied.push(k.label());
        } else {
            not_applied.push((k.label(), not_onboard_reason(k).to_string()));
        }
    }
    Ok(Export { table, applied, not_applied })
}
