#!/usr/bin/env python3
"""dm_control's side of the cross-check: the reference that `sim-bridge` must reproduce.

Run with the project venv (scripts/setup-dm-control), MUJOCO_GL=disable:

  replay  --task TASK --seed S --actions FILE.csv
      Same semantics and output as `sim-bridge replay`: suite.load(domain, task,
      task_kwargs={'random': S}), reset(), then step(row) per CSV row, one JSON object per line
      (step, reward, discount, obs, qpos, qvel; reward and discount null at reset), stopping at the
      episode's end.

  record  [--out DIR]
      Writes reference recordings for every task into DIR (default .deps/dm_reference/): seeded
      episodes with random actions, random actions outside [-1, 1], sinusoids, zeros and +-1.5
      bang-bang, and one environment reset twice (the second reset continues the RandomState
      stream). Each file is JSON lines: a header {"task", "seed", "kind", "episodes": [[row, ...],
      ...]} with the actions of each episode, then for each episode the lines `replay` prints.

  time    --task TASK [--steps N] [--rounds R]
      Prints the best of R rounds of the mean seconds per env.step over N random-action steps
      (for the benchmark; resets are not timed).
"""

import argparse
import json
import math
import os
import sys
import time

os.environ.setdefault("MUJOCO_GL", "disable")

import numpy as np  # noqa: E402
from absl import logging  # noqa: E402
from dm_control import suite  # noqa: E402

# cheetah.xml's deprecated `settotalmass` makes MuJoCo warn on every load; only errors matter here.
logging.set_verbosity(logging.ERROR)

TASKS = [
    "cartpole-balance", "cartpole-swingup", "hopper-stand", "hopper-hop", "acrobot-swingup",
    "pendulum-swingup", "walker-stand", "walker-walk", "walker-run", "cheetah-run",
]
REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def load(task, seed):
    if task not in TASKS:
        sys.exit(f"error: unknown task '{task}'; valid tasks: {', '.join(TASKS)}")
    domain, name = task.split("-", 1)
    return suite.load(domain, name, task_kwargs={"random": seed})


def flat_obs(observation):
    """All observation arrays, flattened and concatenated in the OrderedDict's order."""
    return np.concatenate([np.asarray(v, dtype=np.float64).ravel() for v in observation.values()])


def line(step, timestep, env):
    physics = env.physics
    return json.dumps({
        "step": step,
        "reward": None if timestep.reward is None else float(timestep.reward),
        "discount": None if timestep.discount is None else float(timestep.discount),
        "obs": flat_obs(timestep.observation).tolist(),
        "qpos": physics.data.qpos.tolist(),
        "qvel": physics.data.qvel.tolist(),
    }, separators=(",", ":"))


def run_episode(env, rows, out):
    timestep = env.reset()
    out.write(line(0, timestep, env) + "\n")
    for i, row in enumerate(rows):
        timestep = env.step(np.asarray(row, dtype=np.float64))
        out.write(line(i + 1, timestep, env) + "\n")
        if timestep.last():
            break


def replay(args):
    env = load(args.task, args.seed)
    with open(args.actions) as f:
        rows = [[float(x) for x in l.split(",")] for l in f.read().splitlines()]
    run_episode(env, rows, sys.stdout)


def action_sets(task, act_dim, steps=1000):
    """(seed, kind, episodes) for one task: every episode a list of action rows."""
    k = TASKS.index(task)
    rng = np.random.RandomState(1000 + k)
    t = np.arange(steps)[:, None]
    j = np.arange(act_dim)[None, :]
    sinusoid = 1.5 * np.sin(2 * np.pi * t / (40 + 7 * j) + j)
    bang = np.where(((t // 25) + j) % 2 == 0, 1.5, -1.5)
    bang[:200] = 0.0
    return [
        (0, "random", [rng.uniform(-1, 1, (steps, act_dim))]),
        (1, "random-wide", [rng.uniform(-1.5, 1.5, (steps, act_dim))]),
        (42, "sinusoid", [sinusoid]),
        (2**32 - 1, "zeros-bang", [bang]),
        (7, "two-resets", [rng.uniform(-1, 1, (steps, act_dim)), rng.uniform(-1, 1, (200, act_dim))]),
    ]


def record(args):
    os.makedirs(args.out, exist_ok=True)
    for task in TASKS:
        act_dim = load(task, 0).action_spec().shape[0]
        for seed, kind, episodes in action_sets(task, act_dim):
            env = load(task, seed)
            path = os.path.join(args.out, f"{task}_{kind}.jsonl")
            tmp = path + ".tmp"
            with open(tmp, "w") as out:
                header = {"task": task, "seed": seed, "kind": kind,
                          "episodes": [np.asarray(e).tolist() for e in episodes]}
                out.write(json.dumps(header, separators=(",", ":")) + "\n")
                for rows in episodes:
                    run_episode(env, rows, out)
            os.replace(tmp, path)
    with open(os.path.join(args.out, "COMPLETE"), "w") as f:
        f.write("dm-control 1.0.50, mujoco 3.17.0\n")


def timing(args):
    """Best round's mean seconds per env.step (random actions, resets not timed)."""
    env = load(args.task, 0)
    act_dim = env.action_spec().shape[0]
    rng = np.random.RandomState(0)
    actions = rng.uniform(-1, 1, (args.steps, act_dim))
    env.reset()
    rounds = []
    for _ in range(args.rounds):
        elapsed = 0.0
        for a in actions:
            t0 = time.perf_counter()
            ts = env.step(a)
            elapsed += time.perf_counter() - t0
            if ts.last():
                env.reset()
        rounds.append(elapsed / len(actions))
    print(json.dumps({"task": args.task, "seconds_per_step": min(rounds)}))


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="command", required=True)
    p = sub.add_parser("replay")
    p.add_argument("--task", required=True)
    p.add_argument("--seed", type=int, required=True)
    p.add_argument("--actions", required=True)
    p = sub.add_parser("record")
    p.add_argument("--out", default=os.path.join(REPO, ".deps", "dm_reference"))
    p = sub.add_parser("time")
    p.add_argument("--task", required=True)
    p.add_argument("--steps", type=int, default=2000)
    p.add_argument("--rounds", type=int, default=7)
    args = parser.parse_args()
    {"replay": replay, "record": record, "time": timing}[args.command](args)


if __name__ == "__main__":
    main()
