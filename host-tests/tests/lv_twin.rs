//! The navigation step's protection against upsets (`ssis::nav::unit`), on the ascent
//! scenario's accelerometer and GNSS bytes (`scenarios/lv-ascent.toml`):
//!
//! - a bit of the navigation state flipped in RAM between two steps (the strapdown
//!   state and history, the biases, the pending sum, the running means, the block being
//!   summed, the covariance) is restored at the next step: every output after it is the
//!   undisturbed unit's, bit for bit;
//! - a bit flipped in one of the step's two computations (a register corrupted in it,
//!   `NavUnit::step_upset`) is outvoted by a third: every output is the undisturbed
//!   unit's; when no two computations agree the step is refused and flagged
//!   (`NAV_FAULT`), its state the one before the step: no frame claims a good solution
//!   with a wrong state.

use std::path::Path;

use nalgebra::Vector3;
use ssis::calib::accel::AccelTable;
use ssis::frames::navout::flags;
use ssis::nav::init::PadInit;
use ssis::nav::unit::{NavLinks, NavStepOutput, NavUnit, TwinUpset};
use ssis::state_map::StateField;
use ssis_common::mock::{MockLink, MockSink};
use ssis_sim::lv_replay::{pad_init, AscentSensors, LvScenario, LvStepBytes};

type Links = NavLinks<MockLink, MockLink, MockSink>;

/// Steps flown before the upset (past two covariance propagations).
const BEFORE: u64 = 200;
/// Steps compared after it (past two more propagations and a GNSS fix's update).
const AFTER: u64 = 200;

struct Flight {
    init: PadInit,
    bytes: Vec<LvStepBytes>,
}

fn flight() -> Flight {
    let sc = LvScenario::from_file(&Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios/lv-ascent.toml"))
        .expect("scenario");
    let mut sensors = AscentSensors::new(&sc);
    let init = pad_init(sensors.initial());
    let bytes = (1..=BEFORE + AFTER).map(|k| sensors.step(k)).collect();
    Flight { init, bytes }
}

fn links() -> Links {
    NavLinks { accel: MockLink::ideal(), gnss: MockLink::ideal(), out: MockSink::default() }
}

fn fresh_nav(init: &PadInit) -> NavUnit {
    let comp = AccelTable::IDEAL.compensator().expect("ideal accelerometer table");
    NavUnit::new(init.state, ssis::flight::Profile::LAUNCH_VEHICLE.dt_s(), comp, init.gnss).expect("pad state")
}

/// The body angle increment of every step (the flight core's, not under test here).
const DTHETA_RAD: Vector3<f64> = Vector3::new(2e-6, -1e-6, 5e-7);

/// One period: step `k` (with `upset`, if any) and the filter work; the output and the
/// frame bytes written.
fn fly(f: &Flight, u: &mut NavUnit, l: &mut Links, k: u64, upset: Option<TwinUpset>) -> (NavStepOutput, Vec<u8>) {
    let b = &f.bytes[(k - 1) as usize];
    l.accel.send(&b.accel);
    l.gnss.send(&b.gnss);
    let o = match upset {
        Some(up) => u.step_upset(&DTHETA_RAD, k * 1_250, l, up),
        None => u.step(&DTHETA_RAD, k * 1_250, l),
    };
    let _ = u.filter_work();
    (o, std::mem::take(&mut l.out.bytes))
}

/// The undisturbed unit after `BEFORE` steps, and every output after.
fn reference(f: &Flight) -> (NavUnit, Vec<(NavStepOutput, Vec<u8>)>) {
    let (mut u, mut l) = (fresh_nav(&f.init), links());
    for k in 1..=BEFORE {
        fly(f, &mut u, &mut l, k, None);
    }
    let base = u;
    let outs = (BEFORE + 1..=BEFORE + AFTER).map(|k| fly(f, &mut u, &mut l, k, None)).collect();
    (base, outs)
}

fn bytes_of(u: &mut NavUnit) -> &mut [u8] {
    // SAFETY: every bit pattern of NavUnit is a value (the `bytemuck::AnyBitPattern`
    // derive in src/nav/unit.rs).
    unsafe { std::slice::from_raw_parts_mut(u as *mut NavUnit as *mut u8, size_of::<NavUnit>()) }
}

/// The field at `path` (names from the unit down), with its offset in the unit.
fn field(path: &[&str]) -> (usize, usize) {
    let (mut fields, mut offset, mut size) = (NavUnit::state_map(), 0, 0);
    for name in path {
        let f: &StateField = fields.iter().find(|f| f.name == *name).unwrap_or_else(|| panic!("{path:?} mapped"));
        offset += f.offset;
        size = f.size;
        fields = f.parts;
    }
    (offset, size)
}

#[test]
fn a_bit_flipped_between_steps_is_restored() {
    let f = flight();
    let (base, outs) = reference(&f);
    let paths: &[&[&str]] = &[
        &["nav", "nav", "state"],
        &["nav", "nav", "prev_dtheta_rad"],
        &["nav", "nav", "prev_dv_m_s"],
        &["nav", "nav", "prev_gc_m_s2"],
        &["nav", "nav", "q_earth"],
        &["nav", "nav", "dt_s"],
        &["nav", "accel_bias_m_s2"],
        &["nav", "gyro_bias_rad_s"],
        &["nav", "sum_dv_e_m_s"],
        &["nav", "pending_steps"],
        &["nav", "p"],
        &["last_dv_m_s"],
        &["mean_dtheta_rad"],
        &["mean_dv_m_s"],
        &["spread_dv_m2_s2"],
        &["block_rad"],
    ];
    let mut flips = 0;
    for path in paths {
        let (offset, size) = field(path);
        // Every word of the field (every 7th of the covariance), bits across the mantissa,
        // the exponent and the sign.
        let stride = if size > 256 { 7 * 8 } else { 8 };
        for word in (0..size.div_ceil(8)).map(|w| w * 8).step_by(stride / 8) {
            for bit in [0, 19, 40, 52, 61, 63] {
                let byte = offset + word + bit / 8;
                if byte >= offset + size {
                    continue;
                }
                let (mut u, mut l) = (base, links());
                bytes_of(&mut u)[byte] ^= 1 << (bit % 8);
                let restored = u.counters().nav_state_restored;
                for (i, k) in (BEFORE + 1..=BEFORE + AFTER).enumerate() {
                    let got = fly(&f, &mut u, &mut l, k, None);
                    assert_eq!(got, outs[i], "{path:?} byte {} bit {bit}: step {k} differs", byte - offset);
                }
                assert_eq!(u.counters().nav_state_restored, restored + 1, "{path:?} bit {bit}: restored once");
                flips += 1;
            }
        }
    }
    println!("{flips} flips between two steps: all restored, every output the undisturbed unit's");
    assert!(flips > 300);
}

#[test]
fn a_bit_flipped_in_one_computation_is_outvoted() {
    let f = flight();
    let (base, outs) = reference(&f);
    let (mut cases, mut mismatches) = (0, 0);
    for word in 0..NavUnit::TWIN_WORDS {
        for bit in [0, 30, 51, 62] {
            for runs in [0b001, 0b010] {
                let (mut u, mut l) = (base, links());
                let before = u.counters();
                let k = BEFORE + 1;
                let got = fly(&f, &mut u, &mut l, k, Some(TwinUpset { runs, word, bit }));
                assert_eq!(got, outs[0], "word {word} bit {bit} runs {runs:#b}: the step differs");
                for (i, k) in (BEFORE + 2..=BEFORE + 20).enumerate() {
                    let got = fly(&f, &mut u, &mut l, k, None);
                    assert_eq!(got, outs[i + 1], "word {word} bit {bit} runs {runs:#b}: step {k} differs");
                }
                let c = u.counters();
                assert_eq!(c.nav_faults, before.nav_faults, "word {word} bit {bit}: no step refused");
                mismatches += c.nav_twin_mismatches - before.nav_twin_mismatches;
                cases += 1;
            }
        }
    }
    println!("{cases} flips in one computation: {mismatches} seen as a mismatch and outvoted, every output unchanged");
    // Only a flip the write-back cannot hold (the correction flags' unused bits) goes unseen.
    assert!(mismatches * 10 >= cases * 9, "{mismatches} of {cases} seen");
}

#[test]
fn no_two_computations_agreeing_refuses_the_step() {
    let f = flight();
    let (base, outs) = reference(&f);
    let before_state = *base.nav().state();
    // Velocity and position words of the state (the strapdown's words 4..10).
    for word in 4..10 {
        for runs in [0b011, 0b111] {
            let (mut u, mut l) = (base, links());
            let faults = u.counters().nav_faults;
            let (o, _) = fly(&f, &mut u, &mut l, BEFORE + 1, Some(TwinUpset { runs, word, bit: 45 }));
            assert_ne!(o.flags & flags::NAV_FAULT, 0, "word {word} runs {runs:#b}: the frame is not flagged");
            assert_eq!(o.state, before_state, "word {word} runs {runs:#b}: the state is not the one before the step");
            assert_eq!(u.counters().nav_faults, faults + 1);
            assert_ne!(o.state, outs[0].0.state, "the refused step held the state");
        }
    }
}
