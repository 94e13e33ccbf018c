//! Bad bytes on any link are counted and flagged; the step keeps running and loses no
//! more than what was corrupted.

use nalgebra::Quaternion;
use ssis::calib::CalibrationTable;
use ssis::flight::{health, FlightCore, FogLinks, Links, Profile};
use ssis::frames::fog::FogFrame;
use ssis::link::{RxRing, TxRing};
use ssis_common::mock::{Impairments, MockLink, MockSink};
use ssis_sim::harness::run;
use ssis_sim::scenario::{ProfileName, Scenario};

fn short_scenario() -> Scenario {
    let text = r#"
        name = "links"
        profile = "spacecraft"
        duration_s = 120
        seed = 5
        [motion]
        base_rate_deg_s = [0.0, -0.0638, 0.0]
        [star_tracker]
        rate_hz = 4
    "#;
    toml::from_str(text).expect("scenario")
}

#[test]
fn corrupted_fog_and_star_bytes_are_counted_not_fatal() {
    let mut sc = short_scenario();
    sc.links.fog = Impairments { bit_flip_prob: 1e-3, drop_prob: 1e-3, max_read: 5, delay_steps: 0 };
    sc.links.star = Impairments { bit_flip_prob: 1e-3, drop_prob: 1e-3, max_read: 3, delay_steps: 2 };
    let s = run(&sc, |_| {}).expect("run");
    println!("{}", s.report());
    let damaged: u64 = s.fog_links.iter().map(|l| l.corrupted + l.dropped).sum();
    assert!(damaged > 50, "impairments did not happen: {damaged}");
    let c = s.counters;
    assert!(c.fog_frames_rejected > 0 && c.fog_samples_missing > 0, "{c:?}");
    // Every step still produced a good output frame.
    assert_eq!(s.frames_out, s.steps);
    assert_eq!(s.frames_out_bad, 0);
    // Losing a few FOG samples (the other three carry the step) costs no attitude.
    let att = s.accuracy.att.max_abs();
    assert!(att.iter().all(|e| *e < 30.0), "attitude error {att:?}");
}

#[test]
fn a_silent_fog_is_flagged_and_the_other_three_carry_on() {
    let mut core = FlightCore::new(Profile::SPACECRAFT, &CalibrationTable::DEFAULT, false).expect("core");
    core.align(Quaternion::identity());
    let mut links = Links {
        fog: FogLinks::PerFog([0, 1, 2, 3].map(|_| MockLink::ideal())),
        star: MockLink::ideal(),
        out: MockSink::default(),
    };
    let w = 1e-3; // rad/s about X
    for n in 1..=400u16 {
        let FogLinks::PerFog(fogs) = &mut links.fog else { unreachable!() };
        for (i, l) in fogs.iter_mut().enumerate() {
            if i == 2 {
                continue; // FOG3 silent
            }
            let s = ssis::calib::CalibrationTable::DEFAULT.axes()[i];
            // One LSB of dither, as a real FOG's noise (a constant output is stuck).
            let dither = f64::from(n % 2) * FogFrame::DTHETA_LSB_RAD;
            l.send(&FogFrame::from_physical(i as u8, n, 0, s.x * w * 0.005 + dither, 25.0).to_bytes());
        }
        let out = core.step(&mut links);
        assert_eq!(out.fog_health[2] & health::MISSING, health::MISSING);
        assert_eq!(out.fog_health[0] & health::USED, health::USED);
        assert!(out.flags & ssis::flight::flags::DEGRADED != 0);
        assert!((out.rate_rad_s.x - w).abs() < 1e-8, "rate {}", out.rate_rad_s);
    }
    assert_eq!(core.counters().fog_samples_missing, 400);
}

#[test]
fn a_blocked_output_is_counted_and_flagged() {
    let mut core = FlightCore::new(Profile::SPACECRAFT, &CalibrationTable::DEFAULT, false).expect("core");
    let mut links = Links {
        fog: FogLinks::PerFog([0, 1, 2, 3].map(|_| MockLink::ideal())),
        star: MockLink::ideal(),
        out: MockSink { blocked: true, ..Default::default() },
    };
    core.step(&mut links);
    links.out.blocked = false;
    let out = core.step(&mut links);
    assert!(out.flags & ssis::flight::flags::OUTPUT_DROPPED != 0);
    assert_eq!(core.counters().output_dropped, 1);
}

#[test]
fn isr_rings_carry_bytes_and_count_overflow() {
    use embedded_io::{Read, ReadReady, Write};
    let rx: RxRing<8> = RxRing::new();
    for b in 0..10u8 {
        rx.push(b);
    }
    assert_eq!(rx.overflows(), 2);
    let mut r = rx.reader();
    let mut buf = [0u8; 16];
    assert!(r.read_ready().expect("ready"));
    assert_eq!(r.read(&mut buf).expect("read"), 8);
    assert_eq!(&buf[..8], &[0, 1, 2, 3, 4, 5, 6, 7]);
    assert!(!r.read_ready().expect("ready"));
    let tx: TxRing<4> = TxRing::new();
    let mut w = tx.writer();
    assert_eq!(w.write(&[9, 8, 7, 6, 5]).expect("write"), 4);
    assert_eq!(tx.pop(), Some(9));
    assert_eq!(tx.len(), 3);
}

#[test]
fn a_link_behind_drops_whole_output_frames_never_a_fragment() {
    // The firmware's output ring (256 bytes) with a UART that sends nothing for a while:
    // the core writes through a frame writer, or the frame port the firmware uses (the
    // frame encoded in the ring), so a step that finds less than one frame of room drops
    // its frame whole (counted), and what the UART sends decodes cleanly.
    use ssis::frames::output::OutputFrame;
    let tx: TxRing<256> = TxRing::new();
    behind(&tx, tx.frame_writer(OutputFrame::LEN));
    let tx: TxRing<256> = TxRing::new();
    behind(&tx, tx.frame_port());
}

/// 40 steps into `out` (a handle of `tx`) with a UART that falls behind.
fn behind<O: ssis::link::OutPort>(tx: &TxRing<256>, out: O) {
    use ssis::frames::decoder::StreamDecoder;
    use ssis::frames::output::OutputFrame;
    let mut core = FlightCore::new(Profile::SPACECRAFT, &CalibrationTable::DEFAULT, false).expect("core");
    let mut links =
        Links { fog: FogLinks::PerFog([0, 1, 2, 3].map(|_| MockLink::ideal())), star: MockLink::ideal(), out };
    let mut sent = Vec::new();
    for k in 0..40 {
        core.step(&mut links);
        // The UART takes 50 bytes a step only every 4th step: it falls behind.
        if k % 4 == 3 {
            sent.extend((0..50).map_while(|_| tx.pop()));
        }
    }
    sent.extend(std::iter::from_fn(|| tx.pop()));
    let dropped = core.counters().output_dropped;
    let mut dec: StreamDecoder<OutputFrame, 128> = StreamDecoder::new();
    let mut good = 0u32;
    dec.push_slice(&sent, |r| good += u32::from(r.is_ok()));
    println!("40 steps: {good} frames sent whole, {dropped} dropped, {} rejected", dec.stats().rejected());
    assert!(dropped > 0, "the link was meant to fall behind");
    assert_eq!(good + dropped, 40);
    assert_eq!(dec.stats().rejected(), 0);
    assert_eq!(sent.len(), good as usize * OutputFrame::LEN);
}

proptest::proptest! {
    /// The rings copy whole runs in and out across the wrap; any mix of single bytes and
    /// runs must behave as a plain FIFO of capacity 7 that drops (RX) or refuses (TX)
    /// what does not fit; the receive port hands out the bytes where they lie (in one or
    /// two runs), and the frame port takes a frame whole or not at all, encoded in the
    /// ring or, where the free space wraps, beside it.
    #[test]
    fn isr_rings_behave_as_bounded_fifos(ops in proptest::collection::vec((0u8..6, 0usize..12), 1..200)) {
        use embedded_io::{Read, Write};
        use ssis::link::{OutPort, RxPort};
        use std::collections::VecDeque;
        let rx: RxRing<7> = RxRing::new();
        let tx: TxRing<7> = TxRing::new();
        let (mut r, mut w) = (rx.reader(), tx.writer());
        let (mut rp, mut fp) = (rx.port(), tx.frame_port());
        let (mut mrx, mut mtx) = (VecDeque::new(), VecDeque::new());
        let (mut dropped, mut next) = (0u32, 0u8);
        for (op, n) in ops {
            let data: Vec<u8> = (0..n).map(|i| next.wrapping_add(i as u8)).collect();
            next = next.wrapping_add(n as u8);
            match op {
                0 => for &b in &data {
                    rx.push(b);
                    if mrx.len() < 7 { mrx.push_back(b) } else { dropped += 1 }
                },
                1 => {
                    let mut buf = vec![0u8; n];
                    let got = r.read(&mut buf).expect("read");
                    let want: Vec<u8> = (0..n.min(mrx.len())).filter_map(|_| mrx.pop_front()).collect();
                    proptest::prop_assert_eq!(&buf[..got], &want[..]);
                }
                2 => {
                    let put = w.write(&data).expect("write");
                    proptest::prop_assert_eq!(put, n.min(7 - mtx.len()));
                    mtx.extend(&data[..put]);
                }
                3 => for _ in 0..n {
                    proptest::prop_assert_eq!(tx.pop(), mtx.pop_front());
                },
                4 => {
                    let mut got = Vec::new();
                    let rep = rp.drain_into(n, &mut [], |run| got.extend_from_slice(run));
                    let want: Vec<u8> = (0..n.min(mrx.len())).filter_map(|_| mrx.pop_front()).collect();
                    proptest::prop_assert_eq!(rep.bytes, want.len());
                    proptest::prop_assert_eq!(got, want);
                }
                _ => {
                    let mut scratch = [0u8; 12];
                    let ok = fp.send_frame(&mut scratch, n, |buf| {
                        buf.copy_from_slice(&data);
                        true
                    });
                    proptest::prop_assert_eq!(ok, n <= 7 - mtx.len());
                    if ok {
                        mtx.extend(&data);
                    }
                }
            }
            proptest::prop_assert_eq!(rx.overflows(), dropped);
            proptest::prop_assert_eq!(tx.len(), mtx.len());
            proptest::prop_assert_eq!(w.free(), 7 - mtx.len());
        }
    }
}

#[test]
fn launch_vehicle_profile_runs_three_fogs_at_1_25_ms() {
    let mut sc = short_scenario();
    sc.profile = ProfileName::LaunchVehicle;
    sc.duration_s = 20.0;
    sc.motion.base_rate_deg_s = [5.0, -20.0, 50.0];
    let s = run(&sc, |_| {}).expect("run");
    println!("{}", s.report());
    assert_eq!(s.steps, 16_000);
    assert_eq!(s.frames_out, s.steps);
    // Free inertial on ideal-but-noisy gyros for 20 s: a few arcsec at most.
    assert!(s.accuracy.att.max_abs().iter().all(|e| *e < 5.0), "{:?}", s.accuracy.att.max_abs());
    let _ = Profile::LAUNCH_VEHICLE;
}

/// Runs a 60 s scenario with FOG link impairments `imp`; returns the summary.
fn run_with_fog_links(imp: Impairments) -> ssis_sim::harness::Summary {
    let mut sc = short_scenario();
    sc.duration_s = 60.0;
    sc.links.fog = imp;
    sc.star_tracker.latency_ms = 40.0;
    run(&sc, |_| {}).expect("run")
}

#[test]
fn constant_link_latency_costs_nothing_but_startup() {
    // Frames arrive 3 steps late on every FOG link: the sample clock follows the FOG
    // counters, so nothing is discarded and the time tags stay those of the samples.
    let ideal = run_with_fog_links(Impairments::default());
    let late = run_with_fog_links(Impairments { delay_steps: 3, ..Default::default() });
    println!("{}\n{}", ideal.report(), late.report());
    assert_eq!(late.counters.fog_samples_stale, 0);
    // Only the three steps before the first sample lack data.
    assert_eq!(late.counters.fog_samples_missing, 0);
    assert!(late.accuracy.att.max_abs().iter().zip(ideal.accuracy.att.max_abs()).all(|(a, b)| (a - b).abs() < 0.5));
}

#[test]
fn the_fog_bus_gives_the_same_output_as_separate_links() {
    // Same frames, one multi-drop link instead of four: bit-identical output.
    use rand::SeedableRng;
    use ssis::frames::output::OutputFrame;
    use ssis_sim::fog::{FogModel, FogSpec};
    use ssis_sim::truth::{MotionSpec, Truth};
    let mut rng = rand_chacha::ChaCha20Rng::seed_from_u64(3);
    let mut truth = Truth::new(MotionSpec::earth_pointing(5640.0, Vec::new()));
    let mut fogs = FogModel::new(&FogSpec::paper_post_calibration(), &mut rng);
    let t = CalibrationTable::DEFAULT;
    let mut a = FlightCore::new(Profile::SPACECRAFT, &t, false).expect("core");
    let mut b = FlightCore::new(Profile::SPACECRAFT, &t, false).expect("core");
    a.align(Quaternion::identity());
    b.align(Quaternion::identity());
    let mut per = Links {
        fog: FogLinks::PerFog([0, 1, 2, 3].map(|_| MockLink::ideal())),
        star: MockLink::ideal(),
        out: MockSink::default(),
    };
    let mut bus = Links { fog: FogLinks::Bus(MockLink::ideal()), star: MockLink::ideal(), out: MockSink::default() };
    for _ in 0..2000 {
        let ts = truth.advance(0.005);
        let s = fogs.sample(&ts.dtheta_rad, ts.t_s, 0.005, &mut rng);
        let (FogLinks::PerFog(ls), FogLinks::Bus(l)) = (&mut per.fog, &mut bus.fog) else { unreachable!() };
        for (i, f) in s.frames.iter().enumerate() {
            ls[i].send(&f.to_bytes());
            l.send(&f.to_bytes());
        }
        let oa = a.step(&mut per);
        let ob = b.step(&mut bus);
        assert_eq!(oa, ob);
    }
    assert_eq!(per.out.bytes, bus.out.bytes);
    assert_eq!(per.out.bytes.len(), 2000 * OutputFrame::LEN);
}
