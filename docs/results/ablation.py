#!/usr/bin/env python3
"""The ablation of the frontier's mechanisms (issue 35 item 6), as a markdown table.

Usage: docs/results/ablation.py [--at STEP]

One line per mechanism, one column per task it is measured on (hopper-hop, walker-run). Each
mechanism is compared as one or more pairs of rows, the row with it on against the row with
it off (`simba` has both network mechanisms; `residual` only the networks, `categorical` only
the critic, `mlp` neither; the `simba-*` rows are `simba` with one setting changed, named as
in `scripts/frontier`). A cell reads the kept runs (docs/results/TASK/ROW-seedS, or the run
`runs.TASK_ROWS` lists for that row and seed) and gives, per pair, "on / off (difference;
seeds)": the evaluation mean at STEP (default 500000, the budget) averaged over the seeds both
rows have reached STEP on. Where one row's seeds stopped short of STEP, the pair is also read
at the last step every seed of both rows has ("seeds 0-2 at 460k: ..."); where no seed of a
pair has both rows at STEP, at the last step the two share on the first seed both have, said
as "stopped short". "not run" where either row has no kept run. Seeds are 0, 1 and 2, as the
plan's. A cell's pairs are one per line (`<br>`), in the order of the rows column.
"""
import statistics
import sys
from pathlib import Path

import runs

HERE = Path(__file__).resolve().parent
TASKS = runs.ABLATION_TASKS
SEEDS = [0, 1, 2]
# mechanism -> pairs of (row with it on, row with it off)
MECHANISMS = [
    ("residual, layer-normalised networks", [("simba", "categorical"), ("residual", "mlp")]),
    ("categorical critic (101 atoms, HL-Gauss)", [("simba", "residual"), ("categorical", "mlp")]),
    ("both", [("simba", "mlp")]),
    ("one update per step (not one per two)", [("simba-ratio1", "simba")]),
    ("resets every 100k updates", [("simba-resets", "simba")]),
    ("weights on the sphere (SimbaV2's alternative to resets)", [("simba-sphere", "simba")]),
]


def evaluations(task, row, seed, step):
    """{step: evaluation mean} of the kept run of `row`'s seed on `task`, or None if none is
    kept: the run named TASK/ROW-seedS, else the one runs.TASK_ROWS lists for the row and seed,
    the first of them that reaches `step` (else the first that exists)."""
    listed = [d for net, _, dirs in runs.TASK_ROWS[task][1] if net == row for d in dirs
              if d.endswith(f"-seed{seed}")]
    found = []
    for d in [f"{task}/{row}-seed{seed}"] + listed:
        if (HERE / d / "metrics.csv").exists():
            rows = runs.read_rows(str(HERE / d))
            found.append({int(r["env_steps"]): float(r["eval_return_mean"]) for r in rows})
    return next((e for e in found if step in e), found[0] if found else None)


def seeds_text(seeds):
    if len(seeds) == 1:
        return f"seed {seeds[0]}"
    if seeds == list(range(seeds[0], seeds[-1] + 1)):
        return f"seeds {seeds[0]}-{seeds[-1]}"
    return "seeds " + ", ".join(map(str, seeds))


def compare(pairs, at, seeds=True):
    """'on / off (+d; seeds)' over `pairs` [(seed, on evals, off evals)] at step `at`."""
    on = statistics.mean(p[1][at] for p in pairs)
    off = statistics.mean(p[2][at] for p in pairs)
    which = f"; {seeds_text([p[0] for p in pairs])}" if seeds else ""
    return f"{on:.1f} / {off:.1f} ({on - off:+.1f}{which})"


def last_shared(pairs):
    """The last evaluation step every run of `pairs` has."""
    steps = set.intersection(*(set(e) for p in pairs for e in p[1:]))
    return max(steps)


def cell(task, on, off, step):
    both = [(s, evaluations(task, on, s, step), evaluations(task, off, s, step)) for s in SEEDS]
    both = [p for p in both if p[1] is not None and p[2] is not None]
    if not both:
        return "not run"
    done = [p for p in both if step in p[1] and step in p[2]]
    if not done:
        at = last_shared(both[:1])
        return f"{compare(both[:1], at)} at {at // 1000}k, stopped short"
    text = compare(done, step)
    if len(done) < len(both):
        at = last_shared(both)
        text += f"; {seeds_text([p[0] for p in both])} at {at // 1000}k: {compare(both, at, False)}"
    return text


def main():
    args = sys.argv[1:]
    if args and args[0] in ("-h", "--help"):
        print(__doc__.strip())
        return
    step = runs.budget(TASKS[0])
    if args[:1] == ["--at"] and len(args) == 2:
        step = int(args[1])
    elif args:
        sys.exit(f"unknown arguments {args} (--help explains)")
    print("| mechanism | on / off (rows) | " + " | ".join(TASKS) + " |")
    print("|---|---|" + "---|" * len(TASKS))
    for name, pairs in MECHANISMS:
        rows = "; ".join(f"`{a}` / `{b}`" for a, b in pairs)
        cells = [[cell(t, a, b, step) for a, b in pairs] for t in TASKS]
        cells = ["not run" if set(c) == {"not run"} else "<br>".join(c) for c in cells]
        print(f"| {name} | {rows} | " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
