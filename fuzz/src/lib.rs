//! Checks shared by the fuzz targets: every input must be decoded without a panic, and
//! whatever a decoder accepts must be exactly what an encoder would have sent.

use ssis::frames::decoder::StreamDecoder;
use ssis::frames::{Frame, CRC32C, CRC_LEN, SYNC};

/// Largest frame (the output frame, 97 bytes) with room to spare.
const MAX_LEN: usize = 128;

/// Encodes `f` (panics if the encoder fails: that is a finding).
pub fn encoded<F: Frame>(f: &F) -> Vec<u8> {
    let mut buf = [0u8; MAX_LEN];
    let n = f.encode_into(&mut buf).expect("an accepted frame encodes");
    buf[..n].to_vec()
}

/// Fuzzes frame type `F`. The first byte chooses how the rest is used, so that the fuzzer
/// reaches the field checks behind the CRC:
/// - bit 0: write sync and kind over the first three bytes;
/// - bit 1: write the matching CRC over the last four bytes of the first `LEN`.
///
/// The rest is then decoded as one frame ([`Frame::decode`]) and streamed byte by byte
/// through a [`StreamDecoder`]. Every accepted frame must re-encode to exactly the bytes
/// it was decoded from, and the decoder's byte accounting must hold.
pub fn check_frame<F: Frame + PartialEq + core::fmt::Debug>(data: &[u8]) {
    let Some((&mode, rest)) = data.split_first() else { return };
    let mut bytes = rest.to_vec();
    if mode & 1 != 0 && bytes.len() >= 3 {
        bytes[..2].copy_from_slice(&SYNC);
        bytes[2] = F::KIND;
    }
    if mode & 2 != 0 && bytes.len() >= F::LEN {
        let crc = CRC32C.checksum(&bytes[..F::LEN - CRC_LEN]);
        bytes[F::LEN - CRC_LEN..F::LEN].copy_from_slice(&crc.to_le_bytes());
    }
    if let Ok(f) = F::decode(&bytes) {
        assert_eq!(encoded(&f), bytes, "decode accepted bytes its encoder would not send");
        assert_eq!(F::decode(&encoded(&f)).ok(), Some(f));
    }
    if bytes.len() >= F::LEN {
        if let Ok(f) = F::decode(&bytes[..F::LEN]) {
            assert_eq!(encoded(&f), &bytes[..F::LEN]);
        }
    }
    let mut dec: StreamDecoder<F, MAX_LEN> = StreamDecoder::new();
    for (i, &b) in bytes.iter().enumerate() {
        if let Some(Ok(f)) = dec.push(b) {
            // An accepted frame is the last LEN bytes pushed.
            let start = (i + 1).checked_sub(F::LEN).expect("a frame longer than the bytes pushed");
            assert_eq!(encoded(&f), &bytes[start..=i], "stream accepted bytes its encoder would not send");
        }
        assert!(dec.buffered() < F::LEN);
    }
    let s = dec.stats();
    let accounted = s.frames_ok as usize * F::LEN + s.bytes_skipped as usize + dec.buffered();
    assert_eq!(accounted, bytes.len(), "stream decoder lost or invented bytes: {s:?}");
}
