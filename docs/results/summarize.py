#!/usr/bin/env python3
"""Summarises `mpo train` run directories into the markdown rows of docs/training.md.

Usage: docs/results/summarize.py [--target X] [--at STEP] [--label NAME] RUN_DIR...
(each RUN_DIR with metrics.csv). Per run: first environment step whose evaluation mean is
>= X (default 900) and the training wall clock there, best and final evaluation, total wall
clock, mean environment steps/s and updates/s. `--at STEP` reads each run as if it ended at
the evaluation of environment step STEP (so runs stopped at different steps compare at one
budget; a run without that evaluation is an error). With several runs, a last row gives the final
evaluation's mean +- standard deviation over the runs (population std, as the evaluation's).
"""
import statistics
import sys

import runs


def main():
    args = sys.argv[1:]
    target, label, at = 900.0, None, None
    runs.help_or_usage(__doc__, args)
    while args and args[0].startswith("--"):
        if args[0] == "--target":
            target = float(args[1])
        elif args[0] == "--at":
            at = int(args[1])
        elif args[0] == "--label":
            label = args[1]
        else:
            sys.exit(f"unknown option {args[0]}")
        args = args[2:]
    t = f"{target:g}"
    print(f"| run | first eval >= {t} at (steps) | wall there (s) | best eval | final eval (mean +- std) | env steps | total wall (s) | env steps/s | updates/s |")
    print("|---|---|---|---|---|---|---|---|---|")
    finals = []
    for d in args:
        rows = runs.read_rows(d)
        if at is not None:
            i = runs.index_at(rows, at)
            if i is None:
                sys.exit(f"{d}: no evaluation at environment step {at}")
            rows = rows[: i + 1]
        first = runs.first_at_or_above(rows, target)
        last = rows[-1]
        best = runs.best(rows)
        wall = float(last["wall_s"])
        steps = int(last["env_steps"])
        updates = int(last["updates"])
        final = float(last["eval_return_mean"])
        finals.append(final)
        name = d.rstrip("/").split("/")[-1]
        reached = (f"{int(first['env_steps'])} | {float(first['wall_s']):.0f}" if first else "not reached | -")
        print(
            f"| {name} | {reached} | {best:.1f} | {final:.1f} +- {float(last['eval_return_std']):.1f} | "
            f"{steps} | {wall:.0f} | {steps / wall:.0f} | {updates / wall:.1f} |"
        )
    if len(finals) > 1:
        print(
            f"| {label or 'mean over runs'} | | | | {statistics.fmean(finals):.1f} +- "
            f"{statistics.pstdev(finals):.1f} ({len(finals)} runs) | | | | |"
        )


if __name__ == "__main__":
    main()
