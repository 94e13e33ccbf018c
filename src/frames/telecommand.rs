//! Telecommand frame (kind 0x50, 98 bytes): ground → unit, on the output link's receive
//! line, and the unit's command report (kind 0x51, 34 bytes) on its output line.
//!
//! A telecommand carries a sequence number and a message authentication code
//! (HMAC-SHA-256 under the unit's key, truncated to [`MAC_LEN`] bytes: CCSDS Space Data
//! Link Security allows truncation to 128 bits), and the CRC-32C of every frame over
//! everything before it. The MAC and the sequence are checked by
//! `crate::telecommand`; this module is the wire format only.
//!
//! | off | size | field | type | meaning |
//! |---|---|---|---|---|
//! | 0 | 2 | sync | `EB 90` | |
//! | 2 | 1 | kind | `0x50` | |
//! | 3 | 1 | command | u8 | [`command`] |
//! | 4 | 4 | seq | u32 | sequence number, ≥ 1, higher than every one the unit accepted before |
//! | 8 | 1 | index | u8 | TABLE_CHUNK: chunk index; else 0 |
//! | 9 | 1 | count | u8 | TABLE_CHUNK: chunks in the upload; else 0 |
//! | 10 | 4 | table_crc | u32 | TABLE_CHUNK, ARM, FIRE: the table's CRC-32 (its last 4 bytes); STATUS: 0 |
//! | 14 | 64 | data | bytes | TABLE_CHUNK: table bytes 64·index …; else 0 |
//! | 78 | 16 | mac | bytes | HMAC-SHA-256(key, bytes 0..78), its first 16 bytes |
//! | 94 | 4 | crc | u32 | CRC-32C (Castagnoli) over bytes 0..94 |
//!
//! The CRC-32C detects every error of up to five bits in a frame: its Hamming distance
//! at 752 data bits is 6 (`host-tests/tests/frames.rs` proves it for every frame's
//! length from the single-bit syndromes).

use super::{kind, DecodeError, FieldReader, FieldWriter, Frame, HEADER_LEN, SYNC};

/// Length of a telecommand frame in bytes.
pub const FRAME_LEN: usize = 98;
/// Bytes of table data a chunk carries.
pub const CHUNK_LEN: usize = 64;
/// Bytes of the truncated MAC.
pub const MAC_LEN: usize = 16;
/// Bytes the MAC covers (the frame up to the MAC).
pub const MAC_COVERED_LEN: usize = 78;
/// Bytes the CRC-32C covers (the frame up to the CRC).
pub const CRC_COVERED_LEN: usize = FRAME_LEN - 4;

/// The CRC of every frame, a telecommand's included (`super::CRC32C`).
pub use super::CRC32C;

/// Command codes.
pub mod command {
    /// One chunk of a calibration table upload.
    pub const TABLE_CHUNK: u8 = 1;
    /// Arm the activation of the staged table (named by its CRC).
    pub const TABLE_ARM: u8 = 2;
    /// Activate the armed table (its CRC echoed): the next accepted command after ARM.
    pub const TABLE_FIRE: u8 = 3;
    /// Send a command report.
    pub const STATUS: u8 = 4;
}

/// One telecommand.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Telecommand {
    /// Command ([`command`]).
    pub command: u8,
    /// Sequence number.
    pub seq: u32,
    /// Chunk index (TABLE_CHUNK).
    pub index: u8,
    /// Chunks in the upload (TABLE_CHUNK).
    pub count: u8,
    /// The table's CRC-32 (TABLE_CHUNK, ARM, FIRE).
    pub table_crc: u32,
    /// Chunk data (TABLE_CHUNK; zero otherwise).
    pub data: [u8; CHUNK_LEN],
    /// Truncated HMAC-SHA-256 over the frame's first [`MAC_COVERED_LEN`] bytes.
    pub mac: [u8; MAC_LEN],
}

impl Default for Telecommand {
    fn default() -> Self {
        Telecommand {
            command: command::STATUS,
            seq: 0,
            index: 0,
            count: 0,
            table_crc: 0,
            data: [0; CHUNK_LEN],
            mac: [0; MAC_LEN],
        }
    }
}

impl Telecommand {
    /// Frame length in bytes.
    pub const LEN: usize = FRAME_LEN;

    /// The frame's bytes.
    pub fn to_bytes(&self) -> [u8; FRAME_LEN] {
        let mut out = [0u8; FRAME_LEN];
        // Cannot fail: `out` is exactly one frame long.
        let _ = self.encode_into(&mut out);
        out
    }

    /// The bytes the MAC covers: the frame's first [`MAC_COVERED_LEN`] bytes (header
    /// and fields up to the MAC), written without the CRC.
    pub fn mac_input(&self) -> [u8; MAC_COVERED_LEN] {
        let mut out = [0u8; MAC_COVERED_LEN];
        let (head, fields) = out.split_at_mut(HEADER_LEN);
        let [s0, s1] = SYNC;
        head.copy_from_slice(&[s0, s1, Self::KIND]);
        self.write_covered(&mut FieldWriter::new(fields));
        out
    }

    /// The fields the MAC covers.
    fn write_covered(&self, w: &mut FieldWriter<'_>) {
        w.u8(self.command);
        w.u32(self.seq);
        w.u8(self.index);
        w.u8(self.count);
        w.u32(self.table_crc);
        w.bytes(self.data);
    }
}

impl Frame for Telecommand {
    const KIND: u8 = kind::TELECOMMAND;
    const LEN: usize = FRAME_LEN;

    fn write_fields(&self, w: &mut FieldWriter<'_>) {
        self.write_covered(w);
        w.bytes(self.mac);
    }

    fn read_fields(r: &mut FieldReader<'_>) -> Result<Self, DecodeError> {
        let command = r.u8()?;
        if !(command::TABLE_CHUNK..=command::STATUS).contains(&command) {
            return Err(DecodeError::BadField);
        }
        let t = Telecommand {
            command,
            seq: r.u32()?,
            index: r.u8()?,
            count: r.u8()?,
            table_crc: r.u32()?,
            data: r.bytes()?,
            mac: r.bytes()?,
        };
        // Only a chunk has a chunk index, count or data; STATUS names no table.
        let chunk = command == command::TABLE_CHUNK;
        if !chunk && (t.index != 0 || t.count != 0 || t.data.iter().any(|&b| b != 0))
            || command == command::STATUS && t.table_crc != 0
        {
            return Err(DecodeError::BadField);
        }
        Ok(t)
    }
}

/// State of the table upload, as the command report gives it.
pub mod upload_state {
    /// Nothing received.
    pub const IDLE: u8 = 0;
    /// Chunks arriving.
    pub const RECEIVING: u8 = 1;
    /// A whole, valid table is staged in the inactive slot.
    pub const STAGED: u8 = 2;
    /// The staged table is armed: FIRE activates it.
    pub const ARMED: u8 = 3;
}

/// Length of a command report in bytes.
pub const REPORT_LEN: usize = 34;

/// The unit's command report (kind 0x51, 34 bytes), sent after the output frame of the
/// step in which an accepted STATUS command arrived.
///
/// | off | size | field | type | meaning |
/// |---|---|---|---|---|
/// | 0 | 2 | sync | `EB 90` | |
/// | 2 | 1 | kind | `0x51` | |
/// | 3 | 1 | upload | u8 | [`upload_state`] |
/// | 4 | 4 | last_seq | u32 | the last sequence number accepted |
/// | 8 | 1 | chunks | u8 | bit i: chunk i of the upload received |
/// | 9 | 1 | last_refusal | u8 | why the last command was refused (`telecommand::Refusal` code), 0 none |
/// | 10 | 4 | staged_crc | u32 | CRC-32 of the table being uploaded, staged or armed (0 idle) |
/// | 14 | 4 | table_revision | u32 | the active table's revision |
/// | 18 | 4 | table_crc | u32 | the active table's CRC-32 |
/// | 22 | 2 | key_id | u16 | the provisioned key's id (0: none) |
/// | 24 | 2 | accepted | u16 | commands accepted and acted on, saturating |
/// | 26 | 2 | refused | u16 | commands refused (every reason), saturating |
/// | 28 | 2 | reserved | u16 | 0 |
/// | 30 | 4 | crc | u32 | CRC-32C over bytes 0..30 |
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct CommandReport {
    /// [`upload_state`].
    pub upload: u8,
    /// The last sequence number accepted.
    pub last_seq: u32,
    /// Chunks received (bit i: chunk i).
    pub chunks: u8,
    /// The last refusal's code (0: none).
    pub last_refusal: u8,
    /// CRC-32 of the table being uploaded, staged or armed.
    pub staged_crc: u32,
    /// The active table's revision.
    pub table_revision: u32,
    /// The active table's CRC-32.
    pub table_crc: u32,
    /// The provisioned key's id (0: none).
    pub key_id: u16,
    /// Commands accepted and acted on (saturating).
    pub accepted: u16,
    /// Commands refused (saturating).
    pub refused: u16,
}

impl CommandReport {
    /// Frame length in bytes.
    pub const LEN: usize = REPORT_LEN;

    /// The frame's bytes.
    pub fn to_bytes(&self) -> [u8; REPORT_LEN] {
        let mut out = [0u8; REPORT_LEN];
        // Cannot fail: `out` is exactly one frame long.
        let _ = self.encode_into(&mut out);
        out
    }
}

impl Frame for CommandReport {
    const KIND: u8 = kind::COMMAND_REPORT;
    const LEN: usize = REPORT_LEN;

    fn write_fields(&self, w: &mut FieldWriter<'_>) {
        w.u8(self.upload);
        w.u32(self.last_seq);
        w.u8(self.chunks);
        w.u8(self.last_refusal);
        w.u32(self.staged_crc);
        w.u32(self.table_revision);
        w.u32(self.table_crc);
        w.u16(self.key_id);
        w.u16(self.accepted);
        w.u16(self.refused);
        w.u16(0);
    }

    fn read_fields(r: &mut FieldReader<'_>) -> Result<Self, DecodeError> {
        let c = CommandReport {
            upload: r.u8()?,
            last_seq: r.u32()?,
            chunks: r.u8()?,
            last_refusal: r.u8()?,
            staged_crc: r.u32()?,
            table_revision: r.u32()?,
            table_crc: r.u32()?,
            key_id: r.u16()?,
            accepted: r.u16()?,
            refused: r.u16()?,
        };
        if r.u16()? != 0 || c.upload > upload_state::ARMED {
            return Err(DecodeError::BadField);
        }
        Ok(c)
    }
}
