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
use ssis::calib::{CalibrationTable, ObserverConfig};
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

impl Scenario {
    /// Reads and checks a scenario file; errors name the file, line and field.
    pub fn from_file(path: &Path) -> Result<Self> {
        let text = std::fs::read_to_string(path).with_context(|| format!("cannot read scenario {}", path.display()))?;
        let mut sc: Scenario = toml::from_str(&text).map_err(|e| anyhow::anyhow!("{}: {}", path.display(), e))?;
        sc.base_dir = path.parent().map(Path::to_path_buf).unwrap_or_default();
        sc.check().with_context(|| format!("{}: invalid scenario", path.display()))?;
        Ok(sc)
    }

    /// Sanity checks that TOML types cannot express.
    pub fn check(&self) -> Result<()> {
        anyhow::ensure!(self.duration_s > 0.0 && self.duration_s.is_finite(), "duration_s must be > 0");
        anyhow::ensure!(self.settle_s >= 0.0 && self.settle_s < self.duration_s, "settle_s must be in [0, duration_s)");
        anyhow::ensure!(
            !self.star_tracker.enabled || self.star_tracker.rate_hz > 0.0,
            "star_tracker.rate_hz must be > 0"
        );
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
        t.validate().map_err(|e| anyhow::anyhow!("unit table invalid: {e}"))?;
        Ok(t)
    }
}
