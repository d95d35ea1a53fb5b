#!/usr/bin/env python3
"""Writes sim-bridge/tests/fixtures/numpy_random_state.json: draws from numpy's legacy
RandomState(seed) that `sim_bridge::numpy_rng::RandomState` must reproduce bit for bit.

Run with any numpy (the project venv has one): .deps/venv/bin/python scripts/numpy_rng_fixture.py
Each case is a seed and a program of draws, interleaved so that the Gaussian cache survives other
draws and the MT19937 state is regenerated (every 624 words) several times.
"""
import json
import os

import numpy as np

PROGRAM = (
    [("random_sample",)] * 3
    + [("standard_normal",)] * 5
    + [("uniform", -np.pi, np.pi)] * 2
    + [("standard_normal",)]
    + [("uniform", -0.034, 0.034), ("standard_normal",), ("uniform", 5.0, 150.0)]
    + [("random_sample",)] * 400
    + [("standard_normal",)] * 101
)


def main():
    cases = []
    for seed in [0, 42, 2**32 - 1]:
        rs = np.random.RandomState(seed)
        values = []
        for op in PROGRAM:
            if op[0] == "random_sample":
                values.append(float(rs.random_sample()))
            elif op[0] == "standard_normal":
                values.append(float(rs.randn()))
            else:
                values.append(float(rs.uniform(op[1], op[2])))
        cases.append({"seed": seed, "values": values})
    program = [list(op) for op in PROGRAM]
    out = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "sim-bridge", "tests",
                       "fixtures", "numpy_random_state.json")
    with open(out, "w") as f:
        json.dump({"numpy": np.__version__, "program": program, "cases": cases}, f)
        f.write("\n")


if __name__ == "__main__":
    main()
