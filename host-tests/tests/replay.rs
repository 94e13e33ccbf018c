//! Recorded logs through the flight core (`docs/RECORDED-LOG.md`): the committed log from
//! a peer simulator at the estimation limit; captures of the links, damaged or not, give
//! the same output as the CSV. (`ssis-sim replay` on damaged logs and `--check`:
//! `sim/tests/replay_files.rs`.)

use std::path::{Path, PathBuf};

use ssis::flight::Profile;
use ssis_sim::recorded;
use ssis_sim::replay::{farrenkopf_1sigma_arcsec, replay, Feed};

fn example(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../examples/basilisk").join(name)
}

/// A scratch directory per case.
struct Scratch(PathBuf);

impl Scratch {
    fn new(case: &str) -> Scratch {
        let d = std::env::temp_dir().join(format!("ssis-replay-{}-{case}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        std::fs::create_dir_all(&d).expect("scratch dir");
        Scratch(d)
    }

    fn write(&self, name: &str, bytes: impl AsRef<[u8]>) -> PathBuf {
        let p = self.0.join(name);
        std::fs::write(&p, bytes).expect("written");
        p
    }
}

#[test]
fn peer_simulator_log_replays_at_the_estimation_limit() {
    let table = ssis_common::table::read_toml(&example("table.toml")).expect("the example's table");
    let rec = recorded::read(&[example("leo-nadir-280s.csv")], Profile::SPACECRAFT.dt_us).expect("reads");
    assert!(rec.problems.is_clean(), "the committed log is clean:\n{}", rec.problems.report());
    let s = replay(&rec, &table, 60.0, |_, _| {}).expect("replays");
    let dt = Profile::SPACECRAFT;
    let latency_s = rec.st_latency_s(dt.dt_us);
    assert!((latency_s - 0.05).abs() < 1e-9, "the log's tracker latency: {latency_s} s");
    let limit = farrenkopf_1sigma_arcsec(&table.observer, &table.axes(), dt.dt_s(), latency_s);
    println!("{}", s.report(&rec, Some(limit)));
    let att = s.accuracy.att.three_sigma();
    assert_eq!(s.frames_out, 56_000);
    assert!(s.accuracy.att.count() >= 2_200, "steps scored against truth: {}", s.accuracy.att.count());
    for (k, a) in att.iter().enumerate() {
        let (post, mean) = (3.0 * limit.posterior_arcsec[k], 3.0 * limit.period_mean_arcsec[k]);
        let late = 3.0 * limit.latency_mean_arcsec[k];
        println!("axis {k}: 3σ {a:.2}″, limit {post:.2}″ after update, {mean:.2}″ over the period, {late:.2}″ with the latency");
        assert!(*a <= 1.1 * mean, "axis {k}: {a:.2}″ over 1.1 × the limit {mean:.2}″");
        // No estimator beats the limit for its sensors by more than the scatter of 220 s
        // of statistics (some 300 independent samples: a few per cent).
        assert!(*a >= 0.9 * late, "axis {k}: {a:.2}″ below 0.9 × the limit {late:.2}″: truth leaks in?");
    }
    // The unit's own evidence agrees: residuals at the tracker's noise, no frame gated
    // beyond the gate's 0.1 %.
    let c = s.evidence.last.expect("frames").counters;
    assert!(c.st_updates_gated <= 4, "gated {}", c.st_updates_gated);
}

#[test]
fn captures_with_crc_failures_replay_like_the_csv() {
    let d = Scratch::new("capture");
    let table = ssis::calib::CalibrationTable::DEFAULT;
    let mut rec = recorded::read(&[example("leo-nadir-280s.csv")], Profile::SPACECRAFT.dt_us).expect("reads");
    rec.steps.truncate(2000);
    let mut feed = Feed::new(&rec, &table, Profile::SPACECRAFT.dt_us);
    // Two links logged apart, and the same merged by a logger in arrival order.
    let (mut fog, mut st, mut merged) = (Vec::new(), Vec::new(), Vec::new());
    while let Some(i) = feed.next_step() {
        for f in &i.fog_frames {
            fog.extend_from_slice(f);
            merged.extend_from_slice(f);
        }
        st.extend_from_slice(&i.st_bytes);
        merged.extend_from_slice(&i.st_bytes);
    }
    let merged = d.write("merged.bin", &merged);
    let clean = (d.write("fog.bin", &fog), d.write("st.bin", &st));
    // Every 97th FOG frame and the 5th star frame with one bit flipped; 7 stray bytes.
    let flen = ssis::frames::fog::FogFrame::LEN;
    let mut bad = fog.clone();
    let mut flipped = 0u64;
    for k in (0..bad.len() / flen).step_by(97) {
        bad[k * flen + 8] ^= 0x10;
        flipped += 1;
    }
    bad.splice(flen * 10..flen * 10, [0xEB, 0x90, 0x00, 1, 2, 3, 4]);
    let mut st_bad = st.clone();
    st_bad[ssis::frames::star::StarFrame::LEN * 4 + 20] ^= 1;
    let damaged_paths = (d.write("fog-bad.bin", &bad), d.write("st-bad.bin", &st_bad));
    let dt = Profile::SPACECRAFT.dt_us;
    let clean_rec = recorded::read(&[clean.0.clone(), clean.1.clone()], dt).expect("reads");
    assert!(clean_rec.problems.is_clean(), "{}", clean_rec.problems.report());
    let bad_rec = recorded::read(&[damaged_paths.0.clone(), damaged_paths.1.clone()], dt).expect("reads");
    println!("{}", bad_rec.problems.report());
    assert_eq!(bad_rec.problems.crc_failures.count, flipped + 1);
    assert_eq!(bad_rec.problems.field_errors.count, 0);
    assert!(bad_rec.problems.bytes_skipped.count >= 7 + (flipped + 1) * flen as u64 - 16);
    assert_eq!(bad_rec.fog_samples() + flipped as usize, clean_rec.fog_samples());
    // The capture carries the same bytes as the CSV: the same output.
    let csv = rec.clone();
    let cap = recorded::read(&[merged], Profile::SPACECRAFT.dt_us).expect("reads");
    assert!(cap.problems.is_clean(), "{}", cap.problems.report());
    let h = |r: &recorded::Recorded| replay(r, &table, 5.0, |_, _| {}).expect("replays").hash;
    assert_eq!(h(&csv), h(&cap), "capture and CSV give different outputs");
}

#[test]
fn the_latency_limit_adds_the_angle_random_walk_over_the_latency() {
    let table = ssis_common::table::read_toml(&example("table.toml")).expect("the example's table");
    let dt = Profile::SPACECRAFT.dt_s();
    let none = farrenkopf_1sigma_arcsec(&table.observer, &table.axes(), dt, 0.0);
    assert_eq!(none.latency_mean_arcsec, none.period_mean_arcsec, "no latency: the period average");
    let late = farrenkopf_1sigma_arcsec(&table.observer, &table.axes(), dt, 0.05);
    // Over 50 ms the attitude variance grows by the FOGs' angle random walk per body axis
    // (0.05 °/√h = 3″/√s on one FOG; 5/6 of its variance through the four-FOG least
    // squares); the drift's share over 50 ms is below 1e-6 of it.
    let q_arcsec2_s = 9.0 * 5.0 / 6.0;
    for k in 0..3 {
        let want = (none.period_mean_arcsec[k].powi(2) + q_arcsec2_s * 0.05).sqrt();
        let got = late.latency_mean_arcsec[k];
        println!("axis {k}: {got:.4}″ 1σ with 50 ms, {want:.4}″ from the random walk alone");
        assert!((got / want - 1.0).abs() < 1e-3, "axis {k}: {got} against {want}");
    }
}

/// A log longer than the conventions check's head (`CHECK_SPAN_S`) replays streamed (in
/// three stages on threads of their own) exactly as the same log read whole: the output
/// frames' fingerprint, the frames, the events and every accuracy figure.
#[test]
fn a_log_streamed_in_stages_replays_as_read_whole() {
    use ssis_sim::recorded::LogStream;
    use ssis_sim::streamed::{replay_stream, CHECK_SPAN_S};
    let sc = ssis_sim::scenario::Scenario::from_file(Path::new("scenarios/earth-pointing-2h.toml")).expect("scenario");
    let mut sim = ssis_sim::harness::Simulation::new(&sc).expect("simulation");
    let steps = ((CHECK_SPAN_S + 150.0) / sim.profile.dt_s()) as u64;
    let mut csv = Vec::new();
    ssis_sim::sc_record::write_log(&mut sim, steps, 2, false, &mut csv).expect("log written");
    let table = ssis::calib::CalibrationTable::DEFAULT;
    let open = || LogStream::from_reader(Box::new(std::io::Cursor::new(csv.clone())), "long.csv".into()).expect("log");
    let whole = replay(&open().collect().expect("read whole"), &table, 60.0, |_, _| {}).expect("replays");
    let (mut frames, mut last) = (0u64, None);
    let streamed = replay_stream(
        open(),
        &table,
        60.0,
        |_| {},
        |f, _| {
            frames += 1;
            last = Some(*f);
        },
    )
    .expect("replays streamed");
    let s = streamed.summary;
    assert_eq!(s.steps, steps);
    assert_eq!((s.hash, s.frames_out, frames), (whole.hash, whole.frames_out, whole.frames_out));
    assert_eq!(s.events, whole.events);
    assert_eq!(last.map(|f| f.time_us), whole.evidence.last.map(|f| f.time_us));
    assert_eq!(format!("{:?}", s.accuracy), format!("{:?}", whole.accuracy));
    assert_eq!(streamed.conventions.span_s, Some(CHECK_SPAN_S));
}
