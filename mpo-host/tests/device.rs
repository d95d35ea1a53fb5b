//! `mpo train --net mcu --device PATH`: the learner on the freestanding device trainer
//! (`freestanding/trainer`: no std, no allocator, everything in `.bss`), the plant here.
//!
//! Builds the trainer (release, baseline x86-64 CPU), then: the device run has the bits of the
//! in-process run; damaged and truncated frames in both directions are detected, counted and
//! recovered from with the same bits; a dying device is a clear error; the device answers
//! malformed and out-of-order commands with `ERROR` frames and goes on; the build fails when
//! `alloc` or `std` enter.

mod common;
use common::*;

use std::io::{Read, Write};
use std::path::PathBuf;
use std::process::{Command, Stdio};

use mpo_frames::{Event, Fault, Receiver, encode, kind};
use mpo_integration::cortex_m;

fn target_dir() -> PathBuf {
    mpo_integration::workspace_root().join("target/freestanding")
}

fn build(features: &str) -> std::process::Output {
    mpo_integration::build_freestanding("trainer", features, &[], &target_dir())
}

/// The device trainer, built once per test binary.
fn trainer() -> PathBuf {
    static BUILT: std::sync::Once = std::sync::Once::new();
    BUILT.call_once(|| {
        let out = build("");
        assert!(
            out.status.success(),
            "device trainer build failed:\n{}",
            String::from_utf8_lossy(&out.stderr)
        );
    });
    target_dir().join("x86_64-unknown-linux-gnu/release/mpo-trainer")
}

/// The device trainer built for the Cortex-M4F (thumbv7em-none-eabihf), once per test binary.
fn trainer_cortex_m() -> PathBuf {
    static BUILT: std::sync::Once = std::sync::Once::new();
    let target = mpo_integration::workspace_root().join("target/cortex-m");
    BUILT.call_once(|| {
        let out = cortex_m::build("trainer", "", &[], &target);
        assert!(
            out.status.success(),
            "device trainer build for the Cortex-M4F failed:\n{}",
            String::from_utf8_lossy(&out.stderr)
        );
    });
    cortex_m::elf(&target, "mpo-trainer")
}

/// Where `mpo train --net mcu` runs the learner.
#[derive(Clone, Copy)]
enum On<'a> {
    /// In-process.
    Host,
    /// The x86-64 device trainer (a child process).
    Device,
    /// This device command line (QEMU).
    Command(&'a str),
}

/// `mpo train --net mcu` for `steps` steps into `dir`, in-process or on a device, with extra
/// arguments `more`.
fn mcu(
    dir: &std::path::Path,
    steps: u64,
    on: On,
    env: &[(&str, &str)],
    more: &[&str],
) -> serde_json::Value {
    let steps = steps.to_string();
    let bin = trainer().display().to_string();
    let mut args = vec![
        "train",
        "--net",
        "mcu",
        "--threads",
        "1",
        "--no-progress",
        "--steps",
        &steps,
        "--out",
        dir.to_str().unwrap(),
    ];
    match on {
        On::Host => {}
        On::Device => args.extend_from_slice(&["--device", &bin, "--device-timeout", "0.05"]),
        On::Command(cmd) => args.extend_from_slice(&["--device", cmd]),
    }
    args.extend_from_slice(more);
    let out = Command::new(env!("CARGO_BIN_EXE_mpo"))
        .args(&args)
        .envs(env.iter().copied())
        .output()
        .expect("spawn mpo");
    ok_json(&out)
}

#[test]
fn device_run_equals_the_in_process_run_bit_for_bit() {
    let d = scratch("device-same-bits");
    let here = mcu(&d.join("here"), 4000, On::Host, &[], &[]);
    let there = mcu(&d.join("device"), 4000, On::Device, &[], &[]);
    assert_eq!(there["params_sha256"], here["params_sha256"]);
    assert_eq!(there["updates"], here["updates"]);
    assert_eq!(there["eval_return_mean"], here["eval_return_mean"]);
    // A loaded machine may miss the 50 ms reply timeout and ask again (counted as retries):
    // the bits must not care. A clean link never damages a frame.
    let dev = &there["device"];
    assert_eq!(dev["rejected_by_host"], 0, "{dev}");
    assert_eq!(dev["rejected_by_device"], 0);
    // Every metrics row agrees but the wall clock and the learner statistics (the device does
    // not send them).
    let rows = |p: PathBuf| -> Vec<(u64, u64, f64)> {
        std::fs::read_to_string(p.join("metrics.jsonl"))
            .unwrap()
            .lines()
            .map(|l| {
                let v: serde_json::Value = serde_json::from_str(l).unwrap();
                (
                    v["env_steps"].as_u64().unwrap(),
                    v["updates"].as_u64().unwrap(),
                    v["eval_return_mean"].as_f64().unwrap(),
                )
            })
            .collect()
    };
    assert_eq!(rows(d.join("here")), rows(d.join("device")));
}

/// The same run with the trainer on a Cortex-M4F: built for thumbv7em-none-eabihf (hardware
/// FPU) and run on QEMU's `mps2-an386` board, the frames over its UART. Kept short for the
/// fast test set (1000 steps, warm-up 500: 250 updates; one evaluation episode).
#[test]
fn device_run_on_the_cortex_m4f_in_qemu_equals_the_in_process_run() {
    let d = scratch("device-cortex-m");
    let cmd = cortex_m::command(&trainer_cortex_m(), None).join(" ");
    let short = [
        "--set",
        "schedule.warmup_steps=500",
        "--set",
        "schedule.eval_episodes=1",
    ];
    let here = mcu(&d.join("here"), 1000, On::Host, &[], &short);
    let there = mcu(&d.join("qemu"), 1000, On::Command(&cmd), &[], &short);
    assert_eq!(
        there["updates"], 251,
        "updates at steps 500, 502, ..., 1000"
    );
    assert_eq!(there["params_sha256"], here["params_sha256"]);
    assert_eq!(there["eval_return_mean"], here["eval_return_mean"]);
    assert_eq!(there["device"]["retries"], 0, "{}", there["device"]);
}

/// A longer run with the trainer on the Cortex-M4F (10,000 steps: 4,501 updates, three
/// evaluations of ten episodes): every evaluation and the parameters equal the in-process
/// run's. About 4 minutes (QEMU emulates about 25 updates a second here).
#[test]
#[ignore = "long: scripts/test --long"]
fn longer_device_run_on_the_cortex_m4f_in_qemu_equals_the_in_process_run() {
    let d = scratch("device-cortex-m-long");
    let cmd = cortex_m::command(&trainer_cortex_m(), None).join(" ");
    let here = mcu(&d.join("here"), 10_000, On::Host, &[], &[]);
    let there = mcu(&d.join("qemu"), 10_000, On::Command(&cmd), &[], &[]);
    assert_eq!(there["params_sha256"], here["params_sha256"]);
    assert_eq!(there["updates"], here["updates"]);
    let evals = |p: PathBuf| -> Vec<(u64, f64, f64)> {
        std::fs::read_to_string(p.join("metrics.jsonl"))
            .unwrap()
            .lines()
            .map(|l| {
                let v: serde_json::Value = serde_json::from_str(l).unwrap();
                (
                    v["env_steps"].as_u64().unwrap(),
                    v["eval_return_mean"].as_f64().unwrap(),
                    v["eval_return_std"].as_f64().unwrap(),
                )
            })
            .collect()
    };
    let (a, b) = (evals(d.join("here")), evals(d.join("qemu")));
    assert_eq!(a.len(), 3, "evaluations at 0, 5000 and 10000 steps");
    assert_eq!(a, b);
}

/// The frames of `HELLO`, `START` (the core's report configuration, seed 0, no warm-up) and
/// `EVAL` of a finite observation so large (every value -3.4e38) that this policy's mean comes
/// out NaN (the first layer overflows to infinity, and infinities of both signs meet later).
fn nan_request() -> Vec<u8> {
    let mut input = Vec::new();
    let mut frame = |k: u8, seq: u8, payload: &[u8]| {
        let mut out = vec![0u8; 512];
        let n = encode(k, seq, payload, &mut out);
        input.extend_from_slice(&out[..n]);
    };
    frame(kind::HELLO, 1, &[]);
    let mut start = vec![0u8; mpo_frames::START_LEN];
    start[8..16].copy_from_slice(&1u64.to_le_bytes()); // update interval
    start[16..24].copy_from_slice(&1u64.to_le_bytes()); // updates per interval
    start[24..28].copy_from_slice(&1u32.to_le_bytes()); // n-step
    for (i, w) in mpo_core::config::MpoConfig::REPORT
        .to_words()
        .iter()
        .enumerate()
    {
        start[32 + 4 * i..36 + 4 * i].copy_from_slice(&w.to_le_bytes());
    }
    frame(kind::START, 2, &start);
    let mut obs = [0u8; 20];
    mpo_frames::put_f32s(&[-f32::from_bits(0x7f7f_7f7f); 5], &mut obs);
    frame(kind::EVAL, 3, &obs);
    input
}

/// The replies' frames: (kind, payload).
fn frames_in(bytes: &[u8]) -> Vec<(u8, Vec<u8>)> {
    let mut rx = Box::new(Receiver::<20_000>::new(5, 1, 1330 + 1377));
    bytes
        .iter()
        .filter_map(|&b| match rx.push(b) {
            Event::Frame(k, _) => Some((k, rx.payload().to_vec())),
            _ => None,
        })
        .collect()
}

/// A NaN leaves the x86-64 and the Cortex-M4F trainers as the same bytes. The NaN an invalid
/// operation makes has its sign bit set on x86 and clear on Arm; the frames carry every NaN as
/// the canonical one (`mpo_frames::f32_bytes`), so the two devices' replies are equal.
#[test]
fn a_nan_action_leaves_x86_and_the_cortex_m4f_as_the_same_bytes() {
    let input = nan_request();
    let mut child = Command::new(trainer())
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .spawn()
        .unwrap();
    child.stdin.take().unwrap().write_all(&input).unwrap();
    let x86 = child.wait_with_output().unwrap().stdout;
    let frames = frames_in(&x86);
    let kinds: Vec<u8> = frames.iter().map(|f| f.0).collect();
    assert_eq!(kinds, [kind::INFO, kind::ACK, kind::ACTION]);
    let action = mpo_frames::u32_at(&frames[2].1, 0);
    assert_eq!(
        action,
        mpo_frames::CANONICAL_NAN,
        "the mean action for a huge observation: {:#x}",
        action
    );
    // What the x86 trainer computed before encoding: the same learner here (seed 0, the same
    // configuration) gives a NaN with the sign bit set, which is not what was sent.
    let mut learner: Box<mpo_core::learner::Learner<5, 1, 1, 32, 32, 32, 32, 32, 1, 1, 8, 8>> =
        bytemuck::zeroed_box();
    learner
        .init(mpo_core::config::MpoConfig::REPORT, 0)
        .unwrap();
    let mut raw = [0f32; 1];
    learner.mean_action(&[-f32::from_bits(0x7f7f_7f7f); 5], &mut raw);
    assert!(
        raw[0].is_nan() && raw[0].is_sign_negative(),
        "x86's own NaN: {:#x}",
        raw[0].to_bits()
    );
    let cmd = cortex_m::command(&trainer_cortex_m(), None);
    let arm = cortex_m::exchange_until(
        &cmd,
        input,
        |got| got.iter().filter(|&&b| b == mpo_frames::DELIMITER).count() >= 3,
        std::time::Duration::from_secs(60),
    );
    assert_eq!(frames_in(&arm), frames, "the Cortex-M4F's replies differ");
}

#[test]
#[ignore = "long: scripts/test --long"]
fn damaged_and_truncated_frames_both_ways_are_counted_and_recovered_from() {
    let d = scratch("device-damage");
    let clean = mcu(&d.join("clean"), 2000, On::Host, &[], &[]);
    // Every 7th frame to the device damaged (a flipped byte, or only its first half, in
    // turn); every 5th frame from it damaged (a flipped or a dropped byte, in turn).
    let damaged = mcu(
        &d.join("damaged"),
        2000,
        On::Device,
        &[
            ("MPO_TEST_DAMAGE_EVERY", "7"),
            ("MPO_TEST_DAMAGE_REPLIES_EVERY", "5"),
        ],
        &[],
    );
    assert_eq!(damaged["params_sha256"], clean["params_sha256"]);
    let dev = &damaged["device"];
    eprintln!("damaged link: {dev}");
    for k in [
        "retries",
        "rejected_by_host",
        "rejected_by_device",
        "repeats_answered",
    ] {
        assert!(dev[k].as_u64().unwrap() > 100, "{k}: {dev}");
    }
}

#[test]
fn a_dying_device_is_a_clear_error_and_the_last_checkpoint_stays() {
    let d = scratch("device-dies");
    // The device's line goes dead after 600 kB of replies (`dd` passes them on byte by byte; about 18 bytes an action, 10,000 evaluation actions per evaluation): past the first checkpoint (at
    // 5000 steps), before the second.
    let bin = trainer();
    let script = d.join("dying-device.sh");
    std::fs::write(
        &script,
        format!(
            "#!/bin/sh\n{} | dd bs=1 count=600000 status=none\n",
            shell_quote(&bin.display().to_string())
        ),
    )
    .unwrap();
    std::fs::set_permissions(&script, std::os::unix::fs::PermissionsExt::from_mode(0o755)).unwrap();
    let cmd = script.display().to_string();
    let out = Command::new(env!("CARGO_BIN_EXE_mpo"))
        .args([
            "train",
            "--net",
            "mcu",
            "--no-progress",
            "--steps",
            "20000",
            "--out",
        ])
        .arg(d.join("run"))
        .args(["--device", &cmd, "--device-timeout", "0.2"])
        .output()
        .unwrap();
    let e = err_text(&out);
    assert!(e.contains("the device stopped"), "{e}");
    let meta: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(d.join("run/checkpoint/meta.json")).expect("a checkpoint"),
    )
    .unwrap();
    assert_eq!(meta["env_steps"], 5000, "the last checkpoint fetched stays");
    // A program that does not exist.
    let out = Command::new(env!("CARGO_BIN_EXE_mpo"))
        .args([
            "train",
            "--net",
            "mcu",
            "--no-progress",
            "--steps",
            "2000",
            "--out",
        ])
        .arg(d.join("run2"))
        .args(["--device", "/nonexistent/trainer"])
        .output()
        .unwrap();
    let e = err_text(&out);
    assert!(e.contains("cannot start the device program"), "{e}");
    // --device cannot resume.
    let out = Command::new(env!("CARGO_BIN_EXE_mpo"))
        .args(["train", "--resume"])
        .arg(d.join("run"))
        .args(["--device", bin.to_str().unwrap()])
        .output()
        .unwrap();
    assert!(err_text(&out).contains("cannot be resumed"));
    // Correlated noise has no field in START: refused before the device is started.
    let out = Command::new(env!("CARGO_BIN_EXE_mpo"))
        .args(["train", "--net", "mcu", "--no-progress", "--out"])
        .arg(d.join("run4"))
        .args(["--set", "schedule.noise_corr=0.5"])
        .args(["--device", "/nonexistent/trainer"])
        .output()
        .unwrap();
    let e = err_text(&out);
    assert!(e.contains("cannot run on a device"), "{e}");
    let out = Command::new(env!("CARGO_BIN_EXE_mpo"))
        .args(["train", "--net", "mcu", "--no-progress", "--out"])
        .arg(d.join("run5"))
        .args(["--set", "schedule.noise_pink=true"])
        .args(["--device", "/nonexistent/trainer"])
        .output()
        .unwrap();
    let e = err_text(&out);
    assert!(e.contains("noise_pink cannot run on a device"), "{e}");
    // A device for other sizes: a hopper row against the cartpole trainer (with the hopper
    // rows' correlated noise turned off, which would be refused before the device is asked).
    let out = Command::new(env!("CARGO_BIN_EXE_mpo"))
        .args([
            "train",
            "--task",
            "hopper-hop",
            "--net",
            "small",
            "--no-progress",
            "--out",
        ])
        .arg(d.join("run3"))
        .args(["--set", "schedule.noise_corr=0"])
        .args(["--device", bin.to_str().unwrap()])
        .output()
        .unwrap();
    let e = err_text(&out);
    assert!(e.contains("the device reports 5 observations"), "{e}");
}

fn shell_quote(s: &str) -> String {
    format!("'{}'", s.replace('\'', "'\\''"))
}

/// Talks to the device binary directly: frames in, frames out.
#[test]
fn malformed_and_out_of_order_commands_get_error_frames() {
    let mut child = Command::new(trainer())
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .spawn()
        .unwrap();
    fn frame(input: &mut Vec<u8>, k: u8, seq: u8, payload: &[u8]) {
        let mut out = vec![0u8; 256];
        let n = encode(k, seq, payload, &mut out);
        input.extend_from_slice(&out[..n]);
    }
    let mut input = Vec::new();
    frame(&mut input, kind::HELLO, 1, &[]); // INFO
    frame(&mut input, kind::STEP, 2, &[0; 29]); // before START: OutOfOrder
    frame(&mut input, kind::EVAL, 3, &[0; 19]); // wrong length: Length (rejected)
    frame(&mut input, 0x42, 4, &[]); // unknown kind
    frame(&mut input, kind::PARAMS, 5, &[]); // PARAMS works before START
    let mut bad = vec![0u8; 256];
    let n = encode(kind::HELLO, 6, &[], &mut bad);
    bad[2] ^= 0x01; // a flipped bit: Checksum
    input.extend_from_slice(&bad[..n]);
    frame(&mut input, kind::HELLO, 6, &[]); // the same request again, intact: INFO
    frame(&mut input, kind::HELLO, 6, &[]); // a repeat: the last reply again
    let mut stdin = child.stdin.take().unwrap();
    stdin.write_all(&input).unwrap();
    drop(stdin);
    let mut bytes = Vec::new();
    child
        .stdout
        .take()
        .unwrap()
        .read_to_end(&mut bytes)
        .unwrap();
    assert!(
        child.wait().unwrap().success(),
        "the device exits cleanly at end of input"
    );
    // actor 1330 (its input normalisation: 3 x 5; its mean's bound: 1), critic 1377 (its
    // 32-wide layer norm: 64)
    let params = 1330 + 1377;
    let mut rx = Box::new(Receiver::<20_000>::new(5, 1, params));
    let mut got = Vec::new();
    for b in bytes {
        if let Event::Frame(k, s) = rx.push(b) {
            let code = (k == kind::ERROR).then(|| Fault::from_code(rx.payload()[0]).unwrap());
            got.push((k, s, code));
        }
    }
    assert_eq!(rx.rejected, 0, "the device's own frames are intact");
    let (e, seq_after) = (kind::ERROR, |s: u8| s + 1);
    assert_eq!(
        got,
        [
            (kind::INFO, 1, None),
            (e, 2, Some(Fault::OutOfOrder)),
            (e, seq_after(2), Some(Fault::Length)),
            (e, seq_after(2), Some(Fault::UnknownKind)),
            (kind::PARAMS_REPLY, 5, None),
            (e, seq_after(5), Some(Fault::Checksum)),
            (kind::INFO, 6, None),
            (kind::INFO, 6, None),
        ]
    );
}

#[test]
fn trainer_build_fails_when_alloc_or_std_enter() {
    mpo_integration::assert_builds_fail(
        &[
            ("use-alloc", "no global memory allocator"),
            ("use-std", "duplicate lang item"),
        ],
        build,
    );
}
