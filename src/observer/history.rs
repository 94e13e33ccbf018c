//! The attitude history and its lazy fix.
//!
//! A star-tracker frame's time tag t_s lags the present by the tracker's latency. The
//! estimators compare Λ* with Λ(t_s), not with the present Λ: the history holds the last
//! H propagated attitudes, and [`History::attitude_at`] interpolates between the two
//! steps around t_s.
//!
//! An update corrects Λ(t_s) and the drift Δω of eq. (6); the attitudes propagated after
//! t_s carry both corrections. The present attitude is corrected at once; the history
//! entries after t_s lazily: the correction is kept as a pending fix and applied to
//! the (at most two) entries a later update reads, with the same arithmetic in the same
//! order as applying it to every entry at once, so the result is bit-identical. A later
//! frame's time tag usually lies after the present step of the previous update (4 Hz,
//! 50 ms latency), and then no fix is applied at all.

use nalgebra::{Quaternion, Vector3};

use super::UpdateError;
use crate::attitude::Attitude;
use crate::math;
use crate::state::Ring;
use crate::state_map::{state_map, StateField};

/// One propagated attitude and its unit time.
#[derive(Debug, Clone, Copy, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
#[repr(C)]
struct Sample {
    time_us: u64,
    q: Quaternion<f64>,
}

/// Pending fixes kept at once: a frame per update, the history spans H steps; more
/// star-tracker updates than this within the history (an 8 Hz tracker with 0.5 s
/// latency) apply the oldest fix to the stored entries, as an eager update would.
const PENDING_FIXES: usize = 4;

/// A correction of eq. (6) not yet applied to the history: entries with `from_us` ≤
/// t ≤ `to_us` (recorded before the update) become c ∘ Λ(t) ∘ q(−δΔω · (t − from_us)).
#[derive(Debug, Clone, Copy, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
#[repr(C)]
struct Fix {
    from_us: u64,
    to_us: u64,
    c: Quaternion<f64>,
    d_drift: Vector3<f64>,
}

impl Fix {
    fn covers(&self, t_us: u64) -> bool {
        self.from_us <= t_us && t_us <= self.to_us
    }

    fn apply(&self, q: &Quaternion<f64>, t_us: u64) -> Quaternion<f64> {
        let dt_s = f64::from(u32::try_from(t_us.saturating_sub(self.from_us)).unwrap_or(u32::MAX)) * 1e-6;
        self.c * q * math::quat_from_rotvec(&(-self.d_drift * dt_s))
    }
}

/// The last `H` propagated attitudes (H × step bounds the latency absorbed: 64 × 5 ms =
/// 320 ms) and the corrections not yet applied to them.
#[derive(Debug, Clone, Copy, bytemuck::AnyBitPattern)]
pub struct History<const H: usize> {
    /// Ring of the last H propagated attitudes: `head` is the next slot written, `len` how
    /// many are held (a plain array: one store a step, no deque bookkeeping).
    ring: [Sample; H],
    head: usize,
    len: usize,
    fixes: Ring<Fix, PENDING_FIXES>,
}

impl<const H: usize> Default for History<H> {
    fn default() -> Self {
        History { ring: [Sample { time_us: 0, q: Quaternion::identity() }; H], head: 0, len: 0, fixes: Ring::new() }
    }
}

impl<const H: usize> History<H> {
    /// Where each field lies in the value ([`crate::state_map`]).
    pub const STATE_MAP: &'static [StateField] = state_map!(History<H> {
        ring: [Sample; H],
        head: usize,
        len: usize,
        fixes: Ring<Fix, PENDING_FIXES>,
    });

    /// Records the propagated attitude at the end of a step.
    #[inline]
    pub fn record(&mut self, time_us: u64, q: Quaternion<f64>) {
        if let Some(slot) = self.ring.get_mut(self.head) {
            *slot = Sample { time_us, q };
        }
        self.head = (self.head + 1) % H;
        self.len = (self.len + 1).min(H);
    }

    /// Entries from the newest back to the oldest: slots below `head` hold the newest (the
    /// last written at `head − 1`), those from `head` on the previous lap, valid only once
    /// the ring has filled (then `len` = H).
    fn newest_first(&self) -> impl Iterator<Item = &Sample> {
        let (recent, lap) = self.ring.split_at_checked(self.head).unwrap_or((&[], &[]));
        recent.iter().rev().chain(lap.iter().rev()).take(self.len)
    }

    /// The oldest entry held.
    fn oldest(&self) -> Option<&Sample> {
        if self.len < H {
            if self.len == 0 {
                None
            } else {
                self.ring.first()
            }
        } else {
            self.ring.get(self.head)
        }
    }

    /// An entry as corrected by every update so far (pending fixes in order).
    fn corrected(&self, s: &Sample) -> Quaternion<f64> {
        let mut q = s.q;
        for f in self.fixes.iter() {
            if f.covers(s.time_us) {
                q = f.apply(&q, s.time_us);
            }
        }
        q
    }

    /// Propagated attitude at `time_us`, interpolated between recorded steps.
    pub fn attitude_at(&self, time_us: u64) -> Result<Quaternion<f64>, UpdateError> {
        let (first, last) = match (self.oldest(), self.newest_first().next()) {
            (Some(f), Some(l)) => (f, l),
            _ => return Err(UpdateError::Stale),
        };
        if time_us < first.time_us {
            return Err(UpdateError::Stale);
        }
        if time_us > last.time_us {
            return Err(UpdateError::Future);
        }
        // From the newest entry back: a time tag lags the present by the star tracker's
        // latency, a few entries, so this is shorter than a scan from the oldest.
        let mut next = last;
        for s in self.newest_first() {
            if s.time_us <= time_us {
                let span = next.time_us.saturating_sub(s.time_us);
                if span == 0 {
                    return Ok(self.corrected(s));
                }
                // u32 µs (71 min) covers any span here; u32 → f64 is one instruction on
                // the M7, u64 → f64 a library call.
                let us = |d: u64| f64::from(u32::try_from(d).unwrap_or(u32::MAX));
                let frac = us(time_us - s.time_us) / us(span);
                return Ok(math::nlerp(&self.corrected(s), &self.corrected(next), frac));
            }
            next = s;
        }
        Err(UpdateError::Stale)
    }

    /// Left-multiplies by `c` every attitude at or after `t_s` (and the present one, `att`
    /// at `now_us`), and removes the drift change `d_drift` integrated from t_s to each of
    /// them: the present attitude now, the history through a pending fix.
    pub fn fix(&mut self, att: &mut Attitude, now_us: u64, t_s: u64, c: &Quaternion<f64>, d_drift: &Vector3<f64>) {
        let fix = Fix { from_us: t_s, to_us: now_us, c: *c, d_drift: *d_drift };
        // Fixes whose span has left the history cover nothing any more.
        let oldest = self.oldest().map_or(u64::MAX, |s| s.time_us);
        while self.fixes.front().is_some_and(|f| f.to_us < oldest) {
            let _ = self.fixes.pop_front();
        }
        if self.fixes.is_full() {
            if let Some(old) = self.fixes.pop_front() {
                // Each entry on its own, so slot order does not matter (rare: more
                // updates within the history than pending fixes).
                for s in self.ring.iter_mut() {
                    if old.covers(s.time_us) {
                        s.q = old.apply(&s.q, s.time_us);
                    }
                }
            }
        }
        att.set_quaternion(fix.apply(&att.quaternion(), now_us));
        self.fixes.push_back_in_place(fix);
    }
}

#[cfg(test)]
mod tests {
    extern crate std;
    use std::vec::Vec;

    use super::*;
    use crate::attitude::Coning;

    /// The reference: every correction applied at once to every entry it covers.
    struct Eager {
        entries: Vec<(u64, Quaternion<f64>)>,
    }

    impl Eager {
        fn fix(&mut self, att: &mut Attitude, now_us: u64, t_s: u64, c: &Quaternion<f64>, d: &Vector3<f64>) {
            let f = Fix { from_us: t_s, to_us: now_us, c: *c, d_drift: *d };
            for (t, q) in self.entries.iter_mut() {
                if f.covers(*t) {
                    *q = f.apply(q, *t);
                }
            }
            att.set_quaternion(f.apply(&att.quaternion(), now_us));
        }

        fn attitude_at(&self, time_us: u64) -> Option<Quaternion<f64>> {
            let k = self.entries.iter().rposition(|(t, _)| *t <= time_us)?;
            let (t0, q0) = self.entries[k];
            if t0 == time_us {
                return Some(q0);
            }
            let (t1, q1) = *self.entries.get(k + 1)?;
            Some(math::nlerp(&q0, &q1, (time_us - t0) as f64 / (t1 - t0) as f64))
        }
    }

    /// Steps of 5 ms on a turning body; every `every` steps an update at a tag `lag`
    /// steps back (between two steps) corrects the present and the history. The lazy
    /// history must read what the eager one holds, bit for bit.
    fn lazy_reads_eager(every: u64, lag: u64) -> u32 {
        const H: usize = 16;
        let mut lazy: History<H> = History::default();
        let mut eager = Eager { entries: Vec::new() };
        let mut att_a = Attitude::new(Quaternion::identity(), Coning::ThreeSample);
        let mut att_b = att_a;
        let mut read_pending = 0;
        let mut last_fix_now = 0;
        for k in 1..=400u64 {
            let now_us = k * 5_000;
            let w = Vector3::new(0.01, -0.004, 0.002 * (k as f64 * 0.01).sin());
            att_a.step(&(w * 0.005));
            att_b.step(&(w * 0.005));
            lazy.record(now_us, att_a.quaternion());
            eager.entries.push((now_us, att_b.quaternion()));
            if eager.entries.len() > H {
                eager.entries.remove(0);
            }
            if k % every == 0 && k > lag {
                let tag = now_us - lag * 5_000 + 1_700;
                if tag <= last_fix_now {
                    read_pending += 1;
                }
                let q_lazy = lazy.attitude_at(tag).unwrap();
                assert_eq!(Some(q_lazy), eager.attitude_at(tag), "step {k}");
                let c = math::quat_from_rotvec(&Vector3::new(1e-5, -2e-5, 3e-6 * k as f64));
                let d = Vector3::new(1e-7, 2e-7, -1e-7);
                lazy.fix(&mut att_a, now_us, tag, &c, &d);
                eager.fix(&mut att_b, now_us, tag, &c, &d);
                last_fix_now = now_us;
            }
            assert_eq!(att_a.quaternion(), att_b.quaternion(), "present attitude at step {k}");
        }
        read_pending
    }

    #[test]
    fn lazy_fixes_read_as_the_eager_history() {
        // A tag after the previous update's present: no pending fix is read.
        assert_eq!(lazy_reads_eager(20, 3), 0);
        // Tags two updates back: the pending fixes are read.
        assert!(lazy_reads_eager(3, 7) > 50);
        // More updates within the history than pending fixes: the oldest is written in.
        assert!(lazy_reads_eager(1, 12) > 300);
    }

    #[test]
    fn times_outside_the_history_are_refused() {
        let mut h: History<4> = History::default();
        assert_eq!(h.attitude_at(0), Err(UpdateError::Stale));
        for k in 1..=6u64 {
            h.record(k * 10, Quaternion::identity());
        }
        // Held: 30, 40, 50, 60.
        assert_eq!(h.attitude_at(29), Err(UpdateError::Stale));
        assert_eq!(h.attitude_at(61), Err(UpdateError::Future));
        assert_eq!(h.attitude_at(30), Ok(Quaternion::identity()));
        assert!(h.attitude_at(45).is_ok());
    }
}
