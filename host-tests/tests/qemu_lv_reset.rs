//! A forced reset of the launch-vehicle firmware (`ssis-fw-lv-test`) in QEMU mid-ascent:
//! the runner flies the ascent scenario in lockstep, resets the unit (QEMU's
//! `system_reset`, what its SYSRESETREQ does) after step [`RESET_AFTER`] (7.575 s into the
//! ascent, under first-stage thrust), withholds the next [`DOWN_STEPS`] steps' bytes (the
//! unit down 50 ms, as in `tests/lv_resume.rs`) and follows the unit back into lockstep
//! (`ssis_runner::qemu_lv::run_lv_reset`).
//!
//! The claim: navigation resumes from its snapshot (`NavSnapshot`, in the SNAP region
//! after the core's), with position and velocity continuous within the GNSS-free error
//! growth over the samples it lost. The bound is the bridge's own: the same snapshot,
//! read from the unit's RAM at the reset, resumed on the host (`LvCore`) and fed the same
//! first bytes after the reset, states the 1σ position and velocity growth of carrying
//! the navigation free over the lost samples (the increments' spread of the scenario's
//! own FOG and accelerometer models, `ssis::nav::snapshot`). At the first step back the
//! firmware's position and velocity must lie within 3σ of that growth of the
//! uninterrupted flight's (the same flight, same bytes, no reset), and over the next
//! second its error against truth may exceed the uninterrupted flight's by no more than
//! 3σ of the growth carried on (position: σ_pos + σ_vel·τ), the host test's criterion.
//! And the firmware's resume is the host's: every navigation frame after the reset is
//! the host's resume of the same snapshot, fed the same bytes.

use std::cell::RefCell;
use std::path::Path;

use ssis::calib::CalibrationTable;
use ssis::flight::Profile;
use ssis::frames::navout::NavOutputFrame;
use ssis::frames::Frame;
use ssis::nav::NavState;
use ssis_runner::qemu_lv::{build_firmware, run_lv_reset, LvOptions, LvReset, LvRun, LvScenario};
use ssis_sim::lv_replay::{pad_init, AscentSensors, LvCore, LvStepBytes};

/// The unit is reset after this step (7.575 s at 1.25 ms; 61 samples after its last
/// snapshot, which the firmware takes every 80).
const RESET_AFTER: u64 = 6_060;
/// Steps whose bytes are lost while it is down (50 ms).
const DOWN_STEPS: u64 = 40;
/// Steps followed after it is back (1 s).
const AFTER_STEPS: u64 = 800;

#[test]
fn a_reset_mid_ascent_resumes_navigation_from_its_snapshot_continuous() {
    let elf = build_firmware().expect("ssis-fw-lv builds");
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios/lv-ascent.toml");
    let sc = LvScenario::from_file(&path).expect("scenario");
    let mut sensors = AscentSensors::new(&sc);
    let init = pad_init(sensors.initial());
    let steps = RESET_AFTER + DOWN_STEPS + AFTER_STEPS;
    let bytes: RefCell<Vec<LvStepBytes>> = RefCell::new(Vec::new());
    let run = LvRun {
        name: "lv-ascent, reset mid-ascent".into(),
        steps,
        table: CalibrationTable::DEFAULT,
        init,
        next: Box::new(|n| {
            let b = sensors.step(n);
            bytes.borrow_mut().push(b.clone());
            Some(b)
        }),
    };
    let reset = LvReset { after_step: RESET_AFTER, down_steps: DOWN_STEPS, record_steps: AFTER_STEPS };
    let (s, seen) = run_lv_reset(run, &LvOptions { elf, progress: false }, reset).expect("QEMU run");
    let bytes = bytes.into_inner();
    assert_eq!(s.steps, steps);
    assert!(
        s.log.iter().any(|l| l.starts_with("reset: navigation resumed from its snapshot")),
        "the firmware resumed its navigation: {:?}",
        s.log
    );
    let snap = seen.snapshot.expect("the navigation snapshot in the unit's SNAP region");
    assert!(snap.newest().is_some_and(|r| r.sealed()), "a sealed copy of the record at the reset");
    let age = RESET_AFTER - u64::from(snap.accel_counter());
    assert!(age < 80, "the snapshot was taken {age} samples before the reset (every 80)");

    // The bound: the same snapshot resumed on the host, fed the first bytes back.
    let first = RESET_AFTER + DOWN_STEPS + 1;
    let mut host = LvCore::new(&CalibrationTable::DEFAULT, &init).expect("host unit");
    host.resume_nav(&snap).expect("the host resumes the firmware's snapshot");
    // The last navigation frame of a host period's (what the firmware sends in it, before
    // the filter work that follows the outputs).
    let frame_state = |nav: &[u8]| {
        let f = nav.chunks_exact(NavOutputFrame::LEN).last().expect("a navigation frame in every period");
        NavOutputFrame::decode(f).expect("the host's frame decodes").state()
    };
    let mut host_states = vec![frame_state(&host.period(&bytes[(first - 1) as usize]).nav)];
    let bridge = host.nav().bridged().expect("the host's first step bridged the reset");
    for n in first + 1..first + AFTER_STEPS {
        host_states.push(frame_state(&host.period(&bytes[(n - 1) as usize]).nav));
    }

    let after = &seen.after;
    assert_eq!(after.len() as u64, AFTER_STEPS, "a navigation frame in every step back");
    let f = after.first().expect("the first step back");
    assert_eq!(f.n, first);
    let diff = |a: &NavState, b: &NavState| ((a.r_e_m - b.r_e_m).norm(), (a.v_e_m_s - b.v_e_m_s).norm());
    let (jump_pos_m, jump_vel_m_s) = diff(&f.firmware, &f.uninterrupted);
    let dt_s = Profile::LAUNCH_VEHICLE.dt_s();
    let mut excess_ratio = f64::NEG_INFINITY;
    let (mut excess_pos_m, mut excess_vel_m_s) = (f64::NEG_INFINITY, f64::NEG_INFINITY);
    let (mut host_equal, mut from_host_pos_m, mut from_host_vel_m_s) = (0u64, 0.0f64, 0.0f64);
    for (a, h) in after.iter().zip(&host_states) {
        let (dp, dv) = diff(&a.firmware, h);
        (from_host_pos_m, from_host_vel_m_s) = (from_host_pos_m.max(dp), from_host_vel_m_s.max(dv));
        host_equal += u64::from(a.firmware == *h);
        let t = a.truth.expect("the scenario has truth");
        let ((ep, ev), (rp, rv)) = (diff(&a.firmware, &t), diff(&a.uninterrupted, &t));
        let tau_s = (a.n - first) as f64 * dt_s;
        excess_pos_m = excess_pos_m.max(ep - rp);
        excess_vel_m_s = excess_vel_m_s.max(ev - rv);
        let ratio =
            ((ep - rp) / (bridge.sigma_pos_m + bridge.sigma_vel_m_s * tau_s)).max((ev - rv) / bridge.sigma_vel_m_s);
        excess_ratio = excess_ratio.max(ratio);
    }
    println!(
        "reset after step {RESET_AFTER} ({:.3} s), down {DOWN_STEPS} steps; snapshot {age} samples old; bridged {} \
         samples, stated 1σ {:.4} m, {:.5} m/s; first step back: {jump_pos_m:.4} m, {jump_vel_m_s:.5} m/s from the \
         uninterrupted flight (bound 3σ {:.4} m, {:.5} m/s); over {AFTER_STEPS} steps the error against truth exceeds the \
         uninterrupted flight's by at most {excess_pos_m:.4} m, {excess_vel_m_s:.5} m/s ({excess_ratio:.2}σ); wall \
         {:.0} s; the host's resume of the same snapshot: {host_equal} of {AFTER_STEPS} \
         frames' states identical, at most {from_host_pos_m:.2e} m, {from_host_vel_m_s:.2e} m/s apart",
        RESET_AFTER as f64 * dt_s,
        bridge.steps,
        bridge.sigma_pos_m,
        bridge.sigma_vel_m_s,
        3.0 * bridge.sigma_pos_m,
        3.0 * bridge.sigma_vel_m_s,
        s.wall_s
    );
    assert_eq!(u64::from(bridge.steps), age + DOWN_STEPS, "the samples lost: the snapshot's age and the down time");
    assert!(
        jump_pos_m <= 3.0 * bridge.sigma_pos_m && jump_vel_m_s <= 3.0 * bridge.sigma_vel_m_s,
        "resumed {jump_pos_m:.4} m, {jump_vel_m_s:.5} m/s from the uninterrupted flight"
    );
    assert_eq!(host_equal, AFTER_STEPS, "the firmware's resume is the host's, frame for frame");
    assert!(excess_ratio <= 3.0, "error against truth over the uninterrupted flight's: {excess_ratio:.2}σ");
}
