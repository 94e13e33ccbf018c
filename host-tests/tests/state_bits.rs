//! No bit pattern of the flight core's state makes the core read outside a
//! buffer or take an invalid enum or bool as valid. The state's types are checked at
//! compile time (`bytemuck::AnyBitPattern`, src/flight/mod.rs); this test writes random
//! bytes over a converged core (all of it but the calibration table,
//! `FlightCore::TABLE_BYTES`) many times and steps each for 1,000 steps on the flight's
//! data: no panic, no crash, and every output either finite or not claiming a good
//! attitude.

use std::path::Path;

use rand::{RngCore, SeedableRng};
use rand_chacha::ChaCha8Rng;
use ssis::flight::{flags, FlightCore, FogLinks, Links};
use ssis_common::mock::{MockLink, MockSink};
use ssis_sim::harness::Simulation;
use ssis_sim::scenario::Scenario;

/// Random fills of the state.
const FILLS: usize = 1_000;
/// Steps after each fill.
const STEPS: usize = 1_000;
/// Steps flown before the fills (the qemu-flight scenario converges by 10 s).
const SETTLE_STEPS: usize = 4_000;

/// Writes random bytes over every byte of `core` outside `keep`.
fn fill_random(core: &mut FlightCore, keep: &std::ops::Range<usize>, rng: &mut ChaCha8Rng) {
    let n = std::mem::size_of::<FlightCore>();
    // SAFETY: every field of FlightCore outside the table's bytes is valid under any bit
    // pattern (asserted at compile time in src/flight/mod.rs), padding bytes may hold
    // anything, and the table's bytes are not written.
    let bytes = unsafe { std::slice::from_raw_parts_mut(core as *mut FlightCore as *mut u8, n) };
    for (i, b) in bytes.iter_mut().enumerate() {
        if !keep.contains(&i) {
            *b = rng.next_u32() as u8;
        }
    }
}

#[test]
fn random_state_steps_without_fault_and_claims_nothing_wrong() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios/qemu-flight.toml");
    let sc = Scenario::from_file(&path).expect("scenario");
    let mut sim = Simulation::new(&sc).expect("simulation");
    let mut core = FlightCore::new(sim.profile, &sim.table, false).expect("core");
    let (mut fog, mut star, mut out) = (MockLink::ideal(), MockLink::ideal(), MockSink::default());
    let mut inputs = Vec::new();
    for n in 0..SETTLE_STEPS + STEPS {
        let input = sim.next_step().expect("the scenario is long enough");
        let fog_bytes: Vec<u8> = input.fog_frames.iter().flatten().copied().collect();
        if n < SETTLE_STEPS {
            fog.send(&fog_bytes);
            star.send(&input.st_bytes);
            core.step(&mut Links { fog: FogLinks::Bus(&mut fog), star: &mut star, out: &mut out });
            out.bytes.clear();
        } else {
            inputs.push((fog_bytes, input.st_bytes.clone()));
        }
    }
    assert_ne!(core.last_output().flags & flags::CONVERGED, 0, "the core converged before the fills");
    let keep = FlightCore::TABLE_BYTES;
    assert!(keep.end <= std::mem::size_of::<FlightCore>());
    eprintln!("FlightCore: {} bytes, table {:?}", std::mem::size_of::<FlightCore>(), keep);
    // The undisturbed core's first output after the fill point.
    let undisturbed = {
        let mut c = core.clone();
        let (mut fog, mut star) = (MockLink::ideal(), MockLink::ideal());
        fog.send(&inputs[0].0);
        star.send(&inputs[0].1);
        c.step(&mut Links { fog: FogLinks::Bus(&mut fog), star: &mut star, out: &mut out })
    };
    out.bytes.clear();
    let mut rng = ChaCha8Rng::seed_from_u64(30);
    let (mut claimed_nonfinite, mut outputs, mut disturbed) = (0usize, 0usize, 0usize);
    for _ in 0..FILLS {
        let mut c = core.clone();
        fill_random(&mut c, &keep, &mut rng);
        let (mut fog, mut star) = (MockLink::ideal(), MockLink::ideal());
        for (k, (fog_bytes, st_bytes)) in inputs.iter().enumerate() {
            fog.send(fog_bytes);
            star.send(st_bytes);
            let o = c.step(&mut Links { fog: FogLinks::Bus(&mut fog), star: &mut star, out: &mut out });
            out.bytes.clear();
            while c.take_event().is_some() {}
            let claims_good = o.flags & flags::CONVERGED != 0 && o.flags & (flags::DEGRADED | flags::FDI_ALARM) == 0;
            let finite = o.q.coords.iter().all(|x| x.is_finite());
            if claims_good && !finite {
                claimed_nonfinite += 1;
            }
            if k == 0 && o != undisturbed {
                disturbed += 1;
            }
            outputs += 1;
        }
    }
    assert!(disturbed > FILLS / 2, "the fills changed the outputs ({disturbed} of {FILLS})");
    assert_eq!(outputs, FILLS * STEPS);
    assert_eq!(claimed_nonfinite, 0, "frames claiming a good attitude with a non-finite quaternion");
}
