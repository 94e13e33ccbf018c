//! The reset snapshot: what a reset (watchdog, HardFault) resumes from, so the unit does
//! not align again from nothing.
//!
//! [`FlightCore::snapshot`] writes the state that takes minutes to rebuild into a
//! [`Snapshot`], a `repr(C)` plain-old-data record sealed with a CRC-32C
//! ([`Snapshot::checksum`]): the attitude Λ, the drift estimate Δω, unit time (the sample
//! clock), the alignment and the estimator's convergence and covariance, the FOG
//! assignment, the mean body increment and the CRC of the table it was taken under, and
//! the fields the core's declaration keeps over a reset ([`super::Survivors`], copied
//! as they are). The board keeps two copies ([`Snapshots`], written in turn by the
//! executive, so a reset that tears one write, or an upset of one copy before a reset,
//! leaves the other, one snapshot period older) in RAM its reset does not clear
//! (`ssis-firmware`: the SNAP region) and, after a reset, hands them to
//! [`FlightCore::resume_from`], which takes the newer copy that passes; each goes
//! through [`FlightCore::resume`], which resumes only a snapshot that passes every check
//! ([`SnapshotError`]): its check word, its format, the table in use, and plausibility (a unit
//! quaternion, finite values, a drift within [`MAX_DRIFT_RAD_S`]). Its age is checked at
//! the first FOG sample after the reset: the samples sent meanwhile are bridged on the
//! last increment, and a snapshot more than [`MAX_AGE_STEPS`] old is dropped (the
//! estimate restarts and the next star-tracker frame aligns, as at power-on). Logged:
//! `resumed` (with the age in steps) or `snapshot_invalid` (with the reason).
//!
//! Any bit pattern of the record is a value ([`bytemuck::Pod`]: no enum, no bool): a snapshot read back from
//! RAM that a reset, an upset or a cold start left in any state is judged by its checks
//! only. Not carried over: the MEKF's star-tracker LFE states (they restart unknown, at
//! their stationary covariance σ_c² I, ĉ = 0, uncorrelated with the rest), the attitude
//! history (frames tagged before the resume are refused as late), a FOG isolated by the
//! parity logic (isolated again if still faulty) and the mounting check (not run again
//! once it had cleared the unit); a unit flying two FOGs swapped is not resumed (it
//! aligns again and the check finds the swap again).

use nalgebra::{Quaternion, Vector3};

use super::{FlightCore, Survivors};
use crate::observer::ResumeState;
use crate::telemetry::events::Event;
use crate::telemetry::Counter;

/// First word: "SNP" and the layout version 2.
const MAGIC: u32 = u32::from_le_bytes(*b"SNP\x02");
/// Largest drift estimate a snapshot may carry, rad/s (1 °/s: far beyond any FOG's bias).
pub const MAX_DRIFT_RAD_S: f64 = 1.0 * core::f64::consts::PI / 180.0;
/// Oldest snapshot resumed, in steps (1 s at 5 ms): older, the bridge over the reset on
/// the last increment is not trusted.
pub const MAX_AGE_STEPS: u64 = 200;
/// How far the interval's mean increment may be from the last sample, beyond a tenth of
/// the increment, before the last sample is bridged on instead, rad.
const MEAN_TOLERANCE_RAD: f64 = 1e-6;
/// Room the boards keep for the snapshot's two copies ([`Snapshots`]) in RAM their reset
/// does not clear (the SNAP region of the firmware's memory layout), bytes.
pub const SNAPSHOT_ROOM_BYTES: usize = 1024;
const _: () = assert!(core::mem::size_of::<Snapshots>() <= SNAPSHOT_ROOM_BYTES);

/// [`Snapshot::flags`]: the mounting check had cleared the unit; bits 8..16: the FOG
/// assignment.
const MOUNT_CLEARED: u32 = 1;
/// [`Snapshot::flags`] of the identity FOG assignment (channel k on axis k, bits 8 + 2k).
const IDENTITY_FLAGS: u32 = 1 << 10 | 2 << 12 | 3 << 14;

/// Why a snapshot was not resumed (the detail `a` of the `snapshot_invalid` event).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
#[repr(u8)]
pub enum SnapshotError {
    /// No snapshot: wrong magic or layout (a cold start).
    Absent = 1,
    /// Its check word does not match: corrupted.
    BadCrc = 2,
    /// Taken under another calibration table.
    OtherTable = 3,
    /// A value is not plausible (not a unit quaternion, not finite, drift too large), or
    /// two FOGs were flown swapped (the mounting check finds the swap again after the
    /// new alignment).
    Implausible = 4,
    /// Older than [`MAX_AGE_STEPS`] at the first sample after the reset.
    TooOld = 5,
}

/// Data bits over which CRC-32C keeps a Hamming distance of 6 (Koopman's tables): the
/// bytes before [`Snapshot`]'s check word must stay within them.
pub const CHECKED_BITS_HD6: usize = 5_243;
const _: () = assert!(
    8 * core::mem::offset_of!(Snapshot, check) <= CHECKED_BITS_HD6,
    "the snapshot outgrew CRC-32C's distance-6 length"
);

/// The snapshot: a plain-old-data record, its last word the CRC-32C of the bytes before
/// it ([`Snapshot::checksum`]).
#[derive(Debug, Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
#[repr(C)]
pub struct Snapshot {
    /// [`MAGIC`]: "SNP" and the layout version.
    magic: u32,
    /// CRC-32 of the table it was taken under.
    table_crc: u32,
    /// Bit 0: the mounting check had cleared the unit; bits 8..16: the FOG assignment.
    flags: u32,
    /// The sample counter the sample clock expects next.
    expected: u32,
    /// Updates since alignment.
    updates: u32,
    /// Zero (the record has no padding).
    reserved: u32,
    /// Unit time it was taken at, in samples (the sample clock's index).
    index: u64,
    /// Unit time of the alignment, µs.
    aligned_us: u64,
    /// Time tag of the last frame that updated the estimate, µs.
    last_update_tag_us: u64,
    /// Λ (w x y z).
    q: [f64; 4],
    /// Λ(t_s) after the last update (w x y z).
    last_q: [f64; 4],
    /// Drift estimate Δω, rad/s.
    drift_rad_s: [f64; 3],
    /// The body increment a reset bridges on, rad.
    dtheta_rad: [f64; 3],
    /// Running mean-square mismatch per axis, rad².
    innov_ms_rad2: f64,
    /// The estimator's covariance.
    cov: [f64; 27],
    /// The increment's change per step, rad.
    trend_rad: [f64; 3],
    /// The fields the core's declaration keeps over a reset.
    kept: Survivors,
    /// Zero.
    reserved_end: u32,
    /// CRC-32C of every byte before it.
    check: u32,
}

/// The snapshot's two copies, written in turn ([`Snapshots::write`]): a copy torn by a
/// reset during its write, or one an upset flipped a bit of before a reset, leaves the
/// other, one snapshot period older, to resume from ([`FlightCore::resume_from`]).
#[derive(Debug, Clone, Copy, Default, bytemuck::Pod, bytemuck::Zeroable)]
#[repr(C)]
pub struct Snapshots {
    copies: [Snapshot; 2],
}

impl Snapshots {
    /// Writes `core`'s snapshot into copy `slot` (taken modulo 2: the board's executive
    /// alternates; an upset of its count at worst writes one copy twice, and the other,
    /// older, is then refused by its age); a core with nothing to resume leaves the copy
    /// as it was.
    #[inline]
    pub fn write(&mut self, core: &FlightCore, slot: u32) {
        let [a, b] = &mut self.copies;
        let _ = core.snapshot_into(if slot & 1 == 0 { a } else { b });
    }

    /// Spoils both copies (the board after resuming: a snapshot is resumed at most once).
    pub fn invalidate(&mut self) {
        for c in &mut self.copies {
            c.invalidate();
        }
    }

    /// The copies, the one taken at the later unit time first (by the index each holds:
    /// the resume checks each before it trusts anything else in it).
    pub fn newest_first(&self) -> [&Snapshot; 2] {
        let [a, b] = &self.copies;
        if b.index() > a.index() {
            [b, a]
        } else {
            [a, b]
        }
    }

    /// Copy `k` (0 or 1; tests: a bit flipped in one copy, a copy torn).
    pub fn copy_mut(&mut self, k: usize) -> Option<&mut Snapshot> {
        self.copies.get_mut(k)
    }
}

impl Default for Snapshot {
    fn default() -> Self {
        bytemuck::Zeroable::zeroed()
    }
}

impl Snapshot {
    /// The check word of every byte before it: CRC-32C (the frames' polynomial, through
    /// their table: [`crate::frames::crc32c_register`]). Over the bytes before the check
    /// word (at most 655, [`CHECKED_BITS_HD6`], checked at build time) its
    /// Hamming distance is 6 (Koopman's tables: HD 6 up to 5,243 data bits): every error
    /// of 1 to 5 bits is detected, and every burst up to 32 bits.
    /// About 3 instructions a byte.
    pub fn checksum(&self) -> u32 {
        let bytes = bytemuck::bytes_of(self);
        let body = bytes.get(..core::mem::offset_of!(Snapshot, check)).unwrap_or(bytes);
        crate::frames::crc32c_register(crc::CRC_32_ISCSI.init, body) ^ crc::CRC_32_ISCSI.xorout
    }

    /// Whether its check word matches (the first check of [`FlightCore::resume`]).
    pub fn sealed(&self) -> bool {
        self.check == self.checksum()
    }

    /// Writes the check word (the last step of [`FlightCore::snapshot_into`]).
    pub fn seal(&mut self) {
        self.check = self.checksum();
    }

    /// Unit time it was taken at, in samples (the sample clock's index).
    pub fn index(&self) -> u64 {
        self.index
    }

    /// Spoils the check word (the board after resuming: the same snapshot is not resumed twice).
    pub fn invalidate(&mut self) {
        self.check = !self.check;
    }

    /// Its bytes (tests: a bit flipped in RAM).
    pub fn bytes_mut(&mut self) -> &mut [u8] {
        bytemuck::bytes_of_mut(self)
    }
}

impl FlightCore {
    /// The snapshot of this core now (see the module doc); `None` before alignment, when
    /// there is nothing a reset would lose.
    pub fn snapshot(&self) -> Option<Snapshot> {
        let mut s = Snapshot::default();
        self.snapshot_into(&mut s).then_some(s)
    }

    /// Writes the snapshot into `s` in place, sealed (the board's copy in RAM a reset does
    /// not clear); returns false, leaving `s` as it was, before alignment or before the
    /// first FOG sample.
    #[inline(never)]
    pub fn snapshot_into(&self, s: &mut Snapshot) -> bool {
        let (index, Some(expected)) = self.fog_intake.clock() else { return false };
        let Some(o) = self.observer.resume_state() else { return false };
        let q = self.attitude.quaternion();
        let map = self.fog_map.iter().enumerate().fold(0u32, |acc, (k, &a)| acc | ((a as u32 & 3) << (8 + 2 * k)));
        let cleared = self.mounting.as_ref().is_none_or(|m| !m.checking() || m.clear_to_report());
        // The increment a reset bridges on: the mean body increment since the snapshot
        // before (its attitude turned to this one over `steps` samples, with the drift
        // estimate added back), not the last sample alone, whose noise a bridge of 40–60
        // steps multiplies (one sample: up to 6″ at the first frame after the reset). With
        // its change per step (the turn's angular acceleration, from the snapshot before's
        // increment and change) it corrects the bridge. A mean far from the last sample (the snapshot before
        // corrupted, or a turn faster than the interval resolves) is not used: the last
        // sample is, with no change per step.
        let steps = index.wrapping_sub(s.index);
        let follows = s.magic == MAGIC && (1..=4 * MAX_AGE_STEPS).contains(&steps);
        let last = self.last_body_dtheta;
        let mean = follows.then(|| {
            let n = steps as f64;
            let [w, i, j, k] = s.q;
            let turn = crate::math::rotvec_from_quat(&(Quaternion::new(w, i, j, k).conjugate() * q));
            // The interval's mean is the rate at its middle, (n − 1) / 2 samples before
            // this one: taken there from the mean before (its own middle, the same way),
            // and carried to now by the change per step.
            let mean = turn / n + Vector3::from(o.drift_rad_s) * self.profile.dt_s();
            let lag = (n - 1.0) / 2.0;
            let old_mean = Vector3::from(s.dtheta_rad) - Vector3::from(s.trend_rad) * lag;
            let trend = (mean - old_mean) / n;
            (mean + trend * lag, [trend.x, trend.y, trend.z])
        });
        // Within 1 µrad (ten times a sample's noise) plus a tenth of the increment; false
        // for a NaN.
        let plausible = |d: &Vector3<f64>| {
            (d - last).norm_squared() <= MEAN_TOLERANCE_RAD * MEAN_TOLERANCE_RAD + 0.01 * last.norm_squared()
        };
        let (d, trend) = mean.filter(|(d, _)| plausible(d)).unwrap_or((last, [0.0; 3]));
        // Written in place (the board's copy), field by field.
        s.magic = MAGIC;
        s.table_crc = self.table_crc;
        s.flags = map | if cleared { MOUNT_CLEARED } else { 0 };
        s.expected = u32::from(expected);
        s.updates = o.updates;
        s.reserved = 0;
        s.index = index;
        s.aligned_us = o.aligned_us;
        s.last_update_tag_us = o.last_update_tag_us;
        s.q = [q.w, q.i, q.j, q.k];
        s.last_q = o.last_q;
        s.drift_rad_s = o.drift_rad_s;
        s.dtheta_rad = [d.x, d.y, d.z];
        s.innov_ms_rad2 = o.innov_ms_rad2;
        s.cov = o.cov;
        s.trend_rad = trend;
        s.reserved_end = 0;
        self.save_survivors(&mut s.kept);
        s.seal();
        true
    }

    /// Resumes this core (just built at boot, on the table the snapshot names) from `s`:
    /// the attitude, the drift estimate, unit time, the alignment and the estimator; the
    /// frames report aligned from the first step. Refused, the core unchanged and
    /// `snapshot_invalid` logged, when a check fails ([`SnapshotError`]; not for
    /// [`SnapshotError::Absent`], a cold start); the age is checked at the first FOG
    /// sample.
    #[inline(never)]
    pub fn resume(&mut self, s: &Snapshot) -> Result<(), SnapshotError> {
        let r = self.check_snapshot(s);
        match r {
            Ok(()) => self.apply_snapshot(s),
            // A cold start has no snapshot: nothing to report.
            Err(SnapshotError::Absent) => {}
            Err(e) => self.snapshot_refused(e),
        }
        r
    }

    /// Resumes from the newer of the two copies that passes every check, the newer
    /// first ([`FlightCore::resume`] on each: a refused copy is logged, the core left
    /// unchanged); the newer copy's refusal when neither is resumed.
    #[inline(never)]
    pub fn resume_from(&mut self, s: &Snapshots) -> Result<(), SnapshotError> {
        let [newer, older] = s.newest_first();
        self.resume(newer).or_else(|e| self.resume(older).map_err(|_| e))
    }

    fn check_snapshot(&self, s: &Snapshot) -> Result<(), SnapshotError> {
        if s.magic != MAGIC {
            return Err(SnapshotError::Absent);
        }
        if !s.sealed() {
            return Err(SnapshotError::BadCrc);
        }
        if s.table_crc != self.table_crc {
            return Err(SnapshotError::OtherTable);
        }
        let norm2 = |v: &[f64; 4]| v.iter().map(|x| x * x).sum::<f64>();
        let drift2 = s.drift_rad_s.iter().map(|v| v * v).sum::<f64>();
        let f64s = [&s.q[..], &s.last_q, &s.drift_rad_s, &s.dtheta_rad, &[s.innov_ms_rad2], &s.cov, &s.trend_rad];
        let plausible = f64s.iter().all(|f| f.iter().all(|v| v.is_finite()))
            && (norm2(&s.q) - 1.0).abs() < 1e-6
            && (norm2(&s.last_q) - 1.0).abs() < 1e-6
            && drift2 <= MAX_DRIFT_RAD_S * MAX_DRIFT_RAD_S
            && s.flags & !MOUNT_CLEARED == IDENTITY_FLAGS;
        if plausible {
            Ok(())
        } else {
            Err(SnapshotError::Implausible)
        }
    }

    fn apply_snapshot(&mut self, s: &Snapshot) {
        let state = ResumeState {
            drift_rad_s: s.drift_rad_s,
            aligned_us: s.aligned_us,
            last_update_tag_us: s.last_update_tag_us,
            last_q: s.last_q,
            updates: s.updates,
            innov_ms_rad2: s.innov_ms_rad2,
            cov: s.cov,
        };
        if s.flags & MOUNT_CLEARED != 0 {
            self.mounting = crate::state::Maybe::none();
        }
        let [w, i, j, k] = s.q;
        self.attitude.set_quaternion(Quaternion::new(w, i, j, k));
        self.last_body_dtheta = Vector3::from(s.dtheta_rad);
        self.fog_intake.resume_clock(s.index, s.expected as u16);
        self.observer.resume(&state);
        let now_us = self.fog_intake.time_us(self.profile.dt_us);
        self.observer.record(now_us, self.attitude.quaternion());
        self.star_intake.used(now_us);
        self.resumed_at = crate::state::Maybe::some(s.index);
        self.resume_trend = s.trend_rad;
        self.load_survivors(&s.kept);
        // The guarded state changed between steps: saved again at the next check.
        self.guard_unseal();
    }

    fn snapshot_refused(&mut self, e: SnapshotError) {
        self.telemetry.counters.bump(Counter::SnapshotsInvalid);
        self.events.log(self.last_output.time_us, Event::SnapshotInvalid, e as u8, 0);
    }

    /// After a resume, at the end of a step that integrated a sample: at the first with
    /// FOG data, the age of the snapshot (the samples bridged over the reset). Too old,
    /// the estimate restarts and the next star-tracker frame aligns. A sample bridged
    /// while nothing came (the unit stepping on its own before the FOGs' frames return)
    /// does not confirm it: only a FOG counter tells the age.
    #[inline(never)]
    pub(super) fn confirm_resume(&mut self, taken_at: u64) {
        if self.fog_intake.bridged() {
            return;
        }
        self.guard_touch();
        self.twin_check_rare();
        self.resumed_at = crate::state::Maybe::none();
        let age = self.fog_intake.index().saturating_sub(taken_at);
        let now_us = self.fog_intake.time_us(self.profile.dt_us);
        if age > MAX_AGE_STEPS {
            self.resume_trend = [0.0; 3];
            self.observer.restart();
            self.telemetry.counters.bump(Counter::SnapshotsInvalid);
            self.events.log(now_us, Event::SnapshotInvalid, SnapshotError::TooOld as u8, 0);
        } else {
            // The samples bridged on the snapshot's last increment turned by that increment
            // plus k times its change per step: their sum, lost (lost + 1) / 2 times the
            // change, as a body rotation now (second order in the small angles).
            let lost = age.saturating_sub(1) as f64;
            let t = Vector3::from(core::mem::take(&mut self.resume_trend)) * (lost * (lost + 1.0) / 2.0);
            let q = self.attitude.quaternion() * crate::math::quat_from_rotvec(&t);
            self.attitude.set_quaternion(q);
            self.telemetry.counters.bump(Counter::Resumes);
            self.events.log(now_us, Event::Resumed, 0, age as u16);
        }
        self.twin_seal();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The check word is the CRC-32C of the bytes before it (the `crc` crate's, bytewise).
    #[test]
    fn check_word_is_crc32c_of_the_record() {
        let mut x = 0x9E37_79B9_7F4A_7C15u64;
        for round in 0..20 {
            let mut s = Snapshot::default();
            for b in s.bytes_mut().iter_mut() {
                x ^= x << 13;
                x ^= x >> 7;
                x ^= x << 17;
                *b = if round == 0 { 0 } else { x as u8 };
            }
            let n = core::mem::offset_of!(Snapshot, check);
            let want = crate::frames::CRC32C.checksum(&bytemuck::bytes_of(&s)[..n]);
            assert_eq!(s.checksum(), want, "round {round}");
            s.seal();
            assert!(s.sealed());
        }
    }

    /// Every error of up to three bits in the sealed bytes (the check word included) is
    /// found: the single-bit syndromes of the CRC (its register change for one flipped bit,
    /// linear in the flips) are all nonzero and distinct (distance ≥ 3), and no two of
    /// them XOR to a third (≥ 4).
    #[test]
    fn the_check_word_finds_every_error_of_up_to_three_bits() {
        let mut s = Snapshot::default();
        s.seal();
        let n = core::mem::offset_of!(Snapshot, check) + 4;
        let good = s;
        let syndrome = |byte: usize, bit: u32| {
            let mut t = good;
            t.bytes_mut()[byte] ^= 1 << bit;
            t.checksum() ^ t.check ^ good.checksum() ^ good.check
        };
        let syn: Vec<u32> = (0..n).flat_map(|b| (0..8).map(move |k| (b, k))).map(|(b, k)| syndrome(b, k)).collect();
        assert_eq!(syn.len(), 8 * n);
        let set: std::collections::HashSet<u32> = syn.iter().copied().collect();
        assert!(!set.contains(&0), "a single flip unseen");
        assert_eq!(set.len(), syn.len(), "two flips unseen");
        for (i, a) in syn.iter().enumerate() {
            for b in &syn[i + 1..] {
                assert!(!set.contains(&(a ^ b)), "three flips unseen");
            }
        }
    }
}
