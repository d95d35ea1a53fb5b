//! The `sim-bridge` launcher: checks that libmujoco loads, then execs `sim-bridge-engine`.
//!
//! A binary that links libmujoco dynamically cannot report a missing library itself: the dynamic
//! loader exits with status 127 before `main`. The launcher links no MuJoCo symbol, so it always
//! starts; it `dlopen`s the library with the same search path the engine will use (its own
//! RUNPATH, which is the engine's since both sit in the same directory and are built with the same
//! flags, plus LD_LIBRARY_PATH), and only then replaces itself with the engine.

use std::ffi::{CStr, CString, OsString};
use std::path::PathBuf;

use crate::error::SimError;

/// The soname the engine's DT_NEEDED names.
pub const LIBRARY: &str = "libmujoco.so.3.17.0";
/// The engine binary, expected next to the launcher.
pub const ENGINE: &str = "sim-bridge-engine";
/// Set by the launcher for the engine, which checks it against its own build id.
pub const BUILD_ID_VAR: &str = "SIM_BRIDGE_LAUNCHER_BUILD_ID";
/// A hash of this crate's sources (see `build.rs`).
pub const BUILD_ID: &str = env!("SIM_BRIDGE_BUILD_ID");

/// Loads and unloads libmujoco the way the engine's loader would find it.
pub fn check_library() -> Result<(), SimError> {
    let name = CString::new(LIBRARY).expect("no NUL in the library name");
    // SAFETY: `name` is a valid C string; the handle is closed right away; loading runs
    // libmujoco's initialisers, which have no effect on this process beyond that.
    unsafe {
        let handle = libc::dlopen(name.as_ptr(), libc::RTLD_LAZY | libc::RTLD_LOCAL);
        if handle.is_null() {
            let err = libc::dlerror();
            let detail = if err.is_null() {
                format!("{LIBRARY} not found")
            } else {
                CStr::from_ptr(err).to_string_lossy().into_owned()
            };
            return Err(SimError::MissingLibrary { detail });
        }
        libc::dlclose(handle);
    }
    Ok(())
}

/// The engine path next to the running launcher.
pub fn engine_path() -> Result<PathBuf, String> {
    let exe =
        std::env::current_exe().map_err(|e| format!("cannot locate the sim-bridge binary: {e}"))?;
    let path = exe.with_file_name(ENGINE);
    if path.is_file() {
        Ok(path)
    } else {
        Err(format!(
            "{} is missing (it is built with the launcher: run `cargo build -p sim-bridge --bins`)",
            path.display()
        ))
    }
}

/// Checks, then execs the engine with the launcher's arguments; returns only on failure.
pub fn launch(args: Vec<OsString>) -> String {
    use std::os::unix::process::CommandExt;
    if let Err(e) = check_library() {
        return e.to_string();
    }
    let engine = match engine_path() {
        Ok(path) => path,
        Err(message) => return message,
    };
    let err = std::process::Command::new(&engine)
        .args(args)
        .env(BUILD_ID_VAR, BUILD_ID)
        .exec();
    format!("cannot run {}: {err}", engine.display())
}

/// In the engine: an error when the launcher that started it was built from other sources.
pub fn check_engine_matches_launcher() -> Result<(), String> {
    match std::env::var(BUILD_ID_VAR) {
        Ok(id) if id != BUILD_ID => Err(format!(
            "{ENGINE} was built from different sources than the sim-bridge launcher; rebuild both \
             with `cargo build -p sim-bridge --bins`"
        )),
        _ => Ok(()),
    }
}
