//! `ssis-faults --out` over an existing document: refused before the campaign runs.

#[path = "../../tests/hostile_common/mod.rs"]
mod hostile;
use hostile::*;

const FAULTS: &str = env!("CARGO_BIN_EXE_ssis-faults");

#[test]
fn out_over_an_existing_file_needs_force() {
    let s = Scratch::new("faults-out");
    s.file("campaign.md", "# my notes\n");
    refused(FAULTS, &s, &["--seeds", "1", "--out", "campaign.md"], &["campaign.md", "exists", "--force"]);
    std::fs::create_dir_all(s.path("d")).unwrap();
    refused(FAULTS, &s, &["--seeds", "1", "--out", "d"], &["d", "directory"]);
}
