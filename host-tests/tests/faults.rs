//! Fault tolerance: the designed behaviour under each injected fault, through
//! `ssis_faults` on the in-process flight core. Short scenarios and few seeds; the
//! full Monte Carlo figures are the campaign's (`ssis-faults`, docs/FAULT-CAMPAIGN.md).
//!
//! Every run is the campaign's scenario (the paper's sensors, Earth pointing with a 10°
//! roll slew at 50–80 s, star tracker 20″ 3σ at 4 Hz) with the fault from 60 s, and is
//! compared where it matters with the same seed flown without a fault.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use ssis::calib::{Estimator, N_FOG};
use ssis::flight::{flags, health, st_status, MAX_WAIT_STEPS, ST_OUTAGE_US};
use ssis::integrity::channel::STUCK_SAMPLES;
use ssis::integrity::parity::K_SPIKE;
use ssis::observer::{steady_state, CHI2_GATE};
use ssis_common::ARCSEC_PER_RAD;
use ssis_faults::{self as faults, Fault, FaultKind, FaultRun, FaultScale, FaultStep, FAULT_START_S};
use ssis_sim::harness::Simulation;

/// Step, s (the spacecraft unit's 5 ms).
const DT_S: f64 = 0.005;
/// Seconds of flight after each fault.
const AFTER_S: f64 = 30.0;

/// The campaign's seed for run `seed` on FOG `fog` (as `ssis-faults` numbers them).
fn seed(seed: u64, fog: usize) -> u64 {
    seed * 7919 + fog as u64
}

fn fault(kind: FaultKind, duration_s: f64) -> Fault {
    Fault { kind, start_s: FAULT_START_S, duration_s }
}

/// Runs `f` on `seed` (the scenario long enough for the fault and [`AFTER_S`] after it).
fn run(seed: u64, f: &Fault) -> FaultRun {
    run_observed(seed, f, |_| {})
}

fn run_observed(seed: u64, f: &Fault, on_step: impl FnMut(&FaultStep)) -> FaultRun {
    run_with(seed, f, Estimator::Luenberger, on_step)
}

/// [`run_observed`] with `estimator` flying.
fn run_with(seed: u64, f: &Fault, estimator: Estimator, on_step: impl FnMut(&FaultStep)) -> FaultRun {
    let sc = faults::scenario_with(seed, f.start_s + f.duration_s + AFTER_S, estimator).expect("scenario");
    faults::run_observed(&sc, f, on_step).expect("run")
}

/// The same seed and window without a fault.
fn nominal(seed: u64, f: &Fault) -> FaultRun {
    run(seed, &Fault { kind: FaultKind::None, ..*f })
}

fn scale() -> FaultScale {
    FaultScale::of(&faults::scenario(1, 1.0).expect("scenario")).expect("scale")
}

/// The largest angular acceleration of the campaign scenario's slews, rad/s² (rate
/// A/D·(1 − cos 2πτ/D): acceleration up to 2πA/D²).
fn slew_accel_max_rad_s2() -> f64 {
    let sc = faults::scenario(1, 1.0).expect("scenario");
    sc.motion
        .slews
        .iter()
        .map(|s| s.angle_deg.to_radians() * std::f64::consts::TAU / (s.duration_s * s.duration_s))
        .fold(0.0, f64::max)
}

/// What a stuck FOG costs before it is flagged, arcsec: until then the frozen increment
/// is combined; during the slew the true increment moves away from it by a·Δt² a sample
/// (a: the slew's largest angular acceleration), and the frozen sample's own noise σ₁
/// repeats. Over the STUCK_SAMPLES − 1 samples before the flag: a·Δt²·N(N+1)/2 + 3·N·σ₁.
fn stuck_allowance_arcsec() -> f64 {
    let n = f64::from(STUCK_SAMPLES - 1);
    (slew_accel_max_rad_s2() * DT_S * DT_S * n * (n + 1.0) / 2.0 + 3.0 * n * scale().sigma1_rad) * ARCSEC_PER_RAD
}

fn max_abs(e: &[f64; 3]) -> f64 {
    e.iter().fold(0.0f64, |m, x| m.max(x.abs()))
}

/// The largest attitude error (any axis) of the same seed flown without the fault,
/// arcsec: the nominal band.
fn band(nom: &FaultRun) -> f64 {
    nom.att_before_arcsec.max(nom.att_during_arcsec).max(nom.att_after_arcsec)
}

/// The fault did not corrupt the attitude: its largest error during and after the
/// fault stays within the nominal band (1.5 × the same seed's largest error without the
/// fault: another noise realisation, three gyros instead of four) plus `allowance`, what
/// the design lets through before it acts, arcsec. A corrupted sample alone would be
/// hundreds to millions of arcseconds (i32::MIN counts are 0.03 rad).
fn assert_attitude_unharmed(what: &str, r: &FaultRun, nom: &FaultRun, allowance_arcsec: f64) {
    println!(
        "{what}: attitude error max during / after {:.2} / {:.2}″ (nominal {:.2} / {:.2}″, allowance {:.2}″)",
        r.att_during_arcsec, r.att_after_arcsec, nom.att_during_arcsec, nom.att_after_arcsec, allowance_arcsec
    );
    let limit = 1.5 * band(nom) + allowance_arcsec;
    assert!(
        r.att_during_arcsec <= limit && r.att_after_arcsec <= limit,
        "{what}: attitude error {:.2} / {:.2}″ beyond {limit:.2}″",
        r.att_during_arcsec,
        r.att_after_arcsec
    );
}

/// Only the faulty FOG `i`, if any, was isolated.
fn assert_no_healthy_fog_isolated(what: &str, r: &FaultRun, i: usize) {
    if let Some((j, _)) = r.isolated {
        assert_eq!(j, i, "{what}: FOG{} isolated for a fault on FOG{}", j + 1, i + 1);
    }
}

#[test]
fn bias_step_of_5_sigma_is_detected_within_20_steps_and_the_right_fog_isolated_within_10_s() {
    let k = scale();
    let seeds = 5u64;
    let (mut runs, mut right10) = (0u32, 0u32);
    for i in 0..N_FOG {
        for s in 1..=seeds {
            let f = fault(FaultKind::FogBiasStep(i, k.bias_for_sigma_rad_s(i, 5.0)), 30.0);
            let sd = seed(s, i);
            // The error at the last step before the isolation.
            let mut at_isolation = 0.0f64;
            let r = run_observed(sd, &f, |st| {
                if st.out.fdi & 0xF0 == 0 {
                    at_isolation = max_abs(&st.att_err_arcsec);
                }
            });
            let nom = nominal(sd, &f);
            println!(
                "FOG{} seed {sd}: detected after {:?} steps, isolated {:?}, error during {:.1}″, at isolation {:.1}″, \
                 after isolation {:?}″ (nominal max {:.2}″)",
                i + 1,
                r.detected_after_steps,
                r.isolated,
                r.att_during_arcsec,
                at_isolation,
                r.att_after_isolation_arcsec,
                band(&nom)
            );
            runs += 1;
            // Goal: detected within 20 steps, every run.
            let steps = r.detected_after_steps.expect("bias step not detected");
            assert!(steps <= 20, "FOG{} seed {sd}: detected after {steps} steps", i + 1);
            // Never the wrong gyro.
            assert_no_healthy_fog_isolated(&format!("seed {sd}"), &r, i);
            if r.isolated.is_some_and(|(_, t)| t <= 10.0) {
                right10 += 1;
            }
            if let Some(after) = r.att_after_isolation_arcsec {
                // At the isolation the fault's drift since the alarm is removed, scaled by
                // the fitted gain c. The fit decides once the explained mismatch energy is
                // ISOLATION_MIN_ENERGY = 100 mismatch variances, i.e. c known to 1/√100 =
                // 10 % (1σ): what is left is up to 3σ = 30 % of the error at isolation.
                let limit = 0.3 * at_isolation + 1.5 * band(&nom);
                assert!(after <= limit, "FOG{} seed {sd}: {after:.1}″ after isolation, limit {limit:.1}″", i + 1);
            }
        }
    }
    // Goal: the right gyro isolated within 10 s in ≥ 95 % of the runs.
    println!("right FOG isolated within 10 s: {right10} of {runs}");
    assert!(f64::from(right10) >= 0.95 * f64::from(runs), "{right10} of {runs} isolated within 10 s");
}

/// The goal is for every bias step of 5σ or more. Above the spike threshold (K_SPIKE =
/// 6.5 σ₁ in one sample) the step is handled as repeated spikes: the faulty FOG's
/// samples are dropped and, after SPIKE_LATCH in a row, it is isolated. Until the fix of
/// 2026-11-23 the latch isolated the wrong FOG (FOG4, for faults on FOG1–3) in 6 of these
/// 40 runs: an unattributed sample became the reference of the next one, the step then
/// no longer showed in the increments' change, and the quietest triad won on noise.
/// The spike test now needs the residual to jump as well as to be high, and scores each
/// triad against its own noise gain.
#[test]
fn bias_step_of_20_sigma_isolates_the_right_fog() {
    let k = scale();
    let (mut runs, mut right10) = (0u32, 0u32);
    let mut wrong = Vec::new();
    for i in 0..N_FOG {
        for s in 1..=10 {
            let sd = seed(s, i);
            let f = fault(FaultKind::FogBiasStep(i, k.bias_for_sigma_rad_s(i, 20.0)), 30.0);
            let r = run(sd, &f);
            runs += 1;
            let steps = r.detected_after_steps.expect("bias step not detected");
            assert!(steps <= 20, "FOG{} seed {sd}: detected after {steps} steps", i + 1);
            match r.isolated {
                Some((j, t)) if j == i => right10 += u32::from(t <= 10.0),
                Some((j, _)) => wrong.push((i + 1, sd, j + 1, r.att_during_arcsec.max(r.att_after_arcsec))),
                None => {}
            }
        }
    }
    println!("right FOG within 10 s: {right10} of {runs}; wrong (FOG, seed, isolated, error ″): {wrong:?}");
    assert!(wrong.is_empty(), "wrong FOG isolated (faulty FOG, seed, isolated FOG, attitude error ″): {wrong:?}");
    assert!(f64::from(right10) >= 0.95 * f64::from(runs), "{right10} of {runs} isolated within 10 s");
}

/// A NaN as the ICD encodes it (0 counts) is a step of minus the true increment: on
/// FOG2, which carries the orbital rate, it is a 54 σ₁ step. It must be excluded (as a
/// spike latch, or stuck) with no healthy FOG isolated; before the fix above the latch
/// isolated FOG4, FOG2 was then flagged stuck, two gyros remained and the attitude ran
/// away (26,000″ in a minute).
#[test]
fn nan_sent_as_zero_is_excluded_without_harm() {
    for i in 0..N_FOG {
        let sd = seed(1, i);
        let f = fault(FaultKind::FogNanAsZero(i), 30.0);
        let r = run(sd, &f);
        let nom = nominal(sd, &f);
        println!("FOG{} sends 0: isolated {:?}, stuck {:?}", i + 1, r.isolated, r.counters.fog.map(|c| c.stuck));
        assert_no_healthy_fog_isolated("zero output", &r, i);
        assert!(r.detected_after_steps.is_some_and(|n| n <= u64::from(STUCK_SAMPLES)), "FOG{}", i + 1);
        assert_attitude_unharmed(&format!("FOG{} sends 0", i + 1), &r, &nom, stuck_allowance_arcsec());
    }
}

#[test]
fn stuck_fog_is_flagged_stuck_and_excluded() {
    for i in 0..N_FOG {
        let sd = seed(1, i);
        let f = fault(FaultKind::FogStuck(i), 30.0);
        let mut flagged = false;
        let mut used_while_flagged = 0u32;
        let mut unflagged_after = 0u32;
        let r = run_observed(sd, &f, |s| {
            if !s.active {
                return;
            }
            let h = s.out.fog_health[i];
            flagged |= h & health::STUCK != 0;
            if flagged {
                // From the flag on: refused every step, never combined.
                if h & health::STUCK == 0 {
                    unflagged_after += 1;
                }
                if s.out.fogs_used.contains(i) || h & health::USED != 0 {
                    used_while_flagged += 1;
                }
            }
        });
        let nom = nominal(sd, &f);
        let c = r.counters.fog[i];
        println!(
            "FOG{} stuck: flagged after {:?} steps, {} samples refused as stuck, isolated {:?}",
            i + 1,
            r.detected_after_steps,
            c.stuck,
            r.isolated
        );
        // Flagged after STUCK_SAMPLES identical increments (the first stuck sample repeats
        // the last good one, so the 39th stuck sample is the 40th in the row).
        assert_eq!(r.detected_after_steps, Some(u64::from(STUCK_SAMPLES) - 1), "FOG{}", i + 1);
        assert_eq!(unflagged_after, 0, "FOG{}: stuck flag dropped while stuck", i + 1);
        assert_eq!(used_while_flagged, 0, "FOG{}: combined while flagged stuck", i + 1);
        let fault_steps = (30.0 / DT_S) as u32;
        assert_eq!(c.stuck, fault_steps - (u32::from(STUCK_SAMPLES) - 2), "FOG{}: stuck samples", i + 1);
        for (j, o) in r.counters.fog.iter().enumerate() {
            if j != i {
                assert_eq!(o.stuck, 0, "FOG{} counted stuck for a fault on FOG{}", j + 1, i + 1);
            }
        }
        assert_no_healthy_fog_isolated("stuck", &r, i);
        assert_attitude_unharmed(&format!("FOG{} stuck", i + 1), &r, &nom, stuck_allowance_arcsec());
    }
}

#[test]
fn nan_and_dropout_are_counted_and_do_not_corrupt_the_attitude() {
    for i in 0..N_FOG {
        let sd = seed(1, i);
        // NaN: the FOG's increment saturates (i32::MIN counts) for 30 s.
        let f = fault(FaultKind::FogNan(i), 30.0);
        let mut used = 0u32;
        let r = run_observed(sd, &f, |s| {
            if s.active && s.out.fogs_used.contains(i) {
                used += 1;
            }
        });
        let nom = nominal(sd, &f);
        // Every sample refused and counted: out of range, and once the same saturated
        // value has come STUCK_SAMPLES times in a row, stuck (the stuck check runs first).
        let fault_steps = (30.0 / DT_S) as u32;
        for (j, c) in r.counters.fog.iter().enumerate() {
            let want = if j == i { (u32::from(STUCK_SAMPLES) - 1, fault_steps) } else { (0, 0) };
            assert_eq!(
                (c.out_of_range, c.out_of_range + c.stuck),
                want,
                "NaN on FOG{}: FOG{} (out of range, out of range + stuck)",
                i + 1,
                j + 1
            );
        }
        assert_eq!(used, 0, "NaN on FOG{}: combined {used} times", i + 1);
        assert_eq!(r.detected_after_steps, Some(1), "NaN on FOG{}", i + 1);
        assert_eq!(r.isolations, 0, "NaN on FOG{}: a healthy FOG isolated", i + 1);
        assert_attitude_unharmed(&format!("FOG{} NaN", i + 1), &r, &nom, 0.0);

        // Dropout: the FOG's frames stop for 10 s.
        let f = fault(FaultKind::FogDropout(i), 10.0);
        let r = run(sd, &f);
        let nom = nominal(sd, &f);
        for (j, c) in r.counters.fog.iter().enumerate() {
            let want = if j == i { (10.0 / DT_S) as u32 } else { 0 };
            assert_eq!(c.missing, want, "dropout of FOG{}: FOG{} missing count", i + 1, j + 1);
        }
        // Flagged missing once the unit has waited MAX_WAIT_STEPS for the owed sample.
        let latency = r.detected_after_steps.expect("dropout not flagged");
        assert!(latency <= u64::from(MAX_WAIT_STEPS) + 1, "dropout of FOG{}: flagged after {latency} steps", i + 1);
        assert_eq!(r.isolations, 0, "dropout of FOG{}: a healthy FOG isolated", i + 1);
        assert_attitude_unharmed(&format!("FOG{} dropout", i + 1), &r, &nom, 0.0);
    }
}

#[test]
fn spikes_are_dropped() {
    let k = scale();
    let (mut sent, mut dropped) = (0u32, 0u32);
    for i in 0..N_FOG {
        let sd = seed(1, i);
        // Spikes that move the parity residual by 3.5 σ₁ more than the spike threshold
        // K_SPIKE = 6.5 σ₁, four a second for 30 s. (The campaign's 20 σ₁ spikes on FOG1–3,
        // |v_i| = 0.41, are only 8.2 σ₁ in the parity.)
        let size = (K_SPIKE + 3.5) * k.sigma1_rad / k.v[i].abs();
        let f = fault(FaultKind::FogSpikes(i, size, 50), 30.0);
        let r = run(sd, &f);
        let nom = nominal(sd, &f);
        let c = r.counters.fog;
        println!("FOG{} spikes: {} sent, dropped per FOG {:?}", i + 1, r.spikes_sent, c.map(|c| c.spikes));
        assert_eq!(r.spikes_sent, 120);
        sent += r.spikes_sent;
        dropped += c[i].spikes;
        for (j, c) in c.iter().enumerate() {
            if j != i {
                assert_eq!(c.spikes, 0, "spikes on FOG{}: FOG{} dropped {}", i + 1, j + 1, c.spikes);
            }
        }
        assert_eq!((r.alarms, r.isolations), (0, 0), "spikes on FOG{}: parity alarm or isolation", i + 1);
        assert_attitude_unharmed(&format!("FOG{} spikes", i + 1), &r, &nom, 0.0);
    }
    // The design's misses for a spike 3.5 σ₁ over K_SPIKE: its level must exceed K_SPIKE σ₁
    // (noise σ₁: 0.02 % missed) and jump by K_JUMP = 4 σ₁ from the previous sample's (noise
    // √2 σ₁: below 1e-4); the owner's triad, scored against its own noise gain, must stay
    // below OWNER_MAX = 20 σ₁² (noise alone exceeds it in ~0.2 %, more where one axis
    // dominates the triad's gain) with the others clear of it. Measured 98.5 %
    // (473 of 480); a missed spike is used, harmless at this size. Asserted: ≥ 97 %
    // (about 3σ of the binomial under the measured rate).
    let achieved = f64::from(dropped) / f64::from(sent);
    println!("spikes dropped: {dropped} of {sent} ({:.1} %)", 100.0 * achieved);
    assert!(achieved >= 0.97, "{dropped} of {sent} spikes dropped");
}

#[test]
fn temperature_sensor_failure_is_flagged_and_the_gyro_kept() {
    for i in 0..N_FOG {
        let sd = seed(1, i);
        let f = fault(FaultKind::FogTempSensor(i), 30.0);
        let mut dropped = 0u32;
        let r = run_observed(sd, &f, |s| {
            if s.active && !s.out.fogs_used.contains(i) {
                dropped += 1;
            }
        });
        let nom = nominal(sd, &f);
        assert_eq!(r.detected_after_steps, Some(1), "FOG{}", i + 1);
        for (j, c) in r.counters.fog.iter().enumerate() {
            assert_eq!(c.temp_failures, u32::from(j == i), "open sensor on FOG{}: FOG{}", i + 1, j + 1);
        }
        // The gyro flies on with its last temperature estimate.
        assert_eq!(dropped, 0, "FOG{} dropped {dropped} times for its temperature sensor", i + 1);
        assert_attitude_unharmed(&format!("FOG{} temperature sensor", i + 1), &r, &nom, 0.0);
    }
}

#[test]
fn frozen_star_tracker_is_refused() {
    let sd = seed(1, 0);
    let f = fault(FaultKind::StFrozen, 60.0);
    let (mut frames, mut updated, mut outage_from, mut updated_after) = (0u32, 0u32, None, 0u32);
    let r = run_observed(sd, &f, |s| {
        let st = s.out.st_status;
        if s.active {
            frames += u32::from(st & st_status::FRAME != 0);
            updated += u32::from(st & (st_status::UPDATED | st_status::LISTENED) != 0);
            if outage_from.is_none() && st & st_status::OUTAGE != 0 {
                outage_from = Some(s.t_s - f.start_s);
            }
        } else if s.t_s > f.start_s {
            updated_after += u32::from(st & st_status::UPDATED != 0);
        }
    });
    let nom = nominal(sd, &f);
    println!(
        "frozen star tracker: {frames} frames, {} refused as frozen, outage flagged after {outage_from:?} s, \
         {updated_after} updates after; error during / after {:.2} / {:.2}″ (nominal {:.2} / {:.2}″)",
        r.st_frozen, r.att_during_arcsec, r.att_after_arcsec, nom.att_during_arcsec, nom.att_after_arcsec
    );
    assert!(frames >= 239, "{frames} star-tracker frames in 60 s at 4 Hz");
    // Every frozen frame refused and counted as frozen, none used.
    assert_eq!(r.st_frozen, frames);
    assert_eq!(updated, 0);
    // The unit coasts on its gyros and says so: outage after ST_OUTAGE_US (2 s) plus a
    // frame period at most.
    let t = outage_from.expect("no outage flagged");
    assert!(t <= ST_OUTAGE_US as f64 * 1e-6 + 0.25 + DT_S, "outage flagged after {t} s");
    // It takes the live tracker again: AFTER_S at 4 Hz, nearly every frame.
    assert!(f64::from(updated_after) >= 0.9 * 4.0 * AFTER_S, "{updated_after} updates after the tracker thawed");
}

#[test]
fn star_tracker_outage_of_10_min_is_flagged_and_the_return_makes_no_jump() {
    // The campaign's: 10 min from 1800 s, the observer's drift estimate in steady state.
    let sd = seed(1, 0);
    let f = Fault { kind: FaultKind::StOutage, start_s: 1800.0, duration_s: 600.0 };
    let end = f.start_s + f.duration_s;
    let window = 60.0;
    // Largest step-to-step change of the attitude error in the minute after the return.
    let observe = |jump: &mut f64, last: &mut Option<[f64; 3]>, s: &FaultStep| {
        if s.t_s > end - 1.0 && s.t_s <= end + window {
            if let Some(l) = *last {
                let d = (0..3).map(|k| (s.att_err_arcsec[k] - l[k]).abs()).fold(0.0, f64::max);
                if s.t_s > end {
                    *jump = jump.max(d);
                }
            }
            *last = Some(s.att_err_arcsec);
        }
    };
    let (mut flagged, mut steps, mut first_update) = (0u32, 0u32, None);
    let (mut jump, mut last) = (0.0f64, None);
    let r = run_observed(sd, &f, |s| {
        // Outage flag and degraded from ST_OUTAGE_US after the last frame to the return.
        if s.active && s.t_s > f.start_s + ST_OUTAGE_US as f64 * 1e-6 + 0.3 {
            steps += 1;
            let out = s.out.st_status & st_status::OUTAGE != 0 && s.out.flags & flags::DEGRADED != 0;
            flagged += u32::from(out);
        }
        if first_update.is_none() && s.t_s > end && s.out.st_status & st_status::UPDATED != 0 {
            first_update = Some(s.t_s - end);
        }
        observe(&mut jump, &mut last, s);
    });
    let (mut jump_nom, mut last_nom) = (0.0f64, None);
    let nom = run_observed(sd, &Fault { kind: FaultKind::None, ..f }, |s| observe(&mut jump_nom, &mut last_nom, s));
    let max_err = r.att_during_arcsec.max(r.att_after_arcsec);
    println!(
        "10 min outage: flagged {flagged} of {steps} steps, {} outage(s) counted, first update {first_update:?} s after \
         the return; error max before / during / after {:.2} / {:.2} / {:.2}″ (nominal {:.2} / {:.2} / {:.2}″); \
         largest step-to-step change in the minute after the return {jump:.3}″ (nominal {jump_nom:.3}″)",
        r.counters.st_outages,
        r.att_before_arcsec,
        r.att_during_arcsec,
        r.att_after_arcsec,
        nom.att_before_arcsec,
        nom.att_during_arcsec,
        nom.att_after_arcsec
    );
    assert_eq!(flagged, steps, "outage not flagged degraded on every step");
    assert_eq!(r.counters.st_outages, 1);
    let t = first_update.expect("star tracker never taken again");
    assert!(t <= 1.0, "first update {t} s after the return");
    // The goal is ≤ 15″. What a gyro-only coast of 10 min allows with these
    // sensors is 8.7″ 1σ per axis (the estimation limit of a gyro-only coast), so the largest axis of
    // a run exceeds 15″ in a good share of runs: the goal is not met in the campaign
    // (docs/FAULT-CAMPAIGN.md). Asserted here: within 3σ of that limit.
    assert!(max_err <= 3.0 * 8.7, "error {max_err:.1}″ beyond 3σ of the 10-min coasting limit");
    // No jump on return: the observer takes the error out at its gain K_B a frame, so the
    // output moves step to step by no more than in nominal flight plus K_B × the error (a
    // reset onto the tracker would move it by the whole error in one step).
    let sim = Simulation::new(&faults::scenario(1, 1.0).expect("scenario")).expect("sim");
    let k_b = steady_state(&sim.table.observer).expect("steady state").gains.k_b[0];
    let allowed = jump_nom + k_b * max_err;
    println!("return: step-to-step change {jump:.3}″, allowed {allowed:.3}″ (K_B = {k_b:.4})");
    assert!(jump <= allowed, "jump {jump:.3}″ at the return, nominal {jump_nom:.3}″, allowed {allowed:.3}″");
}

/// Probability that a `k`σ outlier (σ: the tracker's per-axis noise; a rotation about
/// any axis) passes the χ² gate when the mismatch variance per axis is `var_rad2` (R +
/// the prior): Monte Carlo of the mismatch, the outlier plus Gaussian noise of `var_rad2`
/// per axis.
fn gate_pass_probability(k: f64, r_rad2: f64, var_rad2: f64) -> f64 {
    let mut rng = ChaCha8Rng::seed_from_u64(6);
    let n = 1_000_000;
    let sigma = var_rad2.sqrt();
    let a = k * r_rad2.sqrt();
    let normal = |rng: &mut ChaCha8Rng| {
        // Box–Muller.
        let (u1, u2): (f64, f64) = (rng.random::<f64>().max(1e-300), rng.random());
        (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
    };
    let mut pass = 0u32;
    for _ in 0..n {
        let e = [a + sigma * normal(&mut rng), sigma * normal(&mut rng), sigma * normal(&mut rng)];
        if e.iter().map(|x| x * x).sum::<f64>() <= CHI2_GATE * var_rad2 {
            pass += 1;
        }
    }
    f64::from(pass) / f64::from(n)
}

#[test]
fn star_tracker_outliers_of_6_sigma_are_mostly_gated() {
    let (mut sent, mut taken, mut nom_frames, mut nom_refused) = (0u64, 0u64, 0u64, 0u64);
    for s in 1..=6 {
        let r = run(seed(s, 0), &fault(FaultKind::StOutliers(6.0, 4), 300.0));
        sent += u64::from(r.outliers_sent);
        taken += u64::from(r.outliers_accepted);
        nom_frames += u64::from(r.nominal_frames);
        nom_refused += u64::from(r.nominal_refused);
    }
    // What the design gives: the gate refuses |e|² > CHI2_GATE·var; a 6σ rotation plus
    // the mismatch noise (R + the prior attitude variance at 4 Hz, steady state) lands
    // inside it with probability p.
    let sim = Simulation::new(&faults::scenario(1, 1.0).expect("scenario")).expect("sim");
    let ss = steady_state(&sim.table.observer).expect("steady state");
    let p = gate_pass_probability(6.0, ss.r_rad2, ss.r_rad2 + ss.prior_var_rad2);
    let design = 1.0 - p;
    let rejected = 1.0 - taken as f64 / sent as f64;
    let sd = (p * (1.0 - p) / sent as f64).sqrt();
    let false_rate = nom_refused as f64 / nom_frames as f64;
    println!(
        "6σ outliers: {} of {sent} rejected ({:.2} %), design {:.2} % (±{:.2} % for this count); \
         nominal frames refused {nom_refused} of {nom_frames} ({:.3} %)",
        sent - taken,
        100.0 * rejected,
        100.0 * design,
        100.0 * sd,
        100.0 * false_rate
    );
    assert!(sent >= 1500, "{sent} outliers sent");
    // The gate's radius is √16.27 = 4.0 σ of the mismatch: a 6σ rotation plus 3-axis
    // noise of 1σ falls inside it about 1.8 % of the time (design ≈ 98.2 % rejected).
    // Asserted: the design's rate ± 0.5 points.
    assert!(design >= 0.98, "design rejection {:.2} %", 100.0 * design);
    assert!((rejected - design).abs() <= 0.005, "rejected {:.2} %, design {:.2} %", 100.0 * rejected, 100.0 * design);
    // False rejections on the undamaged frames: the gate's 0.1 %, within 3σ of the count.
    let allowed = 0.001 * nom_frames as f64 + 3.0 * (0.001 * nom_frames as f64).sqrt();
    assert!((nom_refused as f64) <= allowed, "{nom_refused} of {nom_frames} nominal frames refused");
}

#[test]
fn nominal_flight_raises_no_parity_alarm() {
    // Five minutes from the start, through the slew.
    let sc = faults::scenario(seed(1, 0), 300.0).expect("scenario");
    let mut alarm_steps = 0u32;
    let mut degraded_after_settle = 0u32;
    let f = Fault { kind: FaultKind::None, start_s: f64::INFINITY, duration_s: 0.0 };
    let r = faults::run_observed(&sc, &f, |s| {
        alarm_steps += u32::from(s.out.flags & flags::FDI_ALARM != 0 || s.out.fdi & 0xF0 != 0);
        if s.t_s >= sc.settle_s {
            degraded_after_settle += u32::from(s.out.flags & flags::DEGRADED != 0);
        }
    })
    .expect("run");
    println!(
        "nominal {} steps: {} alarms, {} isolations, {} spikes, {alarm_steps} alarm steps, {degraded_after_settle} \
         degraded steps after settling, error max {:.2}″",
        r.steps, r.alarms, r.isolations, r.spikes, r.att_before_arcsec
    );
    assert_eq!((r.alarms, r.isolations, r.spikes), (0, 0, 0));
    assert_eq!(alarm_steps, 0);
    assert_eq!(degraded_after_settle, 0);
    let c = r.counters;
    assert_eq!(c.fog.map(|f| (f.stuck, f.out_of_range, f.missing, f.temp_failures)), [(0, 0, 0, 0); N_FOG]);
}

#[test]
fn bit_errors_at_1e_4_accept_no_corrupted_frame() {
    for s in 1..=2 {
        let sd = seed(s, 0);
        let f = fault(FaultKind::BitErrors(1e-4), 60.0);
        let r = run(sd, &f);
        let nom = nominal(sd, &f);
        let c = r.counters;
        println!(
            "bit errors seed {sd}: {} corrupted frames ({:?} FOG), {} still decoded; FOG missing {:?}, \
             rejected {:?}; star tracker rejected {}",
            r.corrupted_sent,
            r.corrupted_fog_frames,
            r.corrupted_accepted,
            c.fog.map(|f| f.missing),
            c.fog.map(|f| f.rejected),
            c.st_frames_rejected
        );
        assert!(r.corrupted_sent >= 500, "only {} corrupted frames", r.corrupted_sent);
        assert_eq!(r.corrupted_accepted, 0, "corrupted frames decoded");
        // Each corrupted FOG frame costs its own sample and no other (resynchronisation
        // within one frame).
        for (i, (fc, n)) in c.fog.iter().zip(r.corrupted_fog_frames).enumerate() {
            assert_eq!(u64::from(fc.missing), n, "FOG{}: samples missing vs corrupted frames", i + 1);
        }
        assert_eq!(r.isolations, 0);
        assert_attitude_unharmed("bit errors", &r, &nom, 0.0);
    }
}

#[test]
fn star_tracker_outliers_of_10_sigma_are_all_gated() {
    let (mut sent, mut taken) = (0u64, 0u64);
    for s in 1..=4 {
        let r = run(seed(s, 0), &fault(FaultKind::StOutliers(10.0, 4), 300.0));
        sent += u64::from(r.outliers_sent);
        taken += u64::from(r.outliers_accepted);
    }
    let sim = Simulation::new(&faults::scenario(1, 1.0).expect("scenario")).expect("sim");
    let ss = steady_state(&sim.table.observer).expect("steady state");
    let p = gate_pass_probability(10.0, ss.r_rad2, ss.r_rad2 + ss.prior_var_rad2);
    println!("10σ outliers: {} of {sent} rejected, {taken} taken; design pass probability {p:.1e}", sent - taken);
    assert!(sent >= 1000, "{sent} outliers sent");
    // The goal is ≥ 99.99 % rejected; the design lets fewer than 1e-4 through, so none
    // of these should pass (the campaign counts 30,000).
    assert!(p < 1e-4, "design pass probability {p:.1e}");
    assert_eq!(taken, 0, "10σ outliers taken");
}

/// At the end of a 10-min outage from steady state (1800 s), for each estimator: the
/// error per axis over the runs is what gyro-only coasting from the steady state predicts
/// (Farrenkopf: 8.7″ 1σ with the paper's sensors; within 1.2×), and the unit's own
/// reported 1σ is within 20 % of the measured RMS. 24 seeds × 3 axes = 72 samples pooled
/// (the RMS known to about 8 % 1σ, so ± 20 % is a 2.4σ band: a covariance off by 2×, or
/// by the √(6/5) of one FOG's noise against the four-FOG combination's, fails it).
#[test]
fn ten_minute_outage_ends_at_the_prediction_and_the_unit_reports_its_error() {
    const SEEDS: u64 = 24;
    let k = scale();
    let predicted = faults::coasting_sigma_rad(&k.steady, 600.0) * ARCSEC_PER_RAD;
    let f = Fault { kind: FaultKind::StOutage, start_s: 1800.0, duration_s: 600.0 };
    let one = |est: Estimator| -> Vec<(usize, FaultRun)> {
        (1..=SEEDS).map(|s| (0, run_with(seed(s, 0), &f, est, |_| {}))).collect()
    };
    let results: Vec<(Estimator, Vec<(usize, FaultRun)>)> = std::thread::scope(|sc| {
        let hs: Vec<_> =
            [Estimator::Luenberger, Estimator::Mekf].into_iter().map(|e| (e, sc.spawn(move || one(e)))).collect();
        hs.into_iter().map(|(e, h)| (e, h.join().expect("thread"))).collect()
    });
    for (est, runs) in &results {
        let (rms, sigma) = faults::end_of_outage(runs);
        let pooled = (rms.iter().map(|x| x * x).sum::<f64>() / 3.0).sqrt();
        let reported = sigma.iter().sum::<f64>() / 3.0;
        println!(
            "{est:?}, 10-min outage end over {} runs: RMS {:.2} / {:.2} / {:.2}″ (pooled {pooled:.2}″), predicted \
             {predicted:.2}″ (ratio {:.2}); reported 1σ {:.2} / {:.2} / {:.2}″ (reported / pooled {:.2})",
            runs.len(),
            rms[0],
            rms[1],
            rms[2],
            pooled / predicted,
            sigma[0],
            sigma[1],
            sigma[2],
            reported / pooled
        );
        // The prediction is the same on every axis; the three axes are pooled here, the
        // campaign gives each.
        assert!(pooled <= 1.2 * predicted, "{est:?}: pooled RMS {pooled:.2}″ against {predicted:.2}″");
        assert!(pooled >= predicted / 1.2, "{est:?}: pooled RMS {pooled:.2}″ against {predicted:.2}″: no coast");
        assert!(
            (reported / pooled - 1.0).abs() <= 0.2,
            "{est:?}: reported 1σ {reported:.2}″ against the measured {pooled:.2}″"
        );
    }
}

/// A constant offset on FOG1 from power-on (3 °/h: the parity baseline takes it for
/// calibration residue, the drift estimate learns its share u₁ p̄, about 1.5 °/h by
/// 1800 s), then a 20σ bias step at 1800 s that isolates FOG1 at once: the isolation
/// takes what the estimate learned of FOG1's share out of it (each estimator by its own
/// gains: the observer's slow pole, the MEKF's P_bb P_bb(0)⁻¹), so the drift estimate is
/// back at the calibration residue at once, without a jump of FOG1's size, and the
/// attitude returns to the nominal band (it was off by the estimator's lag behind the
/// offset before the step). For both estimators.
#[test]
fn an_isolation_takes_the_fogs_share_out_of_the_drift_estimate() {
    let k = scale();
    let offset_rad_s = 3.0 / ssis_common::DEG_H_PER_RAD_S;
    let f = Fault {
        kind: FaultKind::FogOffsetThenStep(0, offset_rad_s, k.bias_for_sigma_rad_s(0, 20.0)),
        start_s: 1800.0,
        duration_s: 90.0,
    };
    let sd = seed(1, 0);
    let one = |est: Estimator| {
        let (mut before, mut after, mut late_err) = (0.0f64, 0.0f64, 0.0f64);
        let r = run_with(sd, &f, est, |s| {
            let d = s.out.drift_rad_s.amax() * ssis_common::DEG_H_PER_RAD_S;
            if s.t_s > 1799.0 && s.t_s <= 1800.0 {
                before = before.max(d);
            }
            if s.t_s > 1801.0 && s.t_s <= 1802.0 {
                after = after.max(d);
            }
            if s.t_s > 1860.0 {
                late_err = late_err.max(max_abs(&s.att_err_arcsec));
            }
        });
        let nom = run_with(sd, &Fault { kind: FaultKind::None, ..f }, est, |_| {});
        (r, nom, before, after, late_err)
    };
    let results: Vec<_> = std::thread::scope(|sc| {
        let hs: Vec<_> =
            [Estimator::Luenberger, Estimator::Mekf].into_iter().map(|e| (e, sc.spawn(move || one(e)))).collect();
        hs.into_iter().map(|(e, h)| (e, h.join().expect("thread"))).collect()
    });
    for (est, (r, nom, before, after, late_err)) in &results {
        println!(
            "{est:?}: offset 3 °/h on FOG1, step at 1800 s: isolated {:?}; drift estimate (largest axis) {before:.3} °/h \
             before, {after:.3} °/h after; error from 60 s after the isolation {late_err:.2}″, nominal band {:.2}″",
            r.isolated,
            band(nom)
        );
        assert!(r.isolated.is_some_and(|(i, t)| i == 0 && t < 1.0), "{est:?}: isolated {:?}", r.isolated);
        assert!(*before > 1.0, "{est:?}: the drift estimate had not learned FOG1's share: {before:.3} °/h");
        // The observer's slow pole is known exactly; the MEKF's unlearned fraction F is
        // an upper bound (it forgets its prior faster with the rate random walk), counted
        // as a 1σ error of its own size, so its gains relearn the rest within seconds:
        // what stays a second on is under a fifth of what it had learned of FOG1's share.
        let limit = if *est == Estimator::Mekf { 0.2 * before } else { 0.1 };
        assert!(*after < limit, "{est:?}: FOG1's share left in the drift estimate: {after:.3} °/h");
        assert!(
            *late_err <= band(nom) + 1.0,
            "{est:?}: error {late_err:.2}″ a minute after the isolation, band {:.2}″",
            band(nom)
        );
    }
}
