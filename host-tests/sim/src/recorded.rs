//! Recorded logs (`docs/RECORDED-LOG.md`): sensor data from a test bench, a flight or
//! another simulator, read into the steps the unit integrates.
//!
//! Two forms are read:
//! - a CSV file, one row per FOG sample (units in the column names): per FOG its angle
//!   increment, counter, temperature and status; star-tracker solutions with their time
//!   tags and validity; optional truth (attitude quaternion, body rate);
//! - raw byte captures of the links (the ICD frames as a serial logger records them),
//!   one or more files, each scanned for FOG and star-tracker frames.
//!
//! Any start time or counter: the replay numbers the samples from 1 (the core takes unit
//! time from the first FOG frame's counter, so unit time 0 is one sample interval before
//! the log's first sample) and re-bases the star-tracker time tags to that clock.
//!
//! A damaged log is read as far as it goes: each kind of damage (a truncated line, a
//! value that is not a number, time or a counter that repeats, goes back or jumps, a star
//! tag that repeats or goes back, a frame that fails its CRC) is counted with the first
//! places it was found ([`Problems`]); the read fails only when nothing usable remains.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use anyhow::{bail, Context, Result};
use nalgebra::{Quaternion, Vector3};
use ssis::calib::N_FOG;
use ssis::combination::FogSet;
use ssis::frames::fog::FogFrame;
use ssis::frames::star::StarFrame;
use ssis::frames::{DecodeError, Frame};

/// One FOG's sample in a row.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FogSample {
    /// Angle increment about the sensitive axis over the sample interval, rad.
    pub dtheta_rad: f64,
    /// Temperature, °C.
    pub t_degc: f64,
    /// Status bits (`docs/ICD.md`, FOG sample frame).
    pub status: u8,
}

/// One star-tracker solution.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StarSample {
    /// The instant the quaternion holds, µs of unit time (re-based).
    pub time_us: u64,
    /// Valid flag.
    pub valid: bool,
    /// Λ* (the star tracker's frame in the 2ECS), scalar first.
    pub q: [f64; 4],
}

/// Truth at the end of a sample.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TruthRow {
    /// Λ of the ICS in the 2ECS.
    pub q: Quaternion<f64>,
    /// Body rate in ICS components, rad/s (zero when the log has none).
    pub rate_rad_s: Vector3<f64>,
}

/// One step of the unit: the samples that arrive for it.
#[derive(Debug, Clone, Default)]
pub struct LogStep {
    /// Per FOG slot, its sample (`None`: not in the log for this step).
    pub fog: [Option<FogSample>; N_FOG],
    /// Star-tracker solutions delivered in this step.
    pub st: Vec<StarSample>,
    /// Truth at the step's end, if the log has it.
    pub truth: Option<TruthRow>,
}

/// A log read into steps of the unit.
#[derive(Debug, Clone)]
pub struct Recorded {
    /// What was read (for messages).
    pub origin: String,
    /// Steps from 1: `steps[k]` is step k + 1 (steps inside a gap are empty).
    pub steps: Vec<LogStep>,
    /// The FOG slots the log has.
    pub fogs: FogSet,
    /// The log's time of unit time 0 (one interval before the first sample), s.
    pub t0_s: f64,
    /// What was wrong with it.
    pub problems: Problems,
    /// Whether the log carries truth.
    pub has_truth: bool,
}

/// One kind of damage: how often, and where first.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Damage {
    /// Occurrences.
    pub count: u64,
    /// The first few places, `file:line: what` (or a byte offset in a capture).
    pub first: Vec<String>,
}

/// Places kept per kind of damage.
const FIRST_KEPT: usize = 3;

impl Damage {
    fn add(&mut self, n: u64, at: impl FnOnce() -> String) {
        if self.count < FIRST_KEPT as u64 {
            self.first.push(at());
        }
        self.count += n;
    }
}

/// Every kind of damage a log can have, counted (never fatal on its own).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Problems {
    /// Lines with fewer or more fields than the header, or a last line without its end.
    pub truncated_lines: Damage,
    /// Fields that are not a finite number (the row's other fields are kept where they
    /// do not depend on it).
    pub bad_values: Damage,
    /// Samples whose time (or counter) repeats the previous one: dropped.
    pub repeated_samples: Damage,
    /// Samples whose time (or counter) is before the previous one: dropped.
    pub backward_samples: Damage,
    /// Gaps: samples missing between two rows (count: samples missing).
    pub gaps: Damage,
    /// FOG counters that do not advance with the time (repeat, go back or jump): the
    /// sample is kept at its time.
    pub counter_jumps: Damage,
    /// Star-tracker time tags that repeat or go back: dropped.
    pub st_time_backward: Damage,
    /// Star-tracker quaternions that are not unit quaternions (|‖q‖ − 1| > 1e-3): dropped.
    pub st_not_unit: Damage,
    /// Capture: frames that fail their CRC.
    pub crc_failures: Damage,
    /// Capture: frames with a good CRC and a field out of range.
    pub field_errors: Damage,
    /// Capture: bytes between frames (hunting for sync, rejected frames, a cut frame).
    pub bytes_skipped: Damage,
}

impl Problems {
    /// Each kind with its name, in the order of a report.
    pub fn kinds(&self) -> [(&'static str, &Damage); 11] {
        [
            ("truncated_lines", &self.truncated_lines),
            ("bad_values", &self.bad_values),
            ("repeated_samples", &self.repeated_samples),
            ("backward_samples", &self.backward_samples),
            ("gap_samples_missing", &self.gaps),
            ("counter_jumps", &self.counter_jumps),
            ("st_time_tags_repeated_or_backward", &self.st_time_backward),
            ("st_not_unit_quaternion", &self.st_not_unit),
            ("frames_failing_crc", &self.crc_failures),
            ("frames_with_bad_fields", &self.field_errors),
            ("bytes_skipped", &self.bytes_skipped),
        ]
    }

    /// Whether nothing was wrong.
    pub fn is_clean(&self) -> bool {
        self.kinds().iter().all(|(_, d)| d.count == 0)
    }

    /// The report: one line per kind found, with its first places.
    pub fn report(&self) -> String {
        let mut s = String::new();
        for (name, d) in self.kinds() {
            if d.count > 0 {
                s.push_str(&format!("  {name}: {}", d.count));
                if !d.first.is_empty() {
                    s.push_str(&format!("  (first: {})", d.first.join("; ")));
                }
                s.push('\n');
            }
        }
        if s.is_empty() {
            s.push_str("  none\n");
        }
        s
    }
}

/// Reads a log: one CSV file, or one or more capture files (any other name than `.csv`).
pub fn read(paths: &[PathBuf], dt_us: u32) -> Result<Recorded> {
    match paths {
        [] => bail!("no log given"),
        [p] if is_csv(p) => read_csv(p, dt_us),
        ps => {
            if let Some(p) = ps.iter().find(|p| is_csv(p)) {
                bail!("{}: a CSV log is replayed alone (captures may be given together)", p.display());
            }
            read_captures(ps, dt_us)
        }
    }
}

fn is_csv(p: &Path) -> bool {
    p.extension().is_some_and(|e| e.eq_ignore_ascii_case("csv"))
}

/// Columns of a CSV log, by index.
#[derive(Debug, Default)]
struct Columns {
    t: Option<usize>,
    fog_dtheta: [Option<usize>; N_FOG],
    fog_counter: [Option<usize>; N_FOG],
    fog_t: [Option<usize>; N_FOG],
    fog_status: [Option<usize>; N_FOG],
    st_t: Option<usize>,
    st_valid: Option<usize>,
    st_q: [Option<usize>; 4],
    true_q: [Option<usize>; 4],
    true_w: [Option<usize>; 3],
}

impl Columns {
    fn parse(header: &str, origin: &str) -> Result<Columns> {
        let mut c = Columns::default();
        for (k, name) in header.split(',').map(str::trim).enumerate() {
            let slot = |prefix: &str, suffix: &str, n: usize| -> Option<usize> {
                let mid = name.strip_prefix(prefix)?.strip_suffix(suffix)?;
                mid.parse::<usize>().ok().filter(|&i| i < n)
            };
            let set = |col: &mut Option<usize>| *col = Some(k);
            match name {
                "t_s" => set(&mut c.t),
                "st_t_s" => set(&mut c.st_t),
                "st_valid" => set(&mut c.st_valid),
                _ => {
                    if let Some(i) = slot("fog", "_dtheta_rad", N_FOG) {
                        c.fog_dtheta[i] = Some(k);
                    } else if let Some(i) = slot("fog", "_counter", N_FOG) {
                        c.fog_counter[i] = Some(k);
                    } else if let Some(i) = slot("fog", "_t_degc", N_FOG) {
                        c.fog_t[i] = Some(k);
                    } else if let Some(i) = slot("fog", "_status", N_FOG) {
                        c.fog_status[i] = Some(k);
                    } else if let Some(i) = slot("st_q", "", 4) {
                        c.st_q[i] = Some(k);
                    } else if let Some(i) = slot("true_q", "", 4) {
                        c.true_q[i] = Some(k);
                    } else if let Some(i) =
                        ["true_wx_rad_s", "true_wy_rad_s", "true_wz_rad_s"].iter().position(|n| *n == name)
                    {
                        c.true_w[i] = Some(k);
                    } else if name.starts_with("fog") && (name.ends_with("_deg") || name.ends_with("_arcsec")) {
                        bail!(
                            "{origin}: line 1, column {} ({name}): angle increments are in rad (`fogN_dtheta_rad`)",
                            k + 1
                        );
                    }
                    // Anything else (accelerometer, GNSS, the user's own columns) is kept
                    // out of the attitude replay.
                }
            }
        }
        if c.fog_dtheta.iter().all(Option::is_none) {
            bail!("{origin}: line 1: no FOG column (`fog0_dtheta_rad` … `fog3_dtheta_rad`)");
        }
        if c.t.is_none() && c.fog_counter.iter().all(Option::is_none) {
            bail!("{origin}: line 1: neither `t_s` nor a FOG counter (`fogN_counter`): no time for the samples");
        }
        let st_any = c.st_t.is_some() || c.st_q.iter().any(Option::is_some);
        if st_any && (c.st_t.is_none() || c.st_q.iter().any(Option::is_none)) {
            bail!("{origin}: line 1: a star tracker needs `st_t_s` and `st_q0` … `st_q3`");
        }
        if c.true_q.iter().any(Option::is_some) && c.true_q.iter().any(Option::is_none) {
            bail!("{origin}: line 1: truth needs all of `true_q0` … `true_q3`");
        }
        Ok(c)
    }
}

/// A CSV row before it is placed on the unit's clock.
struct RawRow {
    line: usize,
    t_s: Option<f64>,
    counter: [Option<u16>; N_FOG],
    fog: [Option<FogSample>; N_FOG],
    st: Option<(f64, bool, [f64; 4])>,
    truth: Option<TruthRow>,
}

/// Reads a CSV log (`docs/RECORDED-LOG.md`).
pub fn read_csv(path: &Path, dt_us: u32) -> Result<Recorded> {
    let bytes = std::fs::read(path).with_context(|| format!("cannot read {}", path.display()))?;
    let origin = path.display().to_string();
    let text = String::from_utf8_lossy(bytes.strip_prefix(b"\xEF\xBB\xBF").unwrap_or(&bytes)).into_owned();
    let mut p = Problems::default();
    let mut lines = text.split_inclusive('\n').enumerate().map(|(i, l)| (i + 1, l));
    let (cols, header_line) = loop {
        let Some((ln, l)) = lines.next() else { bail!("{origin}: empty log: no header line") };
        let l = l.trim_end_matches(['\n', '\r']);
        if l.trim().is_empty() || l.starts_with('#') {
            continue;
        }
        break (Columns::parse(l, &origin)?, (ln, l.split(',').count()));
    };
    let mut rows = Vec::new();
    for (ln, raw) in lines {
        let ended = raw.ends_with('\n');
        let l = raw.trim_end_matches(['\n', '\r']);
        if l.trim().is_empty() || l.starts_with('#') {
            continue;
        }
        let fields: Vec<&str> = l.split(',').map(str::trim).collect();
        if fields.len() != header_line.1 || !ended {
            let why = if ended {
                format!("{} fields, the header has {}", fields.len(), header_line.1)
            } else {
                "last line without its line end (cut while written?)".to_string()
            };
            p.truncated_lines.add(1, || format!("{origin}:{ln}: {why}"));
            continue;
        }
        rows.push(parse_row(&fields, &cols, ln, &origin, &mut p));
    }
    let has_truth = cols.true_q[0].is_some();
    place_rows(rows, dt_us, origin, p, has_truth)
}

/// One row's fields; a value that is not a finite number is counted and left out.
fn parse_row(fields: &[&str], c: &Columns, ln: usize, origin: &str, p: &mut Problems) -> RawRow {
    let mut num = |col: Option<usize>, name: &str| -> Option<f64> {
        let f = *fields.get(col?)?;
        if f.is_empty() {
            return None;
        }
        match f.parse::<f64>() {
            Ok(v) if v.is_finite() => Some(v),
            _ => {
                p.bad_values.add(1, || format!("{origin}:{ln}: field {name} = {f:?} is not a finite number"));
                None
            }
        }
    };
    let t_s = num(c.t, "t_s");
    let mut counter = [None; N_FOG];
    let mut fog = [None; N_FOG];
    for i in 0..N_FOG {
        counter[i] = num(c.fog_counter[i], &format!("fog{i}_counter")).map(|v| v.rem_euclid(65536.0) as u16);
        let t = num(c.fog_t[i], &format!("fog{i}_t_degc")).unwrap_or(25.0);
        let status = num(c.fog_status[i], &format!("fog{i}_status")).unwrap_or(0.0);
        fog[i] = num(c.fog_dtheta[i], &format!("fog{i}_dtheta_rad")).map(|d| FogSample {
            dtheta_rad: d,
            t_degc: t,
            status: status.clamp(0.0, 255.0) as u8,
        });
    }
    let st = num(c.st_t, "st_t_s").and_then(|t| {
        let valid = num(c.st_valid, "st_valid").is_none_or(|v| v != 0.0);
        let q = [0, 1, 2, 3].map(|k| num(c.st_q[k], &format!("st_q{k}")));
        Some((t, valid, [q[0]?, q[1]?, q[2]?, q[3]?]))
    });
    let truth = (|| {
        let q = [0, 1, 2, 3].map(|k| num(c.true_q[k], &format!("true_q{k}")));
        let w = [0, 1, 2].map(|k| num(c.true_w[k], ["true_wx_rad_s", "true_wy_rad_s", "true_wz_rad_s"][k]));
        let q = Quaternion::new(q[0]?, q[1]?, q[2]?, q[3]?);
        Some(TruthRow {
            q: q / q.norm(),
            rate_rad_s: Vector3::new(w[0].unwrap_or(0.0), w[1].unwrap_or(0.0), w[2].unwrap_or(0.0)),
        })
    })();
    RawRow { line: ln, t_s, counter, fog, st, truth }
}

/// Places rows on the unit's clock: sample k of the log is step k + 1 after re-basing;
/// repeated and backward samples dropped, gaps left empty, each counted.
fn place_rows(rows: Vec<RawRow>, dt_us: u32, origin: String, mut p: Problems, has_truth: bool) -> Result<Recorded> {
    let dt_s = f64::from(dt_us) * 1e-6;
    // Time of a row: t_s, or the first FOG counter unwrapped (sample interval dt).
    let mut unwrap = Unwrap::default();
    let mut timed: Vec<(f64, RawRow)> = Vec::with_capacity(rows.len());
    for r in rows {
        let t = match r.t_s {
            Some(t) => Some(t),
            None => r.counter.iter().flatten().next().map(|&c| unwrap.next(c) as f64 * dt_s),
        };
        if let Some(t) = t {
            timed.push((t, r));
        }
    }
    let Some(first) = timed.first().map(|(t, _)| *t) else {
        bail!("{origin}: nothing usable: no row with a time and a FOG sample\n{}", p.report());
    };
    check_interval(&timed, dt_s, &origin)?;
    let t0_s = first - dt_s;
    let mut steps: Vec<LogStep> = Vec::with_capacity(timed.len());
    let mut fogs = 0u8;
    let mut last_n = 0u64;
    let mut last_counter: [Option<(u64, u16)>; N_FOG] = [None; N_FOG];
    let mut last_st_us: Option<u64> = None;
    for (t, r) in timed {
        let n = ((t - t0_s) / dt_s).round();
        let at = || format!("{origin}:{}", r.line);
        if n <= last_n as f64 {
            let d = if n == last_n as f64 { &mut p.repeated_samples } else { &mut p.backward_samples };
            d.add(1, || format!("{}: t = {t} s, the sample before is at {} s", at(), t0_s + last_n as f64 * dt_s));
            continue;
        }
        let n = n as u64;
        if n > last_n + 1 {
            let lost = n - last_n - 1;
            p.gaps.add(lost, || format!("{}: {lost} samples missing before t = {t} s", at()));
        }
        for (i, c) in r.counter.iter().enumerate() {
            if let (Some(c), Some((ln, lc))) = (c, last_counter[i]) {
                if c.wrapping_sub(lc) as u64 != n - ln {
                    p.counter_jumps.add(1, || format!("{}: fog{i}_counter {c} after {lc}", at()));
                }
            }
            if let Some(c) = c {
                last_counter[i] = Some((n, *c));
            }
        }
        steps.resize_with(n as usize, LogStep::default);
        let step = &mut steps[n as usize - 1];
        step.fog = r.fog;
        for (i, f) in r.fog.iter().enumerate() {
            if f.is_some() {
                fogs |= 1 << i;
            }
        }
        step.truth = r.truth;
        if let Some((t_st, valid, q)) = r.st {
            let norm = q.iter().map(|v| v * v).sum::<f64>().sqrt();
            let us = ((t_st - t0_s) * 1e6).round();
            if (norm - 1.0).abs() > 1e-3 {
                p.st_not_unit.add(1, || format!("{}: |st_q| = {norm}", at()));
            } else if us < 0.0 || last_st_us.is_some_and(|l| us as u64 <= l) {
                p.st_time_backward.add(1, || format!("{}: st_t_s = {t_st} s not after the previous tag", at()));
            } else {
                last_st_us = Some(us as u64);
                step.st.push(StarSample { time_us: us as u64, valid, q: q.map(|v| v / norm) });
            }
        }
        last_n = n;
    }
    if fogs == 0 {
        bail!("{origin}: nothing usable: no FOG sample\n{}", p.report());
    }
    Ok(Recorded { origin, steps, fogs: FogSet(fogs), t0_s, problems: p, has_truth })
}

/// The log's sample interval must be the unit's: the median of the first intervals
/// within 1 %.
fn check_interval(timed: &[(f64, RawRow)], dt_s: f64, origin: &str) -> Result<()> {
    let mut d: Vec<f64> = timed.windows(2).take(1000).map(|w| w[1].0 - w[0].0).filter(|d| *d > 0.0).collect();
    if d.is_empty() {
        return Ok(());
    }
    d.sort_by(f64::total_cmp);
    let med = d[d.len() / 2];
    if (med - dt_s).abs() > 0.01 * dt_s {
        bail!(
            "{origin}: the samples are {:.4} ms apart (median of the first intervals); the unit integrates one FOG sample \
             every {:.4} ms: resample the log to that interval",
            med * 1e3,
            dt_s * 1e3
        );
    }
    Ok(())
}

/// A 16-bit counter unwrapped into a sample count.
#[derive(Default)]
struct Unwrap {
    last: Option<(u16, u64)>,
}

impl Unwrap {
    fn next(&mut self, c: u16) -> u64 {
        let v = match self.last {
            None => u64::from(c),
            Some((lc, lv)) => {
                let d = c.wrapping_sub(lc);
                if d < 0x8000 {
                    lv + u64::from(d)
                } else {
                    lv.saturating_sub(u64::from(lc.wrapping_sub(c)))
                }
            }
        };
        self.last = Some((c, v));
        v
    }
}

/// Reads raw captures of the links (FOG bus, star tracker; one file or several, frames
/// whole or not): FOG frames grouped by their counter, star frames by their time tag.
pub fn read_captures(paths: &[PathBuf], dt_us: u32) -> Result<Recorded> {
    let mut p = Problems::default();
    let mut fog_frames: Vec<(usize, FogFrame)> = Vec::new();
    // Star frames with the number of FOG frames decoded before them in the same file
    // (a logger that merges the links records when each arrived).
    let mut st_frames: Vec<(usize, StarFrame, Option<usize>)> = Vec::new();
    for path in paths {
        let bytes = std::fs::read(path).with_context(|| format!("cannot read {}", path.display()))?;
        let name = path.display().to_string();
        scan_capture(&bytes, &name, &mut p, &mut fog_frames, &mut st_frames);
    }
    let origin = paths.iter().map(|p| p.display().to_string()).collect::<Vec<_>>().join(" + ");
    if fog_frames.is_empty() {
        bail!("{origin}: nothing usable: no FOG frame decoded\n{}", p.report());
    }
    // Samples by unwrapped counter, in capture order.
    let mut unwrap = Unwrap::default();
    let mut by_sample: BTreeMap<u64, [Option<FogSample>; N_FOG]> = BTreeMap::new();
    let mut last: Option<u64> = None;
    let mut fogs = 0u8;
    let mut sample_of = Vec::with_capacity(fog_frames.len());
    for (off, f) in &fog_frames {
        let k = unwrap.next(f.counter);
        sample_of.push(k);
        let slot = by_sample.entry(k).or_default();
        let i = usize::from(f.fog_id);
        if slot[i].is_some() {
            p.repeated_samples.add(1, || format!("byte {off}: FOG{i} counter {} again", f.counter));
            continue;
        }
        if last.is_some_and(|l| k + 1 < l) {
            p.backward_samples.add(1, || format!("byte {off}: FOG{i} counter {} after a later one", f.counter));
            continue;
        }
        last = Some(last.map_or(k, |l| l.max(k)));
        slot[i] = Some(FogSample { dtheta_rad: f.dtheta_rad(), t_degc: f.temperature_degc(), status: f.status });
        fogs |= 1 << i;
    }
    let first = *by_sample.keys().next().unwrap_or(&0);
    let dt = u64::from(dt_us);
    // Unit time of the capture's first sample was first·dt; re-based to 1·dt.
    let shift_us = first.saturating_sub(1) * dt;
    let n_last = by_sample.keys().next_back().map_or(0, |k| k - first + 1);
    let mut steps = vec![LogStep::default(); n_last as usize];
    let mut prev: Option<u64> = None;
    for (k, fog) in by_sample {
        let n = k - first + 1;
        if let Some(pn) = prev {
            if n > pn + 1 {
                let lost = n - pn - 1;
                p.gaps.add(lost, || format!("counter jump: {lost} samples missing before sample {n}"));
            }
        }
        prev = Some(n);
        steps[n as usize - 1].fog = fog;
    }
    let mut last_st: Option<u64> = None;
    for (off, f, after) in st_frames {
        let Some(us) = f.time_us.checked_sub(shift_us) else {
            p.st_time_backward
                .add(1, || format!("byte {off}: star time tag {} µs before the first FOG sample", f.time_us));
            continue;
        };
        if last_st.is_some_and(|l| us <= l) {
            p.st_time_backward.add(1, || format!("byte {off}: star time tag {} µs not after the previous", f.time_us));
            continue;
        }
        last_st = Some(us);
        // Delivered with the FOG sample logged before it, or (a capture of its own) in the
        // step whose end is at or after its tag.
        let n = match after.and_then(|k| k.checked_sub(1)).and_then(|k| sample_of.get(k)) {
            Some(&k) => (k.saturating_sub(first) + 1) as usize,
            None => us.div_ceil(dt).max(1) as usize,
        };
        if let Some(s) = steps.get_mut(n - 1) {
            s.st.push(StarSample { time_us: us, valid: f.valid(), q: f.quaternion() });
        }
    }
    Ok(Recorded { origin, steps, fogs: FogSet(fogs), t0_s: shift_us as f64 * 1e-6, problems: p, has_truth: false })
}

/// Scans one capture for frames of the kinds the unit reads; every byte not in a good
/// frame is counted, and a rejected frame is resynchronised inside (as the unit does).
fn scan_capture(
    bytes: &[u8],
    name: &str,
    p: &mut Problems,
    fog: &mut Vec<(usize, FogFrame)>,
    st: &mut Vec<(usize, StarFrame, Option<usize>)>,
) {
    let fog_before = fog.len();
    let mut i = 0usize;
    let mut skipped_from: Option<usize> = None;
    let skip = |p: &mut Problems, from: &mut Option<usize>, at: usize| {
        if let Some(s) = from.take() {
            p.bytes_skipped.add((at - s) as u64, || format!("{name}: bytes {s}..{at}"));
        }
    };
    while i < bytes.len() {
        let kind = bytes.get(i + 2).copied();
        let is_sync = bytes.get(i..i + 2) == Some(&ssis::frames::SYNC[..]);
        let len = match kind {
            Some(k) if is_sync && k == FogFrame::KIND => FogFrame::LEN,
            Some(k) if is_sync && k == StarFrame::KIND => StarFrame::LEN,
            _ => 0,
        };
        let Some(cand) = (len > 0).then(|| bytes.get(i..i + len)).flatten() else {
            skipped_from.get_or_insert(i);
            i += 1;
            continue;
        };
        let r = if len == FogFrame::LEN && kind == Some(FogFrame::KIND) {
            FogFrame::decode(cand).map(|f| fog.push((i, f)))
        } else {
            let seen = fog.len();
            StarFrame::decode(cand).map(|f| st.push((i, f, (seen > fog_before).then_some(seen))))
        };
        match r {
            Ok(()) => {
                skip(p, &mut skipped_from, i);
                i += len;
            }
            Err(e) => {
                let d = if e == DecodeError::BadCrc { &mut p.crc_failures } else { &mut p.field_errors };
                d.add(1, || format!("{name}: frame at byte {i} ({e:?})"));
                skipped_from.get_or_insert(i);
                i += 1;
            }
        }
    }
    skip(p, &mut skipped_from, bytes.len());
}

impl Recorded {
    /// Seconds of log time of the end of step `n`.
    pub fn log_time_s(&self, n: u64, dt_us: u32) -> f64 {
        self.t0_s + n as f64 * f64::from(dt_us) * 1e-6
    }

    /// Star-tracker solutions delivered.
    pub fn st_count(&self) -> usize {
        self.steps.iter().map(|s| s.st.len()).sum()
    }

    /// The star tracker's latency as logged, s: the median over its solutions of the end
    /// of the step a solution arrives in less the instant it holds (0 without solutions).
    pub fn st_latency_s(&self, dt_us: u32) -> f64 {
        let mut late_us: Vec<u64> = (1u64..)
            .zip(&self.steps)
            .flat_map(|(n, s)| s.st.iter().map(move |st| (n * u64::from(dt_us)).saturating_sub(st.time_us)))
            .collect();
        late_us.sort_unstable();
        late_us.get(late_us.len() / 2).map_or(0.0, |&us| us as f64 * 1e-6)
    }

    /// FOG samples present.
    pub fn fog_samples(&self) -> usize {
        self.steps.iter().map(|s| s.fog.iter().flatten().count()).sum()
    }
}
