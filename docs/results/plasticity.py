#!/usr/bin/env python3
"""Signs of lost plasticity in a trained run's networks: dormant units and grown weights.

Usage: "$(scripts/setup-python-plant)" docs/results/plasticity.py [--rows N] [--fresh] CHECKPOINT_DIR...

(numpy is needed: the plant venv of scripts/setup-python-plant has it.) For each run's
`checkpoint/` (params.safetensors, replay.safetensors, meta.json), its online critic and
policy are evaluated on N (default 4096) transitions drawn uniformly from its replay buffer
(seed 0; the stored observations, normalised as the learner does with the policy's input
normalisation, and the stored behaviour actions), and per ReLU layer it prints:

- dormant units (Sokar et al. 2023): a unit whose mean |activation| over the rows is at most
  tau times its layer's average is tau-dormant. tau = 0 counts the units that never fire on
  these states (dead ReLUs); tau = 0.025 is Sokar et al.'s threshold for the units that have
  all but stopped contributing. A network that has lost plasticity has many: their gradients
  are zero or nearly, so no later step revives them;
- how far the incoming weights grew: each output unit's incoming weight vector's L2 norm,
  averaged over the layer's units, against its expectation at initialisation (uniform in
  +-1/sqrt(fan_in): sqrt(1/3) = 0.577). Grown weights make Adam's fixed-size steps a smaller
  fraction of each weight: the effective learning rate decays.

`--fresh` also prints each network at a fresh draw of the same initialisation (numpy's
generator, not the learner's: the same distribution, other numbers) on the same rows: what
the figures are before any learning. The residual networks' layers are `blockD.up` (ReLU of
width F); the MLPs' are `l1` (ReLU, or layer norm and tanh in the critic of rows with
`critic_layer_norm`: then not a ReLU, not counted) and `l2`.
"""
import json
import struct
import sys
from pathlib import Path

import numpy as np

TAUS = (0.0, 0.025)
INIT_NORM = (1.0 / 3.0) ** 0.5


def load(path):
    """The tensors of a safetensors file, as numpy arrays by name."""
    raw = Path(path).read_bytes()
    n = struct.unpack("<Q", raw[:8])[0]
    header = json.loads(raw[8:8 + n])
    out = {}
    for name, t in header.items():
        if name == "__metadata__":
            continue
        a, b = t["data_offsets"]
        dtype = {"F32": np.float32, "U64": np.uint64}[t["dtype"]]
        out[name] = np.frombuffer(raw[8 + n + a:8 + n + b], dtype=dtype).reshape(t["shape"])
    return out


def layer_norm(x, g, b):
    mu = x.mean(axis=1, keepdims=True)
    var = ((x - mu) ** 2).mean(axis=1, keepdims=True)
    return (x - mu) / np.sqrt(var + 1e-5) * g + b


def relu_layers(p, net, x):
    """(name, ReLU activations) of every ReLU layer of network `net` ("actor" or "critic") on
    input rows `x` (the critic's: observation and action concatenated)."""
    out = []
    if f"{net}.block0.up.w" in p:
        if net == "critic":
            obs_dim = p["critic.embed_s.w"].shape[0]
            h = x[:, :obs_dim] @ p["critic.embed_s.w"] + p["critic.embed_s.b"] + x[:, obs_dim:] @ p["critic.embed_a.w"]
        else:
            h = x @ p["actor.embed.w"] + p["actor.embed.b"]
        d = 0
        while f"{net}.block{d}.up.w" in p:
            k = f"{net}.block{d}"
            y = layer_norm(h, p[f"{k}.norm.g"], p[f"{k}.norm.b"])
            u = np.maximum(y @ p[f"{k}.up.w"] + p[f"{k}.up.b"], 0.0)
            out.append((f"block{d}.up", u))
            h = h + u @ p[f"{k}.down.w"] + p[f"{k}.down.b"]
            d += 1
        return out
    if net == "critic":
        obs_dim = p["critic.l1s.w"].shape[0]
        h = x[:, :obs_dim] @ p["critic.l1s.w"] + p["critic.l1s.b"] + x[:, obs_dim:] @ p["critic.l1a.w"]
        if "critic.ln1.g" in p:
            h = np.tanh(layer_norm(h, p["critic.ln1.g"], p["critic.ln1.b"]))
        else:
            h = np.maximum(h, 0.0)
            out.append(("l1", h))
    else:
        h = np.maximum(x @ p["actor.l1.w"] + p["actor.l1.b"], 0.0)
        out.append(("l1", h))
    out.append(("l2", np.maximum(h @ p[f"{net}.l2.w"] + p[f"{net}.l2.b"], 0.0)))
    return out


def hidden_weights(p, net):
    """(name, weight matrix) of the hidden layers' incoming weights (not the heads')."""
    names = [k for k in p if k.startswith(f"{net}.") and k.endswith(".w")
             and not any(h in k for h in (".out.", ".mean.", ".chol."))]
    return [(k[len(net) + 1:-2], p[k]) for k in sorted(names)]


def fresh(p, rng):
    """The same networks' tensors at a fresh draw of the learner's initialisation (uniform in
    +-1/sqrt(fan_in) for weights and biases, layer norms at gain 1 and bias 0)."""
    q = dict(p)
    for k, v in p.items():
        if k.endswith(".w"):
            fan_in = v.shape[0]
            if k.endswith("embed_s.w") or k.endswith("l1s.w"):
                fan_in += p[k.replace("embed_s", "embed_a").replace("l1s", "l1a")].shape[0]
            bound = 1.0 / np.sqrt(fan_in)
            q[k] = rng.uniform(-bound, bound, v.shape).astype(np.float32)
            b = k[:-2] + ".b"
            if b in p:
                q[b] = rng.uniform(-bound, bound, p[b].shape).astype(np.float32)
        elif k.endswith("norm.g") or k.endswith("ln1.g"):
            q[k] = np.ones_like(v)
        elif k.endswith("norm.b") or k.endswith("ln1.b"):
            q[k] = np.zeros_like(v)
    return q


def report(label, p, rows_obs, rows_act):
    """Prints one markdown line per ReLU layer of each network."""
    x_actor = rows_obs
    x_critic = np.concatenate([rows_obs, rows_act], axis=1)
    norms = {}
    for net in ("critic", "actor"):
        for name, w in hidden_weights(p, net):
            norms[(net, name)] = float(np.linalg.norm(w, axis=0).mean()) / INIT_NORM
    for net, x in (("critic", x_critic), ("actor", x_actor)):
        for name, h in relu_layers(p, net, x):
            score = np.abs(h).mean(axis=0)
            score = score / max(score.mean(), 1e-30)
            dormant = [f"{(score <= t).mean() * 100:.1f}%" for t in TAUS]
            w = norms.get((net, name))
            grown = f"{w:.2f}x" if w is not None else "-"
            print(f"| {label} | {net} {name} | {h.shape[1]} | {' | '.join(dormant)} | {grown} |")


def main():
    args = sys.argv[1:]
    if not args or args[0] in ("-h", "--help"):
        print(__doc__.strip(), file=sys.stdout if args else sys.stderr)
        sys.exit(0 if args else 2)
    n, with_fresh = 4096, False
    while args and args[0].startswith("--"):
        if args[0] == "--rows":
            n, args = int(args[1]), args[2:]
        elif args[0] == "--fresh":
            with_fresh, args = True, args[1:]
        else:
            sys.exit(f"unknown option {args[0]}")
    taus = " | ".join(f"dormant, tau {t:g}" for t in TAUS)
    print(f"| run (steps) | layer | units | {taus} | incoming weight norm / init |")
    print("|---|---|---:|---:|---:|---:|")
    for d in args:
        ck = Path(d) / "checkpoint" if (Path(d) / "checkpoint").is_dir() else Path(d)
        p = {k: v for k, v in load(ck / "params.safetensors").items()
             if k.startswith(("actor.", "critic."))}
        steps = int(json.loads((ck / "meta.json").read_text())["env_steps"])
        replay = load(ck / "replay.safetensors")
        # The stored transitions: every step's, or the buffer's capacity once it wrapped.
        idx = np.random.default_rng(0).integers(0, min(steps, len(replay["obs"])), size=n)
        obs = replay["obs"][idx]
        obs = np.clip((obs - p["actor.in.shift"]) * p["actor.in.scale"],
                      -p["actor.in.limit"], p["actor.in.limit"])
        act = replay["action"][idx]
        label = f"{Path(d).resolve().relative_to(Path(d).resolve().parents[2])} ({steps // 1000}k)"
        report(label, p, obs, act)
        if with_fresh:
            report(f"{label.rsplit(' ', 1)[0]} at init", fresh(p, np.random.default_rng(1)), obs, act)


if __name__ == "__main__":
    main()
