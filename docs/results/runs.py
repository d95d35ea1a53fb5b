"""What the scripts beside this file share: reading a run's `metrics.csv` and their usage text.

Each script is run from anywhere (`docs/results/x.py` or `./x.py`); Python puts the script's
own folder first on the import path, so `import runs` finds this file.
"""
import csv
import sys


# task -> (target, [(net, label, [run dirs relative to docs/results])]). A row lists its
# planned seeds too (scripts/frontier): the scripts read the dirs that exist (kept with
# `scripts/frontier keep`) and leave out a row none of whose runs is kept yet.
TASK_ROWS = {
    "cartpole-balance": (995, [
        ("default", "default (64-64)", [f"cartpole-balance/clip-dual-1e-3-seed{s}" for s in range(5)]),
        ("simba", "`simba`", [f"cartpole-balance/simba-seed{s}" for s in range(3)]),
    ]),
    "cartpole-swingup": (870, [
        ("mlp", "`mlp` (the default before)", [f"cartpole-swingup/default-seed{s}" for s in range(3)]),
        ("simba", "`simba` (the default now)", [f"cartpole-swingup/simba-seed{s}" for s in range(3)]),
    ]),
    "pendulum-swingup": (820, [
        ("mlp", "`mlp` (the default before)", [f"pendulum-swingup/mlp-seed{s}" for s in range(3)]),
        ("ceiling", "`ceiling` (the default now)", [f"pendulum-swingup/mlp-alphamax1e3-seed{s}" for s in range(3)]),
        ("simba", "`simba`", ["pendulum-swingup/simba-seed0"]),
    ]),
    "acrobot-swingup": (300, [
        ("mlp", "`mlp` (the default before)", ["acrobot-swingup/noise-0.95-seed0"]),
        ("simba", "`simba` (the default now)", [f"acrobot-swingup/simba-seed{s}" for s in range(3)]),
    ]),
    "walker-stand": (970, [
        ("default", "default", ["walker-stand/mlp-seed0"] + [f"walker-stand/default-seed{s}" for s in (1, 2)]),
        ("simba", "`simba`", ["walker-stand/simba-seed0"]),
    ]),
    "walker-walk": (960, [
        ("default", "default", [f"walker-walk/default-seed{s}" for s in range(3)]),
        ("simba", "`simba`", ["walker-walk/simba-seed0"]),
    ]),
    "walker-run": (700, [
        ("mlp", "`mlp` (the default before)", ["walker-run/default-seed0", "walker-run/mlp-seed1", "walker-run/mlp-seed2"]),
        ("simba", "`simba` (the default now)", [f"walker-run/simba-seed{s}" for s in range(3)]),
        ("residual", "`residual` (scalar critic; ablation)", ["walker-run/residual-seed0"]),
        ("categorical", "`categorical` (MLP networks; ablation)", ["walker-run/categorical-seed0"]),
    ]),
    "cheetah-run": (800, [
        ("default", "default", [f"cheetah-run/mlp-seed{s}" for s in (0, 1)] + ["cheetah-run/default-seed2"]),
        ("simba", "`simba` (seed 0, no logit floor)", ["cheetah-run/simba-seed0"]),
    ]),
    "hopper-stand": (900, [
        ("mlp", "`mlp` (the default before)", [f"hopper-stand/eps-penalty-0.01-seed{s}" for s in range(3)]),
        ("simba", "`simba` (the default now)", ["hopper-stand/simba-seed0"]),
    ]),
    "hopper-hop": (250, [
        ("mlp", "`mlp` (the default before)", ["hopper-hop/mlp-seed0"] + [f"hopper-hop/eps-penalty-0.01-seed{s}" for s in (1, 2)]),
        ("simba", "`simba` (the default now)", [f"hopper-hop/simba-seed{s}" for s in range(3)]),
        ("residual", "`residual` (scalar critic; ablation)", ["hopper-hop/residual-seed0"]),
        ("categorical", "`categorical` (MLP networks; ablation)", ["hopper-hop/categorical-seed0"]),
    ]),
}

# The tasks whose default moved off their MLP row in this issue, and the named row their default
# repeats (the same networks, settings and budget): `simba`, or on pendulum-swingup `ceiling`
# (the MLP with the multipliers' ceiling). Their MLP row, the default before, is `--net mlp`
# (mpo-host/src/table.rs; tests/results_scripts.rs checks the three agree). scripts/frontier and
# scripts/bench-rows read it from here.
MOVED_DEFAULT = {
    **{t: "simba" for t in ("hopper-hop", "acrobot-swingup", "cartpole-swingup", "hopper-stand",
                            "walker-run")},
    "pendulum-swingup": "ceiling",
}

# The tasks the ablation runs every mechanism on and off (issue 35 item 6): scripts/frontier
# plans them, ablation.py tables them.
ABLATION_TASKS = ["hopper-hop", "walker-run"]

# The row each task trains by default, by its `net` above.
DEFAULT_NET = {task: MOVED_DEFAULT.get(task, "default") for task in TASK_ROWS}

# Rows whose updates cost what another row's do and have no rate of their own in the rate files:
# `ceiling` is the MLP row with two more clamps per update (the multipliers').
SAME_RATE = {("pendulum-swingup", "ceiling"): "mlp"}


def rate_net(task, net):
    """The row whose measured rate (the rate files) stands for `net`'s."""
    return SAME_RATE.get((task, net), net)


def budget(task):
    """The frontier's budget for a task, in environment steps (cartpole-balance's target is at
    100k, every other task's at 500k)."""
    return 100_000 if task == "cartpole-balance" else 500_000


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
