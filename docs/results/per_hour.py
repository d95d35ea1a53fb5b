#!/usr/bin/env python3
"""Return per hour of this machine: each run's evaluation after H hours at a given update rate.

Usage: docs/results/per_hour.py --rate R [--hours 1,2,3] [--steps-per-s S] [--target X] RUN_DIR...

Runs on a shared machine record wall clocks that say more about what ran beside them than about
their row, so this reads a run by its updates instead: at R updates/s (the row's rate measured
in one window with the rows it is compared against, `time` in a short run's summary) plus the
environment at S steps/s (default: infinite, i.e. ignored; the environment is 1-2% of a run),
H hours reach some number of updates, and the run's last evaluation at or before that point
is its return after H hours. A run that ends before is reported as `ended` with its last step.
With several runs, a last row gives the mean over the runs that got there. `--target X` adds a
column: the hours to the run's first evaluation at or above X, or `not reached` with the run's
best and the hours it had run (rates per row: `scripts/bench-rows`).
"""
import statistics
import sys

import runs


def seconds_to(row, rate, env_rate):
    """Learning (and stepping) time to reach a metrics row at the given rates."""
    t = int(row["updates"]) / rate
    if env_rate:
        t += int(row["env_steps"]) / env_rate
    return t


def to_target(rows, target, rate, env_rate):
    """Hours to the first evaluation at or above `target`, or the run's best if none."""
    hit = runs.first_at_or_above(rows, target)
    if hit is not None:
        h = seconds_to(hit, rate, env_rate) / 3600
        return f"{h:.2f} h ({int(hit['env_steps']) // 1000}k)"
    h = seconds_to(rows[-1], rate, env_rate) / 3600
    return f"not reached (best {runs.best(rows):.1f} in {h:.2f} h, {int(rows[-1]['env_steps']) // 1000}k)"


def main():
    args = sys.argv[1:]
    runs.help_or_usage(__doc__, args)
    rate, hours, env_rate, target = None, [1.0, 2.0, 3.0], None, None
    while args and args[0].startswith("--"):
        if args[0] == "--rate":
            rate = float(args[1])
        elif args[0] == "--hours":
            hours = [float(h) for h in args[1].split(",")]
        elif args[0] == "--steps-per-s":
            env_rate = float(args[1])
        elif args[0] == "--target":
            target = float(args[1])
        else:
            sys.exit(f"unknown option {args[0]}")
        args = args[2:]
    if rate is None or rate <= 0 or not args:
        sys.exit("need --rate R (> 0) and at least one run directory")
    head = " | ".join(f"after {h:g} h" for h in hours)
    extra = f" {target:g} reached after |" if target is not None else ""
    print(f"| run | {head} |{extra}")
    print("|---" * (len(hours) + 1 + (target is not None)) + "|")
    got = [[] for _ in hours]
    for d in args:
        rows = runs.read_rows(d)
        cells = []
        for k, h in enumerate(hours):
            reached = [r for r in rows if seconds_to(r, rate, env_rate) <= h * 3600]
            last = rows[-1]
            if seconds_to(last, rate, env_rate) < h * 3600:
                cells.append(f"ended ({int(last['env_steps']) // 1000}k)")
                continue
            r = reached[-1]
            v = float(r["eval_return_mean"])
            got[k].append(v)
            cells.append(f"{v:.1f} ({int(r['env_steps']) // 1000}k)")
        if target is not None:
            cells.append(to_target(rows, target, rate, env_rate))
        print(f"| {d.rstrip('/')} | " + " | ".join(cells) + " |")
    if len(args) > 1:
        means = [
            f"{statistics.mean(g):.1f} ({len(g)})" if g else "-" for g in got
        ]
        print("| mean (runs that got there) | " + " | ".join(means) + " |")


if __name__ == "__main__":
    main()
