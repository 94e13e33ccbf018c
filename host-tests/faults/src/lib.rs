//! Fault injection: the simulator's frames are damaged on their way to
//! the in-process flight core the way a failing sensor or link would damage them, and
//! the core's output is scored against truth.
//!
//! One run: a scenario (the paper's sensors, Earth pointing, star tracker at 4 Hz),
//! one [`Fault`] from `start_s` for `duration_s` (or to the end), a seed. Scored:
//! - **detected**: the first step at or after the start where the output shows it (the
//!   FOG's health bits, the parity alarm, the isolation bits, the held-temperature bit;
//!   for the star tracker the outage bit or its counters);
//! - **isolated**: which FOG the fault logic isolated, and when;
//! - the attitude error (largest axis, arcsec) before, during and after the fault,
//!   and the largest step-to-step change of the error (a jump in the output);
//! - false alarms: parity alarms, spikes and isolations of healthy FOGs, gated frames.

use anyhow::{Context, Result};
use nalgebra::{Quaternion, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use ssis::calib::{CalibrationTable, Estimator, N_FOG};
use ssis::flight::{flags, health, st_status, Counters, FlightCore, StepOutput};
use ssis::frames::fog::{status, FogFrame};
use ssis::frames::star::StarFrame;
use ssis::frames::Frame;
use ssis::math;
use ssis::observer::SteadyState;

use ssis_common::mock::{MockLink, MockSink};
use ssis_common::ARCSEC_PER_RAD;
use ssis_sim::fog::Mounting;
use ssis_sim::harness::{step_on_mock_links, Evaluator, Observed, Simulation, StepInput};
use ssis_sim::scenario::Scenario;

pub mod mounting;
pub mod upset;

/// What goes wrong.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum FaultKind {
    /// Nothing (false-alarm runs).
    None,
    /// The FOG's raw increment freezes at its last value.
    FogStuck(usize),
    /// The FOG's bias steps by this much, rad/s.
    FogBiasStep(usize, f64),
    /// The FOG's bias ramps at this rate, rad/s².
    FogDriftRamp(usize, f64),
    /// Every `every`-th sample of the FOG carries an extra angle, rad.
    FogSpikes(usize, f64, u64),
    /// The FOG's increment saturates at i32::MIN counts (a NaN or overflow in the FOG
    /// that saturates its field).
    FogNan(usize),
    /// The FOG sends 0 counts: a NaN as the ICD encodes it ("a NaN is sent as 0").
    FogNanAsZero(usize),
    /// The FOG's frames stop.
    FogDropout(usize),
    /// The FOG's temperature reads −128 °C (an open sensor).
    FogTempSensor(usize),
    /// The star tracker stops sending.
    StOutage,
    /// Every `every`-th star-tracker frame is rotated by `k` σ (per-axis σ of the
    /// tracker) about a random axis.
    StOutliers(f64, u64),
    /// The star tracker repeats its last quaternion (time tags go on).
    StFrozen,
    /// Every bit on every link flips with this probability.
    BitErrors(f64),
    /// The FOG carries a constant bias, rad/s, from power-on (the parity baseline takes it
    /// for calibration residue), and its bias steps by a further amount, rad/s, from the
    /// fault's start.
    FogOffsetThenStep(usize, f64, f64),
    /// From power-on, the FOG is mounted backwards (start and duration are ignored).
    FogFlipped(usize),
    /// From power-on, the two FOGs are in each other's mounts.
    FogSwapped(usize, usize),
}

/// A fault and when it acts.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Fault {
    /// What.
    pub kind: FaultKind,
    /// From, s.
    pub start_s: f64,
    /// For how long, s (`f64::INFINITY`: to the end).
    pub duration_s: f64,
}

/// What one run measured.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct FaultRun {
    /// Time from the fault's start to the first output that shows it, s.
    pub detected_after_s: Option<f64>,
    /// Steps from the start to detection.
    pub detected_after_steps: Option<u64>,
    /// The FOG isolated, and when (s after the start).
    pub isolated: Option<(usize, f64)>,
    /// Largest attitude error (any axis, after settling, before the fault), arcsec.
    pub att_before_arcsec: f64,
    /// Largest attitude error during the fault, arcsec.
    pub att_during_arcsec: f64,
    /// Largest attitude error after the fault (to the end of the run), arcsec.
    pub att_after_arcsec: f64,
    /// Largest attitude error from the isolation of a FOG to the end of the run, arcsec
    /// (`None`: nothing isolated).
    pub att_after_isolation_arcsec: Option<f64>,
    /// Largest change of the attitude error from one step to the next after the
    /// fault's end, arcsec (a jump at re-acquisition).
    pub jump_after_arcsec: f64,
    /// Parity alarms, isolations, spike drops (any FOG).
    pub alarms: u32,
    /// Isolations.
    pub isolations: u32,
    /// Spike drops.
    pub spikes: u32,
    /// Spikes put on the FOG's samples.
    pub spikes_sent: u32,
    /// Star-tracker frames gated, and accepted.
    pub st_gated: u32,
    /// Star-tracker frames that updated the observer.
    pub st_accepted: u32,
    /// Star-tracker frames refused as frozen.
    pub st_frozen: u32,
    /// Star-tracker frames damaged as outliers.
    pub outliers_sent: u32,
    /// Outliers the observer took (the step they arrived in updated it).
    pub outliers_accepted: u32,
    /// Undamaged star-tracker frames after settling (the observer converged).
    pub nominal_frames: u32,
    /// Undamaged frames the observer refused (false rejections).
    pub nominal_refused: u32,
    /// Corrupted frames (bit errors) that still decoded: accepted corruption.
    pub corrupted_accepted: u64,
    /// Frames with at least one bit error.
    pub corrupted_sent: u64,
    /// FOG frames with at least one bit error, per FOG.
    pub corrupted_fog_frames: [u64; N_FOG],
    /// Steps flagged degraded during the fault.
    pub degraded_steps: u64,
    /// Steps run.
    pub steps: u64,
    /// The core's counters at the end of the run.
    pub counters: Counters,
    /// The table axis each FOG channel flew on at the end ([`FlightCore::fog_map`]).
    pub fog_map: [usize; N_FOG],
    /// Attitude error per axis at the fault's last step, arcsec.
    pub end_err_arcsec: Option<[f64; 3]>,
    /// The unit's reported attitude 1σ per axis at the fault's last step, arcsec.
    pub end_sigma_arcsec: Option<[f64; 3]>,
}

/// One step of a fault run, as [`run_observed`] hands it out.
#[derive(Debug, Clone, Copy)]
pub struct FaultStep<'a> {
    /// Time tag of the output, s.
    pub t_s: f64,
    /// Whether the fault acted on this step's input.
    pub active: bool,
    /// The core's output.
    pub out: &'a StepOutput,
    /// The core's counters after the step.
    pub counters: &'a Counters,
    /// Attitude error of the output, arcsec per axis (ICS).
    pub att_err_arcsec: [f64; 3],
}

/// When the campaign's faults start, s: after settling, inside the slew of 50–80 s.
pub const FAULT_START_S: f64 = 60.0;

/// The campaign's scenario: the main job's (`scenarios/qemu-flight.toml`: Earth pointing
/// with a 10° roll slew at 50–80 s, the paper's sensors, star tracker 20″ 3σ at 4 Hz)
/// with `seed`, `duration_s` and 40 s of settling.
pub fn scenario(seed: u64, duration_s: f64) -> Result<Scenario> {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenarios/qemu-flight.toml");
    let mut sc = Scenario::from_file(&path).with_context(|| format!("reading {}", path.display()))?;
    sc.seed = seed;
    sc.duration_s = duration_s;
    sc.settle_s = 40.0;
    // The unit's table states what calibration left of each FOG's bias, the scenario's
    // turn-on bias (3σ → 1σ): the estimators' drift covariance at alignment
    // (`ObserverConfig::initial_drift_sigma_deg_h`; the default is the paper's
    // pre-calibration figure).
    if sc.fog.random_bias_3sigma_deg_h > 0.0 {
        let mut o = sc.table.observer.unwrap_or(CalibrationTable::DEFAULT.observer);
        o.initial_drift_sigma_deg_h = sc.fog.random_bias_3sigma_deg_h / 3.0;
        sc.table.observer = Some(o);
    }
    Ok(sc)
}

/// [`scenario`] with `estimator` flying.
pub fn scenario_with(seed: u64, duration_s: f64, estimator: Estimator) -> Result<Scenario> {
    let mut sc = scenario(seed, duration_s)?;
    sc.table.estimator = Some(estimator);
    Ok(sc)
}

/// Runs `sc` with `fault`.
pub fn run(sc: &Scenario, fault: &Fault) -> Result<FaultRun> {
    run_observed(sc, fault, |_| {})
}

/// [`run`], handing every scored step to `on_step` (tests look at the output frame by
/// frame: health bits, flags, the attitude error's course).
pub fn run_observed(sc: &Scenario, fault: &Fault, mut on_step: impl FnMut(&FaultStep)) -> Result<FaultRun> {
    let mut sim = Simulation::new(sc)?;
    mount_for(&mut sim, fault);
    let mut eval = Evaluator::new(&sim);
    let profile = sim.profile;
    let mut core = FlightCore::new(profile, &sim.table, false).map_err(|e| anyhow::anyhow!("core: {e:?}"))?;
    let mut fog_links = [0u64, 1, 2, 3].map(|_| MockLink::ideal());
    let mut star_link = MockLink::ideal();
    let mut out_link = MockSink::default();
    let dt_s = profile.dt_s();
    let end_s = fault.start_s + fault.duration_s;
    let sigma_st_rad = sc.star_tracker.sigma_3sigma_arcsec / 3.0 / ARCSEC_PER_RAD;
    let mut inj = Injector::new(*fault, sigma_st_rad, sc.seed);
    let mut r = FaultRun::default();
    let mut last_err: Option<[f64; 3]> = None;
    while let Some(mut input) = sim.next_step() {
        let t_s = input.n as f64 * dt_s;
        let active = t_s > fault.start_s && t_s <= end_s;
        let outlier = inj.apply(&mut input, active, t_s - fault.start_s, &mut r);
        let sending = match fault.kind {
            FaultKind::FogDropout(i) if active => profile.fogs.without(i),
            _ => profile.fogs,
        };
        if let Some(t) = input.truth {
            eval.push_truth(t);
        }
        let out = step_on_mock_links(&mut core, &mut fog_links, &mut star_link, &mut out_link, &input, sending);
        out_link.bytes.clear();
        r.steps += 1;
        let c = core.counters();
        if outlier {
            r.outliers_sent += 1;
            if out.st_status & st_status::UPDATED != 0 {
                r.outliers_accepted += 1;
            }
        } else if out.st_status & st_status::FRAME != 0 && out.flags & flags::CONVERGED != 0 {
            r.nominal_frames += 1;
            if out.st_status & st_status::REFUSED != 0 {
                r.nominal_refused += 1;
            }
        }
        let Some(rec) = eval.evaluate(&Observed::from(&out)) else { continue };
        let err = rec.att_err_arcsec.iter().fold(0.0f64, |m, e| m.max(e.abs()));
        let t = rec.t_s;
        on_step(&FaultStep { t_s: t, active, out: &out, counters: &c, att_err_arcsec: rec.att_err_arcsec });
        if t >= sc.settle_s && t <= fault.start_s {
            r.att_before_arcsec = r.att_before_arcsec.max(err);
        } else if t > fault.start_s && t <= end_s {
            r.att_during_arcsec = r.att_during_arcsec.max(err);
            if out.flags & flags::DEGRADED != 0 {
                r.degraded_steps += 1;
            }
        } else if t > end_s {
            r.att_after_arcsec = r.att_after_arcsec.max(err);
            if let Some(l) = last_err {
                let d = (0..3).map(|k| (rec.att_err_arcsec[k] - l[k]).abs()).fold(0.0, f64::max);
                r.jump_after_arcsec = r.jump_after_arcsec.max(d);
            }
        }
        last_err = Some(rec.att_err_arcsec);
        if active {
            r.end_err_arcsec = Some(rec.att_err_arcsec);
            r.end_sigma_arcsec = Some(out.att_sigma_rad.map(|s| s * ARCSEC_PER_RAD));
        }
        if t > fault.start_s {
            if r.detected_after_s.is_none() && shows(&fault.kind, &out, &c) {
                r.detected_after_s = Some(t - fault.start_s);
                r.detected_after_steps = Some(((t - fault.start_s) / dt_s).round() as u64);
            }
            if r.isolated.is_none() {
                if let Some(i) = (0..N_FOG).find(|i| out.fdi & (0x10 << i) != 0) {
                    r.isolated = Some((i, t - fault.start_s));
                }
            }
        }
        if out.fdi & 0xF0 != 0 {
            r.att_after_isolation_arcsec = Some(r.att_after_isolation_arcsec.map_or(err, |m| m.max(err)));
        }
    }
    let c = core.counters();
    r.counters = c;
    r.fog_map = core.fog_map();
    r.alarms = c.fdi_alarms;
    r.isolations = c.fdi_isolations;
    r.spikes = c.fog.iter().map(|f| f.spikes).sum();
    r.st_gated = c.st_updates_gated;
    r.st_accepted = c.st_frames_accepted;
    r.st_frozen = c.st_frozen;
    Ok(r)
}

/// Mounts the FOGs of `sim` as `fault` says (an integration fault acts from power-on,
/// on the simulated sensors rather than on their frames); other faults leave them.
pub fn mount_for(sim: &mut Simulation, fault: &Fault) {
    match fault.kind {
        FaultKind::FogFlipped(i) => sim.mount_fogs(Mounting::Flipped(i)),
        FaultKind::FogSwapped(i, j) => sim.mount_fogs(Mounting::Swapped(i, j)),
        _ => {}
    }
}

/// The attitude 1σ per axis after `tau_s` of gyro-only coasting from the steady state
/// `ss` of the per-axis Kalman filter (Farrenkopf 1978), rad: the posterior at an update,
/// P₁₁ = (1 − K_B) M₁₁ and P₁₂ = (1 − K_B) M₁₂ with M₁₂ = −K_U (M₁₁ + R), propagated as
/// P₁₁ − 2τP₁₂ + τ²P₂₂ + σ_v²τ + σ_u²τ³/3.
pub fn coasting_sigma_rad(ss: &SteadyState, tau_s: f64) -> f64 {
    let (k_b, k_u) = (ss.gains.k_b[0], ss.gains.k_u_per_s[0]);
    let m11 = ss.prior_var_rad2;
    let p11 = (1.0 - k_b) * m11;
    let p12 = -(1.0 - k_b) * k_u * (m11 + ss.r_rad2);
    let t = tau_s;
    (p11 - 2.0 * t * p12 + t * t * ss.drift_var_rad2_s2 + ss.arw_var_rad2_s * t + ss.rrw_var_rad2_s3 * t * t * t / 3.0)
        .sqrt()
}

/// Whether the output shows `kind`.
fn shows(kind: &FaultKind, out: &StepOutput, c: &Counters) -> bool {
    let fog_bits = |i: usize, mask: u8| out.fog_health.get(i).is_some_and(|h| h & mask != 0);
    let any_fdi = out.flags & flags::FDI_ALARM != 0 || out.fdi & 0xF0 != 0;
    match *kind {
        FaultKind::None => false,
        FaultKind::FogStuck(i) => fog_bits(i, health::STUCK),
        FaultKind::FogNan(i) => fog_bits(i, health::OUT_OF_RANGE),
        FaultKind::FogNanAsZero(i) => any_fdi || fog_bits(i, health::EXCLUDED | health::STUCK),
        FaultKind::FogDropout(i) => fog_bits(i, health::MISSING),
        FaultKind::FogTempSensor(i) => out.fdi & (1 << i) != 0,
        FaultKind::FogBiasStep(i, _)
        | FaultKind::FogDriftRamp(i, _)
        | FaultKind::FogSpikes(i, _, _)
        | FaultKind::FogOffsetThenStep(i, _, _) => any_fdi || fog_bits(i, health::EXCLUDED),
        FaultKind::StOutage => out.st_status & st_status::OUTAGE != 0,
        FaultKind::StOutliers(..) => c.st_updates_gated > 0,
        FaultKind::StFrozen => c.st_frozen > 0,
        FaultKind::BitErrors(_) => c.fog_frames_rejected > 0 || c.st_frames_rejected > 0,
        FaultKind::FogFlipped(_) | FaultKind::FogSwapped(..) => {
            any_fdi || out.flags & flags::FOGS_REMAPPED != 0 || out.flags & flags::DEGRADED != 0
        }
    }
}

/// The fault's hand on the frames: the fault, what it needs to act, and its memory.
/// Used by [`run`] and by the QEMU runner (`QemuOptions::fault`).
pub struct Injector {
    fault: Fault,
    /// Per-axis σ of the star tracker, rad (the outliers' unit).
    sigma_st_rad: f64,
    rng: ChaCha8Rng,
    stuck: Option<[i32; N_FOG]>,
    frozen: Option<[i32; 4]>,
    st_frames: u64,
}

impl Injector {
    /// An injector of `fault`; `sigma_st_rad` is the star tracker's per-axis σ (the
    /// outliers' unit), `seed` the scenario's seed (the fault's own random draws).
    pub fn new(fault: Fault, sigma_st_rad: f64, seed: u64) -> Self {
        Injector {
            fault,
            sigma_st_rad,
            rng: ChaCha8Rng::seed_from_u64(seed ^ 0xFA17),
            stuck: None,
            frozen: None,
            st_frames: 0,
        }
    }

    /// Damages `input` for the fault (`active`: within its window, `since_s` after its
    /// start); bit errors are counted in `r`. Returns whether a star-tracker outlier was
    /// sent.
    pub fn apply(&mut self, input: &mut StepInput, active: bool, since_s: f64, r: &mut FaultRun) -> bool {
        let fault = self.fault;
        let rng = &mut self.rng;
        let fog = |input: &mut StepInput, i: usize, f: &mut dyn FnMut(&mut FogFrame)| {
            if let Some(bytes) = input.fog_frames.get_mut(i) {
                if let Ok(mut frame) = FogFrame::decode(bytes) {
                    f(&mut frame);
                    *bytes = frame.to_bytes();
                }
            }
        };
        let lsb = FogFrame::DTHETA_LSB_RAD;
        let dt_s = 0.005;
        if let FaultKind::FogOffsetThenStep(i, b, step) = fault.kind {
            let b = if active { b + step } else { b };
            fog(input, i, &mut |f| f.dtheta_counts = f.dtheta_counts.saturating_add((b * dt_s / lsb).round() as i32));
            return false;
        }
        if !active {
            if let FaultKind::FogStuck(i) = fault.kind {
                // Remember the last value before the fault.
                let mut last = 0;
                fog(input, i, &mut |f| last = f.dtheta_counts);
                self.stuck.get_or_insert([0; N_FOG])[i] = last;
            }
            if fault.kind == FaultKind::StFrozen {
                if let Some(f) = star_frame(&input.st_bytes) {
                    self.frozen = Some(f.q_counts);
                }
            }
            return false;
        }
        match fault.kind {
            FaultKind::None
            | FaultKind::FogDropout(_)
            | FaultKind::FogFlipped(_)
            | FaultKind::FogSwapped(..)
            | FaultKind::FogOffsetThenStep(..) => {}
            FaultKind::StOutage => input.st_bytes.clear(),
            FaultKind::FogStuck(i) => {
                let v = self.stuck.map_or(0, |s| s[i]);
                fog(input, i, &mut |f| f.dtheta_counts = v);
            }
            FaultKind::FogBiasStep(i, b) => fog(input, i, &mut |f| {
                f.dtheta_counts = f.dtheta_counts.saturating_add((b * dt_s / lsb).round() as i32)
            }),
            FaultKind::FogDriftRamp(i, a) => fog(input, i, &mut |f| {
                f.dtheta_counts = f.dtheta_counts.saturating_add((a * since_s * dt_s / lsb).round() as i32)
            }),
            FaultKind::FogSpikes(i, size, every) => {
                if input.n.is_multiple_of(every) {
                    r.spikes_sent += 1;
                    fog(input, i, &mut |f| {
                        f.dtheta_counts = f.dtheta_counts.saturating_add((size / lsb).round() as i32)
                    })
                }
            }
            FaultKind::FogNan(i) => fog(input, i, &mut |f| f.dtheta_counts = i32::MIN),
            FaultKind::FogNanAsZero(i) => fog(input, i, &mut |f| f.dtheta_counts = 0),
            FaultKind::FogTempSensor(i) => fog(input, i, &mut |f| {
                f.temperature_counts = i16::MIN / 2;
                f.status &= !status::TEMP_SENSOR_FAULT;
            }),
            FaultKind::StOutliers(k, every) => {
                if let Some(mut f) = star_frame(&input.st_bytes) {
                    self.st_frames += 1;
                    if self.st_frames.is_multiple_of(every) {
                        let axis = Vector3::new(
                            rng.random::<f64>() - 0.5,
                            rng.random::<f64>() - 0.5,
                            rng.random::<f64>() - 0.5,
                        )
                        .normalize();
                        let [w, x, y, z] = f.quaternion();
                        let q = Quaternion::new(w, x, y, z) * math::quat_from_rotvec(&(axis * (k * self.sigma_st_rad)));
                        let q = q.normalize();
                        f = StarFrame::from_physical(f.flags, f.counter, f.time_us, [q.w, q.i, q.j, q.k]);
                        input.st_bytes = f.to_bytes().to_vec();
                        return true;
                    }
                }
            }
            FaultKind::StFrozen => {
                if let Some(mut f) = star_frame(&input.st_bytes) {
                    if let Some(q) = self.frozen {
                        f.q_counts = q;
                        input.st_bytes = f.to_bytes().to_vec();
                    }
                }
            }
            FaultKind::BitErrors(ber) => {
                for (bytes, n) in input.fog_frames.iter_mut().zip(r.corrupted_fog_frames.iter_mut()) {
                    if flip(bytes, ber, rng) {
                        r.corrupted_sent += 1;
                        *n += 1;
                        if FogFrame::decode(bytes).is_ok() {
                            r.corrupted_accepted += 1;
                        }
                    }
                }
                if !input.st_bytes.is_empty() && flip(&mut input.st_bytes, ber, rng) {
                    r.corrupted_sent += 1;
                    if StarFrame::decode(&input.st_bytes).is_ok() {
                        r.corrupted_accepted += 1;
                    }
                }
            }
        }
        false
    }
}

/// The star-tracker frame in a step's bytes (the simulator sends whole frames).
fn star_frame(bytes: &[u8]) -> Option<StarFrame> {
    (bytes.len() == StarFrame::LEN).then(|| StarFrame::decode(bytes).ok()).flatten()
}

/// Flips every bit of `bytes` with probability `ber`; whether any flipped.
fn flip(bytes: &mut [u8], ber: f64, rng: &mut ChaCha8Rng) -> bool {
    let mut any = false;
    for b in bytes.iter_mut() {
        for bit in 0..8 {
            if rng.random::<f64>() < ber {
                *b ^= 1 << bit;
                any = true;
            }
        }
    }
    any
}

/// The sizes faults are stated in: σ₁ of the parity residual and the parity vector.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FaultScale {
    /// σ₁: the parity residual's noise in one sample, rad.
    pub sigma1_rad: f64,
    /// The unit parity vector v.
    pub v: [f64; N_FOG],
    /// Step, s.
    pub dt_s: f64,
    /// The observer's steady state (the outage's coasting prediction).
    pub steady: SteadyState,
}

impl FaultScale {
    /// For the unit of `sc`.
    pub fn of(sc: &Scenario) -> Result<Self> {
        let sim = Simulation::new(sc)?;
        let core = FlightCore::new(sim.profile, &sim.table, false).map_err(|e| anyhow::anyhow!("core: {e:?}"))?;
        let m = core.fdi().ok_or_else(|| anyhow::anyhow!("no parity fault logic for this unit"))?;
        let v = core.combiner().parity_vector();
        let steady = ssis::observer::steady_state(&sim.table.observer).map_err(|e| anyhow::anyhow!("gains: {e:?}"))?;
        Ok(FaultScale { sigma1_rad: m.sigma1_rad(), v: [v[0], v[1], v[2], v[3]], dt_s: sim.profile.dt_s(), steady })
    }

    /// The bias step on FOG `i` that moves the parity residual by `k` σ₁, rad/s.
    pub fn bias_for_sigma_rad_s(&self, i: usize, k: f64) -> f64 {
        k * self.sigma1_rad / (self.v[i].abs() * self.dt_s)
    }
}

fn median(mut v: Vec<f64>) -> Option<f64> {
    v.sort_by(f64::total_cmp);
    v.get(v.len() / 2).copied()
}

fn fmt_opt(x: Option<f64>, prec: usize) -> String {
    x.map_or("–".into(), |x| format!("{x:.prec$}"))
}

/// One row of the campaign: a fault family run over FOGs and seeds.
#[derive(Debug, Clone, PartialEq)]
pub struct CampaignRow {
    /// The fault family, as in the table's first column.
    pub name: String,
    /// How long each fault acted, s.
    pub fault_s: f64,
    /// The runs, each with the FOG the fault was on.
    pub runs: Vec<(usize, FaultRun)>,
}

/// The campaign's Markdown: one line per fault family, the outlier and nominal
/// figures, the long nominal flight.
pub fn report(
    k: &FaultScale,
    rows: &[CampaignRow],
    nominal: Option<&FaultRun>,
    nominal_hours: f64,
    seeds: u64,
) -> String {
    use std::fmt::Write;
    let mut s = String::new();
    let _ = writeln!(
        s,
        "| fault | runs | detected | latency, steps (median / max) | right FOG isolated (within 10 s) | \
         wrong FOG isolated | isolation time, s (median / max) | attitude error max, ″: before / during / after | \
         after isolation, ″ (median / max) | jump after, ″ | false alarms | parity alarms / spike drops / gated frames |"
    );
    let _ = writeln!(s, "|---|---|---|---|---|---|---|---|---|---|---|---|");
    for CampaignRow { name, runs, .. } in rows {
        family_line(&mut s, name, runs);
    }
    let _ = writeln!(s);
    outage_lines(&mut s, k, rows);
    frame_lines(&mut s, rows, nominal, nominal_hours);
    let _ = writeln!(
        s,
        "- Scale: σ₁ = {:.3e} rad (parity residual noise per 5 ms sample); a 5σ₁ step is {:.1} °/h on FOG1–3 and \
         {:.1} °/h on FOG4. Seeds per FOG: {seeds}.",
        k.sigma1_rad,
        k.bias_for_sigma_rad_s(0, 5.0) * ssis_common::DEG_H_PER_RAD_S,
        k.bias_for_sigma_rad_s(3, 5.0) * ssis_common::DEG_H_PER_RAD_S
    );
    s
}

/// The table line of one fault family (see [`report`]'s header for the columns).
fn family_line(s: &mut String, name: &str, runs: &[(usize, FaultRun)]) {
    use std::fmt::Write;
    let n = runs.len();
    let det: Vec<f64> = runs.iter().filter_map(|(_, r)| r.detected_after_steps.map(|x| x as f64)).collect();
    let right = runs.iter().filter(|(i, r)| r.isolated.is_some_and(|(j, _)| j == *i)).count();
    let right10 = runs.iter().filter(|(i, r)| r.isolated.is_some_and(|(j, t)| j == *i && t <= 10.0)).count();
    let t_iso: Vec<f64> = runs.iter().filter_map(|(_, r)| r.isolated.map(|(_, t)| t)).collect();
    let after_iso: Vec<f64> = runs.iter().filter_map(|(_, r)| r.att_after_isolation_arcsec).collect();
    let max = |f: &dyn Fn(&FaultRun) -> f64| runs.iter().map(|(_, r)| f(r)).fold(0.0f64, f64::max);
    let sum = |f: &dyn Fn(&FaultRun) -> u64| runs.iter().map(|(_, r)| f(r)).sum::<u64>();
    let fog_fault = name.starts_with("FOG");
    let healthy = |i: usize, j: usize| !fog_fault || j != i;
    let wrong = runs.iter().filter(|(i, r)| r.isolated.is_some_and(|(j, _)| healthy(*i, j))).count();
    // False alarms: samples of a healthy gyro dropped as spikes and, for faults that
    // are not a FOG's, any parity alarm (isolations of a healthy gyro: their own
    // column).
    let false_alarms: u64 = runs
        .iter()
        .map(|(i, r)| {
            let spikes: u64 = r
                .counters
                .fog
                .iter()
                .enumerate()
                .filter(|(j, _)| healthy(*i, *j))
                .map(|(_, c)| u64::from(c.spikes))
                .sum();
            spikes + if fog_fault { 0 } else { u64::from(r.alarms) }
        })
        .sum();
    let spikes = if runs.iter().any(|(_, r)| r.spikes_sent > 0) {
        format!("{} of {} sent", sum(&|r| u64::from(r.spikes)), sum(&|r| u64::from(r.spikes_sent)))
    } else {
        sum(&|r| u64::from(r.spikes)).to_string()
    };
    let _ = writeln!(
        s,
        "| {name} | {n} | {}/{n} | {} / {} | {} | {wrong} | {} / {} | {:.1} / {:.1} / {:.1} | {} / {} | {:.2} | {false_alarms} | \
         {} / {spikes} / {} |",
        det.len(),
        fmt_opt(median(det.clone()), 0),
        fmt_opt(det.iter().copied().reduce(f64::max), 0),
        if fog_fault { format!("{right}/{n} ({right10}/{n})") } else { "–".into() },
        fmt_opt(median(t_iso.clone()), 2),
        fmt_opt(t_iso.iter().copied().reduce(f64::max), 2),
        max(&|r| r.att_before_arcsec),
        max(&|r| r.att_during_arcsec),
        max(&|r| r.att_after_arcsec),
        fmt_opt(median(after_iso.clone()), 1),
        fmt_opt(after_iso.iter().copied().reduce(f64::max), 1),
        max(&|r| r.jump_after_arcsec),
        sum(&|r| u64::from(r.alarms)),
        sum(&|r| u64::from(r.st_gated)),
    );
}

/// The star-tracker outage families' attitude errors, a line each.
fn outage_lines(s: &mut String, k: &FaultScale, rows: &[CampaignRow]) {
    use std::fmt::Write;
    for CampaignRow { name, runs, fault_s } in rows.iter().filter(|r| r.name.starts_with("star tracker outage")) {
        let predicted = coasting_sigma_rad(&k.steady, *fault_s) * ARCSEC_PER_RAD;
        let (rms, sigma) = end_of_outage(runs);
        let _ = writeln!(
            s,
            "- {name}: at the outage's end, per-axis RMS error over the {} runs {:.2} / {:.2} / {:.2} ″ against the \
             gyro-coasting prediction {predicted:.2} ″ 1σ (ratio {:.2} / {:.2} / {:.2}); the unit's reported 1σ \
             {:.2} / {:.2} / {:.2} ″ (reported / measured {:.2} / {:.2} / {:.2}).",
            runs.len(),
            rms[0],
            rms[1],
            rms[2],
            rms[0] / predicted,
            rms[1] / predicted,
            rms[2] / predicted,
            sigma[0],
            sigma[1],
            sigma[2],
            sigma[0] / rms[0],
            sigma[1] / rms[1],
            sigma[2] / rms[2],
        );
        let errs: Vec<f64> = runs.iter().map(|(_, r)| r.att_during_arcsec.max(r.att_after_arcsec)).collect();
        let within = errs.iter().filter(|&&e| e <= 15.0).count();
        let _ = writeln!(
            s,
            "- {name}: largest attitude error of each run (any axis, during the outage or after it), median {} ″, \
             max {} ″; {within} of {} runs within 15″.",
            fmt_opt(median(errs.clone()), 1),
            fmt_opt(errs.iter().copied().reduce(f64::max), 1),
            errs.len()
        );
    }
}

/// Per-axis RMS of the attitude error at the fault's last step over `runs`, and the mean
/// of the unit's reported 1σ there, arcsec.
pub fn end_of_outage(runs: &[(usize, FaultRun)]) -> ([f64; 3], [f64; 3]) {
    let (mut ss, mut sig, mut n) = ([0.0f64; 3], [0.0f64; 3], 0.0);
    for (_, r) in runs {
        if let (Some(e), Some(s)) = (r.end_err_arcsec, r.end_sigma_arcsec) {
            for k in 0..3 {
                ss[k] += e[k] * e[k];
                sig[k] += s[k];
            }
            n += 1.0;
        }
    }
    let n = f64::max(n, 1.0);
    (ss.map(|x| (x / n).sqrt()), sig.map(|x| x / n))
}

/// The star-tracker outliers rejected, the nominal frames refused, the corrupted frames
/// accepted over all runs, and the long nominal flight's figures.
fn frame_lines(s: &mut String, rows: &[CampaignRow], nominal: Option<&FaultRun>, nominal_hours: f64) {
    use std::fmt::Write;
    let (mut nom, mut refused, mut cs, mut ca) = (0u64, 0u64, 0u64, 0u64);
    let pct = |a: u64, b: u64| if b == 0 { 0.0 } else { 100.0 * a as f64 / b as f64 };
    for CampaignRow { name, runs, .. } in rows.iter().filter(|r| r.name.starts_with("star tracker outliers")) {
        let sent: u64 = runs.iter().map(|(_, r)| u64::from(r.outliers_sent)).sum();
        let acc: u64 = runs.iter().map(|(_, r)| u64::from(r.outliers_accepted)).sum();
        let _ = writeln!(
            s,
            "- {name} (rotations about random axes): {} of {sent} rejected ({:.3} %), {acc} taken.",
            sent - acc,
            pct(sent - acc, sent)
        );
    }
    for CampaignRow { name, runs, .. } in rows {
        for (_, r) in runs {
            cs += r.corrupted_sent;
            ca += r.corrupted_accepted;
            if name.starts_with("none") {
                nom += u64::from(r.nominal_frames);
                refused += u64::from(r.nominal_refused);
            }
        }
    }
    if let Some(r) = nominal {
        nom += u64::from(r.nominal_frames);
        refused += u64::from(r.nominal_refused);
    }
    let _ = writeln!(
        s,
        "- Star-tracker frames refused once converged on nominal data (the \"none\" runs and the nominal flight): \
         {refused} of {nom} ({:.3} %).",
        pct(refused, nom)
    );
    let _ = writeln!(s, "- Frames with bit errors that still decoded (accepted corruption): {ca} of {cs}.");
    if let Some(r) = nominal {
        let _ = writeln!(
            s,
            "- Nominal flight, {nominal_hours} h ({} steps): {} parity alarms, {} isolations, {} spike drops; \
             star-tracker frames gated {} of {} ({:.3} %); attitude error max {:.1}″.",
            r.steps,
            r.alarms,
            r.isolations,
            r.spikes,
            r.st_gated,
            r.st_gated + r.st_accepted,
            pct(u64::from(r.st_gated), u64::from(r.st_gated + r.st_accepted)),
            r.att_before_arcsec
        );
    }
}
