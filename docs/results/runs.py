"""What the scripts beside this file share: reading a run's `metrics.csv` and their usage text.

Each script is run from anywhere (`docs/results/x.py` or `./x.py`); Python puts the script's
own folder first on the import path, so `import runs` finds this file.
"""
import csv
import sys


def read_rows(run):
    """The rows of `RUN/metrics.csv`, one per evaluation in step order, as dicts of strings."""
    with open(f"{run.rstrip('/')}/metrics.csv", newline="") as f:
        return list(csv.DictReader(f))


def index_at(rows, step):
    """The index of the evaluation at environment step `step`, or None if the run has none."""
    return next((i for i, r in enumerate(rows) if int(r["env_steps"]) == step), None)


def first_at_or_above(rows, target):
    """The first evaluation whose mean is at or above `target`, or None."""
    return next((r for r in rows if float(r["eval_return_mean"]) >= target), None)


def best(rows):
    """The best evaluation mean of a run."""
    return max(float(r["eval_return_mean"]) for r in rows)


def help_or_usage(doc, args):
    """`-h`/`--help` prints `doc` and exits 0; no arguments prints it to stderr and exits 2."""
    if not args or args[0] in ("-h", "--help"):
        print(doc.strip(), file=sys.stdout if args else sys.stderr)
        sys.exit(0 if args else 2)
