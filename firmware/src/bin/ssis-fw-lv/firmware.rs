//! `ssis-fw-lv`: the launch-vehicle unit on a Cortex-M7, here the QEMU `mps2-an500`
//! board: three FOGs and three accelerometers, the flight core and the
//! strapdown navigation with loosely coupled GNSS aiding, every 1.25 ms.
//!
//! The loop is the executive every board and mission share (`ssis::bsp::exec::run`,
//! with the after-step work on its one schedule: table scrub, code check, snapshot);
//! this file is the board setup and the mission ([`Ascent`]), whose hooks are the
//! navigation. Each period (a SysTick, or a STEP control frame in lockstep):
//!
//! 1. the step: [`FlightCore::step_with`] (FOG bus → decoding, compensation,
//!    combination, attitude, flight output frame on UART0), and from its hook, for each
//!    integrated FOG sample, [`NavUnit::step`] (accelerometer bus → compensation,
//!    strapdown step in ECEF, GNSS frames held, navigation output frame on UART2);
//! 2. the output frames are handed to the UARTs (real time; in lockstep after 3, so the
//!    runner's next bytes cannot interrupt the measured filter work);
//! 3. the heavy filter work, [`NavUnit::filter_work`]: a held GNSS fix's update (about
//!    67,000 instructions) or the 15×15 covariance propagation every 80 steps (about
//!    54,000). It runs after the outputs, so it never delays a sample's output frame,
//!    and to completion in the same period, so the next period's step starts on time;
//!    the design needs the step and the filter work together to fit 1.25 ms, and checks
//!    it every period.
//!
//! Overruns: on the timer, a SysTick that passes without a step taken (the previous
//! period's work, or anything else, ran past it); in lockstep, where there is no tick to
//! miss, a period whose step + filter work took longer than the 1.25 ms period. Either
//! is counted in the flight output frame. The step time in the output frame is the
//! previous period's step + filter work, in SysTick ticks (40 instructions under
//! QEMU `-icount shift=0`).
//!
//! Lockstep (test equipment only): a STEP control frame names the byte totals the runner
//! has sent so far, and the unit steps once they have arrived; in this unit its fields
//! mean FOG bus total (`fog_bytes`), accelerometer bus total (`st_bytes`, the LV unit has
//! no star tracker) and GNSS link total modulo 2^16 (`arg`), see `docs/ICD.md`.
//!
//! | UART | RX | TX |
//! |---|---|---|
//! | 0 | control frames (test equipment) | flight output frames (kind 0x30) |
//! | 1 | FOG bus: FOG1..FOG3, told apart by `fog_id` | — |
//! | 2 | — | navigation output frames (kind 0x31) |
//! | 3 | accelerometer bus: X, Y, Z, told apart by `accel_id` | — |
//! | 4 | GNSS receiver (kind 0x21) | — |
//!
//! Board: `ssis_firmware::mps2`, as the spacecraft firmware's. Memory: `link/memory-lv.x`
//! (264 KiB flash, 256 KiB of it the flight image's budget, 64 KiB RAM: 52 KiB of stack at the bottom, 4 KiB of statics above,
//! 8 KiB for the reset snapshot; FOG table, accelerometer section and pad
//! initialisation block in their own regions, loaded separately). A reset resumes the
//! core from its snapshot and the navigation from its own (`ssis::nav::snapshot`), which
//! the executive writes with the core's ([`Mission::save`]) after it in the SNAP region.

use core::convert::Infallible;

use cortex_m::peripheral::SYST;
use ssis::bsp::boot::{self, BootReport};
use ssis::bsp::exec::{self, LoopStats, Mission};
use ssis::bsp::Board;
use ssis::calib::accel::{AccelCompensator, AccelTable, AccelTableError, TABLE_LEN as ACCEL_TABLE_LEN};
use ssis::flight::{FlightCore, FogLinks, Links, Profile, StepOutput};
use ssis::frames::control::ControlFrame;
use ssis::frames::navout::NavOutputFrame;
use ssis::link::{FramePort, NotFitted, RingPort, RxRing, RxRingReader, TxRing, TxRingWriter};
use ssis::nav::init::{PadInit, BLOCK_LEN as INIT_BLOCK_LEN};
use ssis::nav::snapshot::NavSnapshot;
use ssis::nav::unit::{FilterWork, NavLinks, NavUnit};
use ssis_firmware::mps2::{self, Mps2, Mps2Unit, Times, Uart, UartMap};
use ssis_firmware::resilience;

/// Watchdog period in steps (warning after one period, reset after two): 40 steps,
/// 50 ms, the spacecraft unit's watchdog time (10 of its 5 ms steps). Ten 1.25 ms steps
/// (12.5 ms) proved too short under QEMU: with `-icount shift=0` and the guest idle,
/// QEMU adds a host stall of its own process to virtual time in one jump, and a 25 ms
/// stall on the loaded build machine reset the unit between two steps.
const WATCHDOG_STEPS: u32 = 40;

/// The SNAP region's length in `link/memory-lv.x`: the core's two snapshots and the
/// navigation's two copies must fit (else the navigation would have no snapshot).
const SNAP_BYTES: usize = 8 * 1024;
const _: () = assert!(
    4 * core::mem::size_of::<ssis::flight::snapshot::Snapshots>().div_ceil(4) + core::mem::size_of::<NavSnapshot>()
        <= SNAP_BYTES
);

/// Offset of the pad initialisation block in the LVDATA region (the accelerometer
/// section is at 0).
const INIT_OFFSET: usize = 0x100;

/// FOG bus receive buffer (three 18-byte frames per 1.25 ms step, nine steps of margin).
static FOG_RX: RxRing<512> = RxRing::new();
/// Accelerometer bus receive buffer (three 18-byte frames per step).
static ACCEL_RX: RxRing<512> = RxRing::new();
/// GNSS receive buffer (45-byte frames, 1 Hz).
static GNSS_RX: RxRing<256> = RxRing::new();
/// Control receive buffer.
static CTL_RX: RxRing<{ mps2::CTL_RX_LEN }> = RxRing::new();
/// Flight output transmit buffer (output frames, `docs/ICD.md`).
static OUT_TX: TxRing<256> = TxRing::new();
/// Steps between two event frames on UART0 at most.
const EVENT_EVERY: u32 = 8;
/// Navigation output transmit buffer (64-byte frames).
static NAV_TX: TxRing<256> = TxRing::new();

/// This firmware's UARTs (table in the module doc).
static UARTS: UartMap = [
    Uart { rx: Some(&CTL_RX), tx: Some(&OUT_TX) },
    Uart { rx: Some(&FOG_RX), tx: None },
    Uart { rx: None, tx: Some(&NAV_TX) },
    Uart { rx: Some(&ACCEL_RX), tx: None },
    Uart { rx: Some(&GNSS_RX), tx: None },
];

ssis_firmware::mps2_firmware!(UARTS);

/// Step-time statistics: per kind of filter work (none, propagation, GNSS update or
/// refusal), the step alone and the whole period (step + filter work).
#[derive(Default)]
struct StepTimes {
    step: [Times; 3],
    period: [Times; 3],
}

fn kind(w: FilterWork) -> usize {
    match w {
        FilterWork::None => 0,
        FilterWork::Propagated => 1,
        FilterWork::Updated | FilterWork::Refused(_) => 2,
    }
}

/// The launch vehicle's mission in the executive: the core's step with the navigation
/// on its increments, the filter work after the outputs, the event frames paced.
struct Ascent<'a> {
    links: Links<RingPort<'static, 512>, NotFitted, FramePort<'static, 256>>,
    nav: &'a mut NavUnit,
    nav_links: NavLinks<RxRingReader<'static, 512>, RxRingReader<'static, 256>, TxRingWriter<'static, 256>>,
    /// The last filter work (the period's kind).
    work: FilterWork,
    /// The navigation's reset snapshot (two copies), after the core's in the SNAP region
    /// (`None` when the region cannot hold it).
    snap: Option<&'static mut NavSnapshot>,
    event_wait: u32,
    nav_steps: u32,
    times: StepTimes,
}

impl Mission for Ascent<'_> {
    #[inline(always)]
    fn step(&mut self, core: &mut FlightCore) -> StepOutput {
        let Ascent { links, nav, nav_links, nav_steps, .. } = self;
        core.step_with(links, |t_us, body| {
            nav.step(body, t_us, nav_links);
            *nav_steps = nav_steps.wrapping_add(1);
        })
    }

    fn after_outputs(&mut self, _core: &mut FlightCore) {
        self.work = self.nav.filter_work();
    }

    fn send_events(&mut self, core: &mut FlightCore) {
        // UART0 carries the output frames at 84 % of its rate (docs/ICD.md): an event
        // frame at most every EVENT_EVERY steps, so the ring always has room for the
        // next output frame.
        self.event_wait = self.event_wait.saturating_sub(1);
        if self.event_wait == 0 && core.send_events(&mut self.links.out) {
            self.event_wait = EVENT_EVERY;
        }
    }

    fn record(&mut self, step: u32, busy: u32, _out: &StepOutput) {
        // Only a test build reports them (at END): a flight build keeps none.
        if !mps2::TEST_HOOKS {
            return;
        }
        let k = kind(self.work);
        if let Some(t) = self.times.step.get_mut(k) {
            t.push(step);
        }
        if let Some(t) = self.times.period.get_mut(k) {
            t.push(busy);
        }
    }

    /// The navigation's snapshot, written with the core's over its older copy.
    fn save(&mut self) {
        if let Some(s) = self.snap.as_deref_mut() {
            self.nav.snapshot_into(s);
        }
    }

    /// At boot: the navigation resumed from the newest copy of its snapshot that passes
    /// its checks (the samples lost over the reset bridged at the first step; both
    /// refused, or the resumed one stale, leaves the navigation lost and flagged until
    /// the pad initialisation is loaded again; none at all, a cold start, keeps the pad
    /// initialisation), then both copies spoiled, so one snapshot is resumed at most
    /// once.
    fn resume(&mut self, _core: &mut FlightCore) {
        let Some(s) = self.snap.as_deref_mut() else { return };
        match self.nav.resume(s) {
            Ok(()) => defmt::warn!("reset: navigation resumed from its snapshot (sample {})", self.nav.resumed_from()),
            Err(e) => defmt::info!("no navigation snapshot resumed ({}), lost: {}", e, self.nav.lost()),
        }
        s.invalidate();
    }

    fn lockstep_began(&mut self) {
        // The statistics cover the lockstep run only (not the empty steps on the timer
        // before it).
        self.times = StepTimes::default();
    }

    fn report(&self, _core: &FlightCore, _stats: &LoopStats) {
        report_end(self.nav, &self.times, self.nav_steps);
    }
}

/// Whether the bytes a STEP frame names have all arrived: in this unit its fields are
/// the FOG bus total (`fog_bytes`), the accelerometer bus total (`st_bytes`) and the
/// GNSS total modulo 2^16 (`arg`).
fn arrived(c: &ControlFrame) -> bool {
    FOG_RX.received().wrapping_sub(c.fog_bytes) < 0x8000_0000
        && ACCEL_RX.received().wrapping_sub(c.st_bytes) < 0x8000_0000
        && (GNSS_RX.received() as u16).wrapping_sub(c.arg) < 0x8000
}

/// Bytes dropped by full receive rings.
fn rx_overflows() -> u32 {
    FOG_RX.overflows().saturating_add(ACCEL_RX.overflows()).saturating_add(GNSS_RX.overflows())
}

#[cortex_m_rt::entry]
fn main() -> ! {
    mps2::start();
    let mut board = Mps2;
    let Some(cp) = cortex_m::Peripherals::take() else { board.stop(false) };
    let profile = Profile::LAUNCH_VEHICLE;
    // The accelerometer section is only checked here, for the defaulted flag (either
    // table defaulted: flagged in every flight output frame); `fly` decodes it again
    // where the navigation is built, so `main`'s frame does not hold it under the loop.
    let accel_defaulted = accel_section().is_err();
    match boot::boot(&mut board, profile, accel_defaulted, |_, core, report| fly(core, report, cp.SYST, profile)) {
        Ok(never) => match never {},
        Err(e) => {
            defmt::error!("cannot fly: {}", e);
            board.stop(false)
        }
    }
}

/// The accelerometer section (LVDATA + 0), decoded.
fn accel_section() -> Result<AccelCompensator, AccelTableError> {
    AccelTable::from_bytes(mps2::lvdata(0, ACCEL_TABLE_LEN)).and_then(|t| t.compensator())
}

/// The navigation set up on the booted core, then the main loop.
fn fly(core: &mut FlightCore, report: &BootReport, syst: SYST, profile: Profile) -> Infallible {
    let accel = match accel_section() {
        Ok(c) => c,
        Err(e) => {
            defmt::warn!("accelerometer section refused ({}): flying on the ideal one", e);
            match AccelTable::IDEAL.compensator() {
                Ok(c) => c,
                Err(e) => {
                    defmt::error!("ideal accelerometer section refused: {}", e);
                    mps2::exit(false)
                }
            }
        }
    };
    let init = match PadInit::from_bytes(mps2::lvdata(INIT_OFFSET, INIT_BLOCK_LEN)) {
        Ok(i) => i,
        Err(e) => {
            defmt::error!("no valid pad initialisation block ({}): cannot navigate", e);
            mps2::exit(false)
        }
    };
    // The core's attitude starts at the pad attitude: its output is the body in ECEF
    // frozen at lift-off (an inertial frame); the navigation carries q_eb itself.
    core.align(init.state.q_eb);
    // Borrowed where it was built, never moved: one copy on the stack.
    let mut built = NavUnit::new(init.state, profile.dt_s(), accel, init.gnss);
    let nav = match &mut built {
        Ok(n) => n,
        Err(e) => {
            defmt::error!("navigation refused the pad state: {}", e);
            mps2::exit(false)
        }
    };
    defmt::info!(
        "ssis-fw-lv up: table revision {}, defaulted {}, pad block revision {}, step {} us",
        core.table().revision,
        report.defaulted,
        init.revision,
        profile.dt_us
    );
    // No command link on the launch vehicle: the control line carries control frames only.
    let mut unit = Mps2Unit::start(syst, profile.dt_us, WATCHDOG_STEPS, &UARTS, &CTL_RX, arrived, rx_overflows, ());
    let mut mission = Ascent {
        links: Links {
            fog: FogLinks::Bus(FOG_RX.port()),
            // No star tracker on the launch vehicle: the stage is compiled out.
            star: NotFitted,
            out: OUT_TX.frame_port(),
        },
        nav,
        nav_links: NavLinks {
            accel: ACCEL_RX.reader(),
            gnss: GNSS_RX.reader(),
            out: NAV_TX.frame_writer(NavOutputFrame::LEN),
        },
        work: FilterWork::None,
        snap: NavSnapshot::in_words(resilience::snapshot_extra()),
        event_wait: 0,
        nav_steps: 0,
        times: StepTimes::default(),
    };
    exec::run(&mut unit, &mut mission, core)
}

/// The end-of-run figures, on the defmt log (`host-tests/runner/src/qemu_lv.rs` reads
/// them; the board's counters follow).
fn report_end(nav: &NavUnit, t: &StepTimes, nav_steps: u32) {
    for (k, name) in ["none", "propagation", "gnss_update"].into_iter().enumerate() {
        let (s, p) = (t.step.get(k).copied().unwrap_or_default(), t.period.get(k).copied().unwrap_or_default());
        defmt::info!(
            "lv_times {} periods {} step_mean_ticks_x100 {} step_max_ticks {} period_mean_ticks_x100 {} period_max_ticks {}",
            name,
            s.n,
            s.mean_x100(),
            s.max,
            p.mean_x100(),
            p.max
        );
    }
    let n = nav.counters();
    let (used, refused) = nav.nav().counts();
    defmt::info!(
        "nav steps {} accel_rejected {} accel_held {} gnss_rejected {} gnss_superseded {} nav_faults {} out_dropped {} fixes_used {} fixes_refused {}",
        nav_steps,
        n.accel_frames_rejected,
        n.accel_steps_held,
        n.gnss_frames_rejected,
        n.gnss_fixes_superseded,
        n.nav_faults,
        n.output_dropped,
        used,
        refused
    );
}
