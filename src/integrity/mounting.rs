//! Mounting check from power-on: is each FOG mounted as the table says?
//!
//! A FOG mounted backwards, or two FOGs in each other's place, reads a rate that
//! calibration cannot explain but that the parity residual cannot name: at a constant
//! rate the parity's baseline takes the offset for calibration residue. The star tracker
//! can name it. Between consecutive star-tracker frames k−1, k the body turns by
//! φ_k = 2 vect(Λ*ₖ₋₁⁻¹ ∘ Λ*ₖ) (Λ* taken to the ICS through the mount, eq. (5)), and FOG i,
//! mounted along s_i, measures s_i · φ_k plus its noise and calibration residue. Over the
//! frames since the check began
//!
//! ```text
//! S_i = Σ_k ΔA_i(k)          (FOG i's compensated increments between the frames, rad)
//! Φ   = Σ_k φ_k              (the body rotation the tracker saw, rad)
//! r_i(c) = | S_i − c · Φ |   (FOG i's evidence against mounting axis c)
//! ```
//!
//! Φ telescopes: its noise is two frames' (√2 σ_st per axis), not the sum of all; S_i adds
//! the FOG's angle random walk over the span T. A mounting axis c is **consistent** with
//! FOG i while r_i(c) is within
//!
//! ```text
//! τ = K_MOUNT · √(2 σ_st² + σ_v² T) + B_MAX · T + MODEL_RESIDUAL · |Φ|
//! ```
//!
//! (noise, a bias residue of up to [`BIAS_MAX_RAD_S`], the scale-factor and axis residue
//! of the parity check). FOG i is **faulty** when its own axis s_i is not consistent,
//! and **verified** when its own axis is and every other candidate axis (±s_j, −s_i) is
//! not: the motion has told them apart. A motion that leaves s_i · Φ near zero (no turn
//! about FOG i's axis, or no turn at all) cannot verify FOG i, and a flip of that FOG is
//! invisible to every sensor until the body turns about its axis.
//!
//! The hypotheses are a single flip (FOG i faulty, −s_i consistent with it, the others
//! not faulty) and a single swap (FOGs i and j faulty, s_j consistent with FOG i and s_i
//! with FOG j, the others not faulty). The faulty set names the hypothesis; it is the
//! verdict when it fits at two frames in a row (one bad frame is undone by the next, as
//! Φ telescopes).
//!
//! With no FOG faulty after [`PASS_SPAN_US`] the power-on check has passed. FOGs it
//! could not verify are watched on: the evidence starts again every [`PASS_SPAN_US`]
//! (so the bias term stays small), until a turn about their axes verifies them or shows
//! them wrong (a flip of FOG1 under Earth pointing shows at the first roll). A flipped FOG is isolated; a swapped pair is flown on the corrected
//! assignment (isolating both would leave two gyros, which cannot give a 3-axis rate,
//! and isolating one leaves the other reading the wrong axis).
//!
//! Every sum is a running sum: O(1) per sample and per star-tracker frame.

use nalgebra::{Quaternion, Vector3, Vector4};

use crate::calib::N_FOG;
use crate::math;
use crate::state::{Flag, Maybe};

/// Threshold on a FOG's evidence, in its own σ (noise of two star-tracker frames and the
/// FOG's random walk): with four FOGs tested at every frame, a false "faulty" about once
/// in 1e8 frames of noise.
pub const K_MOUNT: f64 = 6.5;
/// Largest bias residue calibration can leave, rad/s (1 °/h: three times the paper's
/// pre-calibration 3σ of ±0.3 °/h; after calibration 0.05 °/h).
pub const BIAS_MAX_RAD_S: f64 = 1.0 * core::f64::consts::PI / 180.0 / 3600.0;
/// Relative residue of scale factor and axes after calibration (as the parity check's).
pub const MODEL_RESIDUAL: f64 = crate::integrity::parity::MODEL_RESIDUAL;
/// Span before any verdict, µs (4 frames at 4 Hz: one frame is not evidence).
pub const MIN_SPAN_US: u64 = 1_000_000;
/// Span after which, with no FOG faulty, the unit reports aligned, µs.
pub const REPORT_SPAN_US: u64 = 2_000_000;
/// Span after which, with no FOG faulty, the check ends with what it verified, µs.
pub const PASS_SPAN_US: u64 = 10_000_000;
/// Span after which the check ends in any case, µs (60 s).
pub const MAX_SPAN_US: u64 = 60_000_000;
/// Samples in a row a FOG of the check must miss before it leaves the check (200 ms at
/// 5 ms, as a lost FOG): a shorter gap only skips the interval between two frames.
pub const LEAVE_SAMPLES: u16 = 40;
/// Every FOG slot.
const ALL_FOGS: u8 = (1 << N_FOG) - 1;

/// What the check found.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MountVerdict {
    /// FOG i reads with reversed polarity (mounted backwards or its sign wired wrong).
    Flipped(usize),
    /// FOGs i and j are in each other's mounts (each reads the other's axis).
    Swapped(usize, usize),
    /// FOG i disagrees with the tracker and no single flip or swap explains it
    /// (decided only at the end of the check, when it alone is faulty).
    Unexplained(usize),
}

/// State of the check.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MountState {
    /// Collecting evidence.
    Checking,
    /// The power-on check passed; the FOGs it could not verify are watched on.
    Watching {
        /// FOGs not verified yet (bit i).
        unverified: u8,
    },
    /// Done without a fault: every FOG verified.
    Passed {
        /// FOGs the motion did not verify (bit i).
        unverified: u8,
    },
    /// Done with a verdict (acted on by the caller).
    Found(MountVerdict),
    /// Done at [`MAX_SPAN_US`] with FOGs at odds with the tracker that no hypothesis
    /// explains.
    Undecided {
        /// The FOGs at odds (bit i).
        faulty: u8,
    },
}

/// A verdict, or none, as the check stores it: a kind (0: none) and the FOGs. Every
/// triple decodes: an unknown kind or a FOG that is not one as no verdict.
#[derive(Debug, Clone, Copy, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
#[repr(C)]
struct VerdictCode {
    kind: u8,
    i: u8,
    j: u8,
}

impl VerdictCode {
    fn of(v: Option<MountVerdict>) -> Self {
        let fog = |i: usize| u8::try_from(i).unwrap_or(u8::MAX);
        match v {
            None => VerdictCode { kind: 0, i: 0, j: 0 },
            Some(MountVerdict::Flipped(i)) => VerdictCode { kind: 1, i: fog(i), j: 0 },
            Some(MountVerdict::Swapped(i, j)) => VerdictCode { kind: 2, i: fog(i), j: fog(j) },
            Some(MountVerdict::Unexplained(i)) => VerdictCode { kind: 3, i: fog(i), j: 0 },
        }
    }

    fn get(self) -> Option<MountVerdict> {
        let (i, j) = (usize::from(self.i), usize::from(self.j));
        if i >= N_FOG || j >= N_FOG {
            return None;
        }
        match self.kind {
            1 => Some(MountVerdict::Flipped(i)),
            2 => Some(MountVerdict::Swapped(i, j)),
            3 => Some(MountVerdict::Unexplained(i)),
            _ => None,
        }
    }
}

/// [`MountState`] as the check stores it: a kind, the FOG bits and the verdict. Every
/// pattern decodes: an unknown one (or a verdict that is none) as [`MountState::Checking`],
/// which does not clear the unit to report while a FOG is at odds.
#[derive(Debug, Clone, Copy, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
#[repr(C)]
struct StateCode {
    kind: u8,
    bits: u8,
    verdict: VerdictCode,
}

impl StateCode {
    fn of(s: MountState) -> Self {
        let (kind, bits, v) = match s {
            MountState::Checking => (0, 0, None),
            MountState::Watching { unverified } => (1, unverified, None),
            MountState::Passed { unverified } => (2, unverified, None),
            MountState::Found(v) => (3, 0, Some(v)),
            MountState::Undecided { faulty } => (4, faulty, None),
        };
        StateCode { kind, bits, verdict: VerdictCode::of(v) }
    }

    fn get(self) -> MountState {
        match (self.kind, self.verdict.get()) {
            (1, _) => MountState::Watching { unverified: self.bits },
            (2, _) => MountState::Passed { unverified: self.bits },
            (3, Some(v)) => MountState::Found(v),
            (4, _) => MountState::Undecided { faulty: self.bits },
            _ => MountState::Checking,
        }
    }
}

/// The previous star-tracker frame: its time tag, Λ* (ICS) and the FOGs' sums at it.
#[derive(Debug, Clone, Copy, PartialEq, bytemuck::AnyBitPattern)]
struct Anchor {
    time_us: u64,
    q: Quaternion<f64>,
    acc_rad: Vector4<f64>,
}

/// The mounting check.
#[derive(Debug, Clone, Copy, PartialEq, bytemuck::AnyBitPattern)]
pub struct MountCheck {
    axes: [Vector3<f64>; N_FOG],
    /// 2 σ_st², rad².
    st_var_rad2: f64,
    /// σ_v² per second (angle random walk), rad²/s.
    arw_var_rad2_s: f64,
    /// Step, µs (to extrapolate a FOG's sum back to a frame's time tag).
    dt_us: u32,
    /// Running sums of every FOG's increments since the check (re)started, rad.
    acc_rad: Vector4<f64>,
    /// The last sample's increments, rad.
    last_rad: Vector4<f64>,
    /// Unit time at the end of the last sample, µs.
    last_us: u64,
    anchor: Maybe<Anchor>,
    start_us: u64,
    s_rad: Vector4<f64>,
    phi_rad: Vector3<f64>,
    verified: u8,
    faulty: u8,
    /// The FOGs the evidence is about (bit i): all at each start of the evidence, less a
    /// FOG that missed [`LEAVE_SAMPLES`] in a row (lost: the others' evidence goes on).
    fogs: u8,
    /// A FOG of the check missed a sample since the last frame: the interval to the next
    /// frame is no one's evidence.
    broken: Flag,
    /// Samples in a row that missed a FOG of the check.
    missing_run: u16,
    /// The hypothesis that fitted at the last frame.
    pending: VerdictCode,
    state: StateCode,
}

impl MountCheck {
    /// A check of the mounting `axes` (rows of H, ICS) with star-tracker noise
    /// `st_sigma_rad` (1σ per axis), FOG noise `sample_noise_rad` per sample of `dt_us`.
    pub fn new(axes: [Vector3<f64>; N_FOG], st_sigma_rad: f64, sample_noise_rad: f64, dt_us: u32) -> Self {
        let dt_s = f64::from(dt_us.max(1)) * 1e-6;
        MountCheck {
            axes,
            st_var_rad2: 2.0 * st_sigma_rad * st_sigma_rad,
            arw_var_rad2_s: sample_noise_rad * sample_noise_rad / dt_s,
            dt_us: dt_us.max(1),
            acc_rad: Vector4::zeros(),
            last_rad: Vector4::zeros(),
            last_us: 0,
            anchor: Maybe::none(),
            start_us: 0,
            s_rad: Vector4::zeros(),
            phi_rad: Vector3::zeros(),
            verified: 0,
            faulty: 0,
            fogs: ALL_FOGS,
            broken: Flag::CLEAR,
            missing_run: 0,
            pending: VerdictCode::of(None),
            state: StateCode::of(MountState::Checking),
        }
    }

    /// State of the check.
    pub fn state(&self) -> MountState {
        self.state.get()
    }

    /// Whether the check still collects evidence (at power-on, or watching FOGs it
    /// could not verify).
    #[inline]
    pub fn checking(&self) -> bool {
        // `StateCode::get` read for the two states that check (any unknown code reads
        // as checking), without decoding the verdict on every sample.
        match self.state.kind {
            2 | 4 => false,
            3 => self.state.verdict.get().is_none(),
            _ => true,
        }
    }

    /// Whether the unit may report itself aligned: the check is done, or it has run
    /// [`REPORT_SPAN_US`] and no FOG disagrees with the tracker.
    pub fn clear_to_report(&self) -> bool {
        match self.state.get() {
            MountState::Watching { .. } => self.faulty == 0,
            MountState::Checking => {
                self.faulty == 0
                    && self.anchor.get().is_some_and(|a| a.time_us.saturating_sub(self.start_us) >= REPORT_SPAN_US)
            }
            _ => true,
        }
    }

    /// FOGs at odds with the tracker at the last frame (bit i).
    pub fn faulty(&self) -> u8 {
        self.faulty
    }

    /// FOGs verified so far (bit i).
    pub fn verified(&self) -> u8 {
        self.verified
    }

    /// FOGs the evidence is about (bit i): a FOG lost meanwhile has left it.
    pub fn fogs(&self) -> u8 {
        self.fogs
    }

    /// One sample: every FOG's compensated increment `m_rad` (`used`: bit i, FOG i was
    /// there and usable) ending at unit time `t_us`. A sample that misses a FOG of the
    /// check makes the interval between the frames around it no one's evidence (a FOG's
    /// sum would miss it, and Φ must span what the sums span); a FOG that misses
    /// [`LEAVE_SAMPLES`] in a row leaves the check, so the others' evidence goes on.
    pub fn on_sample(&mut self, m_rad: &Vector4<f64>, used: u8, t_us: u64) {
        if !self.checking() {
            return;
        }
        let missing = self.fogs & !used;
        if missing != 0 {
            self.missing_run = self.missing_run.saturating_add(1);
            if self.missing_run < LEAVE_SAMPLES {
                self.broken = Flag::SET;
                return;
            }
            self.fogs &= used;
            self.faulty &= used;
            self.pending = VerdictCode::of(None);
        }
        self.missing_run = 0;
        self.acc_rad += m_rad;
        self.last_rad = *m_rad;
        self.last_us = t_us;
    }

    /// One star-tracker frame: Λ* taken to the ICS `q_ics` with time tag `time_us` (at or
    /// before the last sample's end). Returns the verdict when one is reached.
    pub fn on_frame(&mut self, time_us: u64, q_ics: &Quaternion<f64>) -> Option<MountVerdict> {
        if !self.checking() || time_us > self.last_us {
            return None;
        }
        // The FOGs' sums at the time tag: back from the last sample on its own increments
        // (a tag lags by the tracker's latency, a few samples).
        let back = f64::from(u32::try_from(self.last_us - time_us).unwrap_or(u32::MAX)) / f64::from(self.dt_us);
        let acc_rad = self.acc_rad - self.last_rad * back;
        let here = Anchor { time_us, q: *q_ics, acc_rad };
        let prev = self.anchor.get();
        self.anchor = Maybe::some(here);
        let Some(prev) = prev else {
            self.restart_evidence(time_us);
            return None;
        };
        if time_us <= prev.time_us {
            self.anchor = Maybe::some(prev);
            return None;
        }
        if self.broken.get() {
            // A sample missed since the previous frame: this interval is skipped.
            self.broken = Flag::CLEAR;
            return None;
        }
        self.phi_rad += math::rotvec_from_quat(&(prev.q.conjugate() * q_ics));
        self.s_rad += acc_rad - prev.acc_rad;
        // A start after now is a corrupted state (a flipped bit): the evidence starts again.
        let Some(span_us) = time_us.checked_sub(self.start_us) else {
            self.restart_evidence(time_us);
            return None;
        };
        if span_us < MIN_SPAN_US {
            return None;
        }
        self.decide(span_us)
    }

    /// Evidence from the frame at `time_us` on.
    fn restart_evidence(&mut self, time_us: u64) {
        self.start_us = time_us;
        self.fogs = ALL_FOGS;
        self.broken = Flag::CLEAR;
        self.s_rad = Vector4::zeros();
        self.phi_rad = Vector3::zeros();
        self.faulty = 0;
        self.pending = VerdictCode::of(None);
    }

    /// The threshold τ for a span of `span_us`, rad.
    fn threshold_rad(&self, span_us: u64) -> f64 {
        let t_s = f64::from(u32::try_from(span_us).unwrap_or(u32::MAX)) * 1e-6;
        K_MOUNT * math::sqrt(self.st_var_rad2 + self.arw_var_rad2_s * t_s)
            + BIAS_MAX_RAD_S * t_s
            + MODEL_RESIDUAL * self.phi_rad.norm()
    }

    /// Whether axis `c` is consistent with FOG `i`'s evidence.
    fn consistent(&self, i: usize, c: &Vector3<f64>, tau: f64) -> bool {
        self.s_rad.get(i).is_some_and(|s| (s - c.dot(&self.phi_rad)).abs() <= tau)
    }

    fn decide(&mut self, span_us: u64) -> Option<MountVerdict> {
        let tau = self.threshold_rad(span_us);
        let axes = self.axes;
        self.faulty = 0;
        for (i, a) in axes.iter().enumerate() {
            if self.fogs & (1 << i) == 0 {
                continue;
            }
            if !self.consistent(i, a, tau) {
                self.faulty |= 1 << i;
            } else if self.verified & (1 << i) == 0 && self.others_excluded(i, tau) {
                self.verified |= 1 << i;
            }
        }
        let fits = self.hypothesis(tau);
        let confirmed = fits.filter(|v| self.pending.get() == Some(*v));
        self.pending = VerdictCode::of(fits);
        if let Some(v) = confirmed {
            self.state = StateCode::of(MountState::Found(v));
            return confirmed;
        }
        let all = ALL_FOGS;
        if self.faulty == 0 && self.verified == all {
            self.state = StateCode::of(MountState::Passed { unverified: 0 });
        } else if self.faulty == 0 && span_us >= PASS_SPAN_US {
            self.state = StateCode::of(MountState::Watching { unverified: all & !self.verified });
            self.restart_evidence(self.anchor.get().map_or(self.start_us, |a| a.time_us));
        } else if span_us >= MAX_SPAN_US {
            if self.faulty.count_ones() == 1 {
                let v = MountVerdict::Unexplained(self.faulty.trailing_zeros() as usize);
                self.state = StateCode::of(MountState::Found(v));
                return Some(v);
            }
            self.state = StateCode::of(MountState::Undecided { faulty: self.faulty });
        }
        None
    }

    /// Whether every candidate axis other than FOG i's own (−s_i, ±s_j) is inconsistent
    /// with FOG i's evidence.
    fn others_excluded(&self, i: usize, tau: f64) -> bool {
        self.axes.iter().enumerate().all(|(j, a)| {
            let minus = !self.consistent(i, &-a, tau);
            let plus = j == i || !self.consistent(i, a, tau);
            minus && plus
        })
    }

    /// The single flip or swap that explains the faulty FOGs: the faulty set names the
    /// hypothesis (one FOG: a flip, two: their swap). Each faulty FOG's own axis must be
    /// off by twice the threshold, so a FOG at the threshold's edge waits for evidence.
    fn hypothesis(&self, tau: f64) -> Option<MountVerdict> {
        let axis = |i: usize| self.axes.get(i).copied().unwrap_or_else(Vector3::zeros);
        let clear = |i: usize| !self.consistent(i, &axis(i), 2.0 * tau);
        let i = self.faulty.trailing_zeros() as usize;
        match self.faulty.count_ones() {
            1 => (clear(i) && self.consistent(i, &-axis(i), tau)).then_some(MountVerdict::Flipped(i)),
            2 => {
                let j = (self.faulty & !(1 << i)).trailing_zeros() as usize;
                let fits = self.consistent(i, &axis(j), tau) && self.consistent(j, &axis(i), tau);
                (clear(i) && clear(j) && fits).then_some(MountVerdict::Swapped(i, j))
            }
            _ => None,
        }
    }
}
