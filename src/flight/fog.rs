//! The FOG channels of one sample: intake of each fitted FOG's frame, the channel checks
//! (stuck output, temperature sensor, device fault, range), thermal tracking and
//! compensation ([`FlightCore::take_sample`]), and the lasting changes of the FOG set
//! (a FOG lost, restored); then the four-FOG parity check, which may drop a spike or the
//! isolated FOG ([`FlightCore::check_parity`]). Every cause of an isolation (the parity
//! verdict, a channel refused during an alarm, the star tracker's verdict, the mounting
//! check) goes through one routine, [`FlightCore::isolate`].

use nalgebra::{Vector3, Vector4};

use super::FlightCore;
use crate::calib::{FogCal, N_FOG};
use crate::combination::FogSet;
use crate::compensation::{compensate_increment, ThermalTracker};
use crate::frames::fog::{status, FogFrame};
use crate::integrity::channel::ChannelMonitor;
use crate::integrity::parity::SampleVerdict;
use crate::telemetry::events::Event;
use crate::telemetry::{health, Counter, Counters, FogCounter, FogSetChange};

/// Why a FOG is isolated (`isolated`, detail b).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) enum IsolationCause {
    /// The parity check named it (its verdict on a sample of all four).
    Parity,
    /// Its own channel checks refused it while a parity alarm stood.
    ChannelRefused,
    /// The star tracker named it while a parity alarm stood: the fault's drift since the
    /// alarm (ICS, rad/s) leaves the attitude.
    StarAided {
        /// Unit time of the alarm, µs.
        since_us: u64,
        /// The fault's attitude drift since then, rad/s.
        drift_rad_s: Vector3<f64>,
    },
    /// The mounting check found it reversed, or alone at odds with the tracker: the
    /// estimator starts again, so nothing of the wrong gyro stays in it.
    Mounting,
}

impl IsolationCause {
    /// Its code in the event (`docs/ICD.md`, event `isolated`).
    fn code(&self) -> u16 {
        match self {
            IsolationCause::Parity => 1,
            IsolationCause::ChannelRefused => 2,
            IsolationCause::StarAided { .. } => 3,
            IsolationCause::Mounting => 4,
        }
    }
}

/// What one FOG gave for one sample.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) enum FogValue {
    /// No sample arrived.
    Missing,
    /// The sample arrived but is not used (device fault, stuck, out of range).
    Refused,
    /// The compensated increment, rad.
    Used(f64),
}

/// One FOG's sample after intake, the channel checks and compensation.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) struct FogTaken {
    /// Health bits ([`health`]).
    health: u8,
    value: FogValue,
}

/// One sample of every fitted FOG.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) struct Sample {
    /// Compensated increments, rad (0 for a FOG not used).
    pub(super) dtheta: Vector4<f64>,
    /// FOGs to combine.
    pub(super) used: FogSet,
    /// Health bits per FOG ([`health`]).
    pub(super) health: [u8; N_FOG],
}

impl FlightCore {
    /// Takes sample `target` from every fitted FOG that has it: intake, channel checks,
    /// compensation.
    pub(super) fn take_sample(&mut self, target: u16, dt_s: f64) -> Sample {
        let fitted = self.profile.fogs;
        let gap = self.fog_intake.begin(target);
        let limit_rad = self.profile.rate_limit_rad_s * dt_s;
        let mut dtheta = [0.0f64; N_FOG];
        let mut health_bits = [health::EXCLUDED; N_FOG];
        let mut used = 0u8;
        let mut present = 0u8;
        let stages = self.channel_monitors.iter_mut().zip(self.thermal.iter_mut()).zip(&self.table.fog);
        for (i, (((monitor, thermal), cal), (d, h))) in
            stages.zip(dtheta.iter_mut().zip(health_bits.iter_mut())).enumerate()
        {
            let bit = 1u8 << i;
            if fitted.0 & bit == 0 {
                continue;
            }
            let arrival = self.fog_intake.take(i, target, &mut self.telemetry.counters);
            let taken = match arrival.frame {
                None => FogTaken { health: arrival.health, value: FogValue::Missing },
                Some(frame) => {
                    let counters = &mut self.telemetry.counters;
                    let step = StepFigures { dt_s, limit_rad };
                    let taken = check_and_compensate(i, &frame, monitor, thermal, cal, step, counters);
                    FogTaken { health: arrival.health | taken.health, value: taken.value }
                }
            };
            if taken.health & health::USED != 0 && monitor.temp_failed() {
                self.temp_failed_bits |= bit;
            }
            *h = taken.health | gap;
            match taken.value {
                FogValue::Missing => {}
                FogValue::Refused => present |= bit,
                FogValue::Used(v) => {
                    present |= bit;
                    *d = v;
                    used |= bit;
                }
            }
        }
        self.fog_intake.end(FogSet(present));
        if self.telemetry.fog_set.changing(FogSet(used)) {
            self.watch_fog_set(FogSet(used), &health_bits);
        }
        Sample { dtheta: Vector4::from(dtheta), used: FogSet(used), health: health_bits }
    }

    /// The FOG set changed in this sample, or a change is being counted: a FOG unusable
    /// for [`crate::telemetry::FOG_SET_SAMPLES`] in a row is lost, a lost one usable as
    /// long is restored; each recorded with its cause (`fog_lost`: the health bits of
    /// its last sample). An isolated FOG is not watched (its isolation is recorded).
    #[inline(never)]
    fn watch_fog_set(&mut self, used: FogSet, health_bits: &[u8; N_FOG]) {
        let now_us = self.fog_intake.time_us(self.profile.dt_us);
        let watched = self.flying();
        let (events, counters) = (&mut self.events, &mut self.telemetry.counters);
        let mut watch = self.telemetry.fog_set;
        watch.on_sample(used, watched, |c| {
            let (event, i, why) = match c {
                FogSetChange::Lost(i) => (Event::FogLost, i, health_bits.get(i).copied().unwrap_or(0)),
                FogSetChange::Restored(i) => (Event::FogRestored, i, 0),
            };
            events.record(counters, now_us, event, u8::try_from(i + 1).unwrap_or(0), u16::from(why));
        });
        self.telemetry.fog_set = watch;
    }

    /// Isolates FOG `i` for `cause` at unit time `now_us`: the one routine every cause
    /// calls. The parity logic's own verdicts have isolated it already; on the mounting
    /// check's verdict it is isolated here (unless another FOG is). Then, once, whatever
    /// the cause: counted and logged (`isolated`, with the cause), the estimate cleared
    /// of what the gyro put in it (the fault's drift since the alarm on the star
    /// tracker's verdict; the estimator started again on the mounting check's; else the
    /// gyro's share of the drift estimate), and the estimators' noise that of the FOGs
    /// flying from now on.
    pub(super) fn isolate(&mut self, i: usize, cause: IsolationCause, now_us: u64) {
        let Some(fdi) = self.fdi.as_mut() else { return };
        let done = match cause {
            IsolationCause::Mounting => fdi.isolate_mounted_wrong(i),
            _ => fdi.isolated() == Some(i),
        };
        if !done {
            return;
        }
        // Λ and Δω change below: compared with their twins first, sealed after.
        self.twin_check_rare();
        let counters = &mut self.telemetry.counters;
        self.events.record(counters, now_us, Event::Isolated, u8::try_from(i + 1).unwrap_or(0), cause.code());
        match cause {
            IsolationCause::Mounting => {
                counters.bump(Counter::MountIsolated);
                self.guard_touch_tuning();
                self.observer.restart();
                self.observer.set_noise(&super::geometry::flying_noise(&self.combiner, self.flying()));
            }
            IsolationCause::StarAided { since_us, drift_rad_s } => {
                self.observer.remove_drift(&mut self.attitude, now_us, since_us, &drift_rad_s);
                self.on_isolation(i, now_us);
            }
            IsolationCause::Parity | IsolationCause::ChannelRefused => self.on_isolation(i, now_us),
        }
        self.twin_seal();
    }

    /// Integrity, parity: checks a sample of all four FOGs and drops a spike, or the
    /// isolated FOG, from it. Returns the parity residual, rad (0 unless all four were
    /// there and none is isolated).
    pub(super) fn check_parity(&mut self, sample: &mut Sample, time_us: u64) -> f64 {
        let Some(fdi) = self.fdi.as_mut() else { return 0.0 };
        let before = fdi.state();
        let was_isolated = fdi.isolated().is_some();
        let mut parity_rad = 0.0;
        let mut cause = IsolationCause::Parity;
        let drop = match fdi.isolated() {
            Some(i) => Some(i),
            None if sample.used == FogSet::ALL => {
                parity_rad = self.combiner.parity(&sample.dtheta);
                match fdi.on_sample(&sample.dtheta, parity_rad, self.last_body_dtheta.norm_squared(), time_us) {
                    SampleVerdict::Use => None,
                    SampleVerdict::Drop(i) | SampleVerdict::Isolate(i) => {
                        self.telemetry.counters.bump_fog(i, FogCounter::Spikes);
                        Some(i)
                    }
                }
            }
            None => {
                fdi.on_partial_sample();
                // A fitted gyro refused by its own checks during an alarm is the faulty one.
                let refused = self.profile.fogs.0 & !sample.used.0;
                if fdi.alarm() && refused.count_ones() == 1 {
                    let i = refused.trailing_zeros() as usize;
                    fdi.isolate_failed_channel(i);
                    cause = IsolationCause::ChannelRefused;
                    Some(i)
                } else {
                    None
                }
            }
        };
        self.telemetry.counters.count_fdi(before, fdi.state());
        let newly = if was_isolated { None } else { fdi.isolated() };
        if let Some(i) = newly {
            // Isolated in this sample: its share leaves the drift estimate too.
            self.isolate(i, cause, time_us);
        }
        if let Some(i) = drop {
            sample.used = sample.used.without(i);
            if let Some(h) = sample.health.get_mut(i) {
                *h = (*h & !health::USED) | health::EXCLUDED;
            }
        }
        parity_rad
    }
}

/// The step's figures every channel's checks use.
#[derive(Clone, Copy)]
struct StepFigures {
    /// Step period, s.
    dt_s: f64,
    /// Largest angle increment in range, rad.
    limit_rad: f64,
}

/// FOG `i`'s frame through its channel's checks (integrity), thermal tracking and
/// compensation.
#[inline]
fn check_and_compensate(
    i: usize,
    frame: &FogFrame,
    monitor: &mut ChannelMonitor,
    thermal: &mut ThermalTracker,
    cal: &FogCal,
    step: StepFigures,
    counters: &mut Counters,
) -> FogTaken {
    let StepFigures { dt_s, limit_rad } = step;
    let stuck = monitor.stuck(frame);
    let temp_was_failed = monitor.temp_failed();
    let reading_degc = monitor.temperature(frame, thermal.predicted_degc(dt_s));
    if monitor.temp_failed() && !temp_was_failed {
        counters.bump_fog(i, FogCounter::TempFailures);
    }
    let t = thermal.update(reading_degc, dt_s);
    let refused = |c: FogCounter, health: u8, counters: &mut Counters| {
        counters.bump_fog(i, c);
        FogTaken { health, value: FogValue::Refused }
    };
    if frame.status & (status::LIGHT_SOURCE_FAULT | status::LOOP_LOCK_LOST) != 0 {
        return refused(FogCounter::DeviceFault, health::DEVICE_FAULT, counters);
    }
    if stuck {
        return refused(FogCounter::Stuck, health::STUCK, counters);
    }
    let dtheta = compensate_increment(cal, frame.dtheta_rad(), dt_s, t.t_degc, t.g_degc_s);
    if !dtheta.is_finite() || dtheta.abs() > limit_rad {
        return refused(FogCounter::OutOfRange, health::OUT_OF_RANGE, counters);
    }
    FogTaken { health: health::USED, value: FogValue::Used(dtheta) }
}
