//! `ssis-fw-lv`: the launch-vehicle unit on a Cortex-M7, here the QEMU `mps2-an500`
//! board (issue 7): three FOGs and three accelerometers, the flight core and the
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
//! Memory: `link/lv/memory.x` (128 KiB flash, 64 KiB RAM; FOG table, accelerometer
//! section and pad initialisation block in their own regions, loaded separately).
#![no_std]
#![no_main]
#![deny(clippy::unwrap_used, clippy::expect_used, clippy::indexing_slicing, clippy::panic)]

mod board;

use defmt_semihosting as _;
use heapless::Deque;
use ssis::calib::accel::AccelTable;
use ssis::calib::store;
use ssis::flight::{FlightCore, FogLinks, Links, Profile};
use ssis::frames::control::{command, ControlFrame};
use ssis::frames::decoder::StreamDecoder;
use ssis::frames::navout::NavOutputFrame;
use ssis::frames::output::OutputFrame;
use ssis::link::drain;
use ssis::nav::init::PadInit;
use ssis::nav::unit::{FilterWork, NavLinks, NavUnit};

/// Watchdog period in steps (warning after one period, reset after two): 40 steps,
/// 50 ms, the spacecraft unit's watchdog time (10 of its 5 ms steps). Ten 1.25 ms steps
/// (12.5 ms) proved too short under QEMU: with `-icount shift=0` and the guest idle,
/// QEMU adds a host stall of its own process to virtual time in one jump, and a 25 ms
/// stall on the loaded build machine reset the unit between two steps.
const WATCHDOG_STEPS: u32 = 40;

#[panic_handler]
fn panic(_info: &core::panic::PanicInfo) -> ! {
    defmt::error!("panic");
    board::exit(false)
}

/// Count, sum and worst of a time in SysTick ticks.
#[derive(Default, Clone, Copy)]
struct Times {
    n: u32,
    sum: u64,
    max: u32,
}

impl Times {
    fn push(&mut self, ticks: u32) {
        self.n = self.n.saturating_add(1);
        self.sum = self.sum.saturating_add(u64::from(ticks));
        self.max = self.max.max(ticks);
    }

    fn mean_x100(&self) -> u64 {
        (self.sum * 100).checked_div(u64::from(self.n)).unwrap_or(0)
    }
}

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

/// SysTick ticks from (`n0` interrupts, value `c0`) to now.
fn elapsed(n0: u32, c0: u32, period: u32) -> u32 {
    let (n1, c1) = (board::ticks(), board::systick_now());
    // SysTick counts down; each interrupt in between adds a period.
    let e = i64::from(n1.wrapping_sub(n0)) * i64::from(period) + i64::from(c0) - i64::from(c1);
    u32::try_from(e.max(0)).unwrap_or(u32::MAX)
}

#[cortex_m_rt::entry]
fn main() -> ! {
    board::paint_stack();
    let Some(cp) = cortex_m::Peripherals::take() else { board::exit(false) };
    let profile = Profile::LAUNCH_VEHICLE;
    let loaded = store::load(board::calib_bytes());
    for (slot, err) in [store::Slot::A, store::Slot::B].into_iter().zip(loaded.slot_errors) {
        if let Some(e) = err {
            defmt::warn!("calibration copy {} refused ({})", slot, e);
        }
    }
    let accel = match AccelTable::from_bytes(board::accel_table_bytes()).and_then(|t| t.compensator()) {
        Ok(c) => Some(c),
        Err(e) => {
            defmt::warn!("accelerometer section refused ({}): flying on the ideal one", e);
            None
        }
    };
    // Either table defaulted: flagged in every flight output frame.
    let defaulted = loaded.defaulted() || accel.is_none();
    let accel = match accel.map_or_else(|| AccelTable::IDEAL.compensator(), Ok) {
        Ok(c) => c,
        Err(e) => {
            defmt::error!("ideal accelerometer section refused: {}", e);
            board::exit(false)
        }
    };
    let init = match PadInit::from_bytes(board::init_block_bytes()) {
        Ok(i) => i,
        Err(e) => {
            defmt::error!("no valid pad initialisation block ({}): cannot navigate", e);
            board::exit(false)
        }
    };
    let mut core = match FlightCore::new(profile, &loaded.table, defaulted) {
        Ok(c) => c,
        Err(e) => {
            defmt::error!("flight core refused the table: {}", e);
            board::exit(false)
        }
    };
    // The core's attitude starts at the pad attitude: its output is the body in ECEF
    // frozen at lift-off (an inertial frame); the navigation carries q_eb itself.
    core.align(init.state.q_eb);
    let mut nav = match NavUnit::new(init.state, profile.dt_s(), accel, init.gnss) {
        Ok(n) => n,
        Err(e) => {
            defmt::error!("navigation refused the pad state: {}", e);
            board::exit(false)
        }
    };
    defmt::info!(
        "ssis-fw-lv up: table revision {}, defaulted {}, pad block revision {}, step {} us",
        loaded.table.revision,
        defaulted,
        init.revision,
        profile.dt_us
    );
    if let Err(e) = ssis::bit::power_on() {
        defmt::error!("built-in test failed: {}", e);
        core.note_bit_failure();
    }
    board::init(cp.SYST, profile.dt_us);
    board::watchdog_start(WATCHDOG_STEPS * profile.dt_us);

    let mut links = Links {
        fog: FogLinks::Bus(board::FOG_RX.reader()),
        // No star tracker on the launch vehicle: an empty link, never filled.
        star: board::NO_STAR_RX.reader(),
        out: board::OUT_TX.frame_writer(OutputFrame::LEN),
    };
    let mut nav_links = NavLinks {
        accel: board::ACCEL_RX.reader(),
        gnss: board::GNSS_RX.reader(),
        out: board::NAV_TX.frame_writer(NavOutputFrame::LEN),
    };
    let mut ctl_reader = board::CTL_RX.reader();
    let mut ctl: StreamDecoder<ControlFrame, 32> = StreamDecoder::new();
    let mut steps_due: Deque<ControlFrame, 8> = Deque::new();
    let mut ctl_scratch = [0u8; 32];
    let mut lockstep = false;
    let mut end = false;
    let mut handled = board::ticks();
    let mut times = StepTimes::default();
    let period = board::ticks_per_step();
    let mut nav_steps = 0u32;

    loop {
        board::poll_rx();
        let _ = drain(&mut ctl_reader, 64, &mut ctl_scratch, |bytes| {
            ctl.push_slice(bytes, |r| {
                if let Ok(c) = r {
                    match c.command {
                        command::LOCKSTEP => {
                            // The statistics cover the lockstep run only (not the
                            // empty steps on the timer before it).
                            lockstep = true;
                            times = StepTimes::default();
                        }
                        command::STEP => {
                            let _ = steps_due.push_back(c);
                        }
                        command::END => end = true,
                        _ => {}
                    }
                }
            });
        });
        let due = if lockstep {
            match steps_due.front() {
                Some(c)
                    if board::FOG_RX.received().wrapping_sub(c.fog_bytes) < 0x8000_0000
                        && board::ACCEL_RX.received().wrapping_sub(c.st_bytes) < 0x8000_0000
                        && (board::GNSS_RX.received() as u16).wrapping_sub(c.arg) < 0x8000 =>
                {
                    let _ = steps_due.pop_front();
                    true
                }
                _ => false,
            }
        } else {
            let t = board::ticks();
            if t != handled {
                for _ in 0..t.wrapping_sub(handled).saturating_sub(1).min(1000) {
                    core.note_overrun();
                }
                handled = t;
                true
            } else {
                false
            }
        };
        if due {
            let (n0, c0) = (board::ticks(), board::systick_now());
            core.step_with(&mut links, |t_us, body| {
                nav.step(body, t_us, &mut nav_links);
                nav_steps = nav_steps.wrapping_add(1);
            });
            let step_ticks = elapsed(n0, c0, period);
            if !lockstep {
                board::pump_tx();
            }
            let work = nav.filter_work();
            let busy = elapsed(n0, c0, period);
            if lockstep && busy > period {
                core.note_overrun();
            }
            core.set_step_ticks(u16::try_from(busy).unwrap_or(u16::MAX));
            let k = kind(work);
            if let Some(t) = times.step.get_mut(k) {
                t.push(step_ticks);
            }
            if let Some(t) = times.period.get_mut(k) {
                t.push(busy);
            }
        }
        board::pump_tx();
        board::watchdog_feed();
        if end && board::OUT_TX.is_empty() && board::NAV_TX.is_empty() {
            report(&core, &nav, &times, nav_steps);
            board::exit(true);
        }
        if !due && !end {
            cortex_m::asm::wfi();
        }
    }
}

/// The end-of-run figures, on the defmt log (`host-tests/src/qemu_lv.rs` reads them).
fn report(core: &FlightCore, nav: &NavUnit, t: &StepTimes, nav_steps: u32) {
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
    defmt::info!("stack_high_water_bytes {} static_ram_bytes {}", board::stack_high_water(), board::static_ram());
    defmt::info!("watchdog_warnings {}", board::watchdog_warnings());
    let c = core.counters();
    defmt::info!(
        "counters fog_rejected {} fog_missing {} fog_stale {} overruns {} out_dropped {} rx_overflows {}",
        c.fog_frames_rejected,
        c.fog_samples_missing,
        c.fog_samples_stale,
        c.overruns,
        c.output_dropped,
        board::rx_overflows()
    );
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
