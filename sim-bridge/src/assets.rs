//! Finding and loading the Control Suite model files.
//!
//! The XMLs are not checked in: `scripts/setup-mujoco` extracts them from the `dm-control==1.0.50`
//! wheel into `.deps/dm_control/suite/`, which is found relative to this crate's source directory
//! (an environment variable overrides it, e.g. for an installed binary).
//!
//! The models are loaded through MuJoCo's virtual file system so that the skybox include can be
//! replaced by an empty model: the skybox is a 800x800 procedural texture that only rendering uses,
//! and generating it dominates loading (43 ms with it, 0.5 ms without, `benches/env_step.rs`). The
//! replay tests prove that the dynamics stay bit-identical to dm_control's (which loads it).

use std::path::PathBuf;

use mujoco_rs::prelude::MjModel;
use mujoco_rs::wrappers::mj_auxiliary::MjVfs;

use crate::error::SimError;

/// Overrides the directory that holds `cartpole.xml`, ..., `common/materials.xml`.
pub const SUITE_DIR_VAR: &str = "SIM_BRIDGE_SUITE_DIR";

/// The include files of the suite models, as the models name them.
const COMMON_FILES: [&str; 3] = ["materials.xml", "skybox.xml", "visual.xml"];

/// The directory with the Control Suite XMLs.
pub fn suite_dir() -> PathBuf {
    match std::env::var_os(SUITE_DIR_VAR) {
        Some(dir) if !dir.is_empty() => PathBuf::from(dir),
        _ => PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../.deps/dm_control/suite"),
    }
}

/// Reads `<suite>/<file>` or reports which file is missing and how to get it.
fn read(dir: &std::path::Path, file: &str) -> Result<Vec<u8>, SimError> {
    let path = dir.join(file);
    std::fs::read(&path).map_err(|_| SimError::MissingAssets { path })
}

/// Loads `<domain>.xml` with its `./common/*.xml` includes, the skybox replaced by an empty model.
pub fn load_model(domain: &str) -> Result<MjModel, SimError> {
    load(domain, false)
}

/// Loads `<domain>.xml` with every visual asset, the skybox included: the model a renderer
/// draws, as dm_control loads it. Its dynamics are the same as [`load_model`]'s.
pub fn load_visual_model(domain: &str) -> Result<MjModel, SimError> {
    load(domain, true)
}

fn load(domain: &str, skybox: bool) -> Result<MjModel, SimError> {
    crate::logging::install();
    let dir = suite_dir();
    let file = format!("{domain}.xml");
    let main = read(&dir, &file)?;
    let mut vfs = MjVfs::new();
    let vfs_err = |e: &dyn std::fmt::Display| SimError::ModelLoad {
        path: dir.join(&file),
        message: e.to_string(),
    };
    vfs.add_from_buffer(&file, &main).map_err(|e| vfs_err(&e))?;
    for common in COMMON_FILES {
        let rel = format!("common/{common}");
        let contents = if common == "skybox.xml" && !skybox {
            // Still required to exist, so a wrong directory is caught here, not silently used.
            read(&dir, &rel)?;
            b"<mujoco><asset/></mujoco>".to_vec()
        } else {
            read(&dir, &rel)?
        };
        vfs.add_from_buffer(&rel, &contents)
            .map_err(|e| vfs_err(&e))?;
    }
    MjModel::from_xml_vfs(&file, &vfs).map_err(|e| vfs_err(&e))
}
