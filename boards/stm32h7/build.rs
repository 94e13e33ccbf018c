//! Puts `memory.x` on the linker search path and adds the cortex-m-rt (`link.x`) and defmt
//! (`defmt.x`) linker scripts, unless the rustflags in force already pass them.
//!
//! Why not in `.cargo/config.toml`: cargo also reads the repository root's
//! `.cargo/config.toml` (every parent directory's config applies) and *joins* rustflags
//! lists, so today the root's `-Tlink.x -Tdefmt.x` reach this build too, and passing them
//! twice fails the link ("region 'FLASH' already defined"). Adding them here only when
//! missing works both with the root's flags and without them.
#![deny(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use std::{env, error::Error, fs, path::PathBuf};

fn main() -> Result<(), Box<dyn Error>> {
    let out = PathBuf::from(env::var_os("OUT_DIR").ok_or("OUT_DIR is not set")?);
    fs::write(out.join("memory.x"), include_bytes!("memory.x"))?;
    println!("cargo:rustc-link-search={}", out.display());
    println!("cargo:rerun-if-changed=memory.x");
    println!("cargo:rerun-if-changed=build.rs");

    let flags = env::var("CARGO_ENCODED_RUSTFLAGS").unwrap_or_default();
    for script in ["-Tlink.x", "-Tdefmt.x"] {
        let passed = flags.split('\x1f').any(|f| f == script || f.ends_with(&format!("link-arg={script}")));
        if !passed {
            println!("cargo:rustc-link-arg-bins={script}");
        }
    }
    Ok(())
}
