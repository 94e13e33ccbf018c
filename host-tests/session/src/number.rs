//! The number parser of the reader: correctly rounded, plain decimal forms 16 bytes at a
//! time where the CPU has SSSE3.

/// Parses the number at the start of `b` (spaces already skipped), returning the value and
/// the bytes it took, or `None` when `b` does not start with one. `b` may go on past the
/// field (the number ends at the first byte that cannot continue it).
///
/// Every value correctly rounded, the same `f64` as `str::parse::<f64>` gives for the field
/// (`inf`, `nan` included). The plain decimal forms a session is written in take
/// `plain::parse` where the CPU has SSSE3 (16 bytes at once); everything else (more
/// digits, bigger exponents, a form starting with `.`, `inf`, `nan`, `b` too short for the
/// 16 bytes) the `fast-float2` crate (a port of Lemire's `fast_float`, the algorithm the
/// standard library's own parser uses), which accepts the same forms and stops at the same
/// byte.
#[inline]
pub fn parse_number(b: &[u8]) -> Option<(f64, usize)> {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("ssse3") {
        // SAFETY: the CPU has SSSE3 (checked above).
        return unsafe { parse_number_ssse3(b) };
    }
    parse_number_general(b)
}

/// [`parse_number`] without the fast path: `fast-float2`.
#[inline]
pub(crate) fn parse_number_general(b: &[u8]) -> Option<(f64, usize)> {
    fast_float2::parse_partial::<f64, _>(b).ok()
}

/// [`parse_number`] where the CPU has SSSE3.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "ssse3")]
#[inline]
pub(crate) fn parse_number_ssse3(b: &[u8]) -> Option<(f64, usize)> {
    // SAFETY: this function has SSSE3.
    match unsafe { plain::parse(b) } {
        Some(r) => Some(r),
        None => parse_number_general(b),
    }
}

/// The plain decimal numbers, `[+-]digits[.digits][(e|E)[+-]digits]`, 16 bytes at a time
/// with SSSE3.
#[cfg(target_arch = "x86_64")]
mod plain {
    use std::arch::x86_64::{
        __m128i, _mm_cmpeq_epi8, _mm_cvtsi128_si64, _mm_loadu_si128, _mm_madd_epi16, _mm_maddubs_epi16, _mm_min_epu8,
        _mm_movemask_epi8, _mm_set1_epi16, _mm_set1_epi32, _mm_set1_epi8, _mm_shuffle_epi8, _mm_sub_epi8,
        _mm_unpackhi_epi64,
    };

    /// 10^k, k = 0..=22: every one exact in an `f64`.
    const POW10: [f64; 23] = [
        1e0, 1e1, 1e2, 1e3, 1e4, 1e5, 1e6, 1e7, 1e8, 1e9, 1e10, 1e11, 1e12, 1e13, 1e14, 1e15, 1e16, 1e17, 1e18, 1e19,
        1e20, 1e21, 1e22,
    ];

    /// `SHUFFLE[i][n]`: the `pshufb` control that takes the n digits of a number with i
    /// digits before its dot (i = n: no dot) out of its 16 bytes (the dot, byte i, left out)
    /// to the last n bytes, zeros before them (leading zeros).
    static SHUFFLE: [[[u8; 16]; 16]; 16] = shuffle_table();

    const fn shuffle_table() -> [[[u8; 16]; 16]; 16] {
        let mut t = [[[0x80u8; 16]; 16]; 16];
        let mut i = 0;
        while i < 16 {
            let mut n = 0;
            while n < 16 {
                let mut k = 16 - n;
                while k < 16 {
                    let j = k - (16 - n);
                    t[i][n][k] = (if j >= i { j + 1 } else { j }) as u8;
                    k += 1;
                }
                n += 1;
            }
            i += 1;
        }
        t
    }

    /// The number at the start of `b` when it is plain: its sign, digits and dot within 16
    /// bytes after the sign (so at most 15 digits, m < 10^15 < 2^53), the exponent at most
    /// three digits, and the decimal exponent e after the fraction's digits within ±22.
    /// Then the value is exact by Clinger's fast path: m and 10^|e| are exact `f64`s and one
    /// multiply or divide rounds once, correctly. The bytes it took are the ones
    /// `fast-float2` takes (after them comes a byte that cannot continue the number).
    /// `None` for anything else, and when `b` is shorter than the bytes it reads at once (17
    /// from the start, 9 from an `e`).
    ///
    /// The digits: the 16 bytes after the sign less `0`, a byte mask of the digits, the
    /// first non-digit (a dot: then the first after it), one shuffle that leaves the dot
    /// out and puts the digits last (leading zeros before), then pairs, fours and eights of
    /// digits by multiply-adds.
    ///
    /// # Safety
    ///
    /// The CPU must have SSSE3. (Not a `target_feature` function, so that it inlines into
    /// the line loop of one, `parse_next_line_ssse3` (reader.rs).)
    #[inline(always)]
    pub(super) unsafe fn parse(b: &[u8]) -> Option<(f64, usize)> {
        let c0 = *b.first()?;
        let neg = c0 == b'-';
        let s = usize::from(neg || c0 == b'+');
        let chunk: &[u8; 16] = b.get(s..s + 16)?.try_into().ok()?;
        // SAFETY: the 16 bytes of `chunk` (an unaligned load).
        let v = unsafe { _mm_loadu_si128(chunk.as_ptr().cast::<__m128i>()) };
        let t = _mm_sub_epi8(v, _mm_set1_epi8(b'0' as i8));
        let digit = _mm_cmpeq_epi8(_mm_min_epu8(t, _mm_set1_epi8(9)), t);
        // A bit per byte that is not a digit, and every bit from 16 on.
        let non_digit = !(_mm_movemask_epi8(digit) as u32);
        let n_int = non_digit.trailing_zeros() as usize;
        if n_int == 0 || n_int >= 16 {
            return None;
        }
        let (n, stop) = if chunk[n_int] == b'.' {
            let n_frac = (non_digit >> (n_int + 1)).trailing_zeros() as usize;
            (n_int + n_frac, n_int + 1 + n_frac)
        } else {
            (n_int, n_int)
        };
        // The byte after the digits must be one of the 16.
        if stop >= 16 {
            return None;
        }
        // SAFETY: `SHUFFLE[n_int][n]` is 16 bytes (an unaligned load).
        let control = unsafe { _mm_loadu_si128(SHUFFLE[n_int][n].as_ptr().cast::<__m128i>()) };
        let digits = _mm_shuffle_epi8(t, control);
        // Pairs (10 a + b), then fours (100 ab + cd): 4 × u32, the most significant first.
        let fours = _mm_madd_epi16(_mm_maddubs_epi16(digits, _mm_set1_epi16(0x010A)), _mm_set1_epi32(0x0001_0064));
        let lo = _mm_cvtsi128_si64(fours) as u64;
        let hi = _mm_cvtsi128_si64(_mm_unpackhi_epi64(fours, fours)) as u64;
        let m = ((lo & 0xFFFF_FFFF) * 10_000 + (lo >> 32)) * 100_000_000 + (hi & 0xFFFF_FFFF) * 10_000 + (hi >> 32);
        let mut used = s + stop;
        let mut e10 = n_int as i64 - n as i64;
        if chunk[stop] | 0x20 == b'e' {
            let (ev, len) = exponent(b.get(used + 1..)?)?;
            e10 += ev;
            used += 1 + len;
        }
        if !(-22..=22).contains(&e10) {
            return None;
        }
        let f = m as f64;
        let x = if e10 < 0 { f / POW10[(-e10) as usize] } else { f * POW10[e10 as usize] };
        Some((f64::from_bits(x.to_bits() | (u64::from(neg) << 63)), used))
    }

    /// The exponent's sign and digits at the start of `b` (after the `e`) when it has one to
    /// three digits: its value and the bytes it took. `None` else (no digits: the number
    /// ends before the `e`, which `fast-float2` works out; more digits), and when `b` is
    /// shorter than 8 bytes.
    #[inline(always)]
    fn exponent(b: &[u8]) -> Option<(i64, usize)> {
        let x = u64::from_le_bytes(b.get(..8)?.try_into().ok()?);
        let c = x as u8;
        let neg = c == b'-';
        let j = usize::from(neg || c == b'+');
        let x = x >> (8 * j);
        // The first byte that is not a digit, eight bytes at once: a byte below `0` sets its
        // top bit in `x - 0x30…`, one above `9` (up to 0xAF) in `x + 0x46…`, one from 0xB0
        // in `x - 0x30…`; a borrow or carry only runs upwards from a non-digit, so the lowest
        // flagged byte is the first non-digit.
        let lo = x.wrapping_sub(0x3030_3030_3030_3030);
        let hi = x.wrapping_add(0x4646_4646_4646_4646);
        let n = ((lo | hi) & 0x8080_8080_8080_8080).trailing_zeros() as usize / 8;
        if n == 0 || n > 3 {
            return None;
        }
        // The digits at the top of three bytes, zeros below.
        let d = ((lo as u32) << (8 * (3 - n))) & 0x00FF_FFFF;
        let v = i64::from((d & 0xFF) * 100 + ((d >> 8) & 0xFF) * 10 + (d >> 16));
        Some((if neg { -v } else { v }, j + n))
    }
}

#[cfg(all(test, target_arch = "x86_64"))]
mod tests {
    /// The fast number path takes the forms a session is written in (the property test in
    /// `tests/numbers.rs` checks that whatever it takes is right; this, that it is used).
    #[test]
    fn plain_takes_the_session_forms() {
        if !std::arch::is_x86_feature_detected!("ssse3") {
            return;
        }
        let forms = [
            "0.01",
            "99999.99",
            "1.749461098e-2",
            "-9.289446890e-6",
            "24.8201",
            "0.000000000e0",
            "39.934",
            "-1.5E+3",
            "+7",
            "12345678901234",
            "5.",
            "1.2e22",
            "-0",
        ];
        for t in forms {
            let buf = format!("{t},1.750919261e-2,0.000000000e0\n");
            // SAFETY: the CPU has SSSE3 (checked above).
            let got = unsafe { super::plain::parse(buf.as_bytes()) };
            let want = t.parse::<f64>().unwrap();
            assert_eq!(got.map(|(x, n)| (x.to_bits(), n)), Some((want.to_bits(), t.len())), "{t}");
        }
    }
}
