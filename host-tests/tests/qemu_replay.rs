//! A recorded log on the firmware in QEMU (`ssis-qemu --replay`, docs/RECORDED-LOG.md):
//! the committed log from a peer simulator streamed in lockstep over Unix sockets, and,
//! the hardware-in-the-loop path, to a unit already running on serial ports
//! (`ssis-qemu --board`): QEMU started here by hand with its UARTs on pseudo-terminals
//! (`-serial pty`) stands in for the board, and the runner only opens the ports it is
//! given. Every output frame bit-identical to the host replay's, and the two runs' to each
//! other.

use std::io::BufReader;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use ssis::flight::Profile;
use ssis::frames::output::OutputFrame;
use ssis_runner::progress::ICOUNT_LOCKSTEP;
use ssis_runner::qemu::{build_firmware, masked, run_feed, Feed, QemuOptions, QemuSummary};
use ssis_runner::transport::{read_pty_names, BoardPorts, BAUD};
use ssis_sim::recorded::{self, Recorded};
use ssis_sim::replay::{replay, Feed as LogFeed};

/// Simulated seconds of the log streamed per run.
const DURATION_S: f64 = 60.0;

fn example(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../examples/basilisk").join(name)
}

/// The first [`DURATION_S`] of `rec` on the firmware with `opts`: the summary and every
/// output frame without what the board fills in itself (`masked`), as bytes.
fn on_firmware(
    rec: &Recorded,
    table: &ssis::calib::CalibrationTable,
    name: &str,
    opts: &QemuOptions,
) -> (QemuSummary, Vec<Vec<u8>>) {
    let steps = (DURATION_S / Profile::SPACECRAFT.dt_s()).round() as u64;
    let mut log = LogFeed::new(rec, table, Profile::SPACECRAFT.dt_us);
    let feed = Feed {
        name: name.into(),
        profile: Profile::SPACECRAFT,
        table: *table,
        steps,
        settle_s: 30.0,
        next: Box::new(move || log.next_step().filter(|i| i.n <= steps)),
        on_step: None,
    };
    let mut frames = Vec::new();
    let s = run_feed(feed, opts, |f, _| frames.push(masked(*f).to_bytes().to_vec())).expect("run");
    println!("{}", s.report());
    (s, frames)
}

/// The stand-in board: QEMU started as a user would by hand, UARTs on pseudo-terminals,
/// the table's flash image loaded at the ELF's `_calib_start`; stopped when dropped.
struct StandIn {
    child: Child,
    ptys: Vec<String>,
    dir: PathBuf,
}

impl StandIn {
    fn start(elf: &Path, table: &ssis::calib::CalibrationTable) -> StandIn {
        let dir = std::env::temp_dir().join(format!("ssis-standin-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).expect("scratch dir");
        let img = dir.join("table.img");
        std::fs::write(&img, ssis::calib::store::image(table)).expect("table image");
        let calib = ssis_runner::qemu::symbol(elf, "_calib_start").expect("_calib_start");
        let mut child = Command::new("qemu-system-arm")
            .args(["-machine", "mps2-an500", "-cpu", "cortex-m7", "-display", "none", "-monitor", "none"])
            .args(["-semihosting-config", "enable=on,target=native", "-icount", ICOUNT_LOCKSTEP])
            .args(["-serial", "pty", "-serial", "pty", "-serial", "pty"])
            .args(["-device", &format!("loader,file={},addr={calib:#x}", img.display())])
            .arg("-kernel")
            .arg(elf)
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::null())
            .spawn()
            .expect("qemu-system-arm starts");
        let mut out = BufReader::new(child.stdout.take().expect("stdout"));
        let ptys = read_pty_names(&mut out, 3).expect("QEMU names its pseudo-terminals");
        // The rest is the firmware's log over semihosting: drained, so QEMU never blocks.
        std::thread::spawn(move || std::io::copy(&mut out, &mut std::io::sink()));
        StandIn { child, ptys, dir }
    }

    /// QEMU's exit status once it has exited by itself (within `wait`), else `None`.
    fn exit_within(&mut self, wait: Duration) -> Option<std::process::ExitStatus> {
        let t = Instant::now();
        while t.elapsed() < wait {
            if let Ok(Some(st)) = self.child.try_wait() {
                return Some(st);
            }
            std::thread::sleep(Duration::from_millis(50));
        }
        None
    }
}

impl Drop for StandIn {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
        let _ = std::fs::remove_dir_all(&self.dir);
    }
}

#[test]
fn recorded_log_on_the_firmware_over_sockets_and_on_a_running_board_over_serial_ports() {
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
    let elf = build_firmware().expect("firmware builds");

    let (sockets, socket_frames) = on_firmware(&rec, &table, "basilisk-sockets", &QemuOptions::lockstep(elf.clone()));
    assert_eq!(sockets.exit_code, Some(0), "sockets: the firmware did not end cleanly");

    let mut board = StandIn::start(&elf, &table);
    println!("stand-in board on {}", board.ptys.join(", "));
    let ports = BoardPorts { links: [0, 1, 2].map(|i| (board.ptys[i].clone(), BAUD)) };
    let opts = QemuOptions { board: Some(ports), ..QemuOptions::lockstep(elf.clone()) };
    let (on_board, board_frames) = on_firmware(&rec, &table, "basilisk-board", &opts);
    assert!(on_board.board && on_board.exit_code.is_none(), "the runner started or stopped a process");
    let exit = board.exit_within(Duration::from_secs(30));
    assert!(exit.is_some_and(|st| st.success()), "the stand-in did not end cleanly at END: {exit:?}");

    for (name, s, frames) in [("sockets", &sockets, &socket_frames), ("board", &on_board, &board_frames)] {
        assert!(s.clean(), "{name}: not clean");
        assert_eq!(s.frames_out_bad, 0, "{name}");
        assert_eq!(s.equal_frames, s.steps, "{name}: {} frames differ from the in-process core's", s.differing_frames);
        assert_eq!(frames.len(), steps, "{name}: output frames");
        let differ = frames.iter().zip(&host).filter(|(a, b)| a != b).count();
        println!("{name}: {} of {} output frames bit-identical to the host replay's", steps - differ, steps);
        assert_eq!(differ, 0, "{name}: frames differ from the host replay's");
        let att = s.accuracy.att.three_sigma();
        println!("{name}: attitude 3σ after 30 s {:.2} / {:.2} / {:.2}″", att[0], att[1], att[2]);
    }
    assert!(board_frames == socket_frames, "the board run's frames differ from the socket run's");
}
