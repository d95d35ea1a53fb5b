#!/usr/bin/env python3
"""Prints chosen `metrics.csv` columns of several runs at one evaluation, as a markdown table.

Usage: docs/results/columns.py --cols COL[,COL...] [--at STEP] RUN_DIR...
(each RUN_DIR with metrics.csv). One row per run: the run's evaluation at environment step
STEP (default: its last), each column to three significant figures ("-" where the run has no
such column or the value is empty, as the learner statistics are before learning starts). A
run without an evaluation at STEP is listed as "no evaluation at STEP" rather than skipped, so
the table always has every run asked for. Column names: the header of any metrics.csv
(docs/training.md, "Commands", lists them).
"""
import sys

import runs


def value(row, col):
    v = row.get(col, "")
    return f"{float(v):.3g}" if v not in ("", None) else "-"


def main():
    args = sys.argv[1:]
    runs.help_or_usage(__doc__, args)
    cols, at = None, None
    while args and args[0].startswith("--"):
        if args[0] == "--cols" and len(args) > 1:
            cols = args[1].split(",")
        elif args[0] == "--at" and len(args) > 1:
            at = int(args[1])
        else:
            sys.exit(f"unknown option or missing value: {args[0]}")
        args = args[2:]
    if not cols or not args:
        sys.exit("usage: columns.py --cols COL[,COL...] [--at STEP] RUN_DIR...")
    print("| run | step | " + " | ".join(cols) + " |")
    print("|---|---:|" + "---:|" * len(cols))
    for d in args:
        rows = runs.read_rows(d)
        i = len(rows) - 1 if at is None else runs.index_at(rows, at)
        if i is None:
            print(f"| {d} | no evaluation at {at} |" + " |" * len(cols))
            continue
        row = rows[i]
        print(f"| {d} | {row['env_steps']} | " + " | ".join(value(row, c) for c in cols) + " |")


if __name__ == "__main__":
    main()
