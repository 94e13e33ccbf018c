//! Fuzz target: the CSV session reader (`ssis_session`, the host workspace's crate that the
//! model lab and the calibration methods read sessions with).
//!
//! The reader reads files (a fixed buffer, line by line), so each input is written to a
//! file of this process in the temporary directory (a tmpfs where there is one) and read
//! back with `read_session`: any input must give a session or a `SessionError`, never a
//! panic; an accepted session's columns must all have the same length.
#![no_main]

use std::path::PathBuf;
use std::sync::OnceLock;

fn path() -> &'static PathBuf {
    static P: OnceLock<PathBuf> = OnceLock::new();
    P.get_or_init(|| {
        let shm = std::path::Path::new("/dev/shm");
        let dir = if shm.is_dir() { shm.to_path_buf() } else { std::env::temp_dir() };
        dir.join(format!("ssis-fuzz-session-{}.csv", std::process::id()))
    })
}

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    let p = path();
    std::fs::write(p, data).expect("temporary file");
    if let Ok(s) = ssis_session::read_session(p, None) {
        let n = s.cols.first().map_or(0, Vec::len);
        assert!(s.cols.iter().all(|c| c.len() == n));
        assert_eq!(s.cols.len(), s.names.len());
    }
});
