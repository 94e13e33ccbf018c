//! The navigation stage with its links (`ssis::nav::unit::NavUnit`): accelerometer
//! frames on a multi-drop mock link, GNSS frames on their own link, navigation output
//! frames decoded back, over the 600 s ascent with a 300–330 s GNSS outage. The body
//! angle increments are the truth's (the FOG stage is the flight step's, not under
//! test here).

use rand::SeedableRng;
use rand_chacha::ChaCha20Rng;
use ssis::calib::accel::AccelTable;
use ssis::frames::decoder::StreamDecoder;
use ssis::frames::gnss::{status, GnssFrame};
use ssis::frames::navout::{flags, NavOutputFrame, POS_LSB_M, VEL_LSB_M_S};
use ssis::nav::unit::{NavLinks, NavUnit};
use ssis_common::mock::{Impairments, MockLink, MockSink};
use ssis_sim::accel::{AccelModel, AccelSpec};
use ssis_sim::fog::FogSpec;
use ssis_sim::gnss::GnssSpec;
use ssis_sim::launch::LaunchProfile;
use ssis_sim::lv::{filter_config, AscentRecord};

const DT_S: f64 = 1.25e-3;

struct Outcome {
    steps: usize,
    frames_out: usize,
    updated: usize,
    outage_steps: usize,
    accel_fault_steps: usize,
    nav_faults: usize,
    max_frame_vs_state: (f64, f64),
    final_err: (f64, f64),
    max_err_after_400_s: (f64, f64),
    counters: ssis::nav::unit::NavCounters,
    fixes_used: u32,
}

fn run(duration_s: f64, accel_imp: Impairments) -> Outcome {
    let rec = AscentRecord::record(LaunchProfile::default(), DT_S, duration_s);
    let mut rng = ChaCha20Rng::seed_from_u64(3);
    let mut accels = AccelModel::new(&AccelSpec::default(), &mut rng);
    let gnss = GnssSpec { outages_s: vec![[300.0, 330.0]], ..GnssSpec::default() };
    let cfg = filter_config(&FogSpec::paper_post_calibration(), &AccelSpec::typical_pendulous());
    let comp = AccelTable::IDEAL.compensator().expect("table");
    let mut unit = NavUnit::new(rec.initial, DT_S, comp, cfg).expect("unit");
    let mut links = NavLinks { accel: MockLink::new(accel_imp, 11), gnss: MockLink::ideal(), out: MockSink::default() };
    let mut out_dec: StreamDecoder<NavOutputFrame, 128> = StreamDecoder::new();
    let mut o = Outcome {
        steps: 0,
        frames_out: 0,
        updated: 0,
        outage_steps: 0,
        accel_fault_steps: 0,
        nav_faults: 0,
        max_frame_vs_state: (0.0, 0.0),
        final_err: (0.0, 0.0),
        max_err_after_400_s: (0.0, 0.0),
        counters: Default::default(),
        fixes_used: 0,
    };
    let mut fix_counter = 0u16;
    for (k, ((dth, dv), truth)) in rec.increments.iter().zip(&rec.truth).enumerate() {
        let step = k as u64 + 1;
        let t_us = step * 1_250;
        for f in accels.sample(dv, step as f64 * DT_S, DT_S, &mut rng) {
            links.accel.send(&f.to_bytes());
        }
        if let Some(fix) = gnss.fix(step, DT_S, truth, &mut rng) {
            let g = GnssFrame::from_physical(status::FIX_VALID | status::FIX_3D, fix_counter, 10, t_us, &fix);
            fix_counter = fix_counter.wrapping_add(1);
            links.gnss.send(&g.to_bytes());
        }
        let out = unit.step(dth, t_us, &mut links);
        // The heavy filter work after the step's output, as the firmware does.
        unit.filter_work();
        links.accel.tick();
        links.gnss.tick();
        // Decode what the unit sent.
        let bytes = std::mem::take(&mut links.out.bytes);
        let mut frames = Vec::new();
        out_dec.push_slice(&bytes, |r| {
            if let Ok(f) = r {
                frames.push(f);
            }
        });
        o.frames_out += frames.len();
        if let Some(f) = frames.last() {
            let s = f.state();
            let dr = (s.r_e_m - out.state.r_e_m).amax();
            let dv = (s.v_e_m_s - out.state.v_e_m_s).amax();
            o.max_frame_vs_state = (o.max_frame_vs_state.0.max(dr), o.max_frame_vs_state.1.max(dv));
            assert_eq!(f.flags, out.flags);
            assert_eq!(f.time_tag_us, t_us);
        }
        o.updated += usize::from(out.flags & flags::GNSS_UPDATED != 0);
        o.outage_steps += usize::from(out.flags & flags::GNSS_OUTAGE != 0);
        o.accel_fault_steps += usize::from(out.flags & flags::ACCEL_FAULT != 0);
        o.nav_faults += usize::from(out.flags & flags::NAV_FAULT != 0);
        let err = ((out.state.r_e_m - truth.r_e_m).norm(), (out.state.v_e_m_s - truth.v_e_m_s).norm());
        o.final_err = err;
        if step as f64 * DT_S >= 400.0 {
            o.max_err_after_400_s = (o.max_err_after_400_s.0.max(err.0), o.max_err_after_400_s.1.max(err.1));
        }
        o.steps += 1;
    }
    o.counters = unit.counters();
    o.fixes_used = unit.nav().counts().0;
    o
}

#[test]
fn nav_unit_over_the_ascent_through_its_links() {
    let o = run(600.0, Impairments::default());
    println!(
        "{} steps, {} output frames, {} GNSS updates, {} steps flagged outage, {} accel-held, {} nav faults; \
         frame vs state {:.1e} m / {:.1e} m/s; error at 600 s {:.2} m / {:.4} m/s, worst after 400 s {:.2} m / {:.4} m/s; {:?}",
        o.steps,
        o.frames_out,
        o.updated,
        o.outage_steps,
        o.accel_fault_steps,
        o.nav_faults,
        o.max_frame_vs_state.0,
        o.max_frame_vs_state.1,
        o.final_err.0,
        o.final_err.1,
        o.max_err_after_400_s.0,
        o.max_err_after_400_s.1,
        o.counters
    );
    assert_eq!(o.frames_out, o.steps, "one output frame per step");
    assert_eq!(o.nav_faults, 0);
    assert_eq!(o.accel_fault_steps, 0, "ideal link: no accelerometer sample missing");
    assert_eq!(o.fixes_used, 570, "every fix outside the outage used");
    // A fix is applied by the filter work after the step it arrived in and flagged in the
    // next frame: the fix of the last step (600 s) has no frame after it.
    assert_eq!(o.updated, 569, "frames flagged GNSS_UPDATED");
    // Outage flag: from the start to the first fix's step (1 s: 800 steps; that step's
    // frame precedes the update) and from 2 s after the last fix before the outage
    // (299 s) to the first fix's step after it (330 s), inclusive.
    let before_first_fix = 800;
    let in_outage = ((330.0 - 301.0) / DT_S) as usize + 1;
    assert!(o.outage_steps.abs_diff(before_first_fix + in_outage) <= 2, "outage steps {}", o.outage_steps);
    assert!(o.max_frame_vs_state.0 <= 0.5 * POS_LSB_M && o.max_frame_vs_state.1 <= 0.5 * VEL_LSB_M_S);
    // Ideal accelerometers and angle increments: the error is the GNSS noise's share.
    assert!(o.max_err_after_400_s.0 < 5.0 && o.max_err_after_400_s.1 < 0.1, "{:?}", o.max_err_after_400_s);
}

/// Bit errors on the accelerometer link: frames are rejected and counted, the step
/// holds the previous increment and flags it, the output never stops.
#[test]
fn nav_unit_with_a_corrupted_accelerometer_link() {
    let o = run(20.0, Impairments { bit_flip_prob: 2e-4, ..Impairments::default() });
    println!(
        "{} steps, {} held, rejected {} accel frames, error at 20 s {:.3} m / {:.4} m/s",
        o.steps, o.accel_fault_steps, o.counters.accel_frames_rejected, o.final_err.0, o.final_err.1
    );
    assert_eq!(o.frames_out, o.steps);
    assert!(o.counters.accel_frames_rejected > 0 && o.accel_fault_steps > 0);
    assert_eq!(o.counters.accel_steps_held as usize, o.accel_fault_steps);
    assert_eq!(o.nav_faults, 0);
}

/// The pad initialisation block (`ssis::nav::init`): what the firmware reads from its
/// LVDATA region round-trips, and a damaged or out-of-range block is refused.
#[test]
fn pad_init_block_round_trip_and_refusals() {
    use ssis::nav::init::{InitError, PadInit, BLOCK_LEN};
    let rec = AscentRecord::record(LaunchProfile::default(), DT_S, DT_S);
    let cfg = filter_config(&FogSpec::paper_post_calibration(), &AccelSpec::typical_pendulous());
    let p = PadInit { revision: 3, state: rec.initial, gnss: cfg };
    let bytes = p.to_bytes();
    assert_eq!(bytes.len(), BLOCK_LEN);
    assert_eq!(PadInit::from_bytes(&bytes), Ok(p));
    let mut bad = bytes;
    bad[40] ^= 0x10;
    assert_eq!(PadInit::from_bytes(&bad), Err(InitError::Crc));
    assert_eq!(PadInit::from_bytes(&bytes[..BLOCK_LEN - 1]), Err(InitError::Length));
    let mut magic = bytes;
    magic[0] = b'X';
    assert_eq!(PadInit::from_bytes(&magic), Err(InitError::Magic));
    let refused = |f: &dyn Fn(&mut PadInit)| {
        let mut q = p;
        f(&mut q);
        PadInit::from_bytes(&q.to_bytes())
    };
    assert_eq!(refused(&|q| q.state.v_e_m_s.x = f64::NAN), Err(InitError::Value));
    assert_eq!(refused(&|q| q.state.q_eb *= 1.001), Err(InitError::Value));
    assert_eq!(refused(&|q| q.state.r_e_m *= 0.1), Err(InitError::Value));
    assert_eq!(refused(&|q| q.gnss.vrw_m_s_sqrt_s = -1.0), Err(InitError::Value));
    assert_eq!(refused(&|q| q.gnss.gate_sigma = 0.0), Err(InitError::Value));
}
