//! The learner's end of the external-plant protocol against Python plant programs in their own
//! processes: Gymnasium's Pendulum-v1 served by `python/mpo_plant`, and a toy plant
//! (`tests/fixtures/faulty_plant.py`) that answers wrongly, raises, hangs or exits on request.
//! Every failure must be a one-line error naming the cause, within the deadline, never a hang.

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::{Duration, Instant};

use mpo_link::RunId;
use mpo_link::external::{Expected, ExternalOptions, ExternalPlant, PlantCommand, PlantError};

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

fn pendulum() -> Expected {
    Expected {
        task: "pendulum-v1".into(),
        obs: 3,
        act: 1,
        episode_steps: 200,
        bounds: vec![(-2.0, 2.0)],
    }
}

fn opts(timeout_s: f64) -> ExternalOptions {
    ExternalOptions {
        connect_timeout: Duration::from_secs(60),
        timeout: Duration::from_secs_f64(timeout_s),
    }
}

fn gym() -> PlantCommand {
    PlantCommand {
        argv: vec![
            python(),
            "-m".into(),
            "mpo_plant".into(),
            "--gym".into(),
            "Pendulum-v1".into(),
        ],
        dir: root(),
    }
}

/// The toy plant with `args` (see the fixture's doc string).
fn toy(args: &[&str]) -> PlantCommand {
    let mut argv = vec![python(), "faulty_plant.py".into()];
    argv.extend(args.iter().map(|s| s.to_string()));
    PlantCommand {
        argv,
        dir: Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures"),
    }
}

/// Steps instance `env` with a constant action until the `n`th step or an error.
fn run_steps(p: &mut ExternalPlant, env: u64, n: usize) -> Result<(), PlantError> {
    let mut obs = [0f64; 3];
    p.reset(env, 1, true, &mut obs)?;
    for _ in 0..n {
        if p.step(env, &[0.5], &mut obs)?.last {
            p.reset(env, 0, false, &mut obs)?;
        }
    }
    Ok(())
}

/// One line, mentioning every one of `parts`.
fn assert_one_line(e: &PlantError, parts: &[&str]) {
    let m = e.to_string();
    assert!(!m.contains('\n'), "one line: {m}");
    for p in parts {
        assert!(m.contains(p), "`{p}` missing from: {m}");
    }
}

#[test]
fn pendulum_runs_seeded_episodes_through_the_link_and_leaves_no_files() {
    let mut p = ExternalPlant::start(&gym(), pendulum(), opts(10.0), "test").expect("connect");
    assert_eq!(p.info().name, "gymnasium Pendulum-v1");
    assert_eq!(p.info().bounds, vec![(-2.0, 2.0)]);
    let env = p.new_env();
    let mut obs = [0f64; 3];
    p.reset(env, 7, true, &mut obs).unwrap();
    let first = obs;
    // cos, sin of the angle and the velocity; Gymnasium's float32 observation, exactly.
    assert!(
        ((obs[0] * obs[0] + obs[1] * obs[1]) - 1.0).abs() < 1e-6,
        "{obs:?}"
    );
    assert!(obs.iter().all(|x| *x == (*x as f32) as f64), "{obs:?}");
    let mut returns = 0.0;
    let mut steps = 0;
    loop {
        let s = p.step(env, &[1.5], &mut obs).unwrap();
        steps += 1;
        returns += s.reward;
        assert_eq!(s.discount, 1.0, "Pendulum-v1 never terminates");
        if s.last {
            break;
        }
    }
    assert_eq!(steps, 200, "Pendulum-v1's TimeLimit truncates at 200");
    assert!(returns < 0.0);
    // A second instance seeded alike starts alike; the first one's next reset continues its
    // own random stream (a different start).
    let env2 = p.new_env();
    let mut again = [0f64; 3];
    p.reset(env2, 7, true, &mut again).unwrap();
    assert_eq!(first, again);
    p.reset(env, 0, false, &mut obs).unwrap();
    assert_ne!(obs, first);
    p.close(env2);
    let run = p.run_id().clone();
    let pid = p.pid().unwrap();
    drop(p);
    assert!(run.files().is_empty(), "left behind: {:?}", run.files());
    // The plant program exited on BYE.
    assert!(!Path::new(&format!("/proc/{pid}")).exists());
}

#[test]
fn a_plant_of_other_sizes_is_refused_naming_both() {
    let mut e = pendulum();
    e.obs = 4;
    let err = ExternalPlant::start(&gym(), e, opts(10.0), "tasks/x.toml").unwrap_err();
    assert_one_line(
        &err,
        &[
            "tasks/x.toml",
            "gymnasium Pendulum-v1",
            "observation size 3",
            "obs = 4",
        ],
    );
    let mut e = pendulum();
    e.episode_steps = 1000;
    let err = ExternalPlant::start(&gym(), e, opts(10.0), "tasks/x.toml").unwrap_err();
    assert_one_line(&err, &["after 200 steps", "episode_steps = 1000"]);
    let mut e = pendulum();
    e.bounds = vec![(-1.0, 1.0)];
    let err = ExternalPlant::start(&gym(), e, opts(10.0), "tasks/x.toml").unwrap_err();
    assert_one_line(&err, &["[-2, 2]", "[-1, 1]", "action_low"]);
}

#[test]
fn an_observation_of_the_wrong_length_is_an_error() {
    let mut p = ExternalPlant::start(&toy(&["--send-obs", "5"]), pendulum(), opts(10.0), "t")
        .expect("the handshake declares 3");
    let env = p.new_env();
    let mut obs = [0f64; 3];
    let err = p.reset(env, 1, true, &mut obs).unwrap_err();
    // The Python server catches it before it is sent.
    assert_one_line(
        &err,
        &[
            "the plant failed RESET",
            "an observation of 5 values",
            "declared obs_size = 3",
        ],
    );
}

#[test]
fn a_plant_that_exits_is_reported_at_once_with_its_last_words() {
    let mut p = ExternalPlant::start(&toy(&["--die-at", "250"]), pendulum(), opts(30.0), "t")
        .expect("connect");
    let env = p.new_env();
    let t0 = Instant::now();
    let err = run_steps(&mut p, env, 1000).unwrap_err();
    assert!(
        t0.elapsed() < Duration::from_secs(10),
        "noticed by the process, not the 30 s deadline: {:?}",
        t0.elapsed()
    );
    assert_one_line(
        &err,
        &[
            "exited",
            "exit status: 3",
            "exiting at step 250",
            "waiting for STEP",
        ],
    );
    let run = p.run_id().clone();
    drop(p);
    assert!(run.files().is_empty(), "left behind: {:?}", run.files());
}

#[test]
fn a_plant_that_hangs_misses_its_deadline() {
    let mut p = ExternalPlant::start(&toy(&["--hang-at", "10"]), pendulum(), opts(1.0), "t")
        .expect("connect");
    let env = p.new_env();
    let t0 = Instant::now();
    let err = run_steps(&mut p, env, 100).unwrap_err();
    assert!(t0.elapsed() < Duration::from_secs(5), "{:?}", t0.elapsed());
    assert_one_line(&err, &["no answer to STEP within 1.0 s", "timeout"]);
    // Dropping kills the hanging program (after its grace period).
    let pid = p.pid().unwrap();
    drop(p);
    assert!(!Path::new(&format!("/proc/{pid}")).exists());
}

#[test]
fn the_plants_own_errors_come_back_as_text() {
    let mut p = ExternalPlant::start(&toy(&["--raise-at", "5"]), pendulum(), opts(10.0), "t")
        .expect("connect");
    let env = p.new_env();
    let err = run_steps(&mut p, env, 100).unwrap_err();
    assert_one_line(
        &err,
        &[
            "the plant failed STEP",
            "ValueError: the toy broke at step 5",
        ],
    );
    let mut p = ExternalPlant::start(&toy(&["--nan-at", "3"]), pendulum(), opts(10.0), "t")
        .expect("connect");
    let env = p.new_env();
    let err = run_steps(&mut p, env, 100).unwrap_err();
    assert_one_line(&err, &["reward NaN"]);
}

#[test]
fn nobody_serving_the_run_is_a_timeout_not_a_hang() {
    // A program that never opens the services.
    let cmd = PlantCommand {
        argv: vec![python(), "-c".into(), "import time; time.sleep(60)".into()],
        dir: root(),
    };
    let o = ExternalOptions {
        connect_timeout: Duration::from_secs(1),
        timeout: Duration::from_secs(1),
    };
    let t0 = Instant::now();
    let err = ExternalPlant::start(&cmd, pendulum(), o, "t").unwrap_err();
    assert!(t0.elapsed() < Duration::from_secs(8), "{:?}", t0.elapsed());
    assert_one_line(&err, &["no plant answered within 1 s", "connect_timeout"]);
    // Attaching to a run id nobody serves.
    let run = RunId::parse("nobody-serves-this").unwrap();
    let err = ExternalPlant::attach(run.clone(), pendulum(), o, "t").unwrap_err();
    assert_one_line(&err, &["no plant answered", "is the plant program running"]);
    assert!(run.files().is_empty(), "left behind: {:?}", run.files());
    // A program that does not exist.
    let cmd = PlantCommand {
        argv: vec!["./no-such-plant".into()],
        dir: root(),
    };
    let err = ExternalPlant::start(&cmd, pendulum(), o, "t").unwrap_err();
    assert_one_line(&err, &["cannot start the plant program `./no-such-plant`"]);
}

#[test]
fn an_attached_plant_serves_like_a_started_one() {
    let run = RunId::new();
    let mut plant = Command::new(python())
        .args([
            "-m",
            "mpo_plant",
            "--gym",
            "Pendulum-v1",
            "--run",
            run.as_str(),
        ])
        .args(["--idle-timeout", "30"])
        .current_dir(root())
        .spawn()
        .expect("start the plant");
    let mut attached = ExternalPlant::attach(run, pendulum(), opts(10.0), "t").expect("attach");
    let mut started = ExternalPlant::start(&gym(), pendulum(), opts(10.0), "t").expect("start");
    let (a, b) = (attached.new_env(), started.new_env());
    let (mut x, mut y) = ([0f64; 3], [0f64; 3]);
    attached.reset(a, 11, true, &mut x).unwrap();
    started.reset(b, 11, true, &mut y).unwrap();
    for k in 0..300 {
        let act = [((k as f64) * 0.1).sin() * 2.0];
        let (sa, sb) = (
            attached.step(a, &act, &mut x).unwrap(),
            started.step(b, &act, &mut y).unwrap(),
        );
        assert_eq!((x, sa), (y, sb), "step {k}");
        if sa.last {
            attached.reset(a, 0, false, &mut x).unwrap();
            started.reset(b, 0, false, &mut y).unwrap();
        }
    }
    drop(attached);
    // BYE ends the attached program too (it was not started with --keep-serving).
    let t0 = Instant::now();
    while plant.try_wait().unwrap().is_none() {
        assert!(t0.elapsed() < Duration::from_secs(5), "plant still running");
        std::thread::sleep(Duration::from_millis(20));
    }
}
