//! Checkpoints: everything a run needs to continue bit-identically, in a directory.
//!
//! ```text
//! checkpoint/
//!   params.safetensors     actor.*, critic.*, target_actor.*, target_critic.*  (f32, [in, out])
//!   optimizer.safetensors  Adam moments (actor_m.*, ...), Adam step counters, duals
//!   replay.safetensors     the replay's stored slots (obs [len, OBS], ..., episode u64)
//!   meta.json              format version, resolved settings, counters, RNG states, metrics
//!   SHA256SUMS             sha256 of the four files (`sha256sum -c SHA256SUMS` checks them)
//! ```
//! Networks, moments and small optimiser scalars go through safetensors (exact bytes,
//! little-endian, readable by numpy and PyTorch) rather than JSON, so no float is ever
//! re-parsed. Checkpoints are written only at episode boundaries: an environment's
//! `RandomState` advances on every reset and sim-bridge exposes no setter for it, so the
//! training environment is restored by recreating it from its seed and replaying its
//! `episodes` resets.
//!
//! Crash safety: a new checkpoint is written into `checkpoint.tmp/`, every file and the
//! directory fsynced, `SHA256SUMS` last (its presence marks a complete write), then swapped in
//! by two renames (`checkpoint/` -> `checkpoint.old/`, `checkpoint.tmp/` -> `checkpoint/`) and
//! the run directory fsynced before `checkpoint.old/` is removed. A crash at any moment leaves
//! at least one complete checkpoint among the three directories; [`open`] picks the newest
//! complete one, and the next [`save`] first finishes an interrupted swap ([`CANDIDATES`]).

use std::collections::HashMap;
use std::fs;
use std::path::{Path, PathBuf};

use mpo_core::learner::LearnerOf;
use mpo_core::network::{PolicyTrain, ValueNet};
use mpo_core::params::Params;
use mpo_core::replay::{Replay, ReplayCounters};
use safetensors::tensor::{Dtype, SafeTensors, TensorView};
use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};

use crate::metrics::{MetricsRow, StatsAccumulator};
use crate::settings::Settings;
use crate::sizes::Sizes;

/// Format identifier in `meta.json`.
pub const FORMAT: &str = "mpo-checkpoint";
/// Format version; bumped on any incompatible change.
pub const VERSION: u32 = 5;
/// The checkpoint's subdirectory in a run directory.
pub const SUBDIR: &str = "checkpoint";
/// Where a checkpoint can be found in a run directory after a crash, in order of preference
/// between checkpoints of the same environment step: the live one, a complete new one whose
/// swap was interrupted, the previous one whose removal was interrupted.
pub const CANDIDATES: [&str; 3] = ["checkpoint", "checkpoint.tmp", "checkpoint.old"];
/// Test hook: milliseconds [`save`] sleeps before each file it writes and before each rename
/// or removal of the swap, so a test can kill the process inside that window. Read only by
/// [`save`]; unset (the normal case) means no pause.
pub const PAUSE_ENV: &str = "MPO_TEST_CHECKPOINT_PAUSE_MS";
/// The checksum file.
pub const SUMS: &str = "SHA256SUMS";
/// The checksummed files, in the order they are listed.
pub const FILES: [&str; 4] = [
    "meta.json",
    "params.safetensors",
    "optimizer.safetensors",
    "replay.safetensors",
];

/// What went wrong reading or writing a checkpoint; every variant names the file.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum CheckpointError {
    /// Reading or writing failed.
    // The cause is part of the message and not a `source()`: `mpo` prints error chains, which
    // would repeat it.
    #[error("{path}: {cause}")]
    Io {
        /// File.
        path: PathBuf,
        /// Cause.
        cause: std::io::Error,
    },
    /// No checkpoint where one was expected.
    #[error(
        "no checkpoint in {path} (expected {path}/{SUBDIR}/{SUMS}, or after a crash {path}/{SUBDIR}.tmp/{SUMS} or {path}/{SUBDIR}.old/{SUMS}, or {path}/{SUMS})"
    )]
    NotFound {
        /// Directory.
        path: PathBuf,
    },
    /// The file's bytes do not match SHA256SUMS.
    #[error(
        "{path}: checksum mismatch (sha256 {actual}, SHA256SUMS says {expected}): the file is corrupt or truncated"
    )]
    Checksum {
        /// File.
        path: PathBuf,
        /// Listed hash.
        expected: String,
        /// Hash of the bytes read.
        actual: String,
    },
    /// Unreadable content (bad checksum list, JSON, safetensors, or a tensor of the wrong
    /// name, type or shape).
    #[error("{path}: {message}")]
    Corrupt {
        /// File.
        path: PathBuf,
        /// What is wrong.
        message: String,
    },
}

/// Ring counters as stored.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[allow(missing_docs)]
pub struct Counters {
    pub head: u64,
    pub len: u64,
    pub inserted: u64,
    pub current_episode: u64,
}

/// `meta.json`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Meta {
    /// [`FORMAT`].
    pub format: String,
    /// [`VERSION`].
    pub version: u32,
    /// The run's resolved settings.
    pub settings: Settings,
    /// The task file the run trained on (absent for a built-in task): where it was, its text
    /// and the hash of text and model, so a changed file is refused rather than silently
    /// evaluated on another plant.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub task_file: Option<TaskFileRecord>,
    /// The learner's sizes (checked against the task table on load).
    pub sizes: Sizes,
    /// Environment steps taken.
    pub env_steps: u64,
    /// Training episodes completed (= resets of the training environment).
    pub episodes: u64,
    /// Learner updates.
    pub updates: u64,
    /// Training wall clock so far.
    pub wall_s: f64,
    /// Learner random stream (hex).
    pub learner_rng: String,
    /// Collector random stream: exploration noise and warm-up actions (hex).
    pub collector_rng: String,
    /// Replay sampler random stream (hex).
    pub sampler_rng: String,
    /// Replay ring counters.
    pub replay: Counters,
    /// Statistics accumulated since the last metrics row.
    pub stats: StatsAccumulator,
    /// Every metrics row so far.
    pub metrics: Vec<MetricsRow>,
    /// sha256 of the online actor and critic (see [`params_sha256`]).
    pub params_sha256: String,
    /// A fleet's run id and its plants' streams (absent for a run collecting in-process).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub fleet: Option<FleetRecord>,
}

/// What a checkpoint keeps of a fleet (`mpo train --plants`): a resumed learner joins the
/// same run id, and each plant's process continues its streams where the plant's last
/// inserted block left them (docs/fleet.md).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct FleetRecord {
    /// The run id plants join with.
    pub run: String,
    /// Each plant's streams, by index.
    pub plants: Vec<PlantRecord>,
}

/// A plant's streams after its last inserted block.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct PlantRecord {
    /// Its collector stream (hex).
    pub collector: String,
    /// Resets of its environment (a new process replays them from the plant's seed).
    pub resets: u64,
}

/// A task file as a checkpoint records it.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct TaskFileRecord {
    /// Its absolute path when the run started.
    pub path: PathBuf,
    /// sha256 of its text and its model's files (`sim_bridge::TaskDef::sha256`).
    pub sha256: String,
    /// Its text.
    pub text: String,
}

impl Meta {
    /// The run-level part of a checkpoint's metadata; a trainer fills in its state
    /// (`crate::training::Training::meta`).
    pub fn new(
        settings: Settings,
        task_file: Option<TaskFileRecord>,
        sizes: Sizes,
        metrics: Vec<MetricsRow>,
        wall_s: f64,
    ) -> Self {
        Self {
            format: FORMAT.into(),
            version: VERSION,
            settings,
            task_file,
            sizes,
            env_steps: 0,
            episodes: 0,
            updates: 0,
            wall_s,
            learner_rng: String::new(),
            collector_rng: String::new(),
            sampler_rng: String::new(),
            replay: Counters {
                head: 0,
                len: 0,
                inserted: 0,
                current_episode: 0,
            },
            stats: StatsAccumulator::default(),
            metrics,
            params_sha256: String::new(),
            fleet: None,
        }
    }
}

/// Hex of bytes.
pub fn hex(b: &[u8]) -> String {
    b.iter().map(|x| format!("{x:02x}")).collect()
}

/// 32 bytes from hex.
pub fn unhex32(s: &str) -> Option<[u8; 32]> {
    if s.len() != 64 {
        return None;
    }
    let mut out = [0u8; 32];
    for (i, o) in out.iter_mut().enumerate() {
        *o = u8::from_str_radix(s.get(2 * i..2 * i + 2)?, 16).ok()?;
    }
    Some(out)
}

/// Lower-case hex SHA-256 of `bytes`, as `SHA256SUMS` lists it.
pub fn sha256_hex(bytes: &[u8]) -> String {
    hex(&Sha256::digest(bytes))
}

/// sha256 over the online actor's then the online critic's parameters, each tensor in
/// tensor order as little-endian f32: the run's fingerprint.
pub fn params_sha256<P: Params, Q: Params>(actor: &P, critic: &Q) -> String {
    let mut h = Sha256::new();
    actor.for_each(|x| h.update(x.to_le_bytes()));
    critic.for_each(|x| h.update(x.to_le_bytes()));
    hex(&h.finalize())
}

/// A tensor's name and shape as a checkpoint stores it.
pub type Layout = Vec<(String, Vec<usize>)>;

/// Tensor names and `[in, out]` shapes of the actor, in tensor order: the two-layer MLP, or
/// (with `actor_blocks`) the residual network.
pub fn actor_layout(s: &Sizes) -> Layout {
    let tri = s.act * (s.act + 1) / 2;
    let mut l = named(&[
        ("in.shift", vec![s.obs]),
        ("in.scale", vec![s.obs]),
        ("in.limit", vec![s.obs]),
    ]);
    let h = if s.actor_blocks == 0 {
        let [h1, h2] = s.actor;
        l.extend(named(&[
            ("l1.w", vec![s.obs, h1]),
            ("l1.b", vec![h1]),
            ("l2.w", vec![h1, h2]),
            ("l2.b", vec![h2]),
        ]));
        h2
    } else {
        let w = s.actor[0];
        l.extend(named(&[("embed.w", vec![s.obs, w]), ("embed.b", vec![w])]));
        l.extend(trunk_layout(s.actor, s.actor_blocks));
        w
    };
    l.extend(named(&[
        ("mean.w", vec![h, s.act]),
        ("mean.b", vec![s.act]),
        ("chol.w", vec![h, tri]),
        ("chol.b", vec![tri]),
        ("squash.bound", vec![s.act]),
    ]));
    l
}

/// Tensor names and shapes of the critic, in tensor order: the two-layer MLP, or (with
/// `critic_blocks`) the residual network; `bins` outputs.
pub fn critic_layout(s: &Sizes) -> Layout {
    if s.critic_blocks == 0 {
        let [h1, h2] = s.critic;
        return named(&[
            ("l1s.w", vec![s.obs, h1]),
            ("l1s.b", vec![h1]),
            ("l1a.w", vec![s.act, h1]),
            ("ln1.g", vec![h1]),
            ("ln1.b", vec![h1]),
            ("l2.w", vec![h1, h2]),
            ("l2.b", vec![h2]),
            ("out.w", vec![h2, s.bins]),
            ("out.b", vec![s.bins]),
        ]);
    }
    let w = s.critic[0];
    let mut l = named(&[
        ("embed_s.w", vec![s.obs, w]),
        ("embed_s.b", vec![w]),
        ("embed_a.w", vec![s.act, w]),
    ]);
    l.extend(trunk_layout(s.critic, s.critic_blocks));
    l.extend(named(&[
        ("out.w", vec![w, s.bins]),
        ("out.b", vec![s.bins]),
    ]));
    l
}

/// A residual trunk's tensors (`mpo_core::residual::Trunk`): per block its norm, `up`,
/// `down`; then the final norm.
fn trunk_layout([w, f]: [usize; 2], blocks: usize) -> Layout {
    let mut l = Layout::new();
    for d in 0..blocks {
        for (name, shape) in [
            ("norm.g", vec![w]),
            ("norm.b", vec![w]),
            ("up.w", vec![w, f]),
            ("up.b", vec![f]),
            ("down.w", vec![f, w]),
            ("down.b", vec![w]),
        ] {
            l.push((format!("block{d}.{name}"), shape));
        }
    }
    l.extend(named(&[("norm.g", vec![w]), ("norm.b", vec![w])]));
    l
}

fn named(v: &[(&str, Vec<usize>)]) -> Layout {
    v.iter().map(|(n, s)| (n.to_string(), s.clone())).collect()
}

/// Owned tensors waiting to be serialised.
#[derive(Default)]
struct Tensors(Vec<(String, Dtype, Vec<usize>, Vec<u8>)>);

impl Tensors {
    fn f32s(&mut self, name: String, shape: Vec<usize>, v: &[f32]) {
        assert_eq!(shape.iter().product::<usize>(), v.len(), "{name}: shape");
        let bytes = v.iter().flat_map(|x| x.to_le_bytes()).collect();
        self.0.push((name, Dtype::F32, shape, bytes));
    }
    fn u64s(&mut self, name: String, v: &[u64]) {
        let bytes = v.iter().flat_map(|x| x.to_le_bytes()).collect();
        self.0.push((name, Dtype::U64, vec![v.len()], bytes));
    }
    fn params<P: Params>(&mut self, prefix: &str, p: &P, layout: &[(String, Vec<usize>)]) {
        assert_eq!(layout.len(), P::TENSORS);
        for (k, (name, shape)) in layout.iter().enumerate() {
            self.f32s(format!("{prefix}.{name}"), shape.clone(), p.tensor(k));
        }
    }
    fn serialize(&self, meta: &Settings) -> Vec<u8> {
        let views: Vec<(String, TensorView<'_>)> = self
            .0
            .iter()
            .map(|(n, d, s, b)| {
                (
                    n.clone(),
                    TensorView::new(*d, s.clone(), b).expect("consistent tensor"),
                )
            })
            .collect();
        // One entry only: the header serialises a HashMap, whose order is random, and
        // checkpoints must be byte-reproducible.
        let _ = meta;
        let info = HashMap::from([("format".to_string(), FORMAT.to_string())]);
        safetensors::tensor::serialize(views, Some(info)).expect("serialisable tensors")
    }
}

/// A verified, parsed safetensors file.
struct Reader<'a> {
    path: PathBuf,
    st: SafeTensors<'a>,
}

impl<'a> Reader<'a> {
    fn new(path: PathBuf, bytes: &'a [u8]) -> Result<Self, CheckpointError> {
        let st = SafeTensors::deserialize(bytes).map_err(|e| CheckpointError::Corrupt {
            path: path.clone(),
            message: format!("not a safetensors file: {e}"),
        })?;
        Ok(Self { path, st })
    }
    fn raw(&self, name: &str, dtype: Dtype, shape: &[usize]) -> Result<&'a [u8], CheckpointError> {
        let t = self.st.tensor(name).map_err(|_| CheckpointError::Corrupt {
            path: self.path.clone(),
            message: format!("tensor `{name}` missing"),
        })?;
        if t.dtype() != dtype || t.shape() != shape {
            return Err(CheckpointError::Corrupt {
                path: self.path.clone(),
                message: format!(
                    "tensor `{name}` is {:?} {:?}, expected {dtype:?} {shape:?}",
                    t.dtype(),
                    t.shape()
                ),
            });
        }
        Ok(t.data())
    }
    fn f32s(&self, name: &str, shape: &[usize], out: &mut [f32]) -> Result<(), CheckpointError> {
        let d = self.raw(name, Dtype::F32, shape)?;
        for (o, c) in out.iter_mut().zip(d.chunks_exact(4)) {
            *o = f32::from_le_bytes(c.try_into().expect("4 bytes"));
        }
        Ok(())
    }
    fn u64s(&self, name: &str, out: &mut [u64]) -> Result<(), CheckpointError> {
        let d = self.raw(name, Dtype::U64, &[out.len()])?;
        for (o, c) in out.iter_mut().zip(d.chunks_exact(8)) {
            *o = u64::from_le_bytes(c.try_into().expect("8 bytes"));
        }
        Ok(())
    }
    fn params<P: Params>(
        &self,
        prefix: &str,
        p: &mut P,
        layout: &[(String, Vec<usize>)],
    ) -> Result<(), CheckpointError> {
        for (k, (name, shape)) in layout.iter().enumerate() {
            self.f32s(&format!("{prefix}.{name}"), shape, p.tensor_mut(k))?;
        }
        Ok(())
    }
}

fn io(path: &Path) -> impl FnOnce(std::io::Error) -> CheckpointError + '_ {
    move |cause| CheckpointError::Io {
        path: path.to_path_buf(),
        cause,
    }
}

/// The checkpoint directories in `dir` that carry a checksum list: `dir` itself if it is a
/// checkpoint directory, else those of [`CANDIDATES`] inside it (a run directory), in that
/// order. Complete or not: [`open`] verifies.
pub fn candidates(dir: &Path) -> Vec<PathBuf> {
    if dir.join(SUMS).exists() {
        return vec![dir.to_path_buf()];
    }
    CANDIDATES
        .iter()
        .map(|c| dir.join(c))
        .filter(|d| d.join(SUMS).exists())
        .collect()
}

/// The first checkpoint directory of [`candidates`] (whether it verifies is [`open`]'s job).
pub fn locate(dir: &Path) -> Result<PathBuf, CheckpointError> {
    candidates(dir)
        .into_iter()
        .next()
        .ok_or_else(|| CheckpointError::NotFound {
            path: dir.to_path_buf(),
        })
}

/// The run directory a checkpoint directory belongs to (its parent if it is one of
/// [`CANDIDATES`], else the directory itself).
pub fn run_dir_of(checkpoint_dir: &Path) -> PathBuf {
    match (checkpoint_dir.file_name(), checkpoint_dir.parent()) {
        (Some(n), Some(p)) if CANDIDATES.iter().any(|c| n == *c) => p.to_path_buf(),
        _ => checkpoint_dir.to_path_buf(),
    }
}

/// The pause of the [`PAUSE_ENV`] test hook, read once per [`save`].
fn test_pause() -> Option<std::time::Duration> {
    let ms: u64 = std::env::var(PAUSE_ENV).ok()?.parse().ok()?;
    (ms > 0).then(|| std::time::Duration::from_millis(ms))
}

/// Finishes what a crash interrupted, so that `checkpoint/` is the newest complete checkpoint
/// of `run_dir` (as [`open`] chooses it) and nothing else is left: a complete newer
/// `checkpoint.tmp/` (or, if `checkpoint/` does not verify, `checkpoint.old/`) is renamed into
/// place, older or partial ones are removed. [`save`] does this before it writes, and
/// `mpo train --resume` before it continues in the same directory. If no candidate is
/// complete, nothing is touched. Nothing is read in the normal state (no `checkpoint.tmp/` or
/// `checkpoint.old/`).
pub fn settle(run_dir: &Path) -> Result<(), CheckpointError> {
    let [fin, tmp, old] = CANDIDATES.map(|c| run_dir.join(c));
    if !tmp.exists() && !old.exists() {
        return Ok(());
    }
    let Ok(best) = open(run_dir) else {
        return Ok(()); // nothing complete: keep everything for inspection
    };
    let rename = |a: &Path, b: &Path| fs::rename(a, b).map_err(io(a));
    let remove = |d: &Path| {
        if d.exists() {
            fs::remove_dir_all(d).map_err(io(d))
        } else {
            Ok(())
        }
    };
    if best.dir == tmp {
        remove(&old)?;
        if fin.exists() {
            rename(&fin, &old)?;
        }
        rename(&tmp, &fin)?;
    } else if best.dir == old {
        remove(&tmp)?;
        if fin.exists() {
            rename(&fin, &tmp)?;
        }
        rename(&old, &fin)?;
    }
    // `checkpoint/` is the newest complete one and durable; the rest are older or partial.
    crate::durable::sync_dir(run_dir).map_err(io(run_dir))?;
    remove(&tmp)?;
    remove(&old)?;
    crate::durable::sync_dir(run_dir).map_err(io(run_dir))
}

/// Writes a checkpoint of `learner`, `replay` and `meta` into `run_dir/checkpoint`,
/// replacing the previous one only once the new one is complete.
pub fn save<
    const OBS: usize,
    const ACT: usize,
    const TRI: usize,
    P: PolicyTrain<OBS, ACT, TRI>,
    Q: ValueNet<OBS, ACT>,
    const BC: usize,
    const C: usize,
    const L: usize,
    const M: usize,
    const N: usize,
    const CAP: usize,
>(
    run_dir: &Path,
    learner: &LearnerOf<OBS, ACT, TRI, P, Q, BC, C, L, M, N>,
    replay: &Replay<CAP, OBS, ACT>,
    meta: &Meta,
) -> Result<(), CheckpointError> {
    let contents: [Vec<u8>; 4] = [
        serde_json::to_vec_pretty(meta).expect("meta serialises"),
        network_tensors(learner, &meta.sizes).serialize(&meta.settings),
        optimizer_tensors(learner, &meta.sizes).serialize(&meta.settings),
        replay_tensors(replay).serialize(&meta.settings),
    ];
    settle(run_dir)?;
    write_swapped(run_dir, &contents)
}

/// The online and target networks.
fn network_tensors<
    const OBS: usize,
    const ACT: usize,
    const TRI: usize,
    P: PolicyTrain<OBS, ACT, TRI>,
    Q: ValueNet<OBS, ACT>,
    const BC: usize,
    const C: usize,
    const L: usize,
    const M: usize,
    const N: usize,
>(
    learner: &LearnerOf<OBS, ACT, TRI, P, Q, BC, C, L, M, N>,
    s: &Sizes,
) -> Tensors {
    let (al, cl) = (actor_layout(s), critic_layout(s));
    let mut params = Tensors::default();
    params.params("actor", &learner.live.actor, &al);
    params.params("critic", &learner.live.critic, &cl);
    params.params("target_actor", &learner.target_actor, &al);
    params.params("target_critic", &learner.target_critic, &cl);
    params
}

/// Adam's moments and step counters, and the dual variables.
fn optimizer_tensors<
    const OBS: usize,
    const ACT: usize,
    const TRI: usize,
    P: PolicyTrain<OBS, ACT, TRI>,
    Q: ValueNet<OBS, ACT>,
    const BC: usize,
    const C: usize,
    const L: usize,
    const M: usize,
    const N: usize,
>(
    learner: &LearnerOf<OBS, ACT, TRI, P, Q, BC, C, L, M, N>,
    s: &Sizes,
) -> Tensors {
    let (al, cl) = (actor_layout(s), critic_layout(s));
    let l = &learner.live;
    let mut opt = Tensors::default();
    opt.params("actor_m", &l.actor_m, &al);
    opt.params("actor_v", &l.actor_v, &al);
    opt.params("critic_m", &l.critic_m, &cl);
    opt.params("critic_v", &l.critic_v, &cl);
    for (name, st) in [
        ("actor_opt", l.actor_opt),
        ("critic_opt", l.critic_opt),
        ("duals.opt", l.duals.opt),
    ] {
        opt.u64s(format!("{name}.t"), &[st.t]);
        opt.f32s(
            format!("{name}.beta_pow"),
            vec![2],
            &[st.beta1_pow, st.beta2_pow],
        );
    }
    let d = &l.duals;
    opt.f32s("duals.eta".into(), vec![1], &[d.eta]);
    opt.f32s("duals.eta_penalty".into(), vec![1], &[d.eta_penalty]);
    opt.f32s("duals.alpha_mean_raw".into(), vec![ACT], &d.alpha_mean_raw);
    opt.f32s("duals.alpha_cov_raw".into(), vec![ACT], &d.alpha_cov_raw);
    opt.f32s(
        "duals.moments".into(),
        vec![4, ACT],
        d.moments.as_flattened(),
    );
    opt
}

/// The replay's stored slots (a ring that is not full fills slots `0..len`).
fn replay_tensors<const CAP: usize, const OBS: usize, const ACT: usize>(
    replay: &Replay<CAP, OBS, ACT>,
) -> Tensors {
    let raw = replay.raw();
    let n = raw.counters.len as usize;
    let mut rep = Tensors::default();
    let (obs, next_obs) = (raw.obs.as_flattened(), raw.next_obs.as_flattened());
    rep.f32s("obs".into(), vec![n, OBS], &obs[..n * OBS]);
    rep.f32s(
        "action".into(),
        vec![n, ACT],
        &raw.action.as_flattened()[..n * ACT],
    );
    rep.f32s("next_obs".into(), vec![n, OBS], &next_obs[..n * OBS]);
    rep.f32s("reward".into(), vec![n], &raw.reward[..n]);
    rep.f32s("discount".into(), vec![n], &raw.discount[..n]);
    rep.f32s(
        "behaviour_log_prob".into(),
        vec![n],
        &raw.behaviour_log_prob[..n],
    );
    rep.u64s("episode".into(), &raw.episode[..n]);
    rep
}

/// Writes the files of [`FILES`] into `run_dir/checkpoint.tmp/`, each fsynced, then
/// SHA256SUMS (whose presence marks the write complete), then the directory; only then swaps
/// it in for `checkpoint/` (keeping the previous one as `checkpoint.old/` until the swap is
/// durable). The [`PAUSE_ENV`] test hook sleeps between the steps.
fn write_swapped(run_dir: &Path, contents: &[Vec<u8>; 4]) -> Result<(), CheckpointError> {
    let pause = test_pause();
    let pause = || {
        if let Some(d) = pause {
            std::thread::sleep(d);
        }
    };
    let [final_dir, tmp, old] = CANDIDATES.map(|c| run_dir.join(c));
    if tmp.exists() {
        fs::remove_dir_all(&tmp).map_err(io(&tmp))?;
    }
    fs::create_dir_all(&tmp).map_err(io(&tmp))?;
    let written = (|| {
        let mut sums = String::new();
        for (name, bytes) in FILES.iter().zip(contents) {
            pause();
            let p = tmp.join(name);
            crate::durable::write_synced(&p, bytes).map_err(io(&p))?;
            sums.push_str(&format!("{}  {name}\n", sha256_hex(bytes)));
        }
        pause();
        let p = tmp.join(SUMS);
        crate::durable::write_synced(&p, sums.as_bytes()).map_err(io(&p))?;
        crate::durable::sync_dir(&tmp).map_err(io(&tmp))
    })();
    if let Err(e) = written {
        // Best effort: free the space of the partial write (a full disk is the usual cause).
        let _ = fs::remove_dir_all(&tmp);
        return Err(e);
    }
    pause();
    if old.exists() {
        fs::remove_dir_all(&old).map_err(io(&old))?;
    }
    pause();
    if final_dir.exists() {
        fs::rename(&final_dir, &old).map_err(io(&final_dir))?;
    }
    pause();
    fs::rename(&tmp, &final_dir).map_err(io(&tmp))?;
    crate::durable::sync_dir(run_dir).map_err(io(run_dir))?;
    pause();
    if old.exists() {
        fs::remove_dir_all(&old).map_err(io(&old))?;
        crate::durable::sync_dir(run_dir).map_err(io(run_dir))?;
    }
    Ok(())
}

/// A checkpoint whose files all match their checksums, with its parsed `meta.json`.
pub struct Verified {
    /// The checkpoint directory.
    pub dir: PathBuf,
    /// Parsed metadata.
    pub meta: Meta,
    /// Set when [`open`] chose another directory than the run's `checkpoint/` (after a
    /// crash, or because `checkpoint/` does not verify): why, for a note to the user.
    pub fallback: Option<String>,
    files: HashMap<&'static str, Vec<u8>>,
}

/// Reads a checkpoint from a run directory or a checkpoint directory, checks every file
/// against SHA256SUMS and the format version, and parses `meta.json`.
///
/// In a run directory, every one of [`CANDIDATES`] with a checksum list is verified and the
/// complete one with the most environment steps is chosen (the live `checkpoint/` on a tie):
/// after a crash in the middle of [`save`] that is `checkpoint.tmp/` if its write had
/// finished, else `checkpoint/` or `checkpoint.old/`. [`Verified::fallback`] says when the
/// choice is not `checkpoint/`. If none verifies, the error is the first candidate's.
pub fn open(dir: &Path) -> Result<Verified, CheckpointError> {
    let found = candidates(dir);
    let mut best: Option<Verified> = None;
    let mut first_err = None;
    for d in found {
        match open_dir(&d) {
            Ok(v) => {
                if best
                    .as_ref()
                    .is_none_or(|b| v.meta.env_steps > b.meta.env_steps)
                {
                    best = Some(v);
                }
            }
            Err(e) => {
                first_err.get_or_insert(e);
            }
        }
    }
    match (best, first_err) {
        (Some(mut v), err) => {
            if v.dir.file_name().is_some_and(|n| n != SUBDIR) && v.dir != dir {
                v.fallback = Some(match err {
                    Some(e) => format!(
                        "{} is not usable ({e}); using {} (environment step {})",
                        dir.join(SUBDIR).display(),
                        v.dir.display(),
                        v.meta.env_steps
                    ),
                    None => format!(
                        "using {} (environment step {}), the newest complete checkpoint: a crash interrupted the swap into {}",
                        v.dir.display(),
                        v.meta.env_steps,
                        dir.join(SUBDIR).display()
                    ),
                });
            }
            Ok(v)
        }
        (None, Some(e)) => Err(e),
        (None, None) => Err(CheckpointError::NotFound {
            path: dir.to_path_buf(),
        }),
    }
}

/// [`verify`] of the files of one checkpoint directory.
pub fn open_dir(dir: &Path) -> Result<Verified, CheckpointError> {
    verify(dir, |name| fs::read(dir.join(name)))
}

/// Checks a checkpoint's files against its SHA256SUMS and the format version and parses
/// `meta.json`: everything [`open`] does after reading bytes. `read(name)` returns the bytes
/// of `SHA256SUMS` and of each of [`FILES`]; `dir` only names the files in errors. (Pure, so
/// the fuzz target `checkpoint` reaches the decoders without a file system.)
pub fn verify(
    dir: &Path,
    mut read: impl FnMut(&str) -> std::io::Result<Vec<u8>>,
) -> Result<Verified, CheckpointError> {
    let dir = dir.to_path_buf();
    let expected = read_sums(&dir, &mut read)?;
    let mut files = HashMap::new();
    for name in FILES {
        let path = dir.join(name);
        let Some(want) = expected.get(name) else {
            return Err(CheckpointError::Corrupt {
                path: dir.join(SUMS),
                message: format!("no checksum for {name}"),
            });
        };
        let bytes = read(name).map_err(io(&path))?;
        let got = sha256_hex(&bytes);
        if &got != want {
            return Err(CheckpointError::Checksum {
                path,
                expected: want.clone(),
                actual: got,
            });
        }
        files.insert(name, bytes);
    }
    let meta = parse_meta(&dir.join("meta.json"), &files["meta.json"])?;
    Ok(Verified {
        dir,
        meta,
        files,
        fallback: None,
    })
}

/// The checksum of each file from `SHA256SUMS` (`sha256sum`'s format).
fn read_sums(
    dir: &Path,
    read: &mut impl FnMut(&str) -> std::io::Result<Vec<u8>>,
) -> Result<HashMap<String, String>, CheckpointError> {
    let sums_path = dir.join(SUMS);
    let sums = read(SUMS).map_err(io(&sums_path))?;
    let sums = String::from_utf8(sums).map_err(|_| CheckpointError::Corrupt {
        path: sums_path.clone(),
        message: "not UTF-8 text".into(),
    })?;
    let mut expected = HashMap::new();
    for line in sums.lines().filter(|l| !l.trim().is_empty()) {
        let mut parts = line.split_whitespace();
        match (parts.next(), parts.next(), parts.next()) {
            (Some(h), Some(name), None) if h.len() == 64 => {
                expected.insert(name.trim_start_matches('*').to_string(), h.to_string());
            }
            _ => {
                return Err(CheckpointError::Corrupt {
                    path: sums_path,
                    message: format!("malformed line `{line}`"),
                });
            }
        }
    }
    Ok(expected)
}

/// `meta.json`, after checking its format and version (a checkpoint of another version is
/// refused, not converted).
fn parse_meta(meta_path: &Path, bytes: &[u8]) -> Result<Meta, CheckpointError> {
    let corrupt = |message: String| CheckpointError::Corrupt {
        path: meta_path.to_path_buf(),
        message,
    };
    let value: serde_json::Value =
        serde_json::from_slice(bytes).map_err(|e| corrupt(e.to_string()))?;
    let format = value.get("format").and_then(|v| v.as_str());
    if format != Some(FORMAT)
        || value.get("version").and_then(|v| v.as_u64()) != Some(VERSION as u64)
    {
        return Err(corrupt(format!(
            "not an {FORMAT} version {VERSION} file (format {}, version {}){}",
            value.get("format").unwrap_or(&serde_json::Value::Null),
            value.get("version").unwrap_or(&serde_json::Value::Null),
            if format == Some(FORMAT) {
                "; checkpoints of another version are not converted: train again, or use \
                 the release that wrote it"
            } else {
                ""
            }
        )));
    }
    serde_json::from_value(value).map_err(|e| corrupt(e.to_string()))
}

impl Verified {
    fn reader(&self, name: &'static str) -> Result<Reader<'_>, CheckpointError> {
        Reader::new(self.dir.join(name), &self.files[name])
    }

    /// Loads the online policy alone (what the inference commands need). Every file was
    /// checked against SHA256SUMS when the checkpoint was opened; the tensors' names and
    /// shapes are checked here against `meta.json`'s sizes.
    pub fn load_actor<P: Params>(&self, actor: &mut P) -> Result<(), CheckpointError> {
        let r = self.reader("params.safetensors")?;
        r.params("actor", actor, &actor_layout(&self.meta.sizes))
    }

    /// Loads the online and target networks (all `eval` needs).
    pub fn load_networks<
        const OBS: usize,
        const ACT: usize,
        const TRI: usize,
        P: PolicyTrain<OBS, ACT, TRI>,
        Q: ValueNet<OBS, ACT>,
        const BC: usize,
        const C: usize,
        const L: usize,
        const M: usize,
        const N: usize,
    >(
        &self,
        learner: &mut LearnerOf<OBS, ACT, TRI, P, Q, BC, C, L, M, N>,
    ) -> Result<(), CheckpointError> {
        let s = &self.meta.sizes;
        let (al, cl) = (actor_layout(s), critic_layout(s));
        let r = self.reader("params.safetensors")?;
        r.params("actor", &mut learner.live.actor, &al)?;
        r.params("critic", &mut learner.live.critic, &cl)?;
        r.params("target_actor", &mut learner.target_actor, &al)?;
        r.params("target_critic", &mut learner.target_critic, &cl)?;
        let got = params_sha256(&learner.live.actor, &learner.live.critic);
        if got != self.meta.params_sha256 {
            return Err(CheckpointError::Corrupt {
                path: self.dir.join("params.safetensors"),
                message: format!(
                    "parameters hash to {got}, meta.json says {}",
                    self.meta.params_sha256
                ),
            });
        }
        Ok(())
    }

    /// Loads everything into an initialised learner and a replay of the row's sizes.
    pub fn restore<
        const OBS: usize,
        const ACT: usize,
        const TRI: usize,
        P: PolicyTrain<OBS, ACT, TRI>,
        Q: ValueNet<OBS, ACT>,
        const BC: usize,
        const C: usize,
        const L: usize,
        const M: usize,
        const N: usize,
        const CAP: usize,
    >(
        &self,
        learner: &mut LearnerOf<OBS, ACT, TRI, P, Q, BC, C, L, M, N>,
        replay: &mut Replay<CAP, OBS, ACT>,
    ) -> Result<(), CheckpointError> {
        self.load_networks(learner)?;
        self.load_optimizer(learner)?;
        learner.updates = self.meta.updates;
        learner.rng_state =
            unhex32(&self.meta.learner_rng).ok_or_else(|| self.bad_meta("bad learner_rng"))?;
        self.load_replay(replay)
    }

    fn bad_meta(&self, m: &str) -> CheckpointError {
        CheckpointError::Corrupt {
            path: self.dir.join("meta.json"),
            message: m.to_string(),
        }
    }

    /// Adam's moments and counters and the dual variables.
    fn load_optimizer<
        const OBS: usize,
        const ACT: usize,
        const TRI: usize,
        P: PolicyTrain<OBS, ACT, TRI>,
        Q: ValueNet<OBS, ACT>,
        const BC: usize,
        const C: usize,
        const L: usize,
        const M: usize,
        const N: usize,
    >(
        &self,
        learner: &mut LearnerOf<OBS, ACT, TRI, P, Q, BC, C, L, M, N>,
    ) -> Result<(), CheckpointError> {
        let s = &self.meta.sizes;
        let (al, cl) = (actor_layout(s), critic_layout(s));
        let r = self.reader("optimizer.safetensors")?;
        let l = &mut learner.live;
        r.params("actor_m", &mut l.actor_m, &al)?;
        r.params("actor_v", &mut l.actor_v, &al)?;
        r.params("critic_m", &mut l.critic_m, &cl)?;
        r.params("critic_v", &mut l.critic_v, &cl)?;
        for (name, st) in [
            ("actor_opt", &mut l.actor_opt),
            ("critic_opt", &mut l.critic_opt),
            ("duals.opt", &mut l.duals.opt),
        ] {
            let mut t = [0u64];
            r.u64s(&format!("{name}.t"), &mut t)?;
            let mut p = [0f32; 2];
            r.f32s(&format!("{name}.beta_pow"), &[2], &mut p)?;
            (st.t, st.beta1_pow, st.beta2_pow) = (t[0], p[0], p[1]);
        }
        let d = &mut l.duals;
        let mut eta = [0f32];
        r.f32s("duals.eta", &[1], &mut eta)?;
        d.eta = eta[0];
        r.f32s("duals.eta_penalty", &[1], &mut eta)?;
        d.eta_penalty = eta[0];
        r.f32s("duals.alpha_mean_raw", &[ACT], &mut d.alpha_mean_raw)?;
        r.f32s("duals.alpha_cov_raw", &[ACT], &mut d.alpha_cov_raw)?;
        r.f32s("duals.moments", &[4, ACT], d.moments.as_flattened_mut())
    }

    /// The replay's slots and ring counters.
    fn load_replay<const CAP: usize, const OBS: usize, const ACT: usize>(
        &self,
        replay: &mut Replay<CAP, OBS, ACT>,
    ) -> Result<(), CheckpointError> {
        let r = self.reader("replay.safetensors")?;
        let c = self.meta.replay;
        let n = c.len as usize;
        if n > CAP {
            return Err(self.bad_meta("replay length exceeds the capacity"));
        }
        let raw = replay.raw_columns_mut();
        let obs = &mut raw.obs.as_flattened_mut()[..n * OBS];
        r.f32s("obs", &[n, OBS], obs)?;
        let action = &mut raw.action.as_flattened_mut()[..n * ACT];
        r.f32s("action", &[n, ACT], action)?;
        let next_obs = &mut raw.next_obs.as_flattened_mut()[..n * OBS];
        r.f32s("next_obs", &[n, OBS], next_obs)?;
        r.f32s("reward", &[n], &mut raw.reward[..n])?;
        r.f32s("discount", &[n], &mut raw.discount[..n])?;
        r.f32s("behaviour_log_prob", &[n], &mut raw.behaviour_log_prob[..n])?;
        r.u64s("episode", &mut raw.episode[..n])?;
        replay
            .set_counters(ReplayCounters {
                head: c.head,
                len: c.len,
                inserted: c.inserted,
                current_episode: c.current_episode,
            })
            .map_err(|e| self.bad_meta(&e.to_string()))
    }
}
