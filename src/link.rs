//! RS-422 links: one non-blocking byte stream per device, on the `embedded-io` traits.
//!
//! A receive link is anything that implements [`embedded_io::Read`] +
//! [`embedded_io::ReadReady`]; the flight step only reads while `read_ready()` says bytes
//! have arrived, so it never waits. A transmit link is [`embedded_io::Write`] +
//! [`embedded_io::WriteReady`]. The firmware's UART drivers and the host's mock links
//! implement these traits; nothing here is specific to a board.
//!
//! [`RxRing`] / [`TxRing`] are the interrupt-to-loop buffers: an ISR pushes (or pops)
//! bytes inside a `critical-section`, the step reads (or writes) through a handle.

use core::cell::RefCell;
use core::convert::Infallible;
use core::sync::atomic::{AtomicU32, Ordering};

use critical_section::Mutex;

/// A receive link: non-blocking byte source.
pub trait RxLink: embedded_io::Read + embedded_io::ReadReady {}
impl<T: embedded_io::Read + embedded_io::ReadReady> RxLink for T {}

/// A transmit link: non-blocking byte sink.
pub trait TxLink: embedded_io::Write + embedded_io::WriteReady {}
impl<T: embedded_io::Write + embedded_io::WriteReady> TxLink for T {}

/// The FOG intake's port: any receive link (read through the caller's scratch buffer,
/// [`drain`]), or an [`RxRing`]'s [`RingPort`], whose bytes the sink reads where they
/// lie in the ring: no copy.
pub trait RxPort {
    /// Hands at most `max_bytes` that have already arrived to `sink`, in order, in one
    /// or more slices; never waits.
    fn drain_into(&mut self, max_bytes: usize, scratch: &mut [u8], sink: impl FnMut(&[u8])) -> DrainReport;
}

impl<T: RxLink> RxPort for T {
    #[inline]
    fn drain_into(&mut self, max_bytes: usize, scratch: &mut [u8], sink: impl FnMut(&[u8])) -> DrainReport {
        drain(self, max_bytes, scratch, sink)
    }
}

/// The output port of the flight step: where it sends its frame. Any transmit link
/// (the frame is encoded into the caller's scratch and written), or a [`TxRing`]'s
/// [`FramePort`], into whose memory the frame is encoded in place: no copy of the frame,
/// one critical section a frame.
pub trait OutPort {
    /// Sends one frame of `len` bytes that `encode` writes into the slice it is given
    /// (`false`: nothing to send); `scratch` (at least `len` bytes) is used where the port
    /// cannot lend its own memory. `true` if the whole frame was taken; a port that cannot
    /// take it whole takes none of it.
    fn send_frame(&mut self, scratch: &mut [u8], len: usize, encode: impl FnOnce(&mut [u8]) -> bool) -> bool;
}

impl<T: TxLink> OutPort for T {
    #[inline]
    fn send_frame(&mut self, scratch: &mut [u8], len: usize, encode: impl FnOnce(&mut [u8]) -> bool) -> bool {
        match scratch.get_mut(..len) {
            Some(buf) => encode(buf) && write_frame(self, buf),
            None => false,
        }
    }
}

/// The star-tracker port of the flight step: a receive link, or [`NotFitted`] on a unit
/// that has no star tracker (the launch vehicle). With `NotFitted` the star-tracker stage
/// is known absent at compile time, so its code (frame intake, the observer's update, the
/// MEKF's update, the mounting check's frames) is not in that unit's firmware.
pub trait StarPort {
    /// The link behind the port.
    type Link: RxLink;
    /// The link, or `None` when no star tracker is fitted.
    fn link(&mut self) -> Option<&mut Self::Link>;
}

impl<T: RxLink> StarPort for T {
    type Link = T;
    #[inline(always)]
    fn link(&mut self) -> Option<&mut T> {
        Some(self)
    }
}

/// No star tracker fitted ([`StarPort`]).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct NotFitted;

/// The link type of [`NotFitted`]: uninhabited, never read.
#[derive(Debug)]
pub enum NoLink {}

impl embedded_io::ErrorType for NoLink {
    type Error = Infallible;
}

impl embedded_io::Read for NoLink {
    fn read(&mut self, _buf: &mut [u8]) -> Result<usize, Infallible> {
        match *self {}
    }
}

impl embedded_io::ReadReady for NoLink {
    fn read_ready(&mut self) -> Result<bool, Infallible> {
        match *self {}
    }
}

impl StarPort for NotFitted {
    type Link = NoLink;
    #[inline(always)]
    fn link(&mut self) -> Option<&mut NoLink> {
        None
    }
}

/// What one drain of a receive link did.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct DrainReport {
    /// Bytes read.
    pub bytes: usize,
    /// Driver errors (each ends the drain for this step).
    pub io_errors: u32,
}

/// Reads at most `max_bytes` that have already arrived on `link`, handing each chunk to
/// `sink`. Never waits: stops when `read_ready()` is false, on an error, or at the bound.
/// Chunks are read through `scratch` (the caller's buffer, kept between calls so a step
/// does not clear one); an empty `scratch` reads nothing.
pub fn drain<L: RxLink>(
    link: &mut L,
    max_bytes: usize,
    scratch: &mut [u8],
    mut sink: impl FnMut(&[u8]),
) -> DrainReport {
    let mut report = DrainReport::default();
    let buf = scratch;
    if buf.is_empty() {
        return report;
    }
    // Bounded: each pass reads at least one byte or stops.
    while report.bytes < max_bytes {
        match link.read_ready() {
            Ok(true) => {}
            Ok(false) => break,
            Err(_) => {
                report.io_errors = report.io_errors.saturating_add(1);
                break;
            }
        }
        let want = (max_bytes - report.bytes).min(buf.len());
        let Some(chunk) = buf.get_mut(..want) else { break };
        match link.read(chunk) {
            Ok(0) => break,
            Ok(n) => {
                if let Some(got) = chunk.get(..n) {
                    sink(got);
                }
                report.bytes += n;
            }
            Err(_) => {
                report.io_errors = report.io_errors.saturating_add(1);
                break;
            }
        }
    }
    report
}

/// Writes one frame's `bytes` without waiting: `true` if all of it was taken, `false`
/// (for the caller to count) if the link could not take it now. Never calls
/// `write_all`, whose default panics when a non-blocking sink takes nothing. A sink that
/// fills part-way leaves a truncated frame, which the receiver's decoder rejects; a
/// [`TxRing::frame_writer`] never does (it is ready only when the whole frame fits).
pub fn write_frame<O: TxLink>(out: &mut O, bytes: &[u8]) -> bool {
    let mut rest = bytes;
    // Bounded: each pass takes at least one byte or stops.
    for _ in 0..bytes.len() {
        if rest.is_empty() {
            break;
        }
        if !matches!(out.write_ready(), Ok(true)) {
            return false;
        }
        match out.write(rest) {
            Ok(n) if n > 0 => rest = rest.get(n..).unwrap_or(&[]),
            _ => return false,
        }
    }
    rest.is_empty()
}

/// A fixed byte FIFO with whole-run copies in and out (at most two `copy_from_slice` each
/// way), so a step moves a frame with a couple of memcpys instead of a loop per byte.
struct ByteFifo<const N: usize> {
    buf: [u8; N],
    /// Index of the oldest byte.
    head: usize,
    /// Bytes stored.
    len: usize,
}

impl<const N: usize> ByteFifo<N> {
    const fn new() -> Self {
        ByteFifo { buf: [0; N], head: 0, len: 0 }
    }

    fn free(&self) -> usize {
        N - self.len
    }

    /// Stores one byte; `false` when full.
    fn push(&mut self, byte: u8) -> bool {
        if self.len >= N {
            return false;
        }
        let i = self.head + self.len;
        let i = if i >= N { i - N } else { i };
        if let Some(slot) = self.buf.get_mut(i) {
            *slot = byte;
            self.len += 1;
            true
        } else {
            false
        }
    }

    /// Removes the oldest byte.
    fn pop(&mut self) -> Option<u8> {
        if self.len == 0 {
            return None;
        }
        let b = self.buf.get(self.head).copied();
        self.head = if self.head + 1 >= N { 0 } else { self.head + 1 };
        self.len -= 1;
        if self.len == 0 {
            self.head = 0;
        }
        b
    }

    /// Moves up to `out.len()` of the oldest bytes into `out`; returns the count.
    fn pop_into(&mut self, out: &mut [u8]) -> usize {
        let n = self.len.min(out.len());
        let first = n.min(N - self.head);
        let (o1, o2) = out.split_at_mut(first);
        if let (Some(d), Some(s)) = (Some(o1), self.buf.get(self.head..self.head + first)) {
            d.copy_from_slice(s);
        }
        if let (Some(d), Some(s)) = (o2.get_mut(..n - first), self.buf.get(..n - first)) {
            d.copy_from_slice(s);
        }
        let h = self.head + n;
        self.head = if h >= N { h - N } else { h };
        self.len -= n;
        if self.len == 0 {
            // Restart at the front: the next run is copied whole and word-aligned.
            self.head = 0;
        }
        n
    }

    /// The `len` bytes after the stored ones, if they are free and contiguous.
    fn tail_run(&mut self, len: usize) -> Option<&mut [u8]> {
        if self.free() < len {
            return None;
        }
        let tail = self.head + self.len;
        let tail = if tail >= N { tail - N } else { tail };
        self.buf.get_mut(tail..tail + len)
    }

    /// Drops the `n` oldest bytes (at most all of them).
    fn consume(&mut self, n: usize) {
        let n = n.min(self.len);
        let h = self.head + n;
        self.head = if h >= N { h - N } else { h };
        self.len -= n;
        if self.len == 0 {
            // Restart at the front: the next run is whole and word-aligned.
            self.head = 0;
        }
    }

    /// Appends as much of `data` as fits; returns the count.
    fn push_from(&mut self, data: &[u8]) -> usize {
        let n = self.free().min(data.len());
        let tail = self.head + self.len;
        let tail = if tail >= N { tail - N } else { tail };
        let first = n.min(N - tail);
        if let (Some(d), Some(s)) = (self.buf.get_mut(tail..tail + first), data.get(..first)) {
            d.copy_from_slice(s);
        }
        if let (Some(d), Some(s)) = (self.buf.get_mut(..n - first), data.get(first..n)) {
            d.copy_from_slice(s);
        }
        self.len += n;
        n
    }
}

/// Borrows of a ring's state that failed since start ([`ring_faults`]).
static RING_FAULTS: AtomicU32 = AtomicU32::new(0);

/// A ring's indices, which every operation keeps within its buffer (the oldest byte's
/// index below N, the count at most N): a state outside them is an upset.
trait Sound {
    fn sound(&self) -> bool;
}

impl<const N: usize> Sound for ByteFifo<N> {
    #[inline(always)]
    fn sound(&self) -> bool {
        self.head < N && self.len <= N
    }
}

impl<const N: usize> Sound for RingState<N> {
    #[inline(always)]
    fn sound(&self) -> bool {
        self.bytes.sound()
    }
}

/// Runs `f` on a ring's state inside a critical section. Only this function borrows the
/// cell, one closure at a time with interrupts masked, so in a sound state the borrow
/// cannot fail. It fails only when the cell's borrow flag is corrupted (a bit flipped in
/// RAM, or in the register that writes the flag back), and then for good: the ring would
/// take no byte again. Its indices out of their range are an upset too, that would last:
/// a count above the buffer's length (one high bit flipped) drops every byte received
/// until it has been read down, seconds of a link's data, and in lockstep the STEP that
/// paces the unit. So either skips `f`, returns `otherwise` and is counted in
/// [`ring_faults`], for the main loop to reset the unit. (`borrow_ref_mut` would panic
/// there: a panic path the release firmware may not link, README "No panics".)
fn with_state<T: Sound, R>(m: &Mutex<RefCell<T>>, otherwise: R, f: impl FnOnce(&mut T) -> R) -> R {
    critical_section::with(|cs| match m.borrow(cs).try_borrow_mut() {
        Ok(mut s) if s.sound() => f(&mut s),
        _ => {
            RING_FAULTS.fetch_add(1, Ordering::Relaxed);
            otherwise
        }
    })
}

/// Borrows of an [`RxRing`]'s or a [`TxRing`]'s state that failed since start: not zero
/// only when a ring's borrow flag or its indices are corrupted, which nothing but a reset
/// clears (the firmware's main loop resets the unit, which resumes from its snapshot).
pub fn ring_faults() -> u32 {
    RING_FAULTS.load(Ordering::Relaxed)
}

/// Receive buffer shared between a UART interrupt (producer) and the step (consumer).
pub struct RxRing<const N: usize> {
    inner: Mutex<RefCell<RingState<N>>>,
}

struct RingState<const N: usize> {
    bytes: ByteFifo<N>,
    overflows: u32,
    received: u32,
}

impl<const N: usize> RxRing<N> {
    /// An empty ring (usable in a `static`).
    pub const fn new() -> Self {
        RxRing { inner: Mutex::new(RefCell::new(RingState { bytes: ByteFifo::new(), overflows: 0, received: 0 })) }
    }

    /// Called from the interrupt: stores one received byte; a full ring drops it and
    /// counts an overflow.
    pub fn push(&self, byte: u8) {
        with_state(&self.inner, (), |s| {
            s.received = s.received.wrapping_add(1);
            if !s.bytes.push(byte) {
                s.overflows = s.overflows.saturating_add(1);
            }
        });
    }

    /// Bytes received since start (wrapping), including any dropped.
    pub fn received(&self) -> u32 {
        with_state(&self.inner, 0, |s| s.received)
    }

    /// Bytes dropped because the ring was full.
    pub fn overflows(&self) -> u32 {
        with_state(&self.inner, 0, |s| s.overflows)
    }

    /// The consumer's handle, which implements the receive-link traits.
    pub fn reader(&self) -> RxRingReader<'_, N> {
        RxRingReader { ring: self }
    }

    /// The consumer's port ([`RxPort`]): the sink reads the bytes in the ring, inside one
    /// critical section (decoding a step's four 18-byte FOG frames, some 800
    /// instructions, 2 µs at 400 MHz; the UARTs' receive FIFOs hold far longer than that),
    /// then they are consumed.
    pub fn port(&self) -> RingPort<'_, N> {
        RingPort { ring: self }
    }
}

/// An [`RxRing`]'s port ([`RxRing::port`]).
pub struct RingPort<'a, const N: usize> {
    ring: &'a RxRing<N>,
}

impl<const N: usize> RxPort for RingPort<'_, N> {
    fn drain_into(&mut self, max_bytes: usize, _scratch: &mut [u8], mut sink: impl FnMut(&[u8])) -> DrainReport {
        let bytes = with_state(&self.ring.inner, 0, |s| {
            let f = &mut s.bytes;
            let n = f.len.min(max_bytes);
            let first = n.min(N - f.head);
            if let Some(run) = f.buf.get(f.head..f.head + first) {
                sink(run);
            }
            if let Some(run) = f.buf.get(..n - first).filter(|r| !r.is_empty()) {
                sink(run);
            }
            f.consume(n);
            n
        });
        DrainReport { bytes, io_errors: 0 }
    }
}

impl<const N: usize> Default for RxRing<N> {
    fn default() -> Self {
        Self::new()
    }
}

/// Consumer handle of an [`RxRing`].
pub struct RxRingReader<'a, const N: usize> {
    ring: &'a RxRing<N>,
}

impl<const N: usize> embedded_io::ErrorType for RxRingReader<'_, N> {
    type Error = Infallible;
}

impl<const N: usize> embedded_io::ReadReady for RxRingReader<'_, N> {
    fn read_ready(&mut self) -> Result<bool, Infallible> {
        Ok(with_state(&self.ring.inner, false, |s| s.bytes.len > 0))
    }
}

impl<const N: usize> embedded_io::Read for RxRingReader<'_, N> {
    fn read(&mut self, buf: &mut [u8]) -> Result<usize, Infallible> {
        Ok(with_state(&self.ring.inner, 0, |s| s.bytes.pop_into(buf)))
    }
}

/// Transmit buffer: the step writes frames, the UART interrupt takes bytes.
pub struct TxRing<const N: usize> {
    inner: Mutex<RefCell<ByteFifo<N>>>,
}

impl<const N: usize> TxRing<N> {
    /// An empty ring.
    pub const fn new() -> Self {
        TxRing { inner: Mutex::new(RefCell::new(ByteFifo::new())) }
    }

    /// Called from the interrupt: the next byte to send, if any.
    pub fn pop(&self) -> Option<u8> {
        with_state(&self.inner, None, |f| f.pop())
    }

    /// Bytes waiting.
    pub fn len(&self) -> usize {
        with_state(&self.inner, 0, |f| f.len)
    }

    /// Whether nothing is waiting.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The producer's handle, which implements the transmit-link traits; ready while
    /// one byte fits.
    pub fn writer(&self) -> TxRingWriter<'_, N> {
        TxRingWriter { ring: self, ready_free: 1 }
    }

    /// The producer's frame port ([`OutPort`]): each frame is encoded straight into the
    /// ring, inside one critical section (the encoding of a 97-byte output frame, some
    /// 500 instructions, about 1 µs at 400 MHz: interrupts wait that long at most), and
    /// is taken whole or not at all.
    pub fn frame_port(&self) -> FramePort<'_, N> {
        FramePort { ring: self }
    }

    /// A producer's handle for frames of `frame_len` bytes: ready only while a whole
    /// frame fits, so a step that finds the link behind drops its frame whole (and
    /// counts it) instead of sending a truncated one that the receiver must reject.
    pub fn frame_writer(&self, frame_len: usize) -> TxRingWriter<'_, N> {
        TxRingWriter { ring: self, ready_free: frame_len.clamp(1, N.max(1)) }
    }
}

impl<const N: usize> Default for TxRing<N> {
    fn default() -> Self {
        Self::new()
    }
}

/// A [`TxRing`]'s frame port ([`TxRing::frame_port`]).
pub struct FramePort<'a, const N: usize> {
    ring: &'a TxRing<N>,
}

/// What encoding in place found.
enum InPlace {
    /// The frame was encoded in the ring (`true`) or `encode` declined (`false`).
    Done(bool),
    /// The free space wraps round the end of the ring, or is too short.
    NoRun,
}

impl<const N: usize> OutPort for FramePort<'_, N> {
    fn send_frame(&mut self, scratch: &mut [u8], len: usize, encode: impl FnOnce(&mut [u8]) -> bool) -> bool {
        let mut encode = Some(encode);
        let r = with_state(&self.ring.inner, InPlace::Done(false), |f| match f.tail_run(len) {
            Some(run) => {
                let ok = encode.take().is_some_and(|e| e(run));
                if ok {
                    f.len += len;
                }
                InPlace::Done(ok)
            }
            None => InPlace::NoRun,
        });
        match (r, encode) {
            (InPlace::Done(ok), _) => ok,
            // The free space wraps: encoded aside, copied in two runs if it all fits.
            (InPlace::NoRun, Some(e)) => match scratch.get_mut(..len) {
                Some(buf) => {
                    e(&mut *buf) && with_state(&self.ring.inner, false, |f| f.free() >= len && f.push_from(buf) == len)
                }
                None => false,
            },
            (InPlace::NoRun, None) => false,
        }
    }
}

/// Producer handle of a [`TxRing`]. `write` stores what fits and returns the count.
pub struct TxRingWriter<'a, const N: usize> {
    ring: &'a TxRing<N>,
    /// Free bytes needed before `write_ready` says yes.
    ready_free: usize,
}

impl<const N: usize> TxRingWriter<'_, N> {
    /// Free space in bytes.
    pub fn free(&self) -> usize {
        with_state(&self.ring.inner, 0, |f| f.free())
    }
}

impl<const N: usize> embedded_io::ErrorType for TxRingWriter<'_, N> {
    type Error = Infallible;
}

impl<const N: usize> embedded_io::WriteReady for TxRingWriter<'_, N> {
    fn write_ready(&mut self) -> Result<bool, Infallible> {
        Ok(self.free() >= self.ready_free)
    }
}

impl<const N: usize> embedded_io::Write for TxRingWriter<'_, N> {
    fn write(&mut self, buf: &[u8]) -> Result<usize, Infallible> {
        Ok(with_state(&self.ring.inner, 0, |f| f.push_from(buf)))
    }

    fn flush(&mut self) -> Result<(), Infallible> {
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    extern crate std;
    use std::vec::Vec;

    use super::*;

    /// Everything the port hands over, in order.
    fn drain_all<const N: usize>(ring: &RxRing<N>, max_bytes: usize) -> Vec<u8> {
        let mut got = Vec::new();
        ring.port().drain_into(max_bytes, &mut [], |s| got.extend_from_slice(s));
        got
    }

    /// The receive ring keeps order across its wrap and counts what a full ring drops.
    #[test]
    fn the_receive_ring_wraps_in_order_and_counts_overflows() {
        let ring = RxRing::<8>::new();
        for b in 0..6u8 {
            ring.push(b);
        }
        assert_eq!(drain_all(&ring, 4), [0, 1, 2, 3]);
        // Head at 4: these wrap round the end.
        for b in 6..12u8 {
            ring.push(b);
        }
        assert_eq!(drain_all(&ring, 100), [4, 5, 6, 7, 8, 9, 10, 11]);
        for b in 0..10u8 {
            ring.push(b);
        }
        assert_eq!(ring.overflows(), 2);
        assert_eq!(ring.received(), 22);
        assert_eq!(drain_all(&ring, 100), [0, 1, 2, 3, 4, 5, 6, 7]);
        assert!(drain_all(&ring, 100).is_empty());
    }

    /// A ring whose count or oldest index an upset put beyond its buffer takes no byte
    /// and gives none, and is counted for the main loop, which resets the unit (the
    /// count 2^17 higher: the QEMU campaign's control ring, which then dropped every
    /// byte, the runner's STEP among them).
    #[test]
    fn indices_beyond_the_buffer_are_counted_not_used() {
        for (head, len) in [(0, 3 + (1 << 17)), (8, 3), (1 << 20, 0), (0, 9)] {
            let ring = RxRing::<8>::new();
            for b in 0..3u8 {
                ring.push(b);
            }
            critical_section::with(|cs| {
                let mut s = ring.inner.borrow(cs).borrow_mut();
                (s.bytes.head, s.bytes.len) = (head, len);
            });
            let before = ring_faults();
            ring.push(9);
            assert!(drain_all(&ring, 100).is_empty(), "head {head} len {len}");
            assert!(ring_faults() >= before + 2, "head {head} len {len}");
        }
        // At the bounds: sound.
        let ring = RxRing::<8>::new();
        for b in 0..8u8 {
            ring.push(b);
        }
        let before = ring_faults();
        assert_eq!(drain_all(&ring, 100), [0, 1, 2, 3, 4, 5, 6, 7]);
        assert_eq!(ring_faults(), before);
    }

    /// A borrow that fails (here: a push while the port holds the ring, the state a
    /// corrupted borrow flag leaves for good) loses that byte and is counted for the main
    /// loop, which resets the unit.
    #[test]
    fn a_failed_borrow_is_counted_not_ignored() {
        let ring = RxRing::<8>::new();
        ring.push(1);
        let before = ring_faults();
        let mut got = Vec::new();
        ring.port().drain_into(8, &mut [], |s| {
            got.extend_from_slice(s);
            ring.push(2);
        });
        assert_eq!(got, [1]);
        assert!(ring_faults() > before);
        assert_eq!(ring.received(), 1);
        assert!(drain_all(&ring, 8).is_empty());
    }

    /// The reader (embedded-io) and `drain` give the bytes in order, bounded by the
    /// caller's limit and scratch.
    #[test]
    fn drain_reads_what_arrived_up_to_its_bound() {
        let ring = RxRing::<16>::new();
        for b in 0..12u8 {
            ring.push(b);
        }
        let mut reader = ring.reader();
        let mut scratch = [0u8; 5];
        let mut got = Vec::new();
        let r = drain(&mut reader, 9, &mut scratch, |s| {
            assert!(s.len() <= 5);
            got.extend_from_slice(s);
        });
        assert_eq!(r, DrainReport { bytes: 9, io_errors: 0 });
        assert_eq!(got, (0..9).collect::<Vec<u8>>());
        let r = drain(&mut reader, 100, &mut [], |_| panic!("an empty scratch reads nothing"));
        assert_eq!(r.bytes, 0);
        let r = drain(&mut reader, 100, &mut scratch, |s| got.extend_from_slice(s));
        assert_eq!(r.bytes, 3);
        assert_eq!(got, (0..12).collect::<Vec<u8>>());
    }

    /// The frame port takes a frame whole or not at all, in place or, when the free
    /// space wraps, through the scratch buffer.
    #[test]
    fn the_frame_port_takes_frames_whole_or_not_at_all() {
        let ring = TxRing::<10>::new();
        let mut port = ring.frame_port();
        let mut scratch = [0u8; 16];
        let frame = |first: u8| {
            move |buf: &mut [u8]| {
                for (i, b) in buf.iter_mut().enumerate() {
                    *b = first + i as u8;
                }
                true
            }
        };
        assert!(port.send_frame(&mut scratch, 4, frame(10)));
        assert!(port.send_frame(&mut scratch, 4, frame(20)));
        // 2 bytes free: refused whole.
        assert!(!port.send_frame(&mut scratch, 4, frame(30)));
        assert_eq!(ring.len(), 8);
        for want in [10, 11, 12, 13, 20, 21] {
            assert_eq!(ring.pop(), Some(want));
        }
        // 8 free, but from index 8 only 2 are contiguous: encoded aside and copied.
        assert!(port.send_frame(&mut scratch, 6, frame(40)));
        let rest: Vec<u8> = core::iter::from_fn(|| ring.pop()).collect();
        assert_eq!(rest, [22, 23, 40, 41, 42, 43, 44, 45]);
        // An encoder that declines sends nothing.
        assert!(!port.send_frame(&mut scratch, 4, |_| false));
        assert!(ring.is_empty());
    }

    /// A frame writer is ready only while a whole frame fits; `write_frame` never
    /// blocks and reports a frame it could not send.
    #[test]
    fn a_frame_writer_sends_whole_frames_only() {
        let ring = TxRing::<10>::new();
        let mut w = ring.frame_writer(4);
        assert!(write_frame(&mut w, &[1, 2, 3, 4]));
        assert!(write_frame(&mut w, &[5, 6, 7, 8]));
        assert_eq!(w.free(), 2);
        assert!(!write_frame(&mut w, &[9, 10, 11, 12]));
        assert_eq!(ring.len(), 8);
        // A byte writer takes what fits: the frame is cut, and write_frame says so.
        let mut b = ring.writer();
        assert!(!write_frame(&mut b, &[9, 10, 11, 12]));
        assert_eq!(ring.len(), 10);
    }
}
