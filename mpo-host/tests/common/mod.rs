//! Helpers shared by the integration tests: run the built `mpo` binary in a fresh directory.
#![allow(dead_code)]

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use mpo_host::spec::Spec;
use mpo_host::table::CartpoleTinySimba;
use mpo_host::trainer::{MlpTrainer, Trainer};

/// The tiny cartpole row's trainer type (`cartpole-balance --net tiny`).
pub type Tiny = MlpTrainer<5, 1, 1, 32, 32, 32, 32, 32, 2, 4, 10, 10, 50_000>;
/// The tiny residual row's (`tiny-simba`: residual networks, a categorical critic).
pub type TinySimba = Trainer<
    5,
    1,
    1,
    <CartpoleTinySimba as Spec>::Policy,
    <CartpoleTinySimba as Spec>::Critic,
    32,
    2,
    4,
    10,
    10,
    50_000,
>;

/// A fresh, empty directory under the target directory (kept for inspection after a failure).
pub fn scratch(name: &str) -> PathBuf {
    let dir = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join(format!("mpo-host-{name}"));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// `mpo ARGS`, with the output captured.
pub fn mpo(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_mpo"))
        .args(args)
        .output()
        .expect("spawn mpo")
}

/// The JSON summary line of a successful run (panics with stderr otherwise).
pub fn ok_json(out: &Output) -> serde_json::Value {
    assert!(
        out.status.success(),
        "status {:?}\nstderr:\n{}",
        out.status,
        String::from_utf8_lossy(&out.stderr)
    );
    let stdout = String::from_utf8(out.stdout.clone()).unwrap();
    assert_eq!(stdout.lines().count(), 1, "one summary line: {stdout}");
    serde_json::from_str(stdout.trim()).unwrap()
}

/// Stderr of a failed run, checking exit status 1 and no panic.
pub fn err_text(out: &Output) -> String {
    let stderr = String::from_utf8_lossy(&out.stderr).to_string();
    assert_eq!(out.status.code(), Some(1), "exit status; stderr:\n{stderr}");
    assert!(!stderr.contains("panicked"), "a panic: {stderr}");
    assert!(out.stdout.is_empty(), "no summary on failure");
    stderr
}

/// A tiny cartpole run: `steps` environment steps into `dir`.
pub fn tiny(dir: &Path, steps: u64, extra: &[&str]) -> Output {
    let steps = steps.to_string();
    let mut args = vec![
        "train",
        "--net",
        "tiny",
        "--no-progress",
        "--steps",
        &steps,
        "--out",
        dir.to_str().unwrap(),
    ];
    args.extend_from_slice(extra);
    mpo(&args)
}
