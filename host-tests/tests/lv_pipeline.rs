//! The launch-vehicle pipeline on the host: FOG frames through `FlightCore::step()`
//! (launch-vehicle profile: three FOGs, 1.25 ms; decoding, compensation, combination)
//! and each integrated body increment, with accelerometer frames, through the
//! navigation stage (`NavUnit`) — over the first 200 s of the ascent (vertical rise,
//! pitch program, staging at 150 s, vibration) with ideal sensors (frame quantisation
//! only) and no GNSS: the free-inertial error must stay within criterion (a)'s 1 m and
//! 0.01 m/s, which a lost, doubled or misaligned sample would break.

use rand::SeedableRng;
use rand_chacha::ChaCha20Rng;
use ssis::calib::accel::AccelTable;
use ssis::calib::CalibrationTable;
use ssis::flight::{FlightCore, FogLinks, Links, Profile};
use ssis::nav::unit::{NavLinks, NavUnit};
use ssis_common::mock::{MockLink, MockSink};
use ssis_sim::accel::{AccelModel, AccelSpec};
use ssis_sim::fog::{FogModel, FogSpec};
use ssis_sim::launch::LaunchProfile;
use ssis_sim::lv::{filter_config, AscentRecord};

const DT_S: f64 = 1.25e-3;

#[test]
fn flight_core_and_nav_unit_over_200_s() {
    let rec = AscentRecord::record(LaunchProfile::default(), DT_S, 200.0);
    let mut rng = ChaCha20Rng::seed_from_u64(5);
    let mut fogs = FogModel::new(&FogSpec { arw_deg_sqrt_h: 0.0, ..FogSpec::default() }, &mut rng);
    let mut accels = AccelModel::new(&AccelSpec::default(), &mut rng);
    let mut core = FlightCore::new(Profile::LAUNCH_VEHICLE, &CalibrationTable::DEFAULT, false).expect("core");
    let cfg = filter_config(&FogSpec::paper_post_calibration(), &AccelSpec::typical_pendulous());
    let comp = AccelTable::IDEAL.compensator().expect("table");
    let mut unit = NavUnit::new(rec.initial, DT_S, comp, cfg).expect("unit");
    let mut links = Links {
        fog: FogLinks::PerFog([MockLink::ideal(), MockLink::ideal(), MockLink::ideal(), MockLink::ideal()]),
        star: MockLink::ideal(),
        out: MockSink::default(),
    };
    let mut nav_links = NavLinks { accel: MockLink::ideal(), gnss: MockLink::ideal(), out: MockSink::default() };
    let (mut max_dr, mut max_dv, mut nav_steps) = (0.0f64, 0.0f64, 0usize);
    for (k, ((dth, dv), truth)) in rec.increments.iter().zip(&rec.truth).enumerate() {
        let t_end = (k + 1) as f64 * DT_S;
        let s = fogs.sample(dth, t_end, DT_S, &mut rng);
        if let FogLinks::PerFog(l) = &mut links.fog {
            for (link, f) in l.iter_mut().zip(s.frames.iter()) {
                link.send(&f.to_bytes());
            }
        }
        for f in accels.sample(dv, t_end, DT_S, &mut rng) {
            nav_links.accel.send(&f.to_bytes());
        }
        let mut incs = Vec::new();
        core.step_with(&mut links, |t_us, body| incs.push((t_us, *body)));
        for (t_us, body) in incs {
            let out = unit.step(&body, t_us, &mut nav_links);
            nav_steps += 1;
            assert_eq!(t_us, (k as u64 + 1) * 1_250, "sample time");
            max_dr = max_dr.max((out.state.r_e_m - truth.r_e_m).norm());
            max_dv = max_dv.max((out.state.v_e_m_s - truth.v_e_m_s).norm());
        }
        // The heavy filter work once per flight step, after its outputs (as the firmware).
        unit.filter_work();
        links.out.bytes.clear();
        nav_links.out.bytes.clear();
        if let FogLinks::PerFog(l) = &mut links.fog {
            l.iter_mut().for_each(MockLink::tick);
        }
        nav_links.accel.tick();
    }
    println!(
        "{nav_steps} navigation steps over {} core steps; free inertial through the frames: max {max_dr:.3e} m, {max_dv:.3e} m/s; {:?}",
        rec.increments.len(),
        unit.counters()
    );
    assert_eq!(nav_steps, rec.increments.len(), "one navigation step per FOG sample");
    assert_eq!(unit.counters().accel_steps_held, 0);
    assert!(max_dr <= 1.0 && max_dv <= 0.01, "{max_dr} m, {max_dv} m/s");
}
