//! Mock RS-422 links for the host: they implement the same `embedded-io` traits as the
//! firmware's UART drivers and can delay, drop, split and corrupt bytes.

use std::collections::VecDeque;
use std::convert::Infallible;

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha20Rng;
use serde::{Deserialize, Serialize};

/// Impairments of one link. All probabilities are per byte.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Impairments {
    /// Steps a byte waits before it can be read.
    pub delay_steps: u64,
    /// Probability that a byte is lost.
    pub drop_prob: f64,
    /// Probability that one bit of a byte is flipped.
    pub bit_flip_prob: f64,
    /// At most this many bytes per `read` call (0 = no limit): splits frames.
    pub max_read: usize,
}

impl Default for Impairments {
    fn default() -> Self {
        Impairments { delay_steps: 0, drop_prob: 0.0, bit_flip_prob: 0.0, max_read: 0 }
    }
}

/// What a link did to the bytes it carried.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct LinkStats {
    /// Bytes offered.
    pub sent: u64,
    /// Bytes dropped.
    pub dropped: u64,
    /// Bytes with a flipped bit.
    pub corrupted: u64,
}

/// A receive link fed by the simulator.
pub struct MockLink {
    imp: Impairments,
    rng: ChaCha20Rng,
    pending: VecDeque<(u64, u8)>,
    ready: VecDeque<u8>,
    step: u64,
    stats: LinkStats,
}

impl MockLink {
    /// A link with `imp`, its randomness seeded by `seed`.
    pub fn new(imp: Impairments, seed: u64) -> Self {
        MockLink {
            imp,
            rng: ChaCha20Rng::seed_from_u64(seed),
            pending: VecDeque::new(),
            ready: VecDeque::new(),
            step: 0,
            stats: LinkStats::default(),
        }
    }

    /// An ideal link.
    pub fn ideal() -> Self {
        Self::new(Impairments::default(), 0)
    }

    /// The device sends `bytes` now.
    pub fn send(&mut self, bytes: &[u8]) {
        let ideal = self.imp.drop_prob <= 0.0 && self.imp.bit_flip_prob <= 0.0 && self.imp.delay_steps == 0;
        if ideal && self.pending.is_empty() {
            // Nothing to delay, drop or flip: readable at once, in order.
            self.stats.sent += bytes.len() as u64;
            self.ready.extend(bytes);
            return;
        }
        for &b in bytes {
            self.stats.sent += 1;
            if self.imp.drop_prob > 0.0 && self.rng.random::<f64>() < self.imp.drop_prob {
                self.stats.dropped += 1;
                continue;
            }
            let mut b = b;
            if self.imp.bit_flip_prob > 0.0 && self.rng.random::<f64>() < self.imp.bit_flip_prob {
                b ^= 1 << self.rng.random_range(0..8);
                self.stats.corrupted += 1;
            }
            self.pending.push_back((self.step + self.imp.delay_steps, b));
        }
        self.release();
    }

    /// A step boundary: delayed bytes whose time has come become readable.
    pub fn tick(&mut self) {
        self.step += 1;
        self.release();
    }

    fn release(&mut self) {
        while let Some(&(due, b)) = self.pending.front() {
            if due > self.step {
                break;
            }
            self.ready.push_back(b);
            self.pending.pop_front();
        }
    }

    /// What the link did so far.
    pub fn stats(&self) -> LinkStats {
        self.stats
    }
}

impl embedded_io::ErrorType for MockLink {
    type Error = Infallible;
}

impl embedded_io::ReadReady for MockLink {
    fn read_ready(&mut self) -> Result<bool, Infallible> {
        Ok(!self.ready.is_empty())
    }
}

impl embedded_io::Read for MockLink {
    fn read(&mut self, buf: &mut [u8]) -> Result<usize, Infallible> {
        let limit = if self.imp.max_read == 0 { buf.len() } else { buf.len().min(self.imp.max_read) };
        let n = limit.min(self.ready.len());
        // The ring's two runs, each copied whole.
        let (a, b) = self.ready.as_slices();
        let from_a = n.min(a.len());
        let (to_a, to_b) = buf[..n].split_at_mut(from_a);
        to_a.copy_from_slice(&a[..from_a]);
        to_b.copy_from_slice(&b[..n - from_a]);
        self.ready.drain(..n);
        Ok(n)
    }
}

/// The output link: collects every byte the core writes.
#[derive(Default)]
pub struct MockSink {
    /// Bytes written and not yet taken.
    pub bytes: Vec<u8>,
    /// When set, the sink refuses writes (to test dropped output).
    pub blocked: bool,
}

impl embedded_io::ErrorType for MockSink {
    type Error = Infallible;
}

impl embedded_io::WriteReady for MockSink {
    fn write_ready(&mut self) -> Result<bool, Infallible> {
        Ok(!self.blocked)
    }
}

impl embedded_io::Write for MockSink {
    fn write(&mut self, buf: &[u8]) -> Result<usize, Infallible> {
        if self.blocked {
            return Ok(0);
        }
        self.bytes.extend_from_slice(buf);
        Ok(buf.len())
    }

    fn flush(&mut self) -> Result<(), Infallible> {
        Ok(())
    }
}
