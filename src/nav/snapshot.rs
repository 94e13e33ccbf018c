//! The navigation's reset snapshot: what a reset of the launch-vehicle unit (watchdog,
//! HardFault) resumes the navigation from mid-ascent, where the pad initialisation
//! ([`super::init`]) is no longer the vehicle's state.
//!
//! [`NavUnit::snapshot_into`] writes a [`NavSnapshot`], a `#[repr(C, packed)]`
//! plain-old-data record (any bit pattern is a value: it is judged by its checks only),
//! beside the flight core's own snapshot in RAM the reset does not clear: a header (the
//! accelerometer sample counter of its last step and a digest of the step period and
//! filter tuning it was taken under) and the fields the stage's declaration marks
//! `reset(Keep)` ([`NavKept`], derived from the declarations of [`NavUnit`],
//! [`AidedNav`] and [`super::Strapdown`]: the navigation state (q_eb, v_e, r_e), the
//! strapdown's increment history and step count, the filter's covariance, bias
//! estimates, pending propagation and counts, the running means and spreads of the
//! increments ([`super::unit::MEAN_STEPS`]) and the output frame counter); sealed with
//! CRC-32C (the `crc` crate's, [`crate::frames::CRC32C`]) and its complement. A field
//! marked there is carried over a reset with no other change here.
//!
//! **Writing** ([`NavUnit::snapshot_into`]): the complement is spoiled first, then the
//! fields are written, then the CRC, then its complement, with compiler fences between
//! the three phases; a reset anywhere in the write leaves a record whose two check words
//! disagree, refused.
//!
//! **Resuming** ([`NavUnit::resume`], on a unit just built from the pad block): refused
//! ([`NavResumeError`]) unless the magic and length are this layout's, the CRC and its
//! complement match, the step period and filter tuning are the unit's, and every value
//! is plausible: finite, ‖q_eb‖ within 1e-6 of 1, the position between
//! [`super::wgs84::MIN_RADIUS_M`] and [`MAX_RADIUS_M`], the speed below
//! [`MAX_SPEED_M_S`], the covariance's diagonal ≥ 0, the bias estimates and the mean
//! increments within the sensors' ranges. Accepted, the unit takes the snapshot's state
//! and holds it until its first step that takes an accelerometer frame; there the
//! frame's counter tells the samples lost since the snapshot (its age: up to one
//! snapshot period plus the time the unit was down), and
//!
//! - up to [`MAX_BRIDGE_STEPS`]: the unit **bridges** them, one strapdown step per lost
//!   sample on the snapshot's mean increments (constant body rate and specific force),
//!   and adds the bridge's own error growth to the covariance: the increments' spread
//!   about their mean as a random walk over the lost steps
//!   (σ_v² = n s_υ²/3 per axis, σ_r² = n³ Δt² s_υ²/9, cov = n² Δt s_υ²/6,
//!   σ_φ² = n s_α²/3), so the frames' σ and the next GNSS fix's weight cover it;
//! - more (a snapshot the unit cannot bridge, **stale**): the navigation is lost.
//!
//! **The rule after a reset**: no snapshot (wrong magic: a power-on, whose RAM holds
//! nothing of a flight) keeps the pad initialisation the unit was built from (the
//! vehicle is on the pad); a snapshot that is there but refused, or stale at its first
//! sample, leaves the navigation **lost**: the state held, [`flags::NAV_FAULT`] in every
//! output frame, no fix used, until the ground equipment loads a pad initialisation
//! again (a new [`NavUnit`]). The unit never resumes from a record it cannot check.
//! Not carried over: the link decoders and queues (the rings start empty after the
//! reset), a fix held for the filter work (the next one, 1 s later, is used) and the
//! time of the last fix used (the frames show [`flags::GNSS_OUTAGE`] until the next
//! fix); the output frame counter goes on past the lost samples.
//!
//! [`flags::NAV_FAULT`]: crate::frames::navout::flags::NAV_FAULT
//! [`flags::GNSS_OUTAGE`]: crate::frames::navout::flags::GNSS_OUTAGE

use core::sync::atomic::{compiler_fence, Ordering};

use bytemuck::{Pod, Zeroable};

use super::gnss::AidedNav;
use super::unit::{BridgeReport, NavKept, NavUnit};
use super::{wgs84, NavState};
use crate::frames::CRC32C;
use crate::state::{Flag, Maybe};

/// First word: "NSN" and the layout version 2.
const MAGIC: u32 = u32::from_le_bytes(*b"NSN\x02");
/// Most samples a resume bridges (0.5 s at 1.25 ms): the snapshot period (80 steps in
/// the firmware) plus a reset and boot, with margin; older, the snapshot is stale.
pub const MAX_BRIDGE_STEPS: u16 = 400;
/// Largest position radius a snapshot may carry, m (twice the Earth's: an ascent stays
/// far below).
pub const MAX_RADIUS_M: f64 = 2.0 * wgs84::EQUATORIAL_RADIUS_M;
/// Largest speed relative to the Earth a snapshot may carry, m/s.
pub const MAX_SPEED_M_S: f64 = 15_000.0;
/// Largest accelerometer bias estimate, m/s² (10 000 µg: far beyond a calibrated
/// pendulous accelerometer).
pub const MAX_ACCEL_BIAS_M_S2: f64 = 0.1;
/// Largest gyro bias estimate, rad/s (1 °/s).
pub const MAX_GYRO_BIAS_RAD_S: f64 = core::f64::consts::PI / 180.0;
/// Largest mean specific force, m/s² (the AK-30's ±85 m/s² on each of three axes).
pub const MAX_SPECIFIC_FORCE_M_S2: f64 = 150.0;
/// Largest mean body rate, rad/s (the launch vehicle's ±100 °/s on each of three axes).
pub const MAX_RATE_RAD_S: f64 = 175.0 * core::f64::consts::PI / 180.0;

/// Why a snapshot was not resumed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub enum NavResumeError {
    /// No snapshot: wrong magic or length (a power-on; the pad initialisation stands).
    Absent,
    /// Its CRC or the CRC's complement does not match: corrupted, or torn by a reset
    /// during its write.
    BadCrc,
    /// Taken under another step period or filter tuning.
    OtherSetup,
    /// A value is not plausible (module documentation).
    Implausible,
}

/// The navigation's reset snapshot (module documentation). Plain old data: any bit
/// pattern is a value. Packed: the kept fields' record ([`NavKept`]) is, and the check
/// words follow it.
#[derive(Debug, Clone, Copy, Pod, Zeroable)]
#[repr(C, packed)]
pub struct NavSnapshot {
    magic: u32,
    /// `size_of::<NavSnapshot>()`.
    len: u32,
    /// The accelerometer sample counter of the last step (u16): what a resume bridges
    /// from.
    accel_counter: u32,
    /// CRC-32C of the step period and the filter tuning.
    setup_crc: u32,
    /// The fields the unit's declaration keeps over a reset ([`NavUnit`]'s `reset`
    /// marks), down to the filter and the strapdown.
    kept: NavKept,
    /// CRC-32C of every byte before it.
    check: u32,
    /// `!check`.
    check_inv: u32,
}

impl Default for NavSnapshot {
    fn default() -> Self {
        NavSnapshot::zeroed()
    }
}

impl PartialEq for NavSnapshot {
    /// Bit for bit.
    fn eq(&self, other: &Self) -> bool {
        bytemuck::bytes_of(self) == bytemuck::bytes_of(other)
    }
}

/// Bytes the CRC covers: all before `check`.
const COVERED: usize = core::mem::offset_of!(NavSnapshot, check);

fn finite(v: &[f64]) -> bool {
    v.iter().all(|x| x.is_finite())
}

fn sq(x: f64) -> f64 {
    x * x
}

fn norm2(v: &[f64]) -> f64 {
    v.iter().map(|x| x * x).sum()
}

impl NavSnapshot {
    /// CRC-32C of the covered bytes.
    fn crc(&self) -> u32 {
        CRC32C.checksum(bytemuck::bytes_of(self).get(..COVERED).unwrap_or(&[]))
    }

    /// Whether both check words match.
    pub fn sealed(&self) -> bool {
        let c = self.crc();
        self.check == c && self.check_inv == !c
    }

    /// Spoils the check words (the board after resuming: the same snapshot is not
    /// resumed twice; it is rewritten within a snapshot period once the unit navigates).
    pub fn invalidate(&mut self) {
        self.check_inv = self.check;
    }

    /// Its bytes (as the board's RAM holds them).
    pub fn as_bytes(&self) -> &[u8] {
        bytemuck::bytes_of(self)
    }

    /// Its bytes, mutable.
    pub fn as_bytes_mut(&mut self) -> &mut [u8] {
        bytemuck::bytes_of_mut(self)
    }

    /// A record from `bytes` (any content; `None` for a wrong length).
    pub fn from_bytes(bytes: &[u8]) -> Option<Self> {
        bytemuck::try_pod_read_unaligned(bytes).ok()
    }

    /// The record that starts `words` (a board's RAM the reset does not clear, as words):
    /// `None` when the words are too few.
    pub fn in_words(words: &mut [u32]) -> Option<&mut Self> {
        let bytes: &mut [u8] = bytemuck::cast_slice_mut(words);
        bytemuck::try_from_bytes_mut(bytes.get_mut(..core::mem::size_of::<Self>())?).ok()
    }

    /// The accelerometer sample counter of the step it was taken after.
    pub fn accel_counter(&self) -> u16 {
        self.accel_counter as u16
    }

    /// The navigation state it holds (unchecked).
    pub fn state(&self) -> NavState {
        self.kept.nav.nav.state
    }
}

impl AidedNav {
    /// CRC-32C of the step period and the filter tuning.
    fn setup_crc(&self) -> u32 {
        let c = &self.cfg;
        let mut d = CRC32C.digest();
        let fields = [
            self.nav.dt_s(),
            c.init_att_rad,
            c.init_vel_m_s,
            c.init_pos_m,
            c.init_accel_bias_m_s2,
            c.init_gyro_bias_rad_s,
            c.arw_rad_sqrt_s,
            c.vrw_m_s_sqrt_s,
            c.accel_bias_rw_m_s2_sqrt_s,
            c.gyro_bias_rw_rad_s_sqrt_s,
            c.gate_sigma,
        ];
        for f in fields {
            d.update(&f.to_le_bytes());
        }
        d.finalize()
    }

    /// Adds a bridge's error growth over `n` steps with per-step increment spreads
    /// `s_dtheta_rad2` and `s_dv_m2_s2` (3-D mean squares) to the covariance: a random
    /// walk of the velocity (and so of the position) and of the attitude (module
    /// documentation).
    fn add_bridge_growth(&mut self, n: u16, s_dtheta_rad2: f64, s_dv_m2_s2: f64) -> BridgeReport {
        let steps = u32::from(n);
        let n = f64::from(n);
        let dt = self.nav.dt_s();
        let (qa, qv) = (s_dtheta_rad2 / 3.0, s_dv_m2_s2 / 3.0);
        for i in 0..3 {
            let add = |p: &mut Self, r: usize, c: usize, v: f64| {
                if let Some(x) = p.p.get_mut((r, c)) {
                    *x += v;
                }
            };
            add(self, i, i, n * qa);
            add(self, 3 + i, 3 + i, n * qv);
            add(self, 6 + i, 6 + i, n * n * n * dt * dt * qv / 3.0);
            add(self, 3 + i, 6 + i, n * n * dt * qv / 2.0);
            add(self, 6 + i, 3 + i, n * n * dt * qv / 2.0);
        }
        BridgeReport {
            steps,
            sigma_pos_m: crate::math::sqrt(n * n * n * dt * dt * s_dv_m2_s2 / 3.0),
            sigma_vel_m_s: crate::math::sqrt(n * s_dv_m2_s2),
        }
    }
}

impl NavUnit {
    /// Writes the snapshot of the navigation now into `s` in place, sealed (the board's
    /// record in RAM a reset does not clear; module documentation for the write order).
    /// Returns false, leaving `s` as it was, when there is nothing a reset could resume:
    /// the navigation lost, a resume not yet bridged, or no accelerometer sample yet.
    #[inline(never)]
    pub fn snapshot_into(&self, s: &mut NavSnapshot) -> bool {
        let Some(counter) = self.accel_counter.get() else { return false };
        if self.lost.get() || self.resume_from.is_some() {
            return false;
        }
        // Spoiled first: a reset during the write leaves the check words disagreeing.
        s.check_inv = s.check;
        compiler_fence(Ordering::SeqCst);
        s.magic = MAGIC;
        s.len = core::mem::size_of::<NavSnapshot>() as u32;
        s.accel_counter = u32::from(counter);
        s.setup_crc = self.nav.setup_crc();
        self.save_survivors(&mut s.kept);
        compiler_fence(Ordering::SeqCst);
        let c = s.crc();
        s.check = c;
        compiler_fence(Ordering::SeqCst);
        s.check_inv = !c;
        true
    }

    /// Resumes this unit (just built at boot from the pad block) from `s` (module
    /// documentation): the state is taken now and the samples lost over the reset are
    /// bridged at the first step that takes an accelerometer frame. Refused: with
    /// [`NavResumeError::Absent`] the unit is left as built (a power-on on the pad); with
    /// any other error the navigation is lost ([`NavUnit::lost`]).
    #[inline(never)]
    pub fn resume(&mut self, s: &NavSnapshot) -> Result<(), NavResumeError> {
        let r = self.check_snapshot(s);
        match r {
            Ok(()) => self.apply_snapshot(s),
            Err(NavResumeError::Absent) => {}
            Err(_) => self.lost = Flag::SET,
        }
        r
    }

    fn check_snapshot(&self, s: &NavSnapshot) -> Result<(), NavResumeError> {
        if s.magic != MAGIC || s.len as usize != core::mem::size_of::<NavSnapshot>() {
            return Err(NavResumeError::Absent);
        }
        if !s.sealed() {
            return Err(NavResumeError::BadCrc);
        }
        if s.setup_crc != self.nav.setup_crc() {
            return Err(NavResumeError::OtherSetup);
        }
        let dt = self.nav.nav.dt_s();
        let k = &s.kept;
        let (a, sd) = (k.nav, k.nav.nav);
        let st = sd.state;
        let q = [st.q_eb.w, st.q_eb.i, st.q_eb.j, st.q_eb.k];
        let (v, r) = (st.v_e_m_s, st.r_e_m);
        let (mean_dv, last_dv, mean_dtheta) = (k.mean_dv_m_s, k.last_dv_m_s, k.mean_dtheta_rad);
        let (spread_dtheta, spread_dv) = (k.spread_dtheta_rad2, k.spread_dv_m2_s2);
        let (prev_dtheta, prev_dv) = (sd.prev_dtheta_rad, sd.prev_dv_m_s);
        let (accel_bias, gyro_bias, sum_dv, p) = (a.accel_bias_m_s2, a.gyro_bias_rad_s, a.sum_dv_e_m_s, a.p);
        let vectors =
            [&v, &r, &prev_dtheta, &prev_dv, &accel_bias, &gyro_bias, &sum_dv, &last_dv, &mean_dtheta, &mean_dv];
        let plausible = finite(&q)
            && vectors.iter().all(|x| finite(x.as_slice()))
            && finite(&[spread_dtheta, spread_dv])
            && finite(p.as_slice())
            && s.accel_counter <= u32::from(u16::MAX)
            && (norm2(&q) - 1.0).abs() < 1e-6
            && (sq(wgs84::MIN_RADIUS_M)..=sq(MAX_RADIUS_M)).contains(&r.norm_squared())
            && v.norm_squared() <= MAX_SPEED_M_S * MAX_SPEED_M_S
            && accel_bias.norm_squared() <= MAX_ACCEL_BIAS_M_S2 * MAX_ACCEL_BIAS_M_S2
            && gyro_bias.norm_squared() <= MAX_GYRO_BIAS_RAD_S * MAX_GYRO_BIAS_RAD_S
            && [mean_dv, prev_dv, last_dv].iter().all(|x| x.norm_squared() <= sq(MAX_SPECIFIC_FORCE_M_S2 * dt))
            && [mean_dtheta, prev_dtheta].iter().all(|x| x.norm_squared() <= sq(MAX_RATE_RAD_S * dt))
            && spread_dtheta >= 0.0
            && spread_dv >= 0.0
            && p.diagonal().iter().all(|d| *d >= 0.0);
        if plausible {
            Ok(())
        } else {
            Err(NavResumeError::Implausible)
        }
    }

    fn apply_snapshot(&mut self, s: &NavSnapshot) {
        self.load_survivors(&s.kept);
        // The state again through the strapdown's own check (it normalises the
        // quaternion and rebuilds the gravity term); checked plausible above, a state it
        // refuses all the same is lost.
        if self.nav.nav.set_state(s.state()).is_err() {
            self.lost = Flag::SET;
            return;
        }
        self.accel_counter = Maybe::none();
        self.resume_from = Maybe::some(s.accel_counter());
        self.resume_wait = 0;
        self.bridged = Maybe::none();
        self.lost = Flag::CLEAR;
    }

    /// At each step while a resume waits ([`NavUnit::resume`]): with this step's
    /// accelerometer counter, bridges the samples lost since the snapshot (or finds it
    /// stale: lost); without one, waits (stale after [`MAX_BRIDGE_STEPS`] steps).
    /// Whether the navigation steps now.
    pub(super) fn settle_resume(&mut self, counter: Option<u16>) -> bool {
        let Some(c0) = self.resume_from.get() else { return !self.lost.get() };
        let Some(c) = counter else {
            self.resume_wait = self.resume_wait.saturating_add(1);
            if self.resume_wait > u32::from(MAX_BRIDGE_STEPS) {
                self.resume_from = Maybe::none();
                self.lost = Flag::SET;
            }
            return false;
        };
        self.resume_from = Maybe::none();
        // This step's sample is c; the snapshot's step took c0: c − c0 − 1 were lost.
        let lost = c.wrapping_sub(c0).wrapping_sub(1);
        if lost > MAX_BRIDGE_STEPS {
            self.lost = Flag::SET;
            return false;
        }
        let (dtheta, dv) = (self.mean_dtheta_rad, self.mean_dv_m_s);
        // Bounded: at most MAX_BRIDGE_STEPS strapdown steps.
        for _ in 0..lost {
            if self.nav.step_deferred(&dtheta, &dv).is_err() {
                self.lost = Flag::SET;
                return false;
            }
        }
        let report = self.nav.add_bridge_growth(lost, self.spread_dtheta_rad2, self.spread_dv_m2_s2);
        self.last_dv_m_s = dv;
        self.out_counter = self.out_counter.wrapping_add(lost);
        self.bridged = Maybe::some(report);
        true
    }
}
