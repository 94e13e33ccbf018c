//! On-target benchmark of the launch-vehicle navigation: accelerometer
//! compensation, the strapdown step (`ssis::nav::Strapdown` inside
//! `ssis::nav::gnss::AidedNav`, covariance propagation every 80 steps) and a GNSS
//! update once a second, on synthetic 1.25 ms increments (a constant climb with a pitch
//! rate and a small vibration). Not the flight step: no frames, no links.
//!
//! SysTick runs free from the core clock (reload 2^24 − 1, no interrupt); the time of
//! each measured call is the counter difference (it counts down, modulo 2^24). Under
//! QEMU with `-icount shift=0` one tick is 40 instructions (BENCHMARKS.md).
//! It logs (defmt) the totals and passes (`ssis_firmware::harness`) when every step was
//! accepted.
#![no_std]
#![no_main]
#![deny(clippy::unwrap_used, clippy::expect_used, clippy::indexing_slicing, clippy::panic)]

use cortex_m::peripheral::syst::SystClkSource;
use cortex_m::peripheral::SYST;
use nalgebra::{Quaternion, Vector3};
use ssis::calib::accel::AccelTable;
use ssis::nav::gnss::{AidedNav, GnssConfig, GnssFix};
use ssis::nav::{wgs84, NavState};

/// Steps measured (10 s of flight at 1.25 ms).
const STEPS: u32 = 8_000;
/// Steps per GNSS fix (1 Hz).
const FIX_EVERY: u32 = 800;
const DT_S: f64 = 1.25e-3;
const MASK: u32 = 0x00FF_FFFF;

ssis_firmware::mps2_test!();

fn finish(ok: bool) -> ! {
    ssis_firmware::harness::finish("navbench", ok)
}

fn ticks_since(start: u32) -> u32 {
    start.wrapping_sub(SYST::get_current()) & MASK
}

#[cortex_m_rt::entry]
fn main() -> ! {
    let Some(cp) = cortex_m::Peripherals::take() else { finish(false) };
    let mut syst = cp.SYST;
    syst.set_clock_source(SystClkSource::Core);
    syst.set_reload(MASK);
    syst.clear_current();
    syst.enable_counter();

    let Ok(comp) = AccelTable::IDEAL.compensator() else { finish(false) };
    let r0 = wgs84::ecef_from_geodetic(0.8, 1.1, 100.0);
    let state = NavState { q_eb: Quaternion::identity(), v_e_m_s: Vector3::zeros(), r_e_m: r0 };
    let cfg = GnssConfig {
        init_att_rad: 1e-4,
        init_vel_m_s: 0.01,
        init_pos_m: 1.0,
        init_accel_bias_m_s2: 1e-3,
        init_gyro_bias_rad_s: 1e-7,
        arw_rad_sqrt_s: 1.5e-6,
        vrw_m_s_sqrt_s: 1e-4,
        accel_bias_rw_m_s2_sqrt_s: 2e-4,
        gyro_bias_rw_rad_s_sqrt_s: 1e-7,
        gate_sigma: 1e9,
    };
    let Ok(mut nav) = AidedNav::new(state, DT_S, cfg) else { finish(false) };

    let (mut step_ticks, mut max_step, mut fix_ticks, mut max_fix) = (0u64, 0u32, 0u64, 0u32);
    let mut failures = 0u32;
    let temps = [25.0; 3];
    for k in 1..=STEPS {
        // Synthetic increments (outside the measurement).
        let s = if k % 2 == 0 { 1.0 } else { -1.0 };
        let dtheta = Vector3::new(1e-5 * s, 2e-6, 1e-6 * s);
        let dv_raw = Vector3::new(25.0 * DT_S + 1e-4 * s, 1e-4, -1e-4 * s);

        let t0 = SYST::get_current();
        let dv = comp.compensate(&dv_raw, &temps, DT_S).unwrap_or(dv_raw);
        if nav.step(&dtheta, &dv).is_err() {
            failures += 1;
        }
        let t = ticks_since(t0);
        step_ticks += u64::from(t);
        max_step = max_step.max(t);

        if k % FIX_EVERY == 0 {
            let st = *nav.state();
            let fix = GnssFix { r_e_m: st.r_e_m, v_e_m_s: st.v_e_m_s, sigma_pos_m: 5.0, sigma_vel_m_s: 0.1 };
            let t0 = SYST::get_current();
            if nav.gnss_update(&fix).is_err() {
                failures += 1;
            }
            let t = ticks_since(t0);
            fix_ticks += u64::from(t);
            max_fix = max_fix.max(t);
        }
    }
    defmt::info!(
        "navbench steps {} step_ticks {} max_step_ticks {} fixes {} fix_ticks {} max_fix_ticks {} failures {}",
        STEPS,
        step_ticks,
        max_step,
        STEPS / FIX_EVERY,
        fix_ticks,
        max_fix,
        failures
    );
    finish(failures == 0)
}
