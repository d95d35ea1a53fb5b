//! Crash safety of checkpoints.
//!
//! - `sigkill_at_random_moments_then_resume_matches`: `mpo train` (tiny row, 3000 steps, a
//!   checkpoint every 1000) is killed with SIGKILL again and again, at uniformly random times
//!   and at each phase of a checkpoint write (widened by the `MPO_TEST_CHECKPOINT_PAUSE_MS`
//!   hook), and resumed each time. Every resume must start from the newest checkpoint that is
//!   complete on disk (checked here with our own SHA-256 of the files, not mpo-host's reader),
//!   no crash may leave less than the newest checkpoint known complete before it, and every
//!   chain of kills and resumes must end at the uninterrupted run's `params_sha256`.
//! - `full_disk_during_a_checkpoint_keeps_the_previous_one`: a resume on a small tmpfs runs
//!   out of space while writing its checkpoint: a clear error naming the file, the previous
//!   checkpoint byte for byte intact, and the run completes once there is space again.
//! - `files_and_directories_are_fsynced_before_the_swap`: strace of a run: every checkpoint
//!   file and `checkpoint.tmp/` are fsynced before the rename that makes it live, and the run
//!   directory is fsynced before the previous checkpoint is removed.

mod common;
use common::*;

use std::io::BufRead;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::mpsc;
use std::time::{Duration, Instant};

use mpo_core::rng::Rng;
use sha2::{Digest, Sha256};

const STEPS: &str = "3000";
/// The test hook's pause before each file and each rename of a checkpoint write.
const PAUSE_MS: u64 = 25;
/// Kills per run of the test (`MPO_CRASH_KILLS` overrides, e.g. for a quick check).
const KILLS: usize = 60;

fn train_args(dir: &Path) -> Vec<String> {
    [
        "train",
        "--net",
        "tiny",
        "--no-progress",
        "--steps",
        STEPS,
        "--set",
        "schedule.eval_interval=1000",
        "--out",
    ]
    .iter()
    .map(|s| s.to_string())
    .chain([dir.display().to_string()])
    .collect()
}

fn resume_args(dir: &Path) -> Vec<String> {
    vec![
        "train".into(),
        "--no-progress".into(),
        "--resume".into(),
        dir.display().to_string(),
    ]
}

/// A running `mpo` whose stderr lines arrive on a channel as they are printed.
struct Proc {
    child: Child,
    lines: mpsc::Receiver<String>,
    stderr: Vec<String>,
}

impl Proc {
    fn spawn(args: &[String]) -> Self {
        let mut child = Command::new(env!("CARGO_BIN_EXE_mpo"))
            .args(args)
            .env(mpo_host::checkpoint::PAUSE_ENV, PAUSE_MS.to_string())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .expect("spawn mpo");
        let (tx, lines) = mpsc::channel();
        let err = child.stderr.take().unwrap();
        std::thread::spawn(move || {
            for l in std::io::BufReader::new(err).lines() {
                let Ok(l) = l else { break };
                if tx.send(l).is_err() {
                    break;
                }
            }
        });
        Self {
            child,
            lines,
            stderr: Vec::new(),
        }
    }
    fn drain(&mut self) {
        while let Ok(l) = self.lines.try_recv() {
            self.stderr.push(l);
        }
    }
    fn exited(&mut self) -> bool {
        self.child.try_wait().unwrap().is_some()
    }
    /// The environment step of the `resuming from ... at environment step N` line, if printed.
    fn resumed_at(&mut self) -> Option<u64> {
        self.drain();
        self.stderr.iter().find_map(|l| {
            l.strip_prefix("resuming from ")
                .and_then(|r| r.rsplit_once(" at environment step "))
                .and_then(|(_, n)| n.parse().ok())
        })
    }
    fn finish(mut self) -> (std::process::ExitStatus, String, String) {
        let status = self.child.wait().unwrap();
        let mut out = String::new();
        std::io::Read::read_to_string(self.child.stdout.as_mut().unwrap(), &mut out).unwrap();
        // The reader thread ends at EOF.
        for l in self.lines.iter() {
            self.stderr.push(l);
        }
        (status, out, self.stderr.join("\n"))
    }
}

/// The environment step of the checkpoint in `d` if all four files match its SHA256SUMS
/// (verified here, independently of mpo-host's reader).
fn complete_step(d: &Path) -> Option<u64> {
    let sums = std::fs::read_to_string(d.join("SHA256SUMS")).ok()?;
    let mut files = 0;
    for line in sums.lines() {
        let (hash, name) = line.split_once("  ")?;
        let bytes = std::fs::read(d.join(name)).ok()?;
        let got: String = Sha256::digest(&bytes)
            .iter()
            .map(|b| format!("{b:02x}"))
            .collect();
        if got != hash {
            return None;
        }
        files += 1;
    }
    if files != 4 {
        return None;
    }
    let meta: serde_json::Value =
        serde_json::from_slice(&std::fs::read(d.join("meta.json")).ok()?).ok()?;
    meta["env_steps"].as_u64()
}

/// What a crash left of the three checkpoint directories: `-` absent, `p` present but not
/// complete, or the step of a complete one.
fn state(run: &Path) -> String {
    ["checkpoint", "checkpoint.tmp", "checkpoint.old"]
        .iter()
        .map(|c| {
            let d = run.join(c);
            if !d.exists() {
                format!("{c}=-")
            } else {
                match complete_step(&d) {
                    Some(s) => format!("{c}={s}"),
                    None => format!("{c}=p"),
                }
            }
        })
        .collect::<Vec<_>>()
        .join(" ")
}

fn newest_complete(run: &Path) -> Option<u64> {
    ["checkpoint", "checkpoint.tmp", "checkpoint.old"]
        .iter()
        .filter_map(|c| complete_step(&run.join(c)))
        .max()
}

/// The phases of a checkpoint write the targeted kills aim at, observed on the directory.
#[derive(Clone, Copy, Debug)]
enum Phase {
    /// `checkpoint.tmp/` being filled (no SHA256SUMS yet).
    Writing,
    /// `checkpoint.tmp/` complete, `checkpoint/` not yet renamed.
    Written,
    /// Between the two renames: `checkpoint.old/` and `checkpoint.tmp/`, no `checkpoint/`.
    BetweenRenames,
    /// Swapped in, `checkpoint.old/` not yet removed.
    Swapped,
}

const PHASES: [Phase; 4] = [
    Phase::Writing,
    Phase::Written,
    Phase::BetweenRenames,
    Phase::Swapped,
];

fn in_phase(run: &Path, p: Phase) -> bool {
    let (f, t, o) = (
        run.join("checkpoint"),
        run.join("checkpoint.tmp"),
        run.join("checkpoint.old"),
    );
    match p {
        Phase::Writing => t.exists() && !t.join("SHA256SUMS").exists(),
        Phase::Written => t.join("SHA256SUMS").exists() && f.exists(),
        Phase::BetweenRenames => o.exists() && t.exists() && !f.exists(),
        Phase::Swapped => f.exists() && o.exists() && !t.exists(),
    }
}

enum Plan {
    /// Kill this long after the start.
    After(Duration),
    /// Kill as soon as the phase is seen (polled every 0.5 ms; each phase lasts at least the
    /// hook's pause).
    At(Phase),
    /// Let it finish.
    Finish,
}

#[test]
#[ignore = "long: scripts/test --long"]
fn sigkill_at_random_moments_then_resume_matches() {
    let t_start = Instant::now();
    let seed = std::env::var("MPO_CRASH_SEED")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or_else(|| {
            std::time::SystemTime::now()
                .duration_since(std::time::UNIX_EPOCH)
                .unwrap()
                .as_nanos() as u64
        });
    eprintln!("crash test seed {seed} (MPO_CRASH_SEED={seed} repeats the kill times)");
    let mut rng = Rng::seed_from_u64(seed);
    let kills_wanted = std::env::var("MPO_CRASH_KILLS")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(KILLS);
    let d = scratch("crash");

    // The uninterrupted run (with the same pause hook: it changes timing, never results).
    let t0 = Instant::now();
    let p = Proc::spawn(&train_args(&d.join("whole")));
    let (status, out, err) = p.finish();
    assert!(status.success(), "{err}");
    let whole: serde_json::Value = serde_json::from_str(out.trim()).unwrap();
    let reference = whole["params_sha256"].as_str().unwrap().to_string();
    let t_run = t0.elapsed();

    let mut kills = 0;
    let mut chains = 0;
    let mut resumes_checked = 0;
    let mut fresh_restarts = 0;
    let mut states: std::collections::BTreeMap<String, usize> = Default::default();
    let mut phase_hits = [0usize; 4];
    let mut targeted = 0usize;
    while kills < kills_wanted {
        chains += 1;
        let run = d.join(format!("chain{chains}"));
        let mut args = train_args(&run);
        // The step the next process must resume from (None: a fresh start).
        let mut expect: Option<u64> = None;
        // The newest checkpoint known complete: no later crash may leave less.
        let mut floor: Option<u64> = None;
        loop {
            let plan = if kills >= kills_wanted {
                Plan::Finish
            } else if rng.uniform() < 0.5 {
                let ph = PHASES[targeted % PHASES.len()];
                Plan::At(ph)
            } else {
                Plan::After(t_run.mul_f64(1.1 * rng.uniform() as f64))
            };
            let mut p = Proc::spawn(&args);
            let t = Instant::now();
            let killed = loop {
                if p.exited() {
                    break false;
                }
                let now = match plan {
                    Plan::After(d) => t.elapsed() >= d,
                    Plan::At(ph) => in_phase(&run, ph),
                    Plan::Finish => false,
                };
                if now {
                    p.child.kill().unwrap(); // SIGKILL
                    break true;
                }
                assert!(t.elapsed() < Duration::from_secs(120), "mpo train hangs");
                std::thread::sleep(Duration::from_micros(500));
            };
            let resumed_at = p.resumed_at();
            let (status, out, err) = p.finish();
            if let Some(e) = expect {
                // Printed before training starts; absent only if killed before that.
                if let Some(r) = resumed_at {
                    assert_eq!(
                        r, e,
                        "resumed from step {r}, but the newest complete checkpoint was {e}\n{err}"
                    );
                    resumes_checked += 1;
                } else {
                    assert!(
                        killed,
                        "a resume that ran to the end did not say where from"
                    );
                }
            }
            if !killed {
                assert!(status.success(), "chain {chains}: {err}");
                let s: serde_json::Value = serde_json::from_str(out.trim()).unwrap();
                assert_eq!(
                    s["params_sha256"].as_str().unwrap(),
                    reference,
                    "chain {chains} (seed {seed}) ended with other parameters"
                );
                assert_eq!(
                    state(&run),
                    "checkpoint=3000 checkpoint.tmp=- checkpoint.old=-"
                );
                break;
            }
            kills += 1;
            if let Plan::At(ph) = plan {
                // Counted only if the kill landed in the phase (the process may have been
                // done before reaching it, or finished the pause first: then it is a random
                // moment like the others).
                if in_phase(&run, ph) {
                    phase_hits[ph as usize] += 1;
                    targeted += 1;
                }
            }
            let st = state(&run);
            *states.entry(st.clone()).or_default() += 1;
            expect = newest_complete(&run);
            assert!(
                expect >= floor,
                "{st}: the newest complete checkpoint was {floor:?} and is gone (seed {seed})"
            );
            floor = expect;
            match expect {
                Some(_) => args = resume_args(&run),
                None => {
                    // Nothing complete yet: `--resume` says so, and a fresh start is allowed.
                    let e = err_text(&mpo(&resume_args(&run)
                        .iter()
                        .map(String::as_str)
                        .collect::<Vec<_>>()));
                    assert!(e.contains("no checkpoint in"), "{st}: {e}");
                    fresh_restarts += 1;
                    args = train_args(&run);
                }
            }
        }
    }
    eprintln!(
        "{kills} kills in {chains} chains, {resumes_checked} resumes checked against the newest \
         complete checkpoint, {fresh_restarts} fresh restarts (killed before the first \
         checkpoint), all chains ended at params_sha256 {reference}; {:.0} s (uninterrupted run \
         {:.1} s)",
        t_start.elapsed().as_secs_f64(),
        t_run.as_secs_f64()
    );
    eprintln!(
        "kills in a write phase: writing {}, written {}, between renames {}, swapped {}",
        phase_hits[0], phase_hits[1], phase_hits[2], phase_hits[3]
    );
    eprintln!("directory states left by the kills:");
    for (s, n) in &states {
        eprintln!("  {n:3}  {s}");
    }
    for (ph, n) in PHASES.iter().zip(phase_hits) {
        assert!(n > 0, "no kill landed in phase {ph:?}");
    }
    assert!(
        resumes_checked >= KILLS / 2,
        "{resumes_checked} resumes checked"
    );
}

/// A tmpfs mounted for the test, unmounted when dropped.
struct Tmpfs(PathBuf);

impl Tmpfs {
    fn mount(dir: &Path, bytes: u64) -> Self {
        std::fs::create_dir_all(dir).unwrap();
        let out = Command::new("mount")
            .args(["-t", "tmpfs", "-o"])
            .arg(format!("size={bytes}"))
            .arg("tmpfs")
            .arg(dir)
            .output();
        match out {
            Ok(o) if o.status.success() => Self(dir.to_path_buf()),
            Ok(o) => panic!(
                "cannot mount a {bytes}-byte tmpfs on {} to simulate a full disk (this test needs \
                 root or CAP_SYS_ADMIN): {}",
                dir.display(),
                String::from_utf8_lossy(&o.stderr).trim()
            ),
            Err(e) => panic!("cannot run mount(8) to simulate a full disk: {e}"),
        }
    }
    fn resize(&self, bytes: u64) {
        let o = Command::new("mount")
            .args(["-o"])
            .arg(format!("remount,size={bytes}"))
            .arg(&self.0)
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    }
}

impl Drop for Tmpfs {
    fn drop(&mut self) {
        let _ = Command::new("umount").arg(&self.0).status();
    }
}

fn du(dir: &Path) -> u64 {
    let mut n = 0;
    for e in std::fs::read_dir(dir).unwrap() {
        let e = e.unwrap();
        let m = e.metadata().unwrap();
        n += if m.is_dir() {
            du(&e.path())
        } else {
            m.len().div_ceil(4096) * 4096
        };
    }
    n
}

fn copy_dir(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).unwrap();
    for e in std::fs::read_dir(from).unwrap() {
        let e = e.unwrap();
        if e.metadata().unwrap().is_dir() {
            copy_dir(&e.path(), &to.join(e.file_name()));
        } else {
            std::fs::copy(e.path(), to.join(e.file_name())).unwrap();
        }
    }
}

#[test]
fn full_disk_during_a_checkpoint_keeps_the_previous_one() {
    let d = scratch("fulldisk");
    let whole = ok_json(&tiny(&d.join("whole"), 2000, &[]));
    let src = d.join("src");
    ok_json(&tiny(&src, 1000, &[]));
    let ck = src.join("checkpoint");
    let ck_bytes = du(&ck);
    // Room for everything of the first 1000 steps, the metrics and the curve again, but not
    // for the next checkpoint beside the current one (it is larger: 1000 more transitions).
    let fs = Tmpfs::mount(&d.join("mnt"), du(&src) + ck_bytes / 2);
    let run = fs.0.join("run");
    copy_dir(&src, &run);
    let out = mpo(&[
        "train",
        "--no-progress",
        "--resume",
        run.to_str().unwrap(),
        "--steps",
        "2000",
    ]);
    let e = err_text(&out);
    eprintln!("the full disk's error: {}", e.trim());
    assert!(
        e.contains(&format!("{}/checkpoint.tmp/", run.display()))
            && e.contains("No space left on device"),
        "the error names the file and the cause: {e}"
    );
    // The previous checkpoint is intact, byte for byte; the partial write is gone.
    for f in [
        "meta.json",
        "params.safetensors",
        "optimizer.safetensors",
        "replay.safetensors",
        "SHA256SUMS",
    ] {
        let a = std::fs::read(ck.join(f)).unwrap();
        let b = std::fs::read(run.join("checkpoint").join(f)).unwrap();
        assert!(a == b, "{f} changed");
    }
    assert!(!run.join("checkpoint.tmp").exists());
    assert_eq!(complete_step(&run.join("checkpoint")), Some(1000));
    // With space again, the resume completes as if nothing had happened.
    fs.resize(64 << 20);
    let resumed = ok_json(&mpo(&[
        "train",
        "--no-progress",
        "--resume",
        run.to_str().unwrap(),
        "--steps",
        "2000",
    ]));
    assert_eq!(resumed["params_sha256"], whole["params_sha256"]);
}

#[test]
fn files_and_directories_are_fsynced_before_the_swap() {
    let d = scratch("fsync");
    let run = d.join("run");
    let trace = d.join("strace.txt");
    let out = Command::new("strace")
        .args([
            "-f",
            "-qq",
            "-e",
            "trace=openat,fsync,fdatasync,rename,renameat,renameat2,unlink,unlinkat,rmdir",
            "-o",
        ])
        .arg(&trace)
        .arg(env!("CARGO_BIN_EXE_mpo"))
        .args(["train", "--net", "tiny", "--no-progress", "--steps", "2000"])
        .arg("--out")
        .arg(&run)
        .output()
        .unwrap_or_else(|e| panic!("this test needs strace(1) on PATH: {e}"));
    ok_json(&out);
    let text = std::fs::read_to_string(&trace).unwrap();
    let r = run.display().to_string();
    let (ck, tmp, old) = (
        format!("{r}/checkpoint"),
        format!("{r}/checkpoint.tmp"),
        format!("{r}/checkpoint.old"),
    );
    // Replay the trace: fd -> path, the set of paths fsynced so far.
    let mut fds: std::collections::HashMap<(String, String), String> = Default::default();
    let mut synced: Vec<String> = Vec::new();
    let mut swaps = 0;
    let mut swapped_unsynced = false;
    let quoted =
        |s: &str| -> Vec<String> { s.split('"').skip(1).step_by(2).map(String::from).collect() };
    for line in text.lines() {
        let (pid, call) = line.split_once(' ').unwrap_or(("", line));
        let call = call.trim_start();
        let ret = call.rsplit_once("= ").map(|(_, r)| r.trim()).unwrap_or("");
        if call.starts_with("openat(") {
            if let (Some(p), Ok(fd)) = (quoted(call).first(), ret.parse::<i64>()) {
                // Removing the previous checkpoint starts by opening it.
                assert!(
                    !(*p == old && swapped_unsynced),
                    "the previous checkpoint is removed before the run directory is fsynced after the swap"
                );
                fds.insert((pid.into(), fd.to_string()), p.clone());
            }
        } else if call.starts_with("fsync(") || call.starts_with("fdatasync(") {
            let fd = call[call.find('(').unwrap() + 1..call.find(')').unwrap()].to_string();
            if let Some(p) = fds.get(&(pid.to_string(), fd)) {
                synced.push(p.clone());
                if *p == r {
                    swapped_unsynced = false;
                }
            }
        } else if call.starts_with("rename") {
            let q = quoted(call);
            if q.len() == 2 && q[0] == tmp && q[1] == ck {
                for f in [
                    "meta.json",
                    "params.safetensors",
                    "optimizer.safetensors",
                    "replay.safetensors",
                    "SHA256SUMS",
                ] {
                    let p = format!("{tmp}/{f}");
                    assert!(synced.contains(&p), "{p} not fsynced before the swap");
                }
                assert!(
                    synced.contains(&tmp),
                    "{tmp} (the directory) not fsynced before the swap"
                );
                synced.clear();
                swaps += 1;
                swapped_unsynced = true;
            }
            if q.len() == 2 && q[1] == format!("{r}/metrics.csv") {
                assert!(
                    synced.contains(&q[0]),
                    "{} not fsynced before its rename",
                    q[0]
                );
            }
        } else if call.starts_with("unlink") || call.starts_with("rmdir") {
            assert!(
                !(quoted(call).iter().any(|p| p.starts_with(&old)) && swapped_unsynced),
                "the previous checkpoint is removed before the run directory is fsynced after the swap"
            );
        }
    }
    assert_eq!(swaps, 2, "two checkpoints (1000 and 2000 steps) swapped in");
}
