#!/usr/bin/env python3
"""Whether two runs are the same run, bit for bit: a rerun of a seed against its earlier run.

Usage: docs/results/same_run.py A B

A and B are run directories (relative to docs/results or not) with a `metrics.csv`. Compares
every evaluation the two share (by environment step) in every column the two files share but
the timings (`wall_s`, `env_steps_per_s`, `updates_per_s`), as the files print them: the
learner writes each float exactly, so equal text is equal bits. Prints how many evaluations and
columns it compared and each cell that differs; exits 1 when any does, 2 when the two share no
evaluation.
"""
import sys
from pathlib import Path

import runs

HERE = Path(__file__).resolve().parent
TIMINGS = {"wall_s", "env_steps_per_s", "updates_per_s"}


def rows_of(d):
    """{environment steps: row} of a run directory."""
    p = Path(d) if (Path(d) / "metrics.csv").exists() else HERE / d
    return {int(r["env_steps"]): r for r in runs.read_rows(str(p))}


def main():
    args = sys.argv[1:]
    if len(args) != 2 or args[0] in ("-h", "--help"):
        sys.exit(__doc__.strip())
    a, b = rows_of(args[0]), rows_of(args[1])
    steps = sorted(a.keys() & b.keys())
    if not steps:
        print(f"{args[0]} and {args[1]} share no evaluation")
        sys.exit(2)
    cols = [c for c in a[steps[0]] if c in b[steps[0]] and c not in TIMINGS and c != "env_steps"]
    diffs = [(s, c, a[s][c], b[s][c]) for s in steps for c in cols if a[s][c] != b[s][c]]
    for s, c, x, y in diffs:
        print(f"differs at {s}: {c} {x} against {y}")
    verdict = "equal" if not diffs else f"{len(diffs)} cells differ"
    print(f"{len(steps)} evaluations ({steps[0] // 1000}k-{steps[-1] // 1000}k), "
          f"{len(cols)} columns but the timings: {verdict}")
    sys.exit(1 if diffs else 0)


if __name__ == "__main__":
    main()
