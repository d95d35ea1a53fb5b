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
//! `episodes` resets. A new checkpoint is written beside the old one and swapped in by
//! renames, so an interrupted write leaves the previous checkpoint intact.

use std::collections::HashMap;
use std::fs;
use std::path::{Path, PathBuf};

use mpo_core::learner::Learner;
use mpo_core::params::Params;
use mpo_core::replay::{Replay, ReplayCounters};
use safetensors::tensor::{Dtype, SafeTensors, TensorView};
use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};

use crate::metrics::{MetricsRow, StatsAccumulator};
use crate::settings::Settings;
use crate::tasks::Sizes;

/// Format identifier in `meta.json`.
pub const FORMAT: &str = "mpo-checkpoint";
/// Format version; bumped on any incompatible change.
pub const VERSION: u32 = 2;
/// The checkpoint's subdirectory in a run directory.
pub const SUBDIR: &str = "checkpoint";
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
    #[error("{path}: {source}")]
    Io {
        /// File.
        path: PathBuf,
        /// Cause.
        source: std::io::Error,
    },
    /// No checkpoint where one was expected.
    #[error("no checkpoint in {path} (expected {path}/{SUBDIR}/{SUMS} or {path}/{SUMS})")]
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

fn sha256_hex(bytes: &[u8]) -> String {
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

/// Tensor names and `[in, out]` shapes of the actor, in tensor order.
pub fn actor_layout(s: &Sizes) -> Vec<(&'static str, Vec<usize>)> {
    let tri = s.act * (s.act + 1) / 2;
    let [h1, h2] = s.actor;
    vec![
        ("l1.w", vec![s.obs, h1]),
        ("l1.b", vec![h1]),
        ("l2.w", vec![h1, h2]),
        ("l2.b", vec![h2]),
        ("mean.w", vec![h2, s.act]),
        ("mean.b", vec![s.act]),
        ("chol.w", vec![h2, tri]),
        ("chol.b", vec![tri]),
    ]
}

/// Tensor names and shapes of the critic, in tensor order.
pub fn critic_layout(s: &Sizes) -> Vec<(&'static str, Vec<usize>)> {
    let [h1, h2] = s.critic;
    vec![
        ("l1s.w", vec![s.obs, h1]),
        ("l1s.b", vec![h1]),
        ("l1a.w", vec![s.act, h1]),
        ("l2.w", vec![h1, h2]),
        ("l2.b", vec![h2]),
        ("out.w", vec![h2, 1]),
        ("out.b", vec![1]),
    ]
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
    fn params<P: Params>(&mut self, prefix: &str, p: &P, layout: &[(&str, Vec<usize>)]) {
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
        layout: &[(&str, Vec<usize>)],
    ) -> Result<(), CheckpointError> {
        for (k, (name, shape)) in layout.iter().enumerate() {
            self.f32s(&format!("{prefix}.{name}"), shape, p.tensor_mut(k))?;
        }
        Ok(())
    }
}

fn io(path: &Path) -> impl FnOnce(std::io::Error) -> CheckpointError + '_ {
    move |source| CheckpointError::Io {
        path: path.to_path_buf(),
        source,
    }
}

/// The checkpoint directory inside a run directory (or the directory itself if it is one).
pub fn locate(dir: &Path) -> Result<PathBuf, CheckpointError> {
    if dir.join(SUBDIR).join(SUMS).exists() {
        Ok(dir.join(SUBDIR))
    } else if dir.join(SUMS).exists() {
        Ok(dir.to_path_buf())
    } else {
        Err(CheckpointError::NotFound {
            path: dir.to_path_buf(),
        })
    }
}

/// Writes a checkpoint of `learner`, `replay` and `meta` into `run_dir/checkpoint`,
/// replacing the previous one only once the new one is complete.
pub fn save<
    const OBS: usize,
    const ACT: usize,
    const TRI: usize,
    const AH1: usize,
    const AH2: usize,
    const QH1: usize,
    const QH2: usize,
    const BC: usize,
    const C: usize,
    const L: usize,
    const M: usize,
    const N: usize,
    const CAP: usize,
>(
    run_dir: &Path,
    learner: &Learner<OBS, ACT, TRI, AH1, AH2, QH1, QH2, BC, C, L, M, N>,
    replay: &Replay<CAP, OBS, ACT>,
    meta: &Meta,
) -> Result<(), CheckpointError> {
    let s = &meta.sizes;
    let (al, cl) = (actor_layout(s), critic_layout(s));
    let mut params = Tensors::default();
    params.params("actor", &learner.live.actor, &al);
    params.params("critic", &learner.live.critic, &cl);
    params.params("target_actor", &learner.target_actor, &al);
    params.params("target_critic", &learner.target_critic, &cl);

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

    let raw = replay.raw();
    let n = raw.counters.len as usize; // a ring that is not full fills slots 0..len
    let mut rep = Tensors::default();
    rep.f32s(
        "obs".into(),
        vec![n, OBS],
        &raw.obs.as_flattened()[..n * OBS],
    );
    rep.f32s(
        "action".into(),
        vec![n, ACT],
        &raw.action.as_flattened()[..n * ACT],
    );
    rep.f32s(
        "next_obs".into(),
        vec![n, OBS],
        &raw.next_obs.as_flattened()[..n * OBS],
    );
    rep.f32s("reward".into(), vec![n], &raw.reward[..n]);
    rep.f32s("discount".into(), vec![n], &raw.discount[..n]);
    rep.f32s(
        "behaviour_log_prob".into(),
        vec![n],
        &raw.behaviour_log_prob[..n],
    );
    rep.u64s("episode".into(), &raw.episode[..n]);

    let contents: [Vec<u8>; 4] = [
        serde_json::to_vec_pretty(meta).expect("meta serialises"),
        params.serialize(&meta.settings),
        opt.serialize(&meta.settings),
        rep.serialize(&meta.settings),
    ];
    let final_dir = run_dir.join(SUBDIR);
    let tmp = run_dir.join(format!("{SUBDIR}.tmp"));
    let old = run_dir.join(format!("{SUBDIR}.old"));
    if tmp.exists() {
        fs::remove_dir_all(&tmp).map_err(io(&tmp))?;
    }
    fs::create_dir_all(&tmp).map_err(io(&tmp))?;
    let mut sums = String::new();
    for (name, bytes) in FILES.iter().zip(&contents) {
        let p = tmp.join(name);
        crate::metrics::write_atomic(&p, bytes).map_err(io(&p))?;
        sums.push_str(&format!("{}  {name}\n", sha256_hex(bytes)));
    }
    let p = tmp.join(SUMS);
    crate::metrics::write_atomic(&p, sums.as_bytes()).map_err(io(&p))?;
    if old.exists() {
        fs::remove_dir_all(&old).map_err(io(&old))?;
    }
    if final_dir.exists() {
        fs::rename(&final_dir, &old).map_err(io(&final_dir))?;
    }
    fs::rename(&tmp, &final_dir).map_err(io(&tmp))?;
    if old.exists() {
        fs::remove_dir_all(&old).map_err(io(&old))?;
    }
    Ok(())
}

/// A checkpoint whose files all match their checksums, with its parsed `meta.json`.
pub struct Verified {
    /// The checkpoint directory.
    pub dir: PathBuf,
    /// Parsed metadata.
    pub meta: Meta,
    files: HashMap<&'static str, Vec<u8>>,
}

/// Reads a checkpoint (from a run directory or the checkpoint directory itself), checks every
/// file against SHA256SUMS and the format version, and parses `meta.json`.
pub fn open(dir: &Path) -> Result<Verified, CheckpointError> {
    let dir = locate(dir)?;
    let sums_path = dir.join(SUMS);
    let sums = fs::read_to_string(&sums_path).map_err(io(&sums_path))?;
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
    let mut files = HashMap::new();
    for name in FILES {
        let path = dir.join(name);
        let Some(want) = expected.get(name) else {
            return Err(CheckpointError::Corrupt {
                path: sums_path,
                message: format!("no checksum for {name}"),
            });
        };
        let bytes = fs::read(&path).map_err(io(&path))?;
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
    let meta_path = dir.join("meta.json");
    let value: serde_json::Value =
        serde_json::from_slice(&files["meta.json"]).map_err(|e| CheckpointError::Corrupt {
            path: meta_path.clone(),
            message: e.to_string(),
        })?;
    if value.get("format").and_then(|v| v.as_str()) != Some(FORMAT)
        || value.get("version").and_then(|v| v.as_u64()) != Some(VERSION as u64)
    {
        return Err(CheckpointError::Corrupt {
            path: meta_path,
            message: format!(
                "not an {FORMAT} version {VERSION} file (format {}, version {})",
                value.get("format").unwrap_or(&serde_json::Value::Null),
                value.get("version").unwrap_or(&serde_json::Value::Null)
            ),
        });
    }
    let meta: Meta = serde_json::from_value(value).map_err(|e| CheckpointError::Corrupt {
        path: meta_path,
        message: e.to_string(),
    })?;
    Ok(Verified { dir, meta, files })
}

impl Verified {
    fn reader(&self, name: &'static str) -> Result<Reader<'_>, CheckpointError> {
        Reader::new(self.dir.join(name), &self.files[name])
    }

    /// Loads the online and target networks (all `eval` needs).
    pub fn load_networks<
        const OBS: usize,
        const ACT: usize,
        const TRI: usize,
        const AH1: usize,
        const AH2: usize,
        const QH1: usize,
        const QH2: usize,
        const BC: usize,
        const C: usize,
        const L: usize,
        const M: usize,
        const N: usize,
    >(
        &self,
        learner: &mut Learner<OBS, ACT, TRI, AH1, AH2, QH1, QH2, BC, C, L, M, N>,
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
        const AH1: usize,
        const AH2: usize,
        const QH1: usize,
        const QH2: usize,
        const BC: usize,
        const C: usize,
        const L: usize,
        const M: usize,
        const N: usize,
        const CAP: usize,
    >(
        &self,
        learner: &mut Learner<OBS, ACT, TRI, AH1, AH2, QH1, QH2, BC, C, L, M, N>,
        replay: &mut Replay<CAP, OBS, ACT>,
    ) -> Result<(), CheckpointError> {
        self.load_networks(learner)?;
        let meta = &self.meta;
        let s = &meta.sizes;
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
            st.t = t[0];
            st.beta1_pow = p[0];
            st.beta2_pow = p[1];
        }
        let d = &mut l.duals;
        let mut eta = [0f32];
        r.f32s("duals.eta", &[1], &mut eta)?;
        d.eta = eta[0];
        r.f32s("duals.eta_penalty", &[1], &mut eta)?;
        d.eta_penalty = eta[0];
        r.f32s("duals.alpha_mean_raw", &[ACT], &mut d.alpha_mean_raw)?;
        r.f32s("duals.alpha_cov_raw", &[ACT], &mut d.alpha_cov_raw)?;
        r.f32s("duals.moments", &[4, ACT], d.moments.as_flattened_mut())?;
        learner.updates = meta.updates;
        let bad_meta = |m: &str| CheckpointError::Corrupt {
            path: self.dir.join("meta.json"),
            message: m.to_string(),
        };
        learner.rng_state =
            unhex32(&meta.learner_rng).ok_or_else(|| bad_meta("bad learner_rng"))?;

        let r = self.reader("replay.safetensors")?;
        let c = meta.replay;
        let n = c.len as usize;
        if n > CAP {
            return Err(bad_meta("replay length exceeds the capacity"));
        }
        let raw = replay.raw_columns_mut();
        r.f32s("obs", &[n, OBS], &mut raw.obs.as_flattened_mut()[..n * OBS])?;
        r.f32s(
            "action",
            &[n, ACT],
            &mut raw.action.as_flattened_mut()[..n * ACT],
        )?;
        r.f32s(
            "next_obs",
            &[n, OBS],
            &mut raw.next_obs.as_flattened_mut()[..n * OBS],
        )?;
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
            .map_err(|e| bad_meta(&e.to_string()))?;
        Ok(())
    }
}
