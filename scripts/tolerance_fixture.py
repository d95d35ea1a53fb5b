#!/usr/bin/env python3
"""Writes sim-bridge/tests/fixtures/tolerance.json: dm_control's rewards.tolerance evaluated on a
grid for every sigmoid, which `sim_bridge::rewards` must reproduce (within 1e-14).

Run with the project venv: .deps/venv/bin/python scripts/tolerance_fixture.py
"""
import json
import os

import numpy as np
from dm_control.utils import rewards

SIGMOIDS = ["gaussian", "hyperbolic", "long_tail", "reciprocal", "cosine", "linear", "quadratic",
            "tanh_squared"]
XS = [-7.5, -2.0, -1.0, -0.3, 0.0, 0.25, 0.5, 0.999, 1.0, 1.2, 1.7, 2.5, 3.0, 4.0, 10.0, 1e3]
CASES = [
    # (bounds, margin, value_at_margin)
    ((0.0, 0.0), 1.0, 0.1),
    ((0.5, 1.5), 2.0, 0.3),
    ((1.0, float("inf")), 0.5, 0.5),
    ((float("-inf"), 0.25), 3.0, 0.01),
]


def main():
    rows = []
    for sigmoid in SIGMOIDS:
        for bounds, margin, vam in CASES:
            for x in XS:
                value = rewards.tolerance(x, bounds=bounds, margin=margin, sigmoid=sigmoid,
                                          value_at_margin=vam)
                rows.append({"sigmoid": sigmoid, "lower": bounds[0], "upper": bounds[1],
                             "margin": margin, "value_at_margin": vam, "x": x,
                             "value": float(value)})
    # value_at_margin = 0 (allowed for the three bounded sigmoids) and margin = 0 (hard bounds).
    for sigmoid in ["cosine", "linear", "quadratic"]:
        for x in XS:
            rows.append({"sigmoid": sigmoid, "lower": 0.0, "upper": 0.0, "margin": 1.0,
                         "value_at_margin": 0.0, "x": x,
                         "value": float(rewards.tolerance(x, margin=1.0, sigmoid=sigmoid,
                                                          value_at_margin=0.0))})
    for x in XS:
        rows.append({"sigmoid": "gaussian", "lower": -1.0, "upper": 1.0, "margin": 0.0,
                     "value_at_margin": 0.1, "x": x,
                     "value": float(rewards.tolerance(x, bounds=(-1.0, 1.0)))})
    out = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "sim-bridge", "tests",
                       "fixtures", "tolerance.json")
    with open(out, "w") as f:
        # json writes inf as Infinity, which serde_json rejects: store bounds as strings.
        for r in rows:
            r["lower"], r["upper"] = repr(r["lower"]), repr(r["upper"])
        json.dump({"rows": rows}, f)
        f.write("\n")


if __name__ == "__main__":
    main()
