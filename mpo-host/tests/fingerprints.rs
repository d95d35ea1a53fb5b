//! Pinned fingerprints: a short run of every task-table row (and of the learner's optional
//! paths on the tiny row) must end with the `params_sha256` checked into
//! `tests/fingerprints.toml`.
//!
//! The determinism tests compare two builds or two paths of today's code; only these pins
//! catch a change of the arithmetic that is consistent everywhere (a reordered sum, a new
//! rounding, a changed default). An intended change of the numbers updates the file in the
//! same commit, with the reason in the commit message:
//! `MPO_UPDATE_FINGERPRINTS=1 cargo test -p mpo-host --test fingerprints` rewrites it.

mod common;

use std::path::{Path, PathBuf};
use std::sync::Mutex;

use serde::{Deserialize, Serialize};

/// One pinned run: `mpo train --task TASK --net NET` with the short schedule below and `set`.
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
struct Pin {
    task: String,
    net: String,
    /// Extra `--set KEY=VALUE` flags (a variant of the row).
    #[serde(default)]
    set: Vec<String>,
    params_sha256: String,
}

#[derive(Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
struct PinFile {
    run: Vec<Pin>,
}

/// 1000 steps (one episode of every built-in task), learning from step 900 every second
/// step (51 updates: the first at step 900), then one evaluation episode: every path of an
/// update, in about a quarter of the time 201 updates took (these pins replaced the 201-update
/// ones at a commit where those passed).
const SHORT: [&str; 8] = [
    "--steps=1000",
    "--set=schedule.warmup_steps=900",
    "--set=schedule.eval_interval=1000",
    "--set=schedule.eval_episodes=1",
    "--set=schedule.update_interval=2",
    "--set=schedule.updates_per_interval=1",
    "--threads=1",
    "--no-progress",
];

fn pin_file() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fingerprints.toml")
}

/// The run's `params_sha256` (panics with stderr if it fails).
fn fingerprint(pin: &Pin, out: &Path) -> String {
    let mut args: Vec<String> = vec![
        "train".into(),
        "--task".into(),
        pin.task.clone(),
        "--net".into(),
        pin.net.clone(),
        "--out".into(),
        out.display().to_string(),
    ];
    args.extend(SHORT.iter().map(|s| s.to_string()));
    for s in &pin.set {
        args.push("--set".into());
        args.push(s.clone());
    }
    let refs: Vec<&str> = args.iter().map(String::as_str).collect();
    let summary = common::ok_json(&common::mpo(&refs));
    assert_eq!(
        summary["updates"], 51,
        "{}/{} {:?}",
        pin.task, pin.net, pin.set
    );
    summary["params_sha256"].as_str().unwrap().to_string()
}

#[test]
fn every_row_keeps_its_pinned_params_sha256() {
    let text = std::fs::read_to_string(pin_file()).unwrap();
    let mut file: PinFile = toml::from_str(&text).unwrap();
    let rows: Vec<(String, String)> = mpo_host::table::rows()
        .iter()
        .map(|r| (r.task.to_string(), r.net.to_string()))
        .collect();
    for (task, net) in &rows {
        assert!(
            file.run
                .iter()
                .any(|p| &p.task == task && &p.net == net && p.set.is_empty()),
            "row {task}/{net} has no pin in {}",
            pin_file().display()
        );
    }
    let dir = common::scratch("fingerprints");
    // Two runs at a time: each is single-threaded.
    let next = Mutex::new(0usize);
    let got = Mutex::new(vec![String::new(); file.run.len()]);
    std::thread::scope(|s| {
        for _ in 0..2 {
            s.spawn(|| {
                loop {
                    let i = {
                        let mut n = next.lock().unwrap();
                        *n += 1;
                        *n - 1
                    };
                    let Some(pin) = file.run.get(i) else { break };
                    let sha = fingerprint(pin, &dir.join(format!("run{i}")));
                    got.lock().unwrap()[i] = sha;
                }
            });
        }
    });
    let got = got.into_inner().unwrap();
    if std::env::var_os("MPO_UPDATE_FINGERPRINTS").is_some() {
        for (p, sha) in file.run.iter_mut().zip(&got) {
            p.params_sha256 = sha.clone();
        }
        let header: String = text
            .lines()
            .take_while(|l| l.starts_with('#'))
            .map(|l| format!("{l}\n"))
            .collect();
        let body = toml::to_string(&file).unwrap();
        std::fs::write(pin_file(), format!("{header}\n{body}")).unwrap();
        eprintln!("rewrote {}", pin_file().display());
        return;
    }
    let wrong: Vec<String> = file
        .run
        .iter()
        .zip(&got)
        .filter(|(p, sha)| &p.params_sha256 != *sha)
        .map(|(p, sha)| {
            format!(
                "{}/{} {:?}: pinned {}, got {sha}",
                p.task, p.net, p.set, p.params_sha256
            )
        })
        .collect();
    assert!(
        wrong.is_empty(),
        "the arithmetic changed for {} of {} pinned runs (if intended, rerun with \
         MPO_UPDATE_FINGERPRINTS=1 and give the reason in the commit):\n{}",
        wrong.len(),
        got.len(),
        wrong.join("\n")
    );
}
