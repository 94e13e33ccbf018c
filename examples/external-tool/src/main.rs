//! A tool of one's own on the project's crates: encodes a FOG frame with the flight
//! core's encoder, flies 10 s of a simulated scenario through `FlightCore::step` scored by
//! the harness's evaluator, and replays a recorded log given as an argument.
//!
//! `cargo run --release -- ../basilisk/leo-nadir-280s.csv`

use anyhow::Result;
use ssis::frames::fog::FogFrame;
use ssis::frames::Frame;

fn main() -> Result<()> {
    // The frame encoder and decoder (docs/ICD.md).
    let f = FogFrame::from_physical(1, 258, 0, 2.5e-5, 25.5);
    let bytes = f.to_bytes();
    assert_eq!(FogFrame::decode(&bytes), Ok(f));
    println!("FOG frame: {}", bytes.iter().map(|b| format!("{b:02X}")).collect::<Vec<_>>().join(" "));

    // The simulator and the evaluator.
    let mut sc = toml_scenario()?;
    sc.duration_s = 10.0;
    sc.settle_s = 5.0;
    let s = ssis_sim::harness::run(&sc, |_| {})?;
    print!("{}", s.report());

    // A recorded log (docs/RECORDED-LOG.md).
    if let Some(path) = std::env::args().nth(1) {
        let table = ssis::calib::CalibrationTable::DEFAULT;
        let rec = ssis_sim::recorded::read(&[path.into()], ssis::flight::Profile::SPACECRAFT.dt_us)?;
        let r = ssis_sim::replay::replay(&rec, &table, 5.0, |_, _| {})?;
        print!("{}", r.report(&rec, None));
    }
    Ok(())
}

/// One of the project's scenarios (README "Writing a scenario").
fn toml_scenario() -> Result<ssis_sim::scenario::Scenario> {
    let p = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../host-tests/scenarios/qemu-flight.toml");
    ssis_sim::scenario::Scenario::from_file(&p)
}
