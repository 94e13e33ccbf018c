//! Streaming decoder: bytes in, frames (or counted rejections) out.
//!
//! [`StreamDecoder`] holds at most one frame candidate in a fixed buffer. Its invariant:
//! the buffer is empty or holds a *valid prefix* — bytes that match the header
//! (`EB 90 KIND`) as far as they go. Per byte:
//!
//! 1. the byte is appended; if the buffer stops being a valid prefix at the sync bytes
//!    the decoder is hunting and drops bytes silently (counted in `bytes_skipped`); at
//!    the kind byte the candidate is rejected with [`DecodeError::BadKind`];
//! 2. once `LEN` bytes are buffered the candidate is decoded ([`Frame::decode`]: CRC,
//!    then fields); an accepted frame empties the buffer;
//! 3. after any rejection the decoder *resynchronises inside the rejected bytes*: it
//!    keeps the buffer from the first position after the rejected start that is again a
//!    valid prefix, and drops the bytes before it.
//!
//! Guarantee: a frame start is only ever dropped from the buffer as part of an earlier
//! starting candidate that was *accepted*. So a complete frame that follows arbitrary
//! garbage (a false `EB 90`, a truncated frame, a frame of another kind) is decoded,
//! except in one case: the garbage ends with `EB 90 KIND` followed by k − 3 bytes
//! (k < LEN) such that those k bytes plus the first LEN − k bytes of the real frame have a
//! matching CRC and valid fields. That candidate is a frame by every check the link
//! defines (a CRC-32C collision, about 2^-32 for such a tail) and is accepted; the real
//! frame starting inside it is lost, and the decoder is back in sync at most one frame
//! later. No decoder without look-ahead can tell the two apart.
//!
//! Work per byte is bounded: one header comparison, and at a complete or rejected
//! candidate one CRC over `LEN` bytes and one scan of at most `LEN` positions.

// The AnyBitPattern derive bounds a generic parameter once more in its impl.
#![allow(clippy::multiple_bound_locations)]

use core::marker::PhantomData;

use crate::state::Bytes;

use super::{DecodeError, Frame, OVERHEAD_LEN, SYNC};

/// What a decoder has seen so far (saturating counters).
///
/// Every byte pushed is in exactly one place: an accepted frame (`frames_ok × LEN`
/// bytes), `bytes_skipped`, or the buffer ([`StreamDecoder::buffered`]), until the
/// counters saturate.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, bytemuck::AnyBitPattern)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub struct DecoderStats {
    /// Frames accepted.
    pub frames_ok: u32,
    /// Candidates rejected for their CRC.
    pub crc_errors: u32,
    /// Candidates rejected for their kind byte (sync followed by another kind).
    pub kind_errors: u32,
    /// Candidates with a good CRC rejected for a field out of range.
    pub field_errors: u32,
    /// Bytes dropped: hunting for sync, and the bytes of rejected candidates.
    pub bytes_skipped: u32,
}

impl DecoderStats {
    /// All rejected candidates (CRC, kind and field errors).
    pub fn rejected(&self) -> u32 {
        self.crc_errors.saturating_add(self.kind_errors).saturating_add(self.field_errors)
    }
}

/// Streaming decoder of frames of type `F` with a buffer of `CAP` bytes
/// (`CAP >= F::LEN`, checked at compile time by [`StreamDecoder::new`]).
#[derive(Clone, Copy, bytemuck::AnyBitPattern)]
pub struct StreamDecoder<F: Frame, const CAP: usize> {
    buf: Bytes<CAP>,
    stats: DecoderStats,
    _frame: PhantomData<fn() -> F>,
}

impl<F: Frame, const CAP: usize> Default for StreamDecoder<F, CAP> {
    fn default() -> Self {
        Self::new()
    }
}

impl<F: Frame, const CAP: usize> StreamDecoder<F, CAP> {
    /// Evaluated by [`StreamDecoder::new`]: a `CAP` below one frame fails the build.
    const CAPACITY_OK: () = assert!(CAP >= F::LEN && F::LEN >= OVERHEAD_LEN, "StreamDecoder: CAP must hold one frame");

    /// An empty decoder, hunting for sync.
    pub const fn new() -> Self {
        #[allow(clippy::let_unit_value)]
        let () = Self::CAPACITY_OK;
        StreamDecoder {
            buf: Bytes::new(),
            stats: DecoderStats { frames_ok: 0, crc_errors: 0, kind_errors: 0, field_errors: 0, bytes_skipped: 0 },
            _frame: PhantomData,
        }
    }

    /// Takes one byte; returns a frame or a rejection when a candidate is complete (or
    /// rejected at its kind byte), `None` otherwise.
    pub fn push(&mut self, byte: u8) -> Option<Result<F, DecodeError>> {
        if self.buf.push(byte).is_err() {
            // Unreachable while the invariant holds (fewer than LEN <= CAP bytes on
            // entry); recover by starting over.
            self.drop_front(self.buf.len());
            if self.buf.push(byte).is_err() {
                self.count_skipped(1);
                return None;
            }
        }
        if !is_valid_prefix(self.buf.as_slice(), F::KIND) {
            return self.reject_prefix();
        }
        if self.buf.len() < F::LEN {
            return None;
        }
        match F::decode(self.buf.as_slice()) {
            Ok(frame) => {
                self.buf.clear();
                self.stats.frames_ok = self.stats.frames_ok.saturating_add(1);
                Some(Ok(frame))
            }
            Err(e) => Some(Err(self.reject(e))),
        }
    }

    /// Takes a run of bytes, calling `on_frame` with every frame or rejection.
    ///
    /// Fast path, same results as pushing byte by byte: while no candidate is buffered,
    /// bytes before the next sync byte are skipped in one go, and a whole frame that lies
    /// in `bytes` is decoded in place. Anything else (a candidate split across calls, a
    /// rejected frame) goes through [`push`](Self::push).
    pub fn push_slice(&mut self, bytes: &[u8], mut on_frame: impl FnMut(Result<F, DecodeError>)) {
        let mut rest = bytes;
        // Bounded: every pass consumes at least one byte of `rest`.
        while !rest.is_empty() {
            if self.buf.is_empty() {
                let Some(start) = rest.iter().position(|&b| b == SYNC[0]) else {
                    self.count_skipped(rest.len());
                    return;
                };
                if start > 0 {
                    self.count_skipped(start);
                    if let Some((_, from_sync)) = rest.split_at_checked(start) {
                        rest = from_sync;
                    }
                }
                if let Some((candidate, after)) = rest.split_at_checked(F::LEN) {
                    if matches!(*candidate, [s0, s1, k, ..] if [s0, s1, k] == header::<F>()) {
                        if let Ok(frame) = F::decode(candidate) {
                            self.stats.frames_ok = self.stats.frames_ok.saturating_add(1);
                            on_frame(Ok(frame));
                            rest = after;
                            continue;
                        }
                    }
                }
            }
            let Some((&b, tail)) = rest.split_first() else { break };
            if let Some(r) = self.push(b) {
                on_frame(r);
            }
            rest = tail;
        }
    }

    /// Counters so far.
    pub fn stats(&self) -> DecoderStats {
        self.stats
    }

    /// Bytes held as the current candidate.
    pub fn buffered(&self) -> usize {
        self.buf.len()
    }

    /// Drops the current candidate (counted as skipped) and hunts for sync again.
    pub fn reset(&mut self) {
        self.drop_front(self.buf.len());
    }

    /// The last byte broke the header: silent while hunting for sync, a kind error at
    /// the kind byte.
    fn reject_prefix(&mut self) -> Option<Result<F, DecodeError>> {
        if self.buf.len() > SYNC.len() {
            Some(Err(self.reject(DecodeError::BadKind)))
        } else {
            self.resync();
            None
        }
    }

    /// Counts a rejected candidate and resynchronises inside it.
    fn reject(&mut self, e: DecodeError) -> DecodeError {
        let s = &mut self.stats;
        let counter = match e {
            DecodeError::BadCrc => &mut s.crc_errors,
            DecodeError::BadKind => &mut s.kind_errors,
            DecodeError::BadField | DecodeError::BadSync | DecodeError::BadLength => &mut s.field_errors,
        };
        *counter = counter.saturating_add(1);
        self.resync();
        e
    }

    /// Keeps the buffer from the first position after the start that is a valid prefix;
    /// drops everything if there is none.
    fn resync(&mut self) {
        let bytes = self.buf.as_slice();
        let start = (1..bytes.len())
            .find(|&i| bytes.get(i..).is_some_and(|t| is_valid_prefix(t, F::KIND)))
            .unwrap_or(bytes.len());
        self.drop_front(start);
    }

    /// Drops the first `n` buffered bytes, counting them as skipped.
    fn drop_front(&mut self, n: usize) {
        let n = n.min(self.buf.len());
        self.buf.drop_front(n);
        self.count_skipped(n);
    }

    fn count_skipped(&mut self, n: usize) {
        let n = u32::try_from(n).unwrap_or(u32::MAX);
        self.stats.bytes_skipped = self.stats.bytes_skipped.saturating_add(n);
    }
}

/// The header of frame type `F`.
fn header<F: Frame>() -> [u8; 3] {
    [SYNC[0], SYNC[1], F::KIND]
}

/// Whether `bytes` is non-empty and matches the header `EB 90 kind` as far as it goes.
fn is_valid_prefix(bytes: &[u8], kind_byte: u8) -> bool {
    let [s0, s1] = SYNC;
    match bytes {
        [] => false,
        [a] => *a == s0,
        [a, b] => *a == s0 && *b == s1,
        [a, b, k, ..] => *a == s0 && *b == s1 && *k == kind_byte,
    }
}
