//! The reset snapshot: what a reset (watchdog, HardFault) resumes from, so the unit does
//! not align again from nothing.
//!
//! [`FlightCore::snapshot`] writes the state that takes minutes to rebuild into a
//! [`Snapshot`] of plain 32-bit words, sealed with a check word (Fletcher's checksum
//! on the words, [`Snapshot::checksum`]): the attitude Λ, the drift
//! estimate Δω, unit time (the sample clock), the alignment and the estimator's
//! convergence and covariance, the FOG assignment, the last body increment and the CRC
//! of the table it was taken under. The board keeps it in RAM its reset does not clear
//! (`ssis-firmware`: the `.uninit` section) and, after a reset, hands it to
//! [`FlightCore::resume`], which resumes only a snapshot that passes every check
//! ([`SnapshotError`]): its check word, its format, the table in use, and plausibility (a unit
//! quaternion, finite values, a drift within [`MAX_DRIFT_RAD_S`]). Its age is checked at
//! the first FOG sample after the reset: the samples sent meanwhile are bridged on the
//! last increment, and a snapshot more than [`MAX_AGE_STEPS`] old is dropped (the
//! estimate restarts and the next star-tracker frame aligns, as at power-on). Logged:
//! `resumed` (with the age in steps) or `snapshot_invalid` (with the reason).
//!
//! Any bit pattern of the words is a value (no enum, no bool): a snapshot read back from
//! RAM that a reset, an upset or a cold start left in any state is judged by its checks
//! only. Not carried over: the MEKF's star-tracker LFE states (they restart unknown, at
//! their stationary covariance σ_c² I, ĉ = 0, uncorrelated with the rest), the attitude
//! history (frames tagged before the resume are refused as late), a FOG isolated by the
//! parity logic (isolated again if still faulty) and the mounting check (not run again
//! once it had cleared the unit); a unit flying two FOGs swapped is not resumed (it
//! aligns again and the check finds the swap again).

use nalgebra::{Quaternion, Vector3};

use super::FlightCore;
use crate::observer::ResumeState;
use crate::telemetry::events::Event;
use crate::telemetry::Counter;

/// Words of a [`Snapshot`].
pub const SNAPSHOT_WORDS: usize = 104;
/// First word: "SNP" and the layout version 1.
const MAGIC: u32 = u32::from_le_bytes(*b"SNP\x01");
/// Largest drift estimate a snapshot may carry, rad/s (1 °/s: far beyond any FOG's bias).
pub const MAX_DRIFT_RAD_S: f64 = 1.0 * core::f64::consts::PI / 180.0;
/// Oldest snapshot resumed, in steps (1 s at 5 ms): older, the bridge over the reset on
/// the last increment is not trusted.
pub const MAX_AGE_STEPS: u64 = 200;

// Word offsets.
const W_MAGIC: usize = 0;
const W_TABLE_CRC: usize = 1;
/// Bit 0: the mounting check had cleared the unit; bits 8..16: the FOG assignment.
const W_FLAGS: usize = 2;
const W_EXPECTED: usize = 3;
const W_UPDATES: usize = 4;
const W_INDEX: usize = 6;
const W_ALIGNED_US: usize = 8;
const W_TAG_US: usize = 10;
const W_F64: usize = 12;
/// f64 fields from [`W_F64`]: q (4), last_q (4), drift (3), last increment (3), mean
/// square mismatch (1), covariance (27), the increment's change per step (3).
const N_F64: usize = 45;
/// Index of the increment's change per step among the f64 fields.
const F_TREND: usize = 42;
/// How far the interval's mean increment may be from the last sample, beyond a tenth of
/// the increment, before the last sample is bridged on instead, rad.
const MEAN_TOLERANCE_RAD: f64 = 1e-6;
const W_CHECK: usize = SNAPSHOT_WORDS - 1;
const _: () = assert!(W_F64 + 2 * N_F64 <= W_CHECK);

const MOUNT_CLEARED: u32 = 1;
/// [`W_FLAGS`] of the identity FOG assignment (channel k on axis k, bits 8 + 2k).
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

/// The snapshot: [`SNAPSHOT_WORDS`] plain words, the last one the check word of the
/// others ([`Snapshot::checksum`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(C)]
pub struct Snapshot {
    /// The words (layout private to this module).
    pub words: [u32; SNAPSHOT_WORDS],
}

impl Default for Snapshot {
    fn default() -> Self {
        Snapshot { words: [0; SNAPSHOT_WORDS] }
    }
}

impl Snapshot {
    fn u64_at(&self, w: usize) -> u64 {
        let lo = self.words.get(w).copied().unwrap_or(0);
        let hi = self.words.get(w + 1).copied().unwrap_or(0);
        u64::from(lo) | u64::from(hi) << 32
    }

    fn set_u64(&mut self, w: usize, v: u64) {
        if let Some([lo, hi]) = self.words.get_mut(w..w + 2).and_then(|s| <&mut [u32; 2]>::try_from(s).ok()) {
            *lo = v as u32;
            *hi = (v >> 32) as u32;
        }
    }

    fn f64s(&self) -> [f64; N_F64] {
        core::array::from_fn(|k| f64::from_bits(self.u64_at(W_F64 + 2 * k)))
    }

    fn word(&self, w: usize) -> u32 {
        self.words.get(w).copied().unwrap_or(0)
    }

    fn set_word(&mut self, w: usize, v: u32) {
        if let Some(x) = self.words.get_mut(w) {
            *x = v;
        }
    }

    /// The check word of every word but the last: Fletcher's checksum on 32-bit words
    /// (a = Σ wᵢ, b = Σ a, both modulo 2³² − 1), folded to 32 bits. A flip of any one
    /// bit, or of any burst within one word, always changes it; any change of two words
    /// unless a and b both cancel. About 4 instructions a word, where a bytewise CRC-32
    /// costs some 30: the snapshot is rewritten every few tens of steps within the
    /// step's budget. The sums are reduced once, at the end: over the 103 words a < 2³⁹ and
    /// b < 2⁴⁶, far from overflowing 64 bits.
    pub fn checksum(&self) -> u32 {
        const _: () = assert!(W_CHECK < 1 << 16, "a and b stay below 2⁴⁸ and 2⁶⁴");
        let (mut a, mut b) = (0u64, 0u64);
        for w in self.words.iter().take(W_CHECK) {
            a += u64::from(*w);
            b += a;
        }
        let (a, b) = (mod_m(a), mod_m(b));
        (a ^ b.rotate_left(16) ^ (b >> 16)) as u32 ^ MAGIC
    }

    /// Whether its check word matches (the first check of [`FlightCore::resume`]).
    pub fn sealed(&self) -> bool {
        self.word(W_CHECK) == self.checksum()
    }

    /// Writes the check word (the last step of [`FlightCore::snapshot_into`]).
    pub fn seal(&mut self) {
        let c = self.checksum();
        self.set_word(W_CHECK, c);
    }

    /// Unit time it was taken at, in samples (the sample clock's index).
    pub fn index(&self) -> u64 {
        self.u64_at(W_INDEX)
    }

    /// Spoils the check word (the board after resuming: the same snapshot is not resumed twice).
    pub fn invalidate(&mut self) {
        let c = self.word(W_CHECK);
        self.set_word(W_CHECK, !c);
    }
}

/// `x` modulo 2³² − 1 by folding (2³² ≡ 1), without a 64-bit division.
fn mod_m(x: u64) -> u64 {
    const M: u64 = 0xFFFF_FFFF;
    let x = (x & M) + (x >> 32);
    let x = (x & M) + (x >> 32);
    if x >= M {
        x - M
    } else {
        x
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
        // before (its attitude, fields 0..3, turned to this one over `steps` samples, with
        // the drift estimate added back), not the last sample alone, whose noise a bridge
        // of 40–60 steps multiplies (one sample: up to 6″ at the first frame after the
        // reset). With its change per step (the turn's angular acceleration, from the
        // snapshot before's increment and change, fields 11..13 and F_TREND..) it
        // corrects the bridge. A mean far from the last sample (the snapshot before
        // corrupted, or a turn faster than the interval resolves) is not used: the last
        // sample is, with no change per step.
        let old = |k: usize| f64::from_bits(s.u64_at(W_F64 + 2 * k));
        let old_magic = s.word(W_MAGIC);
        let steps = index.wrapping_sub(s.index());
        let follows = old_magic == MAGIC && (1..=4 * MAX_AGE_STEPS).contains(&steps);
        let last = self.last_body_dtheta;
        let mean = follows.then(|| {
            let n = steps as f64;
            let turn =
                crate::math::rotvec_from_quat(&(Quaternion::new(old(0), old(1), old(2), old(3)).conjugate() * q));
            // The interval's mean is the rate at its middle, (n − 1) / 2 samples before
            // this one: taken there from the mean before (its own middle, the same way),
            // and carried to now by the change per step.
            let mean = turn / n + Vector3::from(o.drift_rad_s) * self.profile.dt_s();
            let lag = (n - 1.0) / 2.0;
            let old_mean = Vector3::from_fn(|i, _| old(11 + i) - old(F_TREND + i) * lag);
            let trend = (mean - old_mean) / n;
            (mean + trend * lag, [trend.x, trend.y, trend.z])
        });
        // Within 1 µrad (ten times a sample's noise) plus a tenth of the increment; false
        // for a NaN.
        let plausible = |d: &Vector3<f64>| {
            (d - last).norm_squared() <= MEAN_TOLERANCE_RAD * MEAN_TOLERANCE_RAD + 0.01 * last.norm_squared()
        };
        let (d, trend) = mean.filter(|(d, _)| plausible(d)).unwrap_or((last, [0.0; 3]));
        s.set_word(W_MAGIC, MAGIC);
        s.set_word(W_TABLE_CRC, self.table_crc);
        s.set_word(W_FLAGS, map | if cleared { MOUNT_CLEARED } else { 0 });
        s.set_word(W_EXPECTED, u32::from(expected));
        s.set_word(W_UPDATES, o.updates);
        s.set_u64(W_INDEX, index);
        s.set_u64(W_ALIGNED_US, o.aligned_us);
        s.set_u64(W_TAG_US, o.last_update_tag_us);
        let [dx, dy, dz] = o.drift_rad_s;
        let head = [q.w, q.i, q.j, q.k, o.last_q[0], o.last_q[1], o.last_q[2], o.last_q[3], dx, dy, dz, d.x, d.y, d.z];
        let values = head.iter().chain(core::iter::once(&o.innov_ms_rad2)).chain(o.cov.iter()).chain(trend.iter());
        // The f64 fields as word pairs, low word first (as `set_u64`), in one pass.
        if let Some(slots) = s.words.get_mut(W_F64..W_F64 + 2 * N_F64) {
            for ([lo, hi], v) in slots.as_chunks_mut::<2>().0.iter_mut().zip(values) {
                let b = v.to_bits();
                (*lo, *hi) = (b as u32, (b >> 32) as u32);
            }
        }
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

    fn check_snapshot(&self, s: &Snapshot) -> Result<(), SnapshotError> {
        if s.word(W_MAGIC) != MAGIC {
            return Err(SnapshotError::Absent);
        }
        if !s.sealed() {
            return Err(SnapshotError::BadCrc);
        }
        if s.word(W_TABLE_CRC) != self.table_crc {
            return Err(SnapshotError::OtherTable);
        }
        let f = s.f64s();
        let norm2 = |k: usize| f.iter().skip(k).take(4).map(|v| v * v).sum::<f64>();
        let drift2 = f.iter().skip(8).take(3).map(|v| v * v).sum::<f64>();
        let plausible = f.iter().all(|v| v.is_finite())
            && (norm2(0) - 1.0).abs() < 1e-6
            && (norm2(4) - 1.0).abs() < 1e-6
            && drift2 <= MAX_DRIFT_RAD_S * MAX_DRIFT_RAD_S
            && s.word(W_FLAGS) & !MOUNT_CLEARED == IDENTITY_FLAGS;
        if plausible {
            Ok(())
        } else {
            Err(SnapshotError::Implausible)
        }
    }

    fn apply_snapshot(&mut self, s: &Snapshot) {
        let f = s.f64s();
        let v = |k: usize| f.get(k).copied().unwrap_or(0.0);
        let mut cov = [0.0; 27];
        for (c, x) in cov.iter_mut().zip(f.iter().skip(15)) {
            *c = *x;
        }
        let state = ResumeState {
            drift_rad_s: [v(8), v(9), v(10)],
            aligned_us: s.u64_at(W_ALIGNED_US),
            last_update_tag_us: s.u64_at(W_TAG_US),
            last_q: [v(4), v(5), v(6), v(7)],
            updates: s.word(W_UPDATES),
            innov_ms_rad2: v(14),
            cov,
        };
        if s.word(W_FLAGS) & MOUNT_CLEARED != 0 {
            self.mounting = crate::state::Maybe::none();
        }
        self.attitude.set_quaternion(Quaternion::new(v(0), v(1), v(2), v(3)));
        self.last_body_dtheta = Vector3::new(v(11), v(12), v(13));
        let index = s.index();
        self.fog_intake.resume_clock(index, s.word(W_EXPECTED) as u16);
        self.observer.resume(&state);
        let now_us = self.fog_intake.time_us(self.profile.dt_us);
        self.observer.record(now_us, self.attitude.quaternion());
        self.star_intake.used(now_us);
        self.resumed_at = crate::state::Maybe::some(index);
        self.resume_trend = [v(F_TREND), v(F_TREND + 1), v(F_TREND + 2)];
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
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The check word is Fletcher's checksum with both sums kept modulo 2³² − 1 after
    /// every word: the sums reduced once at the end give the same word.
    #[test]
    fn checksum_is_fletcher_modulo_2_32_minus_1() {
        const M: u64 = 0xFFFF_FFFF;
        let mut x = 0x9E37_79B9_7F4A_7C15u64;
        for fill in [0u32, u32::MAX, 0x8000_0001] {
            for round in 0..50 {
                let mut s = Snapshot::default();
                for w in s.words.iter_mut() {
                    x ^= x << 13;
                    x ^= x >> 7;
                    x ^= x << 17;
                    *w = if round % 2 == 0 { fill } else { x as u32 };
                }
                let (mut a, mut b) = (0u64, 0u64);
                for w in s.words.iter().take(W_CHECK) {
                    a = (a + u64::from(*w)) % M;
                    b = (b + a) % M;
                }
                let want = (a ^ b.rotate_left(16) ^ (b >> 16)) as u32 ^ MAGIC;
                assert_eq!(s.checksum(), want, "fill {fill:#x} round {round}");
            }
        }
    }
}
