//! `mpo plot`: learning curves of run directories, read from their metrics files.

use super::error::Error;
use crate::cli::PlotArgs;
use crate::settings;

fn str_value(t: &toml::Table, k: &str) -> Option<String> {
    t.get(k).and_then(|v| v.as_str()).map(str::to_string)
}

/// `mpo plot`: one curve per run directory, labelled with the directory's name; with
/// `--by-task`, one panel per task.
pub fn plot(args: &PlotArgs) -> Result<(), Error> {
    let metric = args.metric.as_deref().filter(|m| *m != RETURN);
    let mut runs = Vec::new();
    for dir in &args.runs {
        runs.push(read_run_curve(dir, metric)?);
    }
    if args.by_task {
        return plot_by_task(args, runs, metric);
    }
    let title = args.title.clone().unwrap_or_else(|| {
        format!(
            "MPO {}",
            runs.iter().find_map(|r| r.2.clone()).unwrap_or_default()
        )
    });
    let task = runs.iter().find_map(|r| r.2.clone());
    let series: Vec<_> = runs
        .into_iter()
        .map(|(label, pts, _)| (label, pts))
        .collect();
    let what = task.as_deref().unwrap_or("runs");
    let (mean, line) = args
        .mean
        .then(|| mean_of_runs(what, &series, metric))
        .transpose()?
        .unzip();
    crate::plot::write_curves(&args.out, &title, &series, mean, metric).map_err(Error::Plot)?;
    // Only after the image is written, so a refused or failed command prints no figure.
    line.iter().for_each(|l| println!("{l}"));
    Ok(())
}

/// `--mean`: the mean curve over `series` ([`crate::plot::mean_over_runs`]) with its legend
/// label, and the line to print once the image is written: its last point and each run's
/// value there (`what` names the runs): a return to one decimal, another `metric` to three
/// (a loss near 0.01, a weight growth of 1.05).
fn mean_of_runs(
    what: &str,
    series: &[crate::plot::Series],
    metric: Option<&str>,
) -> Result<(crate::plot::Series, String), Error> {
    let d = if metric.is_some() { 3 } else { 1 };
    let pts = crate::plot::mean_over_runs(series).ok_or_else(|| {
        Error::Plot(format!(
            "--mean: the {what} runs share no evaluation step (it averages at the steps every run has)"
        ))
    })?;
    let &(x, m, sd) = pts.last().expect("mean_over_runs returns points or None");
    let each: Vec<String> = series
        .iter()
        .filter_map(|(label, p)| {
            p.iter()
                .find(|q| q.0 == x)
                .map(|q| format!("{label} {:.d$}", q.1))
        })
        .collect();
    let runs = match series.len() {
        1 => "1 run".to_string(),
        n => format!("{n} runs"),
    };
    let line = format!(
        "{what}: mean of {runs} at {x} steps: {m:.d$} +- {sd:.d$} ({})",
        each.join(", ")
    );
    let label = format!("mean of {} (+-1 std over runs)", series.len());
    Ok(((label, pts), line))
}

/// `mpo plot --by-task`: the runs grouped by their task into panels, with the `--target` lines.
fn plot_by_task(args: &PlotArgs, runs: Vec<RunCurve>, metric: Option<&str>) -> Result<(), Error> {
    let mut panels: Vec<crate::plot::Panel> = Vec::new();
    for ((label, pts, task), dir) in runs.into_iter().zip(&args.runs) {
        let task = task.ok_or_else(|| {
            Error::Plot(format!(
                "{}: no `task` in config.toml (--by-task groups runs by it)",
                dir.display()
            ))
        })?;
        match panels.iter_mut().find(|p| p.title == task) {
            Some(p) => p.series.push((label, pts)),
            None => panels.push(crate::plot::Panel {
                title: task,
                series: vec![(label, pts)],
                target: None,
                budget: None,
                mean: None,
                metric: metric.map(str::to_string),
            }),
        }
    }
    for t in &args.target {
        let (panel, value) =
            panel_setting(&mut panels, "--target", "RETURN", "walker-walk=900", t)?;
        panel.target = Some(value);
    }
    for t in &args.budget {
        let (panel, value) =
            panel_setting(&mut panels, "--budget", "STEPS", "walker-run=1000000", t)?;
        if !(1.0..=1e12).contains(&value) {
            return Err(Error::Plot(format!(
                "--budget {t}: STEPS must be from 1 to 10^12"
            )));
        }
        panel.budget = Some(value as u64);
    }
    let mut lines = Vec::new();
    if args.mean {
        for p in &mut panels {
            let (mean, line) = mean_of_runs(&p.title, &p.series, metric)?;
            p.mean = Some(mean);
            lines.push(line);
        }
    }
    let title = args.title.clone().unwrap_or_else(|| "MPO".to_string());
    crate::plot::write_panels(&args.out, &title, &panels).map_err(Error::Plot)?;
    // Only after the image is written, so a refused or failed command prints no figure.
    lines.iter().for_each(|l| println!("{l}"));
    Ok(())
}

/// `TASK=VALUE` of `flag`: the panel of TASK and the value, or an error naming the flag.
fn panel_setting<'a>(
    panels: &'a mut [crate::plot::Panel],
    flag: &str,
    what: &str,
    example: &str,
    arg: &str,
) -> Result<(&'a mut crate::plot::Panel, f64), Error> {
    let bad = || {
        Error::Plot(format!(
            "{flag} {arg}: expected TASK={what}, e.g. {example}"
        ))
    };
    let (task, value) = arg.split_once('=').ok_or_else(bad)?;
    let value: f64 = value.trim().parse().map_err(|_| bad())?;
    let panel = panels
        .iter_mut()
        .find(|p| p.title == task.trim())
        .ok_or_else(|| {
            Error::Plot(format!(
                "{flag} {arg}: none of the runs given is of task {}",
                task.trim()
            ))
        })?;
    Ok((panel, value))
}

/// The column drawn by default, with its band from [`RETURN_STD`].
const RETURN: &str = "eval_return_mean";
/// The spread over the evaluation episodes: the default curve's band.
const RETURN_STD: &str = "eval_return_std";

/// One run's curve: its label (the directory's name), `(env_steps, mean, std)` per evaluation
/// from `metrics.jsonl` (or `metrics.csv` without it), and its task from `config.toml` when there is one.
type RunCurve = (String, Vec<(u64, f64, f64)>, Option<String>);

/// The curve of `metric` (`None`: the evaluation return and its band) of the run in `dir`.
fn read_run_curve(dir: &std::path::Path, metric: Option<&str>) -> Result<RunCurve, Error> {
    let jsonl = dir.join("metrics.jsonl");
    let csv = dir.join("metrics.csv");
    let pts = if jsonl.exists() || !csv.exists() {
        jsonl_points(&jsonl, metric)?
    } else {
        csv_points(&csv, metric)?
    };
    if pts.is_empty() {
        return Err(Error::Plot(format!(
            "{}: no evaluation has a value of `{}`",
            dir.display(),
            metric.unwrap_or(RETURN)
        )));
    }
    let task = settings::read_table(&dir.join("config.toml"))
        .ok()
        .and_then(|t| str_value(&t, "task"));
    let label = dir
        .file_name()
        .map(|n| n.to_string_lossy().to_string())
        .unwrap_or_else(|| dir.display().to_string());
    Ok((label, pts, task))
}

/// `(env_steps, mean, std)` per line of a `metrics.jsonl`: the evaluation return and its
/// spread, or `metric` (std 0) on the lines where it is a number (`null` before learning).
fn jsonl_points(
    path: &std::path::Path,
    metric: Option<&str>,
) -> Result<Vec<(u64, f64, f64)>, Error> {
    let text = std::fs::read_to_string(path)
        .map_err(|e| Error::Plot(format!("{}: {e}", path.display())))?;
    let mut pts = Vec::new();
    let mut seen = false;
    for (i, line) in text.lines().enumerate() {
        let v: serde_json::Value = serde_json::from_str(line)
            .map_err(|e| Error::Plot(format!("{} line {}: {e}", path.display(), i + 1)))?;
        let get = |k: &str| {
            v.get(k).and_then(|x| x.as_f64()).ok_or_else(|| {
                Error::Plot(format!(
                    "{} line {}: no number `{k}`",
                    path.display(),
                    i + 1
                ))
            })
        };
        let step = get("env_steps")? as u64;
        match metric {
            None => pts.push((step, get(RETURN)?, get(RETURN_STD)?)),
            Some(m) => {
                seen |= v.get(m).is_some();
                if let Some(x) = v.get(m).and_then(|x| x.as_f64()) {
                    pts.push((step, x, 0.0));
                }
            }
        }
    }
    if let Some(m) = metric.filter(|_| !seen) {
        return Err(Error::Plot(format!(
            "{}: no `{m}` in any line",
            path.display()
        )));
    }
    Ok(pts)
}

/// The same from a `metrics.csv` (for run directories kept without their JSON lines): the
/// columns found by name in the header; `metric`'s empty cells are left out.
fn csv_points(path: &std::path::Path, metric: Option<&str>) -> Result<Vec<(u64, f64, f64)>, Error> {
    let bad = |m: String| Error::Plot(format!("{}: {m}", path.display()));
    let mut reader = csv::Reader::from_path(path).map_err(|e| bad(e.to_string()))?;
    let header = reader.headers().map_err(|e| bad(e.to_string()))?.clone();
    let col = |k: &str| {
        header
            .iter()
            .position(|h| h == k)
            .ok_or_else(|| bad(format!("no column `{k}` in the header")))
    };
    let step = col("env_steps")?;
    let (value, spread) = match metric {
        None => (col(RETURN)?, Some(col(RETURN_STD)?)),
        Some(m) => (col(m)?, None),
    };
    let mut pts = Vec::new();
    for (i, record) in reader.records().enumerate() {
        let record = record.map_err(|e| bad(e.to_string()))?;
        let cell = |c: usize| record.get(c).map(str::trim).unwrap_or("");
        let number = |c: usize| {
            cell(c)
                .parse::<f64>()
                .map_err(|_| bad(format!("line {}: column {c} is not a number", i + 2)))
        };
        if metric.is_some() && cell(value).is_empty() {
            continue;
        }
        let sd = match spread {
            Some(c) => number(c)?,
            None => 0.0,
        };
        pts.push((number(step)? as u64, number(value)?, sd));
    }
    Ok(pts)
}
