//! The navigation's reset snapshot: what a reset of the launch-vehicle unit (watchdog,
//! HardFault) resumes the navigation from mid-ascent, where the pad initialisation
//! ([`super::init`]) is no longer the vehicle's state.
//!
//! The board's RAM the reset does not clear holds a [`NavSnapshot`] beside the flight
//! core's own snapshot: **two copies** of a [`NavRecord`], each sealed on its own;
//! [`NavUnit::snapshot_into`] overwrites the older copy (by the records' write sequence
//! numbers), so a copy torn by a reset during its write, or one an upset flipped a bit
//! of, leaves the other. A [`NavRecord`] is a `#[repr(C, packed)]` plain-old-data
//! record (any bit pattern is a value: it is judged by its checks only): a header (its
//! write sequence number, the accelerometer sample counter of its last step and a
//! digest of the step period and filter tuning it was taken under) and the fields the
//! stage's declaration marks
//! `reset(Keep)` ([`NavKept`], derived from the declarations of [`NavUnit`],
//! [`AidedNav`] and [`super::Strapdown`]: the navigation state (q_eb, v_e, r_e), the
//! strapdown's increment history and step count, the filter's covariance, bias
//! estimates, pending propagation and counts, the running means and spreads of the
//! increments ([`super::unit::MEAN_STEPS`]), the bridge's window of body angle
//! increments ([`super::unit::WINDOW_BLOCKS`] blocks of [`super::unit::BLOCK_STEPS`]
//! steps, 0.48 s), the output frame counter and the attitude-unconfirmed flag); sealed with
//! CRC-32C (the `crc` crate's, [`crate::frames::CRC32C`]) and its complement. A field
//! marked there is carried over a reset with no other change here.
//!
//! **Writing** ([`NavUnit::snapshot_into`]): the complement is spoiled first, then the
//! fields are written, then the CRC, then its complement, with compiler fences between
//! the three phases; a reset anywhere in the write leaves a record whose two check words
//! disagree, refused.
//!
//! **Resuming** ([`NavUnit::resume`], on a unit just built from the pad block): the
//! newer copy first, the older if the newer is refused. A copy is refused
//! ([`NavResumeError`]) unless the magic and length are this layout's, the CRC and its
//! complement match, the step period and filter tuning are the unit's, and every value
//! is plausible: finite, ‖q_eb‖ within 1e-6 of 1, the position between
//! [`super::wgs84::MIN_RADIUS_M`] and [`MAX_RADIUS_M`], the speed below
//! [`MAX_SPEED_M_S`], the covariance's diagonal ≥ 0, the bias estimates and the mean
//! increments and the window's blocks within the sensors' ranges, the window's counters
//! in range. Accepted, the unit takes the copy's state
//! and holds it until its first step that takes an accelerometer frame; there the
//! frame's counter tells the samples lost since the snapshot (its age: up to one
//! snapshot period plus the time the unit was down for the newer copy, one period more
//! for the older: 80 + 80 + 40 = 200 steps, 0.25 s, with the firmware's period and
//! watchdog), and
//!
//! - up to [`MAX_BRIDGE_STEPS`]: the unit **bridges** them, one strapdown step per lost
//!   sample:
//!   - **attitude** on the window's fit: the angle summed over the window's blocks
//!     (u = steps after the snapshot over the window's span, −1 at its start, 0 at the
//!     snapshot) fitted by a cubic P(u) per axis, weighted least squares with a Hann
//!     taper sin²(π(u+1)) + 10⁻³ (the vibration the window cuts off at its ends leaks
//!     little into the fit); bridged step m of n takes P(m) − P(m−1) − φ₀/n, with
//!     φ₀ = the angle at the snapshot − P(0), the vibration's displacement at the
//!     snapshot, so the bridge ends on the smooth motion. What it cannot know is the
//!     vibration's displacement at the bridge's end and the extrapolation's error: the
//!     **stated attitude error** is ε = r (1 + n / span), r the fit's weighted RMS
//!     residual (3-D), added to the attitude covariance as ε²/3 per axis. Measured in
//!     the roll program (`host-tests/tests/lv_resume.rs`): 10–13″ from the
//!     uninterrupted unit for gaps of 40–200 steps, within ε (12–16″) at every phase;
//!   - **velocity** on the mean increment (constant specific force), with the
//!     increments' spread about their mean as a random walk over the lost steps added to
//!     the covariance (σ_v² = n s_υ²/3 per axis, σ_r² = n³ Δt² s_υ²/9,
//!     cov = n² Δt s_υ²/6), so the frames' σ and the next GNSS fix's weight cover it.
//!
//!   The attitude is **not backed** when the window was not full of measured increments
//!   (0.48 s after the start or after a previous bridge), the gap exceeds
//!   [`ATT_BRIDGE_MAX_STEPS`], or ε exceeds [`ATT_BOUND_MAX_RAD`]: it is bridged all the
//!   same (on the fit, or the mean increment without one), and every output frame from
//!   then on carries [`flags::ATTITUDE_UNCONFIRMED`] (position and velocity stand) until
//!   a pad initialisation builds the unit again; the GNSS fixes cannot confirm an
//!   attitude to arcseconds within the flight.
//! - more (a snapshot the unit cannot bridge, **stale**): the navigation is lost.
//!
//! **The rule after a reset**: no snapshot (neither copy with this layout's magic: a
//! power-on, whose RAM holds nothing of a flight) keeps the pad initialisation the unit
//! was built from (the vehicle is on the pad); a snapshot that is there but refused
//! (both copies), or stale at its first sample, leaves the navigation **lost**: the state held, [`flags::NAV_FAULT`] in every
//! output frame, no fix used, until the ground equipment loads a pad initialisation
//! again (a new [`NavUnit`]). The unit never resumes from a record it cannot check.
//! Not carried over: the link decoders and queues (the rings start empty after the
//! reset), a fix held for the filter work (the next one, 1 s later, is used) and the
//! time of the last fix used (the frames show [`flags::GNSS_OUTAGE`] until the next
//! fix); the output frame counter goes on past the lost samples.
//!
//! [`flags::NAV_FAULT`]: crate::frames::navout::flags::NAV_FAULT
//! [`flags::GNSS_OUTAGE`]: crate::frames::navout::flags::GNSS_OUTAGE
//! [`flags::ATTITUDE_UNCONFIRMED`]: crate::frames::navout::flags::ATTITUDE_UNCONFIRMED

use core::sync::atomic::{compiler_fence, Ordering};

use bytemuck::{Pod, Zeroable};

use nalgebra::Vector3;

use super::gnss::AidedNav;
use super::unit::{BridgeReport, NavKept, NavUnit, BLOCK_STEPS, WINDOW_BLOCKS};
use super::{wgs84, NavState};
use crate::frames::CRC32C;
use crate::state::{Flag, Maybe};

/// First word: "NSN" and the layout version 3.
const MAGIC: u32 = u32::from_le_bytes(*b"NSN\x03");
/// Most samples a resume bridges (0.5 s at 1.25 ms): the snapshot period (80 steps in
/// the firmware) plus a reset and boot, with margin; older, the snapshot is stale.
pub const MAX_BRIDGE_STEPS: u16 = 400;
/// Most samples whose attitude a resume bridges on the window's fit and still backs
/// (0.3 s): the older copy's age (two snapshot periods of 80 steps) plus a reset and boot
/// of 40 steps, with margin; beyond it the attitude is flagged unconfirmed.
pub const ATT_BRIDGE_MAX_STEPS: u16 = 240;
/// Largest stated attitude error of a bridge the navigation still claims (3-D), rad
/// (30″); beyond it the attitude is flagged unconfirmed.
pub const ATT_BOUND_MAX_RAD: f64 = 30.0 / 206_264.806_247_096_36;
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

/// One sealed copy of the navigation's reset snapshot (module documentation). Plain old
/// data: any bit pattern is a value. Packed: the kept fields' record ([`NavKept`]) is,
/// and the check words follow it.
#[derive(Debug, Clone, Copy, Pod, Zeroable)]
#[repr(C, packed)]
pub struct NavRecord {
    magic: u32,
    /// `size_of::<NavRecord>()`.
    len: u32,
    /// Write sequence number: the newer of the two copies has the larger (wrapping).
    seq: u32,
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

impl Default for NavRecord {
    fn default() -> Self {
        NavRecord::zeroed()
    }
}

impl PartialEq for NavRecord {
    /// Bit for bit.
    fn eq(&self, other: &Self) -> bool {
        bytemuck::bytes_of(self) == bytemuck::bytes_of(other)
    }
}

/// Bytes the CRC covers: all before `check`.
const COVERED: usize = core::mem::offset_of!(NavRecord, check);

fn finite(v: &[f64]) -> bool {
    v.iter().all(|x| x.is_finite())
}

fn sq(x: f64) -> f64 {
    x * x
}

fn norm2(v: &[f64]) -> f64 {
    v.iter().map(|x| x * x).sum()
}

impl NavRecord {
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

    /// Whether it carries this layout's magic and length (a copy was written here).
    pub fn present(&self) -> bool {
        self.magic == MAGIC && self.len as usize == core::mem::size_of::<NavRecord>()
    }

    /// Its write sequence number.
    pub fn seq(&self) -> u32 {
        self.seq
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

    /// Adds a bridge's error growth over `n` steps to the covariance: the velocity
    /// increments' per-step spread `s_dv_m2_s2` (3-D mean square) as a random walk of the
    /// velocity (and so of the position), and the attitude's stated bound
    /// `att_bound_rad` (module documentation).
    fn add_bridge_growth(&mut self, n: u16, att_bound_rad: f64, s_dv_m2_s2: f64) -> BridgeReport {
        let steps = u32::from(n);
        let n = f64::from(n);
        let dt = self.nav.dt_s();
        // The attitude's stated bound as a 1σ per axis (bound²/3 each); none when the
        // bridge had no fit (the frames flag the attitude unconfirmed instead).
        let qa = if att_bound_rad.is_finite() { att_bound_rad * att_bound_rad / 3.0 } else { 0.0 };
        let qv = s_dv_m2_s2 / 3.0;
        for i in 0..3 {
            let add = |p: &mut Self, r: usize, c: usize, v: f64| {
                if let Some(x) = p.p.get_mut((r, c)) {
                    *x += v;
                }
            };
            add(self, i, i, qa);
            add(self, 3 + i, 3 + i, n * qv);
            add(self, 6 + i, 6 + i, n * n * n * dt * dt * qv / 3.0);
            add(self, 3 + i, 6 + i, n * n * dt * qv / 2.0);
            add(self, 6 + i, 3 + i, n * n * dt * qv / 2.0);
        }
        BridgeReport {
            steps,
            sigma_pos_m: crate::math::sqrt(n * n * n * dt * dt * s_dv_m2_s2 / 3.0),
            sigma_vel_m_s: crate::math::sqrt(n * s_dv_m2_s2),
            att_bound_rad,
        }
    }
}

/// The navigation's reset snapshot as the board's RAM holds it: two sealed copies
/// ([`NavRecord`]), written alternately (the older one overwritten); a resume takes the
/// newest copy that passes its checks (module documentation).
#[derive(Debug, Clone, Copy, Default, PartialEq, Pod, Zeroable)]
#[repr(C)]
pub struct NavSnapshot {
    /// The two copies.
    pub copies: [NavRecord; 2],
}

/// Whether sequence number `a` is newer than `b` (wrapping).
fn newer(a: u32, b: u32) -> bool {
    (a.wrapping_sub(b) as i32) > 0
}

impl NavSnapshot {
    /// Its bytes (as the board's RAM holds them).
    pub fn as_bytes(&self) -> &[u8] {
        bytemuck::bytes_of(self)
    }

    /// Its bytes, mutable.
    pub fn as_bytes_mut(&mut self) -> &mut [u8] {
        bytemuck::bytes_of_mut(self)
    }

    /// A snapshot from `bytes` (any content; `None` for a wrong length).
    pub fn from_bytes(bytes: &[u8]) -> Option<Self> {
        bytemuck::try_pod_read_unaligned(bytes).ok()
    }

    /// The snapshot that starts `words` (a board's RAM the reset does not clear, as
    /// words): `None` when the words are too few.
    pub fn in_words(words: &mut [u32]) -> Option<&mut Self> {
        let bytes: &mut [u8] = bytemuck::cast_slice_mut(words);
        bytemuck::try_from_bytes_mut(bytes.get_mut(..core::mem::size_of::<Self>())?).ok()
    }

    /// The copies' indices, the newer (by sequence number) first.
    pub fn order(&self) -> [usize; 2] {
        let [a, b] = &self.copies;
        if newer(b.seq, a.seq) {
            [1, 0]
        } else {
            [0, 1]
        }
    }

    /// The newest sealed copy, if one is.
    pub fn newest(&self) -> Option<&NavRecord> {
        self.order().into_iter().filter_map(|i| self.copies.get(i)).find(|r| r.present() && r.sealed())
    }

    /// The accelerometer sample counter of the newest sealed copy (0 if none).
    pub fn accel_counter(&self) -> u16 {
        self.newest().map_or(0, NavRecord::accel_counter)
    }

    /// Spoils both copies' check words (the board after resuming: a written snapshot is
    /// resumed at most once).
    pub fn invalidate(&mut self) {
        for r in &mut self.copies {
            r.invalidate();
        }
    }
}

/// The bridge's fit over the window (module documentation): the angle summed over the
/// window's steps, P(u) = Σ c_k u^k per axis with u the steps after the snapshot over
/// the window's span.
struct WindowFit {
    /// c_0..c_3, rad.
    c: [Vector3<f64>; 4],
    /// The window's span, steps.
    span: f64,
    /// The angle at the snapshot less P(0): the vibration's displacement then, rad.
    phi0: Vector3<f64>,
    /// The fit's weighted RMS residual (3-D), rad.
    resid_rad: f64,
}

impl WindowFit {
    fn at(&self, steps: f64) -> Vector3<f64> {
        let u = steps / self.span;
        let [c0, c1, c2, c3] = &self.c;
        c0 + (c1 + (c2 + c3 * u) * u) * u
    }

    /// The body angle increment of bridged step `m` (1-based) of `n`: the fit's, and the
    /// vibration's displacement at the snapshot spread over the bridge.
    fn increment(&self, m: u16, n: u16) -> Vector3<f64> {
        let (m, n) = (f64::from(m), f64::from(n));
        self.at(m) - self.at(m - 1.0) - self.phi0 / n
    }

    /// The stated attitude error of a bridge over `n` steps (3-D), rad: the residual
    /// (the vibration's displacement at the bridge's end, which the fit cannot know),
    /// grown with the extrapolation, `resid (1 + n / span)`.
    fn bound(&self, n: u16) -> f64 {
        if n == 0 {
            return 0.0;
        }
        self.resid_rad * (1.0 + f64::from(n) / self.span)
    }
}

/// Solves the normal equations `[A | B]` (A 4×4 symmetric positive definite, B 4×3) by
/// Gaussian elimination without pivoting: X with A X = B, or `None` for a pivot that is
/// not positive or a result that is not finite.
#[inline(never)]
fn solve_normal(mut m: [[f64; 7]; 4]) -> Option<[[f64; 3]; 4]> {
    // The loops over the rows run on an opaque count: kept rolled, the code is a quarter
    // of the unrolled (flash is the launch vehicle's budget; this runs once per resume).
    let n = core::hint::black_box(4usize);
    for i in 0..n {
        let (top, rest) = m.split_at_mut_checked(i + 1)?;
        let pivot_row = top.last()?;
        let p = *pivot_row.get(i)?;
        if p.is_nan() || p <= 0.0 {
            return None;
        }
        for row in rest.iter_mut() {
            let f = *row.get(i)? / p;
            for (x, y) in row.iter_mut().zip(pivot_row.iter()) {
                *x -= f * y;
            }
        }
    }
    let mut x = [[0.0f64; 3]; 4];
    for i in (0..n).rev() {
        let row = m.get(i)?;
        let (a, b) = row.split_at(4);
        let mut v = [b.first().copied()?, b.get(1).copied()?, b.get(2).copied()?];
        for (aij, xj) in a.iter().zip(x.iter()).skip(i + 1) {
            for (vk, xk) in v.iter_mut().zip(xj) {
                *vk -= aij * xk;
            }
        }
        let p = *a.get(i)?;
        *x.get_mut(i)? = v.map(|vk| vk / p);
    }
    x.iter().flatten().all(|v| v.is_finite()).then_some(x)
}

/// Weight of a window point at u ∈ [−1, 0]: a Hann taper (sin²), so the vibration the
/// window cuts off at its ends leaks little into the fit, floored at 10⁻³.
fn taper(u: f64) -> f64 {
    let (s, _) = crate::math::sin_cos(core::f64::consts::PI * (u + 1.0));
    s * s + 1e-3
}

impl NavUnit {
    /// Writes the snapshot of the navigation now over the older copy of `s` in place,
    /// sealed (the board's RAM a reset does not clear; module documentation for the
    /// write order), with the next sequence number. Returns false, leaving `s` as it
    /// was, when there is nothing a reset could resume: the navigation lost, a resume not
    /// yet bridged, or no accelerometer sample yet.
    #[inline(never)]
    pub fn snapshot_into(&self, s: &mut NavSnapshot) -> bool {
        let [newest, older] = s.order();
        let seq = s.copies.get(newest).map_or(0, |r| r.seq).wrapping_add(1);
        match s.copies.get_mut(older) {
            Some(r) => self.record_into(r, seq),
            None => false,
        }
    }

    /// Writes the snapshot now into record `s` with sequence number `seq` (module
    /// documentation for the write order).
    #[inline(never)]
    pub fn record_into(&self, s: &mut NavRecord, seq: u32) -> bool {
        let Some(counter) = self.accel_counter.get() else { return false };
        if self.lost.get() || self.resume_from.is_some() {
            return false;
        }
        // Spoiled first: a reset during the write leaves the check words disagreeing.
        s.check_inv = s.check;
        compiler_fence(Ordering::SeqCst);
        s.magic = MAGIC;
        s.len = core::mem::size_of::<NavRecord>() as u32;
        s.seq = seq;
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

    /// Resumes this unit (just built at boot from the pad block) from the newest copy of
    /// `s` that passes its checks (module documentation): the state is taken now and the
    /// samples lost over the reset are bridged at the first step that takes an
    /// accelerometer frame. Refused (neither copy passes): with
    /// [`NavResumeError::Absent`] (no copy there) the unit is left as built (a power-on
    /// on the pad); with any other error (the newest present copy's) the navigation is
    /// lost ([`NavUnit::lost`]).
    #[inline(never)]
    pub fn resume(&mut self, s: &NavSnapshot) -> Result<(), NavResumeError> {
        let mut refused = NavResumeError::Absent;
        for r in s.order().into_iter().filter_map(|i| s.copies.get(i)) {
            match self.resume_record(r) {
                Ok(()) => return Ok(()),
                Err(NavResumeError::Absent) => {}
                Err(e) if refused == NavResumeError::Absent => refused = e,
                Err(_) => {}
            }
        }
        if refused != NavResumeError::Absent {
            self.lost = Flag::SET;
        }
        Err(refused)
    }

    /// Resumes from one record if it passes its checks; refused, the unit is left as it
    /// was.
    pub fn resume_record(&mut self, s: &NavRecord) -> Result<(), NavResumeError> {
        self.check_snapshot(s)?;
        self.apply_snapshot(s);
        Ok(())
    }

    fn check_snapshot(&self, s: &NavRecord) -> Result<(), NavResumeError> {
        if !s.present() {
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
            && p.diagonal().iter().all(|d| *d >= 0.0)
            && Self::window_plausible(k, dt);
        if plausible {
            Ok(())
        } else {
            Err(NavResumeError::Implausible)
        }
    }

    fn apply_snapshot(&mut self, s: &NavRecord) {
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
    #[inline(never)]
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
        // The attitude on the window's fit (else, no fit, the mean increment, and the
        // attitude flagged unconfirmed); the velocity on the mean increment.
        let fit = if lost <= ATT_BRIDGE_MAX_STEPS { self.fit_window() } else { None };
        let bound = fit.as_ref().map_or(f64::INFINITY, |f| f.bound(lost));
        if bound.is_nan() || bound > ATT_BOUND_MAX_RAD {
            self.att_unconfirmed = Flag::SET;
        }
        let dv = self.mean_dv_m_s;
        // Bounded: at most MAX_BRIDGE_STEPS strapdown steps.
        for m in 1..=lost {
            let dtheta = fit.as_ref().map_or(self.mean_dtheta_rad, |f| f.increment(m, lost));
            if self.nav.step_deferred(&dtheta, &dv).is_err() {
                self.lost = Flag::SET;
                return false;
            }
        }
        // The window starts again on measured increments.
        self.blocks_filled = 0;
        self.block_steps = 0;
        self.block_rad = [0.0; 3];
        let report = self.nav.add_bridge_growth(lost, bound, self.spread_dv_m2_s2);
        self.last_dv_m_s = dv;
        self.out_counter = self.out_counter.wrapping_add(lost);
        self.bridged = Maybe::some(report);
        true
    }

    /// The window's fields in a record: finite, each block's angle within the body rate
    /// range, the ring's counters in range.
    fn window_plausible(k: &NavKept, dt_s: f64) -> bool {
        let blocks = k.blocks_rad;
        let block = k.block_rad;
        let (steps, next, filled) = (k.block_steps, k.block_next, k.blocks_filled);
        let most = sq(MAX_RATE_RAD_S * dt_s * f64::from(BLOCK_STEPS));
        blocks.iter().chain(core::iter::once(&block)).all(|b| finite(b) && norm2(b) <= most)
            && steps < BLOCK_STEPS
            && (next as usize) < WINDOW_BLOCKS
            && filled as usize <= WINDOW_BLOCKS
    }

    /// The bridge's fit over the window (module documentation), if the window is full of
    /// measured increments and the fit is well posed.
    #[inline(never)]
    #[cold]
    fn fit_window(&self) -> Option<WindowFit> {
        // Over the blocks filled (the fit is used only with the window full).
        let blocks = (self.blocks_filled as usize).min(WINDOW_BLOCKS);
        let block = f64::from(BLOCK_STEPS);
        let partial = self.block_steps.min(BLOCK_STEPS - 1);
        let span = blocks as f64 * block + f64::from(partial);
        if blocks == 0 || span <= 0.0 {
            return None;
        }
        let first = self.block_next as usize % WINDOW_BLOCKS + WINDOW_BLOCKS - blocks;
        let ring = &self.blocks_rad;
        let last = (partial > 0).then_some(self.block_rad);
        // The angle summed from the window's start at each block's end and at the
        // snapshot, against u = steps after the snapshot / span ∈ [−1, 0].
        let sums = (0..blocks)
            .map(|j| (((j + 1) as f64 * block - span) / span, ring.get((first + j) % WINDOW_BLOCKS)))
            .map(|(u, b)| (u, b.copied().unwrap_or([0.0; 3])))
            .chain(last.map(|b| (0.0, b)));
        let points = core::iter::once((-1.0, Vector3::zeros())).chain(sums.scan(Vector3::zeros(), |sum, (u, b)| {
            *sum += Vector3::from(b);
            Some((u, *sum))
        }));
        // Weighted least squares of a cubic: the normal equations [A | B] (A 4×4, B one
        // column per axis), solved by elimination (A is symmetric positive definite); the
        // weighted residual from Σ w |y|² − Σ_axes cᵀ B.
        let mut m = [[0.0f64; 7]; 4];
        let (mut w_sum, mut wy2, mut sum) = (0.0, 0.0, Vector3::zeros());
        for (u, y) in points {
            let w = taper(u);
            w_sum += w;
            wy2 += w * y.norm_squared();
            sum = y;
            let pw = [1.0, u, u * u, u * u * u];
            for (row, pi) in m.iter_mut().zip(pw) {
                let (a, b) = row.split_at_mut(4);
                for (x, pj) in a.iter_mut().zip(pw) {
                    *x += w * pi * pj;
                }
                for (x, yk) in b.iter_mut().zip(y.iter()) {
                    *x += w * pi * yk;
                }
            }
        }
        let c = solve_normal(m)?;
        let cb: f64 = c
            .iter()
            .zip(m.iter())
            .map(|(ci, row)| ci.iter().zip(row.iter().skip(4)).map(|(x, b)| x * b).sum::<f64>())
            .sum();
        let resid_rad = crate::math::sqrt((wy2 - cb).max(0.0) / w_sum);
        let c = c.map(Vector3::from);
        let phi0 = sum - c[0];
        let fit = WindowFit { c, span, phi0, resid_rad };
        let ok = fit.c.iter().all(|c| finite(c.as_slice())) && resid_rad.is_finite() && finite(phi0.as_slice());
        (ok && blocks == WINDOW_BLOCKS).then_some(fit)
    }
}
