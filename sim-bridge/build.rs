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
    builtin_tasks(&mut hasher);
    println!(
        "cargo::rustc-env=SIM_BRIDGE_BUILD_ID={:016x}",
        hasher.finish()
    );
}

/// `$OUT_DIR/builtin_tasks.rs`: every `tasks/*.toml` of the repository, compiled in (the name
/// is the file's stem), so a task file dropped into `tasks/` is built in with no code change.
/// Subfolders are not read: `tasks/gymnasium/` holds task files loaded from disk like a user's.
fn builtin_tasks(hasher: &mut DefaultHasher) {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../tasks");
    println!("cargo::rerun-if-changed={}", dir.display());
    let mut files: Vec<_> = std::fs::read_dir(&dir)
        .map(|d| d.flatten().map(|e| e.path()).collect())
        .unwrap_or_default();
    files.retain(|p: &std::path::PathBuf| p.extension().is_some_and(|e| e == "toml"));
    files.sort();
    let mut names = String::new();
    let mut table = String::new();
    for p in &files {
        println!("cargo::rerun-if-changed={}", p.display());
        let stem = p.file_stem().unwrap().to_string_lossy().to_string();
        std::fs::read(p).unwrap_or_default().hash(hasher);
        names.push_str(&format!("    {stem:?},\n"));
        table.push_str(&format!(
            "    ({stem:?}, include_str!({:?})),\n",
            p.canonicalize().unwrap().display().to_string()
        ));
    }
    let code = format!(
        "/// The built-in tasks' names, in file-name order.\npub const BUILTIN_NAMES: &[&str] = &[\n{names}];\n\n/// `(name, text)` of each built-in task file.\nstatic BUILTIN: &[(&str, &str)] = &[\n{table}];\n"
    );
    let out = Path::new(&std::env::var("OUT_DIR").unwrap()).join("builtin_tasks.rs");
    std::fs::write(out, code).unwrap();
}
