//! The campaign file (docs/MONTE-CARLO.md, "The campaign file"): its serde form, its checks
//! (unknown keys refused with the nearest known one, ranges, each error naming the file,
//! line or field) and its normalised form, [`Campaign`], which every run is drawn from.

use std::path::{Path, PathBuf};

use anyhow::{bail, ensure, Context, Result};
use serde::{Deserialize, Serialize};
use ssis::calib::field::{Field, FogTerm};
use ssis::calib::N_FOG;
use ssis::flight::FlightCore;
use ssis_common::names::{did_you_mean, with_suggestion};
use ssis_sim::harness::Simulation;
use ssis_sim::scenario::Scenario;

use crate::indices::{Index, IndexForm as IndexFile, IndexKind, IndexSpec, Indices};

/// The `format` line of every campaign file.
pub const FORMAT: &str = "ssis-mc-campaign/1";

/// Most runs a campaign may ask for (a typo guard: 10⁹ runs of a minute are 30 CPU-years).
pub const MAX_RUNS: u64 = 100_000_000;

/// Who flies the unit.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "kebab-case")]
pub enum Loop {
    /// The simulator and the flight core in Rust (`crate::run`).
    #[default]
    Open,
    /// Basilisk with `ssis.basilisk.UnitNav`, run by the Python side.
    Closed,
}

/// Where a run's sensor noise comes from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "kebab-case")]
pub enum Noise {
    /// Each run its own noise (and the scenario's own random draws), from (seed, i).
    #[default]
    PerRun,
    /// Every run the scenario's own seed: only the dispersions and faults differ.
    Fixed,
}

/// A distribution of a dispersion's offset δ.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum DistName {
    /// N(mean, sigma²).
    Normal,
    /// U[low, high).
    Uniform,
    /// N(mean, sigma²) restricted to mean ± bound_sigma·sigma (redrawn until inside).
    TruncatedNormal,
}

/// One `[[disperse]]` entry as written.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DisperseFile {
    /// A sensor error of the table's form: `fog.bias_rad_s` (for `fogs`), `fog[2].bias_rad_s`,
    /// `misalignment.d12_rad`.
    #[serde(default)]
    pub table: Option<String>,
    /// A number of the scenario: `star_tracker.latency_ms`, `star_tracker.misalignment_arcsec[0]`.
    #[serde(default)]
    pub scenario: Option<String>,
    /// For a per-FOG table term: which FOGs (default all four).
    #[serde(default)]
    pub fogs: Option<Vec<usize>>,
    /// One draw shared by the FOGs of `fogs` (default: one draw each).
    #[serde(default)]
    pub shared: bool,
    /// The distribution.
    pub dist: DistName,
    /// Mean of a normal, s.d. in the field's unit.
    #[serde(default)]
    pub mean: Option<f64>,
    /// 1σ, in the field's unit (default for a FOG bias: the table's
    /// `observer.initial_drift_sigma_deg_h`).
    #[serde(default)]
    pub sigma: Option<f64>,
    /// A uniform's lower end.
    #[serde(default)]
    pub low: Option<f64>,
    /// A uniform's upper end.
    #[serde(default)]
    pub high: Option<f64>,
    /// A truncated normal's bound, in σ (default 3).
    #[serde(default)]
    pub bound_sigma: Option<f64>,
}

/// A fault event's kind.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum FaultKind {
    /// A FOG's frames stop arriving for the rest of the run.
    FogLost,
    /// The star tracker sends nothing for `duration_s`.
    StarOutage,
    /// An upset: the unit resets, is down for `duration_s` and resumes from its snapshot.
    Reset,
}

/// One `[[fault]]` entry as written.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FaultFile {
    /// What happens.
    pub kind: FaultKind,
    /// Probability that it happens in a run, [0, 1].
    pub probability: f64,
    /// When: drawn uniformly in [start, end), s.
    pub window_s: [f64; 2],
    /// `fog-lost`: which FOG (default: drawn uniformly among the four).
    #[serde(default)]
    pub fog: Option<usize>,
    /// `star-outage`: how long (required); `reset`: the time down (default 0.1 s).
    #[serde(default)]
    pub duration_s: Option<f64>,
}

/// The campaign file as written.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CampaignFile {
    /// [`FORMAT`].
    pub format: String,
    /// Short name.
    pub name: String,
    /// What it studies.
    #[serde(default)]
    pub description: String,
    /// The base scenario, relative to the campaign file.
    pub scenario: PathBuf,
    /// A table file replacing the scenario's `[table]` (relative to the campaign file).
    #[serde(default)]
    pub table: Option<PathBuf>,
    /// Number of runs.
    pub runs: u64,
    /// Seed of every draw.
    pub seed: u64,
    /// Replaces the scenario's duration, s.
    #[serde(default)]
    pub duration_s: Option<f64>,
    /// `open` or `closed`.
    #[serde(default, rename = "loop")]
    pub loop_: Loop,
    /// `per-run` or `fixed`.
    #[serde(default)]
    pub noise: Noise,
    /// The dispersed quantities.
    #[serde(default)]
    pub disperse: Vec<DisperseFile>,
    /// The fault events.
    #[serde(default)]
    pub fault: Vec<FaultFile>,
    /// The indices.
    #[serde(default)]
    pub indices: IndicesFile,
}

/// `[indices]` as written.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct IndicesFile {
    /// Start of the statistics, s (default: the scenario's `settle_s`).
    #[serde(default)]
    pub from_s: Option<f64>,
    /// Statistic over time per run: the `time_fraction` quantile of |index| (1: the max).
    #[serde(default = "one")]
    pub time_fraction: f64,
    /// The indices (default: AKE, RKE over 10 s, KDE of 10-s windows 100 s apart).
    #[serde(default)]
    pub index: Vec<IndexFile>,
}

fn one() -> f64 {
    1.0
}

impl Default for IndicesFile {
    fn default() -> Self {
        IndicesFile { from_s: None, time_fraction: 1.0, index: Vec::new() }
    }
}

/// What a dispersion changes.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Target {
    /// Table fields of the simulated unit's true errors (one per FOG, or one): the truth is
    /// the base scenario's plus δ, the unit's table stays the base's.
    Table(Vec<String>),
    /// A scenario number (path in its TOML form): base value plus δ.
    Scenario(String),
}

/// A distribution with its parameters resolved.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(tag = "dist", rename_all = "kebab-case")]
pub enum Dist {
    /// N(mean, sigma²).
    Normal {
        /// Mean.
        mean: f64,
        /// 1σ.
        sigma: f64,
    },
    /// U[low, high).
    Uniform {
        /// Lower end.
        low: f64,
        /// Upper end.
        high: f64,
    },
    /// N(mean, sigma²) within mean ± bound_sigma·sigma.
    TruncatedNormal {
        /// Mean.
        mean: f64,
        /// 1σ.
        sigma: f64,
        /// Bound in σ.
        bound_sigma: f64,
    },
}

/// One drawn quantity of the normalised campaign: its parameter name (the key of the run's
/// `params`), what it changes, its distribution.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Quantity {
    /// `table.fog[0].bias_rad_s`, `table.fog[*].bias_rad_s` (shared), `scenario.star_tracker.latency_ms`.
    pub name: String,
    /// What it changes.
    pub target: Target,
    /// Its distribution.
    #[serde(flatten)]
    pub dist: Dist,
}

/// A fault event, normalised.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Fault {
    /// `fault[k].<kind>`: the stem of its parameters `.occurs`, `.t_s`, `.fog`.
    pub name: String,
    /// What happens.
    pub kind: FaultKind,
    /// Probability per run.
    pub probability: f64,
    /// Window of its time, s.
    pub window_s: [f64; 2],
    /// Fixed FOG (`fog-lost`), else drawn.
    pub fog: Option<usize>,
    /// Duration, s (`star-outage`, `reset`), 0 for `fog-lost`.
    pub duration_s: f64,
}

/// A campaign, checked and normalised: what `mc_validate` returns as JSON.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Campaign {
    /// [`FORMAT`].
    pub format: String,
    /// Name.
    pub name: String,
    /// What it studies.
    pub description: String,
    /// Where it was read from (errors and relative paths).
    pub origin: String,
    /// The base scenario's path, resolved.
    pub scenario_path: PathBuf,
    /// The base scenario, with the campaign's table and duration applied.
    pub scenario: Scenario,
    /// Runs.
    pub runs: u64,
    /// Seed.
    pub seed: u64,
    /// Open or closed loop.
    #[serde(rename = "loop")]
    pub loop_: Loop,
    /// Noise per run or fixed.
    pub noise: Noise,
    /// The drawn quantities, in draw order.
    pub quantities: Vec<Quantity>,
    /// The fault events.
    pub faults: Vec<Fault>,
    /// The indices.
    pub indices: IndexSpec,
    /// Every parameter a run reports, in order (the quantities', then the faults').
    pub params: Vec<String>,
    /// Every index key a run reports, in order (`AKE_x`, …).
    pub index_keys: Vec<String>,
    /// Steps of one run.
    pub steps_per_run: u64,
    /// The flight core its runs start from, built once per table.
    #[serde(skip)]
    pub cores: CoreCache,
}

/// A flight core as `FlightCore::new` builds it for one table, kept to be cloned: building
/// one computes the observer's steady-state gains, a tenth of a 600-s run's time, and a
/// clone of a new core is that core (so a run flies the same bits with or without it).
#[derive(Clone, Default)]
pub struct CoreCache(std::sync::Arc<std::sync::Mutex<Option<(ssis::calib::CalibrationTable, FlightCore)>>>);

impl std::fmt::Debug for CoreCache {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("CoreCache")
    }
}

impl CoreCache {
    /// A new core of `profile` flying `table`: a clone of the kept one when it was built
    /// for the same table, else built (and kept).
    pub fn core(&self, profile: ssis::flight::Profile, table: &ssis::calib::CalibrationTable) -> Result<FlightCore> {
        let mut kept = self.0.lock().map_err(|_| anyhow::anyhow!("core cache poisoned"))?;
        if let Some((t, core)) = kept.as_ref() {
            if t == table && core.profile() == profile {
                return Ok(core.clone());
            }
        }
        let core = FlightCore::new(profile, table, false).map_err(|e| anyhow::anyhow!("core: {e:?}"))?;
        *kept = Some((*table, core.clone()));
        Ok(core)
    }
}

/// The per-FOG term names a `table` dispersion may name (`fog.<term>`).
fn fog_terms() -> impl Iterator<Item = FogTerm> {
    FogTerm::ALL.into_iter()
}

/// The table fields a dispersion may name, as the user writes them.
fn table_names() -> Vec<String> {
    let mut v: Vec<String> = fog_terms().map(|t| format!("fog.{}", t.name())).collect();
    v.extend(Field::all().filter(|f| is_misalignment(*f)).map(|f| f.to_string()));
    v
}

fn is_misalignment(f: Field) -> bool {
    matches!(f, Field::D12 | Field::D13 | Field::D21 | Field::D23 | Field::D31 | Field::D32 | Field::D42 | Field::D43)
}

impl Campaign {
    /// Reads and checks a campaign file.
    pub fn from_file(path: &Path) -> Result<Campaign> {
        let text = std::fs::read_to_string(path).with_context(|| format!("cannot read campaign {}", path.display()))?;
        Campaign::parse(&text, &path.display().to_string())
    }

    /// Parses and checks a campaign's text; `origin` (its file's path) names it in errors
    /// and relative paths are taken from its directory.
    pub fn parse(text: &str, origin: &str) -> Result<Campaign> {
        let text = text.strip_prefix('\u{feff}').unwrap_or(text);
        let f: CampaignFile =
            toml::from_str(text).map_err(|e| anyhow::anyhow!("{origin}: {}", with_suggestion(&e.to_string())))?;
        Campaign::from_parts(f, origin).map_err(|e| anyhow::anyhow!("{origin}: invalid campaign: {e:#}"))
    }

    fn from_parts(f: CampaignFile, origin: &str) -> Result<Campaign> {
        ensure!(f.format == FORMAT, "field `format`: expected \"{FORMAT}\", found \"{}\"", f.format);
        ensure!((1..=MAX_RUNS).contains(&f.runs), "field `runs` = {}: must be in 1..={MAX_RUNS}", f.runs);
        let base_dir = Path::new(origin).parent().map(Path::to_path_buf).unwrap_or_default();
        let scenario_path = base_dir.join(&f.scenario);
        let mut sc = Scenario::from_file(&scenario_path).context("field `scenario`")?;
        ensure!(
            sc.profile == ssis_sim::scenario::ProfileName::Spacecraft,
            "field `scenario`: {} is a launch-vehicle scenario; campaigns fly the spacecraft unit",
            scenario_path.display()
        );
        if let Some(t) = &f.table {
            sc.table.file = Some(std::path::absolute(base_dir.join(t)).unwrap_or_else(|_| base_dir.join(t)));
        } else if let Some(t) = &sc.table.file {
            sc.table.file = Some(std::path::absolute(sc.base_dir.join(t)).unwrap_or_else(|_| sc.base_dir.join(t)));
        }
        if let Some(d) = f.duration_s {
            ensure!(d.is_finite() && d > 0.0, "field `duration_s` = {d}: must be > 0");
            ensure!(
                d > sc.settle_s,
                "field `duration_s` = {d}: must be after the scenario's settle_s = {}",
                sc.settle_s
            );
            sc.duration_s = d;
        }
        sc.check().context("the base scenario with the campaign's changes")?;
        // The unit's table (and the table's own 1σ figures) as the base scenario flies it.
        let table = Simulation::new(&sc).context("field `table`")?.table;
        let dt_s = sc.profile.profile().dt_s();
        let steps_per_run = (sc.duration_s / dt_s).round() as u64;

        let mut quantities = Vec::new();
        for (k, d) in f.disperse.iter().enumerate() {
            let at = format!("disperse[{k}]");
            quantities.extend(quantities_of(d, &sc, &table, &at).with_context(|| format!("`{at}`"))?);
        }
        if let Some(q) = names_twice(quantities.iter().map(|q| q.name.as_str())) {
            bail!("`{q}` is dispersed twice");
        }

        let mut faults = Vec::new();
        for (k, x) in f.fault.iter().enumerate() {
            let at = format!("fault[{k}]");
            ensure!(
                (0.0..=1.0).contains(&x.probability),
                "field `{at}.probability` = {}: a probability must be in [0, 1]",
                x.probability
            );
            let [a, b] = x.window_s;
            ensure!(
                a.is_finite() && b.is_finite() && 0.0 <= a && a < b && b <= sc.duration_s,
                "field `{at}.window_s` = [{a}, {b}]: must be [start, end) with 0 ≤ start < end ≤ duration_s = {}",
                sc.duration_s
            );
            if let Some(i) = x.fog {
                ensure!(x.kind == FaultKind::FogLost, "field `{at}.fog`: only for kind = \"fog-lost\"");
                ensure!(i < N_FOG, "field `{at}.fog` = {i}: the unit's FOGs are 0..{}", N_FOG - 1);
            }
            let duration_s = match (x.kind, x.duration_s) {
                (FaultKind::FogLost, Some(_)) => {
                    bail!("field `{at}.duration_s`: a lost FOG stays lost (not for fog-lost)")
                }
                (FaultKind::FogLost, None) => 0.0,
                (FaultKind::StarOutage, None) => bail!("field `{at}.duration_s`: required for a star-outage"),
                (FaultKind::Reset, None) => 0.1,
                (_, Some(d)) => d,
            };
            ensure!(
                duration_s.is_finite() && duration_s >= 0.0 && (x.kind == FaultKind::FogLost || duration_s > 0.0),
                "field `{at}.duration_s` = {duration_s}: must be > 0"
            );
            if x.kind == FaultKind::Reset {
                ensure!(
                    duration_s >= 2.0 * dt_s && duration_s <= 10.0,
                    "field `{at}.duration_s` = {duration_s}: a reset's time down must be in [{}, 10] s",
                    2.0 * dt_s
                );
            }
            let kind = serde_json::to_value(x.kind).ok().and_then(|v| v.as_str().map(String::from)).unwrap_or_default();
            faults.push(Fault {
                name: format!("{at}.{kind}"),
                kind: x.kind,
                probability: x.probability,
                window_s: x.window_s,
                fog: x.fog,
                duration_s,
            });
        }

        let indices = index_spec(&f.indices, &sc)?;
        let mut params: Vec<String> = quantities.iter().map(|q| q.name.clone()).collect();
        for x in &faults {
            params.push(format!("{}.occurs", x.name));
            params.push(format!("{}.t_s", x.name));
            if x.kind == FaultKind::FogLost {
                params.push(format!("{}.fog", x.name));
            }
        }
        let index_keys = Indices::keys(&indices);
        Ok(Campaign {
            format: f.format,
            name: f.name,
            description: f.description,
            origin: origin.to_string(),
            scenario_path,
            scenario: sc,
            runs: f.runs,
            seed: f.seed,
            loop_: f.loop_,
            noise: f.noise,
            quantities,
            faults,
            indices,
            params,
            index_keys,
            steps_per_run,
            cores: Default::default(),
        })
    }

    /// The normalised campaign as JSON (what `mc_validate` returns).
    pub fn to_json(&self) -> Result<String> {
        Ok(serde_json::to_string(self)?)
    }
}

fn names_twice<'a>(names: impl Iterator<Item = &'a str>) -> Option<&'a str> {
    let mut seen = std::collections::HashSet::new();
    names.into_iter().find(|n| !seen.insert(*n))
}

/// The quantities of one `[[disperse]]` entry.
fn quantities_of(
    d: &DisperseFile,
    sc: &Scenario,
    table: &ssis::calib::CalibrationTable,
    at: &str,
) -> Result<Vec<Quantity>> {
    let not_for = |key: &str, dist: &str| format!("field `{at}.{key}`: only for dist = \"{dist}\"");
    // The table's own 1σ of a term, in the term's unit, where the table has one.
    let mut table_sigma = None;
    let targets: Vec<(String, Target)> = match (&d.table, &d.scenario) {
        (Some(_), Some(_)) | (None, None) => bail!("give one of `{at}.table` and `{at}.scenario`"),
        (Some(name), None) => {
            let (fogs, field_of): (Vec<usize>, Box<dyn Fn(usize) -> String>) =
                if let Some(term) = name.strip_prefix("fog.") {
                    if !fog_terms().any(|t| t.name() == term) {
                        bail!(
                            "field `{at}.table` = \"{name}\" is not a FOG term of the table{}",
                            did_you_mean(name, table_names().iter().map(String::as_str))
                        );
                    }
                    let fogs = d.fogs.clone().unwrap_or_else(|| (0..N_FOG).collect());
                    ensure!(!fogs.is_empty(), "field `{at}.fogs`: empty");
                    if let Some(i) = fogs.iter().find(|i| **i >= N_FOG) {
                        bail!("field `{at}.fogs`: FOG {i}: the unit's FOGs are 0..{}", N_FOG - 1);
                    }
                    if let Some(i) = names_twice(fogs.iter().map(|i| ["0", "1", "2", "3"][*i])) {
                        bail!("field `{at}.fogs`: FOG {i} twice");
                    }
                    if term == FogTerm::Bias.name() {
                        table_sigma = Some(table.observer.initial_drift_sigma_deg_h / ssis_common::DEG_H_PER_RAD_S);
                    }
                    let term = term.to_string();
                    (fogs, Box::new(move |i| format!("fog[{i}].{term}")))
                } else {
                    let f = ssis_common::table::field_named(name)
                        .filter(|f| is_misalignment(*f) || matches!(f, Field::Fog(..)));
                    let Some(f) = f else {
                        bail!(
                            "field `{at}.table` = \"{name}\" is not a sensor error of the table{}",
                            did_you_mean(name, table_names().iter().map(String::as_str))
                        );
                    };
                    ensure!(d.fogs.is_none() && !d.shared, "field `{at}.fogs`/`shared`: only for `fog.<term>`");
                    if let Field::Fog(_, FogTerm::Bias) = f {
                        table_sigma = Some(table.observer.initial_drift_sigma_deg_h / ssis_common::DEG_H_PER_RAD_S);
                    }
                    let s = f.to_string();
                    (vec![usize::MAX], Box::new(move |_| s.clone()))
                };
            if d.shared {
                let fields: Vec<String> = fogs.iter().map(|i| field_of(*i)).collect();
                let term = name.strip_prefix("fog.").unwrap_or(name);
                vec![(format!("table.fog[*].{term}"), Target::Table(fields))]
            } else {
                fogs.iter().map(|i| (format!("table.{}", field_of(*i)), Target::Table(vec![field_of(*i)]))).collect()
            }
        }
        (None, Some(path)) => {
            ensure!(d.fogs.is_none() && !d.shared, "field `{at}.fogs`/`shared`: only for a table term `fog.<term>`");
            let value = toml::Value::try_from(sc).context("the scenario does not serialise")?;
            scenario_number(&value, path).with_context(|| format!("field `{at}.scenario` = \"{path}\""))?;
            vec![(format!("scenario.{path}"), Target::Scenario(path.clone()))]
        }
    };
    let finite = |key: &str, v: Option<f64>| -> Result<Option<f64>> {
        match v {
            Some(x) if !x.is_finite() => bail!("field `{at}.{key}` = {x}: not a finite number"),
            v => Ok(v),
        }
    };
    let (mean, sigma, low, high, bound) = (
        finite("mean", d.mean)?,
        finite("sigma", d.sigma)?,
        finite("low", d.low)?,
        finite("high", d.high)?,
        finite("bound_sigma", d.bound_sigma)?,
    );
    let sigma_of = || -> Result<f64> {
        let s = sigma.or(table_sigma).with_context(|| {
            format!("field `{at}.sigma`: required (the table has a 1σ for the FOG bias only: observer.initial_drift_sigma_deg_h)")
        })?;
        ensure!(s > 0.0, "field `{at}.sigma` = {s}: must be > 0");
        Ok(s)
    };
    let dist = match d.dist {
        DistName::Normal | DistName::TruncatedNormal => {
            ensure!(low.is_none(), not_for("low", "uniform"));
            ensure!(high.is_none(), not_for("high", "uniform"));
            let (mean, sigma) = (mean.unwrap_or(0.0), sigma_of()?);
            if d.dist == DistName::Normal {
                ensure!(bound.is_none(), not_for("bound_sigma", "truncated-normal"));
                Dist::Normal { mean, sigma }
            } else {
                let b = bound.unwrap_or(3.0);
                ensure!((0.1..=10.0).contains(&b), "field `{at}.bound_sigma` = {b}: must be in [0.1, 10]");
                Dist::TruncatedNormal { mean, sigma, bound_sigma: b }
            }
        }
        DistName::Uniform => {
            for (k, v) in [("mean", mean), ("sigma", sigma), ("bound_sigma", bound)] {
                ensure!(v.is_none(), not_for(k, if k == "bound_sigma" { "truncated-normal" } else { "normal" }));
            }
            let (Some(low), Some(high)) = (low, high) else {
                bail!("fields `{at}.low` and `{at}.high`: required for a uniform")
            };
            ensure!(low < high, "fields `{at}.low` = {low}, `{at}.high` = {high}: must have low < high");
            Dist::Uniform { low, high }
        }
    };
    Ok(targets.into_iter().map(|(name, target)| Quantity { name, target, dist }).collect())
}

/// Splits `a.b[2].c` into keys and indices.
pub(crate) fn path_parts(path: &str) -> Result<Vec<(String, Option<usize>)>> {
    path.split('.')
        .map(|part| match part.split_once('[') {
            None => Ok((part.to_string(), None)),
            Some((key, rest)) => {
                let i = rest
                    .strip_suffix(']')
                    .and_then(|n| n.parse::<usize>().ok())
                    .with_context(|| format!("`{part}`: not key[index]"))?;
                Ok((key.to_string(), Some(i)))
            }
        })
        .collect()
}

/// The number at `path` in a scenario's TOML form; refuses a path that names none, with
/// the nearest key.
pub(crate) fn scenario_number(v: &toml::Value, path: &str) -> Result<f64> {
    let mut cur = v;
    for (key, index) in path_parts(path)? {
        let t = cur.as_table().context("not a table")?;
        cur = t.get(&key).with_context(|| {
            format!("the scenario has no `{key}` here{}", did_you_mean(&key, t.keys().map(String::as_str)))
        })?;
        if let Some(i) = index {
            let a = cur.as_array().with_context(|| format!("`{key}` is not an array"))?;
            cur = a.get(i).with_context(|| format!("`{key}` has {} elements", a.len()))?;
        }
    }
    match cur {
        toml::Value::Float(x) => Ok(*x),
        _ => bail!("not a number of the scenario (the dispersible ones are its real numbers)"),
    }
}

/// Sets the number at `path` (which [`scenario_number`] found).
pub(crate) fn set_scenario_number(v: &mut toml::Value, path: &str, x: f64) -> Result<()> {
    let mut cur = v;
    for (key, index) in path_parts(path)? {
        cur = cur.get_mut(key.as_str()).context("no such key")?;
        if let Some(i) = index {
            cur = cur.get_mut(i).context("no such element")?;
        }
    }
    *cur = toml::Value::Float(x);
    Ok(())
}

/// The indices section, checked.
fn index_spec(f: &IndicesFile, sc: &Scenario) -> Result<IndexSpec> {
    let from_s = f.from_s.unwrap_or(sc.settle_s);
    ensure!(
        from_s.is_finite() && from_s >= 0.0 && from_s < sc.duration_s,
        "field `indices.from_s` = {from_s}: must be in [0, duration_s = {})",
        sc.duration_s
    );
    ensure!(
        f.time_fraction > 0.0 && f.time_fraction <= 1.0,
        "field `indices.time_fraction` = {}: must be in (0, 1]",
        f.time_fraction
    );
    let span = sc.duration_s - from_s;
    let defaults = [
        IndexFile { kind: IndexKind::Ake, window_s: None, separation_s: None },
        IndexFile { kind: IndexKind::Rke, window_s: Some(10.0), separation_s: None },
        IndexFile { kind: IndexKind::Kde, window_s: Some(10.0), separation_s: Some(100.0) },
    ];
    let list = if f.index.is_empty() { &defaults[..] } else { &f.index[..] };
    let mut out = Vec::new();
    for (k, x) in list.iter().enumerate() {
        let at = format!("indices.index[{k}]");
        let window = |v: Option<f64>, key: &str| -> Result<f64> {
            let w = v.with_context(|| format!("field `{at}.{key}`: required for {}", x.kind.name()))?;
            ensure!(
                w.is_finite() && w > 0.0 && w <= span,
                "field `{at}.{key}` = {w}: must be in (0, duration_s − from_s = {span}]"
            );
            Ok(w)
        };
        let index = Index::try_from(x.clone()).map_err(|e| anyhow::anyhow!("field `{at}`: {e}"))?;
        match index {
            Index::Ake => {}
            Index::Rke { window_s } => {
                window(Some(window_s), "window_s")?;
            }
            Index::Kde { window_s, separation_s } => {
                let (w, s) = (window(Some(window_s), "window_s")?, window(Some(separation_s), "separation_s")?);
                ensure!(
                    w + s <= span,
                    "fields `{at}.window_s` + `separation_s` = {}: must be ≤ duration_s − from_s = {span}",
                    w + s
                );
            }
        }
        out.push(index);
    }
    let spec = IndexSpec { from_s, time_fraction: f.time_fraction, index: out };
    if let Some(n) = names_twice(spec.index.iter().map(|i| i.name()).collect::<Vec<_>>().iter().map(String::as_str)) {
        bail!("field `indices.index`: `{n}` twice");
    }
    Ok(spec)
}
