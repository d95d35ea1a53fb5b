//! Links as a static binary with no C runtime (x86_64 Linux) or with the board's memory map
//! (Arm; the linker script comes from mpo-rt), and copies the exported policy named by
//! `MPO_FIRMWARE_WEIGHTS` into the build so `src/main.rs` can include it.
use std::path::PathBuf;

fn main() {
    if std::env::var("CARGO_CFG_TARGET_ARCH").as_deref() == Ok("arm") {
        println!("cargo:rustc-link-arg-bins=-Tmps2-an386.ld");
    } else {
        for arg in ["-nostartfiles", "-nostdlib", "-static", "-Wl,--gc-sections"] {
            println!("cargo:rustc-link-arg-bins={arg}");
        }
    }
    println!("cargo:rerun-if-env-changed=MPO_FIRMWARE_WEIGHTS");
    let Some(src) = std::env::var_os("MPO_FIRMWARE_WEIGHTS") else {
        eprintln!(
            "error: set MPO_FIRMWARE_WEIGHTS to the policy source written by \
             `mpo export --checkpoint DIR --out DIR2` (DIR2/policy.rs)"
        );
        std::process::exit(1);
    };
    let src = PathBuf::from(src);
    println!("cargo:rerun-if-changed={}", src.display());
    let out = PathBuf::from(std::env::var_os("OUT_DIR").unwrap()).join("policy.rs");
    if let Err(e) = std::fs::copy(&src, &out) {
        eprintln!(
            "error: cannot read MPO_FIRMWARE_WEIGHTS={}: {e}",
            src.display()
        );
        std::process::exit(1);
    }
}
