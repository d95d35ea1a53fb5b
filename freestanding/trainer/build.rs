//! Link as a static binary with our own `_start` and no C runtime or libc; only the binary
//! gets these arguments, never a build script.
fn main() {
    for arg in ["-nostartfiles", "-nostdlib", "-static", "-Wl,--gc-sections"] {
        println!("cargo:rustc-link-arg-bins={arg}");
    }
}
