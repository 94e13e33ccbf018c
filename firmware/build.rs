//! Link scripts for the firmware binaries only (cortex-m-rt's link.x with the repository's
//! top-level memory.x, and defmt's), so nested board packages keep their own.
//!
//! The flight firmwares (`ssis-fw`, `ssis-fw-lv`) are also linked with `link/flight-budget.x`,
//! which fails the link when an image outgrows the MPU's 128 KiB read-only region.
//!
//! The launch-vehicle firmware (`ssis-fw-lv`, and the binaries tested in its layout:
//! `ssis-fw-lv-test`, `ssis-navbench`, `ssis-stackcheck-lv`) has a memory budget of its own,
//! `link/memory-lv.x`. cortex-m-rt's link.x includes `memory.x`, which the linker looks
//! for in the working directory (this one) before the search path, so that binary is
//! linked with a copy of link.x that includes `memory-lv.x` instead (written to OUT_DIR
//! from cortex-m-rt's generated script; cortex-m-rt has a `links` key, so its build
//! script has run before this one).
use std::path::{Path, PathBuf};

fn main() {
    let dir = std::env::var("CARGO_MANIFEST_DIR").unwrap_or_default();
    // memory.x (the spacecraft unit's layout, shared by the QEMU firmwares) stays at the
    // repository's top level, beside the workspace's Cargo.toml.
    let top = Path::new(&dir).parent().map(|p| p.display().to_string()).unwrap_or_default();
    println!("cargo:rustc-link-search={top}");
    println!("cargo:rerun-if-changed=../memory.x");
    println!("cargo:rerun-if-changed=link/memory-lv.x");
    println!("cargo:rerun-if-changed=link/flight-budget.x");
    println!("cargo:rerun-if-changed=build.rs");
    if std::env::var("CARGO_CFG_TARGET_OS").as_deref() == Ok("none") {
        for bin in ["ssis-fw", "ssis-fw-test", "ssis-selftest", "ssis-stackcheck"] {
            println!("cargo:rustc-link-arg-bin={bin}=-Tlink.x");
        }
        // The flight image within the MPU's read-only 128 KiB (link/flight-budget.x).
        println!("cargo:rustc-link-arg-bin=ssis-fw=-L{dir}/link");
        println!("cargo:rustc-link-arg-bin=ssis-fw=-Tflight-budget.x");
        println!("cargo:rustc-link-arg-bin=ssis-fw-lv=-L{dir}/link");
        println!("cargo:rustc-link-arg-bin=ssis-fw-lv=-Tflight-budget.x");
        match lv_link_script(Path::new(&dir)) {
            Ok(lv_dir) => {
                // The navigation benchmark is launch-vehicle code: the LV budget (its
                // GNSS update needs more stack than the spacecraft's 28 KiB region).
                for bin in ["ssis-fw-lv", "ssis-fw-lv-test", "ssis-navbench", "ssis-stackcheck-lv"] {
                    println!("cargo:rustc-link-arg-bin={bin}=-L{}", lv_dir.display());
                    println!("cargo:rustc-link-arg-bin={bin}=-Tlink-lv.x");
                }
            }
            Err(e) => println!("cargo:warning=ssis-fw-lv cannot be linked: {e}"),
        }
        println!("cargo:rustc-link-arg-bins=-Tdefmt.x");
    }
}

/// Writes `link-lv.x` (cortex-m-rt's link.x including `memory-lv.x`) and `memory-lv.x`
/// into a directory of OUT_DIR and returns it.
fn lv_link_script(manifest_dir: &Path) -> Result<PathBuf, String> {
    let out = PathBuf::from(std::env::var_os("OUT_DIR").ok_or("OUT_DIR is not set")?);
    // OUT_DIR is <target>/build/ssis-firmware-<hash>/out; cortex-m-rt's is a sibling build dir.
    let build = out.parent().and_then(Path::parent).ok_or("OUT_DIR has no build directory")?;
    let newest = std::fs::read_dir(build)
        .map_err(|e| format!("{}: {e}", build.display()))?
        .filter_map(Result::ok)
        .filter(|d| d.file_name().to_string_lossy().starts_with("cortex-m-rt-"))
        .map(|d| d.path().join("out/link.x"))
        .filter_map(|p| Some((std::fs::metadata(&p).ok()?.modified().ok()?, p)))
        .max()
        .map(|(_, p)| p)
        .ok_or("cortex-m-rt's link.x not found beside OUT_DIR")?;
    let link = std::fs::read_to_string(&newest).map_err(|e| format!("{}: {e}", newest.display()))?;
    if !link.contains("INCLUDE memory.x") {
        return Err(format!("{} does not include memory.x", newest.display()));
    }
    let lv = out.join("lv");
    std::fs::create_dir_all(&lv).map_err(|e| e.to_string())?;
    std::fs::write(lv.join("link-lv.x"), link.replace("INCLUDE memory.x", "INCLUDE memory-lv.x"))
        .map_err(|e| e.to_string())?;
    std::fs::copy(manifest_dir.join("link/memory-lv.x"), lv.join("memory-lv.x")).map_err(|e| e.to_string())?;
    println!("cargo:rerun-if-changed={}", newest.display());
    Ok(lv)
}
