//! Parity fault detection and isolation over the four FOGs.
//!
//! With the calibrated axes as the rows of H (4×3) and v the unit parity vector
//! (v H = 0, [`crate::combination`]), the parity residual of the compensated increments
//! m is p = v · m: white noise of σ₁ = ARW·√Δt when the four gyros agree. A fault f
//! (rad per sample) on gyro i adds v_i f to p, and H⁺_{:,i} f to the combined body
//! increment, so the attitude drifts by u_i P with u_i = H⁺_{:,i} / v_i and P = Σ p.
//!
//! Capabilities:
//! - **detection**: an exponentially weighted mean s of p (weight α = 1/8, σ_s =
//!   σ₁ √(α/(2−α))), less a slow baseline p̄ (time constant [`BASELINE_S`], frozen
//!   while an alarm stands), against K_ALARM σ_s, widened by a model-residual term for
//!   fast motion. The baseline takes up what calibration left of the gyros'
//!   disagreement (constant or slow, as thermal drift: the observer's drift estimate
//!   is there for that); the alarm is for changes. K_ALARM = 6.5: about 1e-10 false
//!   alarms a sample (nothing in 24 h at 200 Hz); a bias step of 5 σ₁ crosses it in
//!   about 4 samples;
//! - **spikes and large steps**: a sample whose residual is above K_SPIKE σ₁ and jumped
//!   by [`K_JUMP`] σ₁ from the previous sample's is tested against the gyros' own history: the
//!   body-rate change implied by each triad (the increments' change since the previous
//!   sample, solved without gyro i, normalised by the triad's noise gain) is small only
//!   for the triad that leaves out the faulty gyro. A clear winner is dropped for that
//!   sample, and the previous sample is cleaned of it, so a step jumps again at the next
//!   sample; [`SPIKE_LATCH`] in a row isolate it for good. A step that is not
//!   attributed at once is left to the detection mean (its level is no longer a jump);
//! - **isolation with the star tracker**: one parity residual cannot name the gyro.
//!   While the alarm stands, the observer only listens: each star-tracker mismatch e_j
//!   is paired with P_j (accumulated since the alarm) and fitted, per hypothesis i, as
//!   e_j = e₀ − c u_i P_j (free offset e₀ and gain c). The hypothesis that explains
//!   the mismatches with c near 1, by a margin over the others, names the gyro; the
//!   attitude is then cleared of the fault's drift since the alarm and the gyro dropped
//!   (reconfiguration to the healthy three). Without the star tracker the alarm stands
//!   (flagged degraded) until it can decide;
//! - **isolation by a channel check**: a gyro whose own checks refuse its samples while
//!   the alarm stands (stuck, out of range, device fault, silent) is the one.
//!
//! Every sum is a running sum: O(1) per sample and per star-tracker frame, no buffers.

use nalgebra::{Matrix3, Matrix3x4, RowVector4, Vector3, Vector4};

use crate::calib::N_FOG;
use crate::state::Maybe;

/// Weight α of the detection mean (1/8: about 16 samples of memory).
pub const ALPHA: f64 = 0.125;
/// Time constant of the parity baseline, s.
pub const BASELINE_S: f64 = 60.0;
/// Samples before the first alarm can be raised (the baseline forms as a plain mean).
pub const WARMUP_SAMPLES: u32 = 200;
/// Alarm threshold on the detection mean, in its own σ.
pub const K_ALARM: f64 = 6.5;
/// Spike threshold on a single sample's residual, in σ₁.
pub const K_SPIKE: f64 = 6.5;
/// A spike's owner: the normalised score of the triad without it must be below this,
/// in σ₁² (noise alone: 2σ₁² on average, above 20σ₁² in about 0.2 % of samples)…
pub const OWNER_MAX: f64 = 20.0;
/// …and every other triad's above 4 times it plus this, in σ₁².
pub const OWNER_MARGIN: f64 = 20.0;
/// A spike must also jump from the previous sample's residual by this, in σ₁ (the jump's
/// noise is √2 σ₁: a level that stays is re-tested in 0.5 % of its samples, while a spike
/// just over K_SPIKE is still caught).
pub const K_JUMP: f64 = 4.0;
/// Consecutive spikes on the same gyro that isolate it.
pub const SPIKE_LATCH: u8 = 3;
/// Samples below half the alarm threshold that end an alarm as a transient (2 s at 5 ms).
pub const CLEAR_SAMPLES: u32 = 400;
/// Relative model residual (scale factor and axis errors after calibration, ~60″):
/// widens the thresholds by this times the body increment.
pub const MODEL_RESIDUAL: f64 = 3e-4;
/// Floor of σ₁, rad (frame quantisation and rounding with ideal sensors).
pub const SIGMA1_FLOOR_RAD: f64 = 1e-9;
/// Star-tracker mismatches needed before an isolation is decided.
pub const ISOLATION_MIN_FRAMES: u32 = 4;
/// Explained mismatch energy needed to isolate, in per-axis mismatch variances.
pub const ISOLATION_MIN_ENERGY: f64 = 100.0;
/// Margin of the best hypothesis over the next, in per-axis mismatch variances.
pub const ISOLATION_MARGIN: f64 = 30.0;
/// Frames after which the observer stops listening and updates again, if no decision.
pub const LISTEN_FRAMES: u32 = 240;

/// What the monitor says of one four-gyro sample.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SampleVerdict {
    /// Use all four.
    Use,
    /// Drop gyro i from this sample (a spike).
    Drop(usize),
    /// Gyro i has just been isolated (repeated spikes): drop it from now on.
    Isolate(usize),
}

/// Isolation decided from the star-tracker mismatches.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Isolation {
    /// The failed gyro.
    pub fog: usize,
    /// Fitted gain c (near 1: the observer listened throughout; the removal uses 1).
    pub gain: f64,
    /// The fault's attitude drift since the alarm, ICS, rad/s (to be removed).
    pub drift_rad_s: Vector3<f64>,
    /// Unit time of the alarm, µs.
    pub since_us: u64,
}

/// State of the fault logic.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FdiState {
    /// No fault seen.
    Watching,
    /// Parity alarm: a gyro is faulty, which one is not known yet (degraded).
    Alarm,
    /// Gyro i is isolated and excluded (reconfigured to the other three).
    Isolated(usize),
}

/// [`FdiState`] as the monitor stores it: a kind and the isolated gyro. Every pair
/// decodes: an unknown kind, or an isolated gyro that is not one, as an alarm (flagged
/// in the output; the fault logic looks at the residual again).
#[derive(Debug, Clone, Copy, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
#[repr(C)]
struct FdiCode {
    kind: u8,
    fog: u8,
}

impl FdiCode {
    const WATCHING: u8 = 0;
    const ALARM: u8 = 1;
    const ISOLATED: u8 = 2;

    #[inline]
    fn of(s: FdiState) -> Self {
        match s {
            FdiState::Watching => FdiCode { kind: Self::WATCHING, fog: 0 },
            FdiState::Alarm => FdiCode { kind: Self::ALARM, fog: 0 },
            FdiState::Isolated(i) => FdiCode { kind: Self::ISOLATED, fog: u8::try_from(i).unwrap_or(u8::MAX) },
        }
    }

    #[inline]
    fn get(self) -> FdiState {
        match self.kind {
            Self::WATCHING => FdiState::Watching,
            Self::ISOLATED if usize::from(self.fog) < N_FOG => FdiState::Isolated(usize::from(self.fog)),
            _ => FdiState::Alarm,
        }
    }
}

/// Running sums of the isolation fit.
#[derive(Debug, Clone, Copy, PartialEq, Default, bytemuck::AnyBitPattern)]
struct Sums {
    n: u32,
    p: f64,
    pp: f64,
    e: Vector3<f64>,
    pe: Vector3<f64>,
}

/// The parity monitor.
#[derive(Debug, Clone, Copy, PartialEq, bytemuck::AnyBitPattern)]
pub struct ParityMonitor {
    v: RowVector4<f64>,
    u: [Vector3<f64>; N_FOG],
    triads: [Matrix3x4<f64>; N_FOG],
    /// 1 / ‖triad i‖²_F: a triad's score divided by its noise gain (the triads with the
    /// skewed FOG4 amplify noise more than the orthogonal one).
    inv_gain: [f64; N_FOG],
    sigma1_rad: f64,
    dt_s: f64,
    alarm2_rad2: f64,
    clear2_rad2: f64,
    spike2_rad2: f64,
    jump2_rad2: f64,
    mean_rad: f64,
    baseline_rad: f64,
    alpha_slow: f64,
    seen: u32,
    last_m: Maybe<Vector4<f64>>,
    /// Parity residual of `last_m` (0 after a spike was taken out of it).
    last_p_rad: f64,
    spike_fog: usize,
    spike_run: u8,
    state: FdiCode,
    alarm_us: u64,
    p_acc_rad: f64,
    samples: u32,
    clear_run: u32,
    sums: Sums,
}

impl ParityMonitor {
    /// A monitor for parity vector `v`, the four-gyro solution `all` and the triad
    /// solutions `without[i]` (gyro i left out), per-sample gyro noise `noise_rad` (1σ),
    /// samples every `dt_s`. `None` when the geometry leaves a gyro out of the parity
    /// (v_i = 0).
    pub fn new(
        v: RowVector4<f64>,
        all: &Matrix3x4<f64>,
        without: [Matrix3x4<f64>; N_FOG],
        noise_rad: f64,
        dt_s: f64,
    ) -> Option<Self> {
        let mut u = [Vector3::zeros(); N_FOG];
        for (i, ui) in u.iter_mut().enumerate() {
            let vi = v.get(i).copied().unwrap_or(0.0);
            if vi.abs() < 1e-3 {
                return None;
            }
            *ui = all.column(i) / vi;
        }
        let mut inv_gain = [0.0; N_FOG];
        for (g, t) in inv_gain.iter_mut().zip(&without) {
            let n2 = t.norm_squared();
            *g = if n2 > 0.0 { 1.0 / n2 } else { 0.0 };
        }
        let s1 = noise_rad.max(SIGMA1_FLOOR_RAD);
        let ss2 = s1 * s1 * ALPHA / (2.0 - ALPHA);
        Some(ParityMonitor {
            v,
            u,
            triads: without,
            inv_gain,
            sigma1_rad: s1,
            dt_s,
            alarm2_rad2: K_ALARM * K_ALARM * ss2,
            clear2_rad2: K_ALARM * K_ALARM * ss2 / 4.0,
            spike2_rad2: K_SPIKE * K_SPIKE * s1 * s1,
            jump2_rad2: K_JUMP * K_JUMP * s1 * s1,
            mean_rad: 0.0,
            baseline_rad: 0.0,
            alpha_slow: (dt_s / BASELINE_S).clamp(1e-9, 1.0),
            seen: 0,
            last_m: Maybe::none(),
            last_p_rad: 0.0,
            spike_fog: 0,
            spike_run: 0,
            state: FdiCode::of(FdiState::Watching),
            alarm_us: 0,
            p_acc_rad: 0.0,
            samples: 0,
            clear_run: 0,
            sums: Sums::default(),
        })
    }

    /// Takes over from `old` (the same unit's monitor on the table before a switch):
    /// a gyro it isolated stays isolated. The residual's statistics start again on the
    /// new geometry.
    pub fn carry_from(&mut self, old: &ParityMonitor) {
        if let FdiState::Isolated(i) = old.state.get() {
            self.state = FdiCode::of(FdiState::Isolated(i));
        }
    }

    /// The output frame's bits of the fault logic: the flag bits
    /// ([`crate::frames::output::flags::FDI_ALARM`] while an alarm stands) and the
    /// fault-logic byte's (FOG i isolated: bit 4 + i).
    #[inline]
    pub fn status_bits(&self) -> (u8, u8) {
        match self.state() {
            FdiState::Alarm => (crate::frames::output::flags::FDI_ALARM, 0),
            FdiState::Isolated(i) => (0, 0x10 << i),
            FdiState::Watching => (0, 0),
        }
    }

    /// State of the fault logic.
    pub fn state(&self) -> FdiState {
        self.state.get()
    }

    /// The isolated gyro, if any.
    pub fn isolated(&self) -> Option<usize> {
        match self.state.get() {
            FdiState::Isolated(i) => Some(i),
            _ => None,
        }
    }

    /// Whether a fault is detected and not yet isolated.
    pub fn alarm(&self) -> bool {
        self.state.get() == FdiState::Alarm
    }

    /// Whether the observer should only listen (alarm, and not yet given up on deciding).
    pub fn listening(&self) -> bool {
        self.alarm() && self.sums.n < LISTEN_FRAMES
    }

    /// The detection statistic s − p̄ (rad) and its alarm threshold (rad, without the
    /// motion term).
    pub fn statistic(&self) -> (f64, f64) {
        (self.mean_rad - self.baseline_rad, crate::math::sqrt(self.alarm2_rad2))
    }

    /// σ₁ in use, rad.
    pub fn sigma1_rad(&self) -> f64 {
        self.sigma1_rad
    }

    /// One sample with all four gyros: compensated increments `m` (rad), their parity
    /// residual `p_rad`, the squared body increment `body2_rad2`, the sample's end `t_us`.
    pub fn on_sample(&mut self, m: &Vector4<f64>, p_rad: f64, body2_rad2: f64, t_us: u64) -> SampleVerdict {
        if self.isolated().is_some() {
            return SampleVerdict::Use;
        }
        let model2 = MODEL_RESIDUAL * MODEL_RESIDUAL * body2_rad2;
        let d_rad = p_rad - self.baseline_rad;
        // A spike or a step shows in the residual's level and as a jump from the previous
        // sample's. A step that was not attributed at once stays in the level but not in
        // the jump, and is left to the mean below: testing its level sample after sample
        // would attribute noise to whichever triad is quietest.
        let jump_rad = p_rad - self.last_p_rad;
        let spike2 = self.spike2_rad2 + model2;
        if d_rad * d_rad > spike2
            && jump_rad * jump_rad > spike2
            && self.last_m.is_some()
            && self.seen >= WARMUP_SAMPLES
        {
            if let Some(i) = self.spike_owner(m) {
                // Keep the previous sample consistent: gyro i's value as the others see it.
                let mut clean = *m;
                if let (Some(ci), Some(vi)) = (clean.get_mut(i), self.v.get(i)) {
                    *ci -= p_rad / vi;
                }
                self.last_m = Maybe::some(clean);
                self.last_p_rad = 0.0;
                self.spike_run = if self.spike_fog == i { self.spike_run.saturating_add(1) } else { 1 };
                self.spike_fog = i;
                if self.spike_run >= SPIKE_LATCH {
                    self.isolate(i);
                    return SampleVerdict::Isolate(i);
                }
                return SampleVerdict::Drop(i);
            }
        }
        self.spike_run = 0;
        self.last_m = Maybe::some(*m);
        self.last_p_rad = p_rad;
        self.mean_rad += ALPHA * (p_rad - self.mean_rad);
        let s = self.mean_rad - self.baseline_rad;
        let s2 = s * s;
        match self.state.get() {
            FdiState::Watching => {
                self.seen = self.seen.saturating_add(1);
                // A plain mean until it would weigh less than the slow one.
                let a = (1.0 / f64::from(self.seen)).max(self.alpha_slow);
                self.baseline_rad += a * (p_rad - self.baseline_rad);
                if s2 > self.alarm2_rad2 + model2 && self.seen > WARMUP_SAMPLES {
                    self.state = FdiCode::of(FdiState::Alarm);
                    self.alarm_us = t_us;
                    self.p_acc_rad = d_rad;
                    self.samples = 1;
                    self.clear_run = 0;
                    self.sums = Sums::default();
                }
            }
            FdiState::Alarm => {
                self.p_acc_rad += d_rad;
                self.samples = self.samples.saturating_add(1);
                if s2 < self.clear2_rad2 {
                    self.clear_run += 1;
                    if self.clear_run >= CLEAR_SAMPLES {
                        self.state = FdiCode::of(FdiState::Watching);
                    }
                } else {
                    self.clear_run = 0;
                }
            }
            FdiState::Isolated(_) => {}
        }
        SampleVerdict::Use
    }

    /// During an alarm, a sample without all four gyros still carries the fault's
    /// drift in time: nothing to add to P (the parity is not defined), but the alarm
    /// stays.
    pub fn on_partial_sample(&mut self) {
        self.last_m = Maybe::none();
        self.last_p_rad = 0.0;
    }

    /// The gyro whose triad (the other three) implies a small body-rate change since the
    /// previous sample while every other triad implies a large one; `None` if unclear.
    fn spike_owner(&self, m: &Vector4<f64>) -> Option<usize> {
        let last = self.last_m.get()?;
        let d = m - last;
        let mut best = (f64::INFINITY, N_FOG);
        let mut second = f64::INFINITY;
        for (i, (t, g)) in self.triads.iter().zip(&self.inv_gain).enumerate() {
            // Normalised by the triad's noise gain: noise alone scores 2σ₁² on average
            // for every triad (d is the difference of two samples).
            let score = (t * d).norm_squared() * g;
            if score < best.0 {
                second = best.0;
                best = (score, i);
            } else if score < second {
                second = score;
            }
        }
        let s12 = self.sigma1_rad * self.sigma1_rad;
        (best.0 < OWNER_MAX * s12 && second > 4.0 * best.0 + OWNER_MARGIN * s12).then_some(best.1)
    }

    /// While an alarm stands, a per-channel check has refused gyro `i`'s sample (stuck,
    /// out of range, device fault, missing): the channel names the faulty gyro.
    /// Isolates it and returns true (only in an alarm).
    pub fn isolate_failed_channel(&mut self, i: usize) -> bool {
        if self.alarm() && i < N_FOG {
            self.isolate(i);
            return true;
        }
        false
    }

    /// Isolates gyro `i` on other evidence (the mounting check found it reversed), in
    /// any state but an isolation. Returns whether it did.
    pub fn isolate_mounted_wrong(&mut self, i: usize) -> bool {
        if self.isolated().is_none() && i < N_FOG {
            self.isolate(i);
            return true;
        }
        false
    }

    /// Gyro `i`'s share of the drift the four-gyro combination shows, ICS, rad/s: the
    /// combination is the triad without i plus u_i p (module doc), so the baseline p̄
    /// (what calibration left of the gyros' disagreement, or a constant fault taken for
    /// it) reaches a drift estimate as u_i p̄ / Δt. On isolating i the estimate loses it.
    pub fn drift_share_rad_s(&self, i: usize) -> Vector3<f64> {
        self.u.get(i).map_or_else(Vector3::zeros, |u| u * (self.baseline_rad / self.dt_s))
    }

    /// The covariance of [`ParityMonitor::drift_share_rad_s`], (rad/s)²: u_i u_iᵀ σ²_p̄ / Δt²
    /// with σ²_p̄ the baseline's noise variance, σ₁²/n while it is a plain mean of n
    /// samples and σ₁² α/(2 − α) as the slow mean of weight α = Δt / [`BASELINE_S`]
    /// (0.027 °/h for the paper's ARW, before u_i).
    pub fn drift_share_cov_rad2_s2(&self, i: usize) -> Matrix3<f64> {
        let plain = 1.0 / f64::from(self.seen.max(1));
        let a = self.alpha_slow;
        let weight = if plain > a { plain } else { a / (2.0 - a) };
        let var_p = self.sigma1_rad * self.sigma1_rad * weight / (self.dt_s * self.dt_s);
        self.u.get(i).map_or_else(Matrix3::zeros, |u| u * u.transpose() * var_p)
    }

    fn isolate(&mut self, i: usize) {
        self.state = FdiCode::of(FdiState::Isolated(i));
    }

    /// One star-tracker mismatch `e_rad` (ICS, the observer's e) while listening;
    /// `var_rad2` is its expected variance per axis. Returns the isolation when decided
    /// (the caller removes `drift_rad_s` since `since_us` and drops the gyro).
    pub fn on_mismatch(&mut self, e_rad: &Vector3<f64>, var_rad2: f64) -> Option<Isolation> {
        if !self.alarm() {
            return None;
        }
        let p = self.p_acc_rad;
        let s = &mut self.sums;
        s.n = s.n.saturating_add(1);
        s.p += p;
        s.pp += p * p;
        s.e += e_rad;
        s.pe += e_rad * p;
        if s.n < ISOLATION_MIN_FRAMES {
            return None;
        }
        let n = f64::from(s.n);
        let spp = s.pp - s.p * s.p / n;
        if spp <= 0.0 || !spp.is_finite() {
            return None;
        }
        let spe = s.pe - s.e * (s.p / n);
        let mut best = (0.0f64, N_FOG, 0.0f64);
        let mut second = 0.0f64;
        for (i, u) in self.u.iter().enumerate() {
            let uu = u.norm_squared();
            let a = u.dot(&spe);
            let explained = a * a / (uu * spp);
            if explained > best.0 {
                second = best.0;
                best = (explained, i, -a / (uu * spp));
            } else if explained > second {
                second = explained;
            }
        }
        let (explained, fog, gain) = best;
        let var = var_rad2.max(f64::MIN_POSITIVE);
        let decided = explained > ISOLATION_MIN_ENERGY * var
            && explained - second > ISOLATION_MARGIN * var
            && (0.5..=2.0).contains(&gain);
        if !decided {
            return None;
        }
        let u = self.u.get(fog).copied().unwrap_or_else(Vector3::zeros);
        let elapsed_s = f64::from(self.samples.max(1)) * self.dt_s;
        self.isolate(fog);
        // The attitude error the fault made since the alarm is u_i P exactly (the observer
        // only listened, so nothing of it was corrected): removed with c = 1, not the
        // fitted c, which is known to 10 % at the decision and served only to decide.
        Some(Isolation { fog, gain, drift_rad_s: u * (self.p_acc_rad / elapsed_s), since_us: self.alarm_us })
    }
}
