//! `mpo` against an external plant (a task file with `plant = "external"`): the plant program
//! is started from the task file (or attached to), trains in lockstep with the same bits
//! twice, evaluates from its checkpoint, and every failure of the plant (other sizes, death
//! mid-run) is a one-line error with nothing half-written. The plants: Gymnasium's
//! Pendulum-v1 served by `python/mpo_plant`, and the toy plant of
//! `mpo-link/tests/fixtures/faulty_plant.py`.

mod common;
use common::*;

use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

/// The plant venv's python, made by scripts/setup-python-plant (idempotent: instant once
/// made). A machine that cannot make it fails here with the command to run.
fn python() -> String {
    let out = Command::new(root().join("scripts/setup-python-plant"))
        .output()
        .expect("run scripts/setup-python-plant");
    assert!(
        out.status.success(),
        "scripts/setup-python-plant failed; run it by hand (it needs PyPI): {}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8(out.stdout).unwrap().trim().to_string()
}

/// A Pendulum-sized external task file in `dir` whose plant is `command` (TOML array items),
/// with `obs` and a small row `test` (the built-in 128-128 pendulum sizes).
fn task_file(dir: &Path, name: &str, obs: usize, command: &[String]) -> PathBuf {
    let command = command
        .iter()
        .map(|s| format!("{s:?}"))
        .collect::<Vec<_>>()
        .join(", ");
    let text = format!(
        r#"plant = "external"
episode_steps = 200

[external]
obs = {obs}
act = 1
action_low = [-2.0]
action_high = [2.0]
command = [{command}]
timeout = 20

[rows.test]
actor = [128, 128]
critic = [128, 128]
steps = 600
schedule = {{ warmup_steps = 400, update_interval = 2, eval_interval = 400, eval_episodes = 1 }}
mpo = {{ clip_critic_actions = true }}
"#
    );
    let path = dir.join(format!("{name}.toml"));
    std::fs::write(&path, text).unwrap();
    path
}

fn gym_command() -> Vec<String> {
    vec![
        python(),
        "-m".into(),
        "mpo_plant".into(),
        "--gym".into(),
        "Pendulum-v1".into(),
    ]
}

fn train(file: &Path, out: &Path, threads: &str, extra: &[&str]) -> std::process::Output {
    let mut args = vec![
        "train",
        "--task-file",
        file.to_str().unwrap(),
        "--net",
        "test",
        "--threads",
        threads,
        "--no-progress",
        "--out",
        out.to_str().unwrap(),
    ];
    args.extend_from_slice(extra);
    mpo(&args)
}

/// The run id `mpo` printed when it connected.
fn run_id(stderr: &str) -> String {
    let at = stderr.find("run id ").expect("the run id is printed") + "run id ".len();
    stderr[at..]
        .split(|c: char| !(c.is_ascii_alphanumeric() || c == '-'))
        .next()
        .unwrap()
        .to_string()
}

/// Files of run `id` under /dev/shm and /tmp/iceoryx2.
fn files_of(id: &str) -> Vec<String> {
    let prefix = format!("iox2_mpo_{id}_");
    let mut out = Vec::new();
    let mut stack = vec![PathBuf::from("/dev/shm"), PathBuf::from("/tmp/iceoryx2")];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).into_iter().flatten().flatten() {
            let name = e.file_name().to_string_lossy().to_string();
            if name.contains(&prefix) {
                out.push(e.path().display().to_string());
            } else if e.file_type().is_ok_and(|t| t.is_dir()) && !d.starts_with("/dev/shm") {
                stack.push(e.path());
            }
        }
    }
    out
}

#[test]
fn pendulum_in_python_trains_with_the_same_bits_twice_and_evaluates_from_its_checkpoint() {
    let dir = scratch("external-pendulum");
    let file = task_file(&dir, "pendulum-gym", 3, &gym_command());
    let (a, b) = (dir.join("a"), dir.join("b"));
    let out_a = train(&file, &a, "1", &[]);
    let ra = ok_json(&out_a);
    let stderr = String::from_utf8_lossy(&out_a.stderr).to_string();
    assert!(
        stderr.contains("external plant `gymnasium Pendulum-v1` connected"),
        "{stderr}"
    );
    assert!(
        files_of(&run_id(&stderr)).is_empty(),
        "the run's files are removed"
    );
    // Another process, another plant program, two learner threads: the same bits.
    let rb = ok_json(&train(&file, &b, "2", &[]));
    assert_eq!(ra["env_steps"], 600);
    assert_eq!(ra["params_sha256"], rb["params_sha256"]);
    assert_eq!(ra["eval_return_mean"], rb["eval_return_mean"]);

    // `mpo eval` starts the plant again and repeats the run's last evaluation.
    let eval = |extra: &[&str]| {
        let mut args = vec![
            "eval",
            "--checkpoint",
            b.to_str().unwrap(),
            "--episodes",
            "1",
        ];
        args.extend_from_slice(extra);
        ok_json(&mpo(&args))
    };
    assert_eq!(eval(&[])["return_mean"], rb["eval_return_mean"]);

    // ... and so does a plant program started by hand and attached to.
    let id = format!("attach-{}", std::process::id());
    let mut plant = Command::new(python())
        .args(["-m", "mpo_plant", "--gym", "Pendulum-v1", "--run", &id])
        .args(["--idle-timeout", "60"])
        .spawn()
        .expect("start the plant by hand");
    assert_eq!(
        eval(&["--attach-plant", &id])["return_mean"],
        rb["eval_return_mean"]
    );
    let t0 = Instant::now();
    while plant.try_wait().unwrap().is_none() {
        assert!(t0.elapsed() < Duration::from_secs(10), "BYE ends the plant");
        std::thread::sleep(Duration::from_millis(20));
    }

    // `mpo run` in lockstep: its first episode is the evaluation's.
    let run = ok_json(&mpo(&[
        "run",
        "--checkpoint",
        b.to_str().unwrap(),
        "--lockstep",
        "--steps",
        "200",
        "--no-progress",
    ]));
    assert_eq!(run["returns"][0], rb["eval_return_mean"]);

    // A plant without a model cannot be drawn: one clear line, no plant started.
    let out = mpo(&[
        "render",
        "--checkpoint",
        b.to_str().unwrap(),
        "--strip",
        dir.join("x.png").to_str().unwrap(),
    ]);
    let e = err_text(&out);
    assert!(e.contains("external plant has no model to draw"), "{e}");
    assert!(!dir.join("x.png").exists());
}

#[test]
fn a_plant_of_other_sizes_is_refused_before_anything_is_written() {
    let dir = scratch("external-sizes");
    // The task file's sizes are the learner's (a build has it); the plant declares obs 4.
    let fixture = root().join("mpo-link/tests/fixtures/faulty_plant.py");
    let command = [
        python(),
        fixture.display().to_string(),
        "--obs".into(),
        "4".into(),
    ];
    let file = task_file(&dir, "toy-obs4", 3, &command);
    let out = dir.join("run");
    let e = err_text(&train(&file, &out, "1", &[]));
    assert_eq!(
        e.lines().filter(|l| l.starts_with("error:")).count(),
        1,
        "{e}"
    );
    for part in [
        "toy-obs4.toml",
        "the plant `faulty toy` has observation size 4 and action size 1",
        "the task file says obs = 3, act = 1",
    ] {
        assert!(e.contains(part), "`{part}` missing from: {e}");
    }
    assert!(!out.exists(), "nothing is written for a refused plant");
    assert!(files_of(&run_id(&e)).is_empty());
}

#[test]
fn a_plant_that_dies_mid_run_stops_training_and_the_last_checkpoint_stays() {
    let dir = scratch("external-death");
    // Plant steps: the untrained evaluation 1-200, training 201-600, the evaluation at 400
    // environment steps 601-800 (then the checkpoint of step 400), training from 801: the
    // program exits at its 900th step, the run's environment step 500.
    let fixture = root().join("mpo-link/tests/fixtures/faulty_plant.py");
    let command = [
        python(),
        fixture.display().to_string(),
        "--die-at".into(),
        "900".into(),
    ];
    let file = task_file(&dir, "toy", 3, &command);
    let out = dir.join("run");
    let t0 = Instant::now();
    let o = train(&file, &out, "1", &["--steps", "2000"]);
    let e = err_text(&o);
    let error = e.lines().find(|l| l.starts_with("error:")).unwrap();
    for part in [
        "toy.toml (external plant, run id",
        "the plant program exited (exit status: 3)",
        "faulty_plant: exiting at step 900",
        "waiting for STEP",
        "Training stopped at environment step 499",
        "the last checkpoint (environment step 400) is kept in",
    ] {
        assert!(error.contains(part), "`{part}` missing from: {e}");
    }
    assert!(t0.elapsed() < Duration::from_secs(120));
    let meta: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("checkpoint/meta.json")).unwrap())
            .unwrap();
    assert_eq!(meta["env_steps"], 400);
    assert!(
        files_of(&run_id(&e)).is_empty(),
        "the run's files are removed"
    );
    // The checkpoint is whole: it resumes to the end (a new plant program, whose 900th step
    // is not reached: 200 training and 200 evaluation steps).
    let r = ok_json(&mpo(&[
        "train",
        "--resume",
        out.to_str().unwrap(),
        "--steps",
        "600",
        "--threads",
        "1",
        "--no-progress",
    ]));
    assert_eq!(r["env_steps"], 600);
}

#[test]
fn a_killed_learner_takes_its_plant_program_and_the_runs_files_with_it() {
    let dir = scratch("external-kill");
    let file = task_file(&dir, "pendulum-gym", 3, &gym_command());
    let mut learner = Command::new(env!("CARGO_BIN_EXE_mpo"))
        .args([
            "train",
            "--task-file",
            file.to_str().unwrap(),
            "--net",
            "test",
        ])
        .args(["--steps", "100000", "--no-progress", "--out"])
        .arg(dir.join("run"))
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let mut lines = BufReader::new(learner.stderr.take().unwrap()).lines();
    let line = lines
        .by_ref()
        .map(|l| l.unwrap())
        .find(|l| l.contains("connected (run id"))
        .expect("the plant connects");
    let pid = line
        .rsplit("pid ")
        .next()
        .unwrap()
        .trim_end_matches(')')
        .to_string();
    let id = run_id(&line);
    // SIGKILL: no BYE, no cleanup by the learner.
    learner.kill().unwrap();
    learner.wait().unwrap();
    let t0 = Instant::now();
    while Path::new(&format!("/proc/{pid}")).exists() {
        assert!(
            t0.elapsed() < Duration::from_secs(5),
            "the plant outlived its learner"
        );
        std::thread::sleep(Duration::from_millis(20));
    }
    // The plant cleared the dead learner's resources and its own on the way out.
    assert!(files_of(&id).is_empty(), "left behind: {:?}", files_of(&id));
}
