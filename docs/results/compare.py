#!/usr/bin/env python3
"""Seeds of one row against another run, evaluation by evaluation.

Usage: docs/results/compare.py --against BASE [--window FROM TO]... RUN...

RUN and BASE are run directories (relative to docs/results or not) with a `metrics.csv`. Prints:
- per RUN: at how many of the evaluations it shares with BASE (step 0 left out) its return is
  above BASE's; its mean over each `--window FROM TO` (environment steps, both ends included);
  its 40-episode evaluation if the directory has `eval-500k-40-episodes.json` (mean +- std,
  episodes below 1 and at or above 100, the best);
- BASE's mean over each window;
- the mean over the RUNs at the steps every RUN and BASE have: at how many it is above BASE,
  and its value at every 100k steps.
"""
import json
import statistics
import sys
from pathlib import Path

import runs

HERE = Path(__file__).resolve().parent


def curve(d):
    """{environment steps: evaluation mean} of a run directory."""
    p = Path(d) if (Path(d) / "metrics.csv").exists() else HERE / d
    return {int(r["env_steps"]): float(r["eval_return_mean"]) for r in runs.read_rows(str(p))}


def window_mean(c, lo, hi):
    vals = [v for k, v in c.items() if lo <= k <= hi]
    return f"{statistics.mean(vals):.1f}" if vals else "-"


def episodes(d):
    p = (Path(d) if Path(d).exists() else HERE / d) / "eval-500k-40-episodes.json"
    if not p.exists():
        return ""
    e = json.loads(p.read_text())
    r = e["returns"]
    low, high = sum(x < 1 for x in r), sum(x >= 100 for x in r)
    return (f"; 40 episodes {e['return_mean']:.1f} +- {e['return_std']:.1f}, "
            f"{low} below 1, {high} at or above 100, best {max(r):.1f}")


def main():
    args = sys.argv[1:]
    if not args or args[0] in ("-h", "--help"):
        print(__doc__.strip(), file=sys.stdout if args else sys.stderr)
        sys.exit(0 if args else 2)
    base, windows, dirs = None, [], []
    while args:
        if args[0] == "--against":
            base, args = args[1], args[2:]
        elif args[0] == "--window":
            windows.append((int(args[1]), int(args[2])))
            args = args[3:]
        else:
            dirs.append(args[0])
            args = args[1:]
    if base is None or not dirs:
        sys.exit("compare.py: give --against BASE and at least one RUN (see --help)")
    b = curve(base)
    curves = [curve(d) for d in dirs]

    def wins(c):
        return ", ".join(f"{lo // 1000}k-{hi // 1000}k {window_mean(c, lo, hi)}"
                         for lo, hi in windows)

    for d, c in zip(dirs, curves):
        shared = [k for k in c if k > 0 and k in b]
        above = sum(c[k] > b[k] for k in shared)
        print(f"{d}: above {base} at {above} of {len(shared)} shared evaluations; "
              f"means {wins(c)}{episodes(d)}")
    print(f"{base}: means {wins(b)}")
    steps = sorted(k for k in b if k > 0 and all(k in c for c in curves))
    mean = {k: statistics.mean(c[k] for c in curves) for k in steps}
    above = sum(mean[k] > b[k] for k in steps)
    at = ", ".join(f"{k // 1000}k {mean[k]:.1f}" for k in steps if k % 100_000 == 0)
    print(f"mean of the {len(dirs)} runs: above {base} at {above} of {len(steps)} shared "
          f"evaluations; {at}")


if __name__ == "__main__":
    main()
