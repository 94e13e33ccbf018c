//! The star-tracker aid: every rule of how the unit uses its star tracker. Frames are
//! taken from the link at their time tag ([`crate::intake::StarIntake`]); a frame goes to
//! the mounting check while it runs (eq. 5), to the fault logic while a parity alarm
//! listens for the faulty FOG, and otherwise to the estimator, whose gate, latency
//! alignment on the attitude history and re-acquisition decide its use
//! ([`crate::observer`]). The mounting check's verdict is acted on here (a FOG isolated,
//! a swapped pair remapped), and a re-alignment by the consistency monitor between the
//! tracker and the propagated attitude ([`crate::observer::gate::Monitor`]) counted and
//! logged. Returns the output frame's star-tracker status bits.

use nalgebra::Quaternion;

use super::geometry::{checked_combiner, flying_noise, sample_noise_rad, IDENTITY_MAP};
use super::FlightCore;
use crate::combination::FogSet;
use crate::frames::star::StarFrame;
use crate::intake::{Pending, ST_PENDING};
use crate::integrity::mounting::{MountCheck, MountState, MountVerdict};
use crate::link::RxLink;
use crate::observer::UpdateError;
use crate::telemetry::events::Event;
use crate::telemetry::{flags, st_status, Counter};

use super::fog::IsolationCause;

/// Why the unit no longer reports aligned (`alignment_lost`, detail a).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u8)]
pub(super) enum AlignmentCause {
    /// The estimator starts again (a mounting verdict, guarded state derived again).
    EstimatorRestarted = 1,
    /// The mounting check finds a FOG at odds with the tracker.
    MountingAtOdds = 2,
    /// The mounting check's evidence started again and has not spanned 2 s yet.
    MountingEvidenceRestarted = 3,
}

impl FlightCore {
    /// The mounting check (from power-on) sees every sample of the four FOGs.
    #[inline]
    pub(super) fn mount_check_sample(&mut self, dtheta: &nalgebra::Vector4<f64>, used: FogSet, time_us: u64) {
        let isolated = self.fdi.as_ref().is_some_and(|m| m.isolated().is_some());
        if let Some(m) = self.mounting.as_mut().filter(|m| m.checking() && !isolated) {
            m.on_sample(dtheta, used.0, time_us);
        }
    }

    /// Observer: drains the star-tracker link and applies every valid frame whose time
    /// tag the propagated attitude has reached; later ones wait (up to [`ST_PENDING`]).
    /// Returns the star-tracker status bits.
    pub(super) fn observe_star<S: RxLink>(&mut self, star: &mut S, now_us: u64) -> u8 {
        let mut status = self.star_intake.receive(star, &mut self.rx_scratch.0, &mut self.telemetry.counters);
        // Bounded: at most ST_PENDING frames are examined.
        for _ in 0..ST_PENDING {
            match self.star_intake.next_due(now_us, &mut self.telemetry.counters) {
                Pending::Due(f) => {
                    self.guard_touch();
                    // The estimator's update (or a mounting verdict, an isolation) changes
                    // Λ and Δω: compared with their twins first, sealed after.
                    self.twin_check_rare();
                    status |= self.apply_star(&f, now_us);
                    self.twin_seal();
                }
                Pending::Refused => status |= st_status::REFUSED,
                Pending::Wait => break,
            }
        }
        let aligned = self.observer.aligned();
        if aligned && self.mounting.as_ref().is_none_or(MountCheck::clear_to_report) {
            status |= st_status::ALIGNED;
        } else if self.last_output.st_status & st_status::ALIGNED != 0 {
            self.alignment_lost(now_us);
        }
        status | self.star_intake.outage(now_us, aligned, &mut self.telemetry.counters)
    }

    /// The unit reported aligned at the last step and does not now: recorded with the
    /// cause (`alignment_lost`).
    #[inline(never)]
    pub(super) fn alignment_lost(&mut self, now_us: u64) {
        let cause = if !self.observer.aligned() {
            AlignmentCause::EstimatorRestarted
        } else if self.mounting.as_ref().is_some_and(|m| m.faulty() != 0) {
            AlignmentCause::MountingAtOdds
        } else {
            AlignmentCause::MountingEvidenceRestarted
        };
        self.events.record(&mut self.telemetry.counters, now_us, Event::AlignmentLost, cause as u8, 0);
    }

    /// One star-tracker frame into the observer (or, while a parity alarm stands, into
    /// the fault logic); returns status bits. Out of line (flash: a step calls it only
    /// when a frame is due).
    #[inline(never)]
    fn apply_star(&mut self, f: &StarFrame, now_us: u64) -> u8 {
        let counters = &mut self.telemetry.counters;
        if !f.valid() {
            counters.bump(Counter::StFramesRejected);
            return st_status::REFUSED;
        }
        if self.star_intake.repeats(f) {
            counters.bump(Counter::StFrozen);
            return st_status::REFUSED;
        }
        let [w, x, y, z] = f.quaternion();
        let q = Quaternion::new(w, x, y, z);
        let isolated = self.fdi.as_ref().is_some_and(|m| m.isolated().is_some());
        if let Some(m) = self.mounting.as_mut().filter(|m| m.checking() && !isolated) {
            let before = m.state();
            // Eq. (5): Λ* taken to the ICS.
            let verdict = m.on_frame(f.time_us, &(q * self.mount.conjugate()));
            match (before, m.state()) {
                (MountState::Checking, MountState::Watching { unverified }) => {
                    let n = unverified.count_ones();
                    self.events.record_n(
                        &mut self.telemetry.counters,
                        now_us,
                        Event::MountUnverified,
                        unverified,
                        0,
                        n,
                    );
                }
                (_, MountState::Undecided { .. }) => {
                    self.events.record(&mut self.telemetry.counters, now_us, Event::MountUndecided, 0, 0);
                }
                _ => {}
            }
            if let Some(v) = verdict {
                self.act_on_mounting(v, now_us);
                // The attitude at this frame's tag was propagated on the wrong gyro up to
                // the present: the observer aligns on the next frame instead.
                self.star_intake.used(now_us);
                return st_status::LISTENED;
            }
        }
        let counters = &mut self.telemetry.counters;
        if let Some(fdi) = self.fdi.as_mut().filter(|m| m.listening()) {
            // A FOG is faulty: the observer listens, the fault logic uses the mismatch.
            return match self.observer.listen(f.time_us, &q, &self.mount) {
                Ok(m) => {
                    self.star_intake.used(now_us);
                    let before = fdi.state();
                    let isolation = fdi.on_mismatch(&m.e_rad, m.var_rad2);
                    counters.count_fdi(before, fdi.state());
                    if let Some(iso) = isolation {
                        let cause = IsolationCause::StarAided { since_us: iso.since_us, drift_rad_s: iso.drift_rad_s };
                        self.isolate(iso.fog, cause, now_us);
                    }
                    st_status::LISTENED
                }
                Err(e) => {
                    counters.bump(star_refusal(e));
                    st_status::REFUSED
                }
            };
        }
        match self.observer.update(&mut self.attitude, now_us, f.time_us, &q, &self.mount) {
            Ok(u) => {
                self.star_intake.used(now_us);
                counters.bump(Counter::StFramesAccepted);
                if u.realigned {
                    let arcsec = u.e_rad.norm() * 180.0 / core::f64::consts::PI * 3600.0;
                    // `as` saturates (and takes NaN to 0).
                    self.events.record(counters, now_us, Event::Realigned, (arcsec / 3600.0) as u8, arcsec as u16);
                }
                if u.reacquired {
                    counters.bump(Counter::StReacquired);
                    st_status::UPDATED | st_status::REACQUIRED
                } else {
                    st_status::UPDATED
                }
            }
            Err(UpdateError::Gated) => {
                counters.bump(Counter::StUpdatesGated);
                st_status::REFUSED
            }
            Err(e) => {
                counters.bump(star_refusal(e));
                st_status::REFUSED
            }
        }
    }
    /// Re-aligns the attitude on the next star-tracker frame the estimator is given,
    /// whatever its mismatch, keeping the drift estimate if it is plausible (the path the
    /// consistency monitor takes on a persistent disagreement,
    /// [`crate::observer::Observer::realign_on_next_frame`]); the frames do not claim
    /// converged meanwhile, nor until the estimate converges again. Logged as
    /// `realigned` when it happens.
    pub fn realign_from_next_star_frame(&mut self) {
        self.observer.realign_on_next_frame();
    }

    /// Acts on the mounting check's verdict: a reversed FOG (or one alone at odds with
    /// the tracker) is isolated, a swapped pair flown on the corrected assignment; the
    /// observer starts again, so nothing of the wrong gyro stays in the attitude or the
    /// drift estimate (the unit has not reported aligned yet).
    fn act_on_mounting(&mut self, v: MountVerdict, now_us: u64) {
        let channel = |i: usize| u16::try_from(i + 1).unwrap_or(0);
        let (kind, fogs) = match v {
            MountVerdict::Flipped(i) => (1, channel(i)),
            MountVerdict::Swapped(i, j) => (2, channel(i) | channel(j) << 4),
            MountVerdict::Unexplained(i) => (3, channel(i)),
        };
        self.events.log(now_us, Event::MountVerdict, kind, fogs);
        match v {
            MountVerdict::Flipped(i) | MountVerdict::Unexplained(i) => {
                self.isolate(i, IsolationCause::Mounting, now_us);
            }
            MountVerdict::Swapped(i, j) => {
                let mut map = self.fog_map;
                if let (Some(&a), Some(&b)) = (map.get(i), map.get(j)) {
                    map = map.map(|k| {
                        if k == a {
                            b
                        } else if k == b {
                            a
                        } else {
                            k
                        }
                    });
                }
                if let Ok(combiner) = checked_combiner(self.profile.get(), &self.table, &map) {
                    self.fog_map = map;
                    // Flagged in every frame from now on; kept with the fixed flags so
                    // the step does not compare the maps (a 16-byte memcmp, ~120
                    // instructions a step).
                    self.fixed_flags &= !flags::FOGS_REMAPPED;
                    if map != IDENTITY_MAP {
                        self.fixed_flags |= flags::FOGS_REMAPPED;
                    }
                    let noise_rad = sample_noise_rad(&self.table, self.profile.dt_s());
                    self.install_geometry(combiner, noise_rad);
                    self.telemetry.counters.bump(Counter::MountSwapped);
                }
            }
        }
        self.guard_touch_tuning();
        self.observer.restart();
        self.observer.set_noise(&flying_noise(&self.combiner, self.flying()));
    }
}

/// The counter of a star-tracker frame the observer could not use (not gated): older
/// than the attitude history is a late frame and newer than it an early one (the unit's
/// clock, not the frame, is off); only a bad quaternion is a bad frame.
fn star_refusal(e: UpdateError) -> Counter {
    match e {
        UpdateError::Stale => Counter::StFramesLate,
        UpdateError::Future => Counter::StFramesEarly,
        UpdateError::Gated | UpdateError::BadQuaternion => Counter::StFramesRejected,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A frame the estimator could not use is counted by why: the unit's clock against
    /// the frame's tag (late, early) is not a bad frame; a gate refusal is counted apart
    /// by the caller and only a bad quaternion is a rejected frame.
    #[test]
    fn refusals_are_counted_by_their_cause() {
        assert_eq!(star_refusal(UpdateError::Stale), Counter::StFramesLate);
        assert_eq!(star_refusal(UpdateError::Future), Counter::StFramesEarly);
        assert_eq!(star_refusal(UpdateError::BadQuaternion), Counter::StFramesRejected);
    }
}
