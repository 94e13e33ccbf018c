//! The in-flight table update: chunks into a staging buffer, the whole table checked and
//! staged in the inactive slot of the two-copy store, armed, then activated.
//!
//! 1. **TABLE_CHUNK** ×[`CHUNKS`]: chunk i carries table bytes 64·i … (the last one 36
//!    bytes, the rest of its data zero), all naming the table's CRC-32. A chunk naming
//!    another CRC starts a new upload (the old one is dropped); chunks may come in any
//!    order; one received again must be the same bytes. When the last one is in, the
//!    table is decoded and checked: its own magic, version, length and CRC-32, that CRC
//!    equal to the one named, every value in range ([`CalibrationTable::validate`]), the
//!    flight core able to fly it ([`FlightCore::check_table`]) and its revision above
//!    the active table's (no roll-back, also not by a replay after a reset). It is then
//!    written into the slot not holding the active copy with its CRC left unwritten
//!    ([`store::stage`]): still refused at boot.
//! 2. **TABLE_ARM** naming the staged table's CRC arms it.
//! 3. **TABLE_FIRE**, the next accepted command after ARM, echoing the same CRC: the
//!    record's CRC is written ([`store::commit`]; the atomic switch in flash) and the
//!    flight core switches to the table ([`FlightCore::switch_table`]) before the next
//!    step. Refused while a parity alarm stands ([`FlightCore::ready_for_table`]).
//!
//! Any other accepted command after ARM disarms (the table stays staged). Every
//! refusal leaves the active table, in flash and in the core, as it was.

use crate::calib::binary::{self, TABLE_LEN};
use crate::calib::store::{self, CalibFlash, Slot, Update};
use crate::calib::CalibrationTable;
use crate::flight::FlightCore;
use crate::frames::telecommand::{command, upload_state, Telecommand, CHUNK_LEN};
use crate::telecommand::auth::{seal, Key};

/// Chunks of a table upload.
pub const CHUNKS: usize = TABLE_LEN.div_ceil(CHUNK_LEN);
const ALL_CHUNKS: u8 = ((1u16 << CHUNKS) - 1) as u8;
const _: () = assert!(CHUNKS <= 8, "the chunk bitmap is one byte");

/// Why an authenticated command of the upload was refused (the code is the command
/// report's `last_refusal`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub enum UploadError {
    /// A chunk's count, index or padding is wrong, or it differs from the same chunk
    /// received before.
    BadChunk = 4,
    /// The whole table fails its checks, is not the CRC named, or the core cannot fly it.
    TableInvalid = 5,
    /// The table's revision is not above the active table's.
    NotNewer = 6,
    /// ARM without a staged table.
    NotStaged = 7,
    /// FIRE that does not follow ARM.
    NotArmed = 8,
    /// ARM or FIRE naming another CRC than the staged table's.
    WrongCrc = 9,
    /// FIRE while a parity alarm stands.
    Busy = 10,
    /// The flash could not be written or read back.
    Store = 11,
}

/// A table written into the inactive slot, CRC unwritten.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Staged {
    table: CalibrationTable,
    crc: u32,
    slot: Slot,
    generation: u32,
}

#[derive(Debug, Clone, Copy, PartialEq)]
enum State {
    Idle,
    Receiving { crc: u32, got: u8 },
    Staged(Staged),
    Armed(Staged),
}

/// The upload's state and its staging buffer.
#[derive(Debug, Clone)]
pub struct Upload {
    state: State,
    buf: [u8; TABLE_LEN],
}

impl Default for Upload {
    fn default() -> Self {
        Upload { state: State::Idle, buf: [0; TABLE_LEN] }
    }
}

impl Upload {
    /// The state as the command report gives it: ([`upload_state`], chunks received,
    /// the CRC named).
    pub fn report(&self) -> (u8, u8, u32) {
        match self.state {
            State::Idle => (upload_state::IDLE, 0, 0),
            State::Receiving { crc, got } => (upload_state::RECEIVING, got, crc),
            State::Staged(s) => (upload_state::STAGED, ALL_CHUNKS, s.crc),
            State::Armed(s) => (upload_state::ARMED, ALL_CHUNKS, s.crc),
        }
    }

    /// An accepted command other than FIRE: an armed table goes back to staged.
    pub fn disarm(&mut self) {
        if let State::Armed(s) = self.state {
            self.state = State::Staged(s);
        }
    }

    /// TABLE_CHUNK; the last chunk in stages the table.
    pub fn chunk<F: CalibFlash + ?Sized>(
        &mut self,
        tc: &Telecommand,
        core: &FlightCore,
        flash: &mut F,
    ) -> Result<(), UploadError> {
        let i = usize::from(tc.index);
        let off = i * CHUNK_LEN;
        let n = CHUNK_LEN.min(TABLE_LEN.saturating_sub(off));
        let (data, pad) = tc.data.split_at(n);
        if usize::from(tc.count) != CHUNKS || i >= CHUNKS || pad.iter().any(|&b| b != 0) {
            return Err(UploadError::BadChunk);
        }
        let got = match self.state {
            State::Receiving { crc, got } if crc == tc.table_crc => got,
            _ => 0,
        };
        let bit = 1u8 << i;
        let dst = self.buf.get_mut(off..off + n).ok_or(UploadError::BadChunk)?;
        if got & bit != 0 {
            return if dst == data { Ok(()) } else { Err(UploadError::BadChunk) };
        }
        dst.copy_from_slice(data);
        let got = got | bit;
        self.state = State::Receiving { crc: tc.table_crc, got };
        if got == ALL_CHUNKS {
            self.state = State::Idle;
            let staged = self.stage(tc.table_crc, core, flash)?;
            self.state = State::Staged(staged);
        }
        Ok(())
    }

    /// The whole table checked and written into the inactive slot, CRC unwritten.
    fn stage<F: CalibFlash + ?Sized>(&self, crc: u32, core: &FlightCore, flash: &mut F) -> Result<Staged, UploadError> {
        let table = binary::decode(&self.buf).map_err(|_| UploadError::TableInvalid)?;
        if self.buf.last_chunk::<4>() != Some(&crc.to_le_bytes()) {
            return Err(UploadError::TableInvalid);
        }
        FlightCore::check_table(core.profile(), &table).map_err(|_| UploadError::TableInvalid)?;
        if table.revision <= core.table().revision {
            return Err(UploadError::NotNewer);
        }
        let u = store::prepare_staged_update(flash.region(), &table).map_err(|_| UploadError::Store)?;
        store::stage(flash, &u).map_err(|_| UploadError::Store)?;
        Ok(Staged { table, crc, slot: u.slot, generation: u.generation })
    }

    /// TABLE_ARM naming `crc`.
    pub fn arm(&mut self, crc: u32) -> Result<(), UploadError> {
        match self.state {
            State::Staged(s) | State::Armed(s) if s.crc == crc => {
                self.state = State::Armed(s);
                Ok(())
            }
            State::Staged(_) | State::Armed(_) => Err(UploadError::WrongCrc),
            _ => Err(UploadError::NotStaged),
        }
    }

    /// TABLE_FIRE echoing `crc`: commits the armed table in flash and switches the core
    /// to it. A wrong CRC disarms.
    pub fn fire<F: CalibFlash + ?Sized>(
        &mut self,
        crc: u32,
        core: &mut FlightCore,
        flash: &mut F,
    ) -> Result<(), UploadError> {
        let State::Armed(s) = self.state else { return Err(UploadError::NotArmed) };
        self.state = State::Staged(s);
        if s.crc != crc {
            return Err(UploadError::WrongCrc);
        }
        if !core.ready_for_table() {
            return Err(UploadError::Busy);
        }
        let u = Update { slot: s.slot, generation: s.generation, record: store::encode_record(&s.table, s.generation) };
        self.state = State::Idle;
        store::commit(flash, &u).map_err(|_| UploadError::Store)?;
        // Checked when staged: the core takes it.
        core.switch_table(&s.table).map_err(|_| UploadError::TableInvalid)
    }
}

/// Telecommands of an upload sequence: [`CHUNKS`] chunks, ARM, FIRE.
pub const SEQUENCE_LEN: usize = CHUNKS + 2;

/// The ground's side: the telecommands that upload and activate `table`, sealed under
/// `key`, with sequence numbers `first_seq`, `first_seq + 1`, … (chunks in order, then
/// TABLE_ARM and TABLE_FIRE naming the table's CRC-32).
pub fn upload_sequence(key: &Key, table: &CalibrationTable, first_seq: u32) -> [Telecommand; SEQUENCE_LEN] {
    let bytes = binary::encode(table);
    let crc = bytes.last_chunk::<4>().map_or(0, |c| u32::from_le_bytes(*c));
    let mut out = [Telecommand::default(); SEQUENCE_LEN];
    for (k, tc) in out.iter_mut().enumerate() {
        let seq = first_seq.wrapping_add(k as u32);
        let mut t = Telecommand { seq, table_crc: crc, ..Telecommand::default() };
        if k < CHUNKS {
            t.command = command::TABLE_CHUNK;
            t.index = k as u8;
            t.count = CHUNKS as u8;
            let chunk = bytes.get(k * CHUNK_LEN..).unwrap_or(&[]);
            for (d, s) in t.data.iter_mut().zip(chunk) {
                *d = *s;
            }
        } else {
            t.command = if k == CHUNKS { command::TABLE_ARM } else { command::TABLE_FIRE };
        }
        *tc = seal(key, t);
    }
    out
}
