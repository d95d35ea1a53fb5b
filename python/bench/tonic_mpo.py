"""Times tonic's PyTorch MPO update on this CPU, for a ratio to `cargo bench --bench learner`.

Tonic (Pardo, 2020) is the PyTorch MPO the speed issue compares with. This script is not part
of the product: it imports tonic from a clone the reader makes (its source is not copied here),
builds its default MPO agent (256-256 actor and critic, a Gaussian policy head, 20 E-step and
20 next-action samples, one gradient step of the actor and of the critic per update, Adam) for
each of the learner bench's sizes, and times its update, `_update_actor_critic`, on a batch of
256 random transitions (the work per update does not depend on the values).

    python3 -m venv /tmp/torchvenv && /tmp/torchvenv/bin/pip install torch 'numpy<2' gym==0.26.2 \
        pandas matplotlib pyyaml termcolor
    git clone https://github.com/fabiopardo/tonic /tmp/tonic    # v0.3 was measured
    /tmp/torchvenv/bin/python python/bench/tonic_mpo.py /tmp/tonic --threads 1

It prints one line per size: updates per second of wall clock over at least `--seconds`, and
by the process's CPU time (as the learner bench's "by CPU time" column).
"""

import argparse
import sys
import time

SIZES = [("cartpole 5/1", 5, 1), ("hopper 15/4", 15, 4), ("walker 24/6", 24, 6)]
BATCH = 256


def batch_of(torch, rng, obs, act):
    """A batch of random transitions in tonic's layout (discounts already gamma^n)."""
    f = torch.float32
    return dict(
        observations=torch.as_tensor(rng.standard_normal((BATCH, obs)), dtype=f),
        actions=torch.as_tensor(rng.uniform(-1, 1, (BATCH, act)), dtype=f),
        next_observations=torch.as_tensor(rng.standard_normal((BATCH, obs)), dtype=f),
        rewards=torch.as_tensor(rng.standard_normal(BATCH), dtype=f),
        discounts=torch.full((BATCH,), 0.99, dtype=f),
    )


def rate(agent, batch, seconds):
    """Updates per second of wall clock and of the process's CPU time (with one thread the
    CPU time is what the update got, which a loaded machine disturbs far less), after five
    updates of warm-up."""
    for _ in range(5):
        agent._update_actor_critic(**batch)
    n, t0, c0 = 0, time.perf_counter(), time.process_time()
    while True:
        agent._update_actor_critic(**batch)
        n += 1
        elapsed = time.perf_counter() - t0
        if elapsed >= seconds:
            return n / elapsed, n / (time.process_time() - c0)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("tonic", help="a clone of tonic's repository")
    ap.add_argument("--threads", type=int, default=1, help="torch's intra-op threads")
    ap.add_argument("--seconds", type=float, default=20.0, help="timed span per size")
    args = ap.parse_args()
    sys.path.insert(0, args.tonic)
    import gym
    import numpy as np
    import torch
    from tonic.torch import agents

    torch.set_num_threads(args.threads)
    torch.manual_seed(0)
    print(f"torch {torch.__version__}, {args.threads} thread(s), batch {BATCH}")
    for name, obs, act in SIZES:
        agent = agents.MPO()
        agent.initialize(
            gym.spaces.Box(-np.inf, np.inf, (obs,), np.float32),
            gym.spaces.Box(-1.0, 1.0, (act,), np.float32),
            seed=0,
        )
        batch = batch_of(torch, np.random.default_rng(0), obs, act)
        wall, cpu = rate(agent, batch, args.seconds)
        print(f"{name:14s} {wall:6.1f} updates/s wall, {cpu:6.1f} by CPU time", flush=True)


if __name__ == "__main__":
    main()
