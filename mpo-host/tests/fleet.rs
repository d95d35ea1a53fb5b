//! `mpo train --plants N` (docs/fleet.md): a one-plant deterministic fleet with one step per
//! block is the in-process run bit for bit; a two-plant deterministic run repeats its bits; a
//! killed plant is dropped and the run finishes, or is restarted and rejoins; a fleet run
//! resumed is the uninterrupted run; a plant started by hand joins a resumed learner; a plant
//! of another task is refused, and says so; the run's iceoryx2 files are its user's alone.

mod common;

use std::io::{BufRead, BufReader};
use std::process::{Command, Stdio};
use std::time::Duration;

use common::{ok_json, scratch, tiny};

fn sha(v: &serde_json::Value) -> &str {
    v["params_sha256"].as_str().unwrap()
}

#[test]
fn one_plant_stepping_once_per_round_is_the_in_process_run() {
    let dir = scratch("fleet-one");
    let alone = ok_json(&tiny(&dir.join("in-process"), 2000, &[]));
    let fleet = ok_json(&tiny(
        &dir.join("fleet"),
        2000,
        &["--plants", "1", "--sync-every", "1"],
    ));
    assert_eq!(sha(&fleet), sha(&alone));
    assert_eq!(fleet["updates"], alone["updates"]);
    assert_eq!(fleet["eval_return_mean"], alone["eval_return_mean"]);
    assert_eq!(fleet["fleet"]["transitions"], 2000);
    assert_eq!(fleet["fleet"]["rounds"], 2000);
}

#[test]
fn two_plants_in_rounds_repeat_their_bits() {
    let dir = scratch("fleet-two");
    let args = ["--plants", "2", "--sync-every", "10"];
    let a = ok_json(&tiny(&dir.join("a"), 2000, &args));
    let b = ok_json(&tiny(&dir.join("b"), 2000, &args));
    assert_eq!(sha(&a), sha(&b));
    assert_eq!(a["fleet"]["blocks"], 200);
    // Plant 1 adds its own episodes: not the one-plant run.
    let one = ok_json(&tiny(
        &dir.join("one"),
        2000,
        &["--plants", "1", "--sync-every", "10"],
    ));
    assert_ne!(sha(&a), sha(&one));
}

#[test]
fn free_running_plants_train_at_the_rows_update_ratio() {
    let dir = scratch("fleet-free");
    let s = ok_json(&tiny(&dir, 2000, &["--plants", "2", "--schedule", "free"]));
    let f = &s["fleet"];
    let inserted = f["transitions"].as_u64().unwrap();
    assert!(inserted >= 2000, "{f}");
    // The tiny row: warm-up 500, one update every 4 inserted transitions.
    assert_eq!(s["updates"].as_u64().unwrap(), (inserted - 500) / 4 + 1);
    assert_eq!(f["dropped"], 0);
}

/// Runs `mpo train` of the tiny row with `args`, kills plant 1's process (SIGKILL) when it
/// first joins, and returns the summary and the log.
fn kill_plant_one(dir: &std::path::Path, args: &[&str]) -> (serde_json::Value, String) {
    signal_plant_one(dir, args, "-KILL")
}

/// As [`kill_plant_one`], with the signal `signal` (`-KILL`, `-STOP`).
fn signal_plant_one(
    dir: &std::path::Path,
    args: &[&str],
    signal: &str,
) -> (serde_json::Value, String) {
    let mut child = Command::new(env!("CARGO_BIN_EXE_mpo"))
        .args(["train", "--net", "tiny", "--no-progress", "--steps", "3000"])
        .args(["--plants", "2", "--sync-every", "10", "--out"])
        .arg(dir)
        .args(args)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let stderr = BufReader::new(child.stderr.take().unwrap());
    let mut log = String::new();
    let mut killed = false;
    for line in stderr.lines() {
        let line = line.unwrap();
        log.push_str(&line);
        log.push('\n');
        if !killed && let Some(rest) = line.strip_prefix("fleet: plant 1 joined (pid ") {
            let pid = rest.split(',').next().unwrap();
            let st = Command::new("kill").args([signal, pid]).status().unwrap();
            assert!(st.success());
            killed = true;
        }
    }
    let out = child.wait_with_output().unwrap();
    assert!(killed, "plant 1 never joined:\n{log}");
    assert!(out.status.success(), "{:?}\n{log}", out.status);
    (serde_json::from_slice(&out.stdout).unwrap(), log)
}

#[test]
fn a_killed_plant_is_dropped_and_the_run_goes_on() {
    let dir = scratch("fleet-kill");
    let (s, log) = kill_plant_one(&dir, &["--plant-restarts", "0"]);
    assert_eq!(s["env_steps"], 3000, "{log}");
    assert_eq!(s["fleet"]["dropped"], 1);
    assert_eq!(s["fleet"]["restarted"], 0);
    assert!(log.contains("fleet: plant 1 (pid") && log.contains("dropped: its process exited"));
    assert!(log.contains("plant 1 is not restarted"), "{log}");
}

#[test]
fn a_killed_plant_is_restarted_and_rejoins_with_its_streams() {
    let dir = scratch("fleet-restart");
    let (s, log) = kill_plant_one(&dir, &[]);
    // Rounds of one plant while plant 1 was away, then of two: the run ends at the first
    // round's end at or past its steps.
    let steps = s["env_steps"].as_u64().unwrap();
    assert!((3000..3020).contains(&steps), "{steps}\n{log}");
    let f = &s["fleet"];
    assert_eq!(f["dropped"], 1, "{log}");
    assert_eq!(f["restarted"], 1, "{log}");
    assert_eq!(f["rejoined"], 1, "{log}");
    assert!(
        log.contains("fleet: plant 1 restarted (restart 1 of 3)"),
        "{log}"
    );
    assert!(log.contains("fleet: plant 1 rejoined (pid"), "{log}");
    // Both plants delivered blocks after the restart: more blocks than plant 0 alone makes.
    assert!(f["blocks"].as_u64().unwrap() > 3000 / 10 / 2 + 10, "{f}");
}

#[test]
fn a_hung_plant_is_dropped_after_its_timeout_restarted_and_rejoins() {
    let dir = scratch("fleet-hang");
    // SIGSTOP: the process lives on but says nothing; the learner drops it after 2 s of
    // silence, kills it, and starts it again.
    let (s, log) = signal_plant_one(&dir, &["--plant-timeout", "2"], "-STOP");
    let steps = s["env_steps"].as_u64().unwrap();
    assert!((3000..3020).contains(&steps), "{steps}\n{log}");
    let f = &s["fleet"];
    assert_eq!(f["dropped"], 1, "{log}");
    assert_eq!(f["restarted"], 1, "{log}");
    assert_eq!(f["rejoined"], 1, "{log}");
    assert!(log.contains("dropped: silent for 2 s"), "{log}");
    assert!(log.contains("fleet: plant 1 rejoined (pid"), "{log}");
}

#[test]
fn a_resumed_fleet_run_is_the_uninterrupted_run() {
    let d = scratch("fleet-resume");
    let (a, b) = (d.join("whole"), d.join("split"));
    // Two plants, 10 steps each per round: 2000 steps end both plants' first episodes.
    let args = ["--plants", "2", "--sync-every", "10"];
    let whole = ok_json(&tiny(&a, 4000, &args));
    let half = ok_json(&tiny(&b, 2000, &args));
    assert_ne!(sha(&half), sha(&whole));
    let meta: serde_json::Value =
        serde_json::from_slice(&std::fs::read(b.join("checkpoint/meta.json")).unwrap()).unwrap();
    let plants = meta["fleet"]["plants"].as_array().unwrap();
    assert_eq!(plants.len(), 2);
    assert!(plants.iter().all(|p| p["resets"] == 1), "{plants:?}");
    let resumed = ok_json(&common::mpo(&[
        "train",
        "--no-progress",
        "--resume",
        b.to_str().unwrap(),
        "--steps",
        "4000",
        "--plants",
        "2",
        "--sync-every",
        "10",
    ]));
    assert_eq!(resumed["env_steps"], 4000);
    assert_eq!(resumed["updates"], whole["updates"]);
    assert_eq!(sha(&resumed), sha(&whole));
}

#[test]
fn a_plant_started_by_hand_joins_the_resumed_learner() {
    use mpo_host::fleet::learner::Fleet;
    use mpo_host::spec::Spec;
    let policy: Box<<mpo_host::table::CartpoleTiny as Spec>::Policy> = bytemuck::zeroed_box();
    let (id, opts) = tiny_fleet(mpo_core::params::Params::len(&*policy));
    let welcome = bytemuck::Zeroable::zeroed();
    let mut first = Fleet::open(opts.clone(), id, welcome, 0, None).unwrap();
    let plant = plant_by_hand(first.run_id(), "cartpole-balance", "tiny");
    first.admit(Duration::from_secs(60)).unwrap();
    // The learner dies (no STOP), and another process resumes the run under its id.
    drop(first);
    let mut second = Fleet::open(opts, id, welcome, 0, None).unwrap();
    if let Err(e) = second.admit(Duration::from_secs(20)) {
        let mut plant = plant;
        let _ = plant.kill();
        let out = plant.wait_with_output().unwrap();
        panic!("{e}: {}", String::from_utf8_lossy(&out.stderr));
    }
    let events = second.take_events().join("\n");
    assert!(events.contains("fleet: plant 0 rejoined"), "{events}");
    let report = second.finish();
    assert_eq!(report.rejoined, 1);
    let out = plant.wait_with_output().unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    assert!(
        stderr.contains("another incarnation of the run's learner speaks; joining again"),
        "{stderr}"
    );
}

#[test]
fn the_runs_iceoryx2_files_are_its_users_alone() {
    use mpo_host::fleet::learner::Fleet;
    use std::os::unix::fs::PermissionsExt;
    let (id, opts) = tiny_fleet(1);
    let run = opts.run.clone().unwrap();
    let fleet = Fleet::open(opts, id, bytemuck::Zeroable::zeroed(), 0, None).unwrap();
    let files = run.files();
    assert!(!files.is_empty(), "no file of run {}", run.as_str());
    for f in &files {
        let mode = std::fs::symlink_metadata(f).unwrap().permissions().mode();
        assert_eq!(
            mode & 0o077,
            0,
            "{} has mode {:o}",
            f.display(),
            mode & 0o777
        );
    }
    drop(fleet);
}

/// `mpo plant-worker` as plant 0 of `run`, started by hand (not by a learner) with `task` and
/// `net`; its stderr is piped.
fn plant_by_hand(run: &str, task: &str, net: &str) -> std::process::Child {
    Command::new(env!("CARGO_BIN_EXE_mpo"))
        .args(["plant-worker", "--run", run, "--index", "0"])
        .args(["--task", task, "--net", net])
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap()
}

/// The identity of the tiny cartpole row (policy length `policy_len`) and a one-plant
/// deterministic fleet's options under a fresh run id.
fn tiny_fleet(
    policy_len: usize,
) -> (
    mpo_link::fleet::frames::Identity,
    mpo_host::fleet::FleetOptions,
) {
    use mpo_host::fleet::{FleetOptions, FleetSchedule};
    let task = sim_bridge::TaskDef::builtin("cartpole-balance").unwrap();
    let row = mpo_host::rows::row(&task, "tiny").unwrap();
    let id = mpo_host::fleet::identity(&task, "tiny", &row.sizes, policy_len);
    let opts = FleetOptions {
        plants: 1,
        sync_every: 10,
        schedule: FleetSchedule::Deterministic,
        timeout: Duration::from_secs(60),
        max_lag: 100,
        rate: None,
        restarts: 0,
        run: Some(mpo_link::RunId::new()),
        remote: None,
    };
    (id, opts)
}

#[test]
fn a_plant_of_another_task_is_refused_with_both_named() {
    use mpo_host::fleet::FleetError;
    use mpo_host::fleet::learner::Fleet;
    let (id, opts) = tiny_fleet(1);
    let welcome = bytemuck::Zeroable::zeroed();
    let mut fleet = Fleet::open(opts, id, welcome, 0, None).unwrap();
    let plant = plant_by_hand(fleet.run_id(), "pendulum-swingup", "default");
    let e = fleet.admit(Duration::from_secs(60)).unwrap_err();
    let FleetError::Refused { index, message } = &e else {
        panic!("not a refusal: {e}");
    };
    assert_eq!(*index, 0);
    assert!(
        message.contains("pendulum-swingup/default (obs 3, act 1"),
        "{message}"
    );
    assert!(
        message.contains("cartpole-balance/tiny (obs 5, act 1"),
        "{message}"
    );
    let out = plant.wait_with_output().unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{stderr}");
    assert!(
        stderr.contains("the learner refused this plant: it runs pendulum-swingup"),
        "{stderr}"
    );
}
