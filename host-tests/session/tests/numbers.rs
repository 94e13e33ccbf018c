//! The session reader's number parser: exactly what `str::parse::<f64>` gives, for the forms a
//! logger writes and odd ones, and the fast path bit for bit against the plain parser.

use proptest::prelude::*;

/// The session reader's number parser gives exactly what `str::parse::<f64>` gives, for the
/// forms a logger writes and for odd ones (long mantissas, large exponents, signs, no digits
/// before or after the point), and refuses what it refuses.
#[test]
fn g_number_parser_matches_the_standard_library() {
    use rand::{Rng, SeedableRng};
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(42);
    let mut texts: Vec<String> = [
        "0",
        "-0",
        "+1",
        "1.",
        ".5",
        "-.5e-3",
        "1e22",
        "1e23",
        "9007199254740993",
        "123456789012345678901",
        "0.000000000000000000001234",
        "1.7976931348623157e308",
        "5e-324",
        "inf",
        "-inf",
        "nan",
        "1e",
        "e5",
        "-",
        ".",
        "1.2.3",
        "12345678.12345678",
        "00000000000000000000001",
        "3.14159265358979323846",
    ]
    .iter()
    .map(|s| s.to_string())
    .collect();
    for _ in 0..200_000 {
        let v: f64 = rng.random_range(-1e6..1e6) * 10f64.powi(rng.random_range(-30..30));
        texts.push(match rng.random_range(0..5) {
            0 => format!("{v:e}"),
            1 => format!("{v:.9e}"),
            2 => format!("{v:.4}"),
            3 => format!("{v}"),
            _ => format!("{:.*}", rng.random_range(0..20), v),
        });
    }
    for t in &texts {
        let std = t.parse::<f64>();
        let ours = ssis_session::parse_number(t.as_bytes()).filter(|(_, used)| *used == t.len());
        match (std, ours) {
            (Ok(a), Some((b, _))) => {
                assert!(a.to_bits() == b.to_bits() || (a.is_nan() && b.is_nan()), "{t}: {a} vs {b}")
            }
            (Err(_), None) => {}
            (a, b) => panic!("{t}: std {a:?}, ours {b:?}"),
        }
    }
    println!("{} numbers parsed bit for bit as str::parse does", texts.len());
}

/// The forms a number can take in a field: digits (leading zeros, 1 to 25 of them), a dot
/// anywhere or none, a sign, an exponent (−400..400, either case, its own sign and leading
/// zeros); `{:e}`, `{:.Ne}`, `{:.N}` and `{}` of any finite f64; and edge cases.
fn number_text() -> impl Strategy<Value = String> {
    let digits = proptest::collection::vec(0u8..10, 1..=25);
    let built = (
        prop_oneof![Just(""), Just("-"), Just("+")],
        digits,
        any::<prop::sample::Index>(),
        any::<bool>(),
        prop_oneof![
            Just(None),
            (prop_oneof![Just('e'), Just('E')], prop_oneof![Just(""), Just("-"), Just("+")], 0u32..3, 0i32..400)
                .prop_map(Some)
        ],
    )
        .prop_map(|(sign, digits, dot_at, dot, exp)| {
            let mut s = String::from(sign);
            let dot_at = dot_at.index(digits.len() + 1);
            for (k, d) in digits.iter().enumerate() {
                if dot && k == dot_at {
                    s.push('.');
                }
                s.push((b'0' + d) as char);
            }
            if dot && dot_at == digits.len() {
                s.push('.');
            }
            if let Some((e, esign, zeros, v)) = exp {
                s.push(e);
                s.push_str(esign);
                s.push_str(&"0".repeat(zeros as usize));
                s.push_str(&v.to_string());
            }
            s
        });
    let finite = any::<f64>().prop_filter("finite", |v| v.is_finite());
    let formatted = (finite, 0usize..25, 0u8..4).prop_map(|(v, n, how)| match how {
        0 => format!("{v:e}"),
        1 => format!("{v:.n$e}"),
        2 => format!("{v:.n$}"),
        _ => format!("{v}"),
    });
    // Values near the data's own: a few digits before the dot, up to 14 after.
    let near = (-1e6f64..1e6, -30i32..30, 0usize..15, 0u8..3).prop_map(|(v, p, n, how)| {
        let v = v * 10f64.powi(p);
        match how {
            0 => format!("{v:.n$e}"),
            1 => format!("{v:.n$}"),
            _ => format!("{v:e}"),
        }
    });
    let edge = prop::sample::select(vec![
        "0",
        "-0",
        "0.0",
        "-0.000000000e0",
        "4.9406564584124654e-324",
        "2.2250738585072014e-308",
        "2.2250738585072011e-308",
        "9007199254740991",
        "9007199254740992",
        "9007199254740993",
        "9007199254740994",
        "900719925474099.3",
        "1e22",
        "1e23",
        "1e-22",
        "1e-23",
        "123456789012345.6e7",
        "123456789012345678901234567890",
        "1.7976931348623157e308",
        "-1.7976931348623157e308",
        "1.7976931348623159e308",
        "999999999999999",
        "9999999999999999",
        "0.00000000000001",
        "1.749461098e-2",
        "-9.289446890e-6",
        "99999.99",
        "24.8201",
    ])
    .prop_map(String::from);
    prop_oneof![3 => built, 2 => formatted, 2 => near, 1 => edge]
}

/// What may follow a number in a buffer: nothing, a separator, the rest of a line (so the
/// 16 bytes the fast path reads are there), or a byte that continues or spoils it.
fn after_number() -> impl Strategy<Value = &'static str> {
    prop::sample::select(vec![
        "",
        ",",
        "\n",
        "\r\n",
        " ,",
        ",1.750919261e-2,0.000000000e0,39.934\n",
        "\n0.02,1.753123996e-2,1.830624834e-5\n",
        "                ",
        "x,1.750919261e-2,0.000000000e0\n",
        ".5,1.750919261e-2,0.000000000e0\n",
        "e,1.750919261e-2,0.000000000e0\n",
        "e+,1.750919261e-2,0.000000000e0\n",
        "E-x1.750919261e-2,0.000000000e0\n",
        "e1234,1.750919261e-2,0.000000000e0\n",
        "0000000000000000000000000000000,\n",
    ])
}

/// The old parser, `fast-float2` as it was called before the fast path.
fn old_parse(b: &[u8]) -> Option<(f64, usize)> {
    fast_float2::parse_partial::<f64, _>(b).ok()
}

fn same(a: Option<(f64, usize)>, b: Option<(f64, usize)>) -> bool {
    match (a, b) {
        (Some((x, n)), Some((y, m))) => n == m && (x.to_bits() == y.to_bits() || (x.is_nan() && y.is_nan())),
        (None, None) => true,
        _ => false,
    }
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 20_000, ..ProptestConfig::default() })]

    /// The fast number path: `parse_number` takes what the old parser took, stops
    /// where it stopped, with the same bits, and those are `str::parse`'s for the bytes
    /// taken; a number followed by a separator is `str::parse`'s for its text.
    #[test]
    fn k_number_fast_path_bit_for_bit(text in number_text(), after in after_number()) {
        let buf = format!("{text}{after}");
        let got = ssis_session::parse_number(buf.as_bytes());
        prop_assert!(same(got, old_parse(buf.as_bytes())), "{buf:?}: new {got:?}, old {:?}", old_parse(buf.as_bytes()));
        if let Some((x, used)) = got {
            let std = buf[..used].parse::<f64>();
            prop_assert!(matches!(std, Ok(y) if y.to_bits() == x.to_bits() || (x.is_nan() && y.is_nan())), "{buf:?}: {x:e} vs std {std:?}");
        }
        if matches!(after.as_bytes().first(), None | Some(b',' | b'\n' | b'\r' | b' ')) {
            let want = text.parse::<f64>().ok().map(|v| (v, text.len()));
            prop_assert!(same(got, want), "{buf:?}: new {got:?}, std {want:?}");
        }
    }
}

/// The fast number path: what the old parser refused it refuses, and where it
/// stopped early it stops, with or without the bytes of a line after the field.
#[test]
fn k_number_fast_path_refusals() {
    let texts = [
        "",
        ".",
        "-",
        "+",
        "--1",
        "+-1",
        "-+1",
        "e5",
        "E5",
        ".e5",
        "-.e5",
        "1.2.3",
        "1..2",
        "1e",
        "1E",
        "1e+",
        "1e-",
        "1e--5",
        "1.e",
        "nan",
        "NaN",
        "-nan",
        "inf",
        "-inf",
        "+infinity",
        "infinity",
        "0x10",
        "1_000",
        " 1",
        "\t1",
        "1 ",
        "1,5",
        "١",
        "1e1000",
        "1e-1000",
        "1e99999999999999999999",
        "-0e-5000",
        "12345678901234567.5",
        "1234567890123456",
        "0.000000000000000000000000000001",
        "00000000000000000000000000001e-3",
    ];
    for t in texts {
        for after in
            ["", ",", "\n", ",1.750919261e-2,0.000000000e0,39.934\n", "x                 ", "e+x              "]
        {
            let buf = format!("{t}{after}");
            let got = ssis_session::parse_number(buf.as_bytes());
            assert!(same(got, old_parse(buf.as_bytes())), "{buf:?}: new {got:?}, old {:?}", old_parse(buf.as_bytes()));
        }
    }
}
