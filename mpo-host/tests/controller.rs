//! `--controller ipc` end to end, with real processes: `mpo train` and `mpo run` start (or
//! attach to) an `mpo controller` process and exchange messages with it over iceoryx2.

mod common;

use std::io::{BufRead, BufReader};
use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::sync::mpsc::{Receiver, channel};
use std::time::{Duration, Instant};

use common::{err_text, mpo, ok_json, scratch, tiny};
use mpo_link::RunId;
use serde_json::Value;

const MPO: &str = env!("CARGO_BIN_EXE_mpo");

/// A trained tiny cartpole checkpoint in a fresh directory.
fn checkpoint(name: &str, steps: u64) -> std::path::PathBuf {
    let dir = scratch(name).join("run");
    ok_json(&tiny(&dir, steps, &[]));
    dir
}

/// A process whose stderr lines arrive on a channel as they are written.
struct Proc {
    child: Child,
    lines: Receiver<String>,
    seen: Vec<String>,
}

impl Proc {
    fn spawn(args: &[&str]) -> Self {
        let mut child = Command::new(MPO)
            .args(args)
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .expect("spawn mpo");
        let (tx, lines) = channel();
        let err = child.stderr.take().unwrap();
        std::thread::spawn(move || {
            for l in BufReader::new(err).lines().map_while(Result::ok) {
                if tx.send(l).is_err() {
                    break;
                }
            }
        });
        Self {
            child,
            lines,
            seen: Vec::new(),
        }
    }

    /// Waits (at most `within`) for a stderr line containing `needle` and returns it.
    fn wait_line(&mut self, needle: &str, within: Duration) -> String {
        let t0 = Instant::now();
        while t0.elapsed() < within {
            if let Ok(l) = self.lines.recv_timeout(Duration::from_millis(50)) {
                self.seen.push(l.clone());
                if l.contains(needle) {
                    return l;
                }
            }
        }
        panic!(
            "no line with {needle:?} within {within:?}; stderr so far:\n{}",
            self.seen.join("\n")
        );
    }

    fn signal(&self, sig: i32) {
        // SAFETY: kill(2) on our own child.
        assert_eq!(unsafe { libc::kill(self.child.id() as i32, sig) }, 0);
    }

    /// Waits for the exit (at most `within`); returns the exit code, stdout and all of stderr.
    fn finish(mut self, within: Duration) -> (Option<i32>, String, String) {
        let t0 = Instant::now();
        let status = loop {
            if let Some(s) = self.child.try_wait().unwrap() {
                break s;
            }
            if t0.elapsed() > within {
                let _ = self.child.kill();
                panic!(
                    "did not exit within {within:?}; stderr:\n{}",
                    self.seen.join("\n")
                );
            }
            std::thread::sleep(Duration::from_millis(10));
        };
        let mut out = String::new();
        std::io::Read::read_to_string(self.child.stdout.as_mut().unwrap(), &mut out).unwrap();
        // The reader thread ends at EOF; collect what it still holds.
        while let Ok(l) = self.lines.recv_timeout(Duration::from_millis(500)) {
            self.seen.push(l);
        }
        (status.code(), out, self.seen.join("\n"))
    }
}

impl Drop for Proc {
    fn drop(&mut self) {
        if let Ok(None) = self.child.try_wait() {
            let _ = self.child.kill();
            let _ = self.child.wait();
        }
    }
}

fn pid_alive(pid: i32) -> bool {
    // SAFETY: signal 0 only checks existence.
    unsafe { libc::kill(pid, 0) == 0 }
}

/// The pid in "acting through controller process pid N (run id ID, ...)".
fn controller_of(line: &str) -> (i32, String) {
    let pid = line
        .split("pid ")
        .nth(1)
        .and_then(|s| s.split_whitespace().next())
        .and_then(|s| s.parse().ok())
        .unwrap_or_else(|| panic!("no pid in {line:?}"));
    let run = line
        .split("run id ")
        .nth(1)
        .and_then(|s| s.split([',', ')']).next())
        .unwrap_or_else(|| panic!("no run id in {line:?}"))
        .to_string();
    (pid, run)
}

fn no_files_left(run_id: &str) {
    let run = RunId::parse(run_id).unwrap();
    let left = run.files();
    assert!(
        left.is_empty(),
        "files of run {run_id} left behind: {left:?}"
    );
}

fn run_json(stdout: &str) -> Value {
    assert_eq!(stdout.lines().count(), 1, "one summary line: {stdout}");
    serde_json::from_str(stdout.trim()).unwrap()
}

#[test]
fn training_through_the_controller_equals_in_process_training() {
    let root = scratch("ctl-train");
    let a = ok_json(&tiny(&root.join("in-process"), 2000, &[]));
    let b = ok_json(&tiny(&root.join("ipc"), 2000, &["--controller", "ipc"]));
    assert_eq!(a["params_sha256"], b["params_sha256"]);
    assert_eq!(a["eval_return_mean"], b["eval_return_mean"]);
    assert_eq!(a["updates"], b["updates"]);
    assert!(a.get("controller").is_none());
    let c = &b["controller"];
    assert_eq!(c["origin"], "spawned");
    assert_eq!(c["misses"], 0, "{c}");
    assert_eq!(c["dropped_replies"], 0, "{c}");
    assert_eq!(c["leftover_files"], 0, "{c}");
    let requests = c["requests"].as_u64().unwrap();
    // Warm-up acts uniformly in-process; every later step and every evaluation step goes
    // through the controller.
    assert!(requests > 2000, "{c}");
    assert_eq!(c["replies"].as_u64().unwrap(), requests);
    let stats = c["controller_stats"].as_str().unwrap();
    assert!(stats.contains(&format!("answered={requests} ")), "{stats}");
    // One push per learner update plus the initial policy.
    assert_eq!(
        c["pushes"].as_u64().unwrap(),
        b["updates"].as_u64().unwrap() + 1
    );
    // The metrics (returns at every evaluation) agree too.
    let m = |d: &str| std::fs::read_to_string(root.join(d).join("metrics.jsonl")).unwrap();
    let strip = |s: String| {
        s.lines()
            .map(|l| {
                let mut v: Value = serde_json::from_str(l).unwrap();
                let o = v.as_object_mut().unwrap();
                o.retain(|k, _| !k.contains("wall") && !k.contains("per_s"));
                v
            })
            .collect::<Vec<_>>()
    };
    assert_eq!(strip(m("in-process")), strip(m("ipc")));
}

#[test]
fn lockstep_run_through_the_controller_equals_mpo_eval() {
    let dir = checkpoint("ctl-run-lockstep", 1000);
    let d = dir.to_str().unwrap();
    let eval = ok_json(&mpo(&["eval", "--checkpoint", d, "--episodes", "3"]));
    for extra in [
        &["--controller", "ipc"][..],
        &[],
        &["--controller", "ipc", "--wait", "busy-poll"],
        &["--controller", "ipc", "--spin-us", "50"],
    ] {
        let mut args = vec![
            "run",
            "--checkpoint",
            d,
            "--lockstep",
            "--steps",
            "3000",
            "--no-progress",
        ];
        args.extend_from_slice(extra);
        let out = mpo(&args);
        let s = ok_json(&out);
        // A miss (the zero action) is the one way the returns may differ: say so if they do.
        assert_eq!(
            s["returns"], eval["returns"],
            "{extra:?}: misses {}, link {}",
            s["misses"], s["link"]
        );
        assert_eq!(s["steps"], 3000);
        assert_eq!(s["misses"], 0);
        assert_eq!(s["mode"], "lockstep");
        assert_eq!(s["latency_us"]["samples"], 3000);
        let table = String::from_utf8_lossy(&out.stderr);
        assert!(table.contains("3 complete"), "{table}");
        if !extra.is_empty() {
            assert_eq!(s["controller"], "ipc");
            assert_eq!(s["link"]["replies"], 3000);
            assert_eq!(s["link"]["leftover_files"], 0);
            no_files_left(s["link"]["run_id"].as_str().unwrap());
            let spin = if extra.contains(&"--spin-us") {
                50.0
            } else {
                0.0
            };
            assert_eq!(s["link"]["spin_us"], spin);
        }
    }
}

#[test]
fn two_concurrent_runs_do_not_interfere() {
    let dir = checkpoint("ctl-concurrent", 1000);
    let d = dir.to_str().unwrap();
    let eval = ok_json(&mpo(&["eval", "--checkpoint", d, "--episodes", "2"]));
    let args = [
        "run",
        "--checkpoint",
        d,
        "--lockstep",
        "--steps",
        "2000",
        "--no-progress",
        "--controller",
        "ipc",
    ];
    let a = Proc::spawn(&args);
    let b = Proc::spawn(&args);
    let (ca, oa, ea) = a.finish(Duration::from_secs(120));
    let (cb, ob, eb) = b.finish(Duration::from_secs(120));
    assert_eq!((ca, cb), (Some(0), Some(0)), "{ea}\n{eb}");
    let (sa, sb) = (run_json(&oa), run_json(&ob));
    assert_ne!(sa["link"]["run_id"], sb["link"]["run_id"]);
    for s in [&sa, &sb] {
        assert_eq!(s["returns"], eval["returns"]);
        assert_eq!(s["link"]["replies"], 2000);
        assert_eq!(s["link"]["dropped_replies"], 0);
    }
}

#[test]
fn sigterm_stops_the_run_and_its_controller_cleanly() {
    let dir = checkpoint("ctl-sigterm", 1000);
    let mut p = Proc::spawn(&[
        "run",
        "--checkpoint",
        dir.to_str().unwrap(),
        "--controller",
        "ipc",
        "--seconds",
        "60",
        "--no-progress",
    ]);
    let line = p.wait_line("acting through controller process", Duration::from_secs(30));
    let (pid, run_id) = controller_of(&line);
    assert!(pid_alive(pid));
    assert!(
        !RunId::parse(&run_id).unwrap().files().is_empty(),
        "the run has files while it runs"
    );
    std::thread::sleep(Duration::from_millis(500));
    p.signal(libc::SIGTERM);
    let (code, out, err) = p.finish(Duration::from_secs(10));
    assert_eq!(code, Some(130), "{err}");
    let s = run_json(&out);
    assert_eq!(s["interrupted"], true);
    assert!(s["steps"].as_u64().unwrap() > 0);
    assert_eq!(s["link"]["leftover_files"], 0);
    assert!(
        s["link"]["controller_stats"]
            .as_str()
            .unwrap()
            .contains("answered="),
        "{s}"
    );
    assert!(!pid_alive(pid), "the controller process outlived the run");
    no_files_left(&run_id);
}

#[test]
fn a_killed_spawned_controller_is_started_again() {
    let dir = checkpoint("ctl-respawn", 1000);
    let mut p = Proc::spawn(&[
        "run",
        "--checkpoint",
        dir.to_str().unwrap(),
        "--controller",
        "ipc",
        "--rate",
        "1000",
        "--seconds",
        "4",
        "--no-progress",
    ]);
    let line = p.wait_line("acting through controller process", Duration::from_secs(30));
    let (pid, run_id) = controller_of(&line);
    std::thread::sleep(Duration::from_millis(1200));
    // SAFETY: kill(2) on the controller the run started.
    assert_eq!(unsafe { libc::kill(pid, libc::SIGKILL) }, 0);
    let (code, out, err) = p.finish(Duration::from_secs(60));
    assert_eq!(code, Some(0), "{err}");
    let s = run_json(&out);
    let link = &s["link"];
    assert!(link["restarts"].as_u64().unwrap() >= 1, "{err}");
    assert!(s["misses"].as_u64().unwrap() > 0, "{err}");
    assert!(err.contains("started it again"), "{err}");
    assert!(err.contains("answering again"), "{err}");
    // The plant never stopped: about 4000 paced steps despite the dead controller, and most of
    // them answered.
    let steps = s["steps"].as_u64().unwrap();
    assert!(steps >= 3000, "{steps} steps\n{err}");
    assert!(link["replies"].as_u64().unwrap() > steps / 2, "{link}");
    assert_eq!(link["requests"].as_u64().unwrap(), steps);
    no_files_left(&run_id);
}

/// `mpo controller --run ID` started by hand; returns it once it printed `ready`.
fn hand_started_controller(run_id: &str) -> Child {
    let mut c = Command::new(MPO)
        .args([
            "controller",
            "--run",
            run_id,
            "--task",
            "cartpole-balance",
            "--net",
            "tiny",
        ])
        .stdout(Stdio::piped())
        .stderr(Stdio::inherit())
        .spawn()
        .unwrap();
    let mut line = String::new();
    BufReader::new(c.stdout.as_mut().unwrap())
        .read_line(&mut line)
        .unwrap();
    assert_eq!(line.trim(), "ready");
    c
}

fn stop(c: Child) -> String {
    // SAFETY: kill(2) on our own child.
    unsafe { libc::kill(c.id() as i32, libc::SIGTERM) };
    let out = c.wait_with_output().unwrap();
    assert!(out.status.success(), "controller exit {:?}", out.status);
    String::from_utf8(out.stdout).unwrap()
}

#[test]
fn attached_controller_killed_mid_episode_then_back() {
    let dir = checkpoint("ctl-attach", 1000);
    let run_id = format!("t{}-attach", std::process::id());
    let first = hand_started_controller(&run_id);
    let mut p = Proc::spawn(&[
        "run",
        "--checkpoint",
        dir.to_str().unwrap(),
        "--controller",
        "ipc",
        "--attach",
        &run_id,
        "--rate",
        "1000",
        "--seconds",
        "4",
        "--no-progress",
    ]);
    p.wait_line(
        "acting through controller process attached",
        Duration::from_secs(30),
    );
    std::thread::sleep(Duration::from_millis(1000));
    let mut first = first;
    first.kill().unwrap();
    first.wait().unwrap();
    p.wait_line("missed", Duration::from_secs(5));
    std::thread::sleep(Duration::from_millis(500));
    let second = hand_started_controller(&run_id);
    p.wait_line("answering again", Duration::from_secs(5));
    let (code, out, err) = p.finish(Duration::from_secs(60));
    assert_eq!(code, Some(0), "{err}");
    let s = run_json(&out);
    let steps = s["steps"].as_u64().unwrap();
    assert!(steps >= 3000, "the plant kept stepping: {steps}\n{err}");
    assert!(s["misses"].as_u64().unwrap() >= 100, "{err}");
    assert_eq!(s["link"]["origin"], "attached");
    assert_eq!(s["link"]["restarts"], 0);
    // The second controller got the checkpoint's policy from the parameter history and
    // answered the rest of the run.
    let stats = stop(second);
    let answered: u64 = stats
        .split("answered=")
        .nth(1)
        .and_then(|s| s.split_whitespace().next())
        .and_then(|s| s.parse().ok())
        .unwrap_or_else(|| panic!("no stats line: {stats:?}"));
    assert!(answered >= 500, "{stats}");
    assert!(stats.contains("swaps=1 "), "{stats}");
    no_files_left(&run_id);
}

#[test]
fn link_flags_need_the_ipc_controller() {
    let dir = checkpoint("ctl-usage", 1000);
    let d = dir.to_str().unwrap();
    for (args, needle) in [
        (
            &["run", "--checkpoint", d, "--attach", "x-1"][..],
            "--attach needs --controller ipc",
        ),
        (
            &["run", "--checkpoint", d, "--wait", "busy-poll"],
            "--wait needs --controller ipc",
        ),
        (
            &["run", "--checkpoint", d, "--deadline-us", "100"],
            "--deadline-us needs --controller ipc",
        ),
        (
            &["run", "--checkpoint", d, "--spin-us", "50"],
            "--spin-us needs --controller ipc",
        ),
        (
            &[
                "run",
                "--checkpoint",
                d,
                "--controller",
                "ipc",
                "--wait",
                "busy-poll",
                "--spin-us",
                "50",
            ],
            "--spin-us applies to --wait event",
        ),
        (
            &[
                "run",
                "--checkpoint",
                d,
                "--controller",
                "ipc",
                "--attach",
                "no/slash",
            ],
            "--attach",
        ),
        (&["run", "--checkpoint", d, "--rate", "0"], "--rate"),
        (&["run", "--checkpoint", d, "--seconds", "0"], "--seconds"),
        (
            &[
                "run",
                "--checkpoint",
                d,
                "--controller",
                "ipc",
                "--wait",
                "busy-poll",
                "--realtime",
                "50",
            ],
            "starve",
        ),
        (
            &[
                "run",
                "--checkpoint",
                Path::new(d).join("nope").to_str().unwrap(),
            ],
            "nope",
        ),
        (
            &[
                "controller",
                "--run",
                "x-1",
                "--task",
                "walker-walk",
                "--net",
                "huge",
            ],
            "no row `huge`",
        ),
        (&["controller", "--run", "bad/name"], "bad/name"),
    ] {
        let e = err_text(&mpo(args));
        assert!(e.contains(needle), "{args:?}: {e}");
    }
    let e = err_text(&tiny(
        &scratch("ctl-usage-train"),
        500,
        &["--attach", "x-1"],
    ));
    assert!(e.contains("--attach needs --controller ipc"), "{e}");
    // Nobody serves the run: a clear error after the connect timeout, nothing left behind.
    let run_id = format!("t{}-nobody", std::process::id());
    let e = err_text(&mpo(&[
        "run",
        "--checkpoint",
        d,
        "--controller",
        "ipc",
        "--attach",
        &run_id,
        "--connect-timeout",
        "0.5",
    ]));
    assert!(e.contains("no controller attached"), "{e}");
    assert!(e.contains(&format!("mpo controller --run {run_id}")), "{e}");
    no_files_left(&run_id);
}
