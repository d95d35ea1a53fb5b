#!/usr/bin/env python3
"""Summarises `mpo train` run directories into the markdown rows of docs/training.md.

Usage: docs/results/summarize.py RUN_DIR... (each with metrics.csv)
Per run: first environment step whose evaluation mean is >= 900 and the training wall clock
there, best and final evaluation, total wall clock, mean updates/s and env steps/s.
"""
import csv
import sys


def main():
    print("| run | first eval >= 900 at (steps) | wall there (s) | best eval | final eval (mean +- std) | total wall (s) | env steps/s | updates/s |")
    print("|---|---|---|---|---|---|---|---|")
    for d in sys.argv[1:]:
        rows = list(csv.DictReader(open(f"{d}/metrics.csv")))
        first = next((r for r in rows if float(r["eval_return_mean"]) >= 900), None)
        last = rows[-1]
        best = max(float(r["eval_return_mean"]) for r in rows)
        wall = float(last["wall_s"])
        steps = int(last["env_steps"])
        updates = int(last["updates"])
        print(
            f"| {d.rstrip('/').split('/')[-1]} | {first['env_steps'] if first else 'not reached'} | "
            f"{float(first['wall_s']):.0f} | {best:.1f} | "
            f"{float(last['eval_return_mean']):.1f} +- {float(last['eval_return_std']):.1f} | "
            f"{wall:.0f} | {steps / wall:.0f} | {updates / wall:.0f} |"
            if first
            else f"| {d.rstrip('/').split('/')[-1]} | not reached | - | {best:.1f} | "
            f"{float(last['eval_return_mean']):.1f} +- {float(last['eval_return_std']):.1f} | "
            f"{wall:.0f} | {steps / wall:.0f} | {updates / wall:.0f} |"
        )


if __name__ == "__main__":
    main()
