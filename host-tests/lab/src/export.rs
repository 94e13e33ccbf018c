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
//!
//! **Only what the session identifies.** A field is exported only when its term is in the
//! model and the fit identified its regressor (the model's `fit.not_identified`); every
//! other field keeps the base table's value (`ssis_common::update::apply` copies the
//! exported fields onto the base bit for bit). T_ref goes with the terms in ΔT (a1..a3, h):
//! it is exported when one of them is. A thermal-chamber session thus sets biases and
//! thermal terms and leaves the scale factors, misalignment, geometry, mount and observer
//! figures of the base as they were.

use ssis::calib::{CalibrationTable, Field, FogTerm, N_FOG};

use super::model::{axis_with, misalignment_partials, partials_at, regressor_id, Catalog, Kind, Model};
use super::session::nominal_axes;
use super::{LabError, LabResult, ModelErrorKind};

/// A table made from a model, and what it leaves out.
#[derive(Debug, Clone)]
pub struct Export {
    /// The base with the model's values in the fields of [`Export::set`].
    pub table: CalibrationTable,
    /// The fields the model's session identified, in storage order: only these change.
    pub set: Vec<Field>,
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

/// The misalignment field of angle `k` (0 or 1, the order of
/// [`super::model::MISALIGNMENT_ANGLES`]) of FOG `fog`.
pub fn angle_field(fog: usize, k: usize) -> Field {
    const ANGLES: [[Field; 2]; N_FOG] =
        [[Field::D12, Field::D13], [Field::D21, Field::D23], [Field::D31, Field::D32], [Field::D42, Field::D43]];
    ANGLES[fog.min(N_FOG - 1)][k.min(1)]
}

/// Builds the table from `model` (fitted) on top of `base`: the fields the model's session
/// identified (module doc) take the model's values, every other field keeps the base's.
pub fn to_table(model: &Model, base: &CalibrationTable) -> LabResult<Export> {
    let kinds = model.kinds();
    let n_fog = model.terms.iter().map(|t| t.coef.len()).max().unwrap_or(0);
    if n_fog > N_FOG {
        return Err(LabError::model(
            ModelErrorKind::Value,
            format!("the table holds {N_FOG} FOGs, the model has {n_fog}"),
        ));
    }
    let not_identified = model.fit.as_ref().map_or(&[][..], |f| &f.not_identified[..]);
    let position = |c: Catalog| kinds.iter().position(|k| *k == Kind::Catalog(c));
    let coef = |c: Catalog, fog: usize, m: usize| -> f64 {
        position(c).and_then(|t| model.terms[t].coef.get(fog)).and_then(|v| v.get(m)).copied().unwrap_or(0.0)
    };
    let identified = |c: Catalog, fog: usize, m: usize| -> bool {
        position(c).is_some_and(|t| model.terms[t].coef.get(fog).is_some_and(|v| m < v.len()))
            && !not_identified.contains(&regressor_id(fog, &Kind::Catalog(c), m))
    };
    let mut table = *base;
    let mut set = Vec::new();
    let mut put = |table: &mut CalibrationTable, f: Field, v: f64| {
        f.set(table, v);
        set.push(f);
    };
    for fog in 0..n_fog {
        let i = fog as u8;
        let (k, d) = exact_axis(
            fog,
            coef(Catalog::ScaleFactor, fog, 0),
            [coef(Catalog::Misalignment, fog, 0), coef(Catalog::Misalignment, fog, 1)],
        );
        if identified(Catalog::Bias, fog, 0) {
            put(&mut table, Field::Fog(i, FogTerm::Bias), coef(Catalog::Bias, fog, 0));
        }
        if identified(Catalog::ScaleFactor, fog, 0) {
            put(&mut table, Field::Fog(i, FogTerm::ScaleFactor), k);
        }
        for (m, angle) in d.iter().enumerate() {
            if identified(Catalog::Misalignment, fog, m) {
                put(&mut table, angle_field(fog, m), *angle);
            }
        }
        let thermal = [
            (Catalog::ThermalT1, FogTerm::ThermalT1),
            (Catalog::ThermalT2, FogTerm::ThermalT2),
            (Catalog::ThermalT3, FogTerm::ThermalT3),
            (Catalog::TempRate, FogTerm::ThermalG),
            (Catalog::TTimesG, FogTerm::ThermalTg),
        ];
        let mut in_dt = false;
        for (c, term) in thermal {
            if identified(c, fog, 0) {
                put(&mut table, Field::Fog(i, term), coef(c, fog, 0));
                in_dt |= c != Catalog::TempRate;
            }
        }
        if in_dt {
            put(&mut table, Field::Fog(i, FogTerm::TRef), model.t_ref_degc);
        }
    }
    set.sort_by_key(|f| Field::all().position(|g| g == *f));
    table
        .validate()
        .map_err(|e| LabError::model(ModelErrorKind::Value, format!("the exported table is refused: {e}")))?;
    let mut applied = Vec::new();
    let mut not_applied = Vec::new();
    for k in &kinds {
        if k.onboard() {
            applied.push(k.label());
        } else {
            not_applied.push((k.label(), not_onboard_reason(k).to_string()));
        }
    }
    Ok(Export { table, set, applied, not_applied })
}

/// The table field regressor `m` of `kind` sets for FOG `fog` (close to first order: the
/// scale factor and the angles are set through [`exact_axis`]), if any.
pub fn table_field(kind: &Kind, fog: usize, m: usize) -> Option<Field> {
    let i = fog.min(N_FOG - 1) as u8;
    let Kind::Catalog(c) = kind else { return None };
    Some(match c {
        Catalog::Bias => Field::Fog(i, FogTerm::Bias),
        Catalog::ScaleFactor => Field::Fog(i, FogTerm::ScaleFactor),
        Catalog::Misalignment => angle_field(fog, m),
        Catalog::ThermalT1 => Field::Fog(i, FogTerm::ThermalT1),
        Catalog::ThermalT2 => Field::Fog(i, FogTerm::ThermalT2),
        Catalog::ThermalT3 => Field::Fog(i, FogTerm::ThermalT3),
        Catalog::TempRate => Field::Fog(i, FogTerm::ThermalG),
        Catalog::TTimesG => Field::Fog(i, FogTerm::ThermalTg),
        _ => return None,
    })
}

/// Every fitted coefficient of `model` outside its table field's plausible range
/// (`docs/CALIBRATION.md`), as a sentence naming the FOG, the term, the value and the range
/// in engineering units.
pub fn implausible(model: &Model) -> Vec<String> {
    let mut out = Vec::new();
    for (t, kind) in model.terms.iter().zip(model.kinds()) {
        for (fog, c) in t.coef.iter().enumerate() {
            for (m, v) in c.iter().enumerate() {
                let Some(f) = table_field(&kind, fog, m) else { continue };
                let spec = f.spec();
                if !spec.admits(*v) {
                    out.push(format!(
                        "FOG{fog} {}: {:.6} {} is outside the table's plausible range {} … {} {}",
                        regressor_id(fog, &kind, m),
                        v * spec.eng_per_unit,
                        spec.eng_unit,
                        spec.eng_range.0,
                        spec.eng_range.1,
                        spec.eng_unit
                    ));
                }
            }
        }
    }
    out
}
