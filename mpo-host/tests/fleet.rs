//! `mpo train --plants N` (docs/fleet.md): a one-plant deterministic fleet with one step per
//! block is the in-process run bit for bit; a two-plant deterministic run repeats its bits; a
//! killed plant is dropped and the run finishes; a plant of another task is refused, and
//! says so.

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

#[test]
fn a_killed_plant_is_dropped_and_the_run_goes_on() {
    let dir = scratch("fleet-kill");
    let mut child = Command::new(env!("CARGO_BIN_EXE_mpo"))
        .args(["train", "--net", "tiny", "--no-progress", "--steps", "3000"])
        .args(["--plants", "2", "--sync-every", "10", "--out"])
        .arg(&dir)
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
            let pid = rest.trim_end_matches(')');
            let st = Command::new("kill").args(["-KILL", pid]).status().unwrap();
            assert!(st.success());
            killed = true;
        }
    }
    let out = child.wait_with_output().unwrap();
    assert!(killed, "plant 1 never joined:\n{log}");
    assert!(out.status.success(), "{:?}\n{log}", out.status);
    let s: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(s["env_steps"], 3000, "{log}");
    assert_eq!(s["fleet"]["dropped"], 1);
    assert!(log.contains("fleet: plant 1 (pid") && log.contains("dropped: its process exited"));
}

#[test]
fn a_plant_of_another_task_is_refused_with_both_named() {
    use mpo_host::fleet::learner::Fleet;
    use mpo_host::fleet::{FleetError, FleetOptions, FleetSchedule};
    let task = sim_bridge::TaskDef::builtin("cartpole-balance").unwrap();
    let row = mpo_host::rows::row(&task, "tiny").unwrap();
    let id = mpo_host::fleet::identity(&task, "tiny", &row.sizes, 1);
    let opts = FleetOptions {
        plants: 1,
        sync_every: 10,
        schedule: FleetSchedule::Deterministic,
        timeout: Duration::from_secs(60),
        max_lag: 100,
        rate: None,
        remote: None,
    };
    let welcome = bytemuck::Zeroable::zeroed();
    let mut fleet = Fleet::open(opts, id, welcome, 0).unwrap();
    let plant = Command::new(env!("CARGO_BIN_EXE_mpo"))
        .args(["plant-worker", "--run", fleet.run_id(), "--index", "0"])
        .args(["--task", "pendulum-swingup", "--net", "default"])
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
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
