#!/usr/bin/env python3
"""Tabulates the covariance multiplier's wind-up of `mpo train` runs for docs/training.md.

Usage: docs/results/multipliers.py [--above X] [--of alpha_mean] RUN_DIR...
       docs/results/multipliers.py --mean RUN_DIR...
(each RUN_DIR with metrics.csv). Per run, over the evaluations after learning started: how many
have `alpha_cov` (the mean over the updates before the evaluation) above X (default 1e4), the
first step where it is, the largest `alpha_cov`, the actor's gradient norm range at those
evaluations, `std_max` at the last evaluation and the last evaluation's return. With
`--of alpha_mean`, the same of the mean's multiplier.

With `--mean`, the mean's multiplier instead: how many evaluations have `alpha_mean` below
1e-6 (at its floor: over the updates before them the mean's KL crossed its bound too seldom to
hold the multiplier up), the mean of `kl_mean_rel` (the mean's KL over its bound) over the
evaluations, and the last return.
"""
import sys

import runs


def row(run, above, col):
    rows = [r for r in runs.read_rows(run) if r[col]]
    if not rows:
        return f"| {run} | no updates yet | | | | | |"
    wound = [r for r in rows if float(r[col]) > above]
    first = f"{int(wound[0]['env_steps']) // 1000}k" if wound else "-"
    grads = [float(r["actor_grad_norm"]) for r in wound]
    grad = f"{min(grads):.3g}-{max(grads):.3g}" if grads else "-"
    last = rows[-1]
    return (
        f"| {run} | {len(wound)} of {len(rows)} | {first} "
        f"| {max(float(r[col]) for r in rows):.2g} | {grad} "
        f"| {float(last['std_max']):.2f} "
        f"| {float(last['eval_return_mean']):.1f} at {int(last['env_steps']) // 1000}k |"
    )


def mean_row(run):
    rows = [r for r in runs.read_rows(run) if r["alpha_mean"]]
    if not rows:
        return f"| {run} | no updates yet | | |"
    floor = sum(1 for r in rows if float(r["alpha_mean"]) < 1e-6)
    kl = sum(float(r["kl_mean_rel"]) for r in rows) / len(rows)
    last = rows[-1]
    return (f"| {run} | {floor} of {len(rows)} | {kl:.2f} "
            f"| {float(last['eval_return_mean']):.1f} at {int(last['env_steps']) // 1000}k |")


def main():
    args = sys.argv[1:]
    if args[:1] == ["--mean"]:
        if len(args) < 2:
            sys.exit(__doc__)
        print("| run | evaluations with `alpha_mean` at its floor (< 1e-6) "
              "| `kl_mean_rel`, mean over them | return at the end |")
        print("|---|---:|---:|---|")
        for run in args[1:]:
            print(mean_row(run))
        return
    above, col = 1e4, "alpha_cov"
    while args[:1] in (["--above"], ["--of"]) and len(args) > 1:
        if args[0] == "--above":
            above = float(args[1])
        elif args[1] in ("alpha_cov", "alpha_mean"):
            col = args[1]
        else:
            sys.exit(f"--of takes alpha_cov or alpha_mean, not {args[1]}")
        args = args[2:]
    if not args:
        sys.exit(__doc__)
    print(
        f"| run | evaluations with `{col}` > {above:g} | first at | largest `{col}` "
        "| actor gradient norm there | `std_max` at the end | return at the end |"
    )
    print("|---|---:|---:|---:|---|---:|---|")
    for run in args:
        print(row(run, above, col))


if __name__ == "__main__":
    main()
