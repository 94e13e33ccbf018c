//! FOG intake: the FOG links (one per FOG or one bus) drained into per-FOG sample queues,
//! and the unit's sample clock that decides which sample is integrated next.
//!
//! Unit time is the FOG sample clock: the FOGs are sampled on the unit's sync pulse and
//! number their samples, so a sample's end is at index × Δt however its frames were
//! delayed on the links. A sample still owed by a FOG that delivered the previous one is
//! waited for up to [`MAX_WAIT_STEPS`] steps; then it is taken from the FOGs that have
//! it, the others flagged missing.

use crate::calib::N_FOG;
use crate::combination::FogSet;
use crate::frames::decoder::StreamDecoder;
use crate::frames::fog::{FogFrame, FogSlot};
use crate::link::RxPort;
use crate::state::{Flag, Maybe, Quad, Ring};
use crate::state_map::state_struct;
use crate::telemetry::{health, Counter, Counters, FogCounter};

/// Receive bytes read per link per step at most (four FOG frames' worth).
pub const MAX_RX_BYTES_PER_STEP: usize = 128;
/// FOG samples a channel holds ahead of the step (absorbs jitter and late links).
pub const FOG_QUEUE: usize = 8;
/// Steps a sample is waited for when a FOG that delivered the previous one owes it.
pub const MAX_WAIT_STEPS: u32 = 2;

/// How the FOGs are wired.
pub enum FogLinks<F> {
    /// One link per FOG slot (FOG1..FOG4); frames must carry the slot's `fog_id`.
    PerFog([F; N_FOG]),
    /// One multi-drop (RS-485-style) bus carrying every FOG's frames, told apart by
    /// their `fog_id`.
    Bus(F),
}

/// What one FOG's queue gave for a sample.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Arrival {
    /// Health bits so far ([`health::REJECTED`], [`health::COUNTER_GAP`], [`health::MISSING`]).
    pub health: u8,
    /// The sample's frame, `None` when it is missing.
    pub frame: Option<FogFrame>,
}

/// One FOG's receive path: decoder and sample queue.
#[derive(Clone, Copy, bytemuck::AnyBitPattern)]
struct FogChannel {
    decoder: StreamDecoder<FogFrame, 32>,
    queue: Ring<FogSlot, FOG_QUEUE>,
    /// Frames rejected (by the decoder, or for a wrong FOG id) since the last sample taken.
    rejected_new: u32,
}

impl FogChannel {
    fn new() -> Self {
        FogChannel { decoder: StreamDecoder::new(), queue: Ring::new(), rejected_new: 0 }
    }

    /// Takes sample `target` from the queue (discarding older ones as stale, leaving a
    /// newer one queued).
    fn take(&mut self, i: usize, target: u16, counters: &mut Counters) -> Arrival {
        let mut health_bits = 0u8;
        let new_rej = core::mem::take(&mut self.rejected_new);
        if new_rej > 0 {
            health_bits |= health::REJECTED;
            counters.add(Counter::FogFramesRejected, new_rej);
            counters.add_fog(i, FogCounter::Rejected, new_rej);
        }
        let mut stale = 0u32;
        let mut frame = None;
        // Bounded by the queue length.
        for _ in 0..FOG_QUEUE {
            let Some(f) = self.queue.pop_front().map(FogFrame::from) else { break };
            let age = target.wrapping_sub(f.counter);
            if age == 0 {
                frame = Some(f);
                break;
            }
            if age >= 0x8000 {
                // Newer than the target: it waits for its own step (room is certain: it
                // was just taken out).
                let _ = self.queue.push_front(f.into());
                break;
            }
            stale += 1;
        }
        if stale > 0 {
            health_bits |= health::COUNTER_GAP;
            counters.add(Counter::FogSamplesStale, stale);
        }
        if frame.is_none() {
            counters.bump(Counter::FogSamplesMissing);
            counters.bump_fog(i, FogCounter::Missing);
            health_bits |= health::MISSING;
        }
        Arrival { health: health_bits, frame }
    }
}

/// Where the unit is in the FOG sample sequence.
#[derive(Debug, Clone, Copy, PartialEq, bytemuck::AnyBitPattern)]
struct SampleClock {
    /// Counter of the next sample to integrate (None before the first frame).
    expected: Maybe<u16>,
    /// Index of the last integrated sample since start (its end time is index × Δt).
    index: u64,
}

state_struct! {
    /// The FOG intake stage.
    #[derive(Clone, Copy, bytemuck::AnyBitPattern)]
    pub struct FogIntake {
        fitted: FogSet = fitted;
        channels: Quad<FogChannel> = Quad::splat(FogChannel::new());
        bus_decoder: StreamDecoder<FogFrame, 32> = StreamDecoder::new();
        clock: SampleClock = SampleClock { expected: Maybe::none(), index: 0 };
        /// FOGs that delivered the last sample taken.
        last_present: FogSet = fitted;
        /// Steps waited for the expected sample.
        waited: u32 = 0;
        /// Samples were lost before the next one taken.
        gap: Flag = Flag::CLEAR;
        /// Samples lost on every link just before the next one, not yet bridged.
        lost: u16 = 0;
    }
    constructor
    /// An intake for the `fitted` FOGs; slots not fitted are never read.
    pub fn new(fitted: FogSet) -> Self => core::convert::identity {}
}

impl FogIntake {
    /// The sample clock's index (unit time) and the counter of the next sample, for the
    /// state guard ([`crate::shadow`]).
    #[inline(always)]
    pub fn visit_clock<V: crate::shadow::Visit>(&mut self, v: &mut V) {
        v.word(&mut self.clock.index);
        // The counter of the next sample (`None` as u64::MAX, never a counter): a flip
        // would take the clock off by the samples it skips or repeats.
        let mut e = self.clock.expected.get().map_or(u64::MAX, u64::from);
        v.word(&mut e);
        if V::WRITES {
            self.clock.expected.set(u16::try_from(e).ok());
        }
    }

    /// Index of the last sample taken since start (its end time is index × Δt).
    #[inline]
    pub fn index(&self) -> u64 {
        self.clock.index
    }

    /// The sample clock: the last sample's index and the counter expected next (`None`
    /// before the first frame); a reset's snapshot.
    pub fn clock(&self) -> (u64, Option<u16>) {
        (self.clock.index, self.clock.expected.get())
    }

    /// Resumes the sample clock after a reset: the samples the FOGs sent meanwhile
    /// (counters from `expected` on) are lost on every link and bridged, so unit time
    /// goes on where it was.
    pub fn resume_clock(&mut self, index: u64, expected: u16) {
        self.clock = SampleClock { expected: Maybe::some(expected), index };
    }

    /// End time of the last sample taken, µs: index × Δt. The product cannot overflow in
    /// any flight (2^64 µs is 585,000 years), so it wraps instead of saturating (a 64-bit
    /// saturating multiply costs a dozen instructions on the M7).
    #[inline]
    pub fn time_us(&self, dt_us: u32) -> u64 {
        self.clock.index.wrapping_mul(u64::from(dt_us))
    }

    /// Whether the last sample taken had no FOG data at all (bridged).
    #[inline]
    pub fn bridged(&self) -> bool {
        self.last_present.0 == 0
    }

    /// A sample was integrated: the wait starts over.
    #[inline]
    pub fn integrated(&mut self) {
        self.waited = 0;
    }

    /// A step passed without a sample.
    #[inline]
    pub fn waited_a_step(&mut self) {
        self.waited = self.waited.saturating_add(1);
    }

    /// Drains the FOG links (or the bus) into the per-FOG sample queues.
    pub fn receive<F: RxPort>(&mut self, fog_links: &mut FogLinks<F>, scratch: &mut [u8], counters: &mut Counters) {
        let fitted = self.fitted;
        match fog_links {
            FogLinks::PerFog(links) => {
                for (i, (ch, link)) in self.channels.iter_mut().zip(links.iter_mut()).enumerate() {
                    if !fitted.contains(i) {
                        continue;
                    }
                    let FogChannel { decoder, queue, rejected_new } = ch;
                    let rep = link.drain_into(MAX_RX_BYTES_PER_STEP, scratch, |bytes| {
                        decoder.push_slice(bytes, |r| match r {
                            Ok(f) if usize::from(f.fog_id) == i => enqueue(queue, f),
                            // Rejected by the decoder, or for a wrong FOG id.
                            _ => *rejected_new = rejected_new.saturating_add(1),
                        });
                    });
                    counters.add(Counter::IoErrors, rep.io_errors);
                }
            }
            FogLinks::Bus(link) => {
                let decoder = &mut self.bus_decoder;
                let channels = &mut self.channels;
                let mut new_rej = 0u32;
                let rep = link.drain_into(N_FOG * MAX_RX_BYTES_PER_STEP, scratch, |bytes| {
                    decoder.push_slice(bytes, |r| match r {
                        Ok(f) => {
                            let i = usize::from(f.fog_id);
                            if let Some(ch) = channels.get_mut(i).filter(|_| fitted.contains(i)) {
                                enqueue(&mut ch.queue, f);
                            }
                        }
                        Err(_) => new_rej = new_rej.saturating_add(1),
                    });
                });
                counters.add(Counter::IoErrors, rep.io_errors);
                counters.add(Counter::FogFramesRejected, new_rej);
            }
        }
    }

    /// Counter of the next sample to integrate now, or `None` to wait for it.
    pub fn next_sample(&mut self, counters: &mut Counters) -> Option<u16> {
        let fitted = self.fitted;
        if self.waited < MAX_WAIT_STEPS && self.channels.iter().all(|ch| ch.queue.is_empty()) {
            // Nothing queued (the usual case once this step's sample is taken).
            return None;
        }
        let fogs = || self.channels.iter().enumerate().filter(move |(i, _)| fitted.contains(*i)).map(|(_, ch)| ch);
        let Some(e) = self.clock.expected.get() else {
            // Before the first sample: start at the oldest one waiting, if any.
            let first = fogs().filter_map(|ch| ch.queue.front().map(|f| f.counter())).min()?;
            self.clock.index = u64::from(first).saturating_sub(1);
            self.clock.expected = Maybe::some(first);
            return Some(first);
        };
        // Per FOG: has sample e queued, has only newer ones (e lost), or has nothing yet.
        // A FOG's frames arrive in counter order, so the first queued frame that is not
        // older than e decides (older ones are discarded as stale by `take`).
        let mut have = 0u8;
        let mut past = 0u8;
        let mut oldest_newer: Option<u16> = None;
        for (i, ch) in self.channels.iter().enumerate() {
            let bit = 1u8 << i;
            if fitted.0 & bit == 0 {
                continue;
            }
            let Some(front) = ch.queue.front() else { continue };
            let mut ahead = front.counter().wrapping_sub(e);
            if ahead >= 0x8000 {
                // Stale frames first (rare): look past them.
                match ch.queue.iter().map(|f| f.counter().wrapping_sub(e)).find(|&d| d < 0x8000) {
                    Some(d) => ahead = d,
                    None => continue,
                }
            }
            if ahead == 0 {
                have |= bit;
            } else {
                past |= bit;
                if oldest_newer.is_none_or(|o| ahead < o.wrapping_sub(e)) {
                    oldest_newer = Some(e.wrapping_add(ahead));
                }
            }
        }
        let owed = self.last_present.0 & fitted.0 & !(have | past);
        if have == 0 && past != 0 && (owed == 0 || self.waited >= MAX_WAIT_STEPS) {
            // Sample e was lost on every link: jump to the oldest newer one.
            let o = oldest_newer?;
            let lost = o.wrapping_sub(e);
            counters.add(Counter::FogSamplesMissing, u32::from(lost).saturating_mul(fitted.count()));
            // The clock moves over the lost span only when the core bridges it
            // ([`FogIntake::take_lost`]): the attitude must turn through it too.
            self.lost = lost;
            self.clock.expected = Maybe::some(o);
            self.gap = Flag::SET;
            return Some(o);
        }
        if have != 0 && (owed == 0 || self.waited >= MAX_WAIT_STEPS) {
            return Some(e);
        }
        if have == 0 && past == 0 && self.waited >= MAX_WAIT_STEPS {
            // No FOG data at all: bridge this sample so time keeps moving.
            return Some(e);
        }
        None
    }

    /// Samples lost on every link just before the sample [`FogIntake::next_sample`]
    /// returned (0 if none): the caller bridges them, and the clock moves over them here.
    #[inline]
    pub fn take_lost(&mut self) -> u16 {
        let lost = core::mem::take(&mut self.lost);
        self.clock.index = self.clock.index.saturating_add(u64::from(lost));
        lost
    }

    /// Starts taking sample `target`: advances the clock; returns the health bits every
    /// FOG carries for it ([`health::COUNTER_GAP`] after lost samples).
    #[inline]
    pub fn begin(&mut self, target: u16) -> u8 {
        let gap = if self.gap.take() { health::COUNTER_GAP } else { 0 };
        self.clock.index = self.clock.index.saturating_add(1);
        self.clock.expected = Maybe::some(target.wrapping_add(1));
        gap
    }

    /// Takes sample `target` from FOG `i`'s queue (see [`FogIntake::begin`]).
    #[inline]
    pub fn take(&mut self, i: usize, target: u16, counters: &mut Counters) -> Arrival {
        match self.channels.get_mut(i) {
            Some(ch) => ch.take(i, target, counters),
            None => Arrival { health: health::MISSING, frame: None },
        }
    }

    /// Ends taking a sample: the FOGs that delivered it.
    #[inline]
    pub fn end(&mut self, present: FogSet) {
        self.last_present = present;
    }
}

/// Queues a FOG sample; a full queue drops its oldest (late backlog).
fn enqueue(queue: &mut Ring<FogSlot, FOG_QUEUE>, f: FogFrame) {
    queue.push_back_overwrite(f.into());
}
