//! Scenarios: data files a user can write (TOML). See `scenarios/*.toml` and the README.
//!
//! ```toml
//! name = "earth-pointing"
//! profile = "spacecraft"          # or "launch-vehicle"
//! duration_s = 7200
//! seed = 1
//! settle_s = 1800                 # statistics start here
//! [motion]                        # sim::truth::MotionSpec
//! base_rate_deg_s = [0.0, -0.0638, 0.0]
//! [[motion.slews]]
//! start_s = 3000
//! duration_s = 120
//! axis = [1.0, 0.0, 0.0]
//! angle_deg = 20
//! [fog]                           # sim::fog::FogSpec
//! random_bias_3sigma_deg_h = 0.05
//! [star_tracker]                  # sim::star::StarSpec
//! rate_hz = 4
//! [table]
//! source = "nominal"              # what the unit flies with: "nominal" or "truth"
//! [links.fog]                     # mock::Impairments, also [links.star]
//! bit_flip_prob = 1e-4
//! ```

use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use serde::{Deserialize, Serialize};
use ssis::calib::{CalibrationTable, Estimator, ObserverConfig};
use ssis::flight::Profile;

use crate::fog::FogSpec;
use crate::star::StarSpec;
use crate::truth::MotionSpec;
use ssis_common::mock::Impairments;

/// Which unit.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum ProfileName {
    /// Four FOGs + star tracker, 5 ms.
    Spacecraft,
    /// Three FOGs, 1.25 ms.
    LaunchVehicle,
}

impl ProfileName {
    /// The core's profile.
    pub fn profile(self) -> Profile {
        match self {
            ProfileName::Spacecraft => Profile::SPACECRAFT,
            ProfileName::LaunchVehicle => Profile::LAUNCH_VEHICLE,
        }
    }
}

/// Where the unit's calibration table comes from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "kebab-case")]
pub enum TableSource {
    /// Nominal geometry, no error terms: the sensor errors are all uncompensated.
    #[default]
    Nominal,
    /// The simulator's true deterministic errors: perfect calibration.
    Truth,
}

/// The table the unit flies with.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
#[serde(deny_unknown_fields, default)]
pub struct TableSpec {
    /// Source of the error terms.
    pub source: TableSource,
    /// A table file in TOML form (replaces `source`), relative to the scenario file.
    pub file: Option<PathBuf>,
    /// Observer settings (noise figures, gain override) replacing the table's.
    pub observer: Option<ObserverConfig>,
    /// The estimator that flies (`"luenberger"`, `"mekf"`), replacing the table's (and
    /// `observer`'s) choice.
    pub estimator: Option<Estimator>,
}

/// Link impairments.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, Default)]
#[serde(deny_unknown_fields, default)]
pub struct LinkSpec {
    /// Every FOG link.
    pub fog: Impairments,
    /// The star-tracker link.
    pub star: Impairments,
}

/// A scenario.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Scenario {
    /// Short name.
    pub name: String,
    /// What it shows.
    #[serde(default)]
    pub description: String,
    /// Which unit.
    pub profile: ProfileName,
    /// Simulated time, s.
    pub duration_s: f64,
    /// Seed of every random draw.
    #[serde(default)]
    pub seed: u64,
    /// Statistics are taken after this time, s.
    #[serde(default)]
    pub settle_s: f64,
    /// Truth motion.
    #[serde(default)]
    pub motion: MotionSpec,
    /// FOG errors.
    #[serde(default)]
    pub fog: FogSpec,
    /// Star tracker.
    #[serde(default)]
    pub star_tracker: StarSpec,
    /// The unit's table.
    #[serde(default)]
    pub table: TableSpec,
    /// Link impairments.
    #[serde(default)]
    pub links: LinkSpec,
    /// Directory of the scenario file (for relative paths).
    #[serde(skip)]
    pub base_dir: PathBuf,
}

/// Longest simulated time a scenario runs without `--allow-long`, s (30 days): a longer one
/// is most likely a typo (hours written as seconds) and would run for days.
pub const LONG_DURATION_S: f64 = 30.0 * 86_400.0;

impl Scenario {
    /// Reads and checks a scenario file; errors name the file, line and field. Longer than
    /// [`LONG_DURATION_S`] is refused ([`Scenario::from_file_with`] allows it).
    pub fn from_file(path: &Path) -> Result<Self> {
        Self::from_file_with(path, false)
    }

    /// [`Scenario::from_file`], with durations over 30 days allowed when `allow_long`.
    pub fn from_file_with(path: &Path, allow_long: bool) -> Result<Self> {
        let text = std::fs::read_to_string(path).with_context(|| format!("cannot read scenario {}", path.display()))?;
        let mut sc: Scenario = toml::from_str(&text).map_err(|e| anyhow::anyhow!("{}: {}", path.display(), e))?;
        sc.base_dir = path.parent().map(Path::to_path_buf).unwrap_or_default();
        sc.check().with_context(|| format!("{}: invalid scenario", path.display()))?;
        anyhow::ensure!(
            allow_long || sc.duration_s <= LONG_DURATION_S,
            "{}: invalid scenario: field `duration_s` = {} s ({:.1} days) is over 30 days (hours written as seconds?); \
             give --allow-long to run it",
            path.display(),
            sc.duration_s,
            sc.duration_s / 86_400.0
        );
        Ok(sc)
    }

    /// Checks that TOML types cannot express, each refusal naming the field: every number
    /// finite; durations and rates positive; probabilities in [0, 1]; axes not zero.
    pub fn check(&self) -> Result<()> {
        let value = toml::Value::try_from(self).context("the scenario does not serialise")?;
        if let Some((path, v)) = first_non_finite(&value, String::new()) {
            anyhow::bail!("field `{path}` = {v} is not a finite number");
        }
        anyhow::ensure!(self.duration_s > 0.0, "field `duration_s` = {}: must be > 0", self.duration_s);
        anyhow::ensure!(
            self.settle_s >= 0.0 && self.settle_s < self.duration_s,
            "field `settle_s` = {}: must be in [0, duration_s = {})",
            self.settle_s,
            self.duration_s
        );
        let st = &self.star_tracker;
        anyhow::ensure!(!st.enabled || st.rate_hz > 0.0, "field `star_tracker.rate_hz` = {}: must be > 0", st.rate_hz);
        for (name, v) in [
            ("star_tracker.sigma_3sigma_arcsec", st.sigma_3sigma_arcsec),
            ("star_tracker.latency_ms", st.latency_ms),
            ("fog.arw_deg_sqrt_h", self.fog.arw_deg_sqrt_h),
            ("fog.rrw_deg_h_sqrt_h", self.fog.rrw_deg_h_sqrt_h),
            ("fog.random_bias_3sigma_deg_h", self.fog.random_bias_3sigma_deg_h),
            ("fog.random_scale_3sigma", self.fog.random_scale_3sigma),
            ("fog.random_axis_3sigma_arcsec", self.fog.random_axis_3sigma_arcsec),
        ] {
            anyhow::ensure!(v >= 0.0, "field `{name}` = {v}: must be ≥ 0");
        }
        for (k, o) in st.outages.iter().enumerate() {
            anyhow::ensure!(
                o[0] < o[1],
                "field `star_tracker.outages[{k}]` = {o:?}: must be [start, end) with start < end"
            );
        }
        anyhow::ensure!(
            self.fog.temperature.sine_period_s > 0.0,
            "field `fog.temperature.sine_period_s` = {}: must be > 0",
            self.fog.temperature.sine_period_s
        );
        for (link, imp) in [("fog", &self.links.fog), ("star", &self.links.star)] {
            for (name, p) in [("drop_prob", imp.drop_prob), ("bit_flip_prob", imp.bit_flip_prob)] {
                anyhow::ensure!(
                    (0.0..=1.0).contains(&p),
                    "field `links.{link}.{name}` = {p}: a probability must be in [0, 1]"
                );
            }
        }
        let zero = |a: [f64; 3]| a.iter().map(|x| x * x).sum::<f64>() < 1e-24;
        for (k, sl) in self.motion.slews.iter().enumerate() {
            anyhow::ensure!(
                !zero(sl.axis),
                "field `motion.slews[{k}].axis` = {:?}: the axis must not be zero",
                sl.axis
            );
            anyhow::ensure!(
                sl.duration_s > 0.0,
                "field `motion.slews[{k}].duration_s` = {}: must be > 0",
                sl.duration_s
            );
        }
        for (k, m) in self.motion.modes.iter().enumerate() {
            anyhow::ensure!(!zero(m.axis), "field `motion.modes[{k}].axis` = {:?}: the axis must not be zero", m.axis);
        }
        if let Some(q) = self.motion.initial_q {
            anyhow::ensure!(
                q.iter().map(|x| x * x).sum::<f64>() > 1e-24,
                "field `motion.initial_q` = {q:?}: must not be zero"
            );
        }
        Ok(())
    }

    /// The table the unit flies with, given the simulator's truth.
    pub fn unit_table(&self, truth: &CalibrationTable) -> Result<CalibrationTable> {
        let mut t = match (&self.table.file, self.table.source) {
            (Some(f), _) => {
                let p = self.base_dir.join(f);
                ssis_common::table::read_toml(&p)?
            }
            (None, TableSource::Nominal) => CalibrationTable::DEFAULT,
            (None, TableSource::Truth) => *truth,
        };
        if let Some(o) = self.table.observer {
            t.observer = o;
        }
        if let Some(e) = self.table.estimator {
            t.observer.estimator = e;
        }
        t.validate().map_err(|e| anyhow::anyhow!("unit table invalid: {e}"))?;
        Ok(t)
    }
}

impl Scenario {
    /// The estimation limits for this scenario's sensors (its FOGs' noise, its star tracker's
    /// noise, rate, latency and low-frequency error; the nominal axes), when its star
    /// tracker has a low-frequency error: the white-tracker limit and the limit with the
    /// error estimated ([`crate::accuracy::farrenkopf_1sigma_arcsec`]). `None` for a white
    /// tracker.
    pub fn lfe_limit(&self) -> Option<crate::accuracy::Limit> {
        let st = &self.star_tracker;
        if !(st.lfe_sigma_arcsec > 0.0 && st.lfe_tau_s > 0.0) {
            return None;
        }
        let profile = self.profile.profile();
        let dt_s = profile.dt_s();
        let cfg = ObserverConfig {
            arw_deg_sqrt_h: self.fog.arw_deg_sqrt_h,
            rrw_deg_h_sqrt_h: self.fog.rrw_deg_h_sqrt_h,
            st_sigma_arcsec: st.sigma_3sigma_arcsec / 3.0,
            st_period_s: ((1.0 / st.rate_hz) / dt_s).round().max(1.0) * dt_s,
            st_lfe_sigma_arcsec: st.lfe_sigma_arcsec,
            st_lfe_tau_s: st.lfe_tau_s,
            ..ObserverConfig::PAPER
        };
        Some(crate::accuracy::farrenkopf_1sigma_arcsec(
            &cfg,
            &CalibrationTable::DEFAULT.axes(),
            dt_s,
            st.latency_ms * 1e-3,
        ))
    }
}

/// An estimator named on a command line (`--estimator`): `luenberger` or `mekf`.
pub fn parse_estimator(s: &str) -> std::result::Result<Estimator, String> {
    match s {
        "luenberger" => Ok(Estimator::Luenberger),
        "mekf" => Ok(Estimator::Mekf),
        other => Err(format!("`{other}` is not an estimator: luenberger or mekf")),
    }
}

/// The path and value of the first number in `v` that is not finite (`motion.slews[0].axis[1]`).
fn first_non_finite(v: &toml::Value, path: String) -> Option<(String, f64)> {
    match v {
        toml::Value::Float(f) if !f.is_finite() => Some((path, *f)),
        toml::Value::Array(a) => a.iter().enumerate().find_map(|(k, x)| first_non_finite(x, format!("{path}[{k}]"))),
        toml::Value::Table(t) => t.iter().find_map(|(key, x)| {
            let p = if path.is_empty() { key.clone() } else { format!("{path}.{key}") };
            first_non_finite(x, p)
        }),
        _ => None,
    }
}
