//! The binary form shared by the small f64 sections (the accelerometer section,
//! [`super::accel`], and the launch-vehicle pad initialisation block,
//! `crate::nav::init`). Little-endian:
//!
//! | off | size | field |
//! |---|---|---|
//! | 0 | 4 | magic |
//! | 4 | 2 | format version |
//! | 6 | 2 | payload length = 8 × N |
//! | 8 | 4 | revision |
//! | 12 | 8 × N | N f64 fields |
//! | 12 + 8N | 4 | CRC-32/ISO-HDLC over everything before it |
//!
//! Decoding checks, in order: length, magic, version, declared payload length, CRC. The
//! values are the caller's to check.

use super::binary::crc32;

/// Length of a section of `n_f64` fields, bytes.
pub const fn section_len(n_f64: usize) -> usize {
    12 + 8 * n_f64 + 4
}

/// Why a section's envelope was refused.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SectionError {
    /// Wrong length, or a declared payload length that is not 8 × N.
    Length,
    /// Wrong magic.
    Magic,
    /// Unknown format version.
    Version,
    /// CRC mismatch.
    Crc,
}

/// Writes the section into `out` (which should be [`section_len`]`(N)` bytes long;
/// whatever is longer is left alone, whatever is shorter is cut, and its CRC is then
/// wrong).
pub fn encode<const N: usize>(magic: [u8; 4], version: u16, revision: u32, fields: &[f64; N], out: &mut [u8]) {
    let payload = u16::try_from(8 * N).unwrap_or(u16::MAX);
    let bytes = magic
        .into_iter()
        .chain(version.to_le_bytes())
        .chain(payload.to_le_bytes())
        .chain(revision.to_le_bytes())
        .chain(fields.iter().flat_map(|v| v.to_le_bytes()));
    let len = section_len(N).min(out.len());
    let Some(section) = out.get_mut(..len) else { return };
    for (slot, b) in section.iter_mut().zip(bytes) {
        *slot = b;
    }
    if let Some((body, crc)) = section.split_last_chunk_mut::<4>() {
        *crc = crc32(body).to_le_bytes();
    }
}

/// Decodes a section of `N` fields: (revision, fields).
pub fn decode<const N: usize>(bytes: &[u8], magic: [u8; 4], version: u16) -> Result<(u32, [f64; N]), SectionError> {
    if bytes.len() != section_len(N) {
        return Err(SectionError::Length);
    }
    let (body, crc) = bytes.split_last_chunk::<4>().ok_or(SectionError::Length)?;
    let (head, payload) = body.split_first_chunk::<12>().ok_or(SectionError::Length)?;
    let [m0, m1, m2, m3, v0, v1, l0, l1, r0, r1, r2, r3] = *head;
    if [m0, m1, m2, m3] != magic {
        return Err(SectionError::Magic);
    }
    if u16::from_le_bytes([v0, v1]) != version {
        return Err(SectionError::Version);
    }
    if usize::from(u16::from_le_bytes([l0, l1])) != 8 * N {
        return Err(SectionError::Length);
    }
    if crc32(body) != u32::from_le_bytes(*crc) {
        return Err(SectionError::Crc);
    }
    let mut f = [0.0; N];
    for (slot, c) in f.iter_mut().zip(payload.chunks_exact(8)) {
        if let Some(b) = c.first_chunk::<8>() {
            *slot = f64::from_le_bytes(*b);
        }
    }
    Ok((u32::from_le_bytes([r0, r1, r2, r3]), f))
}
