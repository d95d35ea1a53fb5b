#!/usr/bin/env python3
"""Gymnasium's side of the cross-check: what the task files in tasks/gymnasium/ must reproduce.

Run with the project venv (scripts/setup-gymnasium), MUJOCO_GL=disable:

  record  [--out DIR]
      Writes reference recordings for each task into DIR (default .deps/gym_reference/):
      `gymnasium.make(TASK)` (its registered wrappers: TimeLimit(1000) and the checkers), the
      first episode after `reset(seed=SEED)`, later ones after `reset()` (the Generator stream
      continues, as in a run of several episodes), each episode stepped with a recorded action
      sequence until `terminated` or `truncated`. Kinds: random actions in the action space,
      random actions beyond it (+-1.5: MuJoCo clamps them to the control range), sinusoids,
      zeros then +-1.5 bang-bang, many short episodes in a row (resets), and for
      InvertedDoublePendulum an LQR controller with action noise (it balances for the whole
      1000 steps, so the episode ends by truncation; with more noise it falls). Each file is JSON
      lines: a header {"task", "seed", "kind", "gymnasium", "episodes": [[row, ...], ...]},
      then per episode one line after reset (step 0) and one per step: step, reward (null at
      reset), terminated, truncated, obs, qpos, qvel.
"""

import argparse
import json
import os
import warnings

os.environ.setdefault("MUJOCO_GL", "disable")

import gymnasium  # noqa: E402
import numpy as np  # noqa: E402

TASKS = ["InvertedDoublePendulum-v5", "HalfCheetah-v5"]
REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def line(step, env, obs, reward, terminated, truncated):
    data = env.unwrapped.data
    return json.dumps({
        "step": step,
        "reward": None if reward is None else float(reward),
        "terminated": bool(terminated),
        "truncated": bool(truncated),
        "obs": np.asarray(obs, dtype=np.float64).tolist(),
        "qpos": data.qpos.tolist(),
        "qvel": data.qvel.tolist(),
    }, separators=(",", ":"))


def run_episode(env, rows, seed, out):
    """One episode: reset (seeded when `seed` is not None), then the rows (or the actions of a
    policy, a function of the environment) until it ends. Returns the rows used."""
    obs, _ = env.reset(seed=seed)
    out.write(line(0, env, obs, None, False, False) + "\n")
    used = []
    for i in range(1000) if callable(rows) else range(len(rows)):
        row = np.asarray(rows(env) if callable(rows) else rows[i], dtype=np.float64)
        used.append(row)
        obs, reward, terminated, truncated, _ = env.step(row)
        out.write(line(i + 1, env, obs, reward, terminated, truncated) + "\n")
        if terminated or truncated:
            break
    return used


def lqr_policy(noise, seed):
    """A discrete LQR controller about the upright pendulum (the 5-substep transition linearised
    by central differences), with Gaussian action noise, clipped to [-1, 1]."""
    import mujoco
    import scipy.linalg

    model = gymnasium.make("InvertedDoublePendulum-v5").unwrapped.model

    def transition(x, u):
        d = mujoco.MjData(model)
        d.qpos[:], d.qvel[:], d.ctrl[:] = x[: model.nq], x[model.nq:], u
        mujoco.mj_step(model, d, nstep=5)
        return np.concatenate([d.qpos, d.qvel])

    n, e = 2 * model.nv, 1e-6
    x0, u0, eye = np.zeros(n), np.zeros(1), np.eye(n)
    a = np.stack([(transition(x0 + e * eye[i], u0) - transition(x0 - e * eye[i], u0)) / (2 * e)
                  for i in range(n)], 1)
    b = ((transition(x0, u0 + e) - transition(x0, u0 - e)) / (2 * e))[:, None]
    q, r = np.diag([1.0, 10.0, 10.0, 0.1, 0.1, 0.1]), np.array([[1.0]])
    p = scipy.linalg.solve_discrete_are(a, b, q, r)
    k = np.linalg.solve(r + b.T @ p @ b, b.T @ p @ a)
    rng = np.random.RandomState(seed)

    def act(env):
        data = env.unwrapped.data
        x = np.concatenate([data.qpos, data.qvel])
        return np.clip(-k @ x + noise * rng.standard_normal(1), -1.0, 1.0)

    return act


def action_sets(task, act_dim, steps=1000):
    """(seed, kind, episodes) for one task: every episode a list of action rows."""
    k = TASKS.index(task)
    rng = np.random.RandomState(2000 + k)
    t = np.arange(steps)[:, None]
    j = np.arange(act_dim)[None, :]
    sinusoid = 1.5 * np.sin(2 * np.pi * t / (40 + 7 * j) + j)
    bang = np.where(((t // 25) + j) % 2 == 0, 1.5, -1.5)
    bang[:200] = 0.0
    lqr = []
    if task == "InvertedDoublePendulum-v5":
        lqr = [(3, "lqr", [lqr_policy(0.1, 0), lqr_policy(0.1, 1)]),
               (4, "lqr-falls", [lqr_policy(0.2, 2)] * 3)]
    return lqr + [
        (0, "random", [rng.uniform(-1, 1, (steps, act_dim))]),
        (1, "random-wide", [rng.uniform(-1.5, 1.5, (steps, act_dim))]),
        (42, "sinusoid", [sinusoid]),
        (2**32 - 1, "zeros-bang", [bang]),
        (7, "resets", [rng.uniform(-1, 1, (steps // 10, act_dim)) for _ in range(25)]),
    ]


def record(args):
    args.out = os.path.abspath(args.out)
    os.makedirs(args.out, exist_ok=True)
    # MuJoCo writes its warnings (half_cheetah.xml's deprecated settotalmass) to
    # ./MUJOCO_LOG.TXT: let that be beside the recordings, not in the caller's directory.
    os.chdir(args.out)
    for task in TASKS:
        act_dim = gymnasium.make(task).action_space.shape[0]
        for seed, kind, episodes in action_sets(task, act_dim):
            env = gymnasium.make(task)
            path = os.path.join(args.out, f"{task}_{kind}.jsonl")
            tmp = path + ".tmp"
            with open(tmp, "w") as out:
                body = []

                class Lines:
                    def write(self, s):
                        body.append(s)

                used = [run_episode(env, rows, seed if e == 0 else None, Lines())
                        for e, rows in enumerate(episodes)]
                header = {"task": task, "seed": seed, "kind": kind,
                          "gymnasium": gymnasium.__version__,
                          "episodes": [np.asarray(u).tolist() for u in used]}
                out.write(json.dumps(header, separators=(",", ":")) + "\n")
                out.writelines(body)
            os.replace(tmp, path)
    with open(os.path.join(args.out, "COMPLETE"), "w") as f:
        f.write(f"gymnasium {gymnasium.__version__}, numpy {np.__version__}\n")


def main():
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="command", required=True)
    p = sub.add_parser("record")
    p.add_argument("--out", default=os.path.join(REPO, ".deps", "gym_reference"))
    args = parser.parse_args()
    # The passive checker warns about float64 actions in a float32 space; they are meant.
    warnings.simplefilter("ignore")
    {"record": record}[args.command](args)


if __name__ == "__main__":
    main()
