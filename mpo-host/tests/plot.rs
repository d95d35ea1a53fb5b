//! `mpo plot`: `--by-task` (runs grouped into one panel per task, target lines), `--mean` (the
//! mean over runs, drawn and printed), and clear errors for runs it cannot group or average.
//! The runs are written by hand (a `metrics.jsonl` and a `config.toml` naming the task), so no
//! training is needed.

mod common;
use common::*;

use std::path::{Path, PathBuf};

/// A run directory with `evals` evaluations of `task` rising from 0 by `slope` per 10k steps.
fn fake_run(root: &Path, name: &str, task: Option<&str>, evals: u64, slope: f64) -> PathBuf {
    let dir = root.join(name);
    std::fs::create_dir_all(&dir).unwrap();
    let lines: Vec<String> = (0..evals)
        .map(|i| {
            format!(
                r#"{{"env_steps":{},"eval_return_mean":{},"eval_return_std":{}}}"#,
                i * 10_000,
                slope * i as f64,
                5.0
            )
        })
        .collect();
    std::fs::write(dir.join("metrics.jsonl"), lines.join("\n")).unwrap();
    if let Some(t) = task {
        std::fs::write(
            dir.join("config.toml"),
            format!("task = \"{t}\"\nseed = 0\n"),
        )
        .unwrap();
    }
    dir
}

/// Width and height from a PNG's IHDR chunk.
fn png_size(path: &Path) -> (u32, u32) {
    let b = std::fs::read(path).unwrap();
    assert!(b.starts_with(b"\x89PNG"), "{} is not a PNG", path.display());
    let word = |i: usize| u32::from_be_bytes(b[i..i + 4].try_into().unwrap());
    (word(16), word(20))
}

fn plot(args: &[&str]) -> std::process::Output {
    let mut all = vec!["plot"];
    all.extend_from_slice(args);
    mpo(&all)
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// `mpo plot ARGS --out d/NAME`, which must succeed: the image's bytes and its size.
fn draw(d: &Path, name: &str, args: &[&str]) -> (Vec<u8>, (u32, u32)) {
    let png = d.join(name);
    let mut all = args.to_vec();
    all.extend_from_slice(&["--out", s(&png)]);
    let out = plot(&all);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    (std::fs::read(&png).unwrap(), png_size(&png))
}

#[test]
fn by_task_draws_one_panel_per_task_and_the_target_line() {
    let d = scratch("plot-by-task");
    let a0 = fake_run(&d, "a-s0", Some("walker-walk"), 6, 100.0);
    let b0 = fake_run(&d, "b-s0", Some("cheetah-run"), 4, 50.0);
    let a1 = fake_run(&d, "a-s1", Some("walker-walk"), 5, 80.0);
    let runs = [s(&a0), s(&b0), s(&a1)];
    let with = |extra: &[&'static str]| [extra, &runs[..]].concat();
    // Two tasks (three runs): two panels side by side under the title band.
    let (two, size) = draw(&d, "two.png", &with(&["--by-task"]));
    assert_eq!(size, (960, 360));
    // Four tasks: three columns, two rows.
    let c = fake_run(&d, "c", Some("hopper-hop"), 3, 10.0);
    let e = fake_run(&d, "e", Some("acrobot-swingup"), 3, 10.0);
    let four = ["--by-task", s(&a0), s(&b0), s(&c), s(&e)];
    assert_eq!(draw(&d, "four.png", &four).1, (1440, 680));
    // A target line: the same size, other pixels.
    let (lined, size) = draw(
        &d,
        "lined.png",
        &with(&["--by-task", "--target", "walker-walk=900"]),
    );
    assert_eq!(size, (960, 360));
    assert_ne!(lined, two);
    // A budget longer than the runs widens the panel's step axis: other pixels again; one no
    // longer than the longest run changes nothing.
    let wide = draw(
        &d,
        "b1.png",
        &with(&["--by-task", "--budget", "cheetah-run=100000"]),
    );
    assert_ne!(wide.0, two);
    let same = draw(
        &d,
        "b2.png",
        &with(&["--by-task", "--budget", "cheetah-run=30000"]),
    );
    assert_eq!(same.0, two);
    // A run kept with only its metrics.csv draws the same pixels as from its JSON lines.
    let csv_only = d.join("csv").join("a-s0");
    std::fs::create_dir_all(&csv_only).unwrap();
    let mut csv = String::from("env_steps,updates,eval_return_mean,eval_return_std\n");
    for i in 0..6u64 {
        let (x, u, m) = (i * 10_000, i * 100, 100.0 * i as f64);
        csv.push_str(&format!("{x},{u},{m},5\n"));
    }
    std::fs::write(csv_only.join("metrics.csv"), csv).unwrap();
    std::fs::copy(a0.join("config.toml"), csv_only.join("config.toml")).unwrap();
    let from_csv = draw(&d, "csv.png", &["--by-task", s(&csv_only), s(&b0), s(&a1)]);
    assert_eq!(from_csv.0, two);
    // Without --by-task the runs share one chart, as before.
    assert_eq!(draw(&d, "one.png", &[s(&a0), s(&a1)]).1, (900, 540));
}

#[test]
fn by_task_refuses_what_it_cannot_group_or_draw() {
    let d = scratch("plot-by-task-errors");
    let a = fake_run(&d, "a", Some("walker-walk"), 3, 100.0);
    let untasked = fake_run(&d, "untasked", None, 3, 100.0);
    let png = d.join("x.png");
    // `mpo plot --by-task FLAG VALUE --out x.png RUNS...` must fail (status 1): its stderr.
    let refused = |flag: &str, value: &str, runs: &[&Path]| {
        let mut args = vec!["--by-task", flag, value, "--out", s(&png)];
        args.retain(|x| !x.is_empty());
        args.extend(runs.iter().map(|r| s(r)));
        err_text(&plot(&args))
    };
    let err = refused("", "", &[&a, &untasked]);
    assert!(
        err.contains("untasked") && err.contains("no `task`"),
        "{err}"
    );
    let err = refused("--target", "cheetah-run=600", &[&a]);
    assert!(
        err.contains("none of the runs given is of task cheetah-run"),
        "{err}"
    );
    for bad in ["walker-walk", "walker-walk=high"] {
        let err = refused("--target", bad, &[&a]);
        assert!(err.contains("expected TASK=RETURN"), "{bad}: {err}");
    }
    for bad in ["walker-walk=x", "walker-walk=0", "walker-walk"] {
        let err = refused("--budget", bad, &[&a]);
        assert!(
            err.contains("--budget") && err.contains("STEPS"),
            "{bad}: {err}"
        );
    }
    // --target needs --by-task: a usage error (exit status 2).
    let out = plot(&["--target", "walker-walk=900", "--out", s(&png), s(&a)]);
    assert_eq!(out.status.code(), Some(2));
    assert!(!png.exists(), "nothing is drawn after an error");
}

#[test]
fn mean_draws_and_prints_the_mean_over_runs_at_the_steps_they_share() {
    let d = scratch("plot-mean");
    // Three seeds of one task; the second stops one evaluation early (0..40k), so the mean
    // ends at 40k, where the returns are 400, 320 and 480.
    let runs = [
        fake_run(&d, "ww-s0", Some("walker-walk"), 6, 100.0),
        fake_run(&d, "ww-s1", Some("walker-walk"), 5, 80.0),
        fake_run(&d, "ww-s2", Some("walker-walk"), 6, 120.0),
    ];
    let names: Vec<&str> = runs.iter().map(|r| s(r)).collect();
    let png = d.join("mean.png");
    let mut args = vec!["--mean", "--out", s(&png)];
    args.extend(&names);
    let out = plot(&args);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    // The population standard deviation of (400, 320, 480), written out independently.
    let sd = ((0.0f64 + 80.0 * 80.0 + 80.0 * 80.0) / 3.0).sqrt();
    let expected = format!(
        "walker-walk: mean of 3 runs at 40000 steps: 400.0 +- {sd:.1} (ww-s0 400.0, ww-s1 320.0, ww-s2 480.0)"
    );
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert_eq!(stdout.trim(), expected);
    // The same runs without --mean: the same size, other pixels (the thin runs, the black mean).
    let plain = draw(&d, "plain.png", &names);
    assert_eq!(png_size(&png), plain.1);
    assert_ne!(std::fs::read(&png).unwrap(), plain.0);
    // With --by-task, one line per panel, each panel's own runs averaged.
    let other = fake_run(&d, "cr-s0", Some("cheetah-run"), 3, 50.0);
    let mut args = vec!["--by-task", "--mean"];
    args.extend(&names);
    args.push(s(&other));
    let png2 = d.join("panels.png");
    args.extend(["--out", s(&png2)]);
    let out = plot(&args);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let stdout = String::from_utf8_lossy(&out.stdout);
    let lines: Vec<&str> = stdout.lines().collect();
    assert_eq!(lines.len(), 2, "{stdout}");
    assert_eq!(lines[0], expected);
    assert_eq!(
        lines[1],
        "cheetah-run: mean of 1 run at 20000 steps: 100.0 +- 0.0 (cr-s0 100.0)"
    );
}

#[test]
fn mean_refuses_runs_that_share_no_evaluation_step() {
    let d = scratch("plot-mean-disjoint");
    let a = fake_run(&d, "a", Some("walker-walk"), 3, 100.0);
    // Evaluations at 5k, 15k, 25k: none at a's 0, 10k, 20k.
    let b = d.join("b");
    std::fs::create_dir_all(&b).unwrap();
    let lines: Vec<String> = (0..3)
        .map(|i| {
            format!(
                r#"{{"env_steps":{},"eval_return_mean":1,"eval_return_std":0}}"#,
                5_000 + 10_000 * i
            )
        })
        .collect();
    std::fs::write(b.join("metrics.jsonl"), lines.join("\n")).unwrap();
    let png = d.join("x.png");
    let err = err_text(&plot(&["--mean", "--out", s(&png), s(&a), s(&b)]));
    assert!(err.contains("share no evaluation step"), "{err}");
    // A refused flag with --by-task: no mean printed either (err_text checks stdout is empty).
    let err = err_text(&plot(&[
        "--by-task",
        "--mean",
        "--target",
        "cheetah-run=600",
        "--out",
        s(&png),
        s(&a),
    ]));
    assert!(err.contains("none of the runs given"), "{err}");
    assert!(!png.exists(), "nothing is drawn after an error");
}

#[test]
fn metric_draws_another_column_and_skips_the_evaluations_without_it() {
    let d = scratch("plot-metric");
    // Two runs' JSON lines with a `q_mean` that is null before learning (step 0), and one
    // run kept as `metrics.csv` only, whose first `q_mean` cell is empty.
    let mut names = Vec::new();
    for (name, q) in [("a", [2.0, 4.0]), ("b", [4.0, 8.0])] {
        let dir = d.join(name);
        std::fs::create_dir_all(&dir).unwrap();
        let lines = [
            r#"{"env_steps":0,"eval_return_mean":0,"eval_return_std":0,"q_mean":null}"#.into(),
            format!(
                r#"{{"env_steps":10000,"eval_return_mean":5,"eval_return_std":1,"q_mean":{}}}"#,
                q[0]
            ),
            format!(
                r#"{{"env_steps":20000,"eval_return_mean":9,"eval_return_std":1,"q_mean":{}}}"#,
                q[1]
            ),
        ];
        std::fs::write(dir.join("metrics.jsonl"), lines.join("\n")).unwrap();
        names.push(dir);
    }
    let c = d.join("c");
    std::fs::create_dir_all(&c).unwrap();
    std::fs::write(
        c.join("metrics.csv"),
        "env_steps,eval_return_mean,eval_return_std,q_mean\n0,0,0,\n10000,5,1,3\n20000,9,1,9\n",
    )
    .unwrap();
    names.push(c);
    let names: Vec<&str> = names.iter().map(|p| s(p)).collect();
    let png = d.join("q.png");
    let mut args = vec!["--metric", "q_mean", "--mean", "--out", s(&png)];
    args.extend(&names);
    let out = plot(&args);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    // The mean at 20k over 4, 8 and 9 (step 0 left out: no run has a number there), to
    // three decimals (a metric's; a return's is one).
    let sd = (((4.0f64 - 7.0).powi(2) + 1.0 + 4.0) / 3.0).sqrt();
    assert_eq!(
        String::from_utf8_lossy(&out.stdout).trim(),
        format!(
            "runs: mean of 3 runs at 20000 steps: 7.000 +- {sd:.3} (a 4.000, b 8.000, c 9.000)"
        )
    );
    // The return of the same runs is another picture.
    let ret = draw(&d, "ret.png", &names);
    assert_ne!(std::fs::read(&png).unwrap(), ret.0);
    // A column no run has is named in the error, from either file.
    for run in [names[0], names[2]] {
        let err = err_text(&plot(&["--metric", "q_meen", "--out", s(&png), run]));
        assert!(err.contains("q_meen"), "{err}");
    }
}
