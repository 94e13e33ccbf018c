//! The launch-vehicle unit's host side, shared by the QEMU runner
//! (`ssis_runner::qemu_lv`), `ssis-sim replay` on a launch-vehicle log and `ssis-sim
//! record`: the ascent scenario and its sensors as link bytes ([`AscentSensors`]), a
//! recorded log as the same bytes ([`LvFeed`]), the firmware's period on them
//! ([`LvCore`]: `FlightCore::step_with()` + `NavUnit`, then `NavUnit::filter_work()`), and
//! what the navigation output frames say against truth or on their own ([`NavEvidence`]).
//!
//! Writing each of these once keeps the host replay, the QEMU runner's in-process
//! reference and the recorded-log writer on one code path: a log written from a scenario
//! replays to the same output frames as the scenario itself.

use std::io::Write;
use std::path::Path;

use anyhow::{Context, Result};
use nalgebra::Vector3;
use rand::SeedableRng;
use rand_chacha::ChaCha20Rng;
use serde::{Deserialize, Serialize};
use ssis::calib::accel::{AccelTable, N_ACCEL};
use ssis::calib::CalibrationTable;
use ssis::flight::{FlightCore, FogLinks, Links, Profile};
use ssis::frames::accel::AccelFrame;
use ssis::frames::decoder::StreamDecoder;
use ssis::frames::fog::FogFrame;
use ssis::frames::gnss::{self, status, GnssFrame};
use ssis::frames::navout::{flags, NavOutputFrame};
use ssis::frames::output::OutputFrame;
use ssis::frames::Frame;
use ssis::link::NotFitted;
use ssis::math::rotvec_from_quat;
use ssis::nav::gnss::GnssFix;
use ssis::nav::init::PadInit;
use ssis::nav::snapshot::{NavResumeError, NavSnapshot};
use ssis::nav::unit::{FilterWork, NavLinks, NavUnit};
use ssis::nav::NavState;
use ssis_common::mock::{MockLink, MockSink};
use ssis_common::stats::AxisStats;
use ssis_common::ARCSEC_PER_RAD;

use crate::accel::{AccelModel, AccelSpec};
use crate::fog::{FogModel, FogSpec};
use crate::gnss::GnssSpec;
use crate::launch::{LaunchProfile, LaunchTruth};
use crate::lv::{angle_between, filter_config};
use crate::recorded::{LogUnit, Recorded};
use crate::replay::OutputHash;

/// The `kind` of a launch-vehicle ascent scenario file.
pub const KIND: &str = "lv-ascent";

/// A launch-vehicle ascent scenario (`host-tests/scenarios/lv-ascent.toml`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LvScenario {
    /// Always [`KIND`].
    pub kind: String,
    /// Short name.
    pub name: String,
    /// What it shows.
    #[serde(default)]
    pub description: String,
    /// Simulated time from lift-off, s.
    pub duration_s: f64,
    /// Seed of every random draw.
    #[serde(default)]
    pub seed: u64,
    /// The ascent.
    #[serde(default)]
    pub launch: LaunchProfile,
    /// FOG errors (FOG1..FOG3, the orthogonal triad, are fitted).
    #[serde(default)]
    pub fog: FogSpec,
    /// Accelerometer errors.
    #[serde(default)]
    pub accel: AccelSpec,
    /// GNSS receiver (none if absent).
    #[serde(default)]
    pub gnss: Option<GnssSpec>,
}

impl LvScenario {
    /// Reads and checks a scenario file.
    pub fn from_file(path: &Path) -> Result<Self> {
        let text = std::fs::read_to_string(path).with_context(|| format!("cannot read scenario {}", path.display()))?;
        let sc: LvScenario = toml::from_str(&text).map_err(|e| anyhow::anyhow!("{}: {}", path.display(), e))?;
        anyhow::ensure!(sc.kind == KIND, "{}: kind must be \"{KIND}\"", path.display());
        anyhow::ensure!(sc.duration_s > 0.0 && sc.duration_s.is_finite(), "duration_s must be > 0");
        Ok(sc)
    }

    /// Whether the scenario file at `path` is a launch-vehicle ascent (its `kind`).
    pub fn is_lv_file(path: &Path) -> bool {
        std::fs::read_to_string(path)
            .ok()
            .and_then(|t| toml::from_str::<toml::Table>(&t).ok())
            .and_then(|t| t.get("kind").and_then(|k| k.as_str().map(|k| k == KIND)))
            .unwrap_or(false)
    }
}

/// The pad initialisation block for a run from `state`: the GNSS filter tuned to the
/// paper's FOGs and the assumed pendulous accelerometers (`docs/LAUNCH-VEHICLE.md`).
pub fn pad_init(state: NavState) -> PadInit {
    PadInit {
        revision: 1,
        state,
        gnss: filter_config(&FogSpec::paper_post_calibration(), &AccelSpec::typical_pendulous()),
    }
}

/// The pad initialisation block a launch-vehicle replay starts from: the block in file
/// `pad` (`SSPI`, as the firmware's flash holds it), else the log's initial state (its
/// `init_*` columns) with the default filter tuning ([`pad_init`]).
pub fn pad_for(rec: &Recorded, pad: Option<&Path>) -> Result<PadInit> {
    if let Some(p) = pad {
        let bytes = std::fs::read(p).with_context(|| format!("cannot read {}", p.display()))?;
        return PadInit::from_bytes(&bytes)
            .map_err(|e| anyhow::anyhow!("{}: not a pad initialisation block ({e:?})", p.display()));
    }
    match rec.init {
        Some(state) => Ok(pad_init(state)),
        None => anyhow::bail!(
            "{}: no initial state: a launch-vehicle log needs the `init_*` columns (docs/RECORDED-LOG.md), and a \
             capture carries none: give the pad initialisation block with --pad FILE",
            rec.origin
        ),
    }
}

/// One step's bytes per link and the truth at its end.
#[derive(Debug, Clone, Default)]
pub struct LvStepBytes {
    /// FOG bus (FOG1..FOG3 frames).
    pub fog: Vec<u8>,
    /// Accelerometer bus (X, Y, Z frames).
    pub accel: Vec<u8>,
    /// GNSS receiver (a fix frame in the steps that have one).
    pub gnss: Vec<u8>,
    /// Truth at the step's end, if known.
    pub truth: Option<NavState>,
}

/// The sensor side of an ascent scenario: truth, FOG, accelerometer and GNSS models,
/// frame bytes.
pub struct AscentSensors {
    truth: LaunchTruth,
    fogs: FogModel,
    accels: AccelModel,
    gnss: Option<GnssSpec>,
    rng: ChaCha20Rng,
    gnss_rng: ChaCha20Rng,
    gnss_counter: u16,
    dt_s: f64,
}

impl AscentSensors {
    /// The sensors of `sc` at the launch vehicle's step.
    pub fn new(sc: &LvScenario) -> Self {
        let dt_s = Profile::LAUNCH_VEHICLE.dt_s();
        let mut rng = ChaCha20Rng::seed_from_u64(sc.seed);
        let fogs = FogModel::new(&sc.fog, &mut rng);
        let accels = AccelModel::new(&sc.accel, &mut rng);
        AscentSensors {
            truth: LaunchTruth::new(sc.launch.clone(), dt_s),
            fogs,
            accels,
            gnss: sc.gnss.clone(),
            rng,
            gnss_rng: ChaCha20Rng::seed_from_u64(sc.seed.wrapping_add(1_000_003)),
            gnss_counter: 0,
            dt_s,
        }
    }

    /// The truth now (the pad state before the first step).
    pub fn initial(&self) -> NavState {
        let (q_eb, v_e_m_s, r_e_m) = self.truth.state_now();
        NavState { q_eb, v_e_m_s, r_e_m }
    }

    /// Step `k` (1-based).
    pub fn step(&mut self, k: u64) -> LvStepBytes {
        let s = self.truth.advance();
        let t_end = s.t_s;
        let fs = self.fogs.sample(&s.dtheta_rad, t_end, self.dt_s, &mut self.rng);
        let mut fog = Vec::with_capacity(3 * FogFrame::LEN);
        for (i, f) in fs.frames.iter().enumerate() {
            if Profile::LAUNCH_VEHICLE.fogs.contains(i) {
                fog.extend_from_slice(&f.to_bytes());
            }
        }
        let mut accel = Vec::with_capacity(N_ACCEL * AccelFrame::LEN);
        for f in self.accels.sample(&s.dv_m_s, t_end, self.dt_s, &mut self.rng) {
            accel.extend_from_slice(&f.to_bytes());
        }
        let truth = NavState { q_eb: s.q_eb, v_e_m_s: s.v_e_m_s, r_e_m: s.r_e_m };
        let mut gnss = Vec::new();
        if let Some(spec) = &self.gnss {
            if let Some(fix) = spec.fix(k, self.dt_s, &truth, &mut self.gnss_rng) {
                let t_us = k * u64::from(Profile::LAUNCH_VEHICLE.dt_us);
                let g = GnssFrame::from_physical(status::FIX_VALID | status::FIX_3D, self.gnss_counter, 10, t_us, &fix);
                self.gnss_counter = self.gnss_counter.wrapping_add(1);
                gnss.extend_from_slice(&g.to_bytes());
            }
        }
        LvStepBytes { fog, accel, gnss, truth: Some(truth) }
    }
}

/// A recorded launch-vehicle log as the unit's links carry it, step by step: FOG and
/// accelerometer frames numbered from counter 1, GNSS frames at their re-based tags.
pub struct LvFeed<'a> {
    rec: &'a Recorded,
    n: u64,
    gnss_counter: u16,
}

impl<'a> LvFeed<'a> {
    /// Steps of the launch-vehicle log `rec`.
    pub fn new(rec: &'a Recorded) -> LvFeed<'a> {
        LvFeed { rec, n: 0, gnss_counter: 0 }
    }

    /// Steps in the log.
    pub fn steps(&self) -> u64 {
        self.rec.steps.len() as u64
    }

    /// The next step's bytes and truth, or `None` at the end.
    pub fn next_step(&mut self) -> Option<LvStepBytes> {
        let step = self.rec.steps.get(self.n as usize)?;
        self.n += 1;
        let counter = (self.n % 65_536) as u16;
        let mut b = LvStepBytes::default();
        for (i, s) in step.fog.iter().enumerate() {
            if let Some(s) = s.filter(|_| Profile::LAUNCH_VEHICLE.fogs.contains(i)) {
                let f = FogFrame::from_physical(i as u8, counter, s.status, s.dtheta_rad, s.t_degc);
                b.fog.extend_from_slice(&f.to_bytes());
            }
        }
        for (i, s) in step.accel.iter().enumerate() {
            if let Some(s) = s {
                let f = AccelFrame::from_physical(i as u8, counter, s.status, s.dv_m_s, s.t_degc);
                b.accel.extend_from_slice(&f.to_bytes());
            }
        }
        for g in &step.gnss {
            let fix = GnssFix {
                r_e_m: g.r_e_m,
                v_e_m_s: g.v_e_m_s,
                sigma_pos_m: g.sigma_pos_m,
                sigma_vel_m_s: g.sigma_vel_m_s,
            };
            let f = GnssFrame::from_physical(g.status, self.gnss_counter, g.satellites, g.time_us, &fix);
            self.gnss_counter = self.gnss_counter.wrapping_add(1);
            b.gnss.extend_from_slice(&f.to_bytes());
        }
        b.truth = step.truth.and_then(|t| t.pos_vel.map(|(r, v)| NavState { q_eb: t.q, v_e_m_s: v, r_e_m: r }));
        Some(b)
    }
}

/// What one period of the unit put out.
pub struct LvPeriod {
    /// Flight output frame bytes (UART0).
    pub flight: Vec<u8>,
    /// Navigation output frame bytes (UART2).
    pub nav: Vec<u8>,
    /// The filter work done after the step.
    pub work: FilterWork,
}

/// The launch-vehicle unit on the host: the flight core and the navigation stage the
/// firmware runs (`firmware/src/bin/ssis-fw-lv`), one 1.25 ms period at a time.
pub struct LvCore {
    core: FlightCore,
    nav: NavUnit,
    links: Links<MockLink, NotFitted, MockSink>,
    nav_links: NavLinks<MockLink, MockLink, MockSink>,
}

impl LvCore {
    /// The unit with FOG table `table`, the nominal accelerometer table and the pad block
    /// `init` (the firmware's flash contents).
    pub fn new(table: &CalibrationTable, init: &PadInit) -> Result<Self> {
        let profile = Profile::LAUNCH_VEHICLE;
        init.validate().map_err(|e| anyhow::anyhow!("pad initialisation block: {e:?}"))?;
        let mut core = FlightCore::new(profile, table, false).map_err(|e| anyhow::anyhow!("core: {e:?}"))?;
        core.align(init.state.q_eb);
        let comp = AccelTable::IDEAL.compensator().map_err(|e| anyhow::anyhow!("accel table: {e:?}"))?;
        let nav = NavUnit::new(init.state, profile.dt_s(), comp, init.gnss).map_err(|e| anyhow::anyhow!("{e:?}"))?;
        Ok(LvCore {
            core,
            nav,
            links: Links { fog: FogLinks::Bus(MockLink::ideal()), star: NotFitted, out: MockSink::default() },
            nav_links: NavLinks { accel: MockLink::ideal(), gnss: MockLink::ideal(), out: MockSink::default() },
        })
    }

    /// The navigation stage.
    pub fn nav(&self) -> &NavUnit {
        &self.nav
    }

    /// The flight core's next logged event (`FlightCore::take_event`): what the
    /// firmware sends in its event frames.
    pub fn take_event(&mut self) -> Option<ssis::telemetry::events::EventRecord> {
        self.core.take_event()
    }

    /// The navigation's reset snapshot now, into `s` (`NavUnit::snapshot_into`).
    pub fn snapshot_into(&self, s: &mut NavSnapshot) -> bool {
        self.nav.snapshot_into(s)
    }

    /// After a reset (this unit just built, as at boot): the navigation resumed from
    /// `s` (`NavUnit::resume`).
    pub fn resume_nav(&mut self, s: &NavSnapshot) -> Result<(), NavResumeError> {
        self.nav.resume(s)
    }

    /// One period on `b`'s bytes: the step (`FlightCore::step_with()`, `NavUnit::step()`
    /// from its hook), then `NavUnit::filter_work()`.
    pub fn period(&mut self, b: &LvStepBytes) -> LvPeriod {
        if let FogLinks::Bus(l) = &mut self.links.fog {
            l.send(&b.fog);
        }
        self.nav_links.accel.send(&b.accel);
        self.nav_links.gnss.send(&b.gnss);
        let (nav, nav_links) = (&mut self.nav, &mut self.nav_links);
        self.core.step_with(&mut self.links, |t_us, body| {
            nav.step(body, t_us, nav_links);
        });
        let work = self.nav.filter_work();
        LvPeriod {
            flight: std::mem::take(&mut self.links.out.bytes),
            nav: std::mem::take(&mut self.nav_links.out.bytes),
            work,
        }
    }
}

/// One navigation output frame against truth.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NavRecord {
    /// Unit time, s.
    pub t_s: f64,
    /// r − r_true, ECEF, m.
    pub pos_err_m: Vector3<f64>,
    /// v − v_true, ECEF, m/s.
    pub vel_err_m_s: Vector3<f64>,
    /// rotvec(q_true⁻¹ ∘ q), body axes, arcsec.
    pub att_err_arcsec: Vector3<f64>,
    /// The filter's 1σ (position m, velocity m/s), as the frame carries it.
    pub sigma: (f64, f64),
    /// The frame's flags.
    pub flags: u8,
}

/// Columns of `ssis-sim replay --csv` on a launch-vehicle log.
pub const LV_CSV_HEADER: [&str; 14] = [
    "t_s",
    "pos_err_x_m",
    "pos_err_y_m",
    "pos_err_z_m",
    "vel_err_x_m_s",
    "vel_err_y_m_s",
    "vel_err_z_m_s",
    "att_err_x_arcsec",
    "att_err_y_arcsec",
    "att_err_z_arcsec",
    "pos_err_m",
    "vel_err_m_s",
    "sigma_pos_m",
    "sigma_vel_m_s",
];

impl NavRecord {
    /// The CSV row ([`LV_CSV_HEADER`]).
    pub fn csv_row(&self) -> Vec<String> {
        let mut v = vec![format!("{:.5}", self.t_s)];
        v.extend(self.pos_err_m.iter().map(|x| format!("{x:.4}")));
        v.extend(self.vel_err_m_s.iter().map(|x| format!("{x:.6}")));
        v.extend(self.att_err_arcsec.iter().map(|x| format!("{x:.3}")));
        v.push(format!("{:.4}", self.pos_err_m.norm()));
        v.push(format!("{:.6}", self.vel_err_m_s.norm()));
        v.push(format!("{:.2}", self.sigma.0));
        v.push(format!("{:.3}", self.sigma.1));
        v
    }
}

/// The navigation error at one time: |r − r_true| m, |v − v_true| m/s, attitude angle ″.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct NavErrorAt {
    /// Unit time, s.
    pub t_s: f64,
    /// Position error, m.
    pub pos_m: f64,
    /// Velocity error, m/s.
    pub vel_m_s: f64,
    /// Attitude error angle, arcsec.
    pub att_arcsec: f64,
}

/// Times at which the navigation error is reported (those inside the log), s.
pub const REPORT_TIMES_S: [f64; 16] =
    [1.0, 2.0, 5.0, 10.0, 20.0, 30.0, 60.0, 120.0, 180.0, 240.0, 300.0, 360.0, 420.0, 480.0, 540.0, 600.0];

/// What a launch-vehicle unit's navigation output frames say about a log: against the
/// log's truth where it has it, and always the unit's own evidence (GNSS innovations,
/// fixes used and refused, steps with accelerometer data missing, outage, faults). Reads
/// output frames only, so the host replay and the firmware's output are judged alike.
#[derive(Debug, Clone)]
pub struct NavEvidence<'a> {
    rec: &'a Recorded,
    next_time: usize,
    /// Navigation frames taken.
    pub frames: u64,
    /// Frames scored against truth.
    pub scored: u64,
    /// The error at [`REPORT_TIMES_S`] (the first scored frame at or after each).
    pub at_times: Vec<NavErrorAt>,
    /// The largest error of each kind over the log.
    pub max: NavErrorAt,
    /// The error of the last scored frame.
    pub end: Option<NavErrorAt>,
    /// GNSS innovation (fix − the state of the step it arrived in, before its update),
    /// position per ECEF axis, m.
    pub innov_pos_m: AxisStats,
    /// The same for velocity, m/s.
    pub innov_vel_m_s: AxisStats,
    /// Frames flagged: accelerometer data missing or faulty.
    pub accel_fault_steps: u64,
    /// Frames flagged: navigation step refused.
    pub nav_fault_steps: u64,
    /// Frames flagged: GNSS outage (no fix used for 2 s).
    pub outage_steps: u64,
    /// Frames flagged: a fix was applied since the previous frame.
    pub updated_frames: u64,
    /// The last frame.
    pub last: Option<NavOutputFrame>,
}

impl<'a> NavEvidence<'a> {
    /// For the launch-vehicle log `rec`.
    pub fn new(rec: &'a Recorded) -> NavEvidence<'a> {
        NavEvidence {
            rec,
            next_time: 0,
            frames: 0,
            scored: 0,
            at_times: Vec::new(),
            max: NavErrorAt::default(),
            end: None,
            innov_pos_m: AxisStats::default(),
            innov_vel_m_s: AxisStats::default(),
            accel_fault_steps: 0,
            nav_fault_steps: 0,
            outage_steps: 0,
            updated_frames: 0,
            last: None,
        }
    }

    /// Takes one navigation output frame; its record against truth, if the log has truth
    /// for its step.
    pub fn frame(&mut self, f: &NavOutputFrame) -> Option<NavRecord> {
        self.frames += 1;
        let dt_us = u64::from(Profile::LAUNCH_VEHICLE.dt_us);
        let count = |bit: u8, c: &mut u64| *c += u64::from(f.flags & bit != 0);
        count(flags::ACCEL_FAULT, &mut self.accel_fault_steps);
        count(flags::NAV_FAULT, &mut self.nav_fault_steps);
        count(flags::GNSS_OUTAGE, &mut self.outage_steps);
        count(flags::GNSS_UPDATED, &mut self.updated_frames);
        self.last = Some(*f);
        let st = f.state();
        let step = f
            .time_tag_us
            .is_multiple_of(dt_us)
            .then(|| (f.time_tag_us / dt_us) as usize)
            .and_then(|n| n.checked_sub(1))
            .and_then(|k| self.rec.steps.get(k))?;
        for g in &step.gnss {
            if g.status & status::FIX_VALID != 0 && g.status & status::RECEIVER_FAULT == 0 {
                let (dr, dv) = (g.r_e_m - st.r_e_m, g.v_e_m_s - st.v_e_m_s);
                self.innov_pos_m.push([dr.x, dr.y, dr.z]);
                self.innov_vel_m_s.push([dv.x, dv.y, dv.z]);
            }
        }
        let t = step.truth?;
        let (r, v) = t.pos_vel?;
        let t_s = f.time_tag_us as f64 * 1e-6;
        let rec = NavRecord {
            t_s,
            pos_err_m: st.r_e_m - r,
            vel_err_m_s: st.v_e_m_s - v,
            att_err_arcsec: rotvec_from_quat(&(t.q.conjugate() * st.q_eb)) * ARCSEC_PER_RAD,
            sigma: (
                f64::from(f.sigma_pos_counts) * ssis::frames::navout::SIGMA_POS_LSB_M,
                f64::from(f.sigma_vel_counts) * ssis::frames::navout::SIGMA_VEL_LSB_M_S,
            ),
            flags: f.flags,
        };
        let e = NavErrorAt {
            t_s,
            pos_m: rec.pos_err_m.norm(),
            vel_m_s: rec.vel_err_m_s.norm(),
            att_arcsec: angle_between(&t.q, &st.q_eb) * ARCSEC_PER_RAD,
        };
        self.scored += 1;
        self.max = NavErrorAt {
            t_s: 0.0,
            pos_m: self.max.pos_m.max(e.pos_m),
            vel_m_s: self.max.vel_m_s.max(e.vel_m_s),
            att_arcsec: self.max.att_arcsec.max(e.att_arcsec),
        };
        while REPORT_TIMES_S.get(self.next_time).is_some_and(|&at| t_s >= at - 1e-9) {
            if REPORT_TIMES_S[self.next_time] > t_s - 1.0 {
                self.at_times.push(e);
            }
            self.next_time += 1;
        }
        self.end = Some(e);
        Some(rec)
    }

    /// The report in words.
    pub fn report(&self) -> String {
        use std::fmt::Write;
        let mut s = String::new();
        if let Some(end) = self.end {
            let _ = writeln!(
                s,
                "navigation error against truth ({} frames scored; |r − r_true|, |v − v_true|, attitude angle):",
                self.scored
            );
            let _ =
                writeln!(s, "  {:>10}  {:>11}  {:>13}  {:>12}", "t, s", "position, m", "velocity, m/s", "attitude, ″");
            let row = |s: &mut String, label: &str, e: &NavErrorAt| {
                let _ = writeln!(s, "  {label:>10}  {:>11.3} {:>14.4} {:>13.2}", e.pos_m, e.vel_m_s, e.att_arcsec);
            };
            for e in &self.at_times {
                row(&mut s, &format!("{:.2}", e.t_s), e);
            }
            row(&mut s, &format!("end {:.2}", end.t_s), &end);
            row(&mut s, "max", &self.max);
        } else {
            s.push_str("no truth in the log: no error against truth\n");
        }
        let _ = writeln!(s, "the unit's own evidence (navigation output frames):");
        let f3 = |v: [f64; 3], p: usize| format!("{:>9.p$} {:>9.p$} {:>9.p$}", v[0], v[1], v[2], p = p);
        let rms = |a: &AxisStats| {
            let (m, d) = (a.mean(), a.std());
            [0, 1, 2].map(|k| (m[k] * m[k] + d[k] * d[k]).sqrt())
        };
        let _ = writeln!(
            s,
            "  GNSS innovations (fix − state before its update), {} fixes:      x         y         z",
            self.innov_pos_m.count()
        );
        let _ = writeln!(s, "    position RMS, m                {}", f3(rms(&self.innov_pos_m), 3));
        let _ = writeln!(s, "    position max, m                {}", f3(self.innov_pos_m.max_abs(), 3));
        let _ = writeln!(s, "    velocity RMS, m/s              {}", f3(rms(&self.innov_vel_m_s), 4));
        let _ = writeln!(s, "    velocity max, m/s              {}", f3(self.innov_vel_m_s.max_abs(), 4));
        if let Some(f) = &self.last {
            let _ = writeln!(
                s,
                "  fixes used {}, refused {}; filter 1σ at the end {:.2} m, {:.3} m/s",
                f.fixes_used,
                f.fixes_refused,
                f64::from(f.sigma_pos_counts) * ssis::frames::navout::SIGMA_POS_LSB_M,
                f64::from(f.sigma_vel_counts) * ssis::frames::navout::SIGMA_VEL_LSB_M_S
            );
        }
        let _ = writeln!(
            s,
            "  frames: {} in all, {} after a fix's update, {} in GNSS outage, {} with accelerometer data missing or \
             faulty, {} with the navigation step refused",
            self.frames, self.updated_frames, self.outage_steps, self.accel_fault_steps, self.nav_fault_steps
        );
        s
    }
}

/// What a host replay of a launch-vehicle log found.
#[derive(Debug, Clone)]
pub struct LvReplaySummary<'a> {
    /// Steps stepped.
    pub steps: u64,
    /// Unit time covered, s.
    pub duration_s: f64,
    /// Flight output frames decoded.
    pub flight_frames: u64,
    /// What the navigation output says.
    pub evidence: NavEvidence<'a>,
    /// Both outputs' bytes, in order (flight then navigation per step).
    pub hash: u64,
}

/// Replays the launch-vehicle log `rec` through the firmware's code path on the host
/// ([`LvCore`]) with FOG table `table` and pad block `init`; `on_frame` sees every
/// navigation output frame and its record against truth (if the log has truth for it).
pub fn replay_lv<'a>(
    rec: &'a Recorded,
    table: &CalibrationTable,
    init: &PadInit,
    mut on_frame: impl FnMut(&NavOutputFrame, Option<&NavRecord>),
) -> Result<LvReplaySummary<'a>> {
    anyhow::ensure!(rec.unit == LogUnit::LaunchVehicle, "{}: not a launch-vehicle log", rec.origin);
    let mut unit = LvCore::new(table, init)?;
    let mut feed = LvFeed::new(rec);
    let mut evidence = NavEvidence::new(rec);
    let mut flight_dec: StreamDecoder<OutputFrame, 256> = StreamDecoder::new();
    let mut nav_dec: StreamDecoder<NavOutputFrame, 256> = StreamDecoder::new();
    let mut flight_frames = 0u64;
    let mut hash = OutputHash::default();
    while let Some(b) = feed.next_step() {
        let out = unit.period(&b);
        hash.write(&out.flight);
        hash.write(&out.nav);
        flight_dec.push_slice(&out.flight, |r| flight_frames += u64::from(r.is_ok()));
        nav_dec.push_slice(&out.nav, |r| {
            if let Ok(f) = r {
                let rec = evidence.frame(&f);
                on_frame(&f, rec.as_ref());
            }
        });
    }
    Ok(LvReplaySummary {
        steps: feed.steps(),
        duration_s: feed.steps() as f64 * Profile::LAUNCH_VEHICLE.dt_s(),
        flight_frames,
        evidence,
        hash: hash.value(),
    })
}

impl LvReplaySummary<'_> {
    /// A report a person can read.
    pub fn report(&self, rec: &Recorded) -> String {
        let mut s = format!(
            "replay  {}  through FlightCore::step_with + NavUnit (launch vehicle, {:.2} s, {} steps, {} flight and {} \
             navigation output frames)\n",
            rec.origin, self.duration_s, self.steps, self.flight_frames, self.evidence.frames
        );
        s.push_str(&log_line(rec));
        s.push_str("damage in the log (counted, skipped):\n");
        s.push_str(&rec.problems.report());
        s.push_str(&self.evidence.report());
        s
    }
}

/// What a launch-vehicle log holds, in a line.
pub fn log_line(rec: &Recorded) -> String {
    let acc: usize = rec.steps.iter().map(|s| s.accel.iter().flatten().count()).sum();
    let gnss: usize = rec.steps.iter().map(|s| s.gnss.len()).sum();
    format!(
        "log: {} FOG samples ({}), {} accelerometer samples, {} GNSS fixes, truth {}\n",
        rec.fog_samples(),
        crate::replay::fog_names(rec.fogs),
        acc,
        gnss,
        if rec.has_truth { "yes" } else { "no" }
    )
}

/// The shortest decimal that gives back `counts` of `lsb` when the unit rounds it to
/// its frame's counts (what a log must hold for the replay to send the same bytes).
pub(crate) fn decimal(counts: i64, lsb: f64) -> String {
    let v = counts as f64 * lsb;
    let sci = (0..=17)
        .map(|d| format!("{v:.d$e}"))
        .find(|t| t.parse::<f64>().is_ok_and(|p| (p / lsb).round() as i64 == counts))
        .unwrap_or_else(|| format!("{v:e}"));
    // The same number without an exponent, where that is shorter ("0.25", "12.5").
    let plain = sci.parse::<f64>().map(|p| p.to_string()).unwrap_or_default();
    if !plain.is_empty() && plain.len() <= sci.len() {
        plain
    } else {
        sci
    }
}

/// How [`write_log`] writes.
#[derive(Debug, Clone, Copy)]
pub struct LogOptions {
    /// Steps to write.
    pub steps: u64,
    /// Truth on every N-th row (1: every row).
    pub truth_every: u64,
    /// Sample counters, temperatures and status on every row (else only the time and the
    /// increments: the counters follow from `t_s`, temperatures default to 25 °C).
    pub full: bool,
}

const _: () = assert!(FogFrame::TEMP_LSB_DEGC == AccelFrame::TEMP_LSB_DEGC);

/// Writes a launch-vehicle recorded log (`docs/RECORDED-LOG.md`) of scenario `sc`: the
/// frames its sensors put on the links, as numbers that give the same frames back, the
/// GNSS fixes, truth and the initial state. Returns the pad block the log's initial
/// state stands for.
pub fn write_log(sc: &LvScenario, opts: LogOptions, w: &mut impl Write) -> Result<PadInit> {
    let dt = Profile::LAUNCH_VEHICLE;
    let mut sensors = AscentSensors::new(sc);
    let init = pad_init(sensors.initial());
    let mut cols: Vec<String> = vec!["t_s".into()];
    for i in 0..3 {
        cols.push(format!("fog{i}_dtheta_rad"));
        if opts.full {
            cols.extend([format!("fog{i}_counter"), format!("fog{i}_t_degc"), format!("fog{i}_status")]);
        }
    }
    for i in 0..N_ACCEL {
        cols.push(format!("acc{i}_dv_m_s"));
        if opts.full {
            cols.extend([format!("acc{i}_counter"), format!("acc{i}_t_degc"), format!("acc{i}_status")]);
        }
    }
    let triple = crate::recorded::xyz_names;
    cols.extend(["gnss_t_s", "gnss_status", "gnss_satellites"].map(String::from));
    cols.extend(triple("gnss_", "_m"));
    cols.extend(triple("gnss_v", "_m_s"));
    cols.extend(["gnss_sigma_pos_m", "gnss_sigma_vel_m_s"].map(String::from));
    cols.extend(["true_q0", "true_q1", "true_q2", "true_q3"].map(String::from));
    cols.extend(triple("true_", "_m"));
    cols.extend(triple("true_v", "_m_s"));
    cols.extend(["init_q0", "init_q1", "init_q2", "init_q3"].map(String::from));
    cols.extend(triple("init_", "_m"));
    cols.extend(triple("init_v", "_m_s"));
    writeln!(
        w,
        "# recorded log: launch-vehicle ascent `{}` (seed {}), {:.2} s from lift-off; written by `ssis-sim record`",
        sc.name,
        sc.seed,
        opts.steps as f64 * dt.dt_s()
    )?;
    writeln!(
        w,
        "# docs/RECORDED-LOG.md: ECEF (WGS-84), q_eb = body in ECEF scalar first, FOG/acc slots 0..2 = X, Y, Z"
    )?;
    writeln!(w, "{}", cols.join(","))?;
    // Truth to 1e-12 (2e-7″), 0.1 mm and 10 µm/s; the initial state exactly.
    let state_fields = |s: &NavState, exact: bool| -> Vec<String> {
        let q = s.q_eb;
        let f = |x: f64, d: usize| if exact { x.to_string() } else { format!("{x:.d$}") };
        let mut v: Vec<String> = [q.w, q.i, q.j, q.k].iter().map(|x| f(*x, 12)).collect();
        v.extend(s.r_e_m.iter().map(|x| f(*x, 4)));
        v.extend(s.v_e_m_s.iter().map(|x| f(*x, 5)));
        v
    };
    for k in 1..=opts.steps {
        let b = sensors.step(k);
        let mut row = vec![format!("{:.5}", k as f64 * dt.dt_s())];
        // Per sensor: its increment, and with `full` its counter, temperature and status.
        let mut sensor = |counts: i32, lsb: f64, counter: u16, temp_counts: i16, status: u8| {
            row.push(decimal(i64::from(counts), lsb));
            if opts.full {
                row.push(counter.to_string());
                row.push(decimal(i64::from(temp_counts), FogFrame::TEMP_LSB_DEGC));
                row.push(status.to_string());
            }
        };
        for c in b.fog.chunks_exact(FogFrame::LEN) {
            let f = FogFrame::decode(c).map_err(|e| anyhow::anyhow!("FOG frame: {e:?}"))?;
            sensor(f.dtheta_counts, FogFrame::DTHETA_LSB_RAD, f.counter, f.temperature_counts, f.status);
        }
        for c in b.accel.chunks_exact(AccelFrame::LEN) {
            let f = AccelFrame::decode(c).map_err(|e| anyhow::anyhow!("accelerometer frame: {e:?}"))?;
            sensor(f.dv_counts, AccelFrame::DV_LSB_M_S, f.counter, f.temperature_counts, f.status);
        }
        match b.gnss.chunks_exact(GnssFrame::LEN).next() {
            Some(c) => {
                let f = GnssFrame::decode(c).map_err(|e| anyhow::anyhow!("GNSS frame: {e:?}"))?;
                row.push(format!("{:.6}", f.time_tag_us as f64 * 1e-6));
                row.push(f.status.to_string());
                row.push(f.satellites.to_string());
                row.extend(f.r_counts.map(|c| decimal(i64::from(c), gnss::POS_LSB_M)));
                row.extend(f.v_counts.map(|c| decimal(i64::from(c), gnss::VEL_LSB_M_S)));
                row.push(decimal(i64::from(f.sigma_pos_counts), gnss::SIGMA_POS_LSB_M));
                row.push(decimal(i64::from(f.sigma_vel_counts), gnss::SIGMA_VEL_LSB_M_S));
            }
            None => row.extend(std::iter::repeat_n(String::new(), 11)),
        }
        match b.truth.filter(|_| k % opts.truth_every.max(1) == 0 || k == opts.steps) {
            Some(t) => row.extend(state_fields(&t, false)),
            None => row.extend(std::iter::repeat_n(String::new(), 10)),
        }
        if k == 1 {
            row.extend(state_fields(&init.state, true));
        } else {
            row.extend(std::iter::repeat_n(String::new(), 10));
        }
        writeln!(w, "{}", row.join(","))?;
    }
    Ok(init)
}
