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
//! write sequence number, the accelerometer sample counter of its last step, the unit
//! time of that step (the state's time tag) and a digest of the step period and filter
//! tuning it was taken under) and the fields the
//! stage's declaration marks
//! `reset(Keep)` ([`NavKept`], derived from the declarations of [`NavUnit`],
//! [`AidedNav`] and [`super::Strapdown`]: the navigation state (q_eb, v_e, r_e), the
//! strapdown's increment history and step count, the filter's covariance, bias
//! estimates, pending propagation and counts, the running means and spreads of the
//! increments ([`super::unit::MEAN_STEPS`]), the bridge's window of body angle
//! increments ([`super::unit::WINDOW_BLOCKS`] blocks of [`super::unit::BLOCK_STEPS`]
//! steps, 0.48 s), the output frame counter and the attitude-unconfirmed flag); sealed with
//! CRC-32C ([`crate::frames::CRC32C`]'s value, computed by the frames' table-driven
//! [`crate::frames::crc32c_register`], whose tables the board links anyway) and its
//! complement. A field
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
//! increments and the block being summed within the sensors' ranges, the window's
//! counters in range. Accepted, the unit takes the copy's state
//! and holds it until its first step that takes an accelerometer frame of that step:
//! the steps since the record's time (the flight core's sample clock, modulo 2^16 as the
//! counters) name the counter the frame must carry (the record's plus those steps);
//! older frames (left in the link over the reset) are dropped, so the time and the
//! counter agree; the counter tells the samples lost since the snapshot (its age: up to one
//! snapshot period plus the time the unit was down for the newer copy, one period more
//! for the older: 80 + 80 + 40 = 200 steps, 0.25 s, with the firmware's period and
//! watchdog), and
//!
//! - up to [`MAX_BRIDGE_STEPS`]: the unit **bridges** them, one strapdown step per lost
//!   sample:
//!   - **attitude** on the window's fit: the angle summed over the window's 48 full
//!     blocks (v = steps from the window's start over its span − ½: −½ at its start, ½
//!     at its end) fitted by a cubic P(v) per axis, weighted least squares with a Hann
//!     taper sin²(π(v+½)) + 10⁻³ (the vibration the window cuts off at its ends leaks
//!     little into the fit). The points are fixed (the blocks' ends), so the fit is
//!     their projections on the polynomials orthogonal over them: one pass over the
//!     window, no system to solve (`fit_window`). The snapshot lies p steps
//!     after the window's end (p < 8, the block being summed); bridged step m of n takes
//!     P at p + m steps − P at p + m − 1 − φ₀/n, with φ₀ = the angle at the snapshot −
//!     P there, the vibration's displacement at the snapshot, so the bridge ends on the
//!     smooth motion. What it cannot know is the vibration's displacement at the
//!     bridge's end and the extrapolation's error: the **stated attitude error** is
//!     ε = r (1 + (p + n) / span), r the fit's weighted RMS residual (3-D), added to the
//!     attitude covariance as ε²/3 per axis. Measured in the roll program
//!     (`host-tests/tests/lv_resume.rs`): 10–13″ from the uninterrupted unit for gaps
//!     of 40–200 steps, within ε (12–16″) at every phase;
//!   - **velocity** on the mean increment (constant specific force), with the
//!     increments' spread about their mean as a random walk over the lost steps added to
//!     the covariance (σ_v² = n s_υ²/3 per axis, σ_r² = n³ Δt² s_υ²/9,
//!     cov = n² Δt s_υ²/6), so the frames' σ and the next GNSS fix's weight cover it.
//!
//!   **The window's guard**: a CRC seals the window only when a record is written; a
//!   bit flipped in the unit's RAM after a block's write and before the record's would
//!   be sealed with it, and a block near the window's end (weight ~10⁻³ in the taper)
//!   hardly moves r while it shifts φ₀ and so the bridged attitude by its whole error.
//!   So the unit keeps `window_xor`, the XOR of the ring's 32-bit half-words, each
//!   rotated left by its position in the ring plus one (mod 32), and of the ring's next
//!   index (rotated by 16), updated from its own value as each block is written; the fit
//!   recomputes it over the ring it uses, and a mismatch gives no fit. The rotation keeps
//!   two adjacent flipped bits, and the same bit flipped in two adjacent words, from
//!   cancelling (`NavUnit::window_xor`).
//!
//!   The attitude is **not backed** when the window was not full of measured increments
//!   (0.48 s after the start or after a previous bridge) or fails its guard, the gap exceeds
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
pub use super::unit::MAX_BRIDGE_STEPS;
use super::unit::{window_index, window_word, NavKept, NavUnit, BLOCK_STEPS, WINDOW_BLOCKS};
use super::{wgs84, NavState};
use crate::frames::crc32c_register;
use crate::state::{Flag, Maybe};

/// First word: "NSN" and the layout version 6.
const MAGIC: u32 = u32::from_le_bytes(*b"NSN\x06");
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
    /// The unit time of its last step, µs: the time tag of its state (a resume counts
    /// the steps to bridge from it, and takes only the accelerometer frame whose counter
    /// agrees).
    t_us: u64,
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
    /// CRC-32C of the covered bytes (one compiled copy for the write and the resume).
    #[inline(never)]
    fn crc(&self) -> u32 {
        crc32c(bytemuck::bytes_of(self).get(..COVERED).unwrap_or(&[]))
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

    /// The unit time of the step it was taken after, µs.
    pub fn t_us(&self) -> u64 {
        self.t_us
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
        let mut r = crc::CRC_32_ISCSI.init;
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
            r = crc32c_register(r, &f.to_le_bytes());
        }
        r ^ crc::CRC_32_ISCSI.xorout
    }
}

/// CRC-32C of `bytes` ([`crate::frames::CRC32C`]'s checksum).
fn crc32c(bytes: &[u8]) -> u32 {
    crc32c_register(crc::CRC_32_ISCSI.init, bytes) ^ crc::CRC_32_ISCSI.xorout
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

/// A record's bytes as the board's RAM holds them: `as_bytes`, `as_bytes_mut`, and
/// `from_bytes` (any content; `None` for a wrong length).
macro_rules! ram_bytes {
    ($($t:ty),*) => {$(
        impl $t {
            /// Its bytes (as the board's RAM holds them).
            pub fn as_bytes(&self) -> &[u8] {
                bytemuck::bytes_of(self)
            }

            /// Its bytes, mutable.
            pub fn as_bytes_mut(&mut self) -> &mut [u8] {
                bytemuck::bytes_of_mut(self)
            }

            /// One from `bytes` (any content; `None` for a wrong length).
            pub fn from_bytes(bytes: &[u8]) -> Option<Self> {
                bytemuck::try_pod_read_unaligned(bytes).ok()
            }
        }
    )*};
}

ram_bytes!(NavRecord, NavSnapshot);

/// Whether sequence number `a` is newer than `b` (wrapping).
fn newer(a: u32, b: u32) -> bool {
    (a.wrapping_sub(b) as i32) > 0
}

impl NavSnapshot {
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

/// The window's span, steps: [`WINDOW_BLOCKS`] blocks of [`BLOCK_STEPS`].
const SPAN_STEPS: f64 = (WINDOW_BLOCKS as u32 * BLOCK_STEPS) as f64;

/// The bridge's fit over the window (module documentation): the angle summed from the
/// window's start, P(v) = Σ c_k v^k per axis, with v = t / span − ½ (t the steps from the
/// window's start: v = −½ at its start, ½ at its last block's end).
struct WindowFit {
    /// c_0..c_3 of each axis, rad.
    c: [[f64; 4]; 3],
    /// Steps from the window's end to the snapshot (the block being summed then).
    lead: f64,
    /// The angle at the snapshot less P there: the vibration's displacement then, rad.
    phi0: Vector3<f64>,
    /// The fit's weighted RMS residual (3-D), rad.
    resid_rad: f64,
}

impl WindowFit {
    /// P at `steps` after the snapshot.
    #[inline(never)]
    fn at(&self, steps: f64) -> Vector3<f64> {
        let v = (self.lead + steps) / SPAN_STEPS + 0.5;
        Vector3::from_fn(|i, _| self.c.get(i).map_or(0.0, |c| c.iter().rev().fold(0.0, |p, ck| p * v + ck)))
    }

    /// The stated attitude error of a bridge over `n` steps (3-D), rad: the residual
    /// (the vibration's displacement at the bridge's end, which the fit cannot know),
    /// grown with the extrapolation from the window's end, `resid (1 + (lead + n) / span)`.
    fn bound(&self, n: u16) -> f64 {
        if n == 0 {
            return 0.0;
        }
        self.resid_rad * (1.0 + (self.lead + f64::from(n)) / SPAN_STEPS)
    }
}

/// One axis of the window's fit (`NavUnit::fit_window` for the method) over `blocks`
/// (the window's, oldest first): the cubic's c_0..c_3 in v, its weighted mean squared
/// residual (rad²) and the angle summed over the blocks (rad).
#[inline(never)]
fn fit_axis<'a>(blocks: impl Iterator<Item = &'a [f64; 3]>, axis: usize) -> ([f64; 4], f64, f64) {
    let (mut y, mut wy2) = (0.0, 0.0);
    // M_0, M_2, M_4, M_6; and Σ w v^k Y, k = 0..3.
    let (mut m, mut s) = ([0.0f64; 4], [0.0f64; 4]);
    let points = core::iter::once(0.0).chain(blocks.map(|b| b.get(axis).copied().unwrap_or(0.0)));
    for (j, b) in points.enumerate() {
        y += b;
        let x = j as f64 / WINDOW_BLOCKS as f64;
        let (sin, _) = crate::math::sin_cos(core::f64::consts::PI * x);
        let (w, v) = (sin * sin + 1e-3, x - 0.5);
        let mut wv = w;
        for sk in &mut s {
            *sk += wv * y;
            wv *= v;
        }
        let mut wv2 = w;
        for mk in &mut m {
            *mk += wv2;
            wv2 *= v * v;
        }
        wy2 += w * y * y;
    }
    let [m0, m2, m4, m6] = m;
    let [s0, s1, s2, s3] = s;
    let (a, b) = (m2 / m0, m4 / m2);
    let n = [m0, m2, m4 - a * m2, m6 - b * m4];
    let d = [s0 / m0, s1 / m2, (s2 - a * s0) / n[2], (s3 - b * s1) / n[3]];
    let explained: f64 = d.iter().zip(n).map(|(dk, nk)| nk * dk * dk).sum();
    let [d0, d1, d2, d3] = d;
    ([d0 - a * d2, d1 - b * d3, d2, d3], (wy2 - explained).max(0.0) / m0, y)
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
        // The state's time tag sealed (it and its complement agree), or no record.
        let t_us = self.last_t_us;
        if self.lost.get() || self.resume_from.is_some() || t_us == 0 || self.last_t_inv_us != !t_us {
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
        s.t_us = t_us;
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
        // A new state: the guard's shadows saved again by the next step, unchecked.
        self.guard.sealed = 0;
        // The state again through the strapdown's own check (it normalises the
        // quaternion and rebuilds the gravity term); checked plausible above, a state it
        // refuses all the same is lost.
        if self.nav.nav.set_state(s.state()).is_err() {
            self.lost = Flag::SET;
            return;
        }
        self.accel_counter = Maybe::none();
        self.resume_from = Maybe::some(s.accel_counter());
        self.resume_t_us = s.t_us;
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
        // Step m of n on the fit: P(m) − P(m − 1) − φ₀/n (the vibration's displacement at
        // the snapshot spread over the bridge).
        let mut before = fit.as_ref().map_or(Vector3::zeros(), |f| f.at(0.0));
        for m in 1..=lost {
            let dtheta = match &fit {
                Some(f) => {
                    let now = f.at(f64::from(m));
                    let d = now - before - f.phi0 / f64::from(lost);
                    before = now;
                    d
                }
                None => self.mean_dtheta_rad,
            };
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

    /// The window's fields in a record: the block being summed finite and within the
    /// body rate range, the ring's counters in range (the ring's blocks are checked
    /// against their guard, `NavUnit::window_xor`, by the fit that uses them).
    fn window_plausible(k: &NavKept, dt_s: f64) -> bool {
        let block = k.block_rad;
        let (steps, next, filled) = (k.block_steps, k.block_next, k.blocks_filled);
        let most = sq(MAX_RATE_RAD_S * dt_s * f64::from(BLOCK_STEPS));
        finite(&block)
            && norm2(&block) <= most
            && steps < BLOCK_STEPS
            && (next as usize) < WINDOW_BLOCKS
            && filled as usize <= WINDOW_BLOCKS
    }

    /// The bridge's fit over the window (module documentation), if the window is full of
    /// measured increments and the fit is finite.
    ///
    /// The points: the angle summed from the window's start, Y_j, at its start and at each
    /// block's end, v_j = j / 48 − ½ (j = 0..48, Y_0 = 0), weighted
    /// w_j = sin²(π j / 48) + 10⁻³ (the Hann taper). They are fixed and symmetric about
    /// v = 0 (the odd moments M_k = Σ w v^k vanish), so the polynomials orthogonal over
    /// them (Gram) are q_0 = 1, q_1 = v, q_2 = v² − a, q_3 = v³ − b v with a = M_2/M_0,
    /// b = M_4/M_2, and the weighted least-squares cubic is the sum of the projections
    /// d_k q_k, d_k = Σ w q_k Y / N_k, N_k = Σ w q_k² (N_2 = M_4 − a M_2,
    /// N_3 = M_6 − b M_4): one pass over the points per axis, no system to solve. The
    /// weighted residual: r² = Σ_axes (Σ w Y² − Σ_k N_k d_k²) / M_0.
    #[inline(never)]
    #[cold]
    fn fit_window(&self) -> Option<WindowFit> {
        if self.blocks_filled as usize != WINDOW_BLOCKS {
            return None;
        }
        // The ring from its oldest block.
        let (newer, older) = self.blocks_rad.split_at_checked(self.block_next as usize)?;
        let mut c = [[0.0; 4]; 3];
        let (mut resid2, mut y) = (0.0, self.block_rad);
        for ((ci, yi), axis) in c.iter_mut().zip(y.iter_mut()).zip(0..) {
            let (coefs, r2, sum) = fit_axis(older.iter().chain(newer), axis);
            *ci = coefs;
            resid2 += r2;
            *yi += sum;
        }
        // The guard of the ring: its words and its index, as they were written
        // (`NavUnit::window_xor`).
        let mut bits = window_index(self.block_next);
        for (k, x) in self.blocks_rad.as_flattened().iter().enumerate() {
            bits ^= window_word(x.to_bits(), k);
        }
        let lead = f64::from(self.block_steps.min(BLOCK_STEPS - 1));
        let mut fit = WindowFit { c, lead, phi0: Vector3::zeros(), resid_rad: crate::math::sqrt(resid2) };
        // The angle at the snapshot: the window's and the block being summed.
        fit.phi0 = Vector3::from(y) - fit.at(0.0);
        // All finite: their sum is (an infinity or NaN anywhere makes it not); and the
        // ring as its guard says it was written (a bit flipped since: no fit).
        let sum = c.as_flattened().iter().sum::<f64>() + fit.resid_rad + fit.phi0.sum();
        (sum.is_finite() && bits == self.window_xor).then_some(fit)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The weighted least-squares cubic over the window's points by its normal equations
    /// (solved with partial pivoting): c_0..c_3 in v and the weighted mean squared residual.
    fn normal_equations(y: &[f64]) -> ([f64; 4], f64) {
        let n = WINDOW_BLOCKS as f64;
        let mut m = [[0.0f64; 5]; 4];
        let mut pts = Vec::new();
        for (j, yj) in y.iter().enumerate() {
            let x = j as f64 / n;
            let w = (core::f64::consts::PI * x).sin().powi(2) + 1e-3;
            let v = x - 0.5;
            let p = [1.0, v, v * v, v * v * v];
            for r in 0..4 {
                for c in 0..4 {
                    m[r][c] += w * p[r] * p[c];
                }
                m[r][4] += w * p[r] * yj;
            }
            pts.push((w, p, *yj));
        }
        for i in 0..4 {
            let piv = (i..4).max_by(|a, b| m[*a][i].abs().total_cmp(&m[*b][i].abs())).unwrap();
            m.swap(i, piv);
            for r in i + 1..4 {
                let (pivot, f) = (m[i], m[r][i] / m[i][i]);
                for (x, p) in m[r].iter_mut().zip(pivot).skip(i) {
                    *x -= f * p;
                }
            }
        }
        let mut c = [0.0; 4];
        for i in (0..4).rev() {
            c[i] = (m[i][4] - (i + 1..4).map(|k| m[i][k] * c[k]).sum::<f64>()) / m[i][i];
        }
        let (mut r2, mut w_sum) = (0.0, 0.0);
        for (w, p, yj) in pts {
            let e = yj - (0..4).map(|k| c[k] * p[k]).sum::<f64>();
            r2 += w * e * e;
            w_sum += w;
        }
        (c, r2 / w_sum)
    }

    /// The one-pass projection on the orthogonal polynomials is the weighted least-squares
    /// cubic the normal equations give, on a smooth motion with vibration and noise, and
    /// reproduces a cubic exactly.
    #[test]
    fn the_window_fit_is_the_weighted_least_squares_cubic() {
        let mut x = 0x9E37_79B9_7F4A_7C15u64;
        let mut noise = || {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            (x >> 11) as f64 / (1u64 << 53) as f64 - 0.5
        };
        for round in 0..40 {
            let k = [noise() * 1e-2, noise() * 1e-3, noise() * 1e-4, noise() * 1e-5];
            let (amp, f_hz) = (if round % 2 == 0 { 0.0 } else { 5e-5 }, 11.0 + round as f64);
            // The angle summed over each block: a cubic in the step, a vibration, noise.
            let angle = |t: f64| {
                k[0] * t
                    + k[1] * t * t / 40.0
                    + k[2] * t.powi(3) / 1600.0
                    + amp * (2.0 * core::f64::consts::PI * f_hz * t * 1.25e-3).sin()
            };
            let blocks: Vec<[f64; 3]> = (0..WINDOW_BLOCKS)
                .map(|i| {
                    let t0 = (i as u32 * BLOCK_STEPS) as f64;
                    let d = angle(t0 + f64::from(BLOCK_STEPS)) - angle(t0);
                    [d, -0.5 * d + amp * 1e-2 * noise(), k[3] * noise()]
                })
                .collect();
            for axis in 0..3 {
                let (c, r2, sum) = fit_axis(blocks.iter(), axis);
                let mut y = vec![0.0];
                for b in &blocks {
                    y.push(y.last().unwrap() + b[axis]);
                }
                let (want, want_r2) = normal_equations(&y);
                let scale = y.iter().fold(0.0f64, |a, v| a.max(v.abs())).max(1e-30);
                for (ck, wk) in c.iter().zip(want) {
                    assert!((ck - wk).abs() <= 1e-11 * scale, "round {round}, axis {axis}: {c:?} against {want:?}");
                }
                assert!(
                    (r2 - want_r2).abs() <= 1e-11 * scale * scale,
                    "round {round}, axis {axis}: {r2} against {want_r2}"
                );
                assert!((sum - y[WINDOW_BLOCKS]).abs() <= 1e-15 * scale);
                // The residual is the difference of two sums of squares: exact to
                // √ε of the angle's scale.
                if amp == 0.0 && axis == 0 {
                    assert!(r2.sqrt() <= 1e-7 * scale, "round {round}: a cubic fitted with residual {r2}");
                }
            }
        }
    }
}
