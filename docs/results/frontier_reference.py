#!/usr/bin/env python3
"""Recompute the figures of "Today's sample-efficient agents" in reference.md.

Every figure is the mean +- population std over seeds, with the number of seeds, of each
seed's evaluation return at the last logged evaluation at or before the budget (500k
environment steps; cartpole-balance also 100k). Environment steps are Control Suite control
steps (1000 per episode). Standard library only; each input is read with
`git -C DIR show COMMIT:PATH` from a clone (or a bare copy) of its repository.

Inputs (repository, commit, path):

- SonyResearch/simba @ 7d0358b1f1fa3404fc5ea0ffedf9dc1424b49a45
  (the files were last changed in 4e83770bce6a63ee763c80ef0d9ab105900e5b40):
  `results/sac_simba.csv` (SAC + SimBa), `results/sac.csv` (SAC, the same codebase),
  `results/bro.csv` (BRO as run for the SimBa paper).
  Columns `,exp_name,env_name,seed,metric,env_step,value`; `env_step` counts environment
  steps (`run.py`: `env_step = interaction_step * action_repeat * num_train_envs`).
- dojeon-ai/SimbaV2 @ 14fafb27e6f78f0b65d19b8873b4433547a2193c:
  `results/baseline/simbaV2_utd2.csv`, `results/baseline/simbaV2_utd8.csv`,
  `results/baseline/bro_utd2.csv`, `results/baseline/bro_utd10.csv`,
  `results/baseline/sac.csv`, `results/baseline/mrq.csv` (the same layout as SimBa's).
- naumix/BiggerRegularizedOptimistic @ 5870a13d4bf4f66eeddfc291a59df6d2009de600:
  `trainingdata.zip`, members `trainingdata/BRO/<task>.npy` (replay ratio 10, the default)
  and `trainingdata/BRO_fast/<task>.npy` (replay ratio 2). Each is float64, shape (40, 10),
  Fortran order: 40 evaluations (every 25k environment steps, 25k to 1M; BRO uses no action
  repeat) by 10 seeds. Row 19 is 500k, row 3 is 100k.
- facebookresearch/MRQ @ 8a44a7d4b1cf117e5da4bf8214d35b02aa68d68b:
  `results/dmc_results.txt`, blocks `Env: Dmc-<domain>-<task>` of rows
  `Timestep<TAB>seed 0 ... seed 9`. A Timestep is one agent step of 2 control steps
  (`MRQ/env_preprocessing.py`: `action_repeat: int = 2`), so 500k environment steps is
  Timestep 250000 and 100k is Timestep 50000.
- nicklashansen/tdmpc2 @ e9f59321933cbc8e11a002b842adc7d4ffae8ff1:
  `results/tdmpc2/<task>.csv` and `results/sac/<task>.csv`, columns `step,reward,seed`,
  `step` in environment steps (see reference.md).

Usage: clone the five repositories (`git clone https://github.com/<owner>/<name>`; a bare
clone is enough: files are read at the commits above), then

    python3 docs/results/frontier_reference.py [--per-seed] \
        --simba DIR --simbav2 DIR --bro DIR --mrq DIR --tdmpc2 DIR
"""

import argparse
import ast
import csv
import io
import statistics
import struct
import subprocess
import zipfile

TASKS = [
    "walker-stand", "walker-walk", "walker-run", "cheetah-run", "hopper-stand",
    "hopper-hop", "acrobot-swingup", "pendulum-swingup", "cartpole-swingup",
    "cartpole-balance",
]
BUDGETS = {t: [500_000] for t in TASKS}
BUDGETS["cartpole-balance"] = [100_000, 500_000]

SIMBA = "7d0358b1f1fa3404fc5ea0ffedf9dc1424b49a45"
SIMBAV2 = "14fafb27e6f78f0b65d19b8873b4433547a2193c"
BRO = "5870a13d4bf4f66eeddfc291a59df6d2009de600"
MRQ = "8a44a7d4b1cf117e5da4bf8214d35b02aa68d68b"
TDMPC2 = "e9f59321933cbc8e11a002b842adc7d4ffae8ff1"


def show(repo, commit, path):
    return subprocess.check_output(["git", "-C", repo, "show", f"{commit}:{path}"])


def norm(name):
    return name.replace("_", "-").lower()


def scale_rl_csv(repo, commit, path):
    """SimBa / SimbaV2 layout -> {task: {seed: {env_step: return}}}."""
    out = {}
    for row in csv.DictReader(io.StringIO(show(repo, commit, path).decode())):
        if row["metric"] != "avg_return":
            continue
        task = norm(row["env_name"])
        out.setdefault(task, {}).setdefault(row["seed"], {})[float(row["env_step"])] = float(row["value"])
    return out


def tdmpc2_csv(repo, algo):
    out = {}
    for task in TASKS:
        text = show(repo, TDMPC2, f"results/{algo}/{task}.csv").decode()
        for row in csv.DictReader(io.StringIO(text)):
            out.setdefault(task, {}).setdefault(row["seed"], {})[float(row["step"])] = float(row["reward"])
    return out


def bro_zip(repo, variant):
    z = zipfile.ZipFile(io.BytesIO(show(repo, BRO, "trainingdata.zip")))
    out = {}
    for task in TASKS:
        name = f"trainingdata/{variant}/{task}.npy"
        if name not in z.namelist():
            continue
        raw = z.read(name)
        assert raw[:6] == b"\x93NUMPY"
        hlen = struct.unpack("<H", raw[8:10])[0]
        header = ast.literal_eval(raw[10:10 + hlen].decode())
        assert header["descr"] == "<f8" and header["fortran_order"]
        rows, seeds = header["shape"]
        data = raw[10 + hlen:]
        vals = struct.unpack(f"<{rows * seeds}d", data[:8 * rows * seeds])
        # Fortran order: element [i, j] (evaluation i, seed j) is vals[i + rows * j].
        out[task] = {str(j): {25_000.0 * (i + 1): vals[i + rows * j] for i in range(rows)}
                     for j in range(seeds)}
    return out


def mrq_txt(repo, action_repeat=2):
    out, task = {}, None
    for line in show(repo, MRQ, "results/dmc_results.txt").decode().splitlines():
        if line.startswith("Env:"):
            name = line.split()[1]
            task = None if "visual" in name else norm(name[len("Dmc-"):])
            continue
        if task is None or not line.strip() or line.startswith("-") or line.startswith("Timestep"):
            continue
        cols = [c for c in line.split("\t") if c != ""]
        step = float(cols[0]) * action_repeat
        for seed, v in enumerate(cols[1:]):
            out.setdefault(task, {}).setdefault(str(seed), {})[step] = float(v)
    return out


def at_budget(curves, task, budget):
    """Per-seed returns at the last evaluation <= budget; None if absent."""
    if task not in curves:
        return None
    vals = []
    for seed in sorted(curves[task], key=lambda s: int(s)):
        steps = [s for s in curves[task][seed] if s <= budget]
        if not steps:
            return None
        vals.append(curves[task][seed][max(steps)])
    return vals


def cell(vals):
    if vals is None:
        return "n/a"
    return f"{statistics.mean(vals):.1f} +- {statistics.pstdev(vals):.1f} ({len(vals)})"


def table(title, columns):
    print(f"\n{title}\n")
    print("| task | budget | " + " | ".join(name for name, _ in columns) + " |")
    print("|---|---|" + "---|" * len(columns))
    for task in TASKS:
        for budget in BUDGETS[task]:
            cells = [cell(at_budget(c, task, budget)) for _, c in columns]
            print(f"| {task} | {budget // 1000}k | " + " | ".join(cells) + " |")


def main():
    p = argparse.ArgumentParser()
    p.add_argument("--simba", required=True, metavar="DIR", help="a clone of SonyResearch/simba")
    p.add_argument("--simbav2", required=True, metavar="DIR", help="a clone of dojeon-ai/SimbaV2")
    p.add_argument("--bro", required=True, metavar="DIR", help="a clone of naumix/BiggerRegularizedOptimistic")
    p.add_argument("--mrq", required=True, metavar="DIR", help="a clone of facebookresearch/MRQ")
    p.add_argument("--tdmpc2", required=True, metavar="DIR", help="a clone of nicklashansen/tdmpc2")
    p.add_argument("--per-seed", action="store_true", help="also print every seed's value")
    a = p.parse_args()

    simba = scale_rl_csv(a.simba, SIMBA, "results/sac_simba.csv")
    simba_sac = scale_rl_csv(a.simba, SIMBA, "results/sac.csv")
    simba_bro = scale_rl_csv(a.simba, SIMBA, "results/bro.csv")
    v2 = scale_rl_csv(a.simbav2, SIMBAV2, "results/baseline/simbaV2_utd2.csv")
    v2_utd8 = scale_rl_csv(a.simbav2, SIMBAV2, "results/baseline/simbaV2_utd8.csv")
    v2_bro2 = scale_rl_csv(a.simbav2, SIMBAV2, "results/baseline/bro_utd2.csv")
    v2_bro10 = scale_rl_csv(a.simbav2, SIMBAV2, "results/baseline/bro_utd10.csv")
    v2_sac = scale_rl_csv(a.simbav2, SIMBAV2, "results/baseline/sac.csv")
    v2_mrq = scale_rl_csv(a.simbav2, SIMBAV2, "results/baseline/mrq.csv")
    bro = bro_zip(a.bro, "BRO")
    bro_fast = bro_zip(a.bro, "BRO_fast")
    mrq = mrq_txt(a.mrq)
    td = tdmpc2_csv(a.tdmpc2, "tdmpc2")
    td_sac = tdmpc2_csv(a.tdmpc2, "sac")

    main_cols = [
        ("TD-MPC2 (tdmpc2)", td),
        ("SimBa: SAC + SimBa (simba)", simba),
        ("SimbaV2 utd2 (SimbaV2)", v2),
        ("BRO, replay ratio 10 (BRO authors)", bro),
        ("MR.Q (MRQ authors)", mrq),
    ]
    other_cols = [
        ("BRO fast, replay ratio 2 (BRO authors)", bro_fast),
        ("BRO (simba results/bro.csv)", simba_bro),
        ("BRO utd2 (SimbaV2)", v2_bro2),
        ("BRO utd10 (SimbaV2)", v2_bro10),
        ("SimbaV2 utd8 (SimbaV2)", v2_utd8),
        ("MR.Q (SimbaV2 copy)", v2_mrq),
    ]
    sac_cols = [
        ("SAC (tdmpc2 results/sac)", td_sac),
        ("SAC (simba results/sac.csv)", simba_sac),
        ("SAC (SimbaV2 results/baseline/sac.csv)", v2_sac),
        ("SAC + SimBa (simba results/sac_simba.csv)", simba),
    ]
    table("Main table", main_cols)
    table("Other BRO, SimbaV2 and MR.Q files", other_cols)
    table("SAC baselines and SAC + SimBa", sac_cols)

    if a.per_seed:
        print("\nPer-seed values (seeds in ascending order of their label)\n")
        for name, curves in main_cols + other_cols + sac_cols:
            for task in TASKS:
                for budget in BUDGETS[task]:
                    vals = at_budget(curves, task, budget)
                    if vals is not None:
                        print(f"{name} | {task} @{budget // 1000}k | " + ", ".join(f"{v:.1f}" for v in vals))


if __name__ == "__main__":
    main()
