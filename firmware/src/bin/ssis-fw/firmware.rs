//! `ssis-fw`: the flight core on a Cortex-M7, here the QEMU `mps2-an500` board
//! (`ssis_firmware::mps2`), spacecraft profile: four FOGs on one bus, a star tracker, 5 ms.
//!
//! Every SysTick the main loop runs one [`FlightCore::step`] on what the UART interrupts
//! have put into the receive rings, measures how long the step took (SysTick ticks, into
//! the output frame) and counts a missed tick as an overrun. Telecommands arriving on
//! UART0's receive line go to the command link ([`CommandLink`]: authenticated, acted on
//! between two steps; a table update is written into the calibration region and flown
//! from the next step); a STATUS command's report follows the next output frame. In its
//! test build (`ssis-fw-test`) a runner may switch it to lockstep (one step per control
//! frame, once the bytes it names have arrived) for exact host/QEMU comparisons, and ends
//! a run with a control frame: the firmware logs its figures (defmt over semihosting) and
//! exits QEMU with success; the flight build ignores control frames. A panic cannot
//! happen (the release build links only without a panic path); a hard fault is logged
//! and resets the unit.
//!
//! | UART | RX | TX |
//! |---|---|---|
//! | 0 | telecommands; control frames (test equipment, test build only) | output frames, command reports |
//! | 1 | FOG bus: all four FOGs, told apart by `fog_id` | — |
//! | 2 | star tracker | — |
//!
//! Memory: `memory.x` (136 KiB flash, 36 KiB RAM: 32 KiB of stack at the bottom, 3.5 KiB
//! of statics above, 512 B for the reset snapshot; the calibration table's two copies
//! and the command key in their own regions).
//!
//! Against upsets and resets (`ssis_firmware::resilience`): after each step, timed with
//! it, the background work: a slice of the CRC of the table in RAM
//! ([`FlightCore::background`], restored from the store when it differs) and of the
//! code in flash ([`CodeCheck`]), the snapshot every [`SNAPSHOT_STEPS`] and the
//! command key against its record every [`KEY_CHECK_STEPS`]. A HardFault resets the
//! unit, as the watchdog does; at boot a good snapshot resumes the core where it was.

use core::convert::Infallible;

use cortex_m::peripheral::SYST;
use ssis::bsp::boot::{self, BootReport};
use ssis::bsp::Board;
use ssis::flight::snapshot::Snapshot;
use ssis::flight::{st_status, FlightCore, FogLinks, Links, Profile};
use ssis::frames::telecommand::{CommandReport, Telecommand};
use ssis::link::{write_frame, RxRing, TxRing};
use ssis::telecommand::{CommandLink, Outcome};
use ssis_firmware::mps2::{self, Mps2, Pacer, Stopwatch, Times, Uart, UartMap};
use ssis_firmware::resilience::{self, CodeCheck, SNAPSHOT_STEPS};

/// Watchdog period in steps (warning after one period, reset after two).
const WATCHDOG_STEPS: u32 = 10;
/// Steps between two background checks of the command key (10 s at 5 ms).
const KEY_CHECK_STEPS: u32 = 2_000;

/// FOG bus receive buffer (four FOG frames per step, several steps of margin).
static FOG_RX: RxRing<512> = RxRing::new();
/// Star-tracker receive buffer.
static ST_RX: RxRing<256> = RxRing::new();
/// Control line receive buffer (telecommands, control frames).
static CTL_RX: RxRing<{ mps2::CTL_RX_LEN }> = RxRing::new();
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

ssis_firmware::mps2_firmware!(UARTS);

/// Step times: all steps, and those with a star-tracker update; and the command link's
/// time for the bytes that completed a telecommand (decode, CRC-32C, HMAC, action).
#[derive(Default)]
struct StepTimes {
    all: Times,
    st: Times,
    tc: Times,
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
    // A reset resumes from the snapshot in RAM the reset does not clear, if it passes.
    let mut spare = Snapshot::default();
    let snap = resilience::snapshot().unwrap_or(&mut spare);
    resilience::resume(core, snap);
    let mut code = CodeCheck::new();
    let (code_len, code_crc) = code.image();
    defmt::info!("code check: {} bytes of flash, CRC {=u32:#010x}", code_len, code_crc);
    mps2::init(syst, profile.dt_us, &UARTS);
    // Ten steps without a pass of the loop give the warning, twenty the reset.
    mps2::watchdog_start(WATCHDOG_STEPS * profile.dt_us);

    let mut links = Links { fog: FogLinks::Bus(FOG_RX.port()), star: ST_RX.reader(), out: OUT_TX.frame_port() };
    let mut reports = OUT_TX.frame_writer(CommandReport::LEN);
    let mut link = CommandLink::new(mps2::key_area());
    defmt::info!("command link: key id {}", link.key_id());
    if mps2::TEST_HOOKS {
        // The cost of one MAC verification (HMAC-SHA-256 of a telecommand, constant
        // time): instructions under QEMU -icount (40 a tick).
        let t = Stopwatch::start();
        let ok = link.authenticator().verify(&Telecommand::default());
        defmt::info!("hmac_verify_ticks {} (verified {})", t.ticks(), ok);
    }
    let mut flash = mps2::CalibRegion;
    let mut pacer = Pacer::new(&UARTS, &CTL_RX);
    let mut times = StepTimes::default();
    let mut warnings = 0;
    let mut steps = 0u32;
    loop {
        if ssis::link::ring_faults() != 0 {
            resilience::reset_on_ring_fault(|| {
                core.snapshot_into(snap);
            });
        }
        let due = pacer.due(
            core,
            |c| {
                FOG_RX.received().wrapping_sub(c.fog_bytes) < 0x8000_0000
                    && ST_RX.received().wrapping_sub(c.st_bytes) < 0x8000_0000
            },
            |core, bytes| {
                let t = Stopwatch::start();
                let mut commands = 0u32;
                link.receive(bytes, core, &mut flash, |o| {
                    commands += 1;
                    if let Outcome::Refused(r) = o {
                        defmt::warn!("telecommand refused: {}", r);
                    }
                });
                if commands > 0 {
                    times.tc.push(t.ticks());
                }
            },
        );
        if due {
            let t = Stopwatch::start();
            let out = core.step(&mut links);
            // The background work, timed with the step: a slice of the table's and the
            // code's CRC, the snapshot every SNAPSHOT_STEPS, the key every KEY_CHECK_STEPS.
            core.background(mps2::calib_area());
            let _ = code.step(core);
            steps = steps.wrapping_add(1);
            if steps.is_multiple_of(SNAPSHOT_STEPS) {
                core.snapshot_into(snap);
            }
            if steps.is_multiple_of(KEY_CHECK_STEPS) && link.check_key(mps2::key_area()) {
                core.note_key_restored();
            }
            let ticks = t.ticks();
            core.set_step_ticks(u16::try_from(ticks).unwrap_or(u16::MAX));
            times.all.push(ticks);
            if out.st_status & st_status::UPDATED != 0 {
                times.st.push(ticks);
            }
            if let Some(r) = link.take_report() {
                let _ = write_frame(&mut reports, &r.to_bytes());
            }
            if mps2::watchdog_warnings() != warnings {
                warnings = mps2::watchdog_warnings();
                core.note_watchdog_warning();
            }
            core.send_events(&mut links.out);
        }
        pacer.end_pass(due, || report_end(core, &times));
    }
}

/// The end-of-run figures, on the defmt log (out of line: once a run, kept out of the
/// main loop's code).
#[inline(never)]
#[cold]
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
    defmt::info!("tc_receives {} tc_mean_ticks_x100 {} tc_max_ticks {}", t.tc.n, t.tc.mean_x100(), t.tc.max);
    mps2::report(core, FOG_RX.overflows().saturating_add(ST_RX.overflows()));
}
