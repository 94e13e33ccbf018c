//! Binary form of the calibration table: what the firmware stores and loads.
//!
//! Little-endian, [`TABLE_LEN`] bytes:
//!
//! | offset | size | field |
//! |---|---|---|
//! | 0 | 4 | magic `SSCT` |
//! | 4 | 2 | format version (u16) = [`FORMAT_VERSION`] |
//! | 6 | 2 | payload length (u16) = [`PAYLOAD_LEN`] |
//! | 8 | 4 | table revision (u32) |
//! | 12 | 464 | 58 × f64, in the order of [`fields`] |
//! | 476 | 1 | flags: bit0 observer gains override present; bit1 star-tracker LFE present; other bits 0 |
//! | 477 | 1 | estimator: 0 Luenberger observer (eq. 6), 1 MEKF ([`super::Estimator`]) |
//! | 478 | 2 | zero |
//! | 480 | 4 | CRC-32/ISO-HDLC over bytes 0..480 (u32) |
//!
//! The star tracker's low-frequency error (`observer.st_lfe_sigma_arcsec`, `st_lfe_tau_s`)
//! is stored in the first two gain slots, K_B x and y (fields 50 and 51, bytes 412 and 420; the other four gain slots 0), with flag bit1;
//! a table has a gain override (the fixed-gain observer's) or an LFE (the MEKF's), never
//! both ([`TableError::LfeWithGains`]). Without an LFE, bit1 and those slots are 0: the
//! bytes and the CRC of a white-tracker table are those of the format without the LFE,
//! and a firmware that does not know bit1 refuses a table with an LFE (flag bits it does
//! not define) rather than flying it as white.
//!
//! Decoding checks, in order: length, magic, version, declared length, CRC, then
//! [`CalibrationTable::validate`]. A table that fails any check is refused whole.

use super::{CalibrationTable, Estimator, FogCal, Misalignment, ObserverConfig, ObserverGains, TableError, N_FOG};

/// Magic bytes at the start of a stored table.
pub const MAGIC: [u8; 4] = *b"SSCT";
/// Format version written and read by this code.
pub const FORMAT_VERSION: u16 = 3;
/// Number of f64 fields.
pub const N_F64: usize = 58;
/// Bytes after the 8-byte header up to the CRC.
pub const PAYLOAD_LEN: usize = 4 + 8 * N_F64 + 4;
/// The first gain slot (K_B x), where a table with an LFE stores its 1σ and τ.
const LFE_SLOT: usize = N_F64 - 8;
/// Total length of the binary table.
pub const TABLE_LEN: usize = 8 + PAYLOAD_LEN + 4;
/// CRC used for the table (CRC-32/ISO-HDLC, the zlib/Ethernet CRC).
pub const CRC32: crc::Crc<u32> = crc::Crc::<u32>::new(&crc::CRC_32_ISO_HDLC);

/// [`CRC32`] of `bytes`, out of line: one copy of the CRC loop for every caller (the
/// table codec, the store, the command link, the built-in test; none on the step's path),
/// where `CRC32.checksum` inlined it into each.
#[inline(never)]
pub fn crc32(bytes: &[u8]) -> u32 {
    CRC32.checksum(bytes)
}

/// Feeds `bytes` to a [`CRC32`] digest, out of line (as [`crc32`]).
#[inline(never)]
pub fn crc32_update(digest: &mut crc::Digest<'_, u32>, bytes: &[u8]) {
    digest.update(bytes);
}

/// The f64 fields of `t` in storage order: per FOG (bias, scale, T_ref, a1, a2, a3, g, h),
/// then δ12 δ13 δ21 δ23 δ31 δ32 δ42 δ43, γ, the mount quaternion (w x y z), the G-filter
/// time constant, ARW, RRW, star-tracker σ, star-tracker period, K_B (3), K_U (3), the
/// initial drift 1σ, the acquisition time (format 3).
pub fn fields(t: &CalibrationTable) -> [f64; N_F64] {
    let mut out = [0.0; N_F64];
    let o = &t.observer;
    let lfe = ObserverGains { k_b: [o.st_lfe_sigma_arcsec, o.st_lfe_tau_s, 0.0], k_u_per_s: [0.0; 3] };
    let gains =
        o.gains_override.unwrap_or(if o.lfe() { lfe } else { ObserverGains { k_b: [0.0; 3], k_u_per_s: [0.0; 3] } });
    let m = &t.misalignment;
    let tail = [m.d12_rad, m.d13_rad, m.d21_rad, m.d23_rad, m.d31_rad, m.d32_rad, m.d42_rad, m.d43_rad, t.gamma_rad];
    let fogs = t.fog.iter().flat_map(|f| {
        let [a1, a2, a3] = f.thermal_t_rad_s;
        [
            f.bias_rad_s,
            f.scale_factor_error,
            f.t_ref_degc,
            a1,
            a2,
            a3,
            f.thermal_g_rad_s_per_degc_s,
            f.thermal_tg_rad_s_per_degc2_s,
        ]
    });
    let rest = [t.t_rate_filter_s, o.arw_deg_sqrt_h, o.rrw_deg_h_sqrt_h, o.st_sigma_arcsec, o.st_period_s];
    let all = fogs
        .chain(tail)
        .chain(t.st_mount_q)
        .chain(rest)
        .chain(gains.k_b)
        .chain(gains.k_u_per_s)
        .chain([o.initial_drift_sigma_deg_h, o.acquisition_s]);
    for (slot, v) in out.iter_mut().zip(all) {
        *slot = v;
    }
    out
}

/// Writes the binary table into `out`; returns the number of bytes written.
pub fn encode_into(t: &CalibrationTable, out: &mut [u8]) -> Result<usize, TableError> {
    let buf = out.get_mut(..TABLE_LEN).ok_or(TableError::BufferTooSmall)?;
    buf.fill(0);
    let pos = encode_body_into(t, buf)?;
    let mut w = Cursor { buf, pos };
    let crc = crc32(w.buf.get(..pos).ok_or(TableError::BufferTooSmall)?);
    w.put(&crc.to_le_bytes())?;
    Ok(w.pos)
}

/// Writes the binary table without its CRC (the first `TABLE_LEN − 4` bytes, the bytes
/// the CRC covers) into `out`; returns the number of bytes written. The background check
/// of the table in RAM computes their CRC in slices (`crate::flight`).
pub fn encode_body_into(t: &CalibrationTable, out: &mut [u8]) -> Result<usize, TableError> {
    let mut w = Cursor { buf: out, pos: 0 };
    w.put(&MAGIC)?;
    w.put(&FORMAT_VERSION.to_le_bytes())?;
    w.put(&(PAYLOAD_LEN as u16).to_le_bytes())?;
    w.put(&t.revision.to_le_bytes())?;
    for v in fields(t) {
        w.put(&v.to_le_bytes())?;
    }
    let flags: u8 = u8::from(t.observer.gains_override.is_some()) | (u8::from(t.observer.lfe()) << 1);
    w.put(&[flags, t.observer.estimator.code(), 0, 0])?;
    Ok(w.pos)
}

/// Encodes into a fixed array (out of line: one copy for its callers).
#[inline(never)]
pub fn encode(t: &CalibrationTable) -> [u8; TABLE_LEN] {
    let mut out = [0u8; TABLE_LEN];
    // The array has exactly TABLE_LEN bytes, so encoding cannot fail; keep the zeroed
    // (and therefore CRC-invalid) buffer if it ever did.
    let _ = encode_into(t, &mut out);
    out
}

/// Decodes and validates a binary table.
pub fn decode(bytes: &[u8]) -> Result<CalibrationTable, TableError> {
    let buf = bytes.get(..TABLE_LEN).ok_or(TableError::Truncated)?;
    let mut r = Reader { buf, pos: 0 };
    if r.take::<4>()? != MAGIC {
        return Err(TableError::BadMagic);
    }
    if u16::from_le_bytes(r.take::<2>()?) != FORMAT_VERSION {
        return Err(TableError::UnsupportedVersion);
    }
    if usize::from(u16::from_le_bytes(r.take::<2>()?)) != PAYLOAD_LEN {
        return Err(TableError::BadLength);
    }
    let body = buf.get(..TABLE_LEN - 4).ok_or(TableError::Truncated)?;
    let stored =
        u32::from_le_bytes(buf.get(TABLE_LEN - 4..).and_then(|s| s.try_into().ok()).ok_or(TableError::Truncated)?);
    if crc32(body) != stored {
        return Err(TableError::BadCrc);
    }
    let revision = u32::from_le_bytes(r.take::<4>()?);
    let mut v = [0.0f64; N_F64];
    for slot in v.iter_mut() {
        *slot = f64::from_le_bytes(r.take::<8>()?);
    }
    let [flags, code, p1, p2] = r.take::<4>()?;
    let estimator = Estimator::from_code(code).ok_or(TableError::BadFlags)?;
    if flags & !3 != 0 || flags == 3 || p1 != 0 || p2 != 0 {
        return Err(TableError::BadFlags);
    }
    let mut t = from_fields(revision, &v, flags & 1 == 1);
    if flags & 2 != 0 {
        let slots = v.get(LFE_SLOT..LFE_SLOT + 6).unwrap_or(&[]);
        let [sigma, tau, rest @ ..] = slots else { return Err(TableError::BadFlags) };
        t.observer.st_lfe_sigma_arcsec = *sigma;
        t.observer.st_lfe_tau_s = *tau;
        if !t.observer.lfe() || rest.iter().any(|x| x.to_bits() != 0) {
            return Err(TableError::BadFlags);
        }
    }
    t.observer.estimator = estimator;
    t.validate()?;
    Ok(t)
}

fn from_fields(revision: u32, v: &[f64; N_F64], gains_present: bool) -> CalibrationTable {
    let mut it = v.iter().copied();
    let mut next = || it.next().unwrap_or(f64::NAN);
    let mut fog = [FogCal::IDEAL; N_FOG];
    for f in fog.iter_mut() {
        *f = FogCal {
            bias_rad_s: next(),
            scale_factor_error: next(),
            t_ref_degc: next(),
            thermal_t_rad_s: [next(), next(), next()],
            thermal_g_rad_s_per_degc_s: next(),
            thermal_tg_rad_s_per_degc2_s: next(),
        };
    }
    let misalignment = Misalignment {
        d12_rad: next(),
        d13_rad: next(),
        d21_rad: next(),
        d23_rad: next(),
        d31_rad: next(),
        d32_rad: next(),
        d42_rad: next(),
        d43_rad: next(),
    };
    let gamma_rad = next();
    let st_mount_q = [next(), next(), next(), next()];
    let t_rate_filter_s = next();
    let (arw, rrw, sig, per) = (next(), next(), next(), next());
    let gains = ObserverGains { k_b: [next(), next(), next()], k_u_per_s: [next(), next(), next()] };
    CalibrationTable {
        revision,
        fog,
        misalignment,
        gamma_rad,
        st_mount_q,
        t_rate_filter_s,
        observer: ObserverConfig {
            arw_deg_sqrt_h: arw,
            rrw_deg_h_sqrt_h: rrw,
            st_sigma_arcsec: sig,
            st_period_s: per,
            gains_override: if gains_present { Some(gains) } else { None },
            estimator: Estimator::Luenberger,
            initial_drift_sigma_deg_h: next(),
            acquisition_s: next(),
            st_lfe_sigma_arcsec: 0.0,
            st_lfe_tau_s: 0.0,
        },
    }
}

struct Cursor<'a> {
    buf: &'a mut [u8],
    pos: usize,
}

impl Cursor<'_> {
    fn put(&mut self, bytes: &[u8]) -> Result<(), TableError> {
        let end = self.pos + bytes.len();
        self.buf.get_mut(self.pos..end).ok_or(TableError::BufferTooSmall)?.copy_from_slice(bytes);
        self.pos = end;
        Ok(())
    }
}

struct Reader<'a> {
    buf: &'a [u8],
    pos: usize,
}

impl Reader<'_> {
    fn take<const N: usize>(&mut self) -> Result<[u8; N], TableError> {
        let s = self.buf.get(self.pos..self.pos + N).ok_or(TableError::Truncated)?;
        self.pos += N;
        s.try_into().map_err(|_| TableError::Truncated)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A table unlike the default in every group of fields, within the plausible ranges.
    fn sample() -> CalibrationTable {
        let mut t = CalibrationTable::DEFAULT;
        t.revision = 0x0102_0304;
        for (i, f) in t.fog.iter_mut().enumerate() {
            let k = i as f64 + 1.0;
            f.bias_rad_s = 1e-7 * k;
            f.scale_factor_error = -2e-5 * k;
            f.t_ref_degc = 20.0 + k;
            f.thermal_t_rad_s = [1e-9 * k, -1e-10 * k, 1e-12 * k];
            f.thermal_g_rad_s_per_degc_s = 3e-8 * k;
            f.thermal_tg_rad_s_per_degc2_s = -1e-9 * k;
        }
        t.misalignment.d12_rad = 1e-4;
        t.misalignment.d43_rad = -2e-4;
        t.gamma_rad += 1e-4;
        t.st_mount_q = [0.0, 1.0, 0.0, 0.0];
        t.t_rate_filter_s = 45.0;
        t.observer.gains_override = Some(ObserverGains { k_b: [0.1, 0.2, 0.3], k_u_per_s: [1e-3, 2e-3, 3e-3] });
        t.observer.estimator = Estimator::Mekf;
        t.observer.acquisition_s = 600.0;
        t
    }

    /// Rewrites the CRC after `bytes` were changed, so a later check sees the change.
    fn reseal(bytes: &mut [u8; TABLE_LEN]) {
        let crc = CRC32.checksum(&bytes[..TABLE_LEN - 4]);
        bytes[TABLE_LEN - 4..].copy_from_slice(&crc.to_le_bytes());
    }

    #[test]
    fn a_table_round_trips_bit_for_bit() {
        let t = sample();
        assert_eq!(t.validate(), Ok(()));
        let bytes = encode(&t);
        assert_eq!(decode(&bytes), Ok(t));
        // The documented layout: header, fields at 12 + 8 i, flags, estimator, CRC.
        assert_eq!(bytes[..4], MAGIC);
        assert_eq!(bytes[4..6], FORMAT_VERSION.to_le_bytes());
        assert_eq!(bytes[6..8], (PAYLOAD_LEN as u16).to_le_bytes());
        assert_eq!(bytes[8..12], t.revision.to_le_bytes());
        for (i, v) in fields(&t).iter().enumerate() {
            assert_eq!(bytes[12 + 8 * i..20 + 8 * i], v.to_le_bytes(), "field {i}");
        }
        assert_eq!(bytes[476..480], [1, Estimator::Mekf.code(), 0, 0]);
        assert_eq!(bytes[480..], CRC32.checksum(&bytes[..480]).to_le_bytes());
        assert_eq!(TABLE_LEN, 484);
    }

    #[test]
    fn without_a_gains_override_the_gains_are_not_stored() {
        let mut t = sample();
        t.observer.gains_override = None;
        let bytes = encode(&t);
        assert_eq!(bytes[476], 0);
        assert_eq!(decode(&bytes), Ok(t));
    }

    #[test]
    fn each_check_refuses_its_damage() {
        let good = encode(&sample());
        assert_eq!(decode(&good[..TABLE_LEN - 1]), Err(TableError::Truncated));

        let mut b = good;
        b[0] ^= 0x20;
        assert_eq!(decode(&b), Err(TableError::BadMagic));

        let mut b = good;
        b[4..6].copy_from_slice(&(FORMAT_VERSION - 1).to_le_bytes());
        assert_eq!(decode(&b), Err(TableError::UnsupportedVersion));

        let mut b = good;
        b[6..8].copy_from_slice(&(PAYLOAD_LEN as u16 + 8).to_le_bytes());
        assert_eq!(decode(&b), Err(TableError::BadLength));

        for at in [8, 100, 477, TABLE_LEN - 1] {
            let mut b = good;
            b[at] ^= 0x01;
            assert_eq!(decode(&b), Err(TableError::BadCrc), "byte {at}");
        }

        for (at, v) in [(476, 0b10), (477, 2), (478, 1), (479, 0x80)] {
            let mut b = good;
            b[at] = v;
            reseal(&mut b);
            assert_eq!(decode(&b), Err(TableError::BadFlags), "byte {at} = {v}");
        }
    }

    /// A copy whose CRC is right but whose numbers are not is refused by the table's own
    /// checks, naming the field.
    #[test]
    fn a_sealed_copy_with_a_bad_number_is_refused() {
        let mut b = encode(&sample());
        b[12..20].copy_from_slice(&f64::NAN.to_le_bytes());
        reseal(&mut b);
        match decode(&b) {
            Err(TableError::Field(e)) => assert!(e.value().is_nan()),
            other => panic!("not refused for the NaN bias: {other:?}"),
        }
        let mut b = encode(&sample());
        // The mount quaternion's w (field 41) doubled: not of unit length.
        b[12 + 8 * 41..20 + 8 * 41].copy_from_slice(&2.0f64.to_le_bytes());
        reseal(&mut b);
        assert!(decode(&b).is_err());
    }

    #[test]
    fn a_tracker_lfe_rides_in_the_gain_slots_and_a_white_table_keeps_its_bytes() {
        let mut white = sample();
        white.observer.gains_override = None;
        let mut lfe = white;
        lfe.observer.st_lfe_sigma_arcsec = 4.0;
        lfe.observer.st_lfe_tau_s = 300.0;
        let bytes = encode(&lfe);
        assert_eq!(decode(&bytes), Ok(lfe));
        assert_eq!(bytes[476], 2);
        assert_eq!(bytes[12 + 8 * LFE_SLOT..20 + 8 * LFE_SLOT], 4.0f64.to_le_bytes());
        assert_eq!(bytes[20 + 8 * LFE_SLOT..28 + 8 * LFE_SLOT], 300.0f64.to_le_bytes());
        // A 1σ without a correlation time is a white tracker: the white table's bytes.
        let mut half = white;
        half.observer.st_lfe_sigma_arcsec = 4.0;
        let w = encode(&white);
        assert_eq!(encode(&half), w);
        assert_eq!(w[412..460], [0u8; 48]);
        // Both flags, or the LFE flag over empty slots, are refused.
        let mut b = bytes;
        b[476] = 3;
        reseal(&mut b);
        assert_eq!(decode(&b), Err(TableError::BadFlags));
        let mut b = w;
        b[476] = 2;
        reseal(&mut b);
        assert_eq!(decode(&b), Err(TableError::BadFlags));
        // An LFE with a gain override is refused before it is stored.
        let mut both = lfe;
        both.observer.gains_override = sample().observer.gains_override;
        assert_eq!(both.validate(), Err(TableError::LfeWithGains));
    }

    #[test]
    fn a_short_buffer_is_refused() {
        let mut out = [0u8; TABLE_LEN - 1];
        assert_eq!(encode_into(&sample(), &mut out), Err(TableError::BufferTooSmall));
    }
}
