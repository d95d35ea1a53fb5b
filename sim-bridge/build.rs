//! Stamps the crate with a hash of its sources, so the `sim-bridge` launcher can refuse to exec a
//! `sim-bridge-engine` binary built from different sources (e.g. after `cargo run --bin
//! sim-bridge`, which rebuilds only the launcher).

use std::hash::{DefaultHasher, Hash, Hasher};
use std::path::Path;

fn hash_dir(dir: &Path, hasher: &mut DefaultHasher) {
    let mut entries: Vec<_> = std::fs::read_dir(dir)
        .map(|d| d.flatten().map(|e| e.path()).collect())
        .unwrap_or_default();
    entries.sort();
    for path in entries {
        if path.is_dir() {
            hash_dir(&path, hasher);
        } else {
            println!("cargo::rerun-if-changed={}", path.display());
            path.file_name().hash(hasher);
            std::fs::read(&path).unwrap_or_default().hash(hasher);
        }
    }
}

fn main() {
    let mut hasher = DefaultHasher::new();
    hash_dir(Path::new("src"), &mut hasher);
    std::fs::read("Cargo.toml")
        .unwrap_or_default()
        .hash(&mut hasher);
    println!("cargo::rerun-if-changed=Cargo.toml");
    println!("cargo::rerun-if-changed=src");
    println!(
        "cargo::rustc-env=SIM_BRIDGE_BUILD_ID={:016x}",
        hasher.finish()
    );
}
