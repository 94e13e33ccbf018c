//! Two-copy storage of the calibration table: what sits in the table's flash region.
//!
//! The region ([`REGION_LEN`] bytes) holds two *slots* at offsets 0 (A) and
//! [`SLOT_STRIDE`] (B). Each slot holds one *record* ([`RECORD_LEN`] bytes, little-endian):
//!
//! | offset | size | field |
//! |---|---|---|
//! | 0 | 4 | magic `SSCR` |
//! | 4 | 2 | record format version (u16) = [`RECORD_VERSION`] |
//! | 6 | 2 | length of the table that follows (u16) = [`TABLE_LEN`] |
//! | 8 | 4 | generation (u32, ≥ 1): which copy is newer |
//! | 12 | 484 | the binary table ([`super::binary`], with its own magic, version and CRC-32) |
//! | 496 | 4 | CRC-32/ISO-HDLC over bytes 0..496 (u32) |
//!
//! Bytes of a slot after the record are not read (erased flash, `FF`).
//!
//! **Loading** ([`load`]) decodes both records; each must pass, in order: length, magic,
//! version, declared length, the record CRC, then the inner table's own checks
//! ([`super::binary::decode`]: magic, version, length, CRC, values). Of the copies that
//! pass, the one with the higher generation is used (A on a tie). A bad copy falls back to
//! the other; with neither, [`CalibrationTable::DEFAULT`] is used and flagged
//! ([`Loaded::defaulted`]). Loading never fails and never panics.
//!
//! **Updating** ([`prepare_update`]): a new table is validated, encoded and decoded back
//! *before* it can become active, with generation = newest + 1, for the slot that does
//! not hold the active copy. While that slot is being written its record fails its CRC,
//! so [`load`] keeps returning the old table; the moment the last byte is written the new
//! table is the one loaded. The switch is atomic at every byte: a load sees the whole old
//! table or the whole new one, never a mixture. A second [`prepare_update`] with the same
//! table then overwrites the older slot, giving two copies again.
//!
//! **Updating in flight** (the command link, `crate::telecommand`): [`stage`] writes the
//! new record into the slot not holding the active copy with its CRC left erased, so
//! the copy is refused until [`commit`] writes those four bytes; the active copy is
//! never touched. A power loss at any byte gives the old table or, after the last CRC
//! byte, the new one (`host-tests/tests/table_store.rs` cuts the command path at every
//! byte written).
//!
//! Why it is enough: CRC-32/ISO-HDLC has Hamming distance 4 over this record length
//! (3,872 bits), so every 1-, 2- and 3-bit error in a record is detected; the host test
//! `host-tests/tests/table.rs` enumerates every 1- and 2-bit flip and every truncation.

use super::binary::{self, crc32, crc32_update, CRC32, TABLE_LEN};
use super::{CalibrationTable, TableError};

/// Magic bytes of a stored record.
pub const RECORD_MAGIC: [u8; 4] = *b"SSCR";
/// Record format version written and read by this code.
pub const RECORD_VERSION: u16 = 1;
/// Bytes before the table in a record.
pub const RECORD_HEADER_LEN: usize = 12;
/// Total length of one record.
pub const RECORD_LEN: usize = RECORD_HEADER_LEN + TABLE_LEN + 4;
/// Distance between the two slots, bytes (slot B starts here).
pub const SLOT_STRIDE: usize = 2048;
/// Length of the table's flash region: two slots.
pub const REGION_LEN: usize = 2 * SLOT_STRIDE;

/// Why a stored record was refused, or an update could not be prepared.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub enum StoreError {
    /// Fewer bytes than one record (or than the region, for a slot beyond it).
    Truncated,
    /// Magic bytes are not `SSCR` (for example erased flash).
    BadMagic,
    /// Record format version this firmware does not read.
    UnsupportedVersion,
    /// Declared table length is not [`TABLE_LEN`].
    BadLength,
    /// Record CRC-32 mismatch.
    BadCrc,
    /// Generation 0 (never written by [`encode_record`]).
    BadGeneration,
    /// The record is intact but the table inside is refused.
    Table(TableError),
    /// No generation left (the newest copy has `u32::MAX`).
    GenerationExhausted,
    /// Writing the flash failed.
    Flash(FlashError),
    /// What reads back from the flash is not what was written.
    Readback,
}

/// Why the table's flash could not be written.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub enum FlashError {
    /// The bytes would lie outside the region.
    OutOfRange,
    /// A byte to be programmed is not erased (`FF`).
    NotErased,
    /// The flash controller reported a failure.
    Failed,
}

/// The table's flash region as a writer sees it: NOR flash, erased a slot at a time to
/// `FF`, programmed only where erased. The QEMU board's region is RAM behind this trait;
/// [`RamFlash`] is the same on the host.
pub trait CalibFlash {
    /// The region as it reads now ([`REGION_LEN`] bytes).
    fn region(&self) -> &[u8];
    /// Erases `slot` (every byte of its [`SLOT_STRIDE`] to `FF`).
    fn erase(&mut self, slot: Slot) -> Result<(), FlashError>;
    /// Programs `bytes` at `offset` in the region; every byte there must be erased.
    fn program(&mut self, offset: usize, bytes: &[u8]) -> Result<(), FlashError>;
}

/// A [`CalibFlash`] in RAM (host tests, fuzzing, the in-process replay of the runner).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RamFlash {
    /// The region's bytes.
    pub bytes: [u8; REGION_LEN],
}

impl RamFlash {
    /// A region holding `image` (cut or padded with `FF` to [`REGION_LEN`]).
    pub fn new(image: &[u8]) -> Self {
        let mut bytes = [0xFF; REGION_LEN];
        for (d, s) in bytes.iter_mut().zip(image) {
            *d = *s;
        }
        RamFlash { bytes }
    }
}

impl CalibFlash for RamFlash {
    fn region(&self) -> &[u8] {
        &self.bytes
    }

    fn erase(&mut self, slot: Slot) -> Result<(), FlashError> {
        let s = self.bytes.get_mut(slot.offset()..slot.offset() + SLOT_STRIDE).ok_or(FlashError::OutOfRange)?;
        s.fill(0xFF);
        Ok(())
    }

    fn program(&mut self, offset: usize, bytes: &[u8]) -> Result<(), FlashError> {
        let end = offset.checked_add(bytes.len()).ok_or(FlashError::OutOfRange)?;
        let dst = self.bytes.get_mut(offset..end).ok_or(FlashError::OutOfRange)?;
        if dst.iter().any(|&b| b != 0xFF) {
            return Err(FlashError::NotErased);
        }
        dst.copy_from_slice(bytes);
        Ok(())
    }
}

impl core::fmt::Display for StoreError {
    /// The variant's name; a refused table says why (a refused field with its name, value
    /// and range).
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            StoreError::Table(e) => write!(f, "{e}"),
            other => write!(f, "{other:?}"),
        }
    }
}

/// One of the two slots.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub enum Slot {
    /// At offset 0.
    A,
    /// At offset [`SLOT_STRIDE`].
    B,
}

impl Slot {
    /// Byte offset of the slot in the region.
    pub const fn offset(self) -> usize {
        match self {
            Slot::A => 0,
            Slot::B => SLOT_STRIDE,
        }
    }

    /// The other slot.
    pub const fn other(self) -> Slot {
        match self {
            Slot::A => Slot::B,
            Slot::B => Slot::A,
        }
    }
}

/// Where the table in use came from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub enum Source {
    /// A stored copy.
    Stored(Slot),
    /// Neither copy passed: [`CalibrationTable::DEFAULT`], flagged.
    Default,
}

/// The outcome of [`load`]: the table to fly with and what was found.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Loaded {
    /// The table in use.
    pub table: CalibrationTable,
    /// Where it came from.
    pub source: Source,
    /// Its generation (0 for the default table).
    pub generation: u32,
    /// Per slot (A, B): `None` if the copy passed, else why it was refused.
    pub slot_errors: [Option<StoreError>; 2],
}

impl Loaded {
    /// Whether the unit flies on the default table (flag it).
    pub fn defaulted(&self) -> bool {
        self.source == Source::Default
    }

    /// Copies refused (0, 1 or 2): one refused copy means the redundancy is lost.
    pub fn bad_copies(&self) -> u32 {
        self.slot_errors.iter().map(|e| u32::from(e.is_some())).sum()
    }
}

/// Encodes `t` as a record of generation `generation`. Does not validate the table (see
/// [`prepare_update`]); a record of an invalid table is refused by [`decode_record`].
pub fn encode_record(t: &CalibrationTable, generation: u32) -> [u8; RECORD_LEN] {
    let mut out = [0u8; RECORD_LEN];
    let table = binary::encode(t);
    let (header, rest) = out.split_at_mut(RECORD_HEADER_LEN);
    let (body, crc_bytes) = rest.split_at_mut(TABLE_LEN);
    let [m0, m1, m2, m3] = RECORD_MAGIC;
    let [v0, v1] = RECORD_VERSION.to_le_bytes();
    let [l0, l1] = (TABLE_LEN as u16).to_le_bytes();
    let [g0, g1, g2, g3] = generation.to_le_bytes();
    header.copy_from_slice(&[m0, m1, m2, m3, v0, v1, l0, l1, g0, g1, g2, g3]);
    body.copy_from_slice(&table);
    let mut digest = CRC32.digest();
    crc32_update(&mut digest, header);
    crc32_update(&mut digest, body);
    crc_bytes.copy_from_slice(&digest.finalize().to_le_bytes());
    out
}

/// Decodes one record (the first [`RECORD_LEN`] bytes of `bytes`; later bytes are not
/// read): the table and its generation.
pub fn decode_record(bytes: &[u8]) -> Result<(CalibrationTable, u32), StoreError> {
    let rec: &[u8; RECORD_LEN] = bytes.first_chunk().ok_or(StoreError::Truncated)?;
    let (covered, crc) = rec.split_last_chunk::<4>().ok_or(StoreError::Truncated)?;
    let (header, table) = covered.split_first_chunk::<RECORD_HEADER_LEN>().ok_or(StoreError::Truncated)?;
    let [m0, m1, m2, m3, v0, v1, l0, l1, g0, g1, g2, g3] = *header;
    if [m0, m1, m2, m3] != RECORD_MAGIC {
        return Err(StoreError::BadMagic);
    }
    if u16::from_le_bytes([v0, v1]) != RECORD_VERSION {
        return Err(StoreError::UnsupportedVersion);
    }
    if usize::from(u16::from_le_bytes([l0, l1])) != TABLE_LEN {
        return Err(StoreError::BadLength);
    }
    if crc32(covered) != u32::from_le_bytes(*crc) {
        return Err(StoreError::BadCrc);
    }
    let generation = u32::from_le_bytes([g0, g1, g2, g3]);
    if generation == 0 {
        return Err(StoreError::BadGeneration);
    }
    let t = binary::decode(table).map_err(StoreError::Table)?;
    Ok((t, generation))
}

/// The record of `slot` in `region`, decoded.
pub fn decode_slot(region: &[u8], slot: Slot) -> Result<(CalibrationTable, u32), StoreError> {
    decode_record(region.get(slot.offset()..).ok_or(StoreError::Truncated)?)
}

/// Loads the table from a region (normally [`REGION_LEN`] bytes of flash): the newest copy
/// that passes every check, else the other, else the default table, flagged.
pub fn load(region: &[u8]) -> Loaded {
    let a = decode_slot(region, Slot::A);
    let b = decode_slot(region, Slot::B);
    let slot_errors = [a.err(), b.err()];
    let chosen = match (a, b) {
        (Ok((ta, ga)), Ok((tb, gb))) => {
            if gb > ga {
                Some((tb, gb, Slot::B))
            } else {
                Some((ta, ga, Slot::A))
            }
        }
        (Ok((ta, ga)), Err(_)) => Some((ta, ga, Slot::A)),
        (Err(_), Ok((tb, gb))) => Some((tb, gb, Slot::B)),
        (Err(_), Err(_)) => None,
    };
    match chosen {
        Some((table, generation, slot)) => Loaded { table, source: Source::Stored(slot), generation, slot_errors },
        None => Loaded { table: CalibrationTable::DEFAULT, source: Source::Default, generation: 0, slot_errors },
    }
}

/// A record ready to be written: write `record` at `slot.offset()` of the region.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Update {
    /// The slot to write (the one not holding the active copy).
    pub slot: Slot,
    /// Generation of the new record.
    pub generation: u32,
    /// The record's bytes.
    pub record: [u8; RECORD_LEN],
}

/// Prepares the activation of `new` in `region`: validates it, encodes it with the next
/// generation for the slot not holding the active copy, and checks that the record decodes
/// back to `new`. Nothing is written; the caller writes [`Update::record`] at
/// [`Update::slot`] (see the module documentation for why that switch is atomic).
pub fn prepare_update(region: &[u8], new: &CalibrationTable) -> Result<Update, StoreError> {
    new.validate().map_err(StoreError::Table)?;
    let current = load(region);
    let (slot, generation) = match current.source {
        Source::Stored(active) => {
            (active.other(), current.generation.checked_add(1).ok_or(StoreError::GenerationExhausted)?)
        }
        Source::Default => (Slot::A, 1),
    };
    let record = encode_record(new, generation);
    match decode_record(&record) {
        Ok((t, g)) if g == generation && t == *new => Ok(Update { slot, generation, record }),
        Ok(_) => Err(StoreError::Table(TableError::RoundTrip)),
        Err(e) => Err(e),
    }
}

/// [`prepare_update`] for [`stage`]: the same record, unless its CRC came out as erased
/// flash (`FF FF FF FF`, one record in 2^32), which a staged record with its CRC left
/// unwritten would then already carry: then with the generation after.
pub fn prepare_staged_update(region: &[u8], new: &CalibrationTable) -> Result<Update, StoreError> {
    let mut u = prepare_update(region, new)?;
    if u.record.last_chunk::<4>() == Some(&[0xFF; 4]) {
        u.generation = u.generation.checked_add(1).ok_or(StoreError::GenerationExhausted)?;
        u.record = encode_record(new, u.generation);
    }
    Ok(u)
}

/// Writes `u`'s record into its slot, all but its CRC: the slot is erased, then
/// programmed and read back. Its last four bytes stay erased, so [`load`] refuses the
/// copy (BadCrc) and keeps returning the active one, at every byte of the way and after
/// a power loss; [`commit`] makes it the active copy.
pub fn stage<F: CalibFlash + ?Sized>(flash: &mut F, u: &Update) -> Result<(), StoreError> {
    let (body, _) = u.record.split_last_chunk::<4>().ok_or(StoreError::Truncated)?;
    flash.erase(u.slot).map_err(StoreError::Flash)?;
    flash.program(u.slot.offset(), body).map_err(StoreError::Flash)?;
    let at = flash.region().get(u.slot.offset()..u.slot.offset() + RECORD_LEN).ok_or(StoreError::Truncated)?;
    match at.split_last_chunk::<4>() {
        Some((b, crc)) if b == body && crc == &[0xFF; 4] => Ok(()),
        _ => Err(StoreError::Readback),
    }
}

/// Activates a record staged by [`stage`]: programs its CRC. The switch is atomic at
/// every byte: until the last of the four is written the copy fails its CRC (the old
/// table loads); once it is, the whole new record with the higher generation loads.
/// Then checks that [`load`] returns it.
pub fn commit<F: CalibFlash + ?Sized>(flash: &mut F, u: &Update) -> Result<(), StoreError> {
    let (_, crc) = u.record.split_last_chunk::<4>().ok_or(StoreError::Truncated)?;
    flash.program(u.slot.offset() + RECORD_LEN - 4, crc).map_err(StoreError::Flash)?;
    let l = load(flash.region());
    if l.source == Source::Stored(u.slot) && l.generation == u.generation {
        Ok(())
    } else {
        Err(StoreError::Readback)
    }
}

/// A factory image of the region: `t` in both slots with generation 1, the rest erased
/// (`FF`). Does not validate `t` (a test may want an image of a refused table).
pub fn image(t: &CalibrationTable) -> [u8; REGION_LEN] {
    let mut out = [0xFFu8; REGION_LEN];
    let record = encode_record(t, 1);
    for slot in [Slot::A, Slot::B] {
        if let Some(dst) = out.get_mut(slot.offset()..slot.offset() + RECORD_LEN) {
            dst.copy_from_slice(&record);
        }
    }
    out
}
