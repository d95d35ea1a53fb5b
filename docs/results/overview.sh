#!/bin/sh
# docs/results/overview.png: every task's runs at its row's current default, one panel per
# task over its step budget, the issue-13 targets as dashed lines. Run from the repository root after a release
# build: docs/results/overview.sh [MPO_BINARY]
set -eu
mpo=${1:-target/release/mpo}
r=docs/results
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
# link TASK SEED DIR: the run DIR as the curve "seedSEED" in TASK's panel
link() { mkdir -p "$tmp/$1"; ln -s "$PWD/$r/$1/$3" "$tmp/$1/seed$2"; }
for s in 0 1 2 3 4; do link cartpole-balance $s clip-dual-1e-3-seed$s; done
# pendulum-swingup: the `ceiling` row, its default since 2026-12-07 (the MLP seeds: mlp-seed*).
for s in 0 1 2; do link pendulum-swingup $s mlp-alphamax1e3-seed$s; done
# walker-stand: seed 0 run on to 500k as mlp-seed0 (default-seed0 is its first 300k).
link walker-stand 0 mlp-seed0
for s in 1 2; do link walker-stand $s default-seed$s; done
for s in 0 1 2; do link walker-walk $s default-seed$s; done
# walker-run: the `simba` row, its default since 2026-12-07 (the MLP seeds: default-seed0,
# mlp-seed1, mlp-seed2).
for s in 0 1 2; do link walker-run $s simba-seed$s; done
# cheetah-run: seeds 0 and 1 run on to 500k as mlp-seed0/1 (default-seed0/1 are their first 480k).
for s in 0 1; do link cheetah-run $s mlp-seed$s; done
link cheetah-run 2 default-seed2
# hopper-stand: the `simba` row, its default since 2026-12-06 (one seed; the MLP seeds:
# eps-penalty-0.01-seed*).
link hopper-stand 0 simba-seed0
# hopper-hop: the `simba` row, its default since 2026-12-05 (the MLP seeds: eps-penalty-0.01-seed*).
for s in 0 1 2; do link hopper-hop $s simba-seed$s; done
# acrobot-swingup: the `simba` row, its default since 2026-12-06 (the MLP seed: noise-0.95-seed0).
for s in 0 1 2; do link acrobot-swingup $s simba-seed$s; done
# cartpole-swingup: the `simba` row, its default since 2026-12-06 (the MLP seeds: default-seed*).
for s in 0 1 2; do link cartpole-swingup $s simba-seed$s; done
set --
for t in cartpole-balance cartpole-swingup pendulum-swingup walker-stand walker-walk walker-run \
    cheetah-run hopper-stand hopper-hop acrobot-swingup; do
    set -- "$@" "$tmp/$t"/seed*
done
LD_LIBRARY_PATH=${LD_LIBRARY_PATH:-}:$PWD/.deps/mujoco "$mpo" plot --by-task \
    --title "MPO (this repository) on the Control Suite: evaluation return, every seed run at each row's default" \
    --target cartpole-balance=900 --target cartpole-swingup=800 --target pendulum-swingup=750 \
    --target walker-stand=950 --target walker-walk=900 --target walker-run=500 \
    --target cheetah-run=600 --target hopper-stand=700 --target hopper-hop=100 \
    --budget cartpole-swingup=500000 --budget pendulum-swingup=500000 --budget walker-walk=500000 --budget walker-run=500000 \
    --budget cheetah-run=1000000 --budget hopper-stand=1000000 --budget hopper-hop=500000 \
    --budget acrobot-swingup=500000 \
    --out "$r/overview.png" "$@"
