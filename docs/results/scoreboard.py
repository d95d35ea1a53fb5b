#!/usr/bin/env python3
"""Where each task stands against the frontier's target and the published agents (issue 35).

Usage: docs/results/scoreboard.py [--runs-root DIR] [--plot OUT.png]

One line per row of each task (`runs.TASK_ROWS`: the rows, their seeds' kept runs in
docs/results and the task's target). A row's figure is the mean +- population std over its
seeds of the evaluation at the frontier's budget (500k environment steps; 100k for
cartpole-balance). Where a seed's run stopped before the budget (the rows made before this
issue had lower budgets of their own), the row gives the mean at the last step every seed
reached instead, and says so: such a figure does not answer the target. "met" compares the
budget's mean with the target.

The published figures (mean over their seeds at the same budget) are read from the tables of
reference.md beside this file, which gives their sources, seeds and step conventions: MPO and
DMPO from DreamerV3's score files, TD-MPC2, SimBa (SAC + SimBa), SimbaV2, BRO and MR.Q from
their authors' files. Where the BRO authors' files lack a task, the SimBa authors' BRO runs
(`results/bro.csv`) fill in, marked with a dagger. `--runs-root DIR` reads the runs from DIR
instead of docs/results (e.g. runs/frontier, to see unfinished runs; the layout
TASK/ROW-seedS is the same as docs/results'). Prints markdown.

`--plot OUT.png` also draws each task's default row (`runs.DEFAULT_NET`; the mean over its seeds,
+-1 std over them, the seeds behind) in a panel of its own against the target (dashed), over
at least the budget, with `mpo plot --by-task --mean` (the release binary of this checkout,
target/release/mpo: build it first).
"""
import re
import statistics
import subprocess
import sys
from pathlib import Path

import runs

HERE = Path(__file__).resolve().parent


def table(lines, header_has):
    """The rows (dicts by header cell) of the markdown table whose header contains `header_has`."""
    start = next(i for i, line in enumerate(lines) if line.startswith("|") and header_has in line)
    head = [c.strip() for c in lines[start].strip().strip("|").split("|")]
    rows = []
    for line in lines[start + 2:]:
        if not line.startswith("|"):
            break
        rows.append(dict(zip(head, (c.strip() for c in line.strip().strip("|").split("|")))))
    return rows


def mean_of(cell):
    """The leading number of a `mean +- std (n)` cell, or None for `n/a`."""
    m = re.match(r"-?\d+(\.\d+)?", cell or "")
    return float(m.group(0)) if m else None


def published(reference):
    """task -> {agent: mean at the task's budget} from reference.md's tables."""
    lines = reference.read_text().splitlines()
    out = {}
    for r in table(lines, "SimBa (SAC + SimBa) mean"):
        task, at = r["task"], r["budget (env steps)"]
        if at != f"{runs.budget(task) // 1000}k":
            continue
        out[task] = {
            "TD-MPC2": mean_of(r["TD-MPC2 mean +- std (n)"]),
            "SimBa": mean_of(r["SimBa (SAC + SimBa) mean +- std (n)"]),
            "SimbaV2": mean_of(r["SimbaV2 mean +- std (n)"]),
            "MR.Q": mean_of(r["MR.Q mean +- std (n)"]),
        }
        bro = mean_of(r["BRO mean +- std (n)"])
        out[task]["BRO"] = f"{bro:.1f}" if bro is not None else None
    for r in table(lines, "BRO (`simba` `results/bro.csv`)"):
        task = r["task"]
        if r["budget"] == f"{runs.budget(task) // 1000}k" and out[task]["BRO"] is None:
            out[task]["BRO"] = f"{mean_of(r['BRO (`simba` `results/bro.csv`)']):.1f} †"
    for r in table(lines, "| task | MPO | DMPO |"):
        task = r["task"].replace(" @100k", "")
        if task == "cartpole-balance" and "@100k" not in r["task"]:
            continue
        out[task]["MPO"] = mean_of(r["MPO"])
        out[task]["DMPO"] = mean_of(r["DMPO"])
    return out


def seeds_at(curves, step):
    """("mean +- std (seeds)", mean) of the curves' returns at `step` (no std for one seed)."""
    vals = [float(c[runs.index_at(c, step)]["eval_return_mean"]) for c in curves]
    mean = statistics.fmean(vals)
    spread = f" +- {statistics.pstdev(vals):.1f}" if len(vals) > 1 else ""
    return f"{mean:.1f}{spread} ({len(vals)})", mean


def row_figure(root, task, dirs):
    """(cell text, mean at the budget or None) for one row's seeds."""
    at = runs.budget(task)
    curves = [runs.read_rows(str(root / d)) for d in dirs if (root / d / "metrics.csv").exists()]
    if not curves:
        return None, None
    common = min(int(c[-1]["env_steps"]) for c in curves)
    if common >= at:
        return seeds_at(curves, at)
    text = f"{seeds_at(curves, common)[0]} at {common // 1000}k, where the runs stopped"
    # The seeds that did reach the budget still give the row a figure there.
    done = [c for c in curves if int(c[-1]["env_steps"]) >= at]
    if done:
        text += f"; at {at // 1000}k: {seeds_at(done, at)[0]}"
    return text, None


def plot(root, out):
    """Each task's default row against its target, one panel per task (`mpo plot`)."""
    cmd = [str(HERE.parent.parent / "target" / "release" / "mpo"), "plot", "--by-task", "--mean",
           "--out", str(out), "--title", "MPO: each task's default row against the frontier's target"]
    for task, (target, rows) in runs.TASK_ROWS.items():
        dirs = next(d for net, _label, d in rows if net == runs.DEFAULT_NET[task])
        cmd += ["--target", f"{task}={target}", "--budget", f"{task}={runs.budget(task)}"]
        cmd += [str(root / d) for d in dirs if (root / d / "metrics.csv").exists()]
    subprocess.run(cmd, check=True, stdout=sys.stderr)


def main():
    args = sys.argv[1:]
    if args and args[0] in ("-h", "--help"):
        print(__doc__.strip())
        return
    root, out = HERE, None
    while args:
        if args[0] == "--runs-root" and len(args) > 1:
            root = Path(args[1]).resolve()
        elif args[0] == "--plot" and len(args) > 1:
            out = Path(args[1]).resolve()
        else:
            sys.exit(f"unknown argument {args[0]} (--help explains)")
        args = args[2:]
    if out is not None:
        plot(root, out)
    pub = published(HERE / "reference.md")
    agents = ["MPO", "DMPO", "TD-MPC2", "SimBa", "SimbaV2", "BRO", "MR.Q"]
    print("| task (budget) | target | row | this project: mean +- std (seeds) | met | "
          + " | ".join(agents) + " |")
    print("|---|---:|---|---|---|" + "---:|" * len(agents))
    for task, (target, rows) in runs.TASK_ROWS.items():
        figures = [(label, *row_figure(root, task, dirs)) for _net, label, dirs in rows]
        for k, (label, text, mean) in enumerate(f for f in figures if f[1] is not None):
            met = "-" if mean is None else ("**yes**" if mean >= target else "no")
            if k == 0:
                name = f"{task} ({runs.budget(task) // 1000}k)"
                cells = [pub[task].get(a) for a in agents]
                theirs = " | ".join("n/a" if v is None else (v if isinstance(v, str) else f"{v:.1f}")
                                    for v in cells)
            else:
                name, theirs = "", " | ".join("" for _ in agents)
            print(f"| {name} | {target if k == 0 else ''} | {label} | {text} | {met} | {theirs} |")


if __name__ == "__main__":
    main()
