//! Event frame (kind 0x32, 60 bytes): up to four records of the unit's event log
//! ([`crate::telemetry::events`]), sent on the output link after a step's output frame,
//! only when the log holds a record not yet sent.
//!
//! | off | size | field | type | meaning |
//! |---|---|---|---|---|
//! | 0 | 2 | sync | `EB 90` | |
//! | 2 | 1 | kind | `0x32` | |
//! | 3 | 1 | count | u8 | records in this frame, 1 to 4 |
//! | 4 | 2 | seq | u16 | sequence number of the first record (the others follow it by one each; wraps) |
//! | 6 | 2 | lost | u16 | records the log dropped unsent since power-on (full log), saturating |
//! | 8 | 48 | records | 4 × 12 bytes | record k at 8 + 12k: time_us u64 (unit time, µs), code u8 (the event table), a u8, b u16; records past `count` all zero |
//! | 56 | 4 | crc | u32 | CRC-32C over bytes 0..56 |
//!
//! Rejected (field error): a count of 0 or more than 4, a record with an unknown code,
//! a non-zero byte past `count`.

use super::{kind, DecodeError, FieldReader, FieldWriter, Frame};
use crate::telemetry::events::{Event, EventRecord};

/// Length of an event frame in bytes.
pub const FRAME_LEN: usize = 60;
/// Records one frame carries at most.
pub const RECORDS: usize = 4;

/// Up to [`RECORDS`] event records as carried on the link.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub struct EventFrame {
    /// Records lost by the log since power-on (saturating).
    pub lost: u16,
    /// The records, oldest first; `None` only after the last one.
    pub records: [Option<EventRecord>; RECORDS],
}

impl EventFrame {
    /// Frame length in bytes (same as [`Frame::LEN`]).
    pub const LEN: usize = FRAME_LEN;

    /// The records it carries, oldest first.
    pub fn iter(&self) -> impl Iterator<Item = &EventRecord> {
        self.records.iter().map_while(Option::as_ref)
    }

    /// The frame's bytes.
    pub fn to_bytes(&self) -> [u8; FRAME_LEN] {
        let mut out = [0u8; FRAME_LEN];
        // Cannot fail: `out` is exactly one frame long.
        let _ = self.encode_into(&mut out);
        out
    }
}

impl Frame for EventFrame {
    const KIND: u8 = kind::EVENT;
    const LEN: usize = FRAME_LEN;

    fn write_fields(&self, w: &mut FieldWriter<'_>) {
        let first = self.records.first().copied().flatten();
        w.u8(self.iter().count() as u8);
        w.u16(first.map_or(0, |r| r.seq));
        w.u16(self.lost);
        let mut open = true;
        for r in &self.records {
            open &= r.is_some();
            match r.filter(|_| open) {
                Some(r) => {
                    w.u64(r.time_us);
                    w.u8(r.event.code());
                    w.u8(r.a);
                    w.u16(r.b);
                }
                None => w.bytes([0u8; 12]),
            }
        }
    }

    fn read_fields(r: &mut FieldReader<'_>) -> Result<Self, DecodeError> {
        let count = r.u8()?;
        let seq = r.u16()?;
        let lost = r.u16()?;
        if count == 0 || usize::from(count) > RECORDS {
            return Err(DecodeError::BadField);
        }
        let mut f = EventFrame { lost, records: [None; RECORDS] };
        for (k, slot) in (0u8..).zip(f.records.iter_mut()) {
            let (time_us, code, a, b) = (r.u64()?, r.u8()?, r.u8()?, r.u16()?);
            if k < count {
                let event = Event::from_code(code).ok_or(DecodeError::BadField)?;
                *slot = Some(EventRecord { time_us, seq: seq.wrapping_add(u16::from(k)), event, a, b });
            } else if time_us != 0 || code != 0 || a != 0 || b != 0 {
                return Err(DecodeError::BadField);
            }
        }
        Ok(f)
    }
}
