//! One metrics row per evaluation, written as `metrics.csv` and `metrics.jsonl`.
//!
//! Learner statistics in a row are means over the updates since the previous row (a single
//! update's values are too noisy to read); the accumulator is part of the checkpoint, so a
//! resumed run writes the same rows as an uninterrupted one (except the wall-clock columns).

use std::path::Path;

use mpo_core::learner::UpdateStats;
use serde::{Deserialize, Serialize};

/// Names of the learner statistics, in column order: the core's one list of them, so a name
/// always labels its own field's value.
pub const STAT_NAMES: [&str; UpdateStats::COUNT] = UpdateStats::NAMES;

/// The statistics as numbers in [`STAT_NAMES`] order.
pub fn stat_values(s: &UpdateStats) -> [f64; UpdateStats::COUNT] {
    s.values()
}

/// The first non-finite statistic, if any.
pub fn first_non_finite(s: &UpdateStats) -> Option<(&'static str, f64)> {
    STAT_NAMES
        .iter()
        .zip(stat_values(s))
        .find(|(_, v)| !v.is_finite())
        .map(|(n, v)| (*n, v))
}

/// Running sums of the statistics since the last row.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct StatsAccumulator {
    /// Sums in [`STAT_NAMES`] order.
    pub sums: Vec<f64>,
    /// Updates summed.
    pub count: u64,
}

impl StatsAccumulator {
    /// Adds one update's statistics (no allocation once the sums exist).
    pub fn add(&mut self, s: &UpdateStats) {
        if self.sums.len() != STAT_NAMES.len() {
            self.sums = vec![0.0; STAT_NAMES.len()];
        }
        for (acc, v) in self.sums.iter_mut().zip(stat_values(s)) {
            *acc += v;
        }
        self.count += 1;
    }

    /// The means (NaN before the first update) and a reset.
    pub fn take_means(&mut self) -> Vec<f64> {
        let out = if self.count == 0 {
            vec![f64::NAN; STAT_NAMES.len()]
        } else {
            self.sums.iter().map(|s| s / self.count as f64).collect()
        };
        self.sums.iter_mut().for_each(|s| *s = 0.0);
        self.count = 0;
        out
    }
}

/// One evaluation.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct MetricsRow {
    /// Environment steps so far.
    pub env_steps: u64,
    /// Learner updates so far.
    pub updates: u64,
    /// Training episodes completed.
    pub episodes: u64,
    /// Wall-clock seconds of training so far (summed over resumed segments).
    pub wall_s: f64,
    /// Mean evaluation return (mean action).
    pub eval_return_mean: f64,
    /// Standard deviation of the evaluation returns (population).
    pub eval_return_std: f64,
    /// Environment steps per second since the previous row.
    pub env_steps_per_s: f64,
    /// Updates per second since the previous row.
    pub updates_per_s: f64,
    /// Mean learner statistics since the previous row, in [`STAT_NAMES`] order (NaN, written
    /// as `null`/empty, before learning starts).
    pub stats: Vec<Option<f64>>,
    /// How far the online policy's and critic's hidden weights have grown since
    /// initialisation, `[actor, critic]` ([`crate::weight_growth`]); `None` in the rows of runs
    /// made before it was logged (an empty cell).
    #[serde(default)]
    pub weight_growth: Option<[f64; 2]>,
    /// The online policy's and critic's dormant ReLU units in percent, `[actor, critic]`
    /// ([`crate::dormant`]); `None` before it was logged or while the buffer was empty.
    #[serde(default)]
    pub dormant: Option<[f64; 2]>,
}

/// The columns of `metrics.csv` after the learner statistics: [`MetricsRow::weight_growth`].
const GROWTH_COLUMNS: [&str; 2] = ["actor_weight_growth", "critic_weight_growth"];

/// The columns after those: [`MetricsRow::dormant`].
const DORMANT_COLUMNS: [&str; 2] = ["actor_dormant", "critic_dormant"];

/// The columns of `metrics.csv` before the learner statistics.
const COLUMNS: [&str; 8] = [
    "env_steps",
    "updates",
    "episodes",
    "wall_s",
    "eval_return_mean",
    "eval_return_std",
    "env_steps_per_s",
    "updates_per_s",
];

/// Writes `metrics.csv` and `metrics.jsonl` in `dir` from all rows (rewritten whole, so a
/// resumed run never leaves rows of an abandoned future behind).
pub fn write_all(dir: &Path, rows: &[MetricsRow]) -> std::io::Result<()> {
    let mut csv = csv::Writer::from_writer(Vec::new());
    csv.write_record(
        COLUMNS
            .iter()
            .chain(STAT_NAMES.iter())
            .chain(GROWTH_COLUMNS.iter())
            .chain(DORMANT_COLUMNS.iter()),
    )?;
    let mut jsonl = String::new();
    for r in rows {
        let mut record = vec![
            r.env_steps.to_string(),
            r.updates.to_string(),
            r.episodes.to_string(),
            format!("{:.3}", r.wall_s),
            r.eval_return_mean.to_string(),
            r.eval_return_std.to_string(),
            format!("{:.1}", r.env_steps_per_s),
            format!("{:.1}", r.updates_per_s),
        ];
        // A statistic not recorded yet (before learning starts) is an empty cell.
        record.extend(
            r.stats
                .iter()
                .map(|v| v.map(|x| x.to_string()).unwrap_or_default()),
        );
        for pair in [r.weight_growth, r.dormant] {
            record.extend((0..2).map(|i| pair.map(|g| g[i].to_string()).unwrap_or_default()));
        }
        csv.write_record(&record)?;
        let mut obj = serde_json::Map::new();
        obj.insert("env_steps".into(), r.env_steps.into());
        obj.insert("updates".into(), r.updates.into());
        obj.insert("episodes".into(), r.episodes.into());
        obj.insert("wall_s".into(), r.wall_s.into());
        obj.insert("eval_return_mean".into(), r.eval_return_mean.into());
        obj.insert("eval_return_std".into(), r.eval_return_std.into());
        obj.insert("env_steps_per_s".into(), r.env_steps_per_s.into());
        obj.insert("updates_per_s".into(), r.updates_per_s.into());
        for (n, v) in STAT_NAMES.iter().zip(&r.stats) {
            obj.insert((*n).into(), (*v).into());
        }
        for (names, pair) in [
            (GROWTH_COLUMNS, r.weight_growth),
            (DORMANT_COLUMNS, r.dormant),
        ] {
            for (i, n) in names.iter().enumerate() {
                obj.insert((*n).into(), pair.map(|g| g[i]).into());
            }
        }
        jsonl.push_str(&serde_json::Value::Object(obj).to_string());
        jsonl.push('\n');
    }
    let csv = csv.into_inner().map_err(|e| e.into_error())?;
    crate::durable::write_atomic(&dir.join("metrics.csv"), &csv)?;
    crate::durable::write_atomic(&dir.join("metrics.jsonl"), jsonl.as_bytes())
}
