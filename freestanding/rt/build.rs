//! On Arm, puts the board's linker script (`mps2-an386.ld`) on the linker's search path of every
//! binary that depends on this crate; the binary names it with `-T` (its own build script).
fn main() {
    println!("cargo:rerun-if-changed=mps2-an386.ld");
    if std::env::var("CARGO_CFG_TARGET_ARCH").as_deref() == Ok("arm") {
        let out = std::path::PathBuf::from(std::env::var_os("OUT_DIR").unwrap());
        std::fs::copy("mps2-an386.ld", out.join("mps2-an386.ld")).unwrap();
        println!("cargo:rustc-link-search={}", out.display());
    }
}
