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
use ssis::calib::accel::N_ACCEL;
use ssis::calib::N_FOG;
use ssis::combination::FogSet;
use ssis::flight::Profile;
use ssis::frames::accel::AccelFrame;
use ssis::frames::fog::FogFrame;
use ssis::frames::gnss::{self, GnssFrame};
use ssis::frames::star::StarFrame;
use ssis::frames::{DecodeError, Frame};
use ssis::nav::NavState;

mod csv;
pub use csv::{read_csv, LogStream};

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

/// One accelerometer's sample in a row (launch-vehicle unit).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AccelSample {
    /// Velocity increment along the sensitive axis over the sample interval, m/s.
    pub dv_m_s: f64,
    /// Temperature, °C.
    pub t_degc: f64,
    /// Status bits (`docs/ICD.md`, accelerometer sample frame).
    pub status: u8,
}

/// One GNSS fix (launch-vehicle unit), what the GNSS frame (kind 0x21) carries.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GnssSample {
    /// The instant the fix holds, µs of unit time (re-based).
    pub time_us: u64,
    /// Status bits (`ssis::frames::gnss::status`: valid, 3-D, receiver fault).
    pub status: u8,
    /// Satellites in the solution.
    pub satellites: u8,
    /// ECEF position, m.
    pub r_e_m: Vector3<f64>,
    /// ECEF velocity (relative to the Earth), m/s.
    pub v_e_m_s: Vector3<f64>,
    /// Position 1σ per axis, m.
    pub sigma_pos_m: f64,
    /// Velocity 1σ per axis, m/s.
    pub sigma_vel_m_s: f64,
}

/// Truth at the end of a sample.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TruthRow {
    /// Λ of the ICS in the 2ECS (spacecraft); q_eb, the body in ECEF (launch vehicle).
    pub q: Quaternion<f64>,
    /// Body rate in ICS components, rad/s (zero when the log has none).
    pub rate_rad_s: Vector3<f64>,
    /// Launch vehicle: ECEF position, m, and velocity relative to the Earth, m/s.
    pub pos_vel: Option<(Vector3<f64>, Vector3<f64>)>,
}

/// One step of the unit: the samples that arrive for it.
#[derive(Debug, Clone, Default)]
pub struct LogStep {
    /// Per FOG slot, its sample (`None`: not in the log for this step).
    pub fog: [Option<FogSample>; N_FOG],
    /// Per accelerometer (X, Y, Z), its sample (launch vehicle; `None`: not in the log).
    pub accel: [Option<AccelSample>; N_ACCEL],
    /// Star-tracker solutions delivered in this step.
    pub st: Vec<StarSample>,
    /// GNSS fixes delivered in this step (launch vehicle).
    pub gnss: Vec<GnssSample>,
    /// Truth at the step's end, if the log has it.
    pub truth: Option<TruthRow>,
}

/// The unit a log is for, told from its columns (or frames) and checked against its
/// sample interval.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LogUnit {
    /// Four FOGs and a star tracker, 5 ms.
    Spacecraft,
    /// Three FOGs, three accelerometers and a GNSS receiver, 1.25 ms.
    LaunchVehicle,
}

impl LogUnit {
    /// The unit's profile (its sample interval and FOGs).
    pub fn profile(self) -> Profile {
        match self {
            LogUnit::Spacecraft => Profile::SPACECRAFT,
            LogUnit::LaunchVehicle => Profile::LAUNCH_VEHICLE,
        }
    }

    /// Its name in messages.
    pub fn name(self) -> &'static str {
        match self {
            LogUnit::Spacecraft => "spacecraft",
            LogUnit::LaunchVehicle => "launch-vehicle",
        }
    }
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
    /// The unit it is for.
    pub unit: LogUnit,
    /// Launch vehicle: the navigation's initial state at unit time 0 (the pad
    /// initialisation block's q_eb, v_e, r_e), from the `init_*` columns; `None` in a
    /// capture (give it apart).
    pub init: Option<NavState>,
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
    /// GNSS fix time tags that repeat or go back: dropped.
    pub gnss_time_backward: Damage,
}

impl Problems {
    /// Each kind with its name, in the order of a report.
    pub fn kinds(&self) -> [(&'static str, &Damage); 12] {
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
            ("gnss_time_tags_repeated_or_backward", &self.gnss_time_backward),
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

/// Reads a log: one CSV file, or one or more capture files (any other name than `.csv`),
/// for the unit whose sample interval is `dt_us`: a log for the other unit is refused.
pub fn read(paths: &[PathBuf], dt_us: u32) -> Result<Recorded> {
    let rec = read_log(paths)?;
    let want = if dt_us == Profile::LAUNCH_VEHICLE.dt_us { LogUnit::LaunchVehicle } else { LogUnit::Spacecraft };
    if rec.unit != want {
        bail!(
            "{}: a {} log ({}); this replays the {} unit only",
            rec.origin,
            rec.unit.name(),
            match rec.unit {
                LogUnit::LaunchVehicle => "accelerometer columns or frames",
                LogUnit::Spacecraft => "no accelerometer columns or frames",
            },
            want.name()
        );
    }
    Ok(rec)
}

/// Reads a log for whichever unit it is for (the launch vehicle's when it has
/// accelerometer, GNSS, position-truth or initial-state columns, or accelerometer or GNSS
/// frames; else the spacecraft's); its sample interval must be that unit's.
pub fn read_log(paths: &[PathBuf]) -> Result<Recorded> {
    match paths {
        [] => bail!("no log given"),
        [p] if is_csv(p) => read_csv(p),
        ps => {
            if let Some(p) = ps.iter().find(|p| is_csv(p)) {
                bail!("{}: a CSV log is replayed alone (captures may be given together)", p.display());
            }
            read_captures(ps)
        }
    }
}

/// Whether `p` names a CSV log (else a capture).
pub fn is_csv(p: &Path) -> bool {
    p.extension().is_some_and(|e| e.eq_ignore_ascii_case("csv"))
}

/// Column names of an x, y, z triple: `{prefix}x{suffix}` ….
pub fn xyz_names(prefix: &str, suffix: &str) -> [String; 3] {
    ["x", "y", "z"].map(|a| format!("{prefix}{a}{suffix}"))
}

/// Columns of a CSV log, by index.
#[derive(Debug, Default)]
struct Columns {
    t: Option<usize>,
    fog_dtheta: [Option<usize>; N_FOG],
    fog_counter: [Option<usize>; N_FOG],
    fog_t: [Option<usize>; N_FOG],
    fog_status: [Option<usize>; N_FOG],
    acc_dv: [Option<usize>; N_ACCEL],
    acc_counter: [Option<usize>; N_ACCEL],
    acc_t: [Option<usize>; N_ACCEL],
    acc_status: [Option<usize>; N_ACCEL],
    st_t: Option<usize>,
    st_valid: Option<usize>,
    st_q: [Option<usize>; 4],
    gnss_t: Option<usize>,
    gnss_valid: Option<usize>,
    gnss_status: Option<usize>,
    gnss_sats: Option<usize>,
    gnss_r: [Option<usize>; 3],
    gnss_v: [Option<usize>; 3],
    gnss_sigma_pos: Option<usize>,
    gnss_sigma_vel: Option<usize>,
    true_q: [Option<usize>; 4],
    true_w: [Option<usize>; 3],
    true_r: [Option<usize>; 3],
    true_v: [Option<usize>; 3],
    init_q: [Option<usize>; 4],
    init_r: [Option<usize>; 3],
    init_v: [Option<usize>; 3],
    unit: Option<LogUnit>,
}

/// Whether some but not all of `cols` are present.
fn partial(cols: &[Option<usize>]) -> bool {
    cols.iter().any(Option::is_some) && cols.iter().any(Option::is_none)
}

impl Columns {
    /// The columns of CSV header line `ln` of `origin`, and which unit's log it is.
    fn parse(header: &str, origin: &str, ln: usize) -> Result<Columns> {
        let mut c = Columns::default();
        for (k, name) in header.split(',').map(str::trim).enumerate() {
            c.place(k, name, origin, ln)?;
        }
        let at = format!("{origin}: line {ln}");
        c.unit = Some(c.unit_of(&at)?);
        Ok(c)
    }

    /// Notes column `k` named `name` (ignored if it is none of the log's).
    fn place(&mut self, k: usize, name: &str, origin: &str, ln: usize) -> Result<()> {
        let c = self;
        let slot = |prefix: &str, suffix: &str, n: usize| -> Option<usize> {
            let mid = name.strip_prefix(prefix)?.strip_suffix(suffix)?;
            mid.parse::<usize>().ok().filter(|&i| i < n)
        };
        let axis = |prefix: &str, suffix: &str| xyz_names(prefix, suffix).iter().position(|n| n == name);
        let set = |col: &mut Option<usize>| *col = Some(k);
        match name {
            "t_s" => set(&mut c.t),
            "st_t_s" => set(&mut c.st_t),
            "st_valid" => set(&mut c.st_valid),
            "gnss_t_s" => set(&mut c.gnss_t),
            "gnss_valid" => set(&mut c.gnss_valid),
            "gnss_status" => set(&mut c.gnss_status),
            "gnss_satellites" => set(&mut c.gnss_sats),
            "gnss_sigma_pos_m" => set(&mut c.gnss_sigma_pos),
            "gnss_sigma_vel_m_s" => set(&mut c.gnss_sigma_vel),
            _ => {
                let found: Option<&mut Option<usize>> = if let Some(i) = slot("fog", "_dtheta_rad", N_FOG) {
                    Some(&mut c.fog_dtheta[i])
                } else if let Some(i) = slot("fog", "_counter", N_FOG) {
                    Some(&mut c.fog_counter[i])
                } else if let Some(i) = slot("fog", "_t_degc", N_FOG) {
                    Some(&mut c.fog_t[i])
                } else if let Some(i) = slot("fog", "_status", N_FOG) {
                    Some(&mut c.fog_status[i])
                } else if let Some(i) = slot("acc", "_dv_m_s", N_ACCEL) {
                    Some(&mut c.acc_dv[i])
                } else if let Some(i) = slot("acc", "_counter", N_ACCEL) {
                    Some(&mut c.acc_counter[i])
                } else if let Some(i) = slot("acc", "_t_degc", N_ACCEL) {
                    Some(&mut c.acc_t[i])
                } else if let Some(i) = slot("acc", "_status", N_ACCEL) {
                    Some(&mut c.acc_status[i])
                } else if let Some(i) = slot("st_q", "", 4) {
                    Some(&mut c.st_q[i])
                } else if let Some(i) = slot("true_q", "", 4) {
                    Some(&mut c.true_q[i])
                } else if let Some(i) = slot("init_q", "", 4) {
                    Some(&mut c.init_q[i])
                } else if let Some(i) = axis("true_w", "_rad_s") {
                    Some(&mut c.true_w[i])
                } else if let Some(i) = axis("gnss_", "_m") {
                    Some(&mut c.gnss_r[i])
                } else if let Some(i) = axis("gnss_v", "_m_s") {
                    Some(&mut c.gnss_v[i])
                } else if let Some(i) = axis("true_", "_m") {
                    Some(&mut c.true_r[i])
                } else if let Some(i) = axis("true_v", "_m_s") {
                    Some(&mut c.true_v[i])
                } else if let Some(i) = axis("init_", "_m") {
                    Some(&mut c.init_r[i])
                } else if let Some(i) = axis("init_v", "_m_s") {
                    Some(&mut c.init_v[i])
                } else if (name.starts_with("fog") || name.starts_with("acc"))
                    && (name.ends_with("_deg") || name.ends_with("_arcsec") || name.ends_with("_g"))
                {
                    bail!(
                        "{origin}: line {ln}, column {} ({name}): increments are in rad and m/s \
                             (`fogN_dtheta_rad`, `accN_dv_m_s`)",
                        k + 1
                    );
                } else {
                    // Anything else (the user's own columns) is ignored.
                    None
                };
                if let Some(col) = found {
                    set(col);
                }
            }
        }
        Ok(())
    }

    /// Which unit's log the columns make (launch vehicle if any of its own columns is
    /// there), after checking that the columns each sensor needs are all there.
    fn unit_of(&self, at: &str) -> Result<LogUnit> {
        let c = self;
        if c.fog_dtheta.iter().all(Option::is_none) {
            bail!("{at}: no FOG column (`fog0_dtheta_rad` … `fog3_dtheta_rad`)");
        }
        if c.t.is_none() && c.fog_counter.iter().all(Option::is_none) {
            bail!("{at}: neither `t_s` nor a FOG counter (`fogN_counter`): no time for the samples");
        }
        let gnss_cols = [c.gnss_t, c.gnss_r[0], c.gnss_r[1], c.gnss_r[2], c.gnss_v[0], c.gnss_v[1], c.gnss_v[2]];
        let gnss_all = [&gnss_cols[..], &[c.gnss_sigma_pos, c.gnss_sigma_vel]].concat();
        let lv_named = [
            &c.acc_dv[..],
            &c.acc_counter,
            &c.acc_t,
            &c.acc_status,
            &gnss_all,
            &[c.gnss_valid, c.gnss_status, c.gnss_sats],
            &c.true_r,
            &c.true_v,
            &c.init_q,
            &c.init_r,
            &c.init_v,
        ]
        .concat();
        let lv = lv_named.iter().any(Option::is_some);
        if lv {
            if c.acc_dv.iter().all(Option::is_none) {
                bail!(
                    "{at}: launch-vehicle columns (GNSS, position truth or initial state) but no accelerometer \
                     column (`acc0_dv_m_s` … `acc2_dv_m_s`): a launch-vehicle log needs its accelerometers"
                );
            }
            if c.fog_dtheta[3].is_some() {
                bail!(
                    "{at}: `fog3_dtheta_rad` in a launch-vehicle log (accelerometer columns): that unit has three \
                     FOGs, `fog0` … `fog2` (X, Y, Z)"
                );
            }
            if c.st_t.is_some() || c.st_q.iter().any(Option::is_some) {
                bail!("{at}: star-tracker columns in a launch-vehicle log: that unit has no star tracker");
            }
            if partial(&gnss_all) {
                bail!(
                    "{at}: a GNSS receiver needs `gnss_t_s`, `gnss_x_m` … `gnss_z_m`, `gnss_vx_m_s` … `gnss_vz_m_s`, \
                     `gnss_sigma_pos_m` and `gnss_sigma_vel_m_s`"
                );
            }
            let truth = [&c.true_q[..], &c.true_r, &c.true_v].concat();
            if partial(&truth) {
                bail!(
                    "{at}: launch-vehicle truth needs all of `true_q0` … `true_q3` (q_eb), `true_x_m` … `true_z_m` \
                     and `true_vx_m_s` … `true_vz_m_s`"
                );
            }
            let init = [&c.init_q[..], &c.init_r, &c.init_v].concat();
            if partial(&init) {
                bail!(
                    "{at}: the initial state needs all of `init_q0` … `init_q3`, `init_x_m` … `init_z_m` and \
                     `init_vx_m_s` … `init_vz_m_s`"
                );
            }
            Ok(LogUnit::LaunchVehicle)
        } else {
            let st_any = c.st_t.is_some() || c.st_q.iter().any(Option::is_some);
            if st_any && (c.st_t.is_none() || c.st_q.iter().any(Option::is_none)) {
                bail!("{at}: a star tracker needs `st_t_s` and `st_q0` … `st_q3`");
            }
            if partial(&c.true_q) {
                bail!("{at}: truth needs all of `true_q0` … `true_q3`");
            }
            Ok(LogUnit::Spacecraft)
        }
    }
}

/// A CSV row before it is placed on the unit's clock.
struct RawRow {
    line: usize,
    t_s: Option<f64>,
    counter: [Option<u16>; N_FOG],
    fog: [Option<FogSample>; N_FOG],
    acc_counter: [Option<u16>; N_ACCEL],
    accel: [Option<AccelSample>; N_ACCEL],
    st: Option<(f64, bool, [f64; 4])>,
    /// A GNSS fix with its tag, s of log time (`time_us` not yet set); boxed, as is
    /// `init`: both are rare (launch vehicle), and a row is moved several times.
    gnss: Option<Box<(f64, GnssSample)>>,
    truth: Option<TruthRow>,
    init: Option<Box<NavState>>,
}

/// Column names in messages, spelt out once (a row's parse allocates none).
mod names {
    pub const FOG_DTHETA: [&str; 4] = ["fog0_dtheta_rad", "fog1_dtheta_rad", "fog2_dtheta_rad", "fog3_dtheta_rad"];
    pub const FOG_COUNTER: [&str; 4] = ["fog0_counter", "fog1_counter", "fog2_counter", "fog3_counter"];
    pub const FOG_T: [&str; 4] = ["fog0_t_degc", "fog1_t_degc", "fog2_t_degc", "fog3_t_degc"];
    pub const FOG_STATUS: [&str; 4] = ["fog0_status", "fog1_status", "fog2_status", "fog3_status"];
    pub const ACC_DV: [&str; 3] = ["acc0_dv_m_s", "acc1_dv_m_s", "acc2_dv_m_s"];
    pub const ACC_COUNTER: [&str; 3] = ["acc0_counter", "acc1_counter", "acc2_counter"];
    pub const ACC_T: [&str; 3] = ["acc0_t_degc", "acc1_t_degc", "acc2_t_degc"];
    pub const ACC_STATUS: [&str; 3] = ["acc0_status", "acc1_status", "acc2_status"];
    pub const ST_Q: [&str; 4] = ["st_q0", "st_q1", "st_q2", "st_q3"];
    pub const TRUE_Q: [&str; 4] = ["true_q0", "true_q1", "true_q2", "true_q3"];
    pub const INIT_Q: [&str; 4] = ["init_q0", "init_q1", "init_q2", "init_q3"];
    pub const TRUE_W: [&str; 3] = ["true_wx_rad_s", "true_wy_rad_s", "true_wz_rad_s"];
    pub const GNSS_R: [&str; 3] = ["gnss_x_m", "gnss_y_m", "gnss_z_m"];
    pub const GNSS_V: [&str; 3] = ["gnss_vx_m_s", "gnss_vy_m_s", "gnss_vz_m_s"];
    pub const TRUE_R: [&str; 3] = ["true_x_m", "true_y_m", "true_z_m"];
    pub const TRUE_V: [&str; 3] = ["true_vx_m_s", "true_vy_m_s", "true_vz_m_s"];
    pub const INIT_R: [&str; 3] = ["init_x_m", "init_y_m", "init_z_m"];
    pub const INIT_V: [&str; 3] = ["init_vx_m_s", "init_vy_m_s", "init_vz_m_s"];
}

/// A field's number: ASCII parsed as it is (`fast-float2`, correctly rounded as
/// `str::parse`), a field with other bytes (or a vertical tab, which `str::trim` trims and
/// `trim_ascii` does not) as text, Unicode spaces trimmed; `Err` with the field's text
/// when it is not a number.
fn field_number(f: &[u8]) -> Result<Option<f64>, String> {
    // An empty field (most of a compact log's: the star and truth columns between their
    // rows) is absent at once; a plain number parses whole as it is (only ASCII without
    // spaces does): no scans first.
    if f.is_empty() {
        return Ok(None);
    }
    if let Ok(v) = fast_float2::parse::<f64, _>(f) {
        return Ok(Some(v));
    }
    if f.is_ascii() && !f.contains(&0x0b) {
        let f = f.trim_ascii();
        if f.is_empty() {
            return Ok(None);
        }
        return fast_float2::parse::<f64, _>(f).map(Some).map_err(|_| String::from_utf8_lossy(f).into_owned());
    }
    let text = String::from_utf8_lossy(f);
    let t = text.trim();
    if t.is_empty() {
        return Ok(None);
    }
    t.parse::<f64>().map(Some).map_err(|_| t.to_string())
}

/// One row's fields (`fields`: byte ranges of `line`); a value that is not a finite
/// number is counted and left out.
fn parse_row(
    line: &[u8],
    fields: &[std::ops::Range<usize>],
    c: &Columns,
    ln: usize,
    origin: &str,
    p: &mut Problems,
) -> RawRow {
    let p = std::cell::RefCell::new(p);
    let num = |col: Option<usize>, name: &str| -> Option<f64> {
        let f = line.get(fields.get(col?)?.clone())?;
        let bad = match field_number(f) {
            Ok(None) => return None,
            Ok(Some(v)) if v.is_finite() => return Some(v),
            Ok(Some(_)) => String::from_utf8_lossy(f.trim_ascii()).into_owned(),
            Err(text) => text,
        };
        p.borrow_mut().bad_values.add(1, || format!("{origin}:{ln}: field {name} = {bad:?} is not a finite number"));
        None
    };
    let t_s = num(c.t, "t_s");
    let mut counter = [None; N_FOG];
    let mut fog = [None; N_FOG];
    let u16_of = |v: f64| v.rem_euclid(65536.0) as u16;
    let u8_of = |v: f64| v.clamp(0.0, 255.0) as u8;
    for i in 0..N_FOG {
        counter[i] = num(c.fog_counter[i], names::FOG_COUNTER[i]).map(u16_of);
        let t = num(c.fog_t[i], names::FOG_T[i]).unwrap_or(25.0);
        let status = num(c.fog_status[i], names::FOG_STATUS[i]).unwrap_or(0.0);
        fog[i] = num(c.fog_dtheta[i], names::FOG_DTHETA[i]).map(|d| FogSample {
            dtheta_rad: d,
            t_degc: t,
            status: u8_of(status),
        });
    }
    let mut acc_counter = [None; N_ACCEL];
    let mut accel = [None; N_ACCEL];
    for i in 0..N_ACCEL {
        acc_counter[i] = num(c.acc_counter[i], names::ACC_COUNTER[i]).map(u16_of);
        let t = num(c.acc_t[i], names::ACC_T[i]).unwrap_or(25.0);
        let status = num(c.acc_status[i], names::ACC_STATUS[i]).unwrap_or(0.0);
        accel[i] =
            num(c.acc_dv[i], names::ACC_DV[i]).map(|d| AccelSample { dv_m_s: d, t_degc: t, status: u8_of(status) });
    }
    let vec3 = |cols: &[Option<usize>; 3], names: [&str; 3]| -> Option<Vector3<f64>> {
        let v = [0, 1, 2].map(|k| num(cols[k], names[k]));
        Some(Vector3::new(v[0]?, v[1]?, v[2]?))
    };
    let gnss = (|| {
        let t = num(c.gnss_t, "gnss_t_s")?;
        let r = vec3(&c.gnss_r, names::GNSS_R)?;
        let v = vec3(&c.gnss_v, names::GNSS_V)?;
        let mut status =
            num(c.gnss_status, "gnss_status").map_or(gnss::status::FIX_VALID | gnss::status::FIX_3D, u8_of);
        match num(c.gnss_valid, "gnss_valid") {
            Some(0.0) => status &= !gnss::status::FIX_VALID,
            Some(_) => status |= gnss::status::FIX_VALID,
            None => {}
        }
        let satellites = num(c.gnss_sats, "gnss_satellites").map_or(0, u8_of);
        let sigma_pos_m = num(c.gnss_sigma_pos, "gnss_sigma_pos_m")?;
        let sigma_vel_m_s = num(c.gnss_sigma_vel, "gnss_sigma_vel_m_s")?;
        Some((t, GnssSample { time_us: 0, status, satellites, r_e_m: r, v_e_m_s: v, sigma_pos_m, sigma_vel_m_s }))
    })();
    let init = (|| {
        let q = [0, 1, 2, 3].map(|k| num(c.init_q[k], names::INIT_Q[k]));
        let q = Quaternion::new(q[0]?, q[1]?, q[2]?, q[3]?);
        let r_e_m = vec3(&c.init_r, names::INIT_R)?;
        let v_e_m_s = vec3(&c.init_v, names::INIT_V)?;
        // Kept as written when it is a unit quaternion to the last bits (a pad block
        // written out exactly replays to the same output); else normalised.
        let q = if (q.norm() - 1.0).abs() > 1e-12 { q / q.norm() } else { q };
        Some(NavState { q_eb: q, v_e_m_s, r_e_m })
    })();
    let pos_vel = (|| Some((vec3(&c.true_r, names::TRUE_R)?, vec3(&c.true_v, names::TRUE_V)?)))();
    let st = num(c.st_t, "st_t_s").and_then(|t| {
        let valid = num(c.st_valid, "st_valid").is_none_or(|v| v != 0.0);
        let q = [0, 1, 2, 3].map(|k| num(c.st_q[k], names::ST_Q[k]));
        Some((t, valid, [q[0]?, q[1]?, q[2]?, q[3]?]))
    });
    let lv = c.unit == Some(LogUnit::LaunchVehicle);
    let truth = (|| {
        let q = [0, 1, 2, 3].map(|k| num(c.true_q[k], names::TRUE_Q[k]));
        let w = [0, 1, 2].map(|k| num(c.true_w[k], names::TRUE_W[k]));
        let q = Quaternion::new(q[0]?, q[1]?, q[2]?, q[3]?);
        if lv && pos_vel.is_none() {
            return None;
        }
        Some(TruthRow {
            q: q / q.norm(),
            rate_rad_s: Vector3::new(w[0].unwrap_or(0.0), w[1].unwrap_or(0.0), w[2].unwrap_or(0.0)),
            pos_vel,
        })
    })();
    RawRow {
        line: ln,
        t_s,
        counter,
        fog,
        acc_counter,
        accel,
        st,
        gnss: gnss.map(Box::new),
        truth,
        init: init.map(Box::new),
    }
}

/// Counts a sample counter that does not advance with the time (`name` in messages).
fn check_counters<const N: usize>(
    counters: &[Option<u16>; N],
    last: &mut [Option<(u64, u16)>; N],
    n: u64,
    name: &str,
    jumps: &mut Damage,
    at: &dyn Fn() -> String,
) {
    for (i, c) in counters.iter().enumerate() {
        if let (Some(c), Some((ln, lc))) = (c, last[i]) {
            if c.wrapping_sub(lc) as u64 != n - ln {
                jumps.add(1, || format!("{}: {name}{i}_counter {c} after {lc}", at()));
            }
        }
        if let Some(c) = c {
            last[i] = Some((n, *c));
        }
    }
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

/// Frames found in captures, each with its byte offset; star and GNSS frames also with
/// the number of FOG frames decoded before them in the same file (a logger that merges
/// the links records when each arrived).
#[derive(Default)]
struct Scanned {
    fog: Vec<(usize, FogFrame)>,
    acc: Vec<(usize, AccelFrame)>,
    st: Vec<(usize, StarFrame, Option<usize>)>,
    gnss: Vec<(usize, GnssFrame, Option<usize>)>,
}

/// Reads raw captures of the links (FOG bus, star tracker, accelerometer bus, GNSS
/// receiver; one file or several, frames whole or not): FOG frames grouped by their
/// counter, accelerometer frames by theirs (the first accelerometer sample with the first
/// FOG sample), star and GNSS frames by their time tags. Accelerometer or GNSS frames
/// make it a launch-vehicle capture (which carries no initial state: `init` is `None`).
pub fn read_captures(paths: &[PathBuf]) -> Result<Recorded> {
    let mut p = Problems::default();
    let mut sc = Scanned::default();
    for path in paths {
        let bytes = std::fs::read(path).with_context(|| format!("cannot read {}", path.display()))?;
        let name = path.display().to_string();
        scan_capture(&bytes, &name, &mut p, &mut sc);
    }
    let origin = paths.iter().map(|p| p.display().to_string()).collect::<Vec<_>>().join(" + ");
    if sc.fog.is_empty() {
        bail!("{origin}: nothing usable: no FOG frame decoded\n{}", p.report());
    }
    let unit = if sc.acc.is_empty() && sc.gnss.is_empty() { LogUnit::Spacecraft } else { LogUnit::LaunchVehicle };
    if unit == LogUnit::LaunchVehicle && sc.acc.is_empty() {
        bail!("{origin}: GNSS frames but no accelerometer frame (kind 0x11): a launch-vehicle capture needs them");
    }
    let dt_us = unit.profile().dt_us;
    // Samples by unwrapped counter, in capture order.
    let fog = group_by_counter(&sc.fog, |f| (f.counter, usize::from(f.fog_id), "FOG"), &mut p);
    let mut fogs = 0u8;
    for s in fog.by_sample.values() {
        for (i, f) in s.iter().enumerate() {
            if f.is_some() {
                fogs |= 1 << i;
            }
        }
    }
    let first = *fog.by_sample.keys().next().unwrap_or(&0);
    let dt = u64::from(dt_us);
    // Unit time of the capture's first sample was first·dt; re-based to 1·dt.
    let shift_us = first.saturating_sub(1) * dt;
    let n_last = fog.by_sample.keys().next_back().map_or(0, |k| k - first + 1);
    let mut steps = vec![LogStep::default(); n_last as usize];
    let mut prev: Option<u64> = None;
    for (k, s) in &fog.by_sample {
        let n = k - first + 1;
        if let Some(pn) = prev {
            if n > pn + 1 {
                let lost = n - pn - 1;
                p.gaps.add(lost, || format!("counter jump: {lost} samples missing before sample {n}"));
            }
        }
        prev = Some(n);
        steps[n as usize - 1].fog = s.map(|f| {
            f.map(|f| FogSample { dtheta_rad: f.dtheta_rad(), t_degc: f.temperature_degc(), status: f.status })
        });
    }
    let acc = group_by_counter(&sc.acc, |f| (f.counter, usize::from(f.accel_id), "accelerometer"), &mut p);
    let acc_first = *acc.by_sample.keys().next().unwrap_or(&0);
    for (k, s) in &acc.by_sample {
        if let Some(step) = steps.get_mut((k - acc_first) as usize) {
            step.accel = std::array::from_fn(|i| {
                s[i].map(|f| AccelSample { dv_m_s: f.dv_m_s(), t_degc: f.temperature_degc(), status: f.status })
            });
        }
    }
    // Delivered with the FOG sample logged before it, or (a capture of its own) in the
    // step whose end is at or after its tag.
    let step_of =
        |after: Option<usize>, us: u64| match after.and_then(|k| k.checked_sub(1)).and_then(|k| fog.sample_of.get(k)) {
            Some(&k) => (k.saturating_sub(first) + 1) as usize,
            None => us.div_ceil(dt).max(1) as usize,
        };
    let rebase = |tag_us: u64, last: &mut Option<u64>, d: &mut Damage, off: usize, what: &str| {
        let Some(us) = tag_us.checked_sub(shift_us) else {
            d.add(1, || format!("byte {off}: {what} time tag {tag_us} µs before the first FOG sample"));
            return None;
        };
        if last.is_some_and(|l| us <= l) {
            d.add(1, || format!("byte {off}: {what} time tag {tag_us} µs not after the previous"));
            return None;
        }
        *last = Some(us);
        Some(us)
    };
    let mut last_st: Option<u64> = None;
    for (off, f, after) in sc.st {
        let Some(us) = rebase(f.time_us, &mut last_st, &mut p.st_time_backward, off, "star") else { continue };
        if let Some(s) = steps.get_mut(step_of(after, us) - 1) {
            s.st.push(StarSample { time_us: us, valid: f.valid(), q: f.quaternion() });
        }
    }
    let mut last_gnss: Option<u64> = None;
    for (off, f, after) in sc.gnss {
        let Some(us) = rebase(f.time_tag_us, &mut last_gnss, &mut p.gnss_time_backward, off, "GNSS") else {
            continue;
        };
        if let Some(s) = steps.get_mut(step_of(after, us) - 1) {
            s.gnss.push(GnssSample {
                time_us: us,
                status: f.status,
                satellites: f.satellites,
                r_e_m: Vector3::from(f.r_counts.map(|c| f64::from(c) * gnss::POS_LSB_M)),
                v_e_m_s: Vector3::from(f.v_counts.map(|c| f64::from(c) * gnss::VEL_LSB_M_S)),
                sigma_pos_m: f64::from(f.sigma_pos_counts) * gnss::SIGMA_POS_LSB_M,
                sigma_vel_m_s: f64::from(f.sigma_vel_counts) * gnss::SIGMA_VEL_LSB_M_S,
            });
        }
    }
    Ok(Recorded {
        origin,
        steps,
        fogs: FogSet(fogs),
        t0_s: shift_us as f64 * 1e-6,
        problems: p,
        has_truth: false,
        unit,
        init: None,
    })
}

/// Frames of one bus grouped into samples by their unwrapped counter (any start).
struct Grouped<F> {
    /// Per sample, the frame of each slot.
    by_sample: BTreeMap<u64, [Option<F>; 4]>,
    /// The sample of each frame, in capture order.
    sample_of: Vec<u64>,
}

/// Groups the frames of one bus (`key`: counter, slot, the sensor's name) by counter;
/// a slot's repeated sample and a sample before the newest but one are counted and
/// dropped.
fn group_by_counter<F: Copy>(
    frames: &[(usize, F)],
    key: impl Fn(&F) -> (u16, usize, &'static str),
    p: &mut Problems,
) -> Grouped<F> {
    let mut unwrap = Unwrap::default();
    let mut g = Grouped { by_sample: BTreeMap::new(), sample_of: Vec::with_capacity(frames.len()) };
    let mut last: Option<u64> = None;
    for (off, f) in frames {
        let (counter, i, what) = key(f);
        let k = unwrap.next(counter);
        g.sample_of.push(k);
        let slot = g.by_sample.entry(k).or_insert([None; 4]);
        if slot[i].is_some() {
            p.repeated_samples.add(1, || format!("byte {off}: {what}{i} counter {counter} again"));
            continue;
        }
        if last.is_some_and(|l| k + 1 < l) {
            p.backward_samples.add(1, || format!("byte {off}: {what}{i} counter {counter} after a later one"));
            continue;
        }
        last = Some(last.map_or(k, |l| l.max(k)));
        slot[i] = Some(*f);
    }
    g
}

/// Scans one capture for frames of the kinds the units read; every byte not in a good
/// frame is counted, and a rejected frame is resynchronised inside (as the unit does).
fn scan_capture(bytes: &[u8], name: &str, p: &mut Problems, sc: &mut Scanned) {
    let fog_before = sc.fog.len();
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
            Some(k) if is_sync && k == AccelFrame::KIND => AccelFrame::LEN,
            Some(k) if is_sync && k == GnssFrame::KIND => GnssFrame::LEN,
            _ => 0,
        };
        let Some(cand) = (len > 0).then(|| bytes.get(i..i + len)).flatten() else {
            skipped_from.get_or_insert(i);
            i += 1;
            continue;
        };
        let seen = sc.fog.len();
        let after = (seen > fog_before).then_some(seen);
        let r = match kind {
            Some(FogFrame::KIND) => FogFrame::decode(cand).map(|f| sc.fog.push((i, f))),
            Some(AccelFrame::KIND) => AccelFrame::decode(cand).map(|f| sc.acc.push((i, f))),
            Some(GnssFrame::KIND) => GnssFrame::decode(cand).map(|f| sc.gnss.push((i, f, after))),
            _ => StarFrame::decode(cand).map(|f| sc.st.push((i, f, after))),
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

#[cfg(test)]
mod tests {
    use super::field_number;
    use rand::{Rng, SeedableRng};

    /// What a field meant when the line was read as text: trimmed, then `str::parse`.
    fn as_text(f: &str) -> Result<Option<f64>, String> {
        let t = f.trim();
        if t.is_empty() {
            return Ok(None);
        }
        t.parse::<f64>().map(Some).map_err(|_| t.to_string())
    }

    #[test]
    fn field_numbers_are_str_parse_bit_for_bit() {
        let fixed = [
            "",
            " ",
            "0",
            "-0",
            "+1.5",
            " 2.25 ",
            ".5",
            "5.",
            "1e5",
            "1E-7",
            "-3.0e+02",
            "1e400",
            "-1e400",
            "1e-400",
            "NaN",
            "nan",
            "inf",
            "-inf",
            "infinity",
            "abc",
            "1.2.3",
            "0x10",
            "1_000",
            "--1",
            "1e",
            "e5",
            "\t7\t",
            "\u{a0}3.5",
            "3.5\u{2003}",
            "\u{0b}7",
            "8\u{0c}",
            "é",
            "1,5",
            "4.9406564584124654e-324",
            "1.7976931348623157e308",
            "0.30000000000000004",
            "123456789012345678901234567890",
        ];
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        let random = (0..20_000).map(|k| {
            let v = f64::from_bits(rng.random::<u64>());
            match k % 4 {
                0 => format!("{v}"),
                1 => format!("{v:e}"),
                2 => format!("{:.9}", v),
                _ => format!("{:.17e}", rng.random::<f64>() * 1e-6),
            }
        });
        for f in fixed.iter().map(|s| s.to_string()).chain(random) {
            let (a, b) = (field_number(f.as_bytes()), as_text(&f));
            match (&a, &b) {
                (Ok(Some(x)), Ok(Some(y))) => assert!(x.to_bits() == y.to_bits() || x.is_nan() && y.is_nan(), "{f:?}"),
                _ => assert_eq!(a, b, "{f:?}"),
            }
        }
    }
}
