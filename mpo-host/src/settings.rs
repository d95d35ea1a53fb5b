//! The resolved configuration of a run: task-table defaults, then a `--config` TOML file, then
//! flags, each layer overriding single keys of the one below.
//!
//! Layers are merged as TOML tables before anything is deserialised, so a file or a `--set`
//! flag may name any subset of keys, an unknown key is an error (a typo never silently
//! falls back to a default), and a resumed run can be compared key by key with its
//! checkpoint. Learner hyperparameters are kept as `f64` here so `config.toml` shows the
//! values as written (`3e-4`, not `0.0003000000142492354`); they become the learner's `f32`
//! by one rounding, identically for fresh and resumed runs.

use mpo_core::config::MpoConfig;
use mpo_core::replay::MAX_NSTEP;
use serde::{Deserialize, Serialize};

use crate::sizes::Sizes;

/// Everything that determines a run (with the task table's sizes, everything that
/// determines its bits).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Settings {
    /// The task's name: a built-in task (`mpo tasks`), e.g. `cartpole-balance`, or the name of
    /// the task file below.
    pub task: String,
    /// A task file (absolute path) to train on instead of a built-in task; `task` is its name.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub task_file: Option<std::path::PathBuf>,
    /// Network variant of the task's table row (`default`, or `tiny` for fast tests).
    pub net: String,
    /// Seed of the networks, the collector and the training environment.
    pub seed: u32,
    /// Total environment steps (a multiple of the episode length).
    pub steps: u64,
    /// When to act, learn, evaluate.
    pub schedule: Schedule,
    /// Learner hyperparameters.
    pub mpo: MpoSettings,
    /// The row's compile-time sizes; written for readers, checked when read back (they
    /// cannot be changed by configuration: they are the learner's type).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub network: Option<Sizes>,
}

/// Acting, learning and evaluation schedule, in environment steps.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Schedule {
    /// Steps with uniformly random actions in [-1, 1] before the policy acts and learning
    /// starts.
    pub warmup_steps: u64,
    /// Environment steps between learning phases.
    pub update_interval: u64,
    /// Learner updates per learning phase (so `updates_per_interval / update_interval`
    /// updates per environment step).
    pub updates_per_interval: u64,
    /// Environment steps between evaluations and checkpoints (a multiple of the episode
    /// length, so both happen at episode boundaries).
    pub eval_interval: u64,
    /// Evaluation episodes, each on a fresh environment with its own evaluation seed.
    pub eval_episodes: u32,
    /// Weight `c` of a penalty subtracted from the stored (training) reward:
    /// `r - c * sum_k (a_k - clip(a_k, -1, 1))^2`; 0 (the default everywhere) stores the
    /// environment's reward. The learner's own remedy for out-of-range actions is
    /// `mpo.action_penalization`; this scalarised form is kept for comparison
    /// (docs/experiments.md). Evaluation returns are always the environment's rewards.
    pub action_penalty: f64,
    /// Correlation in `[0, 1)` of the exploration noise between consecutive steps of an
    /// episode (`mpo_core::agent::AgentSchedule::noise_corr`): 0 = independent draws (the
    /// default but in the rows of `CORRELATED_NOISE_SCHEDULE`, 0.95); 0.9 keeps a push going
    /// for about 10 steps. Not with Retrace, and not on a device (its START frame has no field
    /// for it). Missing in a checkpoint or file written before it existed: 0, which is what
    /// those runs did (so they resume as before).
    #[serde(default)]
    pub noise_corr: f64,
    /// Pink (1/f) exploration noise (`mpo_core::agent::AgentSchedule::noise_pink`): pushes of
    /// every duration from one step to an episode, each draw still standard normal. Off in
    /// every row; exclusive with `noise_corr > 0`, not with Retrace, not on a device. Missing
    /// in a checkpoint or file written before it existed: off (what those runs did).
    #[serde(default)]
    pub noise_pink: bool,
}

/// How the critic's targets are formed.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum PolicyEvaluation {
    /// TD(0) expected SARSA on single transitions (the report's).
    Td,
    /// `n_step`-step transitions (Acme's default, n = 5), then expected SARSA.
    NStep,
    /// Retrace (the paper's) over `n_step` consecutive transitions.
    Retrace,
}

/// [`MpoConfig`] as written in configuration files (see the module doc for the `f64`), plus
/// the choice of policy evaluation (which decides how batches are drawn from the replay).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
#[allow(missing_docs)]
pub struct MpoSettings {
    pub eps_eta: f64,
    pub eps_mean: f64,
    pub eps_cov: f64,
    pub per_dim_kl: bool,
    pub gamma: f64,
    pub actor_lr: f64,
    pub critic_lr: f64,
    pub dual_lr: f64,
    pub mstep_iters: u32,
    pub actor_clip: f64,
    pub critic_clip: f64,
    pub target_period: u32,
    pub init_std: f64,
    pub std_floor: f64,
    pub eta_init: f64,
    pub alpha_mean_init: f64,
    pub alpha_cov_init: f64,
    pub estep_tol: f64,
    pub estep_max_iter: u32,
    /// `td`, `n-step` or `retrace`.
    pub policy_evaluation: PolicyEvaluation,
    /// Steps of an n-step transition, or the length of a Retrace sequence (at most the
    /// row's `seq`); ignored by `td`.
    pub n_step: u32,
    pub action_penalization: bool,
    pub eps_penalty: f64,
    pub shared_samples: bool,
    pub target_tau: f64,
    /// Acme's LayerNormMLP critic torso (layer norm and tanh after the first layer).
    pub critic_layer_norm: bool,
    /// Observation normalisation: refit to the replay's observations every this many steps
    /// from the end of the warm-up; 0 = off.
    pub obs_norm_interval: u32,
    /// tonic's squashed mean: the policy's mean is `tanh` of its head, inside `[-1, 1]`.
    pub tanh_mean: bool,
    /// Acme's clip before the critic: every action the critic sees is clipped to `[-1, 1]`
    /// (what the plant applies), so it never extrapolates beyond the actuators' range. Missing
    /// in a file or checkpoint written before it existed: off, as those runs trained.
    #[serde(default)]
    pub clip_critic_actions: bool,
    /// A categorical critic's smallest atom (read only by rows with `bins > 1`). Missing in a
    /// file or checkpoint written before it existed: the default, which those runs never read.
    #[serde(default = "MpoSettings::default_value_min")]
    pub value_min: f64,
    /// A categorical critic's largest atom.
    #[serde(default = "MpoSettings::default_value_max")]
    pub value_max: f64,
    /// A categorical critic's targets: HL-Gauss with this standard deviation in atom
    /// spacings, or two-hot when 0.
    #[serde(default = "MpoSettings::default_value_sigma")]
    pub value_sigma: f64,
    /// Learner updates between periodic resets of the networks (D'Oro et al. 2023); 0 = never.
    /// Missing in a file or checkpoint written before it existed: 0, as those runs trained.
    #[serde(default)]
    pub reset_interval: u32,
    /// SimbaV2's alternative to resets: the hidden layers' weights held on the unit sphere
    /// (residual rows only). Missing in a file or checkpoint written before it existed: off.
    #[serde(default)]
    pub weight_norm: bool,
    /// A categorical critic's atoms more than this many nats below its largest logit get
    /// probability 0 (the core's `MpoConfig::logit_floor`: keeps subnormal numbers out of the
    /// head); 0 = off. Missing in a file or checkpoint written before it existed: 0, as those
    /// runs trained, so they resume with the same bits.
    #[serde(default)]
    pub logit_floor: f64,
    /// The ceiling of `ln alpha` for both M-step multipliers (the core's
    /// `MpoConfig::log_alpha_max`): 18 (about 6.6e7) unless set; e.g. 6.908 holds them at or
    /// below about 1000 (a ceiling below an initial multiplier's logarithm starts that
    /// multiplier at the ceiling: `ln 1000` itself rounds just below `ln` of the covariance's
    /// initial 1000 in f32). Missing in a file or checkpoint written before it existed: 18,
    /// the ceiling those runs trained with.
    #[serde(default = "MpoSettings::default_log_alpha_max")]
    pub log_alpha_max: f64,
}

impl MpoSettings {
    /// The report's values (`MpoConfig::REPORT`), written as decimals.
    pub const REPORT: Self = Self {
        eps_eta: 0.1,
        eps_mean: 0.1,
        eps_cov: 1e-4,
        per_dim_kl: false,
        gamma: 0.99,
        actor_lr: 3e-4,
        critic_lr: 3e-4,
        dual_lr: 1e-2,
        mstep_iters: 5,
        actor_clip: 0.1,
        critic_clip: 40.0,
        target_period: 100,
        init_std: 0.5,
        std_floor: 1e-4,
        eta_init: 1.0,
        alpha_mean_init: 10.0,
        alpha_cov_init: 1000.0,
        estep_tol: 1e-3,
        estep_max_iter: 50,
        policy_evaluation: PolicyEvaluation::Td,
        n_step: 1,
        action_penalization: false,
        eps_penalty: 1e-3,
        shared_samples: false,
        target_tau: 0.0,
        critic_layer_norm: false,
        obs_norm_interval: 0,
        tanh_mean: false,
        clip_critic_actions: false,
        value_min: -10.0,
        value_max: 110.0,
        value_sigma: 0.75,
        reset_interval: 0,
        weight_norm: false,
        logit_floor: 40.0,
        log_alpha_max: 18.0,
    };

    fn default_value_min() -> f64 {
        Self::REPORT.value_min
    }

    fn default_value_max() -> f64 {
        Self::REPORT.value_max
    }

    fn default_value_sigma() -> f64 {
        Self::REPORT.value_sigma
    }

    fn default_log_alpha_max() -> f64 {
        Self::REPORT.log_alpha_max
    }

    /// The learner's configuration (one `f64 -> f32` rounding per field). Every field is
    /// written out, with no `..` default: a field the core gains fails to compile here until
    /// the host maps it to a setting.
    pub fn to_config(&self) -> MpoConfig {
        MpoConfig {
            eps_eta: self.eps_eta as f32,
            eps_mean: self.eps_mean as f32,
            eps_cov: self.eps_cov as f32,
            per_dim_kl: self.per_dim_kl,
            gamma: self.gamma as f32,
            actor_lr: self.actor_lr as f32,
            critic_lr: self.critic_lr as f32,
            dual_lr: self.dual_lr as f32,
            mstep_iters: self.mstep_iters,
            actor_clip: self.actor_clip as f32,
            critic_clip: self.critic_clip as f32,
            target_period: self.target_period,
            init_std: self.init_std as f32,
            std_floor: self.std_floor as f32,
            eta_init: self.eta_init as f32,
            alpha_mean_init: self.alpha_mean_init as f32,
            alpha_cov_init: self.alpha_cov_init as f32,
            estep_tol: self.estep_tol,
            estep_max_iter: self.estep_max_iter,
            sequence_len: match self.policy_evaluation {
                PolicyEvaluation::Retrace => self.n_step,
                PolicyEvaluation::Td | PolicyEvaluation::NStep => 1,
            },
            action_penalization: self.action_penalization,
            eps_penalty: self.eps_penalty as f32,
            shared_samples: self.shared_samples,
            target_tau: self.target_tau as f32,
            critic_layer_norm: self.critic_layer_norm,
            obs_norm_interval: self.obs_norm_interval,
            tanh_mean: self.tanh_mean,
            clip_critic_actions: self.clip_critic_actions,
            value_min: self.value_min as f32,
            value_max: self.value_max as f32,
            value_sigma: self.value_sigma as f32,
            reset_interval: self.reset_interval,
            weight_norm: self.weight_norm,
            logit_floor: self.logit_floor as f32,
            log_alpha_max: self.log_alpha_max as f32,
        }
    }
}

/// Why a configuration could not be resolved.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum SettingsError {
    /// The file could not be read.
    #[error("cannot read the configuration file {path}: {source}")]
    Read {
        /// File.
        path: String,
        /// Cause.
        source: std::io::Error,
    },
    /// Not TOML, or a value of the wrong type.
    #[error("{origin}: {message}")]
    Parse {
        /// File or flag.
        origin: String,
        /// Parser message.
        message: String,
    },
    /// A key that no setting has.
    #[error("{origin}: unknown setting `{key}` (see config.toml of any run for every key)")]
    UnknownKey {
        /// File or flag.
        origin: String,
        /// Dotted key.
        key: String,
    },
    /// A value out of range.
    #[error("invalid configuration: {0}")]
    Invalid(String),
    /// On resume: the given configuration differs from the checkpoint's.
    #[error(
        "the configuration does not match the checkpoint in {dir}: {}; resume with the checkpoint's configuration (only `steps` may change)",
        .differences.join("; ")
    )]
    Mismatch {
        /// Checkpoint directory.
        dir: String,
        /// `key: checkpoint A, given B` per differing key.
        differences: Vec<String>,
    },
}

/// Reads a TOML file into a table.
pub fn read_table(path: &std::path::Path) -> Result<toml::Table, SettingsError> {
    let text = std::fs::read_to_string(path).map_err(|source| SettingsError::Read {
        path: path.display().to_string(),
        source,
    })?;
    parse_table(&text, &path.display().to_string())
}

/// Parses the text of a TOML configuration file into a table (errors name `origin`).
pub fn parse_table(text: &str, origin: &str) -> Result<toml::Table, SettingsError> {
    text.parse::<toml::Table>()
        .map_err(|e| SettingsError::Parse {
            origin: origin.to_string(),
            message: e.to_string(),
        })
}

/// Parses `--set key=value` (value in TOML syntax; a bare word is taken as a string) into a
/// nested table.
pub fn parse_set(assignment: &str) -> Result<toml::Table, SettingsError> {
    let origin = format!("--set {assignment}");
    let Some((key, value)) = assignment.split_once('=') else {
        return Err(SettingsError::Parse {
            origin,
            message: "expected KEY=VALUE, e.g. mpo.actor_lr=1e-4".into(),
        });
    };
    let parsed = format!("v = {}", value.trim())
        .parse::<toml::Table>()
        .ok()
        .and_then(|mut t| t.remove("v"))
        .unwrap_or_else(|| toml::Value::String(value.trim().to_string()));
    let mut table = toml::Table::new();
    let parts: Vec<&str> = key.trim().split('.').collect();
    let mut cur = &mut table;
    for (i, p) in parts.iter().enumerate() {
        if i + 1 == parts.len() {
            cur.insert((*p).to_string(), parsed.clone());
        } else {
            cur = cur
                .entry((*p).to_string())
                .or_insert_with(|| toml::Value::Table(toml::Table::new()))
                .as_table_mut()
                .expect("fresh table");
        }
    }
    Ok(table)
}

/// Writes every key of `over` into `base`, recursing into tables; a key `base` lacks is an
/// error.
pub fn overlay(
    base: &mut toml::Table,
    over: &toml::Table,
    origin: &str,
    prefix: &str,
) -> Result<(), SettingsError> {
    for (k, v) in over {
        let key = if prefix.is_empty() {
            k.clone()
        } else {
            format!("{prefix}.{k}")
        };
        match (base.get_mut(k), v) {
            (Some(toml::Value::Table(b)), toml::Value::Table(o)) => overlay(b, o, origin, &key)?,
            (Some(slot), _) => *slot = v.clone(),
            (None, _) => {
                return Err(SettingsError::UnknownKey {
                    origin: origin.to_string(),
                    key,
                });
            }
        }
    }
    Ok(())
}

/// `key: a, b` for every leaf where the two tables differ (keys in `ignore` skipped).
pub fn differences(a: &toml::Table, b: &toml::Table, prefix: &str, ignore: &[&str]) -> Vec<String> {
    let mut out = Vec::new();
    for (k, va) in a {
        let key = if prefix.is_empty() {
            k.clone()
        } else {
            format!("{prefix}.{k}")
        };
        if ignore.contains(&key.as_str()) {
            continue;
        }
        match (va, b.get(k)) {
            (toml::Value::Table(ta), Some(toml::Value::Table(tb))) => {
                out.extend(differences(ta, tb, &key, ignore))
            }
            (_, Some(vb)) if vb == va => {}
            (_, Some(vb)) => out.push(format!("`{key}` is {va} in the checkpoint, {vb} here")),
            (_, None) => out.push(format!("`{key}` missing here")),
        }
    }
    out
}

impl Settings {
    /// As a TOML table.
    pub fn to_table(&self) -> toml::Table {
        toml::Table::try_from(self).expect("settings serialise to TOML")
    }

    /// The text of a run's `config.toml` (also what `mpo train --print-config` prints): these
    /// settings with `network` set to `sizes`, under a header that says how to repeat the run.
    pub fn config_toml(&self, sizes: &Sizes) -> String {
        let mut resolved = self.clone();
        resolved.network = Some(*sizes);
        format!(
            "# Resolved configuration of this run (the row's defaults, --config, flags).\n\
             # `mpo train --config config.toml --out NEW` repeats it; [network] is fixed by the row (the learner's type).\n{}",
            toml::to_string(&resolved).expect("settings serialise")
        )
    }

    /// From a merged table (type errors name `origin`).
    pub fn from_table(t: toml::Table, origin: &str) -> Result<Self, SettingsError> {
        toml::Value::Table(t)
            .try_into()
            .map_err(|e: toml::de::Error| SettingsError::Parse {
                origin: origin.to_string(),
                message: e.to_string(),
            })
    }

    /// Range checks beyond the types (episode-aligned schedule, learner validation).
    /// `episode_steps` is the task's episode length and `fixed` true when every episode has
    /// it (no early termination): then `steps` and `eval_interval` must be multiples of it, so
    /// that evaluations and checkpoints fall on episode ends; otherwise they happen at the
    /// first episode end at or after each multiple.
    pub fn validate(
        &self,
        episode_steps: u64,
        fixed: bool,
        sizes: &Sizes,
    ) -> Result<(), SettingsError> {
        let bad = |m: String| Err(SettingsError::Invalid(m));
        if let Some(n) = &self.network
            && n != sizes
        {
            return bad(format!(
                "[network] is {n:?} but the `{}`/`{}` row's are {sizes:?}: sizes are the learner's type and come from the row (choose another `net`)",
                self.task, self.net
            ));
        }
        let episode_steps = if fixed { episode_steps } else { 1 };
        if self.steps == 0 || !self.steps.is_multiple_of(episode_steps) {
            return bad(format!(
                "steps = {} must be a positive multiple of the episode length ({episode_steps}): checkpoints are taken at episode boundaries",
                self.steps
            ));
        }
        self.validate_schedule(episode_steps, sizes)?;
        let m = &self.mpo;
        match m.policy_evaluation {
            PolicyEvaluation::NStep if m.n_step == 0 || m.n_step as usize > MAX_NSTEP => {
                return bad(format!(
                    "mpo.n_step = {} must be in 1..={MAX_NSTEP} for n-step returns",
                    m.n_step
                ));
            }
            PolicyEvaluation::Retrace if m.n_step == 0 || m.n_step as usize > sizes.seq => {
                return bad(format!(
                    "mpo.n_step = {} is the Retrace sequence length: it must be in 1..={} (the `{}`/`{}` row's `seq`)",
                    m.n_step, sizes.seq, self.task, self.net
                ));
            }
            _ => {}
        }
        if m.shared_samples && sizes.m != sizes.n {
            return bad(format!(
                "mpo.shared_samples needs M = N; the `{}`/`{}` row has M = {}, N = {}",
                self.task, self.net, sizes.m, sizes.n
            ));
        }
        m.to_config()
            .validate()
            .map_err(|e| SettingsError::Invalid(format!("mpo: {e}")))
    }

    /// The schedule's ranges: intervals on episode boundaries, exploration noise of one kind
    /// and not with Retrace, a warm-up that fills a batch.
    fn validate_schedule(&self, episode_steps: u64, sizes: &Sizes) -> Result<(), SettingsError> {
        let bad = |m: String| Err(SettingsError::Invalid(m));
        let s = &self.schedule;
        if s.eval_interval == 0 || !s.eval_interval.is_multiple_of(episode_steps) {
            return bad(format!(
                "schedule.eval_interval = {} must be a positive multiple of the episode length ({episode_steps})",
                s.eval_interval
            ));
        }
        if s.update_interval == 0 {
            return bad("schedule.update_interval must be at least 1".into());
        }
        if !(s.action_penalty.is_finite() && s.action_penalty >= 0.0) {
            return bad("schedule.action_penalty must be a finite number >= 0".into());
        }
        if !(s.noise_corr >= 0.0 && s.noise_corr < 1.0) {
            return bad(format!(
                "schedule.noise_corr = {} must be in [0, 1) (0 = independent exploration noise)",
                s.noise_corr
            ));
        }
        if s.noise_corr > 0.0 && self.mpo.policy_evaluation == PolicyEvaluation::Retrace {
            return bad("schedule.noise_corr must be 0 with mpo.policy_evaluation = \"retrace\": Retrace weighs each replayed action by its behaviour density, which correlated noise does not store".into());
        }
        if s.noise_pink && s.noise_corr > 0.0 {
            return bad(format!(
                "schedule.noise_pink and schedule.noise_corr = {} are two kinds of exploration noise: choose one (noise_corr = 0 with pink noise)",
                s.noise_corr
            ));
        }
        if s.noise_pink && self.mpo.policy_evaluation == PolicyEvaluation::Retrace {
            return bad("schedule.noise_pink must be false with mpo.policy_evaluation = \"retrace\": Retrace weighs each replayed action by its behaviour density, which pink noise does not store".into());
        }
        if s.eval_episodes == 0 {
            return bad("schedule.eval_episodes must be at least 1".into());
        }
        if s.warmup_steps < sizes.batch as u64 {
            return bad(format!(
                "schedule.warmup_steps = {} must be at least the batch size {}",
                s.warmup_steps, sizes.batch
            ));
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn t(s: &str) -> toml::Table {
        s.parse().unwrap()
    }

    #[test]
    fn overlay_replaces_leaves_and_rejects_unknown_keys() {
        let mut base = t("a = 1\n[m]\nx = 1.0\ny = 2\n");
        overlay(&mut base, &t("[m]\nx = 3.0\n"), "f", "").unwrap();
        assert_eq!(base, t("a = 1\n[m]\nx = 3.0\ny = 2\n"));
        let e = overlay(&mut base, &t("[m]\nz = 1\n"), "f", "").unwrap_err();
        assert!(e.to_string().contains("unknown setting `m.z`"), "{e}");
    }

    #[test]
    fn set_parses_toml_values_and_bare_words() {
        assert_eq!(
            parse_set("mpo.actor_lr=1e-4").unwrap(),
            t("[mpo]\nactor_lr = 1e-4\n")
        );
        assert_eq!(
            parse_set("task=hopper-stand").unwrap(),
            t("task = \"hopper-stand\"\n")
        );
        assert_eq!(
            parse_set("mpo.per_dim_kl=true").unwrap(),
            t("[mpo]\nper_dim_kl = true\n")
        );
        assert!(parse_set("novalue").is_err());
    }

    #[test]
    fn differences_name_each_key_and_skip_ignored_ones() {
        let a = t("steps = 1\nseed = 0\n[m]\nx = 1.0\n");
        let b = t("steps = 2\nseed = 3\n[m]\nx = 2.0\n");
        let d = differences(&a, &b, "", &["steps"]);
        assert_eq!(d.len(), 2, "{d:?}");
        assert!(d[0].contains("`m.x`") || d[1].contains("`m.x`"));
        assert!(
            d.iter()
                .any(|s| s.contains("`seed` is 0 in the checkpoint, 3 here"))
        );
    }

    /// A run's `config.toml` written before the multipliers' ceiling was a setting resumes
    /// with the ceiling it trained with (18), not with some other value.
    #[test]
    fn settings_without_the_multiplier_ceiling_read_as_the_old_clamp() {
        let mut table = toml::Table::try_from(MpoSettings {
            log_alpha_max: 6.9,
            ..MpoSettings::REPORT
        })
        .unwrap();
        assert_eq!(table.remove("log_alpha_max"), Some(toml::Value::Float(6.9)));
        let old: MpoSettings = table.try_into().unwrap();
        assert_eq!(old.log_alpha_max, 18.0);
        assert_eq!(
            old.to_config().log_alpha_max,
            mpo_core::config::LOG_ALPHA_MAX
        );
    }

    /// A run's `config.toml` written before the categorical head's floor existed resumes with
    /// it off, the arithmetic that run trained with.
    #[test]
    fn settings_without_the_logit_floor_read_as_off() {
        let mut table = toml::Table::try_from(MpoSettings::REPORT).unwrap();
        assert_eq!(table.remove("logit_floor"), Some(toml::Value::Float(40.0)));
        let old: MpoSettings = table.try_into().unwrap();
        assert_eq!(old.logit_floor, 0.0);
        assert_eq!(old.to_config().logit_floor, 0.0);
    }

    #[test]
    fn report_settings_match_the_core_defaults() {
        let c = MpoSettings::REPORT.to_config();
        assert_eq!(c, MpoConfig::REPORT);
    }
}
