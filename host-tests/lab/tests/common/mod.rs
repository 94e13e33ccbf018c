//! What the lab's tests share: a scratch directory, the preset sessions read back through
//! the session reader, the starting model, °/h.
#![allow(dead_code)]

use std::path::{Path, PathBuf};

use ssis_common::DEG_H_PER_RAD_S;
use ssis_lab::model::{Catalog, Kind, Model};
use ssis_lab::session::{read_session, Session};
use ssis_lab::simulate::{generate, preset, SimSession};

pub fn scratch(name: &str) -> PathBuf {
    let d = Path::new(env!("CARGO_TARGET_TMPDIR")).join("lab").join(name);
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// Generates a preset session, writes it as CSV and reads it back through the session reader.
pub fn session(dir: &Path, name: &str, seed: u64, hidden: bool) -> (SimSession, Session) {
    let sim = generate(&preset(name, seed, hidden).unwrap());
    let path = dir.join(format!("{name}-{seed}.csv"));
    sim.write_csv(&path).unwrap();
    let s = read_session(&path, None).unwrap();
    (sim, s)
}

pub fn starting_model(name: &str) -> Model {
    let mut k =
        vec![Kind::Catalog(Catalog::Bias), Kind::Catalog(Catalog::ScaleFactor), Kind::Catalog(Catalog::Misalignment)];
    if name == "thermal" {
        k.push(Kind::Catalog(Catalog::ThermalT1));
    }
    Model::new(&k)
}

pub fn dh(v: f64) -> f64 {
    v * DEG_H_PER_RAD_S
}
