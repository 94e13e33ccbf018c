//! On-target test of the stack-overflow protection in the memory layout `link/memory-lv.x` (the
//! launch-vehicle firmware's: 52 KiB of stack at the bottom of RAM): the flight firmwares' board code
//! (`ssis_firmware::mps2`: MPU guard, HardFault report, logger) under the test harness's
//! recursion (`ssis_firmware::harness::overflow_the_stack`), which must end in a fault
//! reported below the stack with the statics intact. Run by `host-tests/tests/qemu.rs`;
//! built only with `test-hooks`.
#![no_std]
#![no_main]
#![deny(clippy::unwrap_used, clippy::expect_used, clippy::indexing_slicing, clippy::panic)]

ssis_firmware::mps2_test!();

#[cortex_m_rt::entry]
fn main() -> ! {
    ssis_firmware::harness::overflow_the_stack()
}
