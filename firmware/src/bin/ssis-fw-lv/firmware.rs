//! `ssis-fw-lv`: the launch-vehicle unit on a Cortex-M7, here the QEMU `mps2-an500`
//! board: three FOGs and three accelerometers, the flight core and the
//! strapdown navigation with loosely coupled GNSS aiding, every 1.25 ms.
//!
//! Each period (a SysTick, or a STEP control frame in lockstep):
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
//! (128 KiB flash, 64 KiB RAM: 58 KiB of stack at the bottom, the navigation's reset
//! snapshot in 2 KiB, 4 KiB of statics above; FOG table, accelerometer section and pad
//! initialisation block in their own regions, loaded separately).
//!
//! Reset: the navigation's snapshot (`ssis::nav::snapshot`) is written every
//! [`NAV_SNAPSHOT_STEPS`] periods into the NAVSNAP region and, at boot, resumed from if
//! it passes its checks (the samples lost over the reset bridged at the first step); a
//! refused or stale one leaves the navigation lost and flagged until the pad
//! initialisation is loaded again. The flight core itself starts again from the pad
//! attitude (its own snapshot is not wired into this loop).

use core::convert::Infallible;

use cortex_m::peripheral::SYST;
use ssis::bsp::boot::{self, BootReport};
use ssis::bsp::Board;
use ssis::calib::accel::{AccelCompensator, AccelTable, AccelTableError, TABLE_LEN as ACCEL_TABLE_LEN};
use ssis::flight::{FlightCore, FogLinks, Links, Profile};
use ssis::frames::navout::NavOutputFrame;
use ssis::link::{NotFitted, RxRing, TxRing};
use ssis::nav::init::{PadInit, BLOCK_LEN as INIT_BLOCK_LEN};
use ssis::nav::snapshot::NavSnapshot;
use ssis::nav::unit::{FilterWork, NavLinks, NavUnit};
use ssis_firmware::mps2::{self, Mps2, Pacer, Stopwatch, Times, Uart, UartMap};
use ssis_firmware::resilience;

/// Watchdog period in steps (warning after one period, reset after two): 40 steps,
/// 50 ms, the spacecraft unit's watchdog time (10 of its 5 ms steps). Ten 1.25 ms steps
/// (12.5 ms) proved too short under QEMU: with `-icount shift=0` and the guest idle,
/// QEMU adds a host stall of its own process to virtual time in one jump, and a 25 ms
/// stall on the loaded build machine reset the unit between two steps.
const WATCHDOG_STEPS: u32 = 40;

/// Offset of the pad initialisation block in the LVDATA region (the accelerometer
/// section is at 0).
const INIT_OFFSET: usize = 0x100;

/// Periods between two navigation snapshots (100 ms at 1.25 ms): a reset resumes the
/// navigation from the last one, bridging up to this many samples plus the time down
/// (`ssis::nav::snapshot`).
const NAV_SNAPSHOT_STEPS: u32 = 80;

extern "C" {
    /// The NAVSNAP region of the layout (`link/memory-lv.x`): RAM no section is placed in.
    static mut _nav_snapshot_start: u64;
    static _nav_snapshot_len: u8;
}

/// The navigation's reset snapshot in RAM the reset does not clear (the NAVSNAP region);
/// `None` for a layout whose region is too small. Called once, by `fly`.
#[allow(unsafe_code)]
fn nav_snapshot() -> Option<&'static mut NavSnapshot> {
    let len = core::ptr::addr_of!(_nav_snapshot_len) as usize;
    if len < core::mem::size_of::<NavSnapshot>() {
        return None;
    }
    // SAFETY: the NAVSNAP region is 8-byte-aligned RAM of at least
    // `size_of::<NavSnapshot>()` bytes (checked), used by nothing else; `NavSnapshot` is
    // `repr(C)` plain old data, valid for any bit pattern (its CRC judges it); `fly` takes
    // this reference once and no interrupt touches it.
    unsafe { Some(&mut *(core::ptr::addr_of_mut!(_nav_snapshot_start) as *mut NavSnapshot)) }
}

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
    // A reset resumes the navigation from its snapshot, if that passes; spoiled either
    // way, so one snapshot is resumed at most once.
    let mut snap = nav_snapshot();
    if let Some(s) = snap.as_deref_mut() {
        match nav.resume(s) {
            Ok(()) => defmt::warn!("reset: navigation resumed from its snapshot (sample {})", s.accel_counter()),
            Err(e) => defmt::info!("no navigation snapshot resumed ({}), lost: {}", e, nav.lost()),
        }
        s.invalidate();
    }
    defmt::info!(
        "ssis-fw-lv up: table revision {}, defaulted {}, pad block revision {}, step {} us",
        core.table().revision,
        report.defaulted,
        init.revision,
        profile.dt_us
    );
    mps2::init(syst, profile.dt_us, &UARTS);
    mps2::watchdog_start(WATCHDOG_STEPS * profile.dt_us);

    let mut links = Links {
        fog: FogLinks::Bus(FOG_RX.port()),
        // No star tracker on the launch vehicle: the stage is compiled out.
        star: NotFitted,
        out: OUT_TX.frame_port(),
    };
    let mut nav_links =
        NavLinks { accel: ACCEL_RX.reader(), gnss: GNSS_RX.reader(), out: NAV_TX.frame_writer(NavOutputFrame::LEN) };
    let mut pacer = Pacer::new(&UARTS, &CTL_RX);
    let mut times = StepTimes::default();
    let mut event_wait = 0u32;
    let period = mps2::ticks_per_step();
    let mut nav_steps = 0u32;
    let mut periods = 0u32;
    loop {
        if ssis::link::ring_faults() != 0 {
            resilience::reset_on_ring_fault(|| {
                if let Some(s) = snap.as_deref_mut() {
                    nav.snapshot_into(s);
                }
            });
        }
        // In lockstep a STEP frame's fields are the FOG bus total (`fog_bytes`), the
        // accelerometer bus total (`st_bytes`) and the GNSS total modulo 2^16 (`arg`).
        let due = pacer.due(
            core,
            |c| {
                FOG_RX.received().wrapping_sub(c.fog_bytes) < 0x8000_0000
                    && ACCEL_RX.received().wrapping_sub(c.st_bytes) < 0x8000_0000
                    && (GNSS_RX.received() as u16).wrapping_sub(c.arg) < 0x8000
            },
            // No command link on the launch vehicle.
            |_, _| {},
        );
        if pacer.lockstep_began() {
            // The statistics cover the lockstep run only (not the empty steps on the
            // timer before it).
            times = StepTimes::default();
        }
        if due {
            let t = Stopwatch::start();
            core.step_with(&mut links, |t_us, body| {
                nav.step(body, t_us, &mut nav_links);
                nav_steps = nav_steps.wrapping_add(1);
            });
            let step_ticks = t.ticks();
            if !pacer.lockstep() {
                mps2::pump_tx(&UARTS);
            }
            let work = nav.filter_work();
            periods = periods.wrapping_add(1);
            if let Some(s) = snap.as_deref_mut().filter(|_| periods.is_multiple_of(NAV_SNAPSHOT_STEPS)) {
                nav.snapshot_into(s);
            }
            let busy = t.ticks();
            if pacer.lockstep() && busy > period {
                core.note_overrun();
            }
            core.set_step_ticks(u16::try_from(busy).unwrap_or(u16::MAX));
            // UART0 carries the output frames at 84 % of its rate (docs/ICD.md): an event
            // frame at most every EVENT_EVERY steps, so the ring always has room for the
            // next output frame.
            event_wait = event_wait.saturating_sub(1);
            if event_wait == 0 && core.send_events(&mut links.out) {
                event_wait = EVENT_EVERY;
            }
            let k = kind(work);
            if let Some(t) = times.step.get_mut(k) {
                t.push(step_ticks);
            }
            if let Some(t) = times.period.get_mut(k) {
                t.push(busy);
            }
        }
        pacer.end_pass(due, || report_end(core, nav, &times, nav_steps));
    }
}

/// The end-of-run figures, on the defmt log (`host-tests/runner/src/qemu_lv.rs` reads them).
fn report_end(core: &FlightCore, nav: &NavUnit, t: &StepTimes, nav_steps: u32) {
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
    let overflows = FOG_RX.overflows().saturating_add(ACCEL_RX.overflows()).saturating_add(GNSS_RX.overflows());
    mps2::report(core, overflows);
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
