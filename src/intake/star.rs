//! Star-tracker intake: the link drained into a queue of frames held until the attitude
//! reaches their time tag, frozen-tracker detection and the outage clock.

use heapless::Deque;

use crate::frames::decoder::StreamDecoder;
use crate::frames::star::StarFrame;
use crate::link::{drain, RxLink};
use crate::state_map::{state_map, StateField};
use crate::telemetry::{st_status, Counter, Counters};

use super::fog::MAX_RX_BYTES_PER_STEP;

/// Star-tracker frames held until the attitude reaches their time tag.
pub const ST_PENDING: usize = 4;
/// A star-tracker time tag further ahead of the unit's time than this is refused, µs.
pub const ST_MAX_LEAD_US: u64 = 1_000_000;
/// Star-tracker silence after which the output flags an outage, µs.
pub const ST_OUTAGE_US: u64 = 2_000_000;

/// What the pending queue holds next.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Pending {
    /// A frame whose time tag the attitude has reached.
    Due(StarFrame),
    /// A frame too far ahead of the unit's time was refused (and counted).
    Refused,
    /// Nothing due.
    Wait,
}

/// The star-tracker intake stage.
#[derive(Clone)]
pub struct StarIntake {
    decoder: StreamDecoder<StarFrame, 64>,
    pending: Deque<StarFrame, ST_PENDING>,
    /// Quaternion counts of the last frame that was not refused as frozen or invalid.
    last_q_counts: [i32; 4],
    /// Unit time of the last frame the observer used, µs.
    last_used_us: Option<u64>,
    in_outage: bool,
}

impl Default for StarIntake {
    fn default() -> Self {
        Self::new()
    }
}

impl StarIntake {
    /// Where each field lies in the value ([`crate::state_map`]).
    pub const STATE_MAP: &'static [StateField] = state_map!(StarIntake {
        decoder: StreamDecoder<StarFrame, 64>,
        pending: Deque<StarFrame, ST_PENDING>,
        last_q_counts: [i32; 4],
        last_used_us: Option<u64>,
        in_outage: bool,
    });

    /// An empty intake.
    pub fn new() -> Self {
        StarIntake {
            decoder: StreamDecoder::new(),
            pending: Deque::new(),
            last_q_counts: [0; 4],
            last_used_us: None,
            in_outage: false,
        }
    }

    /// Drains the link into the pending queue; returns status bits
    /// ([`st_status::FRAME`], [`st_status::REFUSED`]).
    pub fn receive<S: RxLink>(&mut self, star: &mut S, scratch: &mut [u8], counters: &mut Counters) -> u8 {
        let mut status = 0u8;
        let decoder = &mut self.decoder;
        let pending = &mut self.pending;
        let mut overflow = 0u32;
        let mut arrived = false;
        let mut new_rej = 0u32;
        let rep = drain(star, MAX_RX_BYTES_PER_STEP, scratch, |bytes| {
            decoder.push_slice(bytes, |r| match r {
                Ok(f) => {
                    arrived = true;
                    if pending.is_full() {
                        let _ = pending.pop_front();
                        overflow += 1;
                    }
                    let _ = pending.push_back(f);
                }
                Err(_) => new_rej = new_rej.saturating_add(1),
            });
        });
        counters.add(Counter::IoErrors, rep.io_errors);
        if arrived {
            status |= st_status::FRAME;
        }
        if new_rej > 0 {
            status |= st_status::REFUSED;
            counters.add(Counter::StFramesRejected, new_rej);
        }
        if overflow > 0 {
            // Frames waiting for the unit's clock pushed out by newer ones: early.
            status |= st_status::REFUSED;
            counters.add(Counter::StFramesEarly, overflow);
        }
        status
    }

    /// The next pending frame at unit time `now_us`; frames further ahead than
    /// [`ST_MAX_LEAD_US`] are dropped and counted early.
    pub fn next_due(&mut self, now_us: u64, counters: &mut Counters) -> Pending {
        let Some(f) = self.pending.front().copied() else { return Pending::Wait };
        if f.time_us > now_us {
            if f.time_us - now_us > ST_MAX_LEAD_US {
                let _ = self.pending.pop_front();
                counters.bump(Counter::StFramesEarly);
                return Pending::Refused;
            }
            return Pending::Wait;
        }
        let _ = self.pending.pop_front();
        Pending::Due(f)
    }

    /// Whether `f` repeats the previous frame's quaternion count for count (a frozen
    /// tracker repeats its last solution; a live one never does, noise); remembers `f`.
    #[inline]
    pub fn repeats(&mut self, f: &StarFrame) -> bool {
        if f.q_counts == self.last_q_counts {
            return true;
        }
        self.last_q_counts = f.q_counts;
        false
    }

    /// The observer used a frame at unit time `now_us`.
    #[inline]
    pub fn used(&mut self, now_us: u64) {
        self.last_used_us = Some(now_us);
    }

    /// The outage clock at `now_us`: [`st_status::OUTAGE`] after [`ST_OUTAGE_US`] without
    /// a frame used; an outage that begins after alignment is counted.
    pub fn outage(&mut self, now_us: u64, aligned: bool, counters: &mut Counters) -> u8 {
        let silent = match self.last_used_us {
            Some(t) => now_us.saturating_sub(t) > ST_OUTAGE_US,
            None => true,
        };
        let status = if silent {
            if !self.in_outage && aligned {
                counters.bump(Counter::StOutages);
            }
            st_status::OUTAGE
        } else {
            0
        };
        self.in_outage = silent;
        status
    }
}
