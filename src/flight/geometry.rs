//! The unit's geometry from its calibration table: the combiner of the FOGs that fly
//! (their table axes in the order the channels fly on them), the parity fault logic on
//! it, the sample noise σ₁ and the estimators' noise; the switch to a new table between
//! two steps, and what an isolation changes.

use nalgebra::Vector3;

use super::{CoreError, FlightCore, Profile};
use crate::calib::{CalibrationTable, N_FOG};
use crate::combination::{Combiner, FogSet};
use crate::integrity::parity::ParityMonitor;
use crate::telemetry::events::Event;

impl FlightCore {
    /// Whether the core would fly on `table` ([`FlightCore::switch_table`] would take it):
    /// its fitted FOGs span 3-D space and the observer's gains can be computed.
    pub fn check_table(profile: Profile, table: &CalibrationTable) -> Result<(), CoreError> {
        checked_combiner(profile, table, &IDENTITY_MAP)?;
        crate::observer::steady_state(&table.observer)?;
        Ok(())
    }

    /// Whether a table may be switched now: not while a parity alarm stands (its
    /// isolation fit runs on the table it began with).
    pub fn ready_for_table(&self) -> bool {
        !self.fdi.as_ref().is_some_and(|m| m.alarm())
    }

    /// Switches to `table` between two steps: compensation, combination, the parity
    /// monitor's geometry, the star-tracker mount, the temperature-rate filter and the
    /// observer's gains take the new values from the next step on; the attitude, the
    /// drift estimate, the histories, the counters, an isolated FOG and the flags stay.
    /// So the attitude changes only by what the new values imply. Refused (nothing
    /// changed) if [`FlightCore::check_table`] refuses `table`.
    pub fn switch_table(&mut self, table: &CalibrationTable) -> Result<(), CoreError> {
        self.install_table(table)?;
        let revision = u16::try_from(table.revision).unwrap_or(u16::MAX);
        self.events.log(self.last_output.time_us, Event::TableSwitched, 0, revision);
        Ok(())
    }

    /// Flies on `table` from the next step, everything built from it rebuilt
    /// ([`FlightCore::switch_table`] without its event; a table restored by the
    /// background check).
    pub(super) fn install_table(&mut self, table: &CalibrationTable) -> Result<(), CoreError> {
        let combiner = checked_combiner(self.profile.get(), table, &self.fog_map)?;
        crate::observer::steady_state(&table.observer)?;
        self.guard_touch_tuning();
        self.observer.retune(&table.observer)?;
        let dt = self.profile.dt_s();
        let noise_rad = sample_noise_rad(table, dt);
        self.install_geometry(combiner, noise_rad);
        for m in self.channel_monitors.iter_mut() {
            m.set_noise(noise_rad);
        }
        for t in self.thermal.iter_mut() {
            t.set_time_constant(dt, table.t_rate_filter_s);
        }
        self.mount = table.st_mount();
        self.table = *table;
        self.table_crc = table_crc(table);
        self.scrub.seal(table);
        self.guard_seal_all();
        Ok(())
    }

    /// Flies on `combiner` from the next sample: the parity logic on its geometry, taking
    /// over an isolated FOG and the counters from the one before.
    pub(super) fn install_geometry(&mut self, combiner: Combiner, noise_rad: f64) {
        self.guard_touch_combiner();
        self.guard_touch_tuning();
        let dt = self.profile.dt_s();
        let mut fdi = parity_monitor(self.profile.get(), &combiner, noise_rad, dt);
        if let (Some(new), Some(old)) = (fdi.as_mut(), self.fdi.as_ref()) {
            new.carry_from(old);
        }
        self.fdi = fdi.into();
        self.combiner = combiner;
        self.observer.set_noise(&flying_noise(&self.combiner, self.flying()));
    }

    /// The FOGs the combination flies on: the fitted ones less an isolated one.
    pub(super) fn flying(&self) -> FogSet {
        match self.fdi.as_ref().and_then(ParityMonitor::isolated) {
            Some(i) => self.profile.fogs.without(i),
            None => self.profile.fogs,
        }
    }

    /// FOG `i` has just been isolated at unit time `now_us`: its share leaves the drift
    /// estimate ([`Observer::remove_drift_share`]), and the estimators' noise follows
    /// the triad that flies from now on.
    pub(super) fn on_isolation(&mut self, i: usize, now_us: u64) {
        self.guard_touch_tuning();
        if let Some(fdi) = self.fdi.as_ref() {
            let (share, cov) = (fdi.drift_share_rad_s(i), fdi.drift_share_cov_rad2_s2(i));
            self.observer.remove_drift_share(now_us, &share, &cov);
        }
        self.observer.set_noise(&flying_noise(&self.combiner, self.flying()));
    }
}

/// N = (SᵀS)⁻¹ of the combination of `set` on `combiner` ([`crate::observer::mekf::noise_of`]);
/// the identity if `set` cannot be combined (the estimators keep one FOG's figures).
pub(super) fn flying_noise(combiner: &Combiner, set: FogSet) -> nalgebra::Matrix3<f64> {
    combiner.solution(set).map_or_else(|_| nalgebra::Matrix3::identity(), crate::observer::mekf::noise_of)
}

/// FOG channel k on the table's axis k: the mounting the table describes.
pub(super) const IDENTITY_MAP: [usize; N_FOG] = [0, 1, 2, 3];

/// The table's axes in the order the FOG channels fly on them (`map[k]` for channel k).
fn mounted_axes(table: &CalibrationTable, map: &[usize; N_FOG]) -> [Vector3<f64>; N_FOG] {
    let axes = table.axes();
    map.map(|k| axes.get(k).copied().unwrap_or_else(Vector3::zeros))
}

/// The combiner of `table`'s geometry, if the profile's FOGs span 3-D space with it.
pub(super) fn checked_combiner(
    profile: Profile,
    table: &CalibrationTable,
    map: &[usize; N_FOG],
) -> Result<Combiner, CoreError> {
    let combiner = Combiner::new(&mounted_axes(table, map));
    match combiner.solution(profile.fogs) {
        Ok(_) => Ok(combiner),
        Err(_) => Err(CoreError::Geometry),
    }
}

/// σ₁: the ARW's angle noise in one sample of `dt_s` (the table's noise figure), rad.
pub(super) fn sample_noise_rad(table: &CalibrationTable, dt_s: f64) -> f64 {
    table.observer.arw_deg_sqrt_h * core::f64::consts::PI / 180.0 / 60.0 * crate::math::sqrt(dt_s)
}

/// The parity fault logic for the profile (four FOGs) on `combiner`'s geometry.
pub(super) fn parity_monitor(
    profile: Profile,
    combiner: &Combiner,
    noise_rad: f64,
    dt_s: f64,
) -> Option<ParityMonitor> {
    match (profile.fogs == FogSet::ALL, combiner.solution(FogSet::ALL), combiner.triads()) {
        (true, Ok(all), Some(triads)) => ParityMonitor::new(combiner.parity_vector(), all, triads, noise_rad, dt_s),
        _ => None,
    }
}

/// CRC-32 of `table`'s binary form (its last four bytes: what the table store and the
/// command link name a table by).
pub fn table_crc(table: &CalibrationTable) -> u32 {
    let bytes = crate::calib::binary::encode(table);
    bytes.last_chunk::<4>().map_or(0, |c| u32::from_le_bytes(*c))
}
