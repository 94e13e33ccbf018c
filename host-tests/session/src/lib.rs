//! Session files: CSV with a header naming each column and its unit (`docs/SESSION-FORMAT.md`).
//!
//! [`RowReader`] streams the file line by line, through a memory map of a regular file or a
//! fixed buffer for anything else (never read whole into memory), and parses each number in
//! place ([`parse_number`]: correctly rounded, so every value is the one `str::parse::<f64>`
//! gives). [`Converter`] turns a row into a sample's flat record, read through
//! [`SampleRef`] (rates from increments, the reference rate from the turntable geometry). The model lab's passes over a
//! session (`ssis_lab::stream`) read it this way; [`read_session`] keeps it in memory as `f64` columns
//! for the tools that want every row (replay, tests). Every refusal names the file, the line
//! and, where there is one, the column (1-based, with its header name).

use std::io::Read;
use std::path::Path;

use indicatif::ProgressBar;
use ssis::calib::{Misalignment, GAMMA_NOMINAL_RAD};

/// Earth rotation rate, rad/s (15.041068 °/h, the paper's ω_E).
pub const EARTH_RATE_RAD_S: f64 = 15.041_068 / 3600.0 * std::f64::consts::PI / 180.0;

/// What went wrong with a session file.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SessionErrorKind {
    /// The file cannot be opened or read.
    Io,
    /// The file has no header line.
    Empty,
    /// The header has no data rows after it.
    NoRows,
    /// A column name with a unit the lab does not accept.
    Units,
    /// A column the session needs is absent.
    MissingColumn,
    /// A column name given twice, or a malformed name.
    BadHeader,
    /// A value that is not a number (or not finite).
    BadNumber,
    /// A line with fewer or more fields than the header.
    FieldCount,
    /// A value that is a number but not acceptable (time not increasing).
    BadValue,
    /// A number outside its physical range (a rate beyond the FOG's measuring range, a
    /// temperature outside −100…+150 °C, an absurd magnitude).
    OutOfRange,
    /// The last line has no line end: the file may have been cut while it was written.
    Truncated,
    /// Not UTF-8 text (a UTF-16 byte-order mark).
    Encoding,
}

/// The FOG's measuring range, rad/s: ±100 °/s, that of the launch-vehicle unit, the larger
/// of the two units' (`ssis::flight::Profile`). A session's FOG rates (or increments over
/// their interval) and reference rates beyond it are refused.
pub const MEASURING_RANGE_RAD_S: f64 = 100.0 * std::f64::consts::PI / 180.0;

/// The temperatures a session may hold, °C (a FOG or chamber outside is a wrong column or
/// unit: kelvin, a sensor fault code).
pub const TEMPERATURE_RANGE_DEGC: (f64, f64) = (-100.0, 150.0);

/// Largest magnitude of any value of any column: beyond it a number is a corrupted field
/// (`1e300`), whatever the column's unit.
pub const ABSURD_MAGNITUDE: f64 = 1e12;

/// `v` as a person reads it: plain between 10⁻⁴ and 10⁷ (four decimals at most), else with
/// an exponent (`1e300`).
fn readable(v: f64) -> String {
    if v == 0.0 || (1e-4..1e7).contains(&v.abs()) {
        let s = format!("{v:.4}");
        s.trim_end_matches('0').trim_end_matches('.').to_string()
    } else {
        format!("{v:e}")
    }
}

/// The physical range of a column of `role`, in its unit, and the words that say why.
pub fn physical_range(role: Role) -> ((f64, f64), &'static str) {
    let r = MEASURING_RANGE_RAD_S;
    match role {
        Role::FogRate(_) => ((-r, r), "the FOG's measuring range, ±100 °/s"),
        Role::TableRate | Role::Reference(_) => ((-r, r), "the FOG's measuring range, ±100 °/s (a reference rate)"),
        Role::FogTemp(_) => (TEMPERATURE_RANGE_DEGC, "−100 … +150 °C"),
        Role::Lat => {
            let h = std::f64::consts::FRAC_PI_2;
            ((-h, h), "±π/2 rad (a latitude in degrees?)")
        }
        Role::Field(_) => ((-1e7, 1e7), "±10⁷ nT (10 mT; the Earth's field is about 5·10⁴ nT)"),
        _ => ((-ABSURD_MAGNITUDE, ABSURD_MAGNITUDE), "±10¹² in any unit"),
    }
}

/// A refused session: file, line, column and what is wrong.
#[derive(Debug, Clone, thiserror::Error)]
#[error("{file}{}{}: {message}", line_text(*.line), column_text(.column))]
pub struct SessionError {
    /// What went wrong.
    pub kind: SessionErrorKind,
    /// The file as given.
    pub file: String,
    /// 1-based line number (1 = the header); 0 when the file could not be opened or read
    /// as a whole (then the message names no line).
    pub line: u64,
    /// 1-based column number and header name, when one column is at fault.
    pub column: Option<(usize, String)>,
    /// Plain words.
    pub message: String,
}

fn line_text(line: u64) -> String {
    if line == 0 {
        String::new()
    } else {
        format!(": line {line}")
    }
}

fn column_text(c: &Option<(usize, String)>) -> String {
    match c {
        Some((k, name)) => format!(", column {k} (`{name}`)"),
        None => String::new(),
    }
}

/// The role of one column, from its header name.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Role {
    /// `t_s`: sample time, s (the end of the sample interval).
    Time,
    /// `fogN_rad_s`: raw rate of FOG N, rad/s (mean over the sample interval).
    FogRate(usize),
    /// `fogN_rad`: raw angle increment of FOG N over the sample interval, rad.
    FogIncrement(usize),
    /// `fogN_t_degc`: temperature of FOG N, °C.
    FogTemp(usize),
    /// `table_rate_rad_s`: turntable rate about its axis (= ICS Z_P, vertical), rad/s.
    TableRate,
    /// `psi_rad`: azimuth of X_P from north (clockwise), rad.
    Psi,
    /// `lat_rad`: latitude, rad.
    Lat,
    /// `ref_x_rad_s` … : reference angular rate of the ICS in ICS components, rad/s.
    Reference(usize),
    /// `b_x_nt` …: magnetic induction in ICS components, nT.
    Field(usize),
    /// Any other column: kept for expressions and correlation checks.
    Extra,
}

/// Unit suffixes recognised as units (so `psi_deg` is refused, not taken as a user column).
const OTHER_UNITS: [&str; 22] = [
    "s", "ms", "us", "min", "h", "rad", "mrad", "deg", "arcsec", "rad_s", "deg_s", "deg_h", "rpm", "nt", "ut", "mt",
    "t", "gauss", "g", "degc", "k", "degf",
];

/// Classifies a header name; `Err` says why the name (its unit) is refused.
pub fn classify(name: &str) -> Result<Role, (SessionErrorKind, String)> {
    let units = |what: &str| Err((SessionErrorKind::Units, what.to_string()));
    if name == "t_s" {
        return Ok(Role::Time);
    }
    if let Some(rest) = name.strip_prefix("fog") {
        let digits: String = rest.chars().take_while(|c| c.is_ascii_digit()).collect();
        if let Ok(i) = digits.parse::<usize>() {
            return match &rest[digits.len()..] {
                "_rad_s" => Ok(Role::FogRate(i)),
                "_rad" => Ok(Role::FogIncrement(i)),
                "_t_degc" => Ok(Role::FogTemp(i)),
                _ => {
                    units("a FOG column is `fogN_rad_s` (rate), `fogN_rad` (increment) or `fogN_t_degc` (temperature)")
                }
            };
        }
    }
    let fixed: [(&str, &str, Role); 10] = [
        ("t", "_s", Role::Time),
        ("table_rate", "_rad_s", Role::TableRate),
        ("psi", "_rad", Role::Psi),
        ("lat", "_rad", Role::Lat),
        ("ref_x", "_rad_s", Role::Reference(0)),
        ("ref_y", "_rad_s", Role::Reference(1)),
        ("ref_z", "_rad_s", Role::Reference(2)),
        ("b_x", "_nt", Role::Field(0)),
        ("b_y", "_nt", Role::Field(1)),
        ("b_z", "_nt", Role::Field(2)),
    ];
    for (stem, unit, role) in fixed {
        if name == format!("{stem}{unit}") {
            return Ok(role);
        }
        // A reserved quantity in another unit is refused rather than taken as a user column.
        if let Some(u) = name.strip_prefix(stem).and_then(|r| r.strip_prefix('_')) {
            if OTHER_UNITS.contains(&u) {
                return units(&format!("`{stem}` is given in `{stem}{unit}`, not `{name}`"));
            }
        }
    }
    let ok_ident = name.chars().next().is_some_and(|c| c.is_ascii_lowercase() || c == '_')
        && name.chars().all(|c| c.is_ascii_lowercase() || c.is_ascii_digit() || c == '_');
    if !ok_ident {
        return Err((
            SessionErrorKind::BadHeader,
            "a user column name is lower-case letters, digits and `_` (it is a variable in expressions)".into(),
        ));
    }
    Ok(Role::Extra)
}

/// One FOG's data.
#[derive(Debug, Clone)]
pub struct FogData {
    /// Raw rate, rad/s (from `fogN_rad_s`, or `fogN_rad` divided by the sample interval).
    pub rate_rad_s: Vec<f64>,
    /// Temperature, °C, when the session has it.
    pub t_degc: Option<Vec<f64>>,
}

/// A session in memory: every column, and the quantities the model needs.
#[derive(Debug, Clone)]
pub struct Session {
    /// The file name as given (for messages).
    pub file: String,
    /// Header names, in file order.
    pub names: Vec<String>,
    /// Column data, in file order (after dropping the first row of an increment session).
    pub cols: Vec<Vec<f64>>,
    /// Role of each column.
    pub roles: Vec<Role>,
    /// Per FOG, index = FOG number.
    pub fogs: Vec<FogData>,
    /// Reference angular rate of the ICS, ICS components, rad/s.
    pub ref_rad_s: Vec<[f64; 3]>,
    /// Magnetic induction, ICS components, nT.
    pub field_nt: Option<Vec<[f64; 3]>>,
    /// The file line of each sample (header = 1; comment lines and a dropped first row of
    /// an increment session counted), for messages about a sample.
    pub lines: Vec<u64>,
}

impl Session {
    /// Number of samples.
    pub fn len(&self) -> usize {
        self.t_s().len()
    }

    /// True when there are no samples.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Sample times, s.
    pub fn t_s(&self) -> &[f64] {
        self.column("t_s").unwrap_or(&[])
    }

    /// A column by header name.
    pub fn column(&self, name: &str) -> Option<&[f64]> {
        let k = self.names.iter().position(|n| n == name)?;
        Some(&self.cols[k])
    }

    /// Names of user (extra) columns.
    pub fn extra_columns(&self) -> Vec<&str> {
        self.names.iter().zip(&self.roles).filter(|(_, r)| **r == Role::Extra).map(|(n, _)| n.as_str()).collect()
    }

    /// The session's sample interval, s ([`median_interval_s`]).
    pub fn median_dt_s(&self) -> f64 {
        median_interval_s(self.t_s())
    }
}

/// Intervals [`median_interval_s`] looks at.
pub const INTERVALS_FOR_MEDIAN: usize = 1000;

/// The sample interval of a session: the median of its first [`INTERVALS_FOR_MEDIAN`] sample
/// intervals, s (1 s with fewer than two samples). Known after the first rows, so a pass over
/// a file can use it before it ends.
pub fn median_interval_s(t_s: &[f64]) -> f64 {
    let n = t_s.len().min(INTERVALS_FOR_MEDIAN + 1);
    let mut d: Vec<f64> = t_s[..n].windows(2).map(|w| w[1] - w[0]).collect();
    if d.is_empty() {
        return 1.0;
    }
    d.sort_by(f64::total_cmp);
    d[d.len() / 2]
}

/// Nominal sensitive axes s_i of the unit (misalignment zero, γ nominal), ICS.
pub fn nominal_axes() -> [nalgebra::Vector3<f64>; 4] {
    Misalignment::default().axes(GAMMA_NOMINAL_RAD)
}

/// Earth rate in ICS for the turntable geometry of `docs/SESSION-FORMAT.md`: Z_P up,
/// X_P at azimuth ψ (from north, clockwise), so ω = (Ω_N cos ψ, Ω_N sin ψ, Ω_U), with
/// Ω_N = ω_E cos φ, Ω_U = ω_E sin φ (the paper's reference ω* = ω_E sin φ for a vertical SA).
pub fn earth_rate_ics(psi_rad: f64, lat_rad: f64) -> [f64; 3] {
    let (n, u) = (EARTH_RATE_RAD_S * lat_rad.cos(), EARTH_RATE_RAD_S * lat_rad.sin());
    [n * psi_rad.cos(), n * psi_rad.sin(), u]
}

/// The Earth's field in ICS for the turntable geometry of `docs/SESSION-FORMAT.md` (the frame
/// of [`earth_rate_ics`]: Z_P up, X_P at azimuth ψ from north, clockwise), from its local
/// components (north, west, up), nT: X_P = (cos ψ, −sin ψ, 0) and Y_P = (sin ψ, cos ψ, 0) in
/// (north, west, up), so
///
/// ```text
/// B = (B_N cos ψ − B_W sin ψ,  B_N sin ψ + B_W cos ψ,  B_U)
/// ```
///
/// The paper's B_Π matrix (eq. 3) is this with its azimuth counted counter-clockwise,
/// ψ_Π = −ψ. At ψ = 90° the paper's Kharkov field (21846, 5959, −42343) gives
/// (−5959, 21846, −42343).
pub fn field_ics_nt(b_nwu_nt: [f64; 3], psi_rad: f64) -> [f64; 3] {
    let (s, c) = psi_rad.sin_cos();
    [b_nwu_nt[0] * c - b_nwu_nt[1] * s, b_nwu_nt[0] * s + b_nwu_nt[1] * c, b_nwu_nt[2]]
}

/// The paper's test site, Kharkov: latitude φ = 50°03′ and longitude λ = 36°17′ (degrees),
/// height 150 m.
pub const KHARKOV_SITE: Site = Site { lat_deg: 50.0 + 3.0 / 60.0, lon_deg: 36.0 + 17.0 / 60.0, height_m: 150.0 };

/// The date the simulators take for the field: 2025, day 1 (WMM2025's epoch).
pub const FIELD_EPOCH: (i32, u16) = (2025, 1);

/// The paper's dipole-tilt field at Kharkov, (north, west, up), nT: its worked example
/// (21 846, 5 959, −42 343), as `ssis_methods::magnetic::DipoleTilt::PAPER` computes it.
pub const PAPER_DIPOLE_KHARKOV_NWU_NT: [f64; 3] = [21846.305885789792, 5958.978155627933, -42342.86237302601];

/// A place on the Earth (WGS 84).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Site {
    /// Latitude, degrees north.
    pub lat_deg: f64,
    /// Longitude, degrees east.
    pub lon_deg: f64,
    /// Height above the ellipsoid, m.
    pub height_m: f64,
}

/// Which Earth field a magnetic session is simulated with, or calibrated against.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum FieldModel {
    /// The World Magnetic Model 2025 at the site and date (the real main field; the default).
    #[default]
    Wmm2025,
    /// The paper's dipole tilt (its worked example, Kharkov only): 2.5–9 µT off the real field.
    PaperDipole,
}

impl FieldModel {
    /// The field at `site` on `date` (year, day of the year), (north, west, up), nT. The
    /// paper's dipole is only given at Kharkov: another site is refused.
    pub fn nwu_nt(self, site: Site, date: (i32, u16)) -> Result<[f64; 3], String> {
        match self {
            FieldModel::Wmm2025 => wmm_field_nwu_nt(site, date),
            FieldModel::PaperDipole if site == KHARKOV_SITE => Ok(PAPER_DIPOLE_KHARKOV_NWU_NT),
            FieldModel::PaperDipole => Err(format!(
                "the paper's dipole field is given for Kharkov only ({:.4}°, {:.4}°), not {:.4}°, {:.4}°",
                KHARKOV_SITE.lat_deg, KHARKOV_SITE.lon_deg, site.lat_deg, site.lon_deg
            )),
        }
    }

    /// Its name in messages and on the command line.
    pub fn name(self) -> &'static str {
        match self {
            FieldModel::Wmm2025 => "WMM2025",
            FieldModel::PaperDipole => "the paper's dipole tilt",
        }
    }
}

/// The Earth's main field at `site` on `date` (year, day of the year) from the World
/// Magnetic Model 2025 (the `world_magnetic_model` crate), (north, west, up), nT.
pub fn wmm_field_nwu_nt(site: Site, date: (i32, u16)) -> Result<[f64; 3], String> {
    use world_magnetic_model::time::Date;
    use world_magnetic_model::uom::si::angle::degree;
    use world_magnetic_model::uom::si::f32::{Angle, Length};
    use world_magnetic_model::uom::si::length::meter;
    use world_magnetic_model::uom::si::magnetic_flux_density::nanotesla;
    use world_magnetic_model::GeomagneticField;
    let (year, day) = date;
    let d = Date::from_ordinal_date(year, day).map_err(|e| format!("date {year}-{day:03}: {e}"))?;
    let f = GeomagneticField::new(
        Length::new::<meter>(site.height_m as f32),
        Angle::new::<degree>(site.lat_deg as f32),
        Angle::new::<degree>(site.lon_deg as f32),
        d,
    )
    .map_err(|e| format!("WMM at {}°, {}°, {} m, {year}-{day:03}: {e}", site.lat_deg, site.lon_deg, site.height_m))?;
    // WMM gives X north, Y east, Z down.
    let (x, y, z) = (f.x().get::<nanotesla>() as f64, f.y().get::<nanotesla>() as f64, f.z().get::<nanotesla>() as f64);
    Ok([x, -y, -z])
}

/// The inverse of [`field_ics_nt`]: (north, west, up) components from the ICS ones at ψ.
pub fn field_nwu_nt(b_ics_nt: [f64; 3], psi_rad: f64) -> [f64; 3] {
    let (s, c) = psi_rad.sin_cos();
    [b_ics_nt[0] * c + b_ics_nt[1] * s, -b_ics_nt[0] * s + b_ics_nt[1] * c, b_ics_nt[2]]
}

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
fn parse_number_general(b: &[u8]) -> Option<(f64, usize)> {
    fast_float2::parse_partial::<f64, _>(b).ok()
}

/// [`parse_number`] where the CPU has SSSE3.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "ssse3")]
#[inline]
fn parse_number_ssse3(b: &[u8]) -> Option<(f64, usize)> {
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
    /// the line loop of one, [`super::parse_next_line_ssse3`].)
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

/// The columns of a session by role, from its header.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Layout {
    /// Number of FOGs.
    pub n_fog: usize,
    /// Column of `t_s`.
    pub t: usize,
    /// Column of each FOG's output and whether it is an increment (`fogN_rad`).
    pub fog: Vec<(usize, bool)>,
    /// Column of each FOG's temperature.
    pub fog_temp: Vec<Option<usize>>,
    /// Columns of `ref_x_rad_s`, `ref_y_rad_s`, `ref_z_rad_s` (form 1).
    pub reference: Option<[usize; 3]>,
    /// Columns of `psi_rad`, `lat_rad` (form 2).
    pub turntable: Option<[usize; 2]>,
    /// Column of `table_rate_rad_s`.
    pub table_rate: Option<usize>,
    /// Columns of `b_x_nt`, `b_y_nt`, `b_z_nt`.
    pub field: Option<[usize; 3]>,
}

impl Layout {
    /// Whether the FOG outputs are increments (the first row is then dropped).
    pub fn increments(&self) -> bool {
        self.fog.iter().any(|f| f.1)
    }
}

/// A session's header: names, roles and the column layout.
#[derive(Debug, Clone)]
pub struct Header {
    /// The file name as given.
    pub file: String,
    /// Column names in file order.
    pub names: Vec<String>,
    /// Role of each column.
    pub roles: Vec<Role>,
    /// Columns by role.
    pub layout: Layout,
    /// Line of the header (after comments), 1-based.
    pub line: u64,
}

impl Header {
    fn empty(file: &str) -> Header {
        Header { file: file.to_string(), names: Vec::new(), roles: Vec::new(), layout: Layout::default(), line: 0 }
    }

    fn err(
        &self,
        kind: SessionErrorKind,
        line: u64,
        column: Option<usize>,
        message: impl Into<String>,
    ) -> SessionError {
        SessionError {
            kind,
            file: self.file.clone(),
            line,
            column: column.map(|k| (k + 1, self.names.get(k).cloned().unwrap_or_default())),
            message: message.into(),
        }
    }

    /// Checks one row's values against their columns' physical ranges ([`physical_range`];
    /// a FOG increment as the rate over its interval since `prev_t`, if there is one): the
    /// first value outside, as kind, 0-based column and message.
    pub fn check_values(&self, row: &[f64], prev_t: Option<f64>) -> Option<(SessionErrorKind, usize, String)> {
        for (k, (&v, &role)) in row.iter().zip(&self.roles).enumerate() {
            let (v, role, per) = match (role, prev_t) {
                (Role::FogIncrement(i), Some(p)) => {
                    (v / (row[self.layout.t] - p), Role::FogRate(i), " over its interval")
                }
                (Role::FogIncrement(_), None) => (v, Role::Extra, ""),
                _ => (v, role, ""),
            };
            let ((lo, hi), why) = physical_range(role);
            if !(lo..=hi).contains(&v) {
                let deg = if matches!(role, Role::FogRate(_) | Role::TableRate | Role::Reference(_)) {
                    format!(" ({} °/s)", readable(v.to_degrees()))
                } else {
                    String::new()
                };
                return Some((
                    SessionErrorKind::OutOfRange,
                    k,
                    format!("`{}`{per}{deg} is outside {why}", readable(row[k])),
                ));
            }
        }
        None
    }

    /// A header of any numeric CSV with a `t_s` column and the `required` ones (every column
    /// a user column; for logs that are not sessions, `ssis_lab::framelog`).
    pub fn plain(file: &str, names: Vec<String>, line: u64, required: &[&str]) -> Result<Header, SessionError> {
        let mut h = Header::empty(file);
        h.line = line;
        h.roles = names.iter().map(|n| if n == "t_s" { Role::Time } else { Role::Extra }).collect();
        h.names = names;
        for r in std::iter::once(&"t_s").chain(required) {
            if !h.names.iter().any(|n| n == r) {
                return Err(h.err(SessionErrorKind::MissingColumn, line, None, format!("missing column `{r}`")));
            }
        }
        h.layout.t = h.names.iter().position(|n| n == "t_s").unwrap_or(0);
        Ok(h)
    }

    /// Classifies and checks the header names (`line` is the header's line number).
    pub fn parse(file: &str, names: Vec<String>, line: u64) -> Result<Header, SessionError> {
        let mut h = Header::empty(file);
        h.line = line;
        for (k, name) in names.into_iter().enumerate() {
            let twice = h.names.contains(&name);
            h.names.push(name);
            if twice {
                return Err(h.err(SessionErrorKind::BadHeader, line, Some(k), "this column name is given twice"));
            }
        }
        for (k, name) in h.names.iter().enumerate() {
            match classify(name) {
                Ok(role) => h.roles.push(role),
                Err((kind, why)) => return Err(h.err(kind, line, Some(k), why)),
            }
        }
        let roles = &h.roles;
        let pos = |role: Role| roles.iter().position(|r| *r == role);
        let missing = |what: &str| h.err(SessionErrorKind::MissingColumn, line, None, what.to_string());
        let Some(t) = pos(Role::Time) else { return Err(missing("missing column `t_s` (sample time, s)")) };
        let n_fog = roles
            .iter()
            .filter_map(|r| match r {
                Role::FogRate(i) | Role::FogIncrement(i) => Some(i + 1),
                _ => None,
            })
            .max()
            .unwrap_or(0);
        if n_fog == 0 {
            return Err(missing("missing column `fog0_rad_s` (or `fog0_rad`): the session has no FOG output"));
        }
        let mut fog = Vec::new();
        for i in 0..n_fog {
            match (pos(Role::FogRate(i)), pos(Role::FogIncrement(i))) {
                (Some(_), Some(k)) => {
                    return Err(h.err(
                        SessionErrorKind::BadHeader,
                        line,
                        Some(k),
                        "FOG given both as rate and increment",
                    ))
                }
                (Some(k), None) => fog.push((k, false)),
                (None, Some(k)) => fog.push((k, true)),
                (None, None) => {
                    return Err(missing(&format!(
                        "missing column `fog{i}_rad_s` (FOGs are numbered from 0 without gaps)"
                    )))
                }
            }
        }
        for (k, role) in roles.iter().enumerate() {
            if let Role::FogTemp(i) = role {
                if *i >= n_fog {
                    return Err(h.err(
                        SessionErrorKind::BadHeader,
                        line,
                        Some(k),
                        "temperature of a FOG with no output",
                    ));
                }
            }
        }
        let three = |f: fn(usize) -> Role| -> Option<Vec<usize>> { (0..3).map(|a| pos(f(a))).collect() };
        let any3 = |f: fn(usize) -> Role| (0..3).any(|a| pos(f(a)).is_some());
        let reference = three(Role::Reference);
        if any3(Role::Reference) && reference.is_none() {
            return Err(missing("the reference rate needs all three of `ref_x_rad_s`, `ref_y_rad_s`, `ref_z_rad_s`"));
        }
        let field = three(Role::Field);
        if any3(Role::Field) && field.is_none() {
            return Err(missing("the magnetic field needs all three of `b_x_nt`, `b_y_nt`, `b_z_nt`"));
        }
        let turntable = pos(Role::Psi).zip(pos(Role::Lat)).map(|(a, b)| [a, b]);
        if reference.is_none() && turntable.is_none() {
            return Err(missing(
                "missing reference: give `ref_x_rad_s`, `ref_y_rad_s`, `ref_z_rad_s`, or `psi_rad` and `lat_rad` \
                 (Earth rate on a turntable, plus `table_rate_rad_s` if it turns)",
            ));
        }
        let arr3 = |v: Vec<usize>| [v[0], v[1], v[2]];
        h.layout = Layout {
            n_fog,
            t,
            fog,
            fog_temp: (0..n_fog).map(|i| pos(Role::FogTemp(i))).collect(),
            reference: reference.map(arr3),
            turntable,
            table_rate: pos(Role::TableRate),
            field: field.map(arr3),
        };
        Ok(h)
    }
}

/// Parses the data line `data[a..b]` into `values` (one per column) the fast way: each field
/// a number [`parse_number`] takes whole and finite, fields separated by `,` with optional
/// spaces. Numbers are read from `data[p..]` (what follows the line lets the digit scan take
/// eight bytes at a time; the line's end stops it). `false` on anything else (then
/// [`check_line`] decides).
fn parse_line(data: &[u8], a: usize, b: usize, values: &mut [f64]) -> bool {
    let ncol = values.len();
    let mut p = a;
    for (k, v) in values.iter_mut().enumerate() {
        while p < b && (data[p] == b' ' || data[p] == b'\t') {
            p += 1;
        }
        let Some((x, used)) = parse_number(&data[p..]) else { return false };
        if used == 0 || !x.is_finite() || p + used > b {
            return false;
        }
        *v = x;
        p += used;
        while p < b && (data[p] == b' ' || data[p] == b'\t' || data[p] == b'\r') {
            p += 1;
        }
        if k + 1 < ncol {
            if p >= b || data[p] != b',' {
                return false;
            }
            p += 1;
        }
    }
    p == b
}

/// [`parse_line`] on the line starting at `data[a]`, found as it is read: the same fields,
/// separators and spaces, and then the line's `\n`. The bytes it took (the `\n` included);
/// `None` when the line is anything else (a comment, a blank line, a line [`parse_line`]
/// refuses) or has no `\n` in `data` (then the careful path finds the line first). A line
/// it takes is one [`parse_line`] takes, with the same values: no number or space runs
/// over a `\n`.
///
/// A field whose bytes repeat the column's [`Repeat`] takes its value from there; with
/// `retry`, a field read in full is stored there.
#[inline]
fn parse_next_line(data: &[u8], a: usize, values: &mut [f64], repeats: &mut [Repeat], retry: bool) -> Option<usize> {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("ssse3") {
        // SAFETY: the CPU has SSSE3 (checked above).
        return unsafe { parse_next_line_ssse3(data, a, values, repeats, retry) };
    }
    next_line_with(data, a, values, repeats, retry, parse_number_general)
}

/// [`parse_next_line`] where the CPU has SSSE3.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "ssse3")]
fn parse_next_line_ssse3(
    data: &[u8],
    a: usize,
    values: &mut [f64],
    repeats: &mut [Repeat],
    retry: bool,
) -> Option<usize> {
    next_line_with(data, a, values, repeats, retry, |b| parse_number_ssse3(b))
}

/// [`parse_next_line`] with `parse` for [`parse_number`].
#[inline(always)]
fn next_line_with(
    data: &[u8],
    a: usize,
    values: &mut [f64],
    repeats: &mut [Repeat],
    retry: bool,
    parse: impl Fn(&[u8]) -> Option<(f64, usize)>,
) -> Option<usize> {
    let ncol = values.len();
    let mut p = a;
    // A comment or a line that starts blank goes the careful way.
    if matches!(data.get(p), None | Some(b'#' | b' ' | b'\t' | b'\r' | b'\n')) {
        return None;
    }
    for (k, (v, rep)) in values.iter_mut().zip(repeats.iter_mut()).enumerate() {
        while let Some(b' ' | b'\t') = data.get(p) {
            p += 1;
        }
        let rest = data.get(p..)?;
        let window: Option<&[u8; REPEAT_WINDOW]> = rest.get(..REPEAT_WINDOW).and_then(|w| w.try_into().ok());
        let (x, used) = match window {
            Some(w) if rep.armed && *w == rep.bytes => (rep.value, rep.used),
            _ => {
                rep.armed = false;
                let (x, used) = parse(rest)?;
                if used == 0 || !x.is_finite() {
                    return None;
                }
                if let (true, Some(w)) = (retry, window) {
                    if used < REPEAT_WINDOW && matches!(w[used], b',' | b'\n' | b'\r' | b' ' | b'\t') {
                        *rep = Repeat { bytes: *w, used, value: x, armed: true };
                    }
                }
                (x, used)
            }
        };
        *v = x;
        p += used;
        while let Some(b' ' | b'\t' | b'\r') = data.get(p) {
            p += 1;
        }
        if k + 1 < ncol {
            if data.get(p) != Some(&b',') {
                return None;
            }
            p += 1;
        }
    }
    (data.get(p) == Some(&b'\n')).then_some(p + 1 - a)
}

/// Bytes of a field a [`Repeat`] compares.
const REPEAT_WINDOW: usize = 16;

/// Rows between two tries of the columns whose value changed ([`Repeat`]).
const REPEAT_RETRY: u64 = 64;

/// Per column, the bytes of a value read in full and that value, to take a field that
/// repeats them without parsing it again (a constant column: the reference rate on a dwell,
/// a turntable's azimuth and latitude). A field is taken from it only when its first
/// [`REPEAT_WINDOW`] bytes equal the stored ones, and these held the whole number and the
/// byte after it, a separator (`,` `\n` `\r` space tab: none can be inside a number): the
/// number is then the same bytes, so it has the same value and length. Compared while the
/// column repeats; after a change, stored again every [`REPEAT_RETRY`] rows.
#[derive(Debug, Clone, Default)]
struct Repeat {
    bytes: [u8; REPEAT_WINDOW],
    used: usize,
    value: f64,
    armed: bool,
}

/// The careful reading of a data line: fields split at `,` and trimmed, the field count
/// checked first, then each value. Fills `values` and returns `None` when the line is good,
/// else what is wrong: kind, 0-based column, message.
fn check_line(line: &[u8], values: &mut [f64]) -> Option<(SessionErrorKind, usize, String)> {
    let ncol = values.len();
    let mut k = 0;
    let mut bad: Option<(usize, String)> = None;
    for field in line.split(|&c| c == b',') {
        if k < ncol && bad.is_none() {
            let f = trim(field);
            match parse_number(f) {
                Some((v, used)) if used == f.len() && v.is_finite() => values[k] = v,
                Some((_, used)) if used == f.len() => {
                    bad = Some((k, format!("`{}` is not a finite number", String::from_utf8_lossy(f))))
                }
                _ if f.is_empty() => bad = Some((k, "empty value, expected a number".into())),
                _ => bad = Some((k, format!("`{}` is not a number", String::from_utf8_lossy(f)))),
            }
        }
        k += 1;
    }
    if k != ncol {
        return Some(if k < ncol {
            (
                SessionErrorKind::FieldCount,
                k,
                format!("value missing: the line has {k} fields, the header {ncol} (truncated line?)"),
            )
        } else {
            (SessionErrorKind::FieldCount, ncol - 1, format!("the line has {k} fields, the header only {ncol}"))
        });
    }
    bad.map(|(col, msg)| (SessionErrorKind::BadNumber, col, msg))
}

/// Bytes read from the file at a time.
const READ_CHUNK: usize = 1 << 20;

/// Streams the data rows of a session file: each row's values in file column order, checked
/// (field count, numbers, finite, time increasing). At the end of the file it refuses a
/// session with too few rows.
pub struct RowReader {
    header: Header,
    file: std::fs::File,
    buf: Buf,
    start: usize,
    end: usize,
    eof: bool,
    line: u64,
    values: Vec<f64>,
    repeats: Vec<Repeat>,
    last_t: f64,
    rows: u64,
    bytes: u64,
    /// The last line [`RowReader::next_line`] returned ended the file without a `\n`.
    unterminated: bool,
}

/// The bytes a [`RowReader`] reads from: the whole file mapped ([`map_file`]), or read
/// into a buffer a chunk at a time (what cannot be mapped: a pipe, an empty file).
enum Buf {
    Read(Vec<u8>),
    Mapped(memmap2::Mmap),
}

impl std::ops::Deref for Buf {
    type Target = [u8];
    fn deref(&self) -> &[u8] {
        match self {
            Buf::Read(v) => v,
            Buf::Mapped(m) => m,
        }
    }
}

/// A regular, non-empty file mapped into memory, read ahead as the pages are reached (no
/// copy out of the page cache); `None` when it cannot be (then it is read). A file that
/// another program truncates while it is mapped ends the process on a `SIGBUS` at the first
/// page past its new end: a program that reads sessions calls
/// [`exit_plainly_on_truncated_map`] at its start, so that this ends in a plain message and
/// status 74. A file appended to while it is read is safe (the map ends at the length it
/// had; the pass's count of rows then differs and says so).
fn map_file(file: &std::fs::File) -> Option<memmap2::Mmap> {
    let meta = file.metadata().ok()?;
    if !meta.is_file() || meta.len() == 0 {
        return None;
    }
    // SAFETY: the map is only read; a file truncated under it raises SIGBUS (see above).
    let m = unsafe { memmap2::MmapOptions::new().map(file) }.ok()?;
    let _ = m.advise(memmap2::Advice::Sequential);
    Some(m)
}

/// Installs the process's `SIGBUS` handler for session files mapped by [`RowReader`]: a
/// file truncated by another program while it is read then stops the process with a plain
/// message on stderr and status 74 instead of a crash. For a program's `main` (a signal
/// handler is the whole process's): the lab's outputs are all written to a temporary file
/// and renamed, so none is left half written. Calling it again does nothing.
pub fn exit_plainly_on_truncated_map() {
    static SIGBUS: std::sync::Once = std::sync::Once::new();
    SIGBUS.call_once(|| {
        // SAFETY: a handler that calls only async-signal-safe functions (write, _exit),
        // installed once with a zeroed, then emptied, signal mask.
        unsafe {
            let mut sa: libc::sigaction = std::mem::zeroed();
            sa.sa_sigaction = on_sigbus as extern "C" fn(libc::c_int) as usize;
            libc::sigemptyset(&mut sa.sa_mask);
            libc::sigaction(libc::SIGBUS, &sa, std::ptr::null_mut());
        }
    });
}

/// `SIGBUS` while a mapped session file is read: it was truncated by another program.
extern "C" fn on_sigbus(_: libc::c_int) {
    const MSG: &[u8] = b"error: a session file was truncated by another program while it was being read \
(SIGBUS on its memory map); no output was written in part. Read it again once it is complete.\n";
    // SAFETY: write(2) and _exit(2) are async-signal-safe.
    unsafe {
        libc::write(2, MSG.as_ptr().cast(), MSG.len());
        libc::_exit(74);
    }
}

/// A line of a file: whether it is blank or a comment (skipped everywhere).
fn skipped_line(line: &[u8]) -> bool {
    line.first() == Some(&b'#') || line.iter().all(|c| c.is_ascii_whitespace())
}

fn trim(mut b: &[u8]) -> &[u8] {
    while let [first, rest @ ..] = b {
        if *first == b' ' || *first == b'\t' {
            b = rest;
        } else {
            break;
        }
    }
    while let [rest @ .., last] = b {
        if *last == b' ' || *last == b'\t' || *last == b'\r' {
            b = rest;
        } else {
            break;
        }
    }
    b
}

impl RowReader {
    /// Opens a session file and reads its header (comment lines before it are skipped).
    pub fn open(path: &Path) -> Result<RowReader, SessionError> {
        Self::open_with(path, Header::parse)
    }

    /// Opens any numeric CSV whose header `make` accepts (file, names, line).
    pub fn open_with(
        path: &Path,
        make: impl FnOnce(&str, Vec<String>, u64) -> Result<Header, SessionError>,
    ) -> Result<RowReader, SessionError> {
        let file_name = path.display().to_string();
        let io = |e: &dyn std::fmt::Display| SessionError {
            kind: SessionErrorKind::Io,
            file: file_name.clone(),
            line: 0,
            column: None,
            message: format!("cannot read: {e}"),
        };
        let file = std::fs::File::open(path).map_err(|e| io(&e))?;
        let mapped = map_file(&file);
        let (buf, end, eof) = match mapped {
            Some(m) => {
                let n = m.len();
                (Buf::Mapped(m), n, true)
            }
            None => (Buf::Read(vec![0; READ_CHUNK]), 0, false),
        };
        let mut r = RowReader {
            header: Header::empty(&file_name),
            file,
            buf,
            start: 0,
            end,
            eof,
            line: 0,
            values: Vec::new(),
            repeats: Vec::new(),
            last_t: f64::NEG_INFINITY,
            rows: 0,
            bytes: 0,
            unterminated: false,
        };
        let names = loop {
            let Some((a, b)) = r.next_line().map_err(|e| io(&e))? else {
                return Err(SessionError {
                    kind: SessionErrorKind::Empty,
                    file: file_name,
                    line: 1,
                    column: None,
                    message: "the file is empty: expected a header line naming the columns".into(),
                });
            };
            let mut line = &r.buf[a..b];
            if r.line == 1 {
                if line.starts_with(&[0xFF, 0xFE]) || line.starts_with(&[0xFE, 0xFF]) {
                    return Err(SessionError {
                        kind: SessionErrorKind::Encoding,
                        file: file_name,
                        line: 1,
                        column: None,
                        message: "the file is UTF-16 text (byte-order mark FF FE or FE FF): save it as UTF-8".into(),
                    });
                }
                // A UTF-8 byte-order mark (spreadsheets write one) is not part of the first name.
                line = line.strip_prefix(&[0xEF, 0xBB, 0xBF]).unwrap_or(line);
            }
            if !skipped_line(line) {
                break line.split(|&c| c == b',').map(|f| String::from_utf8_lossy(trim(f)).to_string()).collect();
            }
        };
        r.header = make(&file_name, names, r.line)?;
        r.values = vec![0.0; r.header.names.len()];
        r.repeats = vec![Repeat::default(); r.header.names.len()];
        Ok(r)
    }

    /// The header.
    pub fn header(&self) -> &Header {
        &self.header
    }

    /// Line number of the last line returned, 1-based.
    pub fn line(&self) -> u64 {
        self.line
    }

    /// Bytes of the file consumed so far.
    pub fn bytes(&self) -> u64 {
        self.bytes
    }

    /// The next line without its `\n`, as a range of the buffer (which grows for a line
    /// longer than it).
    fn next_line(&mut self) -> std::io::Result<Option<(usize, usize)>> {
        loop {
            if let Some(k) = memchr::memchr(b'\n', &self.buf[self.start..self.end]) {
                let (a, b) = (self.start, self.start + k);
                self.start = b + 1;
                self.line += 1;
                self.bytes += (k + 1) as u64;
                return Ok(Some((a, b)));
            }
            if self.eof {
                if self.start < self.end {
                    self.unterminated = true;
                    let (a, b) = (self.start, self.end);
                    self.start = self.end;
                    self.line += 1;
                    self.bytes += (b - a) as u64;
                    return Ok(Some((a, b)));
                }
                return Ok(None);
            }
            self.refill()?;
        }
    }

    /// Moves the unread bytes to the front of the buffer (growing it when they fill it) and
    /// reads more behind them; at the end of the file sets `eof`.
    fn refill(&mut self) -> std::io::Result<()> {
        let Buf::Read(buf) = &mut self.buf else {
            self.eof = true;
            return Ok(());
        };
        buf.copy_within(self.start..self.end, 0);
        self.end -= self.start;
        self.start = 0;
        if self.end == buf.len() {
            buf.resize(buf.len() * 2, 0);
        }
        let k = self.file.read(&mut buf[self.end..])?;
        if k == 0 {
            self.eof = true;
        }
        self.end += k;
        Ok(())
    }

    /// Counts the data lines left (not read as rows: unchecked) and returns the last of them.
    fn count_rest(&mut self) -> std::io::Result<(usize, Vec<u8>)> {
        let (mut count, mut last) = (0usize, Vec::new());
        loop {
            let data = &self.buf[self.start..self.end];
            // Whole lines only (all of what is left at the end of the file).
            let upto = match memchr::memrchr(b'\n', data) {
                Some(k) => k + 1,
                None if self.eof => data.len(),
                None => 0,
            };
            let region = &data[..upto];
            if !region.is_empty() {
                let mut line_start = 0;
                let mut last_data: Option<(usize, usize)> = None;
                let mut take = |a: usize, b: usize| {
                    let line = &region[a..b];
                    // A line is skipped only if it starts with '#' or white space (checked whole).
                    let first = line.first().copied().unwrap_or(b'\n');
                    if !(first == b'#' || first.is_ascii_whitespace()) || !skipped_line(line) {
                        count += 1;
                        last_data = Some((a, b));
                    }
                };
                let mut lines = 0u64;
                for p in memchr::memchr_iter(b'\n', region) {
                    take(line_start, p);
                    line_start = p + 1;
                    lines += 1;
                }
                if line_start < region.len() {
                    take(line_start, region.len());
                }
                if let Some((a, b)) = last_data {
                    last.clear();
                    last.extend_from_slice(&region[a..b]);
                }
                self.line += lines;
                self.bytes += region.len() as u64;
                self.start += upto;
            }
            if self.eof && self.start >= self.end {
                return Ok((count, last));
            }
            self.refill()?;
        }
    }

    /// The next data row (values in file column order), or `None` after the last.
    pub fn next_row(&mut self) -> Result<Option<&[f64]>, SessionError> {
        let t_col = self.header.layout.t;
        loop {
            // The common line first: read in one go up to its `\n`, with no search for the
            // line's end before.
            if let Some(len) = parse_next_line(
                &self.buf[..self.end],
                self.start,
                &mut self.values,
                &mut self.repeats,
                self.rows.is_multiple_of(REPEAT_RETRY),
            ) {
                self.start += len;
                self.line += 1;
                self.bytes += len as u64;
            } else {
                let (a, b) = match self.next_line() {
                    Ok(Some(l)) => l,
                    Ok(None) => break,
                    Err(e) => {
                        return Err(self.header.err(SessionErrorKind::Io, self.line, None, format!("cannot read: {e}")))
                    }
                };
                let line = &self.buf[a..b];
                if skipped_line(line) {
                    continue;
                }
                if !parse_line(&self.buf[..self.end], a, b, &mut self.values) {
                    // Something unusual: the careful path, which also words the refusal.
                    let line_no = self.line;
                    if let Some((kind, col, msg)) = check_line(&self.buf[a..b], &mut self.values) {
                        return Err(self.header.err(kind, line_no, Some(col), msg));
                    }
                }
                if self.unterminated {
                    let last = line.rsplit(|&c| c == b',').next().map(trim).unwrap_or(&[]);
                    let (line_no, col) = (self.line, self.values.len().saturating_sub(1));
                    return Err(self.header.err(
                        SessionErrorKind::Truncated,
                        line_no,
                        Some(col),
                        format!(
                            "the file ends inside this line, after `{}` with no line end: it may be truncated (cut \
                             while being written?), a number cut short reads as another; every line of a session \
                             ends with a newline",
                            String::from_utf8_lossy(last)
                        ),
                    ));
                }
            }
            let t = self.values[t_col];
            if t <= self.last_t {
                let line_no = self.line;
                return Err(self.header.err(
                    SessionErrorKind::BadValue,
                    line_no,
                    Some(t_col),
                    "time does not increase",
                ));
            }
            let prev = (self.rows > 0).then_some(self.last_t);
            if let Some((kind, col, msg)) = self.header.check_values(&self.values, prev) {
                let line_no = self.line;
                return Err(self.header.err(kind, line_no, Some(col), msg));
            }
            self.last_t = t;
            self.rows += 1;
            return Ok(Some(&self.values));
        }
        let min_rows = if self.header.layout.increments() { 3 } else { 2 };
        if self.rows < min_rows {
            return Err(self.header.err(
                SessionErrorKind::NoRows,
                self.header.line,
                None,
                format!("fewer than {min_rows} data rows"),
            ));
        }
        Ok(None)
    }
}

/// One sample of a session, in the model's quantities, borrowed from its flat record: t;
/// the FOGs' rates (n); their temperatures (n); ω_ref (3); B (3); every column's value in
/// file order ([`write_record`]). A pass holds samples as records, one after
/// another in one array, and hands them out as views ([`SampleRef::of_record`]).
#[derive(Debug, Clone, Copy)]
pub struct SampleRef<'a> {
    /// Time (end of the sample interval), s.
    pub t_s: f64,
    /// Raw rate of each FOG, rad/s.
    pub rate_rad_s: &'a [f64],
    /// Temperature of each FOG, °C (NaN where the session has none).
    pub t_degc: &'a [f64],
    /// Reference rate of the ICS, ICS components, rad/s.
    pub ref_rad_s: [f64; 3],
    /// Magnetic induction, nT (zeros without field columns).
    pub field_nt: [f64; 3],
    /// Every column's value in file order (increments as they are in the file).
    pub values: &'a [f64],
}

/// Writes the record of a sample to `rec` (its previous contents dropped): t, the FOGs'
/// rates, their temperatures (as many), ω_ref, B, the columns ([`SampleRef::of_record`]
/// reads it).
pub fn write_record(
    rec: &mut Vec<f64>,
    t_s: f64,
    rate_rad_s: impl IntoIterator<Item = f64>,
    t_degc: impl IntoIterator<Item = f64>,
    ref_rad_s: [f64; 3],
    field_nt: [f64; 3],
    values: impl IntoIterator<Item = f64>,
) {
    rec.clear();
    rec.push(t_s);
    rec.extend(rate_rad_s);
    rec.extend(t_degc);
    rec.extend_from_slice(&ref_rad_s);
    rec.extend_from_slice(&field_nt);
    rec.extend(values);
}

impl<'a> SampleRef<'a> {
    /// The sample whose record is `r` (n_fog FOGs; the columns are the rest).
    #[inline]
    pub fn of_record(r: &'a [f64], n_fog: usize) -> Self {
        let w = 1 + 2 * n_fog;
        SampleRef {
            t_s: r[0],
            rate_rad_s: &r[1..1 + n_fog],
            t_degc: &r[1 + n_fog..w],
            ref_rad_s: [r[w], r[w + 1], r[w + 2]],
            field_nt: [r[w + 3], r[w + 4], r[w + 5]],
            values: &r[w + 6..],
        }
    }
}

/// Turns rows into samples: FOG increments into rates over (t_{k−1}, t_k] (the first row of
/// an increment session has no interval and gives no sample), the turntable geometry into
/// the reference rate.
#[derive(Debug, Clone)]
pub struct Converter {
    layout: Layout,
    last_t: Option<f64>,
}

impl Converter {
    /// For sessions with `layout`.
    pub fn new(layout: &Layout) -> Converter {
        Converter { layout: layout.clone(), last_t: None }
    }

    /// Writes the record of the sample of `row` to `rec` ([`SampleRef`]); `false` (and
    /// `rec` empty) when the row gives no sample (first row of increments).
    pub fn convert(&mut self, row: &[f64], rec: &mut Vec<f64>) -> bool {
        let l = &self.layout;
        let t = row[l.t];
        let prev = self.last_t.replace(t);
        rec.clear();
        if l.increments() && prev.is_none() {
            return false;
        }
        let w = match (l.reference, l.turntable) {
            (Some([x, y, z]), _) => [row[x], row[y], row[z]],
            (None, Some([psi, lat])) => {
                let mut w = earth_rate_ics(row[psi], row[lat]);
                w[2] += l.table_rate.map_or(0.0, |c| row[c]);
                w
            }
            (None, None) => [0.0; 3],
        };
        write_record(
            rec,
            t,
            l.fog.iter().map(|&(k, inc)| if inc { row[k] / (t - prev.unwrap_or(t)) } else { row[k] }),
            l.fog_temp.iter().map(|c| c.map_or(f64::NAN, |c| row[c])),
            w,
            l.field.map_or([0.0; 3], |[x, y, z]| [row[x], row[y], row[z]]),
            row.iter().copied(),
        );
        true
    }

    /// FOGs of the records it writes.
    pub fn n_fog(&self) -> usize {
        self.layout.n_fog
    }
}

/// Collects samples into a [`Session`].
struct Builder {
    cols: Vec<Vec<f64>>,
    rates: Vec<Vec<f64>>,
    reference: Vec<[f64; 3]>,
    field: Vec<[f64; 3]>,
    lines: Vec<u64>,
}

impl Builder {
    fn new(h: &Header) -> Builder {
        Builder {
            cols: vec![Vec::new(); h.names.len()],
            rates: vec![Vec::new(); h.layout.n_fog],
            reference: Vec::new(),
            field: Vec::new(),
            lines: Vec::new(),
        }
    }

    fn push(&mut self, s: &SampleRef, line: u64) {
        self.lines.push(line);
        for (c, v) in self.cols.iter_mut().zip(s.values) {
            c.push(*v);
        }
        for (r, v) in self.rates.iter_mut().zip(s.rate_rad_s) {
            r.push(*v);
        }
        self.reference.push(s.ref_rad_s);
        self.field.push(s.field_nt);
    }

    fn finish(self, h: &Header) -> Session {
        let l = &h.layout;
        let cols = self.cols;
        let fogs = self
            .rates
            .into_iter()
            .enumerate()
            .map(|(i, rate_rad_s)| FogData { rate_rad_s, t_degc: l.fog_temp[i].map(|c| cols[c].clone()) })
            .collect();
        Session {
            file: h.file.clone(),
            names: h.names.clone(),
            cols,
            roles: h.roles.clone(),
            fogs,
            ref_rad_s: self.reference,
            field_nt: l.field.map(|_| self.field),
            lines: self.lines,
        }
    }
}

/// Reads and checks a whole session file into memory. `progress`, when given, advances with
/// the bytes read.
pub fn read_session(path: &Path, progress: Option<&ProgressBar>) -> Result<Session, SessionError> {
    let mut rr = RowReader::open(path)?;
    if let (Some(pb), Ok(m)) = (progress, std::fs::metadata(path)) {
        pb.set_length(m.len());
    }
    let h = rr.header().clone();
    let mut conv = Converter::new(&h.layout);
    let mut rec = Vec::new();
    let mut b = Builder::new(&h);
    let mut rows = 0u64;
    while let Some(row) = rr.next_row()? {
        if conv.convert(row, &mut rec) {
            b.push(&SampleRef::of_record(&rec, h.layout.n_fog), rr.line());
        }
        rows += 1;
        if let Some(pb) = progress.filter(|_| rows.is_multiple_of(8192)) {
            pb.set_position(rr.bytes());
        }
    }
    if let Some(pb) = progress {
        pb.set_position(pb.length().unwrap_or(0));
    }
    Ok(b.finish(&h))
}

/// A session from columns in memory (`names` as in a session file's header, `cols[k]` the
/// values of column k), checked as a file would be: `file` names it in messages, and a
/// refusal's line is the row's (header = 1).
pub fn session_from_columns(file: &str, names: Vec<String>, cols: &[Vec<f64>]) -> Result<Session, SessionError> {
    let h = Header::parse(file, names, 1)?;
    let n = cols.first().map_or(0, Vec::len);
    let min_rows = if h.layout.increments() { 3 } else { 2 };
    if n < min_rows {
        return Err(h.err(SessionErrorKind::NoRows, 1, None, format!("fewer than {min_rows} data rows")));
    }
    let mut conv = Converter::new(&h.layout);
    let mut rec = Vec::new();
    let mut b = Builder::new(&h);
    let mut row = vec![0.0; h.names.len()];
    let mut last_t = f64::NEG_INFINITY;
    for j in 0..n {
        for (v, c) in row.iter_mut().zip(cols) {
            *v = c[j];
        }
        let line = j as u64 + 2;
        if let Some(k) = row.iter().position(|v| !v.is_finite()) {
            return Err(h.err(
                SessionErrorKind::BadNumber,
                line,
                Some(k),
                format!("`{}` is not a finite number", row[k]),
            ));
        }
        if row[h.layout.t] <= last_t {
            return Err(h.err(SessionErrorKind::BadValue, line, Some(h.layout.t), "time does not increase"));
        }
        if let Some((kind, col, msg)) = h.check_values(&row, (j > 0).then_some(last_t)) {
            return Err(h.err(kind, line, Some(col), msg));
        }
        last_t = row[h.layout.t];
        if conv.convert(&row, &mut rec) {
            b.push(&SampleRef::of_record(&rec, h.layout.n_fog), line);
        }
    }
    Ok(b.finish(&h))
}

/// A session in memory as the text of a session file: its columns in file order, each
/// value in Rust's shortest form that reads back to the same `f64`.
pub fn session_csv(session: &Session) -> String {
    use std::fmt::Write;
    let mut out = String::new();
    let _ = writeln!(out, "{}", session.names.join(","));
    for j in 0..session.cols.first().map_or(0, Vec::len) {
        for (k, c) in session.cols.iter().enumerate() {
            let _ = write!(out, "{}{}", if k > 0 { "," } else { "" }, c[j]);
        }
        out.push('\n');
    }
    out
}

/// Writes a session in memory as a session file ([`session_csv`]; temporary file and
/// rename).
pub fn write_session_csv(session: &Session, path: &Path) -> std::io::Result<()> {
    let tmp = path.with_extension("partial");
    let named = |e: std::io::Error| std::io::Error::new(e.kind(), format!("{}: cannot write: {e}", path.display()));
    std::fs::write(&tmp, session_csv(session).as_bytes()).map_err(named)?;
    std::fs::rename(&tmp, path).map_err(named)
}

/// What a quick look at a session file tells before a pass: its header, how many samples
/// it has, their time span and the sample interval.
#[derive(Debug, Clone)]
pub struct Shape {
    /// The header.
    pub header: Header,
    /// Samples (rows, less the first of an increment session).
    pub samples: usize,
    /// Time of the first and the last sample, s.
    pub t_span_s: [f64; 2],
    /// The sample interval ([`median_interval_s`]), s.
    pub dt_s: f64,
    /// File size, bytes.
    pub bytes: u64,
}

/// Reads the header and the first rows of a session file (checked) and counts the rest of
/// its lines (not checked: the pass that follows checks them). The last sample's time is
/// read from the last data line.
pub fn shape(path: &Path) -> Result<Shape, SessionError> {
    let mut rr = RowReader::open(path)?;
    let header = rr.header().clone();
    let mut conv = Converter::new(&header.layout);
    let mut rec = Vec::new();
    let mut t = Vec::new();
    while t.len() <= INTERVALS_FOR_MEDIAN {
        match rr.next_row()? {
            Some(row) => {
                if conv.convert(row, &mut rec) {
                    t.push(rec[0]);
                }
            }
            None => break,
        }
    }
    let mut samples = t.len();
    let mut last_line: Vec<u8> = Vec::new();
    if samples > INTERVALS_FOR_MEDIAN {
        let io = |e: std::io::Error| header.err(SessionErrorKind::Io, 0, None, format!("cannot read: {e}"));
        let (n, last) = rr.count_rest().map_err(io)?;
        samples += n;
        last_line = last;
    }
    let t_last = if last_line.is_empty() {
        t[t.len() - 1]
    } else {
        let f = last_line.split(|&c| c == b',').nth(header.layout.t).map(trim).unwrap_or(&[]);
        parse_number(f).map_or(f64::NAN, |v| v.0)
    };
    Ok(Shape {
        samples,
        t_span_s: [t[0], t_last],
        dt_s: median_interval_s(&t),
        bytes: std::fs::metadata(path).map_or(0, |m| m.len()),
        header,
    })
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

#[cfg(all(test, unix))]
mod read_paths {
    use super::RowReader;

    /// Every row, as the reader gives it.
    fn rows(path: &std::path::Path) -> Vec<Vec<u64>> {
        let mut rr = RowReader::open(path).expect("the session reads");
        let mut out = Vec::new();
        while let Some(r) = rr.next_row().expect("a good row") {
            out.push(r.iter().map(|v| v.to_bits()).collect());
        }
        out
    }

    /// A regular file is mapped, a pipe is read a chunk at a time: the same rows, bit for
    /// bit, through comments, blank lines, spaces, CRLF ends, a line longer than a read
    /// chunk (a comment); and both refuse a last line without `\n` as possibly truncated.
    #[test]
    fn mapped_and_read_give_the_same_rows() {
        let mut text = String::from("# a session\nt_s, fog0_rad_s ,fog0_t_degc,ref_x_rad_s,ref_y_rad_s,ref_z_rad_s\n");
        for k in 1..5000 {
            let t = k as f64 * 0.01;
            if k == 1234 {
                text.push_str(&format!("# {}\n\n", "x".repeat(3 * super::READ_CHUNK)));
            }
            let end = if k % 7 == 0 { "\r\n" } else { "\n" };
            text.push_str(&format!(
                "{t}, {:e},{:.4} ,1.75e-2,0,0{end}",
                1e-5 * (k as f64).sin(),
                25.0 + 1e-3 * k as f64
            ));
        }
        text.push_str("50.0,1e-5,25.1,1.75e-2,0,-5.72e-5\n");
        let dir = std::env::temp_dir().join(format!("ssis-read-paths-{}", std::process::id()));
        std::fs::create_dir_all(&dir).expect("a temporary directory");
        let file = dir.join("s.csv");
        std::fs::write(&file, &text).expect("written");
        assert!(super::map_file(&std::fs::File::open(&file).expect("opens")).is_some(), "a regular file is mapped");
        let mapped = rows(&file);
        assert_eq!(mapped.len(), 5000);

        let fifo = dir.join("s.fifo");
        let c = std::ffi::CString::new(fifo.to_str().expect("utf-8")).expect("no NUL");
        // SAFETY: a valid C string path.
        assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o600) }, 0, "mkfifo");
        // Opened for reading and writing, a FIFO does not wait for a writer (Linux).
        let rw = std::fs::OpenOptions::new().read(true).write(true).open(&fifo).expect("opens");
        assert!(super::map_file(&rw).is_none(), "a pipe is read");
        drop(rw);
        let whole = text.clone();
        let writer = std::thread::spawn(move || std::fs::write(&fifo, whole).expect("written to the pipe"));
        let read = rows(&dir.join("s.fifo"));
        writer.join().expect("the writer ends");
        assert_eq!(read, mapped);
        // The same file cut inside its last number (`-5.72e-5` → `-5.72`): refused, mapped or read.
        let cut = &text[..text.len() - 4];
        std::fs::write(&file, cut).expect("written");
        let refusal = |path: &std::path::Path| {
            let mut rr = RowReader::open(path).expect("opens");
            loop {
                match rr.next_row() {
                    Ok(Some(_)) => {}
                    Ok(None) => panic!("a cut last line was read as a row"),
                    Err(e) => return e,
                }
            }
        };
        let e = refusal(&file);
        assert_eq!((e.kind, e.line), (super::SessionErrorKind::Truncated, 5004), "{e}");
        let (fifo, cut) = (dir.join("s.fifo"), cut.to_string());
        let writer = std::thread::spawn(move || std::fs::write(&fifo, cut).expect("written to the pipe"));
        let e2 = refusal(&dir.join("s.fifo"));
        writer.join().expect("the writer ends");
        assert_eq!(e2.to_string(), e.to_string().replace("s.csv", "s.fifo"));
        let _ = std::fs::remove_dir_all(&dir);
    }

    /// A session truncated by another program under the map: the reader's next page past
    /// the new end raises SIGBUS, and the process stops with the plain message and status
    /// 74 ([`super::on_sigbus`], installed as a program does with
    /// [`super::exit_plainly_on_truncated_map`]). Run in a child process (this test binary again, with
    /// `SSIS_SIGBUS_CHILD`), which opens a three-page session, truncates it to one page and
    /// reads on: deterministic, the second page is gone before the reader reaches it.
    #[test]
    fn a_session_truncated_under_the_map_stops_with_a_plain_message() {
        const NAME: &str = "read_paths::a_session_truncated_under_the_map_stops_with_a_plain_message";
        if let Some(path) = std::env::var_os("SSIS_SIGBUS_CHILD") {
            let path = std::path::PathBuf::from(path);
            let mut text = String::from("t_s,fog0_rad_s,fog0_t_degc,ref_x_rad_s,ref_y_rad_s,ref_z_rad_s\n");
            let mut k = 1;
            while text.len() < 3 * 4096 {
                text.push_str(&format!("{}.0,1e-5,25.0,1.75e-2,0,0\n", k));
                k += 1;
            }
            std::fs::write(&path, &text).expect("written");
            super::exit_plainly_on_truncated_map();
            let mut rr = RowReader::open(&path).expect("opens");
            std::fs::OpenOptions::new().write(true).open(&path).expect("opens").set_len(4096).expect("truncated");
            let mut rows = 0;
            while let Ok(Some(_)) = rr.next_row() {
                rows += 1;
            }
            // Not reached: the reader touches the second page first.
            panic!("read {rows} rows past a truncation without SIGBUS");
        }
        let dir = std::env::temp_dir().join(format!("ssis-sigbus-{}", std::process::id()));
        std::fs::create_dir_all(&dir).expect("a temporary directory");
        let out = std::process::Command::new(std::env::current_exe().expect("the test binary"))
            .args(["--exact", NAME, "--nocapture", "--test-threads=1"])
            .env("SSIS_SIGBUS_CHILD", dir.join("s.csv"))
            .output()
            .expect("the child runs");
        let _ = std::fs::remove_dir_all(&dir);
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(74), "status {:?}, stderr: {stderr}", out.status);
        assert!(stderr.contains("truncated by another program while it was being read"), "stderr: {stderr}");
    }
}
