//! What a training run writes into its directory: `config.toml` at the start, the metrics
//! (`metrics.csv`, `metrics.jsonl`) and `curve.png` after every evaluation, the checkpoint
//! after every evaluation and on Ctrl-C. Each file is replaced whole and durably
//! ([`crate::durable`]); a curve that cannot be drawn is a warning, not an error.

use std::path::{Path, PathBuf};

use sim_bridge::TaskDef;

use crate::checkpoint::{Meta, TaskFileRecord};
use crate::metrics::{self, MetricsRow};
use crate::progress::Progress;
use crate::settings::Settings;
use crate::sizes::Sizes;
use crate::training::{TrainError, Training};

/// A run directory being written.
pub struct Outputs {
    dir: PathBuf,
    settings: Settings,
    task_file: Option<TaskFileRecord>,
    sizes: Sizes,
    title: String,
}

fn io_err(path: &Path) -> impl FnOnce(std::io::Error) -> TrainError + '_ {
    move |source| TrainError::Io {
        path: path.to_path_buf(),
        source,
    }
}

impl Outputs {
    /// Creates the run directory and writes its `config.toml`.
    pub fn create(
        dir: &Path,
        settings: &Settings,
        task: &TaskDef,
        sizes: Sizes,
    ) -> Result<Self, TrainError> {
        std::fs::create_dir_all(dir).map_err(io_err(dir))?;
        let cfg = dir.join("config.toml");
        let text = settings.config_toml(&sizes);
        crate::durable::write_atomic(&cfg, text.as_bytes()).map_err(io_err(&cfg))?;
        Ok(Self {
            dir: dir.to_path_buf(),
            settings: settings.clone(),
            task_file: crate::rows::task_record(task),
            sizes,
            title: format!("MPO {} (seed {})", settings.task, settings.seed),
        })
    }

    /// Rewrites the metrics files and the learning curve from every row so far.
    pub fn metrics(&self, rows: &[MetricsRow], progress: &Progress) -> Result<(), TrainError> {
        metrics::write_all(&self.dir, rows).map_err(io_err(&self.dir))?;
        if let Err(e) = crate::plot::write_curve(&self.dir.join("curve.png"), &self.title, rows) {
            progress.log(&format!("warning: curve.png not written: {e}"));
        }
        Ok(())
    }

    /// Writes the checkpoint of `t`'s present state with the metrics so far.
    pub fn checkpoint(
        &self,
        t: &dyn Training,
        rows: &[MetricsRow],
        wall_s: f64,
    ) -> Result<(), TrainError> {
        let base = Meta::new(
            self.settings.clone(),
            self.task_file.clone(),
            self.sizes,
            rows.to_vec(),
            wall_s,
        );
        t.save(&self.dir, &t.meta(base))
    }
}
