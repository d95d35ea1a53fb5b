//! The fuzz binaries link mpo-host and sim-bridge, hence libmujoco.so: give them an rpath to
//! the repository's `.deps/mujoco` (cargo fuzz sets RUSTFLAGS, which replaces the rpath flags
//! of the workspace's `.cargo/config.toml`; a build script's link arguments reach only its own
//! package's binaries, which are the fuzz targets here).
fn main() {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../.deps/mujoco");
    let dir = dir.canonicalize().unwrap_or(dir);
    println!("cargo:rustc-link-arg=-Wl,-rpath,{}", dir.display());
    println!("cargo:rerun-if-changed=build.rs");
}
