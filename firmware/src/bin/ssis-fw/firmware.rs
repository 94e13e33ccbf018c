//! `ssis-fw`: the flight core on a Cortex-M7, here the QEMU `mps2-an500` board
//! (`ssis_firmware::mps2`), spacecraft profile: four FOGs on one bus, a star tracker, 5 ms.
//!
//! The loop is the executive every board and mission share (`ssis::bsp::exec::run`):
//! every SysTick one [`FlightCore::step`] on what the UART interrupts have put into the
//! receive rings, the after-step work on one schedule (table scrub, code check,
//! snapshot, command key), the step's time (SysTick ticks) into the output frame, a
//! missed tick an overrun, and the watchdog fed only by a step that completed within
//! its deadline. This file is the board setup ([`Mps2Unit`]) and the mission
//! ([`Spacecraft`]) plus the command link: telecommands arriving on UART0's receive line
//! go to it ([`CommandLink`]: authenticated, acted on between two steps; a table update
//! is written into the calibration region and flown from the next step); a STATUS
//! command's report follows the next output frame. In its test build (`ssis-fw-test`)
//! a runner may switch it to lockstep (one step per control frame, once the bytes it
//! names have arrived) for exact host/QEMU comparisons, and ends a run with a control
//! frame: the firmware logs its figures (defmt over semihosting) and exits QEMU with
//! success; the flight build ignores control frames. A panic cannot happen (the
//! release build links only without a panic path); a hard fault is logged and resets
//! the unit.
//!
//! | UART | RX | TX |
//! |---|---|---|
//! | 0 | telecommands; control frames (test equipment, test build only) | output frames, command reports |
//! | 1 | FOG bus: all four FOGs, told apart by `fog_id` | — |
//! | 2 | star tracker | — |
//!
//! Memory: `memory.x` (264 KiB flash, 36.5 KiB RAM: 32 KiB of stack at the bottom, 3.5 KiB
//! of statics above, 1 KiB for the reset snapshot's two copies; the calibration table's two copies
//! and the command key in their own regions).
//!
//! Against upsets and resets: a HardFault resets the unit, as the watchdog does; at boot
//! a good snapshot resumes the core where it was (`ssis_firmware::resilience`).

use core::convert::Infallible;

use cortex_m::peripheral::SYST;
use ssis::bsp::boot::{self, BootReport};
use ssis::bsp::exec::{self, Spacecraft};
use ssis::bsp::Board;
use ssis::flight::{FlightCore, FogLinks, Links, Profile};
use ssis::frames::control::ControlFrame;
use ssis::frames::telecommand::{CommandReport, Telecommand};
use ssis::link::{write_frame, RxRing, TxRing, TxRingWriter};
use ssis::telecommand::{CommandLink, Outcome};
use ssis_firmware::mps2::{self, ControlLine, Mps2, Mps2Unit, Stopwatch, Times, Uart, UartMap};

/// Watchdog period in steps (warning after one period, reset after two): 45 ms, so a
/// loop that stops stepping is reset within 90 ms of its last step.
const WATCHDOG_STEPS: u32 = 9;

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

/// The command link on the control line, with its report writer and the time it took
/// for the bytes that completed a telecommand (decode, CRC-32C, HMAC, action).
struct Commands {
    link: CommandLink,
    flash: mps2::CalibRegion,
    reports: TxRingWriter<'static, 256>,
    tc: Times,
}

impl ControlLine for Commands {
    fn receive(&mut self, core: &mut FlightCore, bytes: &[u8]) {
        let t = Stopwatch::start();
        let mut commands = 0u32;
        self.link.receive(bytes, core, &mut self.flash, |o| {
            commands += 1;
            if let Outcome::Refused(r) = o {
                defmt::warn!("telecommand refused: {}", r);
            }
        });
        if commands > 0 {
            self.tc.push(t.ticks());
        }
    }

    fn after_step(&mut self) {
        if let Some(r) = self.link.take_report() {
            let _ = write_frame(&mut self.reports, &r.to_bytes());
        }
    }

    fn check_key(&mut self) -> bool {
        self.link.check_key(mps2::key_area())
    }

    fn report(&self) {
        defmt::info!(
            "tc_receives {} tc_mean_ticks_x100 {} tc_max_ticks {}",
            self.tc.n,
            self.tc.mean_x100(),
            self.tc.max
        );
    }
}

/// Bytes dropped by full receive rings.
fn rx_overflows() -> u32 {
    FOG_RX.overflows().saturating_add(ST_RX.overflows())
}

/// Whether the bytes a STEP frame names have all arrived.
fn arrived(c: &ControlFrame) -> bool {
    FOG_RX.received().wrapping_sub(c.fog_bytes) < 0x8000_0000 && ST_RX.received().wrapping_sub(c.st_bytes) < 0x8000_0000
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

/// The board and the mission set up on the booted core, then the executive.
fn fly(core: &mut FlightCore, report: &BootReport, syst: SYST, profile: Profile) -> Infallible {
    defmt::info!(
        "ssis-fw up: table revision {}, defaulted {}, step {} us",
        core.table().revision,
        report.defaulted,
        profile.dt_us
    );
    let link = CommandLink::new(mps2::key_area());
    defmt::info!("command link: key id {}", link.key_id());
    let commands = Commands {
        link,
        flash: mps2::CalibRegion,
        reports: OUT_TX.frame_writer(CommandReport::LEN),
        tc: Times::default(),
    };
    let mut unit =
        Mps2Unit::start(syst, profile.dt_us, WATCHDOG_STEPS, &UARTS, &CTL_RX, arrived, rx_overflows, commands);
    if mps2::TEST_HOOKS {
        // The cost of one MAC verification (HMAC-SHA-256 of a telecommand, constant
        // time): instructions under QEMU -icount (40 a tick), on the tick just started.
        let t = Stopwatch::start();
        let ok = unit.line.link.authenticator().verify(&Telecommand::default());
        defmt::info!("hmac_verify_ticks {} (verified {})", t.ticks(), ok);
    }
    let links = Links { fog: FogLinks::Bus(FOG_RX.port()), star: ST_RX.reader(), out: OUT_TX.frame_port() };
    exec::run(&mut unit, &mut Spacecraft::new(links), core)
}
