//! Framing of the RS-422 links: FOG samples in, star-tracker solutions in, state out.
//!
//! Byte-by-byte layouts, units and example frames are in `docs/ICD.md`; this module is
//! their one implementation.
//!
//! What it provides:
//! - the common envelope of every frame: [`SYNC`] (`EB 90`), one kind byte
//!   ([`kind`]), the fields (little-endian), and a CRC-32C ([`CRC32C`]) over
//!   everything before it, sent little-endian;
//! - the [`Frame`] trait: one generic envelope codec ([`Frame::encode_into`],
//!   [`Frame::decode`]) around each type's field codec, so that one streaming decoder
//!   serves every frame type;
//! - the frames: [`fog::FogFrame`] (18 bytes), [`accel::AccelFrame`] (18 bytes),
//!   [`star::StarFrame`] (34 bytes), [`gnss::GnssFrame`] (47 bytes),
//!   [`navout::NavOutputFrame`] (66 bytes),
//!   [`output::OutputFrame`] (85 bytes), [`event::EventFrame`] (60 bytes), each with raw-count fields, physical-unit
//!   accessors and a saturating `from_physical` constructor (NaN encodes as 0);
//!   [`control::ControlFrame`] (18 bytes, test equipment), and the command link's
//!   [`telecommand::Telecommand`] (98 bytes) and [`telecommand::CommandReport`]
//!   (34 bytes);
//! - [`decoder::StreamDecoder`]: a fixed-capacity byte-stream decoder that hunts for
//!   sync, checks kind, CRC and fields, counts every rejection and resynchronises inside
//!   rejected bytes, so a frame that follows garbage is not lost.
//!
//! Nothing here allocates, panics or loops without bound.

pub mod accel;
pub mod control;
pub mod decoder;
pub mod event;
pub mod fog;
pub mod gnss;
pub mod navout;
pub mod output;
pub mod star;
pub mod telecommand;

/// The two sync bytes that open every frame.
pub const SYNC: [u8; 2] = [0xEB, 0x90];

/// Frame-kind bytes (byte 2 of every frame).
pub mod kind {
    /// FOG sample frame ([`super::fog::FogFrame`]).
    pub const FOG: u8 = 0x10;
    /// Accelerometer sample frame ([`super::accel::AccelFrame`], launch-vehicle unit).
    pub const ACCEL: u8 = 0x11;
    /// Star-tracker frame ([`super::star::StarFrame`]).
    pub const STAR: u8 = 0x20;
    /// GNSS fix frame ([`super::gnss::GnssFrame`], launch-vehicle unit).
    pub const GNSS: u8 = 0x21;
    /// Output frame ([`super::output::OutputFrame`]).
    pub const OUTPUT: u8 = 0x30;
    /// Navigation output frame ([`super::navout::NavOutputFrame`], launch-vehicle unit).
    pub const NAV_OUTPUT: u8 = 0x31;
    /// Event frame: records of the unit's event log ([`super::event::EventFrame`]).
    pub const EVENT: u8 = 0x32;
    /// Control frame (test equipment → unit).
    pub const CONTROL: u8 = 0x40;
    /// Telecommand (ground → unit, [`super::telecommand::Telecommand`]).
    pub const TELECOMMAND: u8 = 0x50;
    /// Command report (unit → ground, [`super::telecommand::CommandReport`]).
    pub const COMMAND_REPORT: u8 = 0x51;
}

/// Bytes before the fields: sync (2) and kind (1).
pub const HEADER_LEN: usize = 3;
/// Bytes of the trailing CRC.
pub const CRC_LEN: usize = 4;
/// Envelope overhead of every frame: header and CRC.
pub const OVERHEAD_LEN: usize = HEADER_LEN + CRC_LEN;

/// The frame CRC: CRC-32C (Castagnoli; catalogue name CRC-32/ISCSI): polynomial
/// 0x1EDC6F41, input and output reflected, init and xorout 0xFFFFFFFF; check value of
/// `"123456789"` is 0xE3069283. Computed over every byte before the CRC (sync and kind
/// included), sent little-endian.
///
/// Hamming distance at the frames' lengths (`host-tests/tests/frames.rs` proves both
/// from the single-bit syndromes): 8 for the 14 bytes before the CRC of the FOG,
/// accelerometer and control frames (every error of 1 to 7 bits detected), 6 for every
/// longer frame up to the telecommand's 94 bytes (every error of 1 to 5 bits detected).
/// Koopman's tables give this polynomial HD 8 up to 177 data bits and HD 6 up to 5,243.
pub const CRC32C: crc::Crc<u32> = crc::Crc::<u32>::new(&crc::CRC_32_ISCSI);

/// The reflected CRC-32C polynomial (0x1EDC6F41 bit-reversed).
const POLY_REFLECTED: u32 = 0x82F6_3B78;

/// The CRC register after a frame's constant header `EB 90 kind` (init applied, xorout
/// not). The CRC of a whole frame is the CRC of its body continued from this register
/// ([`body_crc`]): the three header bytes, the same in every frame of a kind, are folded
/// in at compile time instead of at every frame.
pub const fn header_crc(kind: u8) -> u32 {
    let [s0, s1] = SYNC;
    // The crate's checksum is the register XOR xorout (reflected in and out).
    CRC32C.checksum(&[s0, s1, kind]) ^ crc::CRC_32_ISCSI.xorout
}

/// CRC-32C of a frame whose register after the header is `header_crc` ([`header_crc`])
/// and whose bytes after the header, up to the CRC field, are `body`: equal to
/// [`CRC32C`] over the whole.
///
/// Four bytes a pass ("slicing by 4"): with T₀ the byte table of the reflected
/// polynomial and Tₖ\[x\] = (Tₖ₋₁\[x\] ≫ 8) ⊕ T₀\[Tₖ₋₁\[x\] & 0xFF\] (the table of a byte
/// followed by k zero bytes), r ← T₃\[r₀\] ⊕ T₂\[r₁\] ⊕ T₁\[r₂\] ⊕ T₀\[r₃\] for
/// r = crc ⊕ (the four bytes read as one little-endian word), rᵢ its bytes, by the
/// linearity of the CRC: one word load, one XOR and four table loads per four bytes;
/// the one to three bytes left over likewise in one pass. 4 KiB of flash.
/// `tests/frames.rs` checks it against [`CRC32C`].
#[inline]
pub fn body_crc(header_crc: u32, body: &[u8]) -> u32 {
    let [t0, t1, t2, t3] = &CRC_TABLES;
    let at = |t: &[u32; 256], i: u8| t.get(usize::from(i)).copied().unwrap_or(0);
    let mut r = header_crc;
    let (words, rest) = body.as_chunks::<4>();
    for w in words {
        let [b0, b1, b2, b3] = (r ^ u32::from_le_bytes(*w)).to_le_bytes();
        r = at(t3, b0) ^ at(t2, b1) ^ at(t1, b2) ^ at(t0, b3);
    }
    // The last one to three bytes in one pass, by the same linearity: Tₖ₋₁ … T₀ of the
    // register's low bytes XOR the bytes, and the register shifted past them.
    let [x0, x1, x2, _] = r.to_le_bytes();
    r = match *rest {
        [b0] => at(t0, x0 ^ b0) ^ (r >> 8),
        [b0, b1] => at(t1, x0 ^ b0) ^ at(t0, x1 ^ b1) ^ (r >> 16),
        [b0, b1, b2] => at(t2, x0 ^ b0) ^ at(t1, x1 ^ b1) ^ at(t0, x2 ^ b2) ^ (r >> 24),
        _ => r,
    };
    r ^ crc::CRC_32_ISCSI.xorout
}

/// The CRC-32C register after `bytes`, continued from register `r` ([`body_crc`] without
/// its final XOR): out of line, one copy for the background checks (the table's in RAM,
/// the code's in flash), which run a slice every few steps.
#[inline(never)]
pub fn crc32c_register(r: u32, bytes: &[u8]) -> u32 {
    body_crc(r, bytes) ^ crc::CRC_32_ISCSI.xorout
}

/// T₀ … T₃ of [`body_crc`], built at compile time.
static CRC_TABLES: [[u32; 256]; 4] = crc_tables(POLY_REFLECTED);

#[allow(
    clippy::indexing_slicing,
    reason = "evaluated at compile time only (a static's initialiser): an index out of bounds is a build error, never a run-time panic"
)]
const fn crc_tables(poly: u32) -> [[u32; 256]; 4] {
    let mut t = [[0u32; 256]; 4];
    let mut i = 0;
    while i < 256 {
        let mut c = i as u32;
        let mut k = 0;
        while k < 8 {
            c = if c & 1 != 0 { (c >> 1) ^ poly } else { c >> 1 };
            k += 1;
        }
        t[0][i] = c;
        i += 1;
    }
    let mut k = 1;
    while k < 4 {
        let mut i = 0;
        while i < 256 {
            let c = t[k - 1][i];
            t[k][i] = (c >> 8) ^ t[0][(c & 0xFF) as usize];
            i += 1;
        }
        k += 1;
    }
    t
}

/// Why a frame was rejected.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub enum DecodeError {
    /// The CRC does not match the bytes.
    BadCrc,
    /// The kind byte is not the expected frame type.
    BadKind,
    /// A field is out of its range (id, reserved bits, quaternion norm, ...).
    BadField,
    /// The bytes do not start with [`SYNC`].
    BadSync,
    /// The slice is not exactly one frame long.
    BadLength,
}

/// Why a frame could not be encoded.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub enum EncodeError {
    /// The output buffer is shorter than [`Frame::LEN`].
    BufferTooSmall,
}

/// One frame type: its kind byte, its length and the codec of its fields.
///
/// A type implements only the field codec ([`Frame::write_fields`],
/// [`Frame::read_fields`]); the envelope (sync, kind, CRC) is the same for all and is
/// done once by the provided [`Frame::encode_into`] and [`Frame::decode`].
pub trait Frame: Sized {
    /// The kind byte (see [`kind`]).
    const KIND: u8;
    /// [`header_crc`] of this kind, folded at compile time.
    const HEADER_CRC: u32 = header_crc(Self::KIND);
    /// Total frame length in bytes, sync and CRC included.
    const LEN: usize;

    /// Writes the fields (the `LEN - 7` bytes between kind and CRC) to `w`.
    fn write_fields(&self, w: &mut FieldWriter<'_>);

    /// Reads and validates the fields from `r` (exactly `LEN - 7` bytes).
    fn read_fields(r: &mut FieldReader<'_>) -> Result<Self, DecodeError>;

    /// Encodes the frame into the first [`Frame::LEN`] bytes of `out`; returns the
    /// number of bytes written (`LEN`). Fields are encoded as they are: a field out of
    /// range gives a frame that [`Frame::decode`] rejects.
    ///
    /// # Errors
    /// [`EncodeError::BufferTooSmall`] if `out` is shorter than `LEN`.
    fn encode_into(&self, out: &mut [u8]) -> Result<usize, EncodeError> {
        encode_frame(self, out)
    }

    /// Decodes one frame: `frame` is exactly [`Frame::LEN`] bytes, sync and CRC included.
    /// Checks, in order: length, sync, kind, CRC, fields.
    ///
    /// # Errors
    /// The first check that fails, as a [`DecodeError`].
    fn decode(frame: &[u8]) -> Result<Self, DecodeError> {
        let body = check_envelope_from(frame, Self::KIND, Self::LEN, Self::HEADER_CRC)?;
        let mut r = FieldReader::new(body);
        let f = Self::read_fields(&mut r)?;
        if r.remaining() != 0 {
            return Err(DecodeError::BadLength);
        }
        Ok(f)
    }
}

/// [`Frame::encode_into`], one out-of-line copy per frame type. Here the frame's length
/// is the constant `F::LEN`, so a field codec inlined into it (the output frame's, every
/// step) is written at fixed offsets: the [`FieldWriter`]'s bounds checks fold away.
#[inline(never)]
fn encode_frame<F: Frame>(f: &F, out: &mut [u8]) -> Result<usize, EncodeError> {
    let frame = out.get_mut(..F::LEN).ok_or(EncodeError::BufferTooSmall)?;
    let (covered, crc) = frame.split_last_chunk_mut::<CRC_LEN>().ok_or(EncodeError::BufferTooSmall)?;
    let (head, body) = covered.split_first_chunk_mut::<HEADER_LEN>().ok_or(EncodeError::BufferTooSmall)?;
    let [s0, s1] = SYNC;
    *head = [s0, s1, F::KIND];
    let mut w = FieldWriter::new(body);
    f.write_fields(&mut w);
    if !w.is_complete() {
        // Only a field codec that disagrees with LEN gets here.
        return Err(EncodeError::BufferTooSmall);
    }
    *crc = body_crc(F::HEADER_CRC, body).to_le_bytes();
    Ok(F::LEN)
}

/// Checks length, sync, kind and CRC of `frame`; returns its field bytes.
///
/// # Errors
/// [`DecodeError::BadLength`], [`DecodeError::BadSync`], [`DecodeError::BadKind`] or
/// [`DecodeError::BadCrc`], the first that applies.
pub fn check_envelope(frame: &[u8], kind: u8, len: usize) -> Result<&[u8], DecodeError> {
    check_envelope_from(frame, kind, len, header_crc(kind))
}

/// [`check_envelope`] with the kind's [`header_crc`] given (a constant per frame type).
fn check_envelope_from(frame: &[u8], kind: u8, len: usize, header_crc: u32) -> Result<&[u8], DecodeError> {
    if frame.len() != len {
        return Err(DecodeError::BadLength);
    }
    let (covered, crc) = frame.split_last_chunk::<CRC_LEN>().ok_or(DecodeError::BadLength)?;
    let (head, body) = covered.split_first_chunk::<HEADER_LEN>().ok_or(DecodeError::BadLength)?;
    let [s0, s1, k] = *head;
    if [s0, s1] != SYNC {
        return Err(DecodeError::BadSync);
    }
    if k != kind {
        return Err(DecodeError::BadKind);
    }
    // The header was just checked to be `EB 90 kind`: continue from its register.
    if body_crc(header_crc, body) != u32::from_le_bytes(*crc) {
        return Err(DecodeError::BadCrc);
    }
    Ok(body)
}

/// Little-endian writer over a frame's field bytes (used by [`Frame::write_fields`]).
///
/// Writing past the end is not an error at the call: the bytes are dropped and the
/// writer remembers it, so [`Frame::encode_into`] reports it.
pub struct FieldWriter<'a> {
    rest: &'a mut [u8],
    overflow: bool,
}

impl<'a> FieldWriter<'a> {
    /// A writer over `buf`.
    pub fn new(buf: &'a mut [u8]) -> Self {
        FieldWriter { rest: buf, overflow: false }
    }

    /// Writes `bytes` as they are.
    pub fn bytes<const N: usize>(&mut self, bytes: [u8; N]) {
        match core::mem::take(&mut self.rest).split_first_chunk_mut::<N>() {
            Some((head, tail)) => {
                *head = bytes;
                self.rest = tail;
            }
            // The frame is refused by `is_complete`; the bytes left do not matter.
            None => self.overflow = true,
        }
    }

    /// Writes a `u8`.
    pub fn u8(&mut self, v: u8) {
        self.bytes([v]);
    }

    /// Writes a `u16`, little-endian.
    pub fn u16(&mut self, v: u16) {
        self.bytes(v.to_le_bytes());
    }

    /// Writes an `i16`, little-endian.
    pub fn i16(&mut self, v: i16) {
        self.bytes(v.to_le_bytes());
    }

    /// Writes an `i32`, little-endian.
    pub fn i32(&mut self, v: i32) {
        self.bytes(v.to_le_bytes());
    }

    /// Writes a `u32`, little-endian.
    pub fn u32(&mut self, v: u32) {
        self.bytes(v.to_le_bytes());
    }

    /// Writes a `u64`, little-endian.
    pub fn u64(&mut self, v: u64) {
        self.bytes(v.to_le_bytes());
    }

    /// Whether every byte was written and nothing overflowed.
    pub fn is_complete(&self) -> bool {
        !self.overflow && self.rest.is_empty()
    }
}

/// Little-endian reader over a frame's field bytes (used by [`Frame::read_fields`]).
/// Reading past the end gives [`DecodeError::BadLength`].
pub struct FieldReader<'a> {
    rest: &'a [u8],
}

impl<'a> FieldReader<'a> {
    /// A reader over `buf`.
    pub fn new(buf: &'a [u8]) -> Self {
        FieldReader { rest: buf }
    }

    /// Reads `N` bytes as they are.
    pub fn bytes<const N: usize>(&mut self) -> Result<[u8; N], DecodeError> {
        let (head, tail) = self.rest.split_first_chunk::<N>().ok_or(DecodeError::BadLength)?;
        self.rest = tail;
        Ok(*head)
    }

    /// Reads a `u8`.
    pub fn u8(&mut self) -> Result<u8, DecodeError> {
        self.bytes::<1>().map(|[b]| b)
    }

    /// Reads a little-endian `u16`.
    pub fn u16(&mut self) -> Result<u16, DecodeError> {
        self.bytes().map(u16::from_le_bytes)
    }

    /// Reads a little-endian `i16`.
    pub fn i16(&mut self) -> Result<i16, DecodeError> {
        self.bytes().map(i16::from_le_bytes)
    }

    /// Reads a little-endian `i32`.
    pub fn i32(&mut self) -> Result<i32, DecodeError> {
        self.bytes().map(i32::from_le_bytes)
    }

    /// Reads a little-endian `u32`.
    pub fn u32(&mut self) -> Result<u32, DecodeError> {
        self.bytes().map(u32::from_le_bytes)
    }

    /// Reads a little-endian `u64`.
    pub fn u64(&mut self) -> Result<u64, DecodeError> {
        self.bytes().map(u64::from_le_bytes)
    }

    /// Bytes not read yet.
    pub fn remaining(&self) -> usize {
        self.rest.len()
    }
}

/// `value / lsb` rounded to the nearest count (ties away from zero), saturated to the
/// `i32` range; NaN gives 0.
pub fn counts_i32(value: f64, lsb: f64) -> i32 {
    // Round half away from zero by adding ±0.5 and truncating: exact for |x| < 2^52, and
    // `as` saturates and maps NaN to 0 (libm::round is a software routine on the M7).
    round_half_away(value / lsb) as i32
}

/// `value / lsb` rounded to the nearest count (ties away from zero), saturated to the
/// `i16` range; NaN gives 0.
pub fn counts_i16(value: f64, lsb: f64) -> i16 {
    round_half_away(value / lsb) as i16
}

/// `value / lsb` rounded to the nearest count, saturated to the `u16` range (negative
/// values give 0); NaN gives 0.
pub fn counts_u16(value: f64, lsb: f64) -> u16 {
    // `as` saturates and maps NaN to 0; +0.5 rounds the non-negative values.
    (value / lsb + 0.5) as u16
}

/// x rounded half away from zero, as f64 (truncation happens in the caller's `as`).
#[inline]
fn round_half_away(x: f64) -> f64 {
    if x >= 0.0 {
        x + 0.5
    } else {
        x - 0.5
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The reflected CRC-32C register after `bytes`, from `r`, one bit at a time: the
    /// definition the tables must agree with.
    fn bitwise(mut r: u32, bytes: &[u8]) -> u32 {
        for &b in bytes {
            r ^= u32::from(b);
            for _ in 0..8 {
                r = if r & 1 != 0 { (r >> 1) ^ POLY_REFLECTED } else { r >> 1 };
            }
        }
        r
    }

    /// Tₖ[x] is the register after byte x and k zero bytes, from 0.
    #[test]
    fn each_table_is_a_byte_followed_by_zero_bytes() {
        for (k, t) in CRC_TABLES.iter().enumerate() {
            for (x, &entry) in t.iter().enumerate() {
                let mut bytes = [0u8; 4];
                bytes[0] = x as u8;
                assert_eq!(entry, bitwise(0, &bytes[..=k]), "T{k}[{x:#04x}]");
            }
        }
        assert_eq!(POLY_REFLECTED, 0x1EDC_6F41u32.reverse_bits());
    }

    /// The sliced CRC equals the catalogue CRC-32C over the whole frame for every body
    /// length (whole words and each remainder) and every kind's header.
    #[test]
    fn the_sliced_crc_is_the_catalogue_crc() {
        assert_eq!(CRC32C.checksum(b"123456789"), 0xE306_9283);
        let mut frame = [0u8; 3 + 40];
        let mut x: u32 = 0x1234_5678;
        for b in frame.iter_mut().skip(3) {
            x = x.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
            *b = (x >> 24) as u8;
        }
        for k in [kind::FOG, kind::STAR, kind::OUTPUT, kind::TELECOMMAND] {
            frame[..3].copy_from_slice(&[SYNC[0], SYNC[1], k]);
            for len in 0..=40 {
                let whole = &frame[..3 + len];
                assert_eq!(body_crc(header_crc(k), &whole[3..]), CRC32C.checksum(whole), "kind {k:#04x}, {len} bytes");
            }
        }
    }

    #[test]
    fn the_envelope_checks_come_in_order() {
        let mut f = [0u8; 12];
        f[..3].copy_from_slice(&[0xEB, 0x90, kind::CONTROL]);
        let crc = CRC32C.checksum(&f[..8]);
        f[8..].copy_from_slice(&crc.to_le_bytes());
        assert_eq!(check_envelope(&f, kind::CONTROL, 12), Ok(&f[3..8]));
        assert_eq!(check_envelope(&f[..11], kind::CONTROL, 12), Err(DecodeError::BadLength));
        assert_eq!(check_envelope(&f, kind::FOG, 12), Err(DecodeError::BadKind));
        let mut g = f;
        g[0] = 0xEA;
        assert_eq!(check_envelope(&g, kind::CONTROL, 12), Err(DecodeError::BadSync));
        let mut g = f;
        g[5] ^= 0x40;
        assert_eq!(check_envelope(&g, kind::CONTROL, 12), Err(DecodeError::BadCrc));
    }

    #[test]
    fn counts_round_half_away_and_saturate() {
        assert_eq!(counts_i32(2.5, 1.0), 3);
        assert_eq!(counts_i32(-2.5, 1.0), -3);
        assert_eq!(counts_i32(2.4999, 1.0), 2);
        assert_eq!(counts_i32(f64::NAN, 1.0), 0);
        assert_eq!(counts_i32(1e12, 1.0), i32::MAX);
        assert_eq!(counts_i16(-1e9, 1.0), i16::MIN);
        assert_eq!(counts_u16(-3.0, 1.0), 0);
        assert_eq!(counts_u16(0.75, 0.5), 2);
        assert_eq!(counts_u16(1e9, 1.0), u16::MAX);
    }

    #[test]
    fn field_readers_and_writers_are_little_endian_and_bounded() {
        let mut buf = [0u8; 7];
        let mut w = FieldWriter::new(&mut buf);
        w.u16(0x0102);
        w.i32(-2);
        assert!(!w.is_complete());
        w.u8(9);
        assert!(w.is_complete());
        w.u8(1);
        assert!(!w.is_complete(), "an overflow is remembered");
        assert_eq!(buf, [0x02, 0x01, 0xFE, 0xFF, 0xFF, 0xFF, 9]);
        let mut r = FieldReader::new(&buf);
        assert_eq!(r.u16(), Ok(0x0102));
        assert_eq!(r.i32(), Ok(-2));
        assert_eq!(r.remaining(), 1);
        assert_eq!(r.u16(), Err(DecodeError::BadLength));
        assert_eq!(r.u8(), Ok(9));
    }
}
