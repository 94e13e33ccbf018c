//! The upset campaign on the firmware in QEMU: single bit flips into the RAM
//! the firmware uses (the live stack, from SP to the stack's top, and its statics) and
//! into its core and FPU registers, through QEMU's gdbstub ([`crate::gdb`]), each at a
//! random instruction inside a random step after convergence, classed against truth and
//! the undisturbed run ([`Outcome`]).
//!
//! How a flip is placed: the runner halts the guest before a step, sets a breakpoint at
//! the first instruction of the inlined `FlightCore::step` (found in the ELF's debug
//! information, [`step_code`]), sends the STEP frame, runs to a random instruction of the
//! step ([`place_flip`]), then flips one bit and lets the guest run.
//!
//! What makes it affordable: the flight is run once in-process (the flight core on the
//! same bytes is bit-identical to the firmware, `host/QEMU equivalence`), giving the
//! undisturbed output of every step. A flip whose outputs stay identical to it for
//! [`UpsetOptions::quiet_s`] is classed masked and the same flight goes on to the next
//! flip; so does one whose outputs changed within the bound and are identical again for
//! the quiet time (tolerated). Any other flip is followed for [`UpsetOptions::window_s`]
//! and ends its flight; the next flight starts QEMU from the guest's state saved before
//! the first flip time (`-incoming`). The caveat: a corruption that stays
//! invisible for the quiet time and shows later is charged to a later flip of the same
//! flight (the document counts how many disturbed flips had earlier flips before them).
//!
//! Resets: the runner keeps breakpoints on the firmware's `Reset` and `HardFault` entries
//! (the watchdog's warnings are read from the firmware's count at `Reset`) and runs QEMU
//! with `-action watchdog=reset`. A
//! HardFault (its faulting instruction read from the exception frame) or a watchdog
//! timeout resets the unit; at `Reset` the runner follows it back into lockstep
//! ([`relock`]) and on with the flight [`RESET_DOWN_STEPS`] later, and the flip is classed
//! "reset and recovered" with its recovery times (to aligned, to within twice the
//! nominal 3σ) or, not back within the bound by the window's end, a crash. With
//! [`UpsetOptions::forced_reset`] the "flip" is a reset itself: the resume measured in
//! QEMU (tests/qemu_resume.rs). A reset the runner makes (a forced one, the snapshot
//! population's) is followed at once, wherever in the pass it lands; one that comes after
//! the last step's outputs went out is found at the next step's start, before its bytes
//! go out (`on_stop`). With [`run_injection`] it is a fault of the loop itself
//! ([`Target::TickStopped`]: the SysTick's enable bit cleared, by the test build's
//! TICK_STOP; [`Target::Stall`]: the test build's STALL): the register check or the
//! watchdog must bring the unit back (tests/qemu_exec.rs). Both are sent on the control
//! line with the guest running: under `-icount …,sleep=off` a debugger stop after the
//! tick is stopped lets QEMU warp to the watchdog's timeouts, and a reset that lands while
//! the runner restores the registers of a guest access leaves the old loop running on
//! reset devices.

mod lv;
mod place;
mod report;

use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use anyhow::{Context, Result};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use ssis::frames::control::{command, ControlFrame};
use ssis::frames::decoder::StreamDecoder;
use ssis::frames::navout::NavOutputFrame;
use ssis::frames::output::{flags, OutputFrame};
use ssis::telemetry::events::EventRecord;
use ssis_common::downlink::{Down, Downlink};
use ssis_common::mock::{MockLink, MockSink};
use ssis_sim::harness::{Evaluator, Observed, Simulation, StepInput};
use ssis_sim::lv_replay::LvScenario;
use ssis_sim::scenario::Scenario;

pub use lv::FLOOR as LV_BOUND_FLOOR;
pub use report::{Campaign, Interval, LvBounds, Run};

use crate::gdb::{self, Gdb};
use crate::qemu::{masked, symbol, QemuOptions, Unit};

/// How a campaign runs.
#[derive(Debug, Clone, serde::Serialize, serde::Deserialize)]
pub struct UpsetOptions {
    /// Firmware ELF (a test build: lockstep).
    pub elf: PathBuf,
    /// Flips to make.
    pub flips: usize,
    /// Seed of the flips' steps, instructions, targets and bits.
    pub seed: u64,
    /// First flip time, s (after the observer's convergence).
    pub first_s: f64,
    /// Outputs identical to the undisturbed run for this long after a flip: masked, s.
    pub quiet_s: f64,
    /// A flip that changed an output is followed this long, s.
    pub window_s: f64,
    /// Largest gap between the end of one flip's quiet time and the next flip, s.
    pub gap_s: f64,
    /// Share of the state's flips into registers (the rest into RAM); negative: in
    /// proportion to their bits.
    pub register_share: f64,
    /// Stop making new flips after this much wall time, s.
    pub max_wall_s: Option<f64>,
    /// Instead of flipping a bit, reset the unit there (QEMU's `system_reset`, what the
    /// firmware's SYSRESETREQ does): the resume measured in QEMU.
    pub forced_reset: bool,
}

impl UpsetOptions {
    /// `flips` flips of `elf` drawn with `seed`, on the command line's schedule (first flip
    /// at 12 s, masked after 0.5 s, followed 10 s, gaps up to 0.5 s), registers in
    /// proportion to their bits, no wall-time limit, bit flips (not forced resets).
    pub fn new(elf: PathBuf, flips: usize, seed: u64) -> Self {
        UpsetOptions {
            elf,
            flips,
            seed,
            first_s: 12.0,
            quiet_s: 0.5,
            window_s: 10.0,
            gap_s: 0.5,
            register_share: -1.0,
            max_wall_s: None,
            forced_reset: false,
        }
    }
}

/// Where a bit was flipped.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub enum Target {
    /// A byte of the live stack (SP to the stack's top) at the flip.
    Stack {
        /// Address.
        addr: u32,
        /// Bit 0–7.
        bit: u8,
    },
    /// A byte of the statics (.data, .bss, .uninit).
    Static {
        /// Address.
        addr: u32,
        /// Bit 0–7.
        bit: u8,
    },
    /// A core register (r0–r15, xPSR as gdb numbers them).
    Core {
        /// gdb register number.
        reg: u32,
        /// Bit 0–31.
        bit: u8,
    },
    /// An FPU register (d0–d15, FPSCR).
    Fpu {
        /// gdb register number.
        reg: u32,
        /// Bit 0–63 (0–31 for FPSCR).
        bit: u8,
    },
    /// Two bits of the RAM in use ([`Population::Double`]): `bit` and `bit + 1` of the
    /// word at `addr` (adjacent bits), or `bit` of the words at `addr` and `addr + 4`
    /// (the same bit in adjacent words).
    Double {
        /// Word address.
        addr: u32,
        /// Bit 0–31 (0–30 for adjacent bits).
        bit: u8,
        /// The same bit in two adjacent words (else two adjacent bits of one word).
        words: bool,
    },
    /// A bit of a device or system register ([`DEVICE_REGS`]), written with the guest's
    /// own store ([`Gdb::write_device_u32`]); PRIMASK and FAULTMASK set with `cpsid`.
    Device {
        /// Index in [`DEVICE_REGS`].
        reg: u8,
        /// Bit 0–31.
        bit: u8,
    },
    /// A bit of the snapshot record in RAM flipped, then the unit reset
    /// ([`Population::SnapshotReset`]).
    SnapshotReset {
        /// Address.
        addr: u32,
        /// Bit 0–7.
        bit: u8,
    },
    /// No flip: the unit reset there ([`UpsetOptions::forced_reset`]).
    Reset,
    /// No flip: the SysTick's enable bit cleared ([`SYST_CSR`]) by the test build's
    /// TICK_STOP control frame, the step tick stopped ([`run_injection`]).
    TickStopped,
    /// No flip: the test build's STALL control frame, the main loop stopped
    /// ([`run_injection`]).
    Stall,
}

/// The SysTick control and status register (ARMv7-M B3.3.3); bit 0 enables the counter.
pub const SYST_CSR: u32 = 0xE000_E010;

/// Where a flip is drawn from, and at which instructions.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
pub enum Population {
    /// One bit of the state: the RAM in use (live stack, statics) and the core and FPU
    /// registers, uniform over their bits (or with [`UpsetOptions::register_share`]), at a
    /// random instruction of a random pass (the step, its outputs and the after-step work,
    /// up to the loop's next `wfi`; steps with and without a star update).
    State,
    /// Two bits of the RAM in use: adjacent bits of a word, or the same bit of two
    /// adjacent words (half each), at a random instruction of a random pass.
    Double,
    /// One bit of a device or system register the unit depends on ([`DEVICE_REGS`]), at a
    /// random instruction of a random pass.
    Device,
    /// One bit of the snapshot record, then a reset, at a random instruction of a random
    /// pass.
    SnapshotReset,
    /// One bit of the state at a random instruction of the UART receive interrupt
    /// (`DefaultHandler`).
    Handler,
    /// At a random instruction of the snapshot write (`FlightCore::snapshot_into`, every
    /// 80th step): a reset there (half), or one bit of the state.
    SnapshotWrite,
}

impl Population {
    /// Every population, in table order.
    pub const ALL: [Population; 6] = [
        Population::State,
        Population::Double,
        Population::Device,
        Population::SnapshotReset,
        Population::Handler,
        Population::SnapshotWrite,
    ];

    /// Its name in the tables and on the command line.
    pub fn name(self) -> &'static str {
        match self {
            Population::State => "state",
            Population::Double => "double",
            Population::Device => "device",
            Population::SnapshotReset => "snapshot-reset",
            Population::Handler => "handler",
            Population::SnapshotWrite => "snapshot-write",
        }
    }

    /// The population named `s`.
    pub fn parse(s: &str) -> Option<Population> {
        Population::ALL.into_iter().find(|p| p.name() == s)
    }
}

/// The campaign's populations and their shares of the flips (drawn per flip).
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Mix(pub Vec<(Population, f64)>);

impl Mix {
    /// Only [`Population::State`] (the campaign as first written).
    pub fn state() -> Mix {
        Mix(vec![(Population::State, 1.0)])
    }

    /// Every population: state 40 %, double 15 %, device 15 %, snapshot-reset 10 %,
    /// handler 10 %, snapshot-write 10 % (a stratified sample: the document weighs each
    /// by its share of the cross-section).
    pub fn all() -> Mix {
        Mix(vec![
            (Population::State, 0.40),
            (Population::Double, 0.15),
            (Population::Device, 0.15),
            (Population::SnapshotReset, 0.10),
            (Population::Handler, 0.10),
            (Population::SnapshotWrite, 0.10),
        ])
    }

    /// `name=share,…` (shares normalised), or `all`, or `state`.
    pub fn parse(s: &str) -> Result<Mix> {
        match s {
            "all" => return Ok(Mix::all()),
            "state" => return Ok(Mix::state()),
            _ => {}
        }
        let mut v = Vec::new();
        for part in s.split(',') {
            let (name, share) = part.split_once('=').unwrap_or((part, "1"));
            let p = Population::parse(name.trim()).with_context(|| format!("no population {name}"))?;
            let w: f64 = share.trim().parse().with_context(|| format!("share {share}"))?;
            anyhow::ensure!(w >= 0.0 && w.is_finite(), "share {share}");
            v.push((p, w));
        }
        anyhow::ensure!(v.iter().any(|(_, w)| *w > 0.0), "no population with a share");
        Ok(Mix(v))
    }

    fn draw(&self, rng: &mut ChaCha8Rng) -> Population {
        let total: f64 = self.0.iter().map(|(_, w)| w).sum();
        let mut x = rng.random_range(0.0..total.max(f64::MIN_POSITIVE));
        for &(p, w) in &self.0 {
            if x < w {
                return p;
            }
            x -= w;
        }
        self.0.last().map_or(Population::State, |p| p.0)
    }
}

/// How a device register's bit is flipped.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum How {
    /// Read, XOR, write.
    Plain,
    /// An NVIC set-enable register: a set bit cleared through its clear-enable twin
    /// (0x80 above), a clear one set.
    Enable,
    /// An MPU region register: the region number selected first.
    Mpu(u32),
    /// A watchdog register: unlocked first, locked after.
    Watchdog,
    /// PRIMASK set (`cpsid i`).
    Primask,
    /// FAULTMASK set (`cpsid f`).
    Faultmask,
}

/// One device or system register of the flip population: name, address, the bits it
/// implements that the unit depends on, and how a bit of it is flipped.
#[derive(Debug, Clone, Copy)]
pub struct DeviceReg {
    /// Its name.
    pub name: &'static str,
    /// Address.
    pub addr: u32,
    /// The bits drawn.
    pub mask: u32,
    /// How it is flipped.
    pub how: How,
}

const fn dev(name: &'static str, addr: u32, mask: u32, how: How) -> DeviceReg {
    DeviceReg { name, addr, mask, how }
}

/// The device and system registers of the QEMU mps2 board the spacecraft firmware
/// configures (`ssis_firmware::mps2`'s list of checked registers): SysTick, the vector
/// table, SysTick's priority, the NVIC's enables and the UARTs' priorities, UARTs 0–2's
/// control and baud divider, the MPU's two regions and control, the watchdog's load and
/// control, and the interrupt masks PRIMASK and FAULTMASK (one bit each, set).
pub const DEVICE_REGS: [DeviceReg; 21] = [
    dev("SYST_CSR", 0xE000_E010, 0b111, How::Plain),
    dev("SYST_RVR", 0xE000_E014, 0x00FF_FFFF, How::Plain),
    dev("VTOR", 0xE000_ED08, 0xFFFF_FF80, How::Plain),
    dev("SHPR3", 0xE000_ED20, 0xFF00_0000, How::Plain),
    dev("NVIC_ISER0", 0xE000_E100, u32::MAX, How::Enable),
    dev("NVIC_IPR0", 0xE000_E400, u32::MAX, How::Plain),
    dev("NVIC_IPR1", 0xE000_E404, u32::MAX, How::Plain),
    dev("UART0_CTRL", 0x4000_4008, 0x7F, How::Plain),
    dev("UART0_BAUDDIV", 0x4000_4010, 0x000F_FFFF, How::Plain),
    dev("UART1_CTRL", 0x4000_5008, 0x7F, How::Plain),
    dev("UART1_BAUDDIV", 0x4000_5010, 0x000F_FFFF, How::Plain),
    dev("UART2_CTRL", 0x4000_6008, 0x7F, How::Plain),
    dev("UART2_BAUDDIV", 0x4000_6010, 0x000F_FFFF, How::Plain),
    dev("MPU_CTRL", 0xE000_ED94, 0b111, How::Plain),
    dev("MPU_RBAR0", 0xE000_ED9C, 0xFFFF_FFE0, How::Mpu(0)),
    dev("MPU_RASR0", 0xE000_EDA0, 0x1F3F_FF3F, How::Mpu(0)),
    dev("MPU_RASR1", 0xE000_EDA0, 0x1F3F_FF3F, How::Mpu(1)),
    dev("WDOG_LOAD", 0x4000_8000, u32::MAX, How::Watchdog),
    dev("WDOG_CONTROL", 0x4000_8008, 0b11, How::Watchdog),
    dev("PRIMASK", 0, 1, How::Primask),
    dev("FAULTMASK", 0, 1, How::Faultmask),
];

/// The bits of [`DEVICE_REGS`] the device population draws from.
pub fn device_bits() -> u32 {
    DEVICE_REGS.iter().map(|d| d.mask.count_ones()).sum()
}

impl Target {
    /// The runner resets the unit with this target (QEMU's `system_reset`).
    pub fn resets(&self) -> bool {
        matches!(self, Target::Reset | Target::SnapshotReset { .. })
    }

    /// The class of the target, for the tables.
    pub fn class(&self) -> &'static str {
        match self {
            Target::Stack { .. } => "stack",
            Target::Static { .. } => "statics",
            Target::Core { reg: gdb::SP, .. } | Target::Core { reg: gdb::PC, .. } => "sp/pc",
            Target::Core { .. } => "core register",
            Target::Fpu { .. } => "FPU register",
            Target::Double { words: false, .. } => "double: adjacent bits",
            Target::Double { words: true, .. } => "double: adjacent words",
            Target::Device { .. } => "device register",
            Target::SnapshotReset { .. } => "snapshot, then reset",
            Target::Reset => "forced reset",
            Target::TickStopped => "tick stopped",
            Target::Stall => "loop stalled",
        }
    }

    /// A short description (`stack 0x20005f10 bit 3`, `r13 bit 7`, `d4 bit 52`).
    pub fn describe(&self) -> String {
        match *self {
            Target::Stack { addr, bit } => format!("stack {addr:#010x} bit {bit}"),
            Target::Static { addr, bit } => format!("statics {addr:#010x} bit {bit}"),
            Target::Core { reg: gdb::XPSR, bit } => format!("xpsr bit {bit}"),
            Target::Core { reg, bit } => format!("r{reg} bit {bit}"),
            Target::Fpu { reg: gdb::FPSCR, bit } => format!("fpscr bit {bit}"),
            Target::Fpu { reg, bit } => format!("d{} bit {bit}", reg - gdb::D0),
            Target::Double { addr, bit, words: false } => format!("{addr:#010x} bits {bit}, {}", bit + 1),
            Target::Double { addr, bit, words: true } => format!("{addr:#010x} and {:#010x} bit {bit}", addr + 4),
            Target::Device { reg, bit } => match DEVICE_REGS.get(usize::from(reg)) {
                Some(d) if d.how == How::Primask || d.how == How::Faultmask => format!("{} set", d.name),
                Some(d) => format!("{} bit {bit}", d.name),
                None => format!("device register {reg} bit {bit}"),
            },
            Target::SnapshotReset { addr, bit } => format!("snapshot {addr:#010x} bit {bit}, reset"),
            Target::Reset => "forced reset".to_string(),
            Target::TickStopped => "SysTick enable bit cleared".to_string(),
            Target::Stall => "STALL control frame".to_string(),
        }
    }
}

/// What a flip did, against truth and the undisturbed run.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub enum Outcome {
    /// Every output identical to the undisturbed run's for the quiet time.
    Masked,
    /// Outputs changed; every frame's error within max(20″, the unit's 3σ).
    Tolerated,
    /// Error beyond the bound only in frames that did not claim a good attitude, and back
    /// within it (and claiming it) before the window's end.
    DetectedRecovered,
    /// Beyond the bound, flagged, and not back by the window's end.
    DetectedNotRecovered,
    /// The unit reset (HardFault, watchdog) and came back: resumed or aligned again, every
    /// frame claiming a good attitude within the bound, and back within it by the
    /// window's end (the runner follows the reset back into lockstep).
    ResetRecovered,
    /// A frame claiming a good attitude beyond the bound.
    Silent,
    /// The firmware stopped: QEMU exited, the guest hung (no output frame), or it reset
    /// and was not back within the bound by the window's end.
    Crash(String),
}

impl Outcome {
    /// The row name in the tables.
    pub fn name(&self) -> &'static str {
        match self {
            Outcome::Masked => "masked",
            Outcome::Tolerated => "tolerated",
            Outcome::DetectedRecovered => "detected and recovered",
            Outcome::DetectedNotRecovered => "detected, not recovered in the window",
            Outcome::ResetRecovered => "reset and recovered",
            Outcome::Silent => "silent",
            Outcome::Crash(_) => "crash",
        }
    }
}

/// One flip and what it did.
#[derive(Debug, Clone, serde::Serialize, serde::Deserialize)]
pub struct Flip {
    /// The population it was drawn from.
    pub population: Population,
    /// Its step took a star-tracker update.
    pub star: bool,
    /// Step the flip was made in.
    pub step: u64,
    /// Instructions executed in that step before the flip.
    pub instr: u32,
    /// Where the guest was at the flip: the address and the function it lies in.
    pub at: String,
    /// The bit.
    pub target: Target,
    /// The class.
    pub outcome: Outcome,
    /// Largest attitude error after the flip, ″ (any axis); the launch vehicle: the
    /// largest ratio of an error to its bound ([`Flip::nav_worst`]).
    pub worst_arcsec: f64,
    /// Largest error in a frame that claimed a good attitude beyond the bound, ″ (the
    /// launch vehicle: the ratio of the error to its bound).
    pub silent_arcsec: f64,
    /// From the flip to the last frame beyond the bound (recovered flips), s.
    pub recovery_s: Option<f64>,
    /// After a reset: what reset it (HardFault with the faulting instruction, watchdog;
    /// "watchdog, N warnings" when the watchdog warned more than once before it).
    pub reset_cause: Option<String>,
    /// After a reset: the runner's steps from the flip's to the one the unit reset in
    /// (in lockstep the unit's virtual time is not the runner's), s.
    pub reset_after_s: Option<f64>,
    /// After a reset: from the step it reset in to the first frame that says aligned, s.
    pub reset_aligned_s: Option<f64>,
    /// After a reset: from the step it reset in to the frame from which every frame is
    /// within twice the nominal 3σ on each axis, s.
    pub reset_nominal_s: Option<f64>,
    /// Events the unit logged after the flip that the undisturbed run did not.
    pub events: Vec<String>,
    /// Flips made earlier in the same flight (classed masked or tolerated).
    pub earlier_in_flight: u32,
    /// The launch vehicle: the largest navigation errors after the flip (position m,
    /// velocity m/s, attitude ″) and the largest ratio of an error to its bound
    /// (above 1 in a frame claiming a good solution: silent).
    pub nav_worst: Option<([f64; 3], f64)>,
}

/// The undisturbed flight: every step's bytes and the in-process core's output frame and
/// events.
struct Flight {
    table: ssis::calib::CalibrationTable,
    profile: ssis::flight::Profile,
    settle_s: f64,
    inputs: Vec<StepInput>,
    frames: Vec<Option<OutputFrame>>,
    events: Vec<EventRecord>,
    /// The undisturbed flight's attitude error 3σ per axis (|mean| + 3 std after
    /// settling), ″: "nominal" of the reset goals.
    nominal_3sigma_arcsec: [f64; 3],
    /// The launch vehicle's ascent (`inputs` then empty: its steps are here).
    lv: Option<lv::LvFlight>,
}

impl Flight {
    fn record(sc: &Scenario) -> Result<Flight> {
        let mut sim = Simulation::new(sc)?;
        let (table, profile) = (sim.table, sim.profile);
        let mut core = ssis::flight::FlightCore::new(profile, &table, false).map_err(|e| anyhow::anyhow!("{e:?}"))?;
        let (mut fog, mut star, mut out) = (MockLink::ideal(), MockLink::ideal(), MockSink::default());
        let mut link = Downlink::new();
        let (mut inputs, mut frames, mut events) = (Vec::new(), Vec::new(), Vec::new());
        while let Some(input) = sim.next_step() {
            fog.send(&fog_bytes(&input, &profile));
            star.send(&input.st_bytes);
            let mut links =
                ssis::flight::Links { fog: ssis::flight::FogLinks::Bus(&mut fog), star: &mut star, out: &mut out };
            core.step(&mut links);
            events.extend(std::iter::from_fn(|| core.take_event()));
            let mut frame = None;
            link.push(&std::mem::take(&mut out.bytes), |d| {
                if let Down::Output(f) = d {
                    frame = Some(f);
                }
            });
            frames.push(frame);
            inputs.push(input);
        }
        let mut eval = Evaluator::for_unit(&table, &profile, sc.settle_s);
        let mut errs = Vec::new();
        for (input, f) in inputs.iter().zip(&frames) {
            if let Some(t) = input.truth {
                eval.push_truth(t);
            }
            let Some(f) = f else { continue };
            if let Some(r) = eval.evaluate(&Observed::from(f)).filter(|r| r.t_s >= sc.settle_s) {
                errs.push(r.att_err_arcsec);
            }
        }
        let nominal_3sigma_arcsec = [0, 1, 2].map(|k| {
            let n = errs.len().max(1) as f64;
            let mean = errs.iter().map(|e| e[k]).sum::<f64>() / n;
            let var = errs.iter().map(|e| (e[k] - mean).powi(2)).sum::<f64>() / n;
            mean.abs() + 3.0 * var.sqrt()
        });
        Ok(Flight { table, profile, settle_s: sc.settle_s, inputs, frames, events, nominal_3sigma_arcsec, lv: None })
    }

    /// The launch vehicle's undisturbed ascent `sc` (the in-process `LvCore`).
    fn record_lv(sc: &LvScenario) -> Result<Flight> {
        let (lv, frames, events) = lv::record(sc)?;
        Ok(Flight {
            table: ssis::calib::CalibrationTable::DEFAULT,
            profile: ssis::flight::Profile::LAUNCH_VEHICLE,
            settle_s: 0.0,
            inputs: Vec::new(),
            frames,
            events,
            nominal_3sigma_arcsec: [0.0; 3],
            lv: Some(lv),
        })
    }

    /// Steps in the flight.
    fn len(&self) -> usize {
        match &self.lv {
            Some(lv) => lv.steps.len(),
            None => self.inputs.len(),
        }
    }
}

/// The FOG bus bytes of one step (the profile's FOGs that sent a frame).
fn fog_bytes(input: &StepInput, profile: &ssis::flight::Profile) -> Vec<u8> {
    let mut b = Vec::with_capacity(64);
    for (i, f) in input.fog_frames.iter().enumerate() {
        if profile.fogs.contains(i) && input.present.contains(i) {
            b.extend_from_slice(f);
        }
    }
    b
}

/// Where the step's code is: `FlightCore::step` as inlined into the firmware's main loop.
#[derive(Debug, Clone)]
pub struct StepCode {
    /// Its first instruction: the lowest address of the inlined instance's ranges in the
    /// ELF's DWARF (`DW_AT_entry_pc` where given).
    pub entry: u32,
    /// The inlined instance's address ranges.
    pub ranges: Vec<(u32, u32)>,
    /// The address range of the function it is inlined into (the main loop).
    pub caller: (u32, u32),
    /// The first instruction of `FlightCore::background`, which the main loop runs right
    /// after the step (inlined there, or called): the traced path ends there. (The
    /// inlined step's ranges interleave with the loop's own code, so leaving them does
    /// not end the step.)
    pub end: u32,
}

/// An inlined instance: whether it is the step (else the background work), its entry
/// and its address ranges.
type Inlined = (bool, u32, Vec<(u32, u32)>);

/// The step's code in `elf` ([`StepCode`]).
pub fn step_code(elf: &Path) -> Result<StepCode> {
    step_code_of(elf, "10FlightCore4step17h")
}

/// The step's code in `elf` where the step is the inlined function whose mangled name
/// contains `step` (`10FlightCore4step17h`, the spacecraft's; `10FlightCore9step_with17h`,
/// the launch vehicle's step with the navigation in its hook).
pub fn step_code_of(elf: &Path, step_name: &str) -> Result<StepCode> {
    with_dwarf(elf, |file, dwarf| step_code_in(elf, step_name, file, dwarf))
}

fn step_code_in(elf: &Path, step_name: &str, file: &object::File<'_>, dwarf: &Dwarf<'_>) -> Result<StepCode> {
    use gimli::AttributeValue;
    use object::{Object, ObjectSymbol};
    // Every inlined instance of FlightCore::step and FlightCore::background.
    let mut found: Vec<Inlined> = Vec::new();
    let mut units = dwarf.units();
    while let Some(header) = units.next()? {
        let unit = dwarf.unit(header)?;
        let mut entries = unit.entries();
        while let Some((_, e)) = entries.next_dfs()? {
            if e.tag() != gimli::DW_TAG_inlined_subroutine {
                continue;
            }
            let Some(AttributeValue::UnitRef(o)) = e.attr_value(gimli::DW_AT_abstract_origin)? else { continue };
            let mut origin = unit.entry(o)?;
            if let Some(AttributeValue::UnitRef(spec)) = origin.attr_value(gimli::DW_AT_specification)? {
                origin = unit.entry(spec)?;
            }
            let Some(name) = origin.attr_value(gimli::DW_AT_linkage_name)? else { continue };
            let name = dwarf.attr_string(&unit, name)?.to_string_lossy().into_owned();
            let step = name.contains(step_name);
            let background = name.contains("FlightCore") && name.contains("10background17h");
            if !(step || background) {
                continue;
            }
            let mut ranges = Vec::new();
            let mut it = dwarf.die_ranges(&unit, e)?;
            while let Some(r) = it.next()? {
                ranges.push((r.begin as u32, r.end as u32));
            }
            let Some(low) = ranges.iter().map(|r| r.0).min() else { continue };
            let entry = match e.attr_value(gimli::DW_AT_entry_pc)? {
                Some(AttributeValue::Addr(a)) => a as u32,
                _ => low,
            };
            found.push((step, entry, ranges));
        }
    }
    let (_, entry, ranges) = found
        .iter()
        .find(|f| f.0)
        .cloned()
        .with_context(|| format!("{}: no inlined FlightCore::step in its debug information", elf.display()))?;
    let caller = file
        .symbols()
        .map(|s| ((s.address() & !1) as u32, s.size() as u32))
        .find(|&(a, size)| size > 0 && (a..a + size).contains(&entry))
        .map(|(a, size)| (a, a + size))
        .context("no function symbol around the step's code")?;
    // The background work follows the step: inlined into the same loop, or called.
    let inlined = found.iter().find(|f| !f.0 && (caller.0..caller.1).contains(&f.1)).map(|f| f.1);
    let called = || {
        file.symbols()
            .find(|s| s.name().is_ok_and(|n| n.contains("FlightCore") && n.contains("10background17h")))
            .map(|s| (s.address() & !1) as u32)
    };
    let end = inlined.or_else(called).context("no FlightCore::background (the step's end)")?;
    Ok(StepCode { entry, ranges, caller, end })
}

/// The memory a RAM flip may hit: the stack's top and the statics' range.
#[derive(Debug, Clone, Copy)]
struct Ram {
    stack_top: u32,
    statics: (u32, u32),
}

impl Ram {
    fn of(elf: &Path) -> Result<Ram> {
        let s = |n: &str| symbol(elf, n).map(|a| a as u32);
        Ok(Ram { stack_top: s("_stack_start")?, statics: (s("__sdata")?, s("__euninit")?) })
    }
}

/// A random target: a register (share `reg_share`), or a byte of the RAM in use with the
/// stack pointer at `sp`.
fn pick_target(rng: &mut ChaCha8Rng, ram: Ram, sp: u32, reg_share: f64) -> Target {
    if rng.random_bool(reg_share.clamp(0.0, 1.0)) {
        // 17 core registers of 32 bits, 16 FPU registers of 64 and FPSCR: uniform per bit.
        let k = rng.random_range(0..17 * 32 + 16 * 64 + 32);
        if k < 17 * 32 {
            let reg = if k / 32 == 16 { gdb::XPSR } else { k / 32 };
            return Target::Core { reg, bit: (k % 32) as u8 };
        }
        let k = k - 17 * 32;
        if k < 16 * 64 {
            return Target::Fpu { reg: gdb::D0 + k / 64, bit: (k % 64) as u8 };
        }
        return Target::Fpu { reg: gdb::FPSCR, bit: (k - 16 * 64) as u8 };
    }
    let stack = ram.stack_top.saturating_sub(sp);
    let statics = ram.statics.1 - ram.statics.0;
    let k = rng.random_range(0..stack + statics);
    let bit = rng.random_range(0..8u8);
    if k < stack {
        Target::Stack { addr: sp + k, bit }
    } else {
        Target::Static { addr: ram.statics.0 + k - stack, bit }
    }
}

/// Bits of the core and FPU registers: r0–r15 and xPSR, d0–d15, FPSCR.
const REGISTER_BITS: u32 = 17 * 32 + 16 * 64 + 32;

/// A random target of the state: uniform over the bits of the registers and the RAM in
/// use with the stack pointer at `sp`, or with a register share `reg_share` when given.
fn pick_state(rng: &mut ChaCha8Rng, ram: Ram, sp: u32, reg_share: Option<f64>) -> Target {
    let share = reg_share.unwrap_or_else(|| {
        let ram_bits = 8.0 * f64::from(ram.stack_top.saturating_sub(sp) + ram.statics.1 - ram.statics.0);
        f64::from(REGISTER_BITS) / (f64::from(REGISTER_BITS) + ram_bits)
    });
    pick_target(rng, ram, sp, share)
}

/// A random double-bit pattern in the RAM in use ([`Population::Double`]).
fn pick_double(rng: &mut ChaCha8Rng, ram: Ram, sp: u32) -> Target {
    let lo = sp & !3;
    let stack = ram.stack_top.saturating_sub(lo) / 4;
    let statics = (ram.statics.1 - ram.statics.0) / 4;
    let words = rng.random_bool(0.5);
    // The second word must be in use too.
    // Word k and k + 1 both in the stack (k < stack − 1) or both in the statics.
    let (in_stack, in_statics) = (stack.saturating_sub(1), statics.saturating_sub(1));
    let k = rng.random_range(0..(in_stack + in_statics).max(1));
    let addr = if k < in_stack { lo + 4 * k } else { (ram.statics.0 & !3) + 4 * (k - in_stack) };
    let bit = if words { rng.random_range(0..32u8) } else { rng.random_range(0..31u8) };
    Target::Double { addr, bit, words }
}

/// A random bit of [`DEVICE_REGS`], uniform over their bits.
fn pick_device(rng: &mut ChaCha8Rng) -> Target {
    let mut k = rng.random_range(0..device_bits());
    for (i, d) in DEVICE_REGS.iter().enumerate() {
        let n = d.mask.count_ones();
        if k < n {
            let bit = (0..32u8).filter(|b| d.mask & (1 << b) != 0).nth(k as usize).unwrap_or(0);
            return Target::Device { reg: i as u8, bit };
        }
        k -= n;
    }
    Target::Device { reg: 0, bit: 0 }
}

/// MPU region number register.
const MPU_RNR: u32 = 0xE000_ED98;
/// The watchdog's lock register and its unlock key.
const WDOG_LOCK: (u32, u32) = (0x4000_8C00, 0x1ACC_E551);

/// Runs the 16-bit Thumb instruction `insn` once in the halted guest at its PC (which
/// it does not move: the instruction there runs after), xPSR's IT bits held off; the
/// code bytes, PC and xPSR restored.
fn run_insn(g: &mut Gdb, insn: u16) -> Result<()> {
    let (pc, xpsr) = (g.read_register(gdb::PC)?, g.register_u32(gdb::XPSR)?);
    let at = u32::from_le_bytes(pc.get(..4).and_then(|b| b.try_into().ok()).context("PC unread")?);
    let code = g.read_memory(at, 2)?;
    g.write_memory(at, &insn.to_le_bytes())?;
    g.write_register(gdb::XPSR, &(xpsr & !0x0600_FC00).to_le_bytes())?;
    let stepped = g.step();
    g.write_memory(at, &code)?;
    g.write_register(gdb::PC, &pc)?;
    g.write_register(gdb::XPSR, &xpsr.to_le_bytes())?;
    stepped
}

/// Flips bit `bit` of device register `d` (its [`How`]).
fn flip_device(g: &mut Gdb, d: &DeviceReg, bit: u8) -> Result<()> {
    let b = 1u32 << bit;
    match d.how {
        How::Primask => return run_insn(g, 0xB672),
        How::Faultmask => return run_insn(g, 0xB671),
        How::Mpu(r) => g.write_device_u32(MPU_RNR, r)?,
        How::Watchdog => g.write_device_u32(WDOG_LOCK.0, WDOG_LOCK.1)?,
        How::Plain | How::Enable => {}
    }
    let v = g.read_device_u32(d.addr)?;
    match d.how {
        How::Enable if v & b != 0 => g.write_device_u32(d.addr + 0x80, b)?,
        How::Enable => g.write_device_u32(d.addr, b)?,
        _ => g.write_device_u32(d.addr, v ^ b)?,
    }
    if d.how == How::Watchdog {
        g.write_device_u32(WDOG_LOCK.0, 0)?;
    }
    Ok(())
}

/// Flips the target's bit through the gdbstub.
fn flip(g: &mut Gdb, t: Target) -> Result<()> {
    match t {
        Target::Double { addr, bit, words } => {
            let pairs: [(u32, u32); 2] = if words {
                [(addr, bit.into()), (addr + 4, bit.into())]
            } else {
                [(addr, bit.into()), (addr, u32::from(bit) + 1)]
            };
            for (a, b) in pairs {
                let byte = a + b / 8;
                let v = g.read_memory(byte, 1)?;
                g.write_memory(byte, &[v.first().copied().unwrap_or(0) ^ (1 << (b % 8))])?;
            }
            Ok(())
        }
        Target::Device { reg, bit } => {
            let d = DEVICE_REGS.get(usize::from(reg)).context("no such device register")?;
            flip_device(g, d, bit)
        }
        Target::SnapshotReset { addr, bit } => {
            let b = g.read_memory(addr, 1)?;
            g.write_memory(addr, &[b.first().copied().unwrap_or(0) ^ (1 << bit)])?;
            g.monitor("system_reset").map(|_| ())
        }
        Target::Stack { addr, bit } | Target::Static { addr, bit } => {
            let b = g.read_memory(addr, 1)?;
            g.write_memory(addr, &[b.first().copied().unwrap_or(0) ^ (1 << bit)])
        }
        Target::Core { reg, bit } | Target::Fpu { reg, bit } => {
            let mut v = g.read_register(reg)?;
            let byte = v.get_mut(usize::from(bit / 8)).context("register shorter than the bit")?;
            *byte ^= 1 << (bit % 8);
            g.write_register(reg, &v)
        }
        Target::Reset => g.monitor("system_reset").map(|_| ()),
        // Sent on the control line once the guest runs ([`place_flip`]).
        Target::TickStopped | Target::Stall => Ok(()),
    }
}

/// What is being watched after a flip.
struct Watch {
    population: Population,
    star: bool,
    flip_step: u64,
    instr: u32,
    at: String,
    target: Target,
    changed: bool,
    /// The last step whose frame differed from the undisturbed one.
    last_diff: Option<u64>,
    worst: f64,
    silent: f64,
    last_bad: Option<u64>,
    last_n: u64,
    earlier: u32,
    /// Twice the undisturbed flight's 3σ per axis, ″ (the reset goal's bound).
    nominal2_arcsec: [f64; 3],
    /// The reset, if the unit reset: the step it reset in and what reset it.
    reset: Option<(u64, String)>,
    /// Events the unit logged while it rebooted (before lockstep again).
    reset_events: Vec<String>,
    /// Event frames received when the events were last compared with the undisturbed
    /// run's.
    events_seen: usize,
    /// After the reset: the first step with a frame, the first saying aligned, the last
    /// beyond twice the nominal 3σ.
    after_reset: (Option<u64>, Option<u64>, Option<u64>),
    /// The launch vehicle: navigation frames received when the watch began or last
    /// judged them, and the largest errors (m, m/s, ″).
    nav_seen: usize,
    worst_nav: [f64; 3],
}

impl Watch {
    /// Takes one step's frame against the undisturbed one and truth.
    fn frame(&mut self, n: u64, f: &OutputFrame, reference: Option<&OutputFrame>, err_arcsec: Option<[f64; 3]>) {
        self.last_n = n;
        if reference.is_none_or(|r| masked(*r) != masked(*f)) {
            self.changed = true;
            self.last_diff = Some(n);
        }
        let Some(e) = err_arcsec else {
            // A time tag with no step of the flight: not judged against truth.
            self.changed = true;
            self.last_diff = Some(n);
            return;
        };
        let o = Observed::from(f);
        let claims = f.flags & flags::CONVERGED != 0 && f.flags & (flags::DEGRADED | flags::FDI_ALARM) == 0;
        let mut bad = false;
        for (k, e) in e.iter().enumerate() {
            let sigma3 = 3.0 * o.att_sigma_rad.get(k).copied().unwrap_or(f64::INFINITY) * ssis_common::ARCSEC_PER_RAD;
            let bound = if sigma3.is_finite() { sigma3.max(BOUND_ARCSEC) } else { BOUND_ARCSEC };
            self.worst = self.worst.max(e.abs());
            if e.abs() > bound || !e.is_finite() {
                bad = true;
            }
        }
        let err = e.iter().fold(0.0f64, |a, e| a.max(e.abs()));
        if self.reset.is_some() {
            let aligned = f.st_status & ssis::flight::st_status::ALIGNED != 0;
            let beyond = e.iter().zip(&self.nominal2_arcsec).any(|(e, b)| e.abs() > *b || !e.is_finite());
            self.after_reset_frame(n, aligned, beyond);
        }
        self.judged(n, bad, claims, err);
    }

    /// After a reset: a frame of step `n`, saying aligned or not, beyond the reset goal's
    /// bound or not.
    fn after_reset_frame(&mut self, n: u64, aligned: bool, beyond: bool) {
        let (first, first_aligned, last_beyond) = &mut self.after_reset;
        first.get_or_insert(n);
        if aligned {
            first_aligned.get_or_insert(n);
        }
        if beyond {
            *last_beyond = Some(n);
        }
    }

    /// The launch vehicle's step `n`: its flight output frame `f` against the undisturbed
    /// one (changed or not; while it claims a good attitude, within max(20″, its 3σ) of
    /// the undisturbed attitude), and its navigation frames `navs` judged ([`lv`]). The
    /// error noted is the ratio of an error to its bound.
    fn lv_step(&mut self, n: u64, f: Option<&OutputFrame>, reference: Option<&OutputFrame>, navs: &[lv::NavVerdict]) {
        self.last_n = n;
        if let Some(f) = f {
            if reference.is_none_or(|r| masked(*r) != masked(*f)) {
                self.changed = true;
                self.last_diff = Some(n);
            }
            if let Some(r) = reference {
                let (o, ro) = (Observed::from(f), Observed::from(r));
                let claims = f.flags & flags::CONVERGED != 0 && f.flags & (flags::DEGRADED | flags::FDI_ALARM) == 0;
                let dev = ssis_sim::lv::angle_between(&o.q, &ro.q) * ssis_common::ARCSEC_PER_RAD;
                let sigma3 = o.att_sigma_rad.iter().fold(0.0f64, |a, s| a.max(3.0 * s)) * ssis_common::ARCSEC_PER_RAD;
                let bound = if sigma3.is_finite() { sigma3.max(BOUND_ARCSEC) } else { BOUND_ARCSEC };
                let ratio = if dev.is_finite() { dev / bound } else { f64::INFINITY };
                self.worst = self.worst.max(ratio);
                // Judged only while it claims a good attitude (the navigation frames carry
                // the launch vehicle's solution; a flagged flight frame is not a claim).
                if claims {
                    self.judged(n, ratio > 1.0, true, ratio);
                }
            }
        }
        for v in navs {
            if v.changed {
                self.changed = true;
                self.last_diff = Some(n);
            }
            for (w, e) in self.worst_nav.iter_mut().zip(v.errors) {
                *w = if e.is_finite() { w.max(e) } else { f64::INFINITY };
            }
            self.worst = self.worst.max(v.ratio);
            let bad = v.ratio > 1.0;
            if self.reset.is_some() {
                self.after_reset_frame(n, v.claims, bad);
            }
            self.judged(n, bad, v.claims, v.ratio);
        }
    }

    /// A frame of step `n` judged: beyond the bound or not, claiming a good solution or
    /// not, its error.
    fn judged(&mut self, n: u64, bad: bool, claims: bool, err: f64) {
        if bad || !claims {
            if bad && claims {
                self.silent = self.silent.max(err);
            }
            if bad || self.last_bad.is_some() {
                // Not back until the frames claim a good attitude within the bound again.
                self.last_bad = Some(n);
            }
        }
    }

    fn outcome(&self, crash: Option<String>) -> Outcome {
        if let Some(why) = crash {
            return Outcome::Crash(why);
        }
        if !self.changed {
            return Outcome::Masked;
        }
        if self.silent > 0.0 {
            return Outcome::Silent;
        }
        if let Some((_, cause)) = &self.reset {
            return match self.last_bad {
                Some(b) if b >= self.last_n => {
                    Outcome::Crash(format!("reset ({cause}), not back within the bound by the window's end"))
                }
                _ => Outcome::ResetRecovered,
            };
        }
        match self.last_bad {
            None => Outcome::Tolerated,
            Some(b) if b < self.last_n => Outcome::DetectedRecovered,
            Some(_) => Outcome::DetectedNotRecovered,
        }
    }
}

/// The tolerance on the attitude error, ″ (or the unit's own 3σ where larger).
pub const BOUND_ARCSEC: f64 = 20.0;

/// What the campaign shares across flights.
struct Ctx<'a> {
    o: &'a UpsetOptions,
    flight: &'a Flight,
    code: StepCode,
    /// The traced paths (empty until the first flip of their kind).
    paths: std::cell::RefCell<std::collections::HashMap<PathKind, place::Traced>>,
    /// The ELF's hash, the key of the paths kept on disk.
    elf_hash: u64,
    /// The populations and their shares.
    mix: Mix,
    /// The snapshot record in RAM: its address and length.
    snap_region: (u32, u32),
    /// The UART receive interrupt's entry (`DefaultHandler`).
    handler: u32,
    /// `FlightCore::snapshot_into`'s entry.
    snapshot_into: Option<u32>,
    /// The runner's steps that write the snapshot: `n % SNAPSHOT_STEPS`, once seen.
    snap_phase: std::cell::Cell<Option<u64>>,
    /// The breakpoint that finds the phase, while set.
    snap_trap: std::cell::Cell<Option<u32>>,
    /// The step whose frame is awaited.
    awaiting: std::cell::Cell<u64>,
    /// The guest's state before the first flip step, once saved.
    snapshot: std::cell::RefCell<Option<Snapshot>>,
    /// Where the snapshot is saved.
    snapshot_path: PathBuf,
    /// Flights that stopped after their flips had all been classed (masked, tolerated).
    latent: std::cell::RefCell<u32>,
    ram: Ram,
    traps: Traps,
    syms: Syms,
    started: Instant,
    /// Not a flip but this fault of the loop ([`run_injection`]).
    inject: Option<Target>,
}

impl Ctx<'_> {
    fn out_of_time(&self) -> bool {
        self.o.max_wall_s.is_some_and(|m| self.started.elapsed().as_secs_f64() >= m)
    }

    fn steps(&self, s: f64) -> u64 {
        (s / self.flight.profile.dt_s()).round().max(1.0) as u64
    }
}

/// Which traced path a flip's instruction is drawn from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
pub enum PathKind {
    /// A pass whose step took a star-tracker update (`true`) or not.
    Pass(bool),
    /// The UART receive interrupt.
    Handler,
    /// The snapshot write.
    SnapshotWrite,
}

/// Steps between two snapshots (`ssis::bsp::exec::SNAPSHOT_STEPS`).
const SNAPSHOT_STEPS: u64 = ssis::bsp::exec::SNAPSHOT_STEPS as u64;

/// The firmware's whole state after a step (QEMU's migration stream), and the runner's
/// side of the links at that point: a flight restored from it starts at the next step.
#[derive(Debug, Clone, Copy)]
struct Snapshot {
    /// The last step the guest completed.
    n: u64,
    fog_total: u32,
    st_total: u32,
    /// The launch vehicle's: FOG, accelerometer, GNSS.
    lv_totals: [u32; 3],
}

/// Removes the snapshot file when the campaign ends.
struct RemoveOnDrop(PathBuf);

impl Drop for RemoveOnDrop {
    fn drop(&mut self) {
        let _ = std::fs::remove_file(&self.0);
    }
}

/// The output links of one flight: output frames (with a sample) and event frames on
/// UART0; the launch vehicle's navigation frames on UART2.
#[derive(Default)]
struct Received {
    link: Downlink,
    frames: Vec<OutputFrame>,
    events: Vec<ssis::frames::event::EventFrame>,
    nav_dec: StreamDecoder<NavOutputFrame, 256>,
    nav: Vec<NavOutputFrame>,
}

impl Received {
    /// Takes a chunk of UART `uart`'s bytes.
    fn push(&mut self, uart: usize, bytes: &[u8]) {
        let Received { link, frames, events, nav_dec, nav } = self;
        if uart == 2 {
            // A frame that does not decode is no frame: the step's verdict misses it.
            nav_dec.push_slice(bytes, |r| {
                if let Ok(f) = r {
                    nav.push(f);
                }
            });
            return;
        }
        link.push(bytes, |d| match d {
            Down::Output(f) if f.time_us != 0 => frames.push(f),
            Down::Events(e) => events.push(e),
            _ => {}
        });
    }
}

impl Received {
    /// More output frames than the `want` STEPs sent: the unit stepped on its own tick
    /// (a reset the breakpoint at `Reset` did not catch).
    fn unasked(&self, want: usize) -> Option<String> {
        (self.frames.len() > want).then(|| "output frames without a STEP".to_string())
    }
}

/// A free TCP port for QEMU's gdbstub.
fn free_port() -> Result<u16> {
    Ok(std::net::TcpListener::bind("127.0.0.1:0")?.local_addr()?.port())
}

/// QEMU processor time without an output frame after which a flipped unit has hung, s.
/// Long enough for the watchdog's reset (100 ms of virtual time) when the guest runs
/// through code QEMU translates afresh at every instruction (a wild jump into zeros
/// runs some ten million instructions a second of processor time).
pub(crate) const HANG_CPU_S: f64 = 8.0;

/// Steps the unit is taken to be down after a reset (100 ms: reset, boot and the
/// watchdog's two periods at most): their sensor frames are not sent, as if lost while
/// the unit was not listening; the resume bridges them (`ssis::flight::snapshot`).
pub const RESET_DOWN_STEPS: u64 = 20;

/// The firmware's exception entries the runner keeps breakpoints on: a reset (the unit
/// rebooting, followed back into lockstep) and a HardFault (its faulting instruction read
/// from the exception frame). The watchdog's first timeout (NMI) is read from the
/// firmware's count of warnings when the unit resets, not caught at a breakpoint: under
/// `-icount …,sleep=off` every stop for the debugger lets QEMU warp virtual time to the
/// next timer deadline (the CPU is stopped before the machine is), and with the SysTick
/// stopped that deadline is the watchdog's second timeout, which resets the unit before
/// the NMI handler's first instruction (measured with `-d int` and
/// `-trace nvic_set_pending`).
#[derive(Debug, Clone, Copy)]
struct Traps {
    reset: u32,
    hard_fault: u32,
    /// The firmware's count of watchdog warnings since its boot (`mps2::WATCHDOG_WARNINGS`).
    warnings: Option<u32>,
}

impl Traps {
    fn of(elf: &Path) -> Result<Traps> {
        let s = |n: &str| symbol(elf, n).map(|a| (a & !1) as u32);
        let warnings = data_symbol(elf, "ssis_firmware::mps2::WATCHDOG_WARNINGS")?;
        Ok(Traps { reset: s("Reset")?, hard_fault: s("HardFault")?, warnings })
    }

    fn set(&self, g: &mut Gdb) -> Result<()> {
        for a in [self.reset, self.hard_fault] {
            g.set_breakpoint(a)?;
        }
        Ok(())
    }

    /// At a stop on `Reset`: the watchdog's warnings before it ("watchdog": one warning,
    /// then the reset at the second timeout; "watchdog, N warnings": the loop fed it in
    /// between), read from the firmware's count (RAM survives the reset). With none
    /// counted, the watchdog's raw interrupt status (WDOGRIS, not cleared by the machine's
    /// reset in QEMU) still set says that it timed out unfed and was never cleared:
    /// "watchdog, warning not handled" (under `-icount …,sleep=off` with the CPU asleep
    /// and the SysTick stopped, QEMU warps to the second timeout before the NMI handler's
    /// first instruction). `None`: no sign of the watchdog.
    fn watchdog_cause(&self, g: &mut Gdb) -> Result<Option<String>> {
        // The guest's own `ldr` at the stop reads the device; the breakpoint there is
        // lifted for that step.
        g.clear_breakpoint(self.reset)?;
        let w = watchdog_at_reset(g, self.warnings);
        g.set_breakpoint(self.reset)?;
        Ok(match w? {
            (0, true) => Some("watchdog, warning not handled".to_string()),
            (0, false) => None,
            (1, _) => Some("watchdog".to_string()),
            (n, _) => Some(format!("watchdog, {n} warnings")),
        })
    }
}

/// At the unit's `Reset` (the guest halted there, no breakpoint at its PC): the firmware's
/// count of watchdog warnings at `warnings` (`mps2::WATCHDOG_WARNINGS`; RAM survives the
/// reset) and whether the watchdog's raw interrupt status is still set (a timeout that no
/// feed cleared; read by the guest's `ldr`: the gdbstub reads the device as 0).
pub(crate) fn watchdog_at_reset(g: &mut Gdb, warnings: Option<u32>) -> Result<(u32, bool)> {
    let n = match warnings {
        Some(addr) => {
            let b = g.read_memory(addr, 4)?;
            b.get(..4).and_then(|b| b.try_into().ok()).map_or(0, u32::from_le_bytes)
        }
        None => 0,
    };
    Ok((n, g.read_device_u32(WDOG_RIS)? & 1 != 0))
}

/// The CMSDK watchdog's raw interrupt status (mps2: the watchdog at 0x4000_8000, WDOGRIS).
const WDOG_RIS: u32 = 0x4000_8010;

/// The address of the data symbol whose demangled path is `path`, if the ELF has one.
/// The debug information of an ELF as the runner reads it.
pub(crate) type Dwarf<'a> = gimli::Dwarf<gimli::EndianSlice<'a, gimli::RunTimeEndian>>;

/// Calls `f` with the ELF `elf` and its debug information.
pub(crate) fn with_dwarf<T>(elf: &Path, f: impl FnOnce(&object::File<'_>, &Dwarf<'_>) -> Result<T>) -> Result<T> {
    use object::{Object, ObjectSection};
    let data = std::fs::read(elf).with_context(|| format!("cannot read {}", elf.display()))?;
    let file = object::File::parse(&*data)?;
    let load = |id: gimli::SectionId| -> Result<std::borrow::Cow<'_, [u8]>, gimli::Error> {
        Ok(file.section_by_name(id.name()).and_then(|s| s.uncompressed_data().ok()).unwrap_or_default())
    };
    let sections = gimli::DwarfSections::load(load)?;
    let dwarf = sections.borrow(|s| gimli::EndianSlice::new(s, gimli::RunTimeEndian::Little));
    f(&file, &dwarf)
}

pub(crate) fn data_symbol(elf: &Path, path: &str) -> Result<Option<u32>> {
    use object::{Object, ObjectSymbol};
    let data = std::fs::read(elf).with_context(|| format!("cannot read {}", elf.display()))?;
    let file = object::File::parse(&*data)?;
    Ok(file.symbols().find(|s| s.name().is_ok_and(|n| demangle(n) == path)).map(|s| s.address() as u32))
}

/// The entry of the function whose (demangled) name ends in `::name` (in `name` itself when
/// it holds a `::`), if the ELF has one.
fn function_named(elf: &Path, name: &str) -> Result<Option<u32>> {
    let syms = Syms::of(elf)?;
    let tail = if name.contains("::") { name.to_string() } else { format!("::{name}") };
    Ok(syms.0.iter().find(|(_, _, n)| n.ends_with(&tail)).map(|(a, _, _)| *a))
}

/// The ELF's functions, to name an address (a HardFault's instruction, a hang's).
struct Syms(Vec<(u32, u32, String)>);

impl Syms {
    fn of(elf: &Path) -> Result<Syms> {
        use object::{Object, ObjectSymbol};
        let data = std::fs::read(elf).with_context(|| format!("cannot read {}", elf.display()))?;
        let file = object::File::parse(&*data)?;
        let mut v: Vec<(u32, u32, String)> = file
            .symbols()
            .filter(|s| s.kind() == object::SymbolKind::Text && s.size() > 0)
            .filter_map(|s| Some(((s.address() & !1) as u32, s.size() as u32, demangle(s.name().ok()?))))
            .collect();
        v.sort_by_key(|s| s.0);
        Ok(Syms(v))
    }

    /// `0x1234 (function)`, or the bare address outside every function.
    fn name(&self, pc: u32) -> String {
        let pc = pc & !1;
        match self.0.iter().find(|(a, size, _)| (*a..a.saturating_add(*size)).contains(&pc)) {
            Some((_, _, n)) => format!("{pc:#x} ({n})"),
            None => format!("{pc:#x}"),
        }
    }
}

/// A legacy-mangled Rust name (`_ZN`, length-prefixed parts, `17h<hash>E`) as its path
/// without the hash; any other name as it is.
fn demangle(name: &str) -> String {
    let Some(mut rest) = name.strip_prefix("_ZN") else { return name.to_string() };
    let mut parts = Vec::new();
    loop {
        let digits = rest.bytes().take_while(u8::is_ascii_digit).count();
        let Some(len) = rest.get(..digits).and_then(|d| d.parse::<usize>().ok()) else { break };
        let Some(part) = rest.get(digits..digits + len) else { break };
        let hash = part.len() == 17 && part.starts_with('h') && part.bytes().skip(1).all(|b| b.is_ascii_hexdigit());
        if !hash {
            let part = part.strip_prefix('_').filter(|p| p.starts_with('$')).unwrap_or(part);
            let mut p = part.to_string();
            for (from, to) in
                [("$LT$", "<"), ("$GT$", ">"), ("$u20$", " "), ("$u7b$", "{"), ("$u7d$", "}"), ("..", "::")]
            {
                p = p.replace(from, to);
            }
            parts.push(p);
        }
        rest = rest.get(digits + len..).unwrap_or("");
    }
    parts.join("::")
}

/// What became of a step sent.
enum Awaited {
    /// Its output frame came.
    Frame,
    /// The unit reset (stopped at the `Reset` breakpoint), and what reset it.
    Reset(String),
    /// It stopped: QEMU exited, the guest hung or stopped for the debugger.
    Stopped(String),
}

/// Waits for the output frame of the step just sent (`want` frames in all). On the way:
/// a stop at the HardFault breakpoint notes the faulting instruction (the stacked PC)
/// in `cause` and the guest runs on; a stop at `Reset` is the unit resetting
/// ([`Awaited::Reset`], the guest left halted there; a watchdog's warnings before it
/// read from the firmware's count).
/// Otherwise stopped when QEMU exited, the guest stopped for the debugger (a
/// breakpoint instruction reached by a wild jump), or no output for [`HANG_CPU_S`] (a
/// hang: the guest halted and its PC and LR named).
fn await_frame(
    ctx: &Ctx<'_>,
    unit: &mut Unit,
    g: &mut Gdb,
    rx: &mut Received,
    want: usize,
    cause: &mut Option<String>,
) -> Result<Awaited> {
    let child = &unit.q.as_ref().context("no QEMU")?.child;
    let patience = crate::progress::Patience::new(child, HANG_CPU_S);
    if let Some(why) = rx.unasked(want) {
        return Ok(Awaited::Stopped(why));
    }
    while rx.frames.len() < want {
        match unit.rx.recv_timeout(Duration::from_millis(20)) {
            Ok((i, b)) => rx.push(i, &b),
            Err(std::sync::mpsc::RecvTimeoutError::Disconnected) => {
                return Ok(Awaited::Stopped("QEMU closed its UARTs".into()))
            }
            Err(std::sync::mpsc::RecvTimeoutError::Timeout) => {
                if let Some(st) = unit.exited()? {
                    return Ok(Awaited::Stopped(format!("QEMU exited ({st})")));
                }
                if let Some(stop) = g.wait_stop(Duration::ZERO).ok().flatten() {
                    match on_stop(ctx, g, &stop, cause)? {
                        Some(a) => return Ok(a),
                        None => continue,
                    }
                }
                if let Some(why) = patience.exhausted() {
                    let at = match g.halt() {
                        Ok(()) => {
                            let (pc, lr) = (g.register_u32(gdb::PC)?, g.register_u32(14)?);
                            // Halted just after a WFI: the main loop is idle, feeding the
                            // watchdog, and never takes the STEP (its lockstep state hit).
                            let idle = g.read_memory(pc.wrapping_sub(2), 2).is_ok_and(|b| b == [0x30, 0xbf]);
                            let idle = if idle {
                                " (idle after WFI: the loop runs, feeds the watchdog, takes no STEP)"
                            } else {
                                ""
                            };
                            format!("; at {}{idle}, lr {}", ctx.syms.name(pc), ctx.syms.name(lr))
                        }
                        Err(_) => String::new(),
                    };
                    return Ok(Awaited::Stopped(format!("hang: {why}{at}")));
                }
            }
        }
    }
    Ok(Awaited::Frame)
}

/// A stop of the guest while a step is awaited: at the snapshot write's breakpoint (its
/// phase noted) or a `HardFault` (its faulting instruction noted in `cause`) the guest runs
/// on (`None`); at `Reset` the unit resets ([`Awaited::Reset`], the guest left halted
/// there; a watchdog's warnings before it read from the firmware's count); anywhere else
/// it stopped for the debugger.
fn on_stop(ctx: &Ctx<'_>, g: &mut Gdb, stop: &str, cause: &mut Option<String>) -> Result<Option<Awaited>> {
    let pc = g.register_u32(gdb::PC)?;
    if Some(pc) == ctx.snap_trap.get() {
        // The snapshot write: its phase in the runner's steps.
        ctx.snap_phase.set(Some(ctx.awaiting.get() % SNAPSHOT_STEPS));
        ctx.snap_trap.set(None);
        g.clear_breakpoint(pc)?;
        g.resume()?;
        return Ok(None);
    }
    if pc == ctx.traps.hard_fault {
        // The exception frame: r0–r3, r12, lr, pc, xpsr from SP.
        // (Unreadable when the stack pointer itself was hit.)
        let sp = g.register_u32(gdb::SP)?;
        let at = g.read_memory(sp.wrapping_add(24), 4).ok();
        let at = at.and_then(|b| b.get(..4).and_then(|b| b.try_into().ok())).map(u32::from_le_bytes);
        cause.get_or_insert(match at {
            Some(at) => format!("HardFault at {}", ctx.syms.name(at)),
            None => format!("HardFault (no exception frame at SP {sp:#x})"),
        });
        g.resume_past(pc)?;
        return Ok(None);
    }
    if pc == ctx.traps.reset {
        let watchdog = ctx.traps.watchdog_cause(g)?;
        return Ok(Some(Awaited::Reset(cause.take().or(watchdog).unwrap_or_else(|| "reset request".to_string()))));
    }
    Ok(Some(Awaited::Stopped(format!("the guest stopped for the debugger ({stop}) at {}", ctx.syms.name(pc)))))
}

/// Back into lockstep after a reset, the guest halted at `Reset`: LOCKSTEP goes out
/// first (the firmware takes it from its first pass, so it steps on its own tick at most
/// a few times), the guest runs, and once it is silent the output link starts afresh.
/// While it boots the guest is let past its breakpoints: a HardFault or a further reset
/// (noted in the returned list, and the boot goes on). Returns the notes and
/// the events the unit logged while booting (a snapshot refused, for one).
fn relock(ctx: &Ctx<'_>, unit: &mut Unit, g: &mut Gdb, rx: &mut Received) -> Result<Vec<String>> {
    unit.command(command::LOCKSTEP)?;
    g.resume_past(ctx.traps.reset)?;
    let mut boot = Received::default();
    let mut notes = Vec::new();
    unit.await_silence(
        |i, b| boot.push(i, b),
        || {
            if g.wait_stop(Duration::ZERO)?.is_some() {
                let pc = g.register_u32(gdb::PC)?;
                let note = if pc == ctx.traps.hard_fault {
                    "boot: HardFault"
                } else if pc == ctx.traps.reset {
                    "boot: reset again"
                } else {
                    anyhow::bail!("the guest stopped for the debugger at {} while booting", ctx.syms.name(pc));
                };
                notes.push(note.to_string());
                g.resume_past(pc)?;
            }
            Ok(())
        },
    )?;
    rx.link = Downlink::new();
    rx.nav_dec = StreamDecoder::default();
    if !boot.frames.is_empty() {
        notes.push(format!("boot: {} steps on its own tick", boot.frames.len()));
    }
    let (events, _) = ssis_common::downlink::records(&boot.events);
    Ok(notes.into_iter().chain(events.iter().map(|e| e.event.name().to_string())).collect())
}

/// The next flip's population and step at or after `from`: a snapshot write's on the
/// next step that writes the snapshot (once its phase is known; before, another
/// population is drawn).
fn schedule(ctx: &Ctx<'_>, rng: &mut ChaCha8Rng, from: u64) -> (u64, Population) {
    // Bounded: a mix whose only population is the snapshot write falls back to the state.
    for _ in 0..16 {
        let pop = ctx.mix.draw(rng);
        if pop != Population::SnapshotWrite {
            return (from, pop);
        }
        if let (Some(ph), Some(_)) = (ctx.snap_phase.get(), ctx.snapshot_into) {
            let n = from + (ph + SNAPSHOT_STEPS - from % SNAPSHOT_STEPS) % SNAPSHOT_STEPS;
            return (n, pop);
        }
    }
    (from, Population::State)
}

/// Whether a flip of `pop` goes into this pass (a star update's, or not): the passes'
/// paths are weighed by their lengths once both are traced.
fn keep(ctx: &Ctx<'_>, rng: &mut ChaCha8Rng, pop: Population, star: bool) -> bool {
    if matches!(pop, Population::Handler | Population::SnapshotWrite) {
        return true;
    }
    let paths = ctx.paths.borrow();
    let len = |k: bool| paths.get(&PathKind::Pass(k)).map(place::Traced::len);
    match (len(star), len(!star)) {
        (Some(a), Some(b)) if a < b => rng.random_bool(a as f64 / b as f64),
        _ => true,
    }
}

/// One flight in QEMU: flips until one changes an output (followed for the window), no
/// further flip fits, or the campaign has its flips; each classed into `flips`.
fn run_flight(
    ctx: &Ctx<'_>,
    rng: &mut ChaCha8Rng,
    flips: &mut Vec<Flip>,
    on_flip: &mut dyn FnMut(&Flip),
) -> Result<()> {
    let (o, fl) = (ctx.o, ctx.flight);
    let port = free_port()?;
    let snap = *ctx.snapshot.borrow();
    // A watchdog timeout resets the unit (QEMU's `-action watchdog=reset`), which the
    // runner follows, as it does a HardFault's reset.
    let mut extra =
        vec!["-gdb".to_string(), format!("tcp:127.0.0.1:{port}"), "-action".to_string(), "watchdog=reset".to_string()];
    if snap.is_some() {
        extra.extend(["-incoming".to_string(), format!("exec:cat {}", ctx.snapshot_path.display())]);
    }
    let mut unit = match &fl.lv {
        Some(lv) => {
            let opts = crate::qemu_lv::LvOptions { elf: o.elf.clone(), progress: false };
            crate::qemu_lv::boot(&opts, &fl.table, &lv.init, &extra)?
        }
        None => Unit::boot_with(&fl.table, &QemuOptions::lockstep(o.elf.clone()), &extra)?,
    };
    if snap.is_none() {
        unit.enter_lockstep(|_, _| {})?;
    }
    let mut g = Gdb::connect(port, Duration::from_secs(10))?;
    if snap.is_some() {
        let t0 = Instant::now();
        while g.monitor("info status")?.contains("inmigrate") {
            anyhow::ensure!(t0.elapsed() < Duration::from_secs(60), "QEMU did not load the saved state");
            std::thread::sleep(Duration::from_millis(5));
        }
    }
    ctx.traps.set(&mut g)?;
    let wants_phase = ctx.mix.0.iter().any(|(p, w)| *p == Population::SnapshotWrite && *w > 0.0);
    if let (true, None, Some(at)) = (wants_phase, ctx.snap_phase.get(), ctx.snapshot_into) {
        g.set_breakpoint(at)?;
        ctx.snap_trap.set(Some(at));
    }
    g.resume()?;
    let (quiet, window, gap) = (ctx.steps(o.quiet_s), ctx.steps(o.window_s), ctx.steps(o.gap_s));
    let last_n = fl.inputs.last().map_or(fl.len() as u64, |i| i.n);
    let dt_us = u64::from(fl.profile.dt_us);
    let first = ctx.steps(o.first_s) + rng.random_range(0..=gap);
    let (mut next_flip, mut next_pop) = schedule(ctx, rng, first);
    let mut watch: Option<Watch> = None;
    let mut earlier = 0;
    let mut eval = Evaluator::for_unit(&fl.table, &fl.profile, fl.settle_s);
    let mut rx = Received::default();
    let (mut fog_total, mut st_total) = snap.map_or((0, 0), |s| (s.fog_total, s.st_total));
    // The launch vehicle's byte totals: FOG, accelerometer, GNSS.
    let mut lv_totals = snap.map_or([0; 3], |s| s.lv_totals);
    let mut crash = None;
    // STEP frames sent in this flight: one output frame each.
    let mut sent = 0usize;
    // After a reset: the last step of the unit's down time (not sent).
    let mut down_to = 0;
    let mut cause = None;
    for i in 0..fl.len() {
        let input = fl.inputs.get(i);
        let n = input.map_or(i as u64 + 1, |x| x.n);
        if snap.is_some_and(|s| n <= s.n) || n <= down_to {
            if let Some(t) = input.and_then(|x| x.truth) {
                eval.push_truth(t);
            }
            continue;
        }
        if ctx.snapshot.borrow().is_none() && n == ctx.steps(o.first_s) {
            g.halt()?;
            g.save_state(&ctx.snapshot_path)?;
            g.resume()?;
            *ctx.snapshot.borrow_mut() = Some(Snapshot { n: n - 1, fog_total, st_total, lv_totals });
        }
        let done = flips.len() >= o.flips || ctx.out_of_time() || next_flip + window > last_n;
        if watch.is_none() && done {
            break;
        }
        // A reset after the last step's outputs went out (a fault late in the pass, or
        // while idle): followed before this step's bytes go to a unit that is not
        // listening.
        let pending = match watch.is_some() {
            true => match g.wait_stop(Duration::ZERO)? {
                Some(stop) => on_stop(ctx, &mut g, &stop, &mut cause)?,
                None => None,
            },
            false => None,
        };
        if let Some(t) = input.and_then(|x| x.truth) {
            eval.push_truth(t);
        }
        let awaited = match pending {
            Some(a) => a,
            None => {
                let (step, star) = match (input, &fl.lv) {
                    (_, Some(lv)) => match lv.send(&mut unit, i, &mut lv_totals) {
                        // A pass with filter work (covariance propagation, GNSS update)
                        // in place of the spacecraft's star update.
                        Ok(step) => (step, lv.filter_work.get(i).copied().unwrap_or(false)),
                        Err(e) => {
                            crash = Some(format!("the unit's links closed ({e})"));
                            break;
                        }
                    },
                    (Some(input), None) => {
                        let fb = fog_bytes(input, &fl.profile);
                        if let Err(e) =
                            unit.uarts[1].write_all(&fb).and_then(|()| unit.uarts[2].write_all(&input.st_bytes))
                        {
                            crash = Some(format!("the unit's links closed ({e})"));
                            break;
                        }
                        fog_total = fog_total.wrapping_add(fb.len() as u32);
                        st_total = st_total.wrapping_add(input.st_bytes.len() as u32);
                        let step =
                            ControlFrame { command: command::STEP, fog_bytes: fog_total, st_bytes: st_total, arg: 0 };
                        let star = fl
                            .inputs
                            .iter()
                            .position(|i| i.n == n)
                            .and_then(|i| fl.frames.get(i))
                            .and_then(Option::as_ref)
                            .is_some_and(|f| f.st_status & ssis::flight::st_status::UPDATED != 0);
                        (step, star)
                    }
                    (None, None) => break,
                };
                if watch.is_none() && n == next_flip && !keep(ctx, rng, next_pop, star) {
                    // Uniform over the instructions of all passes: a pass is taken in proportion
                    // to its path's length.
                    next_flip += 1;
                }
                ctx.awaiting.set(n);
                if watch.is_none() && n == next_flip {
                    let (instr, target, pc, population) =
                        match place::place_flip(ctx, &mut unit, &mut g, rng, &step, next_pop, star)? {
                            place::Placed::Flip { instr, target, pc, population } => (instr, target, pc, population),
                            place::Placed::Traced => {
                                // The path traced in this step: the flip in the next (a snapshot
                                // write's in the next step that writes the snapshot).
                                next_flip += if next_pop == Population::SnapshotWrite { SNAPSHOT_STEPS } else { 1 };
                                sent += 1;
                                match await_frame(ctx, &mut unit, &mut g, &mut rx, sent, &mut cause)? {
                                    Awaited::Frame => continue,
                                    Awaited::Stopped(why) | Awaited::Reset(why) => {
                                        crash = Some(why);
                                        break;
                                    }
                                }
                            }
                            place::Placed::Stopped(why) => {
                                crash = Some(why);
                                break;
                            }
                        };
                    watch = Some(Watch {
                        population,
                        star,
                        flip_step: n,
                        instr,
                        at: ctx.syms.name(pc),
                        target,
                        changed: false,
                        last_diff: None,
                        worst: 0.0,
                        silent: 0.0,
                        last_bad: None,
                        last_n: n,
                        earlier,
                        nominal2_arcsec: fl.nominal_3sigma_arcsec.map(|s| 2.0 * s),
                        reset: None,
                        reset_events: Vec::new(),
                        events_seen: rx.events.len(),
                        after_reset: (None, None, None),
                        nav_seen: rx.nav.len(),
                        worst_nav: [0.0; 3],
                    });
                    sent += 1;
                    if target.resets() {
                        // Reset by the runner: followed at once, wherever in the pass (the
                        // outputs may have gone out already).
                        Awaited::Reset("forced (system_reset)".to_string())
                    } else {
                        await_frame(ctx, &mut unit, &mut g, &mut rx, sent, &mut cause)?
                    }
                } else {
                    unit.control(&step)?;
                    sent += 1;
                    await_frame(ctx, &mut unit, &mut g, &mut rx, sent, &mut cause)?
                }
            }
        };
        match awaited {
            Awaited::Frame => {}
            Awaited::Stopped(why) => {
                crash = Some(why);
                break;
            }
            Awaited::Reset(why) => {
                let Some(w) = watch.as_mut().filter(|w| w.reset.is_none()) else {
                    crash = Some(format!("the unit reset ({why})"));
                    break;
                };
                w.reset = Some((n, why.clone()));
                (w.changed, w.last_diff, w.last_n) = (true, Some(n), n);
                match relock(ctx, &mut unit, &mut g, &mut rx) {
                    Ok(events) => w.reset_events = events,
                    Err(e) => {
                        crash = Some(format!("reset ({why}); not back in lockstep: {e}"));
                        break;
                    }
                }
                // Down 100 ms: the spacecraft's RESET_DOWN_STEPS, the launch vehicle's 80.
                let down = ctx.steps(RESET_DOWN_STEPS as f64 * 0.005);
                (sent, fog_total, st_total, down_to) = (rx.frames.len(), 0, 0, n + down);
                lv_totals = [0; 3];
                continue;
            }
        }
        let Some(w) = watch.as_mut() else { continue };
        if let Some(lv) = &fl.lv {
            // The navigation frame of the step comes on its own link: waited for (up to
            // 100 ms of wall time; none comes from a unit whose navigation output a flip
            // stopped), so that every step's verdict holds its navigation frame.
            if let Some(t) = rx.frames.last().map(|f| f.time_us) {
                let until = Instant::now() + Duration::from_millis(100);
                while rx.nav.last().is_none_or(|x| x.time_tag_us < t) && Instant::now() < until {
                    match unit.rx.recv_timeout(Duration::from_millis(5)) {
                        Ok((i, b)) => rx.push(i, &b),
                        Err(std::sync::mpsc::RecvTimeoutError::Timeout) => {}
                        Err(std::sync::mpsc::RecvTimeoutError::Disconnected) => break,
                    }
                }
            }
            let f = rx.frames.last();
            let k = f.map_or(0, |f| (f.time_us / dt_us) as usize);
            let reference = k.checked_sub(1).and_then(|i| fl.frames.get(i)).and_then(Option::as_ref);
            let navs: Vec<lv::NavVerdict> =
                rx.nav.get(w.nav_seen..).unwrap_or(&[]).iter().filter_map(|f| lv.judge(f)).collect();
            w.nav_seen = rx.nav.len();
            w.lv_step(n, f, reference, &navs);
        } else if let Some(f) = rx.frames.last() {
            if n == w.flip_step && std::env::var_os("SSIS_UPSET_TIMES").is_some() {
                eprintln!("the flip's step took {} ticks on the unit's clock", f.counters.step_ticks);
            }
            let k = (f.time_us / dt_us) as usize;
            let reference = k.checked_sub(1).and_then(|i| fl.frames.get(i)).and_then(Option::as_ref);
            let err = eval.evaluate(&Observed::from(f)).map(|r| r.att_err_arcsec);
            w.frame(n, f, reference, err);
        }
        if rx.events.len() > w.events_seen {
            // Event frames are outputs too: one the undisturbed run did not send is a change.
            w.events_seen = rx.events.len();
            if !new_events(ctx, w.flip_step, w.last_n, &rx).is_empty() {
                (w.changed, w.last_diff) = (true, Some(n));
            }
        }
        let end = if w.changed { w.flip_step + window } else { w.flip_step + quiet };
        // Changed within the bound, then identical again for the quiet time: tolerated, and
        // the flight goes on as after a masked flip (with the same caveat).
        let settled = w.last_bad.is_none() && w.last_diff.is_some_and(|d| n >= d + quiet);
        // A silent frame decides the class: nothing later changes it.
        let decided = w.silent > 0.0;
        if n >= end || settled || decided {
            let goes_on = (!w.changed || settled) && !decided;
            flips.push(finish(w, None, ctx, &rx));
            on_flip(flips.last().context("no flip")?);
            watch = None;
            if !goes_on {
                break;
            }
            earlier += 1;
            let from = n + 1 + rng.random_range(0..=gap);
            (next_flip, next_pop) = schedule(ctx, rng, from);
        }
    }
    if let Some(w) = watch.as_ref() {
        let why = crash.map(|c| {
            unit.kill();
            let log = unit.log(&o.elf);
            let c = match qemu_stderr(&mut unit) {
                Some(e) => format!("{c}; QEMU: {e}"),
                None => c,
            };
            match log.iter().rev().find(|l| !l.is_empty()) {
                Some(l) => format!("{c}; firmware: {l}"),
                None => c,
            }
        });
        flips.push(finish(w, why, ctx, &rx));
        on_flip(flips.last().context("no flip")?);
    } else if let Some(c) = crash {
        // Stopped with no flip being watched: a masked flip's latent effect, or a fault.
        anyhow::ensure!(earlier > 0, "the undisturbed firmware stopped: {c}");
        *ctx.latent.borrow_mut() += 1;
    }
    unit.kill();
    Ok(())
}

/// The first line QEMU wrote on its standard error (`qemu: fatal: Lockup: …` when the
/// guest locked up: QEMU 7.2 ends the emulation there, where a Cortex-M7 stays locked
/// up until its watchdog resets it), once QEMU has ended.
fn qemu_stderr(unit: &mut Unit) -> Option<String> {
    use std::io::Read;
    let mut err = unit.q.as_mut()?.child.stderr.take()?;
    let mut s = String::new();
    let _ = err.read_to_string(&mut s);
    s.lines().find(|l| !l.trim().is_empty()).map(|l| l.trim().to_string())
}

/// The events the unit logged from step `from` (the flip's) to step `to` that the
/// undisturbed run did not.
fn new_events(ctx: &Ctx<'_>, from: u64, to: u64, rx: &Received) -> Vec<String> {
    let dt_us = u64::from(ctx.flight.profile.dt_us);
    let (t0, t1) = (from.saturating_sub(1) * dt_us, to * dt_us);
    let reference: Vec<&EventRecord> =
        ctx.flight.events.iter().filter(|e| e.time_us >= t0 && e.time_us <= t1).collect();
    let (seen, _) = ssis_common::downlink::records(&rx.events);
    seen.iter()
        .filter(|e| e.time_us >= t0 && !reference.iter().any(|r| r.event == e.event && r.time_us == e.time_us))
        .map(|e| e.event.name().to_string())
        .collect()
}

/// The flip's record: its outcome, errors, recovery time and the events the undisturbed
/// run did not log.
fn finish(w: &Watch, crash: Option<String>, ctx: &Ctx<'_>, rx: &Received) -> Flip {
    let events = new_events(ctx, w.flip_step, w.last_n, rx);
    let events = events.into_iter().chain(w.reset_events.iter().cloned()).collect();
    let outcome = w.outcome(crash);
    let dt_s = ctx.flight.profile.dt_s();
    let recovery_s = match (&outcome, w.last_bad) {
        (Outcome::DetectedRecovered | Outcome::ResetRecovered, Some(b)) => Some((b + 1 - w.flip_step) as f64 * dt_s),
        _ => None,
    };
    let (first, aligned, beyond) = w.after_reset;
    let since_reset = |to: u64| w.reset.as_ref().map(|(r, _)| to.saturating_sub(*r) as f64 * dt_s);
    let reset_aligned_s = aligned.and_then(since_reset);
    let back = match beyond {
        Some(b) if b >= w.last_n => None,
        Some(b) => Some(b + 1),
        None => first,
    };
    let reset_nominal_s = back.and_then(since_reset);
    Flip {
        population: w.population,
        star: w.star,
        step: w.flip_step,
        instr: w.instr,
        at: w.at.clone(),
        target: w.target,
        outcome,
        worst_arcsec: w.worst,
        silent_arcsec: w.silent,
        recovery_s,
        reset_cause: w.reset.as_ref().map(|(_, c)| c.clone()),
        reset_after_s: w.reset.as_ref().map(|(r, _)| r.saturating_sub(w.flip_step) as f64 * dt_s),
        reset_aligned_s,
        reset_nominal_s,
        events,
        earlier_in_flight: w.earlier,
        nav_worst: ctx.flight.lv.as_ref().map(|_| (w.worst_nav, w.worst)),
    }
}

/// Runs the campaign on scenario `sc`: `o.flips` flips (fewer if `o.max_wall_s` ends it),
/// `on_flip` told of each.
pub fn run_campaign(sc: &Scenario, o: &UpsetOptions, on_flip: impl FnMut(&Flip)) -> Result<Campaign> {
    campaign(Flown::Spacecraft(sc), o, &Mix::state(), None, on_flip)
}

/// What a campaign flies: a spacecraft scenario on `ssis-fw-test`, or a launch-vehicle
/// ascent on `ssis-fw-lv-test`. The two differ only in the bytes a step sends, the step's
/// code, the RAM in use (from the ELF) and the judgement of the outputs ([`lv`]).
#[derive(Debug, Clone, Copy)]
pub enum Flown<'a> {
    /// The spacecraft unit (5 ms step, FOG bus and star tracker).
    Spacecraft(&'a Scenario),
    /// The launch vehicle (1.25 ms step, FOG bus, accelerometer bus, GNSS; navigation
    /// output frames judged).
    LaunchVehicle(&'a LvScenario),
}

impl Flown<'_> {
    fn name(&self) -> &str {
        match self {
            Flown::Spacecraft(sc) => &sc.name,
            Flown::LaunchVehicle(sc) => &sc.name,
        }
    }
}

/// [`run_campaign`] with the flips drawn from the populations of `mix`.
pub fn run_campaign_mix(sc: &Scenario, o: &UpsetOptions, mix: &Mix, on_flip: impl FnMut(&Flip)) -> Result<Campaign> {
    campaign(Flown::Spacecraft(sc), o, mix, None, on_flip)
}

/// [`run_campaign_mix`] on what `flown` names (the launch vehicle's ascent, for one).
pub fn run_flown_mix(flown: Flown<'_>, o: &UpsetOptions, mix: &Mix, on_flip: impl FnMut(&Flip)) -> Result<Campaign> {
    campaign(flown, o, mix, None, on_flip)
}

/// [`run_campaign`] with a fault of the loop in place of each flip: `fault` is
/// [`Target::TickStopped`] or [`Target::Stall`] (any other target is refused). The
/// watchdog's reset is followed as a flip's is, with its recovery times.
pub fn run_injection(sc: &Scenario, o: &UpsetOptions, fault: Target, on_flip: impl FnMut(&Flip)) -> Result<Campaign> {
    anyhow::ensure!(
        matches!(fault, Target::TickStopped | Target::Stall),
        "{}: not a fault of the loop",
        fault.describe()
    );
    campaign(Flown::Spacecraft(sc), o, &Mix::state(), Some(fault), on_flip)
}

/// [`run_flown_mix`] with the one target `fault` in place of each drawn flip (a device
/// register's bit, a loop fault): the flip replayed at the instants the campaign draws.
pub fn run_flown_injection(
    flown: Flown<'_>,
    o: &UpsetOptions,
    fault: Target,
    on_flip: impl FnMut(&Flip),
) -> Result<Campaign> {
    campaign(flown, o, &Mix::state(), Some(fault), on_flip)
}

fn campaign(
    sc: Flown<'_>,
    o: &UpsetOptions,
    mix: &Mix,
    inject: Option<Target>,
    mut on_flip: impl FnMut(&Flip),
) -> Result<Campaign> {
    crate::qemu::check_qemu_and_elf(&o.elf)?;
    anyhow::ensure!(
        crate::qemu::is_test_build(&o.elf)?,
        "{}: not a test build (lockstep needs ssis-fw-test)",
        o.elf.display()
    );
    let started = Instant::now();
    let (flight, code) = match sc {
        Flown::Spacecraft(sc) => {
            let flight = Flight::record(sc)?;
            anyhow::ensure!(flight.profile.dt_us == 5_000, "the QEMU firmware runs the spacecraft profile (5 ms)");
            (flight, step_code(&o.elf)?)
        }
        Flown::LaunchVehicle(sc) => (Flight::record_lv(sc)?, step_code_of(&o.elf, "10FlightCore9step_with17h")?),
    };
    let elf_hash = place::elf_hash(&o.elf)?;
    static CAMPAIGN: std::sync::atomic::AtomicU32 = std::sync::atomic::AtomicU32::new(0);
    let k = CAMPAIGN.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
    let snapshot_path = std::env::temp_dir().join(format!("ssis-upset-{}-{k}.state", std::process::id()));
    let _remove = RemoveOnDrop(snapshot_path.clone());
    let ctx = Ctx {
        o,
        flight: &flight,
        code,
        paths: std::cell::RefCell::new(
            [PathKind::Pass(false), PathKind::Pass(true), PathKind::Handler, PathKind::SnapshotWrite]
                .into_iter()
                .filter_map(|k| place::Traced::load(elf_hash, k).map(|p| (k, p)))
                .collect(),
        ),
        elf_hash,
        mix: mix.clone(),
        snap_region: (
            symbol(&o.elf, "_snapshot_start")? as u32,
            match flight.lv {
                // The navigation's snapshot follows the core's (word-aligned).
                Some(_) => {
                    let core_words = std::mem::size_of::<ssis::flight::snapshot::Snapshots>().div_ceil(4);
                    (4 * core_words + std::mem::size_of::<ssis::nav::snapshot::NavSnapshot>()) as u32
                }
                None => std::mem::size_of::<ssis::flight::snapshot::Snapshots>() as u32,
            },
        ),
        handler: (symbol(&o.elf, "DefaultHandler")? & !1) as u32,
        snapshot_into: function_named(&o.elf, "FlightCore>::snapshot_into")?,
        snap_phase: Default::default(),
        snap_trap: Default::default(),
        awaiting: Default::default(),
        snapshot: Default::default(),
        snapshot_path,
        latent: Default::default(),
        ram: Ram::of(&o.elf)?,
        traps: Traps::of(&o.elf)?,
        syms: Syms::of(&o.elf)?,
        started,
        inject,
    };
    let mut rng = ChaCha8Rng::seed_from_u64(o.seed);
    let mut flips = Vec::with_capacity(o.flips);
    let mut flights = 0u32;
    let (mut failed, mut failed_run) = (0u32, 0u32);
    while flips.len() < o.flips && !ctx.out_of_time() {
        let before = flips.len();
        if std::env::var_os("SSIS_UPSET_TIMES").is_some() {
            eprintln!("flight {flights} at {:.1} s", started.elapsed().as_secs_f64());
        }
        if let Err(e) = run_flight(&ctx, &mut rng, &mut flips, &mut on_flip) {
            // A runner-side failure (a breakpoint never reached): the flight is dropped,
            // counted, and the campaign goes on; three in a row end it.
            failed += 1;
            eprintln!("flight {flights} failed in the runner: {e:#}");
            anyhow::ensure!(failed_run < 2, "three flights in a row failed in the runner: {e:#}");
            failed_run += 1;
            flights += 1;
            continue;
        }
        failed_run = 0;
        flights += 1;
        // A flight started just before the wall time ran out makes none: the campaign ends.
        anyhow::ensure!(
            flips.len() > before || ctx.out_of_time(),
            "a flight made no flip: is the window longer than the flight?"
        );
    }
    let paths = ctx.paths.borrow();
    let path_len = paths.get(&PathKind::Pass(false)).map_or(0, place::Traced::len);
    let mut path_lens: Vec<(PathKind, usize)> = paths.iter().map(|(k, v)| (*k, v.len())).collect();
    path_lens.sort_by_key(|(k, _)| format!("{k:?}"));
    drop(paths);
    let latent = *ctx.latent.borrow();
    Ok(Campaign {
        name: sc.name().to_string(),
        options: o.clone(),
        flips,
        flights,
        wall_s: started.elapsed().as_secs_f64(),
        entry: ctx.code.entry,
        path_len,
        path_lens,
        mix: mix.clone(),
        failed_flights: failed,
        latent,
        stack_top: ctx.ram.stack_top,
        statics: ctx.ram.statics,
        nominal_3sigma_arcsec: flight.nominal_3sigma_arcsec,
        jobs: 1,
        dt_s: flight.profile.dt_s(),
        lv: flight.lv.as_ref().map(|l| LvBounds { bound: l.bound, undisturbed_max: l.undisturbed_max }),
        elf_hash: ctx.elf_hash,
        runs: Vec::new(),
    })
}

/// [`run_campaign_mix`] as `jobs` campaigns side by side, each in its own QEMU: job j
/// makes its share of the flips with seed `o.seed + j`; the flips in job order, the
/// flights and latent flights summed, the wall time the whole run's.
pub fn run_campaign_jobs(
    sc: &Scenario,
    o: &UpsetOptions,
    mix: &Mix,
    jobs: usize,
    on_flip: impl FnMut(&Flip) + Send,
) -> Result<Campaign> {
    run_flown_jobs(Flown::Spacecraft(sc), o, mix, jobs, on_flip)
}

/// [`run_campaign_jobs`] on what `sc` names (the launch vehicle's ascent, for one).
pub fn run_flown_jobs(
    sc: Flown<'_>,
    o: &UpsetOptions,
    mix: &Mix,
    jobs: usize,
    on_flip: impl FnMut(&Flip) + Send,
) -> Result<Campaign> {
    let jobs = jobs.clamp(1, o.flips.max(1));
    if jobs == 1 {
        return run_flown_mix(sc, o, mix, on_flip);
    }
    let started = Instant::now();
    let on_flip = std::sync::Mutex::new(on_flip);
    let results: Vec<Result<Campaign>> = std::thread::scope(|scope| {
        let handles: Vec<_> = (0..jobs)
            .map(|j| {
                let o = UpsetOptions {
                    flips: o.flips / jobs + usize::from(j < o.flips % jobs),
                    seed: o.seed.wrapping_add(j as u64),
                    ..o.clone()
                };
                let on_flip = &on_flip;
                scope.spawn(move || {
                    run_flown_mix(sc, &o, mix, |f| {
                        if let Ok(mut g) = on_flip.lock() {
                            (*g)(f)
                        }
                    })
                })
            })
            .collect();
        handles.into_iter().map(|h| h.join().unwrap_or_else(|_| Err(anyhow::anyhow!("a job panicked")))).collect()
    });
    let mut all: Option<Campaign> = None;
    for r in results {
        let c = r?;
        match all.as_mut() {
            None => all = Some(c),
            Some(a) => a.absorb(c),
        }
    }
    let mut c = all.context("no job ran")?;
    c.options = o.clone();
    c.wall_s = started.elapsed().as_secs_f64();
    c.jobs = jobs;
    Ok(c)
}

#[cfg(test)]
mod tests {
    use super::demangle;

    #[test]
    fn legacy_rust_names_lose_their_hash_and_escapes() {
        assert_eq!(demangle("_ZN12ssis_fw_test8firmware3fly17h61a948d826c07518E"), "ssis_fw_test::firmware::fly");
        assert_eq!(
            demangle("_ZN4ssis6intake3fog9FogIntake7receive28_$u7b$$u7b$closure$u7d$$u7d$17h57d8c27ef99bbe14E"),
            "ssis::intake::fog::FogIntake::receive::{{closure}}"
        );
        assert_eq!(demangle("HardFault"), "HardFault");
    }
}
