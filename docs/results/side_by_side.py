#!/usr/bin/env python3
"""Prints several runs' evaluations side by side, one row per step, as a markdown table.

Usage: docs/results/side_by_side.py [--every N] [--last] LABEL=RUN_DIR[,RUN_DIR...] ...
(each RUN_DIR with metrics.csv). A column per LABEL; a LABEL with several runs (its seeds)
shows each run's evaluation mean and, in a column after it, their mean (only where every one of
its runs has that step). Rows: every environment step that is a multiple of N (default 40000)
at which any run has an evaluation, and with `--last` each run's last step too. "-" where a run
has no evaluation at that step (it stopped earlier, or evaluates elsewhere).
"""
import statistics
import sys

import runs


def parse(args):
    every, last, columns = 40000, False, []
    while args and args[0].startswith("--"):
        if args[0] == "--every" and len(args) > 1:
            every = int(args[1])
            args = args[2:]
        elif args[0] == "--last":
            last = True
            args = args[1:]
        else:
            sys.exit(f"unknown option {args[0]} (--help explains)")
    for a in args:
        label, sep, dirs = a.partition("=")
        if not sep or not dirs:
            sys.exit(f"{a!r}: expected LABEL=RUN_DIR[,RUN_DIR...]")
        columns.append((label, dirs.split(",")))
    if not columns:
        sys.exit("no runs given (--help explains)")
    return every, last, columns


def main():
    args = sys.argv[1:]
    runs.help_or_usage(__doc__, args)
    every, last, columns = parse(args)
    evals = {}  # (label, run index) -> {step: mean}
    steps = set()
    for label, dirs in columns:
        for i, d in enumerate(dirs):
            rows = runs.read_rows(d)
            evals[label, i] = {int(r["env_steps"]): float(r["eval_return_mean"]) for r in rows}
            steps |= {s for s in evals[label, i] if s % every == 0}
            if last and rows:
                steps.add(int(rows[-1]["env_steps"]))
    header, rule = ["steps"], ["---"]
    for label, dirs in columns:
        header += [label if len(dirs) == 1 else f"{label} ({k})" for k in range(len(dirs))]
        if len(dirs) > 1:
            header.append(f"{label}: mean")
    rule += ["---:"] * (len(header) - 1)
    print("| " + " | ".join(header) + " |")
    print("|" + "|".join(rule) + "|")
    for s in sorted(steps):
        cells = [f"{s // 1000}k"]
        for label, dirs in columns:
            vals = [evals[label, i].get(s) for i in range(len(dirs))]
            cells += [f"{v:.1f}" if v is not None else "-" for v in vals]
            if len(dirs) > 1:
                ok = all(v is not None for v in vals)
                cells.append(f"{statistics.mean(vals):.1f}" if ok else "-")
        print("| " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
