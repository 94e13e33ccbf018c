//! The navigation's reset snapshot: what a reset of the launch-vehicle unit (watchdog,
//! HardFault) resumes the navigation from mid-ascent, where the pad initialisation
//! ([`super::init`]) is no longer the vehicle's state.
//!
//! [`NavUnit::snapshot_into`] writes a [`NavSnapshot`], a `#[repr(C)]` plain-old-data
//! record (any bit pattern is a value: it is judged by its checks only), beside the
//! flight core's own snapshot in RAM the reset does not clear: the navigation state
//! (q_eb, v_e, r_e), the filter (its covariance's upper triangle, the bias estimates,
//! the pending propagation, its counts), the strapdown's increment history, the running
//! means and spreads of the increments ([`super::unit::MEAN_STEPS`]), the accelerometer
//! sample counter of its last step and a digest of the step period and filter tuning it
//! was taken under; sealed with CRC-32C (the `crc` crate's, [`crate::frames::CRC32C`])
//! and its complement.
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
use nalgebra::{Quaternion, Vector3};

use super::gnss::{AidedNav, N_X};
use super::unit::{BridgeReport, NavUnit};
use super::{wgs84, NavState};
use crate::frames::CRC32C;
use crate::state::{Flag, Maybe};

/// First word: "NSN" and the layout version 1.
const MAGIC: u32 = u32::from_le_bytes(*b"NSN\x01");
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
/// Elements of the covariance's upper triangle.
const N_P: usize = N_X * (N_X + 1) / 2;

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
/// pattern is a value.
#[derive(Debug, Clone, Copy, PartialEq, Pod, Zeroable)]
#[repr(C)]
pub struct NavSnapshot {
    magic: u32,
    /// `size_of::<NavSnapshot>()`.
    len: u32,
    /// The accelerometer sample counter of the last step (u16).
    accel_counter: u32,
    /// The output frame counter (u16).
    out_counter: u32,
    updates: u32,
    refused: u32,
    pending_steps: u32,
    /// CRC-32C of the step period and the filter tuning.
    setup_crc: u32,
    steps: u64,
    q_eb: [f64; 4],
    v_e_m_s: [f64; 3],
    r_e_m: [f64; 3],
    prev_dtheta_rad: [f64; 3],
    prev_dv_m_s: [f64; 3],
    accel_bias_m_s2: [f64; 3],
    gyro_bias_rad_s: [f64; 3],
    sum_dv_e_m_s: [f64; 3],
    last_dv_m_s: [f64; 3],
    mean_dtheta_rad: [f64; 3],
    mean_dv_m_s: [f64; 3],
    spread_dtheta_rad2: f64,
    spread_dv_m2_s2: f64,
    /// The covariance's upper triangle, row by row.
    p_upper: [f64; N_P],
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

/// Bytes the CRC covers: all before `check`.
const COVERED: usize = core::mem::offset_of!(NavSnapshot, check);

fn arr3(v: &Vector3<f64>) -> [f64; 3] {
    [v.x, v.y, v.z]
}

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
    /// `None` when the words are too few or not aligned for it.
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
        let [w, i, j, k] = self.q_eb;
        NavState {
            q_eb: Quaternion::new(w, i, j, k),
            v_e_m_s: Vector3::from(self.v_e_m_s),
            r_e_m: Vector3::from(self.r_e_m),
        }
    }

    /// Every f64 of the record.
    fn f64s(&self) -> impl Iterator<Item = &f64> {
        self.q_eb
            .iter()
            .chain(&self.v_e_m_s)
            .chain(&self.r_e_m)
            .chain(&self.prev_dtheta_rad)
            .chain(&self.prev_dv_m_s)
            .chain(&self.accel_bias_m_s2)
            .chain(&self.gyro_bias_rad_s)
            .chain(&self.sum_dv_e_m_s)
            .chain(&self.last_dv_m_s)
            .chain(&self.mean_dtheta_rad)
            .chain(&self.mean_dv_m_s)
            .chain([&self.spread_dtheta_rad2, &self.spread_dv_m2_s2])
            .chain(&self.p_upper)
    }
}

/// The covariance's upper-triangle element k as (row, column).
fn upper(k: usize) -> impl Iterator<Item = (usize, usize)> {
    (0..N_X).flat_map(|i| (i..N_X).map(move |j| (i, j))).skip(k)
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
        let a = &self.nav;
        let st = a.state();
        let (prev_dtheta, prev_dv) = a.nav.history();
        s.magic = MAGIC;
        s.len = core::mem::size_of::<NavSnapshot>() as u32;
        s.accel_counter = u32::from(counter);
        s.out_counter = u32::from(self.out_counter);
        s.updates = a.updates;
        s.refused = a.refused;
        s.pending_steps = a.pending_steps;
        s.setup_crc = a.setup_crc();
        s.steps = a.nav.steps();
        s.q_eb = [st.q_eb.w, st.q_eb.i, st.q_eb.j, st.q_eb.k];
        s.v_e_m_s = arr3(&st.v_e_m_s);
        s.r_e_m = arr3(&st.r_e_m);
        s.prev_dtheta_rad = arr3(&prev_dtheta);
        s.prev_dv_m_s = arr3(&prev_dv);
        s.accel_bias_m_s2 = arr3(&a.accel_bias_m_s2);
        s.gyro_bias_rad_s = arr3(&a.gyro_bias_rad_s);
        s.sum_dv_e_m_s = arr3(&a.sum_dv_e_m_s);
        s.last_dv_m_s = arr3(&self.last_dv_m_s);
        s.mean_dtheta_rad = arr3(&self.mean_dtheta_rad);
        s.mean_dv_m_s = arr3(&self.mean_dv_m_s);
        s.spread_dtheta_rad2 = self.spread_dtheta_rad2;
        s.spread_dv_m2_s2 = self.spread_dv_m2_s2;
        for (slot, (i, j)) in s.p_upper.iter_mut().zip(upper(0)) {
            *slot = a.p.get((i, j)).copied().unwrap_or(0.0);
        }
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
        let r2 = norm2(&s.r_e_m);
        let diagonal_ok = upper(0).zip(&s.p_upper).filter(|((i, j), _)| i == j).all(|(_, v)| *v >= 0.0);
        let plausible = s.f64s().all(|v| v.is_finite())
            && s.accel_counter <= u32::from(u16::MAX)
            && s.out_counter <= u32::from(u16::MAX)
            && (norm2(&s.q_eb) - 1.0).abs() < 1e-6
            && (sq(wgs84::MIN_RADIUS_M)..=sq(MAX_RADIUS_M)).contains(&r2)
            && norm2(&s.v_e_m_s) <= MAX_SPEED_M_S * MAX_SPEED_M_S
            && norm2(&s.accel_bias_m_s2) <= MAX_ACCEL_BIAS_M_S2 * MAX_ACCEL_BIAS_M_S2
            && norm2(&s.gyro_bias_rad_s) <= MAX_GYRO_BIAS_RAD_S * MAX_GYRO_BIAS_RAD_S
            && [&s.mean_dv_m_s, &s.prev_dv_m_s, &s.last_dv_m_s]
                .iter()
                .all(|v| norm2(*v) <= sq(MAX_SPECIFIC_FORCE_M_S2 * dt))
            && [&s.mean_dtheta_rad, &s.prev_dtheta_rad].iter().all(|v| norm2(*v) <= sq(MAX_RATE_RAD_S * dt))
            && s.spread_dtheta_rad2 >= 0.0
            && s.spread_dv_m2_s2 >= 0.0
            && diagonal_ok;
        if plausible && finite(&s.sum_dv_e_m_s) {
            Ok(())
        } else {
            Err(NavResumeError::Implausible)
        }
    }

    fn apply_snapshot(&mut self, s: &NavSnapshot) {
        let v3 = Vector3::from;
        if self.nav.nav.set_state(s.state()).is_err() {
            // Checked plausible above; a state the strapdown refuses all the same is lost.
            self.lost = Flag::SET;
            return;
        }
        self.nav.nav.set_history(v3(s.prev_dtheta_rad), v3(s.prev_dv_m_s), s.steps);
        let a = &mut self.nav;
        for (v, (i, j)) in s.p_upper.iter().zip(upper(0)) {
            if let Some(x) = a.p.get_mut((i, j)) {
                *x = *v;
            }
            if let Some(x) = a.p.get_mut((j, i)) {
                *x = *v;
            }
        }
        a.accel_bias_m_s2 = v3(s.accel_bias_m_s2);
        a.gyro_bias_rad_s = v3(s.gyro_bias_rad_s);
        a.sum_dv_e_m_s = v3(s.sum_dv_e_m_s);
        a.pending_steps = s.pending_steps;
        a.updates = s.updates;
        a.refused = s.refused;
        self.last_dv_m_s = v3(s.last_dv_m_s);
        self.mean_dtheta_rad = v3(s.mean_dtheta_rad);
        self.mean_dv_m_s = v3(s.mean_dv_m_s);
        self.spread_dtheta_rad2 = s.spread_dtheta_rad2;
        self.spread_dv_m2_s2 = s.spread_dv_m2_s2;
        self.out_counter = s.out_counter as u16;
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
