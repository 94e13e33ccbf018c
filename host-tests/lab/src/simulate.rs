//! Session generator with known effects, for the lab's tests and demos.
//!
//! Each row is what a ground-test rig records: the mean FOG rate over the sample interval
//! (so the white noise of angle random walk N appears with σ = N/√Δt), the mean FOG
//! temperature, the reference and, for magnetic tests, the field at the unit. The truth:
//!
//! ```text
//! ω_i,raw = (1 + k_i)(s_i·ω) + b_i + a1 ΔT + a2 ΔT² + g G + h ΔT G        (the table's model)
//!         + k_a,i |s_i·ω|  + c_u B·u_i + c_v B·v_i + A_i sin 2ψ             (hidden effects)
//!         + white noise
//! ```
//!
//! with s_i the exact axes of [`ssis::calib::Misalignment::axes`] and the thermal terms
//! averaged over 16 points inside each interval. Magnitudes follow the paper: ARW
//! 0.005 °/√h, bias ±0.3 °/h and scale factor ±0.1 %, axes ±300″ (3σ, before calibration);
//! magnetic sensitivity 0.05–0.15 °/h under the Earth's field (eqs. 1–3, the field of the
//! paper's Kharkov test, B₀ = (21846, 5967, −42340) nT north, west, up, turned into the
//! session's frame at the azimuth ψ by `ssis_session::field_ics_nt`).

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};
use ssis::calib::{Misalignment, GAMMA_NOMINAL_RAD};

use super::model::loop_plane;
use super::session::{earth_rate_ics, field_ics_nt, FieldModel, EARTH_RATE_RAD_S};
use super::LabResult;
use ssis_common::DEG_H_PER_RAD_S;

/// Latitude of the paper's test site (Kharkov, 50.048°), rad.
pub const KHARKOV_LAT_RAD: f64 = 50.048 * std::f64::consts::PI / 180.0;
/// The Earth field at the paper's test site (Kharkov) in a field model, (north, west, up), nT
/// (turned into the session's frame by `ssis_session::field_ics_nt`): WMM2025 on 2025-001
/// (19 345, −3 141, −47 630) or the paper's dipole tilt (21 846, 5 959, −42 343).
pub fn b0_nwu_nt(model: FieldModel) -> [f64; 3] {
    model
        .nwu_nt(super::session::KHARKOV_SITE, super::session::FIELD_EPOCH)
        .expect("both field models are given at Kharkov on 2025-001")
}
/// Angle random walk of the paper's FOG, °/√h.
pub const ARW_DEG_SQRT_H: f64 = 0.005;

/// How the unit moves.
#[derive(Debug, Clone, PartialEq)]
pub enum Motion {
    /// Turntable in azimuth: 24 positions 15° apart, `dwell_rows` samples each, one full turn
    /// per series; `screened[s]` puts series s inside a magnetic screen (field × 0.01).
    Turntable {
        /// Samples per position.
        dwell_rows: usize,
        /// One entry per series (turn).
        screened: Vec<bool>,
    },
    /// Rate table: the 24 settings (about X, Y, Z in turn, at ±0.1, ±0.2, ±0.5, ±1 × `peak_deg_s`)
    /// in a cycle, `dwell_rows` samples each, the cycle repeated until the session ends.
    RateTable {
        /// Samples per rate.
        dwell_rows: usize,
        /// Highest table rate, °/s (10 for the presets).
        peak_deg_s: f64,
    },
}

/// Thermal conditions.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Thermal {
    /// Constant temperature, °C.
    Constant(f64),
    /// Chamber profile: 2 h holds at 10, 40, 20, 35, 15, 30, 25 °C joined by ramps at a
    /// constant 0.2, 0.5, 0.3 °C/min with 10-min rounded corners, repeated (the paper's
    /// levels of T and G, Table 1).
    Chamber,
}

/// The effect switched on beyond the table's model.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Hidden {
    /// Nothing beyond bias, scale factor, misalignment, a1.
    None,
    /// Magnetic sensitivity, 0.08–0.15 °/h over the horizontal field.
    Magnetic,
    /// Temperature-rate sensitivity g, 15–25 (°/h)/(°C/s).
    TempRate,
    /// Scale-factor asymmetry, 10–20 ppm.
    SfAsymmetry,
    /// A sin 2ψ error, 0.08–0.12 °/h (outside the catalog).
    Sin2Psi,
    /// The whole onboard model: a2, g, h as well (for the round trip to flight).
    FullThermal,
}

/// What to generate.
#[derive(Debug, Clone, PartialEq)]
pub struct Spec {
    /// Random seed.
    pub seed: u64,
    /// Sample (averaging) interval, s.
    pub dt_s: f64,
    /// Number of rows.
    pub rows: usize,
    /// Motion.
    pub motion: Motion,
    /// Temperatures.
    pub thermal: Thermal,
    /// Whether the session records the field (`b_x_nt` …).
    pub field_columns: bool,
    /// The Earth field at the site (the default: WMM2025, the real field).
    pub field: FieldModel,
    /// The hidden effect.
    pub hidden: Hidden,
}

/// The values the generator used, in the model's units.
#[derive(Debug, Clone, PartialEq)]
pub struct Truth {
    /// White-noise σ of one recorded sample, rad/s (ARW/√Δt): the noise floor.
    pub noise_rad_s: f64,
    /// Bias, rad/s.
    pub bias_rad_s: Vec<f64>,
    /// Scale-factor error.
    pub k: Vec<f64>,
    /// Axes.
    pub misalignment: Misalignment,
    /// a1, a2 per FOG, rad/s per °C, °C².
    pub a_rad_s: Vec<[f64; 2]>,
    /// g, rad/s per °C/s.
    pub g: Vec<f64>,
    /// h, rad/s per °C²/s.
    pub h: Vec<f64>,
    /// Asymmetry k_a.
    pub k_asym: Vec<f64>,
    /// Magnetic coefficients along (u_i, v_i), rad/s per nT (the model's `magnetic` coef).
    pub magnetic_rad_s_per_nt: Vec<[f64; 2]>,
    /// Amplitude of sin 2ψ, rad/s.
    pub sin2psi_rad_s: Vec<f64>,
    /// Reference temperature of a1, a2, h, °C.
    pub t_ref_degc: f64,
}

/// A generated session: CSV header, rows, truth.
#[derive(Debug, Clone)]
pub struct SimSession {
    /// Column names.
    pub header: Vec<String>,
    /// Rows.
    pub rows: Vec<Vec<f64>>,
    /// Truth.
    pub truth: Truth,
}

const N_FOG: usize = 4;

/// Blend time at each end of a ramp, s (the chamber's controller rounds the corners).
const CORNER_S: f64 = 600.0;

fn chamber_profile() -> Vec<(f64, f64)> {
    // (time, temperature) knots: hold 2 h, then ramp at a constant rate with rounded corners.
    let levels = [10.0, 40.0, 20.0, 35.0, 15.0, 30.0, 25.0];
    let rates_degc_s = [0.2 / 60.0, 0.5 / 60.0, 0.3 / 60.0];
    let mut knots = vec![(0.0, 25.0)];
    let mut t = 0.0;
    let mut temp: f64 = 25.0;
    for rep in 0..20 {
        for (k, &l) in levels.iter().enumerate() {
            t += 7200.0;
            knots.push((t, temp));
            t += (l - temp).abs() / rates_degc_s[(k + rep) % 3] + CORNER_S;
            temp = l;
            knots.push((t, temp));
        }
    }
    knots
}

/// Chamber temperature and its rate at `t`: holds joined by constant-rate ramps whose rate
/// rises and falls as (1 − cos)/2 over [`CORNER_S`] at each end.
fn chamber(knots: &[(f64, f64)], t: f64) -> (f64, f64) {
    let i = knots.partition_point(|k| k.0 <= t).clamp(1, knots.len() - 1);
    let ((t0, a), (t1, b)) = (knots[i - 1], knots[i]);
    if t1 <= t0 || a == b {
        return (a, 0.0);
    }
    let (pi, c, d) = (std::f64::consts::PI, CORNER_S, t1 - t0);
    let r = (b - a) / (d - c); // peak rate: the corners lose c/2 each
    let s = (t - t0).clamp(0.0, d);
    // ∫ of the rate profile w(u) from 0 to s, and w(s).
    let rise = |s: f64| s / 2.0 - c / (2.0 * pi) * (pi * s / c).sin();
    let (area, w) = if s < c {
        (rise(s), (1.0 - (pi * s / c).cos()) / 2.0)
    } else if s <= d - c {
        (c / 2.0 + (s - c), 1.0)
    } else {
        let e = d - s;
        (d - c - rise(e), (1.0 - (pi * e / c).cos()) / 2.0)
    };
    (a + r * area, r * w)
}

/// Generates a session in memory.
pub fn generate(spec: &Spec) -> SimSession {
    let mut rows = Vec::with_capacity(spec.rows);
    let (header, truth) = generate_with(spec, |r| rows.push(r.to_vec()));
    SimSession { header, rows, truth }
}

/// The hidden effect of a preset session per FOG and row, rad/s: the part of each FOG's error
/// that the preset's hidden effect adds (g·G for `TempRate`, the asymmetry, magnetic and
/// sin 2ψ terms), for tests that compare what the lab removes with the truth.
pub fn hidden_effect_rad_s(spec: &Spec) -> Vec<Vec<f64>> {
    let mut out: Vec<Vec<f64>> = (0..N_FOG).map(|_| Vec::with_capacity(spec.rows)).collect();
    generate_rows(spec, |_, h| out.iter_mut().zip(h).for_each(|(o, v)| o.push(*v)));
    out
}

/// Generates a session row by row: `row` gets each row's values in header order; returns
/// the header and the truth.
pub fn generate_with(spec: &Spec, mut row_out: impl FnMut(&[f64])) -> (Vec<String>, Truth) {
    generate_rows(spec, |r, _| row_out(r))
}

/// [`generate_with`], with each row's hidden effect per FOG, rad/s.
fn generate_rows(spec: &Spec, mut row_out: impl FnMut(&[f64], &[f64; N_FOG])) -> (Vec<String>, Truth) {
    let mut rng = ChaCha8Rng::seed_from_u64(spec.seed);
    let truth = draw_truth(spec, &mut rng);
    let n01 = Normal::new(0.0, 1.0).expect("unit normal");
    let gauss = |s: f64, rng: &mut ChaCha8Rng| s * n01.sample(rng);
    let noise = truth.noise_rad_s;
    let t_ref = truth.t_ref_degc;
    let axes = truth.misalignment.axes(GAMMA_NOMINAL_RAD);
    let nominal = Misalignment::default().axes(GAMMA_NOMINAL_RAD);
    let planes: Vec<_> = (0..N_FOG).map(loop_plane).collect();
    let knots = chamber_profile();
    let t_offset: Vec<f64> = (0..N_FOG).map(|_| gauss(0.3, &mut rng)).collect();
    let turntable = matches!(spec.motion, Motion::Turntable { .. });
    let b0 = b0_nwu_nt(spec.field);
    let header = header(spec);
    let mut humidity = 40.0;
    let mut row = Vec::with_capacity(header.len());
    for j in 0..spec.rows {
        let t_end = (j + 1) as f64 * spec.dt_s;
        let (omega, psi, screened) = motion_at(&spec.motion, j);
        let fscale = if screened { 0.01 } else { 1.0 };
        let field = field_ics_nt(b0, psi).map(|v| fscale * v);
        let w = nalgebra::Vector3::from(omega);
        let bvec = nalgebra::Vector3::from(field);
        row.clear();
        row.push(t_end);
        let mut temps = Vec::new();
        let mut hidden = [0.0; N_FOG];
        for i in 0..N_FOG {
            // Thermal terms averaged over the interval.
            let m = 16;
            let (mut drift, mut tmean, mut g_part) = (0.0, 0.0, 0.0);
            for l in 0..m {
                let tau = t_end - spec.dt_s + (l as f64 + 0.5) * spec.dt_s / m as f64;
                let (temp, gr) = match spec.thermal {
                    Thermal::Constant(v) => (v, 0.0),
                    Thermal::Chamber => {
                        let (v, gr) = chamber(&knots, tau);
                        (v + t_offset[i], gr)
                    }
                };
                let d = temp - t_ref;
                drift += truth.a_rad_s[i][0] * d + truth.a_rad_s[i][1] * d * d + (truth.g[i] + truth.h[i] * d) * gr;
                g_part += truth.g[i] * gr;
                tmean += temp;
            }
            drift /= m as f64;
            tmean /= m as f64;
            let input = axes[i].dot(&w);
            let _ = nominal[i];
            let beyond = truth.k_asym[i] * input.abs()
                + truth.magnetic_rad_s_per_nt[i][0] * planes[i][0].dot(&bvec)
                + truth.magnetic_rad_s_per_nt[i][1] * planes[i][1].dot(&bvec)
                + truth.sin2psi_rad_s[i] * (2.0 * psi).sin();
            hidden[i] = beyond + if spec.hidden == Hidden::TempRate { g_part / m as f64 } else { 0.0 };
            let raw = (1.0 + truth.k[i]) * input
                + truth.bias_rad_s[i]
                + drift
                + truth.k_asym[i] * input.abs()
                + truth.magnetic_rad_s_per_nt[i][0] * planes[i][0].dot(&bvec)
                + truth.magnetic_rad_s_per_nt[i][1] * planes[i][1].dot(&bvec)
                + truth.sin2psi_rad_s[i] * (2.0 * psi).sin()
                + gauss(noise, &mut rng);
            row.push(raw);
            temps.push(tmean + gauss(0.002, &mut rng));
        }
        row.extend(temps);
        if turntable {
            row.extend([psi, KHARKOV_LAT_RAD]);
        } else {
            row.extend(omega);
        }
        if spec.field_columns {
            row.extend(field.iter().map(|v| v + gauss(5.0, &mut rng)));
        }
        humidity += gauss(0.5, &mut rng);
        row.push(humidity);
        row_out(&row, &hidden);
    }
    (header, truth)
}

/// The hidden errors of a session, drawn from `rng` (the first draws of the seed).
fn draw_truth(spec: &Spec, rng: &mut ChaCha8Rng) -> Truth {
    let deg_h = 1.0 / DEG_H_PER_RAD_S;
    let arcsec = std::f64::consts::PI / 180.0 / 3600.0;
    let n01 = Normal::new(0.0, 1.0).expect("unit normal");
    let mut gauss = |s: f64, rng: &mut ChaCha8Rng| s * n01.sample(rng);
    let signed = |lo: f64, hi: f64, rng: &mut ChaCha8Rng| {
        let m = rng.random_range(lo..hi);
        if rng.random_bool(0.5) {
            m
        } else {
            -m
        }
    };
    let noise = ARW_DEG_SQRT_H * deg_h * 60.0 / spec.dt_s.sqrt(); // °/√h → rad/√s, over Δt
    let ang = |rng: &mut ChaCha8Rng, g: &mut dyn FnMut(f64, &mut ChaCha8Rng) -> f64| g(100.0 * arcsec, rng);
    let misalignment = Misalignment {
        d12_rad: ang(rng, &mut gauss),
        d13_rad: ang(rng, &mut gauss),
        d21_rad: ang(rng, &mut gauss),
        d23_rad: ang(rng, &mut gauss),
        d31_rad: ang(rng, &mut gauss),
        d32_rad: ang(rng, &mut gauss),
        d42_rad: ang(rng, &mut gauss),
        d43_rad: ang(rng, &mut gauss),
    };
    let h = spec.hidden;
    let per_fog = |rng: &mut ChaCha8Rng, f: &mut dyn FnMut(&mut ChaCha8Rng) -> f64| -> Vec<f64> {
        (0..N_FOG).map(|_| f(rng)).collect()
    };
    let bias = per_fog(rng, &mut |r| gauss(0.1 * deg_h, r));
    let k = per_fog(rng, &mut |r| gauss(1e-3 / 3.0, r));
    let full = h == Hidden::FullThermal;
    let a: Vec<[f64; 2]> = (0..N_FOG)
        .map(|_| {
            let a1 = signed(0.01, 0.03, rng) * deg_h;
            let a2 = if full { signed(2e-4, 6e-4, rng) * deg_h } else { 0.0 };
            [a1, a2]
        })
        .collect();
    let g = per_fog(rng, &mut |r| {
        if h == Hidden::TempRate || full {
            signed(15.0, 25.0, r) * deg_h
        } else {
            0.0
        }
    });
    let hh = per_fog(rng, &mut |r| if full { signed(0.5, 1.0, r) * deg_h } else { 0.0 });
    let k_asym = per_fog(rng, &mut |r| if h == Hidden::SfAsymmetry { signed(10e-6, 20e-6, r) } else { 0.0 });
    let b0 = b0_nwu_nt(spec.field);
    let b_h = (b0[0] * b0[0] + b0[1] * b0[1]).sqrt();
    let magnetic_rad_s_per_nt: Vec<[f64; 2]> = (0..N_FOG)
        .map(|i| {
            if h != Hidden::Magnetic {
                return [0.0, 0.0];
            }
            let c = signed(0.08, 0.15, rng) * deg_h / b_h;
            // The horizontal direction of the loop plane (FOG1's u is vertical: use v).
            if i == 1 {
                [0.0, c]
            } else {
                [c, 0.0]
            }
        })
        .collect();
    let sin2psi = per_fog(rng, &mut |r| if h == Hidden::Sin2Psi { signed(0.08, 0.12, r) * deg_h } else { 0.0 });
    let t_ref = 25.0;
    Truth {
        noise_rad_s: noise,
        bias_rad_s: bias,
        k,
        misalignment,
        a_rad_s: a,
        g,
        h: hh,
        k_asym,
        magnetic_rad_s_per_nt,
        sin2psi_rad_s: sin2psi,
        t_ref_degc: t_ref,
    }
}

/// The session's column names, in row order.
fn header(spec: &Spec) -> Vec<String> {
    let mut header = vec!["t_s".to_string()];
    header.extend((0..N_FOG).map(|i| format!("fog{i}_rad_s")));
    header.extend((0..N_FOG).map(|i| format!("fog{i}_t_degc")));
    if matches!(spec.motion, Motion::Turntable { .. }) {
        header.extend(["psi_rad".into(), "lat_rad".into()]);
    } else {
        header.extend(["ref_x_rad_s".into(), "ref_y_rad_s".into(), "ref_z_rad_s".into()]);
    }
    if spec.field_columns {
        header.extend(["b_x_nt".into(), "b_y_nt".into(), "b_z_nt".into()]);
    }
    header.push("chamber_rh_pct".into());
    header
}

/// Row `j`'s motion: the rate vector (constant over the interval), rad/s, the azimuth, rad,
/// and whether the field is screened.
fn motion_at(motion: &Motion, j: usize) -> ([f64; 3], f64, bool) {
    let rate_fractions: [f64; 8] = [0.1, -0.1, 0.2, -0.2, 0.5, -0.5, 1.0, -1.0];
    match motion {
        Motion::Turntable { dwell_rows, screened } => {
            let pos = j / dwell_rows.max(&1);
            let series = (pos / 24).min(screened.len().saturating_sub(1));
            let psi = (pos % 24) as f64 * 15f64.to_radians();
            (earth_rate_ics(psi, KHARKOV_LAT_RAD), psi, screened.get(series).copied().unwrap_or(false))
        }
        Motion::RateTable { dwell_rows, peak_deg_s } => {
            let setting = (j / dwell_rows.max(&1)) % (3 * rate_fractions.len());
            let axis = setting / rate_fractions.len();
            let rate = (peak_deg_s * rate_fractions[setting % rate_fractions.len()]).to_radians();
            let mut w = [0.0; 3];
            // The table axis is vertical: the Earth's vertical rate adds along it.
            w[axis] = rate + EARTH_RATE_RAD_S * KHARKOV_LAT_RAD.sin();
            (w, 0.0, false)
        }
    }
}

impl SimSession {
    /// The CSV text.
    pub fn to_csv(&self) -> Vec<u8> {
        let mut w = csv::Writer::from_writer(Vec::new());
        w.write_record(&self.header).expect("in memory");
        for r in &self.rows {
            w.write_record(r.iter().map(|v| format!("{v:e}"))).expect("in memory");
        }
        w.into_inner().expect("in memory")
    }

    /// Writes the CSV (temporary file and rename).
    pub fn write_csv(&self, path: &std::path::Path) -> LabResult<()> {
        super::write_atomic(path, &self.to_csv())
    }
}

/// The sessions of the lab's tests and demos, by name: `magnetic`, `thermal`, `asymmetry`,
/// `sin2psi`, `flight` (thermal rate table with the whole onboard model), `replay` (the same at
/// 0.5-s samples, one flight-core step per row); `hidden = false`
/// gives the same session with no hidden effect.
pub fn preset(name: &str, seed: u64, hidden: bool) -> Option<Spec> {
    let pick = |h: Hidden| if hidden { h } else { Hidden::None };
    Some(match name {
        // 10-min means (the paper averaged 20-min plots): σ = 0.0122 °/h; 4 turns of 24
        // positions, two unscreened and two screened (the paper's eq. 2 method), 48 h.
        "magnetic" => Spec {
            seed,
            dt_s: 600.0,
            rows: 288,
            motion: Motion::Turntable { dwell_rows: 3, screened: vec![false, true, false, true] },
            thermal: Thermal::Constant(23.0),
            field_columns: true,
            field: FieldModel::default(),
            hidden: pick(Hidden::Magnetic),
        },
        // 5-min means in a thermal chamber, 48 h, static at ψ = 0.
        "thermal" => Spec {
            seed,
            dt_s: 300.0,
            rows: 576,
            motion: Motion::Turntable { dwell_rows: 100_000, screened: vec![false] },
            thermal: Thermal::Chamber,
            field_columns: false,
            field: FieldModel::default(),
            hidden: pick(Hidden::TempRate),
        },
        // 1-min means on a rate table, one per setting, 10 cycles of the 24 settings, 4 h.
        "asymmetry" => Spec {
            seed,
            dt_s: 60.0,
            rows: 240,
            motion: Motion::RateTable { dwell_rows: 1, peak_deg_s: 10.0 },
            thermal: Thermal::Constant(23.0),
            field_columns: false,
            field: FieldModel::default(),
            hidden: pick(Hidden::SfAsymmetry),
        },
        "sin2psi" => Spec {
            seed,
            dt_s: 600.0,
            rows: 144,
            motion: Motion::Turntable { dwell_rows: 3, screened: vec![false, false] },
            thermal: Thermal::Constant(23.0),
            field_columns: false,
            field: FieldModel::default(),
            hidden: pick(Hidden::Sin2Psi),
        },
        // Rate table inside the thermal chamber: every onboard term observable.
        "flight" => Spec {
            seed,
            dt_s: 300.0,
            rows: 576,
            motion: Motion::RateTable { dwell_rows: 1, peak_deg_s: 10.0 },
            thermal: Thermal::Chamber,
            field_columns: false,
            field: FieldModel::default(),
            hidden: if hidden { Hidden::FullThermal } else { Hidden::None },
        },
        // The same, sampled at 0.5 s with the table at up to ±3 °/s, 1 min per setting, for
        // 12 h: every row's increment fits a FOG frame (|Δθ| < 2^-5 rad), so the flight core
        // can replay the session one row per step (`super::replay`).
        "replay" => Spec {
            seed,
            dt_s: 0.5,
            rows: 86_400,
            motion: Motion::RateTable { dwell_rows: 120, peak_deg_s: 3.0 },
            thermal: Thermal::Chamber,
            field_columns: false,
            field: FieldModel::default(),
            hidden: if hidden { Hidden::FullThermal } else { Hidden::None },
        },
        _ => return None,
    })
}

/// The effect a [`DriftSpec`] session hides.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DriftEffect {
    /// Nothing the model (bias, a1) lacks.
    None,
    /// Temperature-rate sensitivity, 0.1–0.15 °/h per °C/min.
    TempRate,
    /// Aging: a drift ramp of 0.02–0.03 °/h per hour.
    Aging,
    /// Sensitivity to the supply voltage (the `supply_v` column), 0.05–0.08 °/h per V.
    Supply,
}

/// A 24-h static chamber session of 60-s means with realistic gyro noise: angle random walk
/// 0.005 °/√h, a Gauss–Markov bias wander of 0.005–0.01 °/h (τ 0.5–2 h) per FOG and, with
/// `flicker`, a flicker-like sum of five Gauss–Markov terms (τ 0.03–3 h, 0.003 °/h each).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DriftSpec {
    /// Random seed.
    pub seed: u64,
    /// The hidden effect.
    pub effect: DriftEffect,
    /// Whether to add the flicker-like terms.
    pub flicker: bool,
    /// Whether the bias wanders at all (false: white noise only).
    pub wander: bool,
}

/// A drift session and its truth.
#[derive(Debug, Clone)]
pub struct DriftSession {
    /// The session.
    pub sim: SimSession,
    /// Per FOG: the hidden effect's coefficient, rad/s per its unit (°C/s, hour, V).
    pub coef: Vec<f64>,
    /// Per FOG: RMS of the hidden effect about its mean over the session, rad/s.
    pub effect_rms_rad_s: Vec<f64>,
    /// Per FOG: (σ, τ in s) of each Gauss–Markov term, rad/s.
    pub wander: Vec<Vec<(f64, f64)>>,
}

/// Generates a [`DriftSpec`] session: 1440 rows of 60-s means, static at ψ = 0 in the thermal
/// chamber (bias and a1 = 0.01–0.03 °/h per °C as the table's model), a supply voltage
/// column (`supply_v`, levels of 27–29 V held 10–40 min) and a humidity column.
pub fn drift_session(spec: &DriftSpec) -> DriftSession {
    let mut rng = ChaCha8Rng::seed_from_u64(spec.seed ^ 0x5eed_d21f_7000);
    let n01 = Normal::new(0.0, 1.0).expect("unit normal");
    let deg_h = 1.0 / DEG_H_PER_RAD_S;
    let (dt, rows): (f64, usize) = (60.0, 1440);
    let white = ARW_DEG_SQRT_H * deg_h * 60.0 / dt.sqrt();
    let signed = |lo: f64, hi: f64, rng: &mut ChaCha8Rng| {
        let m = rng.random_range(lo..hi);
        if rng.random_bool(0.5) {
            m
        } else {
            -m
        }
    };
    let axes = Misalignment::default().axes(GAMMA_NOMINAL_RAD);
    let omega = nalgebra::Vector3::from(earth_rate_ics(0.0, KHARKOV_LAT_RAD));
    let mut bias = Vec::new();
    let mut a1 = Vec::new();
    let mut coef = Vec::new();
    let mut wander = Vec::new();
    for _ in 0..N_FOG {
        bias.push(0.1 * deg_h * n01.sample(&mut rng));
        a1.push(signed(0.01, 0.03, &mut rng) * deg_h);
        coef.push(match spec.effect {
            DriftEffect::None => 0.0,
            DriftEffect::TempRate => signed(0.1, 0.15, &mut rng) * deg_h * 60.0,
            DriftEffect::Aging => signed(0.02, 0.03, &mut rng) * deg_h,
            DriftEffect::Supply => signed(0.05, 0.08, &mut rng) * deg_h,
        });
        let mut w = Vec::new();
        if spec.wander {
            w.push((rng.random_range(0.005..0.01) * deg_h, rng.random_range(0.5..2.0) * 3600.0));
        }
        if spec.flicker {
            for tau_h in [0.03, 0.1, 0.3, 1.0, 3.0] {
                w.push((0.003 * deg_h, tau_h * 3600.0));
            }
        }
        wander.push(w);
    }
    let mut state: Vec<Vec<f64>> =
        wander.iter().map(|w| w.iter().map(|&(s, _)| s * n01.sample(&mut rng)).collect()).collect();
    let knots = chamber_profile();
    let t_offset: Vec<f64> = (0..N_FOG).map(|_| 0.3 * n01.sample(&mut rng)).collect();
    let mut header = vec!["t_s".to_string()];
    header.extend((0..N_FOG).map(|i| format!("fog{i}_rad_s")));
    header.extend((0..N_FOG).map(|i| format!("fog{i}_t_degc")));
    header.extend(["psi_rad", "lat_rad", "supply_v", "chamber_rh_pct"].map(String::from));
    let (mut supply, mut hold_until, mut humidity) = (28.0, 0.0, 40.0);
    let mut out = Vec::with_capacity(rows);
    let mut effects: Vec<Vec<f64>> = (0..N_FOG).map(|_| Vec::with_capacity(rows)).collect();
    for j in 0..rows {
        let t_end = (j + 1) as f64 * dt;
        if t_end > hold_until {
            supply = rng.random_range(27.0..29.0);
            hold_until = t_end + rng.random_range(600.0..2400.0);
        }
        let mut row = vec![t_end];
        let mut temps = Vec::new();
        for i in 0..N_FOG {
            let m = 16;
            let (mut drift, mut tmean, mut gmean) = (0.0, 0.0, 0.0);
            for l in 0..m {
                let tau = t_end - dt + (l as f64 + 0.5) * dt / m as f64;
                let (v, gr) = chamber(&knots, tau);
                drift += a1[i] * (v + t_offset[i] - 25.0);
                tmean += v + t_offset[i];
                gmean += gr;
            }
            let (drift, tmean, gmean) = (drift / m as f64, tmean / m as f64, gmean / m as f64);
            let hours = (t_end - 0.5 * dt) / 3600.0;
            let effect = match spec.effect {
                DriftEffect::None => 0.0,
                DriftEffect::TempRate => coef[i] * gmean,
                DriftEffect::Aging => coef[i] * hours,
                DriftEffect::Supply => coef[i] * (supply - 28.0),
            };
            effects[i].push(effect);
            let mut wn = 0.0;
            for (x, &(s, tau)) in state[i].iter_mut().zip(&wander[i]) {
                let phi = (-dt / tau).exp();
                *x = phi * *x + s * (1.0 - phi * phi).sqrt() * n01.sample(&mut rng);
                wn += *x;
            }
            row.push(axes[i].dot(&omega) + bias[i] + drift + effect + wn + white * n01.sample(&mut rng));
            temps.push(tmean + 0.002 * n01.sample(&mut rng));
        }
        row.extend(temps);
        humidity += 0.5 * n01.sample(&mut rng);
        row.extend([0.0, KHARKOV_LAT_RAD, supply + 0.01 * n01.sample(&mut rng), humidity]);
        out.push(row);
    }
    let effect_rms_rad_s = effects
        .iter()
        .map(|e| {
            let m = e.iter().sum::<f64>() / e.len() as f64;
            (e.iter().map(|v| (v - m) * (v - m)).sum::<f64>() / e.len() as f64).sqrt()
        })
        .collect();
    let truth = Truth {
        noise_rad_s: white,
        bias_rad_s: bias,
        k: vec![0.0; N_FOG],
        misalignment: Misalignment::default(),
        a_rad_s: a1.iter().map(|&a| [a, 0.0]).collect(),
        g: if spec.effect == DriftEffect::TempRate { coef.clone() } else { vec![0.0; N_FOG] },
        h: vec![0.0; N_FOG],
        k_asym: vec![0.0; N_FOG],
        magnetic_rad_s_per_nt: vec![[0.0; 2]; N_FOG],
        sin2psi_rad_s: vec![0.0; N_FOG],
        t_ref_degc: 25.0,
    };
    DriftSession { sim: SimSession { header, rows: out, truth }, coef, effect_rms_rad_s, wander }
}

/// The effect a [`PowerSpec`] session hides, on one FOG.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum PowerEffect {
    /// Nothing beyond bias and a1.
    None,
    /// g · G, g in rad/s per °C/s.
    TempRate,
    /// a1 · ΔT (the base model then lacks `thermal_t1`), rad/s per °C.
    ThermalT1,
    /// drift · hours, rad/s per hour.
    Aging,
    /// m_u · (u_i · B), rad/s per nT, the field turning in the unit's frame as in orbit.
    Magnetic,
    /// c · (supply_v − 28), rad/s per V (a user column).
    Column,
    /// A sin(2π t / period + φ), rad/s.
    Sinusoid {
        /// Period, s.
        period_s: f64,
    },
}

/// A session for the power study: static in the thermal chamber (the chamber profile of
/// [`Thermal::Chamber`]), every FOG with a bias, a1 = 0.01–0.03 °/h per °C, angle random
/// walk 0.005 °/√h and optionally a Gauss–Markov wander of 0.005–0.01 °/h (τ 0.5–2 h); the
/// field turning in the unit's frame with a 95-min period (|B| 30–50 µT, as in orbit); a
/// supply voltage in holds of 10–40 min; the effect on FOG `fog` only, of size `size`.
/// The noise is drawn the same way whatever the effect and its size (a session's noise
/// depends on its seed alone).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PowerSpec {
    /// Random seed.
    pub seed: u64,
    /// Sample interval, s.
    pub dt_s: f64,
    /// Session length, h.
    pub hours: f64,
    /// The hidden effect.
    pub effect: PowerEffect,
    /// Its coefficient (SI, per the effect's unit) or amplitude (rad/s).
    pub size: f64,
    /// The FOG it is on (4 or more: every FOG, the same size).
    pub fog: usize,
    /// Whether the bias wanders (Gauss–Markov) besides the white noise.
    pub wander: bool,
}

/// A [`PowerSpec`] session and the true design of its effect FOG (for the optimal test).
#[derive(Debug, Clone)]
pub struct PowerSession {
    /// The session.
    pub sim: SimSession,
    /// Per row, the effect term's regressors on the effect FOG, without measurement noise
    /// (the effect is `size` times the first).
    pub regressors: Vec<Vec<f64>>,
    /// Per row, the base model's true regressors there: 1 and ΔT (1 alone for `ThermalT1`).
    pub base: Vec<Vec<f64>>,
}

/// Generates a [`PowerSpec`] session.
pub fn power_session(spec: &PowerSpec) -> PowerSession {
    let mut rng = ChaCha8Rng::seed_from_u64(spec.seed ^ 0x9e37_79b9_0070_7e40);
    let n01 = Normal::new(0.0, 1.0).expect("unit normal");
    let deg_h = 1.0 / DEG_H_PER_RAD_S;
    let rows = (spec.hours * 3600.0 / spec.dt_s).round() as usize;
    let white = ARW_DEG_SQRT_H * deg_h * 60.0 / spec.dt_s.sqrt();
    let axes = Misalignment::default().axes(GAMMA_NOMINAL_RAD);
    let planes: Vec<_> = (0..N_FOG).map(loop_plane).collect();
    let omega = nalgebra::Vector3::from(earth_rate_ics(0.0, KHARKOV_LAT_RAD));
    let bias: Vec<f64> = (0..N_FOG).map(|_| 0.1 * deg_h * n01.sample(&mut rng)).collect();
    let a1: Vec<f64> = (0..N_FOG).map(|_| rng.random_range(0.01..0.03) * deg_h).collect();
    let wander: Vec<(f64, f64)> =
        (0..N_FOG).map(|_| (rng.random_range(0.005..0.01) * deg_h, rng.random_range(0.5..2.0) * 3600.0)).collect();
    let phase = rng.random_range(0.0..std::f64::consts::TAU);
    let mut state: Vec<f64> = wander.iter().map(|&(s, _)| s * n01.sample(&mut rng)).collect();
    let knots = chamber_profile();
    let t_offset: Vec<f64> = (0..N_FOG).map(|_| 0.3 * n01.sample(&mut rng)).collect();
    let mut header = vec!["t_s".to_string()];
    header.extend((0..N_FOG).map(|i| format!("fog{i}_rad_s")));
    header.extend((0..N_FOG).map(|i| format!("fog{i}_t_degc")));
    header.extend(["psi_rad", "lat_rad", "b_x_nt", "b_y_nt", "b_z_nt", "supply_v"].map(String::from));
    let (mut supply, mut hold_until) = (28.0, 0.0);
    let mut out = Vec::with_capacity(rows);
    let (mut regressors, mut base) = (Vec::with_capacity(rows), Vec::with_capacity(rows));
    let two_pi = std::f64::consts::TAU;
    for j in 0..rows {
        let t_end = (j + 1) as f64 * spec.dt_s;
        let t_mid = t_end - 0.5 * spec.dt_s;
        if t_end > hold_until {
            supply = rng.random_range(27.0..29.0);
            hold_until = t_end + rng.random_range(600.0..2400.0);
        }
        // The field turning with the orbit (95 min) about a slowly precessing axis.
        let (so, co) = (two_pi * t_mid / 5700.0).sin_cos();
        let (sp, cp) = (two_pi * t_mid / 86_400.0 + 1.0).sin_cos();
        let b = nalgebra::Vector3::new(40_000.0 * co, 30_000.0 * so * cp, 20_000.0 * so * sp + 10_000.0);
        let mut row = vec![t_end];
        let mut temps = Vec::new();
        for i in 0..N_FOG {
            let m = 16;
            let (mut drift, mut tmean, mut gmean) = (0.0, 0.0, 0.0);
            for l in 0..m {
                let tau = t_end - spec.dt_s + (l as f64 + 0.5) * spec.dt_s / m as f64;
                let (v, gr) = chamber(&knots, tau);
                drift += a1[i] * (v + t_offset[i] - 25.0);
                tmean += v + t_offset[i];
                gmean += gr;
            }
            let (drift, tmean, gmean) = (drift / m as f64, tmean / m as f64, gmean / m as f64);
            let effect = if i == spec.fog || (spec.fog >= N_FOG && i == 0) {
                let x = match spec.effect {
                    PowerEffect::None => vec![0.0],
                    PowerEffect::TempRate => vec![gmean],
                    PowerEffect::ThermalT1 => vec![tmean - 25.0],
                    PowerEffect::Aging => vec![t_mid / 3600.0],
                    PowerEffect::Magnetic => vec![planes[i][0].dot(&b), planes[i][1].dot(&b)],
                    PowerEffect::Column => vec![supply - 28.0],
                    PowerEffect::Sinusoid { period_s } => {
                        let (sn, cs) = (two_pi * t_mid / period_s + phase).sin_cos();
                        vec![sn, cs]
                    }
                };
                let e = spec.size * x[0];
                regressors.push(x);
                base.push(if spec.effect == PowerEffect::ThermalT1 { vec![1.0] } else { vec![1.0, tmean - 25.0] });
                e
            } else if spec.fog >= N_FOG {
                spec.size
                    * match spec.effect {
                        PowerEffect::Sinusoid { period_s } => (two_pi * t_mid / period_s + phase).sin(),
                        PowerEffect::TempRate => gmean,
                        PowerEffect::ThermalT1 => tmean - 25.0,
                        PowerEffect::Aging => t_mid / 3600.0,
                        PowerEffect::Magnetic => planes[i][0].dot(&b),
                        PowerEffect::Column => supply - 28.0,
                        PowerEffect::None => 0.0,
                    }
            } else {
                0.0
            };
            // ThermalT1 is the effect: the base a1 is then left out of that FOG.
            let drift = if spec.effect == PowerEffect::ThermalT1 { 0.0 } else { drift };
            let mut wn = 0.0;
            if spec.wander {
                let (s, tau) = wander[i];
                let phi = (-spec.dt_s / tau).exp();
                state[i] = phi * state[i] + s * (1.0 - phi * phi).sqrt() * n01.sample(&mut rng);
                wn = state[i];
            }
            row.push(axes[i].dot(&omega) + bias[i] + drift + effect + wn + white * n01.sample(&mut rng));
            temps.push(tmean + 0.002 * n01.sample(&mut rng));
        }
        row.extend(temps);
        row.extend([0.0, KHARKOV_LAT_RAD]);
        row.extend(b.iter().map(|v| v + 5.0 * n01.sample(&mut rng)));
        row.push(supply + 0.01 * n01.sample(&mut rng));
        out.push(row);
    }
    let truth = Truth {
        noise_rad_s: white,
        bias_rad_s: bias,
        k: vec![0.0; N_FOG],
        misalignment: Misalignment::default(),
        a_rad_s: a1.iter().map(|&a| [a, 0.0]).collect(),
        g: vec![0.0; N_FOG],
        h: vec![0.0; N_FOG],
        k_asym: vec![0.0; N_FOG],
        magnetic_rad_s_per_nt: vec![[0.0; 2]; N_FOG],
        sin2psi_rad_s: vec![0.0; N_FOG],
        t_ref_degc: 25.0,
    };
    PowerSession { sim: SimSession { header, rows: out, truth }, regressors, base }
}
