//! Writes the seed corpus of every fuzz target (`fuzz/corpus/<target>/`) from the real
//! encoders: checkpoints written by `mpo train` and by `checkpoint::save`, the `config.toml` a
//! run writes and the `--set` examples of the docs, action files written with Rust's
//! shortest float formatting, link messages from the plant's and the controller's encoders,
//! firmware records of real Control Suite observations, device frames from
//! `mpo_frames::encode`, and the repository's task files (tasks/, tasks/gymnasium/) with
//! expressions of the kinds they use.
//!
//! cargo +nightly fuzz build make_corpus &&
//!     fuzz/target/x86_64-unknown-linux-gnu/release/make_corpus fuzz/corpus RUN_DIR...
//! (each RUN_DIR from `mpo train --net tiny --steps N --out RUN_DIR`; with no RUN_DIR only
//! the task_file corpus is written)

use std::path::{Path, PathBuf};

use mpo_core::actor::Actor;
use mpo_core::rng::Rng;
use mpo_fuzz::{actions_csv, checkpoint as ck, config, frames, link, task_file};
use mpo_host::checkpoint;
use mpo_host::commands;
use mpo_host::trainer::MlpTrainer as Trainer;
use mpo_link::controller::{ControllerStats, respond};
use mpo_link::messages::{ActMsg, CHECKSUM_SEED, ObsMsg, ParamChunk, checksum};

/// The `cartpole-balance`/`tiny` row's types (as in mpo-host/tests/checkpoint.rs).
type Tiny = Trainer<5, 1, 1, 32, 32, 32, 32, 32, 2, 4, 10, 10, 50_000>;

fn write(out: &Path, target: &str, name: &str, bytes: &[u8]) {
    let dir = out.join(target);
    std::fs::create_dir_all(&dir).unwrap();
    std::fs::write(dir.join(name), bytes).unwrap();
    println!("{target}/{name}: {} bytes", bytes.len());
}

fn checkpoint_files(dir: &Path) -> [Vec<u8>; 5] {
    ck::NAMES.map(|n| std::fs::read(dir.join(n)).unwrap())
}

/// A checkpoint of a few warm-up steps through `checkpoint::save` (a small replay).
fn small_checkpoint(tmp: &Path) -> [Vec<u8>; 5] {
    let row = mpo_host::table::row("cartpole-balance", "tiny").unwrap();
    let settings = commands::defaults(row);
    let mut t = Tiny::new(&settings, None, 1).unwrap();
    t.collect(8).unwrap();
    let meta = t.meta(checkpoint::Meta::new(
        settings.clone(),
        None,
        row.sizes,
        vec![],
        0.5,
    ));
    let _ = std::fs::remove_dir_all(tmp);
    std::fs::create_dir_all(tmp).unwrap();
    checkpoint::save(tmp, &t.agent.learner, &t.agent.replay, &meta).unwrap();
    checkpoint_files(&tmp.join(checkpoint::SUBDIR))
}

fn main() {
    let args: Vec<PathBuf> = std::env::args_os().skip(1).map(PathBuf::from).collect();
    let (out, runs) = args
        .split_first()
        .expect("usage: make_corpus OUT RUN_DIR...");
    task_files(out);
    if runs.is_empty() {
        return;
    }

    // checkpoint: real runs with their own SHA256SUMS and with the fix-up flag, and a small one.
    for run in runs {
        let name = run.file_name().unwrap().to_string_lossy();
        let files = checkpoint_files(&run.join(checkpoint::SUBDIR));
        write(
            out,
            "checkpoint",
            &format!("{name}"),
            &ck::encode(0, &files),
        );
        write(
            out,
            "checkpoint",
            &format!("{name}-fix"),
            &ck::encode(ck::FIX_SUMS, &files),
        );
    }
    let small = small_checkpoint(&std::env::temp_dir().join("mpo-fuzz-small-checkpoint"));
    write(
        out,
        "checkpoint",
        "small-8-steps-fix",
        &ck::encode(ck::FIX_SUMS, &small),
    );
    write(out, "checkpoint", "small-8-steps", &ck::encode(0, &small));

    // config: a run's config.toml (file layer) and the documented --set forms.
    let cfg = std::fs::read_to_string(runs[0].join("config.toml")).unwrap();
    write(
        out,
        "config",
        "run-config-toml",
        &config::encode(0, &cfg, &[]),
    );
    write(
        out,
        "config",
        "run-config-toml-resume",
        &config::encode(config::RESUME, &cfg, &[]),
    );
    let sets = [
        "mpo.actor_lr=1e-4",
        "schedule.update_interval=4",
        "schedule.eval_interval=1000",
        "mpo.policy_evaluation=\"retrace\"",
        "mpo.n_step=3",
        "mpo.target_tau=0.01",
        "mpo.per_dim_kl=true",
        "task=hopper-stand",
    ];
    write(
        out,
        "config",
        "sets",
        &config::encode(config::NET, "", &sets[..7]),
    );
    write(
        out,
        "config",
        "sets-task",
        &config::encode(config::SEED | config::STEPS, "", &sets[7..]),
    );
    write(
        out,
        "config",
        "file-and-set-resume",
        &config::encode(
            config::RESUME | config::NET,
            "steps = 4000\n[schedule]\neval_interval = 1000\n",
            &["steps=5000"],
        ),
    );
    write(
        out,
        "config",
        "file-task-net",
        &config::encode(
            config::TASK,
            "task = \"cartpole-balance\"\nnet = \"tiny\"\nseed = 3\n[mpo]\neps_eta = 0.05\n",
            &[],
        ),
    );

    // actions_csv: rows as the sim-bridge tests write them, random actions in and out of
    // [-1, 1], for one, four and six actuators.
    let mut rng = Rng::seed_from_u64(11);
    for width in [1usize, 4, 6] {
        let mut csv = String::new();
        for i in 0..20 {
            let row: Vec<String> = (0..width)
                .map(|j| {
                    let x = if i % 2 == 0 {
                        ((i * 7 + j) % 11) as f64 / 5.0 - 1.0
                    } else {
                        3.0 * (rng.uniform() as f64 * 2.0 - 1.0)
                    };
                    format!("{x}")
                })
                .collect();
            csv.push_str(&(row.join(",") + "\n"));
        }
        write(
            out,
            "actions_csv",
            &format!("width{width}"),
            &actions_csv::encode(width, &csv),
        );
    }

    // link_messages: a parameter push of a cartpole-64 policy (the plant's encoder), a
    // sampled and a mean request (the plant's), the controller's replies.
    let mut policy: Box<Actor<5, 1, 1, 64, 64>> = bytemuck::zeroed_box();
    policy.init(&mut Rng::seed_from_u64(5), 0.5, 1e-4);
    let mut total = CHECKSUM_SEED;
    for k in 0..<Actor<5, 1, 1, 64, 64> as mpo_core::params::Params>::TENSORS {
        total = checksum(total, mpo_core::params::Params::tensor(&*policy, k));
    }
    let mut chunk: Box<ParamChunk> = bytemuck::zeroed_box();
    let mut push = Vec::new();
    for index in 0..2 {
        chunk.set_block(&*policy, 1, index, total);
        link::push(&mut push, link::CHUNK, bytemuck::bytes_of(&*chunk));
    }
    let obs = [0.1f32, -0.5, 0.9, 0.02, -1.3];
    let mut msgs = Vec::new();
    let mut stats = ControllerStats::default();
    for (seq, noise) in [(1u64, Some(&[0.7f32][..])), (2, None)] {
        let mut req: ObsMsg = bytemuck::Zeroable::zeroed();
        req.seq = seq;
        req.set_observation(&obs, noise, 1e-4);
        let mut reply: ActMsg = bytemuck::Zeroable::zeroed();
        respond(&policy, &req, 1, &mut stats, &mut reply);
        link::push(&mut msgs, link::OBS, bytemuck::bytes_of(&req));
        link::push(&mut msgs, link::ACT, bytemuck::bytes_of(&reply));
    }
    let with_flags = |flags: u8, parts: &[&[u8]]| -> Vec<u8> {
        let mut v = vec![flags];
        for p in parts {
            v.extend(*p);
        }
        v
    };
    write(out, "link_messages", "requests", &with_flags(0, &[&msgs]));
    write(
        out,
        "link_messages",
        "push-then-requests",
        &with_flags(0, &[&push, &msgs]),
    );
    write(
        out,
        "link_messages",
        "push-fix",
        &with_flags(link::FIX_CHECKSUMS, &[&push, &msgs]),
    );

    // firmware_records: real observations of cartpole-balance and hopper-stand under random
    // actions, one record with a NaN, and a truncated tail.
    for (which, task) in [(0u8, "cartpole-balance"), (1, "hopper-stand")] {
        let mut env = sim_bridge::make(task, 0).unwrap();
        let spec = env.spec().clone();
        let mut o = vec![0f64; spec.obs_dim];
        env.reset(&mut o);
        let mut recs = vec![which];
        for i in 0..24 {
            let a: Vec<f64> = (0..spec.act_dim)
                .map(|_| rng.uniform() as f64 * 2.0 - 1.0)
                .collect();
            env.step(&a, &mut o);
            for (j, x) in o.iter().enumerate() {
                let v = if i == 5 && j == 0 {
                    f32::NAN
                } else {
                    *x as f32
                };
                recs.extend(v.to_le_bytes());
            }
        }
        write(out, "firmware_records", task, &recs);
        let cut = recs.len() - 3;
        write(
            out,
            "firmware_records",
            &format!("{task}-truncated"),
            &recs[..cut],
        );
    }

    // device_frames: one frame of every kind with its payload length (OBS 5, ACT 1, 300
    // parameters, as the target's receivers), as a stream and as encoder records.
    use mpo_frames::{COUNTERS_LEN, Counters, START_LEN, encode, encoded_max, kind};
    let mut counters = [0u8; COUNTERS_LEN];
    Counters {
        env_steps: 1000,
        updates: 250,
        rejected: 1,
        resent: 2,
    }
    .encode(&mut counters);
    let obs_bytes: Vec<u8> = obs.iter().flat_map(|x| x.to_le_bytes()).collect();
    let mut step = vec![0u8; 9];
    step[..4].copy_from_slice(&0.5f32.to_le_bytes());
    step[4..8].copy_from_slice(&0.99f32.to_le_bytes());
    step.extend(&obs_bytes);
    let mut info = vec![];
    for v in [1u16, 5, 1] {
        info.extend(v.to_le_bytes());
    }
    info.extend(300u32.to_le_bytes());
    info.extend(50_000u32.to_le_bytes());
    let mut error = vec![3u8];
    error.extend(counters);
    let mut params_reply = counters.to_vec();
    params_reply.extend((0..300).flat_map(|i| (i as f32 * 0.01).to_le_bytes()));
    let frames_list: Vec<(u8, Vec<u8>)> = vec![
        (kind::HELLO, vec![]),
        (kind::START, vec![0u8; START_LEN]),
        (kind::BEGIN, obs_bytes.clone()),
        (kind::STEP, step),
        (kind::EVAL, obs_bytes.clone()),
        (kind::PARAMS, vec![]),
        (kind::INFO, info),
        (kind::ACK, counters.to_vec()),
        (
            kind::ACTION,
            [0.25f32, -1.5]
                .iter()
                .flat_map(|x| x.to_le_bytes())
                .collect(),
        ),
        (kind::PARAMS_REPLY, params_reply),
        (kind::ERROR, error),
    ];
    let (mut stream, mut records) = (vec![0u8], vec![1u8]);
    for (seq, (k, p)) in frames_list.iter().enumerate() {
        let mut buf = vec![0u8; encoded_max(p.len())];
        let n = encode(*k, seq as u8, p, &mut buf);
        stream.extend(&buf[..n]);
        frames::push_record(&mut records, *k, seq as u8, p);
    }
    write(out, "device_frames", "stream", &stream);
    write(out, "device_frames", "records", &records);
}

/// task_file: every task file of the repository, and template expressions (see
/// `mpo_fuzz::task_file`) on each template model.
fn task_files(out: &Path) {
    let tasks = Path::new(env!("CARGO_MANIFEST_DIR")).join("../tasks");
    for dir in [tasks.clone(), tasks.join("gymnasium")] {
        let mut files: Vec<PathBuf> = std::fs::read_dir(&dir)
            .unwrap()
            .flatten()
            .map(|e| e.path())
            .filter(|p| p.extension().is_some_and(|x| x == "toml"))
            .collect();
        files.sort();
        for f in files {
            let text = std::fs::read_to_string(&f).unwrap();
            let name = f.file_stem().unwrap().to_string_lossy();
            write(out, "task_file", &name, &task_file::encode_file(&text));
        }
    }
    // (mode, expression): mode % 4 picks the model (cartpole, walker, Gymnasium's cheetah,
    // Gymnasium's double pendulum), odd modes also terminate on it.
    let expressions = [
        (
            4,
            "tolerance(xmat('pole_1', 'zz'), bounds=(0.9, 1), margin=0.5, sigmoid='long_tail')",
        ),
        (
            8,
            "(1 + min(tolerance(qvel[1:], margin=5, sigmoid='reciprocal'))) / 2 * qpos('slider') ** 2",
        ),
        (
            1,
            "xpos('torso', 'z') < 0.8 or abs(xmat('torso', 'zz')) < 0.5",
        ),
        (
            5,
            "clip(qfrc_constraint, -10, 10)[0] + norm(body_linvel('torso', frame='world')) + mean(cvel('*')[:3])",
        ),
        (
            9,
            "where(sensor('torso_subtreelinvel')[0] > 1, 1, exp(-abs(qvel[0]))) * prod(ctrlrange('right_hip'))",
        ),
        (
            2,
            "(qpos('rootx') - prev(qpos('rootx'))) / dt - 0.1 * sum(square(action))",
        ),
        (
            6,
            "arctan2(xipos('torso', 'z'), subtree_com('torso')[0]) + log1p(sum(geom_xpos('*')[-3:]))",
        ),
        (3, "site_xpos('tip', 'z') <= 1"),
        (
            7,
            "10 * (not site_xpos('tip', 'z') <= 1) - 0.01 * site_xpos('tip', 'x') ** 2 - maximum(qvel, -qvel)[1]",
        ),
    ];
    for (i, (mode, e)) in expressions.iter().enumerate() {
        write(
            out,
            "task_file",
            &format!("expression-{i}"),
            &task_file::encode_expression(*mode, e),
        );
    }
}
