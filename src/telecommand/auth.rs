//! Authentication of telecommands: the key record in the unit's protected flash, the
//! truncated HMAC-SHA-256 and the sequence number.
//!
//! Key record (the KEY region, `memory.x`; loaded like the table, never written by the
//! firmware), little-endian:
//!
//! | off | size | field |
//! |---|---|---|
//! | 0 | 4 | magic `SSKY` |
//! | 4 | 2 | record version = [`KEY_VERSION`] |
//! | 6 | 2 | key id (≥ 1; reported in the command report) |
//! | 8 | 32 | the HMAC-SHA-256 key |
//! | 40 | 4 | CRC-32/ISO-HDLC over bytes 0..40 |
//!
//! A record that fails a check leaves the unit without a key: every telecommand is then
//! refused as unauthenticated (the unit keeps flying; the ground sees the count).

use hmac::{Hmac, KeyInit, Mac};
use sha2::Sha256;

use crate::calib::binary::crc32;
use crate::frames::telecommand::{Telecommand, MAC_LEN};

/// Bytes of the key.
pub const KEY_LEN: usize = 32;
/// Magic bytes of a key record.
pub const KEY_MAGIC: [u8; 4] = *b"SSKY";
/// Key record version written and read by this code.
pub const KEY_VERSION: u16 = 1;
/// Bytes of a key record.
pub const KEY_RECORD_LEN: usize = 8 + KEY_LEN + 4;

/// Why a key record was refused.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub enum KeyError {
    /// Fewer bytes than a record.
    Truncated,
    /// Not `SSKY` (erased flash: no key provisioned).
    BadMagic,
    /// A record version this firmware does not read.
    UnsupportedVersion,
    /// CRC-32 mismatch.
    BadCrc,
    /// Key id 0.
    BadId,
}

/// The unit's command key.
#[derive(Clone, PartialEq, Eq)]
pub struct Key {
    /// Key id (≥ 1).
    pub id: u16,
    /// The HMAC-SHA-256 key.
    pub bytes: [u8; KEY_LEN],
}

impl core::fmt::Debug for Key {
    /// The id only: a key is not printed.
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        write!(f, "Key {{ id: {} }}", self.id)
    }
}

impl Key {
    /// Reads a key record (the first [`KEY_RECORD_LEN`] bytes of `bytes`).
    pub fn from_record(bytes: &[u8]) -> Result<Key, KeyError> {
        let rec: &[u8; KEY_RECORD_LEN] = bytes.first_chunk().ok_or(KeyError::Truncated)?;
        let (covered, crc) = rec.split_last_chunk::<4>().ok_or(KeyError::Truncated)?;
        let (head, key) = covered.split_first_chunk::<8>().ok_or(KeyError::Truncated)?;
        let [m0, m1, m2, m3, v0, v1, i0, i1] = *head;
        if [m0, m1, m2, m3] != KEY_MAGIC {
            return Err(KeyError::BadMagic);
        }
        if u16::from_le_bytes([v0, v1]) != KEY_VERSION {
            return Err(KeyError::UnsupportedVersion);
        }
        if crc32(covered) != u32::from_le_bytes(*crc) {
            return Err(KeyError::BadCrc);
        }
        let id = u16::from_le_bytes([i0, i1]);
        if id == 0 {
            return Err(KeyError::BadId);
        }
        let bytes: &[u8; KEY_LEN] = key.try_into().map_err(|_| KeyError::Truncated)?;
        Ok(Key { id, bytes: *bytes })
    }

    /// The key's record (what is programmed into the KEY region).
    pub fn to_record(&self) -> [u8; KEY_RECORD_LEN] {
        let mut out = [0u8; KEY_RECORD_LEN];
        let [m0, m1, m2, m3] = KEY_MAGIC;
        let [v0, v1] = KEY_VERSION.to_le_bytes();
        let [i0, i1] = self.id.to_le_bytes();
        let head = [m0, m1, m2, m3, v0, v1, i0, i1];
        for (d, s) in out.iter_mut().zip(head.iter().chain(&self.bytes)) {
            *d = *s;
        }
        if let Some((covered, crc)) = out.split_last_chunk_mut::<4>() {
            *crc = crc32(covered).to_le_bytes();
        }
        out
    }

    /// The keyed MAC state (the key's inner and outer pads hashed once).
    fn mac(&self) -> Option<Hmac<Sha256>> {
        <Hmac<Sha256> as KeyInit>::new_from_slice(&self.bytes).ok()
    }
}

/// `tc` with its MAC computed under `key` (the ground's side; also the host tools').
pub fn seal(key: &Key, mut tc: Telecommand) -> Telecommand {
    if let Some(mut m) = key.mac() {
        m.update(&tc.mac_input());
        let full = m.finalize().into_bytes();
        if let Some(head) = full.first_chunk::<MAC_LEN>() {
            tc.mac = *head;
        }
    }
    tc
}

/// Why a telecommand was refused before its command was looked at.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub enum AuthError {
    /// The MAC does not verify (wrong key, forged, damaged past the CRC), or the unit has
    /// no key.
    Unauthenticated,
    /// The sequence number of the last accepted telecommand: a replay.
    Replayed,
    /// A sequence number below the last accepted one (or 0).
    OutOfSequence,
}

/// The unit's side of authentication: the keyed MAC and the last sequence number.
///
/// A telecommand is accepted if its MAC verifies (compared in constant time over the
/// [`MAC_LEN`] bytes) and its sequence number is above the last accepted one; gaps are
/// allowed. The last sequence number is kept in RAM: after a reset any number ≥ 1 is
/// accepted again, so a replay across a reset is stopped by the table's revision, which
/// must rise at every activation (`crate::telecommand`).
#[derive(Clone)]
pub struct Authenticator {
    mac: Option<Hmac<Sha256>>,
    key_id: u16,
    last_seq: u32,
}

impl Authenticator {
    /// From the key record in `record` (no key if it is refused: then every telecommand
    /// is unauthenticated).
    pub fn new(record: &[u8]) -> Self {
        match Key::from_record(record) {
            Ok(k) => Authenticator { mac: k.mac(), key_id: k.id, last_seq: 0 },
            Err(_) => Authenticator { mac: None, key_id: 0, last_seq: 0 },
        }
    }

    /// The key's id (0: no key).
    pub fn key_id(&self) -> u16 {
        self.key_id
    }

    /// The last sequence number accepted (0: none).
    pub fn last_seq(&self) -> u32 {
        self.last_seq
    }

    /// Whether `tc`'s MAC verifies under the unit's key (constant time in the MAC).
    pub fn verify(&self, tc: &Telecommand) -> bool {
        let Some(mac) = &self.mac else { return false };
        let mut m = mac.clone();
        m.update(&tc.mac_input());
        m.verify_truncated_left(&tc.mac).is_ok()
    }

    /// The background check of the key in RAM: the keyed MAC state rebuilt from the
    /// protected record `record` and compared with the one in use by their tags on a
    /// fixed message; on a difference (or a key id that differs) the rebuilt state
    /// replaces it and this returns true. A record that no longer passes its own checks
    /// changes nothing (the key in use stays; the record is the ground's to reload).
    pub fn check_key(&mut self, record: &[u8]) -> bool {
        let Ok(k) = Key::from_record(record) else { return false };
        let Some(good) = k.mac() else { return false };
        let tag = |m: &Hmac<Sha256>| {
            let mut m = m.clone();
            m.update(b"ssis key check");
            m.finalize().into_bytes()
        };
        let same = k.id == self.key_id && self.mac.as_ref().is_some_and(|m| tag(m) == tag(&good));
        if !same {
            self.mac = Some(good);
            self.key_id = k.id;
        }
        !same
    }

    /// Authenticates `tc`: its MAC, then its sequence number, which it then takes as the
    /// last accepted one.
    pub fn check(&mut self, tc: &Telecommand) -> Result<(), AuthError> {
        if !self.verify(tc) {
            return Err(AuthError::Unauthenticated);
        }
        if tc.seq == self.last_seq && tc.seq != 0 {
            return Err(AuthError::Replayed);
        }
        if tc.seq <= self.last_seq {
            return Err(AuthError::OutOfSequence);
        }
        self.last_seq = tc.seq;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_key_state_that_differs_from_its_record_is_restored() {
        let key = Key { id: 7, bytes: [0x5A; KEY_LEN] };
        let record = key.to_record();
        let tc = seal(&key, Telecommand { seq: 1, ..Telecommand::default() });
        let mut a = Authenticator::new(&record);
        assert!(a.verify(&tc));
        assert!(!a.check_key(&record), "an intact key is left as it is");
        // An upset in the keyed state: stands for any change of its bytes.
        a.mac = Key { id: 7, bytes: [0x5B; KEY_LEN] }.mac();
        assert!(!a.verify(&tc));
        assert!(a.check_key(&record), "the changed key is found");
        assert!(a.verify(&tc), "and restored from its record");
        assert_eq!(a.key_id(), 7);
        // A record that fails its own checks changes nothing.
        let mut bad = record;
        bad[10] ^= 1;
        a.mac = None;
        assert!(!a.check_key(&bad));
        assert!(!a.verify(&tc));
    }
}
