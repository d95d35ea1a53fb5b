#!/usr/bin/env python3
"""Wall clock to each task's target on this machine (docs/experiments.md, issue 35 item 5).

Usage: docs/results/wall_clock.py RATES.json [MORE_RATES.json...]

RATES.json is what `scripts/bench-rows --threads 1,2 --json RATES.json` wrote: each row's
updates/s while learning and environment steps/s, on one thread and on two, measured in one
window. A row measured in several files takes its rates from the first that has it (so a
later window adds rows without moving the earlier ones'; its ratios hold within its own
window). Each row's runs (`runs.TASK_ROWS`: the row's seeds in docs/results) are read by
their updates and environment steps at those rates, as `per_hour.py` does: the hours to a
run's first evaluation at or above the target, or, where no evaluation reaches it, the run's
best and the hours it had run. Evaluations and checkpoints (under 1% of a run) are left out.
Prints a markdown table, one line per row.
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


def main():
    args = sys.argv[1:]
    runs.help_or_usage(__doc__, args)
    rates = {}
    for path in args:
        for r in json.load(open(path)):
            rates.setdefault((r["task"], r["net"], r["threads"]), r)
    print("| task | target | row | updates/s, 1 / 2 threads | the budget takes (h), 1 / 2 threads "
          "| seeds at the target: hours to it, 1 / 2 threads (step) | the other seeds: best (hours run, 1 / 2 threads; steps) |")
    print("|---|---:|---|---|---|---|---|")
    for task, (target, rows) in ROWS.items():
        for net, label, dirs in rows:
            dirs = [d for d in dirs if (HERE / d / "metrics.csv").exists()]
            if not dirs:
                continue
            one, two = rates.get((task, net, 1)), rates.get((task, net, 2))
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
