"""`python3 -m mpo_plant --gym ENV_ID`: serves a Gymnasium environment as the plant of a run."""

import argparse
import json
import sys

from .server import serve


def main(argv=None):
    ap = argparse.ArgumentParser(
        prog="python3 -m mpo_plant",
        description="Serve a Gymnasium environment as an external plant of `mpo train` "
        "(docs/external-plant.md).",
    )
    ap.add_argument("--gym", required=True, metavar="ENV_ID", help="e.g. Pendulum-v1")
    ap.add_argument(
        "--kwargs",
        default="{}",
        metavar="JSON",
        help="keyword arguments of gymnasium.make, as a JSON object",
    )
    ap.add_argument(
        "--run",
        metavar="RUN_ID",
        help="the learner's run id (default: $MPO_PLANT_RUN, which `mpo` sets when it "
        "starts this program; with `mpo train --attach-plant RUN_ID`, pass the same id)",
    )
    ap.add_argument(
        "--keep-serving",
        action="store_true",
        help="after a learner says BYE, wait for the next one of the same run id",
    )
    ap.add_argument(
        "--idle-timeout",
        type=float,
        metavar="S",
        help="exit after S seconds without a request",
    )
    args = ap.parse_args(argv)
    kwargs = json.loads(args.kwargs)
    if not isinstance(kwargs, dict):
        ap.error("--kwargs must be a JSON object")

    from .gym import GymPlant

    try:
        serve(
            lambda: GymPlant(args.gym, **kwargs),
            args.run,
            keep_serving=args.keep_serving,
            idle_timeout=args.idle_timeout,
        )
    except KeyboardInterrupt:
        return 130
    return 0


if __name__ == "__main__":
    sys.exit(main())
