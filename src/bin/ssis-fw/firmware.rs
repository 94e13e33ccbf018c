//! `ssis-fw`: the flight core on a Cortex-M7, here the QEMU `mps2-an500` board
//! (`ssis::bsp::mps2`), spacecraft profile: four FOGs on one bus, a star tracker, 5 ms.
//!
//! Every SysTick the main loop runs one [`FlightCore::step`] on what the UART interrupts
//! have put into the receive rings, measures how long the step took (SysTick ticks, into
//! the output frame) and counts a missed tick as an overrun. A runner may switch it to
//! lockstep (one step per control frame, once the bytes it names have arrived) for exact
//! host/QEMU comparisons, and ends a run with a control frame: the firmware logs its
//! figures (defmt over semihosting) and exits QEMU with success. A panic cannot happen
//! (the release build links only without a panic path); a hard fault exits with failure.
//!
//! | UART | RX | TX |
//! |---|---|---|
//! | 0 | control frames (test equipment) | output frames |
//! | 1 | FOG bus: all four FOGs, told apart by `fog_id` | — |
//! | 2 | star tracker | — |
//!
//! Memory: `memory.x` (64 KiB flash, 32 KiB RAM: 28 KiB of stack at the bottom, 4 KiB of
//! statics above; the calibration table's two copies in their own 4 KiB region).

use core::convert::Infallible;

use cortex_m::peripheral::SYST;
use ssis::bsp::boot::{self, BootReport};
use ssis::bsp::mps2::{self, Mps2, Pacer, Stopwatch, Times, Uart, UartMap};
use ssis::bsp::Board;
use ssis::flight::{st_status, FlightCore, FogLinks, Links, Profile};
use ssis::frames::output::OutputFrame;
use ssis::link::{RxRing, TxRing};

/// Watchdog period in steps (warning after one period, reset after two).
const WATCHDOG_STEPS: u32 = 10;

/// FOG bus receive buffer (four FOG frames per step, several steps of margin).
static FOG_RX: RxRing<512> = RxRing::new();
/// Star-tracker receive buffer.
static ST_RX: RxRing<256> = RxRing::new();
/// Control receive buffer.
static CTL_RX: RxRing<64> = RxRing::new();
/// Output transmit buffer (two output frames).
static OUT_TX: TxRing<256> = TxRing::new();

/// This firmware's UARTs (table in the module doc).
static UARTS: UartMap = [
    Uart { rx: Some(&CTL_RX), tx: Some(&OUT_TX) },
    Uart { rx: Some(&FOG_RX), tx: None },
    Uart { rx: Some(&ST_RX), tx: None },
    Uart::OFF,
    Uart::OFF,
];

ssis::mps2_firmware!(UARTS);

/// Step times: all steps, and those with a star-tracker update.
#[derive(Default)]
struct StepTimes {
    all: Times,
    st: Times,
}

#[cortex_m_rt::entry]
fn main() -> ! {
    mps2::start();
    let mut board = Mps2;
    let Some(cp) = cortex_m::Peripherals::take() else { board.stop(false) };
    let profile = Profile::SPACECRAFT;
    match boot::boot(&mut board, profile, false, |_, core, report| fly(core, report, cp.SYST, profile)) {
        Ok(never) => match never {},
        Err(e) => {
            defmt::error!("cannot fly: {}", e);
            board.stop(false)
        }
    }
}

/// The main loop, on the booted core.
fn fly(core: &mut FlightCore, report: &BootReport, syst: SYST, profile: Profile) -> Infallible {
    defmt::info!(
        "ssis-fw up: table revision {}, defaulted {}, step {} us",
        core.table().revision,
        report.defaulted,
        profile.dt_us
    );
    mps2::init(syst, profile.dt_us, &UARTS);
    // Ten steps without a pass of the loop give the warning, twenty the reset.
    mps2::watchdog_start(WATCHDOG_STEPS * profile.dt_us);

    let mut links =
        Links { fog: FogLinks::Bus(FOG_RX.reader()), star: ST_RX.reader(), out: OUT_TX.frame_writer(OutputFrame::LEN) };
    let mut pacer = Pacer::new(&UARTS, &CTL_RX);
    let mut times = StepTimes::default();
    loop {
        let due = pacer.due(core, |c| {
            FOG_RX.received().wrapping_sub(c.fog_bytes) < 0x8000_0000
                && ST_RX.received().wrapping_sub(c.st_bytes) < 0x8000_0000
        });
        if due {
            let t = Stopwatch::start();
            let out = core.step(&mut links);
            let ticks = t.ticks();
            core.set_step_ticks(u16::try_from(ticks).unwrap_or(u16::MAX));
            times.all.push(ticks);
            if out.st_status & st_status::UPDATED != 0 {
                times.st.push(ticks);
            }
        }
        pacer.end_pass(due, || report_end(core, &times));
    }
}

/// The end-of-run figures, on the defmt log.
fn report_end(core: &FlightCore, t: &StepTimes) {
    defmt::info!(
        "steps {} mean_ticks_x100 {} max_ticks {} st_steps {} st_mean_ticks_x100 {} st_max_ticks {}",
        t.all.n,
        t.all.mean_x100(),
        t.all.max,
        t.st.n,
        t.st.mean_x100(),
        t.st.max
    );
    mps2::report(core, FOG_RX.overflows().saturating_add(ST_RX.overflows()));
}
