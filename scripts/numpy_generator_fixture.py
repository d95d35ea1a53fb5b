#!/usr/bin/env python3
"""Writes sim-bridge/tests/fixtures/numpy_generator.json: what numpy's
Generator(PCG64(SeedSequence(seed))) (Gymnasium's seeding) gives, for
`sim_bridge::numpy_generator` to reproduce bit for bit.

Run with the project venv: .deps/venv/bin/python scripts/numpy_generator_fixture.py
Per seed: SeedSequence(seed).generate_state(4, uint64), PCG64's first raw outputs, a program
of interleaved draws (values listed), and the sha256 of 10^6 standard normals (the
little-endian float64 bytes): every ziggurat layer is used thousands of times, the tail and
the wedges included, so a wrong table entry shows there.
"""
import hashlib
import json
import os

import numpy as np

PROGRAM = (
    [("random",)] * 3
    + [("standard_normal",)] * 5
    + [("uniform", -0.1, 0.1)] * 9
    + [("standard_normal",)] * 9
    + [("uniform", -np.pi, np.pi), ("standard_normal",), ("uniform", 5.0, 150.0)]
    + [("random",)] * 50
    + [("standard_normal",)] * 200
)
LONG = 1_000_000


def main():
    cases = []
    for seed in [0, 1, 42, 2**32 - 1, 2**40 + 5]:
        state = np.random.SeedSequence(seed).generate_state(4, np.uint64)
        raw = np.random.PCG64(np.random.SeedSequence(seed)).random_raw(5)
        g = np.random.Generator(np.random.PCG64(np.random.SeedSequence(seed)))
        values = []
        for op in PROGRAM:
            if op[0] == "random":
                values.append(float(g.random()))
            elif op[0] == "standard_normal":
                values.append(float(g.standard_normal()))
            else:
                values.append(float(g.uniform(op[1], op[2])))
        g = np.random.Generator(np.random.PCG64(np.random.SeedSequence(seed)))
        long = g.standard_normal(LONG).astype("<f8").tobytes()
        cases.append({
            "seed": seed,
            "seed_sequence_state": [str(int(x)) for x in state],
            "raw": [str(int(x)) for x in raw],
            "values": values,
            "normals_sha256": hashlib.sha256(long).hexdigest(),
        })
    out = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "sim-bridge", "tests",
                       "fixtures", "numpy_generator.json")
    with open(out, "w") as f:
        json.dump({"numpy": np.__version__, "program": [list(op) for op in PROGRAM],
                   "long_normals": LONG, "cases": cases}, f)
        f.write("\n")


if __name__ == "__main__":
    main()
