//! The error model as data: a versioned TOML file with a list of effect terms and their
//! coefficients per FOG.
//!
//! Every term is linear in its coefficients: term j of FOG i contributes Σ_m c_ijm x_ijm(t)
//! to the FOG's error y_i = ω_i,raw − s_i⁰·ω_ref (raw output minus the reference rate along
//! the nominal sensitive axis s_i⁰). The regressors x (catalog, [`Catalog`]):
//!
//! | term | regressors | coefficient unit |
//! |---|---|---|
//! | `bias` | 1 | rad/s |
//! | `scale_factor` | r = s_i⁰·ω_ref | — (k) |
//! | `sf_asymmetry` | \|r\| (k₊ = k + c, k₋ = k − c) | — |
//! | `sf_nonlinearity` | r² | 1/(rad/s) |
//! | `misalignment` | ∂s_i/∂δ_a · ω_ref for FOG i's two angles (δ12, δ13 / δ21, δ23 / δ31, δ32 / δ42, δ43) | rad |
//! | `thermal_t1/t2/t3` | ΔT, ΔT², ΔT³, ΔT = T_i − T_ref | rad/s per °C^k |
//! | `temp_rate` | G = dT_i/dt (smoothed, [`super::stream::temperature_rate`]) | rad/s per °C/s |
//! | `t_times_g` | ΔT·G | rad/s per °C²/s |
//! | `magnetic` | B·u_i, B·v_i (field across the sensitive axis) | rad/s per nT |
//! | `aging` | (t − t₀)/3600 | rad/s per h |
//! | `sinusoid` (`freq_hz`) | sin 2πft, cos 2πft | rad/s |
//! | `expr` (`expr`) | the expression's value | rad/s per unit |
//!
//! The magnetic term follows the paper's Faraday mechanism (eqs. 1–3): the error is largest
//! for a field in the plane of the fiber loop (orthogonal to the sensitive axis) and its
//! sign follows the field; a field along the axis does nothing. u_i, v_i span that plane:
//! FOG0 (Y, Z), FOG1 (Z, X), FOG2 (X, Y), FOG3 u = (1, −1, 0)/√2, v = s_4 × u.

use serde::{Deserialize, Serialize};
use ssis::calib::{Misalignment, GAMMA_NOMINAL_RAD};

use super::session::nominal_axes;
use super::{LabError, LabResult, ModelErrorKind};

/// Format tag of a model file.
pub const MODEL_FORMAT: &str = "ssis-error-model/1";

fn default_t_ref() -> f64 {
    25.0
}

fn default_g_window() -> f64 {
    0.0
}

/// A model file (`format = "ssis-error-model/1"`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Model {
    /// Always [`MODEL_FORMAT`].
    pub format: String,
    /// Version of this model; `add` writes version + 1 to a new file.
    pub version: u32,
    /// Free text: what changed in this version.
    #[serde(default)]
    pub note: String,
    /// Reference temperature of the thermal polynomial, °C.
    #[serde(default = "default_t_ref")]
    pub t_ref_degc: f64,
    /// Width of the window of the temperature-rate estimate G, s ([`super::stream::temperature_rate`]);
    /// 0 (the default) means max(2 × the median sample interval, 60 s).
    #[serde(default = "default_g_window")]
    pub g_window_s: f64,
    /// The terms, in order (earlier terms keep a coefficient when regressors are collinear).
    #[serde(default, rename = "term")]
    pub terms: Vec<TermSpec>,
    /// Where the coefficients came from.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub fit: Option<FitRecord>,
}

/// One term in the file.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TermSpec {
    /// Catalog name, `sinusoid` or `expr`.
    pub term: String,
    /// The expression of an `expr` term, over session columns (see [`Kind::Expr`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub expr: Option<String>,
    /// Frequency of a `sinusoid` term, Hz.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub freq_hz: Option<f64>,
    /// Coefficients, `coef[fog][regressor]`, in the units of the catalog table.
    #[serde(default)]
    pub coef: Vec<Vec<f64>>,
}

/// Provenance of a fitted model.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FitRecord {
    /// Session file the coefficients were fitted on (all rows).
    pub session: String,
    /// Number of samples.
    pub rows: usize,
    /// Held-out residual RMS per FOG, °/h (fit on the training blocks, evaluated on the others).
    pub held_out_rms_deg_h: Vec<f64>,
    /// Regressors that the session could not identify (coefficient left at zero).
    #[serde(default)]
    pub not_identified: Vec<String>,
}

/// The catalog of physical effects.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Catalog {
    /// Zero bias.
    Bias,
    /// Scale-factor error k.
    ScaleFactor,
    /// Scale-factor asymmetry (different k for + and − rate).
    SfAsymmetry,
    /// Scale-factor nonlinearity (rate²).
    SfNonlinearity,
    /// Sensitive-axis misalignment (cross-axis rates).
    Misalignment,
    /// ΔT.
    ThermalT1,
    /// ΔT².
    ThermalT2,
    /// ΔT³.
    ThermalT3,
    /// G = dT/dt, the paper's dominant thermal factor.
    TempRate,
    /// ΔT·G.
    TTimesG,
    /// Magnetic field across the sensitive axis (Faraday effect, eqs. 1–3).
    Magnetic,
    /// Linear drift in time.
    Aging,
}

impl Catalog {
    /// Every catalog term.
    pub const ALL: [Catalog; 12] = [
        Catalog::Bias,
        Catalog::ScaleFactor,
        Catalog::SfAsymmetry,
        Catalog::SfNonlinearity,
        Catalog::Misalignment,
        Catalog::ThermalT1,
        Catalog::ThermalT2,
        Catalog::ThermalT3,
        Catalog::TempRate,
        Catalog::TTimesG,
        Catalog::Magnetic,
        Catalog::Aging,
    ];

    /// Name in model files and on the command line.
    pub fn name(self) -> &'static str {
        match self {
            Catalog::Bias => "bias",
            Catalog::ScaleFactor => "scale_factor",
            Catalog::SfAsymmetry => "sf_asymmetry",
            Catalog::SfNonlinearity => "sf_nonlinearity",
            Catalog::Misalignment => "misalignment",
            Catalog::ThermalT1 => "thermal_t1",
            Catalog::ThermalT2 => "thermal_t2",
            Catalog::ThermalT3 => "thermal_t3",
            Catalog::TempRate => "temp_rate",
            Catalog::TTimesG => "t_times_g",
            Catalog::Magnetic => "magnetic",
            Catalog::Aging => "aging",
        }
    }

    /// The term of a name.
    pub fn from_name(name: &str) -> Option<Catalog> {
        Catalog::ALL.into_iter().find(|c| c.name() == name)
    }

    /// Whether the firmware applies it (`src/compensation.rs`, the table's misalignment).
    pub fn onboard(self) -> bool {
        !matches!(self, Catalog::SfAsymmetry | Catalog::SfNonlinearity | Catalog::Magnetic | Catalog::Aging)
    }
}

/// A term's kind, parsed from its [`TermSpec`].
#[derive(Debug, Clone, PartialEq)]
pub enum Kind {
    /// A catalog effect.
    Catalog(Catalog),
    /// sin and cos of 2π f t (a spectral line found in the residual).
    Sinusoid(f64),
    /// A user expression over session columns (exmex syntax: `+ - * / ^`, `sin`, `cos`,
    /// `abs`, `sqrt`, `exp`, `ln`, `PI`, ...). Variables: any session column by its header
    /// name, and per FOG `rate_rad_s` (s_i⁰·ω_ref), `t_degc`, `dt_degc`, `g_degc_s`, `fog`.
    Expr(String),
}

impl Kind {
    /// Parses a command-line term: a catalog name, `sinusoid:F_HZ`, or an expression.
    pub fn parse_arg(arg: &str) -> LabResult<Kind> {
        if let Some(c) = Catalog::from_name(arg) {
            return Ok(Kind::Catalog(c));
        }
        if let Some(f) = arg.strip_prefix("sinusoid:") {
            let f: f64 = f
                .trim()
                .parse()
                .map_err(|_| LabError::model(ModelErrorKind::Term, format!("`{arg}`: frequency is not a number")))?;
            return Ok(Kind::Sinusoid(f));
        }
        exmex::parse::<f64>(arg).map_err(|e| {
            LabError::model(
                ModelErrorKind::Term,
                format!("`{arg}` is neither a catalog term ({}) nor an expression: {e}", catalog_names()),
            )
        })?;
        Ok(Kind::Expr(arg.to_string()))
    }

    /// The kind of a file term.
    pub fn of_spec(t: &TermSpec) -> LabResult<Kind> {
        match t.term.as_str() {
            "expr" => {
                let e = t
                    .expr
                    .clone()
                    .ok_or_else(|| LabError::model(ModelErrorKind::Term, "term `expr` needs `expr = \"...\"`"))?;
                exmex::parse::<f64>(&e)
                    .map_err(|err| LabError::model(ModelErrorKind::Expression, format!("expression `{e}`: {err}")))?;
                Ok(Kind::Expr(e))
            }
            "sinusoid" => t
                .freq_hz
                .map(Kind::Sinusoid)
                .ok_or_else(|| LabError::model(ModelErrorKind::Term, "term `sinusoid` needs `freq_hz`")),
            name => Catalog::from_name(name).map(Kind::Catalog).ok_or_else(|| {
                LabError::model(
                    ModelErrorKind::Term,
                    format!("unknown term `{name}`: the catalog is {}, or `sinusoid`, `expr`", catalog_names()),
                )
            }),
        }
    }

    /// The spec (no coefficients) of this kind.
    pub fn spec(&self) -> TermSpec {
        let (term, expr, freq_hz) = match self {
            Kind::Catalog(c) => (c.name().to_string(), None, None),
            Kind::Sinusoid(f) => ("sinusoid".to_string(), None, Some(*f)),
            Kind::Expr(e) => ("expr".to_string(), Some(e.clone()), None),
        };
        TermSpec { term, expr, freq_hz, coef: Vec::new() }
    }

    /// Short label for tables.
    pub fn label(&self) -> String {
        match self {
            Kind::Catalog(c) => c.name().to_string(),
            Kind::Sinusoid(f) => format!("sinusoid:{f:.6e}"),
            Kind::Expr(e) => format!("expr:{e}"),
        }
    }

    /// Whether the firmware applies it.
    pub fn onboard(&self) -> bool {
        matches!(self, Kind::Catalog(c) if c.onboard())
    }

    /// Names of the regressors of FOG `fog`, with the coefficient unit.
    pub fn regressor_labels(&self, fog: usize) -> Vec<(String, &'static str)> {
        let one = |n: &str, u: &'static str| vec![(n.to_string(), u)];
        match self {
            Kind::Catalog(c) => match c {
                Catalog::Bias => one("b", "rad/s"),
                Catalog::ScaleFactor => one("k", "-"),
                Catalog::SfAsymmetry => one("k_asym", "-"),
                Catalog::SfNonlinearity => one("k2", "1/(rad/s)"),
                Catalog::Misalignment => {
                    let [a, b] = MISALIGNMENT_ANGLES.get(fog).copied().unwrap_or(["?", "?"]);
                    vec![(a.to_string(), "rad"), (b.to_string(), "rad")]
                }
                Catalog::ThermalT1 => one("a1", "rad/s/degC"),
                Catalog::ThermalT2 => one("a2", "rad/s/degC^2"),
                Catalog::ThermalT3 => one("a3", "rad/s/degC^3"),
                Catalog::TempRate => one("g", "rad/s per degC/s"),
                Catalog::TTimesG => one("h", "rad/s per degC^2/s"),
                Catalog::Magnetic => vec![("m_u".into(), "rad/s/nT"), ("m_v".into(), "rad/s/nT")],
                Catalog::Aging => one("drift", "rad/s/h"),
            },
            Kind::Sinusoid(_) => vec![("sin".into(), "rad/s"), ("cos".into(), "rad/s")],
            Kind::Expr(_) => one("c", "rad/s per unit"),
        }
    }
}

impl Kind {
    /// The engineering unit of each regressor's coefficient (the same as `ssis-cal` and the
    /// table's TOML comments) and the factor from the SI coefficient to it: °/h, ppm, ″,
    /// °/h per °C (°C², °C³), °/h per °C/min, °/h per µT, °/h per hour.
    pub fn eng_units(&self, fog: usize) -> Vec<(&'static str, f64)> {
        use ssis_common::{ARCSEC_PER_RAD, DEG_H_PER_RAD_S as DH};
        let n = self.regressor_labels(fog).len();
        let u = match self {
            Kind::Catalog(c) => match c {
                Catalog::Bias => ("°/h", DH),
                Catalog::ScaleFactor | Catalog::SfAsymmetry => ("ppm", 1e6),
                Catalog::SfNonlinearity => ("ppm per °/s", 1e6 * std::f64::consts::PI / 180.0),
                Catalog::Misalignment => ("″", ARCSEC_PER_RAD),
                Catalog::ThermalT1 => ("°/h per °C", DH),
                Catalog::ThermalT2 => ("°/h per °C²", DH),
                Catalog::ThermalT3 => ("°/h per °C³", DH),
                Catalog::TempRate => ("°/h per °C/min", DH / 60.0),
                Catalog::TTimesG => ("°/h per °C·°C/min", DH / 60.0),
                Catalog::Magnetic => ("°/h per µT", DH * 1000.0),
                Catalog::Aging => ("°/h per hour", DH),
            },
            Kind::Sinusoid(_) => ("°/h", DH),
            Kind::Expr(_) => ("°/h per unit", DH),
        };
        vec![u; n]
    }
}

/// How a fit names regressor `m` of `kind` for FOG `fog` among those it could not identify
/// (`FOG0 scale_factor.k`; the model's `fit.not_identified`).
pub fn regressor_id(fog: usize, kind: &Kind, m: usize) -> String {
    let lab = kind.regressor_labels(fog);
    format!("FOG{fog} {}.{}", kind.label(), lab.get(m).map_or("?", |l| l.0.as_str()))
}

/// The two misalignment angles of each FOG, in the order of its regressors.
pub const MISALIGNMENT_ANGLES: [[&str; 2]; 4] = [["d12", "d13"], ["d21", "d23"], ["d31", "d32"], ["d42", "d43"]];

/// The per-FOG variables an expression may use besides the session's columns
/// (`Kind::Expr`).
pub const FOG_VARIABLES: [&str; 5] = ["rate_rad_s", "t_degc", "dt_degc", "g_degc_s", "fog"];

pub use ssis_common::names::did_you_mean;

/// The catalog names, comma separated.
pub fn catalog_names() -> String {
    Catalog::ALL.iter().map(|c| c.name()).collect::<Vec<_>>().join(", ")
}

impl Model {
    /// A new model (version 1) with the given terms and no coefficients.
    pub fn new(kinds: &[Kind]) -> Model {
        Model {
            format: MODEL_FORMAT.into(),
            version: 1,
            note: String::new(),
            t_ref_degc: default_t_ref(),
            g_window_s: default_g_window(),
            terms: kinds.iter().map(Kind::spec).collect(),
            fit: None,
        }
    }

    /// Parses and checks a model file's text; `origin` names it in errors.
    pub fn parse(text: &str, origin: &str) -> LabResult<Model> {
        let m: Model =
            toml::from_str(text).map_err(|e| LabError::model(ModelErrorKind::Syntax, format!("{origin}: {e}")))?;
        if m.format != MODEL_FORMAT {
            return Err(LabError::model(
                ModelErrorKind::Syntax,
                format!("{origin}: field `format`: expected \"{MODEL_FORMAT}\", found \"{}\"", m.format),
            ));
        }
        let mut seen = Vec::new();
        for t in &m.terms {
            let k = Kind::of_spec(t).map_err(|e| within(origin, e))?;
            if seen.contains(&k) {
                return Err(LabError::model(
                    ModelErrorKind::Term,
                    format!("{origin}: term `{}` is listed twice", k.label()),
                ));
            }
            seen.push(k);
        }
        if !m.g_window_s.is_finite() || m.g_window_s < 0.0 {
            return Err(LabError::model(
                ModelErrorKind::Value,
                format!(
                    "{origin}: field `g_window_s` = {}: must be 0 (automatic) or a positive number of seconds",
                    m.g_window_s
                ),
            ));
        }
        m.check_numbers().map_err(|e| LabError::model(ModelErrorKind::Value, format!("{origin}: {e}")))?;
        Ok(m)
    }

    /// The physics a TOML parser cannot check: a supported version, a finite reference
    /// temperature within the session range, finite coefficients, one set per FOG (as many
    /// as the fit's FOGs, or as the other fitted terms), each with its term's number of
    /// regressors. The message names the field.
    fn check_numbers(&self) -> Result<(), String> {
        if self.version == 0 {
            return Err("field `version` = 0: model versions start at 1".into());
        }
        let (lo, hi) = ssis_session::TEMPERATURE_RANGE_DEGC;
        if !(lo..=hi).contains(&self.t_ref_degc) {
            return Err(format!(
                "field `t_ref_degc` = {}: must be a temperature within {lo} … {hi} °C",
                self.t_ref_degc
            ));
        }
        let fit_fogs = self.fit.as_ref().map(|f| f.held_out_rms_deg_h.len()).filter(|n| *n > 0);
        let n_fog = fit_fogs.or_else(|| self.terms.iter().map(|t| t.coef.len()).max()).unwrap_or(0);
        let by = if fit_fogs.is_some() { "its fit (`fit.held_out_rms_deg_h`)" } else { "another term" };
        for (j, t) in self.terms.iter().enumerate() {
            let kind = Kind::of_spec(t).map_err(|e| e.to_string())?;
            let name = format!("term {} (`{}`)", j + 1, kind.label());
            if let (Kind::Sinusoid(f), false) = (&kind, t.freq_hz.is_some_and(|f| f.is_finite() && f > 0.0)) {
                return Err(format!("{name}: field `freq_hz` = {f}: must be a positive frequency"));
            }
            if t.coef.is_empty() {
                continue;
            }
            if t.coef.len() != n_fog {
                return Err(format!(
                    "{name}: field `coef` holds coefficients for {} FOGs, {by} for {n_fog}: one set per FOG",
                    t.coef.len()
                ));
            }
            for (fog, c) in t.coef.iter().enumerate() {
                let labels = kind.regressor_labels(fog);
                if c.len() != labels.len() {
                    let names: Vec<&str> = labels.iter().map(|l| l.0.as_str()).collect();
                    return Err(format!(
                        "{name}: field `coef[{fog}]` holds {} values, the term has {} per FOG ({})",
                        c.len(),
                        labels.len(),
                        names.join(", ")
                    ));
                }
                if let Some((m, v)) = c.iter().enumerate().find(|(_, v)| !v.is_finite()) {
                    return Err(format!("{name}: field `coef[{fog}][{m}]` = {v} is not a finite number"));
                }
            }
        }
        if let Some(f) = &self.fit {
            if let Some((i, v)) = f.held_out_rms_deg_h.iter().enumerate().find(|(_, v)| !v.is_finite() || **v < 0.0) {
                return Err(format!("field `fit.held_out_rms_deg_h[{i}]` = {v}: must be a finite RMS"));
            }
        }
        Ok(())
    }

    /// Reads a model file.
    pub fn read(path: &std::path::Path) -> LabResult<Model> {
        let text = std::fs::read_to_string(path)
            .map_err(|e| LabError::model(ModelErrorKind::Io, format!("{}: cannot read: {e}", path.display())))?;
        Model::parse(&text, &path.display().to_string())
    }

    /// The TOML text.
    pub fn to_toml(&self) -> String {
        toml::to_string_pretty(self).expect("a model always serialises")
    }

    /// The kinds of the terms, in order.
    pub fn kinds(&self) -> Vec<Kind> {
        self.terms.iter().map(|t| Kind::of_spec(t).expect("checked when read")).collect()
    }
}

/// Sets angle `k` (0 or 1, the order of [`MISALIGNMENT_ANGLES`]) of FOG `fog` in `m`.
pub fn set_angle(m: &mut Misalignment, fog: usize, k: usize, v: f64) {
    let f = match (fog, k) {
        (0, 0) => &mut m.d12_rad,
        (0, _) => &mut m.d13_rad,
        (1, 0) => &mut m.d21_rad,
        (1, _) => &mut m.d23_rad,
        (2, 0) => &mut m.d31_rad,
        (2, _) => &mut m.d32_rad,
        (_, 0) => &mut m.d42_rad,
        (_, _) => &mut m.d43_rad,
    };
    *f = v;
}

/// Exact sensitive axis of FOG `fog` with its two angles `d` (the others zero).
pub fn axis_with(fog: usize, d: [f64; 2]) -> nalgebra::Vector3<f64> {
    let mut m = Misalignment::default();
    set_angle(&mut m, fog, 0, d[0]);
    set_angle(&mut m, fog, 1, d[1]);
    m.axes(GAMMA_NOMINAL_RAD)[fog]
}

/// ∂s_i/∂δ for FOG i's two angles at zero (numerical, from [`Misalignment::axes`], so the
/// lab's angles are the flight table's).
pub fn misalignment_partials(fog: usize) -> [nalgebra::Vector3<f64>; 2] {
    partials_at(fog, [0.0, 0.0])
}

/// ∂s_i/∂δ at angles `d`.
pub fn partials_at(fog: usize, d: [f64; 2]) -> [nalgebra::Vector3<f64>; 2] {
    let h = 1e-6;
    let e = |k: usize, v: f64| {
        let mut x = d;
        x[k] += v;
        axis_with(fog, x)
    };
    [(e(0, h) - e(0, -h)) / (2.0 * h), (e(1, h) - e(1, -h)) / (2.0 * h)]
}

/// The two unit vectors u_i, v_i spanning the plane of FOG i's fiber loop.
pub fn loop_plane(fog: usize) -> [nalgebra::Vector3<f64>; 2] {
    use nalgebra::Vector3;
    match fog {
        0 => [Vector3::y(), Vector3::z()],
        1 => [Vector3::z(), Vector3::x()],
        2 => [Vector3::x(), Vector3::y()],
        _ => {
            let u = Vector3::new(1.0, -1.0, 0.0).normalize();
            [u, nominal_axes()[3].cross(&u)]
        }
    }
}

/// `e` with the model file `origin` named in front, its kind kept.
fn within(origin: &str, e: LabError) -> LabError {
    match e {
        LabError::Model(m) => LabError::model(m.kind, format!("{origin}: {}", m.message)),
        other => LabError::model(ModelErrorKind::Term, format!("{origin}: {other}")),
    }
}
