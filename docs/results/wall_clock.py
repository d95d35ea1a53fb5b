#!/usr/bin/env python3
"""Wall clock to each task's target on this machine (docs/experiments.md, issue 35 item 5).

Usage: docs/results/wall_clock.py [--hours H[,H...]] RATES.json [MORE_RATES.json...]

RATES.json is what `scripts/bench-rows --threads 1,2 --json RATES.json` wrote: each row's
updates/s while learning and environment steps/s, on one thread and on two, measured in one
window. A row measured in several files takes its rates from the first that has it (so a
later window adds rows without moving the earlier ones'; its ratios hold within its own
window). Each row's runs (`runs.TASK_ROWS`: the row's seeds in docs/results) are read by
their updates and environment steps at those rates, as `per_hour.py` does: the hours to a
run's first evaluation at or above the target, or, where no evaluation reaches it, the run's
best and the hours it had run. Evaluations and checkpoints (under 1% of a run) are left out.
Prints a markdown table, one line per row.

With `--hours 0.25,0.5,1,1.5` it prints instead which row buys the most return per hour: for
each task and row, the mean over the row's seeds of the return each had after H hours of one
thread (its last evaluation reached by then, at the rates above), the best row of each task
and horizon in bold where two rows or more have a return there. A run that ended at the
budget sooner counts with its final return (a user stops there; marked `done` where every
seed had); a run that stopped short of both, as the rows made before this issue did, has no
return at H, and its row shows `-` there.
"""
import json
import sys
from pathlib import Path

import runs

HERE = Path(__file__).resolve().parent
ROWS = runs.TASK_ROWS


def hours_to(row, rate):
    """Hours of learning and stepping to reach a metrics row at a measured rate."""
    return (int(row["updates"]) / rate["updates_per_s"]
            + int(row["env_steps"]) / rate["env_steps_per_s"]) / 3600


def seed_result(rows, target, one, two):
    """(hours on one thread, on two, step) to the first evaluation >= target, or None and the
    run's best with the hours it had run."""
    hit = runs.first_at_or_above(rows, target)
    if hit is not None:
        return (hours_to(hit, one), hours_to(hit, two), int(hit["env_steps"])), None
    last = rows[-1]
    return None, (runs.best(rows), hours_to(last, one), hours_to(last, two), int(last["env_steps"]))


def return_after(rows, rate, hours, budget):
    """(return, ended) of a run after `hours` at a one-thread rate: its last evaluation reached
    by then, its evaluation at the budget if it reached the budget sooner, (None, False) if it
    stopped short of both. A run carried on past the budget is read as if stopped there (a user
    stops at the budget). The first evaluation (step 0, no updates) is reached at once."""
    rows = [r for r in rows if int(r["env_steps"]) <= budget]
    last = rows[-1]
    if hours_to(last, rate) <= hours:
        if int(last["env_steps"]) >= budget:
            return float(last["eval_return_mean"]), True
        return None, False
    reached = [r for r in rows if hours_to(r, rate) <= hours]
    return float(reached[-1]["eval_return_mean"]), False


def per_hour_table(rates, horizons):
    """Markdown: each task's rows by their mean return after each horizon, the best bold."""
    print("| task | row (seeds) | " + " | ".join(f"after {h:g} h" for h in horizons) + " |")
    print("|---|---|" + "---:|" * len(horizons))
    for task, (_, rows) in ROWS.items():
        lines = []
        for net, label, dirs in rows:
            dirs = [d for d in dirs if (HERE / d / "metrics.csv").exists()]
            one = rates.get((task, runs.rate_net(task, net), 1))
            if not dirs or one is None:
                continue
            got = [[return_after(runs.read_rows(str(HERE / d)), one, h, runs.budget(task))
                     for d in dirs] for h in horizons]
            means = [None if any(v is None for v, _ in g) else sum(v for v, _ in g) / len(g)
                     for g in got]
            done = [all(e for _, e in g) for g in got]
            lines.append((f"{label} ({len(dirs)})", means, done))
        for i, (label, means, done) in enumerate(lines):
            cells = []
            for k, m in enumerate(means):
                known = [ln[1][k] for ln in lines if ln[1][k] is not None]
                cell = "-" if m is None else f"{m:.1f}" + (" done" if done[k] else "")
                # Bold only where two rows or more can be compared.
                cells.append(f"**{cell}**" if len(known) > 1 and m == max(known) else cell)
            print(f"| {task if i == 0 else ''} | {label} | " + " | ".join(cells) + " |")


def main():
    args = sys.argv[1:]
    runs.help_or_usage(__doc__, args)
    horizons = None
    if args[0] == "--hours":
        if len(args) < 3:
            sys.exit("usage: wall_clock.py --hours H[,H...] RATES.json [MORE_RATES.json...]")
        horizons = [float(h) for h in args[1].split(",")]
        args = args[2:]
    rates = {}
    for path in args:
        for r in json.load(open(path)):
            rates.setdefault((r["task"], r["net"], r["threads"]), r)
    if horizons:
        per_hour_table(rates, horizons)
        return
    print("| task | target | row | updates/s, 1 / 2 threads | the budget takes (h), 1 / 2 threads "
          "| seeds at the target: hours to it, 1 / 2 threads (step) | the other seeds: best (hours run, 1 / 2 threads; steps) |")
    print("|---|---:|---|---|---|---|---|")
    for task, (target, rows) in ROWS.items():
        for net, label, dirs in rows:
            dirs = [d for d in dirs if (HERE / d / "metrics.csv").exists()]
            if not dirs:
                continue
            rate = runs.rate_net(task, net)
            one, two = rates.get((task, rate, 1)), rates.get((task, rate, 2))
            if rate != net:
                label += f" (at the `{rate}` row's rate)"
            if one is None or two is None:
                print(f"| {task} | {target} | {label} | not measured | | | |")
                continue
            hit, miss = [], []
            for d in dirs:
                got, best = seed_result(runs.read_rows(str(HERE / d)), target, one, two)
                if got:
                    hit.append(f"{got[0]:.2f} / {got[1]:.2f} ({got[2] // 1000}k)")
                else:
                    miss.append(f"{best[0]:.1f} ({best[1]:.2f} / {best[2]:.2f} h; {best[3] // 1000}k)")
            print(f"| {task} | {target} | {label} | {one['updates_per_s']:.1f} / "
                  f"{two['updates_per_s']:.1f} | {one['hours_budget']:.2f} / {two['hours_budget']:.2f} "
                  f"| {len(hit)} of {len(dirs)}{': ' if hit else ''}{', '.join(hit)} | {', '.join(miss) or '-'} |")


if __name__ == "__main__":
    main()
