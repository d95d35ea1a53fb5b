//! The scripts that turn kept runs into the docs' tables (`docs/results/*.py`) and the
//! frontier's plan (`scripts/frontier`) still read what the repository holds: each is run
//! here on the real files and its output checked against what it must say. They break
//! silently otherwise: a table's header edited in reference.md, a kept run renamed, a run
//! planned twice.

use std::path::Path;
use std::process::Command;

fn root() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

/// Runs a script of the repository with arguments, whatever its exit status.
fn output(script: &str, args: &[&str], envs: &[(&str, &Path)]) -> std::process::Output {
    let mut cmd = Command::new("python3");
    cmd.arg(root().join(script)).args(args).current_dir(root());
    for (k, v) in envs {
        cmd.env(k, v);
    }
    cmd.output().expect("python3 runs")
}

/// Runs a script of the repository with arguments; its standard output, or a panic with
/// its standard error.
fn run(script: &str, args: &[&str], envs: &[(&str, &Path)]) -> String {
    let out = output(script, args, envs);
    assert!(
        out.status.success(),
        "{script} {args:?} failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8(out.stdout).expect("utf-8 output")
}

/// The markdown table's data rows, as cells.
fn table_rows(md: &str) -> Vec<Vec<String>> {
    md.lines()
        .filter(|l| l.starts_with('|') && !l.starts_with("|---"))
        .skip(1)
        .map(|l| {
            l.trim()
                .trim_matches('|')
                .split('|')
                .map(|c| c.trim().to_string())
                .collect()
        })
        .collect()
}

/// The task names of a table whose first cell names the task on its first line only.
fn task_names(rows: &[Vec<String>]) -> Vec<&str> {
    rows.iter()
        .map(|r| r[0].as_str())
        .filter(|t| !t.is_empty())
        .collect()
}

#[test]
fn the_scoreboard_gives_every_task_its_rows_and_the_published_agents() {
    let md = run("docs/results/scoreboard.py", &[], &[]);
    let rows = table_rows(&md);
    assert_eq!(
        task_names(&rows).len(),
        10,
        "one first line per task:\n{md}"
    );
    for r in &rows {
        assert_eq!(r.len(), 12, "12 cells per line: {r:?}");
        if r[0].is_empty() {
            continue;
        }
        // The first line of a task carries every published figure: a number or n/a, never
        // an empty cell (which is what a renamed column in reference.md would give).
        for cell in &r[5..] {
            let lead = cell.trim_end_matches(" †");
            assert!(
                lead == "n/a" || lead.parse::<f64>().is_ok(),
                "{}: published cell {cell:?}",
                r[0]
            );
        }
    }
    // hopper-hop's default row over its three seeds at 500k: 305.0, 283.0, 200.7 (the kept
    // metrics.csv files), so its mean is 262.9 and the target 250 is met.
    let start = rows
        .iter()
        .position(|r| r[0].starts_with("hopper-hop"))
        .expect("hopper-hop's first line");
    let hop = rows[start..]
        .iter()
        .take_while(|r| r[0].is_empty() || r[0].starts_with("hopper-hop"))
        .find(|r| r[2].starts_with("`simba` (the default now)"))
        .expect("hopper-hop's simba row");
    assert!(hop[3].starts_with("262.9 +- "), "{hop:?}");
    assert_eq!(hop[4], "**yes**");
    // A row whose runs stopped before the budget says so and answers no target.
    let swing = rows
        .iter()
        .find(|r| r[0].starts_with("cartpole-swingup"))
        .unwrap();
    assert!(swing[3].contains("where the runs stopped"), "{swing:?}");
    assert_eq!(swing[4], "-");
    // walker-stand's default: seed 0 to 500k (964.5 there), seeds 1 and 2 to 300k (949.7,
    // 956.8, 909.9 at 300k: 938.8): the mean where all three ran, then seed 0's at the budget.
    let stand = rows
        .iter()
        .find(|r| r[0].starts_with("walker-stand"))
        .unwrap();
    assert_eq!(
        stand[3], "938.8 +- 20.6 (3) at 300k, where the runs stopped; at 500k: 964.5 (1)",
        "{stand:?}"
    );
}

#[test]
fn the_wall_clock_table_reads_every_row_it_has_rates_for() {
    let md = run(
        "docs/results/wall_clock.py",
        &[
            "docs/results/rates-all-rows.json",
            "docs/results/rates.json",
            "docs/results/rates-hopper-hop-ablation.json",
            "docs/results/rates-simba-rows.json",
        ],
        &[],
    );
    let rows = table_rows(&md);
    assert!(rows.len() >= 10, "{md}");
    for r in &rows {
        assert_ne!(r[3], "not measured", "a row without rates: {r:?}");
    }
}

/// The per-hour table (`wall_clock.py --hours HOURS`): its markdown and its rows.
fn per_hour(hours: &str) -> (String, Vec<Vec<String>>) {
    let md = run(
        "docs/results/wall_clock.py",
        &["--hours", hours, "docs/results/rates-all-rows.json"],
        &[],
    );
    let rows = table_rows(&md);
    (md, rows)
}

/// The line of `task`'s block whose row label starts with `label`.
fn row_of<'a>(rows: &'a [Vec<String>], task: &str, label: &str) -> &'a [String] {
    let start = rows.iter().position(|r| r[0] == task).unwrap();
    rows[start..]
        .iter()
        .find(|r| r[1].starts_with(label))
        .unwrap_or_else(|| panic!("{task}'s {label} row"))
}

#[test]
fn the_per_hour_table_reads_the_runs_at_their_rates_and_bolds_only_comparisons() {
    let (md, rows) = per_hour("0.5,1");
    assert_eq!(
        task_names(&rows).len(),
        10,
        "one first line per task:\n{md}"
    );
    // hopper-hop's `simba` seeds after one hour of one thread: 266.3, 249.5, 186.7, mean
    // 234.2, as per_hour.py reads them (docs/experiments.md, "Wall clock"), the best row there.
    let hop = row_of(&rows, "hopper-hop", "`simba` (the default now)");
    assert_eq!(hop[3], "**234.2**", "{hop:?}");
    // A task with one row (walker-walk: no `simba` run kept yet) has nothing to compare: no
    // bold.
    let at = rows.iter().position(|r| r[0] == "walker-walk").unwrap();
    assert!(!rows[at + 1][0].is_empty(), "walker-walk has one row: {md}");
    let walk = &rows[at];
    assert!(walk.iter().all(|c| !c.contains("**")), "{walk:?}");
    // A row with runs that stopped short of an hour and of the budget (walker-stand's MLP
    // seeds 1 and 2, at 300k; its seed 0 reached the budget) has no mean there.
    let stand = rows.iter().find(|r| r[0] == "walker-stand").unwrap();
    assert_eq!(stand[3], "-", "{stand:?}");
}

#[test]
fn the_per_hour_table_reads_a_run_carried_past_its_budget_at_the_budget() {
    // walker-run's MLP seed 0 ran on to 1M (2.44 hours of one thread); after two hours a user
    // who stopped at the 500k budget has its 500k return (556.4), so the row's mean is its
    // three seeds' at 500k, 398.9, and done. Read on past the budget it would be 378.7.
    let (_, rows) = per_hour("2");
    let mlp = row_of(&rows, "walker-run", "`mlp`");
    assert_eq!(mlp[2], "398.9 done", "{mlp:?}");
}

#[test]
fn the_mean_multiplier_table_counts_the_evaluations_at_its_floor() {
    // docs/experiments.md quotes these: walker-run's `simba` seed 0 has `alpha_mean` below
    // 1e-6 at 21 of its 25 evaluations after learning started, its MLP seed 0 at none of 50.
    let md = run(
        "docs/results/multipliers.py",
        &[
            "--mean",
            "docs/results/walker-run/simba-seed0",
            "docs/results/walker-run/default-seed0",
        ],
        &[],
    );
    let rows = table_rows(&md);
    assert_eq!(rows.len(), 2, "{md}");
    assert_eq!(rows[0][1], "21 of 25", "{:?}", rows[0]);
    assert_eq!(rows[1][1], "0 of 50", "{:?}", rows[1]);
}

#[test]
fn the_wind_up_table_reads_either_multiplier() {
    // docs/experiments.md quotes these: pendulum-swingup's MLP seed 0 has `alpha_mean` above
    // 1e4 at 13 of 25 evaluations from 200k and `alpha_cov` at 15 from 180k; its `simba`
    // seed 0's mean multiplier never.
    let runs = [
        "docs/results/pendulum-swingup/mlp-seed0",
        "docs/results/pendulum-swingup/simba-seed0",
    ];
    let of_mean = ["--of", "alpha_mean", runs[0], runs[1]];
    let mean = table_rows(&run("docs/results/multipliers.py", &of_mean, &[]));
    assert_eq!(
        (mean[0][1].as_str(), mean[0][2].as_str()),
        ("13 of 25", "200k")
    );
    assert_eq!(mean[1][1], "0 of 25", "{:?}", mean[1]);
    let cov = table_rows(&run("docs/results/multipliers.py", &runs, &[]));
    assert_eq!(
        (cov[0][1].as_str(), cov[0][2].as_str()),
        ("15 of 25", "180k")
    );
}

#[test]
fn a_rerun_of_a_seed_is_the_same_run_and_another_seed_is_not() {
    // walker-stand's MLP seed 0 to 500k (2026-12-07) repeats the seed's run to 300k
    // (2026-12-02) in every column but the timings; seed 1 differs from it.
    let same = run(
        "docs/results/same_run.py",
        &["walker-stand/default-seed0", "walker-stand/mlp-seed0"],
        &[],
    );
    assert!(
        same.trim_end()
            .ends_with("16 evaluations (0k-300k), 28 columns but the timings: equal"),
        "{same}"
    );
    let other = output(
        "docs/results/same_run.py",
        &["walker-stand/default-seed1", "walker-stand/mlp-seed0"],
        &[],
    );
    assert_eq!(other.status.code(), Some(1));
    let text = String::from_utf8_lossy(&other.stdout);
    assert!(
        text.contains("differs at 20000: eval_return_mean"),
        "{text}"
    );
}

#[test]
fn the_frontier_plans_each_run_once_and_starts_with_what_is_missing() {
    let empty = std::env::temp_dir().join(format!("frontier-plan-{}", std::process::id()));
    std::fs::create_dir_all(&empty).unwrap();
    let out = run("scripts/frontier", &["list"], &[("FRONTIER_DIR", &empty)]);
    let _ = std::fs::remove_dir_all(&empty);
    // One line per run, then a blank line and the hours the plan has left.
    let names: Vec<&str> = out
        .lines()
        .skip(1)
        .take_while(|l| !l.is_empty())
        .map(|l| l.split_whitespace().next().unwrap())
        .collect();
    let total = out.lines().last().unwrap();
    assert!(
        total.contains("runs unfinished: about") && total.contains("hours of one thread"),
        "{total}"
    );
    let mut unique = names.clone();
    unique.sort();
    unique.dedup();
    assert_eq!(unique.len(), names.len(), "a run planned twice:\n{out}");
    // Three seeds of `simba` on the four hardest tasks and one on each of the other six
    // (three on cartpole-balance), as the plan's docstring says.
    for task in [
        "hopper-hop",
        "walker-run",
        "cheetah-run",
        "acrobot-swingup",
        "cartpole-balance",
    ] {
        for s in 0..3 {
            let name = format!("{task}/simba/seed{s}");
            assert!(names.contains(&name.as_str()), "{name} not planned");
        }
    }
    for task in [
        "cartpole-swingup",
        "pendulum-swingup",
        "hopper-stand",
        "walker-stand",
        "walker-walk",
    ] {
        assert!(names.contains(&format!("{task}/simba/seed0").as_str()));
    }
    // With no runs/ the runs kept in docs/results count as done: their line says so.
    let kept = out
        .lines()
        .find(|l| l.starts_with("hopper-hop/simba/seed0 "))
        .unwrap();
    assert!(
        kept.contains("(kept in docs/results/hopper-hop/simba-seed0)"),
        "{kept}"
    );
}

#[test]
fn compare_counts_the_evaluations_a_row_leads_and_its_window_means() {
    // acrobot-swingup's three `simba` seeds against its MLP seed (the kept metrics.csv
    // files): the figures docs/experiments.md quotes for its default change.
    let out = run(
        "docs/results/compare.py",
        &[
            "--against",
            "acrobot-swingup/noise-0.95-seed0",
            "--window",
            "300000",
            "400000",
            "acrobot-swingup/simba-seed0",
            "acrobot-swingup/simba-seed1",
            "acrobot-swingup/simba-seed2",
        ],
        &[],
    );
    let lines: Vec<&str> = out.lines().collect();
    assert_eq!(lines.len(), 5, "{out}");
    for (line, above) in lines.iter().zip(["19 of 20", "19 of 20", "17 of 20"]) {
        assert!(line.contains(&format!("at {above} shared")), "{line}");
    }
    assert!(lines[0].contains("300k-400k 112.1") && lines[0].contains("15 below 1"));
    assert!(lines[3].contains("300k-400k 44.5"), "{}", lines[3]);
    assert!(
        lines[4].contains("at 19 of 20") && lines[4].contains("400k 159.0"),
        "{}",
        lines[4]
    );
}

#[test]
fn the_scripts_know_which_row_each_moved_default_repeats_as_the_table_does() {
    // docs/results/runs.py's MOVED_DEFAULT (read by scripts/frontier and scripts/bench-rows)
    // against the built-in rows: exactly those tasks have an `mlp` row, and their `default`
    // row is the named row it lists (its networks, settings, schedule and budget).
    let listed = Command::new("python3")
        .args([
            "-c",
            "import runs; print(' '.join(f'{t}={n}' for t, n in runs.MOVED_DEFAULT.items()))",
        ])
        .current_dir(root().join("docs/results"))
        .output()
        .expect("python3 runs");
    let listed = String::from_utf8(listed.stdout).unwrap();
    let mut listed: Vec<(&str, &str)> = listed
        .split_whitespace()
        .map(|p| p.split_once('=').unwrap())
        .collect();
    listed.sort();
    let mut table: Vec<&str> = mpo_host::table::rows()
        .iter()
        .filter(|r| r.net == "mlp")
        .map(|r| r.task.as_str())
        .collect();
    table.sort();
    assert_eq!(listed.iter().map(|p| p.0).collect::<Vec<_>>(), table);
    for (task, named) in &listed {
        let d = mpo_host::table::row(task, "default").unwrap();
        let r = mpo_host::table::row(task, named).unwrap();
        assert_eq!(
            (&d.sizes, d.steps, &d.schedule, &d.mpo),
            (&r.sizes, r.steps, &r.schedule, &r.mpo),
            "{task}'s default is not its {named} row"
        );
    }
}

#[test]
fn the_ablation_table_compares_each_mechanism_on_the_seeds_both_rows_reached() {
    let md = run("docs/results/ablation.py", &[], &[]);
    let rows = table_rows(&md);
    assert_eq!(rows.len(), 6, "one line per mechanism:\n{md}");
    let mechanism = |name: &str| {
        rows.iter()
            .find(|r| r[0].starts_with(name))
            .unwrap_or_else(|| panic!("no line for {name}:\n{md}"))
    };
    // hopper-hop's seed 0 (the kept metrics.csv at 500k): `simba` 305.0, `residual` 247.4,
    // `categorical` 247.8, `mlp` 147.8; the critic is on in the first row of each pair.
    assert_eq!(
        mechanism("categorical critic")[2],
        "305.0 / 247.4 (+57.6; seed 0)<br>247.8 / 147.8 (+100.1; seed 0)"
    );
    // walker-run's MLP seed 0 is the row's `default-seed0` (runs.TASK_ROWS), its seeds 1-2
    // `mlp-seed1/2`: all three at 500k. hopper-hop's MLP seeds 1-2 stopped at 460k: seed 0 at
    // the budget, then the three seeds where all six runs are.
    let both = mechanism("both");
    assert_eq!(both[3], "467.9 / 398.9 (+69.0; seeds 0-2)");
    assert_eq!(
        both[2],
        "305.0 / 147.8 (+157.2; seed 0); seeds 0-2 at 460k: 261.7 / 169.5 (+92.2)"
    );
    // Past the budget no seed has both rows: the sphere's pair (both to 500k) is read where
    // the two stopped, and says so.
    let late = run("docs/results/ablation.py", &["--at", "600000"], &[]);
    let late = table_rows(&late);
    let sphere = late
        .iter()
        .find(|r| r[0].starts_with("weights on"))
        .unwrap();
    assert_eq!(
        sphere[3],
        "472.3 / 524.0 (-51.7; seed 0) at 500k, stopped short"
    );
}
