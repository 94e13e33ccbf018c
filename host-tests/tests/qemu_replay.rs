//! A recorded log on the firmware in QEMU (`ssis-qemu --replay`, docs/RECORDED-LOG.md):
//! the committed log from a peer simulator streamed in lockstep over Unix sockets and, the
//! hardware-in-the-loop path, over pseudo-terminals opened as serial ports; every output
//! frame bit-identical to the host replay's, and the two transports' to each other.

use std::path::{Path, PathBuf};

use ssis::flight::Profile;
use ssis::frames::output::OutputFrame;
use ssis_runner::qemu::{build_firmware, masked, run_feed, Feed, QemuOptions, QemuSummary};
use ssis_runner::transport::Transport;
use ssis_sim::recorded::{self, Recorded};
use ssis_sim::replay::{replay, Feed as LogFeed};

/// Simulated seconds of the log streamed per run.
const DURATION_S: f64 = 60.0;

fn example(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../examples/basilisk").join(name)
}

/// The first [`DURATION_S`] of `rec` on the firmware: the summary and every output frame
/// without what the board fills in itself (`masked`), as bytes.
fn on_firmware(
    rec: &Recorded,
    table: &ssis::calib::CalibrationTable,
    transport: Transport,
) -> (QemuSummary, Vec<Vec<u8>>) {
    let elf = build_firmware().expect("firmware builds");
    let steps = (DURATION_S / Profile::SPACECRAFT.dt_s()).round() as u64;
    let mut log = LogFeed::new(rec, table, Profile::SPACECRAFT.dt_us);
    let feed = Feed {
        name: format!("basilisk-{transport:?}"),
        profile: Profile::SPACECRAFT,
        table: *table,
        steps,
        settle_s: 30.0,
        next: Box::new(move || log.next_step().filter(|i| i.n <= steps)),
    };
    let mut frames = Vec::new();
    let opts = QemuOptions { transport, ..QemuOptions::lockstep(elf) };
    let s = run_feed(feed, &opts, |f, _| frames.push(masked(*f).to_bytes().to_vec())).expect("QEMU run");
    println!("{}", s.report());
    (s, frames)
}

#[test]
fn recorded_log_on_the_firmware_over_sockets_and_serial_ports() {
    let table = ssis_common::table::read_toml(&example("table.toml")).expect("the example's table");
    let rec = recorded::read(&[example("leo-nadir-280s.csv")], Profile::SPACECRAFT.dt_us).expect("reads");
    let mut host = Vec::new();
    let steps = (DURATION_S / Profile::SPACECRAFT.dt_s()).round() as usize;
    replay(&rec, &table, 30.0, |f: &OutputFrame, _| {
        if host.len() < steps {
            host.push(masked(*f).to_bytes().to_vec());
        }
    })
    .expect("host replay");

    for transport in [Transport::Sockets, Transport::Pty] {
        let (s, frames) = on_firmware(&rec, &table, transport);
        assert_eq!(s.exit_code, Some(0), "{transport:?}: the firmware did not end cleanly");
        assert_eq!(s.frames_out_bad, 0, "{transport:?}");
        assert_eq!(
            s.equal_frames, s.steps,
            "{transport:?}: {} frames differ from the in-process core's",
            s.differing_frames
        );
        assert_eq!(frames.len(), steps, "{transport:?}: output frames");
        let differ = frames.iter().zip(&host).filter(|(a, b)| a != b).count();
        println!("{transport:?}: {} of {} output frames bit-identical to the host replay's", steps - differ, steps);
        assert_eq!(differ, 0, "{transport:?}: frames differ from the host replay's");
        let att = s.accuracy.att.three_sigma();
        println!("{transport:?}: attitude 3σ after 30 s {:.2} / {:.2} / {:.2}″", att[0], att[1], att[2]);
    }
}
