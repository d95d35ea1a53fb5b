#!/usr/bin/env python3
"""Pairs each evaluation episode's return with the pendulum's start angle.

Usage: mpo eval --checkpoint RUN --episodes K > eval.json   (venv: scripts/setup-dm-control)
       .deps/venv/bin/python docs/results/start_angles.py eval.json

`mpo eval` runs episode i on environment seed (2^31 + 1000 S + i) mod 2^32 (S = the run's
seed, in the JSON); dm_control's pendulum-swingup reset with the same seed gives the start
angle (our task is bit-exact to it), read here from its observation. Prints one line per
episode (angle from upright in degrees, 180 = hanging down) sorted by |angle|, then how many
episodes return 0 among starts with |angle| >= 130 degrees and among the rest.
"""
import json
import math
import sys

from dm_control import suite


def main():
    run = json.load(open(sys.argv[1]))
    rows = []
    for i, ret in enumerate(run["returns"]):
        seed = (2**31 + 1000 * run["seed"] + i) % 2**32
        obs = suite.load("pendulum", "swingup", task_kwargs={"random": seed}).reset().observation
        cos, sin = obs["orientation"]
        rows.append((abs(math.degrees(math.atan2(sin, cos))), i, ret))
    for angle, i, ret in sorted(rows):
        print(f"episode {i:3}  |angle from upright| {angle:6.1f}  return {ret:7.1f}")
    low = [r for a, _, r in rows if a >= 130]
    high = [r for a, _, r in rows if a < 130]
    print(f"|angle| >= 130: {sum(r == 0 for r in low)} of {len(low)} return 0")
    print(f"|angle| <  130: {sum(r == 0 for r in high)} of {len(high)} return 0"
          f" (the others {min((r for r in high if r > 0), default=0):.0f}-{max(high, default=0):.0f})")


if __name__ == "__main__":
    main()
