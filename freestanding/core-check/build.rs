//! Link arguments for the binary only, never a build script: on x86_64 Linux a static binary
//! with our own `_start` and no C runtime or libc; on Arm the board's memory map (the linker
//! script comes from mpo-rt).
fn main() {
    if std::env::var("CARGO_CFG_TARGET_ARCH").as_deref() == Ok("arm") {
        println!("cargo:rustc-link-arg-bins=-Tmps2-an386.ld");
        return;
    }
    for arg in ["-nostartfiles", "-nostdlib", "-static", "-Wl,--gc-sections"] {
        println!("cargo:rustc-link-arg-bins={arg}");
    }
}
