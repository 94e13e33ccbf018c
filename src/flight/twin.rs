//! The attitude Λ and the drift estimate Δω carried twice inside the step: a second copy
//! of each and the checksum of that copy, so that a bit flipped during a step (after the
//! state guard's check, before its seal, [`super::guard`]) is neither integrated on, nor
//! sent in the output frame, nor sealed as the good value.
//!
//! Every change of Λ or Δω in a step goes through the same three moves:
//!
//! 1. **compare** the live value with its twin's checksum just before it is used or
//!    changed ([`FlightCore::twin_check`]): before each sample's propagation (Λ and Δω),
//!    before a lost interval is bridged, before the estimator's update at a star-tracker
//!    frame, before a resume's correction, and once more before the output frame is
//!    assembled;
//! 2. **change** the live value (the propagation, the update);
//! 3. **seal** the twin from the new value with its checksum ([`FlightCore::twin_seal`]).
//!
//! A flip anywhere between two seals shows at the next compare. The checksum (the
//! check word of the copy, as it was sealed) says which copy is good: if the
//! twin still sums to it, the live value took the flip and is written back from the twin;
//! if the live value sums to it, the twin (or the checksum) took the flip and is sealed
//! again. Either way `state_restored` is logged with a = [`TWIN_ID`] (b = 0 the live
//! value written back, 1 the twin sealed again). When neither sums to it (two flips), the
//! good attitude is not known: as for a guard block neither copy restores, what derives
//! from the table is derived again and the estimator starts again from the next
//! star-tracker frame (b = 2); no frame claims a good attitude until it converges again.
//!
//! A compare folds the live words (four for Λ, three for Δω) into the state guard's check
//! word ([`CheckWord`], a 128-bit interleaved parity: any pattern of flips within one word
//! or within two neighbouring words changes it, the same bit of two adjacent words
//! included) and compares the fold with the checksum; the copy itself is read only on a
//! mismatch. A seal stores the words and their fold. The twin is not in the state guard's
//! blocks: a flip in it between two steps shows at the step's first compare (the live
//! value, checked by the guard, sums to the checksum and the twin does not: sealed again,
//! logged), or is overwritten by the next seal.

use nalgebra::{Quaternion, Vector3};

use super::FlightCore;
use crate::shadow::CheckWord;
use crate::state_map::{state_map, StateField};

/// The `state_restored` event's block number for the in-step copies (the guard's blocks
/// are 1..=7).
pub const TWIN_ID: u8 = 8;

/// The second copy of Λ and Δω, each with the checksum of the copy as sealed.
#[derive(Debug, Clone, Copy, PartialEq, bytemuck::AnyBitPattern)]
pub struct Twin {
    /// Λ's words (w, i, j, k as nalgebra stores them: i, j, k, w).
    q: [u64; 4],
    /// Check word of `q` as sealed.
    q_sum: CheckWord,
    /// Δω's words, rad/s.
    drift: [u64; 3],
    /// Check word of `drift` as sealed.
    drift_sum: CheckWord,
}

/// The check word of `w`.
#[inline(always)]
fn fold<const N: usize>(w: &[u64; N]) -> CheckWord {
    CheckWord::of(w)
}

#[inline(always)]
fn q_words(q: &Quaternion<f64>) -> [u64; 4] {
    [q.coords.x.to_bits(), q.coords.y.to_bits(), q.coords.z.to_bits(), q.coords.w.to_bits()]
}

#[inline(always)]
fn drift_words(d: &Vector3<f64>) -> [u64; 3] {
    [d.x.to_bits(), d.y.to_bits(), d.z.to_bits()]
}

impl Twin {
    /// Where each field lies in the value ([`crate::state_map`]).
    pub const STATE_MAP: &'static [StateField] =
        state_map!(Twin { q: [u64; 4], q_sum: CheckWord, drift: [u64; 3], drift_sum: CheckWord });

    /// Twins of `q` and `drift_rad_s`.
    pub fn of(q: &Quaternion<f64>, drift_rad_s: &Vector3<f64>) -> Self {
        let (q, drift) = (q_words(q), drift_words(drift_rad_s));
        Twin { q, q_sum: fold(&q), drift, drift_sum: fold(&drift) }
    }

    /// Flips bit `bit` of Λ's twin word `word` (4: its checksum, bit 0..128; tests).
    #[cfg(test)]
    pub fn flip_q(&mut self, word: usize, bit: u32) {
        match self.q.get_mut(word) {
            Some(w) => *w ^= 1 << bit,
            None => self.q_sum.flip_bit(bit),
        }
    }

    /// Flips bit `bit` of Δω's twin word `word` (3: its checksum, bit 0..128; tests).
    #[cfg(test)]
    pub fn flip_drift(&mut self, word: usize, bit: u32) {
        match self.drift.get_mut(word) {
            Some(w) => *w ^= 1 << bit,
            None => self.drift_sum.flip_bit(bit),
        }
    }
}

/// One value (`live`) against its twin (`twin`, checksum `sum`): `None` when neither
/// took a flip; else 0 the live words written back from the twin, 1 the twin (or its
/// checksum) sealed again from the live words, 2 neither sums to the checksum (lost).
/// Slices: one copy for Λ and Δω (flash).
#[inline(never)]
fn repair(live: &mut [f64], twin: &mut [u64], sum: &mut CheckWord) -> Option<u8> {
    let live_sum = CheckWord::of_f64s(live);
    let twin_sum = CheckWord::of(twin);
    let same = live.iter().zip(twin.iter()).all(|(l, t)| l.to_bits() == *t);
    if live_sum == *sum {
        if same {
            return None;
        }
        for (t, l) in twin.iter_mut().zip(live.iter()) {
            *t = l.to_bits();
        }
        Some(1)
    } else if twin_sum == *sum {
        for (l, t) in live.iter_mut().zip(twin.iter()) {
            *l = f64::from_bits(*t);
        }
        Some(0)
    } else if same {
        *sum = live_sum;
        Some(1)
    } else {
        Some(2)
    }
}

impl FlightCore {
    /// Compares Λ and Δω with the checksums of their twins (their check words, module
    /// doc); a mismatch is resolved
    /// ([`FlightCore::twin_repair`]).
    #[inline(always)]
    pub(super) fn twin_check(&mut self) {
        let q = fold(&q_words(&self.attitude.quaternion()));
        let d = fold(&drift_words(&self.observer.drift_rad_s()));
        if q != self.twin.q_sum || d != self.twin.drift_sum {
            self.twin_repair();
        }
    }

    /// [`FlightCore::twin_check`] out of line, for the places a step rarely reaches (a
    /// frame due, a bridge, an isolation, a resume; flash).
    #[inline(never)]
    pub(super) fn twin_check_rare(&mut self) {
        self.twin_check();
    }

    /// Seals Λ's twin from Λ as it now is (after a change the step made, compared before).
    #[inline(always)]
    pub(super) fn twin_seal_q(&mut self) {
        let q = q_words(&self.attitude.quaternion());
        self.twin.q = q;
        self.twin.q_sum = fold(&q);
    }

    /// Seals both twins (after a change of Λ and Δω the step made, compared before; and
    /// whenever the guard saves every block). Out of line: rare (flash).
    #[inline(never)]
    pub(super) fn twin_seal(&mut self) {
        self.twin = Twin::of(&self.attitude.quaternion(), &self.observer.drift_rad_s());
    }

    /// Λ or Δω differs from its twin: the good copy, by the twin's checksum, is written
    /// back (or the twin sealed again); logged and counted as `state_restored`
    /// ([`TWIN_ID`]). Neither good: the estimator starts again from the next star-tracker
    /// frame, and the frames do not claim a good attitude meanwhile.
    #[inline(never)]
    #[cold]
    fn twin_repair(&mut self) {
        let q = repair(self.attitude.words_mut(), &mut self.twin.q, &mut self.twin.q_sum);
        let d = repair(self.observer.drift_words_mut(), &mut self.twin.drift, &mut self.twin.drift_sum);
        if d == Some(0) {
            // The flip may have been saved at the end of the last step.
            self.guard_save_steady();
        }
        let how = u16::from(q.max(d).unwrap_or(0));
        self.guard_logged(TWIN_ID, how);
        if how == 2 {
            // What derives from the table derived again, the estimator restarted (the
            // guard's path for a block neither copy restores).
            self.guard_rederive();
        }
    }
}
