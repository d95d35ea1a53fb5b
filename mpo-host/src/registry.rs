//! Which learner instantiations this build has: the built-in rows' ([`crate::table`]), those
//! `mpo-host/sizes/local.toml` asks for (read by the build script: `mpo train --task-file`
//! adds a task file's sizes there when the build lacks them, and `./mpo` rebuilds, see
//! [`MissingInstance`]), and any a Rust program registers through [`crate::main_with`].

use std::path::PathBuf;
use std::sync::OnceLock;

use crate::sizes::Sizes;
use crate::spec::Instance;

// The instantiations `sizes/local.toml` asks for (`build.rs` writes one `spec!` line each and
// `LOCAL`, the list of their instances).
include!(concat!(env!("OUT_DIR"), "/local_specs.rs"));

static EXTRA: OnceLock<Vec<Instance>> = OnceLock::new();

/// Adds a program's own instantiations (see [`crate::main_with`]); the first call wins.
pub fn register(extra: Vec<Instance>) {
    let _ = EXTRA.set(extra);
}

/// Every instantiation of this build: the built-in rows', `sizes/local.toml`'s, then those
/// registered by the program.
pub fn instances() -> Vec<Instance> {
    let mut all = crate::table::instances();
    all.extend(LOCAL.iter().map(|f| f()));
    all.extend(EXTRA.get().into_iter().flatten().copied());
    all
}

/// The instantiation of `sizes`, or why there is none.
pub fn find(sizes: &Sizes) -> Result<Instance, MissingInstance> {
    instances()
        .into_iter()
        .find(|i| i.sizes == *sizes)
        .ok_or_else(|| MissingInstance {
            sizes: Box::new(*sizes),
            file: local_sizes_file(),
        })
}

/// Where `mpo` asks for new instantiations: `mpo-host/sizes/local.toml` of the source tree
/// this binary was built from (not tracked by git: a user's own sizes), or the file the
/// environment variable `MPO_LOCAL_SIZES` names (the tests' scratch copy).
pub fn local_sizes_file() -> PathBuf {
    match std::env::var_os("MPO_LOCAL_SIZES") {
        Some(p) => PathBuf::from(p),
        None => PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("sizes/local.toml"),
    }
}

/// Exit status of `mpo` when a command needs a learner this build does not have: `./mpo`
/// then rebuilds and runs the command again.
pub const EXIT_REBUILD: u8 = 3;

/// A task's sizes without an instantiation in this build.
#[derive(Debug, thiserror::Error)]
#[error(
    "this build has no learner of sizes {} (sizes are compile-time types); {}",
    .sizes.describe(),
    match .file.parent().is_some_and(|d| d.is_dir()) {
        true => format!("add them to {} and rebuild (`./mpo` does both by itself)", .file.display()),
        false => "declare them with mpo_host::spec! in your program and pass them to mpo_host::main_with".to_string(),
    }
)]
pub struct MissingInstance {
    /// The sizes asked for (boxed: errors stay small).
    pub sizes: Box<Sizes>,
    /// The file the build script reads.
    pub file: PathBuf,
}

impl MissingInstance {
    /// Appends the sizes to [`local_sizes_file`] (once), so the next build has them. Returns
    /// false when the source tree is not there (an installed binary).
    pub fn request(&self) -> std::io::Result<bool> {
        if !self.file.parent().is_some_and(|d| d.is_dir()) {
            return Ok(false);
        }
        let path = &self.file;
        let mut text = std::fs::read_to_string(path).unwrap_or_default();
        let line = self.sizes.toml_line();
        if text.contains(&line) {
            return Ok(true);
        }
        if text.is_empty() {
            text.push_str(LOCAL_HEADER);
        }
        // One `[[spec]]` table per instantiation, read by build.rs.
        text.push_str(&format!("\n[[spec]]\nsizes = {line}\n"));
        crate::durable::write_atomic(path, text.as_bytes())?;
        Ok(true)
    }
}

/// The head of a new `sizes/local.toml`.
const LOCAL_HEADER: &str =
    "# Learner instantiations this source tree builds beside the built-in rows' (read by
# mpo-host/build.rs). `mpo train --task-file` appends a task file's sizes when the build has
# no learner of them; `./mpo` then rebuilds. Not tracked by git: your own robots' sizes.
";

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_builtin_row_has_an_instance_of_its_sizes() {
        for row in crate::table::rows() {
            let i = find(&row.sizes).unwrap_or_else(|e| panic!("{}/{}: {e}", row.task, row.net));
            assert_eq!(i.sizes, row.sizes);
        }
    }

    #[test]
    fn sizes_check_names_the_field_out_of_range() {
        let mut s = crate::table::rows()[0].sizes;
        assert!(s.check().is_ok());
        s.act = 65;
        assert!(s.check().unwrap_err().starts_with("act = 65"), "{s:?}");
        s.act = 1;
        s.chunks = 3;
        assert!(s.check().unwrap_err().contains("multiple of chunks"));
        s.chunks = 1;
        s.m = 0;
        assert!(s.check().unwrap_err().starts_with("m = 0"));
    }

    #[test]
    fn a_missing_instance_is_requested_once_in_the_local_file() {
        let dir = std::env::temp_dir().join(format!("mpo-spec-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let mut sizes = crate::table::rows()[0].sizes;
        sizes.obs = 4095;
        let m = MissingInstance {
            sizes: Box::new(sizes),
            file: dir.join("local.toml"),
        };
        assert!(m.request().unwrap());
        assert!(m.request().unwrap());
        let text = std::fs::read_to_string(dir.join("local.toml")).unwrap();
        assert_eq!(text.matches("obs = 4095").count(), 1, "{text}");
        let parsed: toml::Table = text.parse().unwrap();
        assert_eq!(parsed["spec"].as_array().unwrap().len(), 1);
        let _ = std::fs::remove_dir_all(&dir);
        let gone = MissingInstance {
            sizes: Box::new(sizes),
            file: dir.join("nowhere/local.toml"),
        };
        assert!(!gone.request().unwrap());
        assert!(gone.to_string().contains("mpo_host::spec!"), "{gone}");
    }
}
