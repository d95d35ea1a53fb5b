//! `mpo export`.

use std::path::PathBuf;

use serde::Serialize;

use super::error::Error;
use crate::cli::ExportArgs;

/// What `mpo export` wrote.
#[derive(Debug, Serialize)]
pub struct ExportSummary {
    /// Task of the checkpoint.
    pub task: String,
    /// Environment steps of the checkpoint.
    pub checkpoint_env_steps: u64,
    /// The written Rust source.
    pub policy: PathBuf,
    /// Observation size.
    pub obs: usize,
    /// Action size.
    pub act: usize,
    /// Hidden widths.
    pub hidden: [usize; 2],
    /// Residual blocks of the actor (0: the two-layer MLP, `hidden` its widths; otherwise
    /// `hidden` is the width and the blocks' inner width).
    pub blocks: usize,
    /// Scalar parameters of the actor (what the firmware keeps in flash, 4 bytes each).
    pub parameters: usize,
}

/// `mpo export`: the checkpoint's online policy as Rust source for the firmware.
pub fn export(args: &ExportArgs) -> Result<ExportSummary, Error> {
    let t = super::trained::trained(&args.checkpoint)?;
    let m = &t.v.meta;
    let origin = format!(
        "checkpoint {} ({} at {} environment steps, params_sha256 {})",
        t.v.dir.display(),
        m.settings.task,
        m.env_steps,
        m.params_sha256
    );
    let src = t.policy.firmware_source(&origin);
    let io = |e: std::io::Error| Error::Io {
        path: args.out.clone(),
        source: e,
    };
    std::fs::create_dir_all(&args.out).map_err(io)?;
    let policy = args.out.join("policy.rs");
    std::fs::write(&policy, src).map_err(io)?;
    Ok(ExportSummary {
        task: m.settings.task.clone(),
        checkpoint_env_steps: m.env_steps,
        policy,
        obs: t.policy.obs_dim(),
        act: t.policy.act_dim(),
        hidden: t.policy.hidden(),
        blocks: t.policy.blocks(),
        parameters: t.policy.parameters(),
    })
}
