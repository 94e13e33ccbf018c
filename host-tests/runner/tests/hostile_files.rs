//! `ssis-qemu` against a careless user, refused before QEMU starts (no QEMU needed): the
//! output directory's log and plot onto inputs or onto files that are not ours, `--json`
//! on a refusal. Every refusal leaves every file byte-identical.

#[path = "../../tests/hostile_common/mod.rs"]
mod hostile;
use hostile::*;

const QEMU: &str = env!("CARGO_BIN_EXE_ssis-qemu");

fn qemu_dir(name: &str) -> Scratch {
    let s = Scratch::new(name);
    s.file("s.toml", "name = \"tiny\"\nprofile = \"spacecraft\"\nduration_s = 5\nseed = 1\nsettle_s = 1\n");
    s.file("fw.elf", "not really an ELF");
    std::fs::create_dir_all(s.path("out")).unwrap();
    s
}

#[test]
fn a_log_over_a_file_not_ours_is_refused() {
    let s = qemu_dir("not-ours");
    s.file("out/tiny-qemu.csv", "my spreadsheet\n");
    let args = ["s.toml", "--elf", "fw.elf", "--out", "out"];
    refused(QEMU, &s, &args, &["out/tiny-qemu.csv", "not recognisably"]);
    s.file("out/tiny-qemu.csv", "t_s,q0\n");
    refused(QEMU, &s, &args, &["out/tiny-qemu.csv", "not recognisably"]);
}

#[test]
fn a_plot_over_a_file_not_ours_is_refused() {
    let s = qemu_dir("plot-not-ours");
    s.file("out/tiny-qemu.svg", "<svg><text>other run</text></svg>");
    refused(QEMU, &s, &["s.toml", "--elf", "fw.elf", "--out", "out"], &["out/tiny-qemu.svg", "not recognisably"]);
}

#[test]
fn outputs_onto_the_scenario_or_the_elf_are_refused() {
    let s = qemu_dir("inputs");
    std::os::unix::fs::symlink(s.path("s.toml"), s.path("out/tiny-qemu.csv")).unwrap();
    refused(QEMU, &s, &["s.toml", "--elf", "fw.elf", "--out", "out"], &["out/tiny-qemu.csv", "input s.toml"]);
    std::fs::remove_file(s.path("out/tiny-qemu.csv")).unwrap();
    std::fs::hard_link(s.path("fw.elf"), s.path("out/tiny-qemu.svg")).unwrap();
    refused(QEMU, &s, &["s.toml", "--elf", "./fw.elf", "--out", "./out/"], &["tiny-qemu.svg", "input ./fw.elf"]);
}

#[test]
fn json_on_a_refusal() {
    let s = qemu_dir("json");
    s.file("out/tiny-qemu.csv", "mine\n");
    let v = json_of(QEMU, &s, &["s.toml", "--elf", "fw.elf", "--out", "out", "--json"], false);
    assert_eq!(at(&v, "/tool"), "ssis-qemu");
    assert_eq!(at(&v, "/command"), "run");
    assert!(at(&v, "/error").as_str().unwrap().contains("out/tiny-qemu.csv"));
    assert_eq!(at(&v, "/files_written").as_array().unwrap().len(), 0);
}
