//! Built-in test (BIT): what the unit can check about itself, with no sensor attached.
//!
//! - [`power_on`]: known-answer tests of the pieces every step relies on: the frame CRC,
//!   the table CRC, double-precision arithmetic and the maths library, the calibration
//!   table's binary round trip, the stream decoder's rejection and resynchronisation,
//!   and the compensation's inverse. The firmware runs it at boot and logs the result;
//!   the on-target test binary runs it under QEMU.
//! - [`replay_digest`]: a deterministic flight of `steps` steps through the whole core
//!   (synthetic FOG frames in, output frames out, over in-memory links), reduced to a
//!   CRC-32 of every output byte and the final attitude. The host computes the same
//!   digest with the same code; equal digests show the target's arithmetic (FPv5-D16,
//!   libm) gives the host's results bit for bit.

use core::convert::Infallible;

use nalgebra::Vector3;

use crate::calib::{binary, CalibrationTable, Estimator, FogCal, N_FOG};
use crate::compensation::compensate_rate;
use crate::flight::{CoreError, FlightCore, FogLinks, Links, Profile};
use crate::frames::decoder::StreamDecoder;
use crate::frames::fog::FogFrame;
use crate::frames::{body_crc, DecodeError};

/// The first known-answer test that failed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub enum BitError {
    /// The frames' CRC-32C (its flight tables, [`body_crc`]) of "123456789" is not
    /// 0xE3069283.
    FrameCrc,
    /// CRC-32/ISO-HDLC of "123456789" is not 0xCBF43926.
    TableCrc,
    /// An f64 operation or maths-library result differs from its known bits.
    Arithmetic,
    /// The default table, or the default with the MEKF selected, does not survive its
    /// binary encoding.
    TableRoundTrip,
    /// The decoder accepted a damaged frame or lost the good one after it.
    Decoder,
    /// Compensation does not invert the error model.
    Compensation,
}

/// Runs the known-answer tests; `Ok` if all pass, else the first failure.
#[inline(never)]
pub fn power_on() -> Result<(), BitError> {
    const CHECK: &[u8] = b"123456789";
    // From the register's initial value 0xFFFFFFFF, as if there were no header.
    if body_crc(crc::CRC_32_ISCSI.init, CHECK) != 0xE306_9283 {
        return Err(BitError::FrameCrc);
    }
    if binary::crc32(CHECK) != 0xCBF4_3926 {
        return Err(BitError::TableCrc);
    }
    arithmetic()?;
    let t = CalibrationTable::DEFAULT;
    let mut mekf = t;
    mekf.observer.estimator = Estimator::Mekf;
    // Compared in the binary form (the table's own derived `==` is 1 KiB of flash the
    // launch-vehicle image does not have): encoding the decoded table gives back the
    // same bytes.
    for t in [t, mekf] {
        let bytes = binary::encode(&t);
        if !binary::decode(&bytes).is_ok_and(|d| binary::encode(&d) == bytes) {
            return Err(BitError::TableRoundTrip);
        }
    }
    decoder()?;
    compensation()
}

/// Correctly rounded IEEE-754 results (hardware on the M7) and the maths library's.
fn arithmetic() -> Result<(), BitError> {
    // Inputs through `black_box` so the compiler cannot fold them at build time.
    let two = core::hint::black_box(2.0f64);
    let three = core::hint::black_box(3.0f64);
    let checks = [
        (1.0 / three, 0x3FD5_5555_5555_5555u64),
        (libm::sqrt(two), 0x3FF6_A09E_667F_3BCD),
        (0.1 * three, 0x3FD3_3333_3333_3334),
        (libm::atan2(1.0, core::hint::black_box(1.0)), 0x3FE9_21FB_5444_2D18),
        (crate::math::sin_cos(two).0, 0x3FED_18F6_EAD1_B446),
    ];
    if checks.iter().all(|&(v, bits)| v.to_bits() == bits) {
        Ok(())
    } else {
        Err(BitError::Arithmetic)
    }
}

/// A frame with one damaged byte is rejected and counted; the frame after it is kept.
fn decoder() -> Result<(), BitError> {
    let f = FogFrame::from_physical(2, 7, 0, 1.0e-6, 21.5);
    let good = f.to_bytes();
    let mut bad = good;
    if let Some(b) = bad.get_mut(9) {
        *b ^= 0x10;
    }
    let mut dec: StreamDecoder<FogFrame, 32> = StreamDecoder::new();
    let (mut ok, mut crc_errors) = (0u32, 0u32);
    for chunk in [bad.as_slice(), good.as_slice()] {
        dec.push_slice(chunk, |r| match r {
            Ok(g) if g == f => ok += 1,
            Err(DecodeError::BadCrc) => crc_errors += 1,
            _ => {}
        });
    }
    if ok == 1 && crc_errors == 1 && dec.stats().crc_errors == 1 {
        Ok(())
    } else {
        Err(BitError::Decoder)
    }
}

/// Raw output from the error model, compensated, gives the true rate back.
fn compensation() -> Result<(), BitError> {
    let cal = FogCal {
        bias_rad_s: 2.0e-6,
        scale_factor_error: 3.0e-4,
        t_ref_degc: 20.0,
        thermal_t_rad_s: [1.0e-8, -2.0e-9, 3.0e-11],
        thermal_g_rad_s_per_degc_s: 4.0e-7,
        thermal_tg_rad_s_per_degc2_s: -1.0e-8,
    };
    let (true_rate_rad_s, t_degc, g_degc_s) = (0.0123, 31.0, 0.02);
    let raw = true_rate_rad_s * (1.0 + cal.scale_factor_error) + cal.drift_rad_s(t_degc, g_degc_s);
    let back = compensate_rate(&cal, core::hint::black_box(raw), t_degc, g_degc_s);
    if (back - true_rate_rad_s).abs() < 1e-15 {
        Ok(())
    } else {
        Err(BitError::Compensation)
    }
}

/// Body rate of the replay, rad/s (a slow tumble, well inside the measuring range).
const REPLAY_RATE_RAD_S: [f64; 3] = [1.0e-3, -5.0e-4, 1.1e-3];

/// What [`replay_digest`] gives.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub struct ReplayDigest {
    /// Steps run.
    pub steps: u32,
    /// CRC-32 of every output byte, in order.
    pub output_crc: u32,
    /// The final quaternion's components (w, x, y, z) as f64 bits.
    pub q_bits: [u64; 4],
}

/// Flies the spacecraft profile for `steps` steps on the default table: four FOG frames
/// a step from a constant body rate, no star tracker; returns the digest.
/// Not inlined, and the core flown where it was built (no second copy): the on-target
/// self-test runs it on a 28 KiB stack.
#[inline(never)]
pub fn replay_digest(steps: u32) -> ReplayDigest {
    let mut built = replay_core();
    match built.as_mut() {
        Ok(core) => replay_on(core, steps),
        Err(_) => ReplayDigest { steps: 0, output_crc: 0, q_bits: [0; 4] },
    }
}

/// The core [`replay_digest`] flies: the spacecraft profile on the default table.
#[inline(never)]
fn replay_core() -> Result<FlightCore, CoreError> {
    FlightCore::new(Profile::SPACECRAFT, &CalibrationTable::DEFAULT, false)
}

/// [`replay_digest`] on `core`, fresh from [`replay_core`].
#[inline(never)]
fn replay_on(core: &mut FlightCore, steps: u32) -> ReplayDigest {
    let table = CalibrationTable::DEFAULT;
    let dt_s = Profile::SPACECRAFT.dt_s();
    let axes = table.axes();
    let mut digest = binary::CRC32.digest();
    let mut q_bits = [0u64; 4];
    let w = Vector3::from(REPLAY_RATE_RAD_S);
    let mut bus = BytesIn::default();
    let mut star = BytesIn::default();
    let mut run = 0u32;
    // Bounded by `steps`.
    for n in 0..steps {
        bus.clear();
        for (i, axis) in axes.iter().enumerate().take(N_FOG) {
            let id = u8::try_from(i).unwrap_or(0);
            let counter = u16::try_from(n % 65_536).unwrap_or(0);
            let f = FogFrame::from_physical(id, counter, 0, axis.dot(&w) * dt_s, 20.0 + 0.001 * f64::from(n));
            bus.push(&f.to_bytes());
        }
        let mut out = DigestOut { digest: &mut digest };
        let mut links = Links { fog: FogLinks::Bus(&mut bus), star: &mut star, out: &mut out };
        let o = core.step(&mut links);
        q_bits = [o.q.w.to_bits(), o.q.i.to_bits(), o.q.j.to_bits(), o.q.k.to_bits()];
        run = n + 1;
    }
    ReplayDigest { steps: run, output_crc: digest.finalize(), q_bits }
}

/// In-memory receive link: the bytes of one step.
#[derive(Default)]
struct BytesIn {
    buf: heapless::Vec<u8, 128>,
    pos: usize,
}

impl BytesIn {
    fn clear(&mut self) {
        self.buf.clear();
        self.pos = 0;
    }

    fn push(&mut self, bytes: &[u8]) {
        let _ = self.buf.extend_from_slice(bytes);
    }
}

impl embedded_io::ErrorType for BytesIn {
    type Error = Infallible;
}

impl embedded_io::ReadReady for BytesIn {
    fn read_ready(&mut self) -> Result<bool, Infallible> {
        Ok(self.pos < self.buf.len())
    }
}

impl embedded_io::Read for BytesIn {
    fn read(&mut self, out: &mut [u8]) -> Result<usize, Infallible> {
        let rest = self.buf.get(self.pos..).unwrap_or(&[]);
        let n = rest.len().min(out.len());
        if let (Some(d), Some(s)) = (out.get_mut(..n), rest.get(..n)) {
            d.copy_from_slice(s);
        }
        self.pos += n;
        Ok(n)
    }
}

/// Transmit link that folds every byte into a CRC-32.
struct DigestOut<'a, 'd> {
    digest: &'a mut crc::Digest<'d, u32>,
}

impl embedded_io::ErrorType for DigestOut<'_, '_> {
    type Error = Infallible;
}

impl embedded_io::WriteReady for DigestOut<'_, '_> {
    fn write_ready(&mut self) -> Result<bool, Infallible> {
        Ok(true)
    }
}

impl embedded_io::Write for DigestOut<'_, '_> {
    fn write(&mut self, buf: &[u8]) -> Result<usize, Infallible> {
        binary::crc32_update(self.digest, buf);
        Ok(buf.len())
    }

    fn flush(&mut self) -> Result<(), Infallible> {
        Ok(())
    }
}
