//! Integration faults from power-on: a FOG mounted backwards, or two FOGs in each other's
//! mounts, flown from the first step, and what the unit's mounting check
//! (`ssis::integrity::mounting`) made of them.
//!
//! Scored per run: when the unit first reported itself aligned, what it found and when
//! (an isolated FOG, a corrected assignment), and the attitude error's course after it,
//! against the same seed flown with the FOGs mounted as the table says.

use anyhow::Result;
use ssis::calib::N_FOG;
use ssis::flight::{flags, st_status};

use crate::{run_observed, Fault, FaultKind, FaultRun};
use ssis_sim::scenario::Scenario;

/// Orbital rate of the campaign's Earth pointing, °/s (a 94-min orbit).
pub const ORBITAL_RATE_DEG_S: f64 = 0.0638;
/// Start of the window in which a nominal run's error statistics are taken, s (after
/// the observer has converged).
pub const NOMINAL_FROM_S: f64 = 60.0;

/// The motion from power-on.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PowerOnMotion {
    /// Orbital rate about an axis that turns every FOG: ω ∝ (1, 2, 3) in the ICS (an
    /// attitude acquisition, or Earth pointing in a rolled and yawed attitude).
    Skewed,
    /// Earth pointing: orbital rate about −Y only, and the campaign's 10° roll slew at
    /// 50–80 s. FOG1 (X) and FOG3 (Z) do not turn at power-on.
    Pitch,
    /// No motion at all.
    Still,
}

impl PowerOnMotion {
    /// Every motion, in the campaign's order.
    pub const ALL: [PowerOnMotion; 3] = [PowerOnMotion::Skewed, PowerOnMotion::Pitch, PowerOnMotion::Still];

    /// Its name in the tables.
    pub fn name(self) -> &'static str {
        match self {
            PowerOnMotion::Skewed => "orbital rate about (1, 2, 3)",
            PowerOnMotion::Pitch => "Earth pointing (pitch only) + roll slew at 50 s",
            PowerOnMotion::Still => "motionless",
        }
    }

    /// Body rate, °/s.
    pub fn rate_deg_s(self) -> [f64; 3] {
        match self {
            PowerOnMotion::Skewed => {
                let n = 14f64.sqrt();
                [ORBITAL_RATE_DEG_S / n, 2.0 * ORBITAL_RATE_DEG_S / n, 3.0 * ORBITAL_RATE_DEG_S / n]
            }
            PowerOnMotion::Pitch => [0.0, -ORBITAL_RATE_DEG_S, 0.0],
            PowerOnMotion::Still => [0.0; 3],
        }
    }
}

/// The campaign's scenario ([`crate::scenario`]) with `motion` from power-on (its roll
/// slew only with [`PowerOnMotion::Pitch`]).
pub fn scenario(seed: u64, duration_s: f64, motion: PowerOnMotion) -> Result<Scenario> {
    let mut sc = crate::scenario(seed, duration_s)?;
    sc.motion.base_rate_deg_s = motion.rate_deg_s();
    if motion != PowerOnMotion::Pitch {
        sc.motion.slews.clear();
    }
    Ok(sc)
}

/// What one run from power-on measured.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct MountRun {
    /// First output reporting the unit aligned (star-tracker status), s.
    pub aligned_at_s: Option<f64>,
    /// First output showing a verdict (an isolated FOG or a corrected assignment), s.
    pub verdict_at_s: Option<f64>,
    /// The largest attitude error (any axis) in each second of flight, arcsec (entry k
    /// covers (k, k + 1] s).
    pub err_per_s_arcsec: Vec<f64>,
    /// Per-axis RMS of the attitude error from [`NOMINAL_FROM_S`] on, arcsec.
    pub rms_arcsec: [f64; 3],
    /// The run's score as the other faults' ([`FaultRun`]: isolation, counters, map).
    pub run: FaultRun,
}

impl MountRun {
    /// The FOG isolated, if any.
    pub fn isolated(&self) -> Option<usize> {
        self.run.isolated.map(|(i, _)| i)
    }

    /// Nominal 3σ of this run (three times the largest axis's RMS), arcsec.
    pub fn three_sigma_arcsec(&self) -> f64 {
        3.0 * self.rms_arcsec.iter().fold(0.0f64, |m, x| m.max(*x))
    }

    /// Seconds from the verdict until the error stays within `bound_arcsec` to the end
    /// of the run (0: it never left it); `None` without a verdict, or if the last second
    /// is still outside.
    pub fn back_within_s(&self, bound_arcsec: f64) -> Option<f64> {
        let v = self.verdict_at_s?;
        let first = v.floor() as usize;
        let tail = self.err_per_s_arcsec.get(first..)?;
        match tail.iter().rposition(|&e| e > bound_arcsec) {
            None => Some(0.0),
            Some(k) if first + k + 1 >= self.err_per_s_arcsec.len() => None,
            Some(k) => Some(((first + k + 1) as f64 - v).max(0.0)),
        }
    }
}

/// Flies `sc` with `kind` (a [`FaultKind::FogFlipped`], [`FaultKind::FogSwapped`] or
/// [`FaultKind::None`]) from power-on.
pub fn run(sc: &Scenario, kind: FaultKind) -> Result<MountRun> {
    let mut m = MountRun::default();
    let mut sumsq = [0.0f64; 3];
    let mut n = 0u64;
    let fault = Fault { kind, start_s: 0.0, duration_s: f64::INFINITY };
    let r = run_observed(sc, &fault, |s| {
        if m.aligned_at_s.is_none() && s.out.st_status & st_status::ALIGNED != 0 {
            m.aligned_at_s = Some(s.t_s);
        }
        if m.verdict_at_s.is_none() && (s.out.fdi & 0xF0 != 0 || s.out.flags & flags::FOGS_REMAPPED != 0) {
            m.verdict_at_s = Some(s.t_s);
        }
        let k = (s.t_s - 1e-9).max(0.0).floor() as usize;
        if m.err_per_s_arcsec.len() <= k {
            m.err_per_s_arcsec.resize(k + 1, 0.0);
        }
        let e = s.att_err_arcsec.iter().fold(0.0f64, |a, x| a.max(x.abs()));
        if let Some(slot) = m.err_per_s_arcsec.get_mut(k) {
            *slot = slot.max(e);
        }
        if s.t_s >= NOMINAL_FROM_S {
            for (acc, x) in sumsq.iter_mut().zip(s.att_err_arcsec) {
                *acc += x * x;
            }
            n += 1;
        }
    })?;
    if n > 0 {
        m.rms_arcsec = sumsq.map(|x| (x / n as f64).sqrt());
    }
    m.run = r;
    Ok(m)
}

/// Whether the run's verdict is the right one for `kind`: a flipped FOG isolated and no
/// other, a swapped pair flown on the corrected assignment with nothing isolated.
pub fn right_verdict(kind: FaultKind, m: &MountRun) -> bool {
    let identity: [usize; N_FOG] = [0, 1, 2, 3];
    match kind {
        FaultKind::FogFlipped(i) => m.isolated() == Some(i) && m.run.fog_map == identity,
        FaultKind::FogSwapped(i, j) => {
            let mut want = identity;
            want.swap(i, j);
            m.isolated().is_none() && m.run.fog_map == want
        }
        _ => m.isolated().is_none() && m.run.fog_map == identity,
    }
}
