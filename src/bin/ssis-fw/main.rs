//! `ssis-fw`: the flight core on a Cortex-M7, here the QEMU `mps2-an500` board.
//!
//! Every SysTick (5 ms, the spacecraft profile) the main loop runs one
//! [`FlightCore::step`] on what the UART interrupts have put into the receive rings,
//! measures how long the step took (SysTick ticks, into the output frame) and counts a
//! missed tick as an overrun. A runner may switch it to lockstep (one step per control
//! frame, once the bytes it names have arrived) for exact host/QEMU comparisons, and
//! ends a run with a control frame: the firmware logs its figures (defmt over
//! semihosting) and exits QEMU with success. A panic or a hard fault exits with failure.
#![no_std]
#![no_main]
#![deny(clippy::unwrap_used, clippy::expect_used, clippy::indexing_slicing, clippy::panic)]

mod board;

use heapless::Deque;
use ssis::calib::store;
use ssis::flight::{st_status, FlightCore, FogLinks, Links, Profile};
use ssis::frames::control::{command, ControlFrame};
use ssis::frames::decoder::StreamDecoder;
use ssis::frames::output::OutputFrame;
use ssis::link::drain;

/// Watchdog period in steps (warning after one period, reset after two).
const WATCHDOG_STEPS: u32 = 10;

/// Step-time statistics in SysTick ticks.
#[derive(Default)]
struct StepTimes {
    n: u32,
    sum: u64,
    max: u32,
    n_st: u32,
    sum_st: u64,
    max_st: u32,
}

#[cortex_m_rt::entry]
fn main() -> ! {
    board::guard_stack();
    board::paint_stack();
    let Some(cp) = cortex_m::Peripherals::take() else { board::exit(false) };
    let profile = Profile::SPACECRAFT;
    // Two stored copies (calib::store): the newest good one, else the other, else the
    // default table, flagged.
    let loaded = store::load(board::calib_bytes());
    for (slot, err) in [store::Slot::A, store::Slot::B].into_iter().zip(loaded.slot_errors) {
        if let Some(e) = err {
            defmt::warn!("calibration copy {} refused ({})", slot, e);
        }
    }
    if loaded.defaulted() {
        defmt::warn!("no calibration copy passed: flying on the default table");
    }
    let (table, defaulted) = (loaded.table, loaded.defaulted());
    let mut core = match FlightCore::new(profile, &table, defaulted) {
        Ok(c) => c,
        Err(e) => {
            defmt::error!("flight core refused the table: {}", e);
            board::exit(false)
        }
    };
    defmt::info!("ssis-fw up: table revision {}, defaulted {}, step {} us", table.revision, defaulted, profile.dt_us);
    // Power-on built-in test: a failure is logged and flagged in every output frame; the
    // unit still flies (the ground decides).
    if let Err(e) = ssis::bit::power_on() {
        defmt::error!("built-in test failed: {}", e);
        core.note_bit_failure();
    }
    board::init(cp.SYST, profile.dt_us);
    // Ten steps without a pass of the loop give the warning, twenty the reset.
    board::watchdog_start(WATCHDOG_STEPS * profile.dt_us);

    let mut links = Links {
        fog: FogLinks::Bus(board::FOG_RX.reader()),
        star: board::ST_RX.reader(),
        out: board::OUT_TX.frame_writer(OutputFrame::LEN),
    };
    let mut ctl_reader = board::CTL_RX.reader();
    let mut ctl: StreamDecoder<ControlFrame, 32> = StreamDecoder::new();
    let mut steps_due: Deque<ControlFrame, 8> = Deque::new();
    let mut ctl_scratch = [0u8; 32];
    let mut lockstep = false;
    let mut end = false;
    let mut stall = false;
    let mut handled = board::ticks();
    let mut times = StepTimes::default();
    let period = board::ticks_per_step();

    loop {
        board::poll_rx();
        let _ = drain(&mut ctl_reader, 64, &mut ctl_scratch, |bytes| {
            ctl.push_slice(bytes, |r| {
                if let Ok(c) = r {
                    match c.command {
                        command::LOCKSTEP => lockstep = true,
                        command::STEP => {
                            let _ = steps_due.push_back(c);
                        }
                        command::END => end = true,
                        command::STALL if cfg!(feature = "test-hooks") => stall = true,
                        _ => {}
                    }
                }
            });
        });
        let due = if lockstep {
            match steps_due.front() {
                Some(c)
                    if board::FOG_RX.received().wrapping_sub(c.fog_bytes) < 0x8000_0000
                        && board::ST_RX.received().wrapping_sub(c.st_bytes) < 0x8000_0000 =>
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
            let out = core.step(&mut links);
            let (n1, c1) = (board::ticks(), board::systick_now());
            // SysTick counts down; each interrupt in between adds a period.
            let elapsed = i64::from(n1.wrapping_sub(n0)) * i64::from(period) + i64::from(c0) - i64::from(c1);
            let ticks = u32::try_from(elapsed.max(0)).unwrap_or(u32::MAX);
            core.set_step_ticks(u16::try_from(ticks).unwrap_or(u16::MAX));
            times.n = times.n.saturating_add(1);
            times.sum = times.sum.saturating_add(u64::from(ticks));
            times.max = times.max.max(ticks);
            if out.st_status & st_status::UPDATED != 0 {
                times.n_st = times.n_st.saturating_add(1);
                times.sum_st = times.sum_st.saturating_add(u64::from(ticks));
                times.max_st = times.max_st.max(ticks);
            }
        }
        board::pump_tx();
        if stall {
            defmt::error!("test hook: main loop stalled on command");
            // Ends only by the watchdog: this is the fault being injected.
            loop {
                cortex_m::asm::nop();
            }
        }
        board::watchdog_feed();
        if end && board::OUT_TX.is_empty() {
            report(&core, &times);
            board::exit(true);
        }
        if !due && !end {
            cortex_m::asm::wfi();
        }
    }
}

/// The end-of-run figures, on the defmt log.
fn report(core: &FlightCore, t: &StepTimes) {
    let c = core.counters();
    defmt::info!(
        "steps {} mean_ticks_x100 {} max_ticks {} st_steps {} st_mean_ticks_x100 {} st_max_ticks {}",
        t.n,
        (t.sum * 100).checked_div(u64::from(t.n)).unwrap_or(0),
        t.max,
        t.n_st,
        (t.sum_st * 100).checked_div(u64::from(t.n_st)).unwrap_or(0),
        t.max_st
    );
    defmt::info!("stack_high_water_bytes {} static_ram_bytes {}", board::stack_high_water(), board::static_ram());
    defmt::info!("watchdog_warnings {}", board::watchdog_warnings());
    defmt::info!("log_dropped {}", board::log_dropped());
    defmt::info!(
        "counters fog_rejected {} fog_missing {} fog_stale {} st_accepted {} st_rejected {} overruns {} out_dropped {} rx_overflows {}",
        c.fog_frames_rejected,
        c.fog_samples_missing,
        c.fog_samples_stale,
        c.st_frames_accepted,
        c.st_frames_rejected,
        c.overruns,
        c.output_dropped,
        board::FOG_RX.overflows() + board::ST_RX.overflows()
    );
}
