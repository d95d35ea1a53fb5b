//! Opening a checkpoint for the commands that use its policy (`eval`, `render`, `run`,
//! `export`).

use std::path::Path;

use sim_bridge::TaskDef;

use super::error::Error;
use crate::checkpoint::{self, Verified};
use crate::policy::Policy;

/// [`checkpoint::open`], with a note on stderr when a crash (or a corrupt `checkpoint/`) made
/// it choose `checkpoint.tmp/` or `checkpoint.old/`.
pub(super) fn open_checkpoint(dir: &Path) -> Result<Verified, Error> {
    let v = checkpoint::open(dir)?;
    if let Some(note) = &v.fallback {
        eprintln!("note: {note}");
    }
    Ok(v)
}

/// A checkpoint's policy, with the task it was trained on (a task file must still hash as
/// it did).
pub(super) struct Trained {
    pub v: Verified,
    pub task: TaskDef,
    pub policy: Box<dyn Policy>,
}

/// Opens the checkpoint in `dir` and loads its online policy (the actor only).
pub(super) fn trained(dir: &Path) -> Result<Trained, Error> {
    let v = open_checkpoint(dir)?;
    let task = crate::rows::task_of_checkpoint(&v.meta, &v.dir)?;
    let instance = crate::registry::find(&v.meta.sizes)?;
    let policy = (instance.policy)(&v)?;
    Ok(Trained { v, task, policy })
}
