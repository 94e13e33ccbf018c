//! The unit's outputs pinned bit for bit, so that a change meant to leave behaviour alone
//! (a restructuring, a new frame on the link) shows it did.
//!
//! Each case flies the flight core in-process and folds every step's output (time,
//! attitude, rate, drift, parity, health, flags, fault bits, star-tracker status and
//! both 1σ) into an FNV-1a digest, and the final counters the frame carries. The
//! expected digests were computed on the core as it was before the flight-core
//! restructuring (commit 2167fa2); a deliberate change of behaviour updates them in the
//! same commit, with the reason in its body.
//!
//! The star-tracker status's bit 7 (attitude valid, derived from the other status bits)
//! is folded apart: the pinned digests of every other field leave it out, and each flight
//! pins the digest of that bit alone, step by step, beside them.

use std::path::Path;

use ssis::calib::{CalibrationTable, Estimator};
use ssis::flight::{Profile, StepOutput};
use ssis::frames::output::OutputFrame;
use ssis::telemetry::st_status;

use ssis_faults::{Fault, FaultKind};
use ssis_sim::lv_replay::{pad_for, replay_lv};
use ssis_sim::recorded;
use ssis_sim::replay::replay;

/// FNV-1a over bytes, a byte at a time: the pinned digests.
#[derive(Debug, Clone, Copy)]
struct Fnv(u64);

impl Default for Fnv {
    fn default() -> Self {
        Fnv(0xcbf2_9ce4_8422_2325)
    }
}

impl Fnv {
    /// Adds bytes.
    fn write(&mut self, bytes: &[u8]) {
        for b in bytes {
            self.0 = (self.0 ^ u64::from(*b)).wrapping_mul(0x0100_0000_01b3);
        }
    }
}

/// Folds every output field into `h`, the attitude-valid bit left out ([`fold_valid`]).
fn fold(h: &mut Fnv, o: &StepOutput) {
    h.write(&o.time_us.to_le_bytes());
    for v in [o.q.w, o.q.i, o.q.j, o.q.k] {
        h.write(&v.to_bits().to_le_bytes());
    }
    for v in o.rate_rad_s.iter().chain(o.drift_rad_s.iter()) {
        h.write(&v.to_bits().to_le_bytes());
    }
    h.write(&o.parity_rad.to_bits().to_le_bytes());
    h.write(&o.fog_health);
    h.write(&[o.st_status & !st_status::VALID, o.flags, o.fogs_used.0, o.fdi]);
    for v in o.att_sigma_rad.iter().chain(o.drift_sigma_rad_s.iter()) {
        h.write(&v.to_bits().to_le_bytes());
    }
}

/// Folds the attitude-valid bit alone into `h`.
fn fold_valid(h: &mut Fnv, st_status_byte: u8) {
    h.write(&[st_status_byte & st_status::VALID]);
}

/// Flies the fault campaign's scenario (the main job's flight) for `duration_s` with
/// `estimator` and `fault`; returns the digest of every output and the step count, and
/// the digest of the attitude-valid bit with the step count.
fn fly(estimator: Estimator, fault: FaultKind, duration_s: f64) -> (Pinned, Pinned) {
    let sc = ssis_faults::scenario_with(7, duration_s, estimator).expect("scenario");
    let fault = Fault { kind: fault, start_s: 45.0, duration_s: f64::INFINITY };
    let (mut h, mut v) = (Fnv::default(), Fnv::default());
    let mut n = 0u64;
    ssis_faults::run_observed(&sc, &fault, |s| {
        fold(&mut h, s.out);
        fold_valid(&mut v, s.out.st_status);
        n += 1;
    })
    .expect("runs");
    ((h.0, n), (v.0, n))
}

/// A run's output digest and the number of outputs folded into it.
type Pinned = (u64, u64);

/// Compares every case of a flight with its pinned (digest, outputs): every field but the
/// attitude-valid bit (`want`), and that bit alone (`want_valid`).
fn check_flights(cases: &[(&str, (Pinned, Pinned), Pinned, Pinned)]) {
    let mut all = Vec::new();
    let names: Vec<String> = cases.iter().map(|c| format!("{} (attitude valid)", c.0)).collect();
    for ((name, (got, got_valid), want, want_valid), valid_name) in cases.iter().zip(&names) {
        all.push((*name, *got, *want));
        all.push((valid_name.as_str(), *got_valid, *want_valid));
    }
    check_all(&all);
}

/// Compares every case of a test with its pinned (digest, outputs), printing all of them
/// before failing on the first that differs.
fn check_all(cases: &[(&str, Pinned, Pinned)]) {
    for (name, got, want) in cases {
        let verdict = if got == want { "same" } else { "DIFFERENT" };
        println!("{name}: digest {:#018x} over {} outputs: {verdict}", got.0, got.1);
    }
    for (name, got, want) in cases {
        assert_eq!(got, want, "{name}: outputs differ from the pinned flight (digest, outputs)");
    }
}

#[test]
fn nominal_flight_on_both_estimators_is_unchanged() {
    check_flights(&[
        (
            "observer nominal",
            fly(Estimator::Luenberger, FaultKind::None, 60.0),
            (0xc1312c465048d8e0, 12000),
            (0xbcdf560aed50b025, 12000),
        ),
        (
            "mekf nominal",
            fly(Estimator::Mekf, FaultKind::None, 60.0),
            (0xde5faa5abda2bfd0, 12000),
            (0xbcdf560aed50b025, 12000),
        ),
    ]);
}

#[test]
fn fog_faults_and_their_isolation_are_unchanged() {
    // 0.5 °/h: well beyond the parity alarm's threshold.
    let step_rad_s = 0.5_f64.to_radians() / 3600.0;
    check_flights(&[
        (
            "observer bias step FOG2",
            fly(Estimator::Luenberger, FaultKind::FogBiasStep(1, step_rad_s), 60.0),
            (0xfbd0201077107fdc, 12000),
            (0xbcdf560aed50b025, 12000),
        ),
        (
            "mekf bias step FOG2",
            fly(Estimator::Mekf, FaultKind::FogBiasStep(1, step_rad_s), 60.0),
            (0x29bc2de89f974d2c, 12000),
            (0xbcdf560aed50b025, 12000),
        ),
        (
            "observer temperature sensor FOG3",
            fly(Estimator::Luenberger, FaultKind::FogTempSensor(2), 60.0),
            (0x878ecc7a56f7cbe0, 12000),
            (0xbcdf560aed50b025, 12000),
        ),
        (
            "observer FOG4 flipped",
            fly(Estimator::Luenberger, FaultKind::FogFlipped(3), 30.0),
            (0x51b9c09be70957e4, 6000),
            (0x0ca7ddffb55c0e65, 6000),
        ),
        (
            "mekf FOG1/FOG2 swapped",
            fly(Estimator::Mekf, FaultKind::FogSwapped(0, 1), 30.0),
            (0x37be75803a3d9253, 6000),
            (0x0ca7ddffb55c0e65, 6000),
        ),
        (
            "observer FOG1 dropout",
            fly(Estimator::Luenberger, FaultKind::FogDropout(0), 60.0),
            (0x40efbb458b2a03c5, 12000),
            (0xcc99f4f180789325, 12000),
        ),
    ]);
}

#[test]
fn star_tracker_faults_are_unchanged() {
    check_flights(&[
        (
            "observer outage",
            fly(Estimator::Luenberger, FaultKind::StOutage, 60.0),
            (0x303a92843b3e1d1e, 12000),
            (0xbcdf560aed50b025, 12000),
        ),
        (
            "mekf outliers",
            fly(Estimator::Mekf, FaultKind::StOutliers(10.0, 3), 60.0),
            (0x3f668db4fd2435ec, 12000),
            (0x9dc5d88c59cce325, 12000),
        ),
        (
            "observer frozen",
            fly(Estimator::Luenberger, FaultKind::StFrozen, 60.0),
            (0xef14751f13182d82, 12000),
            (0xbcdf560aed50b025, 12000),
        ),
        (
            "observer bit errors",
            fly(Estimator::Luenberger, FaultKind::BitErrors(2e-5), 60.0),
            (0xa2bad4242fab0710, 12000),
            (0x5ddfb0f5b63df5a5, 12000),
        ),
    ]);
}

/// The frame's bytes but the counter page (its id and value cycle through every counter,
/// whose numbering a restructuring may change) and the CRC over them.
fn frame_fields(f: &OutputFrame) -> Vec<u8> {
    let b = f.to_bytes();
    let mut v = b[..78].to_vec();
    // The st_status byte without the attitude-valid bit (pinned apart).
    v[62] &= !st_status::VALID;
    v.extend_from_slice(&b[81..93]);
    v
}

#[test]
fn peer_simulator_log_replays_unchanged() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../examples/basilisk");
    let table = ssis_common::table::read_toml(&dir.join("table.toml")).expect("the example's table");
    let rec = recorded::read(&[dir.join("leo-nadir-280s.csv")], Profile::SPACECRAFT.dt_us).expect("reads");
    let (mut h, mut v) = (Fnv::default(), Fnv::default());
    let mut n = 0u64;
    replay(&rec, &table, 60.0, |f, _| {
        h.write(&frame_fields(f));
        fold_valid(&mut v, f.st_status);
        n += 1;
    })
    .expect("replays");
    check_all(&[
        ("basilisk replay (frame fields)", (h.0, n), (0x480767c3ebbdeb7e, 56000)),
        ("basilisk replay (attitude valid)", (v.0, n), (0xbc11a17bad7c77a5, 56000)),
    ]);
}

#[test]
fn built_in_replay_digest_is_unchanged() {
    let d = ssis::bit::replay_digest(2_000);
    let mut h = Fnv::default();
    h.write(&d.output_crc.to_le_bytes());
    for q in d.q_bits {
        h.write(&q.to_le_bytes());
    }
    check_all(&[("bit::replay_digest(2000)", (h.0, u64::from(d.steps)), (0xcabc3f744eeb9427, 2000))]);
}

#[test]
fn launch_vehicle_log_replays_unchanged() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../examples/lv-ascent/ascent-20s.csv");
    let rec = recorded::read_log(&[path]).expect("reads");
    let init = pad_for(&rec, None).expect("the log's initial state");
    let mut h = Fnv::default();
    let mut n = 0u64;
    replay_lv(&rec, &CalibrationTable::DEFAULT, &init, |f, _| {
        h.write(&f.to_bytes());
        n += 1;
    })
    .expect("replays");
    check_all(&[("launch-vehicle replay (navigation frames)", (h.0, n), (0x9f827d9a253d2024, 16000))]);
}
