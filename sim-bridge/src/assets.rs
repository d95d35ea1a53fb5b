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

use crate::error::{SUITE_DIR_VAR, SimError};

/// The include files of the suite models, as the models name them.
const COMMON_FILES: [&str; 3] = ["materials.xml", "skybox.xml", "visual.xml"];

/// The directory with the Control Suite XMLs.
pub fn suite_dir() -> PathBuf {
    match std::env::var_os(SUITE_DIR_VAR) {
        Some(dir) if !dir.is_empty() => PathBuf::from(dir),
        _ => PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../.deps/dm_control/suite"),
    }
}

/// Overrides the directory that holds Gymnasium's MuJoCo models (`half_cheetah.xml`, ...).
pub const GYMNASIUM_DIR_VAR: &str = "SIM_BRIDGE_GYMNASIUM_DIR";

/// The directory with Gymnasium's MuJoCo XMLs (`scripts/setup-gymnasium` extracts them from
/// the `gymnasium` wheel).
pub fn gymnasium_dir() -> PathBuf {
    match std::env::var_os(GYMNASIUM_DIR_VAR) {
        Some(dir) if !dir.is_empty() => PathBuf::from(dir),
        _ => PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../.deps/gymnasium/assets"),
    }
}

/// Loads an MJCF file from disk (its includes and assets resolved by MuJoCo, relative to it).
pub fn load_model_file(path: &std::path::Path) -> Result<MjModel, SimError> {
    crate::logging::install();
    if !path.is_file() {
        return Err(SimError::MissingAssets {
            path: path.to_path_buf(),
        });
    }
    MjModel::from_xml(path).map_err(|e| SimError::ModelLoad {
        path: path.to_path_buf(),
        message: e.to_string(),
    })
}

/// The files a model is made of, relative to `dir`: `main`, then every file named by a
/// `file="..."` attribute (includes, read recursively, meshes, textures, height fields),
/// resolved against `dir` and the `<compiler>` asset folders, in the order found, each once.
/// Files that do not exist are left out (MuJoCo reports them when it loads the model).
pub fn model_files(dir: &std::path::Path, main: &str) -> Result<Vec<String>, String> {
    let mut out: Vec<String> = vec![main.to_string()];
    let mut i = 0;
    while i < out.len() {
        let path = dir.join(&out[i]);
        i += 1;
        if path.extension().and_then(|e| e.to_str()) != Some("xml") {
            continue;
        }
        let text =
            std::fs::read_to_string(&path).map_err(|e| format!("{}: {e}", path.display()))?;
        let folders: Vec<String> = ["meshdir", "texturedir", "assetdir"]
            .iter()
            .filter_map(|a| attribute_values(&text, a).into_iter().next())
            .collect();
        for f in attribute_values(&text, "file") {
            let candidates =
                std::iter::once(f.clone()).chain(folders.iter().map(|d| format!("{d}/{f}")));
            for c in candidates {
                if dir.join(&c).is_file() && !out.contains(&c) {
                    out.push(c);
                    break;
                }
            }
            if out.len() > 10_000 {
                return Err("more than 10000 model files".into());
            }
        }
    }
    Ok(out)
}

/// Every value of `name="..."` (or `'...'`) in an XML text.
fn attribute_values(text: &str, name: &str) -> Vec<String> {
    let mut out = Vec::new();
    let mut rest = text;
    while let Some(at) = rest.find(name) {
        let before = rest[..at].chars().next_back();
        rest = &rest[at + name.len()..];
        if before.is_some_and(|c| c.is_alphanumeric() || c == '_') {
            continue;
        }
        let t = rest.trim_start();
        let Some(t) = t.strip_prefix('=') else {
            continue;
        };
        let t = t.trim_start();
        let Some(q) = t.chars().next().filter(|c| *c == '"' || *c == '\'') else {
            continue;
        };
        if let Some(end) = t[1..].find(q) {
            out.push(t[1..1 + end].to_string());
        }
    }
    out
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

/// [`load_model`] of a suite file named with its extension (`cartpole.xml`).
pub fn load_suite_file(file: &str) -> Result<MjModel, SimError> {
    load(file.strip_suffix(".xml").unwrap_or(file), false)
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
