//! On-target test binary: the built-in test and a replay of the whole core on the target
//! CPU, judged by the semihosting exit code. Runs under QEMU (`mps2-an500`, Cortex-M7)
//! or on any Cortex-M7 board with a debugger attached; it uses no peripheral.
//!
//! It logs (defmt) the result of [`ssis::bit::power_on`] and the [`ssis::bit::replay_digest`]
//! of a 2,000-step flight, then passes only if the built-in test passed (the harness,
//! `ssis_firmware::harness`: semihosting exit code). The host test (`host-tests/tests/qemu.rs`)
//! compares the digest with its own run of the same code: equal digests mean the target
//! computes the host's outputs bit for bit.
#![no_std]
#![no_main]
#![deny(clippy::unwrap_used, clippy::expect_used, clippy::indexing_slicing, clippy::panic)]

ssis_firmware::mps2_test!();

/// Steps of the replay.
const REPLAY_STEPS: u32 = 2_000;

#[cortex_m_rt::entry]
fn main() -> ! {
    let bit = ssis::bit::power_on();
    match bit {
        Ok(()) => defmt::info!("bit ok"),
        Err(e) => defmt::error!("bit failed: {}", e),
    }
    let d = ssis::bit::replay_digest(REPLAY_STEPS);
    let [w, x, y, z] = d.q_bits;
    defmt::info!(
        "replay steps {} output_crc {=u32:08x} q {=u64:016x} {=u64:016x} {=u64:016x} {=u64:016x}",
        d.steps,
        d.output_crc,
        w,
        x,
        y,
        z
    );
    ssis_firmware::harness::finish("selftest", bit.is_ok())
}
