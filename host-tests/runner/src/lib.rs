//! The firmware in QEMU (`qemu-system-arm -machine mps2-an500`) against the simulator: the
//! simulator's frames go in over the emulated UARTs, the firmware's output comes back and
//! is scored as the harness scores the core on the host.
//!
//! - [`qemu`]: the spacecraft firmware (`ssis-fw`), lock-step or real time; building the
//!   firmware and the on-target test binaries.
//! - [`progress`]: waits on QEMU bounded by its processor time, not the wall clock.
//! - [`qemu_lv`]: the launch-vehicle firmware (`ssis-fw-lv`, 1.25 ms period).
//! - [`json`]: the `--json` form of both summaries (docs/JSON.md).
//! - [`flight_build`]: a flight build (no test hooks) under the runner's control frames.
//! - [`transport`]: the UARTs as Unix sockets or serial ports (QEMU's pseudo-terminals,
//!   the board's USB–RS-422 adapters).
//! - [`telecommands`]: the command link's side of a lockstep run (telecommands by step,
//!   the in-process reference's command link).
//! - [`gdb`]: a minimal client of QEMU's gdbstub (halt, step, breakpoints, registers,
//!   memory).
//! - [`upset`]: the upset campaign on the firmware (bit flips through the gdbstub,
//!   `ssis-qemu-upset`).
//!
//! The runner drives the test builds (`ssis-fw-test`, `ssis-fw-lv-test`: the flight
//! firmwares with their test hooks); a flight build ignores control frames and runs in
//! real time only.

pub mod flight_build;
pub mod gdb;
pub mod json;
pub mod progress;
pub mod qemu;
pub mod qemu_lv;
pub mod telecommands;
pub mod transport;
pub mod upset;
